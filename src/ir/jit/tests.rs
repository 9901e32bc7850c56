//! Machine code against the interpreter, bit for bit.

use proptest::prelude::*;

use super::compile;
use crate::check::dag::{BinFn, BlockKind, Dag, Dist, NodeId, UnFn};
use crate::engine::SimRng;
use crate::ir::program::{Frame, Program};

/// Every unary function (the match makes a new variant a compile error
/// here until it is listed).
fn all_un() -> Vec<UnFn> {
    use UnFn::*;
    let all = vec![
        Neg, Abs, Sqrt, Exp, Log, Sin, Cos, Tan, Atan, Tanh, Sign, Floor, Ceil, Round, Not,
    ];
    for f in &all {
        match f {
            Neg | Abs | Sqrt | Exp | Log | Sin | Cos | Tan | Atan | Tanh | Sign | Floor | Ceil
            | Round | Not => {}
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

/// Runs `p` interpreted and as machine code on state `x` (time 0.5, jump
/// counter 3) with generators of the same seed; the outputs' bits of both. NaN counts as
/// one value: which NaN an operation on two NaNs returns depends on the
/// order in which a compiler puts the operands of `+`, and nothing
/// downstream can tell (every comparison with NaN is false).
fn both(p: &Program, x: &[f64; 4]) -> (Vec<u64>, Vec<u64>) {
    let mut jitted = p.clone();
    assert_eq!(compile(&mut [&mut jitted], 1).unwrap(), 1);
    assert!(jitted.is_native());
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

/// A register file shorter than the program's is refused, not overrun.
#[test]
#[should_panic(expected = "register file")]
fn short_register_file_is_refused() {
    let mut dag = Dag::default();
    let x = dag.state(3);
    let y = dag.un(UnFn::Sin, x);
    let mut p = Program::compile(&dag, FRAME, &[y]);
    compile(&mut [&mut p], 0).unwrap();
    let mut regs = vec![0.0; 2];
    p.run(&mut regs, None);
}
