//! Lyapunov (A X + X Aᵀ + Q = 0) and Stein (A X Aᵀ − X + Q = 0) equations by Bartels–Stewart
//! on the real Schur form.

use nalgebra::{Complex, DMatrix, Schur};

use super::{ControlError, check_shape, check_square};

/// Real Schur form A = U T Uᵀ with T quasi-upper-triangular, and the diagonal blocks of T as
/// (start, size) with size 1 (real eigenvalue) or 2 (complex pair).
pub(crate) struct RealSchur {
    pub u: DMatrix<f64>,
    pub t: DMatrix<f64>,
    pub blocks: Vec<(usize, usize)>,
}

pub(crate) fn real_schur(a: &DMatrix<f64>) -> Result<RealSchur, ControlError> {
    let n = a.nrows();
    let schur = Schur::try_new(a.clone(), f64::EPSILON, 1000 * n.max(1)).ok_or(
        ControlError::NoConvergence {
            method: "real Schur decomposition (Francis QR)",
            iterations: 1000 * n.max(1),
        },
    )?;
    let (u, mut t) = schur.unpack();
    let mut blocks = Vec::new();
    let mut k = 0;
    while k < n {
        if k + 1 < n && t[(k + 1, k)] != 0.0 {
            blocks.push((k, 2));
            k += 2;
        } else {
            blocks.push((k, 1));
            k += 1;
        }
    }
    // Entries below the block diagonal are rounding noise; make T exactly quasi-triangular.
    for (start, size) in &blocks {
        for j in *start..start + size {
            for i in start + size..n {
                t[(i, j)] = 0.0;
            }
        }
    }
    Ok(RealSchur { u, t, blocks })
}

/// Eigenvalues of a square real matrix (via the real Schur form).
pub(crate) fn eigenvalues(a: &DMatrix<f64>) -> Result<Vec<Complex<f64>>, ControlError> {
    let s = real_schur(a)?;
    let mut out = Vec::with_capacity(a.nrows());
    for &(k, size) in &s.blocks {
        if size == 1 {
            out.push(Complex::new(s.t[(k, k)], 0.0));
        } else {
            let (p, q, r, w) = (
                s.t[(k, k)],
                s.t[(k, k + 1)],
                s.t[(k + 1, k)],
                s.t[(k + 1, k + 1)],
            );
            let mean = 0.5 * (p + w);
            let disc = 0.25 * (p - w) * (p - w) + q * r;
            if disc >= 0.0 {
                out.push(Complex::new(mean + disc.sqrt(), 0.0));
                out.push(Complex::new(mean - disc.sqrt(), 0.0));
            } else {
                out.push(Complex::new(mean, (-disc).sqrt()));
                out.push(Complex::new(mean, -(-disc).sqrt()));
            }
        }
    }
    Ok(out)
}

/// Spectral abscissa max Re λ(A).
pub(crate) fn spectral_abscissa(a: &DMatrix<f64>) -> Result<f64, ControlError> {
    Ok(eigenvalues(a)?
        .iter()
        .map(|l| l.re)
        .fold(f64::NEG_INFINITY, f64::max))
}

/// Spectral radius max |λ(A)|.
pub(crate) fn spectral_radius(a: &DMatrix<f64>) -> Result<f64, ControlError> {
    Ok(eigenvalues(a)?.iter().map(|l| l.norm()).fold(0.0, f64::max))
}

#[derive(Clone, Copy, PartialEq)]
enum Kind {
    Continuous,
    Discrete,
}

/// Solves the continuous Lyapunov equation A X + X Aᵀ + Q = 0 (MATLAB's `lyap(A, Q)`).
///
/// For a stable A and symmetric Q ⪰ 0, X = ∫₀^∞ e^{At} Q e^{Aᵀt} dt ⪰ 0 (the controllability
/// Gramian when Q = B Bᵀ). For the observability form Aᵀ X + X A + Q = 0 call `lyap(&Aᵀ, Q)`.
/// Fails with [`ControlError::Singular`] when λᵢ(A) + λⱼ(A) = 0 for some i, j.
pub fn lyap(a: &DMatrix<f64>, q: &DMatrix<f64>) -> Result<DMatrix<f64>, ControlError> {
    let n = check_square("A", a)?;
    check_shape("Q", q, n, n)?;
    solve(a, q, Kind::Continuous)
}

