//! `models/platoon.hyb` (Muehlebach and Trimpe, Sec. VII): the distributed
//! event-based platoon of M vehicles in closed loop, compiled once per
//! parameter set (the `design` blocks run at compile time) and simulated for
//! many seeds, with the steady-state statistics of Fig. 5 (left) and Fig. 6
//! computed while each run streams (a 1000-s run has 5·10⁴ steps; at
//! M = 20 a state has ~1300 components, so the arc is never kept):
//!
//! * the communication rate of each vehicle over `t ≥ t_ss`: the fraction
//!   of steps in which it triggered (`tx`), whether or not its packets were
//!   dropped afterwards;
//! * the largest and a high quantile of each distance error `|d_i|`
//!   (`d_i = r_i − r_{i+1}` minus the nominal spacing, measured by vehicle
//!   `i + 1`), and the quantile pooled over all distances;
//! * the power `‖e_i‖ = (mean_k ‖x(k) − x̂_i(k)‖²)^½` of each agent's
//!   estimation error.
//!
//! Quantiles are exact (the `⌊q·n⌋`-th smallest of the n pooled values):
//! every run keeps only the largest values of each distance that an
//! ensemble of its size can need, so memory stays bounded.
//!
//! ```no_run
//! use hybsim_papers::experiments::platoon::{Platoon, Window};
//! let p = Platoon::read("models/platoon.hyb", &["M=5", "corollary=3"]).unwrap();
//! let e = p.ensemble(1..=20, &Window::default()).unwrap();
//! println!("rates {:?} ± {:?}", e.rate_mean, e.rate_std);
//! ```

use std::ops::{ControlFlow, RangeInclusive};
use std::path::Path;

use super::{ExperimentError, compile, simulate_seeded_into};
use hybsim::arc::{ArcSink, HybridTime, SampleKind};
use hybsim::engine::TerminationCause;
use hybsim::lang::CompiledModel;
use hybsim::layout::{Entry, Shape};
use hybsim::source::SourceFile;

/// The model file, relative to the repository root ([`crate::repo_path`]).
pub const MODEL_PATH: &str = "models/platoon.hyb";

/// Which part of a run the statistics cover, and which quantile.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    /// Start of the steady state: steps with `t ≥ t_ss` count. Default 100 s
    /// (the transient of the 5 m/s surplus is over by ~60 s).
    pub t_ss: f64,
    /// Level of the distance-error quantile, in (0, 1). Default 0.999.
    pub quantile: f64,
}

impl Default for Window {
    fn default() -> Self {
        Self {
            t_ss: 100.0,
            quantile: 0.999,
        }
    }
}

/// The steady-state statistics of one run.
#[derive(Debug, Clone, PartialEq)]
pub struct RunStats {
    /// The run's seed (as `hybsim run --seed`).
    pub seed: u64,
    /// Steps with `t ≥ t_ss`.
    pub steps: u64,
    /// Per vehicle: steady-state steps in which it transmitted.
    pub sent: Vec<u64>,
    /// Per vehicle: `sent / steps`.
    pub rate: Vec<f64>,
    /// Per distance `d_i`, i = 1..M−1: largest `|d_i|`.
    pub distance_max: Vec<f64>,
    /// Per agent: `(mean ‖x − x̂_i‖²)^½` over the steady state.
    pub error_power: Vec<f64>,
    /// Per distance: the largest values of `|d_i|` (for quantiles).
    tails: Vec<Tail>,
}

/// The statistics of an ensemble of runs (one compiled model, many seeds).
#[derive(Debug, Clone, PartialEq)]
pub struct EnsembleStats {
    /// Seeds run, in order.
    pub seeds: Vec<u64>,
    /// The window the statistics cover.
    pub window: Window,
    /// Per vehicle: mean rate over the seeds.
    pub rate_mean: Vec<f64>,
    /// Per vehicle: standard deviation of the rate over the seeds (1/S
    /// normalisation; Fig. 6's error bars).
    pub rate_std: Vec<f64>,
    /// Per distance `d_i`: largest `|d_i|` over all seeds.
    pub distance_max: Vec<f64>,
    /// Per distance `d_i`: the `window.quantile` quantile of `|d_i|`,
    /// pooled over the seeds.
    pub distance_quantile: Vec<f64>,
    /// The quantile of `|d|` pooled over all distances and seeds.
    pub distance_quantile_all: f64,
    /// Per agent: `(mean ‖x − x̂_i‖²)^½` pooled over the seeds.
    pub error_power: Vec<f64>,
    /// Every run's own statistics, in seed order.
    pub runs: Vec<RunStats>,
}

