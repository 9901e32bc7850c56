//! What any input must give, however malformed: no panic, every error
//! located inside the text it names, `check` accepting only what compiles,
//! and a short, bounded run of what compiles. The one implementation behind
//! the cargo-fuzz targets (`fuzz/`), the test that runs their seed corpus
//! and the grammar-aware mutation test (`tests/it/mutants.rs`), so that a
//! failure found by one is reproduced by the others.
//!
//! ```
//! use hybsim::fuzz::{self, Budget, Outcome};
//! use hybsim::source::SourceFile;
//!
//! let src = SourceFile::new("m.hyb", "model m\nstate x = 1\nflow { x' = -x }\nsim { T = 100 }\n");
//! assert!(matches!(fuzz::run(&src, &Budget::default()), Ok(Outcome::Ran { .. })));
//! let bad = SourceFile::new("m.hyb", "model m\nstate x = 1\nflow { x' = -y }\n");
//! assert!(matches!(fuzz::check(&bad), Ok(Outcome::Rejected { errors: 1 })));
//! ```
//!
//! A case may also carry `--set` overrides and the CSV files its
//! `table("…")` calls read ([`Input`]); an override's errors must point into
//! the override (`--set name:1:col`), a table's into its file (`line:col`).
//!
//! ```
//! use hybsim::fuzz::{Budget, Input, Outcome};
//!
//! let input = Input::from_bytes(b"model m\nparam k = table(\"k.csv\")\nstate x = k[2]\nflow { x' = -x }\n\
//!     %%set T=0.5\n%%table k.csv\n1\n2\n").unwrap();
//! assert_eq!((input.overrides.len(), input.tables.len()), (1, 1));
//! assert!(matches!(input.run(&Budget::default()), Ok(Outcome::Ran { .. })));
//! let ragged = Input::from_bytes(b"model m\nparam k = table(\"k.csv\")\nstate x = k[1]\nflow { x' = -x }\n\
//!     %%set nosuch=1e308\n%%table k.csv\n1,2\n3\n").unwrap();
//! assert!(matches!(ragged.check(), Ok(Outcome::Rejected { .. })));
//! ```
//!
//! A hang is the one failure these functions cannot see: callers bound the
//! time (the mutation test runs each case on a thread with a deadline,
//! libFuzzer has `-timeout`).

use std::ops::ControlFlow;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::time::{Duration, Instant};

use crate::arc::{ArcSink, HybridTime, SampleKind};
use crate::check::limits::{Limits, Quantity};
use crate::diagnostics::{Diagnostic, Severity};
use crate::lang::{self, CheckOptions, Override};
use crate::source::SourceFile;

/// How far a compiled input is simulated: the model's own horizons, cut to
/// these. The run also stops after `samples` samples or `wall` of wall time
/// (checked at each sample), so an input that asks for 10⁹ steps costs
/// little. `limits` are the checker's resource limits (those of `hybsim`
/// by default; [`Budget::instrumented`] for the fuzz targets).
#[derive(Debug, Clone)]
pub struct Budget {
    /// Largest horizon T.
    pub horizon_t: f64,
    /// Largest horizon J.
    pub horizon_j: u64,
    /// Samples after which the run is stopped.
    pub samples: usize,
    /// Wall time after which the run is stopped.
    pub wall: Duration,
    /// The checker's resource limits (a model's `sim { max_… }` still changes them).
    pub limits: Limits,
}

impl Default for Budget {
    fn default() -> Self {
        Self {
            horizon_t: 2.0,
            horizon_j: 200,
            samples: 20_000,
            wall: Duration::from_secs(1),
            limits: Limits::default(),
        }
    }
}

impl Budget {
    /// The budget of the fuzz targets ([`Target::exercise`]). Coverage instrumentation slows
    /// hybsim's own numerics about 60× (the design layer's above all: the shipped platoon model
    /// compiles in 0.03 s, instrumented in 1.5 s and, on a loaded machine, over libFuzzer's 20-s
    /// limit), so sizes are limited far lower than `hybsim`'s: a larger input is refused at
    /// once, with the located error of any limit (which is fuzzed too), and an input over 20 s
    /// is a hang again. The largest shipped designs (platoon: 626 conic rows;
    /// intermittent_estimation: 5 427) are refused; cooperative_estimation (220) is solved.
    pub fn instrumented() -> Self {
        let mut limits = Limits::default();
        for (q, value) in [
            (Quantity::DesignVars, 200),
            (Quantity::LmiBlocks, 64),
            (Quantity::LmiSize, 32),
            (Quantity::LmiRows, 300),
            (Quantity::States, 1_000),
            (Quantity::Elements, 100_000),
            (Quantity::Iterations, 100_000),
            (Quantity::Ops, 2_000_000),
        ] {
            limits.set(q, value);
        }
        Self {
            limits,
            ..Self::default()
        }
    }
}

