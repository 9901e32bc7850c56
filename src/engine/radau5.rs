//! The engine's Radau IIA stepper of order 5, for stiff flows: the 3-stage
//! collocation method (L-stable, stiffly accurate), solved by simplified
//! Newton iterations on the system transformed by the eigenvectors of the
//! method's matrix (one real n×n and one complex n×n LU factorization per
//! Jacobian and step size), with the embedded order-3 error estimate and
//! the predictive step-size controller of Hairer & Wanner, *Solving ODEs
//! II*, IV.8 (RADAU5), as scipy's `Radau` also implements them.
//!
//! Like the engine's [`Dopri5`](super::dopri5::Dopri5) it is built for
//! hybrid runs: it steps one accepted step at a time (the caller watches
//! events after each), takes the caller's f at a segment start, keeps the
//! step proposal, the Jacobian and its factorizations across segments and
//! jumps (they are only refreshed when the Newton iteration stops
//! converging), gives each step's collocation polynomial (cubic) as dense
//! output (events found on it are found again on re-steps to them, since
//! the cubic is less accurate inside a long stiff step than the step's
//! ends: [`RadauPath`]), and allocates nothing after construction but the
//! re-steps' buffers at the first event: the LU factorizations are done in
//! place, dense or sparse ([`NewtonLu`], shared with the BDF stepper in
//! [`implicit`](super::implicit)).
//!
//! No crate offers this step-level control: `ode_solvers` has no implicit
//! method; `russell_ode`'s Radau5 integrates whole intervals through
//! callbacks, exposes its dense output only on a fixed grid and needs
//! SuiteSparse/MUMPS system libraries; `diffsol` (BDF, SDIRK) steps one
//! step at a time but a jump changes the state only through a new solver
//! state (allocated, history and step restarted), its Jacobian is given as
//! matrix-vector products, and it has no Radau IIA.

// Stage and component indices are written as in the method's formulas.
#![allow(clippy::needless_range_loop)]

use nalgebra::{Complex, ComplexField};

use super::dopri5::{Failure, NonFiniteRate, Rhs};
use super::events::{MAX_CONTROL, StepPath, bernstein_points};
use super::implicit::{Jac, Jacobian, LinearAlgebra, NewtonLu, initial_step, newton_tol};

const S6: f64 = 2.449_489_742_783_178;
/// Nodes of the collocation points.
const C: [f64; 3] = [(4.0 - S6) / 10.0, (4.0 + S6) / 10.0, 1.0];
/// Error-estimate weights (divided by the real eigenvalue's inverse).
const E: [f64; 3] = [
    (-13.0 - 7.0 * S6) / 3.0,
    (-13.0 + 7.0 * S6) / 3.0,
    -1.0 / 3.0,
];
/// Eigenvectors of the inverse of the method's matrix: `A⁻¹ = T Λ T⁻¹` with
/// one real eigenvalue and a complex pair (as published, to 20 digits).
#[allow(clippy::excessive_precision)]
const T: [[f64; 3]; 3] = [
    [
        0.094_438_762_488_975_24,
        -0.141_255_295_020_954_21,
        0.030_029_194_105_147_42,
    ],
    [
        0.250_213_122_965_333_32,
        0.204_129_352_293_799_94,
        -0.382_942_112_757_261_92,
    ],
    [1.0, 1.0, 0.0],
];
#[allow(clippy::excessive_precision)]
const TI: [[f64; 3]; 3] = [
    [
        4.178_718_591_551_904_28,
        0.327_682_820_761_062_37,
        0.523_376_445_499_449_51,
    ],
    [
        -4.178_718_591_551_904_28,
        -0.327_682_820_761_062_37,
        0.476_623_554_500_550_44,
    ],
    [
        0.502_872_634_945_786_82,
        -2.571_926_949_855_605_22,
        0.596_039_204_828_224_92,
    ],
];
/// Coefficients of the collocation polynomial from the stage increments:
/// `y(s0 + θh) = y0 + Σ_k q_k θ^(k+1)` with `q_k = Σ_m P[m][k] z_m`.
const P: [[f64; 3]; 3] = [
    [
        13.0 / 3.0 + 7.0 * S6 / 3.0,
        -23.0 / 3.0 - 22.0 * S6 / 3.0,
        10.0 / 3.0 + 5.0 * S6,
    ],
    [
        13.0 / 3.0 - 7.0 * S6 / 3.0,
        -23.0 / 3.0 + 22.0 * S6 / 3.0,
        10.0 / 3.0 - 5.0 * S6,
    ],
    [1.0 / 3.0, -8.0 / 3.0, 10.0 / 3.0],
];

