//! Linear matrix inequality problems solved with clarabel's positive semidefinite cone or, for
//! large problems, hybsim's Schur-complement interior-point method ([`Backend`]).
//!
//! A [`Problem`] holds decision variables created by name and shape at run time
//! ([`Problem::add_variable`]), constraints on affine matrix expressions ([`Expr`]) and a linear
//! objective. [`Problem::solve`] returns an [`Outcome`]: a verified [`Design`], or an infeasible,
//! unbounded or failed problem — never numbers that do not satisfy the constraints.
//!
//! ```
//! use hybsim::design::lmi::{Problem, VarKind, Relation, Outcome};
//! use nalgebra::dmatrix;
//! // minimize tr(P) subject to AᵀP + PA + I ⪯ 0 (gives the Lyapunov solution)
//! let a = dmatrix![-1.0, 2.0; 0.0, -3.0];
//! let mut prob = Problem::new();
//! let p = prob.add_variable("P", VarKind::Symmetric(2)).unwrap();
//! let lhs = p.left_mul(&a.transpose()).unwrap()
//!     .add(&p.right_mul(&a).unwrap()).unwrap()
//!     .add(&hybsim::design::lmi::Expr::identity(2)).unwrap();
//! prob.constrain("lyapunov", &lhs, Relation::NegSemiDef).unwrap();
//! prob.minimize(&p.trace().unwrap()).unwrap();
//! let Outcome::Solved(design) = prob.solve().unwrap() else { panic!() };
//! assert!(design.worst_margin >= -1e-7);
//! ```
//!
//! # Vectorization convention (the one place it is defined)
//!
//! A symmetric n×n constraint block S is passed to clarabel's `PSDTriangleConeT(n)` as
//! svec(S) ∈ ℝ^{n(n+1)/2}: the **upper triangle, column by column**
//! (S₀₀, S₀₁, S₁₁, S₀₂, S₁₂, S₂₂, …), with every off-diagonal entry multiplied by √2, so that
//! svec(S)·svec(T) = tr(S T). This is clarabel's own `mat_to_svec`/`svec_to_mat` order
//! (`src/algebra/dense/matrix_math.rs`); [`svec`] and [`smat`] implement it and are tested
//! against each other and against the inner product. Decision variables are not vectorized this
//! way: a symmetric variable's scalars are its upper-triangle entries (no √2), see [`VarKind`].
//!
//! # Strict inequalities
//!
//! F ≻ 0 is imposed as F ⪰ ε I with ε = [`Settings::strict_margin`] (default 1e-7, in the units
//! of F), and verified afterwards as λ_min(F) > 0. Choose ε relative to the scale of your data
//! when F is homogeneous in the variables (e.g. P ≻ 0 alone can be scaled freely).
//!
//! # Numerical honesty and scaling
//!
//! After every solve each constraint is re-assembled at the returned point from the original
//! (unscaled) data and its extreme eigenvalue computed ([`ConstraintCheck`]); the worst margin is
//! reported next to the solver status. A point whose constraints do not hold beyond
//! [`Settings::check_tol`] is [`LmiError::Unverified`], never a design.
//!
//! Scaling: each constraint block is passed as D F D with a diagonal D (a congruence, which
//! preserves semidefiniteness) and each matrix variable V as s_V·Ṽ. The first solve uses
//! D = 1/√(row magnitude) of the block's data; if the check fails or the solver's accuracy was
//! reduced, the problem is scaled again from the returned point (D = diag(F(x))^{-1/2}, s_V =
//! max |V|) — which equalizes, e.g., noise covariances of 1e-3 against a Lyapunov matrix of 1e3 —
//! and solved again (see [`Rescale`]).

mod expr;
mod factor;
mod ipm;
mod kron;
mod solve;
#[cfg(test)]
mod tests;

pub use expr::Expr;
pub use solve::{smat, svec};

use std::collections::HashMap;

use nalgebra::DMatrix;
use thiserror::Error;

use expr::Term;

