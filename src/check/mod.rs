//! The checker: resolves names, computes shapes, evaluates parameters and
//! index sets, unrolls families and `for` loops, and lowers every expression
//! into the scalar graph [`dag::Dag`]. All errors are collected and reported
//! at once.
//!
//! Declarations are read in two passes: parameters, graphs, states and
//! noise first (in source order; a parameter may use only parameters
//! declared before it), then flows, jumps, outputs and the `sim` block,
//! which may refer to every state.

mod compose;
pub mod dag;
mod design;
mod error;
mod expr;
pub mod limits;
pub mod log;
pub mod metric;
mod model;
pub mod property;
mod reuse;
mod rule_names;
mod signal;
pub mod sweep;
#[cfg(test)]
mod tests;

use rustc_hash::FxHashMap as HashMap;
use std::collections::BTreeMap;
use std::rc::Rc;

pub use crate::design::lmi::Backend;
pub use design::{DesignError, DesignReport, SolveSummary};
pub use error::{CheckError, Dims, LoneMember};
pub use expr::Val;
pub use log::{LogDecl, RuleSelection};
pub use model::{CheckedModel, CheckedRule, OutputField, Override, SolverKeys, StateField};

use crate::source::Span;
use dag::Dag;

/// What a name refers to.
#[derive(Debug, Clone)]
pub(crate) enum Sym {
    /// A parameter with its constant value.
    Param { val: Rc<Val>, span: Span },
    /// A family of parameters.
    ParamFamily {
        members: BTreeMap<Vec<i64>, Val>,
        span: Span,
    },
    /// A state field.
    State { field: usize, span: Span },
    /// A family of state fields.
    StateFamily {
        members: BTreeMap<Vec<i64>, usize>,
        span: Span,
    },
    /// A white-noise input.
    Wiener { val: Val, span: Span },
    /// A named output.
    Output { val: Rc<Val>, span: Span },
    /// A family of outputs (`for i in 1..N { output e[i] = ... }`).
    OutputFamily {
        members: BTreeMap<Vec<i64>, Val>,
        span: Span,
    },
}

impl Sym {
    fn span(&self) -> Span {
        match self {
            Sym::Param { span, .. }
            | Sym::ParamFamily { span, .. }
            | Sym::State { span, .. }
            | Sym::StateFamily { span, .. }
            | Sym::Wiener { span, .. }
            | Sym::Output { span, .. }
            | Sym::OutputFamily { span, .. } => *span,
        }
    }

    fn kind_words(&self) -> &'static str {
        match self {
            Sym::Param { .. } | Sym::ParamFamily { .. } => "a parameter",
            Sym::State { .. } | Sym::StateFamily { .. } => "a state",
            Sym::Wiener { .. } => "a white-noise input",
            Sym::Output { .. } | Sym::OutputFamily { .. } => "an output",
        }
    }
}

/// The checker's working state.
pub(crate) struct Checker {
    pub(crate) dag: Dag,
    pub(crate) errors: Vec<CheckError>,
    pub(crate) syms: HashMap<String, Sym>,
    /// The bound loop variables, innermost last (names shared: a loop
    /// binds them once per member).
    pub(crate) scopes: Vec<(Rc<str>, i64)>,
    /// Sets bound by `for S in subsets(..)` in design blocks.
    pub(crate) set_scopes: Vec<(String, Vec<i64>)>,
    pub(crate) fields: Vec<StateField>,
    pub(crate) block_spans: Vec<Span>,
    /// `Some(n)` (the state dimension) while checking an `at jumps`
    /// predicate, where `post(…)` is allowed.
    pub(crate) post_frame: Option<usize>,
    /// Names whose value is unavailable, and why. Uses of them record
    /// [`Checker::poison_hit`] instead of an error, so one failure (a
    /// design block, a parameter's or an initial value's own error) gives
    /// one error, not a cascade in everything computed from it.
    pub(crate) poisoned: HashMap<String, Unavailable>,
    /// Set (to the cause) when an expression used a poisoned name.
    pub(crate) poison_hit: Option<Unavailable>,
    /// The interior-point method of the design blocks.
    pub(crate) backend: Backend,
    /// Set while a `metric` expression is lowered (outside reduction
    /// arguments): reduction calls are collected here.
    pub(crate) metric_frame: Option<metric::MetricFrame>,
    /// Outputs and instance inputs, lowered on first use.
    pub(crate) signals: signal::Signals,
    /// The resource limits in force.
    pub(crate) limits: limits::Limits,
    /// The condition under which the expression being lowered is needed
    /// (inside an `if` branch, the right operand of `&&`/`||`); `None`:
    /// always. Run-time table indices fail only where it holds.
    pub(crate) path: Option<dag::NodeId>,
    /// Statement values already lowered in the outermost `for` loop being
    /// checked (`None` outside loops); see [`reuse`].
    pub(crate) reuse: Option<reuse::Reuse>,
    /// What is left of the budget for "did you mean" hints.
    pub(crate) hints: expr::Hints,
}

/// Why a name's value is unavailable ([`Checker::poisoned`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Unavailable {
    /// Design block `.0` failed (or used a failed block's results): the
    /// name is listed in that block's error.
    Design(String),
    /// Its own definition failed, with an error there.
    Failed,
}

/// Checks a parsed model with overrides; on success returns the checked
/// model, otherwise every error found.
pub fn check(
    model: &crate::syntax::ast::Model,
    overrides: &[Override],
) -> Result<CheckedModel, Vec<CheckError>> {
    check_with(model, overrides, &CheckOptions::default())
}

/// As [`check`], and also solves the `design` blocks without results
/// (checks such as a certificate), which [`check`] leaves unsolved since
/// nothing in the model depends on them (`hybsim design`).
pub fn check_with_designs(
    model: &crate::syntax::ast::Model,
    overrides: &[Override],
) -> Result<CheckedModel, Vec<CheckError>> {
    let options = CheckOptions {
        solve_checks: true,
        ..CheckOptions::default()
    };
    check_with(model, overrides, &options)
}

/// How the checker treats `design` blocks; not part of the model (the
/// command line sets them).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CheckOptions {
    /// The interior-point method that solves the design blocks
    /// (`hybsim design|run --sdp`). Default [`Backend::Auto`].
    pub backend: Backend,
    /// Also solve the `check` blocks (see [`check_with_designs`]).
    pub solve_checks: bool,
    /// The resource limits (the model's `sim { max_<name> = N }` and `--set max_<name>=N`
    /// change them further).
    pub limits: limits::Limits,
}

impl Default for CheckOptions {
    fn default() -> Self {
        Self {
            backend: Backend::Auto,
            solve_checks: false,
            limits: limits::Limits::default(),
        }
    }
}

/// As [`check`] with `options`.
pub fn check_with(
    model: &crate::syntax::ast::Model,
    overrides: &[Override],
    options: &CheckOptions,
) -> Result<CheckedModel, Vec<CheckError>> {
    model::check_model(model, overrides, options)
}
