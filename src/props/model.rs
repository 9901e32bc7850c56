//! `.hyb` models as property-test subjects.

use super::monitor::{PropertySink, Verdict};
use super::property::Property;
use super::runner::{Case, Input, Subject};
use crate::arc::{ArcSink, Termination};
use crate::diagnostics::Diagnostic;
use crate::engine::{HybridSystem, SimError, SimSettings, simulate};
use crate::lang::{self, CheckOptions, CompiledModel, Override};
use crate::source::SourceFile;

/// Why a case of a [`ModelSubject`] could not run.
#[derive(Debug, Clone, thiserror::Error)]
pub enum ModelRunError {
    /// The model did not compile with the case's values pinned.
    #[error("the model does not compile with this case's values: {}", first_message(.0))]
    Compile(Vec<Diagnostic>),
    /// The simulation failed.
    #[error(transparent)]
    Sim(#[from] SimError),
}

fn first_message(d: &[Diagnostic]) -> &str {
    d.first().map_or("no diagnostic", |d| d.message.as_str())
}

/// Cases a property test of a model with random draws samples by default.
pub const DEFAULT_CASES: usize = 100;

/// A `.hyb` model whose random initial values
/// ([`CompiledModel::random_inputs`]) are the sampled inputs.
///
/// A case runs exactly as `hybsim run` does: the model is compiled with
/// the user's overrides and each input pinned (`name=value`), started with
/// [`CompiledModel::start`]`(case.seed)` and simulated with its settings
/// (horizons shortened by the case). So `hybsim run MODEL --seed S
/// --set h=V …` ([`replay_args`](super::replay_args)) replays a case bit for bit.
///
/// ```
/// use hybsim::lang::CompiledModel;
/// use hybsim::props::{ModelSubject, Subject};
/// use hybsim::source::SourceFile;
///
/// let src = SourceFile::new("ball.hyb", "model ball
/// state h ~ uniform(0, 2), v = 0
/// flow { h' = v; v' = -9.81 } in h >= 0
/// jump impact when h <= 0 && v <= 0 { v+ = -0.8 * v }
/// sim { T = 3 }
/// ");
/// let ball = ModelSubject::new(src, Vec::new()).unwrap();
/// assert_eq!(ball.inputs()[0].name, "h");
/// ```
#[derive(Debug, Clone)]
pub struct ModelSubject {
    source: SourceFile,
    overrides: Vec<Override>,
    model: CompiledModel,
    inputs: Vec<Input>,
    settings: SimSettings,
    options: CheckOptions,
}

impl ModelSubject {
    /// Compiles `source` with `overrides` (`--set`; a pinned initial value
    /// is no longer an input).
    ///
    /// # Errors
    /// Every diagnostic if the model does not compile.
    pub fn new(source: SourceFile, overrides: Vec<Override>) -> Result<Self, Vec<Diagnostic>> {
        Self::with_options(source, overrides, CheckOptions::default())
    }

    /// As [`ModelSubject::new`], every case compiled with checker `options`
    /// (`hybsim test --sdp`).
    ///
    /// # Errors
    /// Every diagnostic if the model does not compile.
    pub fn with_options(
        source: SourceFile,
        overrides: Vec<Override>,
        options: CheckOptions,
    ) -> Result<Self, Vec<Diagnostic>> {
        let model = lang::compile_with(&source, &overrides, &options)?;
        let inputs = model.random_inputs().to_vec();
        let settings = model.settings();
        Ok(Self {
            source,
            overrides,
            model,
            inputs,
            settings,
            options,
        })
    }

    /// The model as compiled with the user's overrides (inputs not pinned).
    pub fn model(&self) -> &CompiledModel {
        &self.model
    }

    /// How many cases a property test samples unless told: cases differ
    /// only in their random draws, so a model without any
    /// ([`CompiledModel::is_random`]) has one, others
    /// [`DEFAULT_CASES`].
    pub fn default_cases(&self) -> usize {
        if self.model.is_random() {
            DEFAULT_CASES
        } else {
            1
        }
    }

    /// The user's overrides.
    pub fn overrides(&self) -> &[Override] {
        &self.overrides
    }

    /// The overrides of one case: the user's, then one `name=value` per
    /// input (values in shortest round-trip form, as
    /// [`replay_args`](super::replay_args) prints them).
    ///
    /// # Errors
    /// A diagnostic if a pinned value does not parse (not expected).
    pub fn case_overrides(&self, case: &Case) -> Result<Vec<Override>, Diagnostic> {
        // An input the user made random with `--set x=uniform(..)` is pinned
        // instead of drawn: its user override gives way.
        let mut all: Vec<Override> = self
            .overrides
            .iter()
            .filter(|o| !self.inputs.iter().any(|i| i.name == o.name))
            .cloned()
            .collect();
        for (input, v) in self.inputs.iter().zip(&case.values) {
            all.push(format!("{}={}", input.name, super::report::fmt_value(*v)).parse()?);
        }
        Ok(all)
    }

    /// The model compiled for `case` (inputs pinned).
    ///
    /// # Errors
    /// [`ModelRunError::Compile`] if it does not compile.
    pub fn compile_case(&self, case: &Case) -> Result<CompiledModel, ModelRunError> {
        let overrides = self
            .case_overrides(case)
            .map_err(|d| ModelRunError::Compile(vec![d]))?;
        lang::compile_with(&self.source, &overrides, &self.options).map_err(ModelRunError::Compile)
    }
}

impl Subject for ModelSubject {
    type Error = ModelRunError;

    fn inputs(&self) -> &[Input] {
        &self.inputs
    }

    fn state_names(&self) -> Vec<String> {
        self.model.state_names()
    }

    fn report_names(&self) -> Vec<String> {
        let names = self.model.state_names();
        self.model.state_layout().flat_names(names.len())
    }

    fn settings(&self) -> &SimSettings {
        &self.settings
    }

    fn run(&self, case: &Case, sink: &mut dyn ArcSink) -> Result<Termination, ModelRunError> {
        let pinned;
        let model = if self.inputs.is_empty() {
            &self.model
        } else {
            pinned = self.compile_case(case)?;
            &pinned
        };
        run_model(model, case, sink)
    }

    /// As the default, but the model's own properties among `props` are
    /// taken from the case's compilation: parameters (random ones included)
    /// are folded into them.
    fn run_checked(&self, case: &Case, props: &[Property]) -> Result<Verdict, ModelRunError> {
        if self.model.random_params().is_empty() {
            let mut sink = PropertySink::new(props);
            self.run(case, &mut sink)?;
            return Ok(sink.verdict());
        }
        let model = self.compile_case(case)?;
        let own = model.properties();
        let props: Vec<Property> = props
            .iter()
            .map(|p| {
                own.iter()
                    .find(|q| q.name() == p.name())
                    .unwrap_or(p)
                    .clone()
            })
            .collect();
        let mut sink = PropertySink::new(&props);
        run_model(&model, case, &mut sink)?;
        Ok(sink.verdict())
    }
}

/// Simulates `model` for `case` as `hybsim run` does.
fn run_model(
    model: &CompiledModel,
    case: &Case,
    sink: &mut dyn ArcSink,
) -> Result<Termination, ModelRunError> {
    let settings = case.apply(&model.settings());
    let (x0, mut rng) = model.start(case.seed);
    Ok(simulate(model, &x0, &settings, &mut rng, sink)?)
}
