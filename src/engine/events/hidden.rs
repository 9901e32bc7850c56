//! Sign changes hidden between the checkpoints of a step, found by
//! interval bounds ([`HybridSystem::atom_bounds`]).
//!
//! On an interval between two checkpoints at whose ends every watched atom
//! has the same class (or from the last change localized between them that
//! changed no set: the atoms that keep their class from there), each
//! watched atom without an affine form (those are
//! examined exactly through their control points) is bounded over a box of
//! the path there: the hull of the Bernstein
//! control points of each component's polynomial on that interval. A bound
//! on the atom's side of zero proves its sign kept; otherwise the interval
//! is halved, the atom evaluated at the midpoint, and the halves bounded in
//! turn (time order first), until a point of the other class is found, the
//! pieces are proved, or the budget is spent (then the interval is passed
//! undecided: a change there can be missed). The first point found
//! becomes a checkpoint of a second scan of the interval, where the usual
//! localization takes it: a sawtooth (`mod(t, 1)`) or a brief dip
//! (`x ≤ 1 + 0.5·sin(t)`) that comes back before the next checkpoint is
//! found, not skipped.
//!
//! The whole step is bounded first, through a [`Window`]: bounds over a
//! box a few steps ahead serve the steps inside it, so that where the
//! atoms stay far from zero most steps need no evaluation of their own.
//! Only the state components the atoms read get boxes
//! ([`HybridSystem::atom_bound_inputs`]).

use super::{Buf, EventKind, MAX_CONTROL, StepPath, Watcher, class, split, split_left};
use crate::engine::HybridSystem;
use crate::engine::system::Cmp;

/// Midpoints evaluated at most per atom and checkpoint interval (each halving costs one
/// evaluation of the atom and two of the bounds).
const BUDGET: usize = 48;

/// The smallest piece halved, as a fraction of its checkpoint interval.
const MIN_PIECE: f64 = 1.0 / (1u64 << 24) as f64;

/// The smallest piece halved by [`Watcher::first_change_end`], as a
/// fraction of its bracket: the piece holding the change is never proved, so
/// the search goes this deep on every change it narrows.
const FIRST_PIECE: f64 = 1.0 / 256.0;

/// Midpoints evaluated at most by [`Watcher::first_change_end`] per
/// localization (each costs one evaluation of the atom and one of the
/// bounds at most): every change is narrowed, and the pieces just before
/// it are near zero and seldom proved, so the search would otherwise spend
/// [`BUDGET`] on most changes.
const FIRST_BUDGET: usize = 12;

/// The most steps ahead of the one where it is made that a [`Window`]
/// covers if the path goes on as on that step.
const AHEAD: u32 = 8;

/// Bounds of the atoms over a box of `(t, x)` that covers a step and, where
/// the path goes on as it did there, the next ones: a step whose box lies
/// inside takes its proofs from these bounds, without an evaluation of
/// its own (a bound over a larger box holds over any box inside).
#[derive(Default)]
struct Window {
    /// Whether it holds bounds: of jump count `j` over the times `t`.
    valid: bool,
    /// Steps ahead the next one covers: halved when one leaves an atom
    /// unproved (down to the step alone), one more when one proves all.
    ahead: u32,
    j: u64,
    t: (f64, f64),
    /// Per state component (those not read: unbounded).
    xbox: Vec<(f64, f64)>,
    bounds: Vec<(f64, f64)>,
}

impl Window {
    /// Whether the box `(t, xbox)` of jump count `j` (components `reads`)
    /// lies inside.
    fn covers(&self, j: u64, t: (f64, f64), xbox: &[(f64, f64)], reads: &[usize]) -> bool {
        self.valid
            && self.j == j
            && t.0 >= self.t.0
            && t.1 <= self.t.1
            && reads.iter().all(|&i| {
                let (x, w) = (xbox[i], self.xbox[i]);
                x.0 >= w.0 && x.1 <= w.1
            })
    }
}

/// What identifies a step: its span, its segment's start time and jump
/// count.
type StepKey = ((f64, f64), f64, u64);

