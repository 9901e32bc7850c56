//! `Model.run(**sim)`: simulation settings from Python keywords, over the
//! model's `sim` block (the keywords of `hybsim run`'s flags).

use hybsim::engine::{
    ExactAffine, JumpChoice, LinearSolver, Priority, SimError, SimSettings, Solver,
};
use hybsim::ir::CompiledModel;
use pyo3::exceptions::{PyOverflowError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict};

/// The keywords `Model.run` accepts besides `T`, `J` and `seed`.
pub const KEYS: [&str; 17] = [
    "T",
    "J",
    "dt_out",
    "solver",
    "rtol",
    "atol",
    "step",
    "max_step",
    "priority",
    "jump_choice",
    "event_tol",
    "guard_checks",
    "zeno_max_rate",
    "zeno_window",
    "max_total_jumps",
    "exact_affine",
    "linear_solver",
];

fn get<'py, T: FromPyObjectOwned<'py>>(sim: &Bound<'py, PyDict>, key: &str) -> PyResult<Option<T>> {
    match sim.get_item(key)? {
        None => Ok(None),
        Some(v) if v.is_none() => Ok(None),
        // Python's bool is an int: `T=True` ran to T = 1.
        Some(v) if v.is_instance_of::<PyBool>() => Err(PyTypeError::new_err(format!(
            "`{key}`: a bool is not a value of `{key}`"
        ))),
        Some(v) => v.extract::<T>().map(Some).map_err(|e| {
            let e: PyErr = e.into();
            let msg = format!("`{key}`: {}", e.value(sim.py()));
            // An int outside the keyword's range (`J=-1`) is the right type with a wrong value.
            if e.is_instance_of::<PyOverflowError>(sim.py()) {
                PyValueError::new_err(msg)
            } else {
                PyTypeError::new_err(msg)
            }
        }),
    }
}

/// The keyword `J` as a `sim` block takes it: a whole number of jumps ≥ 0,
/// an int or a float (`1e6`), or `inf` (no bound; counts from 2⁶⁴ up are
/// that bound too).
fn jump_horizon(sim: &Bound<'_, PyDict>) -> PyResult<Option<u64>> {
    let Some(v) = sim.get_item("J")?.filter(|v| !v.is_none()) else {
        return Ok(None);
    };
    if v.is_instance_of::<PyBool>() {
        return get::<u64>(sim, "J");
    }
    if let Ok(j) = v.extract::<u64>() {
        return Ok(Some(j));
    }
    match v.extract::<f64>() {
        Ok(x) if x >= 0.0 && (x.fract() == 0.0 || x == f64::INFINITY) => {
            Ok(Some(x.min(u64::MAX as f64) as u64))
        }
        Ok(x) => Err(PyValueError::new_err(format!(
            "`J`: a whole number of jumps ≥ 0, or inf (no bound), got {x}"
        ))),
        // Not a number: the usual message.
        Err(_) => get::<u64>(sim, "J"),
    }
}

/// The keyword `exact_affine` as a `sim` block takes it, `"auto"`, `"on"`
/// or `"off"`, or a bool (`True` is `"on"`): only the bool was taken, so
/// `"auto"` could not undo a model's `exact_affine = off`.
fn exact_affine(sim: &Bound<'_, PyDict>) -> PyResult<Option<ExactAffine>> {
    let Some(v) = sim.get_item("exact_affine")?.filter(|v| !v.is_none()) else {
        return Ok(None);
    };
    if let Ok(on) = v.extract::<bool>() {
        return Ok(Some(on.into()));
    }
    let Ok(name) = v.extract::<String>() else {
        return Err(PyTypeError::new_err(format!(
            "`exact_affine`: \"auto\", \"on\", \"off\" or a bool, not {}",
            v.get_type().name()?
        )));
    };
    match name.as_str() {
        "auto" => Ok(Some(ExactAffine::Auto)),
        "on" => Ok(Some(ExactAffine::On)),
        "off" => Ok(Some(ExactAffine::Off)),
        other => Err(PyValueError::new_err(format!(
            "exact_affine `{other}`: use \"auto\", \"on\" or \"off\" (or True, False)"
        ))),
    }
}

