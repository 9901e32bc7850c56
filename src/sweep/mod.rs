//! Sweeps and Monte Carlo: a Cartesian grid of `--set` values × seeded runs
//! of a model, reduced by the model's `metric` declarations while each run
//! streams (no arc is kept), on all cores, in shards that merge into the
//! same files.
//!
//! ```
//! use hybsim::source::SourceFile;
//! use hybsim::sweep::{self, Axis, Shard, SweepSpec};
//!
//! let src = SourceFile::new("ball.hyb", "model ball
//! param g = 9.81, lambda = 0.8
//! state h = 1, v = 0
//! flow { h' = v; v' = -g } in h >= 0
//! jump impact when h <= 0 && v <= 0 { v+ = -lambda * v }
//! metric bounces = count(impact)
//! sim { T = 1 }
//! ");
//! let spec = SweepSpec::new(vec!["lambda=[0.5, 0.8]".parse::<Axis>().unwrap()], 2, 1);
//! let rows = sweep::run(&src, &[], &spec, Shard::ALL, &Default::default(), Default::default());
//! assert_eq!(rows.len(), 4);
//! let points = sweep::aggregate(&spec, &rows);
//! // A less lively ball lands sooner: two bounces before T = 1, not one.
//! assert_eq!(points[0].stats[0].mean, 2.0);
//! assert_eq!(points[1].stats[0].mean, 1.0);
//! ```
//!
//! Run `r` of grid point `p` has the seed [`run_seed`]`(seed, label(p), r)`,
//! so `hybsim run MODEL --set … --seed S` (the `command` of its row)
//! replays it alone. Results ([`table`]): one row per run and one per grid
//! point (mean, std, min, max, count of each metric over the completed
//! runs), written in grid order whatever the number of threads or shards.

pub mod grid;
pub mod table;

use std::ops::ControlFlow;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use rayon::prelude::*;

pub use grid::{Axis, Shard, run_seed};
pub use table::{PointRow, RunRow, Stats};

use crate::arc::{
    ArcSink, FlowPiece, HybridTime, SampleKind, SolverSwitch, Termination, TerminationCause,
};
use crate::engine::simulate;
use crate::lang::{self, CheckOptions, CompiledModel, Override};
use crate::num::Num;
use crate::sinks::{RunOutcome, RunStatus};
use crate::source::SourceFile;

/// What can go wrong setting up or merging a sweep (a failing *run* is a
/// row, not an error).
#[derive(Debug, thiserror::Error)]
pub enum SweepError {
    /// A `--grid` axis that does not parse.
    #[error("invalid grid axis `{text}`: {message}")]
    Grid {
        /// The axis as written.
        text: String,
        /// What is wrong.
        message: String,
    },
    /// A `--shard` that is not `k/n` with 1 ≤ k ≤ n.
    #[error("invalid shard `{0}`: write k/n with 1 ≤ k ≤ n (e.g. --shard 2/8)")]
    Shard(String),
    /// The same name on two axes, or on an axis and a `--set`.
    #[error("`{0}` is set twice (on two grid axes, or by a grid axis and --set)")]
    Twice(String),
    /// Too many runs.
    #[error(
        "{0} runs in total: at most {MAX_RUNS} per sweep (each run's row is kept in memory, \
         shards and merge included): split the grid into several sweeps"
    )]
    TooMany(u128),
    /// No run per grid point.
    #[error("runs per grid point must be at least 1")]
    NoRuns,
    /// A number of worker threads that is 0 or over [`MAX_THREADS`].
    #[error(
        "{0} worker threads: a sweep takes from 1 to {MAX_THREADS} (more threads than cores \
         only slow it down; the default is all cores)"
    )]
    Threads(u64),
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The results directory cannot be created or written into.
    #[error("cannot write the results into `{path}`: {source}")]
    OutputDir {
        /// The directory.
        path: std::path::PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// A results file that is not what `hybsim sweep` writes.
    #[error("{path}: {message}")]
    Format {
        /// The file.
        path: std::path::PathBuf,
        /// What is wrong.
        message: String,
    },
    /// Shards that do not belong together or do not cover the sweep.
    #[error("cannot merge: {0}")]
    Merge(String),
}

