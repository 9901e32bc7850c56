//! Flow segments: advancing the state from local time 0 to the first event,
//! the segment end `d_end` (next timer event or horizon), or a chunk end.
//!
//! Four methods share the event watcher and the output logic:
//! - the engine's own steppers ([`OwnStepper`]: Dopri5, Dop853, Radau5,
//!   Bdf), one step at a time; events are localized on each step's dense
//!   output;
//! - ode_solvers' Rk4 driven through `solout` with sparse output; events
//!   are localized on the cubic Hermite interpolant of the step ends;
//! - exact advance of affine flows `ẋ = A x + b` by the exponential of the
//!   augmented matrix `[[A, b], [0, 0]]`, cached per distinct step length,
//!   or, where `A` is structurally nilpotent, by the flow's own polynomial
//!   ([`PolynomialFlow`]); events are localized on the exact solution;
//! - Euler–Maruyama with fixed step for noisy flows; events are localized
//!   on the linear interpolant of the step ends.

use std::cell::RefCell;
use std::ops::ControlFlow;

use nalgebra::{DMatrix, DVector};
use ode_solvers::{Rk4, System};

use super::HybridSystem;
use super::affine_modes::ModeAffines;
use super::bdf::{Bdf, BdfPath};
use super::clock::TimeSum;
use super::dop853::{Dop853, Dop853Path};
use super::dopri5::{Dopri5 as OwnDopri5, DopriPath, Failure, NonFiniteRate};
use super::error::SimError;
use super::events::{
    EventKind, Hermite, Linear, MAX_CONTROL, StepPath, Watcher, at_step_end, bernstein_points,
};
use super::implicit::LinearAlgebra;
use super::polynomial::{PolynomialFlow, PolynomialPath};
use super::radau5::{Radau5, RadauPath};
use super::settings::{LinearSolver, SimSettings, Solver};
use super::sparsity::{JacobianEval, system_pattern, use_sparse_lu};
use super::stepper::OwnStepper;
use super::system::SimRng;
use crate::arc::{ArcSink, FlowPiece, HybridTime, SampleKind, SolverSwitch};

/// Steps per `Rk4` stepper before it is restarted from its last state
/// (bounds the memory of its output and preallocation).
const MAX_STEPS_PER_STEPPER: u32 = 10_000;

/// Why a flow segment ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum EndWhy {
    /// Reached `d_end`.
    Reached,
    /// Stopped early at a chunk boundary; keep flowing.
    Partial,
    /// An event was localized.
    Event(EventKind),
    /// The sink asked to stop.
    Stopped,
}

/// Relative deviation from a straight line, per component (against the
/// largest magnitude the component has shown), below which the polyline
/// through the flow samples is taken to draw the flow faithfully.
const DENSE_REL: f64 = 1e-3;
/// Most samples per accepted step in dense output.
const DENSE_MAX: usize = 64;
/// A segment ended by an event carries at most this many times its length
/// as the next segment's first step proposal.
const EVENT_CARRY: f64 = 10.0;

/// A step path that can also give dense output: its midpoint, and the
/// points of a uniform grid on the step. Defaults evaluate the path.
pub(crate) trait DensePath: StepPath {
    /// The state at the step's start, where the path holds it as it
    /// evaluates there (dense output then reads it instead of evaluating
    /// the path). `None`: evaluate.
    fn start(&self) -> Option<&[f64]> {
        None
    }

    /// The length of `[s_lo, s_hi]` as the path measures it (a path
    /// advanced by a step of repeating length gives that length for its
    /// whole step, so that spacings derived from it repeat too).
    fn span(&self, s_lo: f64, s_hi: f64) -> f64 {
        s_hi - s_lo
    }

    /// x((s0 + s1) / 2) into `out`.
    fn mid(&mut self, s0: f64, s1: f64, out: &mut [f64]) {
        self.eval(0.5 * (s0 + s1), out);
    }

    /// x(s0 + k·δ) for k = 1, 2, … while `emit` continues and k < m, each
    /// passed to `emit` (the point's local time and state).
    fn grid(
        &mut self,
        s0: f64,
        delta: f64,
        m: usize,
        buf: &mut [f64],
        emit: &mut dyn FnMut(f64, &[f64]) -> ControlFlow<()>,
    ) -> ControlFlow<()> {
        for k in 1..m {
            let s = s0 + k as f64 * delta;
            self.eval(s, buf);
            emit(s, buf)?;
        }
        ControlFlow::Continue(())
    }
}

impl DensePath for Hermite<'_> {
    fn start(&self) -> Option<&[f64]> {
        Some(self.y0)
    }
}
impl DensePath for DopriPath<'_> {
    fn start(&self) -> Option<&[f64]> {
        Some(self.start())
    }
}
impl DensePath for Dop853Path<'_> {
    fn start(&self) -> Option<&[f64]> {
        Some(self.start())
    }
}
impl DensePath for RadauPath<'_> {}
impl DensePath for BdfPath<'_> {}
impl DensePath for Linear<'_> {}
impl DensePath for PolynomialPath<'_> {
    fn start(&self) -> Option<&[f64]> {
        Some(self.y0)
    }
}

/// Output of flow samples to the sink: a fixed grid (`dt_out`), or dense
/// output: every step end, plus points of the step's path (the solver's
/// interpolant or the exact solution) wherever the polyline through the
/// step ends would deviate from the path by more than [`DENSE_REL`] of the
/// components' magnitudes. The number of points per step follows from the
/// deviation at the step's midpoint (it scales with the square of the
/// spacing). Without a grid, a sink that wants no such points
/// ([`ArcSink::wants_dense_points`]) gets the step ends only; the steps are
/// the same.
pub(crate) struct Output<'a> {
    pub sink: &'a mut dyn ArcSink,
    dt: Option<f64>,
    /// Whether points between step ends are placed (dense output, a sink
    /// that wants them).
    points: bool,
    /// Whether the sink wants each step's path ([`ArcSink::flow_piece`]).
    pieces: bool,
    /// The relative accuracy of the steps (the solver's `rtol`; NaN for
    /// fixed steps), told to the sinks with each step's path.
    accuracy: f64,
    next_k: u64,
    buf: Vec<f64>,
    buf_lo: Vec<f64>,
    buf_hi: Vec<f64>,
    /// Largest magnitude of each component seen in the samples so far.
    scale: Vec<f64>,
    /// The local time of the flow sample at which the sink asked to stop:
    /// the run ends there, not at the end of the step that sample is in.
    stopped_at: Option<f64>,
    /// The global time the current segment ends at unless an event ends it
    /// first (a timer's expiry, the horizon): no flow sample at or after it.
    end_t: f64,
}

impl<'a> Output<'a> {
    pub fn new(sink: &'a mut dyn ArcSink, dt: Option<f64>, x0: &[f64], accuracy: f64) -> Self {
        let n = x0.len();
        let points = sink.wants_dense_points();
        let pieces = sink.wants_flow_pieces();
        Self {
            sink,
            dt,
            points,
            pieces,
            accuracy,
            next_k: 1,
            buf: vec![0.0; n],
            buf_lo: vec![0.0; n],
            buf_hi: vec![0.0; n],
            scale: x0.iter().map(|v| v.abs()).collect(),
            stopped_at: None,
            end_t: f64::INFINITY,
        }
    }

    /// Starts a segment that ends at global time `end_t` at the latest. A
    /// grid point there is the end's own sample (pre-jump or final), also
    /// where the grid's local time falls a rounding short of the end and
    /// on a step of its own (the timer's expiry a few ulps past it).
    pub fn segment_end(&mut self, end_t: f64) {
        self.end_t = end_t;
    }

    /// Whether flows are sampled densely (no output grid): flows advanced
    /// in long exact steps must then cut them so that a step's midpoint
    /// tells its curvature.
    pub fn dense(&self) -> bool {
        self.dt.is_none()
    }

    /// Whether a step's [`step`](Self::step) up to its end pushes nothing:
    /// no output grid, and a sink that wants neither points between step
    /// ends nor the steps' paths (the step's end itself is the next
    /// sample's, a jump's or the run's).
    fn quiet(&self) -> bool {
        self.dt.is_none() && !self.points && !self.pieces
    }

    /// Number of equal parts of `(s_lo, s_hi]` (the state at `s_hi` is
    /// `y_hi`) for dense output.
    fn dense_parts<P: DensePath>(
        &mut self,
        path: &mut P,
        s_lo: f64,
        s_hi: f64,
        y_hi: &[f64],
    ) -> usize {
        path.mid(s_lo, s_hi, &mut self.buf);
        if path.start().is_none() {
            path.eval(s_lo, &mut self.buf_lo);
        }
        let y_lo = path.start().unwrap_or(&self.buf_lo);
        let mut ratio: f64 = 0.0;
        for (((sc, &a), &m), &b) in self.scale.iter_mut().zip(y_lo).zip(&self.buf).zip(y_hi) {
            *sc = sc.max(a.abs()).max(m.abs()).max(b.abs());
            let dev = (m - 0.5 * (a + b)).abs();
            if dev > 0.0 {
                ratio = ratio.max(dev / (DENSE_REL * *sc));
            }
        }
        // A power of two: on the exact path the grid spacings h/parts then
        // repeat across steps and their propagators stay cached.
        if ratio.is_finite() {
            (ratio.sqrt().ceil() as usize)
                .clamp(1, DENSE_MAX)
                .next_power_of_two()
        } else {
            1
        }
    }

    /// Pushes the flow samples of the step `(s_lo, s_hi]` (local times,
    /// global `clock.at(s)`, the times events are recorded at) that lie
    /// strictly before `limit`, in local and in global time: a sample the
    /// global time's rounding puts at the segment's end would be a second
    /// point at the end's hybrid time (a grid point `k·dt` at a timer's
    /// event, with the state a rounding short of the threshold).
    #[allow(clippy::too_many_arguments)]
    fn step<P: DensePath>(
        &mut self,
        clock: TimeSum,
        j: u64,
        path: &mut P,
        s_lo: f64,
        s_hi: f64,
        y_hi: &[f64],
        limit: f64,
    ) -> ControlFlow<()> {
        let s_end = s_hi.min(limit);
        // A straight path (Euler–Maruyama) has no path between its ends to
        // offer: sinks integrate its samples.
        if self.pieces && !P::STRAIGHT && s_end > s_lo {
            let span = s_end - s_lo;
            // The end is the step's own end state where the step is taken
            // whole, so that a sink can recognise its sample there.
            let mut state = |theta: f64, x: &mut [f64]| {
                if theta >= 1.0 {
                    if s_end == s_hi {
                        x.copy_from_slice(y_hi);
                    } else {
                        path.eval(s_end, x);
                    }
                    return clock.at(s_end);
                }
                let s = s_lo + theta * span;
                path.eval(s, x);
                clock.at(s)
            };
            let times = (j, clock.at(s_lo), clock.at(s_end));
            let mut piece = FlowPiece::new(times, self.accuracy, &mut state);
            self.sink.flow_piece(&mut piece);
        }
        let t_limit = if limit.is_finite() {
            clock.at(limit).min(self.end_t)
        } else {
            self.end_t
        };
        match self.dt {
            None => {
                // Dense points only on the part of the step the solution
                // takes (up to an event inside it).
                let parts = if self.points && !P::STRAIGHT && s_end > s_lo {
                    let mut y_end = std::mem::take(&mut self.buf_hi);
                    let parts = if s_end < s_hi {
                        path.eval(s_end, &mut y_end);
                        self.dense_parts(path, s_lo, s_end, &y_end)
                    } else {
                        self.dense_parts(path, s_lo, s_end, y_hi)
                    };
                    self.buf_hi = y_end;
                    parts
                } else {
                    1
                };
                if parts > 1 {
                    let sink = &mut *self.sink;
                    let mut stopped = None;
                    let mut emit = |s: f64, y: &[f64]| {
                        let t = clock.at(s);
                        if s >= limit || t >= t_limit {
                            return ControlFlow::Break(());
                        }
                        let flow = sink.sample(HybridTime::new(t, j), y, SampleKind::Flow);
                        if flow.is_break() {
                            stopped = Some(s);
                        }
                        flow
                    };
                    let delta = path.span(s_lo, s_end) / parts as f64;
                    let _ = path.grid(s_lo, delta, parts, &mut self.buf, &mut emit);
                    if stopped.is_some() {
                        self.stopped_at = stopped;
                        return ControlFlow::Break(());
                    }
                }
                let t_hi = clock.at(s_hi);
                if s_hi < limit && t_hi < t_limit {
                    let flow = self
                        .sink
                        .sample(HybridTime::new(t_hi, j), y_hi, SampleKind::Flow);
                    if flow.is_break() {
                        self.stopped_at = Some(s_hi);
                        return flow;
                    }
                }
            }
            Some(dt) => loop {
                let tg = self.next_k as f64 * dt;
                let sg = tg - clock.value();
                if sg > s_hi || sg >= limit || tg >= t_limit {
                    break;
                }
                if sg > s_lo {
                    path.eval(sg, &mut self.buf);
                    let flow =
                        self.sink
                            .sample(HybridTime::new(tg, j), &self.buf, SampleKind::Flow);
                    if flow.is_break() {
                        self.stopped_at = Some(sg);
                        return flow;
                    }
                }
                self.next_k += 1;
            },
        }
        self.sink.poll()
    }

    /// Local time of the next grid point after `s`, if any.
    fn next_grid_after(&self, t0: f64, s: f64) -> Option<f64> {
        let dt = self.dt?;
        let mut k = self.next_k;
        loop {
            let sg = k as f64 * dt - t0;
            if sg > s {
                return Some(sg);
            }
            k += 1;
        }
    }
}

/// How flows are advanced.
pub(crate) enum Method {
    Ode(Solver),
    /// Always exact (`exact_affine = on`).
    Affine(Box<Affine>),
    /// Exact or the solver, per segment by cost (`exact_affine = auto`).
    Auto(Solver, Box<Affine>),
    EulerMaruyama {
        h: f64,
    },
}

