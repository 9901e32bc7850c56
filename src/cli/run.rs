//! `hybsim run`: compile a model, simulate it into the requested sinks,
//! print a one-line summary.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use clap::Args;

use hybsim::arc::{ArcSink, HybridTime, Termination, TerminationCause};
use hybsim::atomic_file;
use hybsim::diagnostics::render;
use hybsim::engine::{
    ExactAffine, HybridSystem, JumpChoice, LinearSolver, Priority, SimError, SimRng, SimSettings,
    Solver, simulate,
};
use hybsim::ir::CompiledModel;
use hybsim::ir::metric::Metrics;
use hybsim::lang;
use hybsim::layout::{Entry, Shape};
use hybsim::sinks::csv::CsvSink;
use hybsim::sinks::mcap::{Compression, Encoding, McapOptions, McapSink, NonFiniteStop};
use hybsim::sinks::parquet::ParquetSink;
use hybsim::sinks::plot::{ImageFormat, PlotKind, PlotSink};
use hybsim::sinks::{
    Decimation, Fanout, OutputFn, RuleLog, RunInfo, RunOutcome, RunStatus, Tally, rule_name,
};
use serde_json::{Value, json};

use super::progress::{Progress, interrupt_flag};
use super::{
    ArgOverride, EXIT_FAILED, EXIT_INTERRUPTED, EXIT_MODEL_ERROR, EXIT_OK, GuardArgs, JitMode,
    NumberArg, SdpKind,
};

/// Arguments of `hybsim run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// The model file (`.hyb`; `-` reads it from standard input).
    pub model: PathBuf,
    /// MCAP output file. Default: the model's file name with `.mcap`, in
    /// the current directory.
    #[arg(short = 'o', long = "output", value_name = "OUT.mcap")]
    pub output: Option<PathBuf>,
    /// Do not write an MCAP file.
    #[arg(long, conflicts_with = "output")]
    pub no_mcap: bool,
    /// Horizon T in ordinary time (overrides the model's `sim` block).
    #[arg(long = "T", value_name = "T", allow_hyphen_values = true)]
    pub horizon_t: Option<NumberArg>,
    /// Horizon J in jumps (overrides the model's `sim` block): a whole
    /// number (`1e6` too), or `inf` for no bound; checked as the block's `J`.
    #[arg(long = "J", value_name = "J", allow_hyphen_values = true)]
    pub horizon_j: Option<NumberArg>,
    /// Output grid: flow samples at t = k·DT instead of every integrator step
    /// (overrides the model's `sim` block).
    #[arg(long, value_name = "DT", allow_hyphen_values = true)]
    pub dt_out: Option<NumberArg>,
    /// Integrator for flows (overrides the model's).
    #[arg(long, value_enum)]
    pub solver: Option<SolverKind>,
    /// Relative tolerance of the adaptive solvers.
    #[arg(long, value_name = "RTOL")]
    pub rtol: Option<f64>,
    /// Absolute tolerance of the adaptive solvers.
    #[arg(long, value_name = "ATOL")]
    pub atol: Option<f64>,
    /// Step of the fixed-step solvers (rk4, euler-maruyama); default: the
    /// model's `h`, else 1e-3 (as in the `sim` block).
    #[arg(long, value_name = "H", allow_hyphen_values = true)]
    pub step: Option<f64>,
    /// Largest integrator step of the adaptive solvers.
    #[arg(long, value_name = "H", allow_hyphen_values = true)]
    pub max_step: Option<NumberArg>,
    /// What to do when the state is in both C and D.
    #[arg(long, value_enum)]
    pub priority: Option<PriorityKind>,
    /// Which jump fires when several rules are enabled at one point: the
    /// `first` declared, or one drawn at `random` from the run's generator
    /// (overrides the model's `jump_choice`).
    #[arg(long, value_enum, value_name = "CHOICE")]
    pub jump_choice: Option<JumpChoiceKind>,
    #[command(flatten)]
    pub guard: GuardArgs,
    /// Advance affine flows exactly (matrix exponentials): `auto` (by cost,
    /// per segment), `on` or `off` (overrides the model's).
    #[arg(long, value_enum, value_name = "WHEN")]
    pub exact_affine: Option<ExactAffineKind>,
    /// LU of the implicit solvers' Newton matrices: `auto` (sparse for
    /// large sparse Jacobians), `dense` or `sparse` (overrides the model's).
    #[arg(long, value_enum, value_name = "KIND")]
    pub linear_solver: Option<LinearSolverKind>,
    /// Interior-point method of the model's design blocks.
    #[arg(long, value_enum, default_value_t = SdpKind::Auto)]
    pub sdp: SdpKind,
    /// Seed of the run's random generator (overrides the model's).
    #[arg(long, value_name = "N", value_parser = super::parse_seed)]
    pub seed: Option<u64>,
    /// Machine code for the model (`on`, default where supported) or the
    /// interpreter (`off`); overrides the model's `sim { jit = … }`.
    #[arg(long, value_enum)]
    pub jit: Option<JitMode>,
    /// Override a parameter: `--set name=value` (repeatable); the value is
    /// an expression of the model language, e.g. `--set K="[1, 2]"`.
    #[arg(long = "set", value_name = "NAME=VALUE")]
    pub set: Vec<String>,
    /// Also write the logged samples as CSV.
    #[arg(long, value_name = "OUT.csv")]
    pub csv: Option<PathBuf>,
    /// Also write the logged samples as Parquet (the CSV's rows and
    /// columns, typed), and the jumps to OUT.jumps.parquet beside it.
    #[arg(long, value_name = "OUT.parquet")]
    pub parquet: Option<PathBuf>,
    /// Also draw the states (or `--plot-vars`) against t (or `--plot-kind`),
    /// SVG or PNG by the file's extension.
    #[arg(long, value_name = "OUT.svg|OUT.png")]
    pub plot: Option<PathBuf>,
    /// States or outputs to plot, comma-separated: entries (`h`), families
    /// (`xhat`) or members (`xhat[2]`, `theta[1,2]`). Default: the states.
    #[arg(long, value_name = "NAMES", requires = "plot")]
    pub plot_vars: Option<String>,
    /// What the plot draws (HyEQ's kinds): each component against t
    /// (`flows`) or against j (`jumps`), over (t, j) in 3-D (`hybrid`), the
    /// second selected component against the first (`phase`; the first three
    /// in 3-D when three are selected), or the hybrid time domain (`domain`).
    #[arg(long, value_enum, default_value_t = PlotKindArg::Flows, requires = "plot")]
    pub plot_kind: PlotKindArg,
    /// Log every N-th flow sample (samples of logged jumps and the first and
    /// last samples are always logged); overrides the model's `log { every }`.
    #[arg(long, value_name = "N", value_parser = super::parse_positive_count)]
    pub log_every: Option<u64>,
    /// Log flow samples at least DT apart in t (samples of logged jumps and the
    /// first and last samples are always logged); overrides `log { dt }` (0
    /// keeps every flow sample).
    #[arg(long, value_name = "DT", allow_hyphen_values = true)]
    pub log_dt: Option<f64>,
    /// States and outputs written to the MCAP and CSV files, comma-separated:
    /// entries (`xh`, `err`) or family members (`xh[2]`, `e[1,3]`); `*` for
    /// all. Replaces the model's `log { vars }`; default: all.
    #[arg(long, value_name = "NAMES")]
    pub log_vars: Option<String>,
    /// Jump rules whose jumps are logged, comma-separated: `fire` (a rule or
    /// a whole family), `fire[2]`, `v.redraw` (a noise's redraws); empty for
    /// none, `*` for all. Replaces the model's `log { rules }`; default: all but the
    /// noise redraws.
    #[arg(long, value_name = "RULES")]
    pub log_rules: Option<String>,
    /// Jump rules whose jumps are logged as records only (`/hybsim/jumps`,
    /// the Parquet jumps table), without their pre- and post-jump samples:
    /// names as for `--log-rules`. Replaces the model's `log { marks }`; a
    /// rule it names is not logged in full (naming it in `--log-rules` too
    /// is an error).
    #[arg(long, value_name = "RULES")]
    pub log_marks: Option<String>,
    /// Encoding of the MCAP messages: protobuf (default; Foxglove decodes it
    /// natively) or json. Overrides `log { encoding }`.
    #[arg(long, value_enum, value_name = "ENCODING")]
    pub log_encoding: Option<LogEncodingArg>,
    /// Compression of the MCAP chunks: lz4 (default, the fastest), zstd
    /// (level 1: ~10 % smaller files, slower) or none. Overrides
    /// `log { compression }`.
    #[arg(long, value_enum, value_name = "COMPRESSION")]
    pub log_compression: Option<LogCompressionArg>,
    /// Whether MCAP jump records carry the pre- and post-jump states
    /// (`pre`, `post`); without them a jump's states are the pre- and
    /// post-jump samples on `/hybsim/state` around its record. Overrides
    /// `log { jump_states }` (`--log-jump-states=false` turns it off);
    /// default: false.
    #[arg(
        long,
        value_name = "BOOL",
        num_args = 0..=1,
        require_equals = true,
        default_missing_value = "true"
    )]
    pub log_jump_states: Option<bool>,
    /// No progress bar.
    #[arg(short, long)]
    pub quiet: bool,
    /// Print the summary as one JSON object on stdout (model, status, cause,
    /// message, end, jumps per rule, samples, files written, times,
    /// metrics) instead of the summary line.
    #[arg(long)]
    pub json: bool,
}