/// Largest number of runs in one sweep: the rows of all runs are held in
/// memory (about 1 KB each with the tables written, more with long
/// messages), in `--merge` all of them at once, so 10⁷ runs take ~10 GB.
/// Checked before anything is allocated.
pub const MAX_RUNS: u64 = 10_000_000;

/// Most worker threads a sweep takes (`hybsim sweep --threads`, Python's
/// `threads=`). An idle rayon worker looks for work in every other
/// worker's queue, so thousands of threads on a few cores spend their time
/// looking: `--threads 10000` on 2 cores took over a minute for 2 runs.
pub const MAX_THREADS: u64 = 1024;

/// `threads` worker threads asked for, as a count: an error unless it is
/// from 1 to [`MAX_THREADS`].
pub fn check_threads(threads: u64) -> Result<usize, SweepError> {
    if (1..=MAX_THREADS).contains(&threads) {
        Ok(threads as usize)
    } else {
        Err(SweepError::Threads(threads))
    }
}

/// The pool of `threads` worker threads (checked by [`check_threads`]) for
/// `jobs` parallel jobs: no more threads than jobs, which would have
/// nothing to do; `None` (rayon's global pool, all cores) if `threads` is.
pub fn thread_pool(
    threads: Option<usize>,
    jobs: u64,
) -> Result<Option<rayon::ThreadPool>, rayon::ThreadPoolBuildError> {
    threads
        .map(|n| {
            let n = n.min(usize::try_from(jobs).unwrap_or(usize::MAX)).max(1);
            rayon::ThreadPoolBuilder::new().num_threads(n).build()
        })
        .transpose()
}

/// A sweep: grid axes (the first varies slowest), runs per grid point and
/// the base seed.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SweepSpec {
    /// The axes; no axis: one grid point (a plain Monte Carlo).
    pub axes: Vec<Axis>,
    /// Runs per grid point.
    pub runs: u64,
    /// Base seed of the run seeds.
    pub seed: u64,
}

impl SweepSpec {
    /// A sweep over `axes` with `runs` runs per point and base seed `seed`.
    pub fn new(axes: Vec<Axis>, runs: u64, seed: u64) -> Self {
        Self { axes, runs, seed }
    }

    /// Checks names (no axis twice, none also in `fixed`), values (finite,
    /// at least one, none twice) and the size.
    pub fn validate(&self, fixed: &[Override]) -> Result<(), SweepError> {
        if self.runs == 0 {
            return Err(SweepError::NoRuns);
        }
        for (k, a) in self.axes.iter().enumerate() {
            // `--grid` refuses them as it parses; Python's grids and the
            // library's axes arrive as numbers.
            if let Some(v) = a.values.iter().find(|v| !v.is_finite()) {
                return Err(SweepError::Grid {
                    text: format!("{}={}", a.name, Num(*v)),
                    message: format!("`{}` is not a finite number", Num(*v)),
                });
            }
            if a.values.is_empty() {
                return Err(SweepError::Grid {
                    text: format!("{}=[]", a.name),
                    message: "no values".into(),
                });
            }
            if let Some(v) = grid::repeated_value(&a.values) {
                return Err(SweepError::Grid {
                    text: a.name.clone(),
                    message: format!("the value {} is given twice", Num(v)),
                });
            }
            if self.axes[..k].iter().any(|b| b.name == a.name)
                || fixed.iter().any(|o| o.name == a.name)
            {
                return Err(SweepError::Twice(a.name.clone()));
            }
        }
        let total = self
            .axes
            .iter()
            .fold(u128::from(self.runs), |n, a| n * a.values.len() as u128);
        if total > u128::from(MAX_RUNS) {
            return Err(SweepError::TooMany(total));
        }
        Ok(())
    }

    /// Number of grid points.
    pub fn points(&self) -> usize {
        self.axes.iter().map(|a| a.values.len()).product()
    }

    /// Total number of runs.
    pub fn total_runs(&self) -> u64 {
        self.points() as u64 * self.runs
    }

    /// The values of grid point `p` (one per axis; the last axis varies
    /// fastest).
    pub fn point(&self, mut p: usize) -> Vec<f64> {
        let mut v = vec![0.0; self.axes.len()];
        for (k, a) in self.axes.iter().enumerate().rev() {
            v[k] = a.values[p % a.values.len()];
            p /= a.values.len();
        }
        v
    }

