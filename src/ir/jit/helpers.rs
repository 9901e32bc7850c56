//! Rust functions the generated code calls: the transcendental functions
//! (through the interpreter's own `eval_un` / `eval_bin`, so both run the
//! same libm code; the unary ones remember their last results per thread),
//! random draws and matrix blocks.

use std::cell::Cell;
use std::thread::LocalKey;

use crate::check::dag::{BinFn, BlockKind, Dist, Table, UnFn, eval_bin, eval_un};
use crate::engine::SimRng;
use crate::ir::program::{Op, Program, apply_block, draw, lookup};

/// A function of one argument called by the generated code.
pub(super) type Un = extern "C" fn(f64) -> f64;
/// A function of two arguments called by the generated code.
pub(super) type Bin = extern "C" fn(f64, f64) -> f64;
/// `draw(rng, dist, a, b)` for one `dist` ([`rand_helper`]).
pub(super) type Rand = extern "C" fn(*mut SimRng, f64, f64) -> f64;
/// `block(desc, regs)`.
pub(super) type Block = extern "C" fn(*const BlockDesc, *mut f64);
/// `table_lookup(table, row, col, origin, when, t, j)`.
pub(super) type Lookup = extern "C" fn(*const Table, f64, f64, u32, f64, f64, f64) -> f64;
/// `table_interp(table, x, slope)`.
pub(super) type Interp = extern "C" fn(*const Table, f64, u32) -> f64;

/// `sums(nest, regs)`.
pub(super) type Sums = extern "C" fn(*const Nest, *mut f64);

/// One term of a looped sum: register `reg` times `c`.
#[repr(C)]
pub(super) struct LoopTerm {
    pub reg: usize,
    pub c: f64,
}

/// Sums computed by [`sums`], in batches of `width` sums of one length:
/// per batch `[len, d₀, …, d_{width−1}]` in `batches` (terms per sum,
/// result registers), and in `terms`, batch after batch, the `k`-th terms
/// of the batch's sums side by side.
pub(super) struct Nest {
    pub width: usize,
    pub batches: Box<[u32]>,
    pub terms: Box<[LoopTerm]>,
}

/// Computes the sums of `nest` into `regs`, each as the interpreter's
/// `Op::Lin` does: `acc = v₀·c₀`, then `acc += vₖ·cₖ` in order (Rust
/// neither fuses nor reassociates floating-point operations).
pub(super) extern "C" fn sums(nest: *const Nest, regs: *mut f64) {
    // SAFETY: the code passes a nest its `Code` holds.
    let nest = unsafe { &*nest };
    match nest.width {
        4 => sums_of::<4>(nest, regs),
        1 => sums_of::<1>(nest, regs),
        w => unreachable!("no loop nest of width {w}"),
    }
}

fn sums_of<const W: usize>(nest: &Nest, regs: *mut f64) {
    let mut terms = nest.terms.chunks_exact(W);
    for batch in nest.batches.chunks_exact(W + 1) {
        let len = batch[0] as usize;
        // SAFETY (all reads and writes of `regs`): the registers are the
        // program's, below its register count, and `Native::run` checked
        // that the file holds that many.
        let first = terms.next().expect("a sum has terms");
        let mut acc: [f64; W] =
            std::array::from_fn(|w| unsafe { *regs.add(first[w].reg) } * first[w].c);
        for _ in 1..len {
            let row = terms.next().expect("len terms per sum");
            for w in 0..W {
                acc[w] += unsafe { *regs.add(row[w].reg) } * row[w].c;
            }
        }
        for w in 0..W {
            unsafe { *regs.add(batch[w + 1] as usize) = acc[w] };
        }
    }
}

/// A run-time table index (the interpreter's [`lookup`]).
pub(super) extern "C" fn table_lookup(
    table: *const Table,
    row: f64,
    col: f64,
    origin: u32,
    when: f64,
    t: f64,
    j: f64,
) -> f64 {
    // SAFETY: the code addresses a table its program (and its `Code`) holds.
    let table = unsafe { &*table };
    lookup(table, row, col, origin, when, t, j)
}

