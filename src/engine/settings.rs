//! Simulation settings: horizons, integrator, priority, output grid, event
//! tolerance and Zeno guards. Every field has a documented default and unit;
//! [`SimSettings::validate`] checks them all once and names the faulty field.

use super::error::SimError;
use super::system::HybridSystem;
use crate::num::Num;

/// The step of the fixed-step solvers (`rk4`, `euler_maruyama`) when the
/// model's `sim` block or the command line chooses one without giving `h`.
pub const DEFAULT_FIXED_STEP: f64 = 1e-3;

/// The integrator used for flows. Flows whose structure is
/// [`FlowStructure::Affine`](super::FlowStructure::Affine) are advanced
/// exactly instead, unless [`SimSettings::exact_affine`] is off.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Solver {
    /// Dormand–Prince 5(4), adaptive step (the engine's own stepper, events
    /// and dense output on its order-4 interpolant). The default,
    /// with `rtol = 1e-6`, `atol = 1e-9`.
    Dopri5 {
        /// Relative tolerance of the local error (dimensionless).
        rtol: f64,
        /// Absolute tolerance of the local error (state units).
        atol: f64,
    },
    /// Dormand–Prince 8(5,3), adaptive step (the engine's own stepper, events
    /// and dense output on its order-7 interpolant, three more evaluations
    /// of f per step): for tight tolerances.
    Dop853 {
        /// Relative tolerance of the local error (dimensionless).
        rtol: f64,
        /// Absolute tolerance of the local error (state units).
        atol: f64,
    },
    /// Radau IIA of order 5 (implicit, L-stable), adaptive step: for stiff
    /// flows (fast and slow time scales together, where the explicit
    /// methods' steps collapse). Newton iterations use the system's
    /// [`jacobian`](super::HybridSystem::jacobian); dense output is each
    /// step's collocation polynomial.
    Radau5 {
        /// Relative tolerance of the local error (dimensionless).
        rtol: f64,
        /// Absolute tolerance of the local error (state units).
        atol: f64,
    },
    /// Variable-order BDF (orders 1–5, the NDF variant of Shampine &
    /// Reichelt, as MATLAB's ode15s and scipy's `BDF`), adaptive step and
    /// order: for stiff flows, cheaper per step than Radau5 (one real LU,
    /// one f per Newton iteration) but restarting at order 1 after each
    /// jump. Newton iterations use the system's
    /// [`jacobian`](super::HybridSystem::jacobian); dense output is the
    /// interpolating polynomial through the last back values.
    Bdf {
        /// Relative tolerance of the local error (dimensionless).
        rtol: f64,
        /// Absolute tolerance of the local error (state units).
        atol: f64,
    },
    /// Dopri5 while the flow is not stiff, Radau5 while it is, as LSODA
    /// switches between Adams and BDF: Dopri5's stiffness test (Hairer's,
    /// run every 10 steps here, and at every step once it fired) hands the
    /// flow to Radau5 after 15 steps at its stability limit; Radau5 hands it back when its step times the
    /// norm of the Jacobian falls to 1 (the explicit method is then stable
    /// at the same step). The switches are reported to the sink
    /// ([`ArcSink::solver_switch`](crate::arc::ArcSink::solver_switch)).
    /// On a flow that never turns stiff the solution is Dopri5's, bit for
    /// bit.
    Auto {
        /// Relative tolerance of the local error (dimensionless).
        rtol: f64,
        /// Absolute tolerance of the local error (state units).
        atol: f64,
    },
    /// Classic fourth-order Runge–Kutta with fixed step (ode_solvers `Rk4`).
    /// Each flow segment is divided into equal steps of at most `h`.
    Rk4 {
        /// Largest step, in units of t.
        h: f64,
    },
    /// Euler–Maruyama with fixed step, for flows driven by white noise
    /// ([`HybridSystem::noise_dim`](super::HybridSystem::noise_dim) > 0);
    /// the increments are drawn from the run's [`SimRng`](super::SimRng).
    EulerMaruyama {
        /// Largest step, in units of t.
        h: f64,
    },
}

impl Solver {
    /// The names of the adaptive solvers, as `.hyb` files and the command
    /// line spell them.
    pub const ADAPTIVE: [&'static str; 5] = ["dopri5", "dop853", "radau5", "bdf", "auto"];

    /// The name used in `.hyb` files, on the command line and in the logs.
    ///
    /// ```
    /// use hybsim::engine::Solver;
    /// assert_eq!(Solver::Bdf { rtol: 1e-6, atol: 1e-9 }.name(), "bdf");
    /// ```
    pub fn name(&self) -> &'static str {
        match self {
            Solver::Dopri5 { .. } => "dopri5",
            Solver::Dop853 { .. } => "dop853",
            Solver::Radau5 { .. } => "radau5",
            Solver::Bdf { .. } => "bdf",
            Solver::Auto { .. } => "auto",
            Solver::Rk4 { .. } => "rk4",
            Solver::EulerMaruyama { .. } => "euler_maruyama",
        }
    }

