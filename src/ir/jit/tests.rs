//! Machine code against the interpreter, bit for bit.

use proptest::prelude::*;

use super::codegen::LOOP_TERMS;
use super::{FUNCTION_COST, Jit, MAX_TOTAL_OPS, instructions};
use crate::arc::HybridTime;
use crate::check::dag::{BinFn, BlockKind, Dag, Dist, NodeId, UnFn};
use crate::engine::SimRng;
use crate::ir::program::{Frame, Op, Program};

/// Every unary function (the match makes a new variant a compile error
/// here until it is listed).
fn all_un() -> Vec<UnFn> {
    use UnFn::*;
    let all = vec![
        Neg, Abs, Sqrt, Exp, Log, Sin, Cos, Tan, Atan, Tanh, Asin, Acos, Sinh, Cosh, Sign, Floor,
        Ceil, Round, Not,
    ];
    for f in &all {
        match f {
            Neg | Abs | Sqrt | Exp | Log | Sin | Cos | Tan | Atan | Tanh | Asin | Acos | Sinh
            | Cosh | Sign | Floor | Ceil | Round | Not => {}
        }
    }
    all
}

/// Every binary function (see [`all_un`]).
fn all_bin() -> Vec<BinFn> {
    use BinFn::*;
    let all = vec![
        Add, Sub, Mul, Div, Pow, Min, Max, Atan2, Mod, Rem, Hypot, Lt, Le, Gt, Ge, Eq, Ne, And, Or,
    ];
    for f in &all {
        match f {
            Add | Sub | Mul | Div | Pow | Min | Max | Atan2 | Mod | Rem | Hypot | Lt | Le | Gt
            | Ge | Eq | Ne | And | Or => {}
        }
    }
    all
}

const FRAME: Frame = Frame { n: 4, m: 0 };

/// A copy of `p` compiled to machine code at once.
fn compiled(p: &Program, hot: bool) -> Program {
    let q = p.clone();
    Jit::new(0).expect("a supported machine").attach(&q, hot);
    assert!(q.is_native());
    q
}

/// Runs `p` interpreted and as machine code on state `x` (time 0.5, jump
/// counter 3) with generators of the same seed; the outputs' bits of both. NaN counts as
/// one value: which NaN an operation on two NaNs returns depends on the
/// order in which a compiler puts the operands of `+`, and nothing
/// downstream can tell (every comparison with NaN is false).
fn both(p: &Program, x: &[f64; 4]) -> (Vec<u64>, Vec<u64>) {
    let jitted = compiled(p, true);
    let eval = |p: &Program, native: bool| {
        let mut regs = vec![f64::NAN; p.nregs.max(FRAME.fixed())];
        regs[..4].copy_from_slice(x);
        regs[FRAME.time_reg()] = 0.5;
        regs[FRAME.jumps_reg()] = 3.0;
        let mut rng = SimRng::seed_from(7);
        if native {
            p.run(&mut regs, Some(&mut rng));
        } else {
            p.interpret(&mut regs, Some(&mut rng));
        }
        p.outs
            .iter()
            .map(|&o| {
                let v = regs[o as usize];
                if v.is_nan() { f64::NAN } else { v }.to_bits()
            })
            .collect()
    };
    (eval(p, false), eval(&jitted, true))
}

/// Special values every function is tried on.
const SPECIAL: [f64; 12] = [
    0.0,
    -0.0,
    1.0,
    -1.0,
    2.0,
    0.5,
    -2.75,
    1e300,
    f64::INFINITY,
    f64::NEG_INFINITY,
    f64::NAN,
    3.0e-310,
];