/// Exact propagators of `ẋ = A x + b`.
pub(crate) struct Affine {
    n: usize,
    /// Propagators by step (bits of h), as [`exp_step`](Self::exp_step)
    /// gives them.
    cache: Vec<(u64, Vec<f64>)>,
    next_slot: usize,
    /// The slot the last lookup found (checked first).
    last_hit: usize,
    /// Rows of a propagator's columns: the active rows (or all), padded to
    /// a multiple of [`APPLY_BLOCK`].
    padded_rows: usize,
    /// Longest step between guard checks: 1/‖A‖∞.
    watch_step: f64,
    /// Rows of `[A, b]` with a nonzero entry, if at most half of them: the
    /// other components are constant along the flow (zero rows of the
    /// generator are unit rows of its exponential), so the propagators keep
    /// only these rows (k × (n+1)) and a step updates only these components.
    /// `None`: dense propagators ((n+1) × (n+1)).
    active: Option<Vec<usize>>,
    /// A state-sized buffer for chained propagation.
    scratch: Vec<f64>,
    /// The rows of a one-off propagator (event localization, when the
    /// Taylor series of [`action`](Self::action) does not apply).
    one_off: Vec<f64>,
    /// The nonzero entries `(row, column, value)` of `[A, b]`, for the
    /// series of [`action`](Self::action) (one product per term costs the
    /// nonzeros, not n²).
    entries: Vec<(usize, usize, f64)>,
    /// Where each row's entries start in `entries` (n + 1 offsets).
    row_start: Vec<usize>,
    /// ‖A‖∞, for the series' bound.
    norm: f64,
    /// The series' term and its next one.
    term: Vec<f64>,
    term_next: Vec<f64>,
    /// Evaluations of f on the solver path that cost about as much as one
    /// exponential (estimated flops of each, divided and rounded up).
    exp_fevals: u64,
    /// Solver work (evaluations of f) spent so far on whole segments of
    /// each recent duration (bits of the duration), for the auto choice:
    /// the durations (`NO_DURATION` in unused slots), the work on each,
    /// and the slot the next new duration takes (oldest first). Fixed
    /// arrays: every segment looks its duration up.
    spent_keys: [u64; AFFINE_SPENT],
    spent_fevals: [u64; AFFINE_SPENT],
    next_spent: usize,
    /// How many of `spent_keys` fall in each bucket of [`spent_bucket`]
    /// (unused slots as `NO_DURATION`): a zero count answers a lookup
    /// without scanning, so durations that never repeat (random timers)
    /// cost O(1) each.
    spent_count: [u8; SPENT_BUCKETS],
    /// Whether the work on some duration has reached `exp_fevals` (kept once
    /// set). Until then, and while no propagator is cached, no duration is
    /// [`worth`](Self::worth) the exact path.
    spent_ripe: bool,
    /// The flow as a polynomial in time, where `A` is structurally
    /// nilpotent: then every segment takes it (exact, and cheaper than
    /// an exponential or a solver's step, guards watched or not).
    poly: Option<PolynomialFlow>,
    /// The current step's Taylor polynomial, for the watcher's control
    /// points (computed on the first request of a step).
    taylor: RefCell<StepTaylor>,
}

/// The truncated Taylor polynomial of the exact flow on one step, in the
/// step's own variable `u = (s − s₀)/h ∈ [0, 1]`: the coefficients
/// `dₖ = hᵏ/k! (Gᵏ [x(s₀); 1])` for `k <` [`MAX_CONTROL`], component after
/// component (`G = [[A, b], [0, 0]]`), and the first term left out, which
/// bounds the rest of the series. The watcher decides affine guards on
/// exponential steps from its control points as it does on polynomial
/// steps, up to that rest instead of rounding; guarded steps are made short
/// enough for the rest to be below [`TAYLOR_REST`] of the step's motion
/// ([`Affine::guard_step`]).
#[derive(Debug)]
struct StepTaylor {
    /// The step length `d` is for (NaN: none).
    h: f64,
    /// Made by [`Affine::guard_step`] for the step about to be taken.
    fresh: bool,
    d: Vec<f64>,
    /// ‖d_m‖∞ of the first term left out (m = [`MAX_CONTROL`]).
    first_out: f64,
}

impl Default for StepTaylor {
    fn default() -> Self {
        Self {
            h: f64::NAN,
            fresh: false,
            d: Vec::new(),
            first_out: 0.0,
        }
    }
}

/// The rest of the Taylor series on a guarded exponential step, at most,
/// relative to the step's first-order motion ‖h (A x + b)‖∞.
const TAYLOR_REST: f64 = 1e-12;

/// Halvings of a guarded exponential step at most (1/‖A‖∞ down to 1/64 of
/// it: the rest of a solution as fast as ‖A‖∞ allows is then below
/// 1/64⁷/8! of its motion, 2e-17).
const TAYLOR_HALVINGS: u32 = 6;

const AFFINE_CACHE: usize = 16;
/// Rows of a propagator updated together by [`Affine::apply`].
const APPLY_BLOCK: usize = 8;
/// Durations whose solver work is remembered by the auto choice.
const AFFINE_SPENT: usize = 16;
/// An unused slot of the remembered durations: the bits of a NaN that no
/// arithmetic produces (a duration is never NaN anyway).
const NO_DURATION: u64 = u64::MAX;
/// Buckets of [`spent_bucket`] (a power of two, 16× `AFFINE_SPENT`: most
/// lookups of a new duration find its bucket empty).
const SPENT_BUCKETS: usize = 256;

/// The bucket of a remembered duration's bits.
fn spent_bucket(key: u64) -> usize {
    crate::num::hash_slot(key, SPENT_BUCKETS)
}

impl Affine {
    pub fn new(n: usize, a: &[f64], b: &[f64]) -> Result<Self, SimError> {
        if a.len() != n * n || b.len() != n {
            return Err(SimError::InvalidSystem {
                what: format!(
                    "FlowStructure::Affine needs A with {} entries and b with {n}, got {} and {}",
                    n * n,
                    a.len(),
                    b.len()
                ),
            });
        }
        if a.iter().chain(b).any(|v| !v.is_finite()) {
            return Err(SimError::InvalidSystem {
                what: "FlowStructure::Affine has a non-finite entry in A or b".into(),
            });
        }
        // One pass over A: its nonzero entries (b's after each row's) and
        // ‖A‖∞ (row sums in column order). A model of n states declares n²
        // entries, most of them zero (n clocks: A = 0), so nothing n² is
        // kept or built unless an exponential is computed.
        let mut entries = Vec::new();
        let mut norm: f64 = 0.0;
        for r in 0..n {
            let a_r = &a[r * n..(r + 1) * n];
            let mut row = 0.0;
            // Zero rows (clocks, held values) by a vectorised OR of the bits
            // without the sign (-0.0 is zero too).
            if a_r.iter().fold(0u64, |m, v| m | (v.to_bits() << 1)) != 0 {
                for (c, &v) in a_r.iter().enumerate() {
                    row += v.abs();
                    if v != 0.0 {
                        entries.push((r, c, v));
                    }
                }
            }
            if b[r] != 0.0 {
                entries.push((r, n, b[r]));
            }
            norm = norm.max(row);
        }
        let nnz = entries.len();
        let mut row_start = vec![0; n + 1];
        for &(r, _, _) in &entries {
            row_start[r + 1] += 1;
        }
        for r in 0..n {
            row_start[r + 1] += row_start[r];
        }
        let watch_step = if norm > 0.0 {
            1.0 / norm
        } else {
            f64::INFINITY
        };
        let active: Vec<usize> = (0..n)
            .filter(|&r| row_start[r + 1] > row_start[r])
            .collect();
        let poly = PolynomialFlow::from_entries(n, &entries);
        Ok(Self {
            n,
            cache: Vec::with_capacity(AFFINE_CACHE),
            next_slot: 0,
            last_hit: 0,
            padded_rows: if 2 * active.len() <= n {
                active.len()
            } else {
                n
            }
            .next_multiple_of(APPLY_BLOCK),
            watch_step,
            scratch: vec![0.0; n],
            one_off: Vec::new(),
            entries,
            row_start,
            norm,
            term: vec![0.0; n],
            term_next: vec![0.0; n],
            exp_fevals: {
                // Scaling and squaring with a degree-13 Padé approximant:
                // about 20 products of m × m matrices, 2m³ flops each.
                let m = if 2 * active.len() <= n {
                    2 * active.len()
                } else {
                    n + 1
                } as u64;
                // The products of f, and the vector updates of a
                // Runge–Kutta stage (about 12 flops per component).
                let feval = 2 * nnz as u64 + 12 * n as u64;
                m.saturating_pow(3)
                    .saturating_mul(40)
                    .div_ceil(feval.max(1))
            },
            spent_keys: [NO_DURATION; AFFINE_SPENT],
            spent_fevals: [0; AFFINE_SPENT],
            next_spent: 0,
            spent_count: {
                let mut count = [0; SPENT_BUCKETS];
                count[spent_bucket(NO_DURATION)] = AFFINE_SPENT as u8;
                count
            },
            spent_ripe: false,
            active: (2 * active.len() <= n).then_some(active),
            poly,
            taylor: RefCell::default(),
        })
    }

    /// The Taylor coefficients of the step of length `h` from `y0` into
    /// `tay` (see [`StepTaylor`]): `d₀ = y0`, `d₁ = h (A y0 + b)`,
    /// `dₖ₊₁ = h/(k+1) · A dₖ`, and the rest bounded from the first term
    /// left out, `dₘ` (m = [`MAX_CONTROL`]): each later term is at most
    /// ‖hA‖∞/(m+1) of the one before, so the rest is at most
    /// `‖dₘ‖∞ / (1 − ‖hA‖∞/(m+1))`.
    fn taylor_into(&self, tay: &mut StepTaylor, h: f64, y0: &[f64]) {
        const W: usize = MAX_CONTROL;
        let n = self.n;
        tay.d.resize(n * W, 0.0);
        let d = &mut tay.d;
        for (row, &y) in d.chunks_exact_mut(W).zip(y0) {
            row[0] = y;
        }
        let mut largest: f64 = 0.0;
        for k in 1..=W {
            let scale = h / k as f64;
            for r in 0..n {
                let mut v = 0.0;
                for &(_, c, a) in &self.entries[self.row_start[r]..self.row_start[r + 1]] {
                    v += a * match c {
                        c if c < n => d[c * W + k - 1],
                        _ if k == 1 => 1.0,
                        _ => 0.0,
                    };
                }
                if k < W {
                    d[r * W + k] = v * scale;
                } else {
                    largest = largest.max((v * scale).abs());
                }
            }
        }
        (tay.h, tay.first_out) = (h, largest);
    }

    /// The same polynomial for a step of length `h` from the same state:
    /// `dₖ` scales as hᵏ.
    fn taylor_rescale(tay: &mut StepTaylor, h: f64) {
        let q = h / tay.h;
        for row in tay.d.chunks_exact_mut(MAX_CONTROL) {
            let mut qk = 1.0;
            for v in row.iter_mut() {
                *v *= qk;
                qk *= q;
            }
        }
        tay.first_out *= q.powi(MAX_CONTROL as i32);
        tay.h = h;
    }

    /// The bound on the rest of the series of `tay`: each term after
    /// the first left out, `dₘ`, is at most ‖hA‖∞/(m+1) of the one before,
    /// so the rest is at most `‖dₘ‖∞ / (1 − ‖hA‖∞/(m+1))`.
    fn taylor_rest(&self, tay: &StepTaylor) -> f64 {
        let ratio = (tay.h * self.norm).abs() / (MAX_CONTROL + 1) as f64;
        if ratio < 1.0 {
            tay.first_out / (1.0 - ratio)
        } else {
            f64::INFINITY
        }
    }

    /// The length of a guarded step from `y0` of at most `hw`: `hw` halved
    /// until the rest of the Taylor polynomial is below [`TAYLOR_REST`] of
    /// the step's motion (the rest relative to the motion scales as h⁷);
    /// powers of two of `hw`, so that propagators repeat. A smooth solution
    /// (a stiff system's slow modes) keeps `hw`; one turning as fast as
    /// ‖A‖∞ allows (an oscillator) takes about 1/16 of it.
    fn guard_step(&mut self, hw: f64, y0: &[f64]) -> f64 {
        let mut tay = self.taylor.take();
        self.taylor_into(&mut tay, hw, y0);
        let motion = tay
            .d
            .chunks_exact(MAX_CONTROL)
            .fold(0.0f64, |m, row| m.max(row[1].abs()));
        let mut rel = self.taylor_rest(&tay) / motion;
        let mut h = hw;
        for _ in 0..TAYLOR_HALVINGS {
            // Also a NaN `rel` (no motion) ends here.
            if rel.partial_cmp(&TAYLOR_REST) != Some(std::cmp::Ordering::Greater) {
                break;
            }
            h *= 0.5;
            rel /= 128.0;
        }
        if h != hw {
            Self::taylor_rescale(&mut tay, h);
        }
        tay.fresh = true;
        self.taylor.replace(tay);
        h
    }

    /// The auto choice for a whole segment of duration `d`: exact if its
    /// propagator is cached or the solver has already spent the cost of an
    /// exponential on segments of this duration.
    fn worth(&self, d: f64) -> bool {
        let key = d.to_bits();
        self.cache.iter().any(|(k, _)| *k == key)
            || self
                .spent_slot(key)
                .is_some_and(|i| self.spent_fevals[i] >= self.exp_fevals)
    }

    /// Whether some duration may be [`worth`](Self::worth) the exact path.
    fn may_be_worth(&self) -> bool {
        self.spent_ripe || !self.cache.is_empty()
    }

    /// The slot of `spent_keys` holding `key`, if any.
    fn spent_slot(&self, key: u64) -> Option<usize> {
        if self.spent_count[spent_bucket(key)] == 0 {
            return None;
        }
        // Branch-free over the whole array (a key is in one slot at most).
        let mut slot = AFFINE_SPENT;
        for (i, &k) in self.spent_keys.iter().enumerate() {
            if k == key {
                slot = i;
            }
        }
        (slot < AFFINE_SPENT).then_some(slot)
    }

    /// Records `fevals` solver evaluations of f on a whole segment of
    /// duration `d`.
    fn spend(&mut self, d: f64, fevals: u64) {
        let key = d.to_bits();
        let i = if let Some(i) = self.spent_slot(key) {
            self.spent_fevals[i] += fevals;
            i
        } else {
            let i = self.next_spent;
            self.spent_count[spent_bucket(self.spent_keys[i])] -= 1;
            self.spent_count[spent_bucket(key)] += 1;
            (self.spent_keys[i], self.spent_fevals[i]) = (key, fevals);
            self.next_spent = (i + 1) % AFFINE_SPENT;
            i
        };
        self.spent_ripe |= self.spent_fevals[i] >= self.exp_fevals;
    }

    /// Cache slot of the propagator for a step `h` (computed on a miss).
    /// Periodic sampling asks for the same step again and again: that hit
    /// is inlined, the search out of line.
    #[inline]
    fn propagator(&mut self, h: f64) -> usize {
        let key = h.to_bits();
        if self
            .cache
            .get(self.last_hit)
            .is_some_and(|(k, _)| *k == key)
        {
            return self.last_hit;
        }
        self.propagator_search(key)
    }

    /// [`propagator`](Self::propagator) other than the last one used.
    #[inline(never)]
    fn propagator_search(&mut self, key: u64) -> usize {
        let h = f64::from_bits(key);
        let slot = match self.cache.iter().position(|(k, _)| *k == key) {
            Some(i) => i,
            None => {
                let p = self.exp_step(h);
                if self.cache.len() < AFFINE_CACHE {
                    self.cache.push((key, p));
                    self.cache.len() - 1
                } else {
                    let slot = self.next_slot;
                    self.cache[slot] = (key, p);
                    self.next_slot = (slot + 1) % AFFINE_CACHE;
                    slot
                }
            }
        };
        self.last_hit = slot;
        slot
    }

