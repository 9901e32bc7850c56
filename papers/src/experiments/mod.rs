//! Paper experiments run through the whole pipeline: a `.hyb` model is
//! parsed, checked and compiled with `--set`-style overrides
//! ([`hybsim::lang`]), simulated ([`hybsim::engine`]), and the logged arc is
//! read back and analysed ([`crate::analysis`]).
//!
//! * [`StepTable`]: the per-step values (states and outputs) of a
//!   discrete-time run, one row per jump index `j = k`.
//! * [`consensus_estimation`]: `models/consensus_estimation.hyb` (Perez-Salesa
//!   et al.), the metrics of Sec. 5 and the constants of Prop. 1.
//! * [`variance_trigger`]: `models/variance_triggering.hyb` (Trimpe and
//!   D'Andrea) for given parameters, and the Fig. 4 δ sweep against
//!   Algorithm 1 of [`crate::analysis::variance_trigger`].
//! * [`intermittent`]: Fig. 2 of Phillips–Erwin–Sanfelice from
//!   `models/intermittent_estimation.hyb`.
//! * [`platoon`]: `models/platoon.hyb` (Muehlebach and Trimpe) compiled once,
//!   many seeds, streaming steady-state statistics (Fig. 5 left, Fig. 6).
//!
//! Used by the reproduction tests and the `examples/` figure programs, so
//! both compute the same data in the same way.

pub mod consensus_estimation;
pub mod intermittent;
pub mod platoon;
pub mod variance_trigger;

use thiserror::Error;

use hybsim::arc::{ArcSink, HybridArc, Termination};
use hybsim::diagnostics::Diagnostic;
use hybsim::engine::{HybridSystem, SimError, simulate as engine_simulate, simulate_arc};
use hybsim::lang::{self, CompiledModel, Override};
use hybsim::source::SourceFile;

/// Why an experiment could not be run.
#[derive(Debug, Clone, Error)]
pub enum ExperimentError {
    /// An override `name=value` did not parse.
    #[error("override `{text}` does not parse: {}", .diagnostic.message)]
    Override {
        /// The override text.
        text: String,
        /// The parser's diagnostic.
        diagnostic: Box<Diagnostic>,
    },
    /// The model did not compile (render with [`hybsim::diagnostics::render`]).
    #[error("model `{model}` does not compile ({} error(s)): {}", .diagnostics.len(),
            .diagnostics.first().map_or("", |d| d.message.as_str()))]
    Compile {
        /// The model's file name.
        model: String,
        /// Every diagnostic.
        diagnostics: Vec<Diagnostic>,
    },
    /// The simulation failed.
    #[error("simulation of `{model}` failed: {error}")]
    Simulation {
        /// The model's name.
        model: String,
        /// The engine's error.
        error: SimError,
    },
    /// The model has no state or output of this name.
    #[error("model `{model}` has no state or output `{name}`")]
    MissingName {
        /// The model's name.
        model: String,
        /// The name looked up.
        name: String,
    },
    /// The model has no scalar parameter of this name.
    #[error("model `{model}` has no scalar parameter `{name}`")]
    MissingParameter {
        /// The model's name.
        model: String,
        /// The name looked up.
        name: String,
    },
    /// A model file could not be read.
    #[error("cannot read `{path}`: {message}")]
    Io {
        /// The file.
        path: String,
        /// The operating system's message.
        message: String,
    },
    /// A run ended before its time horizon (e.g. at the jump horizon J).
    #[error("run of `{model}` stopped at t = {at} before the horizon T: {cause}")]
    Stopped {
        /// The model's name.
        model: String,
        /// Ordinary time at the end.
        at: f64,
        /// Why it ended (the termination, as text).
        cause: String,
    },
    /// An experiment setting is out of range.
    #[error("invalid experiment setting: {message}")]
    InvalidSetting {
        /// What is wrong.
        message: String,
    },
}

/// Parses `name=value` overrides (values are `.hyb` expressions; format
/// numbers with `{}` so they round-trip exactly).
pub fn overrides<S: AsRef<str>>(sets: &[S]) -> Result<Vec<Override>, ExperimentError> {
    sets.iter()
        .map(|s| {
            s.as_ref()
                .parse::<Override>()
                .map_err(|d| ExperimentError::Override {
                    text: s.as_ref().to_string(),
                    diagnostic: Box::new(d),
                })
        })
        .collect()
}

