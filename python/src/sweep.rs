//! `hybsim._hybsim.sweep`: a sweep of a loaded model on all cores, as the
//! `hybsim sweep` command runs it (same plan, seeds and tables), with its
//! two tables returned as numpy columns instead of files.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use hybsim::lang::CheckOptions;
use hybsim::sinks::parquet::{Column, Table};
use hybsim::sweep::{
    Axis, PlanError, Shard, SweepError, aggregate, check_threads, plan, table, thread_pool,
};
use numpy::PyArray1;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::ModelError;
use crate::convert::diagnostics_error;
use crate::model::Model;

/// How often the waiting thread runs Python's signal handlers (Ctrl-C).
const POLL_EVERY: Duration = Duration::from_millis(50);

/// `name=values` as `--grid` reads it (`lambda=0.5:0.1:0.9`,
/// `lambda=[0.5, 0.8]`): the name and the values. Raises ValueError.
#[pyfunction]
pub fn parse_axis(text: &str) -> PyResult<(String, Vec<f64>)> {
    let a: Axis = text
        .parse()
        .map_err(|e: SweepError| PyValueError::new_err(e.to_string()))?;
    Ok((a.name, a.values))
}

/// Runs a sweep of `model` over the axes `grid` (pairs `(name, values)`;
/// `None`: the model's `sweep` block) with `runs` runs per grid point and
/// base seed `seed` (each else from the block, else 1 and the model's
/// seed), on `threads` threads (default: all cores), with the GIL
/// released; Ctrl-C stops it (KeyboardInterrupt). Returns a dict: `runs`
/// and `points` (the columns of `runs.csv` and `points.csv`, typed as in
/// the Parquet files: numpy arrays, lists of str), `axes`, `metrics`,
/// `seed` and `runs_per_point`.
#[pyfunction]
#[pyo3(signature = (model, grid=None, runs=None, seed=None, threads=None))]
pub fn sweep<'py>(
    py: Python<'py>,
    model: &Model,
    grid: Option<Vec<(String, Vec<f64>)>>,
    runs: Option<u64>,
    seed: Option<u64>,
    threads: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let options = CheckOptions::default();
    let (src, fixed) = (&model.source, &model.overrides);
    let axes = grid.map(|g| {
        g.into_iter()
            .map(|(name, values)| Axis { name, values })
            .collect()
    });
    // At most `MAX_THREADS`, and no more threads than jobs (the others would
    // only look for work); rayon's global pool (all cores) by default.
    let threads = threads
        .map(|n| check_threads(n as u64))
        .transpose()
        .map_err(|e| PyValueError::new_err(format!("`threads`: {e}")))?;
    let pool =
        |jobs: u64| thread_pool(threads, jobs).map_err(|e| PyValueError::new_err(e.to_string()));
    // Planning compiles the model and grid point 0 on the same threads.
    let plan_pool = pool(2)?;
    let plan = py
        .detach(|| {
            on_pool(plan_pool.as_ref(), || {
                plan(src, fixed, axes, runs, seed, &options)
            })
        })
        .map_err(|e| match e {
            PlanError::Model(diags) => diagnostics_error::<ModelError>(py, &diags, src),
            PlanError::Spec(e) => PyValueError::new_err(e.to_string()),
        })?;
    let pool = pool(plan.spec.total_runs())?;
    let spec = &plan.spec;
    let stop = AtomicBool::new(false);
    let control = hybsim::sweep::Control {
        stop: &stop,
        ..Default::default()
    };
    // The runs go on the pool while this thread, GIL released, wakes every
    // POLL_EVERY to run the signal handlers: a KeyboardInterrupt stops the
    // runs under way at their next sample.
    let (rows, raised) = py.detach(|| {
        std::thread::scope(|scope| {
            let work = scope.spawn(|| {
                on_pool(pool.as_ref(), || {
                    hybsim::sweep::run_plan(src, fixed, &plan, Shard::ALL, &options, control)
                })
            });
            let mut raised = None;
            while !work.is_finished() {
                std::thread::sleep(POLL_EVERY);
                if raised.is_none()
                    && let Err(e) = Python::attach(|py| py.check_signals())
                {
                    raised = Some(e);
                    stop.store(true, Ordering::Relaxed);
                }
            }
            (work.join(), raised)
        })
    });
    if let Some(e) = raised {
        return Err(e);
    }
    let rows = rows.map_err(|_| PyValueError::new_err("internal error: the sweep panicked"))?;
    let manifest = table::Manifest {
        hybsim: env!("CARGO_PKG_VERSION").to_string(),
        model: model.command_model().to_string(),
        model_sha256: hybsim::source::sha256_hex(src.text().as_bytes()),
        sets: fixed
            .iter()
            .map(|o| format!("{}={}", o.name, o.value))
            .collect(),
        spec: plan.spec.clone(),
        metrics: plan.metrics.clone(),
        shard: None,
        interrupted: false,
    };
    let points = aggregate(spec, &rows);
    let out = PyDict::new(py);
    out.set_item("runs", table_dict(py, table::runs_table(&manifest, &rows))?)?;
    out.set_item(
        "points",
        table_dict(py, table::points_table(&manifest, &points))?,
    )?;
    out.set_item(
        "axes",
        spec.axes.iter().map(|a| a.name.clone()).collect::<Vec<_>>(),
    )?;
    out.set_item("metrics", plan.metrics)?;
    out.set_item("seed", spec.seed)?;
    out.set_item("runs_per_point", spec.runs)?;
    Ok(out)
}

/// Runs `f` on `pool`, else on rayon's global pool.
fn on_pool<R: Send>(pool: Option<&rayon::ThreadPool>, f: impl FnOnce() -> R + Send) -> R {
    match pool {
        Some(pool) => pool.install(f),
        None => f(),
    }
}

/// A table as a dict of columns, in order: unsigned integers and floats as
/// numpy arrays (a missing float is NaN), text as a list of str.
fn table_dict<'py>(py: Python<'py>, table: Table) -> PyResult<Bound<'py, PyDict>> {
    let out = PyDict::new(py);
    for (name, column) in table.into_columns() {
        match column {
            Column::U64(v) => out.set_item(name, PyArray1::from_vec(py, v))?,
            Column::F64(v) => out.set_item(
                name,
                PyArray1::from_vec(py, v.into_iter().map(|x| x.unwrap_or(f64::NAN)).collect()),
            )?,
            Column::Text(v) => out.set_item(name, v)?,
        }
    }
    Ok(out)
}
