//! Analyses on the scalar graph: continuous guards from conditions, affine
//! structure of the flow, timers, and the split of a noisy flow into drift
//! and diffusion.

use std::collections::HashMap;

use crate::check::dag::{BinFn, Dag, Node, NodeId, UnFn};
use crate::engine::{Cmp, SetExpr};

/// A continuous function that is ≥ 0 where the condition `cond` holds (on
/// its side of the boundary): `a <= b` → `b − a`, `a >= b` → `a − b`,
/// `&&` → min, `||` → max, `!` → negation; other conditions → ±1.
pub(crate) fn guard_of(dag: &mut Dag, cond: NodeId) -> NodeId {
    match dag.node(cond) {
        Node::Bin(f @ (BinFn::Le | BinFn::Lt | BinFn::Ge | BinFn::Gt), a, b) => {
            if matches!(f, BinFn::Le | BinFn::Lt) {
                dag.bin(BinFn::Sub, b, a)
            } else {
                dag.bin(BinFn::Sub, a, b)
            }
        }
        Node::Bin(BinFn::And, p, q) => {
            let (gp, gq) = (guard_of(dag, p), guard_of(dag, q));
            dag.bin(BinFn::Min, gp, gq)
        }
        Node::Bin(BinFn::Or, p, q) => {
            let (gp, gq) = (guard_of(dag, p), guard_of(dag, q));
            dag.bin(BinFn::Max, gp, gq)
        }
        Node::Un(UnFn::Not, p) => {
            let g = guard_of(dag, p);
            dag.un(UnFn::Neg, g)
        }
        Node::Bin(BinFn::Eq, a, b) => {
            let d = dag.bin(BinFn::Sub, a, b);
            let ad = dag.un(UnFn::Abs, d);
            dag.un(UnFn::Neg, ad)
        }
        Node::Bin(BinFn::Ne, a, b) => {
            let d = dag.bin(BinFn::Sub, a, b);
            dag.un(UnFn::Abs, d)
        }
        _ => {
            let one = dag.konst(1.0);
            let minus = dag.konst(-1.0);
            dag.select(cond, one, minus)
        }
    }
}

/// A condition as atoms `g ⋈ 0` (negations pushed into the comparisons)
/// combined by `and`/`or`; `nodes[k]` is the DAG node of atom `k`'s `g`.
pub(crate) struct CondAtoms {
    pub atoms: Vec<(Cmp, NodeId)>,
    pub expr: SetExpr,
}

/// The atoms of condition `cond` in negation normal form: `a ⋈ b` becomes
/// `a − b ⋈ 0`, `!` flips a comparison (`<` ↔ `>=`, `==` ↔ `!=`), `if c
/// then p else q` becomes `(c && p) || (!c && q)`, and any other
/// expression `e` used as a condition is the atom `e != 0`. Comparisons
/// whose `a − b` folds to a constant become constants.
pub(crate) fn atoms_of(dag: &mut Dag, cond: NodeId) -> CondAtoms {
    let mut out = CondAtoms {
        atoms: Vec::new(),
        expr: SetExpr::Const(true),
    };
    out.expr = nnf(dag, cond, false, &mut out.atoms);
    out
}

