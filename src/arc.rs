//! Hybrid time and hybrid arcs: the solution objects the engine produces.
//!
//! A solution of a hybrid system lives on a *hybrid time domain*: a union of
//! intervals `[t_j, t_{j+1}] × {j}`. Ordinary time `t` advances while the
//! solution flows; the jump counter `j` advances by one at each jump, with `t`
//! unchanged. A [`HybridArc`] stores samples `(t, j, x)` in domain order, the
//! record of every jump, and why the solution ended.

use serde::Serialize;

/// A point of a hybrid time domain: ordinary time `t` and jump count `j`.
#[derive(Debug, Clone, Copy, PartialEq, PartialOrd, Serialize)]
pub struct HybridTime {
    /// Ordinary (continuous) time.
    pub t: f64,
    /// Number of jumps taken so far.
    pub j: u64,
}

impl HybridTime {
    /// The hybrid time `(t, j)`.
    pub const fn new(t: f64, j: u64) -> Self {
        Self { t, j }
    }
}

impl std::fmt::Display for HybridTime {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "(t = {}, j = {})", crate::num::Num(self.t), self.j)
    }
}

/// Where a sample sits on the hybrid time domain.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SampleKind {
    /// The initial point (0, 0) of the solution.
    Initial,
    /// A point inside a flow interval (integrator step or output grid).
    Flow,
    /// The last point of a flow interval, just before a jump.
    PreJump,
    /// The first point after a jump.
    PostJump,
    /// The last point of the solution.
    Final,
}

/// One jump: which rule fired, where, and the state on both sides.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct JumpRecord {
    /// Hybrid time of the pre-jump point; the post-jump point is `(t, j + 1)`.
    pub at: HybridTime,
    /// Index of the rule in [`crate::engine::HybridSystem::jump_rules`].
    pub rule: usize,
    /// State before the jump.
    pub pre: Vec<f64>,
    /// State after the jump.
    pub post: Vec<f64>,
}

/// A model's output map y = h(x, t, j), as the sinks evaluate it for each
/// logged sample. Closures `Fn(HybridTime, &[f64], &mut [f64])` are output
/// maps; a compiled model's [`crate::ir::OutputSubset`] also re-evaluates
/// after a jump only what the jump can change.
pub trait OutputMap {
    /// Writes `y` (length = the output layout's dimension) at `at`, `x`.
    fn eval(&self, at: HybridTime, x: &[f64], y: &mut [f64]);

    /// Brings `y`, evaluated at the pre-jump point of a jump in which the
    /// rules `rules` fired, to the post-jump point `at`, `x`, with the
    /// values [`eval`](Self::eval) gives there. Default: `eval`.
    fn eval_after_jump(&self, rules: &[usize], at: HybridTime, x: &[f64], y: &mut [f64]) {
        let _ = rules;
        self.eval(at, x, y);
    }
}

impl<F: Fn(HybridTime, &[f64], &mut [f64])> OutputMap for F {
    fn eval(&self, at: HybridTime, x: &[f64], y: &mut [f64]) {
        self(at, x, y)
    }
}

