//! Interval evaluation of register programs: every register holds an
//! [`Interval`] that contains the value the scalar program computes (to the
//! last bit, NaN included) at every point of the input box.
//!
//! Bounds are conservative: results of correctly rounded operations are
//! widened by one ulp outward, those of library functions (`exp`, `sin`,
//! `powf`, …, not correctly rounded) by a relative 2⁻⁵⁰ and one ulp; a
//! result that may be NaN carries the [`Interval::nan`] flag. The engine
//! uses it to prove that an atom keeps its sign between two checkpoints
//! (see [`HybridSystem::atom_bounds`](crate::engine::HybridSystem::atom_bounds)).

use std::f64::consts::{FRAC_PI_2, PI, TAU};

use super::program::{CONST_TERM, Op, Program};
use crate::check::dag::{BinFn, Table, UnFn};

/// A closed interval `[lo, hi]` (`lo ≤ hi`, infinite ends allowed) of the
/// values an expression can take, and whether it may also be NaN.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Interval {
    pub lo: f64,
    pub hi: f64,
    /// The value may be NaN.
    pub nan: bool,
}

/// Relative widening of a library function's result.
const REL: f64 = 1.0 / (1u64 << 50) as f64;

impl Interval {
    /// Anything, NaN included.
    pub const ENTIRE: Interval = Interval {
        lo: f64::NEG_INFINITY,
        hi: f64::INFINITY,
        nan: true,
    };
    /// A comparison's or logic operation's unknown result.
    const BOOL: Interval = Interval {
        lo: 0.0,
        hi: 1.0,
        nan: false,
    };

    /// `{v}` (ENTIRE for NaN).
    pub fn point(v: f64) -> Self {
        if v.is_nan() {
            Self::ENTIRE
        } else {
            Interval {
                lo: v,
                hi: v,
                nan: false,
            }
        }
    }

    /// `[lo, hi]` as given (exact ends), ENTIRE if an end is NaN.
    pub fn new(lo: f64, hi: f64, nan: bool) -> Self {
        if lo.is_nan() || hi.is_nan() {
            return Self::ENTIRE;
        }
        Interval {
            lo: lo.min(hi),
            hi: lo.max(hi),
            nan,
        }
    }

    /// `[lo, hi]` widened by one ulp each way: the hull of a correctly
    /// rounded operation's results.
    fn rounded(lo: f64, hi: f64, nan: bool) -> Self {
        Self::new(lo.next_down(), hi.next_up(), nan)
    }

    /// `[lo, hi]` widened by a relative 2⁻⁵⁰ and one ulp each way: the hull
    /// of a library function's results.
    fn approx(lo: f64, hi: f64, nan: bool) -> Self {
        let widen = |v: f64| if v.is_finite() { v.abs() * REL } else { 0.0 };
        Self::new(
            (lo - widen(lo)).next_down(),
            (hi + widen(hi)).next_up(),
            nan,
        )
    }

    /// `{b}` for a known comparison result, else `[0, 1]`.
    fn boolean(b: Option<bool>) -> Self {
        match b {
            Some(b) => Self::point(if b { 1.0 } else { 0.0 }),
            None => Self::BOOL,
        }
    }

    /// Whether `v` (a value at a point of the box) is inside.
    #[cfg(test)]
    pub fn contains(self, v: f64) -> bool {
        if v.is_nan() {
            self.nan
        } else {
            (self.lo..=self.hi).contains(&v)
        }
    }

    /// The smallest interval containing both.
    pub fn hull(self, o: Self) -> Self {
        Interval {
            lo: self.lo.min(o.lo),
            hi: self.hi.max(o.hi),
            nan: self.nan || o.nan,
        }
    }

    fn is_point(self) -> bool {
        self.lo == self.hi && !self.nan
    }

    fn with_nan(self, nan: bool) -> Self {
        Interval {
            nan: self.nan || nan,
            ..self
        }
    }