impl EnsembleStats {
    /// Largest `|d_i|` over all distances and seeds.
    pub fn distance_max_all(&self) -> f64 {
        self.distance_max.iter().copied().fold(0.0, f64::max)
    }

    /// Mean of the vehicles' mean rates over the 1-based vehicle range
    /// `vehicles` (e.g. `1..=5` for the leading five).
    pub fn mean_rate_of(&self, vehicles: RangeInclusive<usize>) -> f64 {
        let r: Vec<f64> = vehicles
            .filter_map(|v| v.checked_sub(1).and_then(|i| self.rate_mean.get(i)))
            .copied()
            .collect();
        r.iter().sum::<f64>() / r.len().max(1) as f64
    }
}

/// The largest values of a sample (at most `keep`; all of them if fewer) and
/// the sample size: enough for exact upper quantiles whose rank from the
/// top is below `keep`.
#[derive(Debug, Clone, PartialEq)]
struct Tail {
    keep: usize,
    values: Vec<f64>,
    count: u64,
}

impl Tail {
    fn new(keep: usize) -> Self {
        Self {
            keep: keep.max(1),
            values: Vec::new(),
            count: 0,
        }
    }

    fn push(&mut self, v: f64) {
        self.count += 1;
        self.values.push(v);
        if self.values.len() >= 2 * self.keep {
            self.trim();
        }
    }

    /// Keeps the `keep` largest values (amortised O(1) per push).
    fn trim(&mut self) {
        if self.values.len() > self.keep {
            let cut = self.values.len() - self.keep;
            self.values.select_nth_unstable_by(cut, f64::total_cmp);
            self.values.drain(..cut);
        }
    }

    fn merge(&mut self, other: &Tail) {
        self.count += other.count;
        self.values.extend_from_slice(&other.values);
        self.trim();
    }

    /// The `⌊q·count⌋`-th smallest value (0-based), if it is among those kept.
    fn quantile(&self, q: f64) -> Option<f64> {
        if self.count == 0 {
            return None;
        }
        let idx = ((self.count as f64 * q) as u64).min(self.count - 1);
        let from_top = usize::try_from(self.count - 1 - idx).ok()?;
        let mut v = self.values.clone();
        if from_top >= v.len() {
            return None;
        }
        v.sort_by(|a, b| b.total_cmp(a));
        Some(v[from_top])
    }
}

/// Where the statistics read the state vector.
#[derive(Debug, Clone, Copy)]
struct Indices {
    /// Offset of `x` (n = 2M − 1: velocities, then distances).
    x: usize,
    /// Offset of `XH` (n × M, row-major: column i is agent i's estimate).
    xh: usize,
    /// Offset of `tx` (M).
    tx: usize,
}

/// The platoon model compiled for one parameter set.
#[derive(Debug)]
pub struct Platoon {
    model: CompiledModel,
    vehicles: usize,
    n: usize,
    ix: Indices,
    ts: f64,
}

/// Streams a run and accumulates [`RunStats`].
struct StatsSink<'a> {
    p: &'a Platoon,
    t_ss: f64,
    steps: u64,
    sent: Vec<u64>,
    distance_max: Vec<f64>,
    error_sq: Vec<f64>,
    tails: Vec<Tail>,
}

impl ArcSink for StatsSink<'_> {
    fn sample(&mut self, _: HybridTime, _: &[f64], _: SampleKind) -> ControlFlow<()> {
        ControlFlow::Continue(())
    }

    fn jump(&mut self, at: HybridTime, _rule: usize, _pre: &[f64], x: &[f64]) -> ControlFlow<()> {
        if at.t < self.t_ss {
            return ControlFlow::Continue(());
        }
        let (m, n, ix) = (self.p.vehicles, self.p.n, self.p.ix);
        self.steps += 1;
        for (s, &tx) in self.sent.iter_mut().zip(&x[ix.tx..ix.tx + m]) {
            // tx is 0 or 1 (set by the model's trigger (4)).
            *s += u64::from(tx != 0.0);
        }
        let d = &x[ix.x + m..ix.x + n];
        for ((mx, tail), &di) in self.distance_max.iter_mut().zip(&mut self.tails).zip(d) {
            let a = di.abs();
            *mx = mx.max(a);
            tail.push(a);
        }
        let state = &x[ix.x..ix.x + n];
        let xh = &x[ix.xh..ix.xh + n * m];
        for (i, e2) in self.error_sq.iter_mut().enumerate() {
            *e2 += state
                .iter()
                .enumerate()
                .map(|(r, &xr)| (xr - xh[r * m + i]).powi(2))
                .sum::<f64>();
        }
        ControlFlow::Continue(())
    }
}

