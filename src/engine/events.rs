//! Event detection and localization on one integrator step.
//!
//! The watcher holds every set of the system (C and each D_i) as atoms
//! `g_k ⋈ 0` combined by a monotone boolean expression (see
//! [`SetAtoms`](super::SetAtoms); a system without atoms contributes its
//! guard as the set's only atom). The *flowing* atoms of the sets that can
//! cause an event (C, and the general rules' D_i unless the priority is
//! [`Priority::Flows`]) are watched individually: on each step `[s0, s1]`
//! their sign (−, 0, + or NaN) is evaluated at `guard_checks` interior
//! points and at `s1` on a [`StepPath`] (the stepper's dense output, the
//! cubic Hermite interpolant of the step ends of Rk4, or the exact
//! solution of an affine flow; an Euler–Maruyama
//! step, a straight line between points of a sampled path, only at its
//! ends). Each sign change
//! is bracketed and shrunk (the ITP method, with bisection where the values
//! are down to rounding noise) to the first point where the sign differs
//! from the bracket's start, within the event tolerance (default 4 ulp of
//! t); atoms of several sets with the same function (`x ≥ 0` in C, `x ≤ 0`
//! in D) are localized once; the candidates are taken in
//! time order and at each one every set is re-evaluated on the bracket
//! `[a, b]`:
//!
//! - an inequality atom takes its value at `b`, the post-change end;
//! - an equality atom `g = 0` holds iff `g(b) = 0` or `g` has strictly
//!   opposite signs at `a` and `b` (the quantity reached the value within
//!   the bracket); `g ≠ 0` is its negation;
//! - an atom that cannot change along the flow keeps its value from the
//!   segment's start.
//!
//! The first candidate at which a watched D_i becomes true (declaration
//! order breaks ties) or C becomes false is the event; the segment ends at
//! `b` with the state x(b), a point of D_i (or the first point found
//! outside C). A candidate that changes no set's value is passed and the
//! scan goes on from `b`.
//!
//! Atoms of C that hold at the segment's start only within
//! [`set_tol`](super::SimSettings::set_tol) are watched relaxed by that
//! tolerance (`g + set_tol` for `g ≥ 0`) until they hold exactly. Inequality
//! atoms of C without an affine form, whose sign near zero can be rounding
//! noise (`h ≥ A·sin(ω·t)`), are watched relaxed whenever the segment starts
//! within `set_tol` of their zero, on either side, until they hold by
//! `set_tol`.

use std::ops::ControlFlow;

use super::HybridSystem;
use super::clock::TimeSum;
use super::settings::{Priority, SimSettings};
use super::system::{AffineAtom, Atom, Cmp, GuardKind, SetAtoms, SetRef, Threshold, TruthTable};
use crate::arc::{FailedAtom, HybridTime};

mod hidden;

/// x(s) on one step `[s0, s1]`.
pub(crate) trait StepPath {
    /// Whether the path is the straight line between the step's ends (an
    /// Euler–Maruyama step, which has no interpolant): dense output then
    /// adds no point, and the sets are checked at the step's ends only,
    /// since the line between them is not the solution's path.
    const STRAIGHT: bool = false;

    /// Writes x(s) into `out`, for `s` in `[s0, s1]`.
    fn eval(&mut self, s: f64, out: &mut [f64]);

    /// Where the path is a polynomial in `s` on the whole step `[s0, s1]`
    /// (degree below [`MAX_CONTROL`]): writes the Bernstein control points
    /// of its component `i` over the step into `out` and returns their
    /// number and a bound on their rounding error. The component stays in
    /// the convex hull of its control points, which lets the watcher prove
    /// that an affine atom keeps its sign over the step. `None` (the
    /// default): not a polynomial, or not known as one.
    fn control_points(&self, _i: usize, _out: &mut [f64; MAX_CONTROL]) -> Option<(usize, f64)> {
        None
    }

    /// Whether [`restep`](Self::restep) gives the states inside the step
    /// more accurately than [`eval`](Self::eval): the watcher then finds an
    /// event again on them, so that its time and state are as accurate as
    /// the method's steps (Radau5, whose cubic is of order 3 inside a step
    /// of order 5).
    const RESTEPS: bool = false;

    /// Writes x(s) into `out`, for `s` in `[s0, s1]`, from a fresh step of
    /// the method from the step's start to `s`; `false` if that step
    /// failed (`out` is then unspecified).
    fn restep(&mut self, _s: f64, _out: &mut [f64]) -> bool {
        false
    }
}

/// The most Bernstein control points a [`StepPath`] gives per component.
pub(crate) const MAX_CONTROL: usize = 8;

/// `$body` with `$q` the slice `$p` of points (or coefficients), its
/// length a constant for each length from 2 to [`MAX_CONTROL`]: the
/// loops of a few iterations over it then unroll (they cost more than
/// their arithmetic), with the same operations in the same order. The
/// functions `$body` calls must be inlined into it.
macro_rules! per_count {
    ($p:expr, |$q:ident| $body:expr) => {{
        let p: &[f64] = $p;
        match p.len() {
            2 => per_count!(@fixed 2, p, $q, $body),
            3 => per_count!(@fixed 3, p, $q, $body),
            4 => per_count!(@fixed 4, p, $q, $body),
            5 => per_count!(@fixed 5, p, $q, $body),
            6 => per_count!(@fixed 6, p, $q, $body),
            7 => per_count!(@fixed 7, p, $q, $body),
            8 => per_count!(@fixed 8, p, $q, $body),
            _ => {
                let $q = p;
                $body
            }
        }
    }};
    (@fixed $n:literal, $p:ident, $q:ident, $body:expr) => {{
        let fixed: &[f64; $n] = $p.try_into().expect("the matched length");
        let $q = &fixed[..];
        $body
    }};
}

/// The Bernstein control points on `[0, 1]` of the polynomial
/// `Σ aᵢ τⁱ` (at most [`MAX_CONTROL`] coefficients) into `out`, with a
/// bound on their rounding error: `bₖ = Σ_{i ≤ k} C(k, i)/C(n, i)·aᵢ`.
#[inline]
pub(crate) fn bernstein_points(a: &[f64], out: &mut [f64; MAX_CONTROL]) -> (usize, f64) {
    per_count!(a, |a| bernstein_points_in(a, out))
}

/// [`bernstein_points`], inlined into each length's copy.
#[inline(always)]
fn bernstein_points_in(a: &[f64], out: &mut [f64; MAX_CONTROL]) -> (usize, f64) {
    let n = a.len() - 1;
    // C(k, i)/C(n, i) built up along i: ×(k − i)/(n − i) per step.
    for (k, o) in out.iter_mut().enumerate().take(n + 1) {
        let (mut ratio, mut b) = (1.0, 0.0);
        for (i, &ai) in a.iter().enumerate().take(k + 1) {
            b += ratio * ai;
            ratio *= (k - i) as f64 / (n - i).max(1) as f64;
        }
        *o = b;
    }
    let size: f64 = a.iter().map(|v| v.abs()).sum();
    (n + 1, 32.0 * f64::EPSILON * size)
}

/// Writes the state at `s` into `out` if `s` is an end of the step
/// (`s0` with state `y0`, `s1` with `y1`), which a path gives exactly as
/// held; whether it did.
#[inline]
pub(crate) fn at_step_end(
    s: f64,
    (s0, y0): (f64, &[f64]),
    (s1, y1): (f64, &[f64]),
    out: &mut [f64],
) -> bool {
    let end = if s == s1 {
        y1
    } else if s == s0 {
        y0
    } else {
        return false;
    };
    out.copy_from_slice(end);
    true
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
        if at_step_end(s, (self.s0, self.y0), (self.s1, self.y1), out) {
            return;
        }
        let h = self.s1 - self.s0;
        let th = (s - self.s0) / h;
        let th2 = th * th;
        let th3 = th2 * th;
        let h10 = (th3 - 2.0 * th2 + th) * h;
        let h01 = -2.0 * th3 + 3.0 * th2;
        let h11 = (th3 - th2) * h;
        // h00·y0 + h01·y1 written as y0 + h01·(y1 − y0): a component that
        // does not move (a mode, a counter: y1 = y0, f = 0) keeps its value
        // to the bit, where h00 + h01 rounds away from 1 (a gear index read
        // as 2.9999999999999996 mid-step).
        for (i, o) in out.iter_mut().enumerate() {
            *o = self.y0[i] + h01 * (self.y1[i] - self.y0[i]) + h10 * self.f0[i] + h11 * self.f1[i];
        }
    }

    fn control_points(&self, i: usize, out: &mut [f64; MAX_CONTROL]) -> Option<(usize, f64)> {
        let h = self.s1 - self.s0;
        let (y0, y1) = (self.y0[i], self.y1[i]);
        let (d0, d1) = (h * self.f0[i] / 3.0, h * self.f1[i] / 3.0);
        out[..4].copy_from_slice(&[y0, y0 + d0, y1 - d1, y1]);
        // The points and `eval`'s sums are each a few roundings of terms
        // no larger than these.
        let scale = y0.abs() + y1.abs() + d0.abs() + d1.abs();
        Some((4, 16.0 * f64::EPSILON * scale))
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
    const STRAIGHT: bool = true;

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
    /// Rule `i`'s jump set became true.
    Jump(usize),
    /// The flow set became false.
    LeftFlowSet,
}

/// One set as the watcher sees it.
struct WSet {
    set: SetRef,
    /// `None`: the set's guard is its only atom (`≥ 0`) and the system's
    /// predicate decides membership.
    spec: Option<SetAtoms>,
    /// The truth table of `spec`'s structure, if it has at most
    /// [`TruthTable::MAX_ATOMS`] atoms.
    table: Option<TruthTable>,
    /// Whether a change of this set ends a segment.
    source: bool,
    /// Per atom: its state along the segment ([`AtomState`]), in one
    /// array (one allocation, one bounds check per atom).
    state: Vec<AtomState>,
    /// Atom values at the checkpoint, at the bracket ends, at a trial point.
    vs: Vec<f64>,
    va: Vec<f64>,
    vb: Vec<f64>,
    vt: Vec<f64>,
    /// The set's value past the thresholds and where the timers land
    /// ([`Watcher::cross_timers`]).
    past: bool,
    on: bool,
    /// The set's value at the cursor, and at the candidate being examined.
    cur: bool,
    new: bool,
}

/// One atom of a [`WSet`] as the watcher tracks it along a segment.
#[derive(Debug, Clone, Copy, Default)]
struct AtomState {
    /// Relaxation (C's atoms that held only within `set_tol` at the
    /// segment's start, or that start on their boundary and are `noisy`).
    relax: f64,
    /// How far inside its set a relaxed atom must be for its relaxation to
    /// end (0: where it holds exactly; `set_tol` for a `noisy` atom).
    settle: f64,
    /// A watched inequality atom of C without an affine form. Its sign near
    /// its zero is rounding noise (`h ≥ A·sin(ω·t)`: the rounding of `ω·t`
    /// alone), which the checkpoints cannot tell from a change of sign; so
    /// where the segment starts on its boundary (within `set_tol` on either
    /// side: a jump onto it) it is watched relaxed, until it holds by
    /// `set_tol` (a flow that points out of C leaves it at `−set_tol`, as
    /// any relaxed atom's).
    noisy: bool,
    /// Truth at the segment's start (for an atom that cannot change along
    /// the flow, its truth on the whole segment).
    start_truth: bool,
    /// Truth on the bracket being examined ([`Watcher::evaluate_sets`]).
    truth: bool,
    /// A timer atom crossed at the checkpoint being examined by
    /// [`Watcher::cross_timers`], and its truth where its timer lands there
    /// ([`Watcher::landing`]).
    on_threshold: bool,
    landed: bool,
}

impl WSet {
    /// What [`atom_values`] evaluates the set by.
    fn kind(&self) -> (SetRef, bool) {
        (self.set, self.spec.is_some())
    }

    fn atom_count(&self) -> usize {
        self.spec.as_ref().map_or(1, |s| s.atoms.len())
    }

    #[inline]
    fn cmp(&self, k: usize) -> Cmp {
        self.spec.as_ref().map_or(Cmp::Ge, |s| s.atoms[k].cmp)
    }

    /// Whether atom `k` is watched ([`Atom::watched`](super::system::Atom::watched)).
    fn watched(&self, k: usize) -> bool {
        self.spec.as_ref().is_none_or(|s| s.atoms[k].watched())
    }
}

/// Per rule of `sys`, the sets (indices into `sets`) a jump by it may
/// change: those that read `j` or a component it writes (all, `None`, for
/// a rule that does not say what it writes, or when that is more than
/// half of them).
fn stale_sets<S: HybridSystem + ?Sized>(sys: &S, sets: &[WSet]) -> Vec<Option<Vec<usize>>> {
    // (component, set) for each component a set reads, sorted; the sets
    // every jump changes.
    let mut reads: Vec<(usize, usize)> = Vec::new();
    let mut always = Vec::new();
    for (i, ws) in sets.iter().enumerate() {
        match sys.set_inputs(ws.set) {
            Some(inputs) if !inputs.jumps => reads.extend(inputs.states.iter().map(|&k| (k, i))),
            _ => always.push(i),
        }
    }
    reads.sort_unstable();
    let half = sets.len() / 2;
    sys.jump_rules()
        .iter()
        .map(|rule| {
            if rule.writes.is_empty() || always.len() > half {
                return None;
            }
            let mut stale = always.clone();
            for &k in &rule.writes {
                let from = reads.partition_point(|&(c, _)| c < k);
                stale.extend(
                    reads[from..]
                        .iter()
                        .take_while(|&&(c, _)| c == k)
                        .map(|&(_, i)| i),
                );
            }
            stale.sort_unstable();
            stale.dedup();
            (stale.len() <= half).then_some(stale)
        })
        .collect()
}

/// The truth table of a set of at most [`TruthTable::MAX_ATOMS`] atoms.
fn truth_table(spec: Option<&SetAtoms>) -> Option<TruthTable> {
    spec.filter(|s| s.atoms.len() <= TruthTable::MAX_ATOMS)?
        .expr
        .truth_table()
}

/// The value of set `spec` (truth table `table`, if it has one) when atom
/// `k` has truth `truth(k)`.
#[inline]
fn set_value(spec: &SetAtoms, table: Option<TruthTable>, truth: impl Fn(usize) -> bool) -> bool {
    match table {
        Some(t) => t.value(TruthTable::mask(spec.atoms.len(), truth)),
        None => spec.expr.eval_with(&truth),
    }
}

/// The values of the set `ws` (with atoms) at a checkpoint where timers
/// pass their thresholds ([`Watcher::cross_timers`]): its watched atoms at
/// their checkpoint values `vs`, the others at their truth for the rest of
/// the segment (past the thresholds), and the same with the timers crossed
/// there where they land. With a truth table, both in one pass.
fn timer_set_values(ws: &WSet, spec: &SetAtoms) -> (bool, bool) {
    let past = |k: usize| {
        let atom = &spec.atoms[k];
        if atom.watched() {
            atom.cmp.holds_within(ws.vs[k], ws.state[k].relax)
        } else {
            ws.state[k].start_truth
        }
    };
    let on = |k: usize| {
        if ws.state[k].on_threshold {
            ws.state[k].landed
        } else {
            past(k)
        }
    };
    match ws.table {
        Some(t) => {
            let (mut mp, mut mo) = (0u32, 0u32);
            for k in 0..spec.atoms.len() {
                let p = past(k);
                let st = &ws.state[k];
                let o = if st.on_threshold { st.landed } else { p };
                mp |= u32::from(p) << k;
                mo |= u32::from(o) << k;
            }
            (t.value(mp), t.value(mo))
        }
        None => (spec.expr.eval_with(&past), spec.expr.eval_with(&on)),
    }
}

/// Evaluates the atoms of the set `set` (`atoms`: whether it has atoms, or
/// its guard is its only atom) at (t, j, x) into `out`. The set's parts
/// rather than its [`WSet`], so that `out` may be one of that set's
/// buffers.
fn atom_values<S: HybridSystem + ?Sized>(
    sys: &S,
    (set, atoms): (SetRef, bool),
    at: HybridTime,
    x: &[f64],
    flowing_only: bool,
    out: &mut [f64],
) {
    match (atoms, set) {
        (true, set) => sys.atom_values(set, at, x, flowing_only, out),
        (false, SetRef::Jump(r)) => out[0] = sys.jump_guard(r, at, x),
        (false, SetRef::Flow) => out[0] = sys.flow_guard(at, x).unwrap_or(f64::INFINITY),
    }
}

/// Whether the atom `g ⋈ 0` holds by at least `margin ≥ 0` (`g ≥ margin`
/// for `≥`); with `margin = 0`, whether it holds.
fn holds_by(cmp: Cmp, g: f64, margin: f64) -> bool {
    if margin <= 0.0 {
        return cmp.holds(g);
    }
    match cmp {
        Cmp::Ge | Cmp::Gt => g >= margin,
        Cmp::Le | Cmp::Lt => g <= -margin,
        Cmp::Eq | Cmp::Ne => cmp.holds(g),
    }
}