    /// The propagator of a step `h`: the first n rows `[Φ, γ]` of
    /// `exp(h [[A, b], [0, 0]])`, or its active rows, column after column,
    /// each column padded with zeros to a multiple of [`APPLY_BLOCK`] rows
    /// (a step is then a fixed-width vector update per column and block).
    fn exp_step(&self, h: f64) -> Vec<f64> {
        let mut rows = Vec::new();
        self.exp_step_into(h, &mut rows);
        rows
    }

    /// [`exp_step`](Self::exp_step) into `rows` (its buffer reused).
    fn exp_step_into(&self, h: f64, rows: &mut Vec<f64>) {
        let p = self.exp_rows(h);
        let k = self.active.as_ref().map_or(self.n, Vec::len);
        let pad = self.padded_rows - k;
        // `p` is column-major with p.nrows() rows; its first k rows.
        let (ps, ld) = (p.as_slice(), p.nrows());
        rows.clear();
        if k == 0 {
            return;
        }
        for col in ps.chunks_exact(ld) {
            rows.extend_from_slice(&col[..k]);
            rows.extend(std::iter::repeat_n(0.0, pad));
        }
    }

    /// `exp(h [[A, b], [0, 0]])`, or its active rows. With R the active rows
    /// and G_R their rows of the generator, `exp(hG)_R = I_R + φ₁(h G_RR)
    /// h G_R` (φ₁(X) = Σ X^k/(k+1)!, the top-right block of
    /// `exp([[X, I], [0, 0]])`): a 2k × 2k exponential instead of an
    /// (n+1) × (n+1) one.
    fn exp_rows(&self, h: f64) -> DMatrix<f64> {
        let n = self.n;
        let Some(rows) = &self.active else {
            return (self.generator() * h).exp();
        };
        let k = rows.len();
        let mut p = DMatrix::zeros(k, n + 1);
        if k == 0 {
            return p;
        }
        // Active row a of [A, b] is `h·G_r` below; its entries in the
        // active columns fill the k × k block of the augmented matrix.
        let mut slot = vec![usize::MAX; n + 1];
        for (a, &r) in rows.iter().enumerate() {
            slot[r] = a;
        }
        let mut aug = DMatrix::zeros(2 * k, 2 * k);
        let mut g_r = DMatrix::zeros(k, n + 1);
        for (a, &r) in rows.iter().enumerate() {
            for &(_, c, v) in &self.entries[self.row_start[r]..self.row_start[r + 1]] {
                g_r[(a, c)] = h * v;
                if slot[c] != usize::MAX {
                    aug[(a, slot[c])] = h * v;
                }
            }
            aug[(a, k + a)] = 1.0;
        }
        let phi = aug.exp().view((0, k), (k, k)).into_owned();
        p.gemm(1.0, &phi, &g_r, 0.0);
        for (a, &r) in rows.iter().enumerate() {
            p[(a, r)] += 1.0;
        }
        p
    }

    /// The augmented generator `[[A, b], [0, 0]]`, (n+1) × (n+1), built
    /// for an exponential (not kept: most models never compute one).
    fn generator(&self) -> DMatrix<f64> {
        let mut g = DMatrix::zeros(self.n + 1, self.n + 1);
        for &(r, c, v) in &self.entries {
            g[(r, c)] = v;
        }
        g
    }

    /// A step has been taken: the polynomial `guard_step` made serves that
    /// step only.
    #[inline]
    fn step_taken(&mut self) {
        let tay = self.taylor.get_mut();
        if !std::mem::take(&mut tay.fresh) {
            tay.h = f64::NAN;
        }
    }

    /// `out` = the flow from `x` (finite) after a step `h`; whether `out`
    /// is finite. Inlined, as [`apply`](Self::apply): a period of a
    /// sampled loop is one such step, and their calls cost about as many
    /// instructions as a small model's product.
    #[inline]
    fn advance(&mut self, h: f64, x: &[f64], out: &mut [f64]) -> bool {
        let slot = self.propagator(h);
        self.apply(&self.cache[slot].1, x, out)
    }

    /// Component `i` of `A x + b`: its row's nonzero entries in column
    /// order, `b` last (a timer's rate costs its row's entries, not n).
    fn rate(&self, i: usize, x: &[f64]) -> f64 {
        let row = &self.entries[self.row_start[i]..self.row_start[i + 1]];
        let (terms, b) = match row.last() {
            Some(&(_, c, b)) if c == self.n => (&row[..row.len() - 1], b),
            _ => (row, 0.0),
        };
        b + terms.iter().map(|&(_, c, a)| a * x[c]).sum::<f64>()
    }

    /// [`rate`](Self::rate) of a component whose row of A is zero (the
    /// same at every state), if it is.
    fn constant_rate(&self, i: usize) -> Option<f64> {
        let row = &self.entries[self.row_start[i]..self.row_start[i + 1]];
        row.iter()
            .all(|&(_, c, _)| c == self.n)
            .then(|| self.rate(i, &[]))
    }

    /// `out` = the flow from `x` after `h`, by the Taylor series of the
    /// exponential applied to the state: `x + Σₖ hᵏ/k! Aᵏ⁻¹ (A x + b)`,
    /// each term one sparse product. Where ‖h A‖∞ ≤ 1 (every point inside
    /// a step between guard checks, whose length is at most 1/‖A‖∞) the
    /// terms shrink at least as 1/k, and the series stops at the first term
    /// below half an ulp of the sum's norm, its remainder being below that
    /// term: the one-off states of event localization then cost a few
    /// products instead of an exponential (O(n³)). Returns false, `out`
    /// unwritten, where ‖h A‖∞ > 1.
    fn action(&mut self, h: f64, x: &[f64], out: &mut [f64]) -> bool {
        // At most 1/25! < 2⁻⁸³ of the first term is left after 25 terms.
        const MAX_TERMS: usize = 40;
        let bounded = h.abs() * self.norm <= 1.0;
        if !bounded {
            return false;
        }
        let (mut v, mut w) = (
            std::mem::take(&mut self.term),
            std::mem::take(&mut self.term_next),
        );
        v.fill(0.0);
        for &(r, c, a) in &self.entries {
            v[r] += a * if c == self.n { 1.0 } else { x[c] };
        }
        for (vi, o) in v.iter_mut().zip(out.iter_mut().zip(x)) {
            *vi *= h;
            *o.0 = o.1 + *vi;
        }
        for k in 2..=MAX_TERMS {
            let size = v.iter().fold(0.0f64, |m, t| m.max(t.abs()));
            let sum = out.iter().fold(0.0f64, |m, t| m.max(t.abs()));
            if size <= 0.5 * f64::EPSILON * sum || size == 0.0 {
                break;
            }
            w.fill(0.0);
            for &(r, c, a) in &self.entries {
                if c < self.n {
                    w[r] += a * v[c];
                }
            }
            let scale = h / k as f64;
            for (wi, o) in w.iter_mut().zip(out.iter_mut()) {
                *wi *= scale;
                *o += *wi;
            }
            std::mem::swap(&mut v, &mut w);
        }
        (self.term, self.term_next) = (v, w);
        true
    }

    /// `out = Φ x + γ` with `p` the padded columns of `[Φ, γ]` of
    /// [`exp_step`](Self::exp_step) (all rows, or the active ones: the
    /// other components are copied from `x`). Each row is γ plus Φ's terms
    /// in column order, as a column-major gemv adds them (the same bits);
    /// the rows go [`APPLY_BLOCK`] at a time, held in registers. Returns
    /// whether every component written is finite (decided in the same pass:
    /// `v − v` is 0 for a finite `v`, NaN otherwise), so that a step needs
    /// no second pass over the state. With AVX where the processor has it
    /// (as [`euler_step`]: the same products and sums, so the same bits).
    #[inline]
    fn apply(&self, p: &[f64], x: &[f64], out: &mut [f64]) -> bool {
        let (n, kp) = (self.n, self.padded_rows);
        debug_assert!(p.is_empty() || p.len() == kp * (n + 1));
        if self.active.is_some() {
            out.copy_from_slice(x);
        }
        let (phi, gamma) = p.split_at(n * kp);
        let rows = self.active.as_deref();
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx") {
            // SAFETY: the processor has AVX.
            return unsafe { apply_avx(phi, gamma, &x[..n], rows, out) };
        }
        apply_lanes(phi, gamma, &x[..n], rows, out)
    }
}

/// [`apply_lanes`] compiled for AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
fn apply_avx(
    phi: &[f64],
    gamma: &[f64],
    x: &[f64],
    rows: Option<&[usize]>,
    out: &mut [f64],
) -> bool {
    apply_lanes(phi, gamma, x, rows, out)
}

/// The body of [`Affine::apply`], inlined into each instruction set's copy:
/// `phi` holds `x.len()` columns of `gamma.len()` rows (a multiple of
/// [`APPLY_BLOCK`]); row `i` goes to `out[rows[i]]`, or to `out[i]` for the
/// rows below `out.len()` without `rows`.
#[inline(always)]
#[allow(clippy::eq_op)] // `a - a` is the finiteness test
fn apply_lanes(
    phi: &[f64],
    gamma: &[f64],
    x: &[f64],
    rows: Option<&[usize]>,
    out: &mut [f64],
) -> bool {
    let kp = gamma.len();
    // A state of at most one block written whole (sample-and-hold loops,
    // small plants): the block's sizes known, its loops unrolled.
    if kp == APPLY_BLOCK && rows.is_none() {
        match x.len() {
            1 => return apply_one_block::<1>(phi, gamma, x, out),
            2 => return apply_one_block::<2>(phi, gamma, x, out),
            3 => return apply_one_block::<3>(phi, gamma, x, out),
            4 => return apply_one_block::<4>(phi, gamma, x, out),
            5 => return apply_one_block::<5>(phi, gamma, x, out),
            6 => return apply_one_block::<6>(phi, gamma, x, out),
            7 => return apply_one_block::<7>(phi, gamma, x, out),
            8 => return apply_one_block::<8>(phi, gamma, x, out),
            _ => {}
        }
    }
    let mut nan = [0.0; APPLY_BLOCK];
    for (b, g) in gamma.chunks_exact(APPLY_BLOCK).enumerate() {
        let start = b * APPLY_BLOCK;
        let mut acc: [f64; APPLY_BLOCK] = g.try_into().expect("a block");
        // The block's rows of each column in turn, its updates unrolled.
        for (col, &xc) in phi.chunks_exact(kp).zip(x) {
            let col: &[f64; APPLY_BLOCK] =
                col[start..start + APPLY_BLOCK].try_into().expect("a block");
            for r in 0..APPLY_BLOCK {
                acc[r] += col[r] * xc;
            }
        }
        // Padding rows are 0 (finite): the sums decide, lane by lane.
        for r in 0..APPLY_BLOCK {
            nan[r] += acc[r] - acc[r];
        }
        match rows {
            Some(rows) => {
                for (&r, &a) in rows[start..].iter().zip(&acc) {
                    out[r] = a;
                }
            }
            // A fixed-length copy for a whole block (a short memcpy call
            // costs more than the products of a small model).
            None if start + APPLY_BLOCK <= out.len() => {
                out[start..start + APPLY_BLOCK].copy_from_slice(&acc);
            }
            None => {
                let from = start.min(out.len());
                let tail = &mut out[from..];
                for r in 0..APPLY_BLOCK {
                    if r < tail.len() {
                        tail[r] = acc[r];
                    }
                }
            }
        }
    }
    nan.iter().sum::<f64>() == 0.0
}

/// [`apply_lanes`] for `N` ≤ [`APPLY_BLOCK`] columns of one block, every
/// row written (`out` holds `N` components): the same products and sums in
/// the same order, so the same bits.
#[inline(always)]
#[allow(clippy::eq_op)] // `a - a` is the finiteness test
fn apply_one_block<const N: usize>(phi: &[f64], gamma: &[f64], x: &[f64], out: &mut [f64]) -> bool {
    let cols: &[[f64; APPLY_BLOCK]; N] = phi.as_chunks().0.try_into().expect("N columns");
    let x: &[f64; N] = x.try_into().expect("N components");
    let mut acc: [f64; APPLY_BLOCK] = gamma.try_into().expect("a block");
    for (col, &xc) in cols.iter().zip(x) {
        for r in 0..APPLY_BLOCK {
            acc[r] += col[r] * xc;
        }
    }
    let mut nan = 0.0;
    for a in &acc[..N] {
        nan += a - a;
    }
    out[..N].copy_from_slice(&acc[..N]);
    nan == 0.0
}

/// The exact solution of an affine flow on one step.
struct AffinePath<'a> {
    aff: &'a mut Affine,
    s0: f64,
    s1: f64,
    /// The length the step was advanced by (`s1 - s0` up to rounding).
    h: f64,
    y0: &'a [f64],
    y1: &'a [f64],
}

impl StepPath for AffinePath<'_> {
    fn eval(&mut self, s: f64, out: &mut [f64]) {
        if at_step_end(s, (self.s0, self.y0), (self.s1, self.y1), out) {
            return;
        }
        // Not cached: event localization asks for many one-off times.
        if self.aff.action(s - self.s0, self.y0, out) {
            return;
        }
        let mut p = std::mem::take(&mut self.aff.one_off);
        self.aff.exp_step_into(s - self.s0, &mut p);
        let _ = self.aff.apply(&p, self.y0, out);
        self.aff.one_off = p;
    }

    fn control_points(&self, i: usize, out: &mut [f64; MAX_CONTROL]) -> Option<(usize, f64)> {
        // The step's polynomial: made by `guard_step` for this step's
        // start, rescaled if the step was cut short, else made here.
        let mut tay = self.aff.taylor.borrow_mut();
        if tay.h != self.h {
            if tay.h.is_nan() {
                self.aff.taylor_into(&mut tay, self.h, self.y0);
            } else {
                Affine::taylor_rescale(&mut tay, self.h);
            }
        }
        let rest = self.aff.taylor_rest(&tay);
        if !rest.is_finite() {
            return None;
        }
        let row = &tay.d[i * MAX_CONTROL..(i + 1) * MAX_CONTROL];
        let (len, err) = bernstein_points(row, out);
        // The coefficients' own rounding (a sum of a row's products per
        // term, and their scaling), as the points' bound counts it.
        let size: f64 = row.iter().map(|v| v.abs()).sum();
        Some((len, err + rest + 4.0 * f64::EPSILON * size))
    }
}

/// Dense output on the exact path uses cached propagators (half step, grid
/// spacing): on periodic sampling they are computed once.
impl DensePath for AffinePath<'_> {
    fn start(&self) -> Option<&[f64]> {
        Some(self.y0)
    }

    fn span(&self, s_lo: f64, s_hi: f64) -> f64 {
        if (s_lo, s_hi) == (self.s0, self.s1) {
            self.h
        } else {
            s_hi - s_lo
        }
    }

    fn mid(&mut self, s0: f64, s1: f64, out: &mut [f64]) {
        debug_assert_eq!(s0, self.s0);
        let _ = self.aff.advance(0.5 * self.span(s0, s1), self.y0, out);
    }

    fn grid(
        &mut self,
        s0: f64,
        delta: f64,
        m: usize,
        buf: &mut [f64],
        emit: &mut dyn FnMut(f64, &[f64]) -> ControlFlow<()>,
    ) -> ControlFlow<()> {
        debug_assert_eq!(s0, self.s0);
        let slot = self.aff.propagator(delta);
        let mut prev = std::mem::take(&mut self.aff.scratch);
        prev.copy_from_slice(self.y0);
        let mut flow = ControlFlow::Continue(());
        for k in 1..m {
            let _ = self.aff.apply(&self.aff.cache[slot].1, &prev, buf);
            flow = emit(s0 + k as f64 * delta, buf);
            if flow.is_break() {
                break;
            }
            prev.copy_from_slice(buf);
        }
        self.aff.scratch = prev;
        flow
    }
}