/// The front-end stage an input reached.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// `syntax::parse_model`.
    Parse,
    /// `lang::check_only` (`hybsim check`).
    Check,
    /// `lang::compile` (`hybsim run` before simulating).
    Compile,
    /// The bounded simulation, outputs evaluated at every sample.
    Run,
}

impl std::fmt::Display for Stage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Stage::Parse => "parse",
            Stage::Check => "check",
            Stage::Compile => "compile",
            Stage::Run => "run",
        })
    }
}

/// What a well-behaved front end gave.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    /// The input was refused with `errors` located errors.
    Rejected {
        /// How many.
        errors: usize,
    },
    /// Accepted by the stage (parse or check only).
    Accepted,
    /// Compiled and simulated within the budget, or stopped by it.
    Ran {
        /// Samples the run produced.
        samples: usize,
    },
    /// Compiled, and the run ended with a located run-time error.
    Failed {
        /// Its code (E06xx).
        code: &'static str,
    },
}

/// A broken promise: a bug of hybsim, whatever the input.
#[derive(Debug, Clone, thiserror::Error)]
pub enum Violation {
    /// A panic escaped the stage.
    #[error("panic in {stage}: {message}")]
    Panic {
        /// Where.
        stage: Stage,
        /// The panic's message.
        message: String,
    },
    /// An error without a primary label, or with a label outside the text
    /// of its file.
    #[error("{stage}: error not located ({why}): {diagnostic:?}")]
    Unlocated {
        /// Where.
        stage: Stage,
        /// What is wrong with its labels.
        why: &'static str,
        /// The diagnostic.
        diagnostic: Box<Diagnostic>,
    },
    /// `check` found no error but `compile` did: `hybsim check` would pass a
    /// model `hybsim run` refuses.
    #[error("check passed but compile failed: {diagnostic:?}")]
    CheckMissed {
        /// The first compile error.
        diagnostic: Box<Diagnostic>,
    },
}

/// Runs `f`, turning a panic into [`Violation::Panic`].
fn guarded<T>(stage: Stage, f: impl FnOnce() -> T) -> Result<T, Violation> {
    catch_unwind(AssertUnwindSafe(f)).map_err(|p| {
        let message = p
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| p.downcast_ref::<&str>().map(|s| (*s).to_string()))
            .unwrap_or_else(|| "(no message)".to_string());
        Violation::Panic { stage, message }
    })
}

/// Checks that every error of `diags` has a primary label, and every label
/// a span on character boundaries inside its file (`src`, or the imported
/// or override file the label names).
pub fn located(stage: Stage, src: &SourceFile, diags: &[Diagnostic]) -> Result<(), Violation> {
    for d in diags {
        let why = if d.severity == Severity::Error && d.primary_span().is_none() {
            Some("no primary label")
        } else {
            d.labels.iter().find_map(|l| {
                let text = l.file.as_deref().unwrap_or(src).text();
                let inside = l.span.start <= l.span.end
                    && l.span.end <= text.len()
                    && text.is_char_boundary(l.span.start)
                    && text.is_char_boundary(l.span.end);
                (!inside).then_some("label outside its file")
            })
        };
        // An override's error is shown in the override, a table's contents error in the file.
        let file = d.primary_file(src);
        let why = why.or(match d.code {
            "E0508" if !file.starts_with("--set") => Some("override error not in its --set"),
            "E0804" if file == src.name() => Some("table error not in its file"),
            _ => None,
        });
        if let Some(why) = why {
            return Err(Violation::Unlocated {
                stage,
                why,
                diagnostic: Box::new(d.clone()),
            });
        }
    }
    Ok(())
}