/// One integrator step of a flow interval, as a path a sink can evaluate
/// anywhere on it: the step's interpolant (or the exact solution on the exact
/// paths). Sinks that integrate along the flow (metrics' integrals and means)
/// read it through [`ArcSink::flow_piece`].
///
/// ```
/// use std::ops::ControlFlow;
/// use hybsim::arc::{ArcSink, FlowPiece, HybridTime, SampleKind};
/// use hybsim::{lang, source::SourceFile};
///
/// /// ∫x dt by the midpoint rule on each step's path.
/// struct Area(f64);
/// impl ArcSink for Area {
///     fn sample(&mut self, _: HybridTime, _: &[f64], _: SampleKind) -> ControlFlow<()> {
///         ControlFlow::Continue(())
///     }
///     fn jump(&mut self, _: HybridTime, _: usize, _: &[f64], _: &[f64]) -> ControlFlow<()> {
///         ControlFlow::Continue(())
///     }
///     fn wants_flow_pieces(&self) -> bool {
///         true
///     }
///     fn flow_piece(&mut self, piece: &mut FlowPiece<'_>) {
///         let mut x = [0.0];
///         piece.state_at(0.5, &mut x);
///         self.0 += (piece.t1 - piece.t0) * x[0];
///     }
/// }
///
/// // x' = 1 from 0, reset to 0 at x = 1, to T = 2.5: ∫x dt = 1/2 + 1/2 + 1/8.
/// let src = SourceFile::new(
///     "saw.hyb",
///     "model saw\nstate x = 0\nflow { x' = 1 }\njump r when x >= 1 { x+ = 0 }\nsim { T = 2.5 }\n",
/// );
/// let model = lang::compile(&src, &[]).unwrap();
/// let (x0, mut rng) = model.start(model.seed());
/// let mut area = Area(0.0);
/// hybsim::engine::simulate(&model, &x0, &model.settings(), &mut rng, &mut area).unwrap();
/// assert!((area.0 - 1.125).abs() < 1e-12);
/// ```
pub struct FlowPiece<'a> {
    /// The jump count of the flow interval.
    pub j: u64,
    /// The step's start time.
    pub t0: f64,
    /// The step's end time (the end of the part the solution takes, up to an
    /// event inside the step).
    pub t1: f64,
    /// The relative accuracy the path was computed to (the solver's `rtol`;
    /// NaN for fixed-step methods): quadratures along it need no better.
    pub accuracy: f64,
    state: &'a mut dyn FnMut(f64, &mut [f64]) -> f64,
}

impl<'a> FlowPiece<'a> {
    /// A piece over `[t0, t1]` at jump count `j`, computed to the relative
    /// accuracy `accuracy`; `state(θ, x)` writes the state at the fraction
    /// `θ ∈ [0, 1]` of the piece into `x` and returns its time.
    pub fn new(
        (j, t0, t1): (u64, f64, f64),
        accuracy: f64,
        state: &'a mut dyn FnMut(f64, &mut [f64]) -> f64,
    ) -> Self {
        Self {
            j,
            t0,
            t1,
            accuracy,
            state,
        }
    }

    /// Writes the state at the fraction `theta ∈ [0, 1]` of the piece into
    /// `x` and returns its time (`t0` at 0, `t1` at 1).
    pub fn state_at(&mut self, theta: f64, x: &mut [f64]) -> f64 {
        (self.state)(theta, x)
    }
}

impl std::fmt::Debug for FlowPiece<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FlowPiece")
            .field("j", &self.j)
            .field("t0", &self.t0)
            .field("t1", &self.t1)
            .field("accuracy", &self.accuracy)
            .finish_non_exhaustive()
    }
}

/// Receives a solution as it is computed. The engine pushes samples and
/// jumps in hybrid-time order; a sink may stop the run by returning
/// [`std::ops::ControlFlow::Break`].
pub trait ArcSink {
    /// A sample `(t, j, x)`.
    fn sample(&mut self, at: HybridTime, x: &[f64], kind: SampleKind) -> std::ops::ControlFlow<()>;
    /// A jump of rule `rule` (index into the system's jump rules) at the
    /// pre-jump time `at`, pushed between its `PreJump` and `PostJump`
    /// samples. Slices, not a [`JumpRecord`], so that sinks that do not keep
    /// jumps cost no allocation.
    fn jump(
        &mut self,
        at: HybridTime,
        rule: usize,
        pre: &[f64],
        post: &[f64],
    ) -> std::ops::ControlFlow<()>;

    /// Called once when the run ends, with where and why (after the `Final`
    /// sample). Default: nothing. Sinks that write files may record it.
    fn finish(&mut self, _termination: &Termination) {}

    /// Whether the sink stopped the run because it failed (a value it
    /// cannot write, a write error), rather than to end it (Ctrl-C): the
    /// run then ends without a `Final` sample, as a run the engine fails.
    /// Default: `false`.
    fn failed(&self) -> bool {
        false
    }

