//! `models/variance_triggering.hyb` (Trimpe and D'Andrea, event-based state
//! estimation with variance-based triggering) run through the pipeline, and
//! the paper's Fig. 4 experiment: a δ sweep whose simulated periods are set
//! against Algorithm 1 as implemented in
//! [`crate::analysis::variance_trigger`], and the transmit sequences of
//! three δ drawn like Fig. 4.
//!
//! The model computes `p̄` with its own `dare` and the filter in the form
//! (13)–(17); that module computes `p̄` in closed form and iterates (1)
//! directly. The two agree to rounding, which is what the reproduction
//! tests compare with stated tolerances.
//!
//! ```no_run
//! use hybsim_papers::analysis::variance_trigger::VarianceIteration;
//! use hybsim_papers::experiments::variance_trigger::{Noise, VarianceTriggerModel};
//! let model = VarianceTriggerModel::read("models/variance_triggering.hyb").unwrap();
//! let it = VarianceIteration::new(1.2, 1.0, 1.0, 1.0, 3.0).unwrap(); // Example 1
//! let run = model.run(&it, None, 100, Noise::Off).unwrap();
//! assert_eq!(run.p().len(), 101);
//! ```

use std::path::Path;

use rayon::prelude::*;

use super::{ExperimentError, StepTable, compile, scalar_parameter, simulate, simulate_seeded};
use crate::analysis::variance_trigger::{SweepRow, VarianceIteration, refined_delta_grid};
use hybsim::analysis::periodicity::PeriodSettings;
use hybsim::arc::HybridArc;
use hybsim::lang::CompiledModel;
use hybsim::sinks::plot::{Figure, Panel, Series};
use hybsim::source::SourceFile;

/// The model file, relative to the repository root ([`crate::repo_path`]).
pub const MODEL_PATH: &str = "models/variance_triggering.hyb";

/// The variance-triggering model (source kept; compiled per run with
/// overrides).
#[derive(Debug, Clone)]
pub struct VarianceTriggerModel {
    src: SourceFile,
}

/// One run of the model: the resolved `p̄` and every state and output per
/// step (`p`, `gamma`, `y`, `K`, `xu`, `pu`, `e`, `eu`, …).
#[derive(Debug, Clone, PartialEq)]
pub struct VarianceRun {
    /// `p̄` as the model computed it (`dare` in the file).
    pub p_bar: f64,
    /// The per-step table.
    pub table: StepTable,
}

impl VarianceRun {
    /// A column that the model defines (its absence is a bug of the model
    /// file, reported when the run is made).
    fn col(&self, name: &str) -> &[f64] {
        self.table.column(name).unwrap_or(&[])
    }
    /// The prediction variance `p(0), …, p(steps)`.
    pub fn p(&self) -> &[f64] {
        self.col("p")
    }
    /// The transmit decision `γ(k)` (0 or 1) of (19).
    pub fn gamma(&self) -> &[f64] {
        self.col("gamma")
    }
    /// The updated variance `p(k|k)` of (17).
    pub fn p_updated(&self) -> &[f64] {
        self.col("pu")
    }
    /// The prediction error `x(k) − x̃(k|k−1)` (variance `p(k)`).
    pub fn prediction_error(&self) -> &[f64] {
        self.col("e")
    }
    /// The estimation error `x(k) − x̃(k|k)` (variance `p(k|k)`).
    pub fn update_error(&self) -> &[f64] {
        self.col("eu")
    }
}

/// The noise of a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Noise {
    /// `noise_scale = 0`: `v = w = 0` and `x(0) = x0`, so the unstable
    /// process stays at 0 and long runs stay finite. `p(k)` and `γ(k)` are
    /// the same as with noise: they do not depend on the data.
    Off,
    /// The model's noise, drawn from this seed.
    Seeded(u64),
}

/// Columns every run must have (checked after each run).
const REQUIRED: [&str; 5] = ["p", "gamma", "pu", "e", "eu"];

impl VarianceTriggerModel {
    /// The model from a source file.
    pub fn new(src: SourceFile) -> Self {
        Self { src }
    }

    /// Reads the model file.
    pub fn read(path: impl AsRef<Path>) -> std::io::Result<Self> {
        SourceFile::read(path).map(Self::new)
    }

    /// The source.
    pub fn source(&self) -> &SourceFile {
        &self.src
    }

    /// The overrides for the parameters of `it`, `p0` (`None`: the model's
    /// default `p0 = p̄`), `steps` steps and `noise`. Numbers are formatted
    /// with `{}` (shortest round-trip), so the model sees exactly the same
    /// `f64`.
    pub fn overrides(
        it: &VarianceIteration,
        p0: Option<f64>,
        steps: usize,
        noise: Noise,
    ) -> Vec<String> {
        let mut sets = vec![
            format!("a={}", it.a()),
            format!("c={}", it.c()),
            format!("q={}", it.q()),
            format!("r={}", it.r()),
            format!("delta={}", it.delta()),
            format!("T={}", steps as f64 + 0.5),
            format!("J={steps}"),
        ];
        if let Some(p0) = p0 {
            sets.push(format!("p0={p0}"));
        }
        match noise {
            Noise::Off => sets.push("noise_scale=0".into()),
            Noise::Seeded(seed) => sets.push(format!("seed={seed}")),
        }
        sets
    }