/// The real eigenvalue of `A⁻¹`: 3 + 3^(2/3) − 3^(1/3).
fn mu_real() -> f64 {
    3.0 + 3f64.powf(2.0 / 3.0) - 3f64.cbrt()
}

/// The complex eigenvalue of `A⁻¹` (the other is its conjugate).
fn mu_complex() -> Complex<f64> {
    Complex::new(
        3.0 + 0.5 * (3f64.cbrt() - 3f64.powf(2.0 / 3.0)),
        -0.5 * (3f64.powf(5.0 / 6.0) + 3f64.powf(7.0 / 6.0)),
    )
}

const NEWTON_MAXITER: u32 = 6;
/// The largest h·‖J‖ at which the flow counts as no longer stiff for
/// `Solver::Auto`: well inside Dopri5's stability interval (−3.3, 0), whose
/// stiffness test fires above 3.25.
pub(crate) const NONSTIFF_HLAMB: f64 = 1.0;
const MIN_FACTOR: f64 = 0.2;
const MAX_FACTOR: f64 = 10.0;

/// The collocation system of one step from (`s`, `y`) of length `h`: the
/// Newton matrices `μ_real/h·I − J` and `μ_complex/h·I − J` factorized for
/// `lu_h` (0: not factorized for the current Jacobian), the stage
/// increments z_i = Y_i − y, their transforms w = T⁻¹ z, the stage
/// derivatives. A stepper has one for its steps and one for re-stepping to
/// events ([`RadauPath`]'s `restep`), made at the first.
struct Collocation {
    lu_re: NewtonLu<f64>,
    lu_cx: NewtonLu<Complex<f64>>,
    lu_h: f64,
    z: [Vec<f64>; 3],
    w: [Vec<f64>; 3],
    fs: [Vec<f64>; 3],
    rhs_re: Vec<f64>,
    rhs_cx: Vec<Complex<f64>>,
    y_stage: Vec<f64>,
    /// The weights of the Newton iteration's norm: atol + rtol·|y|.
    scale: Vec<f64>,
}

/// What a Newton iteration counts into its stepper: evaluations of f, and
/// the last non-finite rate met.
struct Counts<'a> {
    fevals: &'a mut u64,
    non_finite: &'a mut Option<NonFiniteRate>,
}

impl Collocation {
    fn new(n: usize, la: &LinearAlgebra) -> Self {
        let v = || vec![0.0; n];
        Self {
            lu_re: NewtonLu::new(la),
            lu_cx: NewtonLu::new(la),
            lu_h: 0.0,
            z: [v(), v(), v()],
            w: [v(), v(), v()],
            fs: [v(), v(), v()],
            rhs_re: v(),
            rhs_cx: vec![Complex::new(0.0, 0.0); n],
            y_stage: v(),
            scale: v(),
        }
    }

    /// Factorizes the two Newton matrices for step `h`; `false` if one is
    /// singular.
    fn factor(&mut self, h: f64, jac: &Jacobian) -> bool {
        let ok = self.lu_re.factor_shifted(mu_real() / h, jac)
            && self.lu_cx.factor_shifted(mu_complex() / h, jac);
        self.lu_h = if ok { h } else { 0.0 };
        ok
    }