    /// The integrator changed (`Solver::Auto` switching between its
    /// explicit and implicit method): flows from `switch.at` on are
    /// advanced by `switch.to`. Default: nothing. Sinks that write files
    /// or summaries record it.
    fn solver_switch(&mut self, _switch: &SolverSwitch) {}

    /// Whether the sink wants the points that dense output adds between a
    /// step's ends where the polyline through them would deviate from the
    /// path (plots, files, trapezoid integrals of metrics). Default: `true`.
    /// A sink that only counts samples or keeps the final state says
    /// `false`, and the engine then pushes step ends only and skips the
    /// test that places those points. Steps, events and every pushed state
    /// are the same either way.
    fn wants_dense_points(&self) -> bool {
        true
    }

    /// Whether the sink wants each integrator step's path
    /// ([`flow_piece`](Self::flow_piece)). Default: `false` (the engine then
    /// builds no pieces).
    fn wants_flow_pieces(&self) -> bool {
        false
    }

    /// The path of one integrator step of a flow interval, pushed before the
    /// step's samples (so a sample at `(t, j)` with `piece.t0 <= t <=
    /// piece.t1` comes after it). The pieces of a flow interval tile it,
    /// except where the flow is advanced by a method without a path between
    /// its steps (Euler–Maruyama): there, and for arcs replayed from memory,
    /// no pieces are pushed. Default: nothing.
    fn flow_piece(&mut self, _piece: &mut FlowPiece<'_>) {}

    /// Called after each accepted integrator step, samples or not: a sink
    /// that stops the run for a reason outside the solution (Ctrl-C, a
    /// wall-clock budget) says so here as in [`sample`](Self::sample), so
    /// that a run whose samples are far apart (a `dt_out` of many steps)
    /// still stops within a step. The run then ends at the step's end, as
    /// when a sample stops it. Default: `Continue`.
    fn poll(&mut self) -> std::ops::ControlFlow<()> {
        std::ops::ControlFlow::Continue(())
    }
}

/// A change of the integrator during a run (`Solver::Auto`): from hybrid
/// time `at` on, flows are advanced by the method named `to` (`"radau5"`
/// when the explicit method found the flow stiff, `"dopri5"` when it no
/// longer is).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SolverSwitch {
    /// Where the new method takes over.
    pub at: HybridTime,
    /// Its name, as `solver = …` spells it.
    pub to: &'static str,
}

/// Why a solution ended. Reaching a horizon, suspecting Zeno behaviour and
/// getting stuck are *outcomes* of a simulation, not errors: they are values
/// of this enum, returned inside [`Termination`].
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "cause", rename_all = "snake_case")]
pub enum TerminationCause {
    /// Ordinary time reached the horizon T (`SimSettings::horizon_t`).
    HorizonT,
    /// The jump count reached the horizon J (`SimSettings::horizon_j`).
    HorizonJ,
    /// A Zeno guard fired before rule `rule` could jump again.
    ZenoSuspected {
        /// Index of the rule that was about to fire.
        rule: usize,
        /// Its name.
        rule_name: String,
        /// Which guard fired.
        detail: ZenoDetail,
    },
    /// The state is neither in C (or cannot flow inside C) nor in D: the
    /// solution is maximal and ends here.
    CannotFlowOrJump {
        /// `true`: the last flow ended because it was leaving C (the state
        /// is on C's boundary, the flow pointing out); `false`: the state is
        /// outside C.
        leaving: bool,
        /// The atoms of C that fail at the state (exactly, without
        /// `set_tol`), in the order of the flow set's atoms; empty for a
        /// system that describes C without atoms.
        failed: Vec<FailedAtom>,
        /// The state.
        state: Vec<f64>,
        /// The time at which the last flow started (the same j): with
        /// `leaving`, the start of the flow that left C (where a jump
        /// landed, or the initial point); else the end's own time.
        flow_from: f64,
    },
    /// The sink asked to stop (e.g. a file limit or a user interrupt); the
    /// sinks still get the `Final` sample of the state where the run stopped.
    StoppedBySink,
}