fn nnf(dag: &mut Dag, cond: NodeId, neg: bool, atoms: &mut Vec<(Cmp, NodeId)>) -> SetExpr {
    let cmp_of = |f: BinFn| match f {
        BinFn::Lt => Some(Cmp::Lt),
        BinFn::Le => Some(Cmp::Le),
        BinFn::Gt => Some(Cmp::Gt),
        BinFn::Ge => Some(Cmp::Ge),
        BinFn::Eq => Some(Cmp::Eq),
        BinFn::Ne => Some(Cmp::Ne),
        _ => None,
    };
    let flip = |c: Cmp| match c {
        Cmp::Lt => Cmp::Ge,
        Cmp::Le => Cmp::Gt,
        Cmp::Gt => Cmp::Le,
        Cmp::Ge => Cmp::Lt,
        Cmp::Eq => Cmp::Ne,
        Cmp::Ne => Cmp::Eq,
    };
    let mut atom = |dag: &mut Dag, cmp: Cmp, g: NodeId| {
        let cmp = if neg { flip(cmp) } else { cmp };
        if let Some(c) = dag.as_const(g) {
            return SetExpr::Const(cmp.holds(c));
        }
        let k = match atoms.iter().position(|&a| a == (cmp, g)) {
            Some(k) => k,
            None => {
                atoms.push((cmp, g));
                atoms.len() - 1
            }
        };
        SetExpr::Atom(k)
    };
    match dag.node(cond) {
        Node::Bin(f, a, b) if cmp_of(f).is_some() => {
            let g = dag.bin(BinFn::Sub, a, b);
            atom(dag, cmp_of(f).expect("a comparison"), g)
        }
        Node::Bin(f @ (BinFn::And | BinFn::Or), p, q) => {
            let (p, q) = (nnf(dag, p, neg, atoms), nnf(dag, q, neg, atoms));
            if (f == BinFn::And) != neg {
                SetExpr::And(vec![p, q])
            } else {
                SetExpr::Or(vec![p, q])
            }
        }
        Node::Un(UnFn::Not, p) => nnf(dag, p, !neg, atoms),
        Node::Select(c, p, q) => {
            let (c_t, c_f) = (nnf(dag, c, false, atoms), nnf(dag, c, true, atoms));
            let (p, q) = (nnf(dag, p, neg, atoms), nnf(dag, q, neg, atoms));
            SetExpr::Or(vec![SetExpr::And(vec![c_t, p]), SetExpr::And(vec![c_f, q])])
        }
        Node::Const(b) => SetExpr::Const((f64::from_bits(b) != 0.0) != neg),
        _ => atom(dag, Cmp::Ne, cond),
    }
}

/// The threshold of a timer atom found by [`timer_atom`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum TimerThreshold {
    /// A constant.
    Const(f64),
    /// A node that does not vary along flows (of parameters, the jump
    /// count and states whose flow is identically zero: `d[q]`).
    Node(NodeId),
}

/// Atom `g ⋈ 0` as a timer atom if it is one: `⋈` is an inequality
/// (`<`, `<=`, `>`, `>=`) and `g` is `±x[k] + h` (sums and differences of
/// one such state and terms that do not vary along flows (`varies`), in
/// any order) for a state `k` with `timers[k]` (a constant nonzero rate
/// along every flow). Returns the atom written as `x[k] − θ ⋈' 0` (the
/// comparison flipped with the sign: the same set up to the rounding of
/// `g`), with `k` and `θ` (a constant where `h` is one): at `x[k] = θ` its
/// `g` is exactly zero.
pub(crate) fn timer_atom(
    dag: &mut Dag,
    cmp: Cmp,
    g: NodeId,
    timers: &[bool],
    varies: &[bool],
) -> Option<(Cmp, NodeId, usize, TimerThreshold)> {
    if !matches!(cmp, Cmp::Le | Cmp::Ge | Cmp::Lt | Cmp::Gt) {
        return None;
    }
    let (k, sign, threshold) = match one_state_sum(dag, g, 0) {
        Some((Some(k), sign, offset)) if timers.get(k) == Some(&true) => {
            // `+ 0.0`: a zero threshold is +0 (the timer is set to it, and shown).
            let threshold = -sign * offset + 0.0;
            if !threshold.is_finite() {
                return None;
            }
            (k, sign, TimerThreshold::Const(threshold))
        }
        Some(_) => return None,
        None => {
            let mut terms = Vec::new();
            let (k, sign) = one_state_and_still(dag, g, 1.0, varies, &mut terms, 0)??;
            if timers.get(k) != Some(&true) {
                return None;
            }
            // θ = −sign · Σ (term signs · terms), in the order written.
            let mut theta = dag.konst(0.0);
            for (t, s) in terms {
                let f = if s * sign < 0.0 {
                    BinFn::Add
                } else {
                    BinFn::Sub
                };
                theta = dag.bin(f, theta, t);
            }
            (k, sign, TimerThreshold::Node(theta))
        }
    };
    let cmp = match (sign > 0.0, cmp) {
        (true, c) => c,
        (false, Cmp::Le) => Cmp::Ge,
        (false, Cmp::Ge) => Cmp::Le,
        (false, Cmp::Lt) => Cmp::Gt,
        (false, _) => Cmp::Lt,
    };
    let x = dag.state(k);
    let c = match threshold {
        TimerThreshold::Const(c) => dag.konst(c),
        TimerThreshold::Node(n) => n,
    };
    Some((cmp, dag.bin(BinFn::Sub, x, c), k, threshold))
}

