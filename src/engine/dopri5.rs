//! The engine's own Dormand–Prince 5(4) stepper, built for hybrid runs:
//! steps one at a time (the caller decides after each accepted step),
//! reuses f at the step end as the next step's first stage (FSAL) and the
//! caller's f at a segment start, keeps the controller's step proposal
//! across segments and jumps, gives the order-4 dense-output interpolant of
//! each step, and allocates nothing after construction.
//!
//! ode_solvers' `Dopri5` (kept for the reference-style benchmarks) hides
//! the step proposal and the interpolant and allocates per stepper; see
//! BENCHMARKS.md for the measured difference. Coefficients and controller
//! follow Hairer, Nørsett & Wanner, *Solving ODEs I*, II.4–II.6 (DOPRI5).

use super::events::{MAX_CONTROL, StepPath, bernstein_points};
use super::explicit::{Deferred, Explicit, Gains, Tableau};

// Nodes and coefficients of the Dormand–Prince pair.
const C2: f64 = 1.0 / 5.0;
const C3: f64 = 3.0 / 10.0;
const C4: f64 = 4.0 / 5.0;
const C5: f64 = 8.0 / 9.0;
const A21: f64 = 1.0 / 5.0;
const A31: f64 = 3.0 / 40.0;
const A32: f64 = 9.0 / 40.0;
const A41: f64 = 44.0 / 45.0;
const A42: f64 = -56.0 / 15.0;
const A43: f64 = 32.0 / 9.0;
const A51: f64 = 19372.0 / 6561.0;
const A52: f64 = -25360.0 / 2187.0;
const A53: f64 = 64448.0 / 6561.0;
const A54: f64 = -212.0 / 729.0;
const A61: f64 = 9017.0 / 3168.0;
const A62: f64 = -355.0 / 33.0;
const A63: f64 = 46732.0 / 5247.0;
const A64: f64 = 49.0 / 176.0;
const A65: f64 = -5103.0 / 18656.0;
const A71: f64 = 35.0 / 384.0;
const A73: f64 = 500.0 / 1113.0;
const A74: f64 = 125.0 / 192.0;
const A75: f64 = -2187.0 / 6784.0;
const A76: f64 = 11.0 / 84.0;
const E1: f64 = 71.0 / 57600.0;
const E3: f64 = -71.0 / 16695.0;
const E4: f64 = 71.0 / 1920.0;
const E5: f64 = -17253.0 / 339200.0;
const E6: f64 = 22.0 / 525.0;
const E7: f64 = -1.0 / 40.0;
const D1: f64 = -12715105075.0 / 11282082432.0;
const D3: f64 = 87487479700.0 / 32700410799.0;
const D4: f64 = -10690763975.0 / 1880347072.0;
const D5: f64 = 701980252875.0 / 199316789632.0;
const D6: f64 = -1453857185.0 / 822651844.0;
const D7: f64 = 69997945.0 / 29380423.0;

// Step-size controller (Hairer's defaults, as ode_solvers uses them) and
// the stiffness test's threshold.
const GAINS: Gains = Gains {
    safe: 0.9,
    beta: 0.04,
    fac_min: 0.2,
    fac_max: 10.0,
    expo: 0.2 - 0.04 * 0.75,
    stiff_hlamb: 3.25,
};

/// The flow in local time: `f(s, y, dy)` writes ẏ at (s, y) into `dy`.
pub(crate) type Rhs<'a> = dyn FnMut(f64, &[f64], &mut [f64]) + 'a;

/// A non-finite value of the flow met at a stage of a rejected step
/// attempt: where (local time), which component, what value. A step size
/// that then collapses is reported as this value (the flow is NaN or ±∞
/// past that point), not as a collapse blamed on the fastest component.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct NonFiniteRate {
    pub s: f64,
    pub component: usize,
    pub value: f64,
}

impl NonFiniteRate {
    /// The first non-finite component of the rate `dy` evaluated at `s`.
    pub fn find(s: f64, dy: &[f64]) -> Option<Self> {
        let component = crate::num::first_non_finite(dy)?;
        Some(Self {
            s,
            component,
            value: dy[component],
        })
    }
}

