//! What the engine's explicit Runge–Kutta pairs ([`Dopri5`] and
//! [`Dop853`]) share: the step loop around a tableau's attempt, Hairer's
//! step-size controller (step proposal carried across segments and jumps,
//! the initial step estimate, limits from the caller) and stiffness test,
//! and their [`OwnStepper`] interface. A pair supplies only what is its
//! own ([`Tableau`]): its stages, error estimate, dense output and gains.
//!
//! [`Dopri5`]: super::dopri5::Dopri5
//! [`Dop853`]: super::dop853::Dop853

use super::dopri5::{Failure, NonFiniteRate, Rhs, initial_step};
use super::flow::DensePath;
use super::implicit::Jac;
use super::stepper::OwnStepper;

/// The constants of a pair's controller and stiffness test.
pub(crate) struct Gains {
    /// Safety factor on the step proposal.
    pub safe: f64,
    /// Weight of the PI controller's previous error (0: none).
    pub beta: f64,
    /// Smallest and largest factor of a step proposal over the last step.
    pub fac_min: f64,
    pub fac_max: f64,
    /// Exponent of the error in the step factor (its I term).
    pub expo: f64,
    /// Stiffness test's threshold on the estimate of h·λ.
    pub stiff_hlamb: f64,
}

/// Steps between stiffness tests (Hairer's default), and how many stiff
/// tests in a row make a failure.
const STIFF_EVERY: u32 = 1000;
const STIFF_COUNT: u32 = 15;

/// Accepted steps in a row over which one component's rate changes sign
/// on every step or every other one (at most [`CHATTER_GAP`] steps in a row
/// without a change) that make a failure ([`Failure::Chatter`]): a resolved
/// flow turns a rate around over several steps, a flow map discontinuous
/// where the solution slides (`x' = -sign(x)`) every step or two (Dopri5's
/// cycle has period 2, Dop853's 4), which the controller accepts at a step
/// of about `atol` / |ẋ| for ever (a relay once took 10⁷ Dopri5 steps per
/// unit of t, 10⁸ of Dop853's). Past Hairer's stiffness test (every 1000
/// steps, 15 in a row), which a stiff flow at the stability limit meets
/// first.
const CHATTER_STEPS: u32 = 10_000;
const CHATTER_GAP: u32 = 1;
/// The longest run of steps without a change that a slide whose steps
/// cross the surface less regularly may have (`x' = -sign(x) + 0.5 sin t`:
/// more steps on the slow side): such a window is a chatter only once the
/// flow's Jacobian confirms it ([`Failure::Chatter`]'s `strict`), as a
/// smooth fast oscillation at loose tolerances turns its rates around
/// every few steps too.
const CHATTER_LOOSE_GAP: u32 = 8;
/// Accepted steps of one flow before the chatter test looks for a
/// component at all: its scan of every rate is then paid by long flows
/// only, not by the short flows between jumps (the 42-state agents
/// benchmark paid 4 % more instructions for it on every step).
const CHATTER_AFTER: u32 = 1_000;

/// The part of an explicit pair that is its own: the stages of a step
/// attempt and the dense output of an accepted step, over a fixed number
/// of state vectors allocated once.
pub(crate) trait Tableau {
    /// The order of the steps (the initial step estimate's).
    const ORDER: i32;
    const GAINS: Gains;
    /// Evaluations of f per step attempt.
    const ATTEMPT_EVALS: u64;
    /// The dense output of one accepted step.
    type Path<'a>: DensePath
    where
        Self: 'a;

    /// The stage vectors for states of length `n`.
    fn new(n: usize) -> Self;

    /// The first stage (f at the step start) and the second (room for a
    /// rate).
    fn first_stages(&mut self) -> (&mut [f64], &mut [f64]);

    /// The stages of an attempt of length `h` from (`s`, `y`) (`ys`: room
    /// for their arguments): the new state into `yn`, and returns the
    /// error norm relative to the tolerances (`(rtol, atol)`), at most 1
    /// on a step to accept, non-finite when a stage is.
    #[allow(clippy::too_many_arguments)]
    fn attempt(
        &mut self,
        s: f64,
        y: &[f64],
        h: f64,
        tol: (f64, f64),
        ys: &mut [f64],
        yn: &mut [f64],
        f: &mut Rhs<'_>,
    ) -> f64;

