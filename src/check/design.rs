//! `design` blocks: elaboration of decision variables, objective and
//! constraints into a [`crate::design::lmi::Problem`], the solve, and the
//! report. The block's results (`param` lines) are declared by the model
//! checker like any parameter, with the variables bound to their values.
//!
//! Expressions that mention no decision variable are ordinary constant
//! expressions (elaborated by the checker). Those that do are lowered
//! structurally into affine matrix expressions ([`LExpr`]): sums, products
//! with constants on either side, division by a constant scalar, transposes,
//! indexing and slices, block matrices (`*` for the transpose of the mirror
//! block, a constant `0` for a zero block of fitting size), `trace`, `diag`,
//! `kron` and `blkdiag` with a constant factor, `sum(..)`, and `if` on a
//! constant condition. Anything else that mentions a variable is not affine.

use std::collections::HashMap;
use std::rc::Rc;

use nalgebra::DMatrix;

use super::dag::NodeId;
use super::error::{CheckError, Dims};
use super::expr::{CONST_CTX, Val};
use super::limits::Quantity;
use super::{Checker, Sym};
use crate::design::lmi::{
    Backend, Expr as LExpr, LmiError, Outcome, Problem, Relation, Rescale, Settings, SolverStatus,
    VarKind,
};
use crate::diagnostics::Diagnostic;
use crate::source::Span;
use crate::syntax::ast::{
    BinOp, Binder, Constraint, DesignBlock, DesignStmt, Expr, ExprKind, Fold, IndexArg, IndexSet,
    LmiSide, Rel, Sense, UnOp, VarShape,
};

/// Most members of the set in `for S in subsets(..)` (2^16 constraints).
pub const MAX_SUBSET_BASE: usize = 16;

/// An error in a `design` block (codes E07xx).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DesignError {
    /// A product (or other non-linear function) of decision variables.
    #[error("not affine in the decision variables: {what}")]
    NonAffine {
        /// What is not affine ("a product of two expressions with decision variables").
        what: String,
        /// Where.
        span: Span,
    },
    /// A matrix inequality on a non-square expression.
    #[error("a matrix inequality needs a square expression, found {}×{}", shape.0, shape.1)]
    NotSquare {
        /// The shape found.
        shape: Dims,
        /// The constraint.
        span: Span,
    },
    /// A matrix inequality on a non-symmetric expression.
    #[error("the matrix in this inequality is not symmetric (|F − Fᵀ| up to {asymmetry:.2e})")]
    NotSymmetric {
        /// Largest asymmetry of the data.
        asymmetry: f64,
        /// The constraint.
        span: Span,
    },
    /// An objective that is not a 1×1 expression.
    #[error("the objective must be a scalar, found {}×{}", shape.0, shape.1)]
    ObjectiveShape {
        /// The shape found.
        shape: Dims,
        /// The objective.
        span: Span,
    },
    /// The problem has no solution: infeasible, unbounded, or the solver
    /// stopped without one.
    #[error("design `{block}` is {outcome} (solver status: {status:?})")]
    NoDesign {
        /// The block.
        block: String,
        /// "infeasible", "unbounded" or "not solved".
        outcome: &'static str,
        /// The solver's status.
        status: SolverStatus,
        /// The block's name.
        span: Span,
        /// What was not evaluated because of this failure (see [`DesignError::unavailable_mut`]).
        unavailable: Vec<String>,
    },
    /// The solver reported a solution at which a constraint does not hold.
    #[error(
        "design `{block}`: the solver reported {status:?} but constraint `{constraint}` does not hold at its point"
    )]
    Unverified {
        /// The block.
        block: String,
        /// The solver's status.
        status: SolverStatus,
        /// The violated constraint's label.
        constraint: String,
        /// The block's name.
        span: Span,
        /// What was not evaluated because of this failure.
        unavailable: Vec<String>,
    },
    /// The solver rejected the problem.
    #[error("design `{block}`: {message}")]
    Solver {
        /// The block.
        block: String,
        /// Why.
        message: String,
        /// The block's name.
        span: Span,
        /// What was not evaluated because of this failure.
        unavailable: Vec<String>,
    },
}

impl DesignError {
    /// The primary span.
    pub fn span(&self) -> Span {
        use DesignError::*;
        match self {
            NonAffine { span, .. }
            | NotSquare { span, .. }
            | NotSymmetric { span, .. }
            | ObjectiveShape { span, .. }
            | NoDesign { span, .. }
            | Unverified { span, .. }
            | Solver { span, .. } => *span,
        }
    }

    /// For the failure of a whole block (no solution, result rejected,
    /// solver error): the block's name and the list of what was not
    /// evaluated because of it (parameters computed from its results,
    /// later blocks that use them), shown as one note instead of an error
    /// for each.
    pub fn unavailable_mut(&mut self) -> Option<(&str, &mut Vec<String>)> {
        use DesignError::*;
        match self {
            NoDesign {
                block, unavailable, ..
            }
            | Unverified {
                block, unavailable, ..
            }
            | Solver {
                block, unavailable, ..
            } => Some((block.as_str(), unavailable)),
            _ => None,
        }
    }

    /// The stable code.
    pub fn code(&self) -> &'static str {
        use DesignError::*;
        match self {
            NonAffine { .. } => "E0701",
            NotSymmetric { .. } => "E0702",
            NotSquare { .. } => "E0703",
            ObjectiveShape { .. } => "E0704",
            NoDesign { .. } => "E0705",
            Unverified { .. } => "E0706",
            Solver { .. } => "E0707",
        }
    }

    /// The error as a diagnostic.
    pub fn to_diagnostic(&self) -> Diagnostic {
        use DesignError::*;
        let mut d = Diagnostic::error(self.code(), self.to_string());
        if let NoDesign {
            block, unavailable, ..
        }
        | Unverified {
            block, unavailable, ..
        }
        | Solver {
            block, unavailable, ..
        } = self
            && !unavailable.is_empty()
        {
            d = d.note(format!(
                "not evaluated because design `{block}` failed: {}",
                unavailable.join(", ")
            ));
        }
        match self {
            NonAffine { span, .. } => d
                .primary(*span, "not affine")
                .help("constraints and objectives must be affine: multiply decision variables only by constants (e.g. use U = P*L as the variable, then L = inv(P)*U as a result)"),
            NotSquare { span, .. } => d
                .primary(*span, "not square")
                .help("`>`, `>=`, `<`, `<=` compare symmetric matrices; use `==` for entries"),
            NotSymmetric { span, .. } => d
                .primary(*span, "not symmetric")
                .help("write the lower blocks as the transposes of the upper ones, or `*`"),
            ObjectiveShape { span, .. } => d
                .primary(*span, "not a scalar")
                .help("minimize a scalar such as `trace(X)` or a `scalar` variable"),
            NoDesign { span, outcome, .. } => d.primary(*span, *outcome).help(match *outcome {
                "infeasible" => "no point satisfies every constraint: check the data, relax a constraint, or use `>=` instead of `>`",
                "unbounded" => "the objective is unbounded: add a constraint that bounds it",
                _ => "the interior-point method stopped without a solution; rescale the data (e.g. covariances near 1) or simplify the problem",
            }),
            Unverified { span, .. } => d
                .primary(*span, "result rejected")
                .help("the problem is badly scaled or only marginally feasible; rescale the data or use `>=`"),
            Solver { span, .. } => d.primary(*span, "in this design"),
        }
    }
}