/// Hairer's initial step estimate (HINIT) for a method of order `order`
/// from `y` with `f0 = f(0, y)`, with one evaluation of f (`scratch`: room
/// for a state and its rate).
pub(crate) fn initial_step(
    order: i32,
    (rtol, atol): (f64, f64),
    y: &[f64],
    f0: &[f64],
    (y1, f1): (&mut [f64], &mut [f64]),
    f: &mut Rhs<'_>,
) -> f64 {
    let n = y.len() as f64;
    let sk = |i: usize| atol + rtol * y[i].abs();
    let (mut dnf, mut dny) = (0.0, 0.0);
    for (i, yi) in y.iter().enumerate() {
        dnf += (f0[i] / sk(i)).powi(2);
        dny += (yi / sk(i)).powi(2);
    }
    // A tolerance far below the rates (`atol = 1e-300` on a state that
    // starts at 0) overflows the sums of squares: the estimate from the
    // norms themselves instead (the sums gave a zero or NaN step, a
    // collapse at t = 0 or a run of NaN steps).
    let overflow = !(dnf.is_finite() && dny.is_finite());
    let (dnf, dny) = if overflow {
        (
            norm_over(y.len(), |i| f0[i] / sk(i)),
            norm_over(y.len(), |i| y[i] / sk(i)),
        )
    } else {
        (dnf, dny)
    };
    let h = if overflow {
        if dnf <= 1e-5 || dny <= 1e-5 {
            1e-6
        } else {
            dny / dnf * 0.01
        }
    } else if dnf <= 1e-10 || dny <= 1e-10 {
        1e-6
    } else {
        (dny / dnf).sqrt() * 0.01
    };
    // Ratios of norms that far apart (below the subnormals) leave no step.
    let h = if h > 0.0 { h } else { f64::MIN_POSITIVE };
    for (i, yi) in y.iter().enumerate() {
        y1[i] = yi + h * f0[i];
    }
    f(h, y1, f1);
    let mut der2: f64 = 0.0;
    for i in 0..y.len() {
        der2 += ((f1[i] - f0[i]) / sk(i)).powi(2);
    }
    let der2 = if der2.is_finite() {
        der2.sqrt() / h
    } else {
        norm_over(y.len(), |i| (f1[i] - f0[i]) / sk(i)) / h
    };
    let rate = if overflow {
        dnf / n.sqrt()
    } else {
        (dnf / n).sqrt()
    };
    let der12 = der2.abs().max(rate);
    let h1 = if der12 <= 1e-15 {
        (h * 1e-3).max(1e-6)
    } else {
        (0.01 / der12).powf(1.0 / f64::from(order))
    };
    let h = (100.0 * h).min(h1);
    // A rate that is itself infinite: the stepper's first attempt finds it.
    if h > 0.0 && h.is_finite() { h } else { 1e-6 }
}

/// The Euclidean norm of `v(0), …, v(n − 1)` without overflow of its
/// squares (scaled by the largest magnitude).
fn norm_over(n: usize, v: impl Fn(usize) -> f64) -> f64 {
    let m = (0..n).fold(0.0f64, |m, i| m.max(v(i).abs()));
    if m == 0.0 || !m.is_finite() {
        return m;
    }
    m * (0..n).map(|i| (v(i) / m).powi(2)).sum::<f64>().sqrt()
}

/// Why a step attempt failed for good.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Failure {
    /// The step size fell below the resolution of the local time.
    Underflow,
    /// The stiffness test fired repeatedly; `component` is where the
    /// stiff mode acts most, `h_lamb` the last test's estimate of h·|λ|
    /// on the step of length `h` (see `Explicit::stiffness`).
    Stiff {
        component: usize,
        h: f64,
        h_lamb: f64,
    },
    /// The rate of `component` kept changing sign over many accepted
    /// steps, the last of length `h` (see `Explicit::chatter`): on every
    /// step or every other one (`strict`), or every few steps, a chatter
    /// only if the flow's Jacobian is small there.
    Chatter {
        component: usize,
        h: f64,
        strict: bool,
    },
}

/// The engine's Dopri5 stepper.
pub(crate) type Dopri5 = Explicit<Dopri5Tableau>;

/// Dopri5's own part: the stages and the interpolant of the last accepted
/// step.
pub(crate) struct Dopri5Tableau {
    /// k1 (f at the step start; FSAL) … k7 (f at the step end).
    k: [Vec<f64>; 7],
    /// The five vectors of the dense-output polynomial of the last step.
    rcont: [Vec<f64>; 5],
}

impl Tableau for Dopri5Tableau {
    const ORDER: i32 = 5;
    const GAINS: Gains = GAINS;
    const ATTEMPT_EVALS: u64 = 6;
    type Path<'a> = DopriPath<'a>;

    fn new(n: usize) -> Self {
        let v = || vec![0.0; n];
        Self {
            k: [v(), v(), v(), v(), v(), v(), v()],
            rcont: [v(), v(), v(), v(), v()],
        }
    }

    fn first_stages(&mut self) -> (&mut [f64], &mut [f64]) {
        let [k1, k2, ..] = &mut self.k;
        (k1, k2)
    }

