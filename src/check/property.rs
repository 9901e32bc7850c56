//! Checking `property` declarations: names, shapes, constants, rule names,
//! and `post(…)` inside `at jumps`; every expression is lowered into the
//! model's scalar graph.
//!
//! Property expressions see a larger frame than the model's: with `n` state
//! components, `State(k)` for `k < n` is the (pre-jump) state, `State(n)` is
//! the jump counter `j`, and `State(n + 1 + k)` is component `k` of the
//! post-jump state (only reachable through `post(…)`).

use std::collections::HashMap;

use super::dag::{Dag, Node, NodeId};
use super::error::CheckError;
use super::expr::{Ctx, Val, dims_words, key_label, suggest};
use super::rule_names::RuleNames;
use super::{Checker, Sym};
use crate::source::Span;
use crate::syntax::ast::{Expr, Item, PropertyBody, PropertyDecl, Target};

/// A checked property.
#[derive(Debug, Clone)]
pub struct CheckedProperty {
    /// Its name.
    pub name: String,
    /// The whole declaration.
    pub span: Span,
    /// The body (what must hold), for reports.
    pub body_span: Span,
    /// What must hold, lowered into the graph.
    pub kind: PropertyKind,
}

/// What a checked property requires; nodes use the property frame (see
/// the module docs).
#[derive(Debug, Clone)]
pub enum PropertyKind {
    /// `always P`.
    Always(NodeId),
    /// `during flows P`.
    DuringFlows(NodeId),
    /// `after E always P`.
    AlwaysAfter {
        /// E.
        enter: NodeId,
        /// P.
        pred: NodeId,
    },
    /// `at jumps [RULE] P`.
    AtJumps {
        /// Index of the rule, if one is named.
        rule: Option<usize>,
        /// The predicate (may read post-jump values).
        pred: NodeId,
    },
    /// `eventually within T P`.
    EventuallyWithin {
        /// T.
        within: f64,
        /// P.
        pred: NodeId,
    },
    /// `decreasing`/`nonincreasing V during flows`/`at jumps` `tol ε`.
    Monotone {
        /// `decreasing` (else `nonincreasing`).
        decreasing: bool,
        /// Across jumps (else along flows).
        jumps: bool,
        /// V.
        v: NodeId,
        /// ε.
        tol: f64,
    },
    /// `exponential V kappa κ alpha α tol ε`.
    Exponential {
        /// `|x|_A`.
        v: NodeId,
        /// κ.
        kappa: f64,
        /// α.
        alpha: f64,
        /// ε.
        tol: f64,
    },
}

const PROP_CTX: Ctx = Ctx {
    random: false,
    wiener: false,
    place: "a property",
};

/// Checks the model-level `property` declarations of `items`; `rules` are
/// the jump rules' names and `dim` the state dimension. Errors go to `c`.
pub(crate) fn check_properties(
    c: &mut Checker,
    items: &[Item],
    rules: &RuleNames,
    dim: usize,
) -> Vec<CheckedProperty> {
    // `j` (the jump counter) is visible in properties unless the model
    // declares its own `j`.
    let j_added = !c.syms.contains_key("j");
    if j_added {
        let val = Val::scalar(c.dag.state(dim));
        c.syms.insert(
            "j".into(),
            Sym::Output {
                val: val.into(),
                span: Span::default(),
            },
        );
    }
    let mut seen: HashMap<String, Span> = HashMap::new();
    let mut out = Vec::new();
    for it in items {
        match it {
            Item::Property(p) => {
                if let Some(&first) = seen.get(&p.name.name) {
                    c.err(CheckError::Duplicate {
                        name: p.name.name.clone(),
                        span: p.name.span,
                        first,
                    });
                    continue;
                }
                seen.insert(p.name.name.clone(), p.name.span);
                if let Some(kind) = property(c, p, rules, dim) {
                    out.push(CheckedProperty {
                        name: p.name.name.clone(),
                        span: p.span,
                        body_span: p.body_span,
                        kind,
                    });
                }
            }
            Item::For(_, inner) => nested(c, inner),
            _ => {}
        }
    }
    if j_added {
        c.syms.remove("j");
    }
    out
}