/// `interp` (the interpreter's [`Table::interp`]).
pub(super) extern "C" fn table_interp(table: *const Table, x: f64, slope: u32) -> f64 {
    // SAFETY: as for [`table_lookup`].
    let table = unsafe { &*table };
    table.interp(x, slope != 0)
}

macro_rules! un_helpers {
    ($($name:ident = $f:ident),* $(,)?) => {
        $(extern "C" fn $name(a: f64) -> f64 {
            eval_un(UnFn::$f, a)
        })*
    };
}

macro_rules! bin_helpers {
    ($($name:ident = $f:ident),* $(,)?) => {
        $(extern "C" fn $name(a: f64, b: f64) -> f64 {
            eval_bin(BinFn::$f, a, b)
        })*
    };
}

un_helpers!(un_round = Round);

/// Slots of a transcendental function's memo (a power of two).
const MEMO_SLOTS: usize = 16;

/// One function's last results, by argument: slot `hash(bits)` holds
/// `(bits, f(bits))`.
type Memo = [Cell<(u64, f64)>; MEMO_SLOTS];

/// `f(a)`, from `memo` if the slot of `a` holds it (the same argument, to
/// the bit), else computed and kept there. The programs evaluated at one
/// point (flow, guards, jump maps, metrics at the same hybrid time) call
/// the same functions of the same arguments, `sin(0.5 t)` of a reference
/// trajectory in each: a repeated call costs a hash and a compare
/// instead of libm's tens of instructions, with the same bits (the value
/// was computed by the same function of the same argument).
#[inline]
fn memoized(memo: &'static LocalKey<Memo>, f: UnFn, a: f64) -> f64 {
    let bits = a.to_bits();
    // Nearby arguments (t, t + h) differ in their low bits.
    let slot = crate::num::hash_slot(bits, MEMO_SLOTS);
    memo.try_with(|m| {
        let (k, v) = m[slot].get();
        if k == bits {
            return v;
        }
        let v = eval_un(f, a);
        m[slot].set((bits, v));
        v
    })
    .unwrap_or_else(|_| eval_un(f, a))
}

macro_rules! memo_helpers {
    ($($name:ident = $f:ident),* $(,)?) => {
        $(extern "C" fn $name(a: f64) -> f64 {
            thread_local! {
                // Every slot valid from the start: argument 0 and its value.
                static MEMO: Memo = std::array::from_fn(|_| Cell::new((0, eval_un(UnFn::$f, 0.0))));
            }
            memoized(&MEMO, UnFn::$f, a)
        })*
    };
}

memo_helpers!(
    un_exp = Exp,
    un_log = Log,
    un_sin = Sin,
    un_cos = Cos,
    un_tan = Tan,
    un_atan = Atan,
    un_tanh = Tanh,
    un_asin = Asin,
    un_acos = Acos,
    un_sinh = Sinh,
    un_cosh = Cosh,
);

bin_helpers!(
    bin_pow = Pow,
    bin_min = Min,
    bin_max = Max,
    bin_atan2 = Atan2,
    bin_hypot = Hypot,
);

/// The helper computing `f`, or `None` for the functions emitted inline
/// (exact IEEE operations and comparisons).
pub(super) fn un_helper(f: UnFn) -> Option<Un> {
    match f {
        UnFn::Exp => Some(un_exp),
        UnFn::Log => Some(un_log),
        UnFn::Sin => Some(un_sin),
        UnFn::Cos => Some(un_cos),
        UnFn::Tan => Some(un_tan),
        UnFn::Atan => Some(un_atan),
        UnFn::Tanh => Some(un_tanh),
        UnFn::Asin => Some(un_asin),
        UnFn::Acos => Some(un_acos),
        UnFn::Sinh => Some(un_sinh),
        UnFn::Cosh => Some(un_cosh),
        // Cranelift's `nearest` rounds halves to even, `f64::round` away
        // from zero: a call.
        UnFn::Round => Some(un_round),
        UnFn::Neg | UnFn::Abs | UnFn::Sqrt | UnFn::Sign | UnFn::Floor | UnFn::Ceil | UnFn::Not => {
            None
        }
    }
}