/// `--log-encoding` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LogEncodingArg {
    /// Protobuf messages, descriptor-set schemas.
    Protobuf,
    /// JSON messages, JSON Schemas.
    Json,
}

/// `--log-compression` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LogCompressionArg {
    /// LZ4 frames.
    Lz4,
    /// zstd, level 1.
    Zstd,
    /// Uncompressed chunks.
    None,
}

/// Solver names on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SolverKind {
    /// Dormand–Prince 5(4), adaptive.
    Dopri5,
    /// Dormand–Prince 8(5,3), adaptive.
    Dop853,
    /// Radau IIA order 5, implicit, adaptive: for stiff flows.
    Radau5,
    /// Variable-order BDF (1–5), implicit, adaptive: for stiff flows.
    Bdf,
    /// Dopri5, switching to Radau5 while the flow is stiff.
    Auto,
    /// Runge–Kutta 4, fixed step (`--step`).
    Rk4,
    /// Euler–Maruyama, fixed step (`--step`), for noise-driven flows.
    EulerMaruyama,
}

/// `--exact-affine` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ExactAffineKind {
    /// Per segment, by cost.
    Auto,
    /// Always exact.
    On,
    /// Always the solver.
    Off,
}

/// `--linear-solver` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LinearSolverKind {
    /// Sparse for large systems with a sparse Jacobian, dense otherwise.
    Auto,
    /// Always dense.
    Dense,
    /// Sparse whenever the Jacobian has a pattern.
    Sparse,
}

/// `jump_choice` names on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum JumpChoiceKind {
    /// The first enabled rule in declaration order.
    First,
    /// A uniform draw among the enabled jumps.
    Random,
}

/// Priority names on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PriorityKind {
    /// Jump whenever x ∈ D.
    Jumps,
    /// Flow while possible; jump only when the flow would leave C.
    Flows,
    /// A fair coin from the run's generator.
    Random,
}

/// The solver after the command-line flags, or what to change.
fn solver_from_flags(
    current: Solver,
    keys: hybsim::check::SolverKeys,
    args: &RunArgs,
) -> Result<Solver, String> {
    let kind = args.solver.unwrap_or(match current {
        Solver::Dopri5 { .. } => SolverKind::Dopri5,
        Solver::Dop853 { .. } => SolverKind::Dop853,
        Solver::Radau5 { .. } => SolverKind::Radau5,
        Solver::Bdf { .. } => SolverKind::Bdf,
        Solver::Auto { .. } => SolverKind::Auto,
        Solver::Rk4 { .. } => SolverKind::Rk4,
        Solver::EulerMaruyama { .. } => SolverKind::EulerMaruyama,
    });
    // The current solver's keys, else those the model's `sim` block gave for another kind
    // (`h = 0.01` beside `solver = dopri5` is the step of `--solver rk4`).
    let (rtol0, atol0, h0) = match current {
        Solver::Rk4 { h } | Solver::EulerMaruyama { h } => (
            keys.rtol.unwrap_or(1e-6),
            keys.atol.unwrap_or(1e-9),
            Some(h),
        ),
        adaptive => {
            let (rtol, atol) = adaptive.tolerances().expect("an adaptive solver");
            (rtol, atol, keys.h)
        }
    };
    match kind {
        SolverKind::Dopri5
        | SolverKind::Dop853
        | SolverKind::Radau5
        | SolverKind::Bdf
        | SolverKind::Auto => {
            if args.step.is_some() {
                return Err(
                    "`--step` applies to the fixed-step solvers; use `--solver rk4` or `--max-step`"
                        .into(),
                );
            }
            let (rtol, atol) = (args.rtol.unwrap_or(rtol0), args.atol.unwrap_or(atol0));
            Ok(match kind {
                SolverKind::Dopri5 => Solver::Dopri5 { rtol, atol },
                SolverKind::Dop853 => Solver::Dop853 { rtol, atol },
                SolverKind::Radau5 => Solver::Radau5 { rtol, atol },
                SolverKind::Bdf => Solver::Bdf { rtol, atol },
                _ => Solver::Auto { rtol, atol },
            })
        }
        SolverKind::Rk4 | SolverKind::EulerMaruyama => {
            if args.rtol.is_some() || args.atol.is_some() {
                return Err(
                    "`--rtol`/`--atol` apply to the adaptive solvers dopri5, dop853, radau5, bdf and auto"
                        .into(),
                );
            }
            // As the `sim` block: the default step where none is given.
            let h = args
                .step
                .or(h0)
                .unwrap_or(hybsim::engine::DEFAULT_FIXED_STEP);
            Ok(if kind == SolverKind::Rk4 {
                Solver::Rk4 { h }
            } else {
                Solver::EulerMaruyama { h }
            })
        }
    }
}