/// The quantity whose sign is watched for an atom `g ⋈ 0` relaxed by
/// `relax`: `g` itself, or the distance to the relaxed set's boundary.
fn watched_value(cmp: Cmp, g: f64, relax: f64) -> f64 {
    if relax <= 0.0 {
        return g;
    }
    match cmp {
        Cmp::Ge | Cmp::Gt => g + relax,
        Cmp::Le | Cmp::Lt => g - relax,
        Cmp::Eq => relax - g.abs(),
        Cmp::Ne => g,
    }
}

/// Sign class: −1, 0, +1, or 2 for NaN.
fn class(v: f64) -> i8 {
    if v > 0.0 {
        1
    } else if v < 0.0 {
        -1
    } else if v == 0.0 {
        0
    } else {
        2
    }
}

/// Whether an equality atom is met on the bracket whose ends have values
/// `ga` and `gb`: exactly at `b`, or by a sign change inside.
fn eq_met(ga: f64, gb: f64) -> bool {
    gb == 0.0 || (ga < 0.0 && gb > 0.0) || (ga > 0.0 && gb < 0.0)
}

/// A watched atom: atom `atom` of set `set`, with its comparison.
#[derive(Debug, Clone, Copy)]
struct WAtom {
    set: usize,
    atom: usize,
    cmp: Cmp,
    /// Its index in the layout of [`HybridSystem::all_atom_values`] (read
    /// where [`Watcher::flat_watched`]).
    flat: usize,
}

/// A timer atom `x[index] − threshold ⋈ 0` (`⋈` an inequality) of set
/// `set`: when it reaches zero is computed at each segment's start (`d`,
/// local time; ∞: not in this segment), not watched.
#[derive(Debug, Clone, Copy)]
struct TimerAtom {
    set: usize,
    atom: usize,
    /// The atom's comparison (`<`, `<=`, `>` or `>=`).
    cmp: Cmp,
    index: usize,
    threshold: f64,
    /// Whether `threshold` is read from the system at each segment's start
    /// ([`Threshold::PerSegment`]).
    per_segment: bool,
    /// Local time at which the timer reaches its threshold (∞: never).
    d: f64,
    /// How much later than a segment's end `d` may be for the timer to
    /// count as due there ([`timer_slack`]).
    slack: f64,
    /// The atom's truth once past the threshold (the sign of the rate).
    after: bool,
    /// Whether the scan has passed `d` ([`Watcher::cross_timers`]), and
    /// whether at the checkpoint being examined.
    crossed: bool,
    now: bool,
    /// Whether a strict atom has the same timer (it may land past the
    /// threshold: [`Watcher::landing`]).
    strict_timer: bool,
}

impl TimerAtom {
    /// Whether the timer is due at the end `d_end` of a segment reached by
    /// the flow: on its threshold there, or past it by no more than the
    /// rounding of its own schedule.
    fn due_at(&self, d_end: f64) -> bool {
        self.d >= d_end && self.d - d_end <= self.slack
    }
}

/// How much later than another timer's a timer's expiry `(threshold −
/// value) / rate` may come and still count as the same instant: the rounding
/// its value gathers over a few tens of integrator steps and segments (a
/// timer integrated by Dopri5, or reset at a different instant from another
/// of a commensurate period, lands a few ulps off). Two timers meant to
/// expire together (sampling every 0.01 and acting every 0.03) then do, at
/// one `t`, instead of with a flow of 10⁻¹⁷ between their jumps.
pub(crate) fn timer_slack(value: f64, threshold: f64, rate: f64) -> f64 {
    64.0 * f64::EPSILON * (value.abs() + threshold.abs()) / rate.abs()
}

/// A jump set whose start [`Watcher::start_sets`] reads from the
/// evaluation of all sets in one tight pass: its atoms (at most
/// [`TruthTable::MAX_ATOMS`], never relaxed) at `off..off + n` of that
/// layout, their comparisons copied out of the set's atoms (no `Option`
/// and no stride of [`Atom`] per atom), its truth table.
#[derive(Debug, Clone, Copy)]
struct FastSet {
    set: usize,
    off: usize,
    n: usize,
    cmps: [Cmp; TruthTable::MAX_ATOMS],
    table: TruthTable,
}

/// How often [`first_other_sign`] halves a step at most: a change of sign
/// narrower than 2⁻³⁰ of the step (a touch of zero) counts as none.
const SPLIT_DEPTH: u32 = 30;

/// The most pieces [`first_other_sign`] examines for one atom on one step
/// before it gives up (the step's checkpoints then watch the atom): an atom
/// that hugs zero over the step would otherwise be split without end.
const SPLIT_BUDGET: u32 = 256;

/// The first point found in `[a, b]` where the polynomial with Bernstein
/// control points `p` on `[a, b]` (strictly of sign `sign` at `a`) has
/// the other sign by more than `tol`, searched from the left by halving.
/// The polynomial lies in the hull of its control points, and has at most
/// as many zeros in `[a, b]` as the points change sign (Descartes' rule in
/// Bernstein form): points all of `sign` leave no change, one change of
/// sign exactly one zero if the end has the other sign and none if not.
///
/// A piece whose points have no sure other sign but come within `tol` of
/// it cannot have it beyond `tol` anywhere (every piece of it has its
/// points in their hull), nor can the last piece be told apart: the
/// polynomial cannot decide whether the flow grazes zero there, so if
/// some point has the other sign the piece's point nearest it goes
/// into `probes` (`[a, b]`'s own variable), where the system's value
/// decides (at most [`MAX_CHANGES`]). A search whose every point is
/// within `tol` of zero from the start (the atom hugs zero) is left to the
/// step's checkpoints. `Err` when `budget` pieces did not settle it.
fn first_other_sign(
    p: &[f64],
    sign: f64,
    tol: f64,
    (a, b): (f64, f64),
    depth: u32,
    budget: &mut u32,
    probes: &mut Vec<f64>,
) -> Result<Option<f64>, ()> {
    *budget = budget.checked_sub(1).ok_or(())?;
    let class = |v: f64| {
        if v * sign > tol {
            1
        } else if v * sign < -tol {
            -1
        } else {
            0
        }
    };
    // An end within the tolerance of zero is the end checkpoint's to see:
    // before it the polynomial keeps its sign or changes it by no more
    // than the tolerance.
    let end = class(p[p.len() - 1]);
    let (mut changes, mut unsure, mut sure, mut before) = (0, false, false, 1);
    for (i, &v) in p.iter().enumerate() {
        match class(v) {
            0 if i + 1 == p.len() => {}
            0 => unsure = true,
            c => {
                sure = true;
                changes += usize::from(c != before);
                before = c;
            }
        }
    }
    if changes == 0 && !unsure {
        return Ok(None);
    }
    if changes == 0 || depth == 0 {
        if changes == 0 && !sure && depth == SPLIT_DEPTH {
            return Err(());
        }
        let interior = &p[1..p.len().max(2) - 1];
        if end != -1 && interior.iter().any(|&v| v * sign < 0.0) {
            if probes.len() == MAX_CHANGES {
                return Err(());
            }
            probes.push(a + (b - a) * nearest_other_sign(p, sign));
        }
        return Ok((end == -1).then_some(b));
    }
    // One change to a sure other sign at the end: the zero is inside.
    // With the end within `tol` of zero the other sign may not be sure
    // anywhere (its points hold the polynomial only in their hull): the
    // halves decide. That end is a checkpoint only at the step's end.
    if changes == 1 && !unsure && end == -1 {
        return Ok(Some(b));
    }
    let n = p.len();
    let (left, right) = split(p, 0.5);
    let m = 0.5 * (a + b);
    match first_other_sign(&left[..n], sign, tol, (a, m), depth - 1, budget, probes)? {
        Some(t) => Ok(Some(t)),
        None => first_other_sign(&right[..n], sign, tol, (m, b), depth - 1, budget, probes),
    }
}

/// Where on `[0, 1]` the polynomial with Bernstein points `p` (at least
/// three) goes furthest toward the sign `−sign`: from its interior point
/// furthest that way, Newton's steps to the zero of the derivative while
/// the polynomial is concave that way.
fn nearest_other_sign(p: &[f64], sign: f64) -> f64 {
    let n = p.len();
    let interior = p[1..n - 1].iter().map(|&v| -sign * v);
    let (i, _) = interior
        .enumerate()
        .fold((0, f64::NEG_INFINITY), |best, (i, v)| {
            if v > best.1 { (i, v) } else { best }
        });
    let mut u = (i + 1) as f64 / (n - 1) as f64;
    let a = bernstein_to_powers(p);
    for _ in 0..8 {
        let (_, dv, hv) = powers_at(&a[..n], u);
        if -sign * hv >= 0.0 || hv.is_nan() {
            break;
        }
        let next = (u - dv / (2.0 * hv)).clamp(0.0, 1.0);
        if next == u {
            break;
        }
        u = next;
    }
    u
}

/// Where the polynomial with Bernstein control points `p` on `[0, 1]`
/// (its start within `tol` of zero, or of no matter which sign) takes a
/// sure sign: a `τ` such that its value at `τ` has a sign `σ` beyond `tol`
/// and on `[0, τ]` it never has the sign `−σ` beyond `tol` (the points of
/// that piece after the first, which hold it in their hull with the
/// start); `(τ, σ)`. The first of the [`EARLY`] fractions that is such a
/// point, so that the change of class a start on the boundary makes is
/// seen apart from the step's other changes; else the largest `2⁻ᵏ`
/// (k ≤ [`SPLIT_DEPTH`]). `None`: no such point (the polynomial hugs
/// zero, or leaves the start with the other sign first).
fn first_sure_sign(p: &[f64], tol: f64) -> Option<(f64, f64)> {
    let n = p.len();
    let sure_on = |piece: &[f64]| {
        let end = piece[n - 1];
        let sure = if end > tol {
            1.0
        } else if end < -tol {
            -1.0
        } else {
            return None;
        };
        piece[1..n]
            .iter()
            .all(|&v| v * sure >= -tol)
            .then_some(sure)
    };
    for tau in EARLY {
        if let Some(sure) = sure_on(&split_left(p, tau)[..n]) {
            return Some((tau, sure));
        }
    }
    let mut piece = [0.0; MAX_CONTROL];
    piece[..n].copy_from_slice(p);
    let mut tau = 1.0;
    for _ in 0..=SPLIT_DEPTH {
        if let Some(sure) = sure_on(&piece[..n]) {
            return Some((tau, sure));
        }
        // Points all within `tol` of zero stay so in every half (each the
        // rounded mean of two, `tol/2` exact above the subnormals): no end
        // beyond `tol` is left to find.
        if tol >= 4.0 * f64::MIN_POSITIVE && piece[..n].iter().all(|v| v.abs() <= tol) {
            return None;
        }
        piece = split_left(&piece[..n], 0.5);
        tau *= 0.5;
    }
    None
}

/// An affine atom's control points on a step, their number and error bound.
type FormPoints = ([f64; MAX_CONTROL], usize, f64);

/// The Bernstein control points on the step of the affine form `form`
/// along `path`'s polynomial, their number and a bound on their rounding
/// error and on that of the system's own evaluation of the form (in
/// another order) at a point of the step. `None`: the path is not a
/// polynomial.
fn form_points<P: StepPath>(form: &AffineAtom, path: &P) -> Option<FormPoints> {
    let mut points = [0.0; MAX_CONTROL];
    // c₀ + Σ cₖ·(xₖ's points).
    let mut g = [form.constant; MAX_CONTROL];
    let mut count = None;
    let mut err = form.constant.abs();
    for &(k, c) in &form.terms {
        let (len, e) = path.control_points(k, &mut points)?;
        if *count.get_or_insert(len) != len {
            return None;
        }
        let mut size: f64 = 0.0;
        for (gi, &p) in g.iter_mut().zip(&points[..len]) {
            *gi += c * p;
            size = size.max(p.abs());
        }
        err += c.abs() * (size + e / f64::EPSILON);
    }
    let tol = (form.terms.len() as f64 + 16.0) * f64::EPSILON * err;
    Some((g, count.unwrap_or(1), tol))
}

/// The coefficients in powers of `t` of the polynomial with Bernstein
/// points `p` on `[0, 1]`: `aⱼ = C(d, j)·Σₖ (−1)^(j−k)·C(j, k)·bₖ` (degree
/// d = `p.len() − 1`).
#[inline(always)]
fn bernstein_to_powers(p: &[f64]) -> [f64; MAX_CONTROL] {
    let d = p.len() - 1;
    let mut a = [0.0; MAX_CONTROL];
    for (j, aj) in a.iter_mut().enumerate().take(d + 1) {
        let mut sum = 0.0;
        for (k, &bk) in p.iter().enumerate().take(j + 1) {
            let c = BINOMIAL[j][k];
            sum += if (j - k) % 2 == 0 { c * bk } else { -c * bk };
        }
        *aj = BINOMIAL[d][j] * sum;
    }
    a
}

/// `C(n, k)` for `n < MAX_CONTROL` (Pascal's triangle).
const BINOMIAL: [[f64; MAX_CONTROL]; MAX_CONTROL] = {
    let mut c = [[0.0; MAX_CONTROL]; MAX_CONTROL];
    let mut n = 0;
    while n < MAX_CONTROL {
        c[n][0] = 1.0;
        let mut k = 1;
        while k <= n {
            c[n][k] = c[n - 1][k - 1] + c[n - 1][k];
            k += 1;
        }
        n += 1;
    }
    c
};

/// The value, the derivative and half the second derivative at `t` of
/// `Σ aⱼ tʲ` (Horner).
#[inline(always)]
fn powers_at(a: &[f64], t: f64) -> (f64, f64, f64) {
    let (mut v, mut dv, mut hv) = (0.0, 0.0, 0.0);
    for &c in a.iter().rev() {
        hv = hv * t + dv;
        dv = dv * t + v;
        v = v * t + c;
    }
    (v, dv, hv)
}

/// A zero in `(a, b)` of the polynomial with Bernstein points `p` on
/// `[0, 1]`, to within about `width` (steps to the zero of the local
/// Taylor quadratic kept inside the bracket, no evaluation of the system;
/// a first trial for the
/// localization, which the system's values then confirm); `None` if its
/// values at `a` and `b` do not have strictly opposite signs.
fn bernstein_zero(p: &[f64], range: (f64, f64), width: f64) -> Option<f64> {
    per_count!(p, |p| bernstein_zero_in(p, range, width))
}

/// [`bernstein_zero`], inlined into each length's copy.
#[inline(always)]
fn bernstein_zero_in(p: &[f64], (mut a, mut b): (f64, f64), width: f64) -> Option<f64> {
    let c = bernstein_to_powers(p);
    let c = &c[..p.len()];
    let ((fa, da, ha), (fb, db, hb)) = (powers_at(c, a), powers_at(c, b));
    // Strictly opposite signs (no zero, no NaN).
    (fa * fb < 0.0).then_some(())?;
    let a_neg = fa < 0.0;
    // Newton from the end where the value and the curvature have the same
    // sign (Fourier's condition: the iterates then approach the zero from
    // that side without overshooting), else from the secant's zero.
    let mut t = if fb * hb > 0.0 {
        b - fb / db
    } else if fa * ha > 0.0 {
        a - fa / da
    } else {
        (a * fb - b * fa) / (fb - fa)
    };
    for _ in 0..32 {
        if !(t > a && t < b) {
            t = 0.5 * (a + b);
        }
        let (ft, dt, ht) = powers_at(c, t);
        if ft == 0.0 {
            break;
        }
        if (ft < 0.0) == a_neg {
            a = t;
        } else {
            b = t;
        }
        // The zero nearest `t` of the Taylor quadratic ft + dt·δ + ht·δ²
        // (exact for quadratics, cubic convergence otherwise), else
        // Newton's step.
        let disc = dt * dt - 4.0 * ft * ht;
        let step = if disc >= 0.0 {
            2.0 * ft / (dt + dt.signum() * disc.sqrt())
        } else {
            ft / dt
        };
        t -= step;
        // The next error is at most about Newton's, step²·f''/(2f'): below
        // the width, this step ends the search.
        if (step * step * ht / dt).abs() <= 0.5 * width || b - a <= width {
            break;
        }
    }
    Some(t.clamp(a, b))
}

/// The Bernstein control points of the polynomial with points `p` on
/// `[0, 1]` restricted to `[0, t]` and to `[t, 1]` (de Casteljau).
fn split(p: &[f64], t: f64) -> ([f64; MAX_CONTROL], [f64; MAX_CONTROL]) {
    let n = p.len();
    let (mut left, mut right) = ([0.0; MAX_CONTROL], [0.0; MAX_CONTROL]);
    de_casteljau(p, t, |r, first, last| {
        left[r] = first;
        right[n - 1 - r] = last;
    });
    (left, right)
}