/// Buffers reused across segments (no allocation per segment besides
/// `Rk4`'s own).
pub(crate) struct Flows {
    pub method: Method,
    /// A switched affine flow's propagators of the modes met, the current
    /// mode's in `method`.
    modes: Option<ModeAffines>,
    pub watcher: Watcher,
    /// State indices of the timers of timer rules (on the exact path,
    /// those not in `timer_rates`).
    timer_rows: Vec<usize>,
    /// On the exact path, the timers whose row of A is zero (clocks) and
    /// their rates, the same at every state.
    timer_rates: Vec<(usize, f64)>,
    max_step: f64,
    y_prev: Vec<f64>,
    f_prev: Vec<f64>,
    f_cur: Vec<f64>,
    y_end: Vec<f64>,
    /// Whether `f_prev` holds only the timers' rates: exact flows, and the
    /// auto choice while it is open (it completes f if it picks the
    /// solver).
    f_prev_partial: bool,
    noise_g: Vec<f64>,
    noise_dw: Vec<f64>,
    /// Evaluations of f by the solver in the current segment.
    fevals: u64,
    /// The engine's Dopri5 stepper, if the solver is Dopri5 (kept across
    /// segments: buffers and the step proposal).
    dopri: Option<OwnDopri5>,
    /// The engine's Dop853 stepper, if the solver is Dop853 (kept across
    /// segments likewise).
    dop853: Option<Dop853>,
    /// The Radau IIA stepper, if the solver is Radau5 (kept across
    /// segments: buffers, step proposal, Jacobian and factorizations).
    radau: Option<Radau5>,
    /// The BDF stepper, if the solver is Bdf (kept across segments:
    /// buffers, step proposal, Jacobian and factorization).
    bdf: Option<Bdf>,
    /// `Solver::Auto`: whether Radau5 (rather than Dopri5) advances the
    /// flow now (kept across segments and jumps).
    auto_implicit: Option<bool>,
    /// The implicit steppers' Jacobian storage and LU (dense or sparse),
    /// decided when the first implicit stepper is made.
    linear: Option<LinearAlgebra>,
    linear_mode: LinearSolver,
    /// How the Jacobian is evaluated (the system's dense one, or the
    /// entries of its pattern).
    jac_eval: JacobianEval,
}

/// How a run of steps on one of the engine's own steppers ended.
enum Stepped {
    End(SegmentEnd),
    /// `Solver::Auto`: the stepper's method no longer suits the flow from
    /// local time `s` on (the state there is in `y_prev`).
    Switch(f64),
}

/// `Solver::Auto` tests whether the flow is still stiff after every step
/// on which the implicit method evaluated its Jacobian anyway, and at the
/// latest after this many steps (then with a Jacobian of its own).
const NONSTIFF_EVERY: u32 = 25;

/// `Solver::Auto` runs Dopri5's stiffness test every this many steps (and
/// at every step once it found the step at its stability limit), so a
/// stiff flow is handed over after about 10 + 15 steps.
const AUTO_STIFF_EVERY: u32 = 10;

/// `Solver::Auto`'s threshold on Dopri5's estimate of h·λ: Hairer's 3.25 up
/// to `rtol` = 1e-6, lower by (rtol / 1e-6)^(1/5) below. Hairer's test finds
/// a step held at the stability limit, h·λ ≈ 3.3; at tight tolerances a
/// stiff flow's steps are held lower, by the error of its stiff mode's
/// forcing (x' = −10⁴(x − cos t) at rtol 1e-10: h·λ ≈ 1.4, 145 000 steps
/// to t = 20 where Radau5 takes 2 000), and the test never fired. A step that
/// resolves a mode of rate λ accurately has h·λ ∝ rtol^(1/5) (its error
/// estimate grows as (h·λ)⁵); scaling the threshold the same way keeps the
/// margin Hairer's has over such steps at the default tolerance (≈ 14×).
/// Not below rtol = 1e-10 (0.51): there the estimate, a ratio of
/// differences of nearly equal stages, is rounding noise, and oscillators
/// resolved accurately (x'' = −2500x at rtol 1e-13) read as stiff.
pub(crate) fn auto_stiff_hlamb(rtol: f64) -> f64 {
    const HAIRER: f64 = 3.25;
    HAIRER * (rtol.clamp(1e-10, 1e-6) / 1e-6).powf(0.2)
}

/// End of a flow segment: local time reached and why; the state is written
/// back into the caller's vector.
pub(crate) struct SegmentEnd {
    pub s: f64,
    pub why: EndWhy,
}

/// The first non-finite component of `x` as an error; `rule`: the jump
/// rule whose map produced `x` (`None`: the flow or the initial state).
pub(crate) fn check_finite<S: HybridSystem + ?Sized>(
    sys: &S,
    at: HybridTime,
    x: &[f64],
    rule: Option<usize>,
) -> Option<SimError> {
    let i = crate::num::first_non_finite(x)?;
    Some(SimError::NonFinite {
        at,
        component: i,
        name: sys.state_names().get(i).cloned().unwrap_or_default(),
        value: x[i],
        rule,
    })
}

/// As [`check_finite`] for the post-jump state `x` of `rule`: only the
/// components its map writes ([`JumpRule::writes`](super::JumpRule::writes),
/// when given), the others being the pre-jump state's, already checked.
#[allow(clippy::eq_op)] // `v - v` is the test itself
pub(crate) fn check_jump_finite<S: HybridSystem + ?Sized>(
    sys: &S,
    at: HybridTime,
    x: &[f64],
    rule: usize,
) -> Option<SimError> {
    let writes = &sys.jump_rules()[rule].writes;
    if writes.is_empty() {
        return check_finite(sys, at, x, Some(rule));
    }
    // x − x is 0 for a finite x and NaN otherwise: one pass without
    // branches decides the usual case, four sums side by side (one sum's
    // chain of additions made the pass twice as long).
    let mut acc = [0.0f64; 4];
    let mut quads = writes.chunks_exact(4);
    for q in &mut quads {
        for (a, &k) in acc.iter_mut().zip(q) {
            *a += x[k] - x[k];
        }
    }
    for &k in quads.remainder() {
        acc[0] += x[k] - x[k];
    }
    if acc.iter().sum::<f64>() == 0.0 {
        return None;
    }
    jump_not_finite(sys, at, x, rule)
}

/// Each rule's components checked by [`check_jump_finite`] (those its map
/// writes, or the whole state), as runs of consecutive components: the
/// check of every jump then reads slices (four lanes at a time, no index
/// per component) instead of gathering the components one by one. Where
/// [`finite`](Self::finite) finds a non-finite value, `check_jump_finite`
/// names it.
pub(crate) struct JumpChecks(Vec<Vec<std::ops::Range<usize>>>);

impl JumpChecks {
    pub fn new(rules: &[super::JumpRule], n: usize) -> Self {
        Self(
            rules
                .iter()
                .map(|rule| {
                    if rule.writes.is_empty() {
                        // One run: the whole state.
                        return std::iter::once(0..n).collect();
                    }
                    let mut runs: Vec<std::ops::Range<usize>> = Vec::new();
                    for &k in &rule.writes {
                        match runs.last_mut() {
                            Some(run) if run.end == k => run.end = k + 1,
                            _ => runs.push(k..k + 1),
                        }
                    }
                    runs
                })
                .collect(),
        )
    }

    /// Whether every component that [`check_jump_finite`] checks for `rule`
    /// is finite in `x`: exactly when it returns `None`.
    #[inline]
    #[allow(clippy::eq_op)] // `v - v` is the test itself
    pub fn finite(&self, rule: usize, x: &[f64]) -> bool {
        let mut acc = [0.0f64; 4];
        for run in &self.0[rule] {
            let mut quads = x[run.clone()].chunks_exact(4);
            for q in &mut quads {
                for (a, &v) in acc.iter_mut().zip(q) {
                    *a += v - v;
                }
            }
            for (a, &v) in acc.iter_mut().zip(quads.remainder()) {
                *a += v - v;
            }
        }
        acc.iter().sum::<f64>() == 0.0
    }
}

/// The error of [`check_jump_finite`] once a written component is known not
/// to be finite: out of line, so that the check of every jump stays small.
#[cold]
#[inline(never)]
fn jump_not_finite<S: HybridSystem + ?Sized>(
    sys: &S,
    at: HybridTime,
    x: &[f64],
    rule: usize,
) -> Option<SimError> {
    let writes = &sys.jump_rules()[rule].writes;
    // The first non-finite component in state order, as the full check.
    let i = writes
        .iter()
        .copied()
        .filter(|&k| !x[k].is_finite())
        .min()?;
    Some(SimError::NonFinite {
        at,
        component: i,
        name: sys.state_names().get(i).cloned().unwrap_or_default(),
        value: x[i],
        rule: Some(rule),
    })
}

/// An Euler step `y1 = y0 + dt·f`; whether every component of `y1` is
/// finite, decided in the same pass (`v − v` is 0 for a finite `v`, NaN
/// otherwise) instead of a second one over the state. With AVX where the
/// processor has it: four lanes instead of SSE2's two, the same products
/// and sums (no fused multiply-add), so the same bits.
fn euler_step(y0: &[f64], dt: f64, f: &[f64], y1: &mut [f64]) -> bool {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the processor has AVX.
        return unsafe { euler_step_avx(y0, dt, f, y1) };
    }
    euler_step_lanes(y0, dt, f, y1)
}

/// [`euler_step_lanes`] compiled for AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
fn euler_step_avx(y0: &[f64], dt: f64, f: &[f64], y1: &mut [f64]) -> bool {
    euler_step_lanes(y0, dt, f, y1)
}

/// The body of [`euler_step`], inlined into each instruction set's copy.
#[inline(always)]
#[allow(clippy::eq_op)] // `v - v` is the test itself
fn euler_step_lanes(y0: &[f64], dt: f64, f: &[f64], y1: &mut [f64]) -> bool {
    let n = y1.len();
    let (y0, f) = (&y0[..n], &f[..n]);
    // Eight sums side by side: the loop vectorizes.
    let mut acc = [0.0f64; 8];
    let whole = n / 8 * 8;
    for c in 0..n / 8 {
        let i = 8 * c;
        let (a, b, y) = (&y0[i..i + 8], &f[i..i + 8], &mut y1[i..i + 8]);
        for k in 0..8 {
            y[k] = a[k] + dt * b[k];
            acc[k] += y[k] - y[k];
        }
    }
    let mut sum: f64 = acc.iter().sum();
    for i in whole..n {
        y1[i] = y0[i] + dt * f[i];
        sum += y1[i] - y1[i];
    }
    sum == 0.0
}

/// (rtol, atol) of an adaptive solver; (0, 1) (plain |ẋᵢ|) for the others.
fn tolerances(solver: Solver) -> (f64, f64) {
    solver.tolerances().unwrap_or((0.0, 1.0))
}

/// How an integrator gives up.
#[derive(Clone, Copy)]
enum GaveUp {
    /// The step size fell below the resolution of t (last accepted step `h`).
    Collapse { h: f64 },
    /// The stiffness test fired; the stiff mode acts most on `component`.
    Stiff { component: usize },
    /// The rate of `component` kept changing sign over a long run of
    /// steps, the last of length `h`.
    Chatter { component: usize, h: f64 },
    /// The stiffness test fired where the Jacobian is small: the rate of
    /// `component` jumps (a discontinuous flow map), the last step `h`.
    Discontinuous { component: usize, h: f64 },
}

/// Whether the flow's Jacobian at (`s`, `y`) (from `jac`, `len` entries:
/// all, or its pattern's) makes `h`·‖J‖ (Frobenius: a bound on every
/// eigenvalue) reach `bound`. Where the flow map is smooth, the rates of
/// two states a step apart differ by at most about that much; the
/// stiffness test's estimate ‖Δf‖/‖Δy‖ far above it ([`STIFF_MARGIN`]×),
/// or rates that turn around every few steps with h·‖J‖ below
/// [`CHATTER_H_NORM`], mean the rates jump: a flow map discontinuous in
/// the state (a relay's sliding mode), which no solver integrates by
/// shrinking its steps. Systems of more than [`JACOBIAN_CHECK_MAX`]
/// states, and a NaN Jacobian, count as explained.
fn jacobian_explains(
    jac: &mut impl FnMut(f64, &[f64], &mut [f64]),
    len: usize,
    s: f64,
    y: &[f64],
    h: f64,
    bound: f64,
) -> bool {
    if y.len() > JACOBIAN_CHECK_MAX {
        return true;
    }
    // Rare (a test failed): the buffer is allocated here.
    let mut m = vec![0.0; len];
    jac(s, y, &mut m);
    let norm = m.iter().map(|v| v * v).sum::<f64>().sqrt();
    h * norm >= bound || norm.is_nan()
}

/// The most states for which [`jacobian_explains`] evaluates the Jacobian.
const JACOBIAN_CHECK_MAX: usize = 1000;

/// How far the stiffness test's h·|λ| may exceed h·‖J‖ on a smooth flow.
const STIFF_MARGIN: f64 = 8.0;

/// h·‖J‖ below which rates that turn around every few steps are a chatter
/// (a smooth oscillation turning them around every k steps has h·ω ≳ π/k).
const CHATTER_H_NORM: f64 = 0.05;

/// The error of an integrator that gave up at `stopped`, `(at, x)` its last accepted point,
/// where a rejected attempt met the non-finite rate `ahead` (if any; its `s` relative to `at`).
/// A flow that is NaN or ±∞ there or ahead is that error (`NonFinite` at its equation: the
/// steps shrank to nothing in front of it); otherwise a collapse names the component changing
/// fastest relative to the tolerances, |ẋᵢ| / (atol + rtol·|xᵢ|): what the integrator most
/// likely struggled with; stiffness names the component its stiff mode moves most.
fn gave_up<S: HybridSystem + ?Sized>(
    sys: &S,
    (at, x): (HybridTime, &[f64]),
    stopped: HybridTime,
    ahead: Option<NonFiniteRate>,
    solver: Solver,
    how: GaveUp,
) -> SimError {
    let name = |k: usize| sys.state_names().get(k).cloned().unwrap_or_default();
    let mut dx = vec![0.0; x.len()];
    sys.flow_map(at, x, &mut dx);
    let here = NonFiniteRate::find(0.0, &dx).map(|r| (at, r));
    let ahead = ahead.map(|r| (HybridTime::new(at.t + r.s, at.j), r));
    if let Some((at, r)) = here.or(ahead) {
        return SimError::NonFinite {
            at,
            component: r.component,
            name: name(r.component),
            value: r.value,
            rule: None,
        };
    }
    match how {
        GaveUp::Collapse { h } => {
            // The fastest-changing component, relative to the tolerances.
            let (rtol, atol) = tolerances(solver);
            let rate = |i: usize| dx[i].abs() / (atol + rtol * x[i].abs());
            let component = (0..x.len())
                .max_by(|&a, &b| rate(a).total_cmp(&rate(b)))
                .unwrap_or(0);
            SimError::StepSizeCollapse {
                at: stopped,
                h,
                component,
                name: name(component),
            }
        }
        GaveUp::Stiff { component } => SimError::Stiff {
            at: stopped,
            component,
            name: name(component),
        },
        GaveUp::Chatter { component, h } => SimError::Chatter {
            at: stopped,
            h,
            component,
            name: name(component),
        },
        GaveUp::Discontinuous { component, h } => SimError::Discontinuous {
            at: stopped,
            h,
            component,
            name: name(component),
        },
    }
}

