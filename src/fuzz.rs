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
//! A hang is the one failure these functions cannot see: callers bound the
//! time (the mutation test runs each case on a thread with a deadline,
//! libFuzzer has `-timeout`).

use std::ops::ControlFlow;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::time::{Duration, Instant};

use crate::arc::{ArcSink, HybridTime, SampleKind};
use crate::diagnostics::{Diagnostic, Severity};
use crate::lang;
use crate::source::SourceFile;

/// How far a compiled input is simulated: the model's own horizons, cut to
/// these. The run also stops after `samples` samples or `wall` of wall time
/// (checked at each sample), so an input that asks for 10⁹ steps costs
/// little.
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
}

impl Default for Budget {
    fn default() -> Self {
        Self {
            horizon_t: 2.0,
            horizon_j: 200,
            samples: 20_000,
            wall: Duration::from_secs(1),
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
    let diags = guarded(Stage::Check, || lang::check_only(src, &[]))?;
    located(Stage::Check, src, &diags)?;
    Ok(match errors(&diags) {
        0 => Outcome::Accepted,
        n => Outcome::Rejected { errors: n },
    })
}

/// Checks and compiles `src` (the fuzz target `compile`); an input `check`
/// accepts must compile.
pub fn compile(src: &SourceFile) -> Result<(Outcome, Option<lang::CompiledModel>), Violation> {
    let checked = check(src)?;
    let compiled = guarded(Stage::Compile, || lang::compile(src, &[]))?;
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
    let (outcome, model) = compile(src)?;
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
    /// [`run`] with the default [`Budget`].
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

    /// The body of the fuzz target: `data` as the text of a model file
    /// `fuzz.hyb` in the current folder (what `hybsim` does with a file that
    /// is not UTF-8 is the CLI's business: such inputs are skipped).
    pub fn exercise(self, data: &[u8]) -> Result<Outcome, Violation> {
        let Ok(text) = std::str::from_utf8(data) else {
            return Ok(Outcome::Rejected { errors: 0 });
        };
        let src = SourceFile::new("fuzz.hyb", text);
        match self {
            Target::Parse => parse(&src),
            Target::Check => check(&src),
            Target::Compile => compile(&src).map(|(o, _)| o),
            Target::Run => run(&src, &Budget::default()),
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
}
