//! Register programs: the scalar graph compiled into a flat list of
//! instructions over a preallocated register file, evaluated without
//! allocation or name lookups.
//!
//! Register file: `[x (n) | t | j | w (m) | temporaries]`. State, time,
//! jump-counter and white-noise nodes live in their fixed registers; every other node
//! reachable from a program's outputs gets one temporary. Constants are
//! immediates of the instructions that use them where possible.
//!
//! Sums are fused: a chain `t₁ ± t₂ ± … ± tₖ` whose terms are registers,
//! constants or products of a register with a constant (the rows of `A*x`
//! with a constant `A`) is one [`Op::Lin`] instead of ~2k instructions; the
//! interpreter's cost is its dispatch per instruction, so a 39-state
//! `A*x + B*u` runs several times faster. The fused sum adds the same
//! products in the same order as the unfused chain, so results are
//! bit-identical (see [`Program::compile`]).

use std::cell::Cell;
use std::sync::Arc;

use crate::arc::HybridTime;
use crate::check::dag::{
    BadIndex, BinFn, BlockKind, Dag, Dist, Node, NodeId, Table, UnFn, eval_bin, eval_un,
};
use crate::engine::SimRng;

/// One instruction; `d` is the destination register.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Op {
    Const {
        d: u32,
        c: f64,
    },
    Add {
        d: u32,
        a: u32,
        b: u32,
    },
    Sub {
        d: u32,
        a: u32,
        b: u32,
    },
    Mul {
        d: u32,
        a: u32,
        b: u32,
    },
    Div {
        d: u32,
        a: u32,
        b: u32,
    },
    AddC {
        d: u32,
        a: u32,
        c: f64,
    },
    MulC {
        d: u32,
        a: u32,
        c: f64,
    },
    /// f(a, c)
    BinRC {
        d: u32,
        f: BinFn,
        a: u32,
        c: f64,
    },
    /// f(c, b)
    BinCR {
        d: u32,
        f: BinFn,
        c: f64,
        b: u32,
    },
    Bin {
        d: u32,
        f: BinFn,
        a: u32,
        b: u32,
    },
    Neg {
        d: u32,
        a: u32,
    },
    Un {
        d: u32,
        f: UnFn,
        a: u32,
    },
    Select {
        d: u32,
        c: u32,
        a: u32,
        b: u32,
    },
    Rand {
        d: u32,
        dist: Dist,
        a: u32,
        b: u32,
    },
    /// `d = v₀ + v₁ + … + v_{len−1}`, summed left to right, with
    /// `vₖ = regs[r]·c` for the term `(r, c)` at `lin[t0 + k]`, or `vₖ = c`
    /// when `r` is [`CONST_TERM`].
    Lin {
        d: u32,
        t0: u32,
        len: u32,
    },
    /// `d = tables[table][row, col]` (1-based, checked: see [`lookup`]).
    Lookup {
        d: u32,
        table: u32,
        row: u32,
        col: u32,
        origin: u32,
        when: u32,
    },
    /// `d = interp(tables[table], x)` (or its slope).
    Interp {
        d: u32,
        table: u32,
        x: u32,
        slope: bool,
    },
    /// Copies `gather[g0..g0+len]` registers to `inp..inp+len`, applies
    /// `kind`, writes outputs to `out..`.
    Block {
        kind: BlockKind,
        g0: u32,
        len: u32,
        inp: u32,
        out: u32,
        origin: u32,
    },
}

thread_local! {
    /// The origin (block span index) of the last block operation that
    /// failed (singular matrix) on this thread.
    static FAULT: Cell<Option<u32>> = const { Cell::new(None) };
}

/// Takes the last recorded block failure on this thread, if any.
pub(crate) fn take_fault() -> Option<u32> {
    FAULT.with(|f| f.take())
}

/// A run-time table index that was out of range or not an integer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct IndexFault {
    /// Span index of the indexing expression.
    pub origin: u32,
    /// The indices as evaluated.
    pub bad: BadIndex,
    /// The table's size.
    pub rows: usize,
    /// The table's size.
    pub cols: usize,
    /// The hybrid time of the evaluation (the program's `t` and `j`
    /// registers).
    pub t: f64,
    /// As `t`.
    pub j: f64,
}

thread_local! {
    /// The first run-time index failure on this thread not yet taken: the
    /// engine polls it (through `HybridSystem::take_fault`) after every
    /// flow segment and jump map, so a bad index stops the run even where
    /// its NaN would go unnoticed (a guard, an output).
    static INDEX_FAULT: Cell<Option<IndexFault>> = const { Cell::new(None) };
    /// Whether `INDEX_FAULT` holds one: the poll, several times a step,
    /// reads a flag instead of moving the whole record out and back.
    static FAULTED: Cell<bool> = const { Cell::new(false) };
}

/// Takes the first recorded index failure on this thread, if any.
#[inline]
pub(crate) fn take_index_fault() -> Option<IndexFault> {
    if !FAULTED.with(Cell::get) {
        return None;
    }
    FAULTED.with(|f| f.set(false));
    INDEX_FAULT.with(|f| f.take())
}

