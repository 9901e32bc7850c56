//! The `.hyb` language front end in one call: parse, check, compile.
//!
//! ```
//! use hybsim::lang;
//! use hybsim::source::SourceFile;
//! use hybsim::engine::simulate_arc;
//!
//! let src = SourceFile::new("ball.hyb", "model ball
//! param g = 9.81, lambda = 0.8
//! state h = 1, v = 0
//! flow { h' = v; v' = -g } in h >= 0
//! jump impact when h <= 0 && v <= 0 { v+ = -lambda * v }
//! sim { T = 1 }
//! ");
//! let model = lang::compile(&src, &[]).expect("a valid model");
//! let (x0, mut rng) = model.start(model.seed());
//! let arc = simulate_arc(&model, &x0, &model.settings(), &mut rng).unwrap();
//! let t1 = (2.0_f64 / 9.81).sqrt();
//! assert!((arc.jumps()[0].at.t - t1).abs() < 1e-9);
//! ```

use std::str::FromStr;

use crate::check;
use crate::diagnostics::Diagnostic;
use crate::source::{SourceFile, SourceMap, Span};
use crate::syntax;

pub use crate::check::{Backend, CheckOptions, DesignReport, Override, SolveSummary};
pub use crate::ir::{CompiledModel, JitStatus};

impl FromStr for Override {
    type Err = Diagnostic;

    /// Parses `name=value`; the value is any `.hyb` expression. A refusal
    /// points into the argument (rendered as `--set name:1:col`).
    fn from_str(s: &str) -> Result<Self, Diagnostic> {
        let Some((name, value)) = s.split_once('=') else {
            return Err(Diagnostic::error(
                "E0508",
                format!("override `{s}` is not of the form name=value"),
            )
            .primary(Span::new(0, s.len()), "no `=` here")
            .help("write e.g. --set g=9.81")
            .in_set_argument("", s, 0));
        };
        let name = name.trim().to_string();
        let value = value.trim().to_string();
        let expr = syntax::parse_expr(&value).map_err(|e| {
            // Long values are shortened in the message; the label says where in the value.
            let shown: String = value.chars().take(60).collect();
            let ellipsis = if shown.len() < value.len() { "…" } else { "" };
            let at = e.span();
            let at = Span::new(at.start.min(value.len()), at.end.min(value.len()));
            // A setting whose values are words, given a keyword (`priority=flow`).
            let key = name.strip_prefix("sim.").unwrap_or(&name);
            let help = syntax::setting_word_help(key, &value).unwrap_or_else(|| {
                "the value must be an expression such as 2.5, -1e-3 or [1, 2; 3, 4]".into()
            });
            Diagnostic::error(
                "E0508",
                format!("in override `{name}={shown}{ellipsis}`: {e}"),
            )
            .primary(at, "here")
            .help(help)
            .in_override(&name, &value)
        })?;
        Ok(Override {
            name,
            value,
            expr,
            flag: None,
        })
    }
}

/// Parses, checks and compiles `src` with `overrides` applied. On failure
/// returns every diagnostic found (render them with
/// [`crate::diagnostics::render`]).
pub fn compile(src: &SourceFile, overrides: &[Override]) -> Result<CompiledModel, Vec<Diagnostic>> {
    compile_with(src, overrides, &CheckOptions::default())
}

/// As [`compile`] with checker options (e.g. the interior-point method of
/// the `design` blocks: `hybsim run --sdp schur`).
///
/// ```
/// use hybsim::lang::{self, Backend, CheckOptions};
/// use hybsim::source::SourceFile;
///
/// let src = SourceFile::new("m.hyb", "model m
/// design d { scalar g
///     minimize g
///     g >= 2 }
/// ");
/// let options = CheckOptions { backend: Backend::Schur, ..CheckOptions::default() };
/// let m = lang::compile_with(&src, &[], &options).unwrap();
/// let s = m.design_reports()[0].solve.clone().unwrap();
/// assert_eq!(s.backend, Backend::Schur);
/// assert!((s.objective - 2.0).abs() < 1e-6);
/// ```
pub fn compile_with(
    src: &SourceFile,
    overrides: &[Override],
    options: &CheckOptions,
) -> Result<CompiledModel, Vec<Diagnostic>> {
    let (model, map) = parse(src)?;
    let report = |diags: Vec<Diagnostic>| report(diags, src, &model, &map, overrides);
    let checked = check::check_with(&model, overrides, options)
        .map_err(|errs| report(errs.iter().map(|e| e.to_diagnostic()).collect()))?;
    let errs = crate::ir::structural_errors(&checked);
    if !errs.is_empty() {
        return Err(report(errs.iter().map(|e| e.to_diagnostic()).collect()));
    }
    Ok(CompiledModel::new(checked, src.clone()).with_imports(map))
}