    /// The simplified Newton iteration of the collocation system from the
    /// stage increments in `z`; returns (converged, iterations, rate).
    fn newton(
        &mut self,
        (s, y, h): (f64, &[f64], f64),
        f: &mut Rhs<'_>,
        newton_tol: f64,
        counts: Counts<'_>,
    ) -> (bool, u32, f64) {
        let n = y.len();
        let (mr, mc) = (mu_real() / h, mu_complex() / h);
        for k in 0..3 {
            for i in 0..n {
                self.w[k][i] =
                    TI[k][0] * self.z[0][i] + TI[k][1] * self.z[1][i] + TI[k][2] * self.z[2][i];
            }
        }
        let mut norm_old: f64 = -1.0;
        let mut rate = f64::NAN;
        for it in 0..NEWTON_MAXITER {
            for st in 0..3 {
                for i in 0..n {
                    self.y_stage[i] = y[i] + self.z[st][i];
                }
                f(s + C[st] * h, &self.y_stage, &mut self.fs[st]);
            }
            *counts.fevals += 3;
            if self.fs.iter().flatten().any(|v| !v.is_finite()) {
                // The stages in time order (C ascending).
                *counts.non_finite = (0..3)
                    .find_map(|st| NonFiniteRate::find(s + C[st] * h, &self.fs[st]))
                    .or(*counts.non_finite);
                return (false, it + 1, rate);
            }
            let [f1, f2, f3] = &self.fs;
            for i in 0..n {
                self.rhs_re[i] =
                    TI[0][0] * f1[i] + TI[0][1] * f2[i] + TI[0][2] * f3[i] - mr * self.w[0][i];
                let fr = TI[1][0] * f1[i] + TI[1][1] * f2[i] + TI[1][2] * f3[i];
                let fi = TI[2][0] * f1[i] + TI[2][1] * f2[i] + TI[2][2] * f3[i];
                self.rhs_cx[i] =
                    Complex::new(fr, fi) - mc * Complex::new(self.w[1][i], self.w[2][i]);
            }
            self.lu_re.solve(&mut self.rhs_re);
            self.lu_cx.solve(&mut self.rhs_cx);
            let mut sum = 0.0;
            for i in 0..n {
                let sc = self.scale[i];
                let (a, b, c) = (self.rhs_re[i], self.rhs_cx[i].re, self.rhs_cx[i].im);
                sum += (a / sc).powi(2) + (b / sc).powi(2) + (c / sc).powi(2);
            }
            let norm = (sum / (3 * n.max(1)) as f64).sqrt();
            if norm_old >= 0.0 {
                rate = norm / norm_old;
            }
            if rate.is_finite()
                && (rate >= 1.0
                    || rate.powi((NEWTON_MAXITER - it) as i32) / (1.0 - rate) * norm > newton_tol)
            {
                return (false, it + 1, rate);
            }
            if !norm.is_finite() {
                return (false, it + 1, rate);
            }
            for i in 0..n {
                self.w[0][i] += self.rhs_re[i];
                self.w[1][i] += self.rhs_cx[i].re;
                self.w[2][i] += self.rhs_cx[i].im;
            }
            for k in 0..3 {
                for i in 0..n {
                    self.z[k][i] =
                        T[k][0] * self.w[0][i] + T[k][1] * self.w[1][i] + T[k][2] * self.w[2][i];
                }
            }
            if norm == 0.0 || (rate.is_finite() && rate / (1.0 - rate) * norm < newton_tol) {
                return (true, it + 1, rate);
            }
            norm_old = norm;
        }
        (false, NEWTON_MAXITER, rate)
    }
}

/// Radau IIA (order 5) state: tolerances, controller memory, the Jacobian
/// and its factorizations, stage buffers and the collocation polynomial of
/// the last accepted step.
pub(crate) struct Radau5 {
    rtol: f64,
    atol: f64,
    newton_tol: f64,
    /// Step proposal (carried across segments); 0 before the first step.
    h_next: f64,
    /// Length and error norm of the previous accepted step of this segment
    /// (the predictive controller); `err_prev = 0`: none.
    h_prev: f64,
    err_prev: f64,
    /// ∂f/∂y (fresh: evaluated at the current step start).
    jac: Jacobian,
    /// The collocation system of the steps.
    col: Collocation,
    /// That of re-steps to events, made at the first ([`RadauPath`]).
    restep: Option<Collocation>,
    la: LinearAlgebra,
    /// f at the current step start (the caller's at a segment start).
    f0: Vec<f64>,
    /// The state at the end of the last accepted step, and f there.
    pub y_new: Vec<f64>,
    f_new: Vec<f64>,
    /// Collocation polynomial of the last accepted step.
    q: [Vec<f64>; 3],
    y_old: Vec<f64>,
    s_old: f64,
    h_old: f64,
    /// Whether `q` belongs to the current segment (then it predicts the
    /// next step's stages).
    q_valid: bool,
    /// Evaluations of f and of the Jacobian, LU factorization pairs.
    pub fevals: u64,
    /// The last non-finite rate met by a rejected attempt since the last
    /// accepted step.
    pub non_finite: Option<NonFiniteRate>,
    pub factorizations: u64,
}

