use proptest::prelude::*;

use super::*;
use crate::check::dag::{Dag, NodeId, eval_bin, eval_un};
use crate::ir::program::Frame;

const UNS: [UnFn; 19] = [
    UnFn::Neg,
    UnFn::Abs,
    UnFn::Sqrt,
    UnFn::Exp,
    UnFn::Log,
    UnFn::Sin,
    UnFn::Cos,
    UnFn::Tan,
    UnFn::Atan,
    UnFn::Tanh,
    UnFn::Asin,
    UnFn::Acos,
    UnFn::Sinh,
    UnFn::Cosh,
    UnFn::Sign,
    UnFn::Floor,
    UnFn::Ceil,
    UnFn::Round,
    UnFn::Not,
];

const BINS: [BinFn; 19] = [
    BinFn::Add,
    BinFn::Sub,
    BinFn::Mul,
    BinFn::Div,
    BinFn::Pow,
    BinFn::Min,
    BinFn::Max,
    BinFn::Atan2,
    BinFn::Mod,
    BinFn::Rem,
    BinFn::Hypot,
    BinFn::Lt,
    BinFn::Le,
    BinFn::Gt,
    BinFn::Ge,
    BinFn::Eq,
    BinFn::Ne,
    BinFn::And,
    BinFn::Or,
];

fn iv(lo: f64, hi: f64) -> Interval {
    Interval::new(lo, hi, false)
}

/// Points of `[lo, hi]`: its ends, its integers and halves near them, and
/// an even grid.
fn samples(a: Interval) -> Vec<f64> {
    let mut v = vec![a.lo, a.hi];
    for k in 0..=64 {
        v.push(a.lo + (a.hi - a.lo) * f64::from(k) / 64.0);
    }
    let (lo, hi) = (a.lo.max(-50.0).ceil(), a.hi.min(50.0).floor());
    let mut k = lo;
    while k <= hi {
        v.extend([k, k - 0.5, k + 0.5, k.next_down(), k.next_up()]);
        k += 1.0;
    }
    v.retain(|p| a.contains(*p));
    if a.nan {
        v.push(f64::NAN);
    }
    v
}

const BOXES: [(f64, f64); 14] = [
    (0.0, 0.0),
    (0.3, 0.3),
    (-1.0, 1.0),
    (0.5, 2.0),
    (-3.0, -0.25),
    (0.9, 1.1),
    (-2.5, 7.0),
    (1.0, 3.0),
    (1.4, 1.8),
    (-0.1, 0.1),
    (3.0, 3.0),
    (-2.0, -2.0),
    (100.0, 100.5),
    (-1e3, 1e3),
];

#[test]
fn every_unary_function_contains_its_values() {
    for f in UNS {
        for &(lo, hi) in &BOXES {
            for nan in [false, true] {
                let a = Interval::new(lo, hi, nan);
                let r = un(f, a);
                for p in samples(a) {
                    let v = eval_un(f, p);
                    assert!(r.contains(v), "{f:?}({p}) = {v} outside {r:?} of {a:?}");
                }
            }
        }
    }
}

#[test]
fn every_binary_function_contains_its_values() {
    for f in BINS {
        for &(alo, ahi) in &BOXES {
            for &(blo, bhi) in &BOXES {
                let (a, b) = (iv(alo, ahi), iv(blo, bhi));
                let r = bin(f, a, b);
                let (sa, sb) = (samples(a), samples(b));
                for &p in sa.iter().step_by(3).chain(&sa[..2]) {
                    for &q in sb.iter().step_by(3).chain(&sb[..2]) {
                        let v = eval_bin(f, p, q);
                        assert!(
                            r.contains(v),
                            "{f:?}({p}, {q}) = {v} outside {r:?} of {a:?}, {b:?}"
                        );
                    }
                }
            }
        }
    }
}

