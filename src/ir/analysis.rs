//! Analyses on the scalar graph: continuous guards from conditions, affine
//! structure of the flow, timers, and the split of a noisy flow into drift
//! and diffusion.

use std::collections::HashMap;

use crate::check::dag::{BinFn, Dag, Node, NodeId, UnFn};

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
    let mut lin: HashMap<NodeId, Option<Lin>> = HashMap::new();
    // For `Vars::Wiener`: nodes that depend on no noise component.
    let mut free: HashMap<NodeId, bool> = HashMap::new();
    for id in 0..dag.len() as NodeId {
        if !reach[id as usize] {
            continue;
        }
        let get = |x: NodeId, lin: &HashMap<NodeId, Option<Lin>>| lin.get(&x).cloned().flatten();
        if vars == Vars::Wiener {
            let node = dag.node(id);
            let is_free = match node {
                Node::Wiener(_) => false,
                Node::Un(_, a) => free[&a],
                Node::Bin(_, a, b) => free[&a] && free[&b],
                Node::Select(c, a, b) => free[&c] && free[&a] && free[&b],
                Node::BlockOut(b, _) => dag.block(b).inputs.iter().all(|i| free[i]),
                Node::Rand(_, a, b, _) => free[&a] && free[&b],
                Node::Const(_) | Node::State(_) | Node::Time | Node::Jumps => true,
            };
            free.insert(id, is_free);
            if is_free && !matches!(node, Node::Const(_)) {
                lin.insert(
                    id,
                    Some(Lin {
                        terms: Vec::new(),
                        c: f64::NAN,
                    }),
                );
                continue;
            }
        }
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
            Node::Un(UnFn::Neg, a) => get(a, &lin).map(|l| l.scale(-1.0)),
            Node::Bin(BinFn::Add, a, b) => match (get(a, &lin), get(b, &lin)) {
                (Some(x), Some(y)) => Some(x.add(&y, 1.0)),
                _ => None,
            },
            Node::Bin(BinFn::Sub, a, b) => match (get(a, &lin), get(b, &lin)) {
                (Some(x), Some(y)) => Some(x.add(&y, -1.0)),
                _ => None,
            },
            Node::Bin(BinFn::Mul, a, b) => match (get(a, &lin), get(b, &lin)) {
                (Some(x), Some(y)) => match (x.constant(), y.constant()) {
                    (Some(c), _) => Some(y.scale(c)),
                    (_, Some(c)) => Some(x.scale(c)),
                    _ => None,
                },
                _ => None,
            },
            Node::Bin(BinFn::Div, a, b) => match (get(a, &lin), get(b, &lin)) {
                (Some(x), Some(y)) => y.constant().map(|c| x.scale(1.0 / c)),
                _ => None,
            },
            _ => None,
        };
        lin.insert(id, l);
    }
    roots
        .iter()
        .map(|r| lin.get(r).cloned().flatten())
        .collect()
}

/// Rebuilds `root` with white-noise components replaced by constants
/// (`w[k] = value(k)`), folding as it goes.
pub(crate) fn substitute_wiener(
    dag: &mut Dag,
    root: NodeId,
    value: &dyn Fn(u32) -> f64,
    memo: &mut HashMap<NodeId, NodeId>,
) -> NodeId {
    if let Some(&r) = memo.get(&root) {
        return r;
    }
    let r = match dag.node(root) {
        Node::Wiener(k) => dag.konst(value(k)),
        Node::Const(_)
        | Node::State(_)
        | Node::Time
        | Node::Jumps
        | Node::Rand(..)
        | Node::BlockOut(..) => root,
        Node::Un(f, a) => {
            let a = substitute_wiener(dag, a, value, memo);
            dag.un(f, a)
        }
        Node::Bin(f, a, b) => {
            let a = substitute_wiener(dag, a, value, memo);
            let b = substitute_wiener(dag, b, value, memo);
            dag.bin(f, a, b)
        }
        Node::Select(c, a, b) => {
            let c = substitute_wiener(dag, c, value, memo);
            let a = substitute_wiener(dag, a, value, memo);
            let b = substitute_wiener(dag, b, value, memo);
            dag.select(c, a, b)
        }
    };
    memo.insert(root, r);
    r
}
