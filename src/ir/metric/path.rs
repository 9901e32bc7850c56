//! Metrics on a step's path ([`FlowPiece`]): integrals and means by
//! adaptive quadrature, and the points where a window opens or closes
//! inside the step, found by bisection (they bound the window's integrals
//! and feed its extremes and finals).
//!
//! A step's path is smooth (a polynomial interpolant, or the exact solution
//! of an affine or polynomial flow). Its ends are shared: the start is the
//! previous step's end or sample, the end is evaluated on the step's own end
//! state and kept for the sample there. The midpoint then tells whether the
//! integrand is straight along the step (Simpson's rule agrees with the
//! trapezoid's: one evaluation per step); if not, Gauss–Legendre's three
//! points (the midpoint shared, exact to degree 5) are checked against
//! Simpson's, and the step is halved until they agree to the solver's
//! `rtol`, within a budget of evaluations per step.

use super::{Acc, Metrics, PathGroup};
use crate::arc::{FlowPiece, HybridTime};

/// The first Gauss–Legendre node on [0, 1] of three: (1 − √(3/5)) / 2.
const NODE: f64 = 0.112_701_665_379_258_31;
/// Deepest halving of a step.
const MAX_DEPTH: u32 = 24;
/// Evaluations of the sample program per step and window group before the
/// quadrature accepts what it has (a singular integrand).
const BUDGET: usize = 4_000;

/// The relative agreement of two quadratures of a step that accepts the
/// better one: the path's own accuracy (the solver's `rtol`), within
/// [1e-13, 1e-6]. The difference estimates the error of the worse rule; the
/// better one's is far smaller.
fn tolerance(accuracy: f64) -> f64 {
    if accuracy.is_finite() {
        accuracy.clamp(1e-13, 1e-6)
    } else {
        1e-10
    }
}

/// Buffers reused across steps.
#[derive(Debug, Default)]
pub(super) struct Scratch {
    /// The state at a point of the step.
    x: Vec<f64>,
    /// The sample program's values at points of the step, one row each
    /// (a stack: a halving pushes its points and pops them when done).
    rows: Vec<f64>,
    /// The time of each row.
    times: Vec<HybridTime>,
    /// Per-integral Simpson sums of the intervals in progress (a stack).
    sums: Vec<f64>,
}

/// The values at the ends of a step: the start given by the caller (row 0),
/// the end left in row 1 for the sample there.
pub(super) struct Ends<'v> {
    /// The sample program's values at the step's start, if known.
    pub start: Option<&'v [f64]>,
    /// Receives the values at the step's end.
    pub end: &'v mut Vec<f64>,
    /// Receives the state at the step's end.
    pub end_x: &'v mut Vec<f64>,
}

/// Adds one step's contributions to the integrals and means, and the points
/// where windows open or close in it to the windowed extremes and finals.
pub(super) fn integrate_piece(
    m: &Metrics,
    acc: &mut [Acc],
    scratch: &mut Scratch,
    piece: &mut FlowPiece<'_>,
    ends: Ends<'_>,
) {
    let width = m.sample.outs.len();
    scratch.x.resize(m.n, 0.0);
    scratch.rows.clear();
    scratch.times.clear();
    scratch.sums.clear();
    let mut walk = Walk {
        m,
        acc,
        scratch,
        tol: tolerance(piece.accuracy),
        piece,
        width,
        evals: 0,
    };
    match ends.start {
        Some(v) => {
            let t0 = walk.piece.t0;
            walk.scratch.rows.extend_from_slice(v);
            walk.scratch.times.push(HybridTime::new(t0, walk.piece.j));
        }
        None => {
            walk.eval(0.0);
        }
    }
    walk.eval(1.0);
    ends.end_x.clear();
    ends.end_x.extend_from_slice(&walk.scratch.x);
    // The midpoint serves integrals only: windowed extremes and finals read
    // the ends (and the boundary between them).
    let mid = if m.path_groups.iter().any(|g| !g.integrals.is_empty()) {
        walk.eval(0.5)
    } else {
        1
    };
    for g in &m.path_groups {
        walk.evals = 0;
        walk.interval(g, (0.0, 1.0), [0, mid, 1], 0);
    }
    ends.end.clear();
    ends.end.extend_from_slice(walk.row(1));
}

