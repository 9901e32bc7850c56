//! `hybsim._hybsim.Model`: a compiled `.hyb` model and its three verbs,
//! run, design and test, each with the GIL released.

use std::sync::Arc;

use hybsim::arc::{HybridTime, Termination};
use hybsim::diagnostics::Diagnostic;
use hybsim::engine::{HybridSystem, SimError, simulate};
use hybsim::lang::{self, CompiledModel, Override};
use hybsim::props::{
    ModelRunError, ModelSubject, Outcome, Property, TestConfig, replay_args, run_tests_each,
};
use hybsim::source::SourceFile;
use numpy::{PyArray1, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::{PyMemoryError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::convert::{columns, diagnostics_error, json, matrix};
use crate::record::{Recorder, user_states};
use crate::{ModelError, SimulationError, settings};

/// A compiled `.hyb` model (see `hybsim.load`).
#[pyclass(frozen, module = "hybsim._hybsim")]
pub struct Model {
    pub(crate) source: SourceFile,
    pub(crate) overrides: Vec<Override>,
    model: Arc<CompiledModel>,
    /// The file it was read from, for replay commands.
    pub(crate) path: Option<String>,
}

/// Parses, checks and compiles the model `text` named `name` (its file
/// path, or a label) with the overrides `set` (pairs `(name, value)`, the
/// value a `.hyb` expression). `path` is the file it came from, if any.
/// Raises `ModelError` with every diagnostic.
#[pyfunction]
#[pyo3(signature = (name, text, set, path=None))]
pub fn compile(
    py: Python<'_>,
    name: String,
    text: String,
    set: Vec<(String, String)>,
    path: Option<String>,
) -> PyResult<Model> {
    // As `hybsim run` reads a model: checking takes ~200 bytes of memory a
    // byte of text, so a text past the limit is refused, not checked.
    if text.len() as u64 > hybsim::source::MAX_SOURCE_BYTES {
        return Err(PyValueError::new_err(format!(
            "`{name}`: more than {} MiB, the limit for a model's text",
            hybsim::source::MAX_SOURCE_BYTES >> 20
        )));
    }
    let source = SourceFile::new(name, text);
    let mut overrides = Vec::new();
    let mut problems: Vec<Diagnostic> = Vec::new();
    for (k, v) in &set {
        match format!("{k}={v}").parse::<Override>() {
            Ok(o) => overrides.push(o),
            Err(d) => problems.push(d),
        }
    }
    if !problems.is_empty() {
        return Err(diagnostics_error::<ModelError>(py, &problems, &source));
    }
    let model = py
        .detach(|| lang::compile(&source, &overrides))
        .map_err(|diags| diagnostics_error::<ModelError>(py, &diags, &source))?;
    Ok(Model {
        source,
        overrides,
        model: Arc::new(model),
        path,
    })
}

impl Model {
    /// The model a run with seed `seed` simulates, compiled anew when it
    /// has random parameters (drawn from the seed, as `hybsim run` does),
    /// and the seed.
    fn for_run(&self, py: Python<'_>, seed: Option<u64>) -> PyResult<(Arc<CompiledModel>, u64)> {
        if self.model.random_params().is_empty() {
            return Ok((self.model.clone(), seed.unwrap_or(self.model.seed())));
        }
        let (m, seed) = py
            .detach(|| lang::compile_run(&self.source, &self.overrides, seed))
            .map_err(|diags| diagnostics_error::<ModelError>(py, &diags, &self.source))?;
        Ok((Arc::new(m), seed))
    }
}

/// A termination as a dict: `cause` (`horizon_t`, `horizon_j`,
/// `zeno_suspected`, `cannot_flow_or_jump`, `stopped_by_sink`) and its
/// fields, `t`, `j`, `message` and `help`.
fn termination<'py>(py: Python<'py>, term: &Termination) -> PyResult<Bound<'py, PyAny>> {
    let mut value =
        serde_json::to_value(&term.cause).map_err(|e| PyValueError::new_err(e.to_string()))?;
    if let Some(map) = value.as_object_mut() {
        map.insert("t".into(), serde_json::json!(term.at.t));
        map.insert("j".into(), serde_json::json!(term.at.j));
        map.insert("message".into(), serde_json::json!(term.to_string()));
        map.insert("help".into(), serde_json::json!(term.help()));
    }
    json(py, &value)
}