    /// Whether the solver can integrate `sys`'s flows: white noise
    /// ([`HybridSystem::noise_dim`] > 0) needs [`Solver::EulerMaruyama`].
    ///
    /// # Errors
    /// [`SimError::NoiseNeedsEulerMaruyama`].
    pub fn suits<S: HybridSystem + ?Sized>(&self, sys: &S) -> Result<(), SimError> {
        match (sys.noise_dim(), self) {
            (0, _) | (_, Solver::EulerMaruyama { .. }) => Ok(()),
            (noise_dim, _) => Err(SimError::NoiseNeedsEulerMaruyama { noise_dim }),
        }
    }

    /// `(rtol, atol)` of an adaptive solver; `None` for the fixed-step ones.
    pub fn tolerances(&self) -> Option<(f64, f64)> {
        match *self {
            Solver::Dopri5 { rtol, atol }
            | Solver::Dop853 { rtol, atol }
            | Solver::Radau5 { rtol, atol }
            | Solver::Bdf { rtol, atol }
            | Solver::Auto { rtol, atol } => Some((rtol, atol)),
            Solver::Rk4 { .. } | Solver::EulerMaruyama { .. } => None,
        }
    }

    /// The adaptive solver called `name` (one of [`Solver::ADAPTIVE`]) with
    /// these tolerances.
    ///
    /// ```
    /// use hybsim::engine::Solver;
    /// assert_eq!(
    ///     Solver::adaptive("radau5", 1e-8, 1e-10),
    ///     Some(Solver::Radau5 { rtol: 1e-8, atol: 1e-10 })
    /// );
    /// assert_eq!(Solver::adaptive("rk4", 1e-8, 1e-10), None);
    /// ```
    pub fn adaptive(name: &str, rtol: f64, atol: f64) -> Option<Solver> {
        Some(match name {
            "dopri5" => Solver::Dopri5 { rtol, atol },
            "dop853" => Solver::Dop853 { rtol, atol },
            "radau5" => Solver::Radau5 { rtol, atol },
            "bdf" => Solver::Bdf { rtol, atol },
            "auto" => Solver::Auto { rtol, atol },
            _ => return None,
        })
    }
}

impl Default for Solver {
    fn default() -> Self {
        Solver::Dopri5 {
            rtol: 1e-6,
            atol: 1e-9,
        }
    }
}

/// Whether flows declared [`FlowStructure::Affine`](super::FlowStructure::Affine)
/// (`ẋ = A x + b`) are advanced exactly, by matrix exponentials of the
/// augmented generator `[[A, b], [0, 0]]`, or by the solver. The answer is
/// the same within the solver's tolerance; only the cost differs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ExactAffine {
    /// Per flow segment, by cost. Segments on which a guard is watched use
    /// the solver (localizing an event on the exact path needs a fresh
    /// exponential per trial time). The others use a cached exponential
    /// when one for the segment's duration exists; otherwise they use the
    /// solver until the solver's work on segments of that same duration
    /// (f-evaluations times an estimate of their flops) has exceeded the
    /// estimated cost of one exponential, and from then on the exact path
    /// with that exponential cached: periodic sampling turns exact after a
    /// few periods, while durations that never repeat (random timers, bouncing)
    /// never pay for an exponential. At most twice the cost of the better
    /// choice made in hindsight (the ski-rental rule).
    ///
    /// Flows whose `A` is structurally nilpotent are polynomials in time
    /// and always take their exact polynomial (guards watched or not),
    /// under `Auto` and `On` alike.
    #[default]
    Auto,
    /// Every segment of an affine flow exactly (exponentials cached per
    /// step length), events localized on the exact solution.
    On,
    /// Always the solver.
    Off,
}

impl From<bool> for ExactAffine {
    /// `true`: [`ExactAffine::On`]; `false`: [`ExactAffine::Off`].
    fn from(on: bool) -> Self {
        if on { Self::On } else { Self::Off }
    }
}

impl ExactAffine {
    /// The name used in `.hyb` files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::On => "on",
            Self::Off => "off",
        }
    }
}

