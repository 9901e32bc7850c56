//! A model's `metric` declarations compiled into two register programs and
//! reduced while a run streams ([`MetricSink`], an [`ArcSink`] that keeps
//! no arc).
//!
//! The *sample program* evaluates, at each sample, every reduction's
//! argument and window in the property frame `[x (n) | j | x⁺ (n) | t]`
//! (see [`crate::check::property`]); the *metric program* combines the
//! reduced values (registers `base..base + r` of its frame, `t` = the final
//! time) into the metrics. Integrals and means are computed on the path of
//! each integrator step ([`ArcSink::flow_piece`]: the solver's interpolant,
//! or the exact solution), by adaptive Gauss–Legendre quadrature, with the
//! times a window opens or closes inside a step found by bisection
//! (`path.rs`), so neither depends on the sample grid; where the flow has
//! no path between its steps (Euler–Maruyama) or the arc is replayed from
//! memory, by the trapezoid rule between consecutive samples in the window.
//! Extremes and finals read the samples, and where a window opens or closes
//! inside a step, the state at that boundary. `period` keeps the last values at the jumps
//! (a bounded buffer) and detects their period when the run ends. A sample
//! at the hybrid time of the previous one, or after jumps that write no
//! component the sample program reads (a noise redraw, for metrics of the
//! plant), reuses the previous values instead of running the program.

mod path;

use std::collections::VecDeque;
use std::ops::ControlFlow;

use super::program::{Frame, Program};
use super::with_regs;
use crate::analysis::periodicity::{PeriodOutcome, PeriodSettings, detect_period_scalar};
use crate::arc::{ArcSink, FlowPiece, HybridTime, SampleKind, Termination};
use crate::check::dag::{Dag, Node};
use crate::check::metric::{CheckedMetrics, ReductionKind};

#[derive(Debug, Clone)]
struct Spec {
    kind: ReductionKind,
    /// Output of the sample program holding the argument.
    arg: Option<usize>,
    /// Output of the sample program holding the window.
    window: Option<usize>,
}

/// Reductions that read a flow's path between samples, grouped by window:
/// one search for the window's boundaries serves the group.
#[derive(Debug, Clone)]
struct PathGroup {
    /// Output of the sample program holding the window.
    window: Option<usize>,
    /// Integrals and means (indices into the specs).
    integrals: Vec<usize>,
    /// Windowed extremes and finals, fed the state where the window opens
    /// or closes inside a step.
    edges: Vec<usize>,
}

/// A model's compiled metrics. Build a [`MetricSink`] per run with
/// [`Metrics::sink`].
#[derive(Debug, Clone)]
pub struct Metrics {
    names: Vec<String>,
    specs: Vec<Spec>,
    /// Count reductions per rule index.
    by_rule: Vec<Vec<usize>>,
    /// Reductions fed at every jump (`period`).
    at_jumps: Vec<usize>,
    sample: Program,
    sample_regs: usize,
    n: usize,
    /// The state components the sample program reads in its frame's x and
    /// x⁺ parts: copied into its registers at each evaluation (often a few
    /// of a large state). Both empty when the program is compiled over x
    /// alone (`on_x`).
    reads_pre: Vec<usize>,
    reads_post: Vec<usize>,
    /// Whether the sample program's frame is the state itself (it reads no
    /// x⁺ component and not the frame's j): it then runs on x where it is.
    on_x: bool,
    combine: Program,
    combine_regs: usize,
    base: usize,
    /// Per rule: whether a jump by it leaves the sample program's values
    /// unchanged (it writes no component the program reads, and the program
    /// reads neither j nor a random draw), so the post-jump sample reuses the
    /// pre-jump values.
    jump_keeps_values: Vec<bool>,
    /// Whether two samples at the same hybrid time have the same values (the
    /// program draws nothing at random).
    deterministic: bool,
    /// Reductions computed on the steps' paths; empty when none is (or the
    /// program draws at random: values between samples would draw too).
    path_groups: Vec<PathGroup>,
}

