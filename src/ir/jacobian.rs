//! The exact Jacobian ∂f/∂x of a compiled flow, derived symbolically from
//! the scalar graph by forward-mode differentiation: for each state x_c,
//! the tangent of every node reachable from the flow's outputs is built as
//! new nodes of the same graph (hash-consed and folded, so terms that do
//! not depend on x_c vanish and shared subexpressions stay shared), in the
//! graph's topological order. The n×n entries are then compiled into one
//! register program, like the flow map.
//!
//! Functions that are piecewise constant (comparisons, logic, `sign`,
//! `floor`, `ceil`, `round`) have derivative 0, as their finite
//! differences away from their jumps; `abs`, `min`, `max`, `mod`, `rem`
//! and `if … then … else` take the derivative of the active branch; a
//! run-time table entry `tk[k]` has derivative 0 in its index, `interp`
//! the slope of its segment (0 where clamped). A flow
//! that reaches a matrix block (`inv`, `solve`, `expm`, `norm2`) of the
//! state, or whose derivative would exceed a size budget, has no symbolic
//! Jacobian: the engine then uses finite differences.

use crate::check::dag::{BinFn, Dag, Node, NodeId, UnFn};

/// Largest (flow graph nodes × states) worked through: beyond it the
/// derivative is left to finite differences (compile time stays bounded).
const BUDGET: u64 = 4_000_000;

/// The nodes of ∂f_r/∂x_c (row-major, `roots.len()` × `n`) for the flow
/// outputs `roots` over states `0..n`, added to `dag`; `None` if the flow
/// reaches a matrix block of the state or the work would exceed the budget.
pub(crate) fn derivative_nodes(dag: &mut Dag, roots: &[NodeId], n: usize) -> Option<Vec<NodeId>> {
    let reach = dag.reachable(roots);
    let order: Vec<NodeId> = reach
        .iter()
        .enumerate()
        .filter(|&(_, &r)| r)
        .map(|(i, _)| i as NodeId)
        .collect();
    if (order.len() as u64).saturating_mul(n as u64) > BUDGET {
        return None;
    }
    // Which nodes depend on the state at all (ids are topological).
    let mut dep = vec![false; dag.len()];
    for &id in &order {
        let d = match dag.node(id) {
            Node::State(_) => true,
            _ => {
                let mut any = false;
                dag.inputs(id, |i| any |= dep[i as usize]);
                any
            }
        };
        if d && matches!(dag.node(id), Node::BlockOut(..)) {
            return None;
        }
        dep[id as usize] = d;
    }
    let zero = dag.konst(0.0);
    let mut jac = vec![zero; roots.len() * n];
    let mut tan = vec![zero; dag.len()];
    for c in 0..n {
        for &id in &order {
            tan[id as usize] = if dep[id as usize] {
                tangent(dag, id, c as u32, &tan, zero)
            } else {
                zero
            };
        }
        for (r, &root) in roots.iter().enumerate() {
            jac[r * n + c] = tan[root as usize];
        }
    }
    Some(jac)
}

