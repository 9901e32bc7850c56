//! `models/consensus_estimation.hyb` (Perez-Salesa, Aldana-Lopez and
//! Sagues, event-triggered consensus for continuous-time distributed
//! estimation) run through the pipeline, with the paper's metrics computed
//! while the run streams (a run has 10⁵ noise redraws, so the arc is not
//! kept in memory):
//!
//! * the error `𝓔_s = (1/(N T_f)) Σ_i ∫ ‖x̂_i − x‖ dt` and the frequency
//!   `𝓕_s = Σ_i e_i / (N T_f)` of Sec. 5 (normalised: `𝓕_s · h`, 1 = an
//!   event at every step);
//! * the consensus error `max_i ‖z̄ − ẑ_i‖` of Prop. 1 (sup over `t ≥ T`);
//! * Prop. 2: the drift of `Σ_i Ẑ_i` across each event and
//!   `max_i ‖Ẑ_i − Z̄‖` at the end;
//! * the inter-event times of each node (≥ τ̲).
//!
//! [`Prop1Bound`] evaluates the constants K̄ and K̃ of the proof of Prop. 1
//! for the model's graph and gains.
//!
//! ```no_run
//! use hybsim_papers::experiments::consensus_estimation::ConsensusModel;
//! let model = ConsensusModel::read("models/consensus_estimation.hyb").unwrap();
//! let m = model.run(&["delta=25"], 1).unwrap();
//! println!("E = {}, F = {}", m.error, m.frequency_normalised);
//! ```

use std::ops::ControlFlow;
use std::path::Path;

use nalgebra::DMatrix;

use super::{ExperimentError, compile, scalar_parameter};
use hybsim::arc::{ArcSink, HybridTime, SampleKind};
use hybsim::engine::{HybridSystem, simulate};
use hybsim::lang::CompiledModel;
use hybsim::source::SourceFile;

/// The model file, relative to the repository root ([`crate::repo_path`]).
pub const MODEL_PATH: &str = "models/consensus_estimation.hyb";

/// The consensus-estimation model (source kept; compiled per setting).
#[derive(Debug, Clone)]
pub struct ConsensusModel {
    src: SourceFile,
}

/// The metrics of one run.
#[derive(Debug, Clone, PartialEq)]
pub struct RunMetrics {
    /// `𝓔_s`: time and node average of `‖x̂_i − x‖` over `[0, T_f]`.
    pub error: f64,
    /// `𝓕_s`: events per node per unit of time.
    pub frequency: f64,
    /// `𝓕_s · h`: 1 means an event at every simulation step.
    pub frequency_normalised: f64,
    /// Events of each node.
    pub events: Vec<u64>,
    /// Shortest time between two events of one node (∞ if none).
    pub min_inter_event: f64,
    /// `sup max_i ‖z̄ − ẑ_i‖` over `t ≥ t_after` (the `T` of Prop. 1).
    pub consensus_sup_after: f64,
    /// `sup max_i ‖z̄ − ẑ_i‖` over the whole run.
    pub consensus_sup: f64,
    /// `sup max_i ‖ẑ_i − ẑ_i(τ_k^i)‖` (the `‖u_i‖` of the proof of Prop. 1).
    pub deviation_sup: f64,
    /// Largest `‖Σ_i Ẑ_i(post) − Σ_i Ẑ_i(pre)‖_max / ‖Σ_i Ẑ_i‖_max` over the
    /// events (Prop. 2: 0 up to rounding).
    pub z_sum_drift: f64,
    /// `max_i ‖Ẑ_i − Z̄‖_F` at t = 0.
    pub z_disagreement_initial: f64,
    /// `max_i ‖Ẑ_i − Z̄‖_F` at the end of the run.
    pub z_disagreement_final: f64,
    /// Horizon `T_f` and step `h` of the run.
    pub horizon: f64,
    /// The simulation step `h` (= noise period).
    pub step: f64,
}

/// Output indices the metrics read.
#[derive(Debug, Clone, Copy)]
struct Outputs {
    err: usize,
    cons: usize,
    dev: usize,
    zdis: usize,
}