impl Metrics {
    /// Compiles the checked metrics of a model with `n` state components
    /// and jump rules writing the components `writes[r]`.
    pub(crate) fn compile(dag: &Dag, m: &CheckedMetrics, n: usize, writes: &[Vec<usize>]) -> Self {
        let rules = writes.len();
        let mut outs = Vec::new();
        let mut specs = Vec::new();
        let mut by_rule = vec![Vec::new(); rules];
        for (k, r) in m.reductions.iter().enumerate() {
            let mut slot = |node: Option<_>| {
                node.map(|node| {
                    outs.push(node);
                    outs.len() - 1
                })
            };
            let arg = slot(r.arg);
            let window = slot(r.window);
            for &rule in &r.rules {
                if let Some(list) = by_rule.get_mut(rule) {
                    list.push(k);
                }
            }
            specs.push(Spec {
                kind: r.kind,
                arg,
                window,
            });
        }
        let at_jumps = (0..specs.len())
            .filter(|&k| specs[k].kind == ReductionKind::Period)
            .collect();
        // What the sample program reads in its frame [x (n) | j | x⁺ (n) | t]
        // (x⁺ = x at a sample).
        let reached = dag.reachable(&outs);
        let mut reads = vec![false; n];
        let (mut reads_pre, mut reads_post) = (Vec::new(), Vec::new());
        let (mut reads_j, mut frame_j, mut draws) = (false, false, false);
        for (id, _) in reached.iter().enumerate().filter(|&(_, &r)| r) {
            match dag.node(id as crate::check::dag::NodeId) {
                Node::State(k) if (k as usize) < n => {
                    reads[k as usize] = true;
                    reads_pre.push(k as usize);
                }
                Node::State(k) if k as usize == n => {
                    reads_j = true;
                    frame_j = true;
                }
                Node::State(k) => {
                    reads[k as usize - n - 1] = true;
                    reads_post.push(k as usize - n - 1);
                }
                Node::Jumps => reads_j = true,
                Node::Rand(..) => draws = true,
                _ => {}
            }
        }
        reads_pre.sort_unstable();
        reads_post.sort_unstable();
        // `eval` fills x⁺ with x and the frame's j with j: a program reading
        // neither is the same program over x, t and j (the state's frame),
        // and runs on x without a copy of the components it reads.
        let on_x = reads_post.is_empty() && !frame_j;
        let frame = if on_x {
            reads_pre.clear();
            Frame { n, m: 0 }
        } else {
            Frame { n: 2 * n + 1, m: 0 }
        };
        let sample = Program::compile(dag, frame, &outs);
        let jump_keeps_values = writes
            .iter()
            .map(|w| {
                !reads_j && !draws && w.iter().all(|&k| !reads.get(k).copied().unwrap_or(true))
            })
            .collect();
        let sample_regs = sample.nregs.max(frame.fixed());
        let path_groups = if draws {
            Vec::new()
        } else {
            path_groups(&specs)
        };
        let cframe = Frame {
            n: m.base + m.reductions.len(),
            m: 0,
        };
        let nodes: Vec<_> = m.metrics.iter().map(|x| x.node).collect();
        let combine = Program::compile(dag, cframe, &nodes);
        let combine_regs = combine.nregs.max(cframe.fixed());
        Self {
            names: m.metrics.iter().map(|x| x.name.clone()).collect(),
            specs,
            by_rule,
            at_jumps,
            sample,
            sample_regs,
            n,
            reads_pre,
            reads_post,
            on_x,
            combine,
            combine_regs,
            base: m.base,
            jump_keeps_values,
            deterministic: !draws,
            path_groups,
        }
    }

    /// The program evaluated at every sample (compiled to machine code
    /// with the model's programs).
    pub(super) fn sample(&self) -> &Program {
        &self.sample
    }