    fn clamp(self, lo: f64, hi: f64) -> Self {
        Interval {
            lo: self.lo.max(lo),
            hi: self.hi.min(hi),
            nan: self.nan,
        }
    }

    /// As a condition (nonzero is true, NaN too): `Some` when every value
    /// gives the same answer.
    fn truth(self) -> Option<bool> {
        if self.lo > 0.0 || self.hi < 0.0 {
            Some(true)
        } else if self.lo == 0.0 && self.hi == 0.0 && !self.nan {
            Some(false)
        } else {
            None
        }
    }

    /// The smallest and largest absolute value.
    fn abs_range(self) -> (f64, f64) {
        if self.lo >= 0.0 {
            (self.lo, self.hi)
        } else if self.hi <= 0.0 {
            (-self.hi, -self.lo)
        } else {
            (0.0, (-self.lo).max(self.hi))
        }
    }

    fn contains_zero(self) -> bool {
        self.lo <= 0.0 && self.hi >= 0.0
    }
}

fn add(a: Interval, b: Interval) -> Interval {
    Interval::rounded(a.lo + b.lo, a.hi + b.hi, a.nan || b.nan)
}

fn sub(a: Interval, b: Interval) -> Interval {
    Interval::rounded(a.lo - b.hi, a.hi - b.lo, a.nan || b.nan)
}

/// The hull of `f` at the four corners (NaN at one: ENTIRE), widened by
/// `wide`.
fn corners(
    a: Interval,
    b: Interval,
    f: impl Fn(f64, f64) -> f64,
    wide: fn(f64, f64, bool) -> Interval,
) -> Interval {
    let v = [f(a.lo, b.lo), f(a.lo, b.hi), f(a.hi, b.lo), f(a.hi, b.hi)];
    if v.iter().any(|v| v.is_nan()) {
        return Interval::ENTIRE;
    }
    let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    wide(lo, hi, a.nan || b.nan)
}

fn mul(a: Interval, b: Interval) -> Interval {
    corners(a, b, |x, y| x * y, Interval::rounded)
}

/// `a·c` for a constant `c` (the rows of `A·x`): two products.
fn mul_const(a: Interval, c: f64) -> Interval {
    let (p, q) = (a.lo * c, a.hi * c);
    if p.is_nan() || q.is_nan() {
        return mul(a, Interval::point(c));
    }
    Interval::rounded(p.min(q), p.max(q), a.nan)
}

fn div(a: Interval, b: Interval) -> Interval {
    if b.contains_zero() {
        return Interval::ENTIRE;
    }
    corners(a, b, |x, y| x / y, Interval::rounded)
}

/// `a·a` (the scalar program's `a^2`).
fn square(a: Interval) -> Interval {
    let (lo, hi) = a.abs_range();
    Interval::rounded(lo * lo, hi * hi, a.nan).clamp(0.0, f64::INFINITY)
}

/// `sin` (`cos`: `cos`) on `a`: the hull of the ends' values, and ±1 where
/// an extremum (`π/2 + 2kπ`, `−π/2 + 2kπ`; for cos `2kπ`, `π + 2kπ`) may
/// lie inside.
fn trig(a: Interval, cos: bool) -> Interval {
    let full = Interval {
        lo: -1.0,
        hi: 1.0,
        nan: a.nan,
    };
    if !(a.lo.is_finite() && a.hi.is_finite()) {
        return full.with_nan(true);
    }
    // Beyond 2^40 the phase below is not computed to a useful accuracy.
    if a.hi - a.lo >= TAU || a.lo.abs().max(a.hi.abs()) > (1u64 << 40) as f64 {
        return full;
    }
    let f = if cos { f64::cos } else { f64::sin };
    let (fa, fb) = (f(a.lo), f(a.hi));
    let mut r = Interval::approx(fa.min(fb), fa.max(fb), a.nan).clamp(-1.0, 1.0);
    // Whether `phase + 2kπ` may lie in [lo, hi] for some integer k (with a
    // margin for the rounding of the quotients and of π).
    let reaches = |phase: f64| {
        let u0 = (a.lo - phase) / TAU;
        let u1 = (a.hi - phase) / TAU;
        let eps = 1e-12 + u0.abs().max(u1.abs()) * 1e-14;
        (u0 - eps).ceil() <= (u1 + eps).floor()
    };
    let (max_at, min_at) = if cos {
        (0.0, PI)
    } else {
        (FRAC_PI_2, -FRAC_PI_2)
    };
    if reaches(max_at) {
        r.hi = 1.0;
    }
    if reaches(min_at) {
        r.lo = -1.0;
    }
    r
}

