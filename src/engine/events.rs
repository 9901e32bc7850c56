//! Event detection and localization on one integrator step.
//!
//! A *watched function* is a jump rule's guard (an event when it becomes
//! ≥ 0 and the rule's jump set then holds) or the flow guard (an event when
//! it becomes < 0 and the flow-set predicate then fails). On each step
//! `[s0, s1]` the watcher evaluates the watched functions at `guard_checks`
//! interior points and at `s1`, on a [`StepPath`] (cubic Hermite interpolant
//! of the step ends, or the exact solution of an affine flow); the first
//! sign change is bracketed and shrunk by the Illinois variant of regula
//! falsi with bisection safeguards, and the *pre-crossing* end of the final
//! bracket is returned: it is still on the flow's side, so the jump map gets
//! a state within the tolerance of D, and the next flow starts strictly on
//! the right side of the guard.

use super::HybridSystem;
use super::settings::{Priority, SimSettings};
use super::system::GuardKind;
use crate::arc::HybridTime;

/// x(s) on one step `[s0, s1]`.
pub(crate) trait StepPath {
    /// Writes x(s) into `out`, for `s` in `[s0, s1]`.
    fn eval(&mut self, s: f64, out: &mut [f64]);
}

/// The cubic Hermite interpolant through `(s0, y0, f0)` and `(s1, y1, f1)`:
/// exact for polynomials of degree ≤ 3, error O(h⁴) otherwise.
pub(crate) struct Hermite<'a> {
    pub s0: f64,
    pub s1: f64,
    pub y0: &'a [f64],
    pub f0: &'a [f64],
    pub y1: &'a [f64],
    pub f1: &'a [f64],
}

impl StepPath for Hermite<'_> {
    fn eval(&mut self, s: f64, out: &mut [f64]) {
        if s == self.s1 {
            out.copy_from_slice(self.y1);
            return;
        }
        if s == self.s0 {
            out.copy_from_slice(self.y0);
            return;
        }
        let h = self.s1 - self.s0;
        let th = (s - self.s0) / h;
        let th2 = th * th;
        let th3 = th2 * th;
        let h00 = 2.0 * th3 - 3.0 * th2 + 1.0;
        let h10 = (th3 - 2.0 * th2 + th) * h;
        let h01 = -2.0 * th3 + 3.0 * th2;
        let h11 = (th3 - th2) * h;
        for (i, o) in out.iter_mut().enumerate() {
            *o = h00 * self.y0[i] + h10 * self.f0[i] + h01 * self.y1[i] + h11 * self.f1[i];
        }
    }
}

/// Linear interpolation between step ends (Euler–Maruyama steps, whose
/// paths have no smooth interpolant).
pub(crate) struct Linear<'a> {
    pub s0: f64,
    pub s1: f64,
    pub y0: &'a [f64],
    pub y1: &'a [f64],
}

impl StepPath for Linear<'_> {
    fn eval(&mut self, s: f64, out: &mut [f64]) {
        if s == self.s1 {
            out.copy_from_slice(self.y1);
            return;
        }
        let w = (s - self.s0) / (self.s1 - self.s0);
        for (i, o) in out.iter_mut().enumerate() {
            *o = self.y0[i] + w * (self.y1[i] - self.y0[i]);
        }
    }
}

/// What a localized event is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum EventKind {
    /// Rule `i`'s guard became ≥ 0 and its jump set holds just past it.
    Jump(usize),
    /// The flow guard became < 0 and the state is outside C just past it.
    LeftFlowSet,
}

#[derive(Debug, Clone, Copy)]
enum Watched {
    Rule(usize),
    LeavesC,
}

/// Watches the guards along a flow segment; see the module docs.
pub(crate) struct Watcher {
    watched: Vec<Watched>,
    /// Whether each watched function is on its event side at the current
    /// step start.
    triggered: Vec<bool>,
    hits: Vec<bool>,
    checks: usize,
    event_tol: f64,
    /// The jump count of the segment being watched (constant along it).
    j: u64,
    buf_s: Vec<f64>,
    buf_a: Vec<f64>,
    buf_b: Vec<f64>,
    buf_best: Vec<f64>,
    buf_best_post: Vec<f64>,
    /// The pre-crossing state of the last event found by [`Watcher::scan`].
    pub event_state: Vec<f64>,
}