    /// The metrics' names in declaration order (`rate[2]` for family members).
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// True if the model declares no metric.
    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }

    /// A sink that reduces one run.
    pub fn sink(&self) -> MetricSink<'_> {
        let specs = &self.specs;
        MetricSink {
            m: self,
            acc: specs.iter().map(|s| Acc::new(s.kind)).collect(),
            prev: None,
            kept_until: None,
            vals: vec![0.0; self.sample.outs.len()],
            prev_vals: vec![0.0; self.sample.outs.len()],
            end: None,
            covered: None,
            scratch: path::Scratch::default(),
            piece_start: Vec::new(),
            piece_end: Vec::new(),
            piece_end_x: Vec::new(),
            piece_end_at: None,
        }
    }

    /// Evaluates the sample program at `(at, x)` into `vals`.
    fn eval(&self, at: HybridTime, x: &[f64], vals: &mut [f64]) {
        if vals.is_empty() {
            return;
        }
        let n = self.n;
        with_regs(self.sample_regs, |regs| {
            if self.on_x {
                self.sample.run_at(regs, at, x, None);
            } else {
                for &k in &self.reads_pre {
                    regs[k] = x[k];
                }
                regs[n] = at.j as f64;
                for &k in &self.reads_post {
                    regs[n + 1 + k] = x[k];
                }
                regs[2 * n + 1] = at.t;
                regs[2 * n + 2] = at.j as f64;
                self.sample.run(regs, None);
            }
            for (v, &o) in vals.iter_mut().zip(&self.sample.outs) {
                *v = regs[o as usize];
            }
        })
    }
}

/// The integrals and means, and the windowed extremes and finals, grouped by
/// window (in order of first appearance).
fn path_groups(specs: &[Spec]) -> Vec<PathGroup> {
    let mut groups: Vec<PathGroup> = Vec::new();
    for (k, spec) in specs.iter().enumerate() {
        let integral = matches!(spec.kind, ReductionKind::Integral | ReductionKind::Mean);
        let edge = spec.window.is_some()
            && matches!(
                spec.kind,
                ReductionKind::Max | ReductionKind::Min | ReductionKind::Final
            );
        if !integral && !edge {
            continue;
        }
        let g = match groups.iter().position(|g| g.window == spec.window) {
            Some(g) => g,
            None => {
                groups.push(PathGroup {
                    window: spec.window,
                    integrals: Vec::new(),
                    edges: Vec::new(),
                });
                groups.len() - 1
            }
        };
        if integral {
            groups[g].integrals.push(k);
        } else {
            groups[g].edges.push(k);
        }
    }
    groups
}

/// The detector `period` uses: periods up to 500 steps, the last 4
/// periods repeating the one before to 1e-9 (absolute and relative).
fn period_settings() -> PeriodSettings {
    PeriodSettings::default()
}

/// Values `period` keeps: enough for the longest period searched with its
/// repeats, so the verdict is that of the whole sequence.
fn period_capacity() -> usize {
    let s = period_settings();
    s.max_period * (s.repeats + 1)
}

/// One reduction's running value.
#[derive(Debug, Clone)]
enum Acc {
    Count(u64),
    Integral(f64),
    Mean {
        num: f64,
        den: f64,
    },
    Extreme(Option<f64>),
    /// The value at the latest point in the window so far (points reach it
    /// out of order: a window's boundary inside a step before the step's
    /// samples).
    Final {
        value: f64,
        at: Option<HybridTime>,
    },
    /// The last values at the jumps (oldest first).
    Period(VecDeque<f64>),
}

impl Acc {
    fn new(kind: ReductionKind) -> Self {
        match kind {
            ReductionKind::Count => Acc::Count(0),
            ReductionKind::Integral => Acc::Integral(0.0),
            ReductionKind::Mean => Acc::Mean { num: 0.0, den: 0.0 },
            ReductionKind::Max | ReductionKind::Min => Acc::Extreme(None),
            ReductionKind::Final => Acc::Final {
                value: f64::NAN,
                at: None,
            },
            ReductionKind::Period => Acc::Period(VecDeque::new()),
        }
    }

    /// A point `(at, value)` inside the window, for an extreme or a final.
    fn offer(&mut self, kind: ReductionKind, at: HybridTime, value: f64) {
        match self {
            Acc::Extreme(best) => {
                let better = match *best {
                    None => true,
                    Some(b) if kind == ReductionKind::Max => value > b,
                    Some(b) => value < b,
                };
                if better || value.is_nan() {
                    *best = Some(value);
                }
            }
            Acc::Final { value: v, at: a } if a.is_none_or(|a| at >= a) => {
                *v = value;
                *a = Some(at);
            }
            _ => {}
        }
    }