/// The outcome of one `design` block.
#[derive(Debug, Clone, PartialEq)]
pub struct DesignReport {
    /// The block's name.
    pub name: String,
    /// The block's name in the source.
    pub span: Span,
    /// `None` when every result was given with `--set` and nothing was solved.
    pub solve: Option<SolveSummary>,
    /// The results (parameters declared by the block): name, shape, row-major values.
    pub results: Vec<(String, Dims, Vec<f64>)>,
    /// A `check` block (no results) that has no solution: the outcome
    /// (`infeasible`, `unbounded`, `not solved`) and the solver's status.
    /// This is a result, not an error: nothing depends on the block, so the
    /// model still compiles and runs. (A block with results and no
    /// solution is error E0705.)
    pub unsolved: Option<(String, SolverStatus)>,
    /// A `check` block (solved by `hybsim design` only).
    pub check: bool,
}

/// Solver figures of a solved design.
#[derive(Debug, Clone, PartialEq)]
pub struct SolveSummary {
    /// `Solved` or `AlmostSolved` (reduced accuracy, constraints verified).
    pub status: SolverStatus,
    /// Objective value (0 for feasibility problems).
    pub objective: f64,
    /// Whether the block has an objective.
    pub has_objective: bool,
    /// Worst relative constraint margin at the solution (≥ 0 up to the check tolerance).
    pub worst_margin: f64,
    /// The constraint with the worst margin.
    pub worst_constraint: String,
    /// Solver wall time (s).
    pub solve_time: f64,
    /// Wall time with assembly and checks (s).
    pub total_time: f64,
    /// Interior-point iterations.
    pub iterations: u32,
    /// The interior-point method that ran ([`Backend::Clarabel`] or
    /// [`Backend::Schur`]; `hybsim design|run --sdp` chooses).
    pub backend: Backend,
    /// Solves (2 when rescaled).
    pub passes: u32,
    /// Scalar decision variables.
    pub variables: usize,
    /// Constraints (matrix blocks and scalar rows).
    pub constraints: usize,
}

impl DesignReport {
    /// A `check` block that was solved and has no solution.
    pub fn check_failed(&self) -> bool {
        self.unsolved.is_some()
    }

    /// One line: `design NAME: solved, objective …, worst margin …, … s`
    /// (`check NAME: feasible (solved), …` or `check NAME: infeasible
    /// (solver status …)` for a `check` block).
    pub fn summary_line(&self) -> String {
        if let Some((outcome, status)) = &self.unsolved {
            return format!("check {}: {outcome} (solver status {status:?})", self.name);
        }
        match &self.solve {
            None if self.check => format!(
                "check {}: not solved here (`hybsim design` solves it)",
                self.name
            ),
            None => format!(
                "design {}: not solved (every result given with --set)",
                self.name
            ),
            Some(s) => {
                let status = match s.status {
                    SolverStatus::Solved => "solved",
                    _ => "solved (reduced accuracy)",
                };
                let objective = if s.has_objective {
                    format!(", objective {:.6e}", s.objective)
                } else {
                    ", feasibility".to_string()
                };
                let (kind, status) = if self.check {
                    ("check", format!("feasible ({status})"))
                } else {
                    ("design", status.to_string())
                };
                format!(
                    "{kind} {}: {status}{objective}, worst margin {:.1e} ({}), {} variables, {} constraints, {} iterations ({}), {:.3} s",
                    self.name,
                    s.worst_margin,
                    s.worst_constraint,
                    s.variables,
                    s.constraints,
                    s.iterations,
                    backend_name(s.backend),
                    s.total_time
                )
            }
        }
    }

    /// The report as JSON (for logs): status, figures and results. Times are
    /// left out so that logs of the same run are byte-identical.
    pub fn to_json(&self) -> serde_json::Value {
        let mut results = serde_json::Map::new();
        for (name, (rows, cols), vals) in &self.results {
            let v = crate::num::matrix_json(*rows, *cols, vals);
            results.insert(name.clone(), v);
        }
        if let Some((outcome, status)) = &self.unsolved {
            return serde_json::json!({
                "name": self.name,
                "status": outcome,
                "solver_status": format!("{status:?}"),
                "results": results,
            });
        }
        match &self.solve {
            None if self.check => serde_json::json!({
                "name": self.name,
                "status": "not solved (a check; see `hybsim design`)",
                "results": results,
            }),
            None => serde_json::json!({
                "name": self.name,
                "status": "not solved (results set)",
                "results": results,
            }),
            Some(s) => serde_json::json!({
                "name": self.name,
                "status": format!("{:?}", s.status),
                "objective": if s.has_objective { Some(s.objective) } else { None },
                "worst_margin": s.worst_margin,
                "worst_constraint": s.worst_constraint,
                "iterations": s.iterations,
                "backend": backend_name(s.backend),
                "passes": s.passes,
                "variables": s.variables,
                "constraints": s.constraints,
                "results": results,
            }),
        }
    }
}

/// A solved block before its results are declared: variable values and the
/// solver figures.
pub(crate) struct Solved {
    pub values: Vec<SolvedVar>,
    pub summary: Option<SolveSummary>,
    /// See [`DesignReport::unsolved`].
    pub unsolved: Option<(String, SolverStatus)>,
}