fn errors(diags: &[Diagnostic]) -> usize {
    diags
        .iter()
        .filter(|d| d.severity == Severity::Error)
        .count()
}

/// Parses `src` (the fuzz target `parse`).
pub fn parse(src: &SourceFile) -> Result<Outcome, Violation> {
    match guarded(Stage::Parse, || crate::syntax::parse_model(src.text()))? {
        Ok(_) => Ok(Outcome::Accepted),
        Err(e) => {
            let d = e.to_diagnostic();
            located(Stage::Parse, src, std::slice::from_ref(&d))?;
            Ok(Outcome::Rejected { errors: 1 })
        }
    }
}

/// Checks `src` as `hybsim check` does (the fuzz target `check`).
pub fn check(src: &SourceFile) -> Result<Outcome, Violation> {
    check_with(src, &[], &Limits::default())
}

/// The checker's options with resource limits `limits`.
fn check_options(limits: &Limits) -> CheckOptions {
    CheckOptions {
        limits: *limits,
        ..CheckOptions::default()
    }
}

/// [`check`] with `--set` overrides and resource limits.
pub fn check_with(
    src: &SourceFile,
    overrides: &[Override],
    limits: &Limits,
) -> Result<Outcome, Violation> {
    let options = check_options(limits);
    let diags = guarded(Stage::Check, || {
        lang::check_only_with(src, overrides, &options)
    })?;
    located(Stage::Check, src, &diags)?;
    Ok(match errors(&diags) {
        0 => Outcome::Accepted,
        n => Outcome::Rejected { errors: n },
    })
}

/// Checks and compiles `src` (the fuzz target `compile`); an input `check`
/// accepts must compile.
pub fn compile(src: &SourceFile) -> Result<(Outcome, Option<lang::CompiledModel>), Violation> {
    compile_with(src, &[], &Limits::default())
}

/// [`compile`] with `--set` overrides and resource limits.
pub fn compile_with(
    src: &SourceFile,
    overrides: &[Override],
    limits: &Limits,
) -> Result<(Outcome, Option<lang::CompiledModel>), Violation> {
    let checked = check_with(src, overrides, limits)?;
    let options = check_options(limits);
    let compiled = guarded(Stage::Compile, || {
        lang::compile_with(src, overrides, &options)
    })?;
    match compiled {
        Ok(model) => Ok((checked, Some(model))),
        Err(diags) => {
            located(Stage::Compile, src, &diags)?;
            if checked == Outcome::Accepted {
                return Err(Violation::CheckMissed {
                    diagnostic: Box::new(diags[0].clone()),
                });
            }
            Ok((
                Outcome::Rejected {
                    errors: errors(&diags),
                },
                None,
            ))
        }
    }
}

/// Checks, compiles and simulates `src` within `budget`, evaluating the
/// outputs at every sample (the fuzz target `run`); a run-time error must be
/// located as `hybsim run` renders it.
pub fn run(src: &SourceFile, budget: &Budget) -> Result<Outcome, Violation> {
    run_with(src, &[], budget)
}

/// [`run`] with `--set` overrides.
pub fn run_with(
    src: &SourceFile,
    overrides: &[Override],
    budget: &Budget,
) -> Result<Outcome, Violation> {
    let (outcome, model) = compile_with(src, overrides, &budget.limits)?;
    let Some(model) = model else {
        return Ok(outcome);
    };
    let mut settings = model.settings();
    settings.horizon_t = settings.horizon_t.min(budget.horizon_t);
    settings.horizon_j = settings.horizon_j.min(budget.horizon_j);
    let mut sink = Bounded {
        model: &model,
        out: vec![0.0; model.output_names().len()],
        samples: 0,
        budget,
        start: Instant::now(),
    };
    let result = guarded(Stage::Run, || {
        let (x0, mut rng) = model.start(model.seed());
        crate::engine::simulate(&model, &x0, &settings, &mut rng, &mut sink)
    })?;
    match result {
        Ok(_) => Ok(Outcome::Ran {
            samples: sink.samples,
        }),
        Err(e) => {
            let d = guarded(Stage::Run, || model.runtime_diagnostic(&e))?;
            located(Stage::Run, src, std::slice::from_ref(&d))?;
            Ok(Outcome::Failed { code: d.code })
        }
    }
}

