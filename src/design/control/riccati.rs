//! Algebraic Riccati equations (continuous and discrete) and LQR gains.

use nalgebra::{Complex, DMatrix};

use super::lyapunov::{dlyap, eigenvalues, lyap, spectral_abscissa, spectral_radius};
use super::{ControlError, check_shape, check_square, check_symmetric, symmetrize};

/// An LQR design: gain, Riccati solution and closed-loop poles.
#[derive(Debug, Clone, PartialEq)]
pub struct Lqr {
    /// State-feedback gain, applied as u = −K x (m×n).
    pub k: DMatrix<f64>,
    /// Stabilizing solution of the Riccati equation (n×n, symmetric).
    pub p: DMatrix<f64>,
    /// Eigenvalues of A − B K.
    pub poles: Vec<Complex<f64>>,
}

const SDA_MAX_ITER: usize = 100;
const SIGN_MAX_ITER: usize = 100;
const REFINE_STEPS: usize = 4;

/// Checks shapes of (A, B, Q, R), symmetry of Q and R, R ≻ 0; returns (n, m, R⁻¹ Bᵀ).
fn check_riccati_data(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    q: &DMatrix<f64>,
    r: &DMatrix<f64>,
) -> Result<(usize, DMatrix<f64>), ControlError> {
    let n = check_square("A", a)?;
    check_shape("B", b, n, b.ncols())?;
    let m = b.ncols();
    check_shape("Q", q, n, n)?;
    check_symmetric("Q", q)?;
    check_shape("R", r, m, m)?;
    check_symmetric("R", r)?;
    let chol = symmetrize(r)
        .cholesky()
        .ok_or(ControlError::NotPositiveDefinite { name: "R" })?;
    Ok((n, chol.solve(&b.transpose())))
}

/// Residual of the continuous algebraic Riccati equation, ‖Aᵀ P + P A − P B R⁻¹ Bᵀ P + Q‖_F.
pub fn care_residual(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    q: &DMatrix<f64>,
    r: &DMatrix<f64>,
    p: &DMatrix<f64>,
) -> Result<f64, ControlError> {
    let (n, rinv_bt) = check_riccati_data(a, b, q, r)?;
    check_shape("P", p, n, n)?;
    let res = a.transpose() * p + p * a - p * b * (&rinv_bt * p) + q;
    Ok(res.norm())
}

/// Residual of the discrete algebraic Riccati equation,
/// ‖Aᵀ P A − P − Aᵀ P B (R + Bᵀ P B)⁻¹ Bᵀ P A + Q‖_F.
pub fn dare_residual(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    q: &DMatrix<f64>,
    r: &DMatrix<f64>,
    p: &DMatrix<f64>,
) -> Result<f64, ControlError> {
    let (n, _) = check_riccati_data(a, b, q, r)?;
    check_shape("P", p, n, n)?;
    let k = discrete_gain(a, b, r, p)?;
    let res = a.transpose() * p * a - p - a.transpose() * p * b * k + q;
    Ok(res.norm())
}

/// K = (R + Bᵀ P B)⁻¹ Bᵀ P A.
fn discrete_gain(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    r: &DMatrix<f64>,
    p: &DMatrix<f64>,
) -> Result<DMatrix<f64>, ControlError> {
    let bt_p = b.transpose() * p;
    let s = r + &bt_p * b;
    symmetrize(&s)
        .lu()
        .solve(&(bt_p * a))
        .ok_or(ControlError::Singular {
            what: "R + Bᵀ P B is singular",
        })
}