/// The search's state and buffers (kept, so that it does not allocate).
#[derive(Default)]
pub(super) struct Hidden {
    /// The system cannot bound its atoms (it said so once).
    unavailable: bool,
    /// The state components the bounds read
    /// ([`HybridSystem::atom_bound_inputs`]), once asked (none asked for
    /// when no atom is searched).
    reads: Option<Vec<usize>>,
    /// The step whose control points `ctrl` holds (its span, its
    /// segment's start time and jump count), and whether it has them.
    step: Option<(StepKey, bool)>,
    /// The watched atoms searched by bounds ([`Watcher::boundable`]),
    /// once asked.
    boundable: Vec<usize>,
    /// Those of them not kept on one side of zero over the whole step.
    unproved: Vec<usize>,
    /// Per state component read: control points of the step's polynomial,
    /// their number and error bound.
    ctrl: Vec<([f64; MAX_CONTROL], usize, f64)>,
    /// Per state component: whether its flow is identically zero
    /// ([`HybridSystem::still_states`]).
    still: Vec<bool>,
    /// Per state component: its box (those not read: unbounded).
    xbox: Vec<(f64, f64)>,
    bounds: Vec<(f64, f64)>,
    window: Window,
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
    /// from a checkpoint or a localized change that changed no set
    /// (classes in `cls`) to the next checkpoint (classes in `cls_s`;
    /// `b`'s state: `y1` if `last`, else on the path; `end_counts` as for
    /// the scan of the step): the atoms of one class at both ends are
    /// searched. `None`:
    /// nothing found (or not searched), the scan goes on as it would have;
    /// `Some`: the interval was scanned again with the first point found
    /// as a checkpoint, with this result, and `cls_s` holds the classes at
    /// `b` as after an ordinary checkpoint.
    pub(super) fn hidden_change<S: HybridSystem + ?Sized, P: StepPath>(
        &mut self,
        sys: &S,
        path: &mut P,
        (a, b): (f64, f64),
        (last, end_counts): (bool, bool),
        y1: &[f64],
    ) -> Option<Option<(f64, EventKind)>> {
        // Relaxed atoms change class where their relaxation ends, and a
        // timer due inside the interval would be passed by the second scan
        // (none is: the timers' thresholds are checkpoints). One due at `b`
        // (a sampling instant, `tau <= Ts` in C) is crossed there by the
        // second scan, as by the first.
        if P::STRAIGHT
            || self.hidden.unavailable
            || self.relaxed > 0
            || self.timers.iter().any(|ta| !ta.crossed && ta.d < b)
        {
            return None;
        }
        // No atom searched, or the step's bounds known and proving every
        // one.
        let h = &self.hidden;
        if h.reads.is_some()
            && (h.boundable.is_empty()
                || matches!(h.step, Some((k, ok)) if k == self.step_key()
                    && (!ok || h.unproved.is_empty())))
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
        let event = self.scan_points(sys, path, a, &[u, b], &xb, end_counts || !last);
        self.hidden.xb = xb;
        self.cls_s.copy_from_slice(&self.cls);
        Some(event)
    }

    /// The end of the bracket in which watched atom `w`, of class
    /// `cls[w]` at the cursor `a` and of the opposite class at the
    /// checkpoint `b`, is localized: `b`, or the earliest point of the
    /// opposite class found by bounds. An atom without an affine form may
    /// change sign several times between two checkpoints (a ball that dips
    /// under a moving table, `h >= A*sin(w*t)`, and comes back up before
    /// the next checkpoint of a long step), and bisection on `[a, b]` would
    /// localize any of those changes, not necessarily the first. The pieces
    /// of `[a, b]` are taken in time order, each halved where the bounds do
    /// not prove the class kept; a midpoint of the opposite class becomes
    /// the new end, and the search goes on left of it, down to
    /// [`FIRST_PIECE`] of the bracket or [`FIRST_BUDGET`] evaluations.
    /// Relaxed atoms are searched on their relaxed value.
    pub(super) fn first_change_end<S: HybridSystem + ?Sized, P: StepPath>(
        &mut self,
        sys: &S,
        path: &mut P,
        w: usize,
        (a, b): (f64, f64),
    ) -> f64 {
        let c0 = self.cls[w];
        if P::STRAIGHT
            || self.hidden.unavailable
            || !matches!(c0, -1 | 1)
            || self.cls_s[w] != -c0
            || !self.boundable(w)
        {
            return b;
        }
        let mut h = std::mem::take(&mut self.hidden);
        let end = self.earliest_other_class(sys, path, &mut h, w, (a, b));
        self.hidden = h;
        end
    }

