//! Analyses of logged solutions and paper algorithms.
//!
//! * [`intermittent_estimation`]: the network data, error/θ coordinates and
//!   matrix inequality of distributed estimation under intermittent
//!   asynchronous transmissions (Phillips–Erwin–Sanfelice).
//! * [`periodicity`]: asymptotic period and periodic points of any logged
//!   sequence (e.g. `p(k)` or `γ(k)` of a discrete-time run), with stated
//!   tolerances.
//! * [`variance_trigger`]: the switched Riccati iteration of event-based
//!   estimation with variance-based triggering (Trimpe–D'Andrea): the map
//!   `h`, `h⁻¹`, the invariant interval, Algorithm 1, Assumption 2 and the
//!   contraction bound.
//! * [`reproduction`]: the per-paper tables of `REPRODUCTION.md`, generated
//!   and checked by the tests.
//!
//! This module depends only on [`crate::arc`] and nalgebra.

pub mod intermittent_estimation;
pub mod periodicity;
pub mod reproduction;
pub mod variance_trigger;