/// The shape of a decision variable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VarKind {
    /// One real number (1×1).
    Scalar,
    /// A symmetric n×n matrix: n(n+1)/2 scalars, the upper triangle column by column.
    Symmetric(usize),
    /// A general rows×cols matrix: rows·cols scalars, column by column.
    Full(usize, usize),
}

impl VarKind {
    /// Number of scalar decision variables.
    pub fn count(&self) -> usize {
        match *self {
            VarKind::Scalar => 1,
            VarKind::Symmetric(n) => n * (n + 1) / 2,
            VarKind::Full(r, c) => r * c,
        }
    }

    /// (rows, columns).
    pub fn shape(&self) -> (usize, usize) {
        match *self {
            VarKind::Scalar => (1, 1),
            VarKind::Symmetric(n) => (n, n),
            VarKind::Full(r, c) => (r, c),
        }
    }
}

/// A constraint relation on an affine expression F.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Relation {
    /// F ≻ 0 (imposed with [`Settings::strict_margin`]).
    PosDef,
    /// F ⪰ 0.
    PosSemiDef,
    /// F ≺ 0 (imposed with [`Settings::strict_margin`]).
    NegDef,
    /// F ⪯ 0.
    NegSemiDef,
    /// F = 0 (any shape).
    Zero,
}

impl Relation {
    fn symbol(&self) -> &'static str {
        match self {
            Relation::PosDef => "≻ 0",
            Relation::PosSemiDef => "⪰ 0",
            Relation::NegDef => "≺ 0",
            Relation::NegSemiDef => "⪯ 0",
            Relation::Zero => "= 0",
        }
    }
}

/// How the problem is rescaled and solved again (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rescale {
    /// One solve with data-based scaling only.
    Never,
    /// Solve again with solution-based scaling when the check fails or accuracy was reduced
    /// (default).
    IfNeeded,
    /// Always solve a second time with solution-based scaling.
    Always,
}

/// Which interior-point method solves the assembled conic program.
///
/// clarabel factors a KKT system whose PSD blocks are dense in the svec dimension d(d+1)/2 and
/// fill in across blocks through shared variables: fast and robust for small problems, but its
/// memory and time grow like the cube of the total svec size. [`Backend::Schur`] is hybsim's
/// own primal–dual method on the Schur complement of the decision variables (as SDPT3, SDPA and
/// CSDP work): memory O(m² + Σ d²) for m scalar variables, so the 20-vehicle platoon (2 380
/// variables, 21 blocks of 78×78) takes megabytes instead of tens of gigabytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backend {
    /// clarabel when the PSD blocks have at most [`AUTO_SCHUR_ROWS`] svec rows in total,
    /// [`Backend::Schur`] above (default).
    Auto,
    /// clarabel's direct method.
    Clarabel,
    /// hybsim's Schur-complement interior-point method.
    Schur,
}

/// The total svec size of the PSD blocks above which [`Backend::Auto`] uses
/// [`Backend::Schur`]: below it clarabel solves in well under a second.
pub const AUTO_SCHUR_ROWS: usize = 1000;

/// Solver settings. Each field has a default; validated by [`Problem::solve`].
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    /// ε in F ⪰ ε I for strict inequalities (units of F). Default 1e-7.
    pub strict_margin: f64,
    /// Relative tolerance of the a-posteriori check: a non-strict constraint holds if
    /// λ_min ≥ −check_tol·(1 + ‖F‖₂). Default 1e-6.
    pub check_tol: f64,
    /// Interior-point tolerances (relative gap and feasibility). Default 1e-9.
    pub solver_tol: f64,
    /// Iteration limit of the interior-point method. Default 200.
    pub max_iter: u32,
    /// Rescaling policy. Default [`Rescale::IfNeeded`].
    pub rescale: Rescale,
    /// Print the solver's iteration log. Default false.
    pub verbose: bool,
    /// Which interior-point method to use. Default [`Backend::Auto`].
    pub backend: Backend,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            strict_margin: 1e-7,
            check_tol: 1e-6,
            solver_tol: 1e-9,
            max_iter: 200,
            rescale: Rescale::IfNeeded,
            verbose: false,
            backend: Backend::Auto,
        }
    }
}