/// The value of one decision variable (or family member) at the solution.
pub(crate) struct SolvedVar {
    /// The variable's (or family's) name.
    pub name: String,
    /// The family index of a member of a variable family.
    pub member: Option<Vec<i64>>,
    /// Its value.
    pub value: DMatrix<f64>,
    /// Its declaration.
    pub span: Span,
}

/// A declared decision variable.
struct DVar {
    /// Its expression (a `diag` variable: the diagonal matrix).
    expr: LExpr,
    shape: VarShape,
    span: Span,
    /// `(family, index)` for a member of a variable family.
    member: Option<(String, Vec<i64>)>,
}

/// The key of member `index` of variable family `name` (also its name in
/// the LMI problem): `P[2]`, `F[1,3]`.
fn member_key(name: &str, index: &[i64]) -> String {
    let idx: Vec<String> = index.iter().map(|i| i.to_string()).collect();
    format!("{name}[{}]", idx.join(","))
}

/// Elaboration state of one block.
struct Cx {
    block: String,
    vars: HashMap<String, DVar>,
    /// Variable families (`sym P[k][n]`): name → first declaration. Members
    /// are in `vars` under [`member_key`].
    families: HashMap<String, Span>,
    problem: Problem,
    objective: Option<Span>,
    /// Scope depth at the start of the block (loop indices above it label constraints).
    depth: usize,
    count: usize,
    /// Conic rows of the constraints so far (Σ d(d+1)/2, or the entries of `= 0` ones).
    rows: usize,
    failed: bool,
}

impl Checker {
    /// Elaborates the block and (if `solve`) solves it. `None` if an error was
    /// recorded (elaboration or solve), or if the block uses the results of
    /// a failed block ([`Checker::poison_hit`] is then set).
    pub(crate) fn design_block(&mut self, d: &DesignBlock, solve: bool) -> Option<Solved> {
        let before = self.errors.len();
        let mut cx = Cx {
            block: d.name.name.clone(),
            vars: HashMap::new(),
            families: HashMap::new(),
            problem: Problem::new().with_settings(design_settings(self.backend)),
            objective: None,
            depth: self.scopes.len(),
            count: 0,
            rows: 0,
            failed: false,
        };
        self.poison_hit = None;
        for s in &d.stmts {
            self.d_stmt(&mut cx, s, true);
        }
        // A block using the results of a failed block fails quietly
        // (`poison_hit` names the failed block).
        if cx.failed || self.errors.len() > before || self.poison_hit.is_some() {
            return None;
        }
        if !solve {
            return Some(Solved {
                values: Vec::new(),
                summary: None,
                unsolved: None,
            });
        }
        let block = cx.block.clone();
        let span = d.name.span;
        let outcome = match cx.problem.solve() {
            Ok(o) => o,
            Err(LmiError::Unverified { status, worst }) => {
                self.err(CheckError::Design(DesignError::Unverified {
                    block,
                    status,
                    constraint: worst.label,
                    span,
                    unavailable: Vec::new(),
                }));
                return None;
            }
            Err(e) => {
                self.err(CheckError::Design(DesignError::Solver {
                    block,
                    message: e.to_string(),
                    span,
                    unavailable: Vec::new(),
                }));
                return None;
            }
        };
        let (outcome, info) = match outcome {
            Outcome::Solved(design) => {
                let worst = design
                    .checks
                    .iter()
                    .map(|c| (c.min_eig / (1.0 + c.norm), c.label.clone()))
                    .min_by(|a, b| a.0.total_cmp(&b.0))
                    .map(|(_, l)| l)
                    .unwrap_or_default();
                let mut values = Vec::new();
                let mut names: Vec<&String> = cx.vars.keys().collect();
                names.sort();
                for name in names {
                    let v = &cx.vars[name];
                    let Some(raw) = design.value(name) else {
                        continue;
                    };
                    let value = match v.shape {
                        VarShape::Diagonal => DMatrix::from_diagonal(&raw.column(0).into_owned()),
                        _ => raw.clone(),
                    };
                    let (name, member) = match &v.member {
                        Some((family, index)) => (family.clone(), Some(index.clone())),
                        None => (name.clone(), None),
                    };
                    values.push(SolvedVar {
                        name,
                        member,
                        value,
                        span: v.span,
                    });
                }
                let info = &design.info;
                return Some(Solved {
                    values,
                    summary: Some(SolveSummary {
                        status: info.status,
                        objective: design.objective,
                        has_objective: cx.objective.is_some(),
                        worst_margin: design.worst_margin,
                        worst_constraint: worst,
                        solve_time: info.solve_time,
                        total_time: info.total_time,
                        iterations: info.iterations,
                        backend: info.backend,
                        passes: info.passes,
                        variables: info.variables,
                        constraints: design.checks.len(),
                    }),
                    unsolved: None,
                });
            }
            Outcome::Infeasible(i) => ("infeasible", i),
            Outcome::Unbounded(i) => ("unbounded", i),
            Outcome::Failed(i) => ("not solved", i),
        };
        // A `check` block's verdict is reported, not an error.
        if d.check {
            return Some(Solved {
                values: Vec::new(),
                summary: None,
                unsolved: Some((outcome.to_string(), info.status)),
            });
        }
        self.err(CheckError::Design(DesignError::NoDesign {
            block,
            outcome,
            status: info.status,
            span,
            unavailable: Vec::new(),
        }));
        None
    }

    /// Binds solved variable values as constant parameters (for the block's
    /// results); members of a variable family become a parameter family.
    pub(crate) fn bind_design_values(&mut self, values: &[SolvedVar]) {
        for v in values {
            let m = &v.value;
            let mut e = Vec::with_capacity(m.len());
            for i in 0..m.nrows() {
                for j in 0..m.ncols() {
                    e.push(self.dag.konst(m[(i, j)]));
                }
            }
            let val = Val {
                rows: m.nrows(),
                cols: m.ncols(),
                e: e.into(),
                boolean: false,
            };
            match &v.member {
                None => {
                    self.syms.insert(
                        v.name.clone(),
                        Sym::Param {
                            val: Rc::new(val),
                            span: v.span,
                        },
                    );
                }
                Some(index) => {
                    let entry =
                        self.syms
                            .entry(v.name.clone())
                            .or_insert_with(|| Sym::ParamFamily {
                                members: std::collections::BTreeMap::new(),
                                span: v.span,
                            });
                    if let Sym::ParamFamily { members, .. } = entry {
                        members.insert(index.clone(), val);
                    }
                }
            }
        }
    }