/// `model`'s settings with the keywords of `sim` applied, validated for the
/// model (a `solver` that cannot integrate its white noise is a `ValueError`).
pub fn apply(model: &CompiledModel, sim: &Bound<'_, PyDict>) -> PyResult<SimSettings> {
    let mut settings = model.settings();
    for key in sim.keys() {
        let key: String = key.extract()?;
        if !KEYS.contains(&key.as_str()) {
            return Err(PyTypeError::new_err(format!(
                "run() got an unexpected keyword `{key}`; the simulation keywords are: {}",
                KEYS.join(", ")
            )));
        }
    }
    if let Some(t) = get::<f64>(sim, "T")? {
        settings = settings.horizon_t(t);
    }
    if let Some(j) = jump_horizon(sim)? {
        settings = settings.horizon_j(j);
    }
    if let Some(dt) = get::<f64>(sim, "dt_out")? {
        settings = settings.dt_out(Some(dt));
    }
    if let Some(h) = get::<f64>(sim, "max_step")? {
        settings = settings.max_step(h);
    }
    if let Some(tol) = get::<f64>(sim, "event_tol")? {
        settings = settings.event_tol(tol);
    }
    if let Some(n) = get::<u32>(sim, "guard_checks")? {
        settings = settings.guard_checks(n);
    }
    if let Some(r) = get::<f64>(sim, "zeno_max_rate")? {
        settings = settings.zeno_max_rate(r);
    }
    if let Some(w) = get::<u32>(sim, "zeno_window")? {
        settings = settings.zeno_window(w);
    }
    if let Some(n) = get::<u64>(sim, "max_total_jumps")? {
        settings = settings.max_total_jumps(n);
    }
    if let Some(mode) = exact_affine(sim)? {
        settings = settings.exact_affine(mode);
    }
    if let Some(name) = get::<String>(sim, "linear_solver")? {
        settings = settings.linear_solver(LinearSolver::from_name(&name).ok_or_else(|| {
            PyValueError::new_err(format!(
                "linear_solver `{name}`: use \"auto\", \"dense\" or \"sparse\""
            ))
        })?);
    }
    if let Some(name) = get::<String>(sim, "jump_choice")? {
        settings = settings.jump_choice(JumpChoice::from_name(&name).ok_or_else(|| {
            PyValueError::new_err(format!("jump_choice `{name}`: use \"first\" or \"random\""))
        })?);
    }
    if let Some(p) = get::<String>(sim, "priority")? {
        settings = settings.priority(match p.as_str() {
            "jumps" => Priority::Jumps,
            "flows" => Priority::Flows,
            "random" => Priority::Random,
            other => {
                return Err(PyValueError::new_err(format!(
                    "priority `{other}`: use \"jumps\", \"flows\" or \"random\""
                )));
            }
        });
    }
    let solver = solver(
        settings.solver,
        model.solver_keys(),
        get::<String>(sim, "solver")?,
        get::<f64>(sim, "rtol")?,
        get::<f64>(sim, "atol")?,
        get::<f64>(sim, "step")?,
    )?;
    let settings = settings.solver(solver);
    settings.validate_for(model).map_err(|e| match e {
        SimError::NoiseNeedsEulerMaruyama { .. } => PyValueError::new_err(format!(
            "solver=\"{}\": the model's flows have white noise (`wiener`), which only \
             solver=\"euler_maruyama\" integrates",
            solver.name()
        )),
        // Named as the caller's keyword, not the engine's field.
        SimError::InvalidSettings { field, reason } => {
            let e = SimError::InvalidSettings {
                field: keyword(field),
                reason,
            };
            PyValueError::new_err(format!("{e}; {}", e.help()))
        }
        e => PyValueError::new_err(format!("{e}; {}", e.help())),
    })?;
    // Keywords change the horizon and steps after the check: held to its limits
    // (a `dt_out` of 1e-300 would otherwise run for ever).
    if let Some((key, why)) = model.over_limit(&settings) {
        // A step too small that the model's `h` gave comes with `solver`.
        let kw = match key {
            "h" if get::<f64>(sim, "step")?.is_none() => "solver",
            "h" => "step",
            key => key,
        };
        return Err(PyValueError::new_err(format!("`{kw}`: {why}")));
    }
    Ok(settings)
}

/// The keyword of `run()` that sets the engine's settings field `field`
/// (`SimError::InvalidSettings` names fields), so that an error names what
/// the caller wrote.
fn keyword(field: &'static str) -> &'static str {
    match field {
        "horizon_t" => "T",
        "horizon_j" => "J",
        "solver.rtol" => "rtol",
        "solver.atol" => "atol",
        "solver.h" => "step",
        f => f,
    }
}

/// The solver after the keywords: a name keeps the model's tolerances or
/// step where they apply; tolerances go with the adaptive solvers, `step`
/// with the fixed-step ones.
fn solver(
    current: Solver,
    keys: hybsim::check::SolverKeys,
    name: Option<String>,
    rtol: Option<f64>,
    atol: Option<f64>,
    step: Option<f64>,
) -> PyResult<Solver> {
    // The current solver's keys, else those the model's `sim` block gave for another kind.
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
    let name = name.unwrap_or_else(|| current.name().to_string());
    let adaptive = |make: fn(f64, f64) -> Solver| {
        if step.is_some() {
            return Err(PyValueError::new_err(
                "`step` applies to the fixed-step solvers; use solver=\"rk4\" or `max_step`",
            ));
        }
        Ok(make(rtol.unwrap_or(rtol0), atol.unwrap_or(atol0)))
    };
    let fixed = |make: fn(f64) -> Solver| {
        if rtol.is_some() || atol.is_some() {
            return Err(PyValueError::new_err(
                "`rtol`/`atol` apply to the adaptive solvers \"dopri5\", \"dop853\", \"radau5\", \"bdf\" and \"auto\"",
            ));
        }
        // As the `sim` block and the command line: the default step where
        // none is given.
        Ok(make(
            step.or(h0).unwrap_or(hybsim::engine::DEFAULT_FIXED_STEP),
        ))
    };
    match name.replace('-', "_").as_str() {
        "dopri5" => adaptive(|rtol, atol| Solver::Dopri5 { rtol, atol }),
        "dop853" => adaptive(|rtol, atol| Solver::Dop853 { rtol, atol }),
        "radau5" => adaptive(|rtol, atol| Solver::Radau5 { rtol, atol }),
        "bdf" => adaptive(|rtol, atol| Solver::Bdf { rtol, atol }),
        "auto" => adaptive(|rtol, atol| Solver::Auto { rtol, atol }),
        "rk4" => fixed(|h| Solver::Rk4 { h }),
        "euler_maruyama" => fixed(|h| Solver::EulerMaruyama { h }),
        other => Err(PyValueError::new_err(format!(
            "solver `{other}`: use \"dopri5\", \"dop853\", \"radau5\", \"bdf\", \"auto\", \"rk4\" or \"euler_maruyama\""
        ))),
    }
}