    /// `name=value` of each axis at grid point `p` (values as shortest
    /// round-trip decimals).
    pub fn point_sets(&self, p: usize) -> Vec<String> {
        self.axes
            .iter()
            .zip(self.point(p))
            .map(|(a, v)| format!("{}={}", a.name, Num(v)))
            .collect()
    }

    /// The label of grid point `p` in seeds: its `name=value`s joined by
    /// `,` (empty without axes).
    pub fn point_label(&self, p: usize) -> String {
        self.point_sets(p).join(",")
    }

    /// The seed of run `run` at grid point `p`.
    pub fn seed_of(&self, p: usize, run: u64) -> u64 {
        run_seed(self.seed, &self.point_label(p), run)
    }
}

/// How a caller follows and stops a sweep, and which runs it already has.
#[derive(Clone, Copy)]
pub struct Control<'a> {
    /// Called after each run (for a progress bar).
    pub done: &'a (dyn Fn() + Sync),
    /// When set, no further run starts and the runs under way stop at
    /// their next sample and are left out (Ctrl-C).
    pub stop: &'a AtomicBool,
    /// Runs not to do again (`index = point · runs + run`), e.g. those an
    /// interrupted sweep already wrote.
    pub skip: &'a (dyn Fn(u64) -> bool + Sync),
}

impl Default for Control<'_> {
    /// No progress, never stopped, nothing skipped.
    fn default() -> Self {
        static NEVER: AtomicBool = AtomicBool::new(false);
        Self {
            done: &|| {},
            stop: &NEVER,
            skip: &|_| false,
        }
    }
}

/// A sweep ready to run: its spec and the model's metric names.
#[derive(Debug, Clone)]
pub struct Plan {
    /// The grid, runs per point and base seed.
    pub spec: SweepSpec,
    /// The model's `metric` names, in declaration order (a row's metrics).
    pub metrics: Vec<String>,
    /// Grid point 0 as compiled while planning ([`run_plan`] reuses it: a
    /// compile solves the `design` blocks), if it compiled.
    first: Option<Arc<CompiledModel>>,
}

/// Why a sweep cannot start.
#[derive(Debug)]
pub enum PlanError {
    /// The model as given does not compile, or an axis names nothing the
    /// model can be set by (E0204, E0508): diagnostics located in `src`.
    Model(Vec<crate::diagnostics::Diagnostic>),
    /// An axis set twice, or too many runs.
    Spec(SweepError),
}

/// Plans a sweep of `src` with the overrides `fixed`: `axes`, `runs` and
/// `seed` as given, each else from the model's `sweep { }` block, else no
/// axis, one run and the model's seed. The model must compile as given and
/// every axis must name something it can be set by; other failures of a
/// grid point (a value that makes it invalid) are its rows, not errors.
pub fn plan(
    src: &SourceFile,
    fixed: &[Override],
    axes: Option<Vec<Axis>>,
    runs: Option<u64>,
    seed: Option<u64>,
    options: &CheckOptions,
) -> Result<Plan, PlanError> {
    let compile_base = || lang::compile_with(src, fixed, options).map_err(PlanError::Model);
    // With the axes given, point 0 (their first values) compiles beside the
    // model as given; else the axes come from the model's block.
    let (base, given_first) = match &axes {
        Some(axes) if !axes.is_empty() => {
            let first = SweepSpec::new(axes.clone(), 1, 0);
            let (base, point) = rayon::join(compile_base, || {
                compile_point(src, fixed, &first, 0, options, None)
            });
            (base?, Some(point))
        }
        _ => (compile_base()?, None),
    };
    let block = base.sweep().cloned().unwrap_or_default();
    let axes = axes.unwrap_or_else(|| {
        block
            .axes
            .into_iter()
            .map(|(name, values)| Axis { name, values })
            .collect()
    });
    let spec = SweepSpec::new(
        axes,
        runs.or(block.runs).unwrap_or(1),
        seed.or(block.seed).unwrap_or(base.seed()),
    );
    spec.validate(fixed).map_err(PlanError::Spec)?;
    let metrics = base.metrics().names().to_vec();
    let first = match given_first {
        _ if spec.axes.is_empty() => Ok(base),
        Some(point) => point,
        None => compile_point(src, fixed, &spec, 0, options, None),
    };
    let first = match first {
        Ok(m) => Some(Arc::new(m)),
        Err(diags) => {
            let unknown: Vec<_> = diags
                .into_iter()
                .filter(|d| d.code == "E0204" || d.code == "E0508")
                .collect();
            if !unknown.is_empty() {
                return Err(PlanError::Model(unknown));
            }
            None
        }
    };
    Ok(Plan {
        spec,
        metrics,
        first,
    })
}