/// Why an LMI problem could not be built or its result not trusted.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum LmiError {
    /// Operand shapes do not fit the operation.
    #[error("shape mismatch in `{op}`: {}×{} and {}×{}", left.0, left.1, right.0, right.1)]
    Shape {
        /// Operation.
        op: &'static str,
        /// Left operand shape.
        left: (usize, usize),
        /// Right operand shape.
        right: (usize, usize),
    },
    /// A square expression was required.
    #[error("expression must be square, found {}×{}", shape.0, shape.1)]
    NotSquare {
        /// Found shape.
        shape: (usize, usize),
    },
    /// A sub-block or entry lies outside the expression.
    #[error("index ({row}, {col}) outside a {}×{} expression", shape.0, shape.1)]
    Index {
        /// Expression shape.
        shape: (usize, usize),
        /// Row bound requested.
        row: usize,
        /// Column bound requested.
        col: usize,
    },
    /// Blocks of a block matrix do not fit together.
    #[error("block matrix: {detail}")]
    BlockLayout {
        /// What does not fit.
        detail: String,
    },
    /// Product of two non-constant expressions.
    #[error("product of two expressions that both contain decision variables is not affine")]
    Nonlinear,
    /// A semidefinite constraint on a non-symmetric expression.
    #[error(
        "constraint `{label}`: the expression is not symmetric (|F − Fᵀ| up to {asymmetry:.2e})"
    )]
    NotSymmetric {
        /// Constraint label.
        label: String,
        /// Largest asymmetry.
        asymmetry: f64,
    },
    /// The objective is not a 1×1 expression.
    #[error("the objective must be a scalar (1×1) expression, found {}×{}", shape.0, shape.1)]
    ObjectiveNotScalar {
        /// Found shape.
        shape: (usize, usize),
    },
    /// Two variables with one name.
    #[error("variable `{name}` is already defined")]
    DuplicateVariable {
        /// The name.
        name: String,
    },
    /// A variable of size zero or a non-finite constant.
    #[error("invalid input: {detail}")]
    Invalid {
        /// What.
        detail: String,
    },
    /// A setting is out of range.
    #[error("setting `{field}` = {value} is out of range")]
    BadSetting {
        /// Field name.
        field: &'static str,
        /// Value given.
        value: f64,
    },
    /// clarabel rejected the data.
    #[error("clarabel rejected the problem: {0}")]
    Solver(String),
    /// The solver reported a solution but a constraint does not hold at it.
    #[error(
        "the solver reported {status:?} but constraint `{}` does not hold at the returned point (λ = {:.3e}, ‖F‖ = {:.3e}); not a design",
        worst.label, worst.min_eig, worst.norm
    )]
    Unverified {
        /// Solver status.
        status: SolverStatus,
        /// The worst constraint.
        worst: ConstraintCheck,
    },
}

/// The interior-point method's termination (clarabel's statuses; the Schur backend uses the same).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SolverStatus {
    /// Solved to full accuracy.
    Solved,
    /// Solved to reduced accuracy.
    AlmostSolved,
    /// Certificate of primal infeasibility.
    PrimalInfeasible,
    /// Reduced-accuracy certificate of primal infeasibility.
    AlmostPrimalInfeasible,
    /// Certificate of dual infeasibility (unbounded objective).
    DualInfeasible,
    /// Reduced-accuracy certificate of dual infeasibility.
    AlmostDualInfeasible,
    /// Iteration limit reached.
    MaxIterations,
    /// Time limit reached.
    MaxTime,
    /// Numerical error in the solver.
    NumericalError,
    /// No progress.
    InsufficientProgress,
    /// Anything else clarabel may report.
    Other,
}

/// The result of a solve.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    /// A design whose constraints were verified at the returned point.
    Solved(Design),
    /// The constraints cannot be satisfied (solver certificate).
    Infeasible(SolveInfo),
    /// The objective is unbounded on the feasible set (solver certificate).
    Unbounded(SolveInfo),
    /// The solver stopped without a solution or certificate (numerical failure, limits).
    Failed(SolveInfo),
}

