//! Reuse of lowered statement values inside `for` loops.
//!
//! A statement in a loop body is lowered once per member, but its value
//! often reads only some of the loop variables: in
//! `for i in 1..N { jump flash[i] … { for k in out(G, i) { tau[k]+ = f(tau[k]) } } }`
//! the value `f(tau[k])` is the same graph for every `i`. Lowering it again
//! costs a hash-consing lookup per node and finds nothing new, so a family
//! with N² resets took N² times the lowering of one. [`Checker::expr_reused`]
//! lowers such a value once per distinct value of the loop variables it
//! reads and hands out the same nodes afterwards.
//!
//! It is exact: only values made of numbers, loop variables, parameters,
//! states, family members and operators (no calls: no random draws, no
//! metric reductions, no run-time table lookups) are reused; lowering
//! those again with the same loop variables interns exactly the nodes it
//! interned the first time (so the graph, its node ids and the compiled
//! programs are unchanged) and reports no error the first lowering did not
//! report. The work the first lowering was charged is charged again, so the
//! resource budget ([`super::limits`]) counts as before; near the budget
//! the value is lowered again (to fail where it did).

use rustc_hash::FxHashMap;
use smallvec::SmallVec;
use std::rc::Rc;

use super::expr::{Ctx, Val};
use super::limits::Quantity;
use super::{Checker, Sym};
use crate::syntax::ast::{Expr, ExprKind, IndexArg};

/// Where an expression is: its address and span. Both are needed: the
/// loop's statements stay in place while the loop runs (the cache lives
/// only that long), and an expression allocated at a freed address has
/// another span unless it is a copy of the same source expression.
type At = (usize, usize, usize);

/// The cache of one outermost `for` loop (see the module documentation).
#[derive(Default)]
pub(crate) struct Reuse {
    /// Per expression: the loop variables it reads, or `None` if its
    /// value is not reusable.
    reads: FxHashMap<At, Option<Rc<[Rc<str>]>>>,
    /// Per expression, context and values of those variables: the value
    /// and the work its lowering was charged.
    values: FxHashMap<(At, bool, bool, SmallVec<[i64; 4]>), (Val, u64)>,
    /// Values handed out again (for tests).
    pub(crate) hits: u64,
}

impl Checker {
    /// Lowers the value `e` of a statement like [`Checker::expr`], reusing
    /// an earlier lowering in the same loop when `e` reads the same loop
    /// variable values (see the module documentation).
    pub(crate) fn expr_reused(&mut self, e: &Expr, ctx: &Ctx) -> Option<Val> {
        // Conditions under which lowering has effects beyond the returned
        // nodes: a path condition (run-time lookups depend on it), the
        // frames of metrics and properties, poisoned names (they record the
        // failed block).
        if self.reuse.is_none()
            || self.path.is_some()
            || self.metric_frame.is_some()
            || self.post_frame.is_some()
            || !self.poisoned.is_empty()
        {
            return self.expr(e, ctx);
        }
        let at: At = (std::ptr::from_ref(e) as usize, e.span.start, e.span.end);
        let reads = match self.reuse.as_ref().and_then(|r| r.reads.get(&at)) {
            Some(reads) => reads.clone(),
            None => {
                let mut vars = Vec::new();
                let reads = self.reusable(e, &mut vars).then(|| Rc::from(vars));
                if let Some(r) = self.reuse.as_mut() {
                    r.reads.insert(at, reads.clone());
                }
                reads
            }
        };
        let Some(reads) = reads else {
            return self.expr(e, ctx);
        };
        let values: SmallVec<[i64; 4]> = reads
            .iter()
            .map(|v| self.scope_lookup(v).unwrap_or(i64::MIN))
            .collect();
        let key = (at, ctx.random, ctx.wiener, values);
        if let Some((val, ops)) = self.reuse.as_ref().and_then(|r| r.values.get(&key)) {
            let (val, ops) = (val.clone(), *ops);
            if self.dag.ops().saturating_add(ops) <= self.limits.get(Quantity::Ops) {
                self.dag.charge(ops);
                if let Some(r) = self.reuse.as_mut() {
                    r.hits += 1;
                }
                return Some(val);
            }
            return self.expr(e, ctx);
        }
        let (ops, errors) = (self.dag.ops(), self.errors.len());
        let val = self.expr(e, ctx)?;
        if self.errors.len() == errors
            && let Some(r) = self.reuse.as_mut()
        {
            r.values.insert(key, (val.clone(), self.dag.ops() - ops));
        }
        Some(val)
    }

    /// True if the value of `e` is reusable; appends the loop variables it
    /// reads to `vars` (each once).
    fn reusable(&self, e: &Expr, vars: &mut Vec<Rc<str>>) -> bool {
        match &e.kind {
            ExprKind::Num(_) | ExprKind::Bool(_) => true,
            ExprKind::Name(n) => {
                if let Some((v, _)) = self.scopes.iter().rev().find(|(v, _)| **v == **n) {
                    if !vars.iter().any(|w| w == v) {
                        vars.push(Rc::clone(v));
                    }
                    return true;
                }
                !self.is_signal(n)
                    && matches!(
                        self.syms.get(n.as_str()),
                        Some(Sym::Param { .. } | Sym::State { .. })
                    )
            }
            ExprKind::Unary(_, a) => self.reusable(a, vars),
            ExprKind::Binary(_, a, b) => self.reusable(a, vars) && self.reusable(b, vars),
            ExprKind::If(c, a, b) => {
                self.reusable(c, vars) && self.reusable(a, vars) && self.reusable(b, vars)
            }
            // A member of a parameter or state family, `tau[k]`.
            ExprKind::Index(base, args) => {
                let ExprKind::Name(n) = &base.kind else {
                    return false;
                };
                !self.scopes.iter().any(|(v, _)| **v == **n)
                    && !self.is_signal(n)
                    && matches!(
                        self.syms.get(n.as_str()),
                        Some(Sym::ParamFamily { .. } | Sym::StateFamily { .. })
                    )
                    && args.iter().all(|a| match a {
                        IndexArg::One(x) => self.reusable(x, vars),
                        _ => false,
                    })
            }
            _ => false,
        }
    }
}