/// Solves the discrete Lyapunov (Stein) equation A X Aᵀ − X + Q = 0 (MATLAB's `dlyap(A, Q)`).
///
/// For a Schur-stable A, X = Σₖ Aᵏ Q (Aᵀ)ᵏ. Fails with [`ControlError::Singular`] when
/// λᵢ(A) λⱼ(A) = 1 for some i, j.
pub fn dlyap(a: &DMatrix<f64>, q: &DMatrix<f64>) -> Result<DMatrix<f64>, ControlError> {
    let n = check_square("A", a)?;
    check_shape("Q", q, n, n)?;
    solve(a, q, Kind::Discrete)
}

fn solve(a: &DMatrix<f64>, q: &DMatrix<f64>, kind: Kind) -> Result<DMatrix<f64>, ControlError> {
    let n = a.nrows();
    if n == 0 {
        return Ok(q.clone());
    }
    let RealSchur { u, t, blocks } = real_schur(a)?;
    // Transformed equation: T Y + Y Tᵀ = −C or T Y Tᵀ − Y = −C with C = Uᵀ Q U, X = U Y Uᵀ.
    let c = u.transpose() * q * &u;
    let mut y = DMatrix::<f64>::zeros(n, n);
    // Discrete case: Z = Y Tᵀ, row blocks filled once the row block of Y is complete.
    let mut z = DMatrix::<f64>::zeros(n, n);
    for &(i0, ip) in blocks.iter().rev() {
        let i_end = i0 + ip;
        for &(j0, jq) in blocks.iter().rev() {
            let j_end = j0 + jq;
            let mut rhs = -c.view((i0, j0), (ip, jq)).into_owned();
            let tii = t.view((i0, i0), (ip, ip)).into_owned();
            let tjj = t.view((j0, j0), (jq, jq)).into_owned();
            // Σ_{l>j} Y_il T_jlᵀ
            let tail = if j_end < n {
                y.view((i0, j_end), (ip, n - j_end))
                    * t.view((j0, j_end), (jq, n - j_end)).transpose()
            } else {
                DMatrix::zeros(ip, jq)
            };
            let coeff = match kind {
                Kind::Continuous => {
                    if i_end < n {
                        rhs -= t.view((i0, i_end), (ip, n - i_end))
                            * y.view((i_end, j0), (n - i_end, jq));
                    }
                    rhs -= tail;
                    // (I ⊗ T_ii + T_jj ⊗ I) vec Y_ij
                    DMatrix::<f64>::identity(jq, jq).kronecker(&tii)
                        + tjj.kronecker(&DMatrix::<f64>::identity(ip, ip))
                }
                Kind::Discrete => {
                    if i_end < n {
                        rhs -= t.view((i0, i_end), (ip, n - i_end))
                            * z.view((i_end, j0), (n - i_end, jq));
                    }
                    rhs -= &tii * tail;
                    // (T_jj ⊗ T_ii − I) vec Y_ij
                    tjj.kronecker(&tii) - DMatrix::<f64>::identity(ip * jq, ip * jq)
                }
            };
            let vec_rhs = DMatrix::from_column_slice(ip * jq, 1, rhs.as_slice());
            let sol = coeff.lu().solve(&vec_rhs).ok_or(ControlError::Singular {
                what: match kind {
                    Kind::Continuous => "lyap: A and −A have a common eigenvalue (λᵢ + λⱼ = 0)",
                    Kind::Discrete => "dlyap: A has eigenvalues with λᵢ λⱼ = 1",
                },
            })?;
            if !sol.iter().all(|v| v.is_finite()) {
                return Err(ControlError::Singular {
                    what: "Lyapunov equation: nearly singular block system",
                });
            }
            y.view_mut((i0, j0), (ip, jq))
                .copy_from(&DMatrix::from_column_slice(ip, jq, sol.as_slice()));
        }
        if kind == Kind::Discrete {
            let zi = y.view((i0, 0), (ip, n)) * t.transpose();
            z.view_mut((i0, 0), (ip, n)).copy_from(&zi);
        }
    }
    Ok(&u * y * u.transpose())
}
