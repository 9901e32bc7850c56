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
//!    declaration order* whose jump set contains x (or whose jump set the
//!    last flow just reached, see below). By default one jump is one rule: it
//!    increments j by exactly one; the state is then re-examined at the same
//!    t, so if several rules are enabled they fire one after another, each
//!    on the state left by the previous one, in declaration order, as long as
//!    they stay enabled. With [`JumpChoice::Random`]
//!    ([`jump_choice`](SimSettings::jump_choice)) the rule is instead drawn
//!    uniformly from the run's [`SimRng`] among the enabled ones (a group
//!    counting once, its parts' rules drawn too): a set-valued jump map
//!    G(x) = G₁(x) ∪ G₂(x) written as rules with overlapping jump sets.
//!    **Simultaneous jumps:** if the enabled rule has a
//!    [`group`](JumpRule::group), every rule of that group whose jump set
//!    holds at the pre-jump point (or that the event just localized reached,
//!    e.g. an equality atom met within the event's bracket;
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
//!    the flow leaves C (at the last point found in C if a jump set holds
//!    there, else at the first point found outside it),
//!    [`Priority::Random`] flips a fair coin from the
//!    run's [`SimRng`]. Where no flow is possible the solution jumps under
//!    every priority: a jump set met where the flow leaves C (after a coin
//!    that chose to flow, C left where a jump set holds), a timer rule whose
//!    timer bounds C ([`GuardKind::Timer`]'s `bounds_flow`) on its
//!    threshold. Membership of C here is tested with
//!    [`set_tol`](SimSettings::set_tol) on C's atoms (default 1e-9): an
//!    atom `g ≥ 0` counts as holding when `g ≥ −set_tol`, so that a jump map
//!    that lands on C's boundary up to rounding (`h⁺ = −h`) lets the
//!    solution flow. A strict atom that cannot change along the flow
//!    (`k < 3` with `k` a counter or `j`) is tested exactly: on its boundary
//!    it fails on the whole flow, not by rounding. Jump sets are tested
//!    exactly.
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
//! # Sets and events
//!
//! Every set is a boolean combination of *atoms* `g(t, x) ⋈ 0` with `⋈` one
//! of `< ≤ > ≥ = ≠` (see [`SetAtoms`]; a `.hyb` comparison `a ⋈ b` is the
//! atom `a − b ⋈ 0`, `!` flips the comparison). As sets of the state:
//! `g ≥ 0` and `g ≤ 0` are closed, `g > 0` and `g < 0` open, `g = 0` the
//! level set (isolated points along a flow that crosses it), `g ≠ 0` its
//! complement.
//!
//! A flow segment runs until the first of: the horizon T, the next *timer*
//! event, or a localized *set* event:
//!
//! - [`GuardKind::Timer`] rules fire when their timer (a state with
//!   constant rate along the flow) reaches the threshold: the time is
//!   computed exactly and the timer is set exactly to the threshold. No
//!   root finding.
//! - Every other set is watched through its atoms. Atoms that cannot change
//!   along a flow (modes, counters, held values, parameters: no
//!   dependence on `t` or on a state with a non-zero flow) are evaluated
//!   once per segment. Each flowing atom of C and of the general rules'
//!   D_i (not watched under [`Priority::Flows`]) has its sign (−, 0, +)
//!   evaluated at each step end and at
//!   [`guard_checks`](SimSettings::guard_checks) interior points of the
//!   step (on the interpolant; Euler–Maruyama steps, a straight line
//!   between points of a sampled path, at their ends only; plus three
//!   early points in the first step when the segment starts within
//!   `set_tol` of an atom's zero; a system
//!   that offers [`HybridSystem::all_atom_values`] gives all sets' atoms of
//!   a checkpoint in one call, sharing what the sets have in common; one
//!   that offers [`HybridSystem::jump_sets_and_atoms`] gives, where the
//!   engine chooses between flowing and jumping, the jump sets and the
//!   atoms a segment started there reads in one evaluation). Each sign
//!   change is bracketed and shrunk to [`event_tol`](SimSettings::event_tol)
//!   (default: 4 ulp of t) around the *first point where the
//!   sign differs*. The candidates are examined in time order; at each one
//!   the sets are re-evaluated on the final bracket `[a, b]`: inequality
//!   atoms at `b` (the post-change end), equality atoms as *met* if
//!   `g(b) = 0` or `g` has strictly opposite signs at `a` and `b` (the
//!   quantity reached the value within `event_tol`), `≠` as not met there.
//!   The earliest candidate at which a watched D_i becomes true (declaration
//!   order breaks ties; a rule wins over leaving C) or C becomes false is
//!   the event; the flow ends at `b`. So **a jump starts from a point of
//!   D**: every inequality atom of D_i holds exactly at the pre-jump state
//!   (a strict `x > 1` is approached from below and first holds at the
//!   first float past the crossing, found to within `event_tol`); an
//!   equality atom holds up to the bracket. The flow before `b` stays in C.
//!   Leaving C ends the flow at the first point found outside C; the
//!   solution jumps there if that point is in D, otherwise it ends.
//! - C's atoms that hold at the start of a flow only within `set_tol` are
//!   watched relaxed (`g + set_tol` for `g ≥ 0`) until they hold exactly:
//!   a flow that points out of C leaves it at `−set_tol`. An inequality
//!   atom of C without an affine form ([`HybridSystem::atom_affine`]),
//!   whose sign near its zero can be rounding noise (`h ≥ A·sin(ω·t)`: the
//!   rounding of `ω·t` alone), is watched relaxed whenever the segment
//!   starts within `set_tol` of its zero, on either side (a jump onto its
//!   boundary), until it holds by `set_tol`: a noisy sign there does not
//!   end a flow that moves into C.
//! - **Limit:** an atom that changes sign and changes back between two
//!   consecutive checkpoints of one step is not seen; lower
//!   [`max_step`](SimSettings::max_step) or raise `guard_checks` for sets
//!   that a flow touches only briefly.
//!
//! A system that does not describe its atoms ([`HybridSystem::set_atoms`]
//! returns `None`) is watched through its guards as single atoms, with its
//! predicates deciding membership at each candidate. [`check_arc`] checks
//! the invariants above on any arc.
//!
//! Flows are advanced by [`Solver::Dopri5`] (default, the engine's own
//! stepper, events on its order-4 interpolant), [`Solver::Radau5`] (the
//! engine's implicit stepper for stiff flows, events on each step's
//! collocation polynomial; Newton iterations on
//! [`HybridSystem::jacobian`], or on the entries of
//! [`HybridSystem::jacobian_pattern`] with a sparse LU for large sparse
//! systems, [`SimSettings::linear_solver`]), [`Solver::Bdf`] (the engine's variable-order
//! BDF, events on the polynomial through its back values; restarted at
//! order 1 after each jump), [`Solver::Auto`] (Dopri5, switching to Radau5
//! while the flow is stiff; each switch reported to the sink,
//! [`ArcSink::solver_switch`](crate::arc::ArcSink::solver_switch)),
//! [`Solver::Dop853`] (the engine's own 8(5,3) stepper, events on its
//! order-7 interpolant), or [`Solver::Rk4`] from `ode_solvers` (events on
//! the cubic Hermite interpolant of the step ends: exact for polynomial
//! flows such as free fall; O(h⁴) otherwise), each
//! segment integrated in local time `[0, d]` while t is kept as a
//! compensated sum of segment lengths. Flows
//! declared [`FlowStructure::Affine`] can be advanced exactly by the
//! exponential of `[[A, b], [0, 0]]`, cached per step length, with their
//! events localized on the exact solution; [`SimSettings::exact_affine`]
//! chooses, by default per segment by cost ([`ExactAffine::Auto`]): a
//! sampled-data loop whose flow is a linear plant plus held inputs and a
//! timer then costs one matrix-vector product per sample, while flows whose
//! segment durations never repeat stay on the solver. So can flows declared
//! [`FlowStructure::SwitchedAffine`] (`A` and `b` functions of modes that
//! do not move along flows), each by its mode's exponential. Noisy flows
//! ([`HybridSystem::noise_dim`] > 0) need [`Solver::EulerMaruyama`].
//!
//! # Output
//! The sink receives an [`Initial`](crate::arc::SampleKind::Initial)
//! sample, `Flow` samples at each integrator step plus, where the straight
//! line between step ends would stray from the flow by more than 1e-3 of
//! the components' magnitudes, points of the step's path in between (dense
//! output: the interpolant, or the exact solution on affine flows), or
//! instead samples at `t = k·dt_out` when [`dt_out`](SimSettings::dt_out)
//! is set (interpolated as above); a
//! `PreJump` sample, the jump, a `PostJump` sample for each jump, and a
//! `Final` sample (which may repeat the last point). A sink may stop the
//! run ([`TerminationCause::StoppedBySink`]) at any sample, a flow sample
//! inside an integrator step too: the run ends at that sample (not at the
//! step's end), and the sinks still get the `Final` sample of that point,
//! unless the sink stopped it because it failed ([`ArcSink::failed`](crate::arc::ArcSink::failed): a
//! failed run has no `Final` sample).
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

mod affine_modes;
mod bdf;
mod clock;
mod dop853;
mod dopri5;
mod error;
mod events;
mod explicit;
mod flow;
mod implicit;
mod invariants;
pub mod models;
mod polynomial;
mod radau5;
mod run;
mod settings;
mod sparsity;
mod stepper;
pub mod system;

pub use crate::arc::{Termination, TerminationCause, ZenoDetail};
pub use error::SimError;
pub use invariants::{ArcViolation, check_arc};
pub use run::{simulate, simulate_arc};
pub use settings::{
    DEFAULT_FIXED_STEP, ExactAffine, JumpChoice, LinearSolver, Priority, SimSettings, Solver,
};
pub use sparsity::{
    PatternError, SPARSE_MAX_FACTOR_DENSITY, SPARSE_MIN_STATES, SparsityPattern, use_sparse_lu,
};
pub use system::{
    AffineAtom, Atom, Cmp, FlowStructure, GuardKind, HybridSystem, JumpRule, SetAtoms, SetExpr,
    SetInputs, SetRef, SimRng, SystemFault, Threshold, finite_difference_jacobian,
};
