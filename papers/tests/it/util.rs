//! Helpers shared by the reproduction tests.

use hybsim::arc::HybridArc;
use hybsim::engine::{HybridSystem, SimError, SimRng, SimSettings};
use hybsim::lang::{self, CompiledModel, Override};
use hybsim::source::SourceFile;

/// `hybsim::engine::simulate_arc`, and every arc it returns checked with
/// `engine::check_arc` (each jump starts from a point of D, each flow in C
/// within `set_tol`), as the library's integration tests do.
pub fn simulate_arc<S: HybridSystem + ?Sized>(
    sys: &S,
    x0: &[f64],
    settings: &SimSettings,
    rng: &mut SimRng,
) -> Result<HybridArc, SimError> {
    let arc = hybsim::engine::simulate_arc(sys, x0, settings, rng)?;
    if let Err(violation) = hybsim::engine::check_arc(sys, &arc, settings) {
        panic!("the arc breaks the engine's invariants: {violation}");
    }
    Ok(arc)
}

/// Compiles the shipped model `models/NAME` with `--set` overrides; panics
/// with the rendered diagnostics if it does not compile.
pub fn load(name: &str, overrides: &[&str]) -> CompiledModel {
    let src = SourceFile::read(hybsim_papers::model_path(name)).expect("model file");
    let ov: Vec<Override> = overrides.iter().map(|s| s.parse().unwrap()).collect();
    match lang::compile(&src, &ov) {
        Ok(m) => m,
        Err(d) => panic!("{}", hybsim::diagnostics::render(&d, &src, false)),
    }
}

/// Runs `m` from its initial state with its own seed and settings.
pub fn run(m: &CompiledModel) -> HybridArc {
    let (x0, mut rng) = m.start(m.seed());
    simulate_arc(m, &x0, &m.settings(), &mut rng).expect("simulation")
}

/// A sweep of a shipped model run as `hybsim sweep models/NAME` runs it:
/// [`hybsim::sweep::plan`] on the model's own `metric` and `sweep { }`
/// declarations (`--grid` axes and `--runs` replacing the block's when
/// given), [`hybsim::sweep::run_plan`] on rayon's pool, and the per-point table
/// of [`hybsim::sweep::aggregate`] (`points.csv`).
pub struct ModelSweep {
    /// The model's metric names (the tables' metric columns).
    pub metrics: Vec<String>,
    /// One row per run (`runs.csv`), in grid order.
    pub rows: Vec<hybsim::sweep::RunRow>,
    /// One row per grid point (`points.csv`).
    pub points: Vec<hybsim::sweep::PointRow>,
}

impl ModelSweep {
    /// Column of metric `name`.
    pub fn metric(&self, name: &str) -> usize {
        self.metrics
            .iter()
            .position(|m| m == name)
            .unwrap_or_else(|| panic!("no metric `{name}` in {:?}", self.metrics))
    }

    /// Statistics of metric `name` at grid point `p` over its completed runs.
    pub fn stats(&self, p: usize, name: &str) -> hybsim::sweep::Stats {
        let k = self.metric(name);
        self.points[p].stats.get(k).copied().unwrap_or_default()
    }

    /// Metric `name` of every completed run of grid point `p`, in run order.
    pub fn values(&self, p: usize, name: &str) -> Vec<f64> {
        let k = self.metric(name);
        self.rows
            .iter()
            .filter(|r| r.point == p && !r.metrics.is_empty())
            .map(|r| r.metrics[k])
            .collect()
    }

    /// Runs that did not complete (reach a horizon).
    pub fn incomplete(&self) -> usize {
        self.rows
            .iter()
            .filter(|r| r.status != hybsim::sinks::RunStatus::Completed)
            .count()
    }
}

/// `hybsim sweep models/NAME --set SETS… [--grid GRID…] [--runs RUNS]`,
/// in-process; panics with the rendered diagnostics if it cannot start.
pub fn model_sweep(name: &str, sets: &[&str], grid: &[&str], runs: Option<u64>) -> ModelSweep {
    use hybsim::sweep::{self, Axis, PlanError, Shard};
    let src = SourceFile::read(hybsim_papers::model_path(name)).expect("model file");
    let fixed: Vec<Override> = sets.iter().map(|s| s.parse().unwrap()).collect();
    let axes = (!grid.is_empty()).then(|| {
        grid.iter()
            .map(|g| g.parse::<Axis>().unwrap_or_else(|e| panic!("{e}")))
            .collect()
    });
    let options = Default::default();
    let plan = match sweep::plan(&src, &fixed, axes, runs, None, &options) {
        Ok(plan) => plan,
        Err(PlanError::Model(d)) => panic!("{}", hybsim::diagnostics::render(&d, &src, false)),
        Err(PlanError::Spec(e)) => panic!("{e}"),
    };
    let rows = sweep::run_plan(
        &src,
        &fixed,
        &plan,
        Shard::ALL,
        &options,
        Default::default(),
    );
    let points = sweep::aggregate(&plan.spec, &rows);
    ModelSweep {
        metrics: plan.metrics,
        rows,
        points,
    }
}
