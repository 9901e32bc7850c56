//! `hybsim sweep`: a grid of `--set` values × seeded runs, reduced by the
//! model's metrics, on all cores; `--shard k/n` runs a part, `--merge`
//! joins the parts.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::Instant;

use clap::Args;
use hybsim::sweep::{self, Axis, Shard, table};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use super::{EXIT_FAILED, EXIT_INTERRUPTED, EXIT_MODEL_ERROR, EXIT_OK, SdpKind};

/// Arguments of `hybsim sweep`.
#[derive(Debug, Args)]
pub struct SweepArgs {
    /// The model file (`.hyb`); it declares the `metric`s to collect, and
    /// may declare the grid in a `sweep { … }` block.
    #[arg(required_unless_present = "merge")]
    pub model: Option<PathBuf>,
    /// A grid axis (repeatable; the first varies slowest):
    /// `name=start:step:stop`, `name=[v1, v2, …]` or `name=v`. Any name
    /// `--set` accepts (parameter, initial value, `sim` key). Given, the
    /// `--grid` axes replace those of the model's `sweep` block.
    #[arg(long = "grid", value_name = "NAME=VALUES")]
    pub grid: Vec<String>,
    /// Runs per grid point, each with its own seed (default: `runs` of the
    /// model's `sweep` block, else 1).
    #[arg(long, value_parser = super::parse_positive_count)]
    pub runs: Option<u64>,
    /// Base seed of the run seeds (default: `seed` of the model's `sweep`
    /// block, else its `sim { seed }`).
    #[arg(long, value_name = "S", value_parser = super::parse_seed)]
    pub seed: Option<u64>,
    /// A fixed override for every run: `--set name=value` (repeatable).
    #[arg(long = "set", value_name = "NAME=VALUE")]
    pub set: Vec<String>,
    /// Run only part k of n of the runs (k = 1…n), e.g. a Slurm array task:
    /// `--shard $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT`.
    #[arg(long, value_name = "K/N", conflicts_with = "merge")]
    pub shard: Option<String>,
    /// Merge the results of shards (directories written with `--shard`)
    /// into `-o DIR`: the same files as an unsharded run.
    #[arg(long, value_name = "DIR", num_args = 1.., conflicts_with_all = ["grid", "set", "seed"])]
    pub merge: Vec<PathBuf>,
    /// Results directory (created if needed).
    #[arg(short = 'o', long = "output", value_name = "DIR")]
    pub output: PathBuf,
    /// Worker threads, 1 to 1024 (default: all cores, or RAYON_NUM_THREADS).
    #[arg(long, value_name = "N", value_parser = super::parse_positive_count)]
    pub threads: Option<u64>,
    /// Interior-point method of the model's design blocks.
    #[arg(long, value_enum, default_value_t = SdpKind::Auto)]
    pub sdp: SdpKind,
    /// Complete the sweep in `-o DIR`, interrupted before its end: the runs
    /// it holds are kept, the others run (the same command otherwise).
    #[arg(long, conflicts_with = "merge")]
    pub resume: bool,
    /// No progress bar.
    #[arg(short, long)]
    pub quiet: bool,
}