/// The points of [`split`]'s first half alone (the start of a step, looked
/// at for every atom on a boundary at a segment's start).
fn split_left(p: &[f64], t: f64) -> [f64; MAX_CONTROL] {
    let mut left = [0.0; MAX_CONTROL];
    de_casteljau(p, t, |r, first, _| left[r] = first);
    left
}

/// The points of [`split`]'s second half alone (the rest of a step after
/// a point of it).
fn split_right(p: &[f64], t: f64) -> [f64; MAX_CONTROL] {
    let n = p.len();
    let mut right = [0.0; MAX_CONTROL];
    de_casteljau(p, t, |r, _, last| right[n - 1 - r] = last);
    right
}

/// De Casteljau's scheme at `t` on the points `p`: `row(r, first, last)`
/// for each row `r` of the triangle, with its first and last entries.
#[inline(always)]
fn de_casteljau(p: &[f64], t: f64, row: impl FnMut(usize, f64, f64)) {
    per_count!(p, |p| de_casteljau_in(p, t, row))
}

/// [`de_casteljau`], inlined into each length's copy.
#[inline(always)]
fn de_casteljau_in(p: &[f64], t: f64, mut row: impl FnMut(usize, f64, f64)) {
    let n = p.len();
    if n == 0 {
        return;
    }
    // The first row from `p` itself (a copy of a few points into `work`
    // would be a call to memcpy).
    row(0, p[0], p[n - 1]);
    let mut work = [0.0; MAX_CONTROL];
    for i in 0..n - 1 {
        work[i] = (1.0 - t) * p[i] + t * p[i + 1];
    }
    for r in 1..n {
        row(r, work[0], work[n - 1 - r]);
        for i in 0..n - 1 - r {
            work[i] = (1.0 - t) * work[i] + t * work[i + 1];
        }
    }
}

/// Sorts a step's checkpoints (by [`f64::total_cmp`]): inline insertion
/// for the few of most steps (a call to the library's sort cost more).
fn sort_points(points: &mut [f64]) {
    if points.len() > 8 {
        points.sort_unstable_by(f64::total_cmp);
        return;
    }
    for i in 1..points.len() {
        let mut k = i;
        while k > 0 && points[k - 1].total_cmp(&points[k]).is_gt() {
            points.swap(k - 1, k);
            k -= 1;
        }
    }
}

/// The most sign changes of one affine atom looked for on one step (a
/// polynomial of degree 7, Dop853's interpolant, changes sign at most 7
/// times).
const MAX_CHANGES: usize = 8;

/// At most this many candidates are examined between two checkpoints (an
/// atom chattering around zero on the interpolant cannot stall the scan).
const MAX_CANDIDATES: usize = 64;

/// Fractions of the first step of a segment that starts near a boundary
/// at which the watched atoms are also evaluated.
const EARLY: [f64; 3] = [
    1.0 / (1u64 << 30) as f64,
    1.0 / (1u64 << 20) as f64,
    1.0 / 1024.0,
];

/// What the scan of one step has computed for one watched atom, each
/// `None` until computed (a twin reads its earlier atom's).
#[derive(Clone, Copy, Default)]
struct StepFacts {
    /// Its affine form's points on the step ([`form_points`]).
    form_pts: Option<FormPoints>,
    /// Its [`first_sure_sign`] on the step.
    sure_pts: Option<Option<(f64, f64)>>,
    /// Where and with which sign the search for its sign changes on the
    /// step started, and whether it settled them
    /// ([`affine_checkpoints`](Watcher::affine_checkpoints)).
    changes_from: Option<(f64, f64, bool)>,
}

/// Watches the sets along a flow segment; see the module docs.
pub(crate) struct Watcher {
    sets: Vec<WSet>,
    /// Index of C in `sets`, if C is not the whole space.
    flow: Option<usize>,
    watched: Vec<WAtom>,
    /// The event sources' timer atoms ([`Atom::timer`](super::system::Atom::timer)).
    timers: Vec<TimerAtom>,
    /// Whether a timer atom's threshold is read at each segment's start.
    per_segment_timers: bool,
    /// The earliest local time `d` of the timer atoms not crossed yet in
    /// the segment (∞: none due): a checkpoint before it crosses none.
    next_due: f64,
    /// Per watched atom: the bracket `(a, b)` of its first change found in
    /// the current [`Watcher::resolve`], with the class and relaxation it
    /// was found for (`a` NaN: none).
    found: Vec<(f64, f64, i8, f64)>,
    /// Per watched atom: whether it needs localizing in the current round
    /// of [`Watcher::resolve`] ([`Watcher::mark_needs`]).
    need: Vec<bool>,
    /// Per set: how many of its watched atoms change class between the
    /// cursor and the checkpoint in the current round ([`Watcher::mark_needs`]).
    changing: Vec<u32>,
    /// Per watched atom: an earlier one with the same function `g`
    /// ([`Atom::g_id`](super::system::Atom::g_id)).
    twin: Vec<Option<usize>>,
    /// Per watched atom: its function as an affine form of the state, if
    /// the system gives one ([`HybridSystem::atom_affine`]).
    affine: Vec<Option<AffineAtom>>,
    /// The checkpoints of the step being scanned, and the points where its
    /// affine atoms have changed sign ([`Watcher::affine_checkpoints`]).
    points: Vec<f64>,
    extra: Vec<f64>,
    /// Those of atoms that change sign more than once on the step.
    extra_many: Vec<f64>,
    /// Where an affine atom's polynomial may graze zero, in the step's
    /// variable ([`first_other_sign`]).
    probes: Vec<f64>,
    /// How many of C's atoms are relaxed (most of the time none, and
    /// [`Watcher::settle_relaxed`] has nothing to do).
    relaxed: usize,
    /// Sign class of each watched atom at the cursor and at the checkpoint.
    cls: Vec<i8>,
    cls_s: Vec<i8>,
    checks: usize,
    event_tol: f64,
    set_tol: f64,
    /// The segment's start time (global time of local time `s`:
    /// `clock.at(s)`, the time the engine records an event at).
    clock: TimeSum,
    /// The jump count of the segment being watched (constant along it).
    j: u64,
    /// Whether a watched atom started the segment within `set_tol` of its
    /// zero.
    near_start: bool,
    /// The step being scanned, `[s0, s1]`.
    span: (f64, f64),
    /// Per watched atom: what is known of it on the step being scanned
    /// ([`StepFacts`], cleared at each step in one pass).
    step: Vec<StepFacts>,
    buf_s: Vec<f64>,
    buf_a: Vec<f64>,
    buf_b: Vec<f64>,
    buf_t: Vec<f64>,
    best_a: Vec<f64>,
    /// Whether an event's bracket start is read: only equality atoms
    /// (`==`, `!=`) are decided from both ends of the bracket (every other
    /// atom at its post-change end), so without them neither the state
    /// nor the atoms there are computed.
    bracket_start_read: bool,
    /// With [`Priority::Flows`] or [`Priority::Random`], the number of jump
    /// rules asked at the last point found in C when the flow leaves it
    /// without meeting a jump set there (0 otherwise): a solution
    /// that cannot flow on jumps there if it may, not one rounding step
    /// (or, with relaxed atoms, `set_tol`) outside C, where it may no
    /// longer be in any set.
    exit_rules: usize,
    /// Offset of each set's atoms in the layout of
    /// [`HybridSystem::all_atom_values`] (`None`: a set without atoms).
    flat_off: Vec<Option<usize>>,
    /// All sets' atom values at one point, in that layout (and at the
    /// second end of an event's bracket).
    flat: Vec<f64>,
    flat_b: Vec<f64>,
    /// Whether the system evaluates all sets at once (found at each
    /// segment's start).
    flat_ok: bool,
    /// The jump sets [`start_sets`](Self::start_sets) reads in one pass
    /// when `flat_ok` ([`FastSet`]), and the other sets (all sets when
    /// not `flat_ok`).
    fast_sets: Vec<FastSet>,
    slow_sets: Vec<usize>,
    /// Whether the checkpoints use that: the event sources hold at least
    /// half of all flowing atoms (the other sets' atoms are evaluated for
    /// nothing) and there are several sources.
    flat_checks: bool,
    /// Whether every event source has its atoms in that layout (a
    /// checkpoint's values are then read per watched atom).
    flat_watched: bool,
    /// The point at which `flat` already holds every set's atoms, if the
    /// next [`start`](Self::start) may start from it
    /// ([`prefetch`](Self::prefetch), [`prefetch_sets`](Self::prefetch_sets)):
    /// a jump moves to another point (j + 1), a start takes them.
    prefetched: Option<HybridTime>,
    /// The point at which `flat` and the engine's `inside` hold every set's
    /// atoms and every rule's membership
    /// ([`prefetch_sets`](Self::prefetch_sets)), until a start or another
    /// evaluation.
    sets_at: Option<HybridTime>,
    /// Per rule: the sets (indices into `sets`) a jump by it alone may
    /// change, those that read `j` or what it writes
    /// ([`HybridSystem::set_inputs`]); `None`: all, or more than half of
    /// them (one evaluation of all sets then costs less). Found at the
    /// first jump from a point where every set was evaluated (the runs of
    /// most systems make none).
    stale_after: Option<Vec<Option<Vec<usize>>>>,
    /// The state at the last event found by [`Watcher::scan`] (the
    /// post-change end of its bracket).
    pub event_state: Vec<f64>,
    /// First rule (declaration order) whose jump set holds at the last
    /// event.
    rule_at_event: Option<usize>,
    /// Whether the flow left C at the last event (also where a jump set was
    /// met there, which is then the event's kind).
    left_at_event: bool,
    /// The search for sign changes between checkpoints ([`hidden`]).
    hidden: hidden::Hidden,
}

impl Watcher {
    /// A watcher for `sys` under `settings`: general jump rules are event
    /// sources unless the priority is [`Priority::Flows`] (which jumps only
    /// when the flow cannot continue); C is one if it is not everything.
    pub fn new<S: HybridSystem + ?Sized>(sys: &S, settings: &SimSettings, x0: &[f64]) -> Self {
        let mut sets = Vec::new();
        let push = |sets: &mut Vec<WSet>, set: SetRef, spec: Option<SetAtoms>, source: bool| {
            let n = spec.as_ref().map_or(1, |s| s.atoms.len());
            sets.push(WSet {
                set,
                table: truth_table(spec.as_ref()),
                spec,
                source,
                state: vec![AtomState::default(); n],
                vs: vec![0.0; n],
                va: vec![0.0; n],
                vb: vec![0.0; n],
                vt: vec![0.0; n],
                past: false,
                on: false,
                cur: false,
                new: false,
            });
        };
        for (i, rule) in sys.jump_rules().iter().enumerate() {
            let source = settings.priority != Priority::Flows && rule.guard == GuardKind::General;
            push(
                &mut sets,
                SetRef::Jump(i),
                sys.set_atoms(SetRef::Jump(i)),
                source,
            );
        }
        let flow_spec = sys.set_atoms(SetRef::Flow);
        let mut flow = None;
        if flow_spec.is_some() || sys.flow_guard(HybridTime::new(0.0, 0), x0).is_some() {
            flow = Some(sets.len());
            push(&mut sets, SetRef::Flow, flow_spec, true);
        }
        let mut watched = Vec::new();
        for (i, ws) in sets.iter().enumerate() {
            if ws.source {
                for k in 0..ws.atom_count() {
                    if ws.watched(k) {
                        watched.push(WAtom {
                            set: i,
                            atom: k,
                            cmp: ws.cmp(k),
                            flat: 0,
                        });
                    }
                }
            }
        }
        // The timer atoms of the event sources: scheduled, not watched.
        let mut timers = Vec::new();
        for (i, ws) in sets.iter().enumerate() {
            if let (true, Some(spec)) = (ws.source, &ws.spec) {
                for (k, a) in spec.atoms.iter().enumerate() {
                    if let (true, Some((index, threshold))) = (a.flows, a.timer) {
                        let (threshold, per_segment) = match threshold {
                            Threshold::Const(c) => (c, false),
                            Threshold::PerSegment => (f64::NAN, true),
                        };
                        timers.push(TimerAtom {
                            set: i,
                            atom: k,
                            cmp: a.cmp,
                            index,
                            threshold,
                            per_segment,
                            d: f64::INFINITY,
                            slack: 0.0,
                            after: false,
                            crossed: false,
                            now: false,
                            strict_timer: false,
                        });
                    }
                }
            }
        }
        for i in 0..timers.len() {
            let index = timers[i].index;
            timers[i].strict_timer = timers
                .iter()
                .any(|t| t.index == index && matches!(t.cmp, Cmp::Lt | Cmp::Gt));
        }
        // An earlier watched atom with the same function: its zeros are
        // this one's.
        let g_id = |w: &WAtom| {
            let ws = &sets[w.set];
            ws.spec.as_ref().and_then(|s| s.atoms[w.atom].g_id)
        };
        let twin = (0..watched.len())
            .map(|w| {
                let id = g_id(&watched[w])?;
                (0..w).find(|&u| g_id(&watched[u]) == Some(id))
            })
            .collect();
        let affine: Vec<Option<AffineAtom>> = watched
            .iter()
            .map(|w| {
                let ws = &sets[w.set];
                ws.spec.as_ref()?;
                sys.atom_affine(ws.set, w.atom)
            })
            .collect();
        for (w, form) in watched.iter().zip(&affine) {
            let inequality = matches!(w.cmp, Cmp::Ge | Cmp::Gt | Cmp::Le | Cmp::Lt);
            if Some(w.set) == flow && form.is_none() && inequality {
                sets[w.set].state[w.atom].noisy = true;
            }
        }
        // The layout of `all_atom_values`: C's atoms, then each rule's.
        let mut flat_off = vec![None; sets.len()];
        let mut total = 0;
        let (mut flowing, mut watched_sets) = (0, 0);
        for i in flow
            .into_iter()
            .chain((0..sets.len()).filter(|&i| Some(i) != flow))
        {
            let ws = &sets[i];
            if let Some(spec) = &ws.spec {
                flat_off[i] = Some(total);
                total += spec.atoms.len();
                flowing += spec.atoms.iter().filter(|a| a.watched()).count();
                watched_sets += usize::from(ws.source);
            }
        }
        for w in &mut watched {
            w.flat = flat_off[w.set].unwrap_or_default() + w.atom;
        }
        let flat_checks = watched_sets >= 2 && 2 * watched.len() >= flowing;
        let (mut fast_sets, mut slow_sets) = (Vec::new(), Vec::new());
        for (i, ws) in sets.iter().enumerate() {
            match (flat_off[i], &ws.spec, ws.table) {
                (Some(off), Some(spec), Some(table)) if Some(i) != flow => {
                    let mut cmps = [Cmp::Ge; TruthTable::MAX_ATOMS];
                    for (c, a) in cmps.iter_mut().zip(&spec.atoms) {
                        *c = a.cmp;
                    }
                    fast_sets.push(FastSet {
                        set: i,
                        off,
                        n: spec.atoms.len(),
                        cmps,
                        table,
                    });
                }
                _ => slow_sets.push(i),
            }
        }
        // Also after a coin that chose to flow (from a point of C ∩ D, where
        // a jump set may hold until C ends).
        let exit_rules = if settings.priority != Priority::Jumps {
            sys.jump_rules().len()
        } else {
            0
        };
        let bracket_start_read = sets.iter().any(|ws| {
            ws.spec.as_ref().is_some_and(|spec| {
                spec.atoms
                    .iter()
                    .any(|a| matches!(a.cmp, Cmp::Eq | Cmp::Ne))
            })
        });
        let flat_watched = (0..sets.len()).all(|i| !sets[i].source || flat_off[i].is_some());
        let n = x0.len();
        let set_count = sets.len();
        // Room for a step's checkpoints from the start (a run's first steps
        // would otherwise grow these): the early ones, the evenly spaced
        // ones, each watched atom's first sure sign, changes and probes, the timers.
        let extra_room = watched.len() * (2 * MAX_CHANGES + 1);
        let points_room =
            EARLY.len() + settings.guard_checks as usize + extra_room + timers.len() + 1;
        Self {
            sets,
            flow,
            flat_off,
            flat: vec![0.0; total],
            flat_b: vec![0.0; total],
            flat_ok: false,
            fast_sets,
            slow_sets,
            flat_checks,
            flat_watched,
            prefetched: None,
            sets_at: None,
            stale_after: None,
            cls: vec![0; watched.len()],
            cls_s: vec![0; watched.len()],
            step: vec![StepFacts::default(); watched.len()],
            found: vec![(f64::NAN, f64::NAN, 0, 0.0); watched.len()],
            need: vec![false; watched.len()],
            changing: vec![0; set_count],
            watched,
            per_segment_timers: timers.iter().any(|ta| ta.per_segment),
            timers,
            next_due: f64::INFINITY,
            twin,
            affine,
            points: Vec::with_capacity(points_room),
            extra: Vec::with_capacity(extra_room),
            extra_many: Vec::with_capacity(extra_room),
            probes: Vec::with_capacity(MAX_CHANGES),
            relaxed: 0,
            checks: settings.guard_checks as usize,
            event_tol: settings.event_tol,
            set_tol: settings.set_tol,
            clock: TimeSum::default(),
            j: 0,
            near_start: false,
            span: (0.0, 0.0),
            buf_s: vec![0.0; n],
            buf_a: vec![0.0; n],
            buf_b: vec![0.0; n],
            buf_t: vec![0.0; n],
            // Read only with equality atoms or at C's exits.
            best_a: vec![0.0; n * usize::from(bracket_start_read || exit_rules > 0)],
            bracket_start_read,
            exit_rules,
            event_state: vec![0.0; n],
            rule_at_event: None,
            left_at_event: false,
            hidden: hidden::Hidden::default(),
        }
    }