/// `n` (times `sign`) as `s·x[k] + Σ sᵢ·hᵢ` with `hᵢ` nodes that do not
/// vary along flows (pushed to `terms` with their signs `sᵢ`): `Some(Some((k,
/// s)))` if `n` is a sum or difference of exactly one varying state and
/// such terms, `Some(None)` if `n` is such a term itself, `None` otherwise;
/// `depth` bounds the recursion.
fn one_state_and_still(
    dag: &Dag,
    n: NodeId,
    sign: f64,
    varies: &[bool],
    terms: &mut Vec<(NodeId, f64)>,
    depth: u32,
) -> Option<Option<(usize, f64)>> {
    if depth > 16 {
        return None;
    }
    if !varies.get(n as usize).copied().unwrap_or(true) {
        terms.push((n, sign));
        return Some(None);
    }
    match dag.node(n) {
        Node::State(k) => Some(Some((k as usize, sign))),
        Node::Un(UnFn::Neg, a) => one_state_and_still(dag, a, -sign, varies, terms, depth + 1),
        Node::Bin(f @ (BinFn::Add | BinFn::Sub), a, b) => {
            let sb = if f == BinFn::Sub { -sign } else { sign };
            let ka = one_state_and_still(dag, a, sign, varies, terms, depth + 1)?;
            let kb = one_state_and_still(dag, b, sb, varies, terms, depth + 1)?;
            match (ka, kb) {
                (Some(_), Some(_)) => None,
                (k, None) | (None, k) => Some(k),
            }
        }
        _ => None,
    }
}

/// `n` as `sign · x[k] + offset` (`sign` ±1, `k` `None` for a constant) if
/// it is a sum or difference of at most one state and constants; `depth`
/// bounds the recursion.
fn one_state_sum(dag: &Dag, n: NodeId, depth: u32) -> Option<(Option<usize>, f64, f64)> {
    if depth > 16 {
        return None;
    }
    if let Some(c) = dag.as_const(n) {
        return Some((None, 1.0, c));
    }
    let both = |a, b, minus: bool| {
        let (ka, sa, oa) = one_state_sum(dag, a, depth + 1)?;
        let (kb, sb, ob) = one_state_sum(dag, b, depth + 1)?;
        let m = if minus { -1.0 } else { 1.0 };
        match (ka, kb) {
            (Some(_), Some(_)) => None,
            (Some(k), None) => Some((Some(k), sa, oa + m * ob)),
            (None, Some(k)) => Some((Some(k), m * sb, oa + m * ob)),
            (None, None) => Some((None, 1.0, oa + m * ob)),
        }
    };
    match dag.node(n) {
        Node::State(k) => Some((Some(k as usize), 1.0, 0.0)),
        Node::Un(UnFn::Neg, a) => {
            let (k, s, o) = one_state_sum(dag, a, depth + 1)?;
            Some((k, -s, -o))
        }
        Node::Bin(BinFn::Add, a, b) => both(a, b, false),
        Node::Bin(BinFn::Sub, a, b) => both(a, b, true),
        _ => None,
    }
}

/// Which nodes of a graph can change along a flow: time (not the jump
/// count), noise, random draws, states not in `still` (the states whose
/// flow is identically zero), and everything computed from them. Kept up to
/// date as the graph grows ([`Varying::of`] looks only at the nodes added
/// since its last call), so the sets of a model with thousands of rules
/// cost one pass over the graph, not one per set.
pub(crate) struct Varying {
    still: Vec<bool>,
    v: Vec<bool>,
}

impl Varying {
    pub(crate) fn new(still: Vec<bool>) -> Self {
        Self {
            still,
            v: Vec::new(),
        }
    }

    /// Whether each node of `dag` (the graph this was used with, grown
    /// since: nodes are only appended, after their inputs) varies.
    pub(crate) fn of(&mut self, dag: &Dag) -> &[bool] {
        for id in self.v.len()..dag.len() {
            let v = &self.v;
            let varies = match dag.node(id as NodeId) {
                // The jump count is constant along a flow.
                Node::Const(_) | Node::Jumps => false,
                Node::State(k) => !self.still.get(k as usize).copied().unwrap_or(false),
                Node::Time | Node::Wiener(_) | Node::Rand(..) => true,
                Node::Un(_, a) => v[a as usize],
                Node::Bin(_, a, b) => v[a as usize] || v[b as usize],
                Node::Select(c, a, b) => v[c as usize] || v[a as usize] || v[b as usize],
                Node::BlockOut(b, _) => dag.block(b).inputs.iter().any(|&i| v[i as usize]),
                // A table entry varies only if its index does (whether it
                // is needed does not change its value).
                Node::Lookup { row, col, .. } => v[row as usize] || v[col as usize],
                Node::Interp { x, .. } => v[x as usize],
            };
            self.v.push(varies);
        }
        &self.v
    }
}

