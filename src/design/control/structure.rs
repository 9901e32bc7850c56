//! Structural properties of (A, C): the unobservable modes and detectability.

use nalgebra::{Complex, DMatrix};

use super::lyapunov::eigenvalues;
use super::{ControlError, check_shape, check_square};

/// Relative threshold on the singular values of the observability matrix
/// below which a direction counts as unobservable.
const RANK_TOL: f64 = 1e-9;

/// The eigenvalues of A restricted to the unobservable subspace of (A, C),
/// the kernel of O = [C; C A; …; C Aⁿ⁻¹] (singular values of O at most
/// 1e-9·max(σ_max, 1) count as zero). Empty when (A, C) is observable.
pub fn unobservable_modes(
    a: &DMatrix<f64>,
    c: &DMatrix<f64>,
) -> Result<Vec<Complex<f64>>, ControlError> {
    let n = check_square("A", a)?;
    check_shape("C", c, c.nrows(), n)?;
    if n == 0 {
        return Ok(Vec::new());
    }
    let p = c.nrows().max(1);
    let mut o = DMatrix::zeros(p * n, n);
    let mut block = if c.nrows() == 0 {
        DMatrix::zeros(1, n)
    } else {
        c.clone()
    };
    for k in 0..n {
        o.view_mut((k * p, 0), (p, n)).copy_from(&block);
        block = &block * a;
    }
    if !o.iter().all(|v| v.is_finite()) {
        return Err(ControlError::NonFinite { name: "A" });
    }
    let svd = crate::linalg::svd(&o, false, true).ok_or(ControlError::NoConvergence {
        method: "unobservable_modes (SVD)",
        iterations: 0,
    })?;
    let v_t = svd.v_t.ok_or(ControlError::NoConvergence {
        method: "unobservable_modes (SVD)",
        iterations: 0,
    })?;
    let smax = svd.singular_values.max().max(1.0);
    let kernel: Vec<usize> = (0..n)
        .filter(|&i| {
            svd.singular_values
                .get(i)
                .is_none_or(|s| *s <= RANK_TOL * smax)
        })
        .collect();
    if kernel.is_empty() {
        return Ok(Vec::new());
    }
    let v = DMatrix::from_fn(n, kernel.len(), |r, k| v_t[(kernel[k], r)]);
    eigenvalues(&(v.transpose() * a * &v))
}

/// Whether (A, C) is detectable: every unobservable mode has a negative real
/// part (below −1e-9·max(‖A‖, 1), so that a computed 0 counts as unstable).
pub fn detectable(a: &DMatrix<f64>, c: &DMatrix<f64>) -> Result<bool, ControlError> {
    let tol = RANK_TOL * a.norm().max(1.0);
    Ok(unobservable_modes(a, c)?.iter().all(|l| l.re < -tol))
}