/// Stabilizing solution of the discrete algebraic Riccati equation
/// Aᵀ P A − P − Aᵀ P B (R + Bᵀ P B)⁻¹ Bᵀ P A + Q = 0 (A n×n, B n×m, Q = Qᵀ n×n, R = Rᵀ ≻ 0).
///
/// Structure-preserving doubling, then Newton (Hewer) refinement; see the module docs.
pub fn dare(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    q: &DMatrix<f64>,
    r: &DMatrix<f64>,
) -> Result<DMatrix<f64>, ControlError> {
    let (n, rinv_bt) = check_riccati_data(a, b, q, r)?;
    let not_stab = ControlError::NotStabilizable {
        method: "dare (doubling)",
    };
    let eye = DMatrix::<f64>::identity(n, n);
    let mut ak = a.clone();
    let mut gk = symmetrize(&(b * &rinv_bt));
    let mut hk = symmetrize(q);
    let mut converged = false;
    for _ in 0..SDA_MAX_ITER {
        let w = &eye + &gk * &hk;
        let lu = w.lu();
        let wi_a = lu.solve(&ak).ok_or(not_stab.clone())?;
        let wi_g = lu.solve(&gk).ok_or(not_stab.clone())?;
        let a_next = &ak * &wi_a;
        let g_next = symmetrize(&(&gk + &ak * wi_g * ak.transpose()));
        let h_next = symmetrize(&(&hk + ak.transpose() * &hk * &wi_a));
        if !h_next.iter().chain(a_next.iter()).all(|v| v.is_finite()) {
            return Err(not_stab);
        }
        let change = (&h_next - &hk).norm();
        let scale = h_next.norm().max(f64::MIN_POSITIVE);
        ak = a_next;
        gk = g_next;
        hk = h_next;
        if change <= 1e-15 * scale || (ak.norm() <= 1e-15 && change <= 1e-13 * scale) {
            converged = true;
            break;
        }
    }
    if !converged {
        return Err(not_stab);
    }
    let p = refine(
        hk,
        |p| {
            let k = discrete_gain(a, b, r, p)?;
            let acl = a - b * &k;
            if spectral_radius(&acl)? >= 1.0 {
                return Err(ControlError::NotStabilizable {
                    method: "dare (Hewer step)",
                });
            }
            let qk = q + k.transpose() * r * &k;
            Ok(symmetrize(&dlyap(&acl.transpose(), &qk)?))
        },
        |p| dare_residual(a, b, q, r, p),
    )?;
    let k = discrete_gain(a, b, r, &p)?;
    if spectral_radius(&(a - b * k))? >= 1.0 {
        return Err(ControlError::NotStabilizable { method: "dare" });
    }
    Ok(p)
}

/// Newton refinement: take steps while the residual decreases; keeps the best iterate.
fn refine(
    mut p: DMatrix<f64>,
    step: impl Fn(&DMatrix<f64>) -> Result<DMatrix<f64>, ControlError>,
    residual: impl Fn(&DMatrix<f64>) -> Result<f64, ControlError>,
) -> Result<DMatrix<f64>, ControlError> {
    let mut res = residual(&p)?;
    for _ in 0..REFINE_STEPS {
        if res == 0.0 {
            break;
        }
        let Ok(next) = step(&p) else { break };
        let next_res = residual(&next)?;
        // NaN residuals count as no improvement.
        if next_res.is_nan() || next_res >= res {
            break;
        }
        p = next;
        res = next_res;
    }
    Ok(p)
}

/// Stabilizing solution of the continuous algebraic Riccati equation
/// Aᵀ P + P A − P B R⁻¹ Bᵀ P + Q = 0 (A n×n, B n×m, Q = Qᵀ n×n, R = Rᵀ ≻ 0).
///
/// Matrix sign function of the Hamiltonian, then Newton–Kleinman refinement; see the module docs.
pub fn care(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    q: &DMatrix<f64>,
    r: &DMatrix<f64>,
) -> Result<DMatrix<f64>, ControlError> {
    let (n, rinv_bt) = check_riccati_data(a, b, q, r)?;
    if n == 0 {
        return Ok(DMatrix::zeros(0, 0));
    }
    let g = symmetrize(&(b * &rinv_bt));
    let p0 = hamiltonian_sign_solution(a, &g, q, "care (sign function)")?;
    let p = refine(
        p0,
        |p| {
            let k = &rinv_bt * p;
            let acl = a - b * &k;
            if spectral_abscissa(&acl)? >= 0.0 {
                return Err(ControlError::NotStabilizable {
                    method: "care (Kleinman step)",
                });
            }
            let qk = q + k.transpose() * r * &k;
            Ok(symmetrize(&lyap(&acl.transpose(), &qk)?))
        },
        |p| care_residual(a, b, q, r, p),
    )?;
    if spectral_abscissa(&(a - b * (&rinv_bt * &p)))? >= 0.0 {
        return Err(ControlError::NotStabilizable { method: "care" });
    }
    Ok(p)
}

