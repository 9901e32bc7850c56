//! `design` blocks: their AST and their conversion from pest pairs.
//!
//! ```text
//! design observer {
//!     sym P[n]; full U[n, p]; sym X[k]; diag Delta[p]; scalar g
//!     for i in 1..N { sym Q[i][n] }          # a family of variables: Q[1], …, Q[N]
//!     minimize trace(X)                       # or `maximize e`; none: feasibility
//!     stab: [P, (P - U*C)*A; *, P] > 0        # `*`: the transpose of the mirror block
//!     for S in subsets(1..p) { [P, (P - sum(m in S: U[:, m]*C[m, :]))*A; *, P] > 0 }
//!     param L = inv(P) * U                    # results, evaluated after the solve
//! }
//! ```

use pest::iterators::Pair;

use super::ast::{Binder, Definition, Expr, Ident, Target};
use super::error::SyntaxError;
use super::parse::{Rule, ambiguous_sign, binder, definition, expr, first, ident, target};
use crate::source::Span;

/// A `design` block.
#[derive(Debug, Clone, PartialEq)]
pub struct DesignBlock {
    /// Its name.
    pub name: Ident,
    /// Statements in source order.
    pub stmts: Vec<DesignStmt>,
    /// The whole block.
    pub span: Span,
    /// `check NAME { … }`: a check (no results; its verdict is reported).
    pub check: bool,
}

/// The shape of a decision variable as declared.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VarShape {
    /// `scalar g`.
    Scalar,
    /// `sym P[n]`: symmetric n×n.
    Symmetric,
    /// `full U[r, c]` (or `full v[r]`: r×1).
    Full,
    /// `diag D[n]`: diagonal n×n.
    Diagonal,
}

/// One declared decision variable.
#[derive(Debug, Clone, PartialEq)]
pub struct VarDecl {
    /// Its name.
    pub name: Ident,
    /// The family index of a member of a variable family (`sym P[k][n]`:
    /// `[k]`); empty for a plain variable.
    pub member: Vec<Expr>,
    /// Its size expressions (`[n]`, `[r, c]`).
    pub dims: Vec<Expr>,
    /// The declaration.
    pub span: Span,
}

/// `minimize` or `maximize`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sense {
    /// `minimize e`.
    Minimize,
    /// `maximize e`.
    Maximize,
}

/// The relation of a constraint.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rel {
    /// `>`: positive definite (strictly greater).
    Gt,
    /// `>=`: positive semidefinite (greater or equal).
    Ge,
    /// `<`.
    Lt,
    /// `<=`.
    Le,
    /// `==`: every entry equal.
    Eq,
}

impl Rel {
    /// The relation as written.
    pub fn symbol(self) -> &'static str {
        match self {
            Rel::Gt => ">",
            Rel::Ge => ">=",
            Rel::Lt => "<",
            Rel::Le => "<=",
            Rel::Eq => "==",
        }
    }
}

/// One side of a constraint.
#[derive(Debug, Clone, PartialEq)]
pub enum LmiSide {
    /// A block matrix whose blocks may be `*` (`None`): the transpose of the
    /// block mirrored across the diagonal.
    Blocks(Vec<Vec<Option<Expr>>>, Span),
    /// Any expression.
    Expr(Expr),
}

impl LmiSide {
    /// Where it is written.
    pub fn span(&self) -> Span {
        match self {
            LmiSide::Blocks(_, s) => *s,
            LmiSide::Expr(e) => e.span,
        }
    }
}

/// `label: lhs REL rhs`.
#[derive(Debug, Clone, PartialEq)]
pub struct Constraint {
    /// Optional label (for reports).
    pub label: Option<Ident>,
    /// Left-hand side.
    pub lhs: LmiSide,
    /// The relation.
    pub rel: Rel,
    /// Right-hand side.
    pub rhs: LmiSide,
    /// The whole constraint.
    pub span: Span,
}

/// Statements of a design block.
#[derive(Debug, Clone, PartialEq)]
pub enum DesignStmt {
    /// `sym P[n], X[k]` etc.
    Var(VarShape, Vec<VarDecl>),
    /// `minimize e` / `maximize e`.
    Objective(Sense, Expr, Span),
    /// A (matrix) inequality or equality.
    Constraint(Constraint),
    /// `for m in 1..N { ... }`, `for S in subsets(1..N) { ... }`.
    For(Binder, Vec<DesignStmt>),
    /// `if c { ... }` with a constant condition.
    If(Expr, Vec<DesignStmt>),
    /// `param a = ..., b = ...`: results.
    Param(Vec<Definition>),
    /// `param (K, S) = dlqr(...)`: results of a control function.
    ParamTuple(Vec<Target>, Expr),
}

type Res<T> = Result<T, SyntaxError>;

/// Converts a `design_block` pair.
pub(super) fn design_block(p: Pair<'_, Rule>) -> Res<DesignBlock> {
    let span = super::parse::significant_span(&p);
    let mut inner = p.into_inner().peekable();
    let check = inner.next_if(|q| q.as_rule() == Rule::w_check).is_some();
    let mut inner = inner.collect::<Vec<_>>().into_iter();
    let name = ident(inner.next().ok_or_else(|| super::SyntaxError::Unexpected {
        span,
        found: "an incomplete design block".into(),
        expected: "a name".into(),
    })?);
    let stmts = inner.map(stmt).collect::<Res<_>>()?;
    Ok(DesignBlock {
        name,
        stmts,
        span,
        check,
    })
}