/// The recorded columns as the dict `hybsim.Solution` is built from.
fn solution_dict<'py>(
    py: Python<'py>,
    model: &Arc<CompiledModel>,
    seed: u64,
    rec: Recorder,
) -> PyResult<Bound<'py, PyDict>> {
    let n = rec.len();
    let width = rec.columns.len();
    let out = PyDict::new(py);
    out.set_item("model", model.name())?;
    out.set_item("seed", seed)?;
    out.set_item("t", PyArray1::from_vec(py, rec.t))?;
    out.set_item("j", PyArray1::from_vec(py, rec.j))?;
    out.set_item("kind", PyArray1::from_vec(py, rec.kind))?;
    // The user's states in the order of `hybsim run --csv` (the recorder kept only those).
    out.set_item("x", columns(py, rec.x, n, width)?)?;
    out.set_item("names", user_states(model).1)?;
    out.set_item(
        "outputs",
        OutputMap {
            model: model.clone(),
            states: rec.columns,
        },
    )?;
    out.set_item("output_names", model.output_names())?;
    // The outputs in the order of the CSV: families grouped as the layout groups them.
    let output_columns: Vec<usize> = (model.output_layout().components().into_iter())
        .map(|(k, _)| k)
        .collect();
    out.set_item("output_columns", output_columns)?;
    out.set_item("rule_names", model.rule_names())?;
    let jumps = PyDict::new(py);
    jumps.set_item("rule", PyArray1::from_vec(py, rec.jump_rule))?;
    jumps.set_item("t", PyArray1::from_vec(py, rec.jump_t))?;
    jumps.set_item("j", PyArray1::from_vec(py, rec.jump_j))?;
    jumps.set_item("row", PyArray1::from_vec(py, rec.jump_row))?;
    out.set_item("jumps", jumps)?;
    match &rec.termination {
        Some(term) => out.set_item("termination", termination(py, term)?)?,
        None => out.set_item("termination", py.None())?,
    }
    let switches = PyList::empty(py);
    for sw in &rec.switches {
        let d = PyDict::new(py);
        d.set_item("t", sw.at.t)?;
        d.set_item("j", sw.at.j)?;
        d.set_item("to", sw.to)?;
        switches.append(d)?;
    }
    out.set_item("solver_switches", switches)?;
    out.set_item("parameters", json(py, &model.parameters_json())?)?;
    Ok(out)
}

/// The outputs of the model a solution came from: `outputs(t, x, j)` evaluates
/// them at every row (GIL released). `Solution.y` calls it on first use, so
/// runs whose outputs are not read do not pay for them.
#[pyclass(frozen, module = "hybsim._hybsim")]
pub struct OutputMap {
    model: Arc<CompiledModel>,
    /// The state component of each column of the `x` it is given (a solution's: the user's
    /// states, no timers; outputs do not read timers, which stay 0).
    states: Vec<usize>,
}

#[pymethods]
impl OutputMap {
    /// One name per output component.
    #[getter]
    fn names(&self) -> Vec<String> {
        self.model.output_names()
    }