impl Radau5 {
    pub fn new(n: usize, rtol: f64, atol: f64, la: &LinearAlgebra) -> Self {
        let v = || vec![0.0; n];
        Self {
            rtol,
            atol,
            newton_tol: newton_tol(rtol),
            h_next: 0.0,
            h_prev: 0.0,
            err_prev: 0.0,
            jac: Jacobian::new(la),
            col: Collocation::new(n, la),
            restep: None,
            la: la.clone(),
            f0: v(),
            y_new: v(),
            f_new: v(),
            q: [v(), v(), v()],
            y_old: v(),
            s_old: 0.0,
            h_old: 0.0,
            q_valid: false,
            fevals: 0,
            non_finite: None,
            factorizations: 0,
        }
    }

    /// Starts a segment at local time 0 from `y` with `f0 = f(0, y)`. The
    /// step proposal, Jacobian and factorizations are kept (the Jacobian is
    /// marked stale); a first step is estimated if there is no proposal.
    pub fn start(&mut self, y: &[f64], f0: &[f64], f: &mut Rhs<'_>) {
        self.f0.copy_from_slice(f0);
        self.q_valid = false;
        self.jac.fresh = false;
        self.err_prev = 0.0;
        if self.h_next <= 0.0 {
            self.h_next = initial_step(
                y,
                f0,
                f,
                self.rtol,
                self.atol,
                3,
                &mut self.col.y_stage,
                &mut self.f_new,
            )
            .0;
            self.fevals += 1;
        }
    }

    /// The proposal for the next step.
    pub fn proposal(&self) -> f64 {
        self.h_next
    }

    /// Sets the proposal for the next step (a method taking over from
    /// another starts from that one's step).
    pub fn set_proposal(&mut self, h: f64) {
        self.h_next = h;
    }

    /// Whether the flow at the end of the last accepted step has stopped
    /// being stiff for it: its step h times the weighted norm of the
    /// Jacobian there (an upper bound of the spectral radius, evaluated
    /// afresh unless `fresh_only` and it is stale) is at most
    /// [`NONSTIFF_HLAMB`] (half `Solver::Auto`'s threshold of Dopri5's
    /// stiffness test where that is lower), so an explicit method of the same order takes
    /// the same steps well inside its stability region. `None`: not tested
    /// (`fresh_only` and the Jacobian there was not evaluated).
    pub fn nonstiff(&mut self, jac: &mut Jac<'_>, fresh_only: bool) -> Option<bool> {
        if !self.jac.fresh {
            if fresh_only {
                return None;
            }
            self.jac.refresh(self.s_old + self.h_old, &self.y_new, jac);
            self.col.lu_h = 0.0;
        }
        for (sc, y) in self.col.scale.iter_mut().zip(&self.y_new) {
            *sc = self.atol + self.rtol * y.abs();
        }
        // Below half the h·λ at which Dopri5 hands a flow over (lower than 1 at
        // tight tolerances), so that the flow is not handed back and forth.
        let limit = NONSTIFF_HLAMB.min(0.5 * super::flow::auto_stiff_hlamb(self.rtol));
        Some(self.h_old * self.jac.weighted_norm(&self.col.scale) <= limit)
    }

    /// Lowers the step proposal to at most `h`.
    pub fn limit_proposal(&mut self, h: f64) {
        self.h_next = self.h_next.min(h);
    }

    /// Evaluates the Jacobian at (`s`, `y`).
    fn refresh_jacobian(&mut self, s: f64, y: &[f64], jac: &mut Jac<'_>) {
        self.jac.refresh(s, y, jac);
        self.col.lu_h = 0.0;
    }

    /// Evaluations of the Jacobian so far.
    #[cfg(test)]
    pub fn jevals(&self) -> u64 {
        self.jac.evals
    }