/// Residual of the general continuous Riccati equation, ‖Aᵀ X + X A − X G X + Q‖_F.
pub fn are_residual(
    a: &DMatrix<f64>,
    g: &DMatrix<f64>,
    q: &DMatrix<f64>,
    x: &DMatrix<f64>,
) -> Result<f64, ControlError> {
    let n = check_are_data(a, g, q)?;
    check_shape("X", x, n, n)?;
    Ok((a.transpose() * x + x * a - x * g * x + q).norm())
}

fn check_are_data(
    a: &DMatrix<f64>,
    g: &DMatrix<f64>,
    q: &DMatrix<f64>,
) -> Result<usize, ControlError> {
    let n = check_square("A", a)?;
    check_shape("G", g, n, n)?;
    check_symmetric("G", g)?;
    check_shape("Q", q, n, n)?;
    check_symmetric("Q", q)?;
    Ok(n)
}

/// Stabilizing solution X of the continuous algebraic Riccati equation with
/// any symmetric quadratic term, Aᵀ X + X A − X G X + Q = 0 (A n×n, G = Gᵀ and
/// Q = Qᵀ n×n, G possibly indefinite), such that A − G X is Hurwitz.
///
/// This covers the H∞ (game) Riccati equations such as
/// Aᵀ X + X A + R − X (B Bᵀ/λ² − B̃ B̃ᵀ/μ²) X = 0, where [`care`] (G = B R⁻¹ Bᵀ ⪰ 0)
/// does not apply. Method: the stable invariant subspace of the Hamiltonian
/// [A, −G; −Q, −Aᵀ] by its matrix sign function, then Newton refinement
/// ((A − G Xₖ)ᵀ Xₖ₊₁ + Xₖ₊₁ (A − G Xₖ) + Xₖ G Xₖ + Q = 0). Fails with
/// [`ControlError::NotStabilizable`] when the Hamiltonian has eigenvalues on
/// the imaginary axis or no stabilizing solution exists.
pub fn are(
    a: &DMatrix<f64>,
    g: &DMatrix<f64>,
    q: &DMatrix<f64>,
) -> Result<DMatrix<f64>, ControlError> {
    let n = check_are_data(a, g, q)?;
    if n == 0 {
        return Ok(DMatrix::zeros(0, 0));
    }
    let g = symmetrize(g);
    let x0 = hamiltonian_sign_solution(a, &g, q, "are (sign function)")?;
    let x = refine(
        x0,
        |x| {
            let acl = a - &g * x;
            if spectral_abscissa(&acl)? >= 0.0 {
                return Err(ControlError::NotStabilizable {
                    method: "are (Newton step)",
                });
            }
            let qk = q + x * &g * x;
            Ok(symmetrize(&lyap(&acl.transpose(), &qk)?))
        },
        |x| are_residual(a, &g, q, x),
    )?;
    if spectral_abscissa(&(a - &g * &x))? >= 0.0 {
        return Err(ControlError::NotStabilizable { method: "are" });
    }
    Ok(x)
}