/// `table[row, col]`, or NaN with the failure recorded for
/// [`take_index_fault`] (the first one is kept) if the entry is needed
/// (`when` ≠ 0); `t`, `j` the evaluation's hybrid time. Shared by the
/// interpreter and the machine code.
#[inline]
pub(super) fn lookup(
    table: &Table,
    row: f64,
    col: f64,
    origin: u32,
    when: f64,
    t: f64,
    j: f64,
) -> f64 {
    match table.lookup(row, col) {
        Ok(v) => v,
        Err(_) if when == 0.0 => f64::NAN,
        Err(bad) => {
            INDEX_FAULT.with(|f| {
                if f.get().is_none() {
                    FAULTED.with(|f| f.set(true));
                    f.set(Some(IndexFault {
                        origin,
                        bad,
                        rows: table.rows,
                        cols: table.cols,
                        t,
                        j,
                    }));
                }
            });
            f64::NAN
        }
    }
}

/// A compiled program: evaluates a list of output nodes.
#[derive(Debug, Clone, Default)]
pub(crate) struct Program {
    pub(super) ops: Vec<Op>,
    /// Source registers of the [`Op::Block`] inputs.
    pub(super) gather: Vec<u32>,
    /// The tables of the [`Op::Lookup`] and [`Op::Interp`] instructions.
    pub(super) tables: Vec<Arc<Table>>,
    /// Terms of the [`Op::Lin`] instructions: (register or [`CONST_TERM`], coefficient).
    pub(super) lin: Vec<(u32, f64)>,
    /// Register of each output.
    pub outs: Vec<u32>,
    /// Where [`run_into`](Self::run_into) writes each output in its
    /// caller's buffer: set by [`scatter_to`](Self::scatter_to) for the
    /// programs the engine evaluates into its own buffers, whose machine
    /// code then stores the outputs there instead of into the register
    /// file; `None`: the identity, through the registers.
    pub(super) dest: Option<Vec<u32>>,
    /// The shortest buffer [`run_into`](Self::run_into) accepts: one past
    /// the largest position.
    pub(super) dest_len: usize,
    /// Registers needed.
    pub nregs: usize,
    /// Number of state registers (`x`, the frame's `n`): [`run_at`](Self::run_at)
    /// takes them from the state slice.
    pub(super) state_regs: usize,
    /// Whether an instruction or output reads the time or jump-count
    /// register: [`run_at`](Self::run_at) and [`run_into`](Self::run_into)
    /// fill them only then (for the interpreter, and for machine code whose
    /// loops read them there; otherwise machine code takes them as
    /// arguments).
    pub(super) clock_reads: bool,
    /// Machine code for the same instructions (see [`super::jit`]),
    /// compiled when the program becomes hot and then used by
    /// [`run`](Self::run).
    pub(super) tier: super::jit::Tier,
}

/// Fixed registers of a model: state dimension and noise dimension.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Frame {
    pub n: usize,
    pub m: usize,
}

impl Frame {
    pub fn time_reg(&self) -> usize {
        self.n
    }
    /// The register of the jump counter j.
    pub fn jumps_reg(&self) -> usize {
        self.n + 1
    }
    pub fn fixed(&self) -> usize {
        self.n + 2 + self.m
    }
}

/// The jump count as a register value: through `i64`, one conversion
/// instruction where `u64` takes several, and no call (a call on the path
/// makes each program call save registers). The same value below 2⁶³; a
/// run makes fewer jumps than that (2⁶³ and beyond read as 2⁶³).
#[inline(always)]
fn jumps_value(j: u64) -> f64 {
    j.min(i64::MAX as u64) as i64 as f64
}

/// The register of node `id`, materializing a constant on first use.
fn as_reg(dag: &Dag, id: NodeId, reg: &mut [u32], ops: &mut Vec<Op>, next: &mut u32) -> u32 {
    if reg[id as usize] == u32::MAX
        && let Some(c) = dag.as_const(id)
    {
        reg[id as usize] = *next;
        ops.push(Op::Const { d: *next, c });
        *next += 1;
    }
    reg[id as usize]
}

/// Register of an [`Op::Lin`] term that is a constant (its coefficient).
pub(super) const CONST_TERM: u32 = u32::MAX;

/// `a ± b`: the sign of `b`, for the nodes that [`Op::Lin`] fuses.
fn as_sum(dag: &Dag, id: NodeId) -> Option<(NodeId, NodeId, f64)> {
    match dag.node(id) {
        Node::Bin(BinFn::Add, a, b) => Some((a, b, 1.0)),
        Node::Bin(BinFn::Sub, a, b) => Some((a, b, -1.0)),
        _ => None,
    }
}

/// `c · a` with a constant `c` and a non-constant `a`, computed by the
/// unfused program as the single product `a * c` (`/ c` as `* (1/c)`,
/// negation as `* −1`, both exact).
fn as_scaled(dag: &Dag, id: NodeId) -> Option<(NodeId, f64)> {
    match dag.node(id) {
        Node::Bin(BinFn::Mul, a, b) => match (dag.as_const(a), dag.as_const(b)) {
            (None, Some(c)) => Some((a, c)),
            (Some(c), None) => Some((b, c)),
            _ => None,
        },
        Node::Bin(BinFn::Div, a, b) if dag.as_const(a).is_none() => {
            dag.as_const(b).map(|c| (a, 1.0 / c))
        }
        Node::Un(UnFn::Neg, a) if dag.as_const(a).is_none() => Some((a, -1.0)),
        _ => None,
    }
}