    /// The first non-finite stage rate (in time) of an attempt of length
    /// `h` from `s`.
    fn non_finite(&self, s: f64, h: f64) -> Option<NonFiniteRate>;

    /// f at the end (`s_new`, `yn`) of an accepted step, where the attempt
    /// did not evaluate it; returns the evaluations of f.
    fn end_rate(&mut self, _s_new: f64, _yn: &[f64], _f: &mut Rhs<'_>) -> u64 {
        0
    }

    /// f at the end of the accepted step and the last stage, evaluated at
    /// the same time (the stiffness test's pair).
    fn end_rates(&self) -> (&[f64], &[f64]);

    /// f at the start of the accepted step (before [`fsal`](Self::fsal)).
    fn start_rate(&self) -> &[f64];

    /// The dense output of the accepted step of length `h` from `y` to
    /// `yn`, or the part of it that needs no more evaluations of f (the
    /// rest is the path's, on its first read of the step's interior).
    fn dense_output(&mut self, y: &[f64], h: f64, yn: &[f64]);

    /// f at the step end becomes the next step's first stage (FSAL).
    fn fsal(&mut self);

    /// The dense output of the last accepted step (`(s0, h)`: its start
    /// and length) ending at local time `s1` in `y1`; `rest` for what it
    /// defers.
    fn path<'a>(
        &'a mut self,
        step: (f64, f64),
        s1: f64,
        y1: &'a [f64],
        rest: Deferred<'a>,
    ) -> Self::Path<'a>;
}

/// What a path needs to finish its step's dense output when the step's
/// interior is first read: room for stage arguments, the count of f's
/// evaluations, and f.
pub(crate) struct Deferred<'a> {
    pub ys: &'a mut [f64],
    pub fevals: &'a mut u64,
    pub f: &'a mut Rhs<'a>,
}

/// An explicit pair: tolerances, the controller's state, the stiffness
/// test's, and the tableau's stages and interpolant of the last accepted
/// step.
pub(crate) struct Explicit<T> {
    rtol: f64,
    atol: f64,
    /// Step proposal of the controller (carried across segments); 0 before
    /// the first step.
    h_next: f64,
    facold: f64,
    /// `facold^beta`, kept with `facold`: it changes only when the error
    /// does (on a flow integrated exactly it stays at `1e-4^beta`).
    facold_beta: f64,
    /// Stiffness test: every how many accepted steps it runs, and its state.
    stiff_every: u32,
    /// Its threshold on h·λ (the pair's own unless set).
    stiff_hlamb: f64,
    accepted: u32,
    stiff_hits: u32,
    nonstiff_hits: u32,
    /// The chatter test's state: the component whose rate kept changing
    /// sign over the last `chatter_steps` accepted steps, and the steps in
    /// a row since its last change.
    chatter_component: usize,
    chatter_steps: u32,
    chatter_idle: u32,
    /// Whether the current window has had no gap above [`CHATTER_GAP`].
    chatter_strict: bool,
    /// Accepted steps since the flow started, counted up to [`CHATTER_AFTER`].
    flow_steps: u32,
    tab: T,
    /// The argument of the last stage evaluated.
    y_stage: Vec<f64>,
    /// The state at the end of the last accepted step.
    pub y_new: Vec<f64>,
    /// Start and length of the last accepted step.
    s_old: f64,
    h_old: f64,
    /// Evaluations of f since construction.
    pub fevals: u64,
    /// The last non-finite stage rate since the last accepted step.
    non_finite: Option<NonFiniteRate>,
}

impl<T: Tableau> Explicit<T> {
    pub fn new(n: usize, rtol: f64, atol: f64) -> Self {
        Self {
            rtol,
            atol,
            h_next: 0.0,
            facold: 1e-4,
            facold_beta: 1e-4f64.powf(T::GAINS.beta),
            stiff_every: STIFF_EVERY,
            stiff_hlamb: T::GAINS.stiff_hlamb,
            accepted: 0,
            stiff_hits: 0,
            nonstiff_hits: 0,
            chatter_component: 0,
            chatter_steps: 0,
            chatter_idle: 0,
            chatter_strict: true,
            flow_steps: 0,
            tab: T::new(n),
            y_stage: vec![0.0; n],
            y_new: vec![0.0; n],
            s_old: 0.0,
            h_old: 0.0,
            fevals: 0,
            non_finite: None,
        }
    }

