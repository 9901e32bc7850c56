//! The scalar expression graph every checked expression is lowered into.
//!
//! Shapes are static, so matrix expressions become scalar nodes (one per
//! element). Nodes are hash-consed (common subexpressions are shared) and
//! folded when their inputs are constants, so parameters cost nothing at run
//! time and products with sparse constant matrices only keep non-zero terms.
//! Node ids increase in dependency order, which the code generator uses as a
//! topological order. Operations that do not scalarize (matrix inverse,
//! linear solve, matrix exponential, spectral norm) are [`Block`] nodes.

use std::collections::hash_map::Entry;
use std::sync::Arc;

use rustc_hash::FxHashMap as HashMap;

use nalgebra::DMatrix;

/// Index of a node.
pub type NodeId = u32;

/// Unary scalar functions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum UnFn {
    /// −a
    Neg,
    /// |a|
    Abs,
    /// √a
    Sqrt,
    /// eᵃ
    Exp,
    /// ln a
    Log,
    /// sin a
    Sin,
    /// cos a
    Cos,
    /// tan a
    Tan,
    /// atan a
    Atan,
    /// tanh a
    Tanh,
    /// asin a (NaN outside [−1, 1])
    Asin,
    /// acos a (NaN outside [−1, 1])
    Acos,
    /// sinh a
    Sinh,
    /// cosh a
    Cosh,
    /// sign a (−1, 0, 1)
    Sign,
    /// ⌊a⌋
    Floor,
    /// ⌈a⌉
    Ceil,
    /// a rounded to the nearest integer, halves away from zero
    Round,
    /// logical not (1 if a == 0)
    Not,
}

/// Binary scalar functions; comparisons and logic return 1.0 or 0.0.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BinFn {
    /// a + b
    Add,
    /// a − b
    Sub,
    /// a · b
    Mul,
    /// a / b
    Div,
    /// aᵇ
    Pow,
    /// min(a, b)
    Min,
    /// max(a, b)
    Max,
    /// atan2(a, b)
    Atan2,
    /// a mod b (floored: the sign of b)
    Mod,
    /// rem(a, b) = a − b·trunc(a/b) (truncated: the sign of a)
    Rem,
    /// √(a² + b²) without undue overflow or underflow
    Hypot,
    /// a < b
    Lt,
    /// a ≤ b
    Le,
    /// a > b
    Gt,
    /// a ≥ b
    Ge,
    /// a == b
    Eq,
    /// a ≠ b
    Ne,
    /// a ∧ b
    And,
    /// a ∨ b
    Or,
}

/// A distribution of a random draw.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Dist {
    /// uniform(lo, hi)
    Uniform,
    /// normal(mean, std)
    Normal,
    /// bernoulli(p): 1 with probability p, else 0.
    Bernoulli,
}

/// Operations on whole matrices (inputs and outputs row-major).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BlockKind {
    /// inv(A), A n×n.
    Inv {
        /// n
        n: u32,
    },
    /// solve(A, B) = A⁻¹B, A n×n, B n×m.
    Solve {
        /// n
        n: u32,
        /// m
        m: u32,
    },
    /// expm(A), A n×n.
    Expm {
        /// n
        n: u32,
    },
    /// Spectral norm of an r×c matrix (one output).
    Norm2 {
        /// rows
        r: u32,
        /// cols
        c: u32,
    },
}

impl BlockKind {
    /// Number of outputs.
    pub fn outputs(self) -> usize {
        match self {
            BlockKind::Inv { n } | BlockKind::Expm { n } => (n * n) as usize,
            BlockKind::Solve { n, m } => (n * m) as usize,
            BlockKind::Norm2 { .. } => 1,
        }
    }