    /// [`first_change_end`](Self::first_change_end) with the search's
    /// state.
    fn earliest_other_class<S: HybridSystem + ?Sized, P: StepPath>(
        &mut self,
        sys: &S,
        path: &mut P,
        h: &mut Hidden,
        w: usize,
        (a, b): (f64, f64),
    ) -> f64 {
        if h.reads.is_none() {
            self.first_bounds(sys, h);
        }
        if !self.step_bounds(sys, path, h) {
            return b;
        }
        let c0 = self.cls[w];
        let smallest = (b - a) * FIRST_PIECE;
        let mut end = b;
        let mut budget = FIRST_BUDGET;
        h.stack.clear();
        h.stack.push((a, b));
        while let Some((p, q)) = h.stack.pop() {
            if budget == 0 || q - p <= smallest {
                // The pieces left are at most as wide: the change is
                // localized on `[a, end]` as found so far.
                if budget == 0 {
                    break;
                }
                continue;
            }
            budget -= 1;
            let m = 0.5 * (p + q);
            if !(m > p && m < q) {
                continue;
            }
            if class(self.watched_at(sys, w, path, m, Buf::T)) == -c0 {
                // A change before `m`: everything right of it is later.
                end = m;
                h.stack.clear();
                h.stack.push((p, m));
                continue;
            }
            // The right half first onto the stack: the left is taken first.
            // A piece that ends where the class is already known to differ
            // holds a change: it is not bounded.
            for piece in [(m, q), (p, m)] {
                if piece.1 != end {
                    if !self.bound(sys, h, piece.0, piece.1) {
                        return end;
                    }
                    if self.keeps_class(h, w, c0) {
                        continue;
                    }
                }
                h.stack.push(piece);
            }
        }
        end
    }

    /// Whether `h.bounds` keep the watched value of atom `w` strictly of
    /// class `c`.
    fn keeps_class(&self, h: &Hidden, w: usize, c: i8) -> bool {
        self.watched_bounds(&h.bounds, w)
            .is_some_and(|(lo, hi)| match c {
                1 => lo > 0.0,
                -1 => hi < 0.0,
                _ => false,
            })
    }

