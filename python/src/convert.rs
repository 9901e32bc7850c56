//! Rust results as Python objects: diagnostics as `ModelError`, matrices and
//! columns as numpy arrays, JSON reports as Python values.

use hybsim::diagnostics::{Diagnostic, Severity, render};
use hybsim::source::SourceFile;
use numpy::{PyArray1, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

/// One diagnostic as a dict: `code`, `severity`, `message`, `file`, `line`,
/// `col` (1-based, of the primary label; `None` without one), `help`,
/// `notes` and `labels` (each with `line`, `col`, `end_line`, `end_col`,
/// `message`, `primary`).
fn diagnostic_dict<'py>(
    py: Python<'py>,
    d: &Diagnostic,
    src: &SourceFile,
) -> PyResult<Bound<'py, PyDict>> {
    let out = PyDict::new(py);
    out.set_item("code", d.code)?;
    out.set_item(
        "severity",
        match d.severity {
            Severity::Error => "error",
            Severity::Warning => "warning",
        },
    )?;
    out.set_item("message", &d.message)?;
    out.set_item("file", d.primary_file(src))?;
    let at = d.line_col(src);
    out.set_item("line", at.map(|lc| lc.line))?;
    out.set_item("col", at.map(|lc| lc.col))?;
    out.set_item("help", d.help.as_deref())?;
    out.set_item("notes", d.notes.clone())?;
    let labels = PyList::empty(py);
    for l in &d.labels {
        // A label in an imported file carries that file.
        let file = l.file.as_deref().unwrap_or(src);
        let (start, end) = (file.line_col(l.span.start), file.line_col(l.span.end));
        let label = PyDict::new(py);
        label.set_item("file", file.name())?;
        label.set_item("line", start.line)?;
        label.set_item("col", start.col)?;
        label.set_item("end_line", end.line)?;
        label.set_item("end_col", end.col)?;
        label.set_item("message", &l.message)?;
        label.set_item("primary", l.primary)?;
        labels.append(label)?;
    }
    out.set_item("labels", labels)?;
    Ok(out)
}

/// An exception of type `E` whose message is the rendered report of
/// `diags` (no colour) and whose `diagnostics` attribute lists them.
pub fn diagnostics_error<E: pyo3::PyTypeInfo>(
    py: Python<'_>,
    diags: &[Diagnostic],
    src: &SourceFile,
) -> PyErr {
    let err = PyErr::from_type(py.get_type::<E>(), render(diags, src, false));
    let list: PyResult<Vec<_>> = diags.iter().map(|d| diagnostic_dict(py, d, src)).collect();
    match list {
        Ok(list) => match err.value(py).setattr("diagnostics", list) {
            Ok(()) => err,
            Err(e) => e,
        },
        Err(e) => e,
    }
}

/// A row-major `rows × cols` block as numpy: a float for 1×1, a 1-D array
/// for a column, a 2-D array otherwise (the shapes of `hybsim design
/// --json` and the MCAP metadata).
pub fn matrix<'py>(
    py: Python<'py>,
    (rows, cols): (usize, usize),
    values: &[f64],
) -> PyResult<Bound<'py, PyAny>> {
    match (rows, cols) {
        (1, 1) => Ok(values[0].into_pyobject(py)?.into_any()),
        (_, 1) => Ok(PyArray1::from_slice(py, values).into_any()),
        (r, c) => Ok(PyArray1::from_slice(py, values).reshape([r, c])?.into_any()),
    }
}

/// A flat row-major buffer of `rows × width` values as a 2-D array (the
/// buffer is moved into numpy, not copied).
pub fn columns<'py>(
    py: Python<'py>,
    flat: Vec<f64>,
    rows: usize,
    width: usize,
) -> PyResult<Bound<'py, PyAny>> {
    Ok(PyArray1::from_vec(py, flat)
        .reshape([rows, width])?
        .into_any())
}

/// A JSON value as Python objects (through the `json` module, so numbers
/// round-trip exactly as `hybsim design --json` prints them).
pub fn json<'py>(py: Python<'py>, value: &serde_json::Value) -> PyResult<Bound<'py, PyAny>> {
    let text = serde_json::to_string(value)
        .map_err(|e| pyo3::exceptions::PyValueError::new_err(e.to_string()))?;
    py.import("json")?.call_method1("loads", (text,))
}
