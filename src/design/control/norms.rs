//! State-space systems, frequency responses, H2 and H∞ norms.

use nalgebra::{Complex, DMatrix};

use super::lyapunov::{dlyap, eigenvalues, lyap, spectral_abscissa, spectral_radius};
use super::{ControlError, check_shape, check_square};

/// Continuous or discrete time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Sampling {
    /// ẋ = A x + B u.
    Continuous,
    /// x_{k+1} = A x_k + B u_k with sampling time `ts` (frequencies in rad per time unit).
    Discrete {
        /// Sampling time (> 0).
        ts: f64,
    },
}

/// A linear time-invariant system (A, B, C, D), continuous or discrete.
#[derive(Debug, Clone, PartialEq)]
pub struct StateSpace {
    /// State matrix (n×n).
    pub a: DMatrix<f64>,
    /// Input matrix (n×m).
    pub b: DMatrix<f64>,
    /// Output matrix (p×n).
    pub c: DMatrix<f64>,
    /// Feedthrough (p×m).
    pub d: DMatrix<f64>,
    /// Time domain.
    pub sampling: Sampling,
}

/// The H∞ norm and a frequency where it is attained.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HinfNorm {
    /// sup_ω σ_max(G(jω)) (continuous) or sup_ω σ_max(G(e^{jωTs})) (discrete).
    pub value: f64,
    /// A frequency (rad per time unit, ≥ 0) where the supremum is attained; `f64::INFINITY` when
    /// it is attained only as ω → ∞ (continuous systems with ‖D‖ the norm).
    pub peak_frequency: f64,
}

impl StateSpace {
    /// A continuous-time system; checks the shapes.
    pub fn continuous(
        a: DMatrix<f64>,
        b: DMatrix<f64>,
        c: DMatrix<f64>,
        d: DMatrix<f64>,
    ) -> Result<Self, ControlError> {
        Self::new(a, b, c, d, Sampling::Continuous)
    }

    /// A discrete-time system with sampling time `ts`; checks the shapes and `ts`.
    pub fn discrete(
        a: DMatrix<f64>,
        b: DMatrix<f64>,
        c: DMatrix<f64>,
        d: DMatrix<f64>,
        ts: f64,
    ) -> Result<Self, ControlError> {
        if !(ts.is_finite() && ts > 0.0) {
            return Err(ControlError::BadSamplingTime { ts });
        }
        Self::new(a, b, c, d, Sampling::Discrete { ts })
    }

    fn new(
        a: DMatrix<f64>,
        b: DMatrix<f64>,
        c: DMatrix<f64>,
        d: DMatrix<f64>,
        sampling: Sampling,
    ) -> Result<Self, ControlError> {
        let n = check_square("A", &a)?;
        check_shape("B", &b, n, b.ncols())?;
        check_shape("C", &c, c.nrows(), n)?;
        check_shape("D", &d, c.nrows(), b.ncols())?;
        Ok(StateSpace {
            a,
            b,
            c,
            d,
            sampling,
        })
    }

    /// Frequency response G(jω) (continuous) or G(e^{jωTs}) (discrete) at ω ≥ 0.
    pub fn freq_response(&self, omega: f64) -> Result<DMatrix<Complex<f64>>, ControlError> {
        let s = match self.sampling {
            Sampling::Continuous => Complex::new(0.0, omega),
            Sampling::Discrete { ts } => Complex::new(0.0, omega * ts).exp(),
        };
        let n = self.a.nrows();
        let to_c = |m: &DMatrix<f64>| m.map(|v| Complex::new(v, 0.0));
        let mut si_a = -to_c(&self.a);
        for i in 0..n {
            si_a[(i, i)] += s;
        }
        let x = si_a
            .lu()
            .solve(&to_c(&self.b))
            .ok_or(ControlError::Singular {
                what: "frequency response: sI − A singular (pole on the frequency axis)",
            })?;
        Ok(to_c(&self.c) * x + to_c(&self.d))
    }

    /// Largest singular value of the frequency response at ω.
    pub fn sigma_max(&self, omega: f64) -> Result<f64, ControlError> {
        let g = self.freq_response(omega)?;
        Ok(max_singular_value_c(&g))
    }

    /// Stability margin: max Re λ(A) (continuous, stable if < 0) or max |λ(A)| (discrete, stable
    /// if < 1).
    pub fn stability_margin(&self) -> Result<f64, ControlError> {
        match self.sampling {
            Sampling::Continuous => spectral_abscissa(&self.a),
            Sampling::Discrete { .. } => spectral_radius(&self.a),
        }
    }