    fn d_stmt(&mut self, cx: &mut Cx, s: &DesignStmt, top: bool) {
        match s {
            DesignStmt::Var(shape, decls) => {
                for d in decls {
                    self.d_var(cx, *shape, d);
                }
            }
            DesignStmt::Objective(sense, e, span) => {
                if let Some(first) = cx.objective {
                    self.err(CheckError::Duplicate {
                        name: "objective".into(),
                        span: *span,
                        first,
                    });
                    return;
                }
                cx.objective = Some(*span);
                let Some(v) = self.aff(cx, e) else { return };
                if v.shape() != (1, 1) {
                    self.err(CheckError::Design(DesignError::ObjectiveShape {
                        shape: v.shape(),
                        span: e.span,
                    }));
                    return;
                }
                let r = match sense {
                    Sense::Minimize => cx.problem.minimize(&v),
                    Sense::Maximize => cx.problem.maximize(&v),
                };
                if let Err(err) = r {
                    self.lmi_err(err, e.span);
                }
            }
            DesignStmt::Constraint(c) => self.d_constraint(cx, c),
            DesignStmt::For(b, body) => self.d_for(cx, b, body),
            DesignStmt::If(c, body) => {
                if let Some(x) = self.const_scalar(c, "the condition of `if` in a design") {
                    if x != 0.0 {
                        for s in body {
                            self.d_stmt(cx, s, false);
                        }
                    }
                } else {
                    cx.failed = true;
                }
            }
            DesignStmt::Param(defs) => {
                // Results inside `for` and `if` are declared by the model
                // checker (it walks the same loops); not inside `subsets`.
                if !top && !self.set_scopes.is_empty() {
                    let span = defs.first().map_or(Span::default(), |d| d.target.span);
                    self.err(CheckError::Expected {
                        expected: "results (`param`) outside `for S in subsets(..)`".into(),
                        found: "a result inside a loop over subsets".into(),
                        span,
                    });
                }
            }
            DesignStmt::ParamTuple(t, _) => {
                if !top && !self.set_scopes.is_empty() {
                    let span = t.first().map_or(Span::default(), |d| d.span);
                    self.err(CheckError::Expected {
                        expected: "results (`param`) outside `for S in subsets(..)`".into(),
                        found: "a result inside a loop over subsets".into(),
                        span,
                    });
                }
            }
        }
    }

    fn d_var(&mut self, cx: &mut Cx, shape: VarShape, d: &crate::syntax::ast::VarDecl) {
        let (dims, span, name_span) = (&d.dims, d.span, d.name.span);
        let family = &d.name.name;
        let member = if d.member.is_empty() {
            None
        } else {
            let mut index = Vec::new();
            for e in &d.member {
                match self.const_int(e, "a family index") {
                    Some(i) => index.push(i),
                    None => {
                        cx.failed = true;
                        return;
                    }
                }
            }
            Some(index)
        };
        let name = match &member {
            Some(index) => member_key(family, index),
            None => family.clone(),
        };
        // A plain variable and a family share one name space (with the
        // model's names); members of one family must differ.
        let clash = match &member {
            None => cx.families.get(family).copied(),
            Some(_) => cx
                .vars
                .get(family)
                .filter(|v| v.member.is_none())
                .map(|v| v.span),
        };
        if let Some(prev) = cx
            .vars
            .get(&name)
            .map(|v| v.span)
            .or(clash)
            .or_else(|| self.syms.get(family).map(Sym::span))
        {
            self.err(CheckError::Duplicate {
                name: name.clone(),
                span: name_span,
                first: prev,
            });
            cx.failed = true;
            return;
        }
        let name = name.as_str();
        let want = match shape {
            VarShape::Scalar => 0..=0,
            VarShape::Symmetric | VarShape::Diagonal => 1..=1,
            VarShape::Full => 1..=2,
        };
        if !want.contains(&dims.len()) {
            let expected = match shape {
                VarShape::Scalar => "no size: `scalar g`",
                VarShape::Symmetric => "one size: `sym P[n]`",
                VarShape::Diagonal => "one size: `diag D[n]`",
                VarShape::Full => "one or two sizes: `full U[rows, cols]`",
            };
            self.err(CheckError::Expected {
                expected: expected.into(),
                found: format!("{} sizes", dims.len()),
                span,
            });
            cx.failed = true;
            return;
        }
        let mut sizes = Vec::new();
        for d in dims {
            match self.const_int(d, "a variable size") {
                Some(k) if (1..=100_000).contains(&k) => sizes.push(k as usize),
                Some(k) => {
                    self.err(CheckError::Expected {
                        expected: "a size between 1 and 100000".into(),
                        found: k.to_string(),
                        span: d.span,
                    });
                    cx.failed = true;
                    return;
                }
                None => {
                    cx.failed = true;
                    return;
                }
            }
        }
        let kind = match (shape, sizes.as_slice()) {
            (VarShape::Symmetric, [n]) => VarKind::Symmetric(*n),
            (VarShape::Full, [r]) => VarKind::Full(*r, 1),
            (VarShape::Full, [r, c]) => VarKind::Full(*r, *c),
            (VarShape::Diagonal, [n]) => VarKind::Full(*n, 1),
            _ => VarKind::Scalar,
        };
        // The solvers' memory grows with the square of the scalar variables (the Schur or KKT
        // matrix): refuse before the variable's expression is built.
        let total = cx.problem.num_scalars() as f64 + kind.count() as f64;
        if !self.within_limit(Quantity::DesignVars, total, span) {
            cx.failed = true;
            return;
        }
        let v = match cx.problem.add_variable(name, kind) {
            Ok(v) => v,
            Err(e) => {
                self.lmi_err(e, span);
                cx.failed = true;
                return;
            }
        };
        let expr = match shape {
            VarShape::Diagonal => match diag_of_vector(&v) {
                Ok(e) => e,
                Err(e) => {
                    self.lmi_err(e, span);
                    cx.failed = true;
                    return;
                }
            },
            _ => v,
        };
        if member.is_some() {
            cx.families.entry(family.clone()).or_insert(name_span);
        }
        cx.vars.insert(
            name.to_string(),
            DVar {
                expr,
                shape,
                span: name_span,
                member: member.map(|index| (family.clone(), index)),
            },
        );
    }