/// Nodes evaluated inside the [`Op::Lin`] of a sum instead of in a register
/// of their own: used once, by a sum, as its left operand if a sum (a
/// left-leaning chain keeps its order of additions), or as either operand
/// if a product with a constant. Anything else (a sum on the right, a
/// product of a sum) would change the rounding, so it stays a register.
/// `order` are the nodes reachable from `outputs`; `uses` (all zero) and
/// `absorbed` (all false) are indexed by node and filled for them.
fn absorbed_nodes(
    dag: &Dag,
    order: &[NodeId],
    outputs: &[NodeId],
    uses: &mut [u32],
    absorbed: &mut [bool],
) {
    for &id in order {
        dag.inputs(id, |i| uses[i as usize] += 1);
    }
    for &o in outputs {
        uses[o as usize] += 1;
    }
    for &id in order {
        if let Some((a, b, _)) = as_sum(dag, id) {
            if uses[a as usize] == 1 && (as_sum(dag, a).is_some() || as_scaled(dag, a).is_some()) {
                absorbed[a as usize] = true;
            }
            if uses[b as usize] == 1 && as_scaled(dag, b).is_some() {
                absorbed[b as usize] = true;
            }
        }
    }
}

/// Per-node work arrays of [`Program::compile`], kept per thread and reset
/// after each program over the nodes it touched, so that compiling a
/// program costs time in its own size, not in the size of the graph (a
/// model with thousands of jump maps compiles each from one shared graph).
#[derive(Default)]
struct Scratch {
    seen: Vec<bool>,
    uses: Vec<u32>,
    absorbed: Vec<bool>,
    reg: Vec<u32>,
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::default();
}

impl Scratch {
    /// The nodes reachable from `roots`, in increasing id order (a
    /// topological order).
    fn reachable(&mut self, dag: &Dag, roots: &[NodeId]) -> Vec<NodeId> {
        let n = dag.len();
        if self.seen.len() < n {
            self.seen.resize(n, false);
            self.uses.resize(n, 0);
            self.absorbed.resize(n, false);
            self.reg.resize(n, u32::MAX);
        }
        let mut order = Vec::new();
        let mut stack: Vec<NodeId> = roots.to_vec();
        while let Some(id) = stack.pop() {
            if std::mem::replace(&mut self.seen[id as usize], true) {
                continue;
            }
            order.push(id);
            dag.inputs(id, |i| stack.push(i));
        }
        order.sort_unstable();
        order
    }

    /// Back to the all-default state after a program over `order`.
    fn reset(&mut self, order: &[NodeId]) {
        for &id in order {
            let i = id as usize;
            self.seen[i] = false;
            self.uses[i] = 0;
            self.absorbed[i] = false;
            self.reg[i] = u32::MAX;
        }
    }
}

/// Appends the terms of node `id`, times `sign`, in evaluation order: the
/// operands of absorbed sums and products are expanded, constants become
/// [`CONST_TERM`] terms, and anything else is its register times `sign`.
fn push_terms(
    dag: &Dag,
    id: NodeId,
    sign: f64,
    absorbed: &[bool],
    reg: &[u32],
    lin: &mut Vec<(u32, f64)>,
) {
    let leaf = |x: NodeId, c: f64, lin: &mut Vec<(u32, f64)>| match dag.as_const(x) {
        Some(k) => lin.push((CONST_TERM, c * k)),
        None => lin.push((reg[x as usize], c)),
    };
    let operand = |x: NodeId, c: f64, lin: &mut Vec<(u32, f64)>| {
        if absorbed[x as usize] {
            if let Some((y, k)) = as_scaled(dag, x) {
                return leaf(y, c * k, lin);
            }
            return push_terms(dag, x, c, absorbed, reg, lin);
        }
        leaf(x, c, lin)
    };
    match as_sum(dag, id) {
        Some((a, b, s)) => {
            operand(a, sign, lin);
            operand(b, sign * s, lin);
        }
        None => leaf(id, sign, lin),
    }
}

impl Program {
    /// Compiles the nodes `outputs` of `dag`.
    pub fn compile(dag: &Dag, frame: Frame, outputs: &[NodeId]) -> Self {
        Self::compile_with(dag, frame, outputs, true)
    }

    /// [`compile`](Self::compile), with sums fused into [`Op::Lin`] or not
    /// (the reference the fused programs are tested against).
    fn compile_with(dag: &Dag, frame: Frame, outputs: &[NodeId], fuse: bool) -> Self {
        SCRATCH.with(|s| match s.try_borrow_mut() {
            Ok(mut s) => Self::compile_in(dag, frame, outputs, fuse, &mut s),
            Err(_) => Self::compile_in(dag, frame, outputs, fuse, &mut Scratch::default()),
        })
    }