    /// The same stepper with the stiffness test run every `every` accepted
    /// steps (≥ 1; default 1000, Hairer's; at every step once it fired):
    /// `Solver::Auto` tests every 10, to hand a stiff flow to the implicit
    /// method early.
    pub fn stiffness_test_every(mut self, every: u32) -> Self {
        self.stiff_every = every.max(1);
        self
    }

    /// The same stepper with the stiffness test's threshold on h·λ lowered
    /// to `h_lamb` (at most the pair's own: a lower one only finds a flow
    /// stiff sooner).
    pub fn stiffness_threshold(mut self, h_lamb: f64) -> Self {
        self.stiff_hlamb = h_lamb.min(T::GAINS.stiff_hlamb);
        self
    }

    /// Sets the proposal for the next step (a method taking over from
    /// another starts from that one's step).
    pub fn set_proposal(&mut self, h: f64) {
        self.h_next = h;
    }

    /// Starts a segment at local time 0 from `y` with `f0 = f(0, y)`; the
    /// carried proposal is kept, or a first step estimated (one more f).
    pub fn start(&mut self, y: &[f64], f0: &[f64], f: &mut Rhs<'_>) {
        // A chatter is counted within one flow (a jump between steps is
        // not a discontinuity of the flow map).
        self.chatter_steps = 0;
        self.flow_steps = 0;
        let (k1, k2) = self.tab.first_stages();
        k1.copy_from_slice(f0);
        if self.h_next <= 0.0 {
            let tol = (self.rtol, self.atol);
            self.h_next = initial_step(T::ORDER, tol, y, k1, (&mut self.y_stage, k2), f);
            self.fevals += 1;
        }
    }

    /// One accepted step from (`s`, `y`) of at most `h_max` (rejected
    /// attempts are retried with smaller steps); `h_max` is taken exactly
    /// if the proposal reaches it. Returns the step length; the new state
    /// is in [`y_new`](Self::y_new) (f there is the next step's first
    /// stage), and the step's interpolant in [`path`](Self::path).
    pub fn step(&mut self, s: f64, y: &[f64], h_max: f64, f: &mut Rhs<'_>) -> Result<f64, Failure> {
        let g = T::GAINS;
        let n = y.len();
        let mut rejected = false;
        loop {
            // A proposal within 1 % of h_max takes h_max: no sliver of a
            // step (or an underflow) left before a segment end.
            let mut h = self.h_next.min(h_max);
            let clipped = h >= 0.99 * h_max;
            if clipped {
                h = h_max;
            }
            if h <= 0.0 || s + 0.1 * h == s {
                return Err(Failure::Underflow);
            }
            let tol = (self.rtol, self.atol);
            let (ys, yn) = (&mut self.y_stage[..n], &mut self.y_new[..n]);
            let err = self.tab.attempt(s, y, h, tol, ys, yn, f);
            self.fevals += T::ATTEMPT_EVALS;
            // pow(0, y > 0) is +0 exactly: an exact step needs no call.
            let fac11 = if err == 0.0 { 0.0 } else { err.powf(g.expo) };
            // Without a PI term the previous error is left out (β = 0:
            // `facold^β` is 1).
            let pi = if g.beta == 0.0 { 1.0 } else { self.facold_beta };
            let fac_free = fac11 / pi / g.safe;
            let fac = fac_free.clamp(1.0 / g.fac_max, 1.0 / g.fac_min);
            let mut h_new = h / fac;
            if !err.is_finite() {
                // A non-finite stage: retry much smaller, remembering the
                // first one in time.
                self.non_finite = self.tab.non_finite(s, h).or(self.non_finite);
                self.h_next = h * g.fac_min;
                rejected = true;
                continue;
            }
            if err > 1.0 {
                self.h_next = h / (1.0 / g.fac_min).min(fac11 / g.safe);
                rejected = true;
                continue;
            }
            self.fevals += self.tab.end_rate(s + h, &self.y_new, f);
            if g.beta != 0.0 {
                let facold = err.max(1e-4);
                if facold != self.facold {
                    self.facold = facold;
                    self.facold_beta = facold.powf(g.beta);
                }
            }
            // A step so accurate that the controller would grow it by more
            // than its largest factor is not held back by stability.
            self.stiffness(h, fac_free < 1.0 / g.fac_max)?;
            self.chatter(h, y)?;
            self.tab.dense_output(y, h, &self.y_new);
            self.tab.fsal();
            if rejected {
                h_new = h_new.min(h);
            }
            // A step cut short by h_max keeps the controller's own proposal,
            // so a segment end (a sampling instant) does not shrink the
            // steps of the next segments.
            self.h_next = if clipped {
                h_new.max(self.h_next)
            } else {
                h_new
            };
            self.s_old = s;
            self.h_old = h;
            self.non_finite = None;
            return Ok(h);
        }
    }