#[test]
fn bounds_are_tight_where_the_function_is_simple() {
    let close = |r: Interval, lo: f64, hi: f64| {
        (r.lo - lo).abs() <= 1e-12 * lo.abs().max(1.0)
            && (r.hi - hi).abs() <= 1e-12 * hi.abs().max(1.0)
            && !r.nan
    };
    // sin: monotone part, an interior maximum, a full period.
    assert!(close(un(UnFn::Sin, iv(0.0, 1.0)), 0.0, 1f64.sin()));
    assert!(close(
        un(UnFn::Sin, iv(1.0, 2.0)),
        1f64.sin().min(2f64.sin()),
        1.0
    ));
    assert!(close(un(UnFn::Sin, iv(0.0, 7.0)), -1.0, 1.0));
    assert!(close(un(UnFn::Cos, iv(-0.5, 0.25)), 0.5f64.cos(), 1.0));
    assert!(close(
        un(UnFn::Cos, iv(3.0, 3.5)),
        -1.0,
        3f64.cos().max(3.5f64.cos())
    ));
    // tan: a branch, and a pole inside.
    assert!(close(
        un(UnFn::Tan, iv(-1.0, 1.0)),
        -(1f64.tan()),
        1f64.tan()
    ));
    assert_eq!(un(UnFn::Tan, iv(1.0, 2.0)), Interval::ENTIRE);
    // mod: no discontinuity inside (exact), and one inside (its range).
    assert!(close(
        bin(BinFn::Mod, iv(2.25, 2.75), Interval::point(1.0)),
        0.25,
        0.75
    ));
    let m = bin(BinFn::Mod, iv(0.75, 1.25), Interval::point(1.0));
    assert!(m.lo <= 0.0 && m.lo > -1e-12 && m.hi >= 1.0 && m.hi < 1.0 + 1e-12 && !m.nan);
    assert!(close(
        bin(BinFn::Rem, iv(-2.75, -2.25), Interval::point(1.0)),
        -0.75,
        -0.25
    ));
    // An infinite divisor: the scalar mod and rem are NaN there (∞·0), which the bound holds.
    for f in [BinFn::Mod, BinFn::Rem] {
        for b in [f64::NEG_INFINITY, f64::INFINITY] {
            let bound = bin(f, Interval::point(-3.3), Interval::point(b));
            assert!(
                bound.contains(eval_bin(f, -3.3, b)),
                "{f:?} by {b}: {bound:?}"
            );
        }
    }
    // floor and friends are exact.
    assert_eq!(un(UnFn::Floor, iv(0.5, 2.5)), iv(0.0, 2.0));
    // Division by an interval holding 0.
    assert_eq!(
        bin(BinFn::Div, iv(1.0, 2.0), iv(-1.0, 1.0)),
        Interval::ENTIRE
    );
    // Powers: integer, even through 0, fractional, real exponent.
    assert!(close(
        bin(BinFn::Pow, iv(-2.0, 1.0), Interval::point(3.0)),
        -8.0,
        1.0
    ));
    assert!(close(
        bin(BinFn::Pow, iv(-2.0, 1.0), Interval::point(4.0)),
        0.0,
        16.0
    ));
    assert!(close(
        bin(BinFn::Pow, iv(4.0, 9.0), Interval::point(0.5)),
        2.0,
        3.0
    ));
    assert!(close(
        bin(BinFn::Pow, iv(2.0, 4.0), iv(-1.0, 2.0)),
        0.25,
        16.0
    ));
    assert!(bin(BinFn::Pow, iv(-1.0, 4.0), Interval::point(0.5)).nan);
    // (−∞)^2.5 = +∞ and (−∞)^−0.5 = +0 (IEEE), not only NaN.
    let neg_inf = Interval::new(f64::NEG_INFINITY, 0.0, false);
    assert!(bin(BinFn::Pow, neg_inf, Interval::point(2.5)).contains(f64::INFINITY));
    assert!(bin(BinFn::Pow, neg_inf, Interval::point(-0.5)).contains(0.0));
    // Comparisons and logic.
    assert_eq!(
        bin(BinFn::Lt, iv(0.0, 1.0), iv(2.0, 3.0)),
        Interval::point(1.0)
    );
    assert_eq!(
        bin(BinFn::Ge, iv(0.0, 1.0), iv(2.0, 3.0)),
        Interval::point(0.0)
    );
    assert_eq!(bin(BinFn::Le, iv(0.0, 2.0), iv(1.0, 3.0)), Interval::BOOL);
    assert_eq!(
        bin(BinFn::Eq, iv(1.0, 1.0), iv(1.0, 1.0)),
        Interval::point(1.0)
    );
    assert_eq!(
        bin(BinFn::Ne, iv(0.0, 1.0), iv(2.0, 2.0)),
        Interval::point(1.0)
    );
    let (t, u) = (Interval::point(1.0), Interval::BOOL);
    assert_eq!(bin(BinFn::And, t, iv(-2.0, -1.0)), t);
    assert_eq!(
        bin(BinFn::And, u, Interval::point(0.0)),
        Interval::point(0.0)
    );
    assert_eq!(bin(BinFn::Or, u, t), t);
    assert_eq!(un(UnFn::Not, iv(0.5, 1.0)), Interval::point(0.0));
    // atan2 off the branch cut, and across it.
    assert!(close(
        bin(BinFn::Atan2, iv(1.0, 2.0), iv(1.0, 2.0)),
        0.5f64.atan(),
        2f64.atan()
    ));
    assert!(close(
        bin(BinFn::Atan2, iv(-1.0, 1.0), iv(-2.0, -1.0)),
        -PI,
        PI
    ));
    // sqrt below 0 may be NaN; the values above it are bounded.
    let s = un(UnFn::Sqrt, iv(-1.0, 4.0));
    assert!(s.nan && s.lo == 0.0 && (s.hi - 2.0).abs() < 1e-12);
}