/// An affine form Σ cᵢ xᵢ + c₀ (sorted by state index).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Lin {
    pub terms: Vec<(u32, f64)>,
    pub c: f64,
}

impl Lin {
    fn scale(&self, s: f64) -> Lin {
        Lin {
            terms: self.terms.iter().map(|&(k, v)| (k, v * s)).collect(),
            c: self.c * s,
        }
    }
    fn add(&self, o: &Lin, s: f64) -> Lin {
        let mut terms = Vec::with_capacity(self.terms.len() + o.terms.len());
        let (mut i, mut j) = (0, 0);
        while i < self.terms.len() || j < o.terms.len() {
            match (self.terms.get(i), o.terms.get(j)) {
                (Some(&(a, va)), Some(&(b, vb))) if a == b => {
                    terms.push((a, va + s * vb));
                    i += 1;
                    j += 1;
                }
                (Some(&(a, va)), Some(&(b, _))) if a < b => {
                    terms.push((a, va));
                    i += 1;
                }
                (Some(&(a, va)), None) => {
                    terms.push((a, va));
                    i += 1;
                }
                (_, Some(&(b, vb))) => {
                    terms.push((b, s * vb));
                    j += 1;
                }
                (None, None) => break,
            }
        }
        Lin {
            terms,
            c: self.c + s * o.c,
        }
    }
    fn constant(&self) -> Option<f64> {
        self.terms.is_empty().then_some(self.c)
    }
}

/// The variables of an affine analysis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Vars {
    /// The state components; only numbers are coefficients (time, noise
    /// and every other leaf make a form non-affine).
    State,
    /// The white-noise components; any expression free of noise (states,
    /// time, functions of them) is a coefficient, of unknown value (`c` and
    /// the term coefficients of such forms are NaN).
    Wiener,
}

/// The affine forms of `roots` in the state, or `None` if any is not affine
/// (or depends on time or noise).
pub(crate) fn affine_forms(dag: &Dag, roots: &[NodeId]) -> Option<Vec<Lin>> {
    affine_in(dag, roots, Vars::State).into_iter().collect()
}

/// The affine form of each root in `vars` (`None` for a root that is not
/// affine in them).
pub(crate) fn affine_in(dag: &Dag, roots: &[NodeId], vars: Vars) -> Vec<Option<Lin>> {
    let reach = dag.reachable(roots);
    // By node id (a node's inputs come before it): the forms are read where they are, cloned
    // only into the roots' answers.
    let mut lin: Vec<Option<Lin>> = vec![None; dag.len()];
    // For `Vars::Wiener`: nodes that depend on no noise component.
    let mut free = vec![false; if vars == Vars::Wiener { dag.len() } else { 0 }];
    for id in 0..dag.len() as NodeId {
        if !reach[id as usize] {
            continue;
        }
        if vars == Vars::Wiener {
            let node = dag.node(id);
            let f = |x: NodeId| free[x as usize];
            let is_free = match node {
                Node::Wiener(_) => false,
                Node::Un(_, a) => f(a),
                Node::Bin(_, a, b) => f(a) && f(b),
                Node::Select(c, a, b) => f(c) && f(a) && f(b),
                Node::BlockOut(b, _) => dag.block(b).inputs.iter().all(|&i| f(i)),
                Node::Rand(_, a, b, _) => f(a) && f(b),
                Node::Lookup { row, col, when, .. } => f(row) && f(col) && f(when),
                Node::Interp { x, .. } => f(x),
                Node::Const(_) | Node::State(_) | Node::Time | Node::Jumps => true,
            };
            free[id as usize] = is_free;
            if is_free && !matches!(node, Node::Const(_)) {
                lin[id as usize] = Some(Lin {
                    terms: Vec::new(),
                    c: f64::NAN,
                });
                continue;
            }
        }
        let get = |x: NodeId| lin[x as usize].as_ref();
        let l = match dag.node(id) {
            Node::Const(b) => Some(Lin {
                terms: Vec::new(),
                c: f64::from_bits(b),
            }),
            Node::State(k) if vars == Vars::State => Some(Lin {
                terms: vec![(k, 1.0)],
                c: 0.0,
            }),
            Node::Wiener(k) if vars == Vars::Wiener => Some(Lin {
                terms: vec![(k, 1.0)],
                c: 0.0,
            }),
            Node::Un(UnFn::Neg, a) => get(a).map(|l| l.scale(-1.0)),
            Node::Bin(BinFn::Add, a, b) => match (get(a), get(b)) {
                (Some(x), Some(y)) => Some(x.add(y, 1.0)),
                _ => None,
            },
            Node::Bin(BinFn::Sub, a, b) => match (get(a), get(b)) {
                (Some(x), Some(y)) => Some(x.add(y, -1.0)),
                _ => None,
            },
            Node::Bin(BinFn::Mul, a, b) => match (get(a), get(b)) {
                (Some(x), Some(y)) => match (x.constant(), y.constant()) {
                    (Some(c), _) => Some(y.scale(c)),
                    (_, Some(c)) => Some(x.scale(c)),
                    _ => None,
                },
                _ => None,
            },
            Node::Bin(BinFn::Div, a, b) => match (get(a), get(b)) {
                (Some(x), Some(y)) => y.constant().map(|c| x.scale(1.0 / c)),
                _ => None,
            },
            _ => None,
        };
        lin[id as usize] = l;
    }
    roots.iter().map(|&r| lin[r as usize].clone()).collect()
}

