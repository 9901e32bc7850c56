//! The exact Jacobian ∂f/∂x of a compiled flow, derived symbolically from
//! the scalar graph by forward-mode differentiation: for each state x_c,
//! the tangent of every node through which x_c reaches the flow's outputs
//! (its cone) is built as new nodes of the same graph (hash-consed and
//! folded, so terms that do not depend on x_c vanish and shared
//! subexpressions stay shared), in the graph's topological order. The
//! nonzero entries, with their sparsity pattern, are then compiled into one
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
//! Jacobian: the engine then takes finite differences on its structural
//! pattern (which states reach which outputs through differentiable
//! operations), by groups of columns.

// Node ids and states index several arrays at once.
#![allow(clippy::needless_range_loop)]

use crate::check::dag::{BinFn, Dag, Node, NodeId, UnFn};
use crate::engine::SparsityPattern;

/// Largest work (Σ over states of the nodes whose derivative in that state
/// can be nonzero) spent on the symbolic derivative: beyond it the
/// derivative is left to finite differences (compile time stays bounded).
const BUDGET: u64 = 4_000_000;

/// Largest work spent on the structural pattern alone (no new nodes).
const PATTERN_BUDGET: u64 = 50_000_000;

/// The structure of ∂f/∂x for flow outputs `roots` (one per row) over
/// states `0..n`.
pub(crate) struct Derivative {
    /// The entries that can be nonzero.
    pub pattern: SparsityPattern,
    /// The node of each of `pattern`'s entries, in its order (added to the
    /// graph); `None` if the flow reaches a matrix block of the state or
    /// the work would exceed the budget.
    pub nodes: Option<Vec<NodeId>>,
}

/// Whether the derivative flows from input `i` into node `id` (the rules of
/// [`tangent`]: piecewise-constant functions, conditions, table indices and
/// draws carry none; a block's outputs depend on all its inputs).
fn carries(dag: &Dag, id: NodeId, mut f: impl FnMut(NodeId)) {
    use BinFn::*;
    match dag.node(id) {
        Node::Un(UnFn::Sign | UnFn::Floor | UnFn::Ceil | UnFn::Round | UnFn::Not, _) => {}
        Node::Un(_, a) => f(a),
        Node::Bin(Lt | Le | Gt | Ge | Eq | Ne | And | Or, ..) => {}
        Node::Bin(_, a, b) => {
            f(a);
            f(b);
        }
        Node::Select(_, a, b) => {
            f(a);
            f(b);
        }
        Node::Interp {
            x, slope: false, ..
        } => f(x),
        Node::BlockOut(..) => dag.inputs(id, f),
        Node::Interp { slope: true, .. }
        | Node::Lookup { .. }
        | Node::Rand(..)
        | Node::Const(_)
        | Node::State(_)
        | Node::Time
        | Node::Jumps
        | Node::Wiener(_) => {}
    }
}

