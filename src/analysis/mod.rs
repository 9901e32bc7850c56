//! Analyses of logged solutions, independent of any model or paper.
//!
//! * [`periodicity`]: asymptotic period and periodic points of any logged
//!   sequence (e.g. `p(k)` and `γ(k)` of a discrete-time run, or a channel of
//!   a [`crate::arc::HybridArc`] at its jumps), with stated tolerances; the
//!   `period(e)` metric of the language reduces a run with it.
//!
//! This module depends only on [`crate::arc`].

pub mod periodicity;