/// An affine form `Σ cᵢ xᵢ + c₀` in the moving states whose coefficients are
/// nodes of the graph: expressions of constants and still states (modes).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ModeLin {
    pub terms: Vec<(u32, NodeId)>,
    pub c: NodeId,
}

/// Coefficients kept by [`affine_in_modes`] before it gives up (a dense
/// switched system of 2000 states would make 4·10⁶ coefficient nodes).
const MAX_MODE_TERMS: usize = 1 << 16;

/// The flow `roots` as affine forms in the states that move (`still[k]`
/// false) with coefficients that are functions of the still ones — modes,
/// counters, held values — and constants: `ẋ = A(q) x + b(q)`, constant
/// along each flow. `if c then p else q` with a condition `c` on the modes
/// selects between the forms of `p` and `q` coefficient by coefficient.
/// `None` if a root is not such a form (time, noise, the jump count, a
/// product of moving states, ...). The coefficient nodes are added to `dag`.
pub(crate) fn affine_in_modes(
    dag: &mut Dag,
    roots: &[NodeId],
    still: &[bool],
) -> Option<Vec<ModeLin>> {
    let reach = dag.reachable(roots);
    let len = reach.len();
    // Nodes that are constant along a flow: built from constants and still states.
    let mut fixed = vec![false; len];
    let mut lin: Vec<Option<ModeLin>> = vec![None; len];
    let (zero, one) = (dag.konst(0.0), dag.konst(1.0));
    let mut kept = 0usize;
    for id in 0..len as NodeId {
        if !reach[id as usize] {
            continue;
        }
        let node = dag.node(id);
        let is_fixed = {
            let f = |x: NodeId| fixed[x as usize];
            match node {
                Node::Const(_) => true,
                Node::State(k) => still.get(k as usize).copied().unwrap_or(false),
                Node::Un(_, a) => f(a),
                Node::Bin(_, a, b) => f(a) && f(b),
                Node::Select(c, a, b) => f(c) && f(a) && f(b),
                Node::BlockOut(b, _) => dag.block(b).inputs.iter().all(|&i| f(i)),
                Node::Lookup { row, col, when, .. } => f(row) && f(col) && f(when),
                Node::Interp { x, .. } => f(x),
                Node::Time | Node::Jumps | Node::Wiener(_) | Node::Rand(..) => false,
            }
        };
        fixed[id as usize] = is_fixed;
        let f = |x: NodeId| fixed[x as usize];
        if is_fixed {
            lin[id as usize] = Some(ModeLin {
                terms: Vec::new(),
                c: id,
            });
            continue;
        }
        let get = |x: NodeId| lin[x as usize].clone();
        let l = match node {
            Node::State(k) => Some(ModeLin {
                terms: vec![(k, one)],
                c: zero,
            }),
            Node::Un(UnFn::Neg, a) => {
                get(a).map(|l| map_coefficients(dag, &l, |d, c| d.un(UnFn::Neg, c)))
            }
            Node::Bin(f @ (BinFn::Add | BinFn::Sub), a, b) => match (get(a), get(b)) {
                (Some(x), Some(y)) => Some(merge(dag, &x, &y, |d, p, q| {
                    d.bin(f, p.unwrap_or(zero), q.unwrap_or(zero))
                })),
                _ => None,
            },
            Node::Bin(BinFn::Mul, a, b) => match (f(a), f(b)) {
                (true, _) => {
                    get(b).map(|l| map_coefficients(dag, &l, |d, c| d.bin(BinFn::Mul, a, c)))
                }
                (_, true) => {
                    get(a).map(|l| map_coefficients(dag, &l, |d, c| d.bin(BinFn::Mul, c, b)))
                }
                _ => None,
            },
            Node::Bin(BinFn::Div, a, b) if f(b) => {
                get(a).map(|l| map_coefficients(dag, &l, |d, c| d.bin(BinFn::Div, c, b)))
            }
            Node::Select(c, a, b) if f(c) => match (get(a), get(b)) {
                (Some(x), Some(y)) => Some(merge(dag, &x, &y, |d, p, q| {
                    d.select(c, p.unwrap_or(zero), q.unwrap_or(zero))
                })),
                _ => None,
            },
            _ => None,
        };
        let l = l?;
        kept += l.terms.len() + 1;
        if kept > MAX_MODE_TERMS {
            return None;
        }
        lin[id as usize] = Some(l);
    }
    roots.iter().map(|&r| lin[r as usize].clone()).collect()
}