    /// The start time of the segment being watched ([`start`](Self::start)).
    pub fn clock(&self) -> TimeSum {
        self.clock
    }

    /// The first rule whose jump set holds at the last event found.
    pub fn rule_at_event(&self) -> Option<usize> {
        self.rule_at_event
    }

    /// Whether the flow left C at the last event found, whatever the
    /// event's kind: a jump set met where the flow leaves C admits no flow
    /// from there, whichever the priority.
    pub fn left_at_event(&self) -> bool {
        self.left_at_event
    }

    /// Whether rule `r`'s jump set holds at the last event found (as the
    /// watcher decided it on the event's bracket: an equality atom met
    /// inside the bracket counts).
    pub fn reached_at_event(&self, r: usize) -> bool {
        self.sets
            .iter()
            .any(|ws| ws.set == SetRef::Jump(r) && ws.new)
    }

    /// `true` if nothing is watched (timers only, C the whole space, no
    /// flowing atom).
    pub fn is_empty(&self) -> bool {
        self.watched.is_empty()
    }

    /// The state components that are timers of the sets' timer atoms.
    pub fn timer_indices(&self) -> impl Iterator<Item = usize> + '_ {
        self.timers.iter().map(|a| a.index)
    }

    /// Schedules the timer atoms of the segment started by
    /// [`start`](Self::start) from `x`, whose flow there is `f` (at least
    /// at the timer components): returns the local time at which the
    /// segment must end for them (∞: never), or `None` if C is left at once
    /// (a timer atom of C on its threshold, or beyond it within `set_tol`,
    /// moving away from C, and C fails with it). A timer atom that becomes
    /// false at once keeps that truth for the segment.
    ///
    /// With watched atoms, every step is scanned and each threshold is a
    /// checkpoint of the step that passes it ([`cross_timers`](Self::cross_timers)):
    /// the segment goes on there unless a set changes (the ball's apex, a
    /// timer atom of C = {h ≥ 0 ∨ v ≥ 0} passed while h > 0, costs no new
    /// segment). Without, the segment ends at the first threshold.
    #[inline]
    pub fn schedule(&mut self, x: &[f64], f: &[f64]) -> Option<f64> {
        // No timer atom (as in most systems): nothing due, C not left.
        if self.timers.is_empty() {
            return Some(f64::INFINITY);
        }
        self.schedule_atoms(x, f)
    }

    /// [`schedule`](Self::schedule) with timer atoms.
    fn schedule_atoms(&mut self, x: &[f64], f: &[f64]) -> Option<f64> {
        let mut first = f64::INFINITY;
        let mut changed = false;
        for ta in &mut self.timers {
            let (v, rate, thr, cmp) = (x[ta.index], f[ta.index], ta.threshold, ta.cmp);
            // Towards the threshold: when it is reached. On (or past) it and
            // moving away from it (`away`): the truth just after the start is
            // that of `g` with the rate's sign. One test of the rate's sign.
            let (d, away) = if rate > 0.0 {
                if v < thr {
                    ((thr - v) / rate, false)
                } else {
                    (f64::INFINITY, v >= thr)
                }
            } else if rate < 0.0 {
                if v > thr {
                    ((thr - v) / rate, false)
                } else {
                    (f64::INFINITY, v <= thr)
                }
            } else {
                (f64::INFINITY, false)
            };
            ta.d = d;
            ta.slack = timer_slack(v, thr, rate);
            let after = cmp.holds(rate);
            ta.after = after;
            ta.crossed = false;
            first = first.min(d);
            if away {
                let ws = &mut self.sets[ta.set];
                if ws.state[ta.atom].start_truth != after {
                    ws.state[ta.atom].start_truth = after;
                    changed = true;
                }
            }
        }
        self.next_due = first;
        if changed {
            for (i, ws) in self.sets.iter_mut().enumerate() {
                if let Some(spec) = &ws.spec {
                    let value = set_value(spec, ws.table, |k| ws.state[k].start_truth);
                    if self.flow == Some(i) {
                        if !value {
                            return None;
                        }
                    } else {
                        ws.cur = value;
                    }
                }
            }
        }
        Some(if self.watched.is_empty() {
            first
        } else {
            f64::INFINITY
        })
    }

    /// Passes the thresholds of the timer atoms due by the checkpoint `s`
    /// (local time; the state there is `x`, the watched atoms' values at it
    /// in `vs`): an event if a jump set holds on a threshold (the timer
    /// exactly on it) or C fails past it, else each set takes its value
    /// past the thresholds and the scan goes on. The event's state is `x`
    /// with the timers crossed there set exactly to their thresholds.
    /// Called only when some are due (`next_due <= s`).
    fn cross_timers(&mut self, s: f64, x: &[f64]) -> Option<EventKind> {
        let mut next = f64::INFINITY;
        for ta in &mut self.timers {
            ta.now = !ta.crossed && ta.d <= s;
            ta.crossed |= ta.now;
            if !ta.crossed {
                next = next.min(ta.d);
            }
        }
        self.next_due = next;
        // Past the thresholds for the rest of the segment, unless an event
        // ends it here (where the timers land).
        for (i, ta) in self.timers.iter().enumerate() {
            if ta.now {
                let landed = ta.cmp.holds(self.landing(i, |t| t.now) - ta.threshold);
                let ws = &mut self.sets[ta.set];
                ws.state[ta.atom].start_truth = ta.after;
                ws.state[ta.atom].on_threshold = true;
                ws.state[ta.atom].landed = landed;
            }
        }
        // Each source set's value past the thresholds and on them (which
        // differ only where one of its timers is crossed now), once; the
        // first jump set met on the thresholds.
        let mut kind = None;
        for ws in &mut self.sets {
            if let Some(spec) = ws.spec.as_ref().filter(|_| ws.source) {
                (ws.past, ws.on) = timer_set_values(ws, spec);
                if let SetRef::Jump(r) = ws.set
                    && kind.is_none()
                    && !ws.cur
                    && ws.on
                {
                    kind = Some(EventKind::Jump(r));
                }
            }
        }
        let decided = |ws: &WSet| ws.source && ws.spec.is_some();
        // Or C left past them.
        let kind = kind.or_else(|| {
            let ws = &self.sets[self.flow?];
            (decided(ws) && !ws.past).then_some(EventKind::LeftFlowSet)
        });
        for ws in &mut self.sets {
            // A set without timer atoms keeps its value here.
            let v = match (decided(ws), kind.is_some() && ws.set != SetRef::Flow) {
                (false, _) => ws.cur,
                (true, true) => ws.on,
                (true, false) => ws.past,
            };
            if kind.is_some() {
                ws.new = v;
            } else {
                ws.cur = v;
            }
        }
        for ta in &self.timers {
            if ta.now {
                let ws = &mut self.sets[ta.set];
                ws.state[ta.atom].on_threshold = false;
            }
        }
        let kind = kind?;
        // As at an event found by `resolve`.
        self.rule_at_event = self.sets.iter().find_map(|ws| match ws.set {
            SetRef::Jump(r) if ws.new => Some(r),
            _ => None,
        });
        self.left_at_event = self.flow.is_some_and(|fi| {
            let ws = &self.sets[fi];
            ws.cur && !ws.new
        });
        self.event_state.copy_from_slice(x);
        for i in 0..self.timers.len() {
            if self.timers[i].now {
                self.event_state[self.timers[i].index] = self.landing(i, |t| t.now);
            }
        }
        Some(kind)
    }

    /// Where the timer of timer atom `i` lands when the segment ends at its
    /// threshold with the timer atoms `due`: on the threshold (where a
    /// non-strict atom holds), unless a strict atom of the same timer due
    /// there holds past it (`tau > Ts`, `tau` rising): then on the first
    /// float past its threshold, the first point where it holds.
    fn landing(&self, i: usize, due: impl Fn(&TimerAtom) -> bool) -> f64 {
        let TimerAtom {
            index,
            threshold,
            strict_timer,
            ..
        } = self.timers[i];
        if !strict_timer {
            return threshold;
        }
        let strict_past = |t: &TimerAtom| match t.cmp {
            Cmp::Gt if t.after => Some(t.threshold.next_up()),
            Cmp::Lt if t.after => Some(t.threshold.next_down()),
            _ => None,
        };
        self.timers
            .iter()
            .filter(|t| t.index == index && due(t))
            .find_map(strict_past)
            .unwrap_or(threshold)
    }

    /// The timer atoms due at the end `d_end` of a segment reached by the
    /// flow: `(index, value)` of each, the value its timer is set to
    /// exactly (its threshold, or the first float past it for a strict
    /// atom: [`landing`](Self::landing)).
    pub fn timers_due(&self, d_end: f64) -> impl Iterator<Item = (usize, f64)> + '_ {
        self.timers
            .iter()
            .enumerate()
            .filter(move |(_, a)| a.due_at(d_end))
            .map(move |(i, a)| (a.index, self.landing(i, |t| t.due_at(d_end))))
    }

    /// Records the state at the start of a flow segment (local time 0,
    /// global hybrid time `at`): constant atoms' truth, relaxations of C's
    /// atoms on its boundary, each set's value and each watched atom's sign.
    #[inline]
    pub fn start<S: HybridSystem + ?Sized>(&mut self, sys: &S, clock: TimeSum, j: u64, x: &[f64]) {
        self.clock = clock;
        self.j = j;
        // Nothing watched and nothing scheduled: no step is scanned and no
        // event found, so nothing reads the start's values (timer rules
        // only, as periodic sampling).
        if self.watched.is_empty() && self.timers.is_empty() {
            return;
        }
        self.start_sets(sys, HybridTime::new(clock.value(), j), x);
    }

    /// [`start`](Self::start) with something watched or scheduled.
    fn start_sets<S: HybridSystem + ?Sized>(&mut self, sys: &S, at: HybridTime, x: &[f64]) {
        if self.per_segment_timers {
            for ta in self.timers.iter_mut().filter(|ta| ta.per_segment) {
                ta.threshold = sys.timer_threshold(self.sets[ta.set].set, ta.atom, at, x);
            }
        }
        let set_tol = self.set_tol;
        // The flow moves the state: nothing is carried past the start.
        self.sets_at = None;
        if std::mem::take(&mut self.prefetched) != Some(at) {
            self.flat_ok = sys.all_atom_values(at, x, false, &mut self.flat);
        }
        self.relaxed = 0;
        // The per-segment common case first: the jump sets (their atoms
        // never relaxed) of at most `TruthTable::MAX_ATOMS` atoms, their
        // values from the evaluation of all sets, in one tight pass.
        let others = if self.flat_ok {
            for fs in &self.fast_sets {
                let ws = &mut self.sets[fs.set];
                let n = fs.n;
                let flat = &self.flat[fs.off..fs.off + n];
                let (vs, state, cmps) = (&mut ws.vs[..n], &mut ws.state[..n], &fs.cmps[..n]);
                let mut mask = 0u32;
                for (k, &g) in flat.iter().enumerate() {
                    vs[k] = g;
                    let holds = cmps[k].holds(g);
                    state[k].start_truth = holds;
                    mask |= u32::from(holds) << k;
                }
                ws.cur = fs.table.value(mask);
            }
            self.slow_sets.len()
        } else {
            self.sets.len()
        };
        for idx in 0..others {
            let i = if self.flat_ok {
                self.slow_sets[idx]
            } else {
                idx
            };
            let (ws, flat_off) = (&mut self.sets[i], self.flat_off[i]);
            let is_flow = self.flow == Some(i);
            // The set's values from the prefetched ones (copied by the pass
            // below: a call to memcpy for 3 or 4 values cost more), or its own.
            let flat = match flat_off {
                Some(off) if self.flat_ok => Some(&self.flat[off..off + ws.vs.len()]),
                _ => {
                    atom_values(sys, ws.kind(), at, x, false, &mut ws.vs);
                    None
                }
            };
            // The atoms' truth, and as bits the truth table's index (a
            // table covers at most `TruthTable::MAX_ATOMS` atoms).
            let mut mask = 0u32;
            match &ws.spec {
                // A jump set's atoms are never relaxed (`relax` stays 0):
                // one pass of comparisons, the per-segment common case.
                Some(spec) if !is_flow => {
                    let n = ws.vs.len();
                    let (vs, state, atoms) = (&mut ws.vs[..], &mut ws.state[..n], &spec.atoms[..n]);
                    let mut pass = |k: usize, g: f64| {
                        let holds = atoms[k].cmp.holds(g);
                        state[k].start_truth = holds;
                        if k < TruthTable::MAX_ATOMS {
                            mask |= u32::from(holds) << k;
                        }
                    };
                    // One loop per source of the values, without a test per atom.
                    match flat {
                        Some(f) => {
                            for (k, (v, &g)) in vs.iter_mut().zip(f).enumerate() {
                                *v = g;
                                pass(k, g);
                            }
                        }
                        None => {
                            for (k, &g) in vs.iter().enumerate() {
                                pass(k, g);
                            }
                        }
                    }
                }
                _ => {
                    let atoms = ws.spec.as_ref().map(|s| &s.atoms[..]);
                    for k in 0..ws.vs.len() {
                        if let Some(f) = flat {
                            ws.vs[k] = f[k];
                        }
                        let g = ws.vs[k];
                        let cmp = atoms.map_or(Cmp::Ge, |a| a[k].cmp);
                        let holds = cmp.holds(g);
                        // Relaxed: C's atoms that hold only within set_tol
                        // (and then hold within their relaxation), and its
                        // noisy atoms that hold on their boundary (within
                        // set_tol of zero).
                        let within = match atoms {
                            Some(a) => a[k].holds_within(g, set_tol),
                            None => cmp.holds_within(g, set_tol),
                        };
                        let outside = !holds && within;
                        let st = &mut ws.state[k];
                        let edge = holds && st.noisy && g.abs() <= set_tol;
                        let relaxed = is_flow && (outside || edge);
                        st.relax = if relaxed { set_tol } else { 0.0 };
                        st.settle = if relaxed && st.noisy { set_tol } else { 0.0 };
                        self.relaxed += usize::from(relaxed);
                        st.start_truth = holds || relaxed;
                        if k < TruthTable::MAX_ATOMS {
                            mask |= u32::from(holds || relaxed) << k;
                        }
                    }
                }
            }
            ws.cur = match (&ws.spec, ws.set) {
                // The engine flows only from points of C (within set_tol).
                _ if is_flow => true,
                (Some(spec), _) => match ws.table {
                    Some(t) => t.value(mask),
                    None => spec.expr.eval_with(&|k| ws.state[k].start_truth),
                },
                (None, SetRef::Jump(r)) => sys.jump_set(r, at, x),
                (None, SetRef::Flow) => true,
            };
        }
        let near = 2.0 * set_tol.max(f64::MIN_POSITIVE);
        let mut near_start = false;
        if self.relaxed == 0 && self.flat_ok && self.flat_watched {
            // No atom relaxed: each watched value is the atom's, as
            // evaluated with all sets.
            for (w, c) in self.watched.iter().zip(self.cls.iter_mut()) {
                let v = self.flat[w.flat];
                near_start |= v.abs() <= near;
                *c = class(v);
            }
        } else {
            for (w, c) in self.watched.iter().zip(self.cls.iter_mut()) {
                let ws = &self.sets[w.set];
                let v = watched_value(w.cmp, ws.vs[w.atom], ws.state[w.atom].relax);
                near_start |= v.abs() <= near;
                *c = class(v);
            }
        }
        self.near_start = near_start;
    }

    /// Evaluates every set's atoms at (`at`, `x`) for the next
    /// [`start`](Self::start), which must start from that point (the
    /// caller asks before deciding whether the flow may start there):
    /// returns C's atom values, in the order of its atoms, so that the
    /// flow-set test does not evaluate them again. `None` (nothing
    /// evaluated): the start evaluates nothing (nothing watched or
    /// scheduled), C has no atoms, or the system has no evaluation of all
    /// sets at once.
    #[inline]
    pub fn prefetch<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        at: HybridTime,
        x: &[f64],
    ) -> Option<&[f64]> {
        // Nothing watched or scheduled (timer rules only): decided without
        // a call.
        if self.watched.is_empty() && self.timers.is_empty() {
            return None;
        }
        self.prefetch_flow(sys, at, x)
    }

    /// [`prefetch`](Self::prefetch) when a start evaluates something.
    #[inline(never)]
    fn prefetch_flow<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        at: HybridTime,
        x: &[f64],
    ) -> Option<&[f64]> {
        let fi = self.flow?;
        let off = self.flat_off[fi]?;
        if self.prefetched != Some(at) {
            self.flat_ok = sys.all_atom_values(at, x, false, &mut self.flat);
            self.prefetched = self.flat_ok.then_some(at);
            // The rules' membership is not evaluated with them.
            self.sets_at = None;
        }
        let len = self.sets[fi].vs.len();
        self.flat_ok.then(|| &self.flat[off..off + len])
    }

    /// Every rule's jump set at (`at`, `x`) into `inside`, with every set's
    /// atoms in the same evaluation
    /// ([`HybridSystem::jump_sets_and_atoms`]) kept for a
    /// [`prefetch`](Self::prefetch) or [`start`](Self::start) from that
    /// point: the engine's choice between flowing and jumping and the
    /// segment's start share one evaluation. `false` (nothing evaluated):
    /// the start evaluates nothing, or the system has no such evaluation.
    ///
    /// `jumped`: the rule whose jump alone led from the last point to this
    /// one, if it did. If every set was evaluated there (by this method,
    /// at the same `t` and `j − 1`), only those the jump may change are
    /// evaluated here; the others keep their atoms and membership (their
    /// inputs are unchanged: [`HybridSystem::set_inputs`]).
    #[inline]
    pub fn prefetch_sets<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        at: HybridTime,
        x: &[f64],
        inside: &mut [bool],
        jumped: Option<usize>,
    ) -> bool {
        if !self.prefetches() {
            return false;
        }
        let before = self.sets_at.take();
        let evaluated = match (jumped, before) {
            (Some(rule), Some(b)) if b.t == at.t && b.j.checked_add(1) == Some(at.j) => {
                self.refresh_sets(sys, rule, at, x, inside)
            }
            _ => false,
        } || sys.jump_sets_and_atoms(at, x, inside, &mut self.flat);
        if evaluated {
            self.sets_at = Some(at);
            self.flat_ok = true;
            self.prefetched = Some(at);
        }
        evaluated
    }

    /// Evaluates at (`at`, `x`) the sets a jump by `rule` may change, their
    /// atoms into `flat` and the rules' membership into `inside`, and
    /// returns `true`; or returns `false` (nothing evaluated) if they are
    /// not known to be at most half of them (`stale_after`).
    #[inline(never)]
    fn refresh_sets<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        rule: usize,
        at: HybridTime,
        x: &[f64],
        inside: &mut [bool],
    ) -> bool {
        let stale_after = (self.stale_after).get_or_insert_with(|| stale_sets(sys, &self.sets));
        let Some(Some(stale)) = stale_after.get(rule) else {
            return false;
        };
        for &i in stale {
            let ws = &self.sets[i];
            let atoms = self.flat_off[i].map(|off| &mut self.flat[off..off + ws.vs.len()]);
            match (ws.set, atoms) {
                (SetRef::Jump(r), Some(atoms)) => {
                    inside[r] = sys.jump_set_and_atoms(r, at, x, atoms)
                }
                (SetRef::Jump(r), None) => inside[r] = sys.jump_set(r, at, x),
                (SetRef::Flow, Some(atoms)) => sys.atom_values(SetRef::Flow, at, x, false, atoms),
                (SetRef::Flow, None) => {}
            }
        }
        true
    }

    /// Whether a segment's start reads atoms that
    /// [`prefetch_sets`](Self::prefetch_sets) would evaluate with the jump
    /// sets (watched atoms or the sets' timers).
    pub fn prefetches(&self) -> bool {
        !(self.watched.is_empty() && self.timers.is_empty())
    }

    /// Drops the atoms of [`prefetch_sets`](Self::prefetch_sets) (their
    /// evaluation reported a fault: evaluated again where needed, the fault
    /// is reported again there).
    pub fn forget_prefetch(&mut self) {
        self.prefetched = None;
        self.sets_at = None;
    }

    /// Sign classes of the watched atoms at (t, x) into `cls_s`, with the
    /// values left in each set's `vs`; whether a class differs from `cls`.
    fn classes_at<S: HybridSystem + ?Sized>(&mut self, sys: &S, t: f64, x: &[f64]) -> bool {
        let at = HybridTime::new(t, self.j);
        let flat =
            self.flat_ok && self.flat_checks && sys.all_atom_values(at, x, true, &mut self.flat);
        if flat && self.flat_watched {
            // Only the watched atoms' values are read at a checkpoint; their
            // classes in the same pass (as `classes_from_vs`; with no atom
            // relaxed, of the values themselves).
            let mut changed = false;
            let relaxed = self.relaxed > 0;
            let pass = self.watched.iter().zip(&mut self.cls_s).zip(&self.cls);
            for ((w, c), &c0) in pass {
                let ws = &mut self.sets[w.set];
                let g = self.flat[w.flat];
                ws.vs[w.atom] = g;
                let v = if relaxed {
                    watched_value(w.cmp, g, ws.state[w.atom].relax)
                } else {
                    g
                };
                *c = class(v);
                changed |= *c != c0;
            }
            return changed;
        }
        for (i, ws) in self.sets.iter_mut().enumerate() {
            if !ws.source {
                continue;
            }
            match self.flat_off[i] {
                Some(off) if flat => {
                    for k in 0..ws.vs.len() {
                        if ws.watched(k) {
                            ws.vs[k] = self.flat[off + k];
                        }
                    }
                }
                _ => atom_values(sys, ws.kind(), at, x, true, &mut ws.vs),
            }
        }
        self.classes_from_vs()
    }

    /// Sign classes of the watched atoms from the values in `vs` (the
    /// checkpoint's) under the current relaxations, into `cls_s`; whether
    /// a class differs from `cls`.
    fn classes_from_vs(&mut self) -> bool {
        let mut changed = false;
        for ((w, c), &c0) in self.watched.iter().zip(&mut self.cls_s).zip(&self.cls) {
            let ws = &self.sets[w.set];
            *c = class(watched_value(w.cmp, ws.vs[w.atom], ws.state[w.atom].relax));
            changed |= *c != c0;
        }
        changed
    }

    /// Ends the relaxation of C's atoms that hold exactly at the point
    /// whose values are in `vs` (`vb` with `at_candidate`); their sign is
    /// then that of `g` itself.
    #[inline]
    fn settle_relaxed(&mut self, at_candidate: bool) {
        if self.relaxed > 0 {
            self.settle_relaxed_atoms(at_candidate);
        }
    }

    /// [`settle_relaxed`](Self::settle_relaxed) with relaxed atoms.
    fn settle_relaxed_atoms(&mut self, at_candidate: bool) {
        let Some(fi) = self.flow else {
            return;
        };
        for (w, c) in self.watched.iter().zip(self.cls.iter_mut()) {
            if w.set != fi {
                continue;
            }
            let ws = &mut self.sets[fi];
            let vals = if at_candidate { &ws.vb } else { &ws.vs };
            let (cmp, g) = (w.cmp, vals[w.atom]);
            if ws.state[w.atom].relax > 0.0 && holds_by(cmp, g, ws.state[w.atom].settle) {
                ws.state[w.atom].relax = 0.0;
                self.relaxed -= 1;
                *c = class(g);
            }
        }
    }

    /// Looks for the first event on the step `[s0, s1]` (local times; global
    /// time `clock.at(s)`) whose end state is `y1`. On success the state at
    /// the event is in [`event_state`](Self::event_state) and the local time
    /// and kind are returned. `end_counts`: whether an event at `s1` itself
    /// counts; `false` when the segment ends at `s1` anyway, where the timer
    /// atoms due are then not crossed (the next [`start`](Self::start)
    /// finds them on or past their thresholds).
    pub fn scan<S: HybridSystem + ?Sized, P: StepPath>(
        &mut self,
        sys: &S,
        path: &mut P,
        (s0, s1): (f64, f64),
        y1: &[f64],
        end_counts: bool,
    ) -> Option<(f64, EventKind)> {
        let m = if P::STRAIGHT { 0 } else { self.checks };
        self.span = (s0, s1);
        self.step.fill(StepFacts::default());
        // A segment that starts on a boundary (a post-jump state, a few ulp
        // on either side of an atom's zero) may cross it right away and
        // come back within the first interval: look early in the first
        // step too.
        let mut early: &[f64] = if s0 == 0.0 && self.near_start {
            &EARLY
        } else {
            &[]
        };
        // The checkpoints: the early ones and `m` evenly spaced, unless
        // every watched atom is affine, whose first sign changes are then
        // the only interior checkpoints (also added to the others).
        let mut m = m;
        if (m > 0 || !early.is_empty()) && self.affine_checkpoints(path, s0, s1) {
            (m, early) = (0, &[]);
        }
        let mut points = std::mem::take(&mut self.points);
        points.clear();
        points.extend(early.iter().map(|e| s0 + (s1 - s0) * e));
        if m > 0 {
            points.extend((1..=m).map(|i| s0 + (s1 - s0) * (i as f64 / (m + 1) as f64)));
        }
        let evenly = points.len();
        points.extend_from_slice(&self.extra);
        // The timers' thresholds reached on the step (`cross_timers`).
        if self.next_due < s1 {
            points.extend(
                self.timers
                    .iter()
                    .filter(|ta| !ta.crossed && ta.d > s0 && ta.d < s1)
                    .map(|ta| ta.d),
            );
        }
        if points.len() > evenly {
            sort_points(&mut points);
        }
        points.push(s1);
        let found = self.scan_points(sys, path, s0, &points, y1, end_counts);
        self.points = points;
        found
    }

    /// [`scan`](Self::scan) over the checkpoints `points` (increasing, the
    /// last the step's end `s1`, whose state is `y1`).
    fn scan_points<S: HybridSystem + ?Sized, P: StepPath>(
        &mut self,
        sys: &S,
        path: &mut P,
        s0: f64,
        points: &[f64],
        y1: &[f64],
        end_counts: bool,
    ) -> Option<(f64, EventKind)> {
        let mut prev = s0;
        for (k, &s) in points.iter().enumerate() {
            let last = k + 1 == points.len();
            if s <= prev && !last {
                continue;
            }
            let changed = if last {
                // The step end itself: no copy.
                self.classes_at(sys, self.clock.at(s), y1)
            } else {
                let mut xs = std::mem::take(&mut self.buf_s);
                path.eval(s, &mut xs);
                let changed = self.classes_at(sys, self.clock.at(s), &xs);
                self.buf_s = xs;
                changed
            };
            if changed {
                let relaxed = self.relaxed;
                // The changes of class that can change a set are localized
                // in time order; where none does, the search ends at the
                // last (`prev` if none needed localizing: `v <= vt` of a
                // guard `h <= s && v <= vt` while `h <= s` fails). After
                // it the other atoms may still change and come back before
                // `s`, searched as where no class changed.
                let reached = match self.resolve(sys, path, prev, s) {
                    ControlFlow::Break(found) => return Some(found),
                    ControlFlow::Continue(reached) => reached,
                };
                // The search may have ended relaxations: the checkpoint's
                // classes again (`classes_at` left them otherwise).
                if self.relaxed != relaxed {
                    self.classes_from_vs();
                } else if reached < s
                    && let Some(found) =
                        self.hidden_change(sys, path, (reached, s), (last, end_counts), y1)
                    && found.is_some()
                {
                    return found;
                }
            } else if let Some(found) =
                self.hidden_change(sys, path, (prev, s), (last, end_counts), y1)
            {
                // A change between the checkpoints, scanned.
                if found.is_some() {
                    return found;
                }
            }
            // Timers due by `s` (none for a NaN `s`); `now` is read only
            // after `cross_timers`' first pass. At an end whose event would
            // not count, the scan ends without them.
            if (end_counts || !last) && self.next_due.partial_cmp(&s).is_some_and(|o| o.is_le()) {
                let xs = std::mem::take(&mut self.buf_s);
                let crossed = self.cross_timers(s, if last { y1 } else { &xs });
                self.buf_s = xs;
                if let Some(kind) = crossed {
                    return Some((s, kind));
                }
            }
            // The checkpoint's classes become the cursor's (`cls_s` is
            // written in full at the next checkpoint before it is read).
            std::mem::swap(&mut self.cls, &mut self.cls_s);
            self.settle_relaxed(false);
            prev = s;
        }
        None
    }

    /// Checkpoints that make the scan exact for affine atoms: for each
    /// watched atom that is an affine form of the state, each point of the
    /// step where its value along the path's polynomial has changed sign
    /// (from the Bernstein control points, see [`first_other_sign`]) goes
    /// into `extra`; a change of sign that comes back within the step is
    /// then found, however brief. An atom on its boundary at the cursor
    /// (within rounding of zero, or relaxed) is examined from the first
    /// point where its sign is sure ([`first_sure_sign`]), itself a
    /// checkpoint if the class changes or a relaxation ends there. Returns
    /// whether every watched atom was so examined (then no other interior
    /// checkpoint is needed, early ones included).
    fn affine_checkpoints<P: StepPath>(&mut self, path: &P, s0: f64, s1: f64) -> bool {
        let mut all = true;
        self.extra.clear();
        self.extra_many.clear();
        for w in 0..self.watched.len() {
            let Some(form) = &self.affine[w] else {
                all = false;
                continue;
            };
            let WAtom { set, atom, cmp, .. } = self.watched[w];
            let (cls, relaxed) = (self.cls[w], self.sets[set].state[atom].relax > 0.0);
            if cls == 2 {
                all = false;
                continue;
            }
            // An earlier atom with the same function has the same points.
            let points = match self.twin[w].and_then(|u| self.step[u].form_pts) {
                Some(points) => points,
                None => {
                    let Some(points) = form_points(form, path) else {
                        return false;
                    };
                    points
                }
            };
            self.step[w].form_pts = Some(points);
            let (g, n, tol) = points;
            if !tol.is_finite() {
                all = false;
                continue;
            }
            let (mut from, mut sign) = (0.0, f64::from(cls));
            if relaxed || g[0] * sign <= tol {
                // On the boundary at the start (within the tolerance of
                // zero, or an atom of C that held only within `set_tol`:
                // just after a jump onto it, or a timer set on its
                // threshold): examined from the first point of a sure sign
                // on. Before it the atom never has the other sign beyond
                // `tol`, so a change of class there is seen at that point.
                // A twin's (the same points) is this atom's.
                let found = match self.twin[w].and_then(|u| self.step[u].sure_pts) {
                    Some(found) => found,
                    None => first_sure_sign(&g[..n], tol),
                };
                self.step[w].sure_pts = Some(found);
                let Some((tau, sure)) = found else {
                    all = false;
                    continue;
                };
                // A relaxed atom moving into its set holds exactly from
                // there on, where the scan ends its relaxation (a point of
                // the step); one moving out is left to the checkpoints.
                if relaxed && !cmp.holds(sure) {
                    all = false;
                    continue;
                }
                // Once for twins (the scan would pass the copy).
                let at = s0 + tau * (s1 - s0);
                if tau < 1.0 && (relaxed || sure != sign) && !self.extra.contains(&at) {
                    self.extra.push(at);
                }
                (from, sign) = (tau, sure);
            }
            // A twin searched from the same point with the same sign (the
            // same points) has the same changes, already checkpoints.
            let twin = self.twin[w].and_then(|u| self.step[u].changes_from);
            if let Some((_, _, settled)) = twin.filter(|&(f, s, _)| (f, s) == (from, sign)) {
                all &= settled;
                continue;
            }
            // Each change of sign in turn: the first point of the other
            // sign, then the first after it of the sign before, … — between
            // two of them the atom does not change sign (beyond `tol`).
            let (mut budget, mut settled) = (SPLIT_BUDGET, false);
            let start = (from, sign);
            let mut rest = if from > 0.0 && from < 1.0 {
                split_right(&g[..n], from)
            } else {
                g
            };
            let first = self.extra.len();
            self.probes.clear();
            for _ in 0..MAX_CHANGES {
                if from >= 1.0 {
                    settled = true;
                    break;
                }
                let range = (from, 1.0);
                let probes = &mut self.probes;
                match first_other_sign(
                    &rest[..n],
                    sign,
                    tol,
                    range,
                    SPLIT_DEPTH,
                    &mut budget,
                    probes,
                ) {
                    Ok(Some(tau)) if tau < 1.0 => {
                        self.extra.push(s0 + tau * (s1 - s0));
                        (from, sign, rest) = (tau, -sign, split_right(&g[..n], tau));
                    }
                    Ok(_) => {
                        settled = true;
                        break;
                    }
                    Err(()) => break,
                }
            }
            self.step[w].changes_from = Some((start.0, start.1, settled));
            // Not settled: the checkpoints watch this atom too.
            all &= settled;
            // Where the polynomial cannot tell a graze from none, the
            // system's value decides.
            let changes = self.extra.len() - first;
            let inside = self.probes.iter().filter(|&&u| u > 0.0 && u < 1.0);
            self.extra.extend(inside.map(|&u| s0 + u * (s1 - s0)));
            // A single change stays visible at every later checkpoint; only
            // changes that come back (a graze among them) can hide between
            // them.
            if changes >= 2 || self.extra.len() > first + changes {
                self.extra_many.extend_from_slice(&self.extra[first..]);
            }
        }
        if !all {
            std::mem::swap(&mut self.extra, &mut self.extra_many);
        }
        all
    }

    /// Examines, in time order, the sign changes of the watched atoms
    /// between the cursor `prev` (classes in `cls`) and the checkpoint `s`
    /// (classes in `cls_s`): breaks with the first event, or continues
    /// from the end of the last change localized (`prev` if none), the
    /// classes there in `cls`.
    fn resolve<S: HybridSystem + ?Sized, P: StepPath>(
        &mut self,
        sys: &S,
        path: &mut P,
        mut cursor: f64,
        s: f64,
    ) -> ControlFlow<(f64, EventKind), f64> {
        // Brackets found in earlier rounds of this call stay valid after the
        // cursor passes a candidate before them (the atom keeps its class and
        // relaxation up to their start): a guard that changes after another
        // one on the same interval is localized once, not once per round.
        for c in &mut self.found {
            c.0 = f64::NAN;
        }
        for _ in 0..MAX_CANDIDATES {
            let mut best: Option<(f64, f64, bool, usize)> = None;
            // Decided once per atom and round (twins read theirs).
            self.mark_needs();
            for w in 0..self.watched.len() {
                if !self.need[w] || self.shares_zero(w) {
                    continue;
                }
                let WAtom { set, atom, .. } = self.watched[w];
                let relax = self.sets[set].state[atom].relax;
                let (a, b, fresh) = match self.found[w] {
                    (a, b, c, r) if a >= cursor && c == self.cls[w] && r == relax => (a, b, false),
                    _ => {
                        // A first change before `s` if the atom changes sign
                        // more than once on the interval.
                        let end = self.first_change_end(sys, path, w, (cursor, s));
                        let (a, b) = self.localize(sys, w, path, cursor, end);
                        self.found[w] = (a, b, self.cls[w], relax);
                        (a, b, true)
                    }
                };
                if best.is_none_or(|(_, bb, _, _)| b < bb) {
                    best = Some((a, b, fresh, w));
                    if fresh {
                        if self.bracket_start_read {
                            self.best_a.copy_from_slice(&self.buf_a);
                        }
                        self.event_state.copy_from_slice(&self.buf_b);
                    }
                }
            }
            let Some((a, b, fresh, w)) = best else {
                return ControlFlow::Continue(cursor);
            };
            if !fresh {
                if self.bracket_start_read {
                    path.eval(a, &mut self.best_a);
                }
                path.eval(b, &mut self.event_state);
            }
            self.evaluate_sets(sys, self.clock.at(a), self.clock.at(b));

            let jump = self
                .sets
                .iter()
                .position(|ws| ws.source && matches!(ws.set, SetRef::Jump(_)) && !ws.cur && ws.new);
            let left = self.flow.filter(|&fi| {
                let ws = &self.sets[fi];
                ws.cur && !ws.new
            });
            if jump.is_none()
                && left.is_some()
                && self.exit_rules > 0
                && let Some(r) = self.rule_at_exit(sys, path, a)
            {
                self.event_state.copy_from_slice(&self.best_a);
                self.rule_at_event = Some(r);
                self.left_at_event = true;
                return ControlFlow::Break((a, EventKind::LeftFlowSet));
            }
            if jump.is_some() || left.is_some() {
                self.left_at_event = left.is_some();
                self.rule_at_event = self.sets.iter().find_map(|ws| match ws.set {
                    SetRef::Jump(r) if ws.new => Some(r),
                    _ => None,
                });
                let kind = match jump.map(|i| self.sets[i].set) {
                    Some(SetRef::Jump(r)) => EventKind::Jump(r),
                    _ => EventKind::LeftFlowSet,
                };
                let b = if P::RESTEPS {
                    self.restep_event(sys, path, w, (cursor, b))
                } else {
                    b
                };
                return ControlFlow::Break((b, kind));
            }
            // No set changed value: go on from b.
            for ws in &mut self.sets {
                ws.cur = ws.new;
            }
            for (w, c) in self.watched.iter().zip(self.cls.iter_mut()) {
                let ws = &self.sets[w.set];
                *c = class(watched_value(w.cmp, ws.vb[w.atom], ws.state[w.atom].relax));
            }
            // Ended relaxations change the checkpoint's classes too.
            let relaxed = self.relaxed;
            self.settle_relaxed(true);
            if self.relaxed != relaxed {
                self.classes_from_vs();
            }
            cursor = b;
            if b >= s {
                break;
            }
        }
        ControlFlow::Continue(cursor)
    }

    /// Whether watched atom `w` changes sign exactly where an earlier
    /// watched atom that is localized does (same function, neither
    /// relaxed), so that its localization would repeat that one's to the
    /// last bit. The earlier atoms' [`need`](Self::need) is this round's.
    #[inline]
    fn shares_zero(&self, w: usize) -> bool {
        let unrelaxed = |w: usize| {
            let WAtom { set, atom, .. } = self.watched[w];
            self.sets[set].state[atom].relax == 0.0
        };
        self.twin[w].is_some_and(|u| unrelaxed(u) && unrelaxed(w) && self.need[u])
    }

    /// Whether each watched atom changed sign class between the cursor and
    /// the checkpoint in a way that can change its set's value, into
    /// `need`. It cannot when the set's other atoms keep their class over
    /// the interval and the set's value does not depend on it there
    /// ([`depends_alone`](Self::depends_alone)): the ball's apex (`v`
    /// crossing 0 while `h > 0` decides C = {h ≥ 0 ∨ v ≥ 0} and
    /// D = {h ≤ 0 ∧ v < 0}) is then not localized at all. One pass counts
    /// the changing atoms of each set.
    fn mark_needs(&mut self) {
        // Only the watched atoms' sets are counted (a fill of all of them
        // would be a call to memset).
        let n = self.watched.len();
        let (watched, cls, cls_s) = (&self.watched[..n], &self.cls[..n], &self.cls_s[..n]);
        for wa in watched {
            self.changing[wa.set] = 0;
        }
        let mut any = false;
        for (w, need) in self.need[..n].iter_mut().enumerate() {
            *need = cls[w] != cls_s[w];
            self.changing[watched[w].set] += u32::from(*need);
            any |= *need;
        }
        if !any {
            return;
        }
        for w in 0..n {
            if self.need[w] && self.changing[self.watched[w].set] == 1 {
                self.need[w] = self.depends_alone(w);
            }
        }
    }

    /// Whether the value of watched atom `w`'s set depends on `w` with its
    /// other atoms at their truth at the checkpoint (unchanged since the
    /// cursor); `true` for a set without atoms.
    fn depends_alone(&self, w: usize) -> bool {
        let WAtom { set, atom, .. } = self.watched[w];
        let ws = &self.sets[set];
        let Some(spec) = ws.spec.as_ref() else {
            return true;
        };
        // The set's value with `w` true and false, the other atoms at their
        // (unchanged) truth at the checkpoint.
        let other = |(a, (&v, st)): (&Atom, (&f64, &AtomState))| {
            if a.watched() {
                a.cmp.holds_within(v, st.relax)
            } else {
                st.start_truth
            }
        };
        let truth =
            |k: usize| (k != atom).then(|| other((&spec.atoms[k], (&ws.vs[k], &ws.state[k]))));
        match ws.table {
            Some(t) => {
                // The truth table's index with `w` false, in one pass over
                // the atoms (a table covers at most `MAX_ATOMS` of them).
                let atoms = spec.atoms.iter().zip(ws.vs.iter().zip(&ws.state));
                let mut m = 0u32;
                for (k, entry) in atoms.enumerate().take(TruthTable::MAX_ATOMS) {
                    m |= u32::from(k != atom && other(entry)) << k;
                }
                t.value(m | 1 << atom) != t.value(m)
            }
            None => {
                spec.expr.eval_with(&|k| truth(k).unwrap_or(true))
                    != spec.expr.eval_with(&|k| truth(k).unwrap_or(false))
            }
        }
    }

    /// The first rule whose jump set holds at `a`, the last point found in
    /// C before the flow leaves it (its state into `best_a`). A set that
    /// reports a fault there counts as not holding: the event then stays at
    /// the bracket's end, where the evaluation reports it.
    fn rule_at_exit<S: HybridSystem + ?Sized, P: StepPath>(
        &mut self,
        sys: &S,
        path: &mut P,
        a: f64,
    ) -> Option<usize> {
        if !self.bracket_start_read {
            path.eval(a, &mut self.best_a);
        }
        let at = HybridTime::new(self.clock.at(a), self.j);
        let rule = (0..self.exit_rules).find(|&r| sys.jump_set(r, at, &self.best_a));
        sys.take_fault().map_or(rule, |_| None)
    }

    /// Evaluates every set on the bracket `[ta, tb]` whose end states are
    /// in `best_a` (if [`bracket_start_read`](Self::bracket_start_read))
    /// and `event_state`, into each set's `new` (module docs).
    fn evaluate_sets<S: HybridSystem + ?Sized>(&mut self, sys: &S, ta: f64, tb: f64) {
        let (ta, tb) = (HybridTime::new(ta, self.j), HybridTime::new(tb, self.j));
        let (xa, xb) = (&self.best_a, &self.event_state);
        let read_a = self.bracket_start_read;
        // Every set's atoms in one evaluation per bracket end where the
        // system offers it, as at the segment's start.
        let flat = self.flat_ok
            && (!read_a || sys.all_atom_values(ta, xa, false, &mut self.flat))
            && sys.all_atom_values(tb, xb, false, &mut self.flat_b);
        for (i, ws) in self.sets.iter_mut().enumerate() {
            // The values from the evaluation of all sets (copied in the
            // pass below: a call to memcpy for a few values cost more), or
            // the set's own.
            let flat_off = self.flat_off[i].filter(|_| flat);
            let kind = ws.kind();
            let WSet {
                set,
                spec,
                table,
                state,
                va,
                vb,
                new,
                ..
            } = ws;
            if flat_off.is_none() {
                if read_a {
                    atom_values(sys, kind, ta, xa, false, va);
                }
                atom_values(sys, kind, tb, xb, false, vb);
            }
            *new = match (&*spec, *set) {
                (Some(spec), _) => {
                    // The truth table's index as the atoms are decided.
                    let mut mask = 0u32;
                    for k in 0..vb.len() {
                        if let Some(off) = flat_off {
                            if read_a {
                                va[k] = self.flat[off + k];
                            }
                            vb[k] = self.flat_b[off + k];
                        }
                        let atom = spec.atoms[k];
                        let st = &mut state[k];
                        st.truth = if !atom.watched() {
                            st.start_truth
                        } else if st.relax > 0.0 {
                            atom.cmp.holds_within(vb[k], st.relax)
                        } else {
                            match atom.cmp {
                                Cmp::Eq => eq_met(va[k], vb[k]),
                                Cmp::Ne => !eq_met(va[k], vb[k]),
                                c => c.holds(vb[k]),
                            }
                        };
                        if k < TruthTable::MAX_ATOMS {
                            mask |= u32::from(st.truth) << k;
                        }
                    }
                    match table {
                        Some(t) => t.value(mask),
                        None => spec.expr.eval_with(&|k| state[k].truth),
                    }
                }
                (None, SetRef::Jump(r)) => sys.jump_set(r, tb, xb),
                (None, SetRef::Flow) => {
                    sys.flow_set(tb, xb) || (state[0].relax > 0.0 && vb[0] >= -state[0].relax)
                }
            };
        }
    }

    /// The watched value of atom `w` at local time `s` (state into `buf`).
    fn watched_at<S: HybridSystem + ?Sized, P: StepPath>(
        &mut self,
        sys: &S,
        w: usize,
        path: &mut P,
        s: f64,
        which: Buf,
    ) -> f64 {
        let WAtom { set, atom, cmp, .. } = self.watched[w];
        let buf = match which {
            Buf::A => &mut self.buf_a,
            Buf::B => &mut self.buf_b,
            Buf::T => &mut self.buf_t,
        };
        path.eval(s, buf);
        let ws = &mut self.sets[set];
        let at = HybridTime::new(self.clock.at(s), self.j);
        atom_values(sys, ws.kind(), at, buf, true, &mut ws.vt);
        watched_value(cmp, ws.vt[atom], ws.state[atom].relax)
    }

    /// Where the watched value of atom `w`, if affine, crosses zero in
    /// `(a, b)` on the polynomial of the step being scanned (local time),
    /// to within a fraction of `tol`.
    fn polynomial_zero<P: StepPath>(
        &self,
        w: usize,
        path: &P,
        a: f64,
        b: f64,
        tol: f64,
    ) -> Option<f64> {
        let form = self.affine[w].as_ref()?;
        let WAtom { set, atom, cmp, .. } = self.watched[w];
        let relax = self.sets[set].state[atom].relax;
        let shift = match cmp {
            _ if relax <= 0.0 => 0.0,
            Cmp::Ge | Cmp::Gt => relax,
            Cmp::Le | Cmp::Lt => -relax,
            Cmp::Ne => 0.0,
            Cmp::Eq => return None,
        };
        let (mut g, n, _) = match self.step[w].form_pts {
            Some(points) => points,
            None => form_points(form, path)?,
        };
        for v in &mut g[..n] {
            *v += shift;
        }
        let (s0, s1) = self.span;
        let h = s1 - s0;
        (h > 0.0).then_some(())?;
        let range = ((a - s0) / h, (b - s0) / h);
        let tau = bernstein_zero(&g[..n], range, 0.25 * tol / h)?;
        Some(s0 + tau * h)
    }

    /// The event of watched atom `w` at `b` (the end of its bracket on the
    /// step's interpolant, the cursor at `cursor`) found again on states of
    /// fresh steps from the step's start ([`StepPath::restep`]): the
    /// change is bracketed by probes placed from the atom's slope on the
    /// interpolant, then localized as on any path. Returns the event's time,
    /// its states in `event_state` (and `best_a`); `b` and the states found
    /// on the interpolant if the atom is an equality or relaxed one, a
    /// re-step fails, or the change is not within the step on the re-steps.
    fn restep_event<S: HybridSystem + ?Sized, P: StepPath>(
        &mut self,
        sys: &S,
        path: &mut P,
        w: usize,
        (cursor, b): (f64, f64),
    ) -> f64 {
        let WAtom { set, atom, cmp, .. } = self.watched[w];
        let (c0, s1) = (self.cls[w], self.span.1);
        if matches!(cmp, Cmp::Eq | Cmp::Ne) || self.sets[set].state[atom].relax > 0.0 || c0 == 0 {
            return b;
        }
        let tol = self
            .event_tol
            .max(4.0 * f64::EPSILON * self.clock.at(b).abs());
        // The atom's slope at b along the interpolant.
        let e = (b - cursor).min(1e-3 * (s1 - self.span.0)).max(tol);
        let slope = (self.watched_at(sys, w, path, b, Buf::T)
            - self.watched_at(sys, w, path, b - e, Buf::T))
            / e;
        let mut truth = Restepped { path, ok: true };
        let v = self.watched_at(sys, w, &mut truth, b, Buf::B);
        let crossed = class(v) != c0;
        // The first probe where the slope puts the change, half again as
        // far (at least a tolerance); then ever farther.
        let mut delta = 1.5 * (v / slope).abs();
        if !delta.is_finite() {
            delta = (s1 - self.span.0) * 2f64.powi(-10);
        }
        let mut delta = delta.max(tol);
        let (mut lo, mut hi) = (b, b);
        let mut bracketed = false;
        for _ in 0..8 {
            if !truth.ok {
                break;
            }
            let p = if crossed {
                (hi - delta).max(cursor)
            } else {
                (lo + delta).min(s1)
            };
            let across = class(self.watched_at(sys, w, &mut truth, p, Buf::T)) != c0;
            match (crossed, across) {
                (true, false) => (lo, bracketed) = (p, true),
                (false, true) => (hi, bracketed) = (p, true),
                (true, true) => hi = p,
                (false, false) => lo = p,
            }
            if bracketed || p == cursor || p == s1 {
                break;
            }
            delta *= 4.0;
        }
        if !(bracketed && truth.ok) {
            return b;
        }
        let (_, b1) = self.localize(sys, w, &mut truth, lo, hi);
        if !truth.ok {
            return b;
        }
        self.event_state.copy_from_slice(&self.buf_b);
        if self.bracket_start_read {
            self.best_a.copy_from_slice(&self.buf_a);
        }
        b1
    }

    /// Shrinks the bracket `(a, b]` of watched atom `w` (sign class
    /// `cls[w]` at `a`, `cls_s[w]` at the checkpoint `b`) to the first
    /// change within the tolerance. Leaves x(b) in `buf_b`, and x(a) in
    /// `buf_a` if [`bracket_start_read`](Self::bracket_start_read).
    /// Not inlined: kept out of the scan's loop, whose registers it would
    /// crowd for a call made at most once per sign change.
    #[inline(never)]
    fn localize<S: HybridSystem + ?Sized, P: StepPath>(
        &mut self,
        sys: &S,
        w: usize,
        path: &mut P,
        mut a: f64,
        mut b: f64,
    ) -> (f64, f64) {
        let c0 = self.cls[w];
        // The values at the bracket's ends (with the states in `buf_a`,
        // `buf_b`) are computed when first read: interpolation reads them,
        // but the guided trials of an affine atom close most brackets
        // first, replacing both ends.
        let (mut fa, mut fb) = (None, None);
        if self.cls_s[w] == 0 {
            let v = self.watched_at(sys, w, path, b, Buf::B);
            fb = Some(v);
            if v == 0.0 && c0 != 0 {
                // b is an exact root (a clock reaching its threshold at a
                // step end): the change is at b. Secant and bisection would
                // only creep towards b for ~50 iterations.
                self.buf_a.copy_from_slice(&self.buf_b);
                return (b, b);
            }
        }
        let event_tol = self.event_tol;
        // A few ulp of t: finer than t itself can hold would only chase
        // rounding noise in the atom's values.
        let clock = self.clock;
        let tol_at = |b: f64| event_tol.max(4.0 * f64::EPSILON * clock.at(b).abs());
        // The tolerance at the bracket's end `b`, kept as `b` moves.
        let mut tol_b = tol_at(b);
        // The ITP schedule of the initial bracket, made when first needed:
        // the guided trials of an affine atom usually close it first.
        let (a0, b0, tol0) = (a, b, tol_b);
        let mut itp: Option<Itp> = None;
        let mut widths = [f64::INFINITY; 2];
        // Leaving an exact zero: the change is almost always right after a.
        let mut leaving_zero = c0 == 0;
        // An affine atom's zero on the path's polynomial (within a quarter
        // tolerance): the first trial, and a trial half a tolerance beyond
        // it on the other side the second (then the bracket is closed in two
        // evaluations, its ends within half a tolerance of the zero).
        let mut guess = if leaving_zero {
            None
        } else {
            // The bracket's smaller tolerance: the zero's own may be either.
            self.polynomial_zero(w, path, a, b, tol_at(a).min(tol_b))
        };
        let mut guided = guess.is_some();
        for _ in 0..400 {
            let width = b - a;
            let tol = tol_b;
            if width <= tol {
                break;
            }
            // Bisect when two trials did not halve the bracket: the values
            // are then too close to rounding noise (or NaN) to interpolate.
            let slow = width > 0.5 * widths[0];
            widths = [widths[1], width];
            // The second trial of a guided search: half a tolerance across
            // the first, which was within a quarter of one of the zero.
            let second = guess.is_some() && !guided;
            let mut s = if leaving_zero {
                a + 0.5 * tol
            } else if let Some(g) = guess.take() {
                g
            } else {
                let fa = *fa.get_or_insert_with(|| self.watched_at(sys, w, path, a, Buf::A));
                let fb = *fb.get_or_insert_with(|| self.watched_at(sys, w, path, b, Buf::B));
                itp.get_or_insert_with(|| Itp::new(a0, b0, tol0)).next(
                    a,
                    b,
                    fa,
                    fb,
                    c0 != 2 && !slow,
                    tol,
                )
            };
            // Keep the trial strictly inside. A trial within `tol` of an end
            // means the estimate has converged there: step almost a full
            // `tol` inside ([`INSIDE`]), so that the probe lands across the
            // root and closes the bracket in one evaluation.
            let margin = if leaving_zero || second || width <= 2.0 * tol {
                0.25 * tol
            } else {
                INSIDE * tol
            };
            s = s.clamp(a + margin, b - margin);
            if !(s > a && s < b) {
                s = 0.5 * (a + b);
                if !(s > a && s < b) {
                    break; // a and b are adjacent floats
                }
            }
            let v = self.watched_at(sys, w, path, s, Buf::T);
            let across = class(v) != c0;
            if across {
                // `b` moves to `s` below.
                tol_b = tol_at(s);
            }
            if std::mem::take(&mut guided) {
                // With the tolerance at the bracket's new end.
                guess = Some(if across {
                    s - 0.5 * tol_b
                } else {
                    s + 0.5 * tol
                });
            }
            if across {
                b = s;
                fb = Some(v);
                std::mem::swap(&mut self.buf_b, &mut self.buf_t);
                if leaving_zero {
                    // The change is within `tol` of a.
                    break;
                }
            } else {
                a = s;
                fa = Some(v);
                std::mem::swap(&mut self.buf_a, &mut self.buf_t);
            }
            leaving_zero = false;
        }
        if fb.is_none() {
            path.eval(b, &mut self.buf_b);
        }
        if fa.is_none() && self.bracket_start_read {
            path.eval(a, &mut self.buf_a);
        }
        (a, b)
    }
}