/// `tan` on `a`: increasing between its poles `π/2 + kπ`; ENTIRE if one
/// may lie inside.
fn tan(a: Interval) -> Interval {
    if !(a.lo.is_finite() && a.hi.is_finite()) || a.hi - a.lo >= PI {
        return Interval::ENTIRE;
    }
    if a.lo.abs().max(a.hi.abs()) > (1u64 << 40) as f64 {
        return Interval::ENTIRE;
    }
    let u0 = (a.lo - FRAC_PI_2) / PI;
    let u1 = (a.hi - FRAC_PI_2) / PI;
    let eps = 1e-12 + u0.abs().max(u1.abs()) * 1e-14;
    if (u0 - eps).ceil() <= (u1 + eps).floor() {
        return Interval::ENTIRE;
    }
    Interval::approx(a.lo.tan(), a.hi.tan(), a.nan)
}

/// `f` nondecreasing: the hull of its ends' values, exact.
fn monotone(a: Interval, f: fn(f64) -> f64) -> Interval {
    Interval::new(f(a.lo), f(a.hi), a.nan)
}

/// `f` nondecreasing, a library function: widened.
fn monotone_approx(a: Interval, f: fn(f64) -> f64) -> Interval {
    Interval::approx(f(a.lo), f(a.hi), a.nan)
}

fn un(f: UnFn, a: Interval) -> Interval {
    match f {
        UnFn::Neg => Interval::new(-a.hi, -a.lo, a.nan),
        UnFn::Abs => {
            let (lo, hi) = a.abs_range();
            Interval::new(lo, hi, a.nan)
        }
        UnFn::Sqrt | UnFn::Log => {
            if a.hi < 0.0 {
                return Interval::ENTIRE;
            }
            let part = Interval::new(a.lo.max(0.0), a.hi, a.nan || a.lo < 0.0);
            if f == UnFn::Sqrt {
                Interval::rounded(part.lo.sqrt(), part.hi.sqrt(), part.nan)
                    .clamp(0.0, f64::INFINITY)
            } else {
                monotone_approx(part, f64::ln)
            }
        }
        UnFn::Exp => monotone_approx(a, f64::exp).clamp(0.0, f64::INFINITY),
        UnFn::Sin => trig(a, false),
        UnFn::Cos => trig(a, true),
        UnFn::Tan => tan(a),
        UnFn::Atan => {
            let lim = FRAC_PI_2.next_up();
            monotone_approx(a, f64::atan).clamp(-lim, lim)
        }
        UnFn::Tanh => monotone_approx(a, f64::tanh).clamp(-1.0, 1.0),
        UnFn::Asin | UnFn::Acos => {
            if a.hi < -1.0 || a.lo > 1.0 {
                return Interval::ENTIRE;
            }
            let nan = a.nan || a.lo < -1.0 || a.hi > 1.0;
            let (lo, hi) = (a.lo.max(-1.0), a.hi.min(1.0));
            if f == UnFn::Asin {
                let lim = FRAC_PI_2.next_up();
                Interval::approx(lo.asin(), hi.asin(), nan).clamp(-lim, lim)
            } else {
                // Decreasing.
                Interval::approx(hi.acos(), lo.acos(), nan).clamp(0.0, PI.next_up())
            }
        }
        UnFn::Sinh => monotone_approx(a, f64::sinh),
        UnFn::Cosh => {
            // Even, least (1) at 0.
            let (lo, hi) = a.abs_range();
            Interval::approx(lo.cosh(), hi.cosh(), a.nan).clamp(1.0, f64::INFINITY)
        }
        UnFn::Sign => {
            let s = |v: f64| crate::check::dag::eval_un(UnFn::Sign, v);
            let r = Interval::new(s(a.lo), s(a.hi), false);
            // sign(NaN) is 0.
            if a.nan {
                r.hull(Interval::point(0.0))
            } else {
                r
            }
        }
        UnFn::Floor => monotone(a, f64::floor),
        UnFn::Ceil => monotone(a, f64::ceil),
        UnFn::Round => monotone(a, f64::round),
        UnFn::Not => Interval::boolean(a.truth().map(|b| !b)),
    }
}