/// How the implicit solvers ([`Solver::Radau5`], [`Solver::Bdf`],
/// [`Solver::Auto`]) factorize their Newton matrices `μI − J`. Both give
/// the same solution within the solver's tolerance; only the cost differs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LinearSolver {
    /// Sparse when the system declares a sparsity pattern
    /// ([`HybridSystem::jacobian_pattern`](super::HybridSystem::jacobian_pattern);
    /// a compiled model always does), n ≥ 32 and the LU factors' estimated
    /// density is at most 0.2 ([`use_sparse_lu`](super::use_sparse_lu));
    /// dense otherwise.
    #[default]
    Auto,
    /// Dense LU (in place, skipping zero multipliers).
    Dense,
    /// Sparse LU (faer's, with a fill-reducing column ordering computed
    /// once per run) whenever the system declares a pattern.
    Sparse,
}

impl LinearSolver {
    /// The name used in `.hyb` files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Dense => "dense",
            Self::Sparse => "sparse",
        }
    }

    /// The variant named `name` (`auto`, `dense`, `sparse`).
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "auto" => Some(Self::Auto),
            "dense" => Some(Self::Dense),
            "sparse" => Some(Self::Sparse),
            _ => None,
        }
    }
}

/// What happens when the state is in both C and D.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Priority {
    /// Jump whenever x ∈ D (as in the HyEQ Toolbox's default `rule = 1`).
    #[default]
    Jumps,
    /// Flow whenever the solution can flow in C; jump only when it cannot
    /// (at the boundary of C where the flow leaves it).
    Flows,
    /// At each point of C ∩ D where the engine decides, a fair coin drawn
    /// from the run's [`SimRng`](super::SimRng) chooses; having chosen to
    /// flow, the solution flows until its next event.
    Random,
}

/// Which jump fires when the jump sets of several rules hold at one point
/// (a set-valued jump map G(x) = G₁(x) ∪ G₂(x) written as rules with
/// overlapping jump sets).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum JumpChoice {
    /// The first enabled rule in declaration order (with the rules of its
    /// group that hold there).
    #[default]
    First,
    /// A uniform draw from the run's [`SimRng`](super::SimRng) among the
    /// enabled jumps: each enabled rule that fires alone counts once, and a
    /// group of simultaneous rules with an enabled member counts once (it
    /// is one jump). Drawn a group, each of its parts fires one of its
    /// enabled rules, drawn uniformly too. Nothing is drawn where a single
    /// jump is enabled: a model whose rules never overlap has the arc of
    /// [`JumpChoice::First`].
    Random,
}

impl JumpChoice {
    /// The name used in `.hyb` files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::First => "first",
            Self::Random => "random",
        }
    }

    /// The variant named `name` (`first`, `random`).
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "first" => Some(Self::First),
            "random" => Some(Self::Random),
            _ => None,
        }
    }
}