/// How far inside a bracket's end, in tolerances, a trial near it is
/// placed: a probe that lands across the root then leaves a bracket no
/// wider than the tolerance, the rounding of the trial point included (at
/// most an eighth of the tolerance, which is at least 4 ulp of t), and the
/// search ends; a full tolerance would miss by that rounding half the time
/// and cost one more evaluation.
const INSIDE: f64 = 0.875;

/// A path's states from re-steps ([`StepPath::restep`]); `ok` turns
/// false at the first that fails (its state then NaN).
struct Restepped<'p, P> {
    path: &'p mut P,
    ok: bool,
}

impl<P: StepPath> StepPath for Restepped<'_, P> {
    fn eval(&mut self, s: f64, out: &mut [f64]) {
        if !(self.ok && self.path.restep(s, out)) {
            self.ok = false;
            out.fill(f64::NAN);
        }
    }
}

#[derive(Clone, Copy)]
enum Buf {
    A,
    B,
    T,
}

/// The trial points of the ITP method (Oliveira and Takahashi, ACM TOMS
/// 47(1), 2020) on a bracket `[a, b]`: regula falsi, truncated towards the
/// midpoint and projected into a ball around it that shrinks as bisection
/// would. It never needs more evaluations than bisection plus one, and
/// converges superlinearly where the function is smooth — unlike regula
/// falsi (Illinois included), which crawls on strongly curved guards such
/// as a ball's height over a short bounce.
struct Itp {
    /// Truncation gain κ₁ (κ₂ = 2).
    k1: f64,
    /// ε·2^(n_max − j), ε = tol / 2: the projection radius plus half the
    /// width bisection would have left after j steps.
    radius: f64,
    /// Evaluations allowed (bisection's count plus one) and done.
    n_max: i32,
    j: i32,
}