impl Flows {
    pub fn new<S: HybridSystem + ?Sized>(
        sys: &S,
        settings: &SimSettings,
        method: Method,
        modes: Option<ModeAffines>,
        x0: &[f64],
    ) -> Result<Self, SimError> {
        let n = x0.len();
        let watcher = Watcher::new(sys, settings, x0);
        let m = sys.noise_dim();
        let mut timer_rows: Vec<usize> = sys
            .jump_rules()
            .iter()
            .filter_map(|r| match r.guard {
                super::GuardKind::Timer { index, .. } => Some(index),
                super::GuardKind::General => None,
            })
            .chain(watcher.timer_indices())
            .collect();
        timer_rows.sort_unstable();
        timer_rows.dedup();
        let mut timer_rates = Vec::new();
        // A switched flow's rates change with its mode: each is read from
        // the mode's A and b at each segment start.
        if modes.is_none()
            && let Method::Affine(aff) | Method::Auto(_, aff) = &method
        {
            timer_rows.retain(|&i| {
                let rate = aff.constant_rate(i);
                timer_rates.extend(rate.map(|r| (i, r)));
                rate.is_none()
            });
        }
        // Exact flows that are always taken (polynomial ones under the auto
        // choice too) never step on a solver: no stepper is made for them.
        let exact_only = match &method {
            Method::Affine(_) => true,
            Method::Auto(_, aff) => aff.poly.is_some() && modes.is_none(),
            _ => false,
        };
        let mut flows = Self {
            method,
            modes,
            watcher,
            timer_rows,
            timer_rates,
            max_step: settings.max_step,
            y_prev: vec![0.0; n],
            f_prev: vec![0.0; n],
            f_cur: vec![0.0; n],
            y_end: vec![0.0; n],
            f_prev_partial: false,
            noise_g: vec![0.0; n * m],
            noise_dw: vec![0.0; m],
            fevals: 0,
            dopri: match settings.solver {
                _ if exact_only => None,
                Solver::Dopri5 { rtol, atol } => Some(OwnDopri5::new(n, rtol, atol)),
                Solver::Auto { rtol, atol } => Some(
                    OwnDopri5::new(n, rtol, atol)
                        .stiffness_test_every(AUTO_STIFF_EVERY)
                        .stiffness_threshold(auto_stiff_hlamb(rtol)),
                ),
                _ => None,
            },
            dop853: match settings.solver {
                Solver::Dop853 { rtol, atol } if !exact_only => Some(Dop853::new(n, rtol, atol)),
                _ => None,
            },
            radau: None,
            bdf: None,
            auto_implicit: matches!(settings.solver, Solver::Auto { .. }).then_some(false),
            linear: None,
            linear_mode: settings.linear_solver,
            jac_eval: JacobianEval::Dense,
        };
        // `Solver::Auto` makes its Radau5 at its first switch: runs that
        // never turn stiff do not pay for its matrices.
        match settings.solver {
            Solver::Radau5 { rtol, atol } => {
                let la = flows.linear_algebra(sys)?;
                flows.radau = Some(Radau5::new(n, rtol, atol, &la));
            }
            Solver::Bdf { rtol, atol } => {
                let la = flows.linear_algebra(sys)?;
                flows.bdf = Some(Bdf::new(n, rtol, atol, &la));
            }
            _ => {}
        }
        Ok(flows)
    }