/// Compiles `src` with the overrides `sets` (`["delta=3", "T=100.5"]`).
pub fn compile<S: AsRef<str>>(
    src: &SourceFile,
    sets: &[S],
) -> Result<CompiledModel, ExperimentError> {
    let ov = overrides(sets)?;
    lang::compile(src, &ov).map_err(|diagnostics| ExperimentError::Compile {
        model: src.name().to_string(),
        diagnostics,
    })
}

/// Simulates `model` as `hybsim run` does, with the model's seed
/// ([`CompiledModel::start`]: initial draws and the run's generator).
pub fn simulate(model: &CompiledModel) -> Result<HybridArc, ExperimentError> {
    simulate_seeded(model, model.seed())
}

/// As [`simulate`] with another seed (same as `hybsim run --seed SEED`), so
/// that an ensemble of runs needs one compilation.
pub fn simulate_seeded(model: &CompiledModel, seed: u64) -> Result<HybridArc, ExperimentError> {
    let (x0, mut rng) = model.start(seed);
    simulate_arc(model, &x0, &model.settings(), &mut rng).map_err(|error| {
        ExperimentError::Simulation {
            model: model.name().to_string(),
            error,
        }
    })
}

/// As [`simulate_seeded`], streaming into `sink` instead of keeping the
/// arc (for long runs whose statistics are computed on the fly).
pub fn simulate_seeded_into(
    model: &CompiledModel,
    seed: u64,
    sink: &mut dyn ArcSink,
) -> Result<Termination, ExperimentError> {
    let (x0, mut rng) = model.start(seed);
    engine_simulate(model, &x0, &model.settings(), &mut rng, sink).map_err(|error| {
        ExperimentError::Simulation {
            model: model.name().to_string(),
            error,
        }
    })
}

/// A scalar parameter of a compiled model, as resolved by the checker
/// (after overrides, derived parameters recomputed).
pub fn scalar_parameter(model: &CompiledModel, name: &str) -> Result<f64, ExperimentError> {
    model.parameters_json()[name]
        .as_f64()
        .ok_or_else(|| ExperimentError::MissingParameter {
            model: model.name().to_string(),
            name: name.to_string(),
        })
}

/// The values of every state and output of a discrete-time run at each
/// jump index `j = 0, 1, …, J`: the initial point, then each post-jump
/// point. For a model whose only rule is an `every` step, row `k` is the
/// state at time k and the outputs computed from it.
#[derive(Debug, Clone, PartialEq)]
pub struct StepTable {
    names: Vec<String>,
    /// `columns[i][k]`: value of `names[i]` at step k.
    columns: Vec<Vec<f64>>,
    times: Vec<f64>,
}

impl StepTable {
    /// Reads the per-step rows of `arc`, a run of `model`.
    pub fn from_arc(model: &CompiledModel, arc: &HybridArc) -> Self {
        let states = model.state_names();
        let outputs = model.output_names();
        let (n, m) = (states.len(), outputs.len());
        let mut columns = vec![Vec::new(); n + m];
        let mut times = Vec::new();
        let mut out = vec![0.0; m];
        let mut last_j = None;
        for s in arc.samples() {
            if last_j == Some(s.at.j) {
                continue;
            }
            last_j = Some(s.at.j);
            times.push(s.at.t);
            model.outputs(s.at, s.x, &mut out);
            for (c, &v) in columns.iter_mut().zip(s.x.iter().chain(&out)) {
                c.push(v);
            }
        }
        Self {
            names: states.into_iter().chain(outputs).collect(),
            columns,
            times,
        }
    }

    /// Number of steps recorded (rows).
    pub fn len(&self) -> usize {
        self.times.len()
    }

    /// `true` if no row was recorded.
    pub fn is_empty(&self) -> bool {
        self.times.is_empty()
    }

    /// Ordinary time of each row.
    pub fn times(&self) -> &[f64] {
        &self.times
    }

    /// Names of the columns: the states, then the outputs.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// The sequence of a state or output, if the model has it.
    pub fn column(&self, name: &str) -> Option<&[f64]> {
        let i = self.names.iter().position(|n| n == name)?;
        Some(&self.columns[i])
    }
}
