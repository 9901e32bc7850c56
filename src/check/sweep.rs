//! Checking a model's `sweep { … }` block: the grid (`NAME in a:step:b`,
//! `NAME in VALUES`) and settings (`runs`, `seed`) that `hybsim sweep`
//! runs when no `--grid` is given. Axis names are those `--set` accepts.

use std::collections::HashMap;

use super::Checker;
use super::error::CheckError;
use super::expr::{dims_words, suggest};
use crate::source::Span;
use crate::syntax::ast::{AxisValues, Item, SweepBlock};

/// A model's checked `sweep` block.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SweepDecl {
    /// The axes in order (the first varies slowest): the name set and its
    /// values.
    pub axes: Vec<(String, Vec<f64>)>,
    /// `runs = N`: runs per grid point.
    pub runs: Option<u64>,
    /// `seed = S`: the base seed of the run seeds.
    pub seed: Option<u64>,
}

/// The settings a `sweep` block knows.
const KEYS: &[&str] = &["runs", "seed"];

/// Checks the `sweep` block among the top-level `items` (at most one; none
/// inside `for`). `settable` are the names `--set` accepts.
pub(crate) fn check_sweeps(
    c: &mut Checker,
    items: &[Item],
    settable: &[String],
) -> Option<SweepDecl> {
    let mut found: Option<(Span, SweepDecl)> = None;
    for it in items {
        match it {
            Item::Sweep(b) => match &found {
                Some((first, _)) => c.err(CheckError::SecondBlock {
                    block: "sweep",
                    span: b.span,
                    first: *first,
                }),
                None => found = Some((b.span, check_block(c, b, settable))),
            },
            Item::For(_, inner) => nested(c, inner),
            _ => {}
        }
    }
    found.map(|(_, d)| d)
}

/// Reports `sweep` blocks inside `for` loops.
fn nested(c: &mut Checker, items: &[Item]) {
    for it in items {
        match it {
            Item::Sweep(b) => c.err(CheckError::Unsupported {
                what: "a `sweep` block inside `for` (write it once, at the top level)".into(),
                span: b.span,
            }),
            Item::For(_, inner) => nested(c, inner),
            _ => {}
        }
    }
}

fn check_block(c: &mut Checker, b: &SweepBlock, settable: &[String]) -> SweepDecl {
    let mut d = SweepDecl::default();
    let mut seen: HashMap<&str, Span> = HashMap::new();
    for axis in &b.axes {
        let name = axis.name.name.as_str();
        let span = axis.name.span;
        if let Some(&first) = seen.get(name) {
            c.err(CheckError::SetTwice {
                name: name.to_string(),
                span,
                first,
            });
            continue;
        }
        seen.insert(name, span);
        if !settable.iter().any(|s| s == name) {
            let suggestion = c
                .hints
                .charge(settable.len())
                .then(|| suggest(name, settable))
                .flatten();
            c.err(CheckError::UnknownSetting {
                name: name.to_string(),
                span,
                suggestion,
            });
            continue;
        }
        let whole = match &axis.values {
            AxisValues::Range(a, _, stop) => Span::new(a.span.start, stop.span.end),
            AxisValues::List(e) => e.span,
        };
        let values = match &axis.values {
            AxisValues::Range(a, step, stop) => {
                let what = "a sweep range";
                let (a, step, stop) = (
                    c.const_scalar(a, what),
                    c.const_scalar(step, what),
                    c.const_scalar(stop, what),
                );
                let (Some(a), Some(step), Some(stop)) = (a, step, stop) else {
                    continue;
                };
                match crate::sweep::grid::range_values(a, step, stop) {
                    Ok(v) => v,
                    Err(reason) => {
                        c.bad_setting(name, reason, whole);
                        continue;
                    }
                }
            }
            AxisValues::List(e) => {
                let Some((v, xs)) = c.const_matrix(e, "sweep values") else {
                    continue;
                };
                if v.rows != 1 && v.cols != 1 {
                    c.err(CheckError::Expected {
                        expected: "a number, a list `[v1, v2, …]` or a range `a:step:b`".into(),
                        found: dims_words(v.dims()),
                        span: e.span,
                    });
                    continue;
                }
                if xs.is_empty() {
                    c.bad_setting(name, "no values", e.span);
                    continue;
                }
                if xs.iter().any(|x| !x.is_finite()) {
                    c.bad_setting(name, "the values must be finite", e.span);
                    continue;
                }
                xs
            }
        };
        if let Some(v) = crate::sweep::grid::repeated_value(&values) {
            let reason = format!("the value {} is given twice", crate::num::Num(v));
            c.bad_setting(name, reason, whole);
            continue;
        }
        d.axes.push((name.to_string(), values));
    }
    let mut keys: HashMap<&str, Span> = HashMap::new();
    for s in &b.settings {
        let key = s.key.name.as_str();
        if let Some(&first) = keys.get(key) {
            c.err(CheckError::SetTwice {
                name: key.to_string(),
                span: s.key.span,
                first,
            });
            continue;
        }
        keys.insert(key, s.key.span);
        let bad = |c: &mut Checker, reason: &str| c.bad_setting(key, reason, s.value.span);
        match key {
            "runs" => match c.const_int(&s.value, "`runs`") {
                Some(n) if n >= 1 => d.runs = Some(n as u64),
                Some(_) => bad(c, "at least 1 run per grid point"),
                None => {}
            },
            // Exactly as written: an `f64` rounds seeds above 2^53.
            "seed" if s.integer.is_some() => d.seed = s.integer,
            "seed" => match c.const_scalar(&s.value, "`seed`") {
                Some(x) if x >= 0.0 && x.fract() == 0.0 && x < 2f64.powi(64) => {
                    d.seed = Some(x as u64)
                }
                Some(_) => bad(c, "an integer from 0 to 2^64 − 1"),
                None => {}
            },
            _ => {
                // `delta = 3` was probably meant as an axis.
                let suggestion = suggest(key, KEYS.iter().copied()).or_else(|| {
                    settable
                        .iter()
                        .any(|n| n == key)
                        .then(|| format!("{key} in [values]"))
                });
                c.err(CheckError::UnknownSetting {
                    name: key.to_string(),
                    span: s.key.span,
                    suggestion,
                });
            }
        }
    }
    d
}