/// Properties inside `for` loops are not supported.
fn nested(c: &mut Checker, items: &[Item]) {
    for it in items {
        match it {
            Item::Property(p) => c.err(CheckError::Unsupported {
                what: "properties inside `for` loops (declare them at model level)".into(),
                span: p.name.span,
            }),
            Item::For(_, inner) | Item::Together(inner, _) => nested(c, inner),
            _ => {}
        }
    }
}

fn property(
    c: &mut Checker,
    p: &PropertyDecl,
    rules: &RuleNames,
    dim: usize,
) -> Option<PropertyKind> {
    Some(match &p.body {
        PropertyBody::Always(e) => PropertyKind::Always(predicate(c, e, dim, false)?),
        PropertyBody::DuringFlows(e) => PropertyKind::DuringFlows(predicate(c, e, dim, false)?),
        PropertyBody::AlwaysAfter { enter, pred } => {
            let enter = predicate(c, enter, dim, false);
            let pred = predicate(c, pred, dim, false);
            PropertyKind::AlwaysAfter {
                enter: enter?,
                pred: pred?,
            }
        }
        PropertyBody::AtJumps { rule, pred } => {
            let rule = match rule {
                Some(t) => Some(rule_index(c, t, rules)?),
                None => None,
            };
            PropertyKind::AtJumps {
                rule,
                pred: predicate(c, pred, dim, true)?,
            }
        }
        PropertyBody::EventuallyWithin { within, pred } => {
            let pred = predicate(c, pred, dim, false);
            let within = constant(c, within, "the deadline of `eventually within`", 0.0)?;
            PropertyKind::EventuallyWithin {
                within,
                pred: pred?,
            }
        }
        PropertyBody::Monotone {
            decreasing,
            jumps,
            v,
            tol,
        } => {
            let v = scalar(c, v, dim);
            let tol = tolerance(c, tol.as_ref())?;
            PropertyKind::Monotone {
                decreasing: *decreasing,
                jumps: *jumps,
                v: v?,
                tol,
            }
        }
        PropertyBody::Exponential {
            v,
            kappa,
            alpha,
            tol,
        } => {
            let v = scalar(c, v, dim);
            let kappa = constant(c, kappa, "`kappa`", 0.0);
            let alpha = constant(c, alpha, "`alpha`", f64::NEG_INFINITY);
            let tol = tolerance(c, tol.as_ref())?;
            PropertyKind::Exponential {
                v: v?,
                kappa: kappa?,
                alpha: alpha?,
                tol,
            }
        }
    })
}

/// A constant scalar `≥ min`, finite.
fn constant(c: &mut Checker, e: &Expr, what: &str, min: f64) -> Option<f64> {
    let x = c.const_scalar(e, what)?;
    if x.is_finite() && x >= min {
        Some(x)
    } else {
        let expected = if min == 0.0 {
            format!("a finite number ≥ 0 for {what}")
        } else {
            format!("a finite number for {what}")
        };
        c.err(CheckError::Expected {
            expected,
            found: x.to_string(),
            span: e.span,
        });
        None
    }
}

fn tolerance(c: &mut Checker, e: Option<&Expr>) -> Option<f64> {
    match e {
        Some(e) => constant(c, e, "the tolerance `tol`", 0.0),
        None => Some(0.0),
    }
}

fn rule_index(c: &mut Checker, t: &Target, rules: &RuleNames) -> Option<usize> {
    let base = t.name.name.as_str();
    let index = match t.indices.first() {
        None => None,
        Some(args) => Some(key_label(&c.family_key(args)?)),
    };
    let name = match &index {
        Some(i) => format!("{base}[{i}]"),
        None => base.to_string(),
    };
    if let Some(k) = rules.get(&name) {
        return Some(k);
    }
    if rules.is_failed(&name) {
        return None;
    }
    let hints = c.hints.charge(rules.names().len());
    let error = rules.not_found(base, index, t.span, |name| {
        hints.then(|| suggest(name, rules.names())).flatten()
    });
    c.err(error);
    None
}