    fn d_for(&mut self, cx: &mut Cx, b: &Binder, body: &[DesignStmt]) {
        // After an error in one iteration, the others are skipped (same error).
        let before = self.errors.len();
        let IndexSet::Subsets(base) = &b.set else {
            self.for_each(b, &mut |this| {
                if this.errors.len() > before {
                    return;
                }
                for s in body {
                    this.d_stmt(cx, s, false);
                }
            });
            return;
        };
        if b.vars.len() != 1 || b.filter.is_some() {
            self.err(CheckError::Expected {
                expected: "`for S in subsets(1..N)` (one name, no filter)".into(),
                found: "something else".into(),
                span: b.span,
            });
            return;
        }
        let inner = Binder {
            vars: b.vars.clone(),
            set: (**base).clone(),
            filter: None,
            span: b.span,
        };
        let Some(members) = self.index_set(&inner) else {
            return;
        };
        let members: Vec<i64> = members
            .into_iter()
            .filter_map(|m| m.first().copied())
            .collect();
        if members.len() > MAX_SUBSET_BASE {
            self.err(CheckError::Expected {
                expected: format!("at most {MAX_SUBSET_BASE} members for `subsets`"),
                found: members.len().to_string(),
                span: b.span,
            });
            return;
        }
        // Every subset repeats the body's constraints: refuse before building any of them.
        let per_subset = count_constraints(body) as f64;
        let estimate = cx.count as f64 + per_subset * (1u64 << members.len()) as f64;
        if per_subset > 0.0 && !self.within_limit(Quantity::LmiBlocks, estimate, b.span) {
            cx.failed = true;
            return;
        }
        let rows_before = cx.rows;
        for mask in 0u64..(1u64 << members.len()) {
            // After the first subset: its conic rows times the number of subsets, before the
            // others are built (one of 2^M is cheap, all of them may not be).
            if mask == 1 {
                let per = (cx.rows - rows_before) as f64;
                let estimate = rows_before as f64 + per * (1u64 << members.len()) as f64;
                if !self.within_limit(Quantity::LmiRows, estimate, b.span) {
                    cx.failed = true;
                    break;
                }
            }
            let subset: Vec<i64> = members
                .iter()
                .enumerate()
                .filter(|(k, _)| mask & (1 << k) != 0)
                .map(|(_, &m)| m)
                .collect();
            self.set_scopes.push((b.vars[0].name.clone(), subset));
            for s in body {
                self.d_stmt(cx, s, false);
            }
            self.set_scopes.pop();
            if self.errors.len() > before {
                break;
            }
        }
    }

    /// The label of a constraint: its own or `#k`, plus the loop bindings.
    fn d_label(&self, cx: &Cx, c: &Constraint) -> String {
        let mut label = match &c.label {
            Some(l) => l.name.clone(),
            None => format!("#{}", cx.count),
        };
        let mut binds: Vec<String> = self.scopes[cx.depth.min(self.scopes.len())..]
            .iter()
            .map(|(n, i)| format!("{n}={i}"))
            .collect();
        binds.extend(self.set_scopes.iter().map(|(n, s)| {
            let items: Vec<String> = s.iter().map(|i| i.to_string()).collect();
            format!("{n}={{{}}}", items.join(","))
        }));
        if !binds.is_empty() {
            label.push_str(&format!("[{}]", binds.join(", ")));
        }
        label
    }

    fn d_constraint(&mut self, cx: &mut Cx, c: &Constraint) {
        cx.count += 1;
        if !self.within_limit(Quantity::LmiBlocks, cx.count as f64, c.span) {
            cx.failed = true;
            return;
        }
        let lhs = self.side(cx, &c.lhs);
        let rhs = self.side(cx, &c.rhs);
        let (Some(lhs), Some(rhs)) = (lhs, rhs) else {
            cx.failed = true;
            return;
        };
        let matrix = c.rel != Rel::Eq;
        for side in [&lhs, &rhs] {
            let (r, k) = side.shape();
            if matrix && r != k {
                self.err(CheckError::Design(DesignError::NotSquare {
                    shape: (r, k),
                    span: c.span,
                }));
                cx.failed = true;
                return;
            }
        }
        let f = match (lhs.shape(), rhs.shape()) {
            (a, b) if a == b => lhs.sub(&rhs),
            ((r, k), (1, 1)) if rhs.is_constant() && (!matrix || r == k) => {
                lhs.sub(&broadcast(&rhs, r, k, matrix))
            }
            ((1, 1), (r, k)) if lhs.is_constant() && (!matrix || r == k) => {
                broadcast(&lhs, r, k, matrix).sub(&rhs)
            }
            (a, b) => {
                self.err(CheckError::ShapeMismatch {
                    op: c.rel.symbol().into(),
                    left: a,
                    right: b,
                    span: c.span,
                });
                cx.failed = true;
                return;
            }
        };
        let f = match f {
            Ok(f) => f,
            Err(e) => {
                self.lmi_err(e, c.span);
                cx.failed = true;
                return;
            }
        };
        if matrix && f.shape().0 != f.shape().1 {
            self.err(CheckError::Design(DesignError::NotSquare {
                shape: f.shape(),
                span: c.span,
            }));
            cx.failed = true;
            return;
        }
        if matrix && !self.within_limit(Quantity::LmiSize, f.shape().0 as f64, c.span) {
            cx.failed = true;
            return;
        }
        let (r, k) = f.shape();
        cx.rows += if matrix { r * (r + 1) / 2 } else { r * k };
        if !self.within_limit(Quantity::LmiRows, cx.rows as f64, c.span) {
            cx.failed = true;
            return;
        }
        let relation = match c.rel {
            Rel::Gt => Relation::PosDef,
            Rel::Ge => Relation::PosSemiDef,
            Rel::Lt => Relation::NegDef,
            Rel::Le => Relation::NegSemiDef,
            Rel::Eq => Relation::Zero,
        };
        let label = self.d_label(cx, c);
        if let Err(e) = cx.problem.constrain(&label, &f, relation) {
            self.lmi_err(e, c.span);
            cx.failed = true;
        }
    }

