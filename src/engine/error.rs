//! Errors of the engine: the run could not produce a solution (bad settings,
//! an inconsistent system, a state that blew up, an integrator that gave
//! up). Outcomes such as reaching a horizon are not errors; they are
//! [`TerminationCause`](crate::arc::TerminationCause) values.

use crate::arc::HybridTime;

/// Why a simulation failed. Each variant names where it happened (`at`) and
/// which state or rule is involved, by index so that a front end can map
/// indices back to source spans; [`SimError::help`] says what to change.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimError {
    /// A setting is out of range.
    #[error("invalid setting `{field}`: {reason}")]
    InvalidSettings {
        /// Name of the field (e.g. `horizon_t`, `solver.rtol`).
        field: &'static str,
        /// What is wrong with its value.
        reason: String,
    },
    /// The initial state does not have the system's dimension.
    #[error("the initial state has {found} components but the system has {expected}")]
    StateDimension {
        /// The system's `state_dim()`.
        expected: usize,
        /// Length of the given initial state.
        found: usize,
    },
    /// The system's own description is inconsistent (timer index out of
    /// range, affine matrices of the wrong size, no state, ...).
    #[error("invalid system: {what}")]
    InvalidSystem {
        /// What is inconsistent.
        what: String,
    },
    /// The system has noise inputs but the solver is deterministic.
    #[error(
        "the system is driven by {noise_dim} Wiener processes but the solver is not EulerMaruyama"
    )]
    NoiseNeedsEulerMaruyama {
        /// The system's `noise_dim()`.
        noise_dim: usize,
    },
    /// A state component became NaN or infinite.
    #[error(
        "state `{name}` became {value} {} {at}",
        if .rule.is_some() { "in the jump at" } else { "at" }
    )]
    NonFinite {
        /// Hybrid time of the first non-finite state seen; for a jump map's, the jump's (its
        /// pre-jump point: the run ends there, the post-jump state is not part of it).
        at: HybridTime,
        /// Index of the component.
        component: usize,
        /// Its name from `state_names()`.
        name: String,
        /// The value (NaN or ±∞).
        value: f64,
        /// The jump rule whose jump map produced it; `None` for the flow
        /// (or the initial state at (0, 0)).
        rule: Option<usize>,
    },
    /// The adaptive integrator could not meet its tolerance with a step
    /// above the rounding level.
    #[error(
        "the step size collapsed at {at} (last accepted step {h:e}); fastest-changing state: `{name}`"
    )]
    StepSizeCollapse {
        /// Hybrid time where the integrator stopped.
        at: HybridTime,
        /// The last accepted step size (0 if none was accepted).
        h: f64,
        /// The state component changing fastest relative to the tolerances
        /// (|ẋᵢ| / (atol + rtol·|xᵢ|)) at the last accepted state: the
        /// likeliest culprit.
        component: usize,
        /// Its name from `state_names()`.
        name: String,
    },
    /// The rate of a component changed sign on every accepted step or
    /// every other one over many steps (10 000), or every few steps where
    /// the flow's Jacobian is small, which an adaptive explicit
    /// solver takes at the step its tolerance allows for ever: the flow map is
    /// discontinuous where the solution slides along a switching surface
    /// (`x' = -sign(x)` at x = 0).
    #[error(
        "the flow chatters at {at}: the rate of `{name}` changed sign every few steps over the last 10000 steps (the last {h:e} long)"
    )]
    Chatter {
        /// Hybrid time where the integrator stopped.
        at: HybridTime,
        /// The last accepted step size.
        h: f64,
        /// The component whose rate changed sign.
        component: usize,
        /// Its name from `state_names()`.
        name: String,
    },
    /// The explicit solver's stiffness test fired where the flow's
    /// Jacobian cannot make it stiff: the rates jump between states a step
    /// apart because the flow map is discontinuous in the state, as where
    /// the solution slides along a switching surface (`x' = y - sign(x)` at
    /// x = 0). Integrating on, with an implicit solver too, would only
    /// shrink the steps.
    #[error(
        "the flow map is discontinuous at {at}: the rate of `{name}` jumps between states a step apart (the last {h:e} long) where the flow's derivative is small"
    )]
    Discontinuous {
        /// Hybrid time where the integrator stopped.
        at: HybridTime,
        /// The last accepted step size.
        h: f64,
        /// The component whose rate jumps most.
        component: usize,
        /// Its name from `state_names()`.
        name: String,
    },
    /// The system reported a failed evaluation
    /// ([`HybridSystem::take_fault`](super::HybridSystem::take_fault)).
    #[error("{what} at {at}")]
    Fault {
        /// Hybrid time of the evaluation.
        at: HybridTime,
        /// The system's index of what failed.
        site: usize,
        /// What failed.
        what: String,
    },
    /// The adaptive integrator detected stiffness.
    #[error("the flow became stiff at {at}; the stiff mode moves `{name}` most")]
    Stiff {
        /// Hybrid time where the integrator stopped.
        at: HybridTime,
        /// The state component the stiff mode moves most (the largest
        /// entry, relative to the tolerances, of the difference of rates
        /// by which the stiffness test estimates the dominant eigenvalue).
        component: usize,
        /// Its name from `state_names()`.
        name: String,
    },
}

impl SimError {
    /// One sentence on what to change.
    pub fn help(&self) -> &'static str {
        match self {
            SimError::InvalidSettings { .. } => "change the named setting to a value in its range",
            SimError::StateDimension { .. } => {
                "give one initial value per state component, in `state_names()` order"
            }
            SimError::InvalidSystem { .. } => {
                "fix the system definition: timer indices and affine matrices must match the state"
            }
            SimError::NoiseNeedsEulerMaruyama { .. } => {
                "choose `Solver::EulerMaruyama { h }` for systems with noise"
            }
            SimError::NonFinite { .. } => {
                "the flow or jump map produced NaN/∞ here: check divisions and unstable dynamics, \
                 or shorten the horizon"
            }
            SimError::StepSizeCollapse { .. } => {
                "the flow may blow up or be discontinuous here: check the flow map, loosen \
                 `rtol`/`atol`, or make the discontinuity a jump"
            }
            SimError::Chatter { .. } | SimError::Discontinuous { .. } => {
                "the flow map switches discontinuously where the solution slides along the \
                 switching surface (a relay such as `sign(x)` or an `if` on the state): make \
                 the switch a jump of a mode with hysteresis, or smooth it (`tanh(x/eps)`)"
            }
            SimError::Fault { .. } => {
                "an expression of the model could not be evaluated here: check the index or \
                 argument it names against the data it reads"
            }
            SimError::Stiff { .. } => {
                "the flow is stiff: use an implicit solver (`solver = radau5` or `bdf`, \
                 `--solver radau5`, `Solver::Radau5`), or `solver = auto` to switch to Radau5 \
                 where the flow is stiff; if instead the flow map switches where the solution \
                 slides along a switching surface (`sign(x)`, an `if` on the state), which looks \
                 stiff too, make the switch a jump with hysteresis or smooth it (`tanh(x/eps)`)"
            }
        }
    }
}

/// The error of a fault the system reported.
impl From<super::system::SystemFault> for SimError {
    fn from(f: super::system::SystemFault) -> Self {
        SimError::Fault {
            at: f.at,
            site: f.site,
            what: f.what,
        }
    }
}
