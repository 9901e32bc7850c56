//! Decompositions that always end. nalgebra's `svd`, `singular_values` and
//! `symmetric_eigenvalues` iterate until convergence with no iteration
//! bound: on a matrix with a NaN or infinite entry, or with entries so large
//! that their squares overflow (|a| ≳ 1e154, e.g. a parameter `1e300`), they
//! never converge and the program hangs. Every decomposition of hybsim goes
//! through here: non-finite matrices are refused (`None`), the others are
//! scaled by a power of two (exact) so that their largest entry is about 1
//! before decomposing, and the SVD has an iteration bound besides.

use nalgebra::{ComplexField, DMatrix, DVector, Dyn, SVD};

/// Sweeps of the SVD's implicit QR iteration per singular value before it
/// gives up (converged problems need a handful).
const SVD_SWEEPS: usize = 100;

/// The power of two that brings the largest |entry| of `m` near 1, or
/// `None` if an entry is not finite.
fn scale_of<T: ComplexField<RealField = f64>>(m: &DMatrix<T>) -> Option<f64> {
    let mut amax = 0.0f64;
    for v in m.iter() {
        let a = v.clone().modulus();
        if !a.is_finite() {
            return None;
        }
        amax = amax.max(a);
    }
    // Only large entries need it (tiny ones underflow harmlessly, and 2^e of a tiny amax would
    // overflow): 2^-e with e the binary exponent of amax, exact, no rounding added.
    if amax <= 2f64.powi(64) {
        return Some(1.0);
    }
    Some(2f64.powi(-amax.log2().round() as i32))
}

/// Singular values (unordered) of a real matrix, or `None` if it has a
/// non-finite entry or the iteration did not converge.
pub fn singular_values(m: &DMatrix<f64>) -> Option<DVector<f64>> {
    svd(m, false, false).map(|s| s.singular_values)
}

/// The SVD of a real matrix (singular values unordered: nalgebra's sort
/// panics on a NaN), or `None` if it has a non-finite entry or the
/// iteration did not converge.
pub fn svd(m: &DMatrix<f64>, compute_u: bool, compute_v: bool) -> Option<SVD<f64, Dyn, Dyn>> {
    let s = scale_of(m)?;
    let sweeps = SVD_SWEEPS * m.nrows().min(m.ncols()).max(1);
    let mut d = SVD::try_new_unordered(m * s, compute_u, compute_v, f64::EPSILON, sweeps)?;
    d.singular_values /= s;
    d.singular_values.iter().all(|v| v.is_finite()).then_some(d)
}

/// Eigenvalues of a real symmetric or complex Hermitian matrix, or `None`
/// if it has a non-finite entry. Scaled, nalgebra's iteration converges.
pub fn symmetric_eigenvalues<T: ComplexField<RealField = f64>>(
    m: &DMatrix<T>,
) -> Option<DVector<f64>> {
    let s = scale_of(m)?;
    let scaled = m.map(|v| v.scale(s));
    let e = scaled.symmetric_eigenvalues() / s;
    e.iter().all(|v| v.is_finite()).then_some(e)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn huge_and_non_finite_matrices_end() {
        // These hung in nalgebra (the squares of 1e300 overflow).
        let huge = DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 1.0, -1e300]);
        let s = singular_values(&huge).unwrap();
        assert!((s.max() - 1e300).abs() <= 1e285, "{s}");
        let e = symmetric_eigenvalues(&huge).unwrap();
        assert!((e.min() + 1e300).abs() <= 1e285, "{e}");
        let tiny = DMatrix::from_row_slice(2, 2, &[0.0, 1e-320, 0.0, -1e-308]);
        assert!(singular_values(&tiny).unwrap().max() > 0.0);
        let nan = DMatrix::from_row_slice(2, 2, &[0.0, f64::NAN, 1.0, 2.0]);
        assert!(singular_values(&nan).is_none());
        assert!(symmetric_eigenvalues(&nan).is_none());
        assert!(svd(&DMatrix::from_element(2, 3, f64::INFINITY), true, true).is_none());
        // Ordinary matrices: the same values as unscaled.
        let a = DMatrix::from_row_slice(2, 2, &[3.0, 1.0, 1.0, 3.0]);
        let mut e: Vec<f64> = symmetric_eigenvalues(&a).unwrap().iter().copied().collect();
        e.sort_by(f64::total_cmp);
        assert!((e[0] - 2.0).abs() < 1e-14 && (e[1] - 4.0).abs() < 1e-14);
        let d = svd(&a, true, true).unwrap();
        assert!((d.recompose().unwrap() - &a).amax() < 1e-14);
    }
}
