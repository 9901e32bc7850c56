//! Register programs: the scalar graph compiled into a flat list of
//! instructions over a preallocated register file, evaluated without
//! allocation or name lookups.
//!
//! Register file: `[x (n) | t | w (m) | temporaries]`. State, time and
//! white-noise nodes live in their fixed registers; every other node
//! reachable from a program's outputs gets one temporary. Constants are
//! immediates of the instructions that use them where possible.

use std::cell::Cell;

use crate::check::dag::{BinFn, BlockKind, Dag, Dist, Node, NodeId, UnFn, eval_bin, eval_un};
use crate::engine::SimRng;

/// One instruction; `d` is the destination register.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Op {
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

/// A compiled program: evaluates a list of output nodes.
#[derive(Debug, Clone, Default)]
pub(crate) struct Program {
    ops: Vec<Op>,
    gather: Vec<u32>,
    /// Register of each output.
    pub outs: Vec<u32>,
    /// Registers needed.
    pub nregs: usize,
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
    pub fn fixed(&self) -> usize {
        self.n + 1 + self.m
    }
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

impl Program {
    /// Compiles the nodes `outputs` of `dag`.
    pub fn compile(dag: &Dag, frame: Frame, outputs: &[NodeId]) -> Self {
        let reach = dag.reachable(outputs);
        let mut reg: Vec<u32> = vec![u32::MAX; dag.len()];
        let mut next = frame.fixed() as u32;
        let mut ops = Vec::new();
        let mut gather = Vec::new();
        let mut done_blocks: Vec<Option<u32>> = Vec::new();
        for id in 0..dag.len() as NodeId {
            if !reach[id as usize] {
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
                Node::Wiener(k) => {
                    reg[id as usize] = (frame.n + 1) as u32 + k;
                    continue;
                }
                _ => {}
            }
            let d = next;
            let r = |x: NodeId, reg: &mut Vec<u32>, ops: &mut Vec<Op>, next: &mut u32| {
                as_reg(dag, x, reg, ops, next)
            };
            match node {
                Node::Un(f, a) => {
                    next += 1;
                    let a = r(a, &mut reg, &mut ops, &mut next);
                    ops.push(if f == UnFn::Neg {
                        Op::Neg { d, a }
                    } else {
                        Op::Un { d, f, a }
                    });
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
                            let a = r(a, &mut reg, &mut ops, &mut next);
                            let b = r(b, &mut reg, &mut ops, &mut next);
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
                    let c = r(c, &mut reg, &mut ops, &mut next);
                    let a = r(a, &mut reg, &mut ops, &mut next);
                    let b = r(b, &mut reg, &mut ops, &mut next);
                    ops.push(Op::Select { d, c, a, b });
                }
                Node::Rand(dist, a, b, _) => {
                    next += 1;
                    let a = r(a, &mut reg, &mut ops, &mut next);
                    let b = r(b, &mut reg, &mut ops, &mut next);
                    ops.push(Op::Rand { d, dist, a, b });
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
                                let ri = r(i, &mut reg, &mut ops, &mut next);
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
                Node::Const(_) | Node::State(_) | Node::Time | Node::Wiener(_) => {}
            }
            reg[id as usize] = d;
        }
        let outs = outputs
            .iter()
            .map(|&o| as_reg(dag, o, &mut reg, &mut ops, &mut next))
            .collect();
        Program {
            ops,
            gather,
            outs,
            nregs: next as usize,
        }
    }

    /// Number of instructions.
    pub fn len(&self) -> usize {
        self.ops.len()
    }

    /// Runs the program on `regs` (fixed registers already filled).
    #[inline]
    pub fn run(&self, regs: &mut [f64], mut rng: Option<&mut SimRng>) {
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
                    let (x, y) = (regs[a as usize], regs[b as usize]);
                    regs[d as usize] = match rng.as_deref_mut() {
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
                    let (lo, hi) = regs.split_at_mut(out);
                    if !kind.apply(&lo[inp..inp + len], &mut hi[..kind.outputs()]) {
                        FAULT.with(|f| f.set(Some(origin)));
                    }
                }
            }
        }
    }
}