    /// Applies the operation to `inputs`, writing the outputs; returns
    /// false if the result is undefined (singular matrix).
    /// Non-finite or empty inputs never reach nalgebra (whose SVD and
    /// decompositions panic on them): NaN in, NaN out.
    pub fn apply(self, inputs: &[f64], out: &mut [f64]) -> bool {
        if out.is_empty() {
            return true;
        }
        if inputs.iter().any(|v| !v.is_finite()) {
            out.fill(f64::NAN);
            return false;
        }
        match self {
            BlockKind::Inv { n } => {
                let n = n as usize;
                let a = DMatrix::from_row_slice(n, n, inputs);
                match a.try_inverse() {
                    Some(inv) => {
                        copy_row_major(&inv, out);
                        true
                    }
                    None => {
                        out.fill(f64::NAN);
                        false
                    }
                }
            }
            BlockKind::Solve { n, m } => {
                let (n, m) = (n as usize, m as usize);
                let a = DMatrix::from_row_slice(n, n, &inputs[..n * n]);
                let b = DMatrix::from_row_slice(n, m, &inputs[n * n..]);
                match a.lu().solve(&b) {
                    Some(x) => {
                        copy_row_major(&x, out);
                        true
                    }
                    None => {
                        out.fill(f64::NAN);
                        false
                    }
                }
            }
            BlockKind::Expm { n } => {
                let n = n as usize;
                let a = DMatrix::from_row_slice(n, n, inputs);
                let e = a.exp();
                copy_row_major(&e, out);
                e.iter().all(|v| v.is_finite())
            }
            BlockKind::Norm2 { r, c } => {
                if r == 0 || c == 0 {
                    out[0] = 0.0;
                    return true;
                }
                let a = DMatrix::from_row_slice(r as usize, c as usize, inputs);
                // None for a NaN/inf matrix: the block fails like a singular inverse.
                let Some(s) = crate::linalg::singular_values(&a) else {
                    out[0] = f64::NAN;
                    return false;
                };
                out[0] = s.iter().copied().fold(0.0, f64::max);
                out[0].is_finite()
            }
        }
    }
}

fn copy_row_major(m: &DMatrix<f64>, out: &mut [f64]) {
    let c = m.ncols();
    for (k, o) in out.iter_mut().enumerate() {
        *o = m[(k / c, k % c)];
    }
}

/// A block operation on constants is undefined (singular matrix).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Singular;

/// A node of the graph.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Node {
    /// A constant (f64 bits).
    Const(u64),
    /// State component `x[k]`.
    State(u32),
    /// Ordinary time t.
    Time,
    /// The jump counter j (constant along a flow; the pre-jump value in a
    /// jump map).
    Jumps,
    /// Component k of the white-noise increment (flows only).
    Wiener(u32),
    /// f(a).
    Un(UnFn, NodeId),
    /// f(a, b).
    Bin(BinFn, NodeId, NodeId),
    /// if c then a else b.
    Select(NodeId, NodeId, NodeId),
    /// A random draw with parameters (a, b); `id` keeps draws distinct.
    Rand(Dist, NodeId, NodeId, u32),
    /// Output k of block b.
    BlockOut(u32, u32),
    /// Entry `[row, col]` (1-based, evaluated at run time) of constant
    /// table `table`; `origin` indexes the span table (the indexing
    /// expression), named when the index is out of range or not an integer.
    Lookup {
        /// The table ([`Dag::table`]).
        table: u32,
        /// Row index node (1-based).
        row: NodeId,
        /// Column index node (1-based).
        col: NodeId,
        /// Span index of the indexing expression.
        origin: u32,
        /// The condition under which the entry is needed (the branch of an
        /// `if`, the right operand of `&&`/`||`): an index that fails where
        /// it is 0 is not an error (short-circuit semantics).
        when: NodeId,
    },
    /// Piecewise-linear interpolation in table `table` (row 0 the strictly
    /// increasing abscissae, row 1 the ordinates) at `x`, clamped at the
    /// ends; with `slope`, its derivative in x instead (the segment's
    /// slope, 0 outside the abscissae).
    Interp {
        /// The table ([`Dag::table`]).
        table: u32,
        /// The argument.
        x: NodeId,
        /// The derivative instead of the value.
        slope: bool,
    },
}

/// A constant matrix looked up at run time (`tk[k]` with a run-time `k`,
/// `interp(xs, ys, x)`): row-major values, shared by the programs that use
/// it.
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    /// Rows.
    pub rows: usize,
    /// Columns.
    pub cols: usize,
    /// Entries, row-major.
    pub data: Box<[f64]>,
}

/// Why a run-time index failed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BadIndex {
    /// The row index as evaluated.
    pub row: f64,
    /// The column index as evaluated.
    pub col: f64,
}

impl Table {
    /// Entry `[row, col]` (1-based); an index that is not an integer in
    /// range is an error (never rounded or clamped: a table index computed
    /// wrongly must not silently read a neighbour).
    #[inline]
    pub fn lookup(&self, row: f64, col: f64) -> Result<f64, BadIndex> {
        let ok = |i: f64, n: usize| i >= 1.0 && i <= n as f64 && i.fract() == 0.0;
        if ok(row, self.rows) && ok(col, self.cols) {
            Ok(self.data[(row as usize - 1) * self.cols + (col as usize - 1)])
        } else {
            Err(BadIndex { row, col })
        }
    }