    /// The implicit steppers' linear algebra, decided on first use from
    /// the system's pattern and [`SimSettings::linear_solver`].
    fn linear_algebra<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
    ) -> Result<LinearAlgebra, SimError> {
        if let Some(la) = &self.linear {
            return Ok(la.clone());
        }
        let pattern = system_pattern(sys)?;
        let sparse = use_sparse_lu(pattern.as_deref(), self.linear_mode);
        let la = LinearAlgebra::new(sys.state_dim(), pattern.clone(), sparse);
        self.jac_eval = JacobianEval::new(pattern);
        self.linear = Some(la.clone());
        Ok(la)
    }

    /// Prepares a segment starting from `x` at ordinary time `clock` and
    /// jump count `j`; returns f(x, t, j) (on the exact path only its timer
    /// components), which give the timers' constant rates.
    #[inline]
    pub fn start<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        clock: TimeSum,
        j: u64,
        x: &[f64],
    ) -> Result<&[f64], SimError> {
        let at = HybridTime::new(clock.value(), j);
        if self.modes.is_some() {
            self.select_mode(sys, at, x)?;
        }
        // Exact flows need no interpolant: only the timers' rates, one row
        // of [A, b] each. So do polynomial flows (always exact), and the
        // auto choice without watched guards while some duration may be
        // worth the exact path; otherwise it takes the solver whatever the
        // duration, and f is computed once here.
        let rates = match &self.method {
            Method::Affine(aff) => Some(aff),
            Method::Auto(_, aff)
                if aff.poly.is_some() || (self.watcher.is_empty() && aff.may_be_worth()) =>
            {
                Some(aff)
            }
            _ => None,
        };
        self.f_prev_partial = rates.is_some();
        match rates {
            Some(aff) => {
                for &(i, rate) in &self.timer_rates {
                    self.f_prev[i] = rate;
                }
                for &i in &self.timer_rows {
                    self.f_prev[i] = aff.rate(i, x);
                }
            }
            // Timer rates, the steppers' first stage and Rk4's Hermite
            // interpolant (guards, output).
            None => sys.flow_map(at, x, &mut self.f_prev),
        }
        self.watcher.start(sys, clock, j, x);
        Ok(&self.f_prev)
    }

    /// A switched affine flow: makes the method's propagators those of the
    /// mode of `x`. The auto choice gives up the exact path for good once
    /// more modes than it keeps have been met (a mode of continuous values
    /// would compute coefficients at every segment and rarely an
    /// exponential worth it), and where a mode's coefficients cannot be had
    /// (not finite, a failed evaluation): the solver then meets the flow as
    /// it would have, and reports what it finds as it would have.
    /// `exact_affine = on` keeps the exact path and reports the error.
    fn select_mode<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        at: HybridTime,
        x: &[f64],
    ) -> Result<(), SimError> {
        let Some(modes) = &mut self.modes else {
            return Ok(());
        };
        match &mut self.method {
            Method::Affine(aff) => modes.select(sys, at, x, aff)?,
            Method::Auto(solver, aff) => {
                let solver = *solver;
                if modes.made() > ModeAffines::AUTO_MODES || modes.select(sys, at, x, aff).is_err()
                {
                    self.method = Method::Ode(solver);
                    self.modes = None;
                }
            }
            _ => {}
        }
        Ok(())
    }

    /// Schedules the sets' timer atoms of the segment [`start`](Self::start)ed
    /// from `x` ([`Watcher::schedule`]).
    #[inline]
    pub fn schedule_timers(&mut self, x: &[f64]) -> Option<f64> {
        self.watcher.schedule(x, &self.f_prev)
    }

    /// Advances `x` (at global time `t0`, jump count `j`) by at most `d_end`.
    /// Call [`start`](Self::start) first. Inlined into the caller: a
    /// segment of [`one_exact_step`](Self::one_exact_step) (a period of a
    /// sample-and-hold loop) then costs no call; only segments that step
    /// pay the general segment's call and prologue.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    pub fn segment<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        out: &mut Output<'_>,
        rng: &mut SimRng,
        t0: f64,
        j: u64,
        x: &mut Vec<f64>,
        d_end: f64,
    ) -> Result<SegmentEnd, SimError> {
        match self.one_exact_step(sys, out, t0, j, x, d_end) {
            Some(end) => end,
            None => self.steps_segment(sys, out, rng, t0, j, x, d_end),
        }
    }

    /// [`segment`](Self::segment) on the method's steps.
    #[inline(never)]
    #[allow(clippy::too_many_arguments)]
    fn steps_segment<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        out: &mut Output<'_>,
        rng: &mut SimRng,
        t0: f64,
        j: u64,
        x: &mut Vec<f64>,
        d_end: f64,
    ) -> Result<SegmentEnd, SimError> {
        // The state moves in and out by swapping buffers (of equal length),
        // not copying: `x` is not read until the segment ends, and `y_end`
        // is written by every segment before it is read.
        std::mem::swap(&mut self.y_prev, x);
        let end = match &mut self.method {
            Method::Ode(solver) => {
                let solver = *solver;
                self.solver_segment(sys, out, solver, t0, j, d_end)?
            }
            Method::Affine(_) => self.affine_segment(sys, out, t0, j, d_end)?,
            Method::Auto(_, aff) if aff.poly.is_some() => {
                self.affine_segment(sys, out, t0, j, d_end)?
            }
            Method::Auto(solver, aff) => {
                let solver = *solver;
                // `start` decided whether the choice is open.
                if self.f_prev_partial && aff.worth(d_end) {
                    self.affine_segment(sys, out, t0, j, d_end)?
                } else {
                    if self.f_prev_partial {
                        sys.flow_map(HybridTime::new(t0, j), &self.y_prev, &mut self.f_prev);
                    }
                    self.fevals = 0;
                    let end = self.solver_segment(sys, out, solver, t0, j, d_end)?;
                    if end.why == EndWhy::Reached
                        && let Method::Auto(_, aff) = &mut self.method
                    {
                        aff.spend(d_end, self.fevals);
                    }
                    end
                }
            }
            Method::EulerMaruyama { h } => {
                let h = *h;
                self.em_segment(sys, out, rng, h, t0, j, d_end)?
            }
        };
        std::mem::swap(x, &mut self.y_end);
        Ok(end)
    }

    /// The segment of [`segment`](Self::segment) when it is one step of
    /// an exponential with nothing watched or sampled inside it (sample-and-
    /// hold loops between their sampling instants): the same step as
    /// [`ExactSteps::run`]'s, without the per-step machinery that cannot
    /// act on it. `None` (nothing done) where that does not hold: something
    /// watched (the step is scanned, and may be shortened for the
    /// watcher), an output grid or dense points (samples inside the
    /// segment), the flow's polynomial, the auto choice on the solver, or
    /// a segment longer than one step (`exact_step_limit` under dense
    /// output, which `quiet` implies: there is no grid).
    #[inline]
    fn one_exact_step<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        out: &Output<'_>,
        t0: f64,
        j: u64,
        x: &mut Vec<f64>,
        d_end: f64,
    ) -> Option<Result<SegmentEnd, SimError>> {
        if !self.watcher.is_empty() || !out.quiet() {
            return None;
        }
        let aff = match &mut self.method {
            Method::Affine(aff) => aff,
            // As `segment` decides it (the polynomial is taken first).
            Method::Auto(_, aff)
                if aff.poly.is_none() && self.f_prev_partial && aff.worth(d_end) =>
            {
                aff
            }
            _ => return None,
        };
        // `exact_step_end` from 0 then ends the first step at `d_end`, of
        // length `d_end` (a NaN `d_end` is not one step).
        let one_step = d_end <= self.max_step.min(aff.watch_step);
        if aff.poly.is_some() || !one_step {
            return None;
        }
        if !aff.advance(d_end, x, &mut self.y_end)
            && let Some(e) = check_finite(sys, HybridTime::new(t0 + d_end, j), &self.y_end, None)
        {
            return Some(Err(e));
        }
        aff.step_taken();
        std::mem::swap(x, &mut self.y_end);
        Some(Ok(SegmentEnd {
            s: d_end,
            why: EndWhy::Reached,
        }))
    }

    /// A segment on the solver: the engine's Dopri5, Dop853, Radau5 or Bdf
    /// (or Dopri5 and Radau5 in turn for `Solver::Auto`), or ode_solvers'
    /// Rk4.
    fn solver_segment<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        out: &mut Output<'_>,
        solver: Solver,
        t0: f64,
        j: u64,
        d_end: f64,
    ) -> Result<SegmentEnd, SimError> {
        if self.auto_implicit.is_some() {
            return self.auto_segment(sys, out, solver, t0, j, d_end);
        }
        let stepped = if let Some(mut st) = self.dopri.take() {
            let result = self.own_segment(sys, out, &mut st, solver, (t0, j), 0.0, d_end);
            self.dopri = Some(st);
            result
        } else if let Some(mut st) = self.dop853.take() {
            let result = self.own_segment(sys, out, &mut st, solver, (t0, j), 0.0, d_end);
            self.dop853 = Some(st);
            result
        } else if let Some(mut st) = self.radau.take() {
            let result = self.own_segment(sys, out, &mut st, solver, (t0, j), 0.0, d_end);
            self.radau = Some(st);
            result
        } else if let Some(mut st) = self.bdf.take() {
            let result = self.own_segment(sys, out, &mut st, solver, (t0, j), 0.0, d_end);
            self.bdf = Some(st);
            result
        } else {
            let Solver::Rk4 { h } = solver else {
                unreachable!("the adaptive solvers run on the engine's own steppers")
            };
            return self.rk4_segment(sys, out, h, t0, j, d_end);
        };
        match stepped? {
            Stepped::End(end) => Ok(end),
            Stepped::Switch(_) => unreachable!("only Solver::Auto switches methods"),
        }
    }

    /// A segment under `Solver::Auto`: the active method (kept from the
    /// previous segment) until it hands over, then the other one from the
    /// same point, starting from the step the first one had reached; each
    /// switch is reported to the sink.
    fn auto_segment<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        out: &mut Output<'_>,
        solver: Solver,
        t0: f64,
        j: u64,
        d_end: f64,
    ) -> Result<SegmentEnd, SimError> {
        let Some(mut explicit) = self.dopri.take() else {
            unreachable!("Solver::Auto has its Dopri5")
        };
        let mut implicit = self.radau.take();
        let (n, (rtol, atol)) = (self.y_prev.len(), tolerances(solver));
        let mut s0 = 0.0;
        let result = loop {
            let on_implicit = self.auto_implicit == Some(true);
            let (stepped, h) = if on_implicit {
                let st = match implicit.as_mut() {
                    Some(st) => st,
                    None => match self.linear_algebra(sys) {
                        Ok(la) => implicit.insert(Radau5::new(n, rtol, atol, &la)),
                        Err(e) => break Err(e),
                    },
                };
                let r = self.own_segment(sys, out, st, solver, (t0, j), s0, d_end);
                (r, st.proposal())
            } else {
                let r = self.own_segment(sys, out, &mut explicit, solver, (t0, j), s0, d_end);
                (r, explicit.proposal())
            };
            match stepped {
                Ok(Stepped::Switch(s)) => {
                    s0 = s;
                    self.auto_implicit = Some(!on_implicit);
                    let to = if on_implicit {
                        explicit.set_proposal(h);
                        "dopri5"
                    } else {
                        if implicit.is_none() {
                            match self.linear_algebra(sys) {
                                Ok(la) => implicit = Some(Radau5::new(n, rtol, atol, &la)),
                                Err(e) => break Err(e),
                            }
                        }
                        if let Some(st) = implicit.as_mut() {
                            st.set_proposal(h);
                        }
                        "radau5"
                    };
                    sys.flow_map(HybridTime::new(t0 + s, j), &self.y_prev, &mut self.f_prev);
                    out.sink.solver_switch(&SolverSwitch {
                        at: HybridTime::new(t0 + s, j),
                        to,
                    });
                }
                Ok(Stepped::End(end)) => break Ok(end),
                Err(e) => break Err(e),
            }
        };
        self.dopri = Some(explicit);
        self.radau = implicit;
        result
    }

    /// Steps on one of the engine's own steppers from local time `s0`
    /// (the state in `y_prev`, f there in `f_prev`) to the segment's end,
    /// counting the evaluations of f.
    #[allow(clippy::too_many_arguments)]
    fn own_segment<S: HybridSystem + ?Sized, St: OwnStepper>(
        &mut self,
        sys: &S,
        out: &mut Output<'_>,
        st: &mut St,
        solver: Solver,
        (t0, j): (f64, u64),
        s0: f64,
        d_end: f64,
    ) -> Result<Stepped, SimError> {
        let fevals0 = st.fevals();
        let result = self.own_steps(sys, out, st, solver, (t0, j), s0, d_end);
        self.fevals += st.fevals() - fevals0 + 1;
        result
    }

    /// The steps of [`own_segment`](Self::own_segment): f at the start
    /// from the caller, the carried step proposal, events and output on
    /// each step's dense output; no allocation. Under `Solver::Auto` a
    /// stiffness failure of the explicit method, or the implicit method's
    /// test that the flow is no longer stiff, ends the run of steps with
    /// [`Stepped::Switch`].
    #[allow(clippy::too_many_arguments)]
    fn own_steps<S: HybridSystem + ?Sized, St: OwnStepper>(
        &mut self,
        sys: &S,
        out: &mut Output<'_>,
        st: &mut St,
        solver: Solver,
        (t0, j): (f64, u64),
        s0: f64,
        d_end: f64,
    ) -> Result<Stepped, SimError> {
        let auto = self.auto_implicit.is_some();
        let mut f =
            |s: f64, y: &[f64], dy: &mut [f64]| sys.flow_map(HybridTime::new(t0 + s, j), y, dy);
        // The stepper starts in its own local time 0.
        {
            let mut f_start = |s: f64, y: &[f64], dy: &mut [f64]| {
                sys.flow_map(HybridTime::new(t0 + s0 + s, j), y, dy);
            };
            let mut jac_start = |s: f64, y: &[f64], jm: &mut [f64]| {
                self.jac_eval
                    .eval(sys, HybridTime::new(t0 + s0 + s, j), y, jm);
            };
            st.start(&self.y_prev, &self.f_prev, &mut f_start, &mut jac_start);
        }
        let jac_len = self.jac_eval.len(self.y_prev.len());
        let mut jac = |s: f64, y: &[f64], jm: &mut [f64]| {
            self.jac_eval.eval(sys, HybridTime::new(t0 + s, j), y, jm);
        };
        let mut s = s0;
        let mut since_test = 0;
        loop {
            let remaining = d_end - s;
            // A segment end a rounding error beyond `max_step` is reached in
            // one step: a step of `max_step` would leave a sliver the stepper
            // cannot take (`T = 4.2` in steps of 0.1 from 4).
            let slack = 1e-9 * self.max_step + 64.0 * f64::EPSILON * d_end.abs();
            let h_max = if remaining <= self.max_step + slack {
                remaining
            } else {
                self.max_step
            };
            let h = match st.step(s, &self.y_prev, h_max, &mut f, &mut jac) {
                Ok(h) => h,
                Err(Failure::Stiff { h, h_lamb, .. })
                    if auto
                        && jacobian_explains(
                            &mut jac,
                            jac_len,
                            s,
                            &self.y_prev,
                            h,
                            h_lamb / STIFF_MARGIN,
                        ) =>
                {
                    return Ok(Stepped::Switch(s));
                }
                // Rates turning around every few steps where the flow's
                // Jacobian allows it (a fast oscillation, h·‖J‖ above
                // 1/20): the step is taken again and the test starts
                // afresh.
                Err(Failure::Chatter {
                    h, strict: false, ..
                }) if jacobian_explains(&mut jac, jac_len, s, &self.y_prev, h, CHATTER_H_NORM) => {
                    st.forgive_chatter();
                    continue;
                }
                Err(failure) => {
                    // A non-finite rate ahead is relative to the attempt's start `s`.
                    let ahead = st.non_finite().map(|r| NonFiniteRate { s: r.s - s, ..r });
                    let how = match failure {
                        Failure::Underflow => GaveUp::Collapse { h: st.proposal() },
                        Failure::Stiff {
                            component,
                            h,
                            h_lamb,
                        } => {
                            let y = &self.y_prev;
                            if jacobian_explains(&mut jac, jac_len, s, y, h, h_lamb / STIFF_MARGIN)
                            {
                                GaveUp::Stiff { component }
                            } else {
                                GaveUp::Discontinuous { component, h }
                            }
                        }
                        Failure::Chatter { component, h, .. } => GaveUp::Chatter { component, h },
                    };
                    let at = HybridTime::new(t0 + s, j);
                    return Err(gave_up(sys, (at, &self.y_prev), at, ahead, solver, how));
                }
            };
            let last = h >= remaining;
            let s1 = if last { d_end } else { s + h };
            if let Some(e) = check_finite(sys, HybridTime::new(t0 + s1, j), st.y_new(), None) {
                return Err(e);
            }
            let (mut path, y1) = st.path(s1, &mut f);
            let end = close_step(
                sys,
                &mut self.watcher,
                &mut self.y_end,
                out,
                &mut path,
                j,
                (s, s1),
                y1,
                last.then_some(EndWhy::Reached),
            );
            if let Some(end) = end {
                drop(path);
                // An event inside the step: the step carried into the next
                // segment grows from this segment's length, not from a step
                // far past the event (on a flow integrated exactly the
                // controller's steps would grow without bound, and with them
                // the rounding error of the interpolant at the events).
                if end.s > 0.0 && end.s < s1 {
                    st.limit_proposal(EVENT_CARRY * end.s);
                }
                return Ok(Stepped::End(end));
            }
            drop(path);
            self.y_prev.copy_from_slice(st.y_new());
            s = s1;
            if auto {
                since_test += 1;
                let fresh_only = since_test < NONSTIFF_EVERY;
                if let Some(nonstiff) = st.nonstiff(&mut jac, fresh_only) {
                    since_test = 0;
                    if nonstiff {
                        return Ok(Stepped::Switch(s));
                    }
                }
            }
        }
    }

    /// A segment on ode_solvers' `Rk4` with step `h` (at most
    /// [`MAX_STEPS_PER_STEPPER`] steps, then a partial end), driven
    /// through `solout`.
    fn rk4_segment<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        out: &mut Output<'_>,
        h: f64,
        t0: f64,
        j: u64,
        d_end: f64,
    ) -> Result<SegmentEnd, SimError> {
        let y0 = DVector::from_column_slice(&self.y_prev);
        let chunk = d_end.min(h * f64::from(MAX_STEPS_PER_STEPPER));
        let steps = (chunk / h).ceil().max(1.0);
        let h_eff = chunk / steps;
        let reach_why = if chunk < d_end {
            EndWhy::Partial
        } else {
            EndWhy::Reached
        };
        let mut step = Stepper {
            sys,
            fl: self,
            out,
            t0,
            j,
            d_stop: chunk,
            last_from: chunk - 0.5 * h_eff,
            reach_why,
            fevals: std::cell::Cell::new(0),
            s_prev: 0.0,
            end: None,
        };
        // `Rk4` never fails: it stops at `chunk`, or where `solout` asks.
        let _ = Rk4::new(&mut step, 0.0, y0, chunk, h_eff).integrate();
        let (s_prev, end, fevals) = (step.s_prev, step.end.take(), step.fevals.get());
        self.fevals += fevals;
        end.unwrap_or_else(|| {
            // Ended without our last-step test firing: continue from the
            // last step end.
            self.y_end.copy_from_slice(&self.y_prev);
            Ok(SegmentEnd {
                s: s_prev,
                why: EndWhy::Partial,
            })
        })
    }

    /// A segment on the exact path: matrix exponentials, or the flow's
    /// polynomial where it has one.
    fn affine_segment<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        out: &mut Output<'_>,
        t0: f64,
        j: u64,
        d_end: f64,
    ) -> Result<SegmentEnd, SimError> {
        let (Method::Affine(aff) | Method::Auto(_, aff)) = &mut self.method else {
            unreachable!("affine method")
        };
        let hw = exact_step_limit(&self.watcher, out, self.max_step, aff.watch_step);
        let mut steps = ExactSteps {
            watcher: &mut self.watcher,
            y_prev: &mut self.y_prev,
            y1: &mut self.f_cur,
            y_end: &mut self.y_end,
        };
        match aff.poly.take() {
            Some(mut poly) => {
                let end = steps.run(sys, out, &mut poly, (t0, j), hw, d_end);
                aff.poly = Some(poly);
                end
            }
            None => steps.run(sys, out, &mut **aff, (t0, j), hw, d_end),
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn em_segment<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        out: &mut Output<'_>,
        rng: &mut SimRng,
        h: f64,
        t0: f64,
        j: u64,
        d_end: f64,
    ) -> Result<SegmentEnd, SimError> {
        let m = self.noise_dw.len();
        let mut s = 0.0;
        let mut y1 = std::mem::take(&mut self.f_cur);
        let result = loop {
            let remaining = d_end - s;
            let last = remaining <= h * (1.0 + 1e-9);
            let (s1, dt) = if last { (d_end, remaining) } else { (s + h, h) };
            // f at the step's start: at the segment's start evaluated by
            // `start`, at a later step's here (into the same buffer).
            if s > 0.0 {
                sys.flow_map(HybridTime::new(t0 + s, j), &self.y_prev, &mut self.f_prev);
            }
            let mut finite = euler_step(&self.y_prev, dt, &self.f_prev, &mut y1);
            if m > 0 {
                sys.diffusion(HybridTime::new(t0 + s, j), &self.y_prev, &mut self.noise_g);
                let sq = dt.sqrt();
                for w in self.noise_dw.iter_mut() {
                    *w = sq * rng.standard_normal();
                }
                for (r, yn) in y1.iter_mut().enumerate() {
                    let row = &self.noise_g[r * m..(r + 1) * m];
                    *yn += row
                        .iter()
                        .zip(&self.noise_dw)
                        .map(|(g, w)| g * w)
                        .sum::<f64>();
                }
                finite = crate::num::first_non_finite(&y1).is_none();
            }
            if !finite && let Some(e) = check_finite(sys, HybridTime::new(t0 + s1, j), &y1, None) {
                break Err(e);
            }
            let mut path = Linear {
                s0: s,
                s1,
                y0: &self.y_prev,
                y1: &y1,
            };
            let reach = last.then_some(EndWhy::Reached);
            if let Some((end, at_y1)) = close_step_at(
                sys,
                &mut self.watcher,
                &mut self.y_end,
                out,
                &mut path,
                j,
                (s, s1),
                &y1,
                reach,
            ) {
                // The state is moved to the end, not copied (a segment of
                // one step, ended by a noise redraw, is the common case).
                if at_y1 {
                    std::mem::swap(&mut self.y_end, &mut y1);
                }
                break Ok(end);
            }
            std::mem::swap(&mut self.y_prev, &mut y1);
            s = s1;
        };
        self.f_cur = y1;
        result
    }
}

/// An exact flow: steps of any length, each with its exact path.
trait ExactFlow {
    type Path<'a>: DensePath
    where
        Self: 'a;

    /// Whether a step costs less when its length repeats (cached
    /// propagators): full steps then advance by exactly the step limit.
    /// Otherwise a step advances by `s1 - s0`.
    const CACHED: bool;

    /// `y1` = the flow from `y0` after `h`; the step whose path
    /// [`path`](Self::path) then gives. Returns `true` if `y1` is known to
    /// be finite (`false`: unknown, the caller checks).
    fn advance(&mut self, h: f64, y0: &[f64], y1: &mut [f64]) -> bool;

    /// The longest step from `y0`, at most `hw`, on which the watcher can
    /// decide the guards from the path's control points (called before
    /// [`advance`](Self::advance) when guards are watched). A polynomial
    /// path is exact at any length: `hw`.
    fn guard_step(&mut self, hw: f64, _y0: &[f64]) -> f64 {
        hw
    }

    /// The path of the step just advanced by `h`, `[s0, s1]` from `y0` to
    /// `y1`.
    fn path<'a>(
        &'a mut self,
        s0: f64,
        s1: f64,
        h: f64,
        y0: &'a [f64],
        y1: &'a [f64],
    ) -> Self::Path<'a>;
}

impl ExactFlow for Affine {
    type Path<'a> = AffinePath<'a>;
    const CACHED: bool = true;

    fn advance(&mut self, h: f64, y0: &[f64], y1: &mut [f64]) -> bool {
        Affine::advance(self, h, y0, y1)
    }

    fn guard_step(&mut self, hw: f64, y0: &[f64]) -> f64 {
        Affine::guard_step(self, hw, y0)
    }

    fn path<'a>(
        &'a mut self,
        s0: f64,
        s1: f64,
        h: f64,
        y0: &'a [f64],
        y1: &'a [f64],
    ) -> AffinePath<'a> {
        self.step_taken();
        AffinePath {
            aff: self,
            s0,
            s1,
            h,
            y0,
            y1,
        }
    }
}

impl ExactFlow for PolynomialFlow {
    type Path<'a> = PolynomialPath<'a>;
    const CACHED: bool = false;

    fn advance(&mut self, h: f64, y0: &[f64], y1: &mut [f64]) -> bool {
        self.set_step(y0, h);
        self.eval_at(1.0, y1);
        false
    }

    fn path<'a>(
        &'a mut self,
        s0: f64,
        s1: f64,
        _h: f64,
        y0: &'a [f64],
        y1: &'a [f64],
    ) -> PolynomialPath<'a> {
        PolynomialPath {
            flow: self,
            s0,
            s1,
            y0,
            y1,
        }
    }
}

/// The buffers an exact segment steps through (borrowed from [`Flows`]).
struct ExactSteps<'a> {
    watcher: &'a mut Watcher,
    y_prev: &'a mut Vec<f64>,
    y1: &'a mut Vec<f64>,
    y_end: &'a mut Vec<f64>,
}