/// An atom `g ⋈ 0` of the flow set that fails at the state where a solution
/// could neither flow nor jump.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FailedAtom {
    /// Index into the flow set's atoms (`HybridSystem::set_atoms`).
    pub index: usize,
    /// The value of `g` there.
    pub value: f64,
    /// How the atom reads in the model (`x <= 1`), if the system says
    /// (`HybridSystem::atom_text`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub text: Option<String>,
}

/// Which Zeno guard stopped a run.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "guard", rename_all = "snake_case")]
pub enum ZenoDetail {
    /// `jumps` jumps (the window) happened within ordinary time `within`,
    /// faster than `SimSettings::zeno_max_rate` allows.
    Rate {
        /// Number of jumps in the window.
        jumps: u32,
        /// Ordinary time they spanned.
        within: f64,
    },
    /// The total number of jumps reached `SimSettings::max_total_jumps`.
    TotalJumps {
        /// The limit.
        limit: u64,
    },
}

/// Where and why a solution ended.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Termination {
    /// Hybrid time of the last point of the solution.
    pub at: HybridTime,
    /// Why it ended there.
    pub cause: TerminationCause,
}

impl Termination {
    /// One sentence on what to change if this ending was not wanted.
    pub fn help(&self) -> &'static str {
        match &self.cause {
            TerminationCause::HorizonT => "raise `horizon_t` to simulate longer",
            TerminationCause::HorizonJ => "raise `horizon_j` to allow more jumps",
            // No time passed over the window: a system that only jumps (an
            // empty flow set, discrete time) ends only at a jump horizon.
            TerminationCause::ZenoSuspected {
                detail: ZenoDetail::Rate { within, .. },
                ..
            } if *within == 0.0 => {
                "these jumps all happened at the same t: a discrete-time system (empty flow set) \
                 needs a jump horizon J (`horizon_j`) to say how many jumps to make; to let the \
                 rule fire at one instant without J, set `zeno_max_rate` to infinity and a jump \
                 budget `max_total_jumps`"
            }
            TerminationCause::ZenoSuspected {
                detail: ZenoDetail::Rate { .. },
                ..
            } => {
                "the named rule fires ever faster (Zeno behaviour?); if this is intended, raise \
                 `zeno_max_rate` or `zeno_window`, or set `zeno_max_rate` to infinity with a jump budget \
                 (`J` or `max_total_jumps`)"
            }
            TerminationCause::ZenoSuspected {
                detail: ZenoDetail::TotalJumps { .. },
                ..
            } => "raise `max_total_jumps` if this many jumps are intended",
            TerminationCause::CannotFlowOrJump { .. } => {
                "the state left C without entering D: check the flow set, the jump sets and \
                 their guards at this point"
            }
            TerminationCause::StoppedBySink => "the output sink stopped the run; see its error",
        }
    }
}

