//! The engine's own one-step integrators behind one interface, so that
//! flow segments drive them alike (events and output on each accepted
//! step's dense output, step carry across segments): the explicit
//! [`Dopri5`] and the implicit [`Radau5`] for stiff flows.

use super::dopri5::{Dopri5, DopriPath, Failure, Rhs};
use super::flow::DensePath;
use super::radau5::{Jac, Radau5, RadauPath};

/// A stepper that advances one accepted step at a time.
pub(crate) trait OwnStepper {
    /// The dense output of one accepted step.
    type Path<'a>: DensePath
    where
        Self: 'a;

    /// Starts a segment at local time 0 from `y` with `f0 = f(0, y)`.
    fn start(&mut self, y: &[f64], f0: &[f64], f: &mut Rhs<'_>);

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

    /// The dense output of the last accepted step, ending at `s1`.
    fn path(&self, s1: f64) -> Self::Path<'_>;

    /// The step proposal.
    fn proposal(&self) -> f64;

    /// Evaluations of f so far.
    fn fevals(&self) -> u64;
}

impl OwnStepper for Dopri5 {
    type Path<'a> = DopriPath<'a>;

    fn start(&mut self, y: &[f64], f0: &[f64], f: &mut Rhs<'_>) {
        Dopri5::start(self, y, f0, f);
    }

    fn step(
        &mut self,
        s: f64,
        y: &[f64],
        h_max: f64,
        f: &mut Rhs<'_>,
        _jac: &mut Jac<'_>,
    ) -> Result<f64, Failure> {
        Dopri5::step(self, s, y, h_max, f)
    }

    fn y_new(&self) -> &[f64] {
        &self.y_new
    }

    fn path(&self, s1: f64) -> DopriPath<'_> {
        Dopri5::path(self, s1)
    }

    fn proposal(&self) -> f64 {
        Dopri5::proposal(self)
    }

    fn fevals(&self) -> u64 {
        self.fevals
    }
}

impl OwnStepper for Radau5 {
    type Path<'a> = RadauPath<'a>;

    fn start(&mut self, y: &[f64], f0: &[f64], f: &mut Rhs<'_>) {
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

    fn path(&self, s1: f64) -> RadauPath<'_> {
        Radau5::path(self, s1)
    }

    fn proposal(&self) -> f64 {
        Radau5::proposal(self)
    }

    fn fevals(&self) -> u64 {
        self.fevals
    }
}