/// Evaluations the ITP schedule allows beyond bisection's count: room for
/// interpolation to recover after a poor start (a strongly curved guard)
/// before the schedule forces bisection.
const SLACK: i32 = 8;

impl Itp {
    /// Not inlined: its logarithm and power would be hoisted out of the
    /// search loop that makes it only when the guided trials fail.
    #[inline(never)]
    fn new(a: f64, b: f64, tol: f64) -> Self {
        let width = b - a;
        let n_half = (width / tol).log2().ceil().max(0.0) as i32;
        let n_max = n_half + SLACK;
        Self {
            k1: 0.2 / width,
            radius: 0.5 * tol * 2f64.powi(n_max),
            n_max,
            j: 0,
        }
    }

    /// The next trial in `(a, b)` for values `fa`, `fb` of opposite sign
    /// classes; `interpolate = false` bisects. `tol` is the width at which
    /// the search stops; when the schedule is used up before (the width
    /// is relative to b and may have shrunk since), it restarts on the
    /// bracket.
    fn next(&mut self, a: f64, b: f64, fa: f64, fb: f64, interpolate: bool, tol: f64) -> f64 {
        if self.j >= self.n_max {
            *self = Self::new(a, b, tol);
        }
        let half = 0.5 * (b - a);
        let mid = a + half;
        let r = (self.radius - half).max(0.0);
        self.radius *= 0.5;
        self.j += 1;
        let falsi = (b * fa - a * fb) / (fa - fb);
        if !interpolate || !falsi.is_finite() {
            return mid;
        }
        let delta = self.k1 * (2.0 * half) * (2.0 * half);
        let sigma = if mid >= falsi { 1.0 } else { -1.0 };
        let truncated = if delta <= (mid - falsi).abs() {
            falsi + sigma * delta
        } else {
            mid
        };
        if (truncated - mid).abs() <= r {
            truncated
        } else {
            mid - sigma * r
        }
    }
}

