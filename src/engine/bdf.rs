//! The engine's variable-order BDF stepper (orders 1–5), for stiff flows:
//! the numerical differentiation formulas (NDF) of Shampine & Reichelt in
//! quasi-constant step-size form (*The MATLAB ODE suite*, SIAM J. Sci.
//! Comput. 18, 1997; the form scipy's `BDF` implements): the history is the
//! array of backward differences of the solution on an equally spaced grid,
//! re-gridded by a small matrix when the step changes; each step solves its
//! implicit formula by a simplified Newton iteration with one real LU
//! factorization of `I/c − J` (c = h / α_k), estimates its local error
//! from the Newton correction, and after k + 1 steps of equal size chooses
//! the order among k − 1, k, k + 1 by the step each would allow.
//!
//! Built for hybrid runs like the engine's other steppers: it steps one
//! accepted step at a time, gives as dense output of each step the
//! interpolating polynomial through the solution's back values (degree k,
//! exact at both step ends), keeps the Jacobian and its factorization
//! across segments and jumps, and allocates nothing after construction. A
//! multistep history does not survive a jump (the state and often the flow
//! map change): each segment restarts at order 1, from the smaller of the
//! carried step and a fresh first-step estimate.
//!
//! Why own code rather than a crate: `diffsol`'s `Bdf` (the same NDF
//! method) steps one step at a time and interpolates inside the last step,
//! but borrows its problem (built from closures over a fixed right-hand
//! side) for the solver's lifetime, takes the Jacobian as Jacobian-vector
//! products (a dense matrix is rebuilt by n products), and changes the
//! state after a jump only through a new solver state (allocated); the
//! Jacobian cache, LU and norms are shared with [`Radau5`](super::radau5).

// Orders and components are written as in the method's formulas.
#![allow(clippy::needless_range_loop)]

use super::dopri5::{Failure, NonFiniteRate, Rhs};
use super::events::{MAX_CONTROL, StepPath, bernstein_points};
use super::implicit::{
    Jac, Jacobian, LinearAlgebra, NewtonLu, initial_step, newton_tol, rms_scaled,
};
use super::radau5::NONSTIFF_HLAMB;

const MAX_ORDER: usize = 5;
const NEWTON_MAXITER: u32 = 4;
/// A Newton increment at most this fraction of the Newton tolerance ends
/// the iteration (converged) whatever the rate.
const NEGLIGIBLE_INCREMENT: f64 = 1e-3;
const MIN_FACTOR: f64 = 0.2;
const MAX_FACTOR: f64 = 10.0;

/// The NDF's κ_k (Shampine & Reichelt's choice; κ₅ = 0: plain BDF5).
const KAPPA: [f64; MAX_ORDER + 1] = [0.0, -0.1850, -1.0 / 9.0, -0.0823, -0.0415, 0.0];

/// γ_k = Σ_{j=1..k} 1/j.
const fn gamma(k: usize) -> f64 {
    let mut s = 0.0;
    let mut j = 1;
    while j <= k {
        s += 1.0 / j as f64;
        j += 1;
    }
    s
}

/// α_k = (1 − κ_k) γ_k: the formula's coefficient of the newest point.
fn alpha(k: usize) -> f64 {
    (1.0 - KAPPA[k]) * gamma(k)
}

/// The local error constant of order k: κ_k γ_k + 1/(k + 1).
fn error_const(k: usize) -> f64 {
    KAPPA[k] * gamma(k) + 1.0 / (k + 1) as f64
}

/// BDF state: tolerances, order and step, the difference array, the
/// Jacobian and its factorization, buffers, and what the dense output of
/// the last accepted step needs.
pub(crate) struct Bdf {
    rtol: f64,
    atol: f64,
    newton_tol: f64,
    /// Step proposal (carried across segments); 0 before the first step.
    h_next: f64,
    /// Order of the next step.
    order: usize,
    /// Spacing of the grid the differences `d` are on.
    h_d: f64,
    /// Accepted steps since the last change of step or order.
    n_equal: usize,
    /// Backward differences: `d[0]` the solution, `d[k]` its k-th backward
    /// difference on the grid of spacing `h_d`; `d[k+1]`, `d[k+2]` also
    /// hold the last corrections (order selection).
    d: [Vec<f64>; MAX_ORDER + 3],
    jac: Jacobian,
    /// `I/c − J`, factorized for `lu_c` (0: not factorized for the current
    /// Jacobian).
    lu: NewtonLu<f64>,
    lu_c: f64,
    y_predict: Vec<f64>,
    psi: Vec<f64>,
    /// The Newton correction y_new − y_predict.
    corr: Vec<f64>,
    rhs: Vec<f64>,
    f_iter: Vec<f64>,
    scale: Vec<f64>,
    /// The state at the end of the last accepted step.
    pub y_new: Vec<f64>,
    /// The last accepted step: its start, end, length and order (the dense
    /// output is the interpolant of degree `path_order` on `d`).
    s_start: f64,
    s_end: f64,
    h_step: f64,
    path_order: usize,
    /// Evaluations of f, LU factorizations.
    pub fevals: u64,
    /// The last non-finite rate met by a rejected attempt since the last
    /// accepted step.
    pub non_finite: Option<NonFiniteRate>,
    pub factorizations: u64,
}

