//! Properties of hybrid arcs as values: what must hold, where on the hybrid
//! time domain, and with which tolerance. See the [module docs](super) for
//! the precise semantics of each kind.

use std::fmt;
use std::sync::Arc;

use crate::arc::HybridTime;

/// A predicate on a point `(t, j, x)` of a solution.
pub type StatePredicate = Arc<dyn Fn(HybridTime, &[f64]) -> bool + Send + Sync>;

/// A scalar function `V(t, j, x)` of a point of a solution (a Lyapunov
/// candidate, a distance `|x|_A`, an energy).
pub type ScalarFn = Arc<dyn Fn(HybridTime, &[f64]) -> f64 + Send + Sync>;

/// A predicate on a jump: its rule and the states on both sides.
pub type JumpPredicate = Arc<dyn Fn(&JumpView<'_>) -> bool + Send + Sync>;

/// One jump as seen by a [`JumpPredicate`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JumpView<'a> {
    /// Hybrid time of the pre-jump point; the post-jump point is
    /// `(t, j + 1)`.
    pub at: HybridTime,
    /// Index of the rule that fired.
    pub rule: usize,
    /// State before the jump.
    pub pre: &'a [f64],
    /// State after the jump.
    pub post: &'a [f64],
}

impl JumpView<'_> {
    /// Hybrid time of the post-jump point, `(t, j + 1)`.
    pub fn post_at(&self) -> HybridTime {
        HybridTime::new(self.at.t, self.at.j + 1)
    }
}

/// Where on the hybrid time domain a monotonicity property compares values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scope {
    /// Between consecutive samples of one flow interval (same `j`,
    /// increasing `t`).
    Flows,
    /// Across each jump: post-jump value against pre-jump value.
    Jumps,
}

/// How a scalar must evolve in a monotonicity property.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Monotonicity {
    /// `V(next) < V(prev)`, unless `V(next) ≤ tol` (the solution is already
    /// in the tolerance's sublevel set, where no strict decrease can be
    /// seen numerically).
    Decreasing,
    /// `V(next) ≤ V(prev) + tol`.
    Nonincreasing,
}

/// What a property requires; built by the constructors of [`Property`].
#[derive(Clone)]
pub(crate) enum Kind {
    Always(StatePredicate),
    DuringFlows(StatePredicate),
    AtJumps {
        rule: Option<usize>,
        pred: JumpPredicate,
    },
    EventuallyWithin {
        within: f64,
        pred: StatePredicate,
    },
    AlwaysAfter {
        enter: StatePredicate,
        pred: StatePredicate,
    },
    Monotone {
        v: ScalarFn,
        how: Monotonicity,
        scope: Scope,
        tol: f64,
    },
    ExponentialBound {
        dist: ScalarFn,
        kappa: f64,
        alpha: f64,
        tol: f64,
    },
}

/// A named property of the solutions of a hybrid system.
///
/// Build one with a constructor ([`Property::always`],
/// [`Property::at_jumps`], [`Property::decreasing`], ...), check it on a
/// stored solution with [`Property::check`], or watch a running simulation
/// with [`PropertySink`](super::PropertySink).
///
/// ```
/// use hybsim::engine::{models::BouncingBall, simulate_arc, SimRng, SimSettings};
/// use hybsim::props::{Property, Scope};
///
/// let ball = BouncingBall::new(9.81, 0.8);
/// let arc = simulate_arc(&ball, &[1.0, 0.0], &SimSettings::default().horizon_t(2.0),
///                        &mut SimRng::seed_from(1)).unwrap();
/// let above_ground = Property::always("above ground", |_, x| x[0] >= -1e-9);
/// let energy = Property::nonincreasing("energy", Scope::Jumps, 0.0,
///                                      |_, x| 0.5 * x[1] * x[1] + 9.81 * x[0]);
/// let too_high = Property::always("below 0.5", |_, x| x[0] <= 0.5);
/// assert!(above_ground.check(&arc).is_ok());
/// assert!(energy.check(&arc).is_ok());
/// let v = too_high.check(&arc).unwrap_err();
/// assert_eq!((v.at.t, v.at.j), (0.0, 0)); // fails at the initial point
/// ```
#[derive(Clone)]
pub struct Property {
    name: String,
    text: Option<String>,
    pub(crate) kind: Kind,
}

impl fmt::Debug for Property {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Property")
            .field("name", &self.name)
            .field("kind", &self.kind_name())
            .field("text", &self.text)
            .finish()
    }
}

impl Property {
    fn new(name: impl Into<String>, kind: Kind) -> Self {
        Self {
            name: name.into(),
            text: None,
            kind,
        }
    }

    /// `always P`: P holds at every sample of the solution — the initial
    /// point, every flow sample, both sides of every jump, the final point.
    pub fn always(
        name: impl Into<String>,
        pred: impl Fn(HybridTime, &[f64]) -> bool + Send + Sync + 'static,
    ) -> Self {
        Self::new(name, Kind::Always(Arc::new(pred)))
    }

    /// `during flows P`: P holds at every sample of every flow interval of
    /// positive length `[t_j, t_{j+1}] × {j}`, endpoints included. Points
    /// where the solution only passes through (a post-jump point followed
    /// at once by another jump) are not checked.
    pub fn during_flows(
        name: impl Into<String>,
        pred: impl Fn(HybridTime, &[f64]) -> bool + Send + Sync + 'static,
    ) -> Self {
        Self::new(name, Kind::DuringFlows(Arc::new(pred)))
    }