    /// Linear interpolation at `x` through the points (row 0, row 1),
    /// clamped to the first and last ordinate outside the abscissae; NaN
    /// for NaN. With `slope`, the derivative: the slope of the segment
    /// `[xs[i], xs[i+1])` holding x (0 outside `[xs[0], xs[n-1])`, as the
    /// right derivative at a breakpoint).
    #[inline]
    pub fn interp(&self, x: f64, slope: bool) -> f64 {
        let n = self.cols;
        let (xs, ys) = self.data.split_at(n);
        if x.is_nan() {
            return f64::NAN;
        }
        if n == 1 || x < xs[0] || x >= xs[n - 1] {
            return if slope {
                0.0
            } else if n == 1 || x < xs[0] {
                ys[0]
            } else {
                ys[n - 1]
            };
        }
        // The segment i with xs[i] <= x < xs[i + 1].
        let i = xs.partition_point(|&v| v <= x) - 1;
        let s = (ys[i + 1] - ys[i]) / (xs[i + 1] - xs[i]);
        if slope { s } else { ys[i] + (x - xs[i]) * s }
    }
}

/// A block operation with its inputs.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Block {
    /// The operation.
    pub kind: BlockKind,
    /// Input nodes, row-major.
    pub inputs: Vec<NodeId>,
    /// Index into the span table of the expression that created it.
    pub origin: u32,
}

/// The graph: nodes, blocks and the hash-consing memo.
#[derive(Debug, Clone, Default)]
pub struct Dag {
    nodes: Vec<Node>,
    memo: HashMap<Node, NodeId>,
    blocks: Vec<Block>,
    block_memo: HashMap<(BlockKind, Vec<NodeId>), u32>,
    tables: Vec<Arc<Table>>,
    table_memo: HashMap<(usize, Vec<NodeId>), u32>,
    draws: u32,
    /// Work done so far (nodes requested, loop iterations charged): the
    /// checker bounds it so that no input makes compilation hang.
    ops: u64,
    /// `State(k)` → its id ([`NO_NODE`] if not made yet), and a small
    /// direct-mapped cache of constants (bits, id): the two most requested
    /// leaves skip the memo's hashing. Both agree with `memo`, which only
    /// grows.
    state_ids: Vec<NodeId>,
    konst_ids: Vec<(u64, NodeId)>,
}

/// No node (the leaf caches' empty entry).
const NO_NODE: NodeId = NodeId::MAX;

/// Entries of the constant cache (a power of two).
const KONST_CACHE: usize = 64;

/// Evaluates a unary function.
pub fn eval_un(f: UnFn, a: f64) -> f64 {
    match f {
        UnFn::Neg => -a,
        UnFn::Abs => a.abs(),
        UnFn::Sqrt => a.sqrt(),
        UnFn::Exp => a.exp(),
        UnFn::Log => a.ln(),
        UnFn::Sin => a.sin(),
        UnFn::Cos => a.cos(),
        UnFn::Tan => a.tan(),
        UnFn::Atan => a.atan(),
        UnFn::Tanh => a.tanh(),
        UnFn::Asin => a.asin(),
        UnFn::Acos => a.acos(),
        UnFn::Sinh => a.sinh(),
        UnFn::Cosh => a.cosh(),
        UnFn::Sign => {
            if a > 0.0 {
                1.0
            } else if a < 0.0 {
                -1.0
            } else {
                0.0
            }
        }
        UnFn::Floor => a.floor(),
        UnFn::Ceil => a.ceil(),
        UnFn::Round => a.round(),
        UnFn::Not => b2f(a == 0.0),
    }
}

#[inline]
fn b2f(b: bool) -> f64 {
    if b { 1.0 } else { 0.0 }
}