/// A scalar condition.
fn predicate(c: &mut Checker, e: &Expr, dim: usize, post: bool) -> Option<NodeId> {
    let v = lower(c, e, dim, post)?;
    if v.rows * v.cols != 1 || !v.boolean {
        let found = if v.rows * v.cols != 1 {
            dims_words(v.dims())
        } else {
            "a number".to_string()
        };
        c.err(CheckError::Expected {
            expected: "a condition such as `h >= 0` (one true/false value)".into(),
            found,
            span: e.span,
        });
        return None;
    }
    Some(v.e[0])
}

/// A scalar value V.
fn scalar(c: &mut Checker, e: &Expr, dim: usize) -> Option<NodeId> {
    let v = lower(c, e, dim, false)?;
    if v.rows * v.cols != 1 {
        c.err(CheckError::Expected {
            expected: "a scalar (e.g. `norm(x)` or `x' * P * x`)".into(),
            found: dims_words(v.dims()),
            span: e.span,
        });
        return None;
    }
    Some(v.e[0])
}

/// Lowers `e`; `post(…)` is allowed in it if `post` (see
/// [`Checker::post_call`]).
fn lower(c: &mut Checker, e: &Expr, dim: usize, post: bool) -> Option<Val> {
    c.post_frame = post.then_some(dim);
    let v = c.expr(e, &PROP_CTX);
    c.post_frame = None;
    v
}

impl Checker {
    /// `post(a)` in an `at jumps` property: `a` evaluated on the post-jump
    /// state. It is elaborated where it stands, so it may use loop indices
    /// (`sum(k in 1..N: post(x[k]))`); nested `post` is an error.
    pub(crate) fn post_call(&mut self, args: &[Expr], span: Span, ctx: &Ctx) -> Option<Val> {
        let Some(dim) = self.post_frame else {
            self.err(CheckError::Expected {
                expected: "`post(…)` only in `at jumps` properties (and not nested)".into(),
                found: "`post`".into(),
                span,
            });
            return None;
        };
        if args.len() != 1 {
            self.err(CheckError::Arity {
                func: "post".into(),
                expected: "1 argument".into(),
                found: args.len(),
                span,
            });
            return None;
        }
        self.post_frame = None;
        let v = self.expr(&args[0], ctx);
        self.post_frame = Some(dim);
        let v = v?;
        let mut memo = HashMap::new();
        let e =
            v.e.iter()
                .map(|&n| to_post(&mut self.dag, n, dim, &mut memo))
                .collect();
        Some(Val { e, ..v })
    }
}

/// `n` with every state component `x[k]` (k < dim) replaced by its
/// post-jump value `State(dim + 1 + k)`.
fn to_post(dag: &mut Dag, n: NodeId, dim: usize, memo: &mut HashMap<NodeId, NodeId>) -> NodeId {
    if let Some(&r) = memo.get(&n) {
        return r;
    }
    let r = match dag.node(n) {
        Node::State(k) if (k as usize) < dim => dag.state(dim + 1 + k as usize),
        Node::BlockOut(b, k) => {
            let block = dag.block(b).clone();
            let inputs: Vec<NodeId> = block
                .inputs
                .iter()
                .map(|&i| to_post(dag, i, dim, memo))
                .collect();
            match dag.add_block(block.kind, inputs, block.origin) {
                Ok(outs) => outs[k as usize],
                // Constant inputs were folded when first built.
                Err(_) => n,
            }
        }
        // Other leaves and draws stay as they are.
        _ => dag
            .map_inputs(n, &mut |dag, c| to_post(dag, c, dim, memo))
            .unwrap_or(n),
    };
    memo.insert(n, r);
    r
}