fn output_index(model: &CompiledModel, name: &str) -> Result<usize, ExperimentError> {
    for entry in &model.output_layout().entries {
        if let hybsim::layout::Entry::Field(f) = entry
            && f.name == name
        {
            return Ok(f.offset);
        }
    }
    Err(ExperimentError::MissingName {
        model: model.name().to_string(),
        name: name.to_string(),
    })
}

/// Streams a run and accumulates [`RunMetrics`].
struct MetricsSink<'a> {
    model: &'a CompiledModel,
    ix: Outputs,
    /// Rule index → node (0-based) for the `event[i]` rules.
    node_of_rule: Vec<Option<usize>>,
    t_after: f64,
    out: Vec<f64>,
    last: Option<(f64, f64)>,
    /// State components of the `Zh[i]` (all entries of all nodes).
    zh_states: Vec<usize>,
    /// Whether the next `PostJump` sample follows a rule that changes the
    /// outputs the suprema read (the noise redraw); events leave `ẑ` alone.
    eval_post: bool,
    integral: f64,
    cons_sup: f64,
    cons_sup_after: f64,
    dev_sup: f64,
    events: Vec<u64>,
    last_event: Vec<f64>,
    min_gap: f64,
    z_sum_drift: f64,
    z_dis: (f64, f64),
}

impl MetricsSink<'_> {
    fn eval(&mut self, at: HybridTime, x: &[f64]) {
        self.model.outputs(at, x, &mut self.out);
    }

    /// Trapezoid step of the error integral and the suprema, at a point
    /// whose outputs are in `self.out`.
    fn point(&mut self, t: f64) {
        let e = self.out[self.ix.err];
        if let Some((t0, e0)) = self.last
            && t > t0
        {
            self.integral += 0.5 * (e0 + e) * (t - t0);
        }
        self.last = Some((t, e));
        let c = self.out[self.ix.cons];
        self.cons_sup = self.cons_sup.max(c);
        if t >= self.t_after {
            self.cons_sup_after = self.cons_sup_after.max(c);
        }
        self.dev_sup = self.dev_sup.max(self.out[self.ix.dev]);
    }
}

impl ArcSink for MetricsSink<'_> {
    fn sample(&mut self, at: HybridTime, x: &[f64], kind: SampleKind) -> ControlFlow<()> {
        // One evaluation per flow interval end and one after each redraw:
        // the error is continuous, `ẑ` (hence `cons`) changes only at
        // redraws, and an event only lowers its node's deviation.
        let needed = match kind {
            SampleKind::PreJump => self.last.is_none_or(|(t0, _)| at.t > t0),
            SampleKind::PostJump => std::mem::take(&mut self.eval_post),
            _ => true,
        };
        if !needed {
            return ControlFlow::Continue(());
        }
        self.eval(at, x);
        if kind == SampleKind::Initial {
            self.z_dis.0 = self.out[self.ix.zdis];
        }
        if kind == SampleKind::Final {
            self.z_dis.1 = self.out[self.ix.zdis];
        }
        self.point(at.t);
        ControlFlow::Continue(())
    }

    fn jump(&mut self, at: HybridTime, rule: usize, pre: &[f64], post: &[f64]) -> ControlFlow<()> {
        let Some(node) = self.node_of_rule.get(rule).copied().flatten() else {
            self.eval_post = true;
            return ControlFlow::Continue(());
        };
        self.events[node] += 1;
        if self.last_event[node].is_finite() {
            self.min_gap = self.min_gap.min(at.t - self.last_event[node]);
        }
        self.last_event[node] = at.t;
        // Σ_i Ẑ_i entry by entry, before and after (summed in node order).
        let entries = self.zh_states.len() / self.events.len();
        let (mut diff, mut scale) = (0.0_f64, 0.0_f64);
        for e in 0..entries {
            let (mut a, mut b) = (0.0, 0.0);
            for k in (e..self.zh_states.len()).step_by(entries) {
                a += pre[self.zh_states[k]];
                b += post[self.zh_states[k]];
            }
            diff = diff.max((b - a).abs());
            scale = scale.max(a.abs());
        }
        if scale > 0.0 {
            self.z_sum_drift = self.z_sum_drift.max(diff / scale);
        }
        ControlFlow::Continue(())
    }
}