impl ExactSteps<'_> {
    /// Steps of at most `hw` from `y_prev` (global time `t0`, jump count
    /// `j`) until an event, the sink's stop or `d_end`.
    fn run<S: HybridSystem + ?Sized, F: ExactFlow>(
        &mut self,
        sys: &S,
        out: &mut Output<'_>,
        flow: &mut F,
        (t0, j): (f64, u64),
        hw: f64,
        d_end: f64,
    ) -> Result<SegmentEnd, SimError> {
        let mut s = 0.0;
        // Whether the last step left the state unchanged (to the bit).
        let mut still = false;
        let guarded = !self.watcher.is_empty() && hw.is_finite();
        loop {
            // Without guards a flow at an equilibrium (the last step left
            // the state unchanged, and f vanishes there) ends its segment
            // in one step: how a solver's steps grow there.
            if still
                && self.watcher.is_empty()
                && at_rest(sys, (t0 + s, j), self.y_prev, self.y_end)
            {
                return Ok(self.rest_to_end(sys, out, j, s, d_end));
            }
            let hs = if guarded {
                flow.guard_step(hw, self.y_prev)
            } else {
                hw
            };
            let (s1, h, last) = exact_step_end(out, t0, s, hs, d_end);
            let h = if F::CACHED { h } else { s1 - s };
            if !flow.advance(h, self.y_prev, self.y1)
                && let Some(e) = check_finite(sys, HybridTime::new(t0 + s1, j), self.y1, None)
            {
                return Err(e);
            }
            let mut path = flow.path(s, s1, h, self.y_prev, self.y1);
            let reach = last.then_some(EndWhy::Reached);
            if let Some((end, at_y1)) = close_step_at(
                sys,
                self.watcher,
                self.y_end,
                out,
                &mut path,
                j,
                (s, s1),
                self.y1,
                reach,
            ) {
                drop(path);
                // Moved to the end, not copied (as an Euler segment's).
                if at_y1 {
                    std::mem::swap(self.y_end, self.y1);
                }
                return Ok(end);
            }
            drop(path);
            still = self.y_prev == self.y1;
            std::mem::swap(self.y_prev, self.y1);
            s = s1;
        }
    }

    /// The rest of a segment from `s` at an equilibrium ([`at_rest`]): one
    /// constant step to `d_end` (the steps of at most `hw` serve dense
    /// output, and a constant path has nothing to show between its ends).
    fn rest_to_end<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        out: &mut Output<'_>,
        j: u64,
        s: f64,
        d_end: f64,
    ) -> SegmentEnd {
        let mut path = Linear {
            s0: s,
            s1: d_end,
            y0: self.y_prev,
            y1: self.y_prev,
        };
        let reach = Some(EndWhy::Reached);
        close_step(
            sys,
            self.watcher,
            self.y_end,
            out,
            &mut path,
            j,
            (s, d_end),
            self.y_prev,
            reach,
        )
        .expect("the segment's last step ends it")
    }
}

/// Whether `y` is an equilibrium of the flow at `(t, j)`: f(y) is zero in
/// every component (`f` is scratch).
fn at_rest<S: HybridSystem + ?Sized>(
    sys: &S,
    (t, j): (f64, u64),
    y: &[f64],
    f: &mut [f64],
) -> bool {
    sys.flow_map(HybridTime::new(t, j), y, f);
    f.iter().all(|&v| v == 0.0)
}

/// The longest step of an exact path: guards, and dense output, need steps
/// short enough that the path cannot turn back unseen between checks
/// (`watch_step`, 1/‖A‖∞; guarded steps may be shorter still, see
/// [`ExactFlow::guard_step`]); without either a step may span the segment.
fn exact_step_limit(watcher: &Watcher, out: &Output<'_>, max_step: f64, watch_step: f64) -> f64 {
    if !watcher.is_empty() || out.dense() {
        max_step.min(watch_step)
    } else {
        f64::INFINITY
    }
}

/// The end of an exact step from `s` (at most `hw` long): the segment's
/// end `d_end` or the next output grid point if sooner; the step's length
/// (`hw` itself for a full step: its bits repeat from step to step, and so
/// do cached propagators, where `s1 - s` would vary in its last bits); and
/// whether it is the segment's end.
fn exact_step_end(out: &Output<'_>, t0: f64, s: f64, hw: f64, d_end: f64) -> (f64, f64, bool) {
    let (mut s1, mut h) = (s + hw, hw);
    if d_end <= s1 {
        (s1, h) = (d_end, d_end - s);
    }
    if let Some(sg) = out.next_grid_after(t0, s)
        && sg < s1
    {
        (s1, h) = (sg, sg - s);
    }
    if s1 >= d_end {
        (d_end, d_end - s, true)
    } else {
        (s1, h, false)
    }
}

/// The end of one accepted step over `[s0, s1]`, shared by the three
/// methods: localize the first guard event on `path` (the state on the
/// step), emit output up to the event or the step end, and say whether the
/// segment ends here. `reach` is `Some(why)` when `s1` is the segment's
/// last point. On an end, `y_end` holds the state where the segment ends.
#[allow(clippy::too_many_arguments)]
fn close_step<S: HybridSystem + ?Sized, P: DensePath>(
    sys: &S,
    watcher: &mut Watcher,
    y_end: &mut [f64],
    out: &mut Output<'_>,
    path: &mut P,
    j: u64,
    span: (f64, f64),
    y1: &[f64],
    reach: Option<EndWhy>,
) -> Option<SegmentEnd> {
    let (end, at_y1) = close_step_at(sys, watcher, y_end, out, path, j, span, y1, reach)?;
    if at_y1 {
        y_end.copy_from_slice(y1);
    }
    Some(end)
}

/// [`close_step`], leaving `y_end` unwritten when the segment ends at the
/// step's end (`true` with the end: the state is `y1`), for a caller that
/// can move `y1` there instead of copying it.
#[allow(clippy::too_many_arguments)]
fn close_step_at<S: HybridSystem + ?Sized, P: DensePath>(
    sys: &S,
    watcher: &mut Watcher,
    y_end: &mut [f64],
    out: &mut Output<'_>,
    path: &mut P,
    j: u64,
    (s0, s1): (f64, f64),
    y1: &[f64],
    reach: Option<EndWhy>,
) -> Option<(SegmentEnd, bool)> {
    let clock = watcher.clock();
    if !watcher.is_empty()
        && let Some((se, kind)) = watcher.scan(sys, path, (s0, s1), y1, reach.is_none())
        && !(reach.is_some() && se >= s1)
    {
        y_end.copy_from_slice(&watcher.event_state);
        if out.step(clock, j, path, s0, s1, y1, se).is_break() {
            let (end, _) = stopped(out, path, y_end, se);
            return Some((end, false));
        }
        let why = EndWhy::Event(kind);
        return Some((SegmentEnd { s: se, why }, false));
    }
    let limit = if reach.is_some() { s1 } else { f64::INFINITY };
    if out.step(clock, j, path, s0, s1, y1, limit).is_break() {
        return Some(stopped(out, path, y_end, s1));
    }
    reach.map(|why| (SegmentEnd { s: s1, why }, true))
}

/// The end of a segment whose sink asked to stop at or before `s_end`: a flow
/// sample before `s_end` ends it at that sample, so the run's last point is
/// the last one logged (its state into `y_end`, `false`); else at `s_end`
/// (`true`: the state is the caller's).
fn stopped<P: DensePath>(
    out: &mut Output<'_>,
    path: &mut P,
    y_end: &mut [f64],
    s_end: f64,
) -> (SegmentEnd, bool) {
    match out.stopped_at.take() {
        Some(s) if s < s_end => {
            path.eval(s, y_end);
            let why = EndWhy::Stopped;
            (SegmentEnd { s, why }, false)
        }
        _ => {
            let why = EndWhy::Stopped;
            (SegmentEnd { s: s_end, why }, true)
        }
    }
}

/// The `ode_solvers::System` seen by `Rk4`: the flow map in local time,
/// and `solout` doing event detection and output after each step.
struct Stepper<'f, 'o, S: ?Sized> {
    sys: &'f S,
    fl: &'f mut Flows,
    out: &'f mut Output<'o>,
    t0: f64,
    j: u64,
    d_stop: f64,
    last_from: f64,
    reach_why: EndWhy,
    /// Evaluations of f (`System::system` takes `&self`).
    fevals: std::cell::Cell<u64>,
    s_prev: f64,
    end: Option<Result<SegmentEnd, SimError>>,
}

impl<S: HybridSystem + ?Sized> Stepper<'_, '_, S> {
    fn finish(&mut self, end: Result<SegmentEnd, SimError>) -> bool {
        self.end = Some(end);
        true
    }

    /// After each step ending at local time `s` with state `y`; returns
    /// `true` to stop the stepper.
    fn on_step(&mut self, s: f64, y: &[f64]) -> bool {
        if let Some(e) = check_finite(self.sys, HybridTime::new(self.t0 + s, self.j), y, None) {
            return self.finish(Err(e));
        }
        let last = s >= self.last_from;
        let s1 = if last { self.d_stop } else { s };
        let fl = &mut *self.fl;
        // `Rk4` passes f at the step's start to `solout`: f at its end is
        // evaluated here.
        self.sys
            .flow_map(HybridTime::new(self.t0 + s1, self.j), y, &mut fl.f_cur);
        let mut path = Hermite {
            s0: self.s_prev,
            s1,
            y0: &fl.y_prev,
            f0: &fl.f_prev,
            y1: y,
            f1: &fl.f_cur,
        };
        let reach = last.then_some(self.reach_why);
        if let Some(end) = close_step(
            self.sys,
            &mut fl.watcher,
            &mut fl.y_end,
            self.out,
            &mut path,
            self.j,
            (self.s_prev, s1),
            y,
            reach,
        ) {
            return self.finish(Ok(end));
        }
        self.s_prev = s1;
        fl.y_prev.copy_from_slice(y);
        std::mem::swap(&mut fl.f_prev, &mut fl.f_cur);
        false
    }
}

impl<S: HybridSystem + ?Sized> System<f64, DVector<f64>> for &mut Stepper<'_, '_, S> {
    fn system(&self, s: f64, y: &DVector<f64>, dy: &mut DVector<f64>) {
        self.fevals.set(self.fevals.get() + 1);
        self.sys.flow_map(
            HybridTime::new(self.t0 + s, self.j),
            y.as_slice(),
            dy.as_mut_slice(),
        );
    }

    fn solout(&mut self, s: f64, y: &DVector<f64>, _dy: &DVector<f64>) -> bool {
        self.on_step(s, y.as_slice())
    }
}

#[cfg(test)]
mod tests {
    use super::{APPLY_BLOCK, Affine, ExactFlow, apply_lanes};
    use crate::arc::HybridTime;
    use crate::engine::{
        GuardKind, HybridSystem, JumpRule, SimRng, SimSettings, Solver, simulate_arc,
    };

    /// x' = 1 with a clock reset every 0.1: Euler steps are exact, so the
    /// arc tells where each segment's state came from.
    struct Ticks(Vec<JumpRule>);

    impl HybridSystem for Ticks {
        fn state_dim(&self) -> usize {
            2
        }
        fn state_names(&self) -> Vec<String> {
            vec!["x".into(), "tau".into()]
        }
        fn flow_map(&self, _: HybridTime, _: &[f64], dx: &mut [f64]) {
            dx.fill(1.0);
        }
        fn jump_rules(&self) -> &[JumpRule] {
            &self.0
        }
        fn jump_set(&self, _: usize, _: HybridTime, x: &[f64]) -> bool {
            x[1] >= 0.1
        }
        fn jump_guard(&self, _: usize, _: HybridTime, x: &[f64]) -> f64 {
            x[1] - 0.1
        }
        fn jump_map(&self, _: usize, _: HybridTime, x: &[f64], _: &mut SimRng, xp: &mut [f64]) {
            xp[0] = x[0];
            xp[1] = 0.0;
        }
    }

    /// A guarded exponential step of a rotation (turning as fast as ‖A‖∞
    /// allows) is halved until its Taylor polynomial's rest is negligible:
    /// 1/16 of 1/‖A‖∞ here. Its control points then give the exponential's
    /// path within their bound, on the full step and on a step cut short
    /// (a grid point, the segment's end: the polynomial rescaled). A stiff
    /// flow whose fast mode is at rest keeps the long step.
    #[test]
    fn guarded_exponential_steps_carry_their_taylor_polynomial() {
        let a = [0.0, 2.0, -2.0, 0.0];
        let mut aff = Affine::new(2, &a, &[0.0, 0.5]).unwrap();
        let y0 = [1.0, -0.25];
        let hw = 0.5; // 1/‖A‖∞
        let full = ExactFlow::guard_step(&mut aff, hw, &y0);
        assert_eq!(full, hw / 16.0);
        for (s0, len) in [(0.3, full), (1.0, 0.6 * full)] {
            if len != full {
                ExactFlow::guard_step(&mut aff, hw, &y0);
            }
            let mut y1 = [0.0; 2];
            ExactFlow::advance(&mut aff, len, &y0, &mut y1);
            let mut path = ExactFlow::path(&mut aff, s0, s0 + len, len, &y0, &y1);
            crate::engine::events::tests::assert_control_points(&mut path, 2, (s0, s0 + len), 8);
        }
        let mut stiff = Affine::new(2, &[-1e4, 0.0, 0.0, -1e-3], &[0.0, 0.0]).unwrap();
        assert_eq!(ExactFlow::guard_step(&mut stiff, 1e-4, &[0.0, 1.0]), 1e-4);
    }

    /// Euler–Maruyama segments of several steps (the last one partial) and
    /// of one step, each ended by a timer: every segment ends with the
    /// state of its last step (moved to the end, not copied) and the next
    /// starts from it, so x is t at every sample.
    #[test]
    fn euler_maruyama_segments_end_with_their_last_step() {
        let ticks = Ticks(vec![JumpRule::new(
            "tick",
            GuardKind::Timer {
                index: 1,
                threshold: 0.1,
                bounds_flow: false,
            },
        )]);
        for h in [0.03, 0.1, 0.25] {
            let s = SimSettings::default()
                .horizon_t(1.0)
                .solver(Solver::EulerMaruyama { h });
            let arc = simulate_arc(&ticks, &[0.0, 0.0], &s, &mut SimRng::seed_from(1)).unwrap();
            assert!(
                arc.jumps().len() >= 9,
                "h = {h}: {} jumps",
                arc.jumps().len()
            );
            for p in arc.samples() {
                assert!(
                    (p.x[0] - p.at.t).abs() < 1e-12,
                    "h = {h}: {:?} at {}",
                    p.x,
                    p.at
                );
            }
        }
    }

    /// x_k' = x_k over 11 components, one of them near the largest float:
    /// an Euler step makes it infinite. The error names the first such
    /// component at the step's end, whether it falls in the blocks of eight
    /// the step checks side by side or in the rest, at the segment's first
    /// step or a later one.
    struct Growth;

