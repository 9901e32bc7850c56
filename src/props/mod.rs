//! Property tests on hybrid solutions: state what must hold on every
//! solution, then search for a counterexample the way proptest/QuickCheck
//! do for code.
//!
//! # Semantics
//!
//! A property is checked on the *samples* the engine produces — the initial
//! point, the flow samples (every integrator step, or `t = k·dt_out`), the
//! pre- and post-jump points of every jump and the final point — and on the
//! jumps themselves. Between samples nothing is checked: use `dt_out` or a
//! small `max_step` for a finer net. Every comparison has an explicit
//! tolerance, either written into the predicate (`h >= -1e-9`) or given as
//! `tol` (default in the language: 0). The failing hybrid time `(t, j)` is
//! reported; for jumps it is the pre-jump point `(t, j)`, the post-jump
//! point being `(t, j + 1)`.
//!
//! | property | holds iff |
//! |---|---|
//! | [`always P`](Property::always) | P(t, j, x) at every sample, both sides of jumps included |
//! | [`during flows P`](Property::during_flows) | P at every sample of every flow interval `[t_j, t_{j+1}] × {j}` of positive length, endpoints included |
//! | [`at jumps P`](Property::at_jumps) | P(pre, post) at every jump (optionally of one rule) |
//! | [`eventually within T P`](Property::eventually_within) | P at some sample with `t ≤ T`; fails at the first sample with `t > T` (or at the end of a solution maximal before T); *inconclusive* if a horizon, the Zeno guard or a sink ends the run first |
//! | [`after E always P`](Property::always_after) | P at every sample from the first one where E holds |
//! | [`decreasing V`](Property::decreasing) during flows / at jumps | `V(next) < V(prev)` or `V(next) ≤ tol` |
//! | [`nonincreasing V`](Property::nonincreasing) during flows / at jumps | `V(next) ≤ V(prev) + tol` |
//! | [`exponential bound`](Property::exponential_bound) | `|x|_A(t, j) ≤ κ e^{−α (t + j)} |x|_A(0, 0) + tol` at every sample |
//!
//! "During flows", `prev` and `next` are consecutive samples of one flow
//! interval (same `j`, `t` increasing; repeated points are skipped); "at
//! jumps" they are the pre- and post-jump states. A NaN value fails every
//! comparison.
//!
//! # Checking
//!
//! - On a stored [`HybridArc`](crate::arc::HybridArc):
//!   [`Property::check`] or [`check_arc`].
//! - While simulating: [`PropertySink`] is an [`ArcSink`](crate::arc::ArcSink)
//!   that stops the run at the first violation.
//! - Many sampled cases: a [`Subject`] (a Rust system with
//!   [`SystemSubject`], or a `.hyb` model) and [`run_tests`], which samples
//!   cases from a master seed, runs them in parallel, and [`shrink`]s the
//!   first failure to a minimal [`Counterexample`].
//! - In your own `cargo test`: [`strategy`] (feature `proptest`, on by
//!   default) turns a subject's inputs into a proptest strategy.
//!
//! ```
//! use hybsim::engine::{models::BouncingBall, SimSettings};
//! use hybsim::props::{run_tests, Dist, Outcome, Property, SystemSubject, TestConfig};
//!
//! let ball = SystemSubject::new(
//!     BouncingBall::new(9.81, 0.8),
//!     SimSettings::default().horizon_t(3.0),
//!     vec![Dist::Uniform { lo: 0.0, hi: 2.0 }, Dist::Fixed(0.0)],
//! ).unwrap();
//! let props = [Property::always("never above 1.5", |_, x| x[0] <= 1.5)];
//! let report = run_tests(&ball, &props, &TestConfig::default().cases(50).seed(7));
//! let Outcome::Failed(cx) = report.outcome else { panic!("must fail") };
//! // Shrunk to an initial height just above 1.5.
//! assert!(cx.case.values[0] > 1.5 && cx.case.values[0] < 1.5 + 1e-9);
//! ```

mod model;
mod monitor;
mod property;
mod report;
mod runner;
#[cfg(feature = "proptest")]
pub mod strategy;
#[cfg(test)]
mod tests;

pub use model::{DEFAULT_CASES, ModelRunError, ModelSubject};
pub use monitor::{Conclusion, PropertySink, Verdict, Violation, ViolationDetail, check_arc};
pub use property::{
    JumpPredicate, JumpView, Monotonicity, Property, ScalarFn, Scope, StatePredicate,
};
pub use report::replay_args;
pub use runner::{
    Case, Counterexample, Dist, Input, Outcome, Subject, SystemSubject, TestConfig, TestReport,
    input_stream, run_case, run_tests, run_tests_each, sample_case, shrink,
};