/// The tangent of node `id` with respect to x_c, from its inputs' tangents.
fn tangent(dag: &mut Dag, id: NodeId, c: u32, tan: &[NodeId], zero: NodeId) -> NodeId {
    use BinFn::*;
    let t = |i: NodeId| tan[i as usize];
    match dag.node(id) {
        Node::State(k) => {
            if k == c {
                dag.konst(1.0)
            } else {
                zero
            }
        }
        Node::Const(_) | Node::Time | Node::Jumps | Node::Wiener(_) | Node::Rand(..) => zero,
        // Excluded by the caller.
        Node::BlockOut(..) => zero,
        // Piecewise constant in its indices; a slope is constant per segment.
        Node::Lookup { .. } | Node::Interp { slope: true, .. } => zero,
        Node::Interp { table, x, .. } => {
            let dx = t(x);
            if dx == zero {
                return zero;
            }
            let s = dag.interp(table, x, true);
            dag.bin(Mul, dx, s)
        }
        Node::Select(cond, a, b) => {
            let (da, db) = (t(a), t(b));
            dag.select(cond, da, db)
        }
        Node::Un(f, a) => {
            let da = t(a);
            if da == zero {
                return zero;
            }
            let factor = match f {
                UnFn::Neg => return dag.un(UnFn::Neg, da),
                UnFn::Abs => dag.un(UnFn::Sign, a),
                UnFn::Sqrt => {
                    // 1 / (2 √a)
                    let two = dag.konst(2.0);
                    let den = dag.bin(Mul, two, id);
                    return dag.bin(Div, da, den);
                }
                UnFn::Exp => id,
                UnFn::Log => return dag.bin(Div, da, a),
                UnFn::Sin => dag.un(UnFn::Cos, a),
                UnFn::Cos => {
                    let s = dag.un(UnFn::Sin, a);
                    dag.un(UnFn::Neg, s)
                }
                UnFn::Tan => {
                    // 1 + tan²
                    let sq = dag.bin(Mul, id, id);
                    let one = dag.konst(1.0);
                    dag.bin(Add, one, sq)
                }
                UnFn::Atan => {
                    let sq = dag.bin(Mul, a, a);
                    let one = dag.konst(1.0);
                    let den = dag.bin(Add, one, sq);
                    return dag.bin(Div, da, den);
                }
                UnFn::Tanh => {
                    let sq = dag.bin(Mul, id, id);
                    let one = dag.konst(1.0);
                    dag.bin(Sub, one, sq)
                }
                UnFn::Sign | UnFn::Floor | UnFn::Ceil | UnFn::Round | UnFn::Not => {
                    return zero;
                }
            };
            dag.bin(Mul, factor, da)
        }
        Node::Bin(f, a, b) => {
            let (da, db) = (t(a), t(b));
            if da == zero && db == zero {
                return zero;
            }
            match f {
                Add => dag.bin(Add, da, db),
                Sub => dag.bin(Sub, da, db),
                Mul => {
                    let l = dag.bin(Mul, da, b);
                    let r = dag.bin(Mul, a, db);
                    dag.bin(Add, l, r)
                }
                Div => {
                    // (da − (a/b)·db) / b
                    let q = dag.bin(Mul, id, db);
                    let num = dag.bin(Sub, da, q);
                    dag.bin(Div, num, b)
                }
                Pow => pow_tangent(dag, id, a, b, da, db, zero),
                Min | Max => {
                    let cmp = if f == Min { Le } else { Ge };
                    let cond = dag.bin(cmp, a, b);
                    dag.select(cond, da, db)
                }
                Atan2 => {
                    // atan2(a, b): (b·da − a·db) / (a² + b²)
                    let l = dag.bin(Mul, b, da);
                    let r = dag.bin(Mul, a, db);
                    let num = dag.bin(Sub, l, r);
                    let a2 = dag.bin(Mul, a, a);
                    let b2 = dag.bin(Mul, b, b);
                    let den = dag.bin(Add, a2, b2);
                    dag.bin(Div, num, den)
                }
                Mod | Rem => {
                    // a − b·q with q piecewise constant: da − q·db,
                    // q = (a − result) / b.
                    if db == zero {
                        return da;
                    }
                    let diff = dag.bin(Sub, a, id);
                    let q = dag.bin(Div, diff, b);
                    let qdb = dag.bin(Mul, q, db);
                    dag.bin(Sub, da, qdb)
                }
                Hypot => {
                    let l = dag.bin(Mul, a, da);
                    let r = dag.bin(Mul, b, db);
                    let num = dag.bin(Add, l, r);
                    dag.bin(Div, num, id)
                }
                Lt | Le | Gt | Ge | Eq | Ne | And | Or => zero,
            }
        }
    }
}

/// The tangent of `id = a^b`.
fn pow_tangent(
    dag: &mut Dag,
    id: NodeId,
    a: NodeId,
    b: NodeId,
    da: NodeId,
    db: NodeId,
    zero: NodeId,
) -> NodeId {
    use BinFn::*;
    let mut out = zero;
    if da != zero {
        // b · a^(b−1) · da
        let power = match dag.as_const(b) {
            Some(1.0) => dag.konst(1.0),
            Some(2.0) => a,
            Some(e) => {
                let em1 = dag.konst(e - 1.0);
                dag.bin(Pow, a, em1)
            }
            None => {
                let one = dag.konst(1.0);
                let em1 = dag.bin(Sub, b, one);
                dag.bin(Pow, a, em1)
            }
        };
        let coef = dag.bin(Mul, b, power);
        out = dag.bin(Mul, coef, da);
    }
    if db != zero {
        // a^b · ln a · db
        let ln = dag.un(UnFn::Log, a);
        let term = dag.bin(Mul, id, ln);
        let term = dag.bin(Mul, term, db);
        out = dag.bin(Add, out, term);
    }
    out
}