/// `hybsim sweep`.
pub fn execute(args: SweepArgs) -> anyhow::Result<u8> {
    if !args.merge.is_empty() {
        return match table::merge(&args.merge, &args.output) {
            Ok(written) => {
                for p in written {
                    eprintln!("wrote {}", p.display());
                }
                Ok(EXIT_OK)
            }
            Err(e) => {
                eprintln!("error: {e}");
                Ok(EXIT_FAILED)
            }
        };
    }
    let model_path = args.model.clone().expect("clap requires the model");
    let Some((src, fixed)) = super::load(&model_path, &super::ArgOverride::set(&args.set))? else {
        return Ok(EXIT_MODEL_ERROR);
    };
    let usage = |e: &dyn std::fmt::Display| {
        eprintln!("error: {e}");
        Ok(EXIT_MODEL_ERROR)
    };
    let mut axes = Vec::new();
    for g in &args.grid {
        match g.parse::<Axis>() {
            Ok(a) => axes.push(a),
            Err(e) => return usage(&e),
        }
    }
    let shard = match args.shard.as_deref().map(str::parse::<Shard>).transpose() {
        Ok(s) => s,
        Err(e) => return usage(&e),
    };
    // The model must compile as given and the axes must name what it can be
    // set by (errors located in the file); grid points that fail later are rows.
    let options = args.sdp.options();
    let axes = (!args.grid.is_empty()).then_some(axes);
    // `--threads` bounds the planning's compiles (two at once: the model
    // and grid point 0) as well as the runs.
    let threads = match args.threads.map(sweep::check_threads).transpose() {
        Ok(n) => n,
        Err(e) => return usage(&e),
    };
    let pool = sweep::thread_pool(threads, 2)?;
    let plan = match on_pool(pool.as_ref(), || {
        sweep::plan(&src, &fixed, axes, args.runs, args.seed, &options)
    }) {
        Ok(plan) => plan,
        Err(sweep::PlanError::Model(diags)) => {
            let color = super::color();
            eprint!("{}", hybsim::diagnostics::render(&diags, &src, color));
            return Ok(EXIT_MODEL_ERROR);
        }
        Err(sweep::PlanError::Spec(e)) => return usage(&e),
    };
    // Before any run: the results of a long sweep were lost when `-o` could
    // not hold them (a file, a read-only place), found only at the end.
    if let Err(e) = table::prepare_dir(&args.output) {
        eprintln!("error: {e}");
        return Ok(EXIT_FAILED);
    }
    if plan.metrics.is_empty() {
        eprintln!(
            "note: {} declares no `metric`; the rows hold only how each run ended",
            model_path.display()
        );
    }
    let spec = plan.spec.clone();
    let mut manifest = table::Manifest {
        hybsim: env!("CARGO_PKG_VERSION").to_string(),
        model: model_path.display().to_string(),
        model_sha256: hybsim::source::sha256_hex(src.text().as_bytes()),
        sets: fixed
            .iter()
            .map(|o| format!("{}={}", o.name, o.value))
            .collect(),
        spec: spec.clone(),
        metrics: plan.metrics.clone(),
        shard,
        interrupted: false,
    };
    // The runs an interrupted sweep in the output directory already holds.
    let kept = if args.resume {
        match resumed_rows(&args.output, &manifest) {
            Ok(rows) => rows,
            Err(e) => {
                eprintln!("error: {e}");
                return Ok(EXIT_FAILED);
            }
        }
    } else {
        Vec::new()
    };
    let kept_index: Vec<u64> = kept
        .iter()
        .map(|r| r.point as u64 * spec.runs + r.run)
        .collect();
    let shard = shard.unwrap_or(Shard::ALL);
    let mine = (0..spec.total_runs())
        .filter(|&i| shard.contains(i))
        .count() as u64;
    let bar = progress_bar(mine, !args.quiet);
    bar.set_position(kept.len() as u64);
    // Installed before the runs start: Ctrl-C, SIGTERM and SIGHUP stop the
    // sweep, and the runs that finished are written.
    let stop = super::progress::interrupt_flag();
    let start = Instant::now();
    let control = sweep::Control {
        done: &|| bar.inc(1),
        stop: &stop,
        skip: &|i| kept_index.binary_search(&i).is_ok(),
    };
    // No more threads than runs to do: the others would only look for work.
    let pool = sweep::thread_pool(threads, mine.saturating_sub(kept.len() as u64))?;
    let new_rows = on_pool(pool.as_ref(), || {
        sweep::run_plan(&src, &fixed, &plan, shard, &options, control)
    });
    bar.finish_and_clear();
    let ran = new_rows.len();
    let mut rows = kept;
    rows.extend(new_rows);
    rows.sort_by_key(|r| (r.point, r.run));
    manifest.interrupted = (rows.len() as u64) < mine;
    let written = table::write(&args.output, &manifest, &rows)?;
    let failed = rows
        .iter()
        .filter(|r| r.status != hybsim::sinks::RunStatus::Completed)
        .count();
    println!(
        "{}: {} runs ({} grid points × {} runs{}; {ran} run now) in {:.2} s; {} completed, \
         {failed} did not",
        manifest.model,
        rows.len(),
        spec.points(),
        spec.runs,
        if shard == Shard::ALL {
            String::new()
        } else {
            format!(", shard {shard}")
        },
        start.elapsed().as_secs_f64(),
        rows.len() - failed,
    );
    for r in rows
        .iter()
        .filter(|r| r.status != hybsim::sinks::RunStatus::Completed)
        .take(5)
    {
        let first = r.message.lines().next().unwrap_or_default();
        eprintln!("  {} ({}): {first}", manifest.command(r), r.cause);
    }
    for p in written {
        eprintln!("wrote {}", p.display());
    }
    if manifest.interrupted {
        eprintln!(
            "interrupted: {} of {mine} runs written; the same command with --resume runs the \
             other {}",
            rows.len(),
            mine - rows.len() as u64
        );
        return Ok(EXIT_INTERRUPTED);
    }
    Ok(EXIT_OK)
}

/// Runs `f` on the pool of `--threads`, else on rayon's global pool.
fn on_pool<R: Send>(pool: Option<&rayon::ThreadPool>, f: impl FnOnce() -> R + Send) -> R {
    match pool {
        Some(pool) => pool.install(f),
        None => f(),
    }
}

/// The rows of the sweep in `dir` if it is the sweep `m` (interrupted or
/// not); none if `dir` holds no sweep.
fn resumed_rows(
    dir: &std::path::Path,
    m: &table::Manifest,
) -> Result<Vec<table::RunRow>, hybsim::sweep::SweepError> {
    if !dir.join("sweep.json").exists() {
        return Ok(Vec::new());
    }
    let (old, rows) = table::read(dir)?;
    if (table::Manifest {
        interrupted: false,
        ..old
    }) != *m
    {
        return Err(hybsim::sweep::SweepError::Merge(format!(
            "{} holds another sweep (model, --set, grid, runs, seed, shard or hybsim version \
             differ): --resume continues only the same command",
            dir.display()
        )));
    }
    Ok(rows)
}

/// A bar with ETA on stderr, only if it is a terminal and `show`.
fn progress_bar(len: u64, show: bool) -> ProgressBar {
    let target = if show && std::io::stderr().is_terminal() {
        ProgressDrawTarget::stderr_with_hz(10)
    } else {
        ProgressDrawTarget::hidden()
    };
    let bar = ProgressBar::with_draw_target(Some(len), target);
    bar.set_style(
        ProgressStyle::with_template("[{elapsed_precise}] {wide_bar} {pos}/{len} runs, ETA {eta}")
            .expect("a valid template"),
    );
    bar
}