    /// Compiles the model for `it`, `p0`, `steps`, `noise` (see
    /// [`Self::overrides`]).
    pub fn compile(
        &self,
        it: &VarianceIteration,
        p0: Option<f64>,
        steps: usize,
        noise: Noise,
    ) -> Result<CompiledModel, ExperimentError> {
        compile(&self.src, &Self::overrides(it, p0, steps, noise))
    }

    /// Runs `steps` steps with the parameters of `it` from `p0` (`None`:
    /// `p̄`).
    pub fn run(
        &self,
        it: &VarianceIteration,
        p0: Option<f64>,
        steps: usize,
        noise: Noise,
    ) -> Result<VarianceRun, ExperimentError> {
        let model = self.compile(it, p0, steps, noise)?;
        Self::read_run(&model, &simulate(&model)?)
    }

    /// Runs with noise for each seed of `seeds` (one compilation; runs in
    /// parallel, results in seed order): an ensemble for statistics of the
    /// estimation error.
    pub fn ensemble(
        &self,
        it: &VarianceIteration,
        p0: Option<f64>,
        steps: usize,
        seeds: std::ops::Range<u64>,
    ) -> Result<Vec<VarianceRun>, ExperimentError> {
        let model = self.compile(it, p0, steps, Noise::Seeded(seeds.start))?;
        seeds
            .into_par_iter()
            .map(|seed| Self::read_run(&model, &simulate_seeded(&model, seed)?))
            .collect()
    }

    fn read_run(model: &CompiledModel, arc: &HybridArc) -> Result<VarianceRun, ExperimentError> {
        let table = StepTable::from_arc(model, arc);
        if let Some(name) = REQUIRED.iter().find(|n| table.column(n).is_none()) {
            return Err(ExperimentError::MissingName {
                model: model.name().to_string(),
                name: name.to_string(),
            });
        }
        Ok(VarianceRun {
            p_bar: scalar_parameter(model, "pbar")?,
            table,
        })
    }

    /// One row of a period sweep: the model simulated `settings.steps`
    /// steps from `p0 = p̄`, its period detected, and Algorithm 1
    /// ([`VarianceIteration::algorithm1`]) for the same parameters.
    pub fn sweep_row(
        &self,
        it: &VarianceIteration,
        settings: &SweepSettings,
    ) -> Result<SweepRow, ExperimentError> {
        let run = self.run(it, None, settings.steps, Noise::Off)?;
        Ok(SweepRow::new(
            it,
            settings.max_points,
            run.p(),
            &settings.period,
        ))
    }

    /// The Fig. 4 sweep for the process of `base` (its δ is ignored): the δ
    /// grid of [`refined_delta_grid`] with `settings`, one
    /// [`Self::sweep_row`] each (in parallel; the rows are in δ order).
    pub fn sweep(
        &self,
        base: &VarianceIteration,
        settings: &SweepSettings,
    ) -> Result<Vec<SweepRow>, ExperimentError> {
        let grid = refined_delta_grid(
            base,
            settings.lo,
            settings.hi,
            settings.intervals,
            settings.levels,
            settings.per_cell,
            settings.max_points,
        );
        grid.par_iter()
            .filter_map(|&d| base.with_delta(d).ok())
            .map(|it| self.sweep_row(&it, settings))
            .collect()
    }

    /// The Fig. 4 experiment: the sweep, and the transmit sequences of
    /// `trace_steps` steps for δ = `base.delta()` and for the smallest δ of
    /// the sweep with simulated period `periods[i]`, for each `i`.
    pub fn fig4(
        &self,
        base: &VarianceIteration,
        periods: &[usize],
        settings: &SweepSettings,
        trace_steps: usize,
    ) -> Result<Fig4, ExperimentError> {
        let sweep = self.sweep(base, settings)?;
        let mut deltas = vec![base.delta()];
        deltas.extend(periods.iter().filter_map(|&n| {
            sweep
                .iter()
                .find(|r| r.simulated_period == Some(n))
                .map(|r| r.analysis.delta)
        }));
        let traces = deltas
            .iter()
            .filter_map(|&d| base.with_delta(d).ok())
            .map(|it| {
                let short = self.run(&it, None, trace_steps, Noise::Off)?;
                Ok(Trace {
                    threshold: short.p_bar + it.delta() / (it.c() * it.c()),
                    p: short.p().to_vec(),
                    gamma: short.gamma().to_vec(),
                    row: self.sweep_row(&it, settings)?,
                })
            })
            .collect::<Result<Vec<_>, ExperimentError>>()?;
        Ok(Fig4 { sweep, traces })
    }
}