    /// Factorizes the two Newton matrices for step `h`; `false` if one is
    /// singular.
    fn factor(&mut self, h: f64) -> bool {
        self.factorizations += 1;
        self.col.factor(h, &self.jac)
    }

    /// The step-size factor of the predictive (Gustafsson) controller.
    fn predict(&self, h: f64, err: f64) -> f64 {
        let multiplier = if self.err_prev > 0.0 && self.h_prev > 0.0 && err > 0.0 {
            h / self.h_prev * (self.err_prev / err).powf(0.25)
        } else {
            1.0
        };
        if err == 0.0 {
            return MAX_FACTOR;
        }
        multiplier.min(1.0) * err.powf(-0.25)
    }

    /// One accepted step from (`s`, `y`) of at most `h_max` (rejected
    /// attempts are retried with smaller steps; a Newton iteration that
    /// does not converge refreshes the Jacobian, then halves the step);
    /// `h_max` is taken exactly if the proposal reaches it. Returns the
    /// step length; the new state is in [`y_new`](Self::y_new), the step's
    /// collocation polynomial in [`path`](Self::path).
    pub fn step(
        &mut self,
        s: f64,
        y: &[f64],
        h_max: f64,
        f: &mut Rhs<'_>,
        jac: &mut Jac<'_>,
    ) -> Result<f64, Failure> {
        let n = y.len();
        if self.jac.ensure(s, y, jac) {
            self.col.lu_h = 0.0;
        }
        for i in 0..n {
            self.col.scale[i] = self.atol + self.rtol * y[i].abs();
        }
        let mut rejected = false;
        loop {
            let mut h = self.h_next.min(h_max);
            let clipped = h >= 0.99 * h_max;
            if clipped {
                h = h_max;
            }
            if h <= 0.0 || s + 0.1 * h == s || !h.is_finite() {
                return Err(Failure::Underflow);
            }
            if self.col.lu_h != h && !self.factor(h) {
                // A singular Newton matrix: a fresh Jacobian, then smaller steps.
                if !self.jac.fresh {
                    self.refresh_jacobian(s, y, jac);
                } else {
                    self.h_next = 0.5 * h;
                    rejected = true;
                }
                continue;
            }
            // Stage guess: the previous step's collocation polynomial
            // extrapolated, or zero after a segment start.
            for k in 0..3 {
                if self.q_valid {
                    let th = (s + C[k] * h - self.s_old) / self.h_old;
                    for i in 0..n {
                        let p = th * (self.q[0][i] + th * (self.q[1][i] + th * self.q[2][i]));
                        self.col.z[k][i] = self.y_old[i] + p - y[i];
                    }
                } else {
                    self.col.z[k].fill(0.0);
                }
            }
            let counts = Counts {
                fevals: &mut self.fevals,
                non_finite: &mut self.non_finite,
            };
            let (converged, iters, rate) = self.col.newton((s, y, h), f, self.newton_tol, counts);
            if !converged {
                if !self.jac.fresh {
                    self.refresh_jacobian(s, y, jac);
                } else {
                    self.h_next = 0.5 * h;
                    self.col.lu_h = 0.0;
                    rejected = true;
                }
                continue;
            }
            for i in 0..n {
                self.y_new[i] = y[i] + self.col.z[2][i];
            }
            // Error estimate: (μ_real/h − J)⁻¹ (f0 + Σ e_k z_k / h).
            let err = self.error_norm(s, y, h, rejected, f);
            let safety =
                0.9 * f64::from(2 * NEWTON_MAXITER + 1) / f64::from(2 * NEWTON_MAXITER + iters);
            if err.is_nan() || err > 1.0 {
                let factor = if err.is_finite() {
                    self.predict(h, err)
                } else {
                    MIN_FACTOR
                };
                self.h_next = h * MIN_FACTOR.max(safety * factor);
                rejected = true;
                continue;
            }
            // Accepted.
            let s_new = s + h;
            f(s_new, &self.y_new, &mut self.f_new);
            self.fevals += 1;
            let recompute = iters > 2 && rate.is_finite() && rate > 1e-3;
            let mut factor = MAX_FACTOR.min(safety * self.predict(h, err));
            if !recompute && (1.0..1.2).contains(&factor) {
                // Keep h (and the factorizations).
                factor = 1.0;
            }
            if rejected {
                factor = factor.min(1.0);
            }
            self.h_prev = h;
            self.err_prev = err.max(1e-10);
            let h_new = h * factor;
            // A step cut short by h_max keeps the controller's own proposal.
            self.h_next = if clipped {
                h_new.max(self.h_next)
            } else {
                h_new
            };
            // Dense output: the collocation polynomial of this step.
            for k in 0..3 {
                for i in 0..n {
                    self.q[k][i] = P[0][k] * self.col.z[0][i]
                        + P[1][k] * self.col.z[1][i]
                        + P[2][k] * self.col.z[2][i];
                }
            }
            self.y_old.copy_from_slice(y);
            self.s_old = s;
            self.h_old = h;
            self.q_valid = true;
            std::mem::swap(&mut self.f0, &mut self.f_new);
            if recompute {
                self.jac.refresh(s_new, &self.y_new, jac);
                self.col.lu_h = 0.0;
            } else {
                self.jac.fresh = false;
            }
            self.non_finite = None;
            return Ok(h);
        }
    }