    fn side(&mut self, cx: &Cx, s: &LmiSide) -> Option<LExpr> {
        match s {
            LmiSide::Expr(e) => self.aff(cx, e),
            LmiSide::Blocks(rows, span) => {
                let mut grid: Vec<Vec<Option<LExpr>>> = Vec::new();
                let mut ok = true;
                for row in rows {
                    let mut r = Vec::new();
                    for b in row {
                        r.push(match b {
                            None => None,
                            Some(e) => match self.aff(cx, e) {
                                Some(v) => Some(v),
                                None => {
                                    ok = false;
                                    None
                                }
                            },
                        });
                    }
                    grid.push(r);
                }
                if !ok {
                    return None;
                }
                // `*`: the transpose of the mirror block.
                for (i, row) in rows.iter().enumerate() {
                    for (j, b) in row.iter().enumerate() {
                        if b.is_some() {
                            continue;
                        }
                        let mirror = rows
                            .get(j)
                            .and_then(|r| r.get(i))
                            .and_then(|m| m.as_ref())
                            .and_then(|_| grid[j][i].as_ref())
                            .map(|m| m.transpose());
                        match mirror {
                            Some(m) => grid[i][j] = Some(m),
                            None => {
                                self.err(CheckError::Expected {
                                    expected: format!(
                                        "a block at ({}, {}) for the `*` at ({}, {})",
                                        j + 1,
                                        i + 1,
                                        i + 1,
                                        j + 1
                                    ),
                                    found: "no block there".into(),
                                    span: *span,
                                });
                                return None;
                            }
                        }
                    }
                }
                self.block_matrix(grid, *span)
            }
        }
    }

    /// A block matrix; constant scalar zeros become zero blocks of fitting size.
    fn block_matrix(&mut self, grid: Vec<Vec<Option<LExpr>>>, span: Span) -> Option<LExpr> {
        let single = grid.len() > 1 || grid.first().is_some_and(|r| r.len() > 1);
        let grid: Vec<Vec<Option<LExpr>>> = grid
            .into_iter()
            .map(|row| {
                row.into_iter()
                    .map(|b| match b {
                        Some(b)
                            if single
                                && b.is_constant()
                                && b.shape() == (1, 1)
                                && b.constant_part()[(0, 0)] == 0.0 =>
                        {
                            None
                        }
                        other => other,
                    })
                    .collect()
            })
            .collect();
        match LExpr::blocks(&grid) {
            Ok(e) => Some(e),
            Err(e) => {
                self.lmi_err(e, span);
                None
            }
        }
    }

    /// Maps an error of the LMI layer to a diagnostic at `span`.
    fn lmi_err(&mut self, e: LmiError, span: Span) {
        let err = match e {
            LmiError::Shape { op, left, right } => CheckError::ShapeMismatch {
                op: op.into(),
                left,
                right,
                span,
            },
            LmiError::NotSquare { shape } => CheckError::Expected {
                expected: "a square matrix".into(),
                found: format!("{}×{}", shape.0, shape.1),
                span,
            },
            LmiError::Nonlinear => CheckError::Design(DesignError::NonAffine {
                what: "a product of two expressions with decision variables".into(),
                span,
            }),
            LmiError::NotSymmetric { asymmetry, .. } => {
                CheckError::Design(DesignError::NotSymmetric { asymmetry, span })
            }
            LmiError::BlockLayout { detail } => CheckError::Expected {
                expected: "blocks that fit together".into(),
                found: detail,
                span,
            },
            other => CheckError::Expected {
                expected: "a valid design".into(),
                found: other.to_string(),
                span,
            },
        };
        self.err(err);
    }

    /// Whether `e` mentions a decision variable of the block.
    fn mentions(&self, cx: &Cx, e: &Expr) -> bool {
        match &e.kind {
            ExprKind::Num(_) | ExprKind::Bool(_) => false,
            ExprKind::Name(n) => {
                (cx.vars.contains_key(n) || cx.families.contains_key(n))
                    && !self.scopes.iter().any(|(s, _)| **s == **n)
            }
            ExprKind::Matrix(rows) => rows.iter().flatten().any(|x| self.mentions(cx, x)),
            ExprKind::Unary(_, a) => self.mentions(cx, a),
            ExprKind::Binary(_, a, b) => self.mentions(cx, a) || self.mentions(cx, b),
            ExprKind::Call(_, args) => args.iter().any(|a| self.mentions(cx, a)),
            ExprKind::Index(b, args) => {
                self.mentions(cx, b)
                    || args.iter().any(|a| match a {
                        IndexArg::One(x) => self.mentions(cx, x),
                        IndexArg::Slice(x, y) => self.mentions(cx, x) || self.mentions(cx, y),
                        IndexArg::All(_) => false,
                    })
            }
            ExprKind::If(c, a, b) => {
                self.mentions(cx, c) || self.mentions(cx, a) || self.mentions(cx, b)
            }
            ExprKind::Fold(_, _, body) => self.mentions(cx, body),
        }
    }

    /// A constant expression as a matrix.
    fn const_dmatrix(&mut self, e: &Expr) -> Option<DMatrix<f64>> {
        let v = self.expr(e, &CONST_CTX)?;
        let vals: Option<Vec<f64>> = v.e.iter().map(|&n: &NodeId| self.dag.as_const(n)).collect();
        match vals {
            Some(x) => Some(DMatrix::from_row_slice(v.rows, v.cols, &x)),
            None => {
                self.err(CheckError::NotConstant {
                    what: "a coefficient in a design".into(),
                    span: e.span,
                });
                None
            }
        }
    }