/// Evaluates a binary function.
#[inline]
pub fn eval_bin(f: BinFn, a: f64, b: f64) -> f64 {
    match f {
        BinFn::Add => a + b,
        BinFn::Sub => a - b,
        BinFn::Mul => a * b,
        BinFn::Div => a / b,
        BinFn::Pow => {
            if b == 2.0 {
                a * a
            } else {
                a.powf(b)
            }
        }
        BinFn::Min => a.min(b),
        BinFn::Max => a.max(b),
        BinFn::Atan2 => a.atan2(b),
        BinFn::Mod => a - b * (a / b).floor(),
        BinFn::Rem => a - b * (a / b).trunc(),
        BinFn::Hypot => a.hypot(b),
        BinFn::Lt => b2f(a < b),
        BinFn::Le => b2f(a <= b),
        BinFn::Gt => b2f(a > b),
        BinFn::Ge => b2f(a >= b),
        BinFn::Eq => b2f(a == b),
        BinFn::Ne => b2f(a != b),
        BinFn::And => b2f(a != 0.0 && b != 0.0),
        BinFn::Or => b2f(a != 0.0 || b != 0.0),
    }
}

impl Dag {
    /// An empty graph.
    pub fn new() -> Self {
        Self::default()
    }

    /// The node with id `id`.
    pub fn node(&self, id: NodeId) -> Node {
        self.nodes[id as usize]
    }

    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    /// True if there are no nodes.
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// The block with index `b`.
    pub fn block(&self, b: u32) -> &Block {
        &self.blocks[b as usize]
    }

    /// Work done so far: every node requested (shared or not) plus what
    /// [`charge`](Self::charge) added.
    pub fn ops(&self) -> u64 {
        self.ops
    }

    /// Adds `n` units of work (e.g. loop iterations).
    pub fn charge(&mut self, n: u64) {
        self.ops = self.ops.saturating_add(n);
    }

    fn intern(&mut self, n: Node) -> NodeId {
        self.ops += 1;
        match self.memo.entry(n) {
            Entry::Occupied(e) => *e.get(),
            Entry::Vacant(e) => {
                let id = self.nodes.len() as NodeId;
                self.nodes.push(n);
                e.insert(id);
                id
            }
        }
    }

    /// A constant.
    pub fn konst(&mut self, v: f64) -> NodeId {
        // Normalize −0 so that hash-consing treats 0 and −0 alike.
        let bits = if v == 0.0 { 0.0_f64 } else { v }.to_bits();
        if self.konst_ids.is_empty() {
            self.konst_ids = vec![(0, NO_NODE); KONST_CACHE];
        }
        let slot = crate::num::hash_slot(bits, KONST_CACHE);
        let (b, id) = self.konst_ids[slot];
        if b == bits && id != NO_NODE {
            self.ops += 1;
            return id;
        }
        let id = self.intern(Node::Const(bits));
        self.konst_ids[slot] = (bits, id);
        id
    }

    /// The constant value of `id`, if it is a constant.
    pub fn as_const(&self, id: NodeId) -> Option<f64> {
        match self.nodes[id as usize] {
            Node::Const(b) => Some(f64::from_bits(b)),
            _ => None,
        }
    }

    /// State component `k`.
    pub fn state(&mut self, k: usize) -> NodeId {
        if let Some(&id) = self.state_ids.get(k)
            && id != NO_NODE
        {
            self.ops += 1;
            return id;
        }
        let id = self.intern(Node::State(k as u32));
        if self.state_ids.len() <= k {
            self.state_ids.resize(k + 1, NO_NODE);
        }
        self.state_ids[k] = id;
        id
    }

    /// Ordinary time.
    pub fn time(&mut self) -> NodeId {
        self.intern(Node::Time)
    }

    /// The jump counter j.
    pub fn jumps(&mut self) -> NodeId {
        self.intern(Node::Jumps)
    }

    /// White-noise component `k`.
    pub fn wiener(&mut self, k: usize) -> NodeId {
        self.intern(Node::Wiener(k as u32))
    }

    /// f(a), folded if a is constant.
    pub fn un(&mut self, f: UnFn, a: NodeId) -> NodeId {
        if let Some(x) = self.as_const(a) {
            return self.konst(eval_un(f, x));
        }
        if f == UnFn::Neg
            && let Node::Un(UnFn::Neg, inner) = self.node(a)
        {
            return inner;
        }
        self.intern(Node::Un(f, a))
    }