    /// The scaled RMS norm of the embedded error estimate of the step
    /// just solved (one more f-evaluation after a rejection, as RADAU5).
    fn error_norm(&mut self, s: f64, y: &[f64], h: f64, rejected: bool, f: &mut Rhs<'_>) -> f64 {
        let n = y.len();
        for i in 0..n {
            let ze =
                (E[0] * self.col.z[0][i] + E[1] * self.col.z[1][i] + E[2] * self.col.z[2][i]) / h;
            // ze is kept in `fs[0]` for a second estimate.
            self.col.fs[0][i] = ze;
            self.col.rhs_re[i] = self.f0[i] + ze;
        }
        self.col.lu_re.solve(&mut self.col.rhs_re);
        let mut norm = self.scaled_err(y);
        if rejected && norm > 1.0 {
            for i in 0..n {
                self.col.y_stage[i] = y[i] + self.col.rhs_re[i];
            }
            f(s, &self.col.y_stage, &mut self.col.rhs_re);
            self.fevals += 1;
            for i in 0..n {
                self.col.rhs_re[i] += self.col.fs[0][i];
            }
            self.col.lu_re.solve(&mut self.col.rhs_re);
            norm = self.scaled_err(y);
        }
        norm
    }

    fn scaled_err(&self, y: &[f64]) -> f64 {
        let n = y.len();
        if n == 0 {
            return 0.0;
        }
        let mut sum = 0.0;
        for i in 0..n {
            let sc = self.atol + self.rtol * y[i].abs().max(self.y_new[i].abs());
            sum += (self.col.rhs_re[i] / sc).powi(2);
        }
        (sum / n as f64).sqrt()
    }

    /// The collocation polynomial of the last accepted step, ending at
    /// local time `s1` (its end, or the segment end it was rounded to), and
    /// the state there; `f` for re-steps from the step's start to points
    /// inside it ([`StepPath::restep`]).
    pub fn path<'a>(&'a mut self, s1: f64, f: &'a mut Rhs<'_>) -> (RadauPath<'a>, &'a [f64]) {
        let la = &self.la;
        let restep = Restep {
            col: &mut self.restep,
            la,
            jac: &self.jac,
            f,
            tol: (self.rtol, self.atol, self.newton_tol),
            fevals: &mut self.fevals,
            factorizations: &mut self.factorizations,
        };
        let path = RadauPath {
            q: &self.q,
            y0: &self.y_old,
            s0: self.s_old,
            h: self.h_old,
            s1,
            y1: &self.y_new,
            restep: Some(restep),
        };
        (path, &self.y_new)
    }
}

/// What re-stepping from a step's start needs of its stepper.
struct Restep<'a> {
    col: &'a mut Option<Collocation>,
    la: &'a LinearAlgebra,
    jac: &'a Jacobian,
    f: &'a mut Rhs<'a>,
    /// rtol, atol, the Newton iteration's tolerance.
    tol: (f64, f64, f64),
    fevals: &'a mut u64,
    factorizations: &'a mut u64,
}

