//! The engine's own one-step integrators behind one interface, so that
//! flow segments drive them alike (events and output on each accepted
//! step's dense output, step carry across segments): the explicit
//! [`Dopri5`] and [`Dop853`] (one implementation for both, in
//! [`explicit`](super::explicit)), and the implicit [`Radau5`] and [`Bdf`]
//! for stiff flows.
//!
//! [`Dopri5`]: super::dopri5::Dopri5
//! [`Dop853`]: super::dop853::Dop853

use super::bdf::{Bdf, BdfPath};
use super::dopri5::{Failure, NonFiniteRate, Rhs};
use super::flow::DensePath;
use super::implicit::Jac;
use super::radau5::{Radau5, RadauPath};

/// A stepper that advances one accepted step at a time.
pub(crate) trait OwnStepper {
    /// The dense output of one accepted step.
    type Path<'a>: DensePath
    where
        Self: 'a;

    /// Starts a segment at local time 0 from `y` with `f0 = f(0, y)` (`jac`:
    /// ∂f/∂y in the same local time, for implicit methods).
    fn start(&mut self, y: &[f64], f0: &[f64], f: &mut Rhs<'_>, jac: &mut Jac<'_>);

    /// One accepted step from (`s`, `y`) of at most `h_max`; returns its
    /// length. `jac` gives ∂f/∂y to implicit methods.
    fn step(
        &mut self,
        s: f64,
        y: &[f64],
        h_max: f64,
        f: &mut Rhs<'_>,
        jac: &mut Jac<'_>,
    ) -> Result<f64, Failure>;

    /// The state at the end of the last accepted step.
    fn y_new(&self) -> &[f64];

    /// The dense output of the last accepted step, ending at `s1`, and the
    /// state there; `f` for what a method evaluates only once the step's
    /// interior is read (Dop853's extra stages).
    fn path<'a>(&'a mut self, s1: f64, f: &'a mut Rhs<'_>) -> (Self::Path<'a>, &'a [f64]);

    /// The step proposal.
    fn proposal(&self) -> f64;

    /// Lowers the step proposal to at most `h` (> 0).
    fn limit_proposal(&mut self, h: f64);

    /// Evaluations of f so far.
    fn fevals(&self) -> u64;

    /// After a [`Failure::Chatter`](super::dopri5::Failure::Chatter) that
    /// was not `strict` and that the flow's Jacobian showed smooth: the
    /// chatter test starts afresh, and the step that failed is taken again
    /// (it is not yet part of the solution).
    fn forgive_chatter(&mut self) {}

    /// The last non-finite value of the flow a rejected attempt met since
    /// the last accepted step (what a following step-size collapse is).
    fn non_finite(&self) -> Option<NonFiniteRate>;

    /// `Solver::Auto`'s test after an accepted step of an implicit method:
    /// `Some(true)` if the flow is no longer stiff there; `None` if not
    /// tested (with `fresh_only`, when that needs a new Jacobian). Explicit
    /// methods: `None`.
    fn nonstiff(&mut self, _jac: &mut Jac<'_>, _fresh_only: bool) -> Option<bool> {
        None
    }
}

impl OwnStepper for Radau5 {
    type Path<'a> = RadauPath<'a>;

    fn start(&mut self, y: &[f64], f0: &[f64], f: &mut Rhs<'_>, _jac: &mut Jac<'_>) {
        Radau5::start(self, y, f0, f);
    }

    fn step(
        &mut self,
        s: f64,
        y: &[f64],
        h_max: f64,
        f: &mut Rhs<'_>,
        jac: &mut Jac<'_>,
    ) -> Result<f64, Failure> {
        Radau5::step(self, s, y, h_max, f, jac)
    }

    fn y_new(&self) -> &[f64] {
        &self.y_new
    }

    fn path<'a>(&'a mut self, s1: f64, f: &'a mut Rhs<'_>) -> (RadauPath<'a>, &'a [f64]) {
        Radau5::path(self, s1, f)
    }

    fn proposal(&self) -> f64 {
        Radau5::proposal(self)
    }

    fn limit_proposal(&mut self, h: f64) {
        Radau5::limit_proposal(self, h);
    }

    fn fevals(&self) -> u64 {
        self.fevals
    }

    fn non_finite(&self) -> Option<NonFiniteRate> {
        self.non_finite
    }

    fn nonstiff(&mut self, jac: &mut Jac<'_>, fresh_only: bool) -> Option<bool> {
        Radau5::nonstiff(self, jac, fresh_only)
    }
}

impl OwnStepper for Bdf {
    type Path<'a> = BdfPath<'a>;

    fn start(&mut self, y: &[f64], f0: &[f64], f: &mut Rhs<'_>, jac: &mut Jac<'_>) {
        Bdf::start(self, y, f0, f, jac);
    }

    fn step(
        &mut self,
        s: f64,
        y: &[f64],
        h_max: f64,
        f: &mut Rhs<'_>,
        jac: &mut Jac<'_>,
    ) -> Result<f64, Failure> {
        Bdf::step(self, s, y, h_max, f, jac)
    }

    fn y_new(&self) -> &[f64] {
        &self.y_new
    }

    fn path<'a>(&'a mut self, s1: f64, _f: &'a mut Rhs<'_>) -> (BdfPath<'a>, &'a [f64]) {
        let this: &'a Self = self;
        (Bdf::path(this, s1), &this.y_new)
    }

    fn proposal(&self) -> f64 {
        Bdf::proposal(self)
    }

    fn limit_proposal(&mut self, h: f64) {
        Bdf::limit_proposal(self, h);
    }

    fn fevals(&self) -> u64 {
        self.fevals
    }

    fn non_finite(&self) -> Option<NonFiniteRate> {
        self.non_finite
    }
}