    /// Lowers an expression into an affine matrix expression of the block's
    /// variables. `None` means an error was recorded.
    fn aff(&mut self, cx: &Cx, e: &Expr) -> Option<LExpr> {
        if !self.mentions(cx, e) {
            return self.const_dmatrix(e).map(LExpr::constant);
        }
        let non_affine = |this: &mut Self, what: &str| {
            this.err(CheckError::Design(DesignError::NonAffine {
                what: what.to_string(),
                span: e.span,
            }));
            None
        };
        match &e.kind {
            ExprKind::Name(n) if cx.families.contains_key(n) => {
                self.err(CheckError::FamilyIndex {
                    lone: None,
                    name: n.clone(),
                    span: e.span,
                });
                None
            }
            ExprKind::Name(n) => cx.vars.get(n).map(|v| v.expr.clone()),
            ExprKind::Index(base, args)
                if matches!(&base.kind, ExprKind::Name(n) if cx.families.contains_key(n)
                    && !self.scopes.iter().any(|(s, _)| **s == **n)) =>
            {
                let ExprKind::Name(n) = &base.kind else {
                    return None;
                };
                let key = self.family_key(args)?;
                match cx.vars.get(&member_key(n, &key)) {
                    Some(v) => Some(v.expr.clone()),
                    None => {
                        let mut keys: Vec<&Vec<i64>> = cx
                            .vars
                            .values()
                            .filter_map(|v| v.member.as_ref())
                            .filter(|(f, _)| f == n)
                            .map(|(_, k)| k)
                            .collect();
                        keys.sort();
                        let words: Vec<String> = keys.iter().map(|k| member_key("", k)).collect();
                        self.err(CheckError::FamilyOutOfRange {
                            lone: None,
                            name: n.clone(),
                            index: member_key("", &key)
                                .trim_matches(|c| c == '[' || c == ']')
                                .to_string(),
                            members: if words.is_empty() {
                                "none".into()
                            } else {
                                words.join(", ")
                            },
                            span: e.span,
                        });
                        None
                    }
                }
            }
            ExprKind::Unary(UnOp::Neg, a) => Some(self.aff(cx, a)?.neg()),
            ExprKind::Unary(UnOp::Transpose, a) => Some(self.aff(cx, a)?.transpose()),
            ExprKind::Unary(UnOp::Not, _) => non_affine(self, "a logical `!`"),
            ExprKind::Binary(op, a, b) => {
                let l = self.aff(cx, a);
                let r = self.aff(cx, b);
                let (l, r) = (l?, r?);
                let res = match op {
                    BinOp::Add | BinOp::Sub => {
                        let (l, r) = match (l.shape(), r.shape()) {
                            (x, y) if x == y => (l, r),
                            ((1, 1), (rr, cc)) => (broadcast(&l, rr, cc, false), r),
                            ((rr, cc), (1, 1)) => {
                                let r = broadcast(&r, rr, cc, false);
                                (l, r)
                            }
                            (x, y) => {
                                self.err(CheckError::ShapeMismatch {
                                    op: op.symbol().into(),
                                    left: x,
                                    right: y,
                                    span: e.span,
                                });
                                return None;
                            }
                        };
                        if *op == BinOp::Add {
                            l.add(&r)
                        } else {
                            l.sub(&r)
                        }
                    }
                    BinOp::Mul => l.mul(&r),
                    BinOp::Div => {
                        if !r.is_constant() || r.shape() != (1, 1) {
                            return non_affine(
                                self,
                                "a division by a decision variable or a matrix",
                            );
                        }
                        Ok(l.scale(1.0 / r.constant_part()[(0, 0)]))
                    }
                    BinOp::ElemMul => {
                        if l.is_constant() {
                            elementwise(l.constant_part(), &r)
                        } else if r.is_constant() {
                            elementwise(r.constant_part(), &l)
                        } else {
                            return non_affine(
                                self,
                                "an elementwise product of decision variables",
                            );
                        }
                    }
                    BinOp::Pow => return non_affine(self, "a power of a decision variable"),
                    _ => {
                        return non_affine(
                            self,
                            "a comparison or logic inside a design expression (write constraints as `lhs > rhs` statements)",
                        );
                    }
                };
                match res {
                    Ok(v) => Some(v),
                    Err(err) => {
                        self.lmi_err(err, e.span);
                        None
                    }
                }
            }
            ExprKind::Matrix(rows) => {
                let mut grid = Vec::new();
                let mut ok = true;
                for row in rows {
                    let mut r = Vec::new();
                    for b in row {
                        match self.aff(cx, b) {
                            Some(v) => r.push(Some(v)),
                            None => ok = false,
                        }
                    }
                    grid.push(r);
                }
                if !ok {
                    return None;
                }
                self.block_matrix(grid, e.span)
            }
            ExprKind::Index(base, args) => {
                let v = self.aff(cx, base)?;
                let (r, c) = v.shape();
                let (rows, cols) = match args.len() {
                    1 if c == 1 => (self.selection(&args[0], r)?, vec![0]),
                    1 if r == 1 => (vec![0], self.selection(&args[0], c)?),
                    2 => {
                        let rs = self.selection(&args[0], r);
                        let cs = self.selection(&args[1], c);
                        (rs?, cs?)
                    }
                    _ => {
                        self.err(CheckError::Expected {
                            expected: "two indices `[row, col]` for a matrix".into(),
                            found: format!("{} indices", args.len()),
                            span: e.span,
                        });
                        return None;
                    }
                };
                if rows.is_empty() || cols.is_empty() {
                    self.err(CheckError::Expected {
                        expected: "a non-empty selection".into(),
                        found: "an empty slice".into(),
                        span: e.span,
                    });
                    return None;
                }
                match v.block(rows[0], cols[0], rows.len(), cols.len()) {
                    Ok(b) => Some(b),
                    Err(err) => {
                        self.lmi_err(err, e.span);
                        None
                    }
                }
            }
            ExprKind::If(c, a, b) => {
                if self.mentions(cx, c) {
                    return non_affine(self, "a condition on a decision variable");
                }
                let cond = self.const_dmatrix(c)?;
                if cond.len() != 1 {
                    self.err(CheckError::Expected {
                        expected: "a scalar condition".into(),
                        found: format!("{}×{}", cond.nrows(), cond.ncols()),
                        span: c.span,
                    });
                    return None;
                }
                if cond[(0, 0)] != 0.0 {
                    self.aff(cx, a)
                } else {
                    self.aff(cx, b)
                }
            }
            ExprKind::Fold(Fold::Max | Fold::Min, ..) => {
                non_affine(self, "a maximum or minimum over decision variables")
            }
            ExprKind::Fold(Fold::Sum, b, body) => {
                let mut acc: Option<LExpr> = None;
                let mut failed = false;
                self.for_each(b, &mut |this| {
                    if failed {
                        return;
                    }
                    let Some(v) = this.aff(cx, body) else {
                        failed = true;
                        return;
                    };
                    acc = match acc.take() {
                        None => Some(v),
                        Some(a) => match a.add(&v) {
                            Ok(s) => Some(s),
                            Err(err) => {
                                this.lmi_err(err, body.span);
                                failed = true;
                                None
                            }
                        },
                    };
                });
                if failed {
                    return None;
                }
                // An empty sum: the shape of the body is unknown; a scalar 0
                // broadcasts where it is used.
                Some(acc.unwrap_or_else(|| LExpr::scalar(0.0)))
            }
            ExprKind::Call(f, args) => self.aff_call(cx, &f.name, args, e),
            ExprKind::Num(_) | ExprKind::Bool(_) => None,
        }
    }