/// `a^b` as the scalar program computes it (`a·a` for `b = 2`, else
/// `powf`).
fn pow(a: Interval, b: Interval) -> Interval {
    if b.is_point() {
        let n = b.lo;
        if n == 2.0 {
            return square(a);
        }
        if n == 0.0 {
            // powf(x, 0) = 1, NaN included.
            return Interval::point(1.0);
        }
        if n.fract() == 0.0 {
            // An integer power: monotone on each side of 0, its extremum
            // (for n > 0 even) at 0, a pole at 0 for n < 0.
            if n < 0.0 && a.contains_zero() {
                return Interval::ENTIRE;
            }
            let (p, q) = (a.lo.powf(n), a.hi.powf(n));
            let r = Interval::approx(p.min(q), p.max(q), a.nan);
            return if a.lo < 0.0 && a.hi > 0.0 {
                r.hull(Interval::point(0.0))
            } else {
                r
            };
        }
        // A fractional power: NaN below 0, increasing (n > 0) or
        // decreasing above.
        if a.hi < 0.0 {
            return Interval::ENTIRE;
        }
        let (p, q) = (a.lo.max(0.0).powf(n), a.hi.powf(n));
        let r = Interval::approx(p.min(q), p.max(q), a.nan || a.lo < 0.0);
        // IEEE's (−∞)^n is +∞ (n > 0) or +0 (n < 0), not NaN.
        return if a.lo == f64::NEG_INFINITY {
            r.hull(Interval::point(a.lo.powf(n)))
        } else {
            r
        };
    }
    // powf(1, NaN) = 1: a NaN operand is not simply propagated.
    if a.nan || b.nan || a.lo < 0.0 {
        return Interval::ENTIRE;
    }
    // For a ≥ 0, a^b = exp(b·ln a), b·ln a bilinear: extrema at corners.
    corners(a, b, f64::powf, Interval::approx)
}

/// `mod(a, b)` (floored) or `rem(a, b)` (truncated): exact where the
/// integer quotient is one value over the box, else the range of the
/// remainder.
fn modulo(a: Interval, b: Interval, floored: bool) -> Interval {
    // An infinite divisor gives NaN (∞·0 in a − b·⌊a/b⌋) or ±∞.
    if b.contains_zero()
        || !(a.lo.is_finite() && a.hi.is_finite() && b.lo.is_finite() && b.hi.is_finite())
    {
        return Interval::ENTIRE;
    }
    let q = div(a, b);
    let int = if floored { f64::floor } else { f64::trunc };
    let nan = a.nan || b.nan;
    if q.lo.is_finite() && q.hi.is_finite() && int(q.lo) == int(q.hi) {
        return sub(a, mul(b, Interval::point(int(q.lo)))).with_nan(nan);
    }
    // The remainder's range, allowing for the rounding of a/b (a quotient
    // rounded up to an integer leaves a remainder of about −|a|·2⁻⁵³).
    let bmax = b.lo.abs().max(b.hi.abs());
    let m = (a.lo.abs().max(a.hi.abs()) + bmax) * REL;
    let (neg, pos) = if floored {
        (b.hi < 0.0, b.lo > 0.0)
    } else {
        (a.hi <= 0.0, a.lo >= 0.0)
    };
    let lo = if pos { -m } else { -bmax - m };
    let hi = if neg { m } else { bmax + m };
    Interval::new(lo, hi, nan)
}

