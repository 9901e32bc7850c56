//! Sign changes hidden between the checkpoints of a step, found by
//! interval bounds ([`HybridSystem::atom_bounds`]).
//!
//! On an interval between two checkpoints at whose ends every watched atom
//! has the same class, each watched atom without an affine form (those are
//! examined exactly through their control points) is bounded over a box of
//! the path there: the hull of the Bernstein
//! control points of each component's polynomial on that interval. A bound
//! on the atom's side of zero proves its sign kept; otherwise the interval
//! is halved, the atom evaluated at the midpoint, and the halves bounded in
//! turn (time order first), until a point of the other class is found, the
//! pieces are proved, or the budget is spent. The first point found
//! becomes a checkpoint of a second scan of the interval, where the usual
//! localization takes it: a sawtooth (`mod(t, 1)`)
//! or a brief dip (`x ≤ 1 + 0.5·sin(t)`) that comes back before the next
//! checkpoint is found, not skipped.

use super::{Buf, EventKind, MAX_CONTROL, StepPath, Watcher, class, split, split_left};
use crate::engine::HybridSystem;

/// Midpoints evaluated at most per atom and checkpoint interval (each halving costs one
/// evaluation of the atom and two of the bounds).
const BUDGET: usize = 48;

/// The smallest piece halved, as a fraction of its checkpoint interval.
const MIN_PIECE: f64 = 1.0 / (1u64 << 24) as f64;

/// The search's state and buffers (kept, so that it does not allocate).
#[derive(Default)]
pub(super) struct Hidden {
    /// The system cannot bound its atoms (it said so once).
    unavailable: bool,
    /// The step whose control points `ctrl` holds (its span, its
    /// segment's start time and jump count), and whether it has them.
    step: Option<(((f64, f64), f64, u64), bool)>,
    /// Per watched atom: kept on one side of zero over the whole step.
    whole: Vec<bool>,
    /// Per state component: control points of the step's polynomial, their
    /// number and error bound.
    ctrl: Vec<([f64; MAX_CONTROL], usize, f64)>,
    xbox: Vec<(f64, f64)>,
    bounds: Vec<(f64, f64)>,
    /// The watched atoms searched on this step.
    cands: Vec<usize>,
    /// Per candidate: whether proved on the current interval.
    open: Vec<bool>,
    stack: Vec<(f64, f64)>,
    /// The state at the end of the interval scanned again.
    xb: Vec<f64>,
}

impl Watcher {
    /// The search described in the module docs on the interval `[a, b]`
    /// between two checkpoints at which every watched atom has the same
    /// class (`b`'s state: `y1` if `last`, else on the path). `None`:
    /// nothing found (or not searched), the scan goes on as it would have;
    /// `Some`: the interval was scanned again with the first point found
    /// as a checkpoint, with this result, and `cls_s` holds the classes at
    /// `b` as after an ordinary checkpoint.
    pub(super) fn hidden_change<S: HybridSystem + ?Sized, P: StepPath>(
        &mut self,
        sys: &S,
        path: &mut P,
        (a, b): (f64, f64),
        last: bool,
        y1: &[f64],
    ) -> Option<Option<(f64, EventKind)>> {
        // Relaxed atoms change class where their relaxation ends, and a
        // timer crossed in the interval would be crossed twice.
        if P::STRAIGHT
            || self.hidden.unavailable
            || self.relaxed > 0
            || self.timers.iter().any(|ta| !ta.crossed && ta.d <= b)
        {
            return None;
        }
        let mut h = std::mem::take(&mut self.hidden);
        let found = self.search(sys, path, (a, b), &mut h);
        self.hidden = h;
        let u = found?;
        // `b`'s state, then the interval again with `u` as a checkpoint
        // (its class differs from both ends'); the scan leaves the classes
        // at `b` in `cls`.
        let mut xb = std::mem::take(&mut self.hidden.xb);
        xb.resize(y1.len(), 0.0);
        if last {
            xb.copy_from_slice(y1);
        } else {
            path.eval(b, &mut xb);
        }
        let event = self.scan_points(sys, path, a, &[u, b], &xb);
        self.hidden.xb = xb;
        self.cls_s.copy_from_slice(&self.cls);
        Some(event)
    }

    /// The first point found in `(a, b)` where a candidate atom has
    /// another class than at the ends.
    fn search<S: HybridSystem + ?Sized, P: StepPath>(
        &mut self,
        sys: &S,
        path: &mut P,
        (a, b): (f64, f64),
        h: &mut Hidden,
    ) -> Option<f64> {
        let candidate = |w: usize| {
            self.affine[w].is_none()
                && self.twin[w].is_none()
                && self.flat_off[self.watched[w].set].is_some()
                && matches!(self.cls[w], -1 | 1)
        };
        if !(0..self.watched.len()).any(candidate) || !self.step_bounds(sys, path, h) {
            return None;
        }
        // Those not kept on one side of zero over the whole step.
        h.cands.clear();
        h.cands
            .extend((0..self.watched.len()).filter(|&w| candidate(w) && !h.whole[w]));
        if h.cands.is_empty() {
            return None;
        }
        if !self.bound(sys, h, a, b) {
            return None;
        }
        h.open.clear();
        for &w in &h.cands {
            h.open.push(!self.proved(h, w));
        }
        let mut first: Option<f64> = None;
        for c in 0..h.cands.len() {
            if !h.open[c] {
                continue;
            }
            let w = h.cands[c];
            let b = first.unwrap_or(b);
            if let Some(u) = self.other_class(sys, path, h, w, (a, b)) {
                first = Some(u);
            }
        }
        first
    }