impl std::fmt::Display for Termination {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.cause {
            TerminationCause::HorizonT => write!(f, "reached the time horizon at {}", self.at),
            TerminationCause::HorizonJ => write!(f, "reached the jump horizon at {}", self.at),
            TerminationCause::ZenoSuspected {
                rule_name, detail, ..
            } => match detail {
                ZenoDetail::Rate { jumps, within } => write!(
                    f,
                    "Zeno behaviour suspected at {}: rule `{rule_name}` about to fire after \
                     {jumps} jumps within Δt = {}",
                    self.at,
                    // As every other number of the line: `0`, `1e-7`, not `0e0`.
                    crate::num::Num(*within)
                ),
                ZenoDetail::TotalJumps { limit } => write!(
                    f,
                    "stopped at {} before rule `{rule_name}` fired: {limit} jumps in total",
                    self.at
                ),
            },
            TerminationCause::CannotFlowOrJump {
                leaving, failed, ..
            } => {
                write!(f, "the solution can neither flow nor jump at {}: ", self.at)?;
                if *leaving {
                    write!(f, "the flow leaves C there")?;
                } else {
                    write!(f, "the state is outside C")?;
                }
                for (k, a) in failed.iter().enumerate() {
                    let sep = if k == 0 { " (failing: " } else { ", " };
                    let g = crate::num::Num(a.value);
                    match &a.text {
                        Some(text) => write!(f, "{sep}`{text}` with g = {g}")?,
                        None => write!(f, "{sep}atom {} of C with g = {g}", a.index)?,
                    }
                }
                if !failed.is_empty() {
                    write!(f, ")")?;
                }
                write!(f, " and it is in no jump set")
            }
            TerminationCause::StoppedBySink => write!(f, "stopped by the sink at {}", self.at),
        }
    }
}

/// One sample of a [`HybridArc`], borrowed from it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample<'a> {
    /// Hybrid time of the sample.
    pub at: HybridTime,
    /// Where it sits on the domain.
    pub kind: SampleKind,
    /// The state.
    pub x: &'a [f64],
}

/// A solution held in memory: samples `(t, j, x)` in hybrid-time order, the
/// jump records and the termination. It is also an [`ArcSink`], so the
/// engine can write into it directly (`engine::simulate_arc` does).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct HybridArc {
    dim: usize,
    times: Vec<HybridTime>,
    kinds: Vec<SampleKind>,
    states: Vec<f64>,
    jumps: Vec<JumpRecord>,
    rule_names: Vec<String>,
    termination: Option<Termination>,
    switches: Vec<SolverSwitch>,
}

impl HybridArc {
    /// An empty arc for states of dimension `dim` whose jump rules are named
    /// `rule_names` (in declaration order).
    pub fn new(dim: usize, rule_names: Vec<String>) -> Self {
        Self {
            dim,
            rule_names,
            ..Self::default()
        }
    }