/// Runs the part `shard` of a planned sweep as [`run`] does, reusing the
/// grid point the plan compiled. A grid point whose metrics are not the
/// plan's (an axis changes the size of a metric family, e.g. `N` in
/// `for i in 1..N { metric r[i] = … }`) gives failed rows (cause
/// `model_error`): the tables have one column per metric of the plan.
pub fn run_plan(
    src: &SourceFile,
    fixed: &[Override],
    plan: &Plan,
    shard: Shard,
    options: &CheckOptions,
    control: Control<'_>,
) -> Vec<RunRow> {
    let given = Given {
        first: plan.first.as_ref(),
        metrics: Some(&plan.metrics),
    };
    run_with(src, fixed, &plan.spec, shard, options, control, given)
}

/// What a planned sweep already knows: grid point 0 compiled, and the
/// metric names every grid point must have.
#[derive(Clone, Copy, Default)]
struct Given<'a> {
    first: Option<&'a Arc<CompiledModel>>,
    metrics: Option<&'a [String]>,
}

/// Runs the part `shard` of `spec` on the model `src` with the fixed
/// overrides `fixed`, on rayon's current thread pool, followed and stopped
/// through `control`. Returns the rows of the runs that finished, in grid
/// order (point, then run), the same for any number of threads. A grid
/// point whose model does not compile gives failed rows (cause
/// `model_error`); a run that panics (a bug) is a failed row (cause
/// `internal_error`). Runs stopped by `control.stop` have no row.
pub fn run(
    src: &SourceFile,
    fixed: &[Override],
    spec: &SweepSpec,
    shard: Shard,
    options: &CheckOptions,
    control: Control<'_>,
) -> Vec<RunRow> {
    run_with(src, fixed, spec, shard, options, control, Given::default())
}

/// [`run`] with what the plan knows.
fn run_with(
    src: &SourceFile,
    fixed: &[Override],
    spec: &SweepSpec,
    shard: Shard,
    options: &CheckOptions,
    control: Control<'_>,
    given: Given<'_>,
) -> Vec<RunRow> {
    let runs = spec.runs;
    let jobs: Vec<u64> = (0..spec.total_runs())
        .filter(|&i| shard.contains(i) && !(control.skip)(i))
        .collect();
    let rows = Mutex::new(Vec::with_capacity(jobs.len()));
    // The jobs are in grid order; a batch is those of the next
    // `POINTS_PER_BATCH` grid points, whose compiled models are dropped
    // once its runs are done.
    let mut start = 0;
    while start < jobs.len() && !control.stop.load(Ordering::Relaxed) {
        let mut points: Vec<usize> = Vec::new();
        let mut end = start;
        while let Some(&i) = jobs.get(end) {
            let p = (i / runs) as usize;
            if points.last() != Some(&p) {
                if points.len() == POINTS_PER_BATCH {
                    break;
                }
                points.push(p);
            }
            end += 1;
        }
        let compiled = compile_points(src, fixed, spec, &points, options, given);
        jobs[start..end].par_iter().for_each(|&i| {
            if control.stop.load(Ordering::Relaxed) {
                return;
            }
            let (p, r) = ((i / runs) as usize, i % runs);
            let k = compiled
                .binary_search_by_key(&p, |c| c.0)
                .expect("every point of a job was compiled");
            let Some(row) = run_one(
                src,
                fixed,
                spec,
                p,
                r,
                &compiled[k].1,
                options,
                control.stop,
            ) else {
                return;
            };
            rows.lock()
                .expect("no run panics while holding the lock")
                .push(row);
            (control.done)();
        });
        start = end;
    }
    let mut rows = rows.into_inner().expect("no run panicked");
    rows.sort_by_key(|row| (row.point, row.run));
    rows
}

