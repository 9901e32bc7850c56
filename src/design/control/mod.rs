//! Control utilities on dense matrices: matrix exponential, zero-order-hold discretization,
//! Lyapunov and Riccati equations, LQR gains, H2 and H∞ norms.
//!
//! All functions take [`DMatrix<f64>`] by reference, check shapes, finiteness and symmetry
//! first, and return [`ControlError`] (never panic) on bad input or when the requested solution
//! does not exist.
//!
//! # Conventions
//!
//! | function | equation solved | as in |
//! |---|---|---|
//! | [`lyap`]`(A, Q)` | A X + X Aᵀ + Q = 0 | MATLAB `lyap(A, Q)` |
//! | [`dlyap`]`(A, Q)` | A X Aᵀ − X + Q = 0 | MATLAB `dlyap(A, Q)` |
//! | [`care`]`(A, B, Q, R)` | Aᵀ P + P A − P B R⁻¹ Bᵀ P + Q = 0, A − B R⁻¹ Bᵀ P Hurwitz | `scipy.linalg.solve_continuous_are` |
//! | [`are`]`(A, G, Q)` | Aᵀ X + X A − X G X + Q = 0, G = Gᵀ of any sign, A − G X Hurwitz | — |
//! | [`detectable`]`(A, C)` | every mode in the kernel of the observability matrix is stable | MATLAB `obsv` + `eig` |
//! | [`dare`]`(A, B, Q, R)` | Aᵀ P A − P − Aᵀ P B (R + Bᵀ P B)⁻¹ Bᵀ P A + Q = 0, A − B K Schur stable | `scipy.linalg.solve_discrete_are` |
//! | [`lqr`]`(A, B, Q, R)` | u = −K x minimizing ∫ xᵀQx + uᵀRu dt; K = R⁻¹ Bᵀ P | MATLAB `lqr` |
//! | [`dlqr`]`(A, B, Q, R)` | u = −K x minimizing Σ xᵀQx + uᵀRu; K = (R + Bᵀ P B)⁻¹ Bᵀ P A | MATLAB `dlqr` |
//! | [`c2d`]`(A, B, Ts)` | zero-order hold: [Ad Bd; 0 I] = exp([A B; 0 0]·Ts) | MATLAB `c2d(sys, Ts, 'zoh')` |
//!
//! # Methods (and why)
//!
//! - **Lyapunov / Stein equations**: Bartels–Stewart on the real Schur form of A (nalgebra's
//!   Francis QR), solving 1×1/2×2 diagonal blocks exactly: O(n³), backward stable.
//! - **Discrete Riccati**: the structure-preserving doubling algorithm (SDA, Chu–Fan–Lin 2005),
//!   which converges quadratically to the stabilizing solution using only linear solves (no
//!   eigenvector reordering, which nalgebra lacks), followed by Newton (Hewer) refinement steps
//!   (each one Stein equation) from that stabilizing start, which bring the residual to
//!   rounding level.
//! - **Continuous Riccati**: the matrix sign function of the Hamiltonian (Newton iteration with
//!   determinant scaling, Byers 1987) gives the stable invariant subspace; P is read off by least
//!   squares, then Newton–Kleinman refinement steps (each one Lyapunov equation) polish it.
//!   Both Riccati solvers check at the end that the closed loop is stable; if it is not, the
//!   pair is reported [`ControlError::NotStabilizable`].
//! - **H2 norm**: controllability Gramian (one Lyapunov/Stein equation).
//! - **H∞ norm**: the Bruinsma–Steinbuch / Boyd–Balakrishnan level-set iteration on the
//!   Hamiltonian's imaginary-axis eigenvalues (quadratically convergent, returns a lower bound
//!   attained at a frequency, accurate to a relative 1e-10); discrete systems are mapped to
//!   continuous ones by the bilinear transform z = (1 + s)/(1 − s), which preserves the H∞ norm.

mod lyapunov;
mod norms;
mod riccati;
mod structure;
#[cfg(test)]
pub(crate) mod tests;

pub use lyapunov::{dlyap, lyap};
pub use norms::{HinfNorm, Sampling, StateSpace, h2_norm, hinf_norm};
pub use riccati::{Lqr, are, are_residual, care, care_residual, dare, dare_residual, dlqr, lqr};
pub use structure::{detectable, unobservable_modes};

use nalgebra::DMatrix;
use thiserror::Error;