    fn compile_in(
        dag: &Dag,
        frame: Frame,
        outputs: &[NodeId],
        fuse: bool,
        scratch: &mut Scratch,
    ) -> Self {
        let order = scratch.reachable(dag, outputs);
        let Scratch {
            uses,
            absorbed,
            reg,
            ..
        } = scratch;
        let mut next = frame.fixed() as u32;
        let mut ops = Vec::new();
        let mut gather = Vec::new();
        let mut done_blocks: Vec<Option<u32>> = Vec::new();
        let mut lin = Vec::new();
        let mut tables: Vec<Arc<Table>> = Vec::new();
        let mut table_ids: Vec<u32> = Vec::new();
        // The program's index of the graph's table `t`.
        let mut local = |t: u32| -> u32 {
            match table_ids.iter().position(|&u| u == t) {
                Some(k) => k as u32,
                None => {
                    table_ids.push(t);
                    tables.push(dag.table_at(t).clone());
                    (tables.len() - 1) as u32
                }
            }
        };
        if fuse {
            absorbed_nodes(dag, &order, outputs, uses, absorbed);
        }
        for &id in &order {
            if absorbed[id as usize] {
                continue;
            }
            let node = dag.node(id);
            match node {
                Node::Const(_) => continue,
                Node::State(k) => {
                    reg[id as usize] = k;
                    continue;
                }
                Node::Time => {
                    reg[id as usize] = frame.time_reg() as u32;
                    continue;
                }
                Node::Jumps => {
                    reg[id as usize] = frame.jumps_reg() as u32;
                    continue;
                }
                Node::Wiener(k) => {
                    reg[id as usize] = (frame.n + 2) as u32 + k;
                    continue;
                }
                _ => {}
            }
            let d = next;
            let r = |x: NodeId, reg: &mut [u32], ops: &mut Vec<Op>, next: &mut u32| {
                as_reg(dag, x, reg, ops, next)
            };
            match node {
                Node::Un(f, a) => {
                    next += 1;
                    let a = r(a, reg, &mut ops, &mut next);
                    ops.push(if f == UnFn::Neg {
                        Op::Neg { d, a }
                    } else {
                        Op::Un { d, f, a }
                    });
                }
                Node::Bin(BinFn::Add | BinFn::Sub, a, _)
                    if absorbed[a as usize]
                        || as_sum(dag, id).is_some_and(|(_, b, _)| absorbed[b as usize]) =>
                {
                    next += 1;
                    let t0 = lin.len() as u32;
                    push_terms(dag, id, 1.0, absorbed, reg, &mut lin);
                    let len = lin.len() as u32 - t0;
                    ops.push(Op::Lin { d, t0, len });
                }
                Node::Bin(f, a, b) => {
                    next += 1;
                    match (dag.as_const(a), dag.as_const(b)) {
                        (None, Some(c)) => {
                            let a = reg[a as usize];
                            ops.push(match f {
                                BinFn::Add => Op::AddC { d, a, c },
                                BinFn::Sub => Op::AddC { d, a, c: -c },
                                BinFn::Mul => Op::MulC { d, a, c },
                                BinFn::Div => Op::MulC { d, a, c: 1.0 / c },
                                _ => Op::BinRC { d, f, a, c },
                            });
                        }
                        (Some(c), None) => {
                            let b = reg[b as usize];
                            ops.push(match f {
                                BinFn::Add => Op::AddC { d, a: b, c },
                                BinFn::Mul => Op::MulC { d, a: b, c },
                                _ => Op::BinCR { d, f, c, b },
                            });
                        }
                        _ => {
                            let a = r(a, reg, &mut ops, &mut next);
                            let b = r(b, reg, &mut ops, &mut next);
                            ops.push(match f {
                                BinFn::Add => Op::Add { d, a, b },
                                BinFn::Sub => Op::Sub { d, a, b },
                                BinFn::Mul => Op::Mul { d, a, b },
                                BinFn::Div => Op::Div { d, a, b },
                                _ => Op::Bin { d, f, a, b },
                            });
                        }
                    }
                }
                Node::Select(c, a, b) => {
                    next += 1;
                    let c = r(c, reg, &mut ops, &mut next);
                    let a = r(a, reg, &mut ops, &mut next);
                    let b = r(b, reg, &mut ops, &mut next);
                    ops.push(Op::Select { d, c, a, b });
                }
                Node::Rand(dist, a, b, _) => {
                    next += 1;
                    let a = r(a, reg, &mut ops, &mut next);
                    let b = r(b, reg, &mut ops, &mut next);
                    ops.push(Op::Rand { d, dist, a, b });
                }
                Node::Lookup {
                    table,
                    row,
                    col,
                    origin,
                    when,
                } => {
                    next += 1;
                    let row = r(row, reg, &mut ops, &mut next);
                    let col = r(col, reg, &mut ops, &mut next);
                    let when = r(when, reg, &mut ops, &mut next);
                    let table = local(table);
                    ops.push(Op::Lookup {
                        d,
                        table,
                        row,
                        col,
                        origin,
                        when,
                    });
                }
                Node::Interp { table, x, slope } => {
                    next += 1;
                    let x = r(x, reg, &mut ops, &mut next);
                    let table = local(table);
                    ops.push(Op::Interp { d, table, x, slope });
                }
                Node::BlockOut(bi, k) => {
                    let bi = bi as usize;
                    if done_blocks.len() <= bi {
                        done_blocks.resize(bi + 1, None);
                    }
                    let out = match done_blocks[bi] {
                        Some(out) => out,
                        None => {
                            let block = dag.block(bi as u32);
                            let g0 = gather.len() as u32;
                            for &i in &block.inputs {
                                let ri = r(i, reg, &mut ops, &mut next);
                                gather.push(ri);
                            }
                            let len = block.inputs.len() as u32;
                            let inp = next;
                            next += len;
                            let out = next;
                            next += block.kind.outputs() as u32;
                            ops.push(Op::Block {
                                kind: block.kind,
                                g0,
                                len,
                                inp,
                                out,
                                origin: block.origin,
                            });
                            done_blocks[bi] = Some(out);
                            out
                        }
                    };
                    reg[id as usize] = out + k;
                    continue;
                }
                Node::Const(_) | Node::State(_) | Node::Time | Node::Jumps | Node::Wiener(_) => {}
            }
            reg[id as usize] = d;
        }
        let outs: Vec<u32> = outputs
            .iter()
            .map(|&o| as_reg(dag, o, reg, &mut ops, &mut next))
            .collect();
        scratch.reset(&order);
        let mut p = Program {
            ops,
            gather,
            tables,
            lin,
            dest: None,
            dest_len: outs.len(),
            outs,
            nregs: next as usize,
            state_regs: frame.n,
            clock_reads: false,
            tier: Default::default(),
        };
        let clock = |r: u32| r as usize == frame.time_reg() || r as usize == frame.jumps_reg();
        p.clock_reads =
            p.outs.iter().any(|&o| clock(o)) || p.ops.iter().any(|op| p.reads(op, clock));
        p
    }