    /// The control points of each component of the step's path into
    /// `h.ctrl`, and which watched atoms the bounds over the whole step
    /// keep on one side of zero into `h.whole` (once per step: on most
    /// steps the atoms are far from zero, and the checkpoint intervals
    /// need no bound of their own); false if the path is not a polynomial
    /// or the system has no bounds.
    fn step_bounds<S: HybridSystem + ?Sized, P: StepPath>(
        &self,
        sys: &S,
        path: &P,
        h: &mut Hidden,
    ) -> bool {
        let key = (self.span, self.clock.value(), self.j);
        if let Some((k, ok)) = h.step
            && k == key
        {
            return ok;
        }
        h.step = Some((key, false));
        let n = self.buf_t.len();
        h.ctrl.resize(n, ([0.0; MAX_CONTROL], 0, 0.0));
        for (i, c) in h.ctrl.iter_mut().enumerate() {
            let Some((k, err)) = path.control_points(i, &mut c.0) else {
                return false;
            };
            (c.1, c.2) = (k, err);
        }
        h.xbox.resize(n, (0.0, 0.0));
        h.bounds.resize(self.flat.len(), (0.0, 0.0));
        if !self.bound(sys, h, self.span.0, self.span.1) {
            return false;
        }
        h.whole.clear();
        for wa in &self.watched {
            let (lo, hi) = self.flat_off[wa.set].map_or((0.0, 0.0), |off| h.bounds[off + wa.atom]);
            h.whole.push(lo > 0.0 || hi < 0.0);
        }
        h.step = Some((key, true));
        true
    }

    /// Whether `h.bounds` keep atom `w` strictly on its class's side.
    fn proved(&self, h: &Hidden, w: usize) -> bool {
        let wa = self.watched[w];
        let Some(off) = self.flat_off[wa.set] else {
            return false;
        };
        let (lo, hi) = h.bounds[off + wa.atom];
        match self.cls[w] {
            1 => lo > 0.0,
            -1 => hi < 0.0,
            _ => false,
        }
    }

    /// The first point found in `(a, b)` where atom `w` has another class
    /// than at the checkpoints, halving where its bound does not prove the
    /// class kept.
    fn other_class<S: HybridSystem + ?Sized, P: StepPath>(
        &mut self,
        sys: &S,
        path: &mut P,
        h: &mut Hidden,
        w: usize,
        (a, b): (f64, f64),
    ) -> Option<f64> {
        let smallest = (b - a) * MIN_PIECE;
        let mut budget = BUDGET;
        h.stack.clear();
        h.stack.push((a, b));
        while let Some((a, b)) = h.stack.pop() {
            if budget == 0 {
                return None;
            }
            budget -= 1;
            let m = 0.5 * (a + b);
            if !(m > a && m < b) {
                continue;
            }
            let v = self.watched_at(sys, w, path, m, Buf::T);
            if class(v) != self.cls[w] {
                return Some(m);
            }
            if b - a <= smallest {
                continue;
            }
            // The right half first onto the stack: the left is taken first.
            for piece in [(m, b), (a, m)] {
                if !self.bound(sys, h, piece.0, piece.1) {
                    return None;
                }
                if !self.proved(h, w) {
                    h.stack.push(piece);
                }
            }
        }
        None
    }

    /// Bounds of all atoms over `[a, b]` (local times) into `h.bounds`;
    /// false if the system has none (then never asked again).
    fn bound<S: HybridSystem + ?Sized>(&self, sys: &S, h: &mut Hidden, a: f64, b: f64) -> bool {
        let (s0, s1) = self.span;
        let len = s1 - s0;
        // The piece as a part of the step, a little wider (the rounding of
        // the quotients).
        let eps = 4.0 * f64::EPSILON;
        let ta = ((a - s0) / len - eps).max(0.0);
        let tb = ((b - s0) / len + eps).min(1.0);
        for ((p, k, err), x) in h.ctrl.iter().zip(h.xbox.iter_mut()) {
            let p = &p[..*k];
            let mut piece = [0.0; MAX_CONTROL];
            piece[..*k].copy_from_slice(p);
            if ta > 0.0 {
                piece = split(p, ta).1;
            }
            if tb < 1.0 {
                let u = ((tb - ta) / (1.0 - ta) * (1.0 + eps)).min(1.0);
                piece = split_left(&piece[..*k], u);
            }
            let piece = &piece[..*k];
            let (lo, hi) = piece
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, u), &v| {
                    (l.min(v), u.max(v))
                });
            // The control points' error, and de Casteljau's (convex
            // combinations: a few roundings of the largest point per row).
            let size = p.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let e = err + 4.0 * (*k as f64) * f64::EPSILON * size;
            *x = (lo - e, hi + e);
        }
        let t = (
            self.clock.at(a).next_down().next_down(),
            self.clock.at(b).next_up().next_up(),
        );
        let ok = sys.atom_bounds(t, self.j, &h.xbox, &mut h.bounds);
        h.unavailable |= !ok;
        ok
    }
}