/// Offset and shape of a top-level state field.
fn field(model: &CompiledModel, name: &str) -> Result<(usize, Shape), ExperimentError> {
    model
        .state_layout()
        .entries
        .iter()
        .find_map(|e| match e {
            Entry::Field(f) if f.name == name => Some((f.offset, f.shape)),
            _ => None,
        })
        .ok_or_else(|| ExperimentError::MissingName {
            model: model.name().to_string(),
            name: name.to_string(),
        })
}

impl Platoon {
    /// Reads and compiles the model file with `--set`-style overrides
    /// (`["M=20", "corollary=3"]`).
    ///
    /// # Errors
    /// The file cannot be read ([`ExperimentError::Io`]), an override does not
    /// parse, the model does not compile, or it is not a platoon model.
    pub fn read<S: AsRef<str>>(
        path: impl AsRef<Path>,
        sets: &[S],
    ) -> Result<Self, ExperimentError> {
        let path = path.as_ref();
        let src = SourceFile::read(path).map_err(|e| ExperimentError::Io {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        Self::compile(&src, sets)
    }

    /// Compiles `src` with overrides (runs its `design` blocks once).
    ///
    /// # Errors
    /// As [`Self::read`], without the file.
    pub fn compile<S: AsRef<str>>(src: &SourceFile, sets: &[S]) -> Result<Self, ExperimentError> {
        Self::new(compile(src, sets)?)
    }

    /// Wraps a compiled platoon model.
    ///
    /// # Errors
    /// The model lacks the parameters `M`, `Ts` or the states `x` (2M − 1),
    /// `XH` (2M − 1 × M), `tx` (M) of models/platoon.hyb.
    pub fn new(model: CompiledModel) -> Result<Self, ExperimentError> {
        let scalar = |name: &str| {
            model
                .parameter(name)
                .filter(|p| p.len() == 1)
                .map(|p| p[(0, 0)])
                .ok_or_else(|| ExperimentError::MissingParameter {
                    model: model.name().to_string(),
                    name: name.to_string(),
                })
        };
        let (vehicles_f, ts) = (scalar("M")?, scalar("Ts")?);
        let vehicles = vehicles_f as usize;
        let n = (2 * vehicles).saturating_sub(1);
        let (x, x_shape) = field(&model, "x")?;
        let (xh, xh_shape) = field(&model, "XH")?;
        let (tx, tx_shape) = field(&model, "tx")?;
        let shapes_ok = vehicles >= 2
            && vehicles_f == vehicles as f64
            && x_shape == Shape::Vector(n)
            && xh_shape
                == (Shape::Matrix {
                    rows: n,
                    cols: vehicles,
                })
            && tx_shape == Shape::Vector(vehicles);
        if !shapes_ok {
            return Err(ExperimentError::MissingName {
                model: model.name().to_string(),
                name: format!("x[{n}], XH[{n}, {vehicles}] and tx[{vehicles}] (M = {vehicles_f})"),
            });
        }
        Ok(Self {
            model,
            vehicles,
            n,
            ix: Indices { x, xh, tx },
            ts,
        })
    }

    /// The compiled model (parameters, design reports).
    pub fn model(&self) -> &CompiledModel {
        &self.model
    }

    /// Number of vehicles M.
    pub fn vehicles(&self) -> usize {
        self.vehicles
    }

    /// An upper bound on the steady-state steps of one run.
    fn steps_bound(&self, window: &Window) -> u64 {
        let span = (self.model.settings().horizon_t - window.t_ss).max(0.0);
        (span / self.ts).ceil() as u64 + 2
    }

    /// How many of the largest `|d_i|` each run keeps so that the quantile
    /// pooled over `pooled` runs × distances is exact: the rank from the top
    /// is at most `(1 − q)·n`.
    fn tail_keep(&self, window: &Window, pooled: u64) -> usize {
        let n = (pooled * self.steps_bound(window)) as f64;
        ((1.0 - window.quantile) * n).floor() as usize + 1
    }

    /// Runs seed `seed` and returns its statistics.
    ///
    /// # Errors
    /// The window is invalid, the simulation fails, or it stopped before the
    /// horizon T ([`ExperimentError::Stopped`], e.g. the model's jump
    /// horizon J is below T / Ts).
    pub fn run(&self, seed: u64, window: &Window) -> Result<RunStats, ExperimentError> {
        check_window(window)?;
        let keep = self.tail_keep(window, (self.vehicles - 1) as u64);
        self.run_keeping(seed, window, keep)
    }

    fn run_keeping(
        &self,
        seed: u64,
        window: &Window,
        keep: usize,
    ) -> Result<RunStats, ExperimentError> {
        let m = self.vehicles;
        let mut sink = StatsSink {
            p: self,
            t_ss: window.t_ss,
            steps: 0,
            sent: vec![0; m],
            distance_max: vec![0.0; m - 1],
            error_sq: vec![0.0; m],
            tails: vec![Tail::new(keep); m - 1],
        };
        let term = simulate_seeded_into(&self.model, seed, &mut sink)?;
        if term.cause != TerminationCause::HorizonT {
            return Err(ExperimentError::Stopped {
                model: self.model.name().to_string(),
                at: term.at.t,
                cause: term.to_string(),
            });
        }
        let steps = sink.steps.max(1) as f64;
        for t in &mut sink.tails {
            t.trim();
        }
        Ok(RunStats {
            seed,
            steps: sink.steps,
            rate: sink.sent.iter().map(|&s| s as f64 / steps).collect(),
            sent: sink.sent,
            distance_max: sink.distance_max,
            error_power: sink.error_sq.iter().map(|e| (e / steps).sqrt()).collect(),
            tails: sink.tails,
        })
    }

    /// Runs every seed of `seeds` (in parallel) and pools the statistics.
    ///
    /// # Errors
    /// As [`Self::run`] for any seed, or `seeds` is empty.
    pub fn ensemble(
        &self,
        seeds: impl IntoIterator<Item = u64>,
        window: &Window,
    ) -> Result<EnsembleStats, ExperimentError> {
        use rayon::prelude::*;
        check_window(window)?;
        let seeds: Vec<u64> = seeds.into_iter().collect();
        if seeds.is_empty() {
            return Err(ExperimentError::InvalidSetting {
                message: "an ensemble needs at least one seed".into(),
            });
        }
        let (m, s) = (self.vehicles, seeds.len());
        let keep = self.tail_keep(window, (s * (m - 1)) as u64);
        let runs: Vec<RunStats> = seeds
            .par_iter()
            .map(|&seed| self.run_keeping(seed, window, keep))
            .collect::<Result<_, _>>()?;
        let sf = s as f64;
        let rate_mean: Vec<f64> = (0..m)
            .map(|i| runs.iter().map(|r| r.rate[i]).sum::<f64>() / sf)
            .collect();
        let rate_std = (0..m)
            .map(|i| {
                (runs
                    .iter()
                    .map(|r| (r.rate[i] - rate_mean[i]).powi(2))
                    .sum::<f64>()
                    / sf)
                    .sqrt()
            })
            .collect();
        let distance_max = (0..m - 1)
            .map(|i| runs.iter().map(|r| r.distance_max[i]).fold(0.0, f64::max))
            .collect();
        let mut all = Tail::new(keep);
        let mut distance_quantile = Vec::with_capacity(m - 1);
        for i in 0..m - 1 {
            let mut pooled = Tail::new(keep);
            for r in &runs {
                pooled.merge(&r.tails[i]);
            }
            distance_quantile.push(quantile_of(&pooled, window.quantile)?);
            all.merge(&pooled);
        }
        let distance_quantile_all = quantile_of(&all, window.quantile)?;
        let error_power = (0..m)
            .map(|i| (runs.iter().map(|r| r.error_power[i].powi(2)).sum::<f64>() / sf).sqrt())
            .collect();
        Ok(EnsembleStats {
            seeds,
            window: *window,
            rate_mean,
            rate_std,
            distance_max,
            distance_quantile,
            distance_quantile_all,
            error_power,
            runs,
        })
    }
}

/// `--set` overrides `L=[..]`, `cstar=..`, `Delta=[..]` from a JSON file of a synthesis done
/// elsewhere (keys `L`: rows of numbers, `cstar`: number, `Delta`: numbers), e.g.
/// `tests/data/platoon_m20_cor_v3.json` (M = 20, Cor. V.3, CSDP). With all three set, the model's
/// `design` blocks are not solved. Numbers are written with `{:?}` (exact round trip).
///
/// # Errors
/// The file cannot be read ([`ExperimentError::Io`]) or lacks a key
/// ([`ExperimentError::InvalidSetting`]).
pub fn synthesis_overrides(path: impl AsRef<Path>) -> Result<Vec<String>, ExperimentError> {
    let path = path.as_ref();
    let bad = |what: &str| ExperimentError::InvalidSetting {
        message: format!("{}: {what}", path.display()),
    };
    let text = std::fs::read_to_string(path).map_err(|e| ExperimentError::Io {
        path: path.display().to_string(),
        message: e.to_string(),
    })?;
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| bad(&format!("not JSON ({e})")))?;
    let nums = |v: &serde_json::Value, key: &str| -> Result<String, ExperimentError> {
        v.as_array()
            .and_then(|a| {
                a.iter()
                    .map(|x| x.as_f64().map(|x| format!("{x:?}")))
                    .collect::<Option<Vec<_>>>()
            })
            .map(|xs| xs.join(", "))
            .ok_or_else(|| bad(&format!("`{key}` must be an array of numbers")))
    };
    let rows = v["L"]
        .as_array()
        .ok_or_else(|| bad("`L` must be an array of rows"))?
        .iter()
        .map(|r| nums(r, "L"))
        .collect::<Result<Vec<_>, _>>()?;
    let cstar = v["cstar"]
        .as_f64()
        .ok_or_else(|| bad("`cstar` must be a number"))?;
    Ok(vec![
        format!("L=[{}]", rows.join("; ")),
        format!("cstar={cstar:?}"),
        format!(
            "Delta=[{}]",
            nums(&v["Delta"], "Delta")?.replace(", ", "; ")
        ),
    ])
}

/// The quantile of a pooled tail; kept tails always hold it (the runs keep
/// as many values as the pooled rank needs), so `None` means no steady-state
/// step was recorded.
fn quantile_of(t: &Tail, q: f64) -> Result<f64, ExperimentError> {
    t.quantile(q).ok_or_else(|| ExperimentError::InvalidSetting {
        message: format!(
            "no distance-error quantile {q}: {} steady-state values recorded (is t_ss below T?)",
            t.count
        ),
    })
}

fn check_window(w: &Window) -> Result<(), ExperimentError> {
    if !(w.quantile > 0.0 && w.quantile < 1.0 && w.t_ss.is_finite()) {
        return Err(ExperimentError::InvalidSetting {
            message: format!(
                "window: t_ss = {} must be finite and the quantile {} in (0, 1)",
                w.t_ss, w.quantile
            ),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::Tail;

    #[test]
    fn tail_quantile_equals_the_sorted_pooled_sample() {
        // Two "runs" of a deterministic scrambled sequence; pooled exact quantiles.
        let a: Vec<f64> = (0..5000).map(|k| ((k * 7919) % 5003) as f64).collect();
        let b: Vec<f64> = (0..4000)
            .map(|k| ((k * 104_729) % 4001) as f64 + 0.5)
            .collect();
        for q in [0.5, 0.9, 0.999] {
            let keep = ((1.0 - q) * 9000.0) as usize + 1;
            let (mut ta, mut tb) = (Tail::new(keep), Tail::new(keep));
            a.iter().for_each(|&v| ta.push(v));
            b.iter().for_each(|&v| tb.push(v));
            ta.merge(&tb);
            let mut all: Vec<f64> = a.iter().chain(&b).copied().collect();
            all.sort_by(f64::total_cmp);
            let want = all[(all.len() as f64 * q) as usize];
            assert_eq!(ta.quantile(q), Some(want), "q = {q}");
            assert!(ta.values.len() <= keep);
        }
        // Not enough kept: no answer rather than a wrong one.
        let mut t = Tail::new(3);
        (0..100).for_each(|k| t.push(f64::from(k)));
        assert_eq!(t.quantile(0.5), None);
        assert_eq!(t.quantile(0.99), Some(99.0));
    }
}