impl RunArgs {
    /// The user's `--set`s followed by the flags that are `sim` keys (`--T`, `--J`, `--dt-out`,
    /// `--max-step` and the guard flags), named `sim.KEY` so that they set the setting even where
    /// the model declares a name `T` or `J`, and a flag wins over a `--set`; the checker
    /// validates it and applies the resource limits (output points, forced steps) as it does
    /// for the model's own `sim` block.
    fn overrides(&self) -> Vec<ArgOverride> {
        let mut all = self.guard.with_overrides(&self.set);
        all.extend(ArgOverride::number("--T", "sim.T", self.horizon_t.as_ref()));
        all.extend(ArgOverride::number("--J", "sim.J", self.horizon_j.as_ref()));
        all.extend(ArgOverride::number(
            "--dt-out",
            "sim.dt_out",
            self.dt_out.as_ref(),
        ));
        all.extend(ArgOverride::number(
            "--max-step",
            "sim.max_step",
            self.max_step.as_ref(),
        ));
        all
    }
}

/// The model's settings with the command-line flags that are not `sim`-key overrides
/// ([`RunArgs::overrides`]) applied, validated for `model` (a `--solver` that cannot
/// integrate its white noise is refused here, as a usage error).
pub fn settings_from_flags(
    mut settings: SimSettings,
    args: &RunArgs,
    model: &CompiledModel,
) -> Result<SimSettings, String> {
    if let Some(p) = args.priority {
        settings = settings.priority(match p {
            PriorityKind::Jumps => Priority::Jumps,
            PriorityKind::Flows => Priority::Flows,
            PriorityKind::Random => Priority::Random,
        });
    }
    if let Some(c) = args.jump_choice {
        settings = settings.jump_choice(match c {
            JumpChoiceKind::First => JumpChoice::First,
            JumpChoiceKind::Random => JumpChoice::Random,
        });
    }
    if let Some(l) = args.linear_solver {
        settings = settings.linear_solver(match l {
            LinearSolverKind::Auto => LinearSolver::Auto,
            LinearSolverKind::Dense => LinearSolver::Dense,
            LinearSolverKind::Sparse => LinearSolver::Sparse,
        });
    }
    if let Some(e) = args.exact_affine {
        settings = settings.exact_affine(match e {
            ExactAffineKind::Auto => ExactAffine::Auto,
            ExactAffineKind::On => ExactAffine::On,
            ExactAffineKind::Off => ExactAffine::Off,
        });
    }
    let solver = solver_from_flags(settings.solver, model.solver_keys(), args)?;
    let settings = settings.solver(solver);
    settings.validate_for(model).map_err(|e| match e {
        SimError::NoiseNeedsEulerMaruyama { .. } => format!(
            "`--solver {}`: the model's flows have white noise (`wiener`), which only \
             `--solver euler-maruyama` integrates",
            solver.name().replace('_', "-")
        ),
        e => format!("{e}; {}", e.help()),
    })?;
    // `--solver`/`--step` change the fixed step after the check: held to its limits.
    if let Some((key, why)) = model.over_limit(&settings) {
        // A step too small that the model's `h` gave comes with `--solver`.
        let flag = match key {
            "h" if args.step.is_none() => "--solver",
            "h" => "--step",
            key => key,
        };
        return Err(format!("`{flag}`: {why}"));
    }
    Ok(settings)
}

/// `--plot-kind` (and `hybsim plot --kind`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PlotKindArg {
    /// Components against t.
    Flows,
    /// Components against j.
    Jumps,
    /// Components over (t, j), in 3-D.
    Hybrid,
    /// The second selected component against the first (three or more: the first three in 3-D).
    Phase,
    /// j against t.
    Domain,
}

impl From<PlotKindArg> for PlotKind {
    fn from(k: PlotKindArg) -> Self {
        match k {
            PlotKindArg::Flows => PlotKind::Flows,
            PlotKindArg::Jumps => PlotKind::Jumps,
            PlotKindArg::Phase => PlotKind::Phase,
            PlotKindArg::Domain => PlotKind::Domain,
            PlotKindArg::Hybrid => PlotKind::Hybrid,
        }
    }
}

/// The files a run writes.
#[derive(Debug, Clone, Default)]
pub struct Outputs {
    /// MCAP file, if any.
    pub mcap: Option<PathBuf>,
    /// CSV file, if any.
    pub csv: Option<PathBuf>,
    /// Parquet file of the samples (the jumps beside it), if any.
    pub parquet: Option<PathBuf>,
    /// SVG or PNG file, if any.
    pub plot: Option<PathBuf>,
    /// Entries to plot.
    pub plot_vars: Vec<String>,
    /// What the plot draws.
    pub plot_kind: PlotKind,
    /// States and outputs written to the MCAP and CSV files (`None`: all).
    pub log_vars: Option<Vec<String>>,
    /// Which samples to write.
    pub decimation: Decimation,
    /// How the MCAP file encodes and compresses its messages.
    pub mcap_options: McapOptions,
    /// Show a progress bar (if stderr is a terminal).
    pub progress: bool,
}

/// What a run produced.
#[derive(Debug)]
pub struct Report {
    /// The outcome as written to the logs.
    pub outcome: RunOutcome,
    /// How the engine ended the run (`None` if it failed).
    pub termination: Option<Termination>,
    /// Counts of samples and jumps.
    pub tally: Tally,
    /// Files written.
    pub written: Vec<PathBuf>,
    /// Wall-clock time of the simulation.
    pub wall: Duration,
    /// Ctrl-C stopped the run.
    pub interrupted: bool,
    /// The model's metrics (name, value), in declaration order.
    pub metrics: Vec<(String, f64)>,
    /// The solver of the run (its switches, under `solver = auto`, are in
    /// the tally).
    pub solver: Solver,
    /// The non-finite value at which the MCAP log stopped the run.
    pub stopped: Option<NonFiniteStop>,
}