fn atan2(y: Interval, x: Interval) -> Interval {
    if y.nan || x.nan {
        return Interval::ENTIRE;
    }
    // The box meets the branch cut (x ≤ 0, y = 0; ±0 give ±π) or the
    // origin: the whole range. Elsewhere the angle over the (convex) box
    // is spanned by its corners.
    if x.lo <= 0.0 && y.contains_zero() {
        return Interval::new(-PI.next_up(), PI.next_up(), false);
    }
    corners(y, x, f64::atan2, Interval::approx)
}

fn bin(f: BinFn, a: Interval, b: Interval) -> Interval {
    let cmp = |sure: bool, never: bool| {
        if a.nan || b.nan {
            Interval::BOOL
        } else {
            Interval::boolean(if sure {
                Some(true)
            } else if never {
                Some(false)
            } else {
                None
            })
        }
    };
    match f {
        BinFn::Add => add(a, b),
        BinFn::Sub => sub(a, b),
        BinFn::Mul => mul(a, b),
        BinFn::Div => div(a, b),
        BinFn::Pow => pow(a, b),
        BinFn::Min | BinFn::Max => {
            // f64::min/max return the other operand for a NaN one.
            if a.nan || b.nan {
                let h = a.hull(b);
                return Interval {
                    nan: a.nan && b.nan,
                    ..h
                };
            }
            if f == BinFn::Min {
                Interval::new(a.lo.min(b.lo), a.hi.min(b.hi), false)
            } else {
                Interval::new(a.lo.max(b.lo), a.hi.max(b.hi), false)
            }
        }
        BinFn::Atan2 => atan2(a, b),
        BinFn::Mod => modulo(a, b, true),
        BinFn::Rem => modulo(a, b, false),
        BinFn::Hypot => {
            if a.nan || b.nan {
                return Interval::ENTIRE;
            }
            let (a0, a1) = a.abs_range();
            let (b0, b1) = b.abs_range();
            Interval::approx(a0.hypot(b0), a1.hypot(b1), false).clamp(0.0, f64::INFINITY)
        }
        BinFn::Lt => cmp(a.hi < b.lo, a.lo >= b.hi),
        BinFn::Le => cmp(a.hi <= b.lo, a.lo > b.hi),
        BinFn::Gt => cmp(a.lo > b.hi, a.hi <= b.lo),
        BinFn::Ge => cmp(a.lo >= b.hi, a.hi < b.lo),
        BinFn::Eq | BinFn::Ne => {
            let same = a.is_point() && b.is_point() && a.lo == b.lo;
            let apart = a.hi < b.lo || b.hi < a.lo;
            // NaN == x is false, NaN != x true: only "apart" survives NaN.
            let (yes, no) = if f == BinFn::Eq {
                (same, apart)
            } else {
                (apart, same)
            };
            if a.nan || b.nan {
                Interval::boolean(apart.then_some(f == BinFn::Ne))
            } else {
                cmp(yes, no)
            }
        }
        BinFn::And | BinFn::Or => {
            let (p, q) = (a.truth(), b.truth());
            Interval::boolean(if f == BinFn::And {
                match (p, q) {
                    (Some(false), _) | (_, Some(false)) => Some(false),
                    (Some(true), Some(true)) => Some(true),
                    _ => None,
                }
            } else {
                match (p, q) {
                    (Some(true), _) | (_, Some(true)) => Some(true),
                    (Some(false), Some(false)) => Some(false),
                    _ => None,
                }
            })
        }
    }
}