/// Each function on states and on immediates, on special values: the
/// inline operations keep NaN, signed zeros and infinities as the
/// interpreter does.
#[test]
fn every_op_on_special_values() {
    for (i, &a) in SPECIAL.iter().enumerate() {
        let b = SPECIAL[(i * 5 + 3) % SPECIAL.len()];
        for &c in &[2.0, -0.0, 0.5, f64::NAN] {
            let mut dag = Dag::default();
            let x: Vec<NodeId> = (0..4).map(|k| dag.state(k)).collect();
            let k = dag.konst(c);
            let mut outs = Vec::new();
            for f in all_un() {
                outs.push(dag.un(f, x[0]));
            }
            for f in all_bin() {
                outs.push(dag.bin(f, x[0], x[1]));
                outs.push(dag.bin(f, x[1], x[0]));
                outs.push(dag.bin(f, x[0], k));
                outs.push(dag.bin(f, k, x[1]));
            }
            outs.push(dag.select(x[2], x[0], x[1]));
            let p = Program::compile(&dag, FRAME, &outs);
            for s in [0.0, f64::NAN, -1.0] {
                let (i, j) = both(&p, &[a, b, s, 0.0]);
                assert_eq!(i, j, "a = {a}, b = {b}, c = {c}, select on {s}");
            }
        }
    }
}

/// Draws and matrix blocks run the interpreter's own code.
#[test]
fn draws_and_blocks() {
    let mut dag = Dag::default();
    let x: Vec<NodeId> = (0..4).map(|k| dag.state(k)).collect();
    let t = dag.time();
    let mut outs = Vec::new();
    for (i, d) in [Dist::Uniform, Dist::Normal, Dist::Bernoulli]
        .into_iter()
        .enumerate()
    {
        outs.push(dag.rand(d, x[i], x[i + 1]));
    }
    let inv = dag
        .add_block(BlockKind::Inv { n: 2 }, x.clone(), 0)
        .unwrap();
    let e = dag
        .add_block(BlockKind::Expm { n: 2 }, inv.clone(), 1)
        .unwrap();
    let s = dag.bin(BinFn::Mul, e[3], t);
    outs.extend(inv);
    outs.extend(e);
    outs.push(s);
    let p = Program::compile(&dag, FRAME, &outs);
    for x in [
        [0.1, 0.9, 0.3, 1.2],
        [1.0, 2.0, 2.0, 4.0],
        [-0.3, 0.2, 0.7, 0.6],
    ] {
        let (i, j) = both(&p, &x);
        assert_eq!(i, j, "x = {x:?}");
    }
}

/// A random graph over 4 states, t and j: every function, selections and
/// shared subexpressions (each step may reuse any earlier node).
fn build(steps: &[(u8, u8, usize, usize, f64)]) -> (Dag, Vec<NodeId>) {
    let (un, bin) = (all_un(), all_bin());
    let mut dag = Dag::default();
    let mut nodes: Vec<NodeId> = (0..4).map(|k| dag.state(k)).collect();
    nodes.push(dag.time());
    nodes.push(dag.jumps());
    for &(kind, f, i, j, c) in steps {
        let (a, b) = (nodes[i % nodes.len()], nodes[j % nodes.len()]);
        let k = dag.konst(c);
        let id = match kind % 6 {
            0 => dag.un(un[f as usize % un.len()], a),
            1 => dag.bin(bin[f as usize % bin.len()], a, b),
            2 => dag.bin(bin[f as usize % bin.len()], a, k),
            3 => dag.bin(bin[f as usize % bin.len()], k, b),
            4 => {
                let c = nodes[(i + j) % nodes.len()];
                dag.select(c, a, b)
            }
            _ => {
                // Sums of scaled terms (fused into `Lin`).
                let p = dag.bin(BinFn::Mul, a, k);
                dag.bin(if f % 2 == 0 { BinFn::Add } else { BinFn::Sub }, p, b)
            }
        };
        nodes.push(id);
    }
    let outs = nodes.iter().rev().take(4).copied().collect();
    (dag, outs)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]
    /// Machine code computes the interpreter's results to the last bit.
    #[test]
    fn machine_code_is_bit_identical(
        steps in prop::collection::vec(
            (0u8..6, 0u8..32, 0usize..64, 0usize..64, -3.0f64..3.0), 1..60),
        x in prop::array::uniform4(-4.0f64..4.0),
    ) {
        let (dag, outs) = build(&steps);
        let p = Program::compile(&dag, FRAME, &outs);
        let (i, j) = both(&p, &x);
        prop_assert_eq!(i, j);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]
    /// Machine code that touches no register file runs without one (the
    /// time and jump count as arguments), to the interpreter's bits; code
    /// with a loop or a block call always gets one.
    #[test]
    fn code_without_a_register_file_is_bit_identical(
        steps in prop::collection::vec(
            (0u8..6, 0u8..32, 0usize..64, 0usize..64, -3.0f64..3.0), 1..40),
        x in prop::array::uniform4(-4.0f64..4.0),
    ) {
        let (dag, outs) = build(&steps);
        let p = Program::compile(&dag, FRAME, &outs).into_buffer();
        let jitted = compiled(&p, true);
        let at = HybridTime { t: 0.5, j: 3 };
        let bits = |out: &[f64]| -> Vec<u64> {
            out.iter().map(|&v| if v.is_nan() { f64::NAN } else { v }.to_bits()).collect()
        };
        let mut regs = vec![f64::NAN; p.nregs.max(FRAME.fixed())];
        let mut want = vec![0.0; outs.len()];
        p.run_into(&mut regs, at, &x, None, &mut want);
        // Without loops or blocks nothing needs the registers.
        let plain = !p.ops.iter().any(|op| matches!(op, Op::Lin { .. } | Op::Block { .. }));
        match jitted.native_without_regs() {
            Some(native) => {
                let mut got = vec![0.0; outs.len()];
                native.run_into_without_regs(&x, None, &mut got, Program::clock(at));
                prop_assert_eq!(bits(&got), bits(&want));
            }
            None => prop_assert!(!plain, "plain code given a register file"),
        }
    }
}