    fn value(&self) -> f64 {
        match self {
            Acc::Count(c) => *c as f64,
            Acc::Integral(s) => *s,
            Acc::Mean { num, den } => {
                if *den > 0.0 {
                    num / den
                } else {
                    f64::NAN
                }
            }
            Acc::Extreme(v) => v.unwrap_or(f64::NAN),
            Acc::Final { value, .. } => *value,
            Acc::Period(values) => {
                let values: Vec<f64> = values.iter().copied().collect();
                match detect_period_scalar(&values, &period_settings()) {
                    PeriodOutcome::Periodic(orbit) => orbit.period as f64,
                    _ => f64::NAN,
                }
            }
        }
    }
}

/// Reduces one run into the model's metrics as it streams; keeps only the
/// previous sample's evaluated values. Read the result with
/// [`MetricSink::values`] after the run (also valid for a run that ended
/// early: the metrics of what was computed).
#[derive(Debug)]
pub struct MetricSink<'a> {
    m: &'a Metrics,
    acc: Vec<Acc>,
    prev: Option<HybridTime>,
    /// The hybrid time up to which the previous sample's values still hold:
    /// its own, or after the jumps since it that left them unchanged.
    kept_until: Option<HybridTime>,
    vals: Vec<f64>,
    prev_vals: Vec<f64>,
    end: Option<HybridTime>,
    /// The flow `(j, from, to)` whose integrals the steps' paths have given
    /// (contiguous pieces): samples inside it add no trapezoid.
    covered: Option<(u64, f64, f64)>,
    scratch: path::Scratch,
    /// The values at the last step's end (`piece_end_at`, state
    /// `piece_end_x`): the next step's start, and the sample's there when
    /// its state is that one.
    piece_end: Vec<f64>,
    piece_end_x: Vec<f64>,
    piece_end_at: Option<HybridTime>,
    piece_start: Vec<f64>,
}

impl MetricSink<'_> {
    /// The metrics' values, in the order of [`Metrics::names`]. A mean over
    /// no flow time, or a max/min/final over no sample, is NaN.
    pub fn values(&self) -> Vec<f64> {
        let m = self.m;
        if m.names.is_empty() {
            return Vec::new();
        }
        let t_end = self.end.map_or(f64::NAN, |e| e.t);
        let j_end = self.end.map_or(f64::NAN, |e| e.j as f64);
        with_regs(m.combine_regs, |regs| {
            regs[..m.base].fill(0.0);
            for (k, a) in self.acc.iter().enumerate() {
                regs[m.base + k] = a.value();
            }
            regs[m.base + self.acc.len()] = t_end;
            regs[m.base + self.acc.len() + 1] = j_end;
            m.combine.run(regs, None);
            m.combine.outs.iter().map(|&o| regs[o as usize]).collect()
        })
    }

    /// The metrics with their names.
    pub fn named_values(&self) -> Vec<(String, f64)> {
        self.m.names.iter().cloned().zip(self.values()).collect()
    }
}