/// `l` with `op` applied to each coefficient (the constant included).
fn map_coefficients(
    dag: &mut Dag,
    l: &ModeLin,
    mut op: impl FnMut(&mut Dag, NodeId) -> NodeId,
) -> ModeLin {
    ModeLin {
        terms: l.terms.iter().map(|&(k, c)| (k, op(dag, c))).collect(),
        c: op(dag, l.c),
    }
}

/// The form whose coefficient of each state is `op` of the two forms'
/// coefficients of it (`None` where a form has no such term).
fn merge(
    dag: &mut Dag,
    x: &ModeLin,
    y: &ModeLin,
    mut op: impl FnMut(&mut Dag, Option<NodeId>, Option<NodeId>) -> NodeId,
) -> ModeLin {
    let mut terms = Vec::with_capacity(x.terms.len() + y.terms.len());
    let (mut i, mut j) = (0, 0);
    while i < x.terms.len() || j < y.terms.len() {
        let (k, p, q) = match (x.terms.get(i), y.terms.get(j)) {
            (Some(&(a, p)), Some(&(b, q))) if a == b => {
                i += 1;
                j += 1;
                (a, Some(p), Some(q))
            }
            (Some(&(a, p)), Some(&(b, _))) if a < b => {
                i += 1;
                (a, Some(p), None)
            }
            (Some(&(a, p)), None) => {
                i += 1;
                (a, Some(p), None)
            }
            (_, Some(&(b, q))) => {
                j += 1;
                (b, None, Some(q))
            }
            (None, None) => break,
        };
        terms.push((k, op(dag, p, q)));
    }
    let c = op(dag, Some(x.c), Some(y.c));
    ModeLin { terms, c }
}

/// Which nodes depend on a white-noise component (by node id; a node's
/// inputs come before it).
pub(crate) fn on_wiener(dag: &Dag) -> Vec<bool> {
    let mut on = Vec::with_capacity(dag.len());
    for id in 0..dag.len() as NodeId {
        let mut v = matches!(dag.node(id), Node::Wiener(_));
        dag.inputs(id, |i| v |= on[i as usize]);
        on.push(v);
    }
    on
}

/// Rebuilds `root` with white-noise components replaced by constants
/// (`w[k] = value(k)`), folding as it goes. `noisy` is [`on_wiener`] of the
/// graph: a node free of noise is its own rebuild (the graph's constructors
/// return a node they made when given its inputs again), so it is kept
/// without visiting it.
pub(crate) fn substitute_wiener(
    dag: &mut Dag,
    root: NodeId,
    value: &dyn Fn(u32) -> f64,
    noisy: &[bool],
    memo: &mut HashMap<NodeId, NodeId>,
) -> NodeId {
    if !noisy[root as usize] {
        return root;
    }
    if let Some(&r) = memo.get(&root) {
        return r;
    }
    let r = match dag.node(root) {
        Node::Wiener(k) => dag.konst(value(k)),
        // Leaves, draws and block outputs (matrix operations, never on
        // noise) stay as they are.
        _ => dag
            .map_inputs(root, &mut |dag, c| {
                substitute_wiener(dag, c, value, noisy, memo)
            })
            .unwrap_or(root),
    };
    memo.insert(root, r);
    r
}