fn stmt(p: Pair<'_, Rule>) -> Res<DesignStmt> {
    let span = super::parse::significant_span(&p);
    let rule = p.as_rule();
    let mut inner = p.into_inner();
    Ok(match rule {
        Rule::design_var => {
            let kind = first(&mut inner, span)?;
            let shape = match kind.as_str() {
                "sym" => VarShape::Symmetric,
                "full" => VarShape::Full,
                "diag" => VarShape::Diagonal,
                _ => VarShape::Scalar,
            };
            let decls = inner
                .map(|d| {
                    let dspan: Span = d.as_span().into();
                    let mut it = d.into_inner();
                    let name = ident(first(&mut it, dspan)?);
                    let mut member = Vec::new();
                    let mut dims = Vec::new();
                    for q in it {
                        if q.as_rule() == Rule::var_member {
                            member = q
                                .into_inner()
                                .filter(|e| e.as_rule() != Rule::member_close)
                                .map(expr)
                                .collect::<Res<_>>()?;
                        } else {
                            dims.push(expr(q)?);
                        }
                    }
                    Ok(VarDecl {
                        name,
                        member,
                        dims,
                        span: dspan,
                    })
                })
                .collect::<Res<_>>()?;
            DesignStmt::Var(shape, decls)
        }
        Rule::design_obj => {
            let sense = match first(&mut inner, span)?.as_str() {
                "minimize" => Sense::Minimize,
                _ => Sense::Maximize,
            };
            DesignStmt::Objective(sense, expr(first(&mut inner, span)?)?, span)
        }
        Rule::design_for => {
            let b = binder(first(&mut inner, span)?)?;
            DesignStmt::For(b, inner.map(stmt).collect::<Res<_>>()?)
        }
        Rule::design_if => {
            let c = expr(first(&mut inner, span)?)?;
            DesignStmt::If(c, inner.map(stmt).collect::<Res<_>>()?)
        }
        Rule::param_decl => DesignStmt::Param(
            inner
                .map(|d| match d.as_rule() {
                    // A design's results are computed from its solution.
                    Rule::param_rand => Err(SyntaxError::Unexpected {
                        span: d.as_span().into(),
                        found: "a random draw".into(),
                        expected: "a result `param NAME = expression` of the design".into(),
                    }),
                    _ => definition(d),
                })
                .collect::<Res<_>>()?,
        ),
        Rule::param_tuple => {
            let mut parts: Vec<Pair<'_, Rule>> = inner.collect();
            let Some(value) = parts.pop() else {
                return Err(SyntaxError::Unexpected {
                    span,
                    found: "this".into(),
                    expected: "a value".into(),
                });
            };
            let targets = parts.into_iter().map(target).collect::<Res<_>>()?;
            DesignStmt::ParamTuple(targets, expr(value)?)
        }
        _ => {
            let mut parts: Vec<Pair<'_, Rule>> = inner.collect();
            let label = match parts.first() {
                Some(l) if l.as_rule() == Rule::cons_label => {
                    let l = parts.remove(0);
                    Some(ident(first(&mut l.into_inner(), span)?))
                }
                _ => None,
            };
            let mut it = parts.into_iter();
            let lhs = side(first_of(&mut it, span)?)?;
            let rel = match first_of(&mut it, span)?.as_str() {
                ">" => Rel::Gt,
                ">=" => Rel::Ge,
                "<" => Rel::Lt,
                "<=" => Rel::Le,
                _ => Rel::Eq,
            };
            let rhs = side(first_of(&mut it, span)?)?;
            DesignStmt::Constraint(Constraint {
                label,
                lhs,
                rel,
                rhs,
                span,
            })
        }
    })
}

fn first_of<'a>(
    it: &mut impl Iterator<Item = Pair<'a, Rule>>,
    parent: Span,
) -> Res<Pair<'a, Rule>> {
    it.next().ok_or_else(|| SyntaxError::Unexpected {
        span: parent,
        found: "an incomplete constraint".into(),
        expected: "`lhs > rhs`".into(),
    })
}

fn side(p: Pair<'_, Rule>) -> Res<LmiSide> {
    let span: Span = p.as_span().into();
    let q = first(&mut p.into_inner(), span)?;
    if q.as_rule() != Rule::lmi_blocks {
        return Ok(LmiSide::Expr(expr(q)?));
    }
    let bspan: Span = q.as_span().into();
    let rows = q
        .into_inner()
        .map(|row| {
            row.into_inner()
                .map(|el| {
                    let espan: Span = el.as_span().into();
                    let e = first(&mut el.into_inner(), espan)?;
                    match e.as_rule() {
                        Rule::lmi_star => Ok(None),
                        _ => {
                            ambiguous_sign(&e)?;
                            expr(e).map(Some)
                        }
                    }
                })
                .collect::<Res<Vec<_>>>()
        })
        .collect::<Res<_>>()?;
    Ok(LmiSide::Blocks(rows, bspan))
}