/// The outcome of a run for the logs.
fn outcome_of(result: &Result<Termination, SimError>, interrupted: bool) -> RunOutcome {
    match result {
        Ok(term) if interrupted && term.cause == TerminationCause::StoppedBySink => RunOutcome {
            cause: "interrupted".into(),
            message: format!("interrupted (Ctrl-C, SIGTERM or SIGHUP) at {}", term.at),
            status: RunStatus::Ended,
        },
        Ok(term) => RunOutcome::from_termination(term),
        Err(e) => RunOutcome::failed("error", format!("{e}; {}", e.help())),
    }
}

/// Simulation settings as JSON for the logs (non-finite numbers as strings).
pub fn settings_json(s: &SimSettings) -> Value {
    let num = |x: f64| {
        if x.is_finite() {
            json!(x)
        } else {
            json!(x.to_string())
        }
    };
    let method = s.solver.name();
    let solver = match s.solver {
        Solver::Rk4 { h } | Solver::EulerMaruyama { h } => json!({"method": method, "h": h}),
        adaptive => {
            let (rtol, atol) = adaptive.tolerances().expect("an adaptive solver");
            json!({"method": method, "rtol": rtol, "atol": atol})
        }
    };
    let priority = match s.priority {
        Priority::Jumps => "jumps",
        Priority::Flows => "flows",
        Priority::Random => "random",
    };
    json!({
        "horizon_t": num(s.horizon_t),
        // Unbounded (u64::MAX) as "inf", the spelling `--J` takes.
        "horizon_j": if s.horizon_j == u64::MAX { json!("inf") } else { json!(s.horizon_j) },
        "solver": solver,
        "priority": priority,
        "jump_choice": s.jump_choice.name(),
        "dt_out": s.dt_out.map(num),
        "max_step": num(s.max_step),
        "event_tol": num(s.event_tol),
        "set_tol": num(s.set_tol),
        "guard_checks": s.guard_checks,
        "zeno_max_rate": num(s.zeno_max_rate),
        "zeno_window": s.zeno_window,
        "max_total_jumps": s.max_total_jumps,
        "exact_affine": s.exact_affine.name(),
        "linear_solver": s.linear_solver.name(),
    })
}

/// Simulates `sys` from `x0` into the sinks named by `outputs`; every file
/// is completed (or removed) before this returns. Returns the report and the
/// engine's error, if the run failed (the files then record the failure).
#[allow(clippy::too_many_arguments)] // the pieces of one run, each optional but the system
pub fn simulate_to_files<S: HybridSystem + ?Sized>(
    sys: &S,
    x0: &[f64],
    settings: &SimSettings,
    rng: &mut SimRng,
    info: &RunInfo,
    output_fn: Option<OutputFn<'_>>,
    logged_output_fn: Option<OutputFn<'_>>,
    outputs: &Outputs,
    metrics: Option<&Metrics>,
) -> anyhow::Result<(Report, Option<SimError>)> {
    // Installed before any output file exists, so that a signal from here
    // on completes (or removes) every file.
    let interrupted = interrupt_flag();
    let mut metric_sink = metrics.filter(|m| !m.is_empty()).map(|m| m.sink());
    // The files log the selected states and outputs; plots choose their own.
    let selected = outputs
        .log_vars
        .as_ref()
        .map(|names| info.select_vars(names).0);
    let logged = selected.as_ref().unwrap_or(info);
    // The files need only the logged outputs (the plot may show others).
    let logged_fn = logged_output_fn.or(output_fn);
    let mut mcap = match &outputs.mcap {
        Some(path) => Some(McapSink::create(
            path,
            logged,
            logged_fn,
            outputs.mcap_options.decimation(outputs.decimation),
        )?),
        None => None,
    };
    let mut csv = match &outputs.csv {
        Some(path) => Some(CsvSink::create(
            path,
            logged,
            logged_fn,
            outputs.decimation,
        )?),
        None => None,
    };
    let mut parquet = match &outputs.parquet {
        Some(path) => Some(ParquetSink::create(
            path,
            logged,
            logged_fn,
            outputs.decimation,
        )?),
        None => None,
    };
    let mut plot = match &outputs.plot {
        Some(path) => Some(
            PlotSink::new(
                path,
                info,
                output_fn,
                &outputs.plot_vars,
                outputs.decimation,
            )?
            .kind(outputs.plot_kind)?,
        ),
        None => None,
    };
    let mut progress = Progress::new(
        settings.horizon_t,
        settings.horizon_j,
        info.rule_names.len(),
        outputs.progress,
        interrupted,
    );

    let start = Instant::now();
    let result = {
        let mut sinks: Vec<&mut dyn ArcSink> = vec![&mut progress];
        if let Some(s) = metric_sink.as_mut() {
            sinks.push(s);
        }
        if let Some(s) = mcap.as_mut() {
            sinks.push(s);
        }
        if let Some(s) = csv.as_mut() {
            sinks.push(s);
        }
        if let Some(s) = parquet.as_mut() {
            sinks.push(s);
        }
        if let Some(s) = plot.as_mut() {
            sinks.push(s);
        }
        let mut fan = Fanout::new(sinks);
        // A panic (a bug) still ends in completed files that record it; the
        // panic hook has already printed the report.
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            simulate(sys, x0, settings, rng, &mut fan)
        }))
    };
    let (result, panic) = match result {
        Ok(result) => (Some(result), None),
        Err(payload) => (None, Some(panic_message(&*payload))),
    };
    let error = result.as_ref().and_then(|r| r.as_ref().err().cloned());
    let termination = result.as_ref().and_then(|r| r.as_ref().ok().cloned());
    let wall = start.elapsed();
    progress.clear();
    let interrupted = progress.was_interrupted();

    let mut outcome = match (&result, &panic) {
        (Some(result), _) => outcome_of(result, interrupted),
        (None, message) => RunOutcome::failed(
            "internal_error",
            format!(
                "internal error (a bug in hybsim): {}",
                message.as_deref().unwrap_or("panic")
            ),
        ),
    };
    let metric_values = metric_sink.map(|m| m.named_values()).unwrap_or_default();
    let mut written = Vec::new();
    let mut first_error: Option<anyhow::Error> = None;
    let mut stopped = None;
    if let Some(mut sink) = mcap {
        sink.set_metrics(metric_values.clone());
        match sink.finish(&outcome) {
            Ok(summary) => {
                outcome = summary.outcome;
                stopped = summary.stopped;
                written.push(summary.path);
            }
            Err(e) => {
                first_error.get_or_insert(e.into());
            }
        }
    }
    if let Some(sink) = csv {
        match sink.finish() {
            Ok(path) => written.push(path),
            Err(e) => {
                first_error.get_or_insert(e.into());
            }
        }
    }
    if let Some(sink) = parquet {
        match sink.finish() {
            Ok(paths) => written.extend(paths),
            Err(e) => {
                first_error.get_or_insert(e.into());
            }
        }
    }
    if let Some(sink) = plot {
        match sink.finish() {
            Ok(path) => written.push(path),
            Err(e) => {
                first_error.get_or_insert(e.into());
            }
        }
    }
    if let Some(e) = first_error {
        return Err(e.context("the run's output could not be written"));
    }
    if let Some(message) = panic {
        let files: Vec<String> = written.iter().map(|p| p.display().to_string()).collect();
        anyhow::bail!(
            "internal error (a bug in hybsim): {message}; the run up to that point is in {}",
            if files.is_empty() {
                "no file".to_string()
            } else {
                files.join(", ")
            }
        );
    }
    let report = Report {
        outcome,
        termination,
        tally: progress.tally,
        written,
        wall,
        interrupted,
        metrics: metric_values,
        solver: settings.solver,
        stopped,
    };
    Ok((report, error))
}