    /// f(a, b), folded and simplified where exact.
    pub fn bin(&mut self, f: BinFn, a: NodeId, b: NodeId) -> NodeId {
        let (ca, cb) = (self.as_const(a), self.as_const(b));
        if let (Some(x), Some(y)) = (ca, cb) {
            return self.konst(eval_bin(f, x, y));
        }
        match f {
            BinFn::Add => {
                if ca == Some(0.0) {
                    return b;
                }
                if cb == Some(0.0) {
                    return a;
                }
                // Canonical order for commutative ops helps sharing.
                let (a, b) = if a <= b { (a, b) } else { (b, a) };
                return self.intern(Node::Bin(f, a, b));
            }
            BinFn::Sub => {
                if cb == Some(0.0) {
                    return a;
                }
                if ca == Some(0.0) {
                    return self.un(UnFn::Neg, b);
                }
            }
            BinFn::Mul => {
                if ca == Some(0.0) || cb == Some(0.0) {
                    return self.konst(0.0);
                }
                if ca == Some(1.0) {
                    return b;
                }
                if cb == Some(1.0) {
                    return a;
                }
                if ca == Some(-1.0) {
                    return self.un(UnFn::Neg, b);
                }
                if cb == Some(-1.0) {
                    return self.un(UnFn::Neg, a);
                }
                let (a, b) = if a <= b { (a, b) } else { (b, a) };
                return self.intern(Node::Bin(f, a, b));
            }
            BinFn::Div if cb == Some(1.0) => return a,
            BinFn::And => {
                if ca == Some(1.0) {
                    return b;
                }
                if cb == Some(1.0) {
                    return a;
                }
            }
            BinFn::Or => {
                if ca == Some(0.0) {
                    return b;
                }
                if cb == Some(0.0) {
                    return a;
                }
            }
            _ => {}
        }
        self.intern(Node::Bin(f, a, b))
    }

    /// if c then a else b, folded if c is constant.
    pub fn select(&mut self, c: NodeId, a: NodeId, b: NodeId) -> NodeId {
        match self.as_const(c) {
            Some(v) if v != 0.0 => a,
            Some(_) => b,
            None if a == b => a,
            None => self.intern(Node::Select(c, a, b)),
        }
    }

    /// Whether the graph holds a random draw.
    pub fn has_draws(&self) -> bool {
        self.draws > 0
    }

    /// A fresh random draw (never shared with another draw).
    pub fn rand(&mut self, d: Dist, a: NodeId, b: NodeId) -> NodeId {
        self.draws += 1;
        self.intern(Node::Rand(d, a, b, self.draws))
    }

    /// A block operation; folded when all inputs are constants. Returns the
    /// output nodes (row-major), or an error if a constant input makes it
    /// undefined ([`Singular`]).
    pub fn add_block(
        &mut self,
        kind: BlockKind,
        inputs: Vec<NodeId>,
        origin: u32,
    ) -> Result<Vec<NodeId>, Singular> {
        let consts: Option<Vec<f64>> = inputs.iter().map(|&i| self.as_const(i)).collect();
        if let Some(vals) = consts {
            let mut out = vec![0.0; kind.outputs()];
            if !kind.apply(&vals, &mut out) {
                return Err(Singular);
            }
            return Ok(out.into_iter().map(|v| self.konst(v)).collect());
        }
        let key = (kind, inputs.clone());
        let b = match self.block_memo.get(&key) {
            Some(&b) => b,
            None => {
                let b = self.blocks.len() as u32;
                self.blocks.push(Block {
                    kind,
                    inputs,
                    origin,
                });
                self.block_memo.insert(key, b);
                b
            }
        };
        Ok((0..kind.outputs())
            .map(|k| self.intern(Node::BlockOut(b, k as u32)))
            .collect())
    }

    /// The constant table with entries `entries` (constant nodes,
    /// row-major, `rows` × `cols`), shared with an earlier one of the same
    /// entries; `None` if an entry is not a constant.
    pub fn table(&mut self, entries: &[NodeId], rows: usize, cols: usize) -> Option<u32> {
        let key = (cols, entries.to_vec());
        if let Some(&t) = self.table_memo.get(&key) {
            return Some(t);
        }
        let data: Option<Box<[f64]>> = entries.iter().map(|&e| self.as_const(e)).collect();
        let t = self.tables.len() as u32;
        self.tables.push(Arc::new(Table {
            rows,
            cols,
            data: data?,
        }));
        self.table_memo.insert(key, t);
        Some(t)
    }

    /// The table with index `t`.
    pub fn table_at(&self, t: u32) -> &Arc<Table> {
        &self.tables[t as usize]
    }