/// The hull of the entries `table[row, col]` at the integer indices in
/// range that the index boxes hold. Their other points are left out: an
/// index there is not an integer or out of range, so the evaluation records
/// a fault (E0604) and the run stops, or the entry is not needed (`when` = 0,
/// the branch not taken) and its NaN reaches no value. Counting them as
/// NaN made every bound over a box slightly wider than its point unbounded:
/// a mode `q` constant along flows, whose box is widened by the rounding of
/// the path's control points, left `tau >= d[q]` unprovable on every step.
fn lookup(table: &Table, row: Interval, col: Interval) -> Interval {
    let range = |i: Interval, n: usize| {
        let lo = i.lo.ceil().max(1.0);
        let hi = i.hi.floor().min(n as f64);
        (lo <= hi).then_some((lo as usize, hi as usize))
    };
    let (Some((r0, r1)), Some((c0, c1))) = (range(row, table.rows), range(col, table.cols)) else {
        // No entry can be read: every point faults or is not needed.
        return Interval::ENTIRE;
    };
    let mut acc: Option<Interval> = None;
    for r in r0..=r1 {
        for c in c0..=c1 {
            let v = Interval::point(table.data[(r - 1) * table.cols + (c - 1)]);
            acc = Some(acc.map_or(v, |a| a.hull(v)));
        }
    }
    acc.unwrap_or(Interval::ENTIRE)
}

/// `interp` (or its slope) over `x`: the function is linear between its
/// breakpoints, so its hull is that of its values at `x`'s ends and at the
/// breakpoints inside (the slope: of the segments they start), widened for
/// the rounding of `y₀ + (x − x₀)·s`.
fn interp(table: &Table, x: Interval, slope: bool) -> Interval {
    let n = table.cols;
    let (xs, ys) = table.data.split_at(n);
    let at = |v: f64| Interval::point(table.interp(v, slope));
    let mut r = at(x.lo).hull(at(x.hi));
    let first = xs.partition_point(|&v| v <= x.lo);
    for &b in xs[first..].iter().take_while(|&&b| b <= x.hi) {
        r = r.hull(at(b));
    }
    if !slope {
        let ymax = ys.iter().fold(0.0f64, |m, y| m.max(y.abs()));
        let m = ymax * 4.0 * f64::EPSILON;
        r = Interval::rounded(r.lo - m, r.hi + m, r.nan);
    }
    r.with_nan(x.nan)
}

/// A reusable register file of intervals (and a buffer for the block
/// operations), so that repeated evaluations do not allocate.
#[derive(Debug, Default)]
pub(crate) struct IntervalRegs {
    regs: Vec<Interval>,
    block: Vec<f64>,
}

impl Program {
    /// Bounds the outputs over the box `x` (state components), `t` and the
    /// jump count `j`, writing output `k` to `out` at its position (as
    /// [`run_into`](Self::run_into) does). Noise registers are ENTIRE.
    pub(crate) fn bound_into(
        &self,
        file: &mut IntervalRegs,
        t: Interval,
        j: f64,
        x: &[Interval],
        out: &mut [Interval],
    ) {
        let n = self.state_regs;
        let regs = &mut file.regs;
        if regs.len() < self.nregs.max(n + 2) {
            regs.resize(self.nregs.max(n + 2), Interval::ENTIRE);
        }
        regs[..n].copy_from_slice(&x[..n]);
        regs[n] = t;
        regs[n + 1] = Interval::point(j);
        // The noise registers and temporaries: every temporary is written
        // before it is read, the noise registers never are.
        regs[n + 2..].fill(Interval::ENTIRE);
        self.bound_regs(regs, &mut file.block);
        for (d, r) in self.positions() {
            out[d] = regs[r as usize];
        }
    }