    impl HybridSystem for Growth {
        fn state_dim(&self) -> usize {
            11
        }
        fn state_names(&self) -> Vec<String> {
            (0..11).map(|k| format!("x{k}")).collect()
        }
        fn flow_map(&self, _: HybridTime, x: &[f64], dx: &mut [f64]) {
            dx.copy_from_slice(x);
        }
        fn jump_rules(&self) -> &[JumpRule] {
            &[]
        }
        fn jump_set(&self, _: usize, _: HybridTime, _: &[f64]) -> bool {
            false
        }
        fn jump_guard(&self, _: usize, _: HybridTime, _: &[f64]) -> f64 {
            -1.0
        }
        fn jump_map(&self, _: usize, _: HybridTime, _: &[f64], _: &mut SimRng, _: &mut [f64]) {}
    }

    /// A jump's finiteness check reads the components its rule writes:
    /// a non-finite one written (the first in state order is named), or
    /// none, whichever its position among the writes; one not written
    /// passes (it is the pre-jump state's, checked already).
    #[test]
    fn jump_checks_name_the_first_non_finite_component_written() {
        let n = 20;
        for len in 1..12 {
            // Written components in no particular order.
            let writes: Vec<usize> = (0..len).map(|k| (7 * k + 3) % n).collect();
            let sys = Ticks(vec![JumpRule {
                name: "r".into(),
                guard: GuardKind::General,
                group: None,
                part: None,
                writes: writes.clone(),
            }]);
            let at = HybridTime::new(0.5, 1);
            assert!(super::check_jump_finite(&sys, at, &vec![1.0; n], 0).is_none());
            for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
                for k in 0..n {
                    let mut x = vec![1.0; n];
                    x[k] = bad;
                    x[(k + 5) % n] = bad;
                    let found = super::check_jump_finite(&sys, at, &x, 0);
                    let want = [k, (k + 5) % n]
                        .into_iter()
                        .filter(|c| writes.contains(c))
                        .min();
                    match (found, want) {
                        (None, None) => {}
                        (Some(crate::engine::SimError::NonFinite { component, .. }), Some(c)) => {
                            assert_eq!(component, c, "writes {writes:?}, bad at {k}");
                        }
                        (f, w) => panic!("writes {writes:?}, bad at {k}: {f:?} vs {w:?}"),
                    }
                }
            }
        }
    }

    /// The engine's check of every jump (`JumpChecks::finite`, on runs of
    /// consecutive components) fails exactly where `check_jump_finite`
    /// finds a non-finite component: written components in runs, alone,
    /// out of order, repeated, or none given (the whole state), with a
    /// NaN or an infinity at any component.
    #[test]
    fn jump_check_runs_fail_exactly_where_the_check_names_a_component() {
        let n = 23;
        let writes_of: Vec<Vec<usize>> = vec![
            vec![],
            vec![4],
            vec![0, 1, 2, 3, 4, 5, 6, 7, 8],
            vec![3, 4, 5, 10, 11, 20, 21, 22],
            vec![22, 21, 20, 9, 7, 8, 1],
            vec![2, 3, 3, 4, 2, 17],
            (0..n).rev().collect(),
            (0..n).filter(|k| k % 3 != 1).collect(),
        ];
        let rules: Vec<JumpRule> = writes_of
            .iter()
            .enumerate()
            .map(|(i, writes)| JumpRule {
                name: format!("r{i}"),
                guard: GuardKind::General,
                group: None,
                part: None,
                writes: writes.clone(),
            })
            .collect();
        let checks = super::JumpChecks::new(&rules, n);
        let sys = Ticks(rules);
        let at = HybridTime::new(0.5, 1);
        for (rule, writes) in writes_of.iter().enumerate() {
            assert!(checks.finite(rule, &vec![-1.5; n]));
            for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
                for k in 0..n {
                    let mut x: Vec<f64> = (0..n).map(|i| i as f64 - 7.25).collect();
                    x[k] = bad;
                    let named = super::check_jump_finite(&sys, at, &x, rule).is_some();
                    assert_eq!(
                        !checks.finite(rule, &x),
                        named,
                        "writes {writes:?}, {bad} at {k}"
                    );
                    // Consistent with the writes themselves.
                    assert_eq!(named, writes.is_empty() || writes.contains(&k));
                }
            }
        }
    }

    /// The Euler step of the processor's widest lanes gives the bits of
    /// the portable one, and the same finiteness, on every length around
    /// the lane blocks and with non-finite values anywhere.
    #[test]
    fn euler_step_lanes_agree_bit_for_bit() {
        let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        for n in 0..40 {
            for bad in [None, Some(f64::NAN), Some(f64::INFINITY), Some(f64::MAX)] {
                let mut y0: Vec<f64> = (0..n)
                    .map(|_| (next() % 2001) as f64 / 7.0 - 140.0)
                    .collect();
                let f: Vec<f64> = (0..n).map(|_| f64::from_bits(next() >> 2) - 1.0).collect();
                if let Some(v) = bad
                    && n > 0
                {
                    y0[next() as usize % n] = v;
                }
                for dt in [1e-4, 0.37, 1e300] {
                    let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
                    let fa = super::euler_step(&y0, dt, &f, &mut a);
                    let fb = super::euler_step_lanes(&y0, dt, &f, &mut b);
                    assert_eq!(fa, fb, "n {n}, {bad:?}, dt {dt}");
                    assert_eq!(fa, a.iter().all(|v| v.is_finite()));
                    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&a), bits(&b), "n {n}, {bad:?}, dt {dt}");
                }
            }
        }
    }

    #[test]
    fn euler_steps_report_the_first_non_finite_component() {
        let s = SimSettings::default()
            .horizon_t(1.0)
            .solver(Solver::EulerMaruyama { h: 0.5 });
        for (big, steps) in [(3, 1), (9, 1), (3, 2), (9, 2)] {
            let mut x0 = vec![1.0; 11];
            // A step multiplies x by 1.5: MAX overflows at the first one,
            // MAX / 2 at the second.
            x0[big] = f64::MAX / if steps == 1 { 1.0 } else { 2.0 };
            x0[10] = x0[big];
            let err = simulate_arc(&Growth, &x0, &s, &mut SimRng::seed_from(1)).unwrap_err();
            match err {
                crate::engine::SimError::NonFinite { at, component, .. } => {
                    assert_eq!((component, at.t), (big, 0.5 * steps as f64), "{x0:?}");
                }
                e => panic!("{e:?}"),
            }
        }
    }

    /// The AVX copy of the propagator's product gives the SSE2 copy's bits
    /// (the same products and sums lane by lane), for dense and sparse
    /// rows, a partial last block, and a non-finite result.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_avx_product_has_the_same_bits() {
        if !std::arch::is_x86_feature_detected!("avx") {
            return;
        }
        let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for (n, rows) in [(7, None), (13, None), (9, Some(vec![1, 4, 8]))] {
            let kp = rows
                .as_ref()
                .map_or(n, Vec::len)
                .next_multiple_of(APPLY_BLOCK);
            let mut p: Vec<f64> = (0..kp * (n + 1)).map(|_| next()).collect();
            let x: Vec<f64> = (0..n).map(|_| next() * 1e3).collect();
            for inf in [false, true] {
                if inf {
                    p[kp + 2] = f64::INFINITY;
                }
                let (phi, gamma) = p.split_at(n * kp);
                let (mut a, mut b) = (x.clone(), x.clone());
                let fa = apply_lanes(phi, gamma, &x, rows.as_deref(), &mut a);
                // SAFETY: the processor has AVX (checked above).
                let fb = unsafe { super::apply_avx(phi, gamma, &x, rows.as_deref(), &mut b) };
                assert_eq!((fa, fb), (!inf, !inf), "n = {n}");
                let bits = |v: &[f64]| v.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&a), bits(&b), "n = {n}, rows {rows:?}");
            }
        }
    }

    /// Sparse propagators (active rows only) equal the rows of the dense
    /// exponential, and a step leaves the inactive components unchanged.
    #[test]
    fn affine_active_rows_match_the_dense_exponential() {
        let n = 7;
        let mut a = vec![0.0; n * n];
        let mut b = vec![0.0; n];
        // Rows 1 and 4 flow, coupled to each other and to constant components.
        for (c, v) in [(1, -0.7), (4, 2.0), (0, 0.3), (6, -1.1)] {
            a[n + c] = v;
        }
        for (c, v) in [(1, -1.5), (4, -0.2), (2, 0.9)] {
            a[4 * n + c] = v;
        }
        b[1] = 0.25;
        b[4] = -3.0;
        let aff = Affine::new(n, &a, &b).unwrap();
        assert_eq!(aff.active.as_deref(), Some(&[1, 4][..]));
        let x = [0.5, -1.0, 2.0, 0.1, 3.0, -0.4, 1.7];
        for h in [1e-3, 0.02, 0.7, 3.0] {
            let dense = (aff.generator() * h).exp();
            let rows = aff.exp_step(h);
            for (k, &r) in [1usize, 4].iter().enumerate() {
                for c in 0..=n {
                    let (d, s) = (dense[(r, c)], rows[c * APPLY_BLOCK + k]);
                    assert!(
                        (d - s).abs() <= 1e-13 * (1.0 + d.abs()),
                        "h {h} ({r},{c}): {d} vs {s}"
                    );
                }
            }
            let mut out = [0.0; 7];
            aff.apply(&rows, &x, &mut out);
            for (i, o) in out.iter().enumerate() {
                let want: f64 = dense[(i, n)] + (0..n).map(|c| dense[(i, c)] * x[c]).sum::<f64>();
                if i == 1 || i == 4 {
                    assert!(
                        (o - want).abs() <= 1e-12 * (1.0 + want.abs()),
                        "h {h} x[{i}]"
                    );
                } else {
                    assert_eq!(*o, x[i], "inactive component {i} is constant");
                }
            }
        }
        // More than half of the rows active: dense propagators.
        let dense = Affine::new(2, &[0.0, 1.0, -1.0, 0.0], &[0.0, 0.0]).unwrap();
        assert!(dense.active.is_none());
        // A zero flow: nothing to propagate.
        let zero = Affine::new(3, &[0.0; 9], &[0.0; 3]).unwrap();
        let mut out = [0.0; 3];
        zero.apply(&zero.exp_step(0.5), &[1.0, 2.0, 3.0], &mut out);
        assert_eq!(out, [1.0, 2.0, 3.0]);
    }

    /// A step by the blocked, padded propagator gives the bits of each
    /// row's γ + Σ Φ_ic x_c in column order, for sizes on and across the
    /// block boundaries, dense and active-row propagators.
    #[test]
    fn affine_steps_match_the_rows_in_column_order() {
        let mut seed = 0x2545_f491_4f6c_dd1d_u64;
        let mut draw = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for (n, flowing) in [
            (1, 1),
            (3, 3),
            (7, 7),
            (8, 8),
            (9, 9),
            (16, 16),
            (17, 17),
            (20, 9),
            (40, 17),
        ] {
            let mut a = vec![0.0; n * n];
            let mut b = vec![0.0; n];
            for r in 0..flowing {
                // Rows spread over the state, so active rows are not 0..k.
                let r = (r * n) / flowing;
                for c in 0..n {
                    a[r * n + c] = draw();
                }
                b[r] = draw();
            }
            let aff = Affine::new(n, &a, &b).unwrap();
            assert_eq!(aff.active.is_some(), 2 * flowing <= n, "n {n}");
            let rows: Vec<usize> = aff.active.clone().unwrap_or_else(|| (0..n).collect());
            let x: Vec<f64> = (0..n).map(|_| 4.0 * draw()).collect();
            for h in [0.01, 0.3] {
                let p = aff.exp_rows(h);
                let mut out = vec![f64::NAN; n];
                aff.apply(&aff.exp_step(h), &x, &mut out);
                let mut want = x.clone();
                for (k, &r) in rows.iter().enumerate() {
                    let mut acc = p[(k, n)];
                    for c in 0..n {
                        acc += p[(k, c)] * x[c];
                    }
                    want[r] = acc;
                }
                let bits = |v: &[f64]| v.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(
                    bits(&out),
                    bits(&want),
                    "n {n}, {flowing} rows flowing, h {h}"
                );
            }
        }
    }

    /// The Taylor series of the exponential's action gives the exponential
    /// applied to the state to rounding wherever ‖h A‖∞ ≤ 1 (stiff, sparse
    /// and with a forcing b), and declines beyond.
    #[test]
    fn the_series_action_matches_the_exponential_within_its_bound() {
        // A stiff chain (rates up to 4·10⁴) with a forcing, and a rotation
        // with constant components.
        let n = 30;
        let k = 1e4;
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            a[i * n + i] = -2.0 * k - 0.5;
            if i > 0 {
                a[i * n + i - 1] = k;
            }
            if i + 1 < n {
                a[i * n + i + 1] = k;
            }
        }
        let mut b = vec![0.0; n];
        b[0] = 3.0e3;
        let chain = Affine::new(n, &a, &b).unwrap();
        let x_chain: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin()).collect();
        let mut rot = vec![0.0; 16];
        (rot[1], rot[4]) = (2.0, -2.0);
        let rotation = Affine::new(4, &rot, &[0.0, 0.5, 0.0, 0.0]).unwrap();
        for (mut aff, x) in [(chain, x_chain), (rotation, vec![1.0, -0.5, 7.0, 2.0])] {
            let n = x.len();
            for frac in [1e-9, 0.013, 0.5, 1.0] {
                let h = frac / aff.norm;
                let mut got = vec![f64::NAN; n];
                assert!(aff.action(h, &x, &mut got), "n {n}, h {h}");
                let mut want = vec![f64::NAN; n];
                aff.apply(&aff.exp_step(h), &x, &mut want);
                let scale = want.iter().fold(1.0f64, |m, v| m.max(v.abs()));
                for (g, w) in got.iter().zip(&want) {
                    assert!((g - w).abs() <= 1e-13 * scale, "n {n}, h {h}: {g} vs {w}");
                }
            }
            let mut out = vec![f64::NAN; n];
            assert!(!aff.action(1.5 / aff.norm, &x, &mut out));
            assert!(out.iter().all(|v| v.is_nan()), "declined: out unwritten");
        }
    }

    /// Full exact steps advance by the step limit itself, whatever the
    /// rounding of their start times: their propagators are cached once.
    #[test]
    fn full_exact_steps_repeat_their_length_exactly() {
        let mut sink = crate::arc::HybridArc::default();
        let out = super::Output::new(&mut sink, None, &[0.0], f64::NAN);
        let hw = 6.25e-6 / 3.0;
        let (mut s, mut steps) = (0.0, 0);
        loop {
            let (s1, h, last) = super::exact_step_end(&out, 0.1, s, hw, 0.37);
            if last {
                assert_eq!(s1, 0.37);
                assert_eq!(h, 0.37 - s);
                break;
            }
            assert_eq!(h.to_bits(), hw.to_bits(), "step {steps} from {s}");
            assert!(s1 > s);
            (s, steps) = (s1, steps + 1);
        }
        assert!(steps > 10_000);
    }
}