    /// Hairer's stiffness test on the last accepted step: h·λ estimated
    /// from f at the step end and the last stage (both at s + h), every
    /// `stiff_every` steps. `free`: the step's error is far below the
    /// tolerance (the controller would grow it by more than its largest
    /// factor). Such a step does not count as stiff: the estimate
    /// ‖Δf‖/‖Δy‖ bounds the Jacobian's norm, not its eigenvalues, and on
    /// flows integrated exactly (constant acceleration: a nilpotent
    /// Jacobian of norm 1) steps longer than the threshold would otherwise
    /// read as stiffness.
    fn stiffness(&mut self, h: f64, free: bool) -> Result<(), Failure> {
        self.accepted += 1;
        if !self.accepted.is_multiple_of(self.stiff_every) && self.stiff_hits == 0 {
            return Ok(());
        }
        // Hairer's test: ‖Δk‖ / ‖Δy‖ between the step's last two stage
        // arguments estimates the Jacobian's dominant |λ|.
        let (k_end, k_last) = self.tab.end_rates();
        let h_lamb = if free {
            0.0
        } else {
            let (mut num, mut den) = (0.0, 0.0);
            for i in 0..self.y_new.len() {
                num += (k_end[i] - k_last[i]).powi(2);
                den += (self.y_new[i] - self.y_stage[i]).powi(2);
            }
            if den > 0.0 {
                h * (num / den).sqrt()
            } else {
                0.0
            }
        };
        let stiff = h_lamb > self.stiff_hlamb;
        if stiff {
            self.nonstiff_hits = 0;
            self.stiff_hits += 1;
            if self.stiff_hits == STIFF_COUNT {
                // A stepper that goes on (under `Solver::Auto`) tests afresh.
                self.stiff_hits = 0;
                self.nonstiff_hits = 0;
                // Δk ≈ J Δy with Δy drawn towards the dominant mode by the
                // steps: its largest entry relative to the tolerances is
                // the component that mode moves most (the stiff one, not
                // merely the fastest-changing).
                let scale = |i: usize| self.atol + self.rtol * self.y_new[i].abs();
                let rate = |i: usize| (k_end[i] - k_last[i]).abs() / scale(i);
                let component = (0..self.y_new.len())
                    .max_by(|&a, &b| rate(a).total_cmp(&rate(b)))
                    .unwrap_or(0);
                return Err(Failure::Stiff {
                    component,
                    h,
                    h_lamb,
                });
            }
        } else {
            self.nonstiff_hits += 1;
            if self.nonstiff_hits == 6 {
                self.stiff_hits = 0;
            }
        }
        Ok(())
    }