/// The cubic collocation polynomial of one Radau IIA step (order 3 between
/// the step ends, exact at them; where the flow is stiff its error inside
/// a long step is well above the step's own, so events are found again on
/// re-steps: [`StepPath::restep`]).
pub(crate) struct RadauPath<'a> {
    q: &'a [Vec<f64>; 3],
    y0: &'a [f64],
    s0: f64,
    h: f64,
    s1: f64,
    y1: &'a [f64],
    /// `None`: a path that cannot re-step (tests).
    restep: Option<Restep<'a>>,
}

impl StepPath for RadauPath<'_> {
    const RESTEPS: bool = true;

    fn eval(&mut self, s: f64, out: &mut [f64]) {
        if s == self.s1 {
            out.copy_from_slice(self.y1);
            return;
        }
        let th = (s - self.s0) / self.h;
        let [q1, q2, q3] = self.q;
        for (i, o) in out.iter_mut().enumerate() {
            *o = self.y0[i] + th * (q1[i] + th * (q2[i] + th * q3[i]));
        }
    }

    /// The cubic of `eval` in powers of τ = (s − s0)/(s1 − s0), then in
    /// Bernstein form.
    fn control_points(&self, i: usize, out: &mut [f64; MAX_CONTROL]) -> Option<(usize, f64)> {
        // θ = (s − s0)/h = w·τ (w = 1 unless the step end was rounded).
        let w = (self.s1 - self.s0) / self.h;
        let [q1, q2, q3] = self.q.each_ref().map(|q| q[i]);
        let a = [self.y0[i], q1 * w, q2 * w * w, q3 * w * w * w];
        Some(bernstein_points(&a, out))
    }

    /// One Radau IIA step of exactly `s − s0` from the step's start (no
    /// error control: it is no longer than the accepted step), its stages
    /// started from the step's cubic; the Jacobian is the stepper's.
    /// `false` if the Newton iteration does not converge.
    fn restep(&mut self, s: f64, out: &mut [f64]) -> bool {
        let Some(r) = self.restep.as_mut() else {
            return false;
        };
        let h = s - self.s0;
        if h <= 0.0 {
            out.copy_from_slice(self.y0);
            return true;
        }
        let n = self.y0.len();
        let col = r.col.get_or_insert_with(|| Collocation::new(n, r.la));
        let (rtol, atol, newton_tol) = r.tol;
        for (sc, y) in col.scale.iter_mut().zip(self.y0) {
            *sc = atol + rtol * y.abs();
        }
        *r.factorizations += 1;
        if !col.factor(h, r.jac) {
            return false;
        }
        let [q1, q2, q3] = self.q;
        for k in 0..3 {
            let th = C[k] * h / self.h;
            for i in 0..n {
                col.z[k][i] = th * (q1[i] + th * (q2[i] + th * q3[i]));
            }
        }
        // A non-finite rate met here is not one ahead of the stepper's steps.
        let mut non_finite = None;
        let counts = Counts {
            fevals: &mut *r.fevals,
            non_finite: &mut non_finite,
        };
        let (converged, _, _) = col.newton((self.s0, self.y0, h), r.f, newton_tol, counts);
        if converged {
            for i in 0..n {
                out[i] = self.y0[i] + col.z[2][i];
            }
        }
        converged
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;

    /// The constants are the eigen-decomposition of the inverse of Radau
    /// IIA's matrix: `T⁻¹ A⁻¹ T` has the real eigenvalue in its first
    /// diagonal entry and the complex pair in its lower 2×2 block.
    #[test]
    fn transformation_diagonalizes_the_method_matrix() {
        let a = DMatrix::from_row_slice(
            3,
            3,
            &[
                (88.0 - 7.0 * S6) / 360.0,
                (296.0 - 169.0 * S6) / 1800.0,
                (-2.0 + 3.0 * S6) / 225.0,
                (296.0 + 169.0 * S6) / 1800.0,
                (88.0 + 7.0 * S6) / 360.0,
                (-2.0 - 3.0 * S6) / 225.0,
                (16.0 - S6) / 36.0,
                (16.0 + S6) / 36.0,
                1.0 / 9.0,
            ],
        );
        let t = DMatrix::from_fn(3, 3, |r, c| T[r][c]);
        let ti = DMatrix::from_fn(3, 3, |r, c| TI[r][c]);
        let id = &ti * &t;
        assert!((id - DMatrix::identity(3, 3)).amax() < 1e-14);
        let l = &ti * a.try_inverse().unwrap() * &t;
        let mc = mu_complex();
        assert!((l[(0, 0)] - mu_real()).abs() < 1e-12, "{l}");
        for (r, c) in [(0, 1), (0, 2), (1, 0), (2, 0)] {
            assert!(l[(r, c)].abs() < 1e-12, "{l}");
        }
        let block = l.view((1, 1), (2, 2));
        assert!((block.trace() - 2.0 * mc.re).abs() < 1e-12);
        assert!((block.determinant() - mc.norm_sqr()).abs() < 1e-11);
        // The collocation polynomial ends at y0 + z3.
        for (k, row) in P.iter().enumerate() {
            let sum: f64 = row.iter().sum();
            assert!((sum - if k == 2 { 1.0 } else { 0.0 }).abs() < 1e-13);
        }
    }

    /// The control points of a step's collocation cubic give back its
    /// values (de Casteljau on [s0, s1]) within their error bound, also for
    /// a step end that is not s0 + h.
    #[test]
    fn control_points_give_the_collocation_polynomial() {
        let mut f = |s: f64, y: &[f64], dy: &mut [f64]| dy[0] = -3.0 * (y[0] - s.cos());
        let mut jac = |_s: f64, _y: &[f64], j: &mut [f64]| j[0] = -3.0;
        let mut st = Radau5::new(1, 1e-6, 1e-8, &LinearAlgebra::dense(1));
        let y = vec![2.0];
        let mut f0 = vec![0.0];
        f(0.0, &y, &mut f0);
        st.start(&y, &f0, &mut f);
        let h = st.step(0.0, &y, 10.0, &mut f, &mut jac).unwrap();
        for s1 in [h, 0.9 * h] {
            crate::engine::events::tests::assert_control_points(
                &mut st.path(s1, &mut f).0,
                1,
                (0.0, s1),
                4,
            );
        }
    }

    /// A stiff linear problem with a closed form, y' = −λ (y − cos s) −
    /// sin s (λ = 10⁴): steps far above 1/λ, steps ends and the
    /// collocation polynomial within the tolerance.
    #[test]
    fn radau5_follows_a_stiff_solution_with_long_steps() {
        let lam = 1e4;
        let exact = |s: f64| s.cos() + (-lam * s).exp();
        let mut f = |s: f64, y: &[f64], dy: &mut [f64]| dy[0] = -lam * (y[0] - s.cos()) - s.sin();
        let mut jac = |_s: f64, _y: &[f64], j: &mut [f64]| j[0] = -lam;
        let mut st = Radau5::new(1, 1e-8, 1e-10, &LinearAlgebra::dense(1));
        let mut y = vec![2.0];
        let mut f0 = vec![0.0];
        f(0.0, &y, &mut f0);
        st.start(&y, &f0, &mut f);
        let (mut s, end) = (0.0, 10.0);
        let mut steps = 0;
        let mut out = [0.0];
        while s < end {
            let h = st.step(s, &y, end - s, &mut f, &mut jac).unwrap();
            let s1 = if s + h >= end { end } else { s + h };
            let mut p = st.path(s1, &mut f).0;
            for k in 1..4 {
                let sm = s + h * k as f64 / 4.0;
                p.eval(sm, &mut out);
                // The cubic interpolant is of order 3: looser inside steps
                // of the initial transient.
                let tol = if s < 1e-2 { 1e-3 } else { 1e-6 };
                assert!(
                    (out[0] - exact(sm)).abs() < tol,
                    "at {sm}: {} vs {}",
                    out[0],
                    exact(sm)
                );
            }
            y.copy_from_slice(&st.y_new);
            assert!((y[0] - exact(s1)).abs() < 1e-7, "at {s1}");
            s = s1;
            steps += 1;
        }
        // An explicit method needs ≥ λ·10/3.3 ≈ 3·10⁴ steps here.
        assert!(steps < 400, "{steps} steps");
        assert!(
            st.jevals() <= 2,
            "a constant Jacobian is evaluated {} times",
            st.jevals()
        );
    }
}
