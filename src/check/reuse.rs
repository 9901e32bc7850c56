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

/// A value's key: where, the context's `random` and `wiener`, and the
/// values of the loop variables it reads.
type Key = (At, bool, bool, SmallVec<[i64; 4]>);

/// The cache of one outermost `for` loop (see the module documentation).
#[derive(Default)]
pub(crate) struct Reuse {
    /// Per expression: the loop variables it reads, or `None` if its
    /// value is not reusable.
    reads: FxHashMap<At, Option<Rc<[Rc<str>]>>>,
    /// Per expression, context and values of those variables: the value
    /// and the work its lowering was charged.
    values: FxHashMap<Key, (Val, u64)>,
}

impl Reuse {
    /// A cache for an outermost loop; `None` when reuse is switched off
    /// (the tests' reference path).
    pub(crate) fn start() -> Option<Self> {
        #[cfg(test)]
        if tests::OFF.get() {
            return None;
        }
        Some(Self::default())
    }
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
        let key: Key = (at, ctx.random, ctx.wiener, values);
        if let Some((val, ops)) = self.reuse.as_ref().and_then(|r| r.values.get(&key)) {
            let (val, ops) = (val.clone(), *ops);
            if self.dag.ops().saturating_add(ops) <= self.limits.get(Quantity::Ops) {
                self.dag.charge(ops);
                #[cfg(test)]
                tests::REUSED.set(tests::REUSED.get() + 1);
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
            #[cfg(test)]
            tests::LOWERED.set(tests::LOWERED.get() + 1);
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

#[cfg(test)]
pub(crate) mod tests {
    use std::cell::Cell;

    use crate::check::{self, CheckedModel};
    use crate::source::SourceFile;

    thread_local! {
        /// Switches reuse off (the reference the tests compare with).
        pub(crate) static OFF: Cell<bool> = const { Cell::new(false) };
        /// Values stored for reuse, and values handed out again.
        pub(crate) static LOWERED: Cell<u64> = const { Cell::new(0) };
        pub(crate) static REUSED: Cell<u64> = const { Cell::new(0) };
    }

    /// Checks `text` with `overrides`, with reuse on or off; returns the
    /// model and (values lowered for reuse, values reused).
    fn checked(text: &str, overrides: &[&str], reuse: bool) -> (CheckedModel, u64, u64) {
        let src = SourceFile::new("m.hyb", text);
        let mut model = crate::syntax::parse_model(src.text()).expect("parses");
        crate::imports::resolve(&src, &mut model).expect("imports");
        crate::tables::resolve(&src, &mut model).expect("tables");
        let overrides: Vec<check::Override> =
            overrides.iter().map(|o| o.parse().unwrap()).collect();
        OFF.set(!reuse);
        LOWERED.set(0);
        REUSED.set(0);
        let m = check::check(&model, &overrides);
        OFF.set(false);
        (m.expect("checks"), LOWERED.get(), REUSED.get())
    }

    /// The same graph, node for node, and the same work charged.
    fn assert_same(a: &CheckedModel, b: &CheckedModel, what: &str) {
        assert_eq!(a.dag.len(), b.dag.len(), "{what}: nodes");
        for id in 0..a.dag.len() as u32 {
            assert_eq!(a.dag.node(id), b.dag.node(id), "{what}: node {id}");
        }
        assert_eq!(a.dag.ops(), b.dag.ops(), "{what}: work charged");
        assert_eq!((&a.init, &a.flow), (&b.init, &b.flow), "{what}: init, flow");
        assert_eq!(a.flow_set, b.flow_set, "{what}: flow set");
        assert_eq!(a.rules, b.rules, "{what}: rules");
        assert_eq!(a.outputs, b.outputs, "{what}: outputs");
    }

    /// Fireflies' N² resets `tau[k]+ = f(tau[k])` read only `k`: their
    /// value is lowered N times, not N² times, and the graph is the one
    /// lowering every reset gives.
    #[test]
    fn family_resets_are_lowered_once_per_member() {
        let text =
            std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/models/fireflies.hyb"))
                .unwrap();
        for n in [7_u64, 20] {
            let set = format!("N={n}");
            let (with, lowered, reused) = checked(&text, &[&set], true);
            let (without, _, none) = checked(&text, &[&set], false);
            assert_same(&with, &without, &set);
            assert_eq!(none, 0);
            // N values of f(tau[k]), the reset `tau[i]+ = 0` and the flow
            // `tau[i]' = 1`; every other statement of the N² + N reuses one.
            assert_eq!(lowered, n + 2, "{set}");
            assert_eq!(reused, n * n + n - lowered, "{set}");
        }
    }

    /// Reuse changes nothing in any shipped model (same graph, same work).
    #[test]
    fn reuse_is_exact_on_the_shipped_models() {
        let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/models");
        let mut seen = 0;
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_none_or(|e| e != "hyb") {
                continue;
            }
            let src = SourceFile::read(&path).unwrap();
            let mut model = crate::syntax::parse_model(src.text()).unwrap();
            crate::imports::resolve(&src, &mut model).unwrap();
            crate::tables::resolve(&src, &mut model).unwrap();
            OFF.set(true);
            let without = check::check(&model, &[]);
            OFF.set(false);
            let with = check::check(&model, &[]);
            let what = path.display().to_string();
            assert_same(&with.expect(&what), &without.expect(&what), &what);
            seen += 1;
        }
        assert!(seen >= 10, "{seen} models");
    }

    /// Values that must not be reused are lowered each time: random draws
    /// (each member its own), and values under a path condition.
    #[test]
    fn draws_are_not_reused() {
        let text = "model m
param N = 4
for i in 1..N {
    state x[i] = 0
    flow { x[i]' = 1 }
}
jump reset when x[1] >= 1 {
    for i in 1..N { x[i]+ = uniform(0, 1) }
}
";
        let (with, _, _) = checked(text, &[], true);
        let (without, _, _) = checked(text, &[], false);
        assert_same(&with, &without, "draws");
        let resets = &with.rules[0].resets;
        let draws: std::collections::BTreeSet<_> = resets.iter().map(|&(_, n)| n).collect();
        assert_eq!(draws.len(), 4, "one draw per member: {resets:?}");
    }
}
