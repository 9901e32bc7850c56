//! Pairs of isomorphic instructions computed together, one in each lane
//! of an `F64X2` vector (superword-level parallelism).
//!
//! The checker scalarizes matrix work, so a matrix product's entries
//! `(i, k)` and `(i, k + 1)` are the same instructions on neighbouring
//! operands: `a·b₁` and `a·b₂` with the same `a` and `b₁`, `b₂` adjacent
//! state components, and then sums of those products term by term. Such
//! two instructions become one vector instruction when their operands are
//! cheap to put into vectors: two adjacent state components (one load),
//! two registers an earlier pair computed in lane order (free), two
//! immediates (a constant), and within a budget of [`MAX_COST`]
//! instructions per pair the same register (a splat) or two unrelated
//! scalars (gathered), each made once. The scalar code's instructions
//! that read one lane extract it (lane 0 costs nothing). Each lane
//! performs the IEEE operation of its scalar instruction, in the same
//! order, so the results are the same bits (a NaN's payload aside: `a + b`
//! may pair with `d + c`, as the interpreter's sums already treat NaNs).
//!
//! [`plan`] chooses the pairs greedily in program order: each instruction
//! takes the cheapest partner of its kind among the next [`WINDOW`]
//! instructions that can move up to it (its operands are defined before;
//! registers are assigned once, so nothing it reads changes).

use rustc_hash::FxHashSet as HashSet;

use crate::ir::program::{CONST_TERM, Op, Program};

/// The most instructions a pair may spend packing its operands (splats,
/// gathers; loads and vectors found packed are free): the pair saves one
/// instruction and, more, the values its scalar code would keep live (on
/// a consensus filter's flow, 2 packs per pair gave the fewest
/// instructions run; 0 and 1 far fewer pairs, 5 more work than saved).
const MAX_COST: u32 = 2;

/// How far after an instruction its partner may be.
const WINDOW: usize = 16;

/// The fewest pairs a program needs for its code to use vectors: below it
/// the vector code would save next to nothing.
const MIN_PAIRS: u32 = 8;

/// An operand of an instruction: a register or an immediate.
#[derive(Clone, Copy, PartialEq, Debug)]
pub(super) enum Slot {
    Reg(u32),
    Imm(f64),
}

/// The instructions that pair (a sum with its number of terms).
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Kind {
    Add,
    Sub,
    Mul,
    Div,
    AddC,
    MulC,
    Neg,
    Lin(u32),
}

fn kind(op: &Op) -> Option<Kind> {
    Some(match *op {
        Op::Add { .. } => Kind::Add,
        Op::Sub { .. } => Kind::Sub,
        Op::Mul { .. } => Kind::Mul,
        Op::Div { .. } => Kind::Div,
        Op::AddC { .. } => Kind::AddC,
        Op::MulC { .. } => Kind::MulC,
        Op::Neg { .. } => Kind::Neg,
        Op::Lin { len, .. } => Kind::Lin(len),
        _ => return None,
    })
}

/// The number of operands of a pairable instruction.
pub(super) fn arity(op: &Op) -> usize {
    match *op {
        Op::Neg { .. } => 1,
        Op::Lin { len, .. } => len as usize,
        _ => 2,
    }
}

/// Operand `k` of a pairable instruction; a sum's operands are its terms'
/// registers or, for a constant term, its value (the coefficients are the
/// emitter's).
pub(super) fn slot(p: &Program, op: &Op, k: usize) -> Slot {
    match *op {
        Op::Add { a, b, .. }
        | Op::Sub { a, b, .. }
        | Op::Mul { a, b, .. }
        | Op::Div { a, b, .. } => Slot::Reg(if k == 0 { a } else { b }),
        Op::AddC { a, c, .. } | Op::MulC { a, c, .. } => {
            if k == 0 {
                Slot::Reg(a)
            } else {
                Slot::Imm(c)
            }
        }
        Op::Neg { a, .. } => Slot::Reg(a),
        Op::Lin { t0, .. } => match p.lin[t0 as usize + k] {
            (CONST_TERM, c) => Slot::Imm(c),
            (r, _) => Slot::Reg(r),
        },
        _ => unreachable!("{op:?} does not pair"),
    }
}

/// The register an instruction defines.
pub(super) fn dest(op: &Op) -> u32 {
    match *op {
        Op::Add { d, .. }
        | Op::Sub { d, .. }
        | Op::Mul { d, .. }
        | Op::Div { d, .. }
        | Op::AddC { d, .. }
        | Op::MulC { d, .. }
        | Op::Neg { d, .. }
        | Op::Lin { d, .. } => d,
        _ => unreachable!("{op:?} does not pair"),
    }
}

/// The chosen pairs of a program.
#[derive(Debug, Default)]
pub(super) struct Plan {
    /// For an instruction that leads a pair (lane 0): its partner (lane 1,
    /// emitted with it) and whether the partner's two operands are taken in
    /// the other order (`+` and `·` only: the same value, NaN's payload
    /// aside, which the interpreter does not keep either).
    partner: Vec<Option<(u32, bool)>>,
    /// The instructions emitted with an earlier one.
    follows: Vec<bool>,
}