impl Watcher {
    /// A watcher for `sys` under `settings`: general jump guards are watched
    /// unless the priority is [`Priority::Flows`] (which jumps only when the
    /// flow cannot continue); the flow guard is watched if C has one.
    pub fn new<S: HybridSystem + ?Sized>(sys: &S, settings: &SimSettings, x0: &[f64]) -> Self {
        let mut watched = Vec::new();
        if settings.priority != Priority::Flows {
            for (i, rule) in sys.jump_rules().iter().enumerate() {
                if rule.guard == GuardKind::General {
                    watched.push(Watched::Rule(i));
                }
            }
        }
        if sys.flow_guard(HybridTime::new(0.0, 0), x0).is_some() {
            watched.push(Watched::LeavesC);
        }
        let n = x0.len();
        Self {
            triggered: vec![false; watched.len()],
            hits: vec![false; watched.len()],
            watched,
            checks: settings.guard_checks as usize,
            event_tol: settings.event_tol,
            j: 0,
            buf_s: vec![0.0; n],
            buf_a: vec![0.0; n],
            buf_b: vec![0.0; n],
            buf_best: vec![0.0; n],
            buf_best_post: vec![0.0; n],
            event_state: vec![0.0; n],
        }
    }

    /// The post-crossing state of the last event found (just past the
    /// boundary, within the event tolerance of [`event_state`](Self::event_state)).
    pub fn post_state(&self) -> &[f64] {
        &self.buf_best_post
    }

    /// `true` if nothing is watched (timers only, C the whole space).
    pub fn is_empty(&self) -> bool {
        self.watched.is_empty()
    }

    fn value<S: HybridSystem + ?Sized>(sys: &S, w: Watched, at: HybridTime, x: &[f64]) -> f64 {
        match w {
            Watched::Rule(i) => sys.jump_guard(i, at, x),
            Watched::LeavesC => -sys.flow_guard(at, x).unwrap_or(f64::INFINITY),
        }
    }

    fn is_triggered(w: Watched, v: f64) -> bool {
        match w {
            Watched::Rule(_) => v >= 0.0,
            Watched::LeavesC => v > 0.0,
        }
    }

    fn confirmed<S: HybridSystem + ?Sized>(sys: &S, w: Watched, at: HybridTime, x: &[f64]) -> bool {
        match w {
            Watched::Rule(i) => sys.jump_set(i, at, x),
            Watched::LeavesC => !sys.flow_set(at, x),
        }
    }

    /// Records the state at the start of a flow segment (local time 0,
    /// global hybrid time `at`).
    pub fn start<S: HybridSystem + ?Sized>(&mut self, sys: &S, at: HybridTime, x: &[f64]) {
        self.j = at.j;
        for (k, &w) in self.watched.iter().enumerate() {
            self.triggered[k] = Self::is_triggered(w, Self::value(sys, w, at, x));
        }
    }

    /// Looks for the first event on the step `[s0, s1]` (local times; global
    /// time is `t0 + s`) whose end state is `y1`. On success the pre-crossing
    /// state is in [`event_state`](Self::event_state) and the local time and
    /// kind are returned.
    pub fn scan<S: HybridSystem + ?Sized, P: StepPath>(
        &mut self,
        sys: &S,
        t0: f64,
        path: &mut P,
        s0: f64,
        s1: f64,
        y1: &[f64],
    ) -> Option<(f64, EventKind)> {
        let m = self.checks;
        let mut prev = s0;
        for k in 1..=m + 1 {
            let s = if k == m + 1 {
                s1
            } else {
                s0 + (s1 - s0) * (k as f64 / (m + 1) as f64)
            };
            if k == m + 1 {
                self.buf_s.copy_from_slice(y1);
            } else {
                path.eval(s, &mut self.buf_s);
            }
            let mut any = false;
            for (i, &w) in self.watched.iter().enumerate() {
                let trig = Self::is_triggered(
                    w,
                    Self::value(sys, w, HybridTime::new(t0 + s, self.j), &self.buf_s),
                );
                self.hits[i] = trig && !self.triggered[i];
                any |= self.hits[i];
                self.triggered[i] = trig;
            }
            if any {
                let mut best: Option<(f64, EventKind)> = None;
                for i in 0..self.watched.len() {
                    if !self.hits[i] {
                        continue;
                    }
                    let w = self.watched[i];
                    if let Some((sb, _)) = best {
                        // Cheap test against the event already found: a
                        // crossing after it, or inside the same tolerance
                        // bracket (the earlier-declared function wins, so a
                        // rule wins over leaving C), cannot replace it.
                        let tb = t0 + sb;
                        let at_post =
                            Self::value(sys, w, HybridTime::new(tb, self.j), &self.buf_best_post);
                        let at_pre =
                            Self::value(sys, w, HybridTime::new(tb, self.j), &self.buf_best);
                        if !Self::is_triggered(w, at_post) || !Self::is_triggered(w, at_pre) {
                            continue;
                        }
                    }
                    let (a, b) = self.localize(sys, w, t0, path, prev, s);
                    if best.is_some_and(|(sb, _)| sb <= a) {
                        continue;
                    }
                    if Self::confirmed(sys, w, HybridTime::new(t0 + b, self.j), &self.buf_b) {
                        let kind = match w {
                            Watched::Rule(r) => EventKind::Jump(r),
                            Watched::LeavesC => EventKind::LeftFlowSet,
                        };
                        best = Some((a, kind));
                        self.buf_best.copy_from_slice(&self.buf_a);
                        self.buf_best_post.copy_from_slice(&self.buf_b);
                    }
                }
                if let Some(found) = best {
                    self.event_state.copy_from_slice(&self.buf_best);
                    return Some(found);
                }
            }
            prev = s;
        }
        None
    }