/// Solver statistics common to all outcomes.
#[derive(Debug, Clone, PartialEq)]
pub struct SolveInfo {
    /// Final status of the last solve.
    pub status: SolverStatus,
    /// Wall time of all solver calls (s), excluding assembly.
    pub solve_time: f64,
    /// Wall time including assembly and checks (s).
    pub total_time: f64,
    /// Interior-point iterations (all passes).
    pub iterations: u32,
    /// Primal residual reported by the solver (scaled problem).
    pub primal_residual: f64,
    /// Dual residual reported by the solver (scaled problem).
    pub dual_residual: f64,
    /// The interior-point method that ran ([`Backend::Clarabel`] or [`Backend::Schur`]).
    pub backend: Backend,
    /// Number of solves (2 when rescaled).
    pub passes: u32,
    /// Number of scalar decision variables.
    pub variables: usize,
    /// Number of rows of the conic constraint (svec entries and scalar rows).
    pub cone_rows: usize,
    /// Nonzeros of the conic constraint matrix.
    pub nonzeros: usize,
}

/// A verified solution.
#[derive(Debug, Clone, PartialEq)]
pub struct Design {
    /// Objective value in user units (0 for feasibility problems).
    pub objective: f64,
    /// Variable values by name.
    pub values: HashMap<String, DMatrix<f64>>,
    /// Per-constraint check at the returned point.
    pub checks: Vec<ConstraintCheck>,
    /// Smallest relative margin over all constraints: min λ_min(F)/(1 + ‖F‖₂) with F oriented so
    /// that the constraint reads F ⪰ 0 (≥ −check_tol means it holds).
    pub worst_margin: f64,
    /// Solver statistics.
    pub info: SolveInfo,
}

impl Design {
    /// Value of a variable by name.
    pub fn value(&self, name: &str) -> Option<&DMatrix<f64>> {
        self.values.get(name)
    }
}

/// The a-posteriori check of one constraint at the returned point.
#[derive(Debug, Clone, PartialEq)]
pub struct ConstraintCheck {
    /// Constraint label.
    pub label: String,
    /// Relation imposed.
    pub relation: Relation,
    /// λ_min of the oriented expression (−F for ≺/⪯); for `= 0` minus the largest |entry|.
    pub min_eig: f64,
    /// ‖F‖₂ at the point (largest |eigenvalue|, or largest |entry| for `= 0`).
    pub norm: f64,
    /// Whether it holds within the tolerance (strict: λ_min > 0).
    pub holds: bool,
}

/// A decision variable as registered in a problem.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct VarInfo {
    pub name: String,
    pub kind: VarKind,
    pub offset: usize,
}

pub(crate) struct Constraint {
    pub label: String,
    pub relation: Relation,
    /// Oriented expression G: the constraint reads G ⪰ 0 (or G = 0); strict margin not included.
    pub expr: Expr,
}

/// An LMI problem: variables, constraints, objective.
#[derive(Default)]
pub struct Problem {
    pub(crate) vars: Vec<VarInfo>,
    pub(crate) n_scalars: usize,
    pub(crate) constraints: Vec<Constraint>,
    /// (coefficients as a 1×1 expression, sign: +1 minimize, −1 maximize)
    pub(crate) objective: Option<(Expr, f64)>,
    pub(crate) settings: Settings,
}

impl Problem {
    /// An empty problem with default [`Settings`].
    pub fn new() -> Self {
        Self::default()
    }

    /// Replaces the settings (by value).
    pub fn with_settings(mut self, settings: Settings) -> Self {
        self.settings = settings;
        self
    }

    /// Mutable access to the settings.
    pub fn settings_mut(&mut self) -> &mut Settings {
        &mut self.settings
    }

    /// Creates a decision variable and returns it as an expression.
    pub fn add_variable(&mut self, name: &str, kind: VarKind) -> Result<Expr, LmiError> {
        if self.vars.iter().any(|v| v.name == name) {
            return Err(LmiError::DuplicateVariable { name: name.into() });
        }
        if kind.count() == 0 {
            return Err(LmiError::Invalid {
                detail: format!("variable `{name}` has size zero"),
            });
        }
        let offset = self.n_scalars;
        self.vars.push(VarInfo {
            name: name.into(),
            kind,
            offset,
        });
        self.n_scalars += kind.count();
        Ok(self.var_expr(self.vars.len() - 1))
    }