    /// Whether `op` reads a register for which `f` holds.
    pub(super) fn reads(&self, op: &Op, mut f: impl FnMut(u32) -> bool) -> bool {
        match *op {
            Op::Const { .. } => false,
            Op::Add { a, b, .. }
            | Op::Sub { a, b, .. }
            | Op::Mul { a, b, .. }
            | Op::Div { a, b, .. }
            | Op::Bin { a, b, .. }
            | Op::Rand { a, b, .. } => f(a) || f(b),
            Op::AddC { a, .. }
            | Op::MulC { a, .. }
            | Op::BinRC { a, .. }
            | Op::Neg { a, .. }
            | Op::Un { a, .. } => f(a),
            Op::BinCR { b, .. } => f(b),
            Op::Select { c, a, b, .. } => f(c) || f(a) || f(b),
            Op::Lookup { row, col, when, .. } => {
                let n = self.state_regs as u32;
                f(row) || f(col) || f(when) || f(n) || f(n + 1)
            }
            Op::Interp { x, .. } => f(x),
            Op::Lin { t0, len, .. } => self.lin[t0 as usize..(t0 + len) as usize]
                .iter()
                .any(|&(r, _)| r != CONST_TERM && f(r)),
            Op::Block { g0, len, .. } => self.gather[g0 as usize..(g0 + len) as usize]
                .iter()
                .any(|&r| f(r)),
        }
    }

    /// The state components the program reads (increasing), its outputs
    /// included (an output may be a state's register itself: an atom `x[k]`).
    pub(crate) fn state_reads(&self) -> Vec<usize> {
        let n = self.state_regs;
        let mut read = vec![false; n];
        let mut mark = |r: u32| {
            if let Some(x) = read.get_mut(r as usize) {
                *x = true;
            }
            false
        };
        for op in &self.ops {
            self.reads(op, &mut mark);
        }
        for &o in &self.outs {
            mark(o);
        }
        (0..n).filter(|&k| read[k]).collect()
    }

    /// The state components the program reads (increasing) and whether it
    /// reads the jump count, its outputs included (an output may be a
    /// state's register itself); `None` if it draws or reads the noise
    /// increments (of `frame`, the program's).
    pub(crate) fn inputs(&self, frame: Frame) -> Option<(Vec<usize>, bool)> {
        let n = self.state_regs;
        let mut read = vec![false; n + 2];
        let mut noise = false;
        let mut mark = |r: u32| {
            match read.get_mut(r as usize) {
                Some(x) => *x = true,
                None => noise |= (r as usize) < frame.fixed(),
            }
            false
        };
        for op in &self.ops {
            if matches!(op, Op::Rand { .. }) {
                return None;
            }
            self.reads(op, &mut mark);
        }
        for &o in &self.outs {
            mark(o);
        }
        if noise {
            return None;
        }
        let states = (0..n).filter(|&k| read[k]).collect();
        Some((states, read[frame.jumps_reg()]))
    }

    /// Whether [`run`](Self::run) executes machine code.
    #[cfg(test)]
    pub fn is_native(&self) -> bool {
        self.tier.is_native()
    }

    /// The same program, with [`run_into`](Self::run_into) writing output
    /// `k` to `dest[k]` of its buffer (a state's components a jump map
    /// resets, the positions of some atoms among all): its machine code
    /// stores each output there directly, with no gather after the call.
    /// For a program the engine evaluates at every step into its own
    /// buffer; [`run`](Self::run) and [`run_at`](Self::run_at) still put
    /// the outputs into their registers, at the cost of a copy.
    ///
    /// # Panics
    /// If `dest` does not give one position per output, or the program
    /// has machine code already.
    pub fn scatter_to(mut self, dest: &[usize]) -> Self {
        assert_eq!(dest.len(), self.outs.len(), "one position per output");
        assert!(
            self.tier.code_is_unset(),
            "positions set before machine code"
        );
        self.dest = Some(
            dest.iter()
                .map(|&d| u32::try_from(d).expect("a position below 2^32"))
                .collect(),
        );
        self.dest_len = dest.iter().map(|&d| d + 1).max().unwrap_or(0);
        self
    }

    /// [`scatter_to`](Self::scatter_to) with output `k` at position `k`.
    pub fn into_buffer(self) -> Self {
        let dest: Vec<usize> = (0..self.outs.len()).collect();
        self.scatter_to(&dest)
    }