    /// `at jumps P`: P holds at every jump, with the pre- and post-jump
    /// states available.
    pub fn at_jumps(
        name: impl Into<String>,
        pred: impl Fn(&JumpView<'_>) -> bool + Send + Sync + 'static,
    ) -> Self {
        Self::new(
            name,
            Kind::AtJumps {
                rule: None,
                pred: Arc::new(pred),
            },
        )
    }

    /// `at jumps of rule P`: as [`at_jumps`](Self::at_jumps), only for the
    /// jumps of rule index `rule`.
    pub fn at_jumps_of(
        name: impl Into<String>,
        rule: usize,
        pred: impl Fn(&JumpView<'_>) -> bool + Send + Sync + 'static,
    ) -> Self {
        Self::new(
            name,
            Kind::AtJumps {
                rule: Some(rule),
                pred: Arc::new(pred),
            },
        )
    }

    /// `eventually within T P`: some sample with `t ≤ T` satisfies P. It
    /// fails at the first sample with `t > T` if none did, or at the end
    /// of a solution that is maximal before `T` (it can neither flow nor
    /// jump). A run cut short by a horizon, the Zeno guard or a sink before
    /// `t = T` is *inconclusive*, not a failure.
    pub fn eventually_within(
        name: impl Into<String>,
        within: f64,
        pred: impl Fn(HybridTime, &[f64]) -> bool + Send + Sync + 'static,
    ) -> Self {
        Self::new(
            name,
            Kind::EventuallyWithin {
                within,
                pred: Arc::new(pred),
            },
        )
    }

    /// `after E always P`: from the first sample where E holds on, P holds
    /// at every sample (that one included). Solutions that never satisfy E
    /// pass.
    pub fn always_after(
        name: impl Into<String>,
        enter: impl Fn(HybridTime, &[f64]) -> bool + Send + Sync + 'static,
        pred: impl Fn(HybridTime, &[f64]) -> bool + Send + Sync + 'static,
    ) -> Self {
        Self::new(
            name,
            Kind::AlwaysAfter {
                enter: Arc::new(enter),
                pred: Arc::new(pred),
            },
        )
    }

    /// `decreasing V during flows` (scope [`Scope::Flows`]) or `at jumps`
    /// ([`Scope::Jumps`]): see [`Monotonicity::Decreasing`].
    pub fn decreasing(
        name: impl Into<String>,
        scope: Scope,
        tol: f64,
        v: impl Fn(HybridTime, &[f64]) -> f64 + Send + Sync + 'static,
    ) -> Self {
        Self::monotone(name, Monotonicity::Decreasing, scope, tol, v)
    }

    /// `nonincreasing V during flows` or `at jumps`: see
    /// [`Monotonicity::Nonincreasing`].
    pub fn nonincreasing(
        name: impl Into<String>,
        scope: Scope,
        tol: f64,
        v: impl Fn(HybridTime, &[f64]) -> f64 + Send + Sync + 'static,
    ) -> Self {
        Self::monotone(name, Monotonicity::Nonincreasing, scope, tol, v)
    }

    /// A monotonicity property of `V` over `scope` with tolerance `tol`
    /// (same units as V).
    pub fn monotone(
        name: impl Into<String>,
        how: Monotonicity,
        scope: Scope,
        tol: f64,
        v: impl Fn(HybridTime, &[f64]) -> f64 + Send + Sync + 'static,
    ) -> Self {
        Self::new(
            name,
            Kind::Monotone {
                v: Arc::new(v),
                how,
                scope,
                tol,
            },
        )
    }

    /// The exponential bound `|x(t, j)|_A ≤ κ e^{−α (t + j)} |x(0, 0)|_A + tol`
    /// at every sample, with `dist` computing `|x|_A`.
    pub fn exponential_bound(
        name: impl Into<String>,
        kappa: f64,
        alpha: f64,
        tol: f64,
        dist: impl Fn(HybridTime, &[f64]) -> f64 + Send + Sync + 'static,
    ) -> Self {
        Self::new(
            name,
            Kind::ExponentialBound {
                dist: Arc::new(dist),
                kappa,
                alpha,
                tol,
            },
        )
    }

    /// Attaches the property's text as the user wrote it (e.g.
    /// `always h >= -1e-9`), shown in reports.
    pub fn with_text(mut self, text: impl Into<String>) -> Self {
        self.text = Some(text.into());
        self
    }

    /// The property's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The property's text, if one was attached.
    pub fn text(&self) -> Option<&str> {
        self.text.as_deref()
    }

    /// Short name of the kind (`always`, `at jumps`, ...).
    pub fn kind_name(&self) -> &'static str {
        match &self.kind {
            Kind::Always(_) => "always",
            Kind::DuringFlows(_) => "during flows",
            Kind::AtJumps { .. } => "at jumps",
            Kind::EventuallyWithin { .. } => "eventually within",
            Kind::AlwaysAfter { .. } => "always after",
            Kind::Monotone {
                how: Monotonicity::Decreasing,
                ..
            } => "decreasing",
            Kind::Monotone {
                how: Monotonicity::Nonincreasing,
                ..
            } => "nonincreasing",
            Kind::ExponentialBound { .. } => "exponential bound",
        }
    }
}

impl fmt::Display for Property {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.text {
            Some(text) => write!(f, "{}: {text}", self.name),
            None => write!(f, "{} ({})", self.name, self.kind_name()),
        }
    }
}