impl ConsensusModel {
    /// Reads the model file.
    ///
    /// # Errors
    /// The file cannot be read.
    pub fn read(path: impl AsRef<Path>) -> std::io::Result<Self> {
        Ok(Self {
            src: SourceFile::read(path)?,
        })
    }

    /// The model source.
    pub fn source(&self) -> &SourceFile {
        &self.src
    }

    /// Compiles the model with overrides (`["delta=50", "ideal=1"]`).
    ///
    /// # Errors
    /// An override does not parse or the model does not compile.
    pub fn compile<S: AsRef<str>>(&self, sets: &[S]) -> Result<CompiledModel, ExperimentError> {
        compile(&self.src, sets)
    }

    /// Runs the model with overrides `sets` and seed `seed` (as
    /// `hybsim run --seed`), measuring the consensus supremum after
    /// `t = 1` (see [`Self::run_compiled`]).
    ///
    /// # Errors
    /// As [`Self::compile`], or the simulation fails.
    pub fn run<S: AsRef<str>>(&self, sets: &[S], seed: u64) -> Result<RunMetrics, ExperimentError> {
        self.run_compiled(&self.compile(sets)?, seed, 1.0)
    }

    /// Runs a compiled model with seed `seed`; `t_after` is the `T` after
    /// which the consensus error is measured.
    ///
    /// # Errors
    /// The model lacks an output the metrics need, or the simulation fails.
    pub fn run_compiled(
        &self,
        model: &CompiledModel,
        seed: u64,
        t_after: f64,
    ) -> Result<RunMetrics, ExperimentError> {
        let ix = Outputs {
            err: output_index(model, "err")?,
            cons: output_index(model, "cons")?,
            dev: output_index(model, "dev")?,
            zdis: output_index(model, "Zdis")?,
        };
        let n_nodes = scalar_parameter(model, "N")? as usize;
        let node_of_rule: Vec<Option<usize>> = model
            .rule_names()
            .iter()
            .map(|name| {
                let k = name.strip_prefix("event[")?.strip_suffix(']')?;
                k.parse::<usize>().ok().and_then(|k| k.checked_sub(1))
            })
            .collect();
        let names = model.state_names();
        let zh_states: Vec<usize> = (1..=n_nodes)
            .flat_map(|i| {
                let prefix = format!("Zh[{i}][");
                names
                    .iter()
                    .enumerate()
                    .filter(move |(_, name)| name.starts_with(&prefix))
                    .map(|(k, _)| k)
                    .collect::<Vec<_>>()
            })
            .collect();
        if zh_states.is_empty() || !zh_states.len().is_multiple_of(n_nodes) {
            return Err(ExperimentError::MissingName {
                model: model.name().to_string(),
                name: "Zh".into(),
            });
        }
        let settings = model.settings();
        let mut sink = MetricsSink {
            model,
            ix,
            node_of_rule,
            t_after,
            out: vec![0.0; model.output_dim()],
            last: None,
            zh_states,
            eval_post: false,
            integral: 0.0,
            cons_sup: 0.0,
            cons_sup_after: 0.0,
            dev_sup: 0.0,
            events: vec![0; n_nodes],
            last_event: vec![f64::NEG_INFINITY; n_nodes],
            min_gap: f64::INFINITY,
            z_sum_drift: 0.0,
            z_dis: (f64::NAN, f64::NAN),
        };
        let (x0, mut rng) = model.start(seed);
        let term = simulate(model, &x0, &settings, &mut rng, &mut sink).map_err(|error| {
            ExperimentError::Simulation {
                model: model.name().to_string(),
                error,
            }
        })?;
        let horizon = term.at.t;
        let step = scalar_parameter(model, "h")?;
        let total: u64 = sink.events.iter().sum();
        let frequency = total as f64 / (n_nodes as f64 * horizon);
        Ok(RunMetrics {
            error: sink.integral / horizon,
            frequency,
            frequency_normalised: frequency * step,
            events: sink.events,
            min_inter_event: sink.min_gap,
            consensus_sup_after: sink.cons_sup_after,
            consensus_sup: sink.cons_sup,
            deviation_sup: sink.dev_sup,
            z_sum_drift: sink.z_sum_drift,
            z_disagreement_initial: sink.z_dis.0,
            z_disagreement_final: sink.z_dis.1,
            horizon,
            step,
        })
    }
}