/// Settings of one simulation run. Build with `SimSettings::default()` and
/// the by-value setters:
///
/// ```
/// use hybsim::engine::{SimSettings, Solver};
/// let s = SimSettings::default()
///     .horizon_t(20.0)
///     .solver(Solver::Dopri5 { rtol: 1e-9, atol: 1e-12 })
///     .dt_out(Some(0.01));
/// assert!(s.validate().is_ok());
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct SimSettings {
    /// Horizon T in ordinary time: the run ends at the first point with
    /// t ≥ T. Finite, > 0. Default 10.
    pub horizon_t: f64,
    /// Horizon J in jumps: the run ends at the first point with j ≥ J.
    /// Default `u64::MAX` (no bound; the Zeno guards still apply).
    pub horizon_j: u64,
    /// Integrator for flows. Default [`Solver::Dopri5`] with rtol 1e-6,
    /// atol 1e-9.
    pub solver: Solver,
    /// Priority when x ∈ C ∩ D. Default [`Priority::Jumps`].
    pub priority: Priority,
    /// Which jump fires when several rules are enabled at one point.
    /// Default [`JumpChoice::First`].
    pub jump_choice: JumpChoice,
    /// Output grid step in units of t: `None` (default) pushes a sample at
    /// every integrator step; `Some(dt)` pushes samples at t = k·dt inside
    /// flows (interpolated, see the module docs) instead. The initial,
    /// pre-jump, post-jump and final points are always pushed.
    pub dt_out: Option<f64>,
    /// Largest integrator step in units of t (adaptive solvers), and the
    /// longest interval between guard checks on exactly-advanced affine
    /// flows. Default ∞ (no limit).
    pub max_step: f64,
    /// Width in t below which an event bracket is accepted. Default 0: the
    /// bracket is shrunk to 4 ulp of t (9e-16 at t = 1, 9e-12 at t = 1e4),
    /// the resolution t itself is stored with; finer brackets would only
    /// chase rounding noise in the guards' values.
    pub event_tol: f64,
    /// Tolerance on the flow set's atoms when deciding whether a state may
    /// flow (at the start of each flow, typically just after a jump): an
    /// atom `g ≥ 0` of C counts as holding when `g ≥ −set_tol` (`|g| ≤
    /// set_tol` for `=`), so that a jump map that lands on C's boundary up
    /// to rounding (a reflecting `h⁺ = −h`) lets the solution flow. Such an
    /// atom stays relaxed along that flow until it holds exactly (a
    /// non-affine atom, whose sign near zero is rounding noise, is relaxed
    /// whenever the flow starts within `set_tol` of its zero, and until it
    /// holds by `set_tol`; module docs of `engine`). Default
    /// 1e-9: above the rounding of quantities up to ~10⁶ (ulp(10⁶) ≈ 1e-10),
    /// far below any meaningful distance to a boundary. Jump sets are never
    /// relaxed, nor is a strict atom of C that cannot change along a flow
    /// (`k < 3` with `k` a counter: on its boundary it would fail on the
    /// whole flow; [`Atom::holds_within`](super::Atom::holds_within)).
    pub set_tol: f64,
    /// Number of interior points per step at which guards are evaluated in
    /// addition to the step ends, to catch a guard that crosses and
    /// re-crosses inside one step. Default 3. Euler–Maruyama steps are
    /// checked at their ends only (the line between them is not the path).
    pub guard_checks: u32,
    /// Zeno guard: the largest number of jumps per unit of ordinary time,
    /// measured over the last `zeno_window` jumps and the next one. Default
    /// 1e6 jumps per unit of t; `f64::INFINITY` disables it. Like
    /// `max_total_jumps`, it applies only when [`horizon_j`](Self::horizon_j)
    /// is unbounded: a run with a finite J always reaches J (or T).
    pub zeno_max_rate: f64,
    /// Zeno guard: number of consecutive jumps over which the rate is
    /// measured (≥ 2). Default 10.
    pub zeno_window: u32,
    /// Zeno guard: the jump budget of a run with unbounded J, which ends
    /// after this many jumps even with `zeno_max_rate = ∞` (≥ 1). Default
    /// 10⁷ (a few minutes of jumps). With a finite J, J is the budget.
    pub max_total_jumps: u64,
    /// When flows declared [`FlowStructure::Affine`](super::FlowStructure::Affine)
    /// are advanced exactly instead of by the solver. Default
    /// [`ExactAffine::Auto`] (by cost, per segment).
    pub exact_affine: ExactAffine,
    /// How the implicit solvers factorize their Newton matrices. Default
    /// [`LinearSolver::Auto`] (sparse for large systems with a sparse
    /// Jacobian pattern).
    pub linear_solver: LinearSolver,
}

impl Default for SimSettings {
    fn default() -> Self {
        Self {
            horizon_t: 10.0,
            horizon_j: u64::MAX,
            solver: Solver::default(),
            priority: Priority::default(),
            jump_choice: JumpChoice::First,
            dt_out: None,
            max_step: f64::INFINITY,
            event_tol: 0.0,
            set_tol: 1e-9,
            guard_checks: 3,
            zeno_max_rate: 1e6,
            zeno_window: 10,
            max_total_jumps: 10_000_000,
            exact_affine: ExactAffine::Auto,
            linear_solver: LinearSolver::Auto,
        }
    }
}