    /// `table[row, col]` at run time (1-based); folded when both indices
    /// are constants (`Err` then: out of range or not an integer).
    pub fn lookup(
        &mut self,
        table: u32,
        row: NodeId,
        col: NodeId,
        origin: u32,
        when: NodeId,
    ) -> Result<NodeId, BadIndex> {
        if let (Some(r), Some(c)) = (self.as_const(row), self.as_const(col)) {
            return match self.tables[table as usize].lookup(r, c) {
                Ok(v) => Ok(self.konst(v)),
                // Never needed: no error (and no value).
                Err(_) if self.as_const(when) == Some(0.0) => Ok(self.konst(f64::NAN)),
                Err(e) => Err(e),
            };
        }
        Ok(self.intern(Node::Lookup {
            table,
            row,
            col,
            origin,
            when,
        }))
    }

    /// `interp` of table `table` at `x` (its `slope`), folded for a
    /// constant `x`.
    pub fn interp(&mut self, table: u32, x: NodeId, slope: bool) -> NodeId {
        if let Some(v) = self.as_const(x) {
            let y = self.tables[table as usize].interp(v, slope);
            return self.konst(y);
        }
        self.intern(Node::Interp { table, x, slope })
    }

    /// `id` rebuilt with each input `c` replaced by `f(self, c)` (and folded
    /// again), for the nodes computed from inputs by a function of the
    /// graph; `None` for the others (leaves, random draws, block outputs),
    /// which each rewrite treats in its own way.
    pub fn map_inputs(
        &mut self,
        id: NodeId,
        f: &mut dyn FnMut(&mut Dag, NodeId) -> NodeId,
    ) -> Option<NodeId> {
        Some(match self.nodes[id as usize] {
            Node::Un(g, a) => {
                let a = f(self, a);
                self.un(g, a)
            }
            Node::Bin(g, a, b) => {
                let a = f(self, a);
                let b = f(self, b);
                self.bin(g, a, b)
            }
            Node::Select(c, a, b) => {
                let c = f(self, c);
                let a = f(self, a);
                let b = f(self, b);
                self.select(c, a, b)
            }
            Node::Lookup {
                table,
                row,
                col,
                origin,
                when,
            } => {
                let row = f(self, row);
                let col = f(self, col);
                let when = f(self, when);
                // A constant index out of range stays a run-time lookup (its
                // error is reported where it is evaluated).
                self.lookup(table, row, col, origin, when).unwrap_or(id)
            }
            Node::Interp { table, x, slope } => {
                let x = f(self, x);
                self.interp(table, x, slope)
            }
            Node::Const(_)
            | Node::State(_)
            | Node::Time
            | Node::Jumps
            | Node::Wiener(_)
            | Node::Rand(..)
            | Node::BlockOut(..) => return None,
        })
    }

    /// Visits the direct inputs of `id`.
    pub fn inputs(&self, id: NodeId, mut f: impl FnMut(NodeId)) {
        match self.nodes[id as usize] {
            Node::Const(_) | Node::State(_) | Node::Time | Node::Jumps | Node::Wiener(_) => {}
            Node::Un(_, a) | Node::Interp { x: a, .. } => f(a),
            Node::Bin(_, a, b) | Node::Rand(_, a, b, _) => {
                f(a);
                f(b);
            }
            Node::Lookup { row, col, when, .. } => {
                f(row);
                f(col);
                f(when);
            }
            Node::Select(c, a, b) => {
                f(c);
                f(a);
                f(b);
            }
            Node::BlockOut(b, _) => {
                for &i in &self.blocks[b as usize].inputs {
                    f(i);
                }
            }
        }
    }

    /// Marks every node reachable from `roots` (inputs included).
    pub fn reachable(&self, roots: &[NodeId]) -> Vec<bool> {
        let mut seen = vec![false; self.nodes.len()];
        // Root by root: a copy of the roots (a billion entries of a huge constant matrix) is
        // not needed.
        let mut stack: Vec<NodeId> = Vec::new();
        for &root in roots {
            stack.push(root);
            while let Some(id) = stack.pop() {
                if std::mem::replace(&mut seen[id as usize], true) {
                    continue;
                }
                self.inputs(id, |i| stack.push(i));
            }
        }
        seen
    }

    /// True if any node reachable from `roots` satisfies `pred`.
    pub fn any_reachable(&self, roots: &[NodeId], pred: impl Fn(Node) -> bool) -> bool {
        self.reachable(roots)
            .iter()
            .enumerate()
            .any(|(i, &r)| r && pred(self.nodes[i]))
    }
}
