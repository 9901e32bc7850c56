//! `hybsim._hybsim`: the native half of the `hybsim` Python package.
//!
//! It wraps the library's one-call front end ([`hybsim::lang`]), the engine
//! ([`hybsim::engine::simulate`]), the design layer
//! ([`hybsim::lang::design_only`]), the property tests
//! ([`hybsim::props::run_tests`]) and sweeps ([`hybsim::sweep`]). Results cross into Python once, as numpy
//! arrays that take over the Rust buffers the run filled (no per-sample
//! Python objects); everything friendlier (the `Solution` class, pandas,
//! plots) lives in the pure-Python half `python/hybsim/`.

use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

mod convert;
mod model;
mod record;
mod settings;
mod sweep;

create_exception!(
    hybsim,
    ModelError,
    PyException,
    "A model that does not parse, check or compile. `str(err)` is the rendered report \
     (`error[E…]: message`, `┌─ file:line:col`, the source line with carets); \
     `err.diagnostics` lists each diagnostic as a dict."
);

create_exception!(
    hybsim,
    SimulationError,
    PyException,
    "A simulation that failed at run time (non-finite state, integrator failure, invalid \
     settings). `str(err)` points at (t, j) and the model line; `err.diagnostics` as for \
     ModelError; `err.partial` holds the solution up to the failure (or None)."
);

/// The native module.
#[pymodule]
fn _hybsim(m: &Bound<'_, PyModule>) -> PyResult<()> {
    // As the `hybsim` binary: one OpenBLAS thread, and the worker threads
    // it started when the extension loaded (spinning on `sched_yield`
    // for their timeout) stopped at import.
    hybsim::design::blas::pin();
    let py = m.py();
    m.add("ModelError", py.get_type::<ModelError>())?;
    m.add("SimulationError", py.get_type::<SimulationError>())?;
    m.add_class::<model::Model>()?;
    m.add_class::<model::OutputMap>()?;
    m.add_function(wrap_pyfunction!(model::compile, m)?)?;
    m.add_function(wrap_pyfunction!(sweep::sweep, m)?)?;
    m.add_function(wrap_pyfunction!(sweep::parse_axis, m)?)?;
    m.add("SAMPLE_KINDS", record::SAMPLE_KINDS.to_vec())?;
    m.add("MAX_SOURCE_BYTES", hybsim::source::MAX_SOURCE_BYTES)?;
    Ok(())
}