    /// Bounds of the watched value of atom `w` (relaxed as it is watched:
    /// `g + relax` for `g >= 0`) from the atoms' `bounds`; `None` where
    /// there are none (a relaxed `==` atom, watched as `relax - |g|`, is
    /// not bounded).
    fn watched_bounds(&self, bounds: &[(f64, f64)], w: usize) -> Option<(f64, f64)> {
        let wa = self.watched[w];
        let (lo, hi) = bounds[self.flat_off[wa.set]? + wa.atom];
        let relax = self.sets[wa.set].state[wa.atom].relax;
        if relax <= 0.0 {
            return Some((lo, hi));
        }
        match wa.cmp {
            Cmp::Ge | Cmp::Gt => Some((lo + relax, hi + relax)),
            Cmp::Le | Cmp::Lt => Some((lo - relax, hi - relax)),
            Cmp::Eq | Cmp::Ne => None,
        }
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
        if h.reads.is_none() {
            self.first_bounds(sys, h);
        }
        // Atoms of one class at both ends (after a checkpoint where other
        // atoms changed class without changing their sets, those alone).
        let off_boundary =
            |w: &usize| matches!(self.cls[*w], -1 | 1) && self.cls_s[*w] == self.cls[*w];
        if !h.boundable.iter().any(off_boundary) || !self.step_bounds(sys, path, h) {
            return None;
        }
        // Those not kept on one side of zero over the whole step.
        h.cands.clear();
        h.cands
            .extend(h.unproved.iter().copied().filter(off_boundary));
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

    /// Whether watched atom `w` is searched by bounds (on an interval where
    /// it is not on its boundary): not affine (those are examined exactly),
    /// not a twin (its first atom is), bounded by the system.
    fn boundable(&self, w: usize) -> bool {
        self.affine[w].is_none()
            && self.twin[w].is_none()
            && self.flat_off[self.watched[w].set].is_some()
    }

    /// What the search needs once per run: the components the bounds
    /// read, the atoms searched, unbounded boxes.
    fn first_bounds<S: HybridSystem + ?Sized>(&self, sys: &S, h: &mut Hidden) {
        h.boundable = (0..self.watched.len())
            .filter(|&w| self.boundable(w))
            .collect();
        // No atom searched (every watched one affine, as the ball's): the
        // rest is never read.
        if h.boundable.is_empty() {
            h.reads = Some(Vec::new());
            return;
        }
        let n = self.buf_t.len();
        let mut reads = sys.atom_bound_inputs().unwrap_or_else(|| (0..n).collect());
        reads.retain(|&i| i < n);
        h.reads = Some(reads);
        h.still = vec![false; n];
        for i in sys.still_states() {
            if let Some(s) = h.still.get_mut(i) {
                *s = true;
            }
        }
        let all = (f64::NEG_INFINITY, f64::INFINITY);
        h.xbox = vec![all; n];
        h.window.xbox = vec![all; n];
        h.window.ahead = AHEAD;
        h.ctrl = vec![([0.0; MAX_CONTROL], 0, 0.0); n];
        let atoms = self.flat.len();
        h.bounds = vec![(0.0, 0.0); atoms];
        h.window.bounds = vec![(0.0, 0.0); atoms];
    }

    /// The step being scanned.
    fn step_key(&self) -> StepKey {
        (self.span, self.clock.value(), self.j)
    }

    /// The control points of each component read of the step's path into
    /// `h.ctrl`, and the atoms searched that bounds over the whole step do
    /// not keep on one side of zero into `h.unproved` (once per step: on
    /// most steps the atoms are far from zero, and the checkpoint
    /// intervals need no bound of their own). The bounds are those of the
    /// window where it covers the step and proves every atom, else of a
    /// new window from this step. False if the path is not a polynomial or
    /// the system has no bounds.
    fn step_bounds<S: HybridSystem + ?Sized, P: StepPath>(
        &self,
        sys: &S,
        path: &P,
        h: &mut Hidden,
    ) -> bool {
        let key = self.step_key();
        if let Some((k, ok)) = h.step
            && k == key
        {
            return ok;
        }
        let reads = h.reads.take().unwrap_or_default();
        let ok = self.step_bounds_of(sys, path, h, &reads);
        h.reads = Some(reads);
        h.step = Some((key, ok));
        ok
    }

    /// [`step_bounds`](Self::step_bounds) with the components read.
    fn step_bounds_of<S: HybridSystem + ?Sized, P: StepPath>(
        &self,
        sys: &S,
        path: &P,
        h: &mut Hidden,
        reads: &[usize],
    ) -> bool {
        for &i in reads {
            let c = &mut h.ctrl[i];
            let Some((k, err)) = path.control_points(i, &mut c.0) else {
                return false;
            };
            (c.1, c.2) = (k, err);
        }
        let (s0, s1) = self.span;
        self.boxes(h, reads, s0, s1);
        let t = self.times(s0, s1);
        let mut ahead = h.window.ahead;
        if h.window.covers(self.j, t, &h.xbox, reads) {
            self.unproved(h);
            if h.unproved.is_empty() {
                return true;
            }
            // An atom came near zero: the step's own box.
            ahead = 0;
        }
        // A new window: the step's box, `ahead` times its extent further
        // each way, for `ahead` times its duration more. Where it proves
        // less than every atom, the step's own box (near a sign change),
        // and the next window half as far ahead; one step further ahead
        // after one that proves all (up to AHEAD).
        if !self.window(sys, h, reads, t, ahead) {
            return false;
        }
        let proved = h.unproved.is_empty();
        if !proved && ahead > 0 && !self.window(sys, h, reads, t, 0) {
            return false;
        }
        h.window.ahead = if proved {
            (ahead + 1).min(AHEAD)
        } else {
            ahead / 2
        };
        true
    }

    /// Bounds over the box of the step (times `t`, components `reads` in
    /// `h.xbox`) grown `ahead` times its extent each way and its duration
    /// forward into `h.window`, and the atoms they do not prove into
    /// `h.unproved`; false if the system has no bounds.
    fn window<S: HybridSystem + ?Sized>(
        &self,
        sys: &S,
        h: &mut Hidden,
        reads: &[usize],
        t: (f64, f64),
        ahead: u32,
    ) -> bool {
        let w = &mut h.window;
        let ahead = f64::from(ahead);
        w.j = self.j;
        w.t = (t.0, t.1 + ahead * (t.1 - t.0));
        for &i in reads {
            let (lo, hi) = h.xbox[i];
            let d = ahead * (hi - lo);
            w.xbox[i] = (lo - d, hi + d);
        }
        w.valid = sys.atom_bounds(w.t, self.j, &w.xbox, &mut w.bounds);
        if !w.valid {
            h.unavailable = true;
            return false;
        }
        self.unproved(h);
        true
    }

    /// The atoms searched that the window's bounds do not keep on one side
    /// of zero into `h.unproved`.
    fn unproved(&self, h: &mut Hidden) {
        h.unproved.clear();
        for &w in &h.boundable {
            let kept = self
                .watched_bounds(&h.window.bounds, w)
                .is_some_and(|(lo, hi)| lo > 0.0 || hi < 0.0);
            if !kept {
                h.unproved.push(w);
            }
        }
    }

    /// Whether `h.bounds` keep atom `w` strictly on its class's side.
    fn proved(&self, h: &Hidden, w: usize) -> bool {
        self.keeps_class(h, w, self.cls[w])
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
        let reads = h.reads.take().unwrap_or_default();
        self.boxes(h, &reads, a, b);
        h.reads = Some(reads);
        let ok = sys.atom_bounds(self.times(a, b), self.j, &h.xbox, &mut h.bounds);
        h.unavailable |= !ok;
        ok
    }

    /// The global times of `[a, b]` (local), a little wider.
    fn times(&self, a: f64, b: f64) -> (f64, f64) {
        (
            self.clock.at(a).next_down().next_down(),
            self.clock.at(b).next_up().next_up(),
        )
    }

    /// The box of the path's components `reads` over `[a, b]` (local
    /// times) into `h.xbox`: the hull of the control points of the piece,
    /// widened by their error.
    fn boxes(&self, h: &mut Hidden, reads: &[usize], a: f64, b: f64) {
        let (s0, s1) = self.span;
        let len = s1 - s0;
        // The piece as a part of the step, a little wider (the rounding of
        // the quotients).
        let eps = 4.0 * f64::EPSILON;
        let ta = ((a - s0) / len - eps).max(0.0);
        let tb = ((b - s0) / len + eps).min(1.0);
        let u = ((tb - ta) / (1.0 - ta) * (1.0 + eps)).min(1.0);
        for &i in reads {
            let (p, k, err) = &h.ctrl[i];
            let p = &p[..*k];
            // A component without flow is its value all along the step
            // (its control points all that value: else the box below).
            if h.still.get(i) == Some(&true) && p.iter().all(|&v| v == p[0]) {
                h.xbox[i] = (p[0], p[0]);
                continue;
            }
            let mut piece = [0.0; MAX_CONTROL];
            let part = ta > 0.0 || tb < 1.0;
            let piece = if part {
                piece[..*k].copy_from_slice(p);
                if ta > 0.0 {
                    piece = split(p, ta).1;
                }
                if tb < 1.0 {
                    piece = split_left(&piece[..*k], u);
                }
                &piece[..*k]
            } else {
                p
            };
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            for &v in piece {
                // A NaN point makes the box NaN (unbounded), not ignored.
                lo = if v < lo || v.is_nan() { v } else { lo };
                hi = if v > hi || v.is_nan() { v } else { hi };
            }
            // The control points' error, and de Casteljau's (convex
            // combinations: a few roundings of the largest point per row;
            // none on the whole step).
            let size = if part {
                p.iter().fold(0.0f64, |m, v| m.max(v.abs()))
            } else {
                lo.abs().max(hi.abs())
            };
            let e = err + 4.0 * (*k as f64) * f64::EPSILON * size;
            h.xbox[i] = (lo - e, hi + e);
        }
    }
}