/// The δ grid and run lengths of a period sweep. The default is the
/// reproduction's: δ ∈ [0.1, 10] in steps of 0.1, refined 3 times with 9
/// points in every cell where Algorithm 1's period changes, 4000 steps per
/// run, Algorithm 1 bounded to 10 000 points, period detection with the
/// default tolerances (1e-9, 4 repeats).
#[derive(Debug, Clone, PartialEq)]
pub struct SweepSettings {
    /// Smallest δ.
    pub lo: f64,
    /// Largest δ.
    pub hi: f64,
    /// Number of equal intervals of the coarse grid.
    pub intervals: usize,
    /// Refinement rounds.
    pub levels: usize,
    /// Points added per cell and round where the period changes.
    pub per_cell: usize,
    /// Bound on Algorithm 1's points.
    pub max_points: usize,
    /// Steps simulated per δ.
    pub steps: usize,
    /// Period detection.
    pub period: PeriodSettings,
}

impl Default for SweepSettings {
    fn default() -> Self {
        Self {
            lo: 0.1,
            hi: 10.0,
            intervals: 99,
            levels: 3,
            per_cell: 9,
            max_points: 10_000,
            steps: 4000,
            period: PeriodSettings::default(),
        }
    }
}

/// The transmit sequence of one δ, as in one sub-figure of Fig. 4.
#[derive(Debug, Clone, PartialEq)]
pub struct Trace {
    /// The transmit threshold `p̄ + δ/c²` (the model's `p̄`).
    pub threshold: f64,
    /// `p(0), …` of the short run drawn.
    pub p: Vec<f64>,
    /// `γ(0), …` of the short run drawn.
    pub gamma: Vec<f64>,
    /// The sweep row of this δ: simulated period and points of a run of
    /// [`SweepSettings::steps`] steps, Algorithm 1 and Theorem 2's cycle.
    pub row: SweepRow,
}

/// Data of the Fig. 4 experiment.
#[derive(Debug, Clone, PartialEq)]
pub struct Fig4 {
    /// The δ sweep, in δ order.
    pub sweep: Vec<SweepRow>,
    /// The transmit sequences drawn.
    pub traces: Vec<Trace>,
}

impl Fig4 {
    /// Fig. 4 proper: for each trace, `p(k)` with the threshold and `γ(k)`.
    pub fn traces_figure(&self) -> Figure {
        let mut fig = Figure::new();
        for tr in &self.traces {
            let k = |v: &[f64]| -> Vec<(f64, f64)> {
                v.iter().enumerate().map(|(k, &x)| (k as f64, x)).collect()
            };
            let n = tr.p.len().saturating_sub(1) as f64;
            let delta = tr.row.analysis.delta;
            let period = tr
                .row
                .simulated_period
                .map_or("none".to_string(), |n| n.to_string());
            fig = fig
                .panel(
                    Panel::new(format!(
                        "δ = {delta}: variance p(k) (simulated period {period})"
                    ))
                    .x_label("k")
                    .y_label("p(k)")
                    .series(Series::line("p(k)", k(&tr.p)).markers(true))
                    .series(Series::line(
                        "threshold p̄ + δ/c²",
                        vec![(0.0, tr.threshold), (n, tr.threshold)],
                    )),
                )
                .panel(
                    Panel::new(format!("δ = {delta}: transmit sequence γ(k)"))
                        .x_label("k")
                        .y_label("γ(k)")
                        .series(Series::points("γ(k)", k(&tr.gamma))),
                );
        }
        fig
    }

    /// Asymptotic period versus δ: simulated (through the model) and N of
    /// Algorithm 1.
    pub fn sweep_figure(&self) -> Figure {
        let sim = self
            .sweep
            .iter()
            .filter_map(|r| r.simulated_period.map(|n| (r.analysis.delta, n as f64)))
            .collect();
        let alg = self
            .sweep
            .iter()
            .filter_map(|r| r.analysis.period.map(|n| (r.analysis.delta, n as f64)))
            .collect();
        Figure::new().panel(
            Panel::new("Asymptotic period of p(k) versus δ (a = 1.2, c = q = r = 1)")
                .x_label("δ")
                .y_label("period")
                .series(Series::points(
                    "simulated (models/variance_triggering.hyb)",
                    sim,
                ))
                .series(Series::points("N of Algorithm 1", alg)),
        )
    }

    /// The sweep as CSV ([`SweepRow::CSV_HEADER`] and one line per δ).
    pub fn sweep_csv(&self) -> String {
        let mut s = String::from(SweepRow::CSV_HEADER);
        s.push('\n');
        for r in &self.sweep {
            s.push_str(&r.csv_line());
            s.push('\n');
        }
        s
    }
}