/// Membership tests of the flow set C with reusable buffers.
pub(crate) struct FlowSetTest {
    spec: Option<SetAtoms>,
    table: Option<TruthTable>,
    vals: Vec<f64>,
}

impl FlowSetTest {
    pub fn new<S: HybridSystem + ?Sized>(sys: &S) -> Self {
        let spec = sys.set_atoms(SetRef::Flow);
        let n = spec.as_ref().map_or(0, |s| s.atoms.len());
        Self {
            table: truth_table(spec.as_ref()),
            spec,
            vals: vec![0.0; n],
        }
    }

    /// Whether x is in C within `tol` on C's atoms (or, for a system
    /// without atoms, in its predicate or within `tol` of its guard's zero).
    /// `known`: C's atom values at x if the caller has them
    /// ([`Watcher::prefetch`]).
    #[inline]
    pub fn contains<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        at: HybridTime,
        x: &[f64],
        tol: f64,
        known: Option<&[f64]>,
    ) -> bool {
        match &self.spec {
            Some(spec) => {
                let vals = match known {
                    Some(vals) => vals,
                    None => {
                        sys.atom_values(SetRef::Flow, at, x, false, &mut self.vals);
                        &self.vals
                    }
                };
                set_value(spec, self.table, |k| {
                    spec.atoms[k].holds_within(vals[k], tol)
                })
            }
            None => {
                sys.flow_set(at, x)
                    || (tol > 0.0 && sys.flow_guard(at, x).is_some_and(|g| g >= -tol))
            }
        }
    }

    /// The atoms of C that fail exactly at x (empty without atoms).
    pub fn failed_atoms<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        at: HybridTime,
        x: &[f64],
    ) -> Vec<FailedAtom> {
        let Some(spec) = &self.spec else {
            return Vec::new();
        };
        sys.atom_values(SetRef::Flow, at, x, false, &mut self.vals);
        spec.atoms
            .iter()
            .zip(&self.vals)
            .enumerate()
            .filter(|(_, (a, g))| !a.cmp.holds(**g))
            .map(|(index, (_, &value))| FailedAtom {
                index,
                value,
                text: sys.atom_text(SetRef::Flow, index),
            })
            .collect()
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::engine::models::BouncingBall;
    use crate::engine::system::{Atom, JumpRule, SetExpr};
    use crate::engine::{SimRng, simulate_arc};
    use std::cell::Cell;

    /// Evaluations ITP needs to shrink `[a, b]` around the root of `g`
    /// (positive at a) to `tol`.
    fn itp_evaluations(g: impl Fn(f64) -> f64, mut a: f64, mut b: f64, tol: f64) -> usize {
        let (mut fa, mut fb) = (g(a), g(b));
        let mut itp = Itp::new(a, b, tol);
        let mut n = 0;
        while b - a > tol {
            // As `Watcher::localize` keeps trials inside.
            let s = itp
                .next(a, b, fa, fb, true, tol)
                .clamp(a + 0.25 * tol, b - 0.25 * tol);
            n += 1;
            let v = g(s);
            if v > 0.0 {
                (a, fa) = (s, v);
            } else {
                (b, fb) = (s, v);
            }
        }
        n
    }

    /// A ball's height over a short hop seen from a long step (the hump
    /// that makes regula falsi crawl) and a smooth monotone guard: ITP
    /// stays within bisection's count plus its slack, and beats bisection
    /// by far on the smooth one.
    #[test]
    fn itp_is_never_much_worse_than_bisection_and_fast_on_smooth_guards() {
        let tol = 4.0 * f64::EPSILON;
        let bisection = |a: f64, b: f64| ((b - a) / tol).log2().ceil() as usize;
        let hop = |s: f64| s * (1e-5 - s);
        let n = itp_evaluations(hop, 1e-7, 5e-3, tol);
        assert!(n <= bisection(1e-7, 5e-3) + SLACK as usize, "{n}");
        let smooth = |s: f64| 0.3 - s.sin();
        let n = itp_evaluations(smooth, 0.0, 1.5, tol);
        assert!(
            n <= 12,
            "{n} evaluations (bisection: {})",
            bisection(0.0, 1.5)
        );
    }

    /// The ball of `BouncingBall` with its sets as atoms (C: h ≥ 0; D:
    /// h ≤ 0 ∧ v ≤ 0), counting atom evaluations; `ids` says whether the
    /// atoms carry function identities.
    struct AtomBall {
        ball: BouncingBall,
        ids: bool,
        evaluations: Cell<usize>,
    }

    impl HybridSystem for AtomBall {
        fn state_dim(&self) -> usize {
            2
        }
        fn state_names(&self) -> Vec<String> {
            self.ball.state_names()
        }
        fn flow_map(&self, at: HybridTime, x: &[f64], dx: &mut [f64]) {
            self.ball.flow_map(at, x, dx);
        }
        fn flow_set(&self, at: HybridTime, x: &[f64]) -> bool {
            self.ball.flow_set(at, x)
        }
        fn jump_rules(&self) -> &[JumpRule] {
            self.ball.jump_rules()
        }
        fn jump_set(&self, rule: usize, at: HybridTime, x: &[f64]) -> bool {
            self.ball.jump_set(rule, at, x)
        }
        fn jump_guard(&self, rule: usize, at: HybridTime, x: &[f64]) -> f64 {
            self.ball.jump_guard(rule, at, x)
        }
        fn jump_map(&self, r: usize, at: HybridTime, x: &[f64], rng: &mut SimRng, xp: &mut [f64]) {
            self.ball.jump_map(r, at, x, rng, xp);
        }
        fn set_atoms(&self, set: SetRef) -> Option<SetAtoms> {
            let atom = |cmp, id| Atom {
                cmp,
                flows: true,
                g_id: self.ids.then_some(id),
                timer: None,
            };
            Some(match set {
                SetRef::Flow => SetAtoms {
                    atoms: vec![atom(Cmp::Ge, 0)],
                    expr: SetExpr::Atom(0),
                },
                SetRef::Jump(_) => SetAtoms {
                    atoms: vec![atom(Cmp::Le, 0), atom(Cmp::Le, 1)],
                    expr: SetExpr::And(vec![SetExpr::Atom(0), SetExpr::Atom(1)]),
                },
            })
        }
        fn atom_values(&self, set: SetRef, _: HybridTime, x: &[f64], _: bool, out: &mut [f64]) {
            self.evaluations.set(self.evaluations.get() + 1);
            out[0] = x[0];
            if set != SetRef::Flow {
                out[1] = x[1];
            }
        }
    }

    /// Impacts to a few ulp of t against the closed form, with a bounded
    /// number of guard evaluations per impact; `h ≥ 0` in C and `h ≤ 0` in
    /// D share one localization when the atoms say they are one function.
    #[test]
    fn impacts_are_exact_in_few_evaluations_and_shared_zeros_are_found_once() {
        let run = |ids| {
            let sys = AtomBall {
                ball: BouncingBall::new(9.81, 0.8),
                ids,
                evaluations: Cell::new(0),
            };
            let settings = SimSettings::default().horizon_j(30);
            let arc = simulate_arc(&sys, &[1.0, 0.0], &settings, &mut SimRng::seed_from(1))
                .expect("simulation");
            (arc, sys.evaluations.get())
        };
        let (arc, shared) = run(true);
        let (arc_apart, apart) = run(false);
        let exact = BouncingBall::new(9.81, 0.8).impacts(1.0, 30);
        let jumps = arc.jumps();
        assert_eq!(jumps.len(), 30);
        for (k, (jump, (t, _))) in jumps.iter().zip(&exact).enumerate() {
            let err = (jump.at.t - t).abs();
            assert!(
                err <= 1e-13 * t.max(1.0),
                "impact {k}: {} vs {t}",
                jump.at.t
            );
        }
        let states = |a: &crate::arc::HybridArc| {
            a.samples().flat_map(|p| p.x.to_vec()).collect::<Vec<f64>>()
        };
        assert_eq!(states(&arc), states(&arc_apart), "same arc either way");
        assert!(
            shared < apart,
            "{shared} evaluations with identities, {apart} without"
        );
        // Checkpoints and localizations: about 77 per impact (2026-12-02;
        // the earlier regula falsi spent over 250 on localizing alone).
        assert!(shared <= 30 * 100, "{shared} evaluations for 30 impacts");
    }

    /// A pendulum kicked back when it swings past θ = −0.9 (D: θ + 0.9 ≤ 0
    /// ∧ ω < 0, atoms affine in the state), counting atom evaluations;
    /// `affine` says whether it gives the atoms' affine forms.
    struct KickedPendulum {
        rules: Vec<JumpRule>,
        affine: bool,
        evaluations: Cell<usize>,
    }

    impl HybridSystem for KickedPendulum {
        fn state_dim(&self) -> usize {
            2
        }
        fn state_names(&self) -> Vec<String> {
            vec!["th".into(), "w".into()]
        }
        fn flow_map(&self, _: HybridTime, x: &[f64], dx: &mut [f64]) {
            dx[0] = x[1];
            dx[1] = -x[0].sin();
        }
        fn jump_rules(&self) -> &[JumpRule] {
            &self.rules
        }
        fn jump_set(&self, _: usize, _: HybridTime, x: &[f64]) -> bool {
            x[0] + 0.9 <= 0.0 && x[1] < 0.0
        }
        fn jump_guard(&self, _: usize, _: HybridTime, x: &[f64]) -> f64 {
            -(x[0] + 0.9).max(x[1])
        }
        fn jump_map(&self, _: usize, _: HybridTime, x: &[f64], _: &mut SimRng, xp: &mut [f64]) {
            xp[0] = x[0];
            xp[1] = -0.95 * x[1];
        }
        fn set_atoms(&self, set: SetRef) -> Option<SetAtoms> {
            let atom = |cmp, id| Atom {
                cmp,
                flows: true,
                g_id: Some(id),
                timer: None,
            };
            (set != SetRef::Flow).then(|| SetAtoms {
                atoms: vec![atom(Cmp::Le, 0), atom(Cmp::Lt, 1)],
                expr: SetExpr::And(vec![SetExpr::Atom(0), SetExpr::Atom(1)]),
            })
        }
        fn atom_values(&self, _: SetRef, _: HybridTime, x: &[f64], _: bool, out: &mut [f64]) {
            self.evaluations.set(self.evaluations.get() + 1);
            out[0] = x[0] + 0.9;
            out[1] = x[1];
        }
        fn atom_affine(&self, _: SetRef, atom: usize) -> Option<AffineAtom> {
            let (k, constant) = [(0, 0.9), (1, 0.0)][atom];
            self.affine.then(|| AffineAtom {
                terms: vec![(k, 1.0)],
                constant,
            })
        }
    }

    /// With affine atoms the watcher looks inside a step only where the
    /// interpolant's control points show an atom changing sign: far fewer
    /// evaluations than at every checkpoint, and the same kicks, each at
    /// the same time within the event tolerance.
    #[test]
    fn affine_atoms_are_checked_only_where_they_change_sign() {
        let run = |affine| {
            let sys = KickedPendulum {
                rules: vec![JumpRule::new("kick", GuardKind::General)],
                affine,
                evaluations: Cell::new(0),
            };
            let settings =
                SimSettings::default()
                    .horizon_t(100.0)
                    .solver(crate::engine::Solver::Dopri5 {
                        rtol: 1e-9,
                        atol: 1e-11,
                    });
            let arc = simulate_arc(&sys, &[1.0, 0.0], &settings, &mut SimRng::seed_from(1))
                .expect("simulation");
            (arc, sys.evaluations.get())
        };
        let ((with, fewer), (without, all)) = (run(true), run(false));
        let (kicks, kicks_without) = (with.jumps(), without.jumps());
        assert!(kicks.len() >= 10, "{} kicks", kicks.len());
        assert_eq!(kicks.len(), kicks_without.len());
        for (a, b) in kicks.iter().zip(kicks_without) {
            assert_eq!(a.at.j, b.at.j);
            assert!(
                (a.at.t - b.at.t).abs() <= 1e-12 * a.at.t,
                "{} vs {}",
                a.at.t,
                b.at.t
            );
        }
        assert!(
            2 * fewer < all,
            "{fewer} evaluations with the forms, {all} without"
        );
    }

    /// The control points of the Hermite cubic give back its values (de
    /// Casteljau at τ = (s − s0)/(s1 − s0)) within their error bound.
    #[test]
    fn hermite_control_points_give_the_path() {
        let (y0, f0, y1, f1) = ([0.3, -2.0], [1.5, 0.25], [1.1, -1.0], [-0.5, 4.0]);
        let mut p = Hermite {
            s0: 0.2,
            s1: 0.7,
            y0: &y0,
            f0: &f0,
            y1: &y1,
            f1: &f1,
        };
        assert_control_points(&mut p, 2, (0.2, 0.7), 4);
    }

    /// The search for a change of sign: none in a polynomial that stays
    /// positive although its control polygon dips (a bump); for s² − 0.04
    /// with s from −0.5 to 1 (zeros at τ = 0.2 and 0.4667), a point of the
    /// other sign between the zeros, then from there a point past the
    /// second; and a bounded give-up on a polynomial that hugs zero within
    /// the tolerance.
    #[test]
    fn the_first_change_of_sign_is_found_and_the_search_ends() {
        let search = |p: &[f64], sign: f64, tol: f64| {
            let mut budget = SPLIT_BUDGET;
            first_other_sign(
                p,
                sign,
                tol,
                (0.0, 1.0),
                SPLIT_DEPTH,
                &mut budget,
                &mut vec![],
            )
        };
        // (1 − 2τ)² + 0.01 in Bernstein form (degree 2): 1.01, −0.99, 1.01.
        assert_eq!(search(&[1.01, -0.99, 1.01], 1.0, 1e-12), Ok(None));
        // s = −0.5 + 1.5τ: s² − 0.04 = 2.25τ² − 1.5τ + 0.21.
        let p = [0.21, -0.54, 0.96];
        let tau = search(&p, 1.0, 1e-12).unwrap().expect("a change");
        let g = |t: f64| split(&p, t).0[2];
        assert!(tau > 0.2 && tau < 0.4666 && g(tau) < 0.0, "{tau}");
        let back = split(&p, tau).1;
        let mut budget = SPLIT_BUDGET;
        let again = first_other_sign(
            &back[..3],
            -1.0,
            1e-12,
            (tau, 1.0),
            SPLIT_DEPTH,
            &mut budget,
            &mut vec![],
        );
        let t2 = again.unwrap().expect("back");
        assert!(t2 > 0.4667 && g(t2) > 0.0, "{t2}");
        // Within the tolerance everywhere: neither sign is ever sure.
        assert_eq!(
            search(&[1e-13, -1e-13, 1e-13, -1e-13, 1e-13], 1.0, 1e-12),
            Err(())
        );
    }

    /// Where the points cannot decide, the search says where to ask: the
    /// graze 1e-13 − (τ − 0.3)² (points −0.09, 0.21, −0.49) peaks above
    /// zero by less than the tolerance: no sure change, a probe at its
    /// top; and 10·τ(1 − τ) − 0.1·(1 − τ)², positive on (0.0098, 1), whose
    /// end is zero: its change of sign is found although the end is
    /// within the tolerance (it was taken for none: the end of a piece is
    /// not a checkpoint).
    #[test]
    fn grazes_are_probed_and_changes_before_an_end_on_zero_are_found() {
        let search = |p: &[f64], tol: f64| {
            let (mut probes, mut budget) = (vec![], SPLIT_BUDGET);
            let range = (0.0, 1.0);
            let found =
                first_other_sign(p, -1.0, tol, range, SPLIT_DEPTH, &mut budget, &mut probes);
            (found, probes)
        };
        let (found, probes) = search(&[-0.09 + 1e-13, 0.21 + 1e-13, -0.49 + 1e-13], 1e-12);
        assert_eq!(found, Ok(None));
        assert!(
            probes.len() == 1 && (probes[0] - 0.3).abs() < 1e-9,
            "{probes:?}"
        );
        // The same below zero by 1e-13: nothing to ask.
        let (found, probes) = search(&[-0.09 - 1e-13, 0.21 - 1e-13, -0.49 - 1e-13], 1e-14);
        assert_eq!((found, probes.len()), (Ok(None), 0));
        let r = [-0.1, 5.0, 0.0];
        let t = search(&r, 1e-12).0.unwrap().expect("a change");
        assert!(split(&r, t).0[2] > 0.0 && t < 1.0, "{t}");
    }

    /// Checks that the control points of each of the `dim` components of
    /// `path` on `[s0, s1]` give back its values (de Casteljau: the last
    /// point of the left piece at τ) within their error bound at τ = k/8,
    /// k < 8 (at `s1` itself a path may give its step's end state), and
    /// that there are `count` of them.
    pub(crate) fn assert_control_points<P: StepPath>(
        path: &mut P,
        dim: usize,
        (s0, s1): (f64, f64),
        count: usize,
    ) {
        for i in 0..dim {
            let mut points = [0.0; MAX_CONTROL];
            let (n, err) = path.control_points(i, &mut points).expect("a polynomial");
            assert_eq!(n, count);
            for k in 0..8 {
                let tau = k as f64 / 8.0;
                let mut out = vec![0.0; dim];
                path.eval(s0 + (s1 - s0) * tau, &mut out);
                let v = split(&points[..n], tau).0[n - 1];
                assert!(
                    (v - out[i]).abs() <= 4.0 * err,
                    "{i} at {tau}: {v} vs {}",
                    out[i]
                );
            }
        }
    }

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

    /// The scan's inline sort orders checkpoints as the library's does
    /// (signed zeros and NaN too).
    #[test]
    fn checkpoints_are_sorted_as_the_library_sorts_them() {
        let many: Vec<f64> = (0..12).map(|k| f64::from((k * 7) % 12) - 5.5).collect();
        let cases: [&[f64]; 4] = [
            &[],
            &[0.5, 0.25, 0.75, 0.25],
            &[1.0, 0.0, -0.0, f64::NAN, 0.3, -1e-300, 0.3],
            &many,
        ];
        for case in cases {
            let (mut ours, mut lib) = (case.to_vec(), case.to_vec());
            sort_points(&mut ours);
            lib.sort_unstable_by(f64::total_cmp);
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&ours), bits(&lib), "{case:?}");
        }
    }

    /// The first sure sign of a polynomial that starts on zero: at the
    /// first early fraction where it is beyond the tolerance (also when it
    /// leaves zero downwards before it turns), else at the largest piece
    /// over which it never has the other sign; none when it hugs zero.
    #[test]
    fn a_start_on_the_boundary_is_examined_from_the_first_sure_sign() {
        // 1e-17 + τ (degree 1).
        assert_eq!(
            first_sure_sign(&[1e-17, 1.0 + 1e-17], 1e-15),
            Some((EARLY[0], 1.0))
        );
        // τ² − τ/2: below zero first, up to τ = 0.5.
        assert_eq!(
            first_sure_sign(&[0.0, -0.25, 0.5], 1e-12),
            Some((EARLY[0], -1.0))
        );
        // τ⁴: within 1e-12 of zero up to τ = 2⁻¹⁰, positive after.
        assert_eq!(
            first_sure_sign(&[0.0, 0.0, 0.0, 0.0, 1.0], 1e-12),
            Some((1.0, 1.0))
        );
        // Within the tolerance everywhere.
        assert_eq!(first_sure_sign(&[0.0, 1e-13, -1e-13], 1e-12), None);
    }

    /// The zero of a polynomial between two values of opposite signs, from
    /// either side and for either curvature, to within the width; none
    /// when the ends have the same sign.
    #[test]
    fn the_zero_of_a_step_polynomial_is_found_without_the_system() {
        // (τ − 0.3)(τ + 1) = τ² + 0.7τ − 0.3 in Bernstein form (degree 2):
        // −0.3, 0.05, 1.4; and its negative; and 0.64 − 1.2τ² as a quartic.
        let cases: [(&[f64], f64); 3] = [
            (&[-0.3, 0.05, 1.4], 0.3),
            (&[0.3, -0.05, -1.4], 0.3),
            (&[0.64, 0.64, 0.44, 0.04, -0.56], (0.64f64 / 1.2).sqrt()),
        ];
        for (p, zero) in cases {
            let t = bernstein_zero(p, (0.0, 1.0), 1e-14).expect("a zero");
            assert!((t - zero).abs() <= 1e-14, "{t} vs {zero}");
            let t = bernstein_zero(p, (0.25, 0.9), 1e-14).expect("a zero");
            assert!((t - zero).abs() <= 1e-14, "{t} vs {zero}");
        }
        assert_eq!(bernstein_zero(&[-0.3, 0.05, 1.4], (0.5, 1.0), 1e-14), None);
    }

    /// A ball bouncing on the ground, h' = v, v' = −g, C = {h ≥ 0 ∨ v ≥ 0},
    /// D = {h ≤ 0 ∧ v < 0}: after each impact both sets start on the
    /// boundary h = 0, at each apex on v = 0.
    struct Ball {
        rules: Vec<JumpRule>,
        affine: bool,
        evaluations: Cell<usize>,
    }

    impl HybridSystem for Ball {
        fn state_dim(&self) -> usize {
            2
        }
        fn state_names(&self) -> Vec<String> {
            vec!["h".into(), "v".into()]
        }
        fn flow_map(&self, _: HybridTime, x: &[f64], dx: &mut [f64]) {
            dx[0] = x[1];
            dx[1] = -9.81;
        }
        fn jump_rules(&self) -> &[JumpRule] {
            &self.rules
        }
        fn jump_set(&self, _: usize, _: HybridTime, x: &[f64]) -> bool {
            x[0] <= 0.0 && x[1] < 0.0
        }
        fn jump_guard(&self, _: usize, _: HybridTime, x: &[f64]) -> f64 {
            (-x[0]).min(-x[1])
        }
        fn flow_set(&self, _: HybridTime, x: &[f64]) -> bool {
            x[0] >= 0.0 || x[1] >= 0.0
        }
        fn flow_guard(&self, _: HybridTime, x: &[f64]) -> Option<f64> {
            Some(x[0].max(x[1]))
        }
        fn jump_map(&self, _: usize, _: HybridTime, x: &[f64], _: &mut SimRng, xp: &mut [f64]) {
            xp[0] = x[0];
            xp[1] = -0.8 * x[1];
        }
        fn set_atoms(&self, set: SetRef) -> Option<SetAtoms> {
            let atom = |cmp, id| Atom {
                cmp,
                flows: true,
                g_id: Some(id),
                timer: None,
            };
            Some(match set {
                SetRef::Flow => SetAtoms {
                    atoms: vec![atom(Cmp::Ge, 0), atom(Cmp::Ge, 1)],
                    expr: SetExpr::Or(vec![SetExpr::Atom(0), SetExpr::Atom(1)]),
                },
                SetRef::Jump(_) => SetAtoms {
                    atoms: vec![atom(Cmp::Le, 0), atom(Cmp::Lt, 1)],
                    expr: SetExpr::And(vec![SetExpr::Atom(0), SetExpr::Atom(1)]),
                },
            })
        }
        fn atom_values(&self, _: SetRef, _: HybridTime, x: &[f64], _: bool, out: &mut [f64]) {
            self.evaluations.set(self.evaluations.get() + 1);
            out[..2].copy_from_slice(&x[..2]);
        }
        fn atom_affine(&self, _: SetRef, atom: usize) -> Option<AffineAtom> {
            self.affine.then(|| AffineAtom {
                terms: vec![(atom, 1.0)],
                constant: 0.0,
            })
        }
    }

    /// Segments that start on a boundary (every one of the ball's) are
    /// watched from the first sure sign of their affine atoms, without the
    /// early and evenly spaced checkpoints, and their impacts localized from
    /// the polynomial's zero: the impacts at their closed-form times (within
    /// rounding), with and without the forms, for fewer evaluations.
    #[test]
    fn segments_starting_on_a_boundary_are_watched_through_the_polynomial() {
        let run = |affine| {
            let sys = Ball {
                rules: vec![JumpRule::new("bounce", GuardKind::General)],
                affine,
                evaluations: Cell::new(0),
            };
            let settings = SimSettings::default().horizon_t(4.0);
            let arc = simulate_arc(&sys, &[1.0, 0.0], &settings, &mut SimRng::seed_from(1))
                .expect("simulation");
            (arc, sys.evaluations.get())
        };
        let ((with, fewer), (without, all)) = (run(true), run(false));
        let exact = BouncingBall::new(9.81, 0.8).impacts(1.0, 40);
        for arc in [&with, &without] {
            let impacts = arc.jumps();
            assert!(impacts.len() >= 10, "{} impacts", impacts.len());
            for (jump, (t, _)) in impacts.iter().zip(&exact) {
                assert!((jump.at.t - t).abs() <= 1e-12, "{} vs {t}", jump.at.t);
            }
        }
        assert_eq!(with.jumps().len(), without.jumps().len());
        // 577 against 774 (the regular and early checkpoints on each
        // segment's first step made it 753 before).
        assert!(
            5 * fewer < 4 * all,
            "{fewer} evaluations with the forms, {all} without"
        );
    }
}