    fn attempt(
        &mut self,
        s: f64,
        y: &[f64],
        h: f64,
        (rtol, atol): (f64, f64),
        ys: &mut [f64],
        yn: &mut [f64],
        f: &mut Rhs<'_>,
    ) -> f64 {
        // Every vector cut to n: the loops below then index without
        // bounds checks (a third of a small system's step otherwise).
        let n = y.len();
        let [k1, k2, k3, k4, k5, k6, k7] = &mut self.k;
        let (k1, k2, k3, k4) = (&mut k1[..n], &mut k2[..n], &mut k3[..n], &mut k4[..n]);
        let (k5, k6, k7) = (&mut k5[..n], &mut k6[..n], &mut k7[..n]);
        let (ys, yn) = (&mut ys[..n], &mut yn[..n]);
        for i in 0..n {
            ys[i] = y[i] + h * A21 * k1[i];
        }
        f(s + C2 * h, ys, k2);
        for i in 0..n {
            ys[i] = y[i] + h * (A31 * k1[i] + A32 * k2[i]);
        }
        f(s + C3 * h, ys, k3);
        for i in 0..n {
            ys[i] = y[i] + h * (A41 * k1[i] + A42 * k2[i] + A43 * k3[i]);
        }
        f(s + C4 * h, ys, k4);
        for i in 0..n {
            ys[i] = y[i] + h * (A51 * k1[i] + A52 * k2[i] + A53 * k3[i] + A54 * k4[i]);
        }
        f(s + C5 * h, ys, k5);
        for i in 0..n {
            ys[i] =
                y[i] + h * (A61 * k1[i] + A62 * k2[i] + A63 * k3[i] + A64 * k4[i] + A65 * k5[i]);
        }
        let s_new = s + h;
        f(s_new, ys, k6);
        for i in 0..n {
            yn[i] =
                y[i] + h * (A71 * k1[i] + A73 * k3[i] + A74 * k4[i] + A75 * k5[i] + A76 * k6[i]);
        }
        f(s_new, yn, k7);
        let mut err = 0.0;
        for i in 0..n {
            let e =
                h * (E1 * k1[i] + E3 * k3[i] + E4 * k4[i] + E5 * k5[i] + E6 * k6[i] + E7 * k7[i]);
            let sk = atol + rtol * y[i].abs().max(yn[i].abs());
            err += (e / sk) * (e / sk);
        }
        (err / n as f64).sqrt()
    }

    fn non_finite(&self, s: f64, h: f64) -> Option<NonFiniteRate> {
        // k6 and k7 are both at s + h.
        let [_, k2, k3, k4, k5, k6, k7] = &self.k;
        let stages = [(C2, k2), (C3, k3), (C4, k4), (C5, k5), (1.0, k6)];
        stages
            .iter()
            .find_map(|&(c, k)| NonFiniteRate::find(s + c * h, k))
            .or_else(|| NonFiniteRate::find(s + h, k7))
    }

    fn end_rates(&self) -> (&[f64], &[f64]) {
        (&self.k[6], &self.k[5])
    }

    fn dense_output(&mut self, y: &[f64], h: f64, yn: &[f64]) {
        let n = y.len();
        let [k1, _, k3, k4, k5, k6, k7] = &self.k;
        let (k1, k3, k4, k5) = (&k1[..n], &k3[..n], &k4[..n], &k5[..n]);
        let (k6, k7, yn) = (&k6[..n], &k7[..n], &yn[..n]);
        let [r1, r2, r3, r4, r5] = &mut self.rcont;
        let (r1, r2, r3) = (&mut r1[..n], &mut r2[..n], &mut r3[..n]);
        let (r4, r5) = (&mut r4[..n], &mut r5[..n]);
        for i in 0..n {
            let ydiff = yn[i] - y[i];
            let bspl = h * k1[i] - ydiff;
            r1[i] = y[i];
            r2[i] = ydiff;
            r3[i] = bspl;
            r4[i] = ydiff - h * k7[i] - bspl;
            r5[i] =
                h * (D1 * k1[i] + D3 * k3[i] + D4 * k4[i] + D5 * k5[i] + D6 * k6[i] + D7 * k7[i]);
        }
    }

    fn start_rate(&self) -> &[f64] {
        &self.k[0]
    }

    fn fsal(&mut self) {
        self.k.swap(0, 6);
    }

    fn path<'a>(
        &'a mut self,
        (s0, h): (f64, f64),
        s1: f64,
        y1: &'a [f64],
        _rest: Deferred<'a>,
    ) -> DopriPath<'a> {
        DopriPath {
            rcont: &self.rcont,
            s0,
            h,
            s1,
            y1,
        }
    }
}