/// Parses `src` and appends the subsystems of the files it imports (see
/// [`crate::imports`]); returns the model and the map of those files.
fn parse(src: &SourceFile) -> Result<(syntax::ast::Model, SourceMap), Vec<Diagnostic>> {
    let mut model = syntax::parse_model(src.text()).map_err(|e| vec![e.to_diagnostic()])?;
    let map = crate::imports::resolve(src, &mut model)?;
    crate::tables::resolve(src, &mut model)?;
    Ok((model, map))
}

/// Compiles `src` as `hybsim run` starts it with run seed `seed` (`None`:
/// the model's `sim { seed }`): the random parameters
/// ([`CompiledModel::random_params`]) are drawn from
/// [`props::input_stream(seed)`](crate::props::input_stream) in declaration
/// order and pinned (derived parameters recompute, as for `--set`), then
/// [`CompiledModel::start`]`(seed)` draws the random initial values from
/// the same stream. A `hybsim test` case with seed `seed` draws its inputs
/// in this order, so `hybsim run --seed S` reproduces it. Returns the model
/// and the seed.
///
/// ```
/// use hybsim::lang::{self, Override};
/// use hybsim::source::SourceFile;
///
/// let src = SourceFile::new("m.hyb", "model m
/// param g ~ uniform(9, 10)
/// param half = g / 2
/// state h = 1
/// flow { h' = -half }
/// ");
/// let (m, seed) = lang::compile_run(&src, &[], Some(7)).unwrap();
/// let g = m.parameters_json()["g"].as_f64().unwrap();
/// assert!(seed == 7 && (9.0..=10.0).contains(&g));
/// assert_eq!(m.parameters_json()["half"].as_f64(), Some(g / 2.0));
/// // Uncompiled draws give the centre.
/// assert_eq!(lang::compile(&src, &[]).unwrap().parameters_json()["g"].as_f64(), Some(9.5));
/// ```
pub fn compile_run(
    src: &SourceFile,
    overrides: &[Override],
    seed: Option<u64>,
) -> Result<(CompiledModel, u64), Vec<Diagnostic>> {
    compile_run_with(src, overrides, seed, &CheckOptions::default())
}

/// As [`compile_run`] with checker options (`hybsim run --sdp`).
pub fn compile_run_with(
    src: &SourceFile,
    overrides: &[Override],
    seed: Option<u64>,
    options: &CheckOptions,
) -> Result<(CompiledModel, u64), Vec<Diagnostic>> {
    let model = compile_with(src, overrides, options)?;
    let seed = seed.unwrap_or(model.seed());
    let params = model.random_params().to_vec();
    if params.is_empty() {
        return Ok((model, seed));
    }
    let mut rng = crate::props::input_stream(seed);
    let mut pinned: Vec<Override> = overrides
        .iter()
        .filter(|o| !params.iter().any(|p| p.name == o.name))
        .cloned()
        .collect();
    for p in &params {
        let v = crate::num::Num(p.dist.sample(&mut rng));
        pinned.push(format!("{}={v}", p.name).parse().map_err(|d| vec![d])?);
    }
    let mut model = compile_with(src, &pinned, options)?;
    model.set_param_draws(params.iter().map(|p| p.dist).collect());
    Ok((model, seed))
}

/// Runs only the checks (`hybsim check`): the diagnostics, empty if the
/// model is valid.
pub fn check_only(src: &SourceFile, overrides: &[Override]) -> Vec<Diagnostic> {
    check_only_with(src, overrides, &CheckOptions::default())
}

/// As [`check_only`] with checker options (other resource limits, say).
pub fn check_only_with(
    src: &SourceFile,
    overrides: &[Override],
    options: &CheckOptions,
) -> Vec<Diagnostic> {
    match parse(src) {
        Err(diags) => diags,
        Ok((model, map)) => {
            let diags = match check::check_with(&model, overrides, options) {
                Ok(checked) => crate::ir::structural_errors(&checked)
                    .iter()
                    .map(|e| e.to_diagnostic())
                    .collect(),
                Err(errs) => errs.iter().map(|e| e.to_diagnostic()).collect(),
            };
            report(diags, src, &model, &map, overrides)
        }
    }
}

/// Runs the checks and the `design` blocks (`hybsim design`), including
/// those without results (checks, which [`compile`] does not solve): the
/// design reports in source order, or every diagnostic.
pub fn design_only(
    src: &SourceFile,
    overrides: &[Override],
) -> Result<Vec<DesignReport>, Vec<Diagnostic>> {
    design_only_with(src, overrides, &CheckOptions::default())
}