/// One step's pass (fractions θ ∈ [0, 1] of it).
struct Walk<'w, 'p> {
    m: &'w Metrics,
    acc: &'w mut [Acc],
    scratch: &'w mut Scratch,
    piece: &'w mut FlowPiece<'p>,
    width: usize,
    evals: usize,
    /// Relative agreement that accepts a quadrature.
    tol: f64,
}

impl Walk<'_, '_> {
    /// Evaluates the sample program at θ into a new row; its index.
    fn eval(&mut self, theta: f64) -> usize {
        self.evals += 1;
        let t = self.piece.state_at(theta, &mut self.scratch.x);
        let at = HybridTime::new(t, self.piece.j);
        let k = self.scratch.times.len();
        let start = self.scratch.rows.len();
        self.scratch.rows.resize(start + self.width, 0.0);
        let (x, rows) = (&self.scratch.x, &mut self.scratch.rows);
        self.m.eval(at, x, &mut rows[start..]);
        self.scratch.times.push(at);
        k
    }

    fn row(&self, k: usize) -> &[f64] {
        &self.scratch.rows[k * self.width..(k + 1) * self.width]
    }

    /// Drops the rows from `k` on.
    fn pop_to(&mut self, k: usize) {
        self.scratch.rows.truncate(k * self.width);
        self.scratch.times.truncate(k);
    }

    fn holds(&self, g: &PathGroup, k: usize) -> bool {
        g.window.is_none_or(|w| self.row(k)[w] != 0.0)
    }

    fn out_of_budget(&self) -> bool {
        self.evals >= BUDGET
    }

    /// `[a, b]` with rows `[at a, at the midpoint, at b]`.
    fn interval(&mut self, g: &PathGroup, (a, b): (f64, f64), r: [usize; 3], depth: u32) {
        let (wa, wm, wb) = (
            self.holds(g, r[0]),
            self.holds(g, r[1]),
            self.holds(g, r[2]),
        );
        if wa != wb {
            self.boundary(g, (a, b), (r[0], r[2]), wa, depth);
            return;
        }
        if g.integrals.is_empty() || (!wa && wm == wa) {
            return;
        }
        let top = self.scratch.times.len();
        let base = self.scratch.sums.len();
        let k = g.integrals.len();
        let deeper = depth < MAX_DEPTH && !self.out_of_budget();
        if wm == wa {
            // Simpson's rule against the trapezoid's: where they agree the
            // integrand is straight along [a, b] and Simpson's stands.
            self.simpson(g, b - a, r);
            let straight = (0..k).all(|i| {
                let s = self.scratch.sums[base + i];
                let trap = self.trapezoid(g, i, b - a, r[0], r[2]);
                self.agree(s, trap)
            });
            if straight || !deeper {
                self.add(g, b - a, base);
                self.scratch.sums.truncate(base);
                return;
            }
            // Gauss–Legendre's three points (the midpoint shared), exact to
            // degree 5, against Simpson's: where they agree, Gauss's stands.
            let n1 = self.eval(a + NODE * (b - a));
            let n3 = self.eval(b - NODE * (b - a));
            if self.holds(g, n1) == wa && self.holds(g, n3) == wa {
                self.gauss(g, b - a, [n1, r[1], n3]);
                let settled = (0..k).all(|i| {
                    let (s, q) = (self.scratch.sums[base + i], self.scratch.sums[base + k + i]);
                    self.agree(q, s)
                });
                if settled {
                    self.add(g, b - a, base + k);
                    self.scratch.sums.truncate(base);
                    self.pop_to(top);
                    return;
                }
            }
            self.scratch.sums.truncate(base);
        } else if !deeper {
            // The window opens and closes again inside, past the budget.
            return;
        }
        // Halves, each with its midpoint.
        self.pop_to(top);
        let mid = 0.5 * (a + b);
        let left = self.eval(0.5 * (a + mid));
        let right = self.eval(0.5 * (mid + b));
        self.interval(g, (a, mid), [r[0], left, r[1]], depth + 1);
        self.interval(g, (mid, b), [r[1], right, r[2]], depth + 1);
        self.pop_to(top);
    }

    /// Whether two quadratures of one integral agree to the tolerance.
    fn agree(&self, p: f64, q: f64) -> bool {
        // A NaN agrees: more points do not make it a number.
        let diff = (p - q).abs();
        diff.is_nan() || diff <= self.tol * (p.abs() + q.abs())
    }