    fn check_stable(&self, norm: &'static str) -> Result<(), ControlError> {
        let margin = self.stability_margin()?;
        let stable = match self.sampling {
            Sampling::Continuous => margin < 0.0,
            Sampling::Discrete { .. } => margin < 1.0,
        };
        if stable {
            Ok(())
        } else {
            Err(ControlError::Unstable { norm, margin })
        }
    }
}

fn max_singular_value_c(g: &DMatrix<Complex<f64>>) -> f64 {
    if g.is_empty() {
        return 0.0;
    }
    // σ_max² = λ_max(Gᴴ G) of the smaller Gram matrix; the Hermitian eigen-solver is robust.
    let gram = if g.nrows() >= g.ncols() {
        g.adjoint() * g
    } else {
        g * g.adjoint()
    };
    // Non-finite: NaN, which the callers' finiteness checks refuse.
    crate::linalg::symmetric_eigenvalues(&gram)
        .map_or(f64::NAN, |e| e.iter().fold(0.0f64, |m, v| m.max(*v)).sqrt())
}

fn max_singular_value(g: &DMatrix<f64>) -> f64 {
    if g.is_empty() {
        return 0.0;
    }
    crate::linalg::singular_values(g).map_or(f64::NAN, |s| s.iter().fold(0.0f64, |m, v| m.max(*v)))
}

/// The H2 norm: √tr(C W Cᵀ) (continuous, D must be 0) or √tr(C W Cᵀ + D Dᵀ) (discrete), with
/// W the controllability Gramian (A W + W Aᵀ + B Bᵀ = 0, resp. A W Aᵀ − W + B Bᵀ = 0).
/// Discrete norms are per sample (impulse-response energy Σ‖G_k‖²_F), as MATLAB's `norm(sys, 2)`.
pub fn h2_norm(sys: &StateSpace) -> Result<f64, ControlError> {
    sys.check_stable("H2")?;
    let bbt = &sys.b * sys.b.transpose();
    let value = match sys.sampling {
        Sampling::Continuous => {
            if sys.d.iter().any(|v| *v != 0.0) {
                return Err(ControlError::NonzeroFeedthrough);
            }
            let w = lyap(&sys.a, &bbt)?;
            (&sys.c * w * sys.c.transpose()).trace()
        }
        Sampling::Discrete { .. } => {
            let w = dlyap(&sys.a, &bbt)?;
            (&sys.c * w * sys.c.transpose()).trace() + (&sys.d * sys.d.transpose()).trace()
        }
    };
    Ok(value.max(0.0).sqrt())
}

/// The H∞ norm of a stable system (level-set iteration of Bruinsma–Steinbuch; discrete systems
/// via the bilinear transform). Relative accuracy about 1e-10.
pub fn hinf_norm(sys: &StateSpace) -> Result<HinfNorm, ControlError> {
    sys.check_stable("H∞")?;
    match sys.sampling {
        Sampling::Continuous => hinf_continuous(sys),
        Sampling::Discrete { ts } => {
            // z = (1 + s)/(1 − s): Ac = (A + I)⁻¹(A − I), Bc = √2 (A + I)⁻¹ B,
            // Cc = √2 C (A + I)⁻¹, Dc = D − C (A + I)⁻¹ B; G_c(jν) = G_d(e^{jθ}), θ = 2 atan ν.
            let n = sys.a.nrows();
            let eye = DMatrix::<f64>::identity(n, n);
            let lu = (&sys.a + &eye).lu();
            let singular = ControlError::Singular {
                what: "bilinear transform: A + I singular",
            };
            let ac = lu.solve(&(&sys.a - &eye)).ok_or(singular.clone())?;
            let aib = lu.solve(&sys.b).ok_or(singular.clone())?;
            let cai = (&sys.a + &eye)
                .transpose()
                .lu()
                .solve(&sys.c.transpose())
                .ok_or(singular)?
                .transpose();
            let cont = StateSpace {
                a: ac,
                b: &aib * std::f64::consts::SQRT_2,
                c: &cai * std::f64::consts::SQRT_2,
                d: &sys.d - &sys.c * &aib,
                sampling: Sampling::Continuous,
            };
            let h = hinf_continuous(&cont)?;
            Ok(HinfNorm {
                value: h.value,
                peak_frequency: if h.peak_frequency.is_finite() {
                    2.0 * h.peak_frequency.atan() / ts
                } else {
                    std::f64::consts::PI / ts
                },
            })
        }
    }
}