/// A random scalar graph over 4 states, t and j using every function,
/// selects, table lookups and interpolation; each step may reuse any
/// earlier node.
fn build(steps: &[(u8, u8, usize, usize, f64)]) -> (Dag, Vec<NodeId>) {
    let mut dag = Dag::default();
    let mut nodes: Vec<NodeId> = (0..4).map(|k| dag.state(k)).collect();
    nodes.push(dag.time());
    nodes.push(dag.jumps());
    let entries: Vec<NodeId> = [0.5, -1.0, 2.0, 3.0, -4.0, 0.25]
        .iter()
        .map(|&v| dag.konst(v))
        .collect();
    let grid = dag.table(&entries, 2, 3).expect("constants");
    let curve: Vec<NodeId> = [-1.0, 0.0, 2.0, 1.0, -3.0, 0.5]
        .iter()
        .map(|&v| dag.konst(v))
        .collect();
    let curve = dag.table(&curve, 2, 3).expect("constants");
    for &(kind, g, i, j, c) in steps {
        let (a, b) = (nodes[i % nodes.len()], nodes[j % nodes.len()]);
        let k = dag.konst(c);
        let id = match kind % 8 {
            0 => dag.un(UNS[g as usize % UNS.len()], a),
            1 => dag.bin(BINS[g as usize % BINS.len()], a, b),
            2 => dag.bin(BINS[g as usize % BINS.len()], a, k),
            3 => dag.bin(BINS[g as usize % BINS.len()], k, b),
            4 => {
                let cond = nodes[(i + j) % nodes.len()];
                dag.select(cond, a, b)
            }
            5 => {
                let one = dag.konst(1.0);
                let row = dag.un(UnFn::Round, a);
                let col = dag.bin(BinFn::Mod, b, k);
                let col = dag.un(UnFn::Floor, col);
                let col = dag.bin(BinFn::Add, col, one);
                dag.lookup(grid, row, col, 0, one).expect("run-time lookup")
            }
            6 => dag.interp(curve, a, g % 2 == 0),
            _ => dag.bin(BinFn::Mul, a, a),
        };
        nodes.push(id);
    }
    let outs = nodes.iter().rev().take(3).copied().collect();
    (dag, outs)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]
    /// At every point of the box where no needed table index fails the
    /// scalar program's value (NaN included) lies in the interval
    /// program's bound.
    #[test]
    fn random_programs_stay_inside_their_bounds(
        steps in prop::collection::vec((0u8..8, 0u8..19, 0usize..64, 0usize..64, -3.0f64..3.0), 1..24),
        centers in prop::array::uniform5(-4.0f64..4.0),
        widths in prop::array::uniform5(prop_oneof![Just(0.0), 0.0f64..0.5, 0.0f64..4.0]),
        j in 0u32..4,
        points in prop::collection::vec(prop::array::uniform5(0.0f64..=1.0), 6),
    ) {
        let (dag, outs) = build(&steps);
        let p = Program::compile(&dag, Frame { n: 4, m: 0 }, &outs).into_buffer();
        let boxes: Vec<Interval> = centers
            .iter()
            .zip(&widths)
            .map(|(&c, &w)| Interval::new(c - w / 2.0, c + w / 2.0, false))
            .collect();
        let mut file = IntervalRegs::default();
        let mut bounds = vec![Interval::ENTIRE; outs.len()];
        p.bound_into(&mut file, boxes[4], f64::from(j), &boxes[..4], &mut bounds);
        let mut regs = vec![0.0; p.nregs];
        // The ends of the box too.
        let corners = [[0.0; 5], [1.0; 5]];
        for u in points.iter().chain(&corners) {
            for k in 0..5 {
                let b = boxes[k];
                regs[k] = (b.lo + (b.hi - b.lo) * u[k]).clamp(b.lo, b.hi);
            }
            regs[5] = f64::from(j);
            p.interpret(&mut regs, None);
            // A point where a needed index is bad stops the run (E0604):
            // the bounds need not hold its NaN.
            if crate::ir::program::take_index_fault().is_some() {
                continue;
            }
            for (k, &o) in p.outs.iter().enumerate() {
                let v = regs[o as usize];
                prop_assert!(
                    bounds[k].contains(v),
                    "output {} = {} outside {:?} at {:?}",
                    k, v, bounds[k], &regs[..6]
                );
            }
        }
    }
}