    /// The trapezoid rule of integral `i` over an interval of length `len`
    /// with rows `ra`, `rb` at its ends.
    fn trapezoid(&self, g: &PathGroup, i: usize, len: f64, ra: usize, rb: usize) -> f64 {
        let arg = self.m.specs[g.integrals[i]].arg;
        let f = |row: usize| arg.map_or(0.0, |o| self.row(row)[o]);
        0.5 * len * (self.piece.t1 - self.piece.t0) * (f(ra) + f(rb))
    }

    /// `[a, b]` (rows `ends`) where the window is `wa` at a and not at b:
    /// bisection to its boundary, then each side.
    fn boundary(
        &mut self,
        g: &PathGroup,
        (a, b): (f64, f64),
        ends: (usize, usize),
        wa: bool,
        depth: u32,
    ) {
        let top = self.scratch.times.len();
        let (mut lo, mut hi) = (a, b);
        // To the rounding of the step's times (θ within an ulp of 1).
        while hi - lo > f64::EPSILON && !self.out_of_budget() {
            let mid = 0.5 * (lo + hi);
            if mid <= lo || mid >= hi {
                break;
            }
            let k = self.eval(mid);
            let w = self.holds(g, k);
            self.pop_to(k);
            if w == wa {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        // The boundary as the window's side sees it.
        let rlo = self.eval(lo);
        let rhi = self.eval(hi);
        self.edge(g, if wa { rlo } else { rhi });
        if !g.integrals.is_empty() {
            if lo > a {
                let m = self.eval(0.5 * (a + lo));
                self.interval(g, (a, lo), [ends.0, m, rlo], depth);
            }
            if b > hi {
                let m = self.eval(0.5 * (hi + b));
                self.interval(g, (hi, b), [rhi, m, ends.1], depth);
            }
        }
        self.pop_to(top);
    }

    /// Pushes the three-point Gauss–Legendre rule of each integral over an
    /// interval of length `len` with rows `r` at its nodes on
    /// `scratch.sums`.
    fn gauss(&mut self, g: &PathGroup, len: f64, r: [usize; 3]) {
        let scale = len * (self.piece.t1 - self.piece.t0) / 18.0;
        for &spec in &g.integrals {
            let arg = self.m.specs[spec].arg;
            let f = |row: usize| arg.map_or(0.0, |o| self.row(row)[o]);
            let s = scale * (5.0 * f(r[0]) + 8.0 * f(r[1]) + 5.0 * f(r[2]));
            self.scratch.sums.push(s);
        }
    }

    /// Pushes Simpson's rule of each integral over an interval of length
    /// `len` (fraction of the step) with rows `r` on `scratch.sums`.
    fn simpson(&mut self, g: &PathGroup, len: f64, r: [usize; 3]) {
        let scale = len * (self.piece.t1 - self.piece.t0) / 6.0;
        for &spec in &g.integrals {
            let arg = self.m.specs[spec].arg;
            let f = |row: usize| arg.map_or(0.0, |o| self.row(row)[o]);
            let s = scale * (f(r[0]) + 4.0 * f(r[1]) + f(r[2]));
            self.scratch.sums.push(s);
        }
    }

    /// Adds the sums at `base` (one per integral) over an interval of
    /// length `len` inside the window.
    fn add(&mut self, g: &PathGroup, len: f64, base: usize) {
        let span = len * (self.piece.t1 - self.piece.t0);
        for (i, &spec) in g.integrals.iter().enumerate() {
            let q = self.scratch.sums[base + i];
            match &mut self.acc[spec] {
                Acc::Integral(s) => *s += q,
                Acc::Mean { num, den } => {
                    *num += q;
                    *den += span;
                }
                _ => {}
            }
        }
    }

    /// A point (row `k`) where the window opens or closes, for the group's
    /// extremes and finals.
    fn edge(&mut self, g: &PathGroup, k: usize) {
        let at = self.scratch.times[k];
        for &spec in &g.edges {
            let s = &self.m.specs[spec];
            let value = s.arg.map_or(0.0, |o| self.row(k)[o]);
            self.acc[spec].offer(s.kind, at, value);
        }
    }
}