impl Bdf {
    pub fn new(n: usize, rtol: f64, atol: f64, la: &LinearAlgebra) -> Self {
        let v = || vec![0.0; n];
        Self {
            rtol,
            atol,
            newton_tol: newton_tol(rtol),
            h_next: 0.0,
            order: 1,
            h_d: 0.0,
            n_equal: 0,
            d: std::array::from_fn(|_| v()),
            jac: Jacobian::new(la),
            lu: NewtonLu::new(la),
            lu_c: 0.0,
            y_predict: v(),
            psi: v(),
            corr: v(),
            rhs: v(),
            f_iter: v(),
            scale: v(),
            y_new: v(),
            s_start: 0.0,
            s_end: 0.0,
            h_step: 0.0,
            path_order: 1,
            fevals: 0,
            non_finite: None,
            factorizations: 0,
        }
    }

    /// Starts a segment at local time 0 from `y` with `f0 = f(0, y)` on the
    /// grid of the smaller of the carried proposal and the first-step
    /// estimate (one evaluation of f). The history is that of the Taylor
    /// polynomial `y + s·f0 + s²/2·y''` (order 2), y'' the difference
    /// quotient of f along the flow from the estimate's probe, where the
    /// flow is not stiff at the segment's step scale: the carried proposal
    /// (the first step for the first segment) times the weighted norm of
    /// the Jacobian (kept, or evaluated here for the first segment; the
    /// same test as `Solver::Auto`'s) is at most 1. Elsewhere, or if the
    /// quotient is not finite, the history of the straight line (order 1),
    /// as scipy's and ode15s's restarts. The Jacobian and its
    /// factorization are kept (marked stale).
    ///
    /// Why order 2: an order-1 start is not exact on a quadratic path, so
    /// a flow cut short by frequent jumps keeps an error of the order of
    /// the tolerance in every segment. On the bouncing ball near its Zeno
    /// time, where the bounces shrink below `atol`, that error compounded
    /// from bounce to bounce into lost energy until the ball sank through
    /// the floor (the run ended with "cannot flow" instead of at the Zeno
    /// guard); the order-2 start follows the parabolas exactly, as Dopri5
    /// and Radau5 do. Why not where stiff: the Taylor history stands for
    /// the past of a smooth solution; after a jump into a stiff transient
    /// (the stiff relay's sensor) the L-stable order-1 start is the more
    /// accurate (order 2 there: switching times 10× further off).
    pub fn start(&mut self, y: &[f64], f0: &[f64], f: &mut Rhs<'_>, jac: &mut Jac<'_>) {
        let (est, probe) = initial_step(
            y,
            f0,
            f,
            self.rtol,
            self.atol,
            1,
            &mut self.y_predict,
            &mut self.f_iter,
        );
        self.fevals += 1;
        let carried = self.h_next;
        let h = if carried > 0.0 { carried.min(est) } else { est };
        self.h_next = h;
        self.h_d = h;
        self.n_equal = 0;
        self.d[0].copy_from_slice(y);
        for d in &mut self.d[2..] {
            d.fill(0.0);
        }
        let evaluated = self.jac.ensure(0.0, y, jac);
        if evaluated {
            self.lu_c = 0.0;
        }
        for (sc, v) in self.scale.iter_mut().zip(y) {
            *sc = self.atol + self.rtol * v.abs();
        }
        let scale = if carried > 0.0 { carried } else { h };
        let nonstiff = scale * self.jac.weighted_norm(&self.scale) <= NONSTIFF_HLAMB;
        let curvature_known = probe > 0.0
            && self
                .f_iter
                .iter()
                .zip(f0)
                .all(|(f1, f0)| ((f1 - f0) / probe).is_finite());
        if nonstiff && curvature_known {
            // ∇y = h·f0 − h²/2·y'', ∇²y = h²·y'' (the Taylor polynomial's
            // backward differences on the grid of spacing h).
            self.order = 2;
            for i in 0..y.len() {
                let ydd = (self.f_iter[i] - f0[i]) / probe;
                self.d[1][i] = h * f0[i] - 0.5 * h * h * ydd;
                self.d[2][i] = h * h * ydd;
            }
        } else {
            self.order = 1;
            for (d1, f) in self.d[1].iter_mut().zip(f0) {
                *d1 = h * f;
            }
        }
        self.jac.fresh = evaluated;
    }