/// The text of a panic's payload.
pub fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    if let Some(s) = payload.downcast_ref::<&str>() {
        (*s).to_string()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "panic".to_string()
    }
}

/// The summary: one line with the final (t, j), jumps per rule, cause and
/// wall time, and `note` (e.g. the compile time), then one line per metric
/// (`  metric NAME = VALUE`).
pub fn summary_line(model: &str, report: &Report, rule_names: &[String], note: &str) -> String {
    let end = match report.tally.end {
        // As every other hybrid time of the line (`HybridTime`'s Display:
        // `Num`, 1e-300 rather than 300 digits).
        Some(at) => format!("(t = {}, j = {})", hybsim::num::Num(at.t), at.j),
        None => "(no sample)".to_string(),
    };
    let fired: Vec<(String, u64)> = report
        .tally
        .jumps
        .iter()
        .enumerate()
        .filter(|(_, n)| **n > 0)
        .map(|(k, &n)| (rule_name(rule_names, k), n))
        .collect();
    let jumps = jump_counts(&fired);
    let jumps = if jumps.is_empty() {
        "none".to_string()
    } else {
        jumps.join(", ")
    };
    let mut line = format!(
        "{model}: ended at {end}; jumps: {jumps}; {}; {} samples{}; wall {:.3} s{note}",
        report.outcome.message,
        report.tally.samples,
        switches_note(report),
        report.wall.as_secs_f64()
    );
    for (name, value) in &report.metrics {
        line.push_str(&format!("\n  metric {name} = {}", hybsim::num::Num(*value)));
    }
    line
}

/// Members of one rule family the summary line lists one by one at most;
/// more are summed (10⁴ agents' rules made a line of 200 kB).
const LISTED_MEMBERS: usize = 8;

/// The summary's jump counts: `rule n` per rule that fired, except that
/// the members of a family (`fire[1]`, `fire[2]`, …) that fired, when more
/// than [`LISTED_MEMBERS`], are one entry with their total, `fire[…] 50000
/// (10000 rules)`, where the first of them would be; `--json` keeps every rule.
/// A family's members need not be next to each other: a loop that declares
/// two rules per member, and a family of instances with two rules, interleave
/// them (`n.fire[1]`, `n.kicked[1]`, `n.fire[2]`, …).
fn jump_counts(fired: &[(String, u64)]) -> Vec<String> {
    // The family of a member: its name without the last index (`a.update[3]` → `a.update`).
    let family = |name: &str| -> Option<String> {
        let open = name.rfind('[')?;
        name.ends_with(']').then(|| name[..open].to_string())
    };
    // (members that fired, their jumps) per family.
    let mut families: HashMap<String, (usize, u64)> = HashMap::new();
    for (name, n) in fired {
        if let Some(fam) = family(name) {
            let e = families.entry(fam).or_default();
            e.0 += 1;
            e.1 += n;
        }
    }
    let mut out = Vec::new();
    let mut summed = HashSet::new();
    for (name, n) in fired {
        match family(name) {
            Some(fam) if families[&fam].0 > LISTED_MEMBERS => {
                if summed.insert(fam.clone()) {
                    let (run, total) = families[&fam];
                    out.push(format!("{fam}[…] {total} ({run} rules)"));
                }
            }
            _ => out.push(format!("{name} {n}")),
        }
    }
    out
}

/// `; solver auto: …` for the summary line: the method throughout, or the
/// number of switches and the first three (method and where it took over).
fn switches_note(report: &Report) -> String {
    if !matches!(report.solver, Solver::Auto { .. }) {
        return String::new();
    }
    let tally = &report.tally;
    if tally.solver_switches_total == 0 {
        return "; solver auto: dopri5 throughout".into();
    }
    let shown: Vec<String> = tally
        .solver_switches
        .iter()
        .take(3)
        .map(|s| format!("{} at {}", s.to, s.at))
        .collect();
    let more = if tally.solver_switches_total > 3 {
        ", …"
    } else {
        ""
    };
    let n = tally.solver_switches_total;
    format!(
        "; solver auto: {n} switch{} ({}{more})",
        if n == 1 { "" } else { "es" },
        shown.join(", ")
    )
}

/// `; compile T s, jit T s`: the time from source to runnable model
/// (design blocks included) and the time spent generating machine code
/// (during the run, as programs became hot), for the summary line.
fn compile_note(total: Duration, jit: &lang::JitStatus) -> String {
    match jit {
        lang::JitStatus::Native { time, .. } => format!(
            "; compile {:.3} s, jit {:.3} s",
            total.as_secs_f64(),
            time.as_secs_f64()
        ),
        _ => format!("; compile {:.3} s", total.as_secs_f64()),
    }
}

/// The exit code of a finished run.
pub fn exit_code(report: &Report) -> u8 {
    if report.interrupted {
        EXIT_INTERRUPTED
    } else if report.outcome.status == RunStatus::Failed {
        EXIT_FAILED
    } else {
        EXIT_OK
    }
}

/// Why the outputs of a run cannot be written as asked: an output path
/// that is the model file or another output of the same run.
pub fn output_path_clash(model: &Path, outputs: &Outputs) -> Option<String> {
    let jumps = outputs
        .parquet
        .as_deref()
        .and_then(hybsim::sinks::parquet::jumps_path);
    let named: Vec<(&str, &Path)> = [
        ("-o", outputs.mcap.as_deref()),
        ("--csv", outputs.csv.as_deref()),
        ("--parquet", outputs.parquet.as_deref()),
        ("--parquet (its jumps table)", jumps.as_deref()),
        ("--plot", outputs.plot.as_deref()),
    ]
    .into_iter()
    .filter_map(|(flag, path)| path.map(|p| (flag, p)))
    .collect();
    // A model read from standard input (`-`) is no file an output could overwrite.
    let inputs: &[(&str, &Path)] = if model == Path::new("-") {
        &[]
    } else {
        &[("the model", model)]
    };
    atomic_file::clash(inputs, &named)
}