    /// The position of each output in [`run_into`](Self::run_into)'s buffer.
    pub(super) fn positions(&self) -> impl Iterator<Item = (usize, u32)> + '_ {
        self.outs.iter().enumerate().map(|(k, &r)| {
            let d = self.dest.as_ref().map_or(k, |d| d[k] as usize);
            (d, r)
        })
    }

    /// Machine code that writes its outputs into the caller's buffer, run
    /// for a caller that wants them in the registers (cold: the engine
    /// calls such programs through [`run_into`](Self::run_into)).
    #[cold]
    fn run_native_to_regs(
        &self,
        native: &super::jit::Native,
        regs: &mut [f64],
        x: Option<(&[f64], [f64; 2])>,
        rng: Option<&mut SimRng>,
    ) {
        let mut out = vec![0.0; self.dest_len];
        match x {
            Some((x, clock)) => native.run_into(regs, x, rng, &mut out, clock),
            None => native.run_regs_into(regs, rng, &mut out),
        }
        for (d, r) in self.positions() {
            regs[r as usize] = out[d];
        }
    }

    /// Whether the program computes nothing (no instruction, no output).
    pub fn is_nothing(&self) -> bool {
        self.ops.is_empty() && self.outs.is_empty()
    }

    /// Number of instructions.
    pub fn len(&self) -> usize {
        self.ops.len()
    }

    /// Runs the program on `regs` (fixed registers already filled): its
    /// machine code if it has some (or gets it now: [`super::jit::Tier`]),
    /// else the interpreter.
    #[inline]
    pub fn run(&self, regs: &mut [f64], rng: Option<&mut SimRng>) {
        match self.tier.code(self) {
            Some(native) if self.dest.is_some() => self.run_native_to_regs(native, regs, None, rng),
            Some(native) => native.run(regs, rng),
            None => self.interpret(regs, rng),
        }
    }

    /// Runs the program at hybrid time `at` on state `x` (length at least
    /// the frame's `n`), with `regs` as the register file (its other fixed
    /// registers already filled). Machine code reads `x` where it is; the
    /// interpreter copies it into `regs` first.
    #[inline(always)]
    pub fn run_at(&self, regs: &mut [f64], at: HybridTime, x: &[f64], rng: Option<&mut SimRng>) {
        let (n, clock) = (self.state_regs, Self::clock(at));
        self.set_clock(regs, clock);
        // The engine's hot path, small enough to inline into each caller;
        // the rest (tier-up, the interpreter) out of line.
        match self.tier.attached() {
            Some(native) if self.dest.is_none() => native.run_at(regs, &x[..n], rng, clock),
            _ => self.run_at_slow(regs, &x[..n], rng, clock),
        }
    }

    /// The program's machine code, if it is attached and runs without a
    /// register file ([`Native::runs_without_regs`](super::jit::Native::runs_without_regs)):
    /// a caller then need not fetch one.
    #[inline(always)]
    pub fn native_without_regs(&self) -> Option<&super::jit::Native> {
        self.tier.attached().filter(|n| n.runs_without_regs())
    }

    /// The time and jump count as the machine code takes them.
    #[inline(always)]
    pub fn clock(at: HybridTime) -> [f64; 2] {
        [at.t, jumps_value(at.j)]
    }

    /// The time and jump-count registers, if the program reads them (the
    /// interpreter does from there; machine code takes them as arguments,
    /// and its loops over sums read their operands from the registers).
    #[inline(always)]
    fn set_clock(&self, regs: &mut [f64], [t, j]: [f64; 2]) {
        if self.clock_reads {
            let frame = Frame {
                n: self.state_regs,
                m: 0,
            };
            regs[frame.time_reg()] = t;
            regs[frame.jumps_reg()] = j;
        }
    }

    /// [`run_at`](Self::run_at) without attached code for it to call
    /// directly (the time registers already filled).
    #[inline(never)]
    fn run_at_slow(&self, regs: &mut [f64], x: &[f64], rng: Option<&mut SimRng>, clock: [f64; 2]) {
        match self.tier.code(self) {
            Some(native) if self.dest.is_some() => {
                self.run_native_to_regs(native, regs, Some((x, clock)), rng)
            }
            Some(native) => native.run_at(regs, x, rng, clock),
            None => {
                regs[..x.len()].copy_from_slice(x);
                self.interpret(regs, rng)
            }
        }
    }

    /// [`run_at`](Self::run_at), with output `k` written to
    /// `out[dest[k]]` (see [`scatter_to`](Self::scatter_to)) instead of
    /// its register; `out`'s other entries are left as they are. Machine
    /// code stores the outputs there directly.
    ///
    /// # Panics
    /// If `out` is shorter than the positions need.
    #[inline(always)]
    pub fn run_into(
        &self,
        regs: &mut [f64],
        at: HybridTime,
        x: &[f64],
        rng: Option<&mut SimRng>,
        out: &mut [f64],
    ) {
        let (n, clock) = (self.state_regs, Self::clock(at));
        self.set_clock(regs, clock);
        // As in `run_at`: the attached code's call inline, the rest not.
        match self.tier.attached() {
            Some(native) if self.dest.is_some() => native.run_into(regs, &x[..n], rng, out, clock),
            _ => self.run_into_slow(regs, &x[..n], rng, out, clock),
        }
    }

    /// [`run_into`](Self::run_into) without attached code for it to call
    /// directly (the time registers already filled).
    #[inline(never)]
    fn run_into_slow(
        &self,
        regs: &mut [f64],
        x: &[f64],
        rng: Option<&mut SimRng>,
        out: &mut [f64],
        clock: [f64; 2],
    ) {
        match self.tier.code(self) {
            Some(native) if self.dest.is_some() => native.run_into(regs, x, rng, out, clock),
            Some(native) => {
                native.run_at(regs, x, rng, clock);
                self.gather_into(regs, out);
            }
            None => {
                regs[..x.len()].copy_from_slice(x);
                self.interpret(regs, rng);
                self.gather_into(regs, out);
            }
        }
    }

    /// The outputs in `regs` written to `out` at their positions.
    fn gather_into(&self, regs: &[f64], out: &mut [f64]) {
        assert!(out.len() >= self.dest_len, "output buffer too short");
        for (d, r) in self.positions() {
            out[d] = regs[r as usize];
        }
    }

    /// Runs the program on `regs` with the interpreter (the reference).
    pub fn interpret(&self, regs: &mut [f64], mut rng: Option<&mut SimRng>) {
        for op in &self.ops {
            match *op {
                Op::Const { d, c } => regs[d as usize] = c,
                Op::Add { d, a, b } => regs[d as usize] = regs[a as usize] + regs[b as usize],
                Op::Sub { d, a, b } => regs[d as usize] = regs[a as usize] - regs[b as usize],
                Op::Mul { d, a, b } => regs[d as usize] = regs[a as usize] * regs[b as usize],
                Op::Div { d, a, b } => regs[d as usize] = regs[a as usize] / regs[b as usize],
                Op::AddC { d, a, c } => regs[d as usize] = regs[a as usize] + c,
                Op::MulC { d, a, c } => regs[d as usize] = regs[a as usize] * c,
                Op::BinRC { d, f, a, c } => regs[d as usize] = eval_bin(f, regs[a as usize], c),
                Op::BinCR { d, f, c, b } => regs[d as usize] = eval_bin(f, c, regs[b as usize]),
                Op::Bin { d, f, a, b } => {
                    regs[d as usize] = eval_bin(f, regs[a as usize], regs[b as usize])
                }
                Op::Neg { d, a } => regs[d as usize] = -regs[a as usize],
                Op::Un { d, f, a } => regs[d as usize] = eval_un(f, regs[a as usize]),
                Op::Select { d, c, a, b } => {
                    regs[d as usize] = if regs[c as usize] != 0.0 {
                        regs[a as usize]
                    } else {
                        regs[b as usize]
                    }
                }
                Op::Rand { d, dist, a, b } => {
                    regs[d as usize] =
                        draw(rng.as_deref_mut(), dist, regs[a as usize], regs[b as usize])
                }
                Op::Lookup {
                    d,
                    table,
                    row,
                    col,
                    origin,
                    when,
                } => {
                    let n = self.state_regs;
                    regs[d as usize] = lookup(
                        &self.tables[table as usize],
                        regs[row as usize],
                        regs[col as usize],
                        origin,
                        regs[when as usize],
                        regs[n],
                        regs[n + 1],
                    );
                }
                Op::Interp { d, table, x, slope } => {
                    regs[d as usize] = self.tables[table as usize].interp(regs[x as usize], slope);
                }
                Op::Lin { d, t0, len } => {
                    let terms = &self.lin[t0 as usize..(t0 + len) as usize];
                    let term = |&(r, c): &(u32, f64)| {
                        if r == CONST_TERM {
                            c
                        } else {
                            regs[r as usize] * c
                        }
                    };
                    let mut acc = term(&terms[0]);
                    for t in &terms[1..] {
                        acc += term(t);
                    }
                    regs[d as usize] = acc;
                }
                Op::Block {
                    kind,
                    g0,
                    len,
                    inp,
                    out,
                    origin,
                } => {
                    let (g0, len, inp, out) =
                        (g0 as usize, len as usize, inp as usize, out as usize);
                    for (k, &src) in self.gather[g0..g0 + len].iter().enumerate() {
                        regs[inp + k] = regs[src as usize];
                    }
                    apply_block(regs, kind, inp, len, out, origin);
                }
            }
        }
    }
}