    /// The proposal for the next step.
    pub fn proposal(&self) -> f64 {
        self.h_next
    }

    /// Lowers the step proposal to at most `h`.
    pub fn limit_proposal(&mut self, h: f64) {
        self.h_next = self.h_next.min(h);
    }

    /// Evaluations of the Jacobian so far.
    #[cfg(test)]
    pub fn jevals(&self) -> u64 {
        self.jac.evals
    }

    /// Re-grids the differences of order ≤ `self.order` from spacing
    /// `h_d` to `h` (the interpolating polynomial is unchanged).
    fn regrid(&mut self, h: f64) {
        let k = self.order;
        let factor = h / self.h_d;
        let r = Self::r_matrix(k, factor);
        let u = Self::r_matrix(k, 1.0);
        // ru = R·U; the new differences are (R·U)ᵀ applied to the old.
        let mut ru = [[0.0; MAX_ORDER + 1]; MAX_ORDER + 1];
        for a in 0..=k {
            for b in 0..=k {
                ru[a][b] = (0..=k).map(|m| r[a][m] * u[m][b]).sum();
            }
        }
        let n = self.y_new.len();
        let mut old = [0.0; MAX_ORDER + 1];
        for i in 0..n {
            for a in 0..=k {
                old[a] = self.d[a][i];
            }
            for b in 1..=k {
                self.d[b][i] = (0..=k).map(|a| ru[a][b] * old[a]).sum();
            }
        }
        self.h_d = h;
    }

    /// The matrix that maps the differences on a grid of spacing h to
    /// those on spacing `factor·h` (with its inverse at factor 1, Shampine
    /// & Reichelt's change of step): `R[i][j] = Π_{m=1..i} (m − 1 −
    /// factor·j) / m`.
    fn r_matrix(k: usize, factor: f64) -> [[f64; MAX_ORDER + 1]; MAX_ORDER + 1] {
        let mut r = [[0.0; MAX_ORDER + 1]; MAX_ORDER + 1];
        for j in 0..=k {
            r[0][j] = 1.0;
            for i in 1..=k {
                r[i][j] = r[i - 1][j] * ((i - 1) as f64 - factor * j as f64) / i as f64;
            }
        }
        r
    }