/// The constants of the proof of Prop. 1 for a graph, gains and threshold:
/// for `t ≥ T`, `‖s̃(t)‖ ≤ K̃` and `‖e(t)‖ ≤ K̄`, hence
/// `‖z̄ − ẑ_i‖ ≤ ‖e‖ + ‖s̃_i‖ ≤ K̄ + K̃`.
#[derive(Debug, Clone, PartialEq)]
pub struct Prop1Bound {
    /// Algebraic connectivity λ₂ of the graph's Laplacian.
    pub lambda2: f64,
    /// `σ_max(1ᵀA_G/N ⊗ I_n)`.
    pub sigma_mean: f64,
    /// `σ_max(H A_G ⊗ I_n)`, `H = I − 11ᵀ/N`.
    pub sigma_h: f64,
    /// `L' = sup_t ‖(H ⊗ I_n)(ż + κ₁z)‖` (noise-free measurements).
    pub l_prime: f64,
    /// `K̄ = e^{−κ₁T}‖e(0)‖ + (κ₂/κ₁) σ_mean √N max δ` (with `e(0) = 0`).
    pub k_bar: f64,
    /// `K̃ = (L' + κ₂ σ_h √N max δ) / (κ₂ λ₂)`.
    pub k_tilde: f64,
}

impl Prop1Bound {
    /// `K̄ + K̃`, the bound on `‖z̄(t) − ẑ_i(t)‖` for `t ≥ T`.
    pub fn k(&self) -> f64 {
        self.k_bar + self.k_tilde
    }

    /// Evaluates the constants for a compiled model: its graph `G`, `k1`,
    /// `k2`, `delta`, and `L'` as the largest value of the output `Lp` on a
    /// grid of `samples` points over `[0, T_f]` (`Lp` depends on `t` only).
    /// `e(0) = −p̄(0) = 0` because the model starts from `p_i(0) = 0`.
    ///
    /// # Errors
    /// A parameter or output is missing.
    pub fn of_model(model: &CompiledModel, samples: usize) -> Result<Self, ExperimentError> {
        let k1 = scalar_parameter(model, "k1")?;
        let k2 = scalar_parameter(model, "k2")?;
        let delta = scalar_parameter(model, "delta")?;
        let tf = scalar_parameter(model, "Tf")?;
        let a = model
            .parameter("G")
            .filter(|g| g.is_square() && g.nrows() > 0)
            .ok_or_else(|| ExperimentError::MissingParameter {
                model: model.name().to_string(),
                name: "G".into(),
            })?;
        let n = a.nrows();
        let nf = n as f64;
        let degrees = DMatrix::from_fn(n, n, |i, j| if i == j { a.row(i).sum() } else { 0.0 });
        let lap = &degrees - &a;
        let mut eig: Vec<f64> = lap.symmetric_eigenvalues().iter().copied().collect();
        eig.sort_by(f64::total_cmp);
        let lambda2 = eig.get(1).copied().unwrap_or(0.0);
        // σ_max(M ⊗ I_n) = σ_max(M).
        let ones = DMatrix::from_element(1, n, 1.0);
        let sigma_mean = (&ones * &a / nf).norm();
        let h = DMatrix::identity(n, n) - DMatrix::from_element(n, n, 1.0 / nf);
        let sigma_h = (&h * &a)
            .singular_values()
            .iter()
            .copied()
            .fold(0.0, f64::max);
        let lp = output_index(model, "Lp")?;
        let x = vec![0.0; model.state_dim()];
        let mut out = vec![0.0; model.output_dim()];
        let mut l_prime = 0.0_f64;
        for k in 0..=samples {
            let t = tf * k as f64 / samples.max(1) as f64;
            model.outputs(HybridTime::new(t, 0), &x, &mut out);
            l_prime = l_prime.max(out[lp]);
        }
        let sqrt_n = nf.sqrt();
        let k_bar = k2 / k1 * sigma_mean * sqrt_n * delta;
        let k_tilde = (l_prime + k2 * sigma_h * sqrt_n * delta) / (k2 * lambda2);
        Ok(Self {
            lambda2,
            sigma_mean,
            sigma_h,
            l_prime,
            k_bar,
            k_tilde,
        })
    }
}