macro_rules! setter {
    ($(#[$doc:meta])* $name:ident: $ty:ty) => {
        $(#[$doc])*
        #[must_use]
        pub fn $name(mut self, value: $ty) -> Self {
            self.$name = value;
            self
        }
    };
}

impl SimSettings {
    setter!(/// Sets [`horizon_t`](Self::horizon_t).
        horizon_t: f64);
    setter!(/// Sets [`horizon_j`](Self::horizon_j).
        horizon_j: u64);
    setter!(/// Sets [`solver`](Self::solver).
        solver: Solver);
    setter!(/// Sets [`priority`](Self::priority).
        priority: Priority);
    setter!(/// Sets [`jump_choice`](Self::jump_choice).
        jump_choice: JumpChoice);
    setter!(/// Sets [`dt_out`](Self::dt_out).
        dt_out: Option<f64>);
    setter!(/// Sets [`max_step`](Self::max_step).
        max_step: f64);
    setter!(/// Sets [`event_tol`](Self::event_tol).
        event_tol: f64);
    setter!(/// Sets [`set_tol`](Self::set_tol).
        set_tol: f64);
    setter!(/// Sets [`guard_checks`](Self::guard_checks).
        guard_checks: u32);
    setter!(/// Sets [`zeno_max_rate`](Self::zeno_max_rate).
        zeno_max_rate: f64);
    setter!(/// Sets [`zeno_window`](Self::zeno_window).
        zeno_window: u32);
    setter!(/// Sets [`max_total_jumps`](Self::max_total_jumps).
        max_total_jumps: u64);
    setter!(/// Sets [`linear_solver`](Self::linear_solver).
        linear_solver: LinearSolver);
    /// Sets [`exact_affine`](Self::exact_affine) (`true`/`false` mean
    /// [`ExactAffine::On`]/[`ExactAffine::Off`]).
    #[must_use]
    pub fn exact_affine(mut self, value: impl Into<ExactAffine>) -> Self {
        self.exact_affine = value.into();
        self
    }

    /// [`validate`](Self::validate), then whether the settings suit `sys`:
    /// a system driven by white noise ([`HybridSystem::noise_dim`] > 0)
    /// needs [`Solver::EulerMaruyama`]. Front ends call it before a run, so
    /// that a solver chosen on the command line is refused as such, not as
    /// a failed run.
    ///
    /// # Errors
    /// The first faulty field, or [`SimError::NoiseNeedsEulerMaruyama`].
    pub fn validate_for<S: HybridSystem + ?Sized>(&self, sys: &S) -> Result<(), SimError> {
        self.validate()?;
        self.solver.suits(sys)
    }

    /// Checks every field; the error names the first faulty one.
    pub fn validate(&self) -> Result<(), SimError> {
        fn bad(field: &'static str, reason: impl Into<String>) -> Result<(), SimError> {
            Err(SimError::InvalidSettings {
                field,
                reason: reason.into(),
            })
        }
        let positive = |x: f64| x.is_finite() && x > 0.0;
        if !positive(self.horizon_t) {
            return bad(
                "horizon_t",
                format!("must be finite and > 0, got {}", Num(self.horizon_t)),
            );
        }
        match self.solver {
            Solver::Dopri5 { rtol, atol }
            | Solver::Dop853 { rtol, atol }
            | Solver::Radau5 { rtol, atol }
            | Solver::Bdf { rtol, atol }
            | Solver::Auto { rtol, atol } => {
                if !positive(rtol) {
                    return bad(
                        "solver.rtol",
                        format!("must be finite and > 0, got {}", Num(rtol)),
                    );
                }
                // A zero atol is a pure relative tolerance, which no step meets on a state
                // that is 0 (the initial step came out NaN, the run went on with NaN steps).
                if !positive(atol) {
                    return bad(
                        "solver.atol",
                        format!("must be finite and > 0, got {}", Num(atol)),
                    );
                }
            }
            Solver::Rk4 { h } | Solver::EulerMaruyama { h } => {
                if !positive(h) {
                    return bad(
                        "solver.h",
                        format!("must be finite and > 0, got {}", Num(h)),
                    );
                }
            }
        }
        if let Some(dt) = self.dt_out
            && !positive(dt)
        {
            return bad("dt_out", format!("must be finite and > 0, got {}", Num(dt)));
        }
        if self.max_step.is_nan() || self.max_step <= 0.0 {
            return bad(
                "max_step",
                format!("must be > 0 (∞ for no limit), got {}", Num(self.max_step)),
            );
        }
        if !(self.event_tol.is_finite() && (0.0..=1e-3).contains(&self.event_tol)) {
            return bad(
                "event_tol",
                format!("must be in [0, 1e-3], got {}", Num(self.event_tol)),
            );
        }
        if !(self.set_tol.is_finite() && self.set_tol >= 0.0) {
            return bad(
                "set_tol",
                format!("must be finite and ≥ 0, got {}", Num(self.set_tol)),
            );
        }
        if self.guard_checks > 64 {
            return bad(
                "guard_checks",
                format!("must be ≤ 64, got {}", self.guard_checks),
            );
        }
        if self.zeno_max_rate.is_nan() || self.zeno_max_rate <= 0.0 {
            return bad(
                "zeno_max_rate",
                format!(
                    "must be > 0 (∞ to disable), got {}",
                    Num(self.zeno_max_rate)
                ),
            );
        }
        if self.zeno_window < 2 {
            return bad(
                "zeno_window",
                format!("must be ≥ 2, got {}", self.zeno_window),
            );
        }
        if self.max_total_jumps == 0 {
            return bad("max_total_jumps", "must be ≥ 1, got 0");
        }
        Ok(())
    }
}