/// A flow map's usual code (states and time in, outputs to a buffer) runs
/// without a register file; a loop over a long sum makes it need one.
#[test]
fn plain_code_needs_no_register_file() {
    let mut dag = Dag::default();
    let states: Vec<NodeId> = (0..4).map(|k| dag.state(k)).collect();
    let s = dag.un(UnFn::Sin, states[0]);
    let y = dag.bin(BinFn::Mul, s, states[1]);
    let t = dag.time();
    let yt = dag.bin(BinFn::Mul, y, t);
    let plain = compiled(&Program::compile(&dag, FRAME, &[yt, s]).into_buffer(), true);
    let native = plain
        .native_without_regs()
        .expect("no register file needed");
    let x = [0.3, -1.25, 2.0, 7.0];
    let mut out = [0.0; 2];
    let at = HybridTime { t: 0.5, j: 3 };
    native.run_into_without_regs(&x, None, &mut out, Program::clock(at));
    assert_eq!(out, [0.3f64.sin() * -1.25 * 0.5, 0.3f64.sin()]);
    // Sums of more than `LOOP_TERMS` terms in all: a loop over the registers.
    // (As `looped_code_grows_with_the_rows`: each coefficient once.)
    let pick: Vec<u8> = (0..39).filter(|p| p % 5 != 3).collect();
    let coef: Vec<f64> = (0..100).map(|i| 0.1 + f64::from(i) * 1e-3).collect();
    let (dag, outs) = sums(10, 10, &pick, &coef);
    let p = Program::compile(&dag, FRAME, &outs).into_buffer();
    let terms: usize = p
        .ops
        .iter()
        .map(|op| match op {
            Op::Lin { len, .. } => *len as usize,
            _ => 0,
        })
        .sum();
    assert!(terms >= LOOP_TERMS, "{terms} terms");
    let looped = compiled(&p, true);
    assert!(
        looped.native_without_regs().is_none(),
        "a loop reads the registers"
    );
}