    /// Runs the program over intervals in `regs` (fixed registers filled).
    fn bound_regs(&self, regs: &mut [Interval], block: &mut Vec<f64>) {
        for op in &self.ops {
            match *op {
                Op::Const { d, c } => regs[d as usize] = Interval::point(c),
                Op::Add { d, a, b } => regs[d as usize] = add(regs[a as usize], regs[b as usize]),
                Op::Sub { d, a, b } => regs[d as usize] = sub(regs[a as usize], regs[b as usize]),
                Op::Mul { d, a, b } => {
                    // x·x is a square, not the product of two independent
                    // intervals.
                    regs[d as usize] = if a == b {
                        square(regs[a as usize])
                    } else {
                        mul(regs[a as usize], regs[b as usize])
                    }
                }
                Op::Div { d, a, b } => regs[d as usize] = div(regs[a as usize], regs[b as usize]),
                Op::AddC { d, a, c } => {
                    regs[d as usize] = add(regs[a as usize], Interval::point(c))
                }
                Op::MulC { d, a, c } => regs[d as usize] = mul_const(regs[a as usize], c),
                Op::BinRC { d, f, a, c } => {
                    regs[d as usize] = bin(f, regs[a as usize], Interval::point(c))
                }
                Op::BinCR { d, f, c, b } => {
                    regs[d as usize] = bin(f, Interval::point(c), regs[b as usize])
                }
                Op::Bin { d, f, a, b } => {
                    regs[d as usize] = bin(f, regs[a as usize], regs[b as usize])
                }
                Op::Neg { d, a } => regs[d as usize] = un(UnFn::Neg, regs[a as usize]),
                Op::Un { d, f, a } => regs[d as usize] = un(f, regs[a as usize]),
                Op::Select { d, c, a, b } => {
                    let (a, b) = (regs[a as usize], regs[b as usize]);
                    regs[d as usize] = match regs[c as usize].truth() {
                        Some(true) => a,
                        Some(false) => b,
                        None => a.hull(b),
                    }
                }
                Op::Rand { d, .. } => regs[d as usize] = Interval::ENTIRE,
                Op::Lookup {
                    d, table, row, col, ..
                } => {
                    regs[d as usize] = lookup(
                        &self.tables[table as usize],
                        regs[row as usize],
                        regs[col as usize],
                    )
                }
                Op::Interp { d, table, x, slope } => {
                    regs[d as usize] = interp(&self.tables[table as usize], regs[x as usize], slope)
                }
                Op::Lin { d, t0, len } => {
                    let terms = &self.lin[t0 as usize..(t0 + len) as usize];
                    let term = |&(r, c): &(u32, f64)| {
                        if r == CONST_TERM {
                            Interval::point(c)
                        } else {
                            mul_const(regs[r as usize], c)
                        }
                    };
                    let mut acc = term(&terms[0]);
                    for t in &terms[1..] {
                        acc = add(acc, term(t));
                    }
                    regs[d as usize] = acc;
                }
                Op::Block {
                    kind, g0, len, out, ..
                } => {
                    let (g0, len, out) = (g0 as usize, len as usize, out as usize);
                    let srcs = &self.gather[g0..g0 + len];
                    let outs = kind.outputs();
                    // Point inputs (a matrix of parameters and the jump
                    // count): the block's own value; else nothing known
                    // but a norm's sign.
                    if srcs.iter().all(|&s| regs[s as usize].is_point()) {
                        block.clear();
                        block.extend(srcs.iter().map(|&s| regs[s as usize].lo));
                        block.resize(len + outs, 0.0);
                        let (inp, res) = block.split_at_mut(len);
                        let ok = kind.apply(inp, res);
                        for (k, &v) in res.iter().enumerate() {
                            regs[out + k] = Interval::approx(v, v, !ok);
                        }
                    } else {
                        let r = match kind {
                            crate::check::dag::BlockKind::Norm2 { .. } => Interval {
                                lo: 0.0,
                                hi: f64::INFINITY,
                                nan: true,
                            },
                            _ => Interval::ENTIRE,
                        };
                        regs[out..out + outs].fill(r);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests;