    /// The outputs at times `t` (n,), states `x` (n, d) and jump counts
    /// `j` (n,) (int64; default 0, for outputs that use `j`): an (n, m)
    /// array.
    #[pyo3(signature = (t, x, j = None))]
    fn __call__<'py>(
        &self,
        py: Python<'py>,
        t: PyReadonlyArray1<'py, f64>,
        x: PyReadonlyArray2<'py, f64>,
        j: Option<PyReadonlyArray1<'py, i64>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let t = t.as_array();
        let x = x.as_array();
        let j = j.as_ref().map(|j| j.as_array());
        let (n, d) = x.dim();
        if j.as_ref().is_some_and(|j| j.len() != n) {
            return Err(PyValueError::new_err(format!(
                "outputs need j of shape ({n},) like t"
            )));
        }
        if t.len() != n || d != self.states.len() {
            return Err(PyValueError::new_err(format!(
                "outputs need t of shape (n,) and x of shape (n, {}); got {} and {:?}",
                self.states.len(),
                t.len(),
                (n, d)
            )));
        }
        let m = self.model.output_dim();
        let model = &self.model;
        let (y, fault) = py.detach(|| {
            // A fault another evaluation left on this thread is not this one's.
            let _ = model.take_fault();
            let mut y = vec![0.0; n * m];
            let mut row = vec![0.0; model.state_dim()];
            if m > 0 {
                for (i, out) in y.chunks_exact_mut(m).enumerate() {
                    for (&k, v) in self.states.iter().zip(x.row(i)) {
                        row[k] = *v;
                    }
                    let jumps = j.as_ref().map_or(0, |j| j[i].max(0) as u64);
                    model.outputs(HybridTime::new(t[i], jumps), &row, out);
                    // A run-time index out of range (E0604) leaves NaN in the output:
                    // an error, as `hybsim run` reports it for a logged output, not a
                    // NaN column. The diagnostic reads the fault on this thread, now.
                    if let Some(f) = model.take_fault() {
                        return (y, Some(model.runtime_diagnostic(&SimError::from(f))));
                    }
                }
            }
            (y, None)
        });
        if let Some(d) = fault {
            return Err(diagnostics_error::<SimulationError>(
                py,
                &[d],
                model.source(),
            ));
        }
        columns(py, y, n, m)
    }
}

/// The `hybsim run` command that replays a counterexample case (as
/// `hybsim test` prints it), as a list of arguments.
fn replay_command(path: &str, subject: &ModelSubject, case: &hybsim::props::Case) -> Vec<String> {
    let inputs = hybsim::props::Subject::inputs(subject);
    let mut cmd = vec!["hybsim".to_string(), "run".to_string(), path.to_string()];
    for o in subject.overrides() {
        if !inputs.iter().any(|i| i.name == o.name) {
            cmd.push("--set".into());
            cmd.push(format!("{}={}", o.name, o.value));
        }
    }
    cmd.extend(replay_args(case, inputs));
    cmd.extend(["-o".to_string(), "replay.mcap".to_string()]);
    cmd
}

impl Model {
    /// The model argument of the `hybsim run` commands that replay its
    /// runs: its file, or `-` (the text on standard input) for a model given
    /// as text, whose label (`<string>`) names no file.
    pub(crate) fn command_model(&self) -> &str {
        self.path.as_deref().unwrap_or("-")
    }
}

#[pymethods]
impl Model {
    /// The model's name (`model NAME`).
    #[getter]
    fn name(&self) -> &str {
        self.model.name()
    }

    /// The file name or label of the source.
    #[getter]
    fn file(&self) -> &str {
        self.source.name()
    }

    /// The path the model was read from, or None.
    #[getter]
    fn path(&self) -> Option<&str> {
        self.path.as_deref()
    }

    /// The model's source text.
    #[getter]
    fn source(&self) -> &str {
        self.source.text()
    }

    /// The overrides applied, as `(name, value)` pairs.
    #[getter]
    fn overrides(&self) -> Vec<(String, String)> {
        self.overrides
            .iter()
            .map(|o| (o.name.clone(), o.value.clone()))
            .collect()
    }

    /// One name per scalar state component (`h`, `x[2]`, `P[1,2]`) the model declares (not the
    /// timers the language adds), in the order of `Solution.names`.
    #[getter]
    fn state_names(&self) -> Vec<String> {
        user_states(&self.model).1
    }

    /// One name per scalar output component.
    #[getter]
    fn output_names(&self) -> Vec<String> {
        self.model.output_names()
    }