/// Default MCAP path: the model's file name with `.mcap`, in the current directory.
pub fn default_mcap_path(model: &Path) -> PathBuf {
    let stem = model
        .file_stem()
        .filter(|_| model != Path::new("-"))
        .map(|s| s.to_os_string())
        .unwrap_or_else(|| "stdin".into());
    PathBuf::from(stem).with_extension("mcap")
}

/// `hybsim run`.
pub fn execute(args: RunArgs) -> anyhow::Result<u8> {
    let Some((src, mut overrides)) = super::load(&args.model, &args.overrides())? else {
        return Ok(EXIT_MODEL_ERROR);
    };
    JitMode::apply(args.jit, &mut overrides);
    let compile_start = Instant::now();
    // Random parameters are drawn from the run's seed.
    let (model, seed) =
        match lang::compile_run_with(&src, &overrides, args.seed, &args.sdp.options()) {
            Ok(compiled) => compiled,
            Err(diags) => {
                eprint!("{}", render(&diags, &src, super::color()));
                return Ok(EXIT_MODEL_ERROR);
            }
        };
    let compile_time = compile_start.elapsed();
    if let (Some(JitMode::On), lang::JitStatus::Unavailable(e)) = (args.jit, &model.jit()) {
        eprintln!("warning: the model runs interpreted: {e}");
    }
    let settings = match settings_from_flags(model.settings(), &args, &model) {
        Ok(s) => s,
        Err(message) => {
            eprintln!("error: {message}");
            return Ok(EXIT_MODEL_ERROR);
        }
    };
    let mut info = RunInfo {
        model_name: model.name().to_string(),
        model_path: args.model.display().to_string(),
        source: src.text().to_string(),
        imports: model
            .imports()
            .files()
            .map(|(_, f)| (f.name().to_string(), f.text().to_string()))
            .collect(),
        tables: model.table_files().to_vec(),
        seed,
        // The program's own path would make files depend on where it is installed.
        argv: std::iter::once("hybsim".to_string())
            .chain(
                std::env::args_os()
                    .skip(1)
                    .map(|a| a.to_string_lossy().into_owned()),
            )
            .collect(),
        overrides: overrides
            .iter()
            .map(|o| (o.name.clone(), o.value.clone()))
            .collect(),
        state_layout: model.state_layout().clone(),
        state_dim: model.state_dim(),
        output_layout: model.output_layout().clone(),
        output_dim: model.output_dim(),
        rule_names: model.rule_names(),
        logged_rules: RuleLog::combine(&model.log_decl().rules, &model.log_decl().marks),
        parameters: model.parameters_json(),
        solver: settings_json(&settings),
        design: model.design_json(),
    };
    // An unknown `--plot-vars` name is a usage error (exit 2), found before the run.
    let plot_vars = args
        .plot_vars
        .as_deref()
        .map(split_names)
        .unwrap_or_default();
    for name in &plot_vars {
        if let Some(message) = unknown_plot_var("--plot-vars", name, &info) {
            eprintln!("error: {message}");
            return Ok(EXIT_MODEL_ERROR);
        }
    }
    if args.plot.is_some()
        && let Err(e) = PlotSink::check_selection(&info, &plot_vars, args.plot_kind.into())
    {
        eprintln!("error: {e}");
        return Ok(EXIT_MODEL_ERROR);
    }
    // Unknown `--log-vars`/`--log-rules` names are usage errors (exit 2),
    // found before the run; the model's `log` block was checked with it.
    let log_vars = match &args.log_vars {
        Some(list) if list.trim() == "*" => None,
        Some(list) => {
            let names = split_names(list);
            let (_, unknown) = info.select_vars(&names);
            if let Some(name) = unknown.first() {
                match index_note(name, &info, false) {
                    Some(note) => eprintln!("error: `--log-vars {name}`: {note}"),
                    None => {
                        let mut known = hybsim::sinks::entry_names(&info.state_layout);
                        known.extend(hybsim::sinks::entry_names(&info.output_layout));
                        eprintln!(
                            "error: `--log-vars {name}`: neither a state nor an output of the model (known: {}; a family member is `name[i]`)",
                            known.join(", ")
                        );
                    }
                }
                return Ok(EXIT_MODEL_ERROR);
            }
            Some(names)
        }
        None => model.log_decl().vars.clone(),
    };
    // `--log-rules` and `--log-marks` replace the block's `rules` and `marks`.
    let rule_flag = |flag: &str, list: &Option<String>| -> Result<Option<Vec<bool>>, u8> {
        let Some(list) = list else { return Ok(None) };
        if list.trim() == "*" {
            return Ok(Some(vec![true; info.rule_names.len()]));
        }
        select_rules(&split_names(list), &info.rule_names)
            .map(Some)
            .map_err(|name| {
                eprintln!(
                    "error: `{flag} {name}`: no jump rule of the model has that name (rules: {}; a family is `fire` or `fire[i]`, a noise's redraws `v.redraw`)",
                    info.rule_names.join(", ")
                );
                EXIT_MODEL_ERROR
            })
    };
    let (full, marks) = match (
        rule_flag("--log-rules", &args.log_rules),
        rule_flag("--log-marks", &args.log_marks),
    ) {
        (Ok(full), Ok(marks)) => (full, marks),
        (Err(code), _) | (_, Err(code)) => return Ok(code),
    };
    if let (Some(full), Some(marks)) = (&full, &marks)
        && let Some(k) = (0..full.len()).find(|&k| full[k] && marks[k])
    {
        eprintln!(
            "error: `{}` is in both `--log-rules` and `--log-marks`: a rule is logged in full or marked, not both",
            info.rule_names[k]
        );
        return Ok(EXIT_MODEL_ERROR);
    }
    if full.is_some() || marks.is_some() {
        let decl = model.log_decl();
        let flag_marks = marks.is_some();
        let marks = marks.unwrap_or_else(|| decl.marks.clone());
        // Flags win over the block: rules the flag marks leave the block's `rules`.
        let full = full.unwrap_or_else(|| {
            let mut full = decl.rules.clone();
            if flag_marks {
                full.iter_mut().zip(&marks).for_each(|(f, &m)| *f &= !m);
            }
            full
        });
        info.logged_rules = RuleLog::combine(&full, &marks);
    }
    for report in model.design_reports() {
        eprintln!("{}", report.summary_line());
    }
    let outputs = Outputs {
        mcap: if args.no_mcap {
            None
        } else {
            Some(
                args.output
                    .clone()
                    .unwrap_or_else(|| default_mcap_path(&args.model)),
            )
        },
        csv: args.csv.clone(),
        parquet: args.parquet.clone(),
        plot: args.plot.clone(),
        plot_vars,
        plot_kind: args.plot_kind.into(),
        log_vars,
        decimation: Decimation::all()
            .every(args.log_every.or(model.log_decl().every).unwrap_or(1))
            .dt(args.log_dt.or(model.log_decl().dt)),
        mcap_options: mcap_options(&args, model.log_decl()),
        progress: !args.quiet,
    };
    // A bad `--log-dt` is a usage error before anything runs, whether or
    // not a file is written (it was exit 1 from the first sink to open, and
    // passed unseen with `--no-mcap` alone).
    if let Err(e) = outputs.decimation.validate() {
        eprintln!("error: {e}");
        return Ok(EXIT_MODEL_ERROR);
    }
    if let Some(message) = output_path_clash(&args.model, &outputs) {
        eprintln!("error: {message}");
        return Ok(EXIT_MODEL_ERROR);
    }
    // The plot's format by its extension, after the clash check (a plot
    // path that is the model is named as such).
    if let Some(Err(e)) = outputs.plot.as_deref().map(ImageFormat::of) {
        eprintln!("error: {e}");
        return Ok(EXIT_MODEL_ERROR);
    }
    let output_fn = |at: HybridTime, x: &[f64], y: &mut [f64]| model.outputs(at, x, y);
    // The files' outputs: only those a log keeps, compiled on their own
    // (only when a file logs), which also re-evaluate after a jump only
    // what the jump can change.
    let logs = outputs.mcap.is_some() || outputs.csv.is_some() || outputs.parquet.is_some();
    let logged_outputs = logs.then(|| {
        let components: Vec<usize> = match &outputs.log_vars {
            Some(names) => {
                let (selected, _) = info.select_vars(names);
                let layout = selected.output_layout.components();
                layout.into_iter().map(|(k, _)| k).collect()
            }
            None => (0..info.output_dim).collect(),
        };
        model.output_subset(&components)
    });
    let logged_fn = logged_outputs.as_ref().map(|s| s as OutputFn<'_>);
    let (x0, mut rng) = model.start(seed);
    let (report, error) = simulate_to_files(
        &model,
        &x0,
        &settings,
        &mut rng,
        &info,
        Some(&output_fn),
        logged_fn,
        &outputs,
        Some(model.metrics()),
    )?;
    if let Some(e) = &error {
        eprint!(
            "{}",
            render(&[model.runtime_diagnostic(e)], &src, super::color())
        );
    }
    if let Some(stop) = report.stopped.filter(|s| s.what == "output") {
        let d = model.non_finite_output_diagnostic(stop.component, stop.value, stop.at);
        eprint!("{}", render(&[d], &src, super::color()));
    }
    if let Some(d) = report
        .termination
        .as_ref()
        .and_then(|t| model.termination_diagnostic(t))
    {
        eprint!("{}", render(&[d], &src, super::color()));
    }
    // An output on standard output (`-o -`, `--csv -`, …) owns it: the
    // summary then goes to stderr, after the data, not into it.
    let to_stdout = [&outputs.mcap, &outputs.csv, &outputs.parquet, &outputs.plot]
        .iter()
        .any(|p| p.as_deref() == Some(Path::new(atomic_file::STDOUT)));
    let say = |text: String| {
        if to_stdout {
            eprintln!("{text}");
        } else {
            println!("{text}");
        }
    };
    if args.json {
        let jit = match model.jit() {
            lang::JitStatus::Native { time, .. } => Some(time),
            _ => None,
        };
        say(summary_json(model.name(), &report, &info.rule_names, compile_time, jit).to_string());
        return Ok(exit_code(&report));
    }
    // The compile time belongs to the run's line, not after the last metric.
    let note = if compile_time.as_secs_f64() > 0.1 {
        compile_note(compile_time, &model.jit())
    } else {
        String::new()
    };
    say(summary_line(model.name(), &report, &info.rule_names, &note));
    for path in &report.written {
        eprintln!("wrote {}", path.display());
    }
    Ok(exit_code(&report))
}

/// The run's summary as JSON (`hybsim run --json`): what [`summary_line`]
/// says, for scripts; `jit_time` is the time spent generating machine code,
/// during the run as programs became hot (`null` when interpreted). Non-finite metric values are strings (`"inf"`, `"nan"`).
pub fn summary_json(
    model: &str,
    report: &Report,
    rule_names: &[String],
    compile_time: Duration,
    jit_time: Option<Duration>,
) -> Value {
    let jumps: serde_json::Map<String, Value> = report
        .tally
        .jumps
        .iter()
        .enumerate()
        .map(|(k, n)| (rule_name(rule_names, k), json!(n)))
        .collect();
    let number = |x: f64| {
        if x.is_finite() {
            json!(x)
        } else {
            json!(hybsim::num::Num(x).to_string())
        }
    };
    let metrics: serde_json::Map<String, Value> = report
        .metrics
        .iter()
        .map(|(name, v)| (name.clone(), number(*v)))
        .collect();
    json!({
        "model": model,
        "status": report.outcome.status,
        "cause": report.outcome.cause,
        "message": report.outcome.message,
        "interrupted": report.interrupted,
        "end": report.tally.end.map(|at| json!({"t": at.t, "j": at.j})),
        "jumps": jumps,
        "jumps_total": report.tally.total_jumps(),
        "samples": report.tally.samples,
        "written": report.written.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
        "wall_s": report.wall.as_secs_f64(),
        "compile_s": compile_time.as_secs_f64(),
        "jit_s": jit_time.map(|t| t.as_secs_f64()),
        "metrics": metrics,
        "solver": report.solver.name(),
        "solver_switches": report.tally.solver_switches,
        "solver_switches_total": report.tally.solver_switches_total,
    })
}

/// The message for `flag name` if `name` is neither a state nor an output
/// of `info` (an entry, a family or a member such as `xhat[2]`).
pub fn unknown_plot_var(flag: &str, name: &str, info: &RunInfo) -> Option<String> {
    if PlotSink::selects(info, name) {
        return None;
    }
    if let Some(note) = index_note(name, info, true) {
        return Some(format!("`{flag} {name}`: {note}"));
    }
    let mut known = hybsim::sinks::entry_names(&info.state_layout);
    known.extend(hybsim::sinks::entry_names(&info.output_layout));
    Some(format!(
        "`{flag} {name}`: neither a state nor an output of the model (known: {}; a family member is `name[i]`, a component `x[2]`, `P[1,2]`)",
        known.join(", ")
    ))
}

/// What is wrong with `name`, an index of an entry of `info` that selects
/// nothing (`x[0]` or `x[3]` of a 2-vector: indices start at 1; a member of a
/// family that has no such member; with `components` false, as for
/// `--log-vars`, any component, which is not chosen alone). `None` when the
/// name before the brackets names nothing either.
fn index_note(name: &str, info: &RunInfo, components: bool) -> Option<String> {
    let (base, label) = name.trim().strip_suffix(']')?.split_once('[')?;
    let base = base.trim();
    if label.contains(['[', ']']) {
        return None;
    }
    let entry = info
        .state_layout
        .find(base)
        .or_else(|| info.output_layout.find(base))?;
    Some(match entry {
        Entry::Field(f) => match f.shape {
            Shape::Scalar => format!("`{base}` is a scalar, without indices: write `{base}`"),
            _ if !components => format!(
                "`{base}` is selected whole (its components are not chosen one by one): write `{base}`"
            ),
            Shape::Vector(n) => format!(
                "`{base}` is a vector of {n}: its components are `{base}[1]` to `{base}[{n}]` (indices start at 1)"
            ),
            Shape::Matrix { rows, cols } => format!(
                "`{base}` is a {rows}×{cols} matrix: its components are `{base}[1,1]` to `{base}[{rows},{cols}]` (indices start at 1)"
            ),
        },
        Entry::Family { labels, .. } => format!(
            "the family `{base}` has the members `{base}[{}]` to `{base}[{}]`",
            labels.first()?,
            labels.last()?
        ),
    })
}

/// Splits a comma-separated list of names, keeping commas inside brackets
/// (`e[1,3],x` → `e[1,3]`, `x`); empty items are dropped.
pub fn split_names(list: &str) -> Vec<String> {
    let mut names = Vec::new();
    let mut depth = 0usize;
    let mut current = String::new();
    for ch in list.chars() {
        match ch {
            '[' => depth += 1,
            ']' => depth = depth.saturating_sub(1),
            ',' if depth == 0 => {
                names.push(std::mem::take(&mut current));
                continue;
            }
            _ => {}
        }
        current.push(ch);
    }
    names.push(current);
    names
        .into_iter()
        .map(|n| n.trim().to_string())
        .filter(|n| !n.is_empty())
        .collect()
}

/// Per rule, whether one of `names` selects it (see
/// [`RuleSelection`](hybsim::check::RuleSelection)); or the first name that
/// selects no rule.
pub fn select_rules(names: &[String], rules: &[String]) -> Result<Vec<bool>, String> {
    let mut logged = vec![false; rules.len()];
    for name in names {
        let selection = hybsim::check::RuleSelection::parse(name);
        let mut any = false;
        for (k, rule) in rules.iter().enumerate() {
            if selection.matches(rule) {
                logged[k] = true;
                any = true;
            }
        }
        if !any {
            return Err(name.clone());
        }
    }
    Ok(logged)
}

/// The MCAP encoding and compression: the flags, else the model's `log`
/// block, else the defaults.
fn mcap_options(args: &RunArgs, decl: &hybsim::check::LogDecl) -> McapOptions {
    let defaults = McapOptions::default();
    let encoding = match args.log_encoding {
        Some(LogEncodingArg::Protobuf) => Encoding::Protobuf,
        Some(LogEncodingArg::Json) => Encoding::Json,
        None => decl.encoding.unwrap_or(defaults.encoding),
    };
    let compression = match args.log_compression {
        Some(LogCompressionArg::Lz4) => Compression::Lz4,
        Some(LogCompressionArg::Zstd) => Compression::Zstd(1),
        Some(LogCompressionArg::None) => Compression::None,
        None => decl.compression.unwrap_or(defaults.compression),
    };
    let jump_states = args
        .log_jump_states
        .or(decl.jump_states)
        .unwrap_or(defaults.jump_states);
    defaults
        .encoding(encoding)
        .compression(compression)
        .jump_states(jump_states)
}

#[cfg(test)]
mod tests {
    use hybsim::engine::models::BouncingBall;

    use super::*;

    /// A family's members are summed wherever they stand: two rules per
    /// member of a loop or of a family of instances interleave them.
    #[test]
    fn the_summary_sums_interleaved_families() {
        let mut fired = vec![("start".to_string(), 1)];
        for i in 1..=10 {
            fired.push((format!("n.fire[{i}]"), 2));
            fired.push((format!("n.kicked[{i}]"), 3));
        }
        fired.extend((1..=3).map(|i| (format!("reset[{i}]"), 1)));
        fired.push(("tick".to_string(), 4));
        assert_eq!(
            jump_counts(&fired),
            [
                "start 1",
                "n.fire[…] 20 (10 rules)",
                "n.kicked[…] 30 (10 rules)",
                "reset[1] 1",
                "reset[2] 1",
                "reset[3] 1",
                "tick 4"
            ]
        );
    }

    #[test]
    fn an_unbounded_jump_horizon_is_logged_as_inf() {
        assert_eq!(settings_json(&SimSettings::default())["horizon_j"], "inf");
        let bounded = SimSettings::default().horizon_j(5);
        assert_eq!(settings_json(&bounded)["horizon_j"], 5);
    }

    fn ball_info() -> RunInfo {
        let mut info = RunInfo::new("ball", &["h", "v"], &["impact"]);
        info.solver = settings_json(&SimSettings::default());
        info
    }

    #[test]
    fn engine_runs_land_in_all_files() {
        let dir = tempfile::tempdir().unwrap();
        let ball = BouncingBall::new(9.81, 0.8);
        let settings = SimSettings::default().horizon_j(5);
        let outputs = Outputs {
            mcap: Some(dir.path().join("b.mcap")),
            csv: Some(dir.path().join("b.csv")),
            plot: Some(dir.path().join("b.svg")),
            ..Outputs::default()
        };
        let info = ball_info();
        let (report, error) = simulate_to_files(
            &ball,
            &[1.0, 0.0],
            &settings,
            &mut SimRng::seed_from(1),
            &info,
            None,
            None,
            &outputs,
            None,
        )
        .unwrap();
        assert!(error.is_none());
        assert_eq!(report.outcome.cause, "horizon_j");
        assert_eq!(report.outcome.status, RunStatus::Completed);
        assert_eq!(report.tally.jumps, [5]);
        assert_eq!(report.written.len(), 3);
        assert_eq!(exit_code(&report), EXIT_OK);
        let line = summary_line("ball", &report, &info.rule_names, "");
        assert!(
            line.contains("j = 5") && line.contains("impact 5"),
            "{line}"
        );
        // The note (compile time) ends the run's line, before the metrics.
        let mut report = report;
        report.metrics = vec![("rate".to_string(), 0.5)];
        let line = summary_line("ball", &report, &info.rule_names, "; compile 0.200 s");
        let lines: Vec<&str> = line.lines().collect();
        assert!(lines[0].ends_with(" s; compile 0.200 s"), "{line}");
        assert_eq!(lines[1..], ["  metric rate = 0.5"], "{line}");
        for f in &report.written {
            assert!(f.exists());
        }
    }
}