/// The helper computing `f`, or `None` for the functions emitted inline.
pub(super) fn bin_helper(f: BinFn) -> Option<Bin> {
    match f {
        BinFn::Pow => Some(bin_pow),
        BinFn::Min => Some(bin_min),
        BinFn::Max => Some(bin_max),
        BinFn::Atan2 => Some(bin_atan2),
        BinFn::Hypot => Some(bin_hypot),
        BinFn::Add
        | BinFn::Sub
        | BinFn::Mul
        | BinFn::Div
        | BinFn::Mod
        | BinFn::Rem
        | BinFn::Lt
        | BinFn::Le
        | BinFn::Gt
        | BinFn::Ge
        | BinFn::Eq
        | BinFn::Ne
        | BinFn::And
        | BinFn::Or => None,
    }
}

/// The helper drawing from `dist`: one per distribution, so a draw decodes
/// no distribution at run time.
pub(super) fn rand_helper(dist: Dist) -> Rand {
    match dist {
        Dist::Uniform => rand_uniform,
        Dist::Normal => rand_normal,
        Dist::Bernoulli => rand_bernoulli,
    }
}

/// A random draw (the interpreter's [`draw`]); `rng` null draws NaN.
#[inline(always)]
fn rand(rng: *mut SimRng, dist: Dist, a: f64, b: f64) -> f64 {
    // SAFETY: `Native::run` passes null or a pointer from a live `&mut SimRng`.
    let rng = unsafe { rng.as_mut() };
    draw(rng, dist, a, b)
}

extern "C" fn rand_uniform(rng: *mut SimRng, a: f64, b: f64) -> f64 {
    rand(rng, Dist::Uniform, a, b)
}

extern "C" fn rand_normal(rng: *mut SimRng, a: f64, b: f64) -> f64 {
    rand(rng, Dist::Normal, a, b)
}

extern "C" fn rand_bernoulli(rng: *mut SimRng, a: f64, b: f64) -> f64 {
    rand(rng, Dist::Bernoulli, a, b)
}

/// What the generated code passes to [`block`]: one matrix operation of a
/// program and the length of its register file.
#[derive(Debug, Clone, Copy)]
pub(super) struct BlockDesc {
    kind: BlockKind,
    inp: usize,
    len: usize,
    out: usize,
    origin: u32,
    nregs: usize,
}

/// The descriptors of `p`'s block operations, in program order.
pub(super) fn block_descs(p: &Program) -> Box<[BlockDesc]> {
    p.ops
        .iter()
        .filter_map(|op| match *op {
            Op::Block {
                kind,
                len,
                inp,
                out,
                origin,
                ..
            } => Some(BlockDesc {
                kind,
                inp: inp as usize,
                len: len as usize,
                out: out as usize,
                origin,
                nregs: p.nregs,
            }),
            _ => None,
        })
        .collect()
}

/// A matrix block (the interpreter's [`apply_block`]) on gathered inputs.
pub(super) extern "C" fn block(desc: *const BlockDesc, regs: *mut f64) {
    // SAFETY: `desc` points into the descriptors kept alive with the code;
    // `regs` is the register file `Native::run` checked to hold `nregs`.
    let (d, regs) = unsafe {
        let d = &*desc;
        (d, std::slice::from_raw_parts_mut(regs, d.nregs))
    };
    apply_block(regs, d.kind, d.inp, d.len, d.out, d.origin);
}