/// Grid points whose compiled models are held at once (a model with large
/// families or `design` results takes up to megabytes): a larger grid is
/// run in batches of this many points, so memory is bounded by the rows.
const POINTS_PER_BATCH: usize = 256;

/// The models of grid points `points` (ascending), compiled in parallel
/// (design blocks solved once per point): each point's model, or the
/// message of its failed rows.
fn compile_points(
    src: &SourceFile,
    fixed: &[Override],
    spec: &SweepSpec,
    points: &[usize],
    options: &CheckOptions,
    given: Given<'_>,
) -> Vec<(usize, Result<Arc<CompiledModel>, String>)> {
    points
        .par_iter()
        .map(|&p| {
            let model = match given.first {
                Some(m) if p == 0 => Ok(Arc::clone(m)),
                _ => compile_point(src, fixed, spec, p, options, None)
                    .map(Arc::new)
                    .map_err(|diags| render_diagnostics(&diags, src)),
            };
            let model = model.and_then(|m| match given.metrics {
                Some(names) if m.metrics().names() != names => Err(format!(
                    "the metrics of this grid point ({}) are not the sweep's ({}): an axis \
                     changes the size of a metric family; sweep its values separately",
                    m.metrics().names().join(", "),
                    names.join(", ")
                )),
                _ => Ok(m),
            });
            (p, model)
        })
        .collect()
}

/// Compiles grid point `p` as the sweep does: the diagnostics if it fails.
pub fn check_point(
    src: &SourceFile,
    fixed: &[Override],
    spec: &SweepSpec,
    p: usize,
    options: &CheckOptions,
) -> Result<(), Vec<crate::diagnostics::Diagnostic>> {
    compile_point(src, fixed, spec, p, options, None).map(|_| ())
}

/// The overrides of grid point `p`: `fixed`, then the axes, each standing for
/// `--grid name=value` so that its errors name the grid, not a `--set`.
fn point_overrides(
    fixed: &[Override],
    spec: &SweepSpec,
    p: usize,
) -> Result<Vec<Override>, Vec<crate::diagnostics::Diagnostic>> {
    let mut all = fixed.to_vec();
    for s in spec.point_sets(p) {
        let o: Override = s.parse().map_err(|d| vec![d])?;
        all.push(o.from_flag(format!("--grid {s}")));
    }
    Ok(all)
}

/// Compiles grid point `p` (with run seed `seed`: as `hybsim run --seed`).
fn compile_point(
    src: &SourceFile,
    fixed: &[Override],
    spec: &SweepSpec,
    p: usize,
    options: &CheckOptions,
    seed: Option<u64>,
) -> Result<CompiledModel, Vec<crate::diagnostics::Diagnostic>> {
    let overrides = point_overrides(fixed, spec, p)?;
    match seed {
        Some(_) => lang::compile_run_with(src, &overrides, seed, options).map(|m| m.0),
        None => lang::compile_with(src, &overrides, options),
    }
}

/// A row's message for a grid point that does not compile.
fn render_diagnostics(diags: &[crate::diagnostics::Diagnostic], src: &SourceFile) -> String {
    crate::diagnostics::render(diags, src, false)
}