    /// The expression of a variable created earlier, by name.
    pub fn var(&self, name: &str) -> Option<Expr> {
        self.vars
            .iter()
            .position(|v| v.name == name)
            .map(|i| self.var_expr(i))
    }

    /// Number of scalar decision variables so far.
    pub fn num_scalars(&self) -> usize {
        self.n_scalars
    }

    fn var_expr(&self, i: usize) -> Expr {
        let v = &self.vars[i];
        let (r, c) = v.kind.shape();
        let mut terms = Vec::with_capacity(r * c);
        match v.kind {
            VarKind::Scalar => terms.push(Term {
                row: 0,
                col: 0,
                var: v.offset,
                coef: 1.0,
            }),
            VarKind::Symmetric(n) => {
                let mut k = v.offset;
                for col in 0..n {
                    for row in 0..=col {
                        terms.push(Term {
                            row,
                            col,
                            var: k,
                            coef: 1.0,
                        });
                        if row != col {
                            terms.push(Term {
                                row: col,
                                col: row,
                                var: k,
                                coef: 1.0,
                            });
                        }
                        k += 1;
                    }
                }
            }
            VarKind::Full(r, c) => {
                for col in 0..c {
                    for row in 0..r {
                        terms.push(Term {
                            row,
                            col,
                            var: v.offset + row + r * col,
                            coef: 1.0,
                        });
                    }
                }
            }
        }
        let symmetric = !matches!(v.kind, VarKind::Full(..));
        let whole = factor::Factor::whole(i, r, c, symmetric);
        Expr::from_terms(r, c, terms, Some(vec![whole])).canonical()
    }

    /// Adds the constraint `expr relation` (e.g. F ⪰ 0). Semidefinite relations need a square,
    /// symmetric expression (relative asymmetry ≤ 1e-12); `Zero` accepts any shape.
    pub fn constrain(
        &mut self,
        label: &str,
        expr: &Expr,
        relation: Relation,
    ) -> Result<(), LmiError> {
        if expr.constant.iter().any(|v| !v.is_finite())
            || expr.terms.iter().any(|t| !t.coef.is_finite())
        {
            return Err(LmiError::Invalid {
                detail: format!("constraint `{label}` has a non-finite entry"),
            });
        }
        if expr.shape().0 == 0 || expr.shape().1 == 0 {
            return Err(LmiError::Invalid {
                detail: format!(
                    "constraint `{label}` is empty ({}×{}): it constrains nothing",
                    expr.shape().0,
                    expr.shape().1
                ),
            });
        }
        if expr.terms.iter().any(|t| t.var >= self.n_scalars) {
            return Err(LmiError::Invalid {
                detail: format!("constraint `{label}` uses a variable of another problem"),
            });
        }
        if relation != Relation::Zero {
            let (r, c) = expr.shape();
            if r != c {
                return Err(LmiError::NotSquare { shape: (r, c) });
            }
            let asym = expr.asymmetry();
            if asym > 1e-12 * expr.magnitude().max(f64::MIN_POSITIVE) {
                return Err(LmiError::NotSymmetric {
                    label: label.into(),
                    asymmetry: asym,
                });
            }
        }
        let oriented = match relation {
            Relation::NegDef | Relation::NegSemiDef => expr.neg(),
            _ => expr.clone(),
        };
        // Exact symmetry of the stored data.
        let oriented = if relation == Relation::Zero {
            oriented
        } else {
            oriented.sym()?
        };
        let mut oriented = oriented;
        oriented.factors = if relation == Relation::Zero {
            None
        } else {
            self.verified_structure(&oriented)
        };
        self.constraints.push(Constraint {
            label: label.into(),
            relation,
            expr: oriented,
        });
        Ok(())
    }