    /// Dimension of the state.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.times.len()
    }

    /// `true` if the arc holds no sample.
    pub fn is_empty(&self) -> bool {
        self.times.is_empty()
    }

    /// The `i`-th sample, if any.
    pub fn sample_at(&self, i: usize) -> Option<Sample<'_>> {
        let at = *self.times.get(i)?;
        Some(Sample {
            at,
            kind: self.kinds[i],
            x: &self.states[i * self.dim..(i + 1) * self.dim],
        })
    }

    /// All samples in hybrid-time order.
    pub fn samples(&self) -> impl ExactSizeIterator<Item = Sample<'_>> + '_ {
        (0..self.len()).map(|i| Sample {
            at: self.times[i],
            kind: self.kinds[i],
            x: &self.states[i * self.dim..(i + 1) * self.dim],
        })
    }

    /// The last sample, if any.
    pub fn last(&self) -> Option<Sample<'_>> {
        self.len().checked_sub(1).and_then(|i| self.sample_at(i))
    }

    /// The jumps, in order.
    pub fn jumps(&self) -> &[JumpRecord] {
        &self.jumps
    }

    /// Names of the jump rules (index = [`JumpRecord::rule`]).
    pub fn rule_names(&self) -> &[String] {
        &self.rule_names
    }

    /// Name of the rule of a jump record, if known.
    pub fn rule_name(&self, rule: usize) -> Option<&str> {
        self.rule_names.get(rule).map(String::as_str)
    }

    /// Ordinary times of the jumps of rule `rule`, in order.
    pub fn jump_times(&self, rule: usize) -> Vec<f64> {
        self.jumps
            .iter()
            .filter(|r| r.rule == rule)
            .map(|r| r.at.t)
            .collect()
    }

    /// The integrator changes of the run (`Solver::Auto`), in order.
    pub fn solver_switches(&self) -> &[SolverSwitch] {
        &self.switches
    }

    /// Where and why the solution ended (set by `engine::simulate_arc`).
    pub fn termination(&self) -> Option<&Termination> {
        self.termination.as_ref()
    }

    /// Records the termination (done by `engine::simulate_arc`).
    pub fn set_termination(&mut self, termination: Termination) {
        self.termination = Some(termination);
    }

    /// The state at hybrid time `(t, j)`: exact at samples; between two
    /// samples of flow interval `j`, the cubic through the four samples of
    /// that interval nearest to `t` (fewer, and a lower degree, where the
    /// interval has fewer samples). The engine's default dense output
    /// samples each flow finely enough for this to follow the solution to
    /// about the solver's tolerance; on a coarse `dt_out` grid it is only as
    /// good as the grid. `None` if `(t, j)` is not in the arc's domain.
    pub fn value_at(&self, at: HybridTime) -> Option<Vec<f64>> {
        // Samples are sorted by (j, t): find the range of interval j.
        let lo = self.times.partition_point(|s| s.j < at.j);
        let hi = self.times.partition_point(|s| s.j <= at.j);
        let interval = &self.times[lo..hi];
        let first = interval.first()?;
        let last = interval.last()?;
        if !(first.t <= at.t && at.t <= last.t) {
            return None;
        }
        // First sample with t >= at.t.
        let k = lo + interval.partition_point(|s| s.t < at.t);
        let xk = &self.states[k * self.dim..(k + 1) * self.dim];
        if self.times[k].t == at.t || k == lo {
            return Some(xk.to_vec());
        }
        // Up to four samples around (k-1, k) with distinct times.
        let mut nodes: Vec<usize> = vec![k - 1, k];
        if k - 1 > lo && self.times[k - 2].t < self.times[k - 1].t {
            nodes.insert(0, k - 2);
        }
        if k + 1 < hi && self.times[k + 1].t > self.times[k].t {
            nodes.push(k + 1);
        }
        if nodes.len() == 3 && nodes[0] == k - 1 && k + 2 < hi {
            // Only a right neighbour so far: take a second one.
            if self.times[k + 2].t > self.times[k + 1].t {
                nodes.push(k + 2);
            }
        } else if nodes.len() == 3
            && nodes[0] == k - 2
            && k > lo + 2
            && self.times[k - 3].t < self.times[k - 2].t
        {
            nodes.insert(0, k - 3);
        }
        // Lagrange form.
        let ts: Vec<f64> = nodes.iter().map(|&i| self.times[i].t).collect();
        let mut out = vec![0.0; self.dim];
        for (a, &ia) in nodes.iter().enumerate() {
            let mut w = 1.0;
            for (b, &tb) in ts.iter().enumerate() {
                if a != b {
                    w *= (at.t - tb) / (ts[a] - tb);
                }
            }
            let xa = &self.states[ia * self.dim..(ia + 1) * self.dim];
            for (o, v) in out.iter_mut().zip(xa) {
                *o += w * v;
            }
        }
        Some(out)
    }
}

impl ArcSink for HybridArc {
    fn sample(&mut self, at: HybridTime, x: &[f64], kind: SampleKind) -> std::ops::ControlFlow<()> {
        if self.dim == 0 && self.times.is_empty() {
            self.dim = x.len();
        }
        self.times.push(at);
        self.kinds.push(kind);
        self.states.extend_from_slice(x);
        std::ops::ControlFlow::Continue(())
    }

    fn jump(
        &mut self,
        at: HybridTime,
        rule: usize,
        pre: &[f64],
        post: &[f64],
    ) -> std::ops::ControlFlow<()> {
        self.jumps.push(JumpRecord {
            at,
            rule,
            pre: pre.to_vec(),
            post: post.to_vec(),
        });
        std::ops::ControlFlow::Continue(())
    }

    fn finish(&mut self, termination: &Termination) {
        self.termination = Some(termination.clone());
    }

    fn solver_switch(&mut self, switch: &SolverSwitch) {
        self.switches.push(*switch);
    }
}