/// `rows` sums, row `r` of `len` terms `cᵢ·vᵢ` (left-leaning, `+` or `−`)
/// over operands drawn from the states, computed temporaries (`sin xₖ`),
/// the earlier rows and constants (`pick` 39), as the checker scalarizes
/// `A * v + b`.
/// `pick` chooses each term's operand and sign, `coef` its coefficient.
fn sums(rows: usize, len: usize, pick: &[u8], coef: &[f64]) -> (Dag, Vec<NodeId>) {
    let mut dag = Dag::default();
    let x: Vec<NodeId> = (0..4).map(|k| dag.state(k)).collect();
    let temps: Vec<NodeId> = x.iter().map(|&v| dag.un(UnFn::Sin, v)).collect();
    let mut rowv: Vec<NodeId> = Vec::new();
    let mut k = 0;
    for _ in 0..rows {
        let mut acc: Option<NodeId> = None;
        for _ in 0..len {
            let (p, c) = (pick[k % pick.len()], coef[k % coef.len()]);
            k += 1;
            let term = match p % 5 {
                0 | 1 => {
                    let c = dag.konst(c);
                    dag.bin(BinFn::Mul, c, x[p as usize / 5 % 4])
                }
                2 => {
                    let c = dag.konst(c);
                    dag.bin(BinFn::Mul, temps[p as usize / 5 % 4], c)
                }
                3 if !rowv.is_empty() => {
                    let c = dag.konst(c);
                    dag.bin(BinFn::Div, rowv[p as usize / 5 % rowv.len()], c)
                }
                // Constant terms (rare: a sum with one stays inline).
                _ if p == 39 => dag.konst(c),
                _ => {
                    let c = dag.konst(c);
                    dag.bin(BinFn::Mul, x[p as usize % 4], c)
                }
            };
            acc = Some(match acc {
                None => term,
                Some(a) if p % 2 == 0 => dag.bin(BinFn::Add, a, term),
                Some(a) => dag.bin(BinFn::Sub, a, term),
            });
        }
        rowv.push(acc.expect("len > 0"));
    }
    (dag, rowv)
}

/// Runs `p` at (0.5, 3) on state `x` kept apart from the register file
/// (whose state part holds garbage), interpreted and as machine code.
fn both_at(p: &Program, x: &[f64; 4]) -> (Vec<u64>, Vec<u64>) {
    let jitted = compiled(p, false);
    let eval = |p: &Program| {
        let mut regs = vec![f64::NAN; p.nregs.max(FRAME.fixed())];
        p.run_at(&mut regs, HybridTime { t: 0.5, j: 3 }, x, None);
        p.outs
            .iter()
            .map(|&o| regs[o as usize].to_bits())
            .collect::<Vec<_>>()
    };
    (eval(p), eval(&jitted))
}

/// `p`'s outputs at (0.5, 3) on state `x` through `run_into` with output
/// `k` at position `2(len − k) − 1` of a buffer of sentinels (every other
/// position left alone), interpreted and as machine code; and through
/// `run_at` as machine code (the outputs copied back into their
/// registers). Bits, NaN as one value.
fn both_into(p: &Program, x: &[f64; 4]) -> [Vec<u64>; 3] {
    let len = p.outs.len();
    let dest: Vec<usize> = (0..len).map(|k| 2 * (len - k) - 1).collect();
    let p = p.clone().scatter_to(&dest);
    let jitted = compiled(&p, true);
    let bits = |v: f64| if v.is_nan() { f64::NAN } else { v }.to_bits();
    let into = |p: &Program| {
        let mut regs = vec![f64::NAN; p.nregs.max(FRAME.fixed())];
        let mut out = vec![-7.5; 2 * len + 1];
        p.run_into(&mut regs, HybridTime { t: 0.5, j: 3 }, x, None, &mut out);
        for k in (0..out.len()).step_by(2) {
            assert_eq!(out[k], -7.5, "position {k} is no output's");
        }
        dest.iter().map(|&d| bits(out[d])).collect::<Vec<_>>()
    };
    let mut regs = vec![f64::NAN; p.nregs.max(FRAME.fixed())];
    jitted.run_at(&mut regs, HybridTime { t: 0.5, j: 3 }, x, None);
    let at = p.outs.iter().map(|&o| bits(regs[o as usize])).collect();
    [into(&p), into(&jitted), at]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(100))]
    /// Sums long enough to become loops (over states read from the
    /// state, computed temporaries, constants and earlier sums of the
    /// same loop) compute the interpreter's results to the last bit.
    #[test]
    fn looped_sums_are_bit_identical(
        rows in 1usize..12,
        len in 1usize..40,
        pick in prop::collection::vec(0u8..40, 1..50),
        coef in prop::collection::vec(-3.0f64..3.0, 1..50),
        x in prop::array::uniform4(-4.0f64..4.0),
    ) {
        let (dag, outs) = sums(rows, len, &pick, &coef);
        let p = Program::compile(&dag, FRAME, &outs);
        let (i, j) = both(&p, &x);
        prop_assert_eq!(i, j);
        let (i, j) = both_at(&p, &x);
        prop_assert_eq!(&i, &j);
        // Stored at their positions in a caller's buffer, the same bits.
        let [interpreted, native, at] = both_into(&p, &x);
        prop_assert_eq!(&interpreted, &i);
        prop_assert_eq!(&native, &i);
        prop_assert_eq!(&at, &i);
    }
}