    /// The Kronecker structure of a constraint's expression in its fewest terms, if it is known,
    /// fits this problem's variables and reproduces the sparse terms at a generic point (a
    /// safeguard: the sparse terms are the definition, the structure only a faster route).
    fn verified_structure(&self, expr: &Expr) -> Option<Vec<factor::Factor>> {
        let fs = expr.factors.clone()?;
        for f in &fs {
            let v = self.vars.get(f.var)?;
            let (r, c) = v.kind.shape();
            let (pre, post) = if f.transposed { (c, r) } else { (r, c) };
            if f.l.ncols() != pre || f.r.ncols() != post || f.l.nrows() != expr.shape().0 {
                return None;
            }
        }
        let fs = factor::compress(fs);
        // A point with no special structure (Weyl sequence in [-1, 1]).
        let x: Vec<f64> = (0..self.n_scalars)
            .map(|s| ((s as f64 * 0.618_033_988_749_895 + 0.1).fract()) * 2.0 - 1.0)
            .collect();
        let sparse = expr.eval(&x) - &expr.constant;
        let mut structured = DMatrix::zeros(sparse.nrows(), sparse.ncols());
        for f in &fs {
            let xv = self.var_value(f.var, &x);
            let xv = if f.transposed { xv.transpose() } else { xv };
            structured += &f.l * xv * f.r.transpose();
        }
        let scale = sparse.amax().max(structured.amax()).max(f64::MIN_POSITIVE);
        ((sparse - structured).amax() <= 1e-9 * scale).then_some(fs)
    }

    /// The matrix value of variable `i` at the scalar values `x`.
    pub(crate) fn var_value(&self, i: usize, x: &[f64]) -> DMatrix<f64> {
        let v = &self.vars[i];
        let (r, c) = v.kind.shape();
        let mut m = DMatrix::zeros(r, c);
        let mut k = v.offset;
        match v.kind {
            VarKind::Scalar => m[(0, 0)] = x[k],
            VarKind::Symmetric(n) => {
                for col in 0..n {
                    for row in 0..=col {
                        m[(row, col)] = x[k];
                        m[(col, row)] = x[k];
                        k += 1;
                    }
                }
            }
            VarKind::Full(..) => m.copy_from_slice(&x[k..k + r * c]),
        }
        m
    }

    /// Convenience: `lhs ⪰ rhs` etc. as `constrain(lhs − rhs, relation)`.
    pub fn constrain_between(
        &mut self,
        label: &str,
        lhs: &Expr,
        rhs: &Expr,
        relation: Relation,
    ) -> Result<(), LmiError> {
        self.constrain(label, &lhs.sub(rhs)?, relation)
    }

    /// Minimize a scalar (1×1) expression.
    pub fn minimize(&mut self, objective: &Expr) -> Result<(), LmiError> {
        self.set_objective(objective, 1.0)
    }

    /// Maximize a scalar (1×1) expression.
    pub fn maximize(&mut self, objective: &Expr) -> Result<(), LmiError> {
        self.set_objective(objective, -1.0)
    }

    fn set_objective(&mut self, objective: &Expr, sign: f64) -> Result<(), LmiError> {
        if objective.shape() != (1, 1) {
            return Err(LmiError::ObjectiveNotScalar {
                shape: objective.shape(),
            });
        }
        self.objective = Some((objective.clone(), sign));
        Ok(())
    }

    /// Labels and relations of the constraints, in order.
    pub fn constraint_labels(&self) -> Vec<(String, Relation)> {
        self.constraints
            .iter()
            .map(|c| (c.label.clone(), c.relation))
            .collect()
    }

    /// A one-line description: variables, constraints and their sizes.
    pub fn summary(&self) -> String {
        let blocks: Vec<String> = self
            .constraints
            .iter()
            .map(|c| {
                format!(
                    "{}×{} {}",
                    c.expr.shape().0,
                    c.expr.shape().1,
                    c.relation.symbol()
                )
            })
            .collect();
        format!(
            "{} scalar variables in {} matrices; {} constraints [{}]",
            self.n_scalars,
            self.vars.len(),
            self.constraints.len(),
            blocks.join(", ")
        )
    }
}