/// As [`design_only`] with checker options (`hybsim design --sdp`); the
/// `check` blocks are solved whatever `options.solve_checks` says.
pub fn design_only_with(
    src: &SourceFile,
    overrides: &[Override],
    options: &CheckOptions,
) -> Result<Vec<DesignReport>, Vec<Diagnostic>> {
    let (model, map) = parse(src)?;
    let options = CheckOptions {
        solve_checks: true,
        ..*options
    };
    check::check_with(&model, overrides, &options)
        .map(|m| m.designs)
        .map_err(|errs| {
            let diags = errs.iter().map(|e| e.to_diagnostic()).collect();
            report(diags, src, &model, &map, overrides)
        })
}

/// The checker's diagnostics as reported: each with the notes of
/// [`override_notes`], then located in its file.
fn report(
    diags: Vec<Diagnostic>,
    src: &SourceFile,
    model: &syntax::ast::Model,
    map: &SourceMap,
    overrides: &[Override],
) -> Vec<Diagnostic> {
    let sources = override_sources(src, model, overrides);
    diags
        .into_iter()
        .map(|d| override_notes(d, src, &sources, overrides).locate(map))
        .collect()
}

/// For each parameter or state of the model whose value an override decides: the
/// overrides it comes from (indices in `overrides`). Parameters are
/// declared before use, so one pass in declaration order follows every
/// chain (`h = Ts / 2` after `--set Ts=0`).
type OverrideSources<'m> = std::collections::HashMap<&'m str, Vec<usize>>;

fn override_sources<'m>(
    src: &'m SourceFile,
    model: &'m syntax::ast::Model,
    overrides: &[Override],
) -> OverrideSources<'m> {
    use syntax::ast::Item;
    let mut sources = OverrideSources::default();
    if overrides.is_empty() {
        return sources;
    }
    let mut define = |targets: &mut dyn Iterator<Item = &'m syntax::ast::Target>, value: Span| {
        let read: Vec<usize> = names_read(src, value, &sources)
            .into_iter()
            .map(|(k, _)| k)
            .collect();
        for t in targets.filter(|t| t.indices.is_empty()) {
            let name = t.name.name.as_str();
            if let Some(k) = overrides.iter().rposition(|o| o.name == name) {
                sources.insert(name, vec![k]);
            } else if !read.is_empty() {
                sources.insert(name, read.clone());
            }
        }
    };
    for it in &model.items {
        match it {
            Item::Param(defs) => {
                for d in defs {
                    define(&mut std::iter::once(&d.target), d.value.span);
                }
            }
            Item::ParamTuple(targets, value) => define(&mut targets.iter(), value.span),
            // A state's shape is its initial value's: `--set x=[1; 2; 3]` on a 2-vector
            // surfaces as shape errors where x is used, which say where that value came from.
            Item::State(defs) => {
                for d in defs {
                    if let Some(init) = &d.init {
                        define(&mut std::iter::once(&d.target), init.span);
                    }
                }
            }
            _ => {}
        }
    }
    sources
}

/// The overrides behind the names in the model's text `span` (lexed: the
/// span of any error), each with the first name there that reads it.
fn names_read<'m>(
    src: &'m SourceFile,
    span: Span,
    sources: &OverrideSources<'m>,
) -> Vec<(usize, &'m str)> {
    let mut found: Vec<(usize, &'m str)> = Vec::new();
    let Some(text) = src.text().get(span.start..span.end) else {
        return found;
    };
    for t in syntax::lex::tokens(text) {
        for &k in sources.get(t.text).into_iter().flatten() {
            if !found.iter().any(|&(f, _)| f == k) {
                found.push((k, t.text));
            }
        }
    }
    found
}

/// `d` with a note for each override behind a value its primary label reads
/// in the model's text (`` Ts = 0 comes from `--set Ts=0` ``): the error is
/// in the model's text, the value that causes it is on the command line.
fn override_notes(
    mut d: Diagnostic,
    src: &SourceFile,
    sources: &OverrideSources<'_>,
    overrides: &[Override],
) -> Diagnostic {
    let Some(span) = d
        .labels
        .iter()
        .find(|l| l.primary && l.file.is_none())
        .map(|l| l.span)
    else {
        return d;
    };
    // A long value (a matrix) is shortened: the note names it, the flag holds it.
    let shown = |s: &str| -> String {
        let short: String = s.chars().take(40).collect();
        if short.len() < s.len() {
            short + "…"
        } else {
            short
        }
    };
    for (k, name) in names_read(src, span, sources) {
        let o = &overrides[k];
        let origin = match &o.flag {
            Some(flag) => shown(flag),
            None => format!("--set {}={}", o.name, shown(&o.value)),
        };
        let mut note = format!("{} = {} comes from `{origin}`", o.name, shown(&o.value));
        if name != o.name {
            note.push_str(&format!(" (`{name}` is computed from it)"));
        }
        d.notes.push(note);
    }
    d
}