/// Outputs that are a state component, a constant, a helper call's
/// result and a loop's land at their positions too, and a buffer shorter
/// than the positions is refused, not overrun.
#[test]
fn outputs_land_at_their_positions() {
    let (mut dag, mut outs) = sums(3, 20, &(0..39).collect::<Vec<u8>>(), &[0.5, -1.25, 2.0]);
    let x0 = dag.state(0);
    let k = dag.konst(4.5);
    let s = dag.un(UnFn::Sin, x0);
    outs.extend([x0, k, s, x0]);
    let p = Program::compile(&dag, FRAME, &outs);
    let x = [0.75, -2.0, 1.5, 3.0];
    let reference: Vec<u64> = {
        let mut regs = vec![0.0; p.nregs.max(FRAME.fixed())];
        p.run_at(&mut regs, HybridTime { t: 0.5, j: 3 }, &x, None);
        p.outs.iter().map(|&o| regs[o as usize].to_bits()).collect()
    };
    assert_eq!(reference[outs.len() - 3], 4.5f64.to_bits());
    for bits in both_into(&p, &x) {
        assert_eq!(bits, reference);
    }
    let short = compiled(&p.clone().scatter_to(&vec![9; outs.len()]), true);
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let mut regs = vec![0.0; short.nregs.max(FRAME.fixed())];
        short.run_into(
            &mut regs,
            HybridTime { t: 0.5, j: 3 },
            &x,
            None,
            &mut [0.0; 9],
        );
    }));
    assert!(result.is_err(), "a buffer of 9 for position 9");
}

/// A register written to neighbouring positions (a constant rate of many
/// components) is stored two at a time: every position gets its value,
/// odd runs and gaps included, and nothing past the outputs is touched.
#[test]
fn repeated_outputs_fill_their_positions() {
    let mut dag = Dag::new();
    let (x0, k) = (dag.state(0), dag.konst(2.5));
    let s = dag.un(UnFn::Sin, x0);
    let outs = [k, k, x0, k, k, k, s, s, k, x0, k];
    let dest = [0, 1, 2, 3, 4, 5, 6, 7, 9, 10, 11];
    let p = Program::compile(&dag, FRAME, &outs).scatter_to(&dest);
    let x = [0.75, -2.0, 1.5, 3.0];
    let run = |p: &Program| {
        let mut regs = vec![f64::NAN; p.nregs.max(FRAME.fixed())];
        let mut out = vec![7.5; 13];
        p.run_into(&mut regs, HybridTime { t: 0.5, j: 3 }, &x, None, &mut out);
        out.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
    };
    let reference = run(&p);
    assert_eq!(reference[3], 2.5f64.to_bits());
    assert_eq!(
        (reference[8], reference[12]),
        (7.5f64.to_bits(), 7.5f64.to_bits())
    );
    for hot in [true, false] {
        assert_eq!(run(&compiled(&p, hot)), reference, "hot: {hot}");
    }
}