    /// The chatter test on the accepted step of length `h` from `y`: a
    /// component whose rate changed sign across it by more than the step
    /// can carry smoothly (h·|Δẋᵢ| above its tolerance: a sign that
    /// rounding flips near ẋᵢ = 0 does not count), the same component on
    /// every step or every other one for [`CHATTER_STEPS`] steps, looked
    /// for after the flow's first [`CHATTER_AFTER`] steps.
    fn chatter(&mut self, h: f64, y: &[f64]) -> Result<(), Failure> {
        if self.flow_steps < CHATTER_AFTER {
            self.flow_steps += 1;
            return Ok(());
        }
        let k0 = self.tab.start_rate();
        let (k1, _) = self.tab.end_rates();
        let tol = |i: usize| self.atol + self.rtol * y[i].abs().max(self.y_new[i].abs());
        // 1: the rate changed sign across the step, by more than the step
        // carries smoothly; 2: both end rates have one sign and the state
        // moved the other way, beyond the tolerance (the rate turned
        // around inside the step: a slide on one side of the surface, its
        // stages across it); 0: neither. The sign first: most steps change
        // no rate's sign.
        let flips = |i: usize| -> u8 {
            let (a, b) = (k0[i], k1[i]);
            if a * b < 0.0 {
                return u8::from(h * (b - a).abs() > tol(i));
            }
            let d = self.y_new[i] - y[i];
            if d * a < 0.0 && d * b < 0.0 && d.abs() > tol(i) {
                2
            } else {
                0
            }
        };
        if self.chatter_steps > 0 {
            self.chatter_idle = match flips(self.chatter_component) {
                0 => self.chatter_idle + 1,
                kind => {
                    self.chatter_strict &= kind == 1;
                    0
                }
            };
            if self.chatter_idle <= CHATTER_LOOSE_GAP {
                self.chatter_strict &= self.chatter_idle <= CHATTER_GAP;
                self.chatter_steps += 1;
                if self.chatter_steps >= CHATTER_STEPS {
                    self.chatter_steps = 0;
                    return Err(Failure::Chatter {
                        component: self.chatter_component,
                        h,
                        strict: self.chatter_strict,
                    });
                }
                return Ok(());
            }
        }
        // A new candidate, if a rate changed sign across this step.
        match (0..y.len()).find_map(|i| (flips(i) != 0).then(|| (i, flips(i) == 1))) {
            Some((i, strict)) => {
                (
                    self.chatter_component,
                    self.chatter_steps,
                    self.chatter_idle,
                    self.chatter_strict,
                ) = (i, 1, 0, strict)
            }
            None => self.chatter_steps = 0,
        }
        Ok(())
    }

    /// The interpolant of the last accepted step, ending at local time
    /// `s1` (its end, or the segment end it was rounded to), and the state
    /// there; `f` evaluates what the interpolant defers. Valid until the
    /// next step.
    pub fn path<'a>(&'a mut self, s1: f64, f: &'a mut Rhs<'_>) -> (T::Path<'a>, &'a [f64]) {
        let rest = Deferred {
            ys: &mut self.y_stage,
            fevals: &mut self.fevals,
            f,
        };
        let step = (self.s_old, self.h_old);
        (self.tab.path(step, s1, &self.y_new, rest), &self.y_new)
    }
}

impl<T: Tableau> OwnStepper for Explicit<T> {
    type Path<'a>
        = T::Path<'a>
    where
        Self: 'a;

    fn start(&mut self, y: &[f64], f0: &[f64], f: &mut Rhs<'_>, _jac: &mut Jac<'_>) {
        Explicit::start(self, y, f0, f);
    }

    fn step(
        &mut self,
        s: f64,
        y: &[f64],
        h_max: f64,
        f: &mut Rhs<'_>,
        _jac: &mut Jac<'_>,
    ) -> Result<f64, Failure> {
        Explicit::step(self, s, y, h_max, f)
    }

    fn y_new(&self) -> &[f64] {
        &self.y_new
    }

    fn path<'a>(&'a mut self, s1: f64, f: &'a mut Rhs<'_>) -> (T::Path<'a>, &'a [f64]) {
        Explicit::path(self, s1, f)
    }

    fn proposal(&self) -> f64 {
        self.h_next
    }

    fn limit_proposal(&mut self, h: f64) {
        self.h_next = self.h_next.min(h);
    }

    fn forgive_chatter(&mut self) {
        self.chatter_steps = 0;
    }

    fn fevals(&self) -> u64 {
        self.fevals
    }

    fn non_finite(&self) -> Option<NonFiniteRate> {
        self.non_finite
    }
}