/// The cargo-fuzz targets (`fuzz/fuzz_targets/*.rs`), one per stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Target {
    /// [`parse`].
    Parse,
    /// [`check`].
    Check,
    /// [`compile`].
    Compile,
    /// [`run`].
    Run,
}

impl Target {
    /// Every target, in pipeline order.
    pub const ALL: [Target; 4] = [Target::Parse, Target::Check, Target::Compile, Target::Run];

    /// The target's name (its file in `fuzz/fuzz_targets/`).
    pub fn name(self) -> &'static str {
        match self {
            Target::Parse => "parse",
            Target::Check => "check",
            Target::Compile => "compile",
            Target::Run => "run",
        }
    }

    /// The body of the fuzz target: `data` as an [`Input`] (a model's
    /// text, possibly followed by `%%set` overrides and `%%table` files;
    /// what `hybsim` does with a model or override that is not UTF-8 is the
    /// CLI's business: such inputs are skipped).
    pub fn exercise(self, data: &[u8]) -> Result<Outcome, Violation> {
        let Some(input) = Input::from_bytes(data) else {
            return Ok(Outcome::Rejected { errors: 0 });
        };
        input.exercise(self)
    }
}

/// One fuzz case: a model's text, the `--set` overrides given with it (as
/// typed: `name=value`) and the files its `table("…")` calls may read
/// (name, bytes), written beside the model in a temporary folder.
///
/// As bytes ([`Input::from_bytes`], the fuzz targets' input and the seed
/// files): the model, then any number of sections, each from a line
/// starting with `%%`: `%%set name=value` (the rest of the line is one
/// override) or `%%table NAME` (the lines up to the next `%%` line are
/// the file `NAME`); other lines after the model, up to the next `%%` line,
/// are ignored. Text without such lines is a model alone.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Input {
    /// The model's text.
    pub model: String,
    /// `--set` arguments, as typed.
    pub overrides: Vec<String>,
    /// Table files: a plain file name (letters, digits, `_`, `-`, `.`; not
    /// starting with `.`) and its bytes.
    pub tables: Vec<(String, Vec<u8>)>,
}

impl Input {
    /// A model without overrides or tables.
    pub fn model(text: impl Into<String>) -> Self {
        Self {
            model: text.into(),
            ..Self::default()
        }
    }