/// A matrix product's code grows with its rows, not with its entries:
/// an n × n constant times the state (plus temporaries) is looped, and
/// four times the rows is at most four times the instructions (sixteen
/// times the terms). Inline, the same sums take about two instructions
/// per term.
#[test]
fn looped_code_grows_with_the_rows() {
    // States and temporaries (no earlier rows: a scaled row used more
    // than once is an instruction of its own; no constants: a sum with one
    // stays inline), each coefficient once (a product used by two rows is
    // an instruction too).
    let pick: Vec<u8> = (0..39).filter(|p| p % 5 != 3).collect();
    let code = |n: usize| {
        let coef: Vec<f64> = (0..n * n).map(|i| 0.1 + i as f64 * 1e-3).collect();
        let (dag, outs) = sums(n, n, &pick, &coef);
        let p = Program::compile(&dag, FRAME, &outs);
        let (i, j) = both(&p, &[0.3, -1.1, 2.5, 0.7]);
        assert_eq!(i, j, "n = {n}");
        (instructions(&p), n * n)
    };
    let (small, terms) = code(10);
    assert!(terms >= LOOP_TERMS);
    let (large, terms) = code(40);
    assert!(large <= 4 * small, "{small} → {large} instructions");
    assert!(large < terms / 4, "{large} instructions for {terms} terms");
    // Below the threshold the sums stay inline (two per term or so).
    let (inline, terms) = code(6);
    assert!(terms < LOOP_TERMS);
    assert!(inline >= terms, "{inline} instructions for {terms} terms");
}

/// The helpers that remember their last results return what the
/// interpreter computes, to the bit, in any order of arguments: repeated
/// ones, ones sharing a slot, zero (every slot's first argument), signed
/// zeros, infinities and NaN payloads.
#[test]
fn memoized_functions_return_the_functions_bits() {
    let mut args: Vec<f64> = SPECIAL.to_vec();
    args.extend((0..100).map(|k| 0.37 * f64::from(k) - 20.0));
    args.extend([f64::from_bits(0x7ff8_0000_0000_0001), -f64::NAN, 1e-320]);
    let mut state = 12345u64;
    for f in all_un() {
        let Some(h) = super::helpers::un_helper(f) else {
            continue;
        };
        for _ in 0..2000 {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1);
            let a = args[(state >> 33) as usize % args.len()];
            let want = crate::check::dag::eval_un(f, a);
            assert_eq!(h(a).to_bits(), want.to_bits(), "{f:?}({a:e})");
        }
    }
}

/// A register file shorter than the program's is refused, not overrun.
#[test]
#[should_panic(expected = "register file")]
fn short_register_file_is_refused() {
    let mut dag = Dag::default();
    let x = dag.state(3);
    let y = dag.un(UnFn::Sin, x);
    let p = compiled(&Program::compile(&dag, FRAME, &[y]), false);
    let mut regs = vec![0.0; 2];
    p.run(&mut regs, None);
}

/// The program `sin(x₀)·x₁ + x₂ / t` and its outputs' bits at state
/// `x` through `run_at` (time 0.5).
fn tiny() -> Program {
    let mut dag = Dag::default();
    let x: Vec<NodeId> = (0..4).map(|k| dag.state(k)).collect();
    let t = dag.time();
    let s = dag.un(UnFn::Sin, x[0]);
    let m = dag.bin(BinFn::Mul, s, x[1]);
    let d = dag.bin(BinFn::Div, x[2], t);
    let y = dag.bin(BinFn::Add, m, d);
    Program::compile(&dag, FRAME, &[y, m])
}

fn run_bits(p: &Program, x: &[f64; 4]) -> Vec<u64> {
    let mut regs = vec![f64::NAN; p.nregs.max(FRAME.fixed())];
    p.run_at(&mut regs, HybridTime { t: 0.5, j: 3 }, x, None);
    p.outs.iter().map(|&o| regs[o as usize].to_bits()).collect()
}