/// A lookup's bound is the hull of the entries at the integer indices in
/// range its index boxes hold: a mode constant along flows, whose box is
/// its value widened by a few roundings, reads its one entry (it read
/// nothing bounded, so `tau >= d[q]` was never proved on a step), and
/// indices past the table's ends or between integers are left out (the
/// evaluation faults there).
#[test]
fn a_lookup_is_bounded_by_the_entries_at_the_integers_its_boxes_hold() {
    let table = Table {
        rows: 3,
        cols: 1,
        data: vec![0.3, 1.1, 0.45].into_boxed_slice(),
    };
    let one = Interval::point(1.0);
    let q = iv(2.0 - 4.0 * f64::EPSILON, 2.0 + 4.0 * f64::EPSILON);
    let b = lookup(&table, q, one);
    assert!(!b.nan && b.lo == 1.1 && b.hi == 1.1, "{b:?}");
    let b = lookup(&table, iv(1.5, 7.0), one);
    assert!(!b.nan && b.lo == 0.45 && b.hi == 1.1, "{b:?}");
    let b = lookup(&table, iv(0.0, 1.0), one);
    assert!(!b.nan && b.lo == 0.3 && b.hi == 0.3, "{b:?}");
    // No integer in range: nothing can be read.
    assert_eq!(lookup(&table, iv(2.2, 2.8), one), Interval::ENTIRE);
    assert_eq!(lookup(&table, iv(4.0, 9.0), one), Interval::ENTIRE);
}