/// Why a control computation failed. Matrices are named as in the function signature.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ControlError {
    /// A matrix that must be square is not.
    #[error("{name} must be square, found {rows}×{cols}")]
    NotSquare {
        /// Argument name (`A`, `Q`, ...).
        name: &'static str,
        /// Rows found.
        rows: usize,
        /// Columns found.
        cols: usize,
    },
    /// A matrix has the wrong shape for the others.
    #[error("{name} must {}, found {}×{}", shape_wanted(*expected, *found), found.0, found.1)]
    ShapeMismatch {
        /// Argument name.
        name: &'static str,
        /// Expected (rows, columns).
        expected: (usize, usize),
        /// Found (rows, columns).
        found: (usize, usize),
    },
    /// A matrix contains NaN or infinity.
    #[error("{name} contains a non-finite entry")]
    NonFinite {
        /// Argument name.
        name: &'static str,
    },
    /// A matrix that must be symmetric is not (relative asymmetry ‖M − Mᵀ‖/‖M‖ above 1e-10).
    #[error("{name} must be symmetric (relative asymmetry {asymmetry:.1e})")]
    NotSymmetric {
        /// Argument name.
        name: &'static str,
        /// ‖M − Mᵀ‖_F / ‖M‖_F.
        asymmetry: f64,
    },
    /// A matrix that must be positive definite is not.
    #[error("{name} must be positive definite")]
    NotPositiveDefinite {
        /// Argument name.
        name: &'static str,
    },
    /// A sampling time that must be positive and finite is not.
    #[error("sampling time must be positive and finite, found {ts}")]
    BadSamplingTime {
        /// The value given.
        ts: f64,
    },
    /// A linear system met on the way is singular: the equation has no unique solution.
    #[error("singular problem: {what}")]
    Singular {
        /// Which system and what it means.
        what: &'static str,
    },
    /// No stabilizing Riccati solution: (A, B) is not stabilizable or (A, Q) has unobservable
    /// modes on the stability boundary.
    #[error(
        "no stabilizing solution: (A, B) is not stabilizable or (Q, A) has unobservable modes on the stability boundary ({method})"
    )]
    NotStabilizable {
        /// Which solver detected it.
        method: &'static str,
    },
    /// A norm was asked of an unstable system (it is infinite).
    #[error(
        "the system is not stable (spectral abscissa/radius {margin:.3e}); its {norm} norm is infinite"
    )]
    Unstable {
        /// `"H2"` or `"H∞"`.
        norm: &'static str,
        /// max Re λ (continuous) or max |λ| (discrete).
        margin: f64,
    },
    /// The continuous-time H2 norm with a nonzero feedthrough D is infinite.
    #[error("the continuous-time H2 norm is infinite when D ≠ 0")]
    NonzeroFeedthrough,
    /// An iteration did not converge.
    #[error("{method} did not converge in {iterations} iterations")]
    NoConvergence {
        /// Which iteration.
        method: &'static str,
        /// Iterations done.
        iterations: usize,
    },
}

pub(crate) fn check_square(name: &'static str, m: &DMatrix<f64>) -> Result<usize, ControlError> {
    if m.nrows() != m.ncols() {
        return Err(ControlError::NotSquare {
            name,
            rows: m.nrows(),
            cols: m.ncols(),
        });
    }
    check_finite(name, m)?;
    Ok(m.nrows())
}

/// What a [`ControlError::ShapeMismatch`] asks for: the rows or the
/// columns alone when only they are wrong (`B` of `n` rows may have any
/// number of columns: "2×2" for a 1×2 `B` read as a demand for two columns).
fn shape_wanted(expected: (usize, usize), found: (usize, usize)) -> String {
    match (expected.0 == found.0, expected.1 == found.1) {
        (false, true) => format!("have {} rows", expected.0),
        (true, false) => format!("have {} columns", expected.1),
        _ => format!("be {}×{}", expected.0, expected.1),
    }
}

pub(crate) fn check_shape(
    name: &'static str,
    m: &DMatrix<f64>,
    rows: usize,
    cols: usize,
) -> Result<(), ControlError> {
    if m.shape() != (rows, cols) {
        return Err(ControlError::ShapeMismatch {
            name,
            expected: (rows, cols),
            found: m.shape(),
        });
    }
    check_finite(name, m)
}

pub(crate) fn check_finite(name: &'static str, m: &DMatrix<f64>) -> Result<(), ControlError> {
    if m.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(ControlError::NonFinite { name })
    }
}

pub(crate) fn check_symmetric(name: &'static str, m: &DMatrix<f64>) -> Result<(), ControlError> {
    let norm = m.norm();
    let asym = (m - m.transpose()).norm();
    if asym > 1e-10 * norm.max(f64::MIN_POSITIVE) {
        return Err(ControlError::NotSymmetric {
            name,
            asymmetry: asym / norm,
        });
    }
    Ok(())
}

pub(crate) fn symmetrize(m: &DMatrix<f64>) -> DMatrix<f64> {
    (m + m.transpose()) * 0.5
}

/// The matrix exponential e^A (Padé approximation with scaling and squaring, Al-Mohy–Higham,
/// as implemented by nalgebra's [`nalgebra::Matrix::exp`]).
pub fn expm(a: &DMatrix<f64>) -> Result<DMatrix<f64>, ControlError> {
    check_square("A", a)?;
    if a.nrows() == 0 {
        return Ok(a.clone());
    }
    let e = a.exp();
    check_finite("expm(A) (overflow)", &e)?;
    Ok(e)
}

/// Zero-order-hold discretization of ẋ = A x + B u with sampling time `ts`:
/// returns (Ad, Bd) with Ad = e^{A Ts}, Bd = ∫₀^Ts e^{A s} ds B, read off the exponential of the
/// augmented matrix [A B; 0 0]·Ts (which is exact also for singular A).
pub fn c2d(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    ts: f64,
) -> Result<(DMatrix<f64>, DMatrix<f64>), ControlError> {
    let n = check_square("A", a)?;
    check_shape("B", b, n, b.ncols())?;
    if !(ts.is_finite() && ts > 0.0) {
        return Err(ControlError::BadSamplingTime { ts });
    }
    let m = b.ncols();
    let mut aug = DMatrix::zeros(n + m, n + m);
    aug.view_mut((0, 0), (n, n)).copy_from(&(a * ts));
    aug.view_mut((0, n), (n, m)).copy_from(&(b * ts));
    let e = expm(&aug)?;
    Ok((
        e.view((0, 0), (n, n)).into_owned(),
        e.view((0, n), (n, m)).into_owned(),
    ))
}