impl Plan {
    /// Instruction `i`'s partner if it leads a pair.
    pub fn partner(&self, i: usize) -> Option<(u32, bool)> {
        self.partner.get(i).copied().flatten()
    }

    /// Whether instruction `i` is emitted with an earlier one.
    pub fn follows(&self, i: usize) -> bool {
        self.follows.get(i).copied().unwrap_or(false)
    }
}

/// The pairs of `p`, none of them an instruction `skip` excludes (sums
/// that go into loops); empty if there are fewer than [`MIN_PAIRS`].
pub(super) fn plan(p: &Program, skip: impl Fn(&Op) -> bool) -> Plan {
    let n = p.ops.len();
    let mut plan = Plan {
        partner: vec![None; n],
        follows: vec![false; n],
    };
    // Where each register is defined: one past its instruction's index, 0
    // for the fixed registers (available from the start).
    let mut def = vec![0u32; p.nregs];
    for (i, op) in p.ops.iter().enumerate() {
        let at = i as u32 + 1;
        match *op {
            Op::Block {
                inp,
                out,
                len,
                kind,
                ..
            } => {
                for r in (inp..inp + len).chain(out..out + kind.outputs() as u32) {
                    def[r as usize] = at;
                }
            }
            Op::Const { d, .. }
            | Op::BinRC { d, .. }
            | Op::BinCR { d, .. }
            | Op::Bin { d, .. }
            | Op::Un { d, .. }
            | Op::Select { d, .. }
            | Op::Rand { d, .. }
            | Op::Lookup { d, .. }
            | Op::Interp { d, .. } => def[d as usize] = at,
            _ => def[dest(op) as usize] = at,
        }
    }
    // The pair (by its leader) and lane of each register a pair computes.
    let mut lane: Vec<Option<(u32, u8)>> = vec![None; p.nregs];
    // Operand pairs splatted or gathered already (the code makes each once).
    let mut made: HashSet<(u32, u32)> = HashSet::default();
    let state = p.state_regs as u32;
    // The instructions it takes to pack two operands into one vector
    // (see `Emit::pack`), if they can be.
    let pack = |lane: &[Option<(u32, u8)>], made: &HashSet<(u32, u32)>, s: Slot, t: Slot| {
        let (a, b) = match (s, t) {
            (Slot::Imm(_), Slot::Imm(_)) => return Some(0),
            (Slot::Reg(a), Slot::Reg(b)) => (a, b),
            _ => return None,
        };
        let (la, lb) = (lane[a as usize], lane[b as usize]);
        if let (Some((i, 0)), Some((j, 1))) = (la, lb)
            && i == j
        {
            return Some(0);
        }
        if made.contains(&(a, b)) || (b == a + 1 && b < state) {
            return Some(0);
        }
        if a == b {
            return Some(1);
        }
        // `b` inserted into lane 1 of `a`'s vector or splat.
        let base = u32::from(!matches!(la, Some((_, 0))));
        let extract = u32::from(matches!(lb, Some((_, 1))));
        Some(1 + base + extract)
    };
    let mut count = 0u32;
    for i in 0..n {
        let x = &p.ops[i];
        if plan.follows[i] || skip(x) {
            continue;
        }
        let Some(k) = kind(x) else { continue };
        let commutes = matches!(k, Kind::Add | Kind::Mul);
        let mut best: Option<(u32, usize, bool)> = None;
        for j in i + 1..n.min(i + 1 + WINDOW) {
            let y = &p.ops[j];
            if plan.follows[j] || kind(y) != Some(k) || skip(y) {
                continue;
            }
            // The cheapest packing of the operands within the budget.
            let bound = best.map_or(MAX_COST, |(b, _, _)| b.saturating_sub(1));
            let cost = |swap: bool| -> Option<u32> {
                (0..arity(x)).try_fold(0, |sum, s| {
                    let t = if swap { 1 - s } else { s };
                    let sum = sum + pack(&lane, &made, slot(p, x, s), slot(p, y, t))?;
                    (sum <= bound).then_some(sum)
                })
            };
            let choice = match (cost(false), commutes.then(|| cost(true)).flatten()) {
                (Some(c), Some(d)) if d < c => Some((d, true)),
                (Some(c), _) => Some((c, false)),
                (None, d) => d.map(|d| (d, true)),
            };
            // Ready where `x` is: its operands are defined before.
            if let Some((c, swap)) = choice
                && !p.reads(y, |r| def[r as usize] > i as u32)
            {
                best = Some((c, j, swap));
                if c == 0 {
                    break;
                }
            }
        }
        if let Some((_, j, swap)) = best {
            let y = &p.ops[j];
            for s in 0..arity(x) {
                let t = if swap { 1 - s } else { s };
                if let (Slot::Reg(a), Slot::Reg(b)) = (slot(p, x, s), slot(p, y, t)) {
                    made.insert((a, b));
                }
            }
            plan.partner[i] = Some((j as u32, swap));
            plan.follows[j] = true;
            // The partner moves up to `x`.
            def[dest(y) as usize] = i as u32 + 1;
            lane[dest(x) as usize] = Some((i as u32, 0));
            lane[dest(y) as usize] = Some((i as u32, 1));
            count += 1;
        }
    }
    if count < MIN_PAIRS {
        return Plan::default();
    }
    plan
}