    /// One accepted step from (`s`, `y`) of at most `h_max` (rejected
    /// attempts are retried with smaller steps; a Newton iteration that
    /// does not converge refreshes the Jacobian at the prediction, then
    /// halves the step); `h_max` is taken exactly if the proposal reaches
    /// it. Returns the step length; the new state is in
    /// [`y_new`](Self::y_new), the step's interpolant in
    /// [`path`](Self::path).
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
            self.lu_c = 0.0;
        }
        loop {
            let mut h = self.h_next.min(h_max);
            let clipped = h >= 0.99 * h_max;
            if clipped {
                h = h_max;
            }
            if h <= 0.0 || s + 0.1 * h == s || !h.is_finite() {
                return Err(Failure::Underflow);
            }
            if h != self.h_d {
                self.regrid(h);
            }
            let k = self.order;
            let c = h / alpha(k);
            for i in 0..n {
                let mut p = 0.0;
                let mut q = 0.0;
                for m in 0..=k {
                    p += self.d[m][i];
                }
                for m in 1..=k {
                    q += gamma(m) * self.d[m][i];
                }
                self.y_predict[i] = p;
                self.psi[i] = q / alpha(k);
                self.scale[i] = self.atol + self.rtol * p.abs();
            }
            let s_new = s + h;
            // Newton, with a fresh Jacobian at the prediction if it does
            // not converge with the kept one.
            let converged = loop {
                if self.lu_c != c {
                    self.factorizations += 1;
                    if self.lu.factor_shifted(1.0 / c, &self.jac) {
                        self.lu_c = c;
                    } else {
                        self.lu_c = 0.0;
                        if self.jac.fresh {
                            break None;
                        }
                        self.jac.refresh(s_new, &self.y_predict, jac);
                        continue;
                    }
                }
                match self.newton(s_new, c, f) {
                    Some(iters) => break Some(iters),
                    None if self.jac.fresh => break None,
                    None => {
                        self.jac.refresh(s_new, &self.y_predict, jac);
                        self.lu_c = 0.0;
                    }
                }
            };
            let Some(iters) = converged else {
                self.h_next = 0.5 * h;
                self.n_equal = 0;
                continue;
            };
            let safety =
                0.9 * f64::from(2 * NEWTON_MAXITER + 1) / f64::from(2 * NEWTON_MAXITER + iters);
            for i in 0..n {
                self.scale[i] = self.atol + self.rtol * self.y_new[i].abs();
            }
            let err = error_const(k) * rms_scaled(&self.corr, &self.scale);
            if err.is_nan() || err > 1.0 {
                let factor = if err.is_finite() {
                    MIN_FACTOR.max(safety * err.powf(-1.0 / (k + 1) as f64))
                } else {
                    MIN_FACTOR
                };
                self.h_next = h * factor;
                self.n_equal = 0;
                continue;
            }
            // Accepted: the new differences.
            self.n_equal += 1;
            for i in 0..n {
                let corr = self.corr[i];
                self.d[k + 2][i] = corr - self.d[k + 1][i];
                self.d[k + 1][i] = corr;
                for m in (0..=k).rev() {
                    self.d[m][i] += self.d[m + 1][i];
                }
            }
            (self.s_start, self.s_end) = (s, s_new);
            self.h_step = h;
            self.path_order = k;
            self.jac.fresh = false;
            let mut h_new = h;
            if self.n_equal > k {
                // Order and step by the step each order allows.
                let e_minus = if k > 1 {
                    error_const(k - 1) * rms_scaled(&self.d[k], &self.scale)
                } else {
                    f64::INFINITY
                };
                let e_plus = if k < MAX_ORDER {
                    error_const(k + 1) * rms_scaled(&self.d[k + 2], &self.scale)
                } else {
                    f64::INFINITY
                };
                let factors = [
                    e_minus.powf(-1.0 / k as f64),
                    err.powf(-1.0 / (k + 1) as f64),
                    e_plus.powf(-1.0 / (k + 2) as f64),
                ];
                let (best, fmax) =
                    factors
                        .iter()
                        .enumerate()
                        .fold(
                            (1, factors[1]),
                            |b, (i, &v)| if v > b.1 { (i, v) } else { b },
                        );
                self.order = k + best - 1;
                h_new = h * MAX_FACTOR.min(safety * fmax);
                self.n_equal = 0;
            }
            // A step cut short by h_max keeps the controller's proposal.
            self.h_next = if clipped {
                h_new.max(self.h_next)
            } else {
                h_new
            };
            self.non_finite = None;
            return Ok(h);
        }
    }

    /// The simplified Newton iteration of the step's formula from the
    /// prediction, into `y_new` and `corr`; the iterations if it converged.
    fn newton(&mut self, s_new: f64, c: f64, f: &mut Rhs<'_>) -> Option<u32> {
        let n = self.y_new.len();
        self.y_new.copy_from_slice(&self.y_predict);
        self.corr.fill(0.0);
        let mut norm_old: f64 = -1.0;
        for it in 0..NEWTON_MAXITER {
            f(s_new, &self.y_new, &mut self.f_iter);
            self.fevals += 1;
            if self.f_iter.iter().any(|v| !v.is_finite()) {
                self.non_finite = NonFiniteRate::find(s_new, &self.f_iter).or(self.non_finite);
                return None;
            }
            for i in 0..n {
                self.rhs[i] = self.f_iter[i] - (self.psi[i] + self.corr[i]) / c;
            }
            self.lu.solve(&mut self.rhs);
            let norm = rms_scaled(&self.rhs, &self.scale);
            if !norm.is_finite() {
                return None;
            }
            let rate = if norm_old > 0.0 {
                norm / norm_old
            } else {
                f64::NAN
            };
            // An increment far below the tolerance: the prediction was the
            // solution up to rounding (a polynomial path of degree ≤ k, as
            // a parabola after the order-2 start), and the ratio of two
            // such increments is rounding noise, not a divergence.
            let negligible = norm <= NEGLIGIBLE_INCREMENT * self.newton_tol;
            if rate.is_finite()
                && !negligible
                && (rate >= 1.0
                    || rate.powi((NEWTON_MAXITER - it) as i32) / (1.0 - rate) * norm
                        > self.newton_tol)
            {
                return None;
            }
            for i in 0..n {
                self.y_new[i] += self.rhs[i];
                self.corr[i] += self.rhs[i];
            }
            if negligible || (rate.is_finite() && rate / (1.0 - rate) * norm < self.newton_tol) {
                return Some(it + 1);
            }
            norm_old = norm;
        }
        None
    }

    /// The interpolant of the last accepted step, ending at local time `s1`
    /// (its end, or the segment end it was rounded to).
    pub fn path(&self, s1: f64) -> BdfPath<'_> {
        BdfPath {
            d: &self.d,
            order: self.path_order,
            s0: self.s_start,
            s_end: self.s_end,
            h: self.h_step,
            s1,
            y1: &self.y_new,
        }
    }
}