/// A program is interpreted until it has run the generator's number of
/// calls, then runs machine code; a program run fewer times never gets
/// any, one that computes nothing needs none, and every call computes
/// the interpreter's bits.
#[test]
fn programs_get_machine_code_when_hot() {
    let jit = Jit::new(5).expect("a supported machine");
    let (hot, cold, empty) = (tiny(), tiny(), Program::default());
    for p in [&hot, &cold, &empty] {
        jit.attach(p, false);
    }
    assert_eq!(jit.counts(), (1, 3), "only the empty program needs no code");
    let x = [0.3, -1.25, 2.0, 7.0];
    let reference = {
        let p = tiny();
        let mut regs = vec![0.0; p.nregs.max(FRAME.fixed())];
        regs[..4].copy_from_slice(&x);
        regs[FRAME.time_reg()] = 0.5;
        regs[FRAME.jumps_reg()] = 3.0;
        p.interpret(&mut regs, None);
        p.outs
            .iter()
            .map(|&o| regs[o as usize].to_bits())
            .collect::<Vec<_>>()
    };
    for call in 1..=8 {
        assert_eq!(run_bits(&hot, &x), reference, "call {call}");
        assert_eq!(hot.is_native(), call >= 5, "after call {call}");
    }
    for _ in 0..4 {
        assert_eq!(run_bits(&cold, &x), reference);
    }
    assert!(!cold.is_native(), "run 4 < 5 times");
    assert_eq!(jit.counts(), (2, 3));
    assert!(jit.time() > std::time::Duration::ZERO);
    // `compile_all` compiles the rest now, and later programs when attached.
    jit.compile_all([&hot, &cold, &empty]);
    assert!(cold.is_native());
    let late = tiny();
    jit.attach(&late, true);
    assert!(late.is_native());
    assert_eq!(jit.counts(), (4, 4));
}

/// Threads sharing a program (a model shared by sweep threads) compile
/// it once, all get the interpreter's bits before and after, and the
/// budget of code per model holds: a program beyond it stays interpreted.
#[test]
fn tier_up_is_shared_and_budgeted() {
    let jit = Jit::new(50).expect("a supported machine");
    let p = tiny();
    jit.attach(&p, true);
    let x = [1.5, 0.25, -3.0, 0.0];
    let reference = run_bits(&tiny(), &x);
    std::thread::scope(|s| {
        for _ in 0..4 {
            s.spawn(|| {
                for _ in 0..100 {
                    assert_eq!(run_bits(&p, &x), reference);
                }
            });
        }
    });
    assert!(p.is_native());
    assert_eq!(jit.counts(), (1, 1), "compiled once");
    // Programs until the budget is spent: the ones that do not fit stay
    // interpreted and still compute the same bits.
    let eager = Jit::new(0).expect("a supported machine");
    let fit = MAX_TOTAL_OPS / (tiny().len() + FUNCTION_COST);
    let programs: Vec<Program> = (0..fit + 3).map(|_| tiny()).collect();
    for p in &programs {
        eager.attach(p, false);
    }
    assert_eq!(eager.counts(), (fit, fit + 3));
    assert!(programs[..fit].iter().all(Program::is_native));
    assert!(!programs[fit].is_native());
    assert_eq!(run_bits(&programs[fit + 2], &x), reference);
}

/// Values the matrix tests draw states and coefficients from: ±1 (the
/// coefficients the scalar code does not multiply by), signed zeros,
/// infinities, NaN and ordinary numbers.
const MATRIX_VALUES: [f64; 12] = [
    1.0,
    -1.0,
    0.0,
    -0.0,
    0.5,
    -2.75,
    3.0,
    1e300,
    f64::INFINITY,
    f64::NEG_INFINITY,
    f64::NAN,
    3.0e-310,
];