/// The order-4 dense output of one Dopri5 step.
pub(crate) struct DopriPath<'a> {
    rcont: &'a [Vec<f64>; 5],
    s0: f64,
    h: f64,
    s1: f64,
    y1: &'a [f64],
}

impl DopriPath<'_> {
    /// The state at the step's start (the interpolant's constant term, its
    /// value there up to the sign of a zero).
    pub fn start(&self) -> &[f64] {
        &self.rcont[0][..self.y1.len()]
    }
}

impl StepPath for DopriPath<'_> {
    fn eval(&mut self, s: f64, out: &mut [f64]) {
        if s == self.s1 {
            out.copy_from_slice(self.y1);
            return;
        }
        let th = (s - self.s0) / self.h;
        let th1 = 1.0 - th;
        let [r1, r2, r3, r4, r5] = self.rcont;
        for (i, o) in out.iter_mut().enumerate() {
            *o = r1[i] + th * (r2[i] + th1 * (r3[i] + th * (r4[i] + th1 * r5[i])));
        }
    }

    /// The quartic of `eval` in powers of τ = (s − s0)/(s1 − s0), then in
    /// Bernstein form.
    fn control_points(&self, i: usize, out: &mut [f64; MAX_CONTROL]) -> Option<(usize, f64)> {
        let r = &self.rcont;
        let (r1, r2, r3, r4, r5) = (r[0][i], r[1][i], r[2][i], r[3][i], r[4][i]);
        // θ = (s − s0)/h = w·τ (w = 1 unless the step end was rounded).
        let w = (self.s1 - self.s0) / self.h;
        let (w2, w3, w4) = (w * w, w * w * w, w * w * w * w);
        let a = [
            r1,
            (r2 + r3) * w,
            (r4 + r5 - r3) * w2,
            -(r4 + 2.0 * r5) * w3,
            r5 * w4,
        ];
        // The coefficients' own rounding is within the bound of their sum.
        Some(bernstein_points(&a, out))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The control points of a step's quartic give back its values (de
    /// Casteljau on [s0, s1]) within their error bound, also when the step
    /// end is not s0 + h (a step end rounded to a segment end).
    #[test]
    fn control_points_give_the_dense_output() {
        let mut f = |s: f64, y: &[f64], dy: &mut [f64]| {
            dy[0] = y[1];
            dy[1] = -y[0].sin() + 0.3 * s.cos();
        };
        let mut st = Dopri5::new(2, 1e-6, 1e-8);
        let y = vec![1.0, -0.5];
        let mut f0 = vec![0.0; 2];
        f(0.0, &y, &mut f0);
        st.start(&y, &f0, &mut f);
        let h = st.step(0.0, &y, 10.0, &mut f).unwrap();
        for s1 in [h, 0.9 * h] {
            let mut p = st.path(s1, &mut f).0;
            crate::engine::events::tests::assert_control_points(&mut p, 2, (0.0, s1), 5);
        }
    }

    /// y' = -y + sin(s): steps and interpolant against the closed form,
    /// within the tolerance.
    #[test]
    fn dopri5_steps_and_dense_output_follow_the_solution() {
        let exact = |s: f64| 1.5 * (-s).exp() + 0.5 * (s.sin() - s.cos());
        let mut f = |s: f64, y: &[f64], dy: &mut [f64]| dy[0] = -y[0] + s.sin();
        let mut st = Dopri5::new(1, 1e-8, 1e-10);
        let mut y = vec![1.0];
        let mut f0 = vec![0.0];
        f(0.0, &y, &mut f0);
        st.start(&y, &f0, &mut f);
        let mut s = 0.0;
        let mut steps = 0;
        while s < 10.0 {
            let h = st.step(s, &y, 10.0 - s, &mut f).unwrap();
            let s1 = if s + h >= 10.0 { 10.0 } else { s + h };
            let (mut p, _) = st.path(s1, &mut f);
            let mut out = [0.0];
            let mut out_start = [0.0];
            // The path's start, which dense output reads instead of
            // evaluating the path there, is the state the step started from.
            assert_eq!(p.start(), &y[..], "start of the step at {s}");
            p.eval(s, &mut out_start);
            assert_eq!(out_start, y[..], "the interpolant at {s}");
            for k in 1..4 {
                let sm = s + h * k as f64 / 4.0;
                p.eval(sm, &mut out);
                assert!((out[0] - exact(sm)).abs() < 1e-7, "at {sm}");
            }
            y.copy_from_slice(&st.y_new);
            s = s1;
            steps += 1;
        }
        assert!((y[0] - exact(10.0)).abs() < 1e-7);
        assert!(steps < 200, "{steps} steps");
        // FSAL: six evaluations per step, plus the initial estimate's one.
        assert!(st.fevals <= 6 * steps as u64 + 6 * 20 + 1);
    }
}