    /// Reads the framed form (see [`Input`]); `None` when the model or an
    /// override is not UTF-8. A table section with an unusable name is
    /// dropped (the model then finds no such file).
    pub fn from_bytes(data: &[u8]) -> Option<Self> {
        let mut input = Input::default();
        let mut lines = data.split_inclusive(|&b| b == b'\n').peekable();
        let mut model = Vec::new();
        while let Some(line) = lines.next_if(|l| !l.starts_with(b"%%")) {
            model.extend_from_slice(line);
        }
        input.model = String::from_utf8(model).ok()?;
        // Each header is a `%%` line: the model, and each section's body, end at one.
        while let Some(header) = lines.next() {
            // The section's body: a table's bytes; ignored after any other header (the lines
            // between `%%set` lines, say).
            let mut body = Vec::new();
            while let Some(line) = lines.next_if(|l| !l.starts_with(b"%%")) {
                body.extend_from_slice(line);
            }
            let header = std::str::from_utf8(&header[2..]).ok()?;
            let header = header.strip_suffix('\n').unwrap_or(header);
            let header = header.strip_suffix('\r').unwrap_or(header);
            if let Some(set) = header.strip_prefix("set ") {
                input.overrides.push(set.to_string());
            } else if let Some(name) = header.strip_prefix("table ") {
                let plain = !name.is_empty()
                    && !name.starts_with('.')
                    && name
                        .bytes()
                        .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'-' | b'.'));
                if plain {
                    input.tables.push((name.to_string(), body));
                }
            }
        }
        Some(input)
    }

    /// The framed form, read back by [`Input::from_bytes`] (a model line
    /// starting with `%%` would be read as a section).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = self.model.clone().into_bytes();
        let sections = !(self.overrides.is_empty() && self.tables.is_empty());
        if sections && !out.is_empty() && !out.ends_with(b"\n") {
            out.push(b'\n');
        }
        for o in &self.overrides {
            out.extend_from_slice(format!("%%set {o}\n").as_bytes());
        }
        for (name, bytes) in &self.tables {
            out.extend_from_slice(format!("%%table {name}\n").as_bytes());
            out.extend_from_slice(bytes);
            if !bytes.is_empty() && !bytes.ends_with(b"\n") {
                out.push(b'\n');
            }
        }
        out
    }

    /// Runs `target` on this case within [`Budget::instrumented`].
    pub fn exercise(&self, target: Target) -> Result<Outcome, Violation> {
        let budget = Budget::instrumented();
        match target {
            Target::Parse => self.parse(),
            Target::Check => self.with_model(|src, ov| check_with(src, ov, &budget.limits)),
            Target::Compile => {
                self.with_model(|src, ov| compile_with(src, ov, &budget.limits).map(|(o, _)| o))
            }
            Target::Run => self.run(&budget),
        }
    }

    /// [`parse`] of the model, and each override parsed as the CLI does.
    pub fn parse(&self) -> Result<Outcome, Violation> {
        let src = SourceFile::new("fuzz.hyb", self.model.as_str());
        let model = parse(&src)?;
        match self.overrides(&src)? {
            Ok(_) => Ok(model),
            Err(errors) => Ok(Outcome::Rejected { errors }),
        }
    }

    /// [`check_with`] on this case, with `hybsim`'s limits.
    pub fn check(&self) -> Result<Outcome, Violation> {
        self.with_model(|src, ov| check_with(src, ov, &Limits::default()))
    }

    /// [`run_with`] on this case.
    pub fn run(&self, budget: &Budget) -> Result<Outcome, Violation> {
        self.with_model(|src, ov| run_with(src, ov, budget))
    }

    /// The overrides parsed as `hybsim` parses `--set`: all of them, or
    /// the number of those refused (each refusal located in its override).
    fn overrides(&self, src: &SourceFile) -> Result<Result<Vec<Override>, usize>, Violation> {
        let mut parsed = Vec::new();
        let mut refused = Vec::new();
        for o in &self.overrides {
            match guarded(Stage::Parse, || o.parse::<Override>())? {
                Ok(o) => parsed.push(o),
                Err(d) => refused.push(d),
            }
        }
        located(Stage::Parse, src, &refused)?;
        Ok(if refused.is_empty() {
            Ok(parsed)
        } else {
            Err(refused.len())
        })
    }

    /// Calls `f` with the model (in a temporary folder holding the
    /// tables, if any) and the parsed overrides; refused overrides end the
    /// case as `hybsim` does, before the model is read.
    fn with_model(
        &self,
        f: impl FnOnce(&SourceFile, &[Override]) -> Result<Outcome, Violation>,
    ) -> Result<Outcome, Violation> {
        let dir;
        let src = if self.tables.is_empty() {
            SourceFile::new("fuzz.hyb", self.model.as_str())
        } else {
            dir = tempfile::tempdir().expect("a temporary folder for the tables");
            for (name, bytes) in &self.tables {
                std::fs::write(dir.path().join(name), bytes).expect("a table file written");
            }
            SourceFile::new(
                dir.path().join("fuzz.hyb").to_string_lossy(),
                self.model.as_str(),
            )
        };
        match self.overrides(&src)? {
            Ok(overrides) => f(&src, &overrides),
            Err(errors) => Ok(Outcome::Rejected { errors }),
        }
    }
}

/// The sink of a bounded run: evaluates the outputs at each sample (as the
/// file sinks do) and stops the run when the budget is spent.
struct Bounded<'a> {
    model: &'a lang::CompiledModel,
    out: Vec<f64>,
    samples: usize,
    budget: &'a Budget,
    start: Instant,
}

impl ArcSink for Bounded<'_> {
    fn sample(&mut self, at: HybridTime, x: &[f64], _kind: SampleKind) -> ControlFlow<()> {
        self.model.outputs(at, x, &mut self.out);
        self.samples += 1;
        if self.samples >= self.budget.samples || self.start.elapsed() > self.budget.wall {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    }

    fn jump(&mut self, _: HybridTime, _: usize, _: &[f64], _: &[f64]) -> ControlFlow<()> {
        ControlFlow::Continue(())
    }

    fn poll(&mut self) -> ControlFlow<()> {
        match self.start.elapsed() > self.budget.wall {
            true => ControlFlow::Break(()),
            false => ControlFlow::Continue(()),
        }
    }
}