    /// Shrinks the bracket `(a, b]` of watched function `w` (not triggered
    /// at `a`, triggered at `b`) until its width is below the tolerance.
    /// Leaves x(a) in `buf_a` and x(b) in `buf_b`.
    fn localize<S: HybridSystem + ?Sized, P: StepPath>(
        &mut self,
        sys: &S,
        w: Watched,
        t0: f64,
        path: &mut P,
        mut a: f64,
        mut b: f64,
    ) -> (f64, f64) {
        path.eval(a, &mut self.buf_a);
        path.eval(b, &mut self.buf_b);
        let mut fa = Self::value(sys, w, HybridTime::new(t0 + a, self.j), &self.buf_a);
        let mut fb = Self::value(sys, w, HybridTime::new(t0 + b, self.j), &self.buf_b);
        if fb == 0.0 && matches!(w, Watched::Rule(_)) {
            // b is an exact root (a clock reaching its threshold at a step
            // end, e.g. on a timer's instant): the crossing is at b. Secant
            // and bisection would only creep towards b for ~50 iterations.
            self.buf_a.copy_from_slice(&self.buf_b);
            return (b, b);
        }
        let mut side = 0i8;
        let mut widths = [f64::INFINITY; 2];
        for _ in 0..200 {
            let width = b - a;
            let tol = self.event_tol.max(4.0 * f64::EPSILON * b.abs());
            if width <= tol {
                break;
            }
            let secant = b - fb * (b - a) / (fb - fa);
            let slow = width > 0.5 * widths[0];
            let mut s = if secant.is_finite() && !slow {
                secant
            } else {
                0.5 * (a + b)
            };
            // Keep the trial strictly inside, a little away from the ends.
            let margin = 0.25 * tol;
            s = s.clamp(a + margin, b - margin);
            if !(s > a && s < b) {
                s = 0.5 * (a + b);
                if !(s > a && s < b) {
                    break; // a and b are adjacent floats
                }
            }
            widths = [widths[1], width];
            path.eval(s, &mut self.buf_s);
            let v = Self::value(sys, w, HybridTime::new(t0 + s, self.j), &self.buf_s);
            if Self::is_triggered(w, v) {
                b = s;
                fb = v;
                std::mem::swap(&mut self.buf_b, &mut self.buf_s);
                if side == -1 {
                    fa *= 0.5;
                }
                side = -1;
            } else {
                a = s;
                fa = v;
                std::mem::swap(&mut self.buf_a, &mut self.buf_s);
                if side == 1 {
                    fb *= 0.5;
                }
                side = 1;
            }
        }
        (a, b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hermite_is_exact_for_cubics() {
        // y = s³ - 2s on [0.5, 2]: y' = 3s² - 2.
        let y = |s: f64| s * s * s - 2.0 * s;
        let f = |s: f64| 3.0 * s * s - 2.0;
        let (s0, s1) = (0.5, 2.0);
        let (y0, f0, y1, f1) = ([y(s0)], [f(s0)], [y(s1)], [f(s1)]);
        let mut p = Hermite {
            s0,
            s1,
            y0: &y0,
            f0: &f0,
            y1: &y1,
            f1: &f1,
        };
        let mut out = [0.0];
        for k in 0..=10 {
            let s = s0 + (s1 - s0) * k as f64 / 10.0;
            p.eval(s, &mut out);
            assert!(
                (out[0] - y(s)).abs() < 1e-14,
                "at {s}: {} vs {}",
                out[0],
                y(s)
            );
        }
    }
}