    fn aff_call(&mut self, cx: &Cx, name: &str, args: &[Expr], e: &Expr) -> Option<LExpr> {
        let arity = |this: &mut Self, want: usize| {
            if args.len() != want {
                this.err(CheckError::Arity {
                    func: name.to_string(),
                    expected: format!("{want} argument(s)"),
                    found: args.len(),
                    span: e.span,
                });
                return false;
            }
            true
        };
        let res = match name {
            "trace" => {
                if !arity(self, 1) {
                    return None;
                }
                self.aff(cx, &args[0])?.trace()
            }
            "diag" => {
                if !arity(self, 1) {
                    return None;
                }
                let v = self.aff(cx, &args[0])?;
                match v.shape() {
                    (_, 1) | (1, _) => {
                        let v = if v.shape().1 == 1 { v } else { v.transpose() };
                        diag_of_vector(&v)
                    }
                    (r, c) if r == c => diagonal_of(&v),
                    (r, c) => Err(LmiError::NotSquare { shape: (r, c) }),
                }
            }
            "kron" => {
                if !arity(self, 2) {
                    return None;
                }
                let a = self.aff(cx, &args[0]);
                let b = self.aff(cx, &args[1]);
                let (a, b) = (a?, b?);
                if a.is_constant() {
                    Ok(b.kron_left(a.constant_part()))
                } else if b.is_constant() {
                    Ok(a.kron_right(b.constant_part()))
                } else {
                    Err(LmiError::Nonlinear)
                }
            }
            "blkdiag" => {
                let mut parts = Vec::new();
                for a in args {
                    parts.push(self.aff(cx, a)?);
                }
                let k = parts.len();
                let grid: Vec<Vec<Option<LExpr>>> = parts
                    .into_iter()
                    .enumerate()
                    .map(|(i, p)| {
                        let mut row: Vec<Option<LExpr>> = vec![None; k];
                        row[i] = Some(p);
                        row
                    })
                    .collect();
                LExpr::blocks(&grid)
            }
            _ => {
                self.err(CheckError::Design(DesignError::NonAffine {
                    what: format!("`{name}` of a decision variable"),
                    span: e.span,
                }));
                return None;
            }
        };
        match res {
            Ok(v) => Some(v),
            Err(err) => {
                self.lmi_err(err, e.span);
                None
            }
        }
    }
}

/// The constraint statements of `body`, those in nested loops and branches once each (a lower
/// bound on what one pass over `body` builds).
fn count_constraints(body: &[DesignStmt]) -> usize {
    body.iter()
        .map(|s| match s {
            DesignStmt::Constraint(_) => 1,
            DesignStmt::For(_, inner) | DesignStmt::If(_, inner) => count_constraints(inner),
            _ => 0,
        })
        .sum()
}

/// Solver settings of design blocks: the LMI layer's defaults, but always a
/// second, solution-scaled solve. A first solve can report "solved" at a
/// point that is feasible yet several percent from optimal when the data are
/// badly scaled (the platoon's covariances of 1e-3 against P of 1e3); the
/// second pass, scaled by the first point, is accurate.
fn design_settings(backend: Backend) -> Settings {
    Settings {
        rescale: Rescale::Always,
        backend,
        ..Settings::default()
    }
}

/// The name of an interior-point method as the command line spells it
/// (`hybsim design --sdp clarabel`).
fn backend_name(b: Backend) -> &'static str {
    match b {
        Backend::Auto => "auto",
        Backend::Clarabel => "clarabel",
        Backend::Schur => "schur",
    }
}

/// A 1×1 expression as an r×k matrix: c·I (`identity`) or every entry c.
fn broadcast(s: &LExpr, r: usize, k: usize, identity: bool) -> LExpr {
    let m = if identity {
        DMatrix::identity(r, k)
    } else {
        DMatrix::from_element(r, k, 1.0)
    };
    s.kron_left(&m)
}

/// diag(v) for an n×1 expression v: the n×n diagonal matrix.
fn diag_of_vector(v: &LExpr) -> Result<LExpr, LmiError> {
    let n = v.shape().0;
    let mut acc = LExpr::zeros(n, n);
    for i in 0..n {
        let mut e = DMatrix::zeros(n, n);
        e[(i, i)] = 1.0;
        acc = acc.add(&v.entry(i, 0)?.kron_left(&e))?;
    }
    Ok(acc)
}

/// The diagonal of a square expression as an n×1 expression.
fn diagonal_of(v: &LExpr) -> Result<LExpr, LmiError> {
    let n = v.shape().0;
    let mut acc = LExpr::zeros(n, 1);
    for i in 0..n {
        let mut e = DMatrix::zeros(n, 1);
        e[(i, 0)] = 1.0;
        acc = acc.add(&v.entry(i, i)?.kron_left(&e))?;
    }
    Ok(acc)
}

/// K .* v for a constant K (or a scalar constant) and an affine v.
fn elementwise(k: &DMatrix<f64>, v: &LExpr) -> Result<LExpr, LmiError> {
    let (r, c) = v.shape();
    if k.shape() == (1, 1) {
        return Ok(v.scale(k[(0, 0)]));
    }
    if k.shape() != (r, c) {
        return Err(LmiError::Shape {
            op: ".*",
            left: k.shape(),
            right: (r, c),
        });
    }
    let mut acc = LExpr::zeros(r, c);
    for i in 0..r {
        for j in 0..c {
            if k[(i, j)] != 0.0 {
                let mut e = DMatrix::zeros(r, c);
                e[(i, j)] = k[(i, j)];
                acc = acc.add(&v.entry(i, j)?.kron_left(&e))?;
            }
        }
    }
    Ok(acc)
}