    /// Names of the jump rules, in declaration order.
    #[getter]
    fn rule_names(&self) -> Vec<String> {
        self.model.rule_names()
    }

    /// Names of the declared properties, in order.
    #[getter]
    fn property_names(&self) -> Vec<String> {
        self.model
            .properties()
            .iter()
            .map(|p| p.name().to_string())
            .collect()
    }

    /// The seed of `sim { seed }` (default 0).
    #[getter]
    fn seed(&self) -> u64 {
        self.model.seed()
    }

    /// Resolved parameters (after overrides and design blocks): name ->
    /// float, 1-D array (vectors) or 2-D array (matrices).
    #[getter]
    fn parameters<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let out = PyDict::new(py);
        for (name, _) in self
            .model
            .parameters_json()
            .as_object()
            .into_iter()
            .flatten()
        {
            if let Some(m) = self.model.parameter(name) {
                // nalgebra is column-major: transpose to get row-major values.
                let values: Vec<f64> = m.transpose().iter().copied().collect();
                out.set_item(name, matrix(py, (m.nrows(), m.ncols()), &values)?)?;
            }
        }
        Ok(out)
    }

    /// Simulates the model (the GIL is released; Ctrl-C stops it with
    /// KeyboardInterrupt). `seed`: the run's seed (default: the model's);
    /// `sim`: settings over the model's `sim` block. Returns the columns
    /// `hybsim.Solution` wraps.
    #[pyo3(signature = (seed=None, sim=None))]
    fn run<'py>(
        &self,
        py: Python<'py>,
        seed: Option<u64>,
        sim: Option<&Bound<'py, PyDict>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let (shared, seed) = self.for_run(py, seed)?;
        let model: &CompiledModel = &shared;
        let settings = settings::apply(model, &sim.cloned().unwrap_or(PyDict::new(py)))?;
        let (result, mut rec, diagnostic) = py.detach(|| {
            let (x0, mut rng) = model.start(seed);
            let mut rec = Recorder::new(user_states(model).0, model.state_dim());
            let result = simulate(model, &x0, &settings, &mut rng, &mut rec);
            // The diagnostic reads where the fault happened: on this thread, now.
            let diagnostic = result
                .as_ref()
                .err()
                .map(|e: &SimError| model.runtime_diagnostic(e));
            (result, rec, diagnostic)
        });
        if let Some(e) = rec.interrupt.raised.take() {
            return Err(e);
        }
        if rec.out_of_memory {
            return Err(PyMemoryError::new_err(format!(
                "the solution does not fit in memory: it was stopped after {} samples of {} \
                 states at t = {}; sample it more sparsely (`dt_out`), shorten the horizon, or \
                 stream it to files with `hybsim run`",
                rec.len(),
                rec.columns.len(),
                rec.t.last().copied().unwrap_or(0.0)
            )));
        }
        let solution = solution_dict(py, &shared, seed, rec)?;
        match (result, diagnostic) {
            (Err(_), Some(d)) => {
                let err = diagnostics_error::<SimulationError>(py, &[d], &self.source);
                err.value(py).setattr("partial", solution)?;
                Err(err)
            }
            _ => Ok(solution),
        }
    }

    /// Solves the `design` and `check` blocks (as `hybsim design`, GIL
    /// released): `{block: {"name", "status", …, "results": {name: value},
    /// "summary", "check", "check_failed"}}`, values as numpy (a float for
    /// scalars), the other fields as `hybsim design --json` prints them.
    fn design<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let reports = py
            .detach(|| lang::design_only(&self.source, &self.overrides))
            .map_err(|diags| diagnostics_error::<ModelError>(py, &diags, &self.source))?;
        let out = PyDict::new(py);
        for r in &reports {
            let block = json(py, &r.to_json())?.cast_into::<PyDict>()?;
            let results = PyDict::new(py);
            for (name, dims, values) in &r.results {
                results.set_item(name, matrix(py, *dims, values)?)?;
            }
            block.set_item("results", results)?;
            block.set_item("summary", r.summary_line())?;
            block.set_item("check", r.check)?;
            block.set_item("check_failed", r.check_failed())?;
            out.set_item(&r.name, block)?;
        }
        Ok(out)
    }

    /// Property test (as `hybsim test`, GIL released): `cases` sampled
    /// cases (default: 100, 1 for a model without random draws) from
    /// master seed `seed` (default: the model's), checking the named
    /// `properties` (default: all); the first failure is shrunk in at most
    /// `max_shrink` runs. Returns the report as a dict.
    #[pyo3(signature = (cases=None, seed=None, properties=None, max_shrink=400))]
    fn test<'py>(
        &self,
        py: Python<'py>,
        cases: Option<usize>,
        seed: Option<u64>,
        properties: Option<Vec<String>>,
        max_shrink: usize,
    ) -> PyResult<Bound<'py, PyDict>> {
        let subject = py
            .detach(|| ModelSubject::new(self.source.clone(), self.overrides.clone()))
            .map_err(|diags| diagnostics_error::<ModelError>(py, &diags, &self.source))?;
        let model = subject.model();
        let all = model.properties();
        if all.is_empty() {
            return Err(PyValueError::new_err(format!(
                "model `{}` declares no property; add e.g. `property ground: always h >= -1e-9`",
                model.name()
            )));
        }
        let mut props: Vec<Property> = Vec::new();
        for name in properties.unwrap_or_default() {
            match all.iter().find(|p| p.name() == name) {
                // Named twice, tested (and listed) once.
                Some(_) if props.iter().any(|q| q.name() == name) => {}
                Some(p) => props.push(p.clone()),
                None => {
                    let names: Vec<&str> = all.iter().map(|p| p.name()).collect();
                    return Err(PyValueError::new_err(format!(
                        "no property `{name}` in model `{}`; it declares: {}",
                        model.name(),
                        names.join(", ")
                    )));
                }
            }
        }
        if props.is_empty() {
            props = all;
        }
        let config = TestConfig::default()
            .cases(cases.unwrap_or(subject.default_cases()))
            .seed(seed.unwrap_or(model.seed()))
            .max_shrink_runs(max_shrink);
        let reports = py.detach(|| run_tests_each(&subject, &props, &config));
        let inputs = hybsim::props::Subject::inputs(&subject);
        let state_names = hybsim::props::Subject::state_names(&subject);
        let report_names = hybsim::props::Subject::report_names(&subject);
        let rule_names = subject.model().rule_names();

        let out = PyDict::new(py);
        out.set_item("model", model.name())?;
        out.set_item("passed", reports.iter().all(|r| r.passed()))?;
        out.set_item("cases", cases)?;
        let most = |count: fn(&hybsim::props::TestReport<_>) -> usize| {
            reports.iter().map(count).max().unwrap_or(0)
        };
        out.set_item("cases_run", most(|r| r.cases_run))?;
        out.set_item("inconclusive", most(|r| r.inconclusive))?;
        out.set_item("seed", config.seed)?;
        out.set_item(
            "properties",
            props.iter().map(|p| p.to_string()).collect::<Vec<_>>(),
        )?;
        out.set_item(
            "inputs",
            inputs
                .iter()
                .map(|i| (i.name.clone(), i.dist.to_string()))
                .collect::<Vec<_>>(),
        )?;
        out.set_item("counterexample", py.None())?;
        out.set_item("error", py.None())?;
        let path = self.command_model();
        // Every failing property's counterexample (`counterexample`: the first).
        let counterexamples = PyList::empty(py);
        out.set_item("outcome", "passed")?;
        for report in &reports {
            match &report.outcome {
                Outcome::Passed => {}
                Outcome::Failed(cx) => {
                    out.set_item("outcome", "failed")?;
                    let v = &cx.violation;
                    let c = PyDict::new(py);
                    c.set_item("property", &v.property)?;
                    if let Some(p) = props.iter().find(|p| p.name() == v.property) {
                        c.set_item("statement", p.to_string())?;
                    }
                    c.set_item("t", v.at.t)?;
                    c.set_item("j", v.at.j)?;
                    c.set_item("state", PyArray1::from_slice(py, &v.state))?;
                    c.set_item("state_names", state_names.clone())?;
                    c.set_item("message", v.to_string())?;
                    c.set_item("case", cx.index)?;
                    c.set_item("seed", cx.case.seed)?;
                    let named = |values: &[f64]| -> PyResult<Bound<'py, PyDict>> {
                        let d = PyDict::new(py);
                        for (i, x) in inputs.iter().zip(values) {
                            d.set_item(&i.name, *x)?;
                        }
                        Ok(d)
                    };
                    c.set_item("inputs", named(&cx.case.values)?)?;
                    c.set_item("sampled", named(&cx.original.values)?)?;
                    c.set_item("horizon_T", cx.case.horizon_t)?;
                    c.set_item("horizon_J", cx.case.horizon_j)?;
                    c.set_item("shrink_runs", cx.shrink_runs)?;
                    c.set_item(
                        "description",
                        cx.describe_with_rules(inputs, &report_names, &rule_names),
                    )?;
                    c.set_item("replay", replay_command(path, &subject, &cx.case))?;
                    if counterexamples.is_empty() {
                        out.set_item("counterexample", &c)?;
                    }
                    counterexamples.append(c)?;
                }
                Outcome::Error { index, case, error } => {
                    out.set_item("outcome", "error")?;
                    let diags = match error {
                        ModelRunError::Compile(diags) => diags.clone(),
                        ModelRunError::Sim(e) => vec![model.runtime_diagnostic(e)],
                    };
                    let e = PyDict::new(py);
                    e.set_item("case", *index)?;
                    e.set_item("seed", case.seed)?;
                    e.set_item(
                        "inputs",
                        inputs
                            .iter()
                            .zip(&case.values)
                            .map(|(i, v)| (i.name.clone(), *v))
                            .collect::<Vec<_>>(),
                    )?;
                    e.set_item(
                        "message",
                        hybsim::diagnostics::render(&diags, &self.source, false),
                    )?;
                    e.set_item("replay", replay_command(path, &subject, case))?;
                    out.set_item("error", e)?;
                }
            }
        }
        out.set_item("counterexamples", counterexamples)?;
        Ok(out)
    }

    /// Benchmark reference: the fastest of `repeats` runs of the Rust
    /// `engine::simulate_arc` call on this model (seconds), with the
    /// settings `Model.run(seed, **sim)` would use. Not part of the API.
    #[pyo3(signature = (seed=None, sim=None, repeats=20))]
    fn _simulate_arc_seconds(
        &self,
        py: Python<'_>,
        seed: Option<u64>,
        sim: Option<&Bound<'_, PyDict>>,
        repeats: usize,
    ) -> PyResult<f64> {
        let (shared, seed) = self.for_run(py, seed)?;
        let model: &CompiledModel = &shared;
        let settings = settings::apply(model, &sim.cloned().unwrap_or(PyDict::new(py)))?;
        py.detach(|| {
            let mut best = f64::INFINITY;
            for _ in 0..repeats.max(1) {
                let start = std::time::Instant::now();
                let (x0, mut rng) = model.start(seed);
                let arc = hybsim::engine::simulate_arc(model, &x0, &settings, &mut rng);
                std::hint::black_box(&arc);
                best = best.min(start.elapsed().as_secs_f64());
            }
            Ok(best)
        })
    }

    fn __repr__(&self) -> String {
        let set: Vec<String> = self
            .overrides
            .iter()
            .map(|o| format!("{}={}", o.name, o.value))
            .collect();
        format!(
            "<hybsim.Model {} from {}{}; {} states, {} rules, seed {}>",
            self.model.name(),
            self.source.name(),
            if set.is_empty() {
                String::new()
            } else {
                format!(" with {}", set.join(", "))
            },
            self.model.state_dim(),
            self.model.rule_names().len(),
            self.model.seed()
        )
    }
}
