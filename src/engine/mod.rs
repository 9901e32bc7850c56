//! The hybrid simulation engine. It knows nothing of the model language: it
//! runs any [`HybridSystem`], be it a compiled `.hyb` model or a Rust struct.
//!
//! # Semantics
//!
//! A solution starts at hybrid time (0, 0) from `x0` and is built as a
//! sequence of flows and jumps. At each point `(t, j)` the engine decides:
//!
//! 1. **Horizons first.** If `t ≥ T` ([`SimSettings::horizon_t`]) or
//!    `j ≥ J` ([`SimSettings::horizon_j`]) the solution ends there
//!    ([`TerminationCause::HorizonT`] / [`TerminationCause::HorizonJ`]); in
//!    particular no jump is taken at `t = T`.
//! 2. **Which rule is enabled.** The enabled rule is the *first rule in
//!    declaration order* whose jump set contains x (or whose event the last
//!    flow just localized, see below). By default one jump is one rule: it
//!    increments j by exactly one; the state is then re-examined at the same
//!    t, so if several rules are enabled they fire one after another, each
//!    on the state left by the previous one, in declaration order, as long as
//!    they stay enabled. **Simultaneous jumps:** if the enabled rule has a
//!    [`group`](JumpRule::group), every rule of that group whose jump set
//!    holds at the pre-jump point (or at the post-crossing end of the event
//!    just localized, i.e. at the same instant within the event tolerance;
//!    grouped timers due within the tolerance land on their threshold with
//!    it) fires in the same jump: each jump map is evaluated at the
//!    pre-jump state and hybrid time, x⁺ takes component `k` from the rule
//!    whose [`writes`](JumpRule::writes) contain `k` and keeps the others,
//!    and j increments by one (HyEQ's `CompositeHybridSystem`). The sink
//!    receives one [`jump`](crate::arc::ArcSink::jump) per firing rule, in
//!    declaration order, all at the same (t, j) with the same pre- and
//!    post-jump states.
//! 3. **Flow or jump.** With x ∈ D only it jumps; with x ∈ C only it flows;
//!    with x ∈ C ∩ D the [`Priority`] decides: [`Priority::Jumps`] (the
//!    default, as HyEQ) jumps, [`Priority::Flows`] flows and jumps only when
//!    the flow leaves C, [`Priority::Random`] flips a fair coin from the
//!    run's [`SimRng`].
//! 4. **Neither.** If x is in neither set (or the previous flow ended
//!    because it was leaving C and x is not in D), the solution is maximal
//!    and ends with [`TerminationCause::CannotFlowOrJump`].
//! 5. **Zeno guards** (only when [`horizon_j`](SimSettings::horizon_j) is
//!    unbounded: a finite J is the run's jump budget, and the run reaches
//!    it). Before each jump, with `j` jumps made: if the last
//!    [`zeno_window`](SimSettings::zeno_window) jumps and this one happen
//!    within less than `zeno_window / zeno_max_rate` units of t (see
//!    [`zeno_max_rate`](SimSettings::zeno_max_rate)), or `j` reached
//!    [`max_total_jumps`](SimSettings::max_total_jumps), the run ends at
//!    `(t, j)` with [`TerminationCause::ZenoSuspected`] naming the rule. A
//!    pure discrete-time system whose jumps all happen at one `t` runs to a
//!    finite J; with J unbounded it needs `zeno_max_rate = ∞` and stops
//!    after `max_total_jumps`.
//!
//! A flow segment runs until the first of: the horizon T, the next *timer*
//! event, or a localized *guard* event:
//!
//! - [`GuardKind::Timer`] rules fire when their timer (a state with
//!   constant rate along the flow) reaches the threshold: the time is
//!   computed exactly and the timer is set exactly to the threshold. No
//!   root finding.
//! - [`GuardKind::General`] rules (not watched under [`Priority::Flows`])
//!   fire when their guard changes from < 0 to ≥ 0 and the jump set holds
//!   just past the crossing; the flow guard triggers when it changes from
//!   ≥ 0 to < 0 and the flow-set predicate fails just past it. Guards are
//!   evaluated at each step end and at [`guard_checks`](SimSettings::guard_checks)
//!   interior points of the step (on the interpolant), then the first sign
//!   change is bracketed and shrunk to [`event_tol`](SimSettings::event_tol)
//!   (default: 4 ulp of the local time). The solution continues from the
//!   *pre-crossing* end of the bracket, which is on the flow's side of the
//!   guard within the tolerance: this point is the pre-jump state (for a
//!   rule) or the last point of C (for the flow guard).
//! - **Limit:** a guard that becomes ≥ 0 and < 0 again between two
//!   consecutive checkpoints of one step (step ends and interior points) is
//!   not seen; lower [`max_step`](SimSettings::max_step) or raise
//!   `guard_checks` for guards that touch D only briefly. A flow that
//!   starts with a guard already ≥ 0 but outside D_i is not an event until
//!   the guard goes below 0 and comes back.
//!
//! Flows are advanced by [`Solver::Dopri5`] (default), [`Solver::Dop853`]
//! or [`Solver::Rk4`] from `ode_solvers`, each segment integrated in local
//! time `[0, d]` while t is kept as a compensated sum of segment lengths;
//! events are localized on the cubic Hermite interpolant of the step ends
//! (exact for polynomial flows such as free fall; O(h⁴) otherwise). Flows
//! declared [`FlowStructure::Affine`] are advanced exactly by the
//! exponential of `[[A, b], [0, 0]]`, cached per step length, and their
//! events are localized on the exact solution; a sampled-data loop whose
//! flow is a linear plant plus held inputs and a timer costs one
//! matrix-vector product per sample. Noisy flows
//! ([`HybridSystem::noise_dim`] > 0) need [`Solver::EulerMaruyama`].
//!
//! # Output
//! The sink receives an [`Initial`](crate::arc::SampleKind::Initial)
//! sample, `Flow` samples at each integrator step (or at `t = k·dt_out`
//! when [`dt_out`](SimSettings::dt_out) is set, interpolated as above), a
//! `PreJump` sample, the jump, a `PostJump` sample for each jump, and a
//! `Final` sample (which may repeat the last point). A sink may stop the
//! run ([`TerminationCause::StoppedBySink`]).
//!
//! # Example: a bouncing ball defined in Rust
//!
//! ```
//! use hybsim::arc::{HybridTime, TerminationCause};
//! use hybsim::engine::{simulate_arc, HybridSystem, JumpRule, GuardKind, SimRng, SimSettings};
//!
//! /// Height h and velocity v; flows in C = {h ≥ 0}, jumps in D = {h ≤ 0, v ≤ 0}.
//! struct Ball { g: f64, lambda: f64, rules: Vec<JumpRule> }
//!
//! impl HybridSystem for Ball {
//!     fn state_dim(&self) -> usize { 2 }
//!     fn state_names(&self) -> Vec<String> { vec!["h".into(), "v".into()] }
//!     fn flow_map(&self, _at: HybridTime, x: &[f64], dx: &mut [f64]) {
//!         dx[0] = x[1];
//!         dx[1] = -self.g;
//!     }
//!     fn flow_set(&self, _at: HybridTime, x: &[f64]) -> bool { x[0] >= 0.0 }
//!     fn flow_guard(&self, _at: HybridTime, x: &[f64]) -> Option<f64> { Some(x[0]) }
//!     fn jump_rules(&self) -> &[JumpRule] { &self.rules }
//!     fn jump_set(&self, _rule: usize, _at: HybridTime, x: &[f64]) -> bool { x[0] <= 0.0 && x[1] <= 0.0 }
//!     fn jump_guard(&self, _rule: usize, _at: HybridTime, x: &[f64]) -> f64 { -x[0] }
//!     fn jump_map(&self, _rule: usize, _at: HybridTime, x: &[f64], _rng: &mut SimRng, xp: &mut [f64]) {
//!         xp[0] = x[0];
//!         xp[1] = -self.lambda * x[1];
//!     }
//! }
//!
//! let ball = Ball {
//!     g: 9.81,
//!     lambda: 0.8,
//!     rules: vec![JumpRule::new("impact", GuardKind::General)],
//! };
//! let arc = simulate_arc(&ball, &[1.0, 0.0], &SimSettings::default(), &mut SimRng::seed_from(0))
//!     .expect("valid settings and system");
//! // First impact at t₁ = √(2h₀/g).
//! let t1 = (2.0_f64 / 9.81).sqrt();
//! assert!((arc.jumps()[0].at.t - t1).abs() < 1e-12);
//! // The impacts accumulate at the Zeno time; the Zeno guard ends the run there.
//! assert!(matches!(arc.termination().unwrap().cause, TerminationCause::ZenoSuspected { .. }));
//! ```

mod error;
mod events;
mod flow;
pub mod models;
mod run;
mod settings;
pub mod system;

pub use crate::arc::{Termination, TerminationCause, ZenoDetail};
pub use error::SimError;
pub use run::{simulate, simulate_arc};
pub use settings::{Priority, SimSettings, Solver};
pub use system::{FlowStructure, GuardKind, HybridSystem, JumpRule, SimRng};