/// The solution of Aᵀ X + X A − X G X + Q = 0 spanned by the stable invariant
/// subspace of the Hamiltonian [A, −G; −Q, −Aᵀ], from its matrix sign function
/// (scaled Newton iteration). n ≥ 1.
fn hamiltonian_sign_solution(
    a: &DMatrix<f64>,
    g: &DMatrix<f64>,
    q: &DMatrix<f64>,
    method: &'static str,
) -> Result<DMatrix<f64>, ControlError> {
    let n = a.nrows();
    let not_stab = ControlError::NotStabilizable { method };
    let nn = 2 * n;
    let mut z = DMatrix::<f64>::zeros(nn, nn);
    z.view_mut((0, 0), (n, n)).copy_from(a);
    z.view_mut((0, n), (n, n)).copy_from(&(-g));
    z.view_mut((n, 0), (n, n)).copy_from(&(-symmetrize(q)));
    z.view_mut((n, n), (n, n)).copy_from(&(-a.transpose()));
    let mut converged = false;
    let mut scaling = true;
    for _ in 0..SIGN_MAX_ITER {
        let lu = z.clone().lu();
        let log_det: f64 = lu.u().diagonal().iter().map(|d| d.abs().ln()).sum();
        let zinv = lu.try_inverse().ok_or(not_stab.clone())?;
        let c = if scaling {
            (log_det / nn as f64).exp()
        } else {
            1.0
        };
        if !(c.is_finite() && c > 0.0) {
            return Err(not_stab);
        }
        let next = (&z / c + zinv * c) * 0.5;
        if !next.iter().all(|v| v.is_finite()) {
            return Err(not_stab);
        }
        let change = (&next - &z).norm();
        let scale = next.norm();
        z = next;
        if change <= 1e-2 * scale {
            scaling = false;
        }
        if change <= 1e-13 * scale {
            converged = true;
            break;
        }
    }
    if !converged {
        return Err(ControlError::NoConvergence {
            method,
            iterations: SIGN_MAX_ITER,
        });
    }
    // [W12; W22 + I] P = −[W11 + I; W21]
    let mut lhs = DMatrix::<f64>::zeros(nn, n);
    let mut rhs = DMatrix::<f64>::zeros(nn, n);
    lhs.view_mut((0, 0), (n, n))
        .copy_from(&z.view((0, n), (n, n)));
    lhs.view_mut((n, 0), (n, n))
        .copy_from(&(z.view((n, n), (n, n)) + DMatrix::<f64>::identity(n, n)));
    rhs.view_mut((0, 0), (n, n))
        .copy_from(&(-(z.view((0, 0), (n, n)) + DMatrix::<f64>::identity(n, n))));
    rhs.view_mut((n, 0), (n, n))
        .copy_from(&(-z.view((n, 0), (n, n))));
    let p0 = crate::linalg::svd(&lhs, true, true)
        .ok_or_else(|| not_stab.clone())?
        .solve(&rhs, 1e-14)
        .map_err(|_| not_stab.clone())?;
    if !p0.iter().all(|v| v.is_finite()) {
        return Err(not_stab);
    }
    Ok(symmetrize(&p0))
}

/// Continuous-time LQR: the gain K = R⁻¹ Bᵀ P of u = −K x minimizing ∫ xᵀ Q x + uᵀ R u dt
/// subject to ẋ = A x + B u, with P from [`care`].
pub fn lqr(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    q: &DMatrix<f64>,
    r: &DMatrix<f64>,
) -> Result<Lqr, ControlError> {
    let p = care(a, b, q, r)?;
    let k = symmetrize(r)
        .cholesky()
        .ok_or(ControlError::NotPositiveDefinite { name: "R" })?
        .solve(&(b.transpose() * &p));
    let poles = eigenvalues(&(a - b * &k))?;
    Ok(Lqr { k, p, poles })
}

/// Discrete-time LQR: the gain K = (R + Bᵀ P B)⁻¹ Bᵀ P A of u_k = −K x_k minimizing
/// Σ xₖᵀ Q xₖ + uₖᵀ R uₖ subject to x_{k+1} = A xₖ + B uₖ, with P from [`dare`].
pub fn dlqr(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    q: &DMatrix<f64>,
    r: &DMatrix<f64>,
) -> Result<Lqr, ControlError> {
    let p = dare(a, b, q, r)?;
    let k = discrete_gain(a, b, r, &p)?;
    let poles = eigenvalues(&(a - b * &k))?;
    Ok(Lqr { k, p, poles })
}