/// Run `r` of grid point `p`; `None` if `stop` stopped it.
#[allow(clippy::too_many_arguments)] // one run of the sweep and where it comes from
fn run_one(
    src: &SourceFile,
    fixed: &[Override],
    spec: &SweepSpec,
    p: usize,
    r: u64,
    compiled: &Result<Arc<CompiledModel>, String>,
    options: &CheckOptions,
    stop: &AtomicBool,
) -> Option<RunRow> {
    let seed = spec.seed_of(p, r);
    let mut row = RunRow {
        point: p,
        run: r,
        seed,
        values: spec.point(p),
        status: RunStatus::Failed,
        cause: String::new(),
        message: String::new(),
        metrics: Vec::new(),
    };
    let model = match compiled {
        Err(message) => {
            row.cause = "model_error".into();
            row.message = message.trim_end().to_string();
            return Some(row);
        }
        Ok(m) => &**m,
    };
    // Random parameters are drawn from the run's seed, as `hybsim run` does.
    let redrawn;
    let model = if model.random_params().is_empty() {
        model
    } else {
        match compile_point(src, fixed, spec, p, options, Some(seed)) {
            Ok(m) => {
                redrawn = m;
                &redrawn
            }
            Err(diags) => {
                let message = render_diagnostics(&diags, src);
                row.cause = "model_error".into();
                row.message = message.trim_end().to_string();
                return Some(row);
            }
        }
    };
    let (x0, mut rng) = model.start(seed);
    let mut sink = Stoppable {
        inner: model.metrics().sink(),
        stop,
    };
    // A panic (a bug) is the row's cause; the panic hook has printed it.
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        simulate(model, &x0, &model.settings(), &mut rng, &mut sink)
    }));
    let Ok(result) = result else {
        row.cause = "internal_error".into();
        row.message = "internal error (a bug in hybsim): the run panicked".into();
        return Some(row);
    };
    if let Ok(term) = &result
        && term.cause == TerminationCause::StoppedBySink
    {
        return None;
    }
    let outcome = match &result {
        Ok(term) => RunOutcome::from_termination(term),
        Err(e) => RunOutcome::failed("error", format!("{e}; {}", e.help())),
    };
    if let Ok(term) = &result
        && matches!(term.cause, TerminationCause::ZenoSuspected { .. })
    {
        row.message = format!("{}; {}", outcome.message, term.help());
    } else {
        row.message = outcome.message.clone();
    }
    row.status = outcome.status;
    row.cause = outcome.cause;
    if row.status == RunStatus::Completed {
        // `runs.csv` writes any NaN as `NaN`, which `--merge` and `--resume`
        // read back as the one quiet NaN: store that one (a NaN computed on
        // x86, 0/0, has the sign bit set), so that Parquet holds the same bits.
        row.metrics = sink
            .inner
            .values()
            .into_iter()
            .map(|v| if v.is_nan() { f64::NAN } else { v })
            .collect();
    }
    Some(row)
}

/// A sink that stops the run at its next sample or step once `stop` is set.
struct Stoppable<'a, S> {
    inner: S,
    stop: &'a AtomicBool,
}

impl<S: ArcSink> ArcSink for Stoppable<'_, S> {
    fn sample(&mut self, at: HybridTime, x: &[f64], kind: SampleKind) -> ControlFlow<()> {
        if self.stop.load(Ordering::Relaxed) {
            return ControlFlow::Break(());
        }
        self.inner.sample(at, x, kind)
    }

    fn jump(&mut self, at: HybridTime, rule: usize, pre: &[f64], post: &[f64]) -> ControlFlow<()> {
        self.inner.jump(at, rule, pre, post)
    }

    fn finish(&mut self, termination: &Termination) {
        self.inner.finish(termination);
    }

    fn solver_switch(&mut self, switch: &SolverSwitch) {
        self.inner.solver_switch(switch);
    }

    fn wants_dense_points(&self) -> bool {
        self.inner.wants_dense_points()
    }

    fn wants_flow_pieces(&self) -> bool {
        self.inner.wants_flow_pieces()
    }

    fn flow_piece(&mut self, piece: &mut FlowPiece<'_>) {
        self.inner.flow_piece(piece);
    }

    fn poll(&mut self) -> ControlFlow<()> {
        if self.stop.load(Ordering::Relaxed) {
            return ControlFlow::Break(());
        }
        self.inner.poll()
    }
}

/// The per-grid-point statistics of `rows` (all rows of each point present
/// in `rows`), in grid order.
pub fn aggregate(spec: &SweepSpec, rows: &[RunRow]) -> Vec<PointRow> {
    let mut out: Vec<PointRow> = Vec::new();
    for row in rows {
        if out.last().is_none_or(|p| p.point != row.point) {
            out.push(PointRow {
                point: row.point,
                values: spec.point(row.point),
                runs: 0,
                completed: 0,
                stats: Vec::new(),
            });
        }
        let p = out.last_mut().expect("just pushed");
        p.runs += 1;
        if row.status == RunStatus::Completed {
            p.completed += 1;
            if p.stats.len() < row.metrics.len() {
                p.stats.resize(row.metrics.len(), Stats::default());
            }
            for (s, &v) in p.stats.iter_mut().zip(&row.metrics) {
                s.push(v);
            }
        }
    }
    for p in &mut out {
        for s in &mut p.stats {
            s.finish();
        }
    }
    out
}