fn hinf_continuous(sys: &StateSpace) -> Result<HinfNorm, ControlError> {
    const REL_TOL: f64 = 1e-10;
    let n = sys.a.nrows();
    let d_norm = max_singular_value(&sys.d);
    let mut best = HinfNorm {
        value: d_norm,
        peak_frequency: f64::INFINITY,
    };
    if n == 0 {
        return Ok(best);
    }
    // Initial frequencies: 0 and the pole with the largest |Im λ / (Re λ |λ|)| (lightest damping).
    let poles = eigenvalues(&sys.a)?;
    let mut trial = vec![0.0];
    let mut worst = None::<(f64, f64)>;
    for p in &poles {
        let mag = p.norm();
        if p.im.abs() > 0.0 {
            let score = (p.im / (p.re * mag)).abs();
            if worst.is_none_or(|(s, _)| score > s) {
                worst = Some((score, mag));
            }
        }
    }
    match worst {
        Some((_, mag)) => trial.push(mag),
        None => {
            let min = poles.iter().map(|p| p.norm()).fold(f64::INFINITY, f64::min);
            if min.is_finite() {
                trial.push(min);
            }
        }
    }
    for w in trial {
        let s = sys.sigma_max(w)?;
        if s > best.value {
            best = HinfNorm {
                value: s,
                peak_frequency: w,
            };
        }
    }
    if best.value == 0.0 {
        return Ok(best);
    }
    for _ in 0..60 {
        let gamma = (1.0 + 2.0 * REL_TOL) * best.value;
        let freqs = imaginary_eigen_frequencies(sys, gamma)?;
        if freqs.len() < 2 {
            return Ok(best);
        }
        let mut improved = false;
        for pair in freqs.windows(2) {
            let mid = 0.5 * (pair[0] + pair[1]);
            let s = sys.sigma_max(mid)?;
            if s > best.value {
                best = HinfNorm {
                    value: s,
                    peak_frequency: mid,
                };
                improved = true;
            }
        }
        if !improved {
            return Ok(best);
        }
    }
    Err(ControlError::NoConvergence {
        method: "H∞ norm (level-set iteration)",
        iterations: 60,
    })
}

/// Non-negative frequencies ω with jω an eigenvalue of the Hamiltonian of level γ (sorted), i.e.
/// where γ is a singular value of G(jω).
fn imaginary_eigen_frequencies(sys: &StateSpace, gamma: f64) -> Result<Vec<f64>, ControlError> {
    let n = sys.a.nrows();
    let m = sys.b.ncols();
    let p = sys.c.nrows();
    let (a, b, c, d) = (&sys.a, &sys.b, &sys.c, &sys.d);
    // R = γ² I − DᵀD ≻ 0 since γ > σ_max(D).
    let r = DMatrix::<f64>::identity(m, m) * (gamma * gamma) - d.transpose() * d;
    let chol = r.cholesky().ok_or(ControlError::Singular {
        what: "H∞ Hamiltonian: γ² I − DᵀD not positive definite",
    })?;
    let rinv_dt_c = chol.solve(&(d.transpose() * c));
    let rinv_bt = chol.solve(&b.transpose());
    let a11 = a + b * &rinv_dt_c;
    let a12 = b * rinv_bt;
    let a21 =
        -(c.transpose() * (DMatrix::<f64>::identity(p, p) + d * chol.solve(&d.transpose())) * c);
    let mut h = DMatrix::<f64>::zeros(2 * n, 2 * n);
    h.view_mut((0, 0), (n, n)).copy_from(&a11);
    h.view_mut((0, n), (n, n)).copy_from(&a12);
    h.view_mut((n, 0), (n, n)).copy_from(&a21);
    h.view_mut((n, n), (n, n)).copy_from(&(-a11.transpose()));
    let scale = h.norm();
    let mut freqs: Vec<f64> = eigenvalues(&h)?
        .into_iter()
        .filter(|l| l.re.abs() <= 1e-8 * scale.max(1.0) && l.im >= 0.0)
        .map(|l| l.im)
        .collect();
    freqs.sort_by(f64::total_cmp);
    Ok(freqs)
}