/// A random draw of `dist` with parameters `(x, y)`; NaN without a
/// generator (programs that may not draw).
#[inline]
pub(super) fn draw(rng: Option<&mut SimRng>, dist: Dist, x: f64, y: f64) -> f64 {
    match rng {
        Some(rng) => match dist {
            Dist::Uniform => rng.uniform(x, y),
            Dist::Normal => rng.normal(x, y),
            Dist::Bernoulli => {
                if rng.bernoulli(x) {
                    1.0
                } else {
                    0.0
                }
            }
        },
        None => f64::NAN,
    }
}

/// Applies block `kind` to the gathered inputs `regs[inp..inp + len]`,
/// writing its outputs from `regs[out]` on; a failure (singular matrix) is
/// recorded for [`take_fault`] with the block's `origin`.
pub(super) fn apply_block(
    regs: &mut [f64],
    kind: BlockKind,
    inp: usize,
    len: usize,
    out: usize,
    origin: u32,
) {
    let (lo, hi) = regs.split_at_mut(out);
    if !kind.apply(&lo[inp..inp + len], &mut hi[..kind.outputs()]) {
        FAULT.with(|f| f.set(Some(origin)));
    }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    /// A random scalar graph over 4 states: sums in both nestings, products
    /// with constants and with states, negation, division by constants, a
    /// nonlinear function and shared subexpressions (each step may reuse any
    /// earlier node).
    fn build(steps: &[(u8, usize, usize, f64)]) -> (Dag, Vec<NodeId>) {
        let mut dag = Dag::default();
        let mut nodes: Vec<NodeId> = (0..4).map(|k| dag.state(k)).collect();
        for &(kind, i, j, c) in steps {
            let (a, b) = (nodes[i % nodes.len()], nodes[j % nodes.len()]);
            let k = dag.konst(c);
            let id = match kind % 9 {
                0 => dag.bin(BinFn::Add, a, b),
                1 => dag.bin(BinFn::Sub, a, b),
                2 => dag.bin(BinFn::Mul, a, k),
                3 => dag.bin(BinFn::Mul, k, b),
                4 => dag.bin(BinFn::Div, a, k),
                5 => dag.un(UnFn::Neg, a),
                6 => dag.bin(BinFn::Add, a, k),
                7 => dag.bin(BinFn::Sub, k, b),
                _ => {
                    let m = dag.bin(BinFn::Mul, a, b);
                    dag.un(UnFn::Sin, m)
                }
            };
            nodes.push(id);
        }
        let outs = nodes.iter().rev().take(3).copied().collect();
        (dag, outs)
    }

    fn run(p: &Program, x: &[f64]) -> Vec<u64> {
        let mut regs = vec![0.0; p.nregs.max(8)];
        regs[..4].copy_from_slice(x);
        p.run(&mut regs, None);
        p.outs.iter().map(|&o| regs[o as usize].to_bits()).collect()
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(500))]
        /// Fusing sums never changes a result, not even in the last bit.
        #[test]
        fn fused_sums_are_bit_identical(
            steps in prop::collection::vec((0u8..9, 0usize..64, 0usize..64, -3.0f64..3.0), 1..40),
            x in prop::array::uniform4(-10.0f64..10.0),
        ) {
            let (dag, outs) = build(&steps);
            let frame = Frame { n: 4, m: 0 };
            let fused = Program::compile_with(&dag, frame, &outs, true);
            let plain = Program::compile_with(&dag, frame, &outs, false);
            prop_assert!(fused.len() <= plain.len());
            prop_assert_eq!(run(&fused, &x), run(&plain, &x));
        }
    }

    /// The time and jump-count registers are filled for the programs that
    /// read them (in an instruction or as an output) and left alone by the
    /// others, which give the same values whatever the register file holds.
    #[test]
    fn clock_registers_are_filled_where_they_are_read() {
        let frame = Frame { n: 2, m: 0 };
        let at = HybridTime::new(2.5, 7);
        let x = [3.0, -1.0];
        let mut dag = Dag::default();
        let (x0, t, j) = (dag.state(0), dag.time(), dag.jumps());
        let tx = dag.bin(BinFn::Mul, t, x0);
        let reads = Program::compile(&dag, frame, &[tx, j]);
        let blind = Program::compile(&dag, frame, &[x0, tx]).scatter_to(&[0, 1]);
        let plain = Program::compile(&dag, frame, &[x0]);
        assert!(reads.clock_reads && blind.clock_reads && !plain.clock_reads);
        let mut regs = vec![f64::NAN; 16];
        reads.run_at(&mut regs, at, &x, None);
        let outs: Vec<f64> = reads.outs.iter().map(|&o| regs[o as usize]).collect();
        assert_eq!(outs, [7.5, 7.0]);
        let mut out = [0.0; 2];
        blind.run_into(&mut regs, at, &x, None, &mut out);
        assert_eq!(out, [3.0, 7.5]);
        let mut regs = vec![f64::NAN; 16];
        plain.run_at(&mut regs, at, &x, None);
        assert_eq!(regs[plain.outs[0] as usize], 3.0);
        assert!(regs[frame.time_reg()].is_nan(), "not written");
    }

    /// The rows of a constant matrix times a state vector become one
    /// instruction each.
    #[test]
    fn matrix_vector_rows_are_one_instruction() {
        let mut dag = Dag::default();
        let x: Vec<NodeId> = (0..4).map(|k| dag.state(k)).collect();
        let mut outs = Vec::new();
        for r in 0..3 {
            let c0 = dag.konst(1.5 + r as f64);
            let mut acc = dag.bin(BinFn::Mul, x[0], c0);
            for (k, &xk) in x.iter().enumerate().skip(1) {
                let c = dag.konst(0.25 * (k + r) as f64 + 0.1);
                let term = dag.bin(BinFn::Mul, c, xk);
                acc = dag.bin(BinFn::Add, acc, term);
            }
            outs.push(acc);
        }
        let p = Program::compile(&dag, Frame { n: 4, m: 0 }, &outs);
        assert_eq!(p.len(), 3);
        let plain = Program::compile_with(&dag, Frame { n: 4, m: 0 }, &outs, false);
        assert_eq!(plain.len(), 3 * 7);
        let x0 = [0.3, -1.2, 2.5, 0.7];
        assert_eq!(run(&p, &x0), run(&plain, &x0));
    }
}