/// A random sequence of 2 × 2 matrix operations (entries row-major) over
/// the states, the states swapped and earlier results, as the checker
/// scalarizes them: products (products summed), sums, differences,
/// scaled and shifted matrices, negations, quotients and products with
/// a constant matrix (sums with a coefficient per term). Entries `(i, 0)`
/// and `(i, 1)` are isomorphic instructions, which pair.
fn matrices(steps: &[(u8, usize, usize, usize, usize)]) -> (Dag, Vec<NodeId>) {
    let mut dag = Dag::default();
    let x: Vec<NodeId> = (0..4).map(|k| dag.state(k)).collect();
    let mut mats = vec![x.clone(), vec![x[1], x[0], x[3], x[2]]];
    for &(kind, i, j, c0, c1) in steps {
        let (a, b) = (mats[i % mats.len()].clone(), mats[j % mats.len()].clone());
        let (c0, c1) = (
            MATRIX_VALUES[c0 % MATRIX_VALUES.len()],
            MATRIX_VALUES[c1 % MATRIX_VALUES.len()],
        );
        let (k0, k1) = (dag.konst(c0), dag.konst(c1));
        let m: Vec<NodeId> = (0..4)
            .map(|e| {
                let (r, c) = (e / 2, e % 2);
                match kind % 8 {
                    0 => {
                        let p = dag.bin(BinFn::Mul, a[2 * r], b[c]);
                        let q = dag.bin(BinFn::Mul, a[2 * r + 1], b[2 + c]);
                        dag.bin(BinFn::Add, p, q)
                    }
                    1 => dag.bin(BinFn::Add, a[e], b[e]),
                    2 => dag.bin(BinFn::Sub, a[e], b[e]),
                    3 => dag.bin(BinFn::Mul, a[e], k0),
                    4 => dag.un(UnFn::Neg, a[e]),
                    5 => dag.bin(BinFn::Div, a[e], b[e]),
                    6 => {
                        // A · [c0 c1; c1 c0]: a coefficient per term.
                        let (u, v) = if c == 0 { (k0, k1) } else { (k1, k0) };
                        let p = dag.bin(BinFn::Mul, u, a[2 * r]);
                        let q = dag.bin(BinFn::Mul, a[2 * r + 1], v);
                        let s = dag.bin(BinFn::Sub, p, q);
                        dag.bin(BinFn::Add, s, k1)
                    }
                    _ => dag.bin(BinFn::Add, a[e], k1),
                }
            })
            .collect();
        mats.push(m);
    }
    let outs = mats.iter().rev().take(3).flatten().copied().collect();
    (dag, outs)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]
    /// Matrix work, whose instructions go in pairs through vector
    /// instructions, computes the interpreter's results to the last bit,
    /// its outputs in the register file or at positions in a buffer.
    #[test]
    fn paired_instructions_are_bit_identical(
        steps in prop::collection::vec(
            (0u8..8, 0usize..16, 0usize..16, 0usize..12, 0usize..12), 8..32),
        x in prop::array::uniform4(0usize..12),
    ) {
        let (dag, outs) = matrices(&steps);
        let x = x.map(|k| MATRIX_VALUES[k]);
        let p = Program::compile(&dag, FRAME, &outs);
        let (i, j) = both(&p, &x);
        prop_assert_eq!(&i, &j);
        let [interpreted, native, at] = both_into(&p, &x);
        prop_assert_eq!(&interpreted, &i);
        prop_assert_eq!(&native, &i);
        prop_assert_eq!(&at, &i);
        let q = p.clone().into_buffer();
        let jitted = compiled(&q, true);
        let hybrid = HybridTime { t: 0.5, j: 3 };
        let mut regs = vec![f64::NAN; q.nregs.max(FRAME.fixed())];
        let mut got = vec![0.0; outs.len()];
        jitted.run_into(&mut regs, hybrid, &x, None, &mut got);
        let bits: Vec<u64> =
            got.iter().map(|&v| if v.is_nan() { f64::NAN } else { v }.to_bits()).collect();
        prop_assert_eq!(&bits, &i);
    }
}

/// The entries of matrix products go in pairs: fewer instructions than
/// the scalar code, the same bits.
#[test]
fn matrix_products_pair() {
    let steps: Vec<(u8, usize, usize, usize, usize)> = vec![
        (3, 0, 0, 6, 0),
        (0, 2, 0, 0, 0),
        (0, 3, 2, 0, 0),
        (6, 4, 0, 4, 5),
        (2, 5, 3, 0, 0),
    ];
    let (dag, outs) = matrices(&steps);
    let p = Program::compile(&dag, FRAME, &outs);
    let plan = super::pairs::plan(&p, |_| false);
    let pairs = (0..p.ops.len())
        .filter(|&i| plan.partner(i).is_some())
        .count();
    assert!(pairs >= 8, "{pairs} pairs in {:?}", p.ops);
    for x in [[0.3, -1.1, 2.5, 0.7], [f64::NAN, -0.0, f64::INFINITY, 1.0]] {
        let (i, j) = both(&p, &x);
        assert_eq!(i, j, "x = {x:?}");
    }
}