/// The polynomial of degree k through the solution at the last k + 1
/// grid points `s_end − m·h` (m = 0..k), in Newton's backward form from
/// the differences.
pub(crate) struct BdfPath<'a> {
    d: &'a [Vec<f64>; MAX_ORDER + 3],
    order: usize,
    /// The step's start (the watcher's step is `[s0, s1]`).
    s0: f64,
    s_end: f64,
    h: f64,
    s1: f64,
    y1: &'a [f64],
}

impl StepPath for BdfPath<'_> {
    fn eval(&mut self, s: f64, out: &mut [f64]) {
        if s == self.s1 {
            out.copy_from_slice(self.y1);
            return;
        }
        // y(s_end + θh) = Σ_m ∇^m y · θ(θ+1)…(θ+m−1)/m!
        let th = (s - self.s_end) / self.h;
        let mut coef = [0.0; MAX_ORDER + 1];
        coef[0] = 1.0;
        for m in 1..=self.order {
            coef[m] = coef[m - 1] * (th + (m - 1) as f64) / m as f64;
        }
        for (i, o) in out.iter_mut().enumerate() {
            *o = (0..=self.order).map(|m| coef[m] * self.d[m][i]).sum();
        }
    }

    fn control_points(&self, i: usize, out: &mut [f64; MAX_CONTROL]) -> Option<(usize, f64)> {
        // On the step, θ = θ₀ + w·τ for τ ∈ [0, 1]; the Newton basis
        // θ(θ+1)…(θ+m−1)/m! in powers of τ, one factor at a time, and
        // the component's coefficients Σ_m ∇^m yᵢ · (basis m).
        let (th0, w) = (
            (self.s0 - self.s_end) / self.h,
            (self.s1 - self.s0) / self.h,
        );
        let k = self.order;
        let mut basis = [0.0; MAX_ORDER + 1];
        basis[0] = 1.0;
        let mut a = [0.0; MAX_ORDER + 1];
        let mut size = 0.0;
        for m in 0..=k {
            if m > 0 {
                // basis ← basis · (θ₀ + m − 1 + w τ)/m
                let c0 = (th0 + (m - 1) as f64) / m as f64;
                let c1 = w / m as f64;
                for p in (0..=m).rev() {
                    let lower = if p > 0 { basis[p - 1] * c1 } else { 0.0 };
                    basis[p] = basis[p] * c0 + lower;
                }
            }
            let dm = self.d[m][i];
            for (ap, &bp) in a.iter_mut().zip(&basis[..=m]) {
                *ap += dm * bp;
                size += (dm * bp).abs();
            }
        }
        let (len, err) = bernstein_points(&a[..=k], out);
        // The basis' and the sums' own rounding, a few ulp of each term.
        Some((len, err + 4.0 * (k + 2) as f64 * f64::EPSILON * size))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Re-gridding keeps the interpolating polynomial: the differences of
    /// samples of a cubic on spacing h, re-gridded to 0.37h, are those of
    /// samples on spacing 0.37h.
    #[test]
    fn regrid_keeps_the_interpolating_polynomial() {
        let p = |s: f64| 1.0 - 2.0 * s + 0.5 * s * s - 0.25 * s * s * s;
        let diffs = |h: f64| {
            let mut v: Vec<f64> = (0..=3).map(|m| p(-(m as f64) * h)).collect();
            let mut out = vec![v[0]];
            for _ in 0..3 {
                v = v.windows(2).map(|w| w[0] - w[1]).collect();
                out.push(v[0]);
            }
            out
        };
        let mut st = Bdf::new(1, 1e-6, 1e-9, &LinearAlgebra::dense(1));
        st.order = 3;
        st.h_d = 0.2;
        for (m, v) in diffs(0.2).into_iter().enumerate() {
            st.d[m][0] = v;
        }
        st.regrid(0.2 * 0.37);
        for (m, v) in diffs(0.2 * 0.37).into_iter().enumerate() {
            assert!(
                (st.d[m][0] - v).abs() < 1e-14,
                "∇^{m}: {} vs {v}",
                st.d[m][0]
            );
        }
    }

    /// A stiff linear problem with a closed form, y' = −λ (y − cos s) −
    /// sin s (λ = 10⁴): steps far above 1/λ, orders up to 5, step ends and
    /// the interpolant within the tolerance, one Jacobian.
    #[test]
    fn bdf_follows_a_stiff_solution_with_long_steps() {
        let lam = 1e4;
        let exact = |s: f64| s.cos() + (-lam * s).exp();
        let mut f = |s: f64, y: &[f64], dy: &mut [f64]| dy[0] = -lam * (y[0] - s.cos()) - s.sin();
        let mut jac = |_s: f64, _y: &[f64], j: &mut [f64]| j[0] = -lam;
        let mut st = Bdf::new(1, 1e-8, 1e-10, &LinearAlgebra::dense(1));
        let mut y = vec![2.0];
        let mut f0 = vec![0.0];
        f(0.0, &y, &mut f0);
        st.start(&y, &f0, &mut f, &mut jac);
        let (mut s, end) = (0.0, 10.0);
        let mut steps = 0;
        let mut top_order = 0;
        let mut out = [0.0];
        while s < end {
            let h = st.step(s, &y, end - s, &mut f, &mut jac).unwrap();
            let s1 = if s + h >= end { end } else { s + h };
            top_order = top_order.max(st.path_order);
            let mut p = st.path(s1);
            p.eval(s, &mut out);
            assert!((out[0] - y[0]).abs() < 1e-12, "continuous at {s}");
            for k in 1..4 {
                let sm = s + h * k as f64 / 4.0;
                p.eval(sm, &mut out);
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
        assert!(steps < 2000, "{steps} steps");
        assert!(top_order == MAX_ORDER, "order {top_order}");
        assert_eq!(st.jevals(), 1, "a constant Jacobian is evaluated once");
    }

    /// The control points give the interpolant on each step, at every
    /// order the method reaches, on full steps and on a step whose end was
    /// rounded to a segment's end.
    #[test]
    fn control_points_give_the_interpolant() {
        let mut f = |s: f64, y: &[f64], dy: &mut [f64]| {
            dy[0] = -50.0 * (y[0] - s.cos());
            dy[1] = y[0] - y[1];
        };
        let mut jac = |_s: f64, _y: &[f64], j: &mut [f64]| {
            j.copy_from_slice(&[-50.0, 0.0, 1.0, -1.0]);
        };
        let mut st = Bdf::new(2, 1e-8, 1e-10, &LinearAlgebra::dense(2));
        let mut y = vec![2.0, 0.0];
        let mut f0 = vec![0.0; 2];
        f(0.0, &y, &mut f0);
        st.start(&y, &f0, &mut f, &mut jac);
        let mut s = 0.0;
        let mut orders = [false; MAX_ORDER + 1];
        for _ in 0..400 {
            let h = st.step(s, &y, 5.0 - s, &mut f, &mut jac).unwrap();
            orders[st.path_order] = true;
            let s1 = s + h;
            for end in [s1, s + 0.999_999_999 * h] {
                let mut p = st.path(end);
                let count = st.path_order + 1;
                crate::engine::events::tests::assert_control_points(&mut p, 2, (s, end), count);
            }
            y.copy_from_slice(&st.y_new);
            s = s1;
            if s >= 5.0 {
                break;
            }
        }
        assert!(orders[2..].iter().all(|&o| o), "orders met: {orders:?}");
    }

    /// The constants: the NDF's α and error constants at order 1 (implicit
    /// Euler: α = 1 − κ₁, error κ₁ + 1/2) and the plain BDF5 at order 5.
    #[test]
    fn ndf_constants() {
        assert!((alpha(1) - 1.185).abs() < 1e-15);
        assert!((error_const(1) - (0.5 - 0.185)).abs() < 1e-15);
        assert!((gamma(5) - 137.0 / 60.0).abs() < 1e-15);
        assert!((error_const(5) - 1.0 / 6.0).abs() < 1e-15);
    }
}
