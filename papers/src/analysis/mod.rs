//! Paper algorithms, independent of simulation, and the reproduction tables.
//!
//! * [`intermittent_estimation`]: the network data, error/θ coordinates and
//!   matrix inequality of distributed estimation under intermittent
//!   asynchronous transmissions (Phillips–Erwin–Sanfelice).
//! * [`variance_trigger`]: the switched Riccati iteration of event-based
//!   estimation with variance-based triggering (Trimpe–D'Andrea): the map
//!   `h`, `h⁻¹`, the invariant interval, Algorithm 1, Assumption 2 and the
//!   contraction bound.
//! * [`reproduction`]: the per-paper tables of `REPRODUCTION.md`, generated
//!   and checked by the tests.
//!
//! The general analysis of logged runs (periodicity detection) is the
//! library's [`hybsim::analysis`].

pub mod intermittent_estimation;
pub mod reproduction;
pub mod variance_trigger;