impl ArcSink for MetricSink<'_> {
    fn sample(&mut self, at: HybridTime, x: &[f64], _kind: SampleKind) -> ControlFlow<()> {
        // A solution has one state per hybrid time: a sample where the
        // previous one's values still hold needs no evaluation, and changes
        // no reduction (no flow time since that sample, whose values an
        // extreme or a final has already seen): the post-jump sample of a
        // jump that leaves them unchanged.
        if self.m.deterministic && self.kept_until == Some(at) {
            self.prev = Some(at);
            self.end = Some(at);
            return ControlFlow::Continue(());
        }
        if self.piece_end_at == Some(at) && self.piece_end_x == x {
            self.vals.copy_from_slice(&self.piece_end);
        } else {
            self.m.eval(at, x, &mut self.vals);
        }
        let holds = |vals: &[f64], w: Option<usize>| w.is_none_or(|w| vals[w] != 0.0);
        // Flow interval since the previous sample (same j), unless the
        // steps' paths have integrated it.
        let dt = match self.prev {
            Some(p) if p.j == at.j && at.t > p.t => {
                let on_path = self
                    .covered
                    .is_some_and(|(j, from, to)| j == at.j && from <= p.t && at.t <= to);
                if on_path { 0.0 } else { at.t - p.t }
            }
            _ => 0.0,
        };
        for (spec, acc) in self.m.specs.iter().zip(&mut self.acc) {
            let now_in = holds(&self.vals, spec.window);
            let value = spec.arg.map_or(0.0, |a| self.vals[a]);
            match acc {
                Acc::Count(_) => {}
                // A flow segment counts if both its samples are in the window.
                Acc::Integral(s) | Acc::Mean { num: s, .. }
                    if dt > 0.0 && now_in && holds(&self.prev_vals, spec.window) =>
                {
                    let before = spec.arg.map_or(0.0, |a| self.prev_vals[a]);
                    *s += 0.5 * dt * (before + value);
                    if let Acc::Mean { den, .. } = acc {
                        *den += dt;
                    }
                }
                Acc::Integral(_) | Acc::Mean { .. } => {}
                Acc::Extreme(_) | Acc::Final { .. } if now_in => acc.offer(spec.kind, at, value),
                Acc::Extreme(_) | Acc::Final { .. } => {}
                Acc::Period(_) => {}
            }
        }
        std::mem::swap(&mut self.vals, &mut self.prev_vals);
        self.prev = Some(at);
        self.kept_until = Some(at);
        self.end = Some(at);
        ControlFlow::Continue(())
    }

    fn jump(&mut self, at: HybridTime, rule: usize, pre: &[f64], _post: &[f64]) -> ControlFlow<()> {
        // The rules of one simultaneous jump all start from `at`.
        let post = HybridTime::new(at.t, at.j + 1);
        let from_kept = self.kept_until == Some(at) || self.kept_until == Some(post);
        let keeps = self.m.jump_keeps_values.get(rule).copied().unwrap_or(false);
        self.kept_until = (from_kept && keeps).then_some(post);
        let list = self.m.by_rule.get(rule).map_or(&[][..], Vec::as_slice);
        if list.is_empty() && self.m.at_jumps.is_empty() {
            return ControlFlow::Continue(());
        }
        // The window at the pre-jump point: the previous sample's values
        // when it is that point.
        let vals = if self.prev == Some(at) {
            &self.prev_vals
        } else {
            self.m.eval(at, pre, &mut self.vals);
            &self.vals
        };
        for &k in list {
            let w = self.m.specs[k].window;
            if w.is_none_or(|w| vals[w] != 0.0)
                && let Acc::Count(c) = &mut self.acc[k]
            {
                *c += 1;
            }
        }
        for &k in &self.m.at_jumps {
            let spec = &self.m.specs[k];
            if spec.window.is_none_or(|w| vals[w] != 0.0)
                && let (Acc::Period(kept), Some(a)) = (&mut self.acc[k], spec.arg)
            {
                if kept.len() == period_capacity() {
                    kept.pop_front();
                }
                kept.push_back(vals[a]);
            }
        }
        ControlFlow::Continue(())
    }

    fn finish(&mut self, _termination: &Termination) {}

    fn wants_flow_pieces(&self) -> bool {
        !self.m.path_groups.is_empty()
    }

    fn flow_piece(&mut self, piece: &mut FlowPiece<'_>) {
        // An empty (or NaN) step adds nothing.
        if piece.t1.partial_cmp(&piece.t0) != Some(std::cmp::Ordering::Greater) {
            return;
        }
        self.covered = match self.covered {
            // Contiguous with the pieces before it in the same flow interval.
            Some((j, from, to))
                if j == piece.j && (piece.t0 - to).abs() <= 1e-12 * to.abs().max(1.0) =>
            {
                Some((j, from, piece.t1))
            }
            _ => Some((piece.j, piece.t0, piece.t1)),
        };
        let t0 = HybridTime::new(piece.t0, piece.j);
        let start = if self.prev == Some(t0) {
            Some(&self.prev_vals[..])
        } else if self.piece_end_at == Some(t0) {
            std::mem::swap(&mut self.piece_start, &mut self.piece_end);
            Some(&self.piece_start[..])
        } else {
            None
        };
        let ends = path::Ends {
            start,
            end: &mut self.piece_end,
            end_x: &mut self.piece_end_x,
        };
        path::integrate_piece(self.m, &mut self.acc, &mut self.scratch, piece, ends);
        self.piece_end_at = Some(HybridTime::new(piece.t1, piece.j));
    }
}