/// ∂f/∂x of the flow outputs `roots` (row r: `roots[r]`) over states
/// `0..n`: its pattern from the nodes through which each state reaches
/// each output (the state's *cone*), and, unless a block or the budget
/// prevents it, its entries as new nodes of `dag`, derived in forward mode
/// over each state's cone only, so that a family model (each state in a
/// few outputs) costs in proportion to its nonzeros, not to n².
/// `None` if even the pattern exceeds its budget.
pub(crate) fn derivative(dag: &mut Dag, roots: &[NodeId], n: usize) -> Option<Derivative> {
    let reach = dag.reachable(roots);
    let len = dag.len();
    // Consumers along derivative-carrying edges, CSR over node ids.
    let mut ptr = vec![0usize; len + 1];
    let mut state_node = vec![None; n];
    for id in 0..len {
        if !reach[id] {
            continue;
        }
        if let Node::State(k) = dag.node(id as NodeId)
            && (k as usize) < n
        {
            state_node[k as usize] = Some(id as NodeId);
        }
        carries(dag, id as NodeId, |i| ptr[i as usize + 1] += 1);
    }
    for i in 0..len {
        ptr[i + 1] += ptr[i];
    }
    let mut fill = ptr.clone();
    let mut consumers = vec![0 as NodeId; ptr[len]];
    for id in 0..len {
        if reach[id] {
            carries(dag, id as NodeId, |i| {
                consumers[fill[i as usize]] = id as NodeId;
                fill[i as usize] += 1;
            });
        }
    }
    // Rows of each root node (several rows may share one node).
    let mut rows_of: Vec<Vec<usize>> = vec![Vec::new(); len];
    for (r, &root) in roots.iter().enumerate() {
        rows_of[root as usize].push(r);
    }
    // Each state's cone, in topological (id) order.
    let mut stamp = vec![usize::MAX; len];
    let mut cones: Vec<Vec<NodeId>> = Vec::with_capacity(n);
    let mut work: u64 = 0;
    let mut blocks = false;
    let mut stack = Vec::new();
    for c in 0..n {
        let mut cone = Vec::new();
        if let Some(s) = state_node[c] {
            stack.push(s);
            stamp[s as usize] = c;
            while let Some(id) = stack.pop() {
                cone.push(id);
                for &k in &consumers[ptr[id as usize]..ptr[id as usize + 1]] {
                    if stamp[k as usize] != c {
                        stamp[k as usize] = c;
                        stack.push(k);
                    }
                }
            }
            cone.sort_unstable();
        }
        work += cone.len() as u64;
        if work > PATTERN_BUDGET {
            return None;
        }
        blocks |= cone
            .iter()
            .any(|&id| matches!(dag.node(id), Node::BlockOut(..)));
        cones.push(cone);
    }
    let rows_of = &rows_of;
    let structural = || {
        SparsityPattern::new(
            n,
            cones.iter().enumerate().flat_map(|(c, cone)| {
                cone.iter()
                    .flat_map(move |&id| rows_of[id as usize].iter().map(move |&r| (r, c)))
            }),
        )
        .expect("rows and states are in range")
    };
    if blocks || work > BUDGET {
        return Some(Derivative {
            pattern: structural(),
            nodes: None,
        });
    }
    let zero = dag.konst(0.0);
    let mut tan = vec![zero; len];
    let mut entries: Vec<(usize, usize, NodeId)> = Vec::new();
    for (c, cone) in cones.iter().enumerate() {
        for &id in cone {
            tan[id as usize] = tangent(dag, id, c as u32, &tan, zero);
        }
        for &id in cone {
            let t = tan[id as usize];
            if t != zero {
                entries.extend(rows_of[id as usize].iter().map(|&r| (r, c, t)));
            }
        }
        for &id in cone {
            tan[id as usize] = zero;
        }
    }
    // Column by column, rows ascending: the pattern's order.
    entries.sort_unstable_by_key(|&(r, c, _)| (c, r));
    let pattern = SparsityPattern::new(n, entries.iter().map(|&(r, c, _)| (r, c)))
        .expect("rows and states are in range");
    Some(Derivative {
        pattern,
        nodes: Some(entries.into_iter().map(|(_, _, t)| t).collect()),
    })
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
                UnFn::Asin | UnFn::Acos => {
                    // ±1 / √(1 − a²)
                    let sq = dag.bin(Mul, a, a);
                    let one = dag.konst(1.0);
                    let rest = dag.bin(Sub, one, sq);
                    let den = dag.un(UnFn::Sqrt, rest);
                    let d = dag.bin(Div, da, den);
                    return if f == UnFn::Asin {
                        d
                    } else {
                        dag.un(UnFn::Neg, d)
                    };
                }
                UnFn::Sinh => dag.un(UnFn::Cosh, a),
                UnFn::Cosh => dag.un(UnFn::Sinh, a),
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
