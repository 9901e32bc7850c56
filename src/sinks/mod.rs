//! Outputs of a run: implementors of [`ArcSink`] that write a solution to
//! disk as it is computed.
//!
//! | sink | file | for |
//! |---|---|---|
//! | [`mcap::McapSink`] | `.mcap` (JSON messages, zstd chunks) | Foxglove, the MCAP readers, archiving a run with everything needed to reproduce it |
//! | [`csv::CsvSink`] | `.csv`, one row per logged sample | spreadsheets, pandas |
//! | [`plot::PlotSink`] | `.svg` or `.png`, one panel per state entry (HyEQ's plot kinds) | a first look at a run |
//! | [`parquet::ParquetSink`] | `.parquet`, one row per logged sample, and `.jumps.parquet`, one row per jump | pandas, polars, DuckDB, Arrow |
//!
//! The engine pushes every sample and jump; each sink decides what to keep
//! through a [`Decimation`] that always keeps the initial, pre-jump,
//! post-jump and final samples. [`Fanout`] forwards one run to several
//! sinks. File sinks write to a temporary file beside `<path>` and rename it
//! into place only when their `finish` succeeds, so a file at `<path>` is
//! always complete, and an unfinished sink leaves nothing behind.
//!
//! Sinks never write non-finite numbers: a sample with a NaN or infinite
//! component stops the run ([`std::ops::ControlFlow::Break`]) and `finish`
//! reports it as [`SinkError::NonFinite`]. The engine normally stops first,
//! with its own error naming (t, j) and the component.

pub mod csv;
pub mod foxglove;
pub mod json;
pub mod mcap;
pub mod mcap_read;
pub mod mcap_writer;
pub mod parquet;
pub mod plot;
pub mod protobuf;
mod record_shape;

use std::collections::BTreeMap;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::arc::{
    ArcSink, FlowPiece, HybridArc, HybridTime, SampleKind, SolverSwitch, Termination,
    TerminationCause,
};
use crate::layout::{Entry, Field, Layout};

/// Errors of the output sinks.
#[derive(Debug, thiserror::Error)]
pub enum SinkError {
    /// A file could not be created, written, synced or renamed.
    #[error("cannot write `{path}`: {source}")]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The MCAP writer failed.
    #[error("cannot write MCAP file `{path}`: {source}")]
    Mcap {
        /// The file concerned.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The CSV writer failed.
    #[error("cannot write CSV file `{path}`: {source}")]
    Csv {
        /// The file concerned.
        path: PathBuf,
        /// The underlying error.
        source: ::csv::Error,
    },
    /// The Parquet writer failed.
    #[error("cannot write Parquet file `{path}`: {source}")]
    Table {
        /// The file concerned.
        path: PathBuf,
        /// The underlying error.
        source: parquet::TableError,
    },
    /// Plotting failed.
    #[error("cannot draw plot `{path}`: {message}")]
    Plot {
        /// The file concerned.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// A layout does not describe a vector of the given dimension.
    #[error("the {what} layout does not match its dimension {dim}: {problem}")]
    Layout {
        /// `state` or `output`.
        what: &'static str,
        /// The dimension of the vector.
        dim: usize,
        /// Which component is missing, doubly covered or out of range.
        problem: String,
    },
    /// A sample carried a NaN or infinite value, which JSON cannot represent;
    /// the run was stopped before it was written.
    #[error(
        "{what} `{name}` is not finite ({value}) at {at}; the run was stopped there and nothing non-finite was written"
    )]
    NonFinite {
        /// `state` or `output`.
        what: &'static str,
        /// The component's index in the state or the outputs.
        component: usize,
        /// Flat name of the component (e.g. `P[1,2]`).
        name: String,
        /// The offending value.
        value: f64,
        /// Where on the hybrid time domain.
        at: HybridTime,
    },
    /// The options are inconsistent.
    #[error("invalid option `{option}`: {message}")]
    Option {
        /// Option name (as on the command line).
        option: &'static str,
        /// What to change.
        message: String,
    },
    /// A plot file's extension names no image format hybsim writes.
    #[error(
        "cannot draw plot `{path}`: `.{extension}` is not an image format hybsim writes (use `.svg` or `.png`)"
    )]
    ImageFormat {
        /// The file asked for.
        path: PathBuf,
        /// Its extension.
        extension: String,
    },
    /// A plot kind needs more components than were selected.
    #[error(
        "a {kind} plot needs {needed}, {selected} selected: name them (e.g. `--plot-vars h,v`, `hybsim plot --vars h,v`)"
    )]
    TooFewComponents {
        /// The plot kind (`phase`).
        kind: &'static str,
        /// Components it draws, in words (`two components`).
        needed: &'static str,
        /// Components selected.
        selected: usize,
    },
    /// A plot selection names something that is neither a state nor an output.
    #[error("`{name}` is neither a state nor an output of the model (known: {known})")]
    UnknownSignal {
        /// The name asked for.
        name: String,
        /// The names that exist.
        known: String,
    },
}

impl SinkError {
    pub(crate) fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// Checks that `layout` covers components of a vector of dimension `dim`
/// at most once each. Components it does not cover are not logged (the
/// timers the language adds, or states left out by a `log` selection).
pub fn check_layout(layout: &Layout, dim: usize, what: &'static str) -> Result<(), SinkError> {
    let mut covered = vec![false; dim];
    let err = |problem: String| SinkError::Layout { what, dim, problem };
    let mut mark = |f: &Field, prefix: &str| -> Result<(), SinkError> {
        // Checked: the layout may come from a file (`hybsim plot`).
        let end = f.offset.saturating_add(f.shape.len());
        if end > dim {
            return Err(err(format!(
                "`{prefix}{}` spans components {}..{end}",
                f.name, f.offset
            )));
        }
        for (k, c) in covered[f.offset..end].iter_mut().enumerate() {
            if *c {
                return Err(err(format!(
                    "component {} is covered twice (again by `{prefix}{}`)",
                    f.offset + k,
                    f.name
                )));
            }
            *c = true;
        }
        Ok(())
    };
    for e in &layout.entries {
        match e {
            Entry::Field(f) => mark(f, "")?,
            Entry::Family {
                name,
                labels,
                members,
            } => {
                if labels.len() != members.len() {
                    return Err(err(format!(
                        "family `{name}` has {} labels for {} members",
                        labels.len(),
                        members.len()
                    )));
                }
                for (label, fields) in labels.iter().zip(members) {
                    for f in fields {
                        mark(f, &format!("{name}[{label}]."))?;
                    }
                }
            }
        }
    }
    Ok(())
}

/// Names of the top-level entries of a layout (fields and families).
pub fn entry_names(layout: &Layout) -> Vec<&str> {
    layout
        .entries
        .iter()
        .map(|e| match e {
            Entry::Field(f) => f.name.as_str(),
            Entry::Family { name, .. } => name.as_str(),
        })
        .collect()
}

pub use crate::arc::OutputMap;

/// The output map the sinks get ([`OutputMap`]).
pub type OutputFn<'a> = &'a (dyn OutputMap + 'a);

/// A file sink's outputs: the values at the last point evaluated, brought
/// to the next point with as little work as its [`OutputMap`] allows (none
/// at the same hybrid time, [`OutputMap::eval_after_jump`] across a jump).
pub(crate) struct LoggedOutputs<'a> {
    map: Option<OutputFn<'a>>,
    y: Vec<f64>,
    /// Where `y` was evaluated (`None`: nowhere yet).
    at: Option<HybridTime>,
    /// The rules that jumped from `fired_at` (whether or not `y` was
    /// evaluated there yet).
    fired: Vec<usize>,
    fired_at: Option<HybridTime>,
}

impl<'a> LoggedOutputs<'a> {
    /// Outputs of dimension `dim` by `map` (`None`: the sink logs none).
    pub fn new(map: Option<OutputFn<'a>>, dim: usize) -> Self {
        Self {
            map,
            y: vec![0.0; if map.is_some() { dim } else { 0 }],
            at: None,
            fired: Vec::new(),
            fired_at: None,
        }
    }

    /// Notes a jump of rule `rule` from the pre-jump point `at`.
    pub fn jump(&mut self, at: HybridTime, rule: usize) {
        if self.fired_at != Some(at) {
            self.fired.clear();
            self.fired_at = Some(at);
        }
        self.fired.push(rule);
    }

    /// The outputs at `at`, `x`: kept, updated after the jump from the
    /// previous point, or evaluated.
    pub fn at(&mut self, at: HybridTime, x: &[f64]) -> &[f64] {
        let Some(map) = self.map else {
            return &self.y;
        };
        match self.at {
            Some(p) if p == at => {}
            Some(p) if self.fired_at == Some(p) && p.t == at.t && p.j + 1 == at.j => {
                map.eval_after_jump(&self.fired, at, x, &mut self.y)
            }
            _ => map.eval(at, x, &mut self.y),
        }
        self.at = Some(at);
        &self.y
    }

    /// The outputs last returned by [`at`](Self::at).
    pub fn values(&self) -> &[f64] {
        &self.y
    }
}

/// What the sinks know about a run: structure of the logged vectors and
/// everything needed to reproduce the run from its log.
#[derive(Debug, Clone, Serialize)]
pub struct RunInfo {
    /// Model name (the `model` header).
    pub model_name: String,
    /// Path of the model file, as given on the command line.
    pub model_path: String,
    /// The model source exactly as parsed.
    #[serde(skip)]
    pub source: String,
    /// The files the model imports (`import "lib/zoh.hyb"`): path and text.
    #[serde(skip)]
    pub imports: Vec<(String, String)>,
    /// The files the model read with `table("…")`: path and SHA-256.
    #[serde(skip)]
    pub tables: Vec<crate::tables::TableFile>,
    /// Seed of the run's random generator.
    pub seed: u64,
    /// Command line of the run (empty for library use).
    pub argv: Vec<String>,
    /// `--set name=value` overrides as given.
    pub overrides: Vec<(String, String)>,
    /// Structure of the state vector.
    pub state_layout: Layout,
    /// Dimension of the state vector.
    pub state_dim: usize,
    /// Structure of the output vector (empty if the model has no outputs).
    pub output_layout: Layout,
    /// Dimension of the output vector.
    pub output_dim: usize,
    /// Names of the jump rules, in the system's order.
    pub rule_names: Vec<String>,
    /// Per rule (the system's order), how its jumps are logged ([`RuleLog`]);
    /// rules past the end are logged in full. A jump in which no rule logged
    /// in full fires leaves, of its two samples, only the pre-jump one, as a
    /// flow sample (see [`LogFilter`]). `hybsim run` leaves the noise
    /// redraws out unless a `log` block or `--log-rules`/`--log-marks` asks
    /// for them.
    pub logged_rules: Vec<RuleLog>,
    /// Resolved parameters (after overrides), name → value.
    pub parameters: serde_json::Value,
    /// Simulation settings (horizons, solver, tolerances, priority).
    pub solver: serde_json::Value,
    /// Results of `design` blocks, if the model has any.
    pub design: Option<serde_json::Value>,
}

impl RunInfo {
    /// Run information for a system with scalar states `state_names`, no
    /// outputs, and jump rules `rule_names`; fill in the other fields as
    /// needed.
    pub fn new<S: AsRef<str>>(model_name: &str, state_names: &[S], rule_names: &[S]) -> Self {
        Self {
            model_name: model_name.to_string(),
            model_path: String::new(),
            source: String::new(),
            imports: Vec::new(),
            tables: Vec::new(),
            seed: 0,
            argv: Vec::new(),
            overrides: Vec::new(),
            state_layout: Layout::scalars(state_names),
            state_dim: state_names.len(),
            output_layout: Layout::default(),
            output_dim: 0,
            rule_names: rule_names.iter().map(|s| s.as_ref().to_string()).collect(),
            logged_rules: vec![RuleLog::Full; rule_names.len()],
            parameters: serde_json::Value::Object(Default::default()),
            solver: serde_json::Value::Object(Default::default()),
            design: None,
        }
    }

    /// This run's information with only the states and outputs named in
    /// `names` logged (entries, whole families or members such as `xh[2]`,
    /// see [`Layout::select`]), and the names that are neither.
    pub fn select_vars<S: AsRef<str>>(&self, names: &[S]) -> (RunInfo, Vec<String>) {
        let (state_layout, unknown_states) = self.state_layout.select(names);
        let (output_layout, _) = self.output_layout.select(names);
        let unknown = unknown_states
            .into_iter()
            .filter(|n| self.output_layout.find_all(n).is_empty())
            .collect();
        let info = RunInfo {
            state_layout,
            output_layout,
            ..self.clone()
        };
        (info, unknown)
    }

    /// How the jumps of rule `rule` are logged.
    pub fn rule_log(&self, rule: usize) -> RuleLog {
        self.logged_rules
            .get(rule)
            .copied()
            .unwrap_or(RuleLog::Full)
    }

    /// Names of the rules whose jumps are logged in full.
    pub fn logged_rule_names(&self) -> Vec<&str> {
        self.rule_names_logged(RuleLog::Full)
    }

    /// Names of the rules whose jumps are logged as records only.
    pub fn marked_rule_names(&self) -> Vec<&str> {
        self.rule_names_logged(RuleLog::Mark)
    }

    fn rule_names_logged(&self, how: RuleLog) -> Vec<&str> {
        self.rule_names
            .iter()
            .enumerate()
            .filter(|(k, _)| self.rule_log(*k) == how)
            .map(|(_, n)| n.as_str())
            .collect()
    }

    /// Checks that both layouts match their dimensions.
    pub fn validate(&self) -> Result<(), SinkError> {
        check_layout(&self.state_layout, self.state_dim, "state")?;
        check_layout(&self.output_layout, self.output_dim, "output")
    }

    /// Hex SHA-256 of the model source.
    pub fn source_sha256(&self) -> String {
        crate::source::sha256_hex(self.source.as_bytes())
    }

    /// Path and hex SHA-256 of each imported file.
    pub fn imports_sha256(&self) -> Vec<(String, String)> {
        self.imports
            .iter()
            .map(|(path, text)| (path.clone(), crate::source::sha256_hex(text.as_bytes())))
            .collect()
    }

    /// Flat names of the logged state components (`h`, `x[2]`, `P[1,2]`,
    /// `agent[3].xhat[1]`), in layout order.
    pub fn state_names(&self) -> Vec<String> {
        self.state_layout
            .components()
            .into_iter()
            .map(|(_, n)| n)
            .collect()
    }

    /// Flat names of the logged output components, in layout order.
    pub fn output_names(&self) -> Vec<String> {
        self.output_layout
            .components()
            .into_iter()
            .map(|(_, n)| n)
            .collect()
    }

    /// The name of state (`what = "state"`) or output component `k` for
    /// messages: its flat name, or `component k` if it is not logged.
    pub fn component_name(&self, what: &str, k: usize) -> String {
        let layout = if what == "output" {
            &self.output_layout
        } else {
            &self.state_layout
        };
        layout
            .components()
            .into_iter()
            .find(|(i, _)| *i == k)
            .map(|(_, n)| n)
            .unwrap_or_else(|| format!("component {k}"))
    }
}

/// Which samples a sink keeps. The initial, pre-jump, post-jump and final
/// samples are always kept, so that every jump appears as a vertical segment
/// and the end of the run is visible; flow samples are thinned.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Decimation {
    /// Keep every `every`-th flow sample (1 = all). Default 1.
    pub every: u64,
    /// Keep a flow sample only if at least `dt` (model time units) passed
    /// since the last kept sample. Default: no minimum.
    pub dt: Option<f64>,
}

impl Default for Decimation {
    fn default() -> Self {
        Self { every: 1, dt: None }
    }
}

impl Decimation {
    /// Keep every sample.
    pub fn all() -> Self {
        Self::default()
    }

    /// Keep every `n`-th flow sample.
    pub fn every(self, n: u64) -> Self {
        Self { every: n, ..self }
    }

    /// Keep flow samples at least `dt` apart.
    pub fn dt(self, dt: Option<f64>) -> Self {
        Self { dt, ..self }
    }

    /// Checks `every ≥ 1` and `dt ≥ 0` finite (0: no minimum, which lets
    /// `--log-dt 0` undo a model's `log { dt }`).
    pub fn validate(&self) -> Result<(), SinkError> {
        if self.every == 0 {
            return Err(SinkError::Option {
                option: "--log-every",
                message: "must be at least 1 (1 keeps every sample)".into(),
            });
        }
        if let Some(dt) = self.dt
            && !(dt.is_finite() && dt >= 0.0)
        {
            return Err(SinkError::Option {
                option: "--log-dt",
                message: format!(
                    "must be a number of time units ≥ 0 (0 keeps every flow sample), got {dt}"
                ),
            });
        }
        Ok(())
    }
}

/// The state of a [`Decimation`] along one run.
#[derive(Debug, Clone)]
pub struct Decimator {
    rule: Decimation,
    flow_count: u64,
    last_kept_t: Option<f64>,
}

impl Decimator {
    /// Starts a run.
    pub fn new(rule: Decimation) -> Self {
        Self {
            rule,
            flow_count: 0,
            last_kept_t: None,
        }
    }

    /// Whether [`keep`](Self::keep) would keep a flow sample at `at` now.
    pub fn would_keep_flow(&self, at: HybridTime) -> bool {
        let by_count = self.flow_count + 1 >= self.rule.every;
        let by_time = match (self.rule.dt, self.last_kept_t) {
            (Some(dt), Some(last)) => at.t - last >= dt,
            _ => true,
        };
        by_count && by_time
    }

    /// Whether to keep the sample at `at` of kind `kind`.
    pub fn keep(&mut self, at: HybridTime, kind: SampleKind) -> bool {
        let keep = match kind {
            SampleKind::Flow => {
                let keep = self.would_keep_flow(at);
                self.flow_count += 1;
                keep
            }
            _ => true,
        };
        if keep {
            self.flow_count = 0;
            self.last_kept_t = Some(at.t);
        }
        keep
    }
}

/// How a file sink logs the jumps of one rule ([`RunInfo::logged_rules`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum RuleLog {
    /// Not at all: no jump record, and of the jump's two samples only the
    /// pre-jump one, as a flow sample (subject to decimation).
    Off,
    /// The jump record alone (MCAP `/hybsim/jumps`, the Parquet jumps
    /// table), the samples as for [`Off`](Self::Off): the times of many
    /// events at a few dozen bytes each.
    Mark,
    /// The pre-jump sample, the jump record and the post-jump sample.
    Full,
}

impl RuleLog {
    /// Per rule: `Full` where `full` says so, else `Mark` where `marked`
    /// does, else `Off`.
    pub fn combine(full: &[bool], marked: &[bool]) -> Vec<RuleLog> {
        full.iter()
            .enumerate()
            .map(
                |(k, &f)| match (f, marked.get(k).copied().unwrap_or(false)) {
                    (true, _) => RuleLog::Full,
                    (false, true) => RuleLog::Mark,
                    (false, false) => RuleLog::Off,
                },
            )
            .collect()
    }
}

/// What of a run a file sink writes: the samples its [`Decimation`] keeps,
/// and the jumps of the rules it logs ([`RunInfo::logged_rules`]).
///
/// The engine sends a pre-jump sample, one jump record per firing rule,
/// then the post-jump sample; the filter holds the pre-jump sample until
/// the rules are known. A jump in which a rule logged in full
/// ([`RuleLog::Full`]) fires is written as usual (pre-jump sample, the
/// records of its logged and marked rules, post-jump sample). In any other
/// jump the samples are invisible: the pre-jump sample becomes a flow
/// sample (subject to decimation) and the post-jump sample is dropped, so
/// that e.g. a noise redraw at every integrator step costs one sample, not
/// three records; a marked rule ([`RuleLog::Mark`]) leaves its record
/// alone (before that flow sample, at the same time).
///
/// A held sample's values are copied only when the decimation would keep
/// it as a flow sample: a logged jump's pre-jump sample is written from the
/// jump's pre-jump state. So a run that fails (or is stopped) between a
/// pre-jump sample and its jump ends its log with that sample only if the
/// decimation keeps it.
#[derive(Debug, Clone)]
pub struct LogFilter {
    decimator: Decimator,
    logged: Vec<RuleLog>,
    /// Some rule is not logged in full (otherwise no sample is held).
    filtering: bool,
    /// The held pre-jump sample, until the jump is known.
    held_at: Option<HybridTime>,
    /// Its values, if copied.
    held: Vec<f64>,
    copied: bool,
    /// A rule logged in full fired in the current jump.
    visible: bool,
}

/// What a sink writes for a sample ([`LogFilter::route_sample`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Route {
    /// Nothing now.
    Nothing,
    /// The sample itself, as a sample of this kind.
    Sample(SampleKind),
    /// In place of the post-jump sample of a jump that is not logged: the
    /// held pre-jump sample ([`LogFilter::take_held`]), at this time, as a
    /// flow sample.
    Held(HybridTime),
}

impl LogFilter {
    /// A filter for the rules logged per `logged` (rules past the end are
    /// logged in full) and the samples `decimation` keeps.
    pub fn new(logged: &[RuleLog], decimation: Decimation) -> Self {
        Self {
            decimator: Decimator::new(decimation),
            logged: logged.to_vec(),
            filtering: logged.iter().any(|&l| l != RuleLog::Full),
            held_at: None,
            held: Vec::new(),
            copied: false,
            visible: false,
        }
    }

    /// How jumps of rule `rule` are logged.
    pub fn logs(&self, rule: usize) -> RuleLog {
        self.logged.get(rule).copied().unwrap_or(RuleLog::Full)
    }

    /// Routes one sample of the run: what the sink writes now.
    pub fn route_sample(&mut self, at: HybridTime, x: &[f64], kind: SampleKind) -> Route {
        match kind {
            SampleKind::PreJump if self.filtering => {
                self.copied = self.decimator.would_keep_flow(at);
                if self.copied {
                    self.held.clear();
                    self.held.extend_from_slice(x);
                }
                self.held_at = Some(at);
                self.visible = false;
                Route::Nothing
            }
            SampleKind::PostJump => match self.held_at.take() {
                // The decimation decides on the held sample as a flow
                // sample; it is copied exactly when that keeps it.
                Some(pre) if !self.visible => {
                    if self.decimator.keep(pre, SampleKind::Flow) && self.copied {
                        Route::Held(pre)
                    } else {
                        Route::Nothing
                    }
                }
                _ => self.keep(at, kind),
            },
            _ => self.keep(at, kind),
        }
    }

    fn keep(&mut self, at: HybridTime, kind: SampleKind) -> Route {
        if self.decimator.keep(at, kind) {
            Route::Sample(kind)
        } else {
            Route::Nothing
        }
    }

    /// Routes one jump record of rule `rule`: whether the record is logged,
    /// and the time of the held pre-jump sample when the sink must write it
    /// first, as a pre-jump sample with the jump's pre-jump state (the
    /// first rule of this jump logged in full).
    pub fn route_jump(&mut self, rule: usize) -> (bool, Option<HybridTime>) {
        if !self.filtering {
            return (true, None);
        }
        match self.logs(rule) {
            RuleLog::Off => (false, None),
            RuleLog::Mark => (true, None),
            RuleLog::Full => {
                let flush = self.held_at.filter(|_| !self.visible);
                self.visible = true;
                (true, flush)
            }
        }
    }

    /// The held sample's values, for [`Route::Held`]; give them back with
    /// [`give_back`](Self::give_back) (the buffer is reused).
    pub fn take_held(&mut self) -> Vec<f64> {
        std::mem::take(&mut self.held)
    }

    /// Returns the buffer [`take_held`](Self::take_held) gave.
    pub fn give_back(&mut self, held: Vec<f64>) {
        self.held = held;
    }

    /// Routes a sample of the run to `sink` (whose filter `filter` returns):
    /// writes what the log gets now with `write(sink, at, x, kind)`;
    /// `nothing` if the log gets nothing.
    pub fn write_sample<S: ?Sized, R>(
        sink: &mut S,
        filter: fn(&mut S) -> &mut LogFilter,
        write: fn(&mut S, HybridTime, &[f64], SampleKind) -> R,
        (at, x, kind): (HybridTime, &[f64], SampleKind),
        nothing: R,
    ) -> R {
        match filter(sink).route_sample(at, x, kind) {
            Route::Nothing => nothing,
            Route::Sample(kind) => write(sink, at, x, kind),
            Route::Held(pre) => {
                let held = filter(sink).take_held();
                let r = write(sink, pre, &held, SampleKind::Flow);
                filter(sink).give_back(held);
                r
            }
        }
    }

    /// Takes the held pre-jump sample of a run that ended before its jump
    /// was known, if its values were kept (the sink writes it as its last
    /// sample).
    pub fn take_unfinished(&mut self) -> Option<(HybridTime, Vec<f64>)> {
        let at = self.held_at.take()?;
        (!self.visible && self.copied).then(|| (at, std::mem::take(&mut self.held)))
    }
}

/// Counts of what a run produced, kept by every sink.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Tally {
    /// First sample's time (t0 of the log).
    pub start: Option<HybridTime>,
    /// Last sample's time.
    pub end: Option<HybridTime>,
    /// Samples received (before decimation).
    pub samples: u64,
    /// Jumps per rule index.
    pub jumps: Vec<u64>,
    /// Integrator changes (`Solver::Auto`), the first
    /// [`Tally::SWITCHES_KEPT`] of them.
    pub solver_switches: Vec<SolverSwitch>,
    /// How many integrator changes in all.
    pub solver_switches_total: u64,
}

impl Tally {
    /// How many integrator changes a tally keeps (a run that switches more
    /// often only counts the others).
    pub const SWITCHES_KEPT: usize = 1000;

    /// Records an integrator change.
    pub fn solver_switch(&mut self, switch: &SolverSwitch) {
        if self.solver_switches.len() < Self::SWITCHES_KEPT {
            self.solver_switches.push(*switch);
        }
        self.solver_switches_total += 1;
    }

    /// A tally for a system with `rules` jump rules.
    pub fn new(rules: usize) -> Self {
        Self {
            jumps: vec![0; rules],
            ..Self::default()
        }
    }

    /// Records a sample.
    pub fn sample(&mut self, at: HybridTime) {
        self.start.get_or_insert(at);
        self.end = Some(at);
        self.samples += 1;
    }

    /// Records a jump of rule `rule`.
    pub fn jump(&mut self, rule: usize) {
        if rule >= self.jumps.len() {
            self.jumps.resize(rule + 1, 0);
        }
        self.jumps[rule] += 1;
    }

    /// Total number of jumps.
    pub fn total_jumps(&self) -> u64 {
        self.jumps.iter().sum()
    }

    /// Jumps per rule name, in name order (rules without a name are `#k`).
    pub fn per_rule(&self, names: &[String]) -> BTreeMap<String, u64> {
        self.jumps
            .iter()
            .enumerate()
            .map(|(k, &n)| (rule_name(names, k), n))
            .collect()
    }
}

/// Name of rule `k`, or `#k` if the system has fewer names.
pub fn rule_name(names: &[String], k: usize) -> String {
    names.get(k).cloned().unwrap_or_else(|| format!("#{k}"))
}

/// How a run ended, as the sinks record it (`hybsim.result` in MCAP, the
/// final `/hybsim/log` message).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunOutcome {
    /// Stable identifier of the cause (`horizon_t`, `horizon_j`, `zeno_suspected`, `non_finite`, ...).
    pub cause: String,
    /// One sentence for people.
    pub message: String,
    /// How the run ended, in three degrees.
    pub status: RunStatus,
}

impl RunOutcome {
    /// The outcome of a run that the engine ended with `termination`.
    pub fn from_termination(termination: &Termination) -> Self {
        let (cause, status) = match termination.cause {
            TerminationCause::HorizonT => ("horizon_t", RunStatus::Completed),
            TerminationCause::HorizonJ => ("horizon_j", RunStatus::Completed),
            TerminationCause::ZenoSuspected { .. } => ("zeno_suspected", RunStatus::Ended),
            TerminationCause::CannotFlowOrJump { .. } => ("cannot_flow_or_jump", RunStatus::Ended),
            TerminationCause::StoppedBySink => ("stopped_by_sink", RunStatus::Ended),
        };
        Self {
            cause: cause.into(),
            message: termination.to_string(),
            status,
        }
    }

    /// A failed run: `cause` is a stable identifier (`error`, `non_finite`).
    pub fn failed(cause: &str, message: impl Into<String>) -> Self {
        Self {
            cause: cause.into(),
            message: message.into(),
            status: RunStatus::Failed,
        }
    }
}

/// How a run ended, as far as logs and exit codes are concerned.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RunStatus {
    /// A horizon (T or J) was reached.
    Completed,
    /// The solution ended for a documented reason worth a look (Zeno
    /// suspected, cannot flow or jump, interrupted).
    Ended,
    /// The run failed (engine error, non-finite value, write error).
    Failed,
}

/// Forwards one run to several sinks; stops the run as soon as one sink asks to.
pub struct Fanout<'a> {
    sinks: Vec<&'a mut dyn ArcSink>,
}

impl<'a> Fanout<'a> {
    /// Forwards to `sinks`, in order.
    pub fn new(sinks: Vec<&'a mut dyn ArcSink>) -> Self {
        Self { sinks }
    }
}

impl ArcSink for Fanout<'_> {
    fn sample(&mut self, at: HybridTime, x: &[f64], kind: SampleKind) -> ControlFlow<()> {
        let mut flow = ControlFlow::Continue(());
        for s in &mut self.sinks {
            if s.sample(at, x, kind).is_break() {
                flow = ControlFlow::Break(());
            }
        }
        flow
    }

    fn jump(&mut self, at: HybridTime, rule: usize, pre: &[f64], post: &[f64]) -> ControlFlow<()> {
        let mut flow = ControlFlow::Continue(());
        for s in &mut self.sinks {
            if s.jump(at, rule, pre, post).is_break() {
                flow = ControlFlow::Break(());
            }
        }
        flow
    }

    fn finish(&mut self, termination: &Termination) {
        for s in &mut self.sinks {
            s.finish(termination);
        }
    }

    fn failed(&self) -> bool {
        self.sinks.iter().any(|s| s.failed())
    }

    fn solver_switch(&mut self, switch: &SolverSwitch) {
        for s in &mut self.sinks {
            s.solver_switch(switch);
        }
    }

    fn wants_dense_points(&self) -> bool {
        self.sinks.iter().any(|s| s.wants_dense_points())
    }

    fn wants_flow_pieces(&self) -> bool {
        self.sinks.iter().any(|s| s.wants_flow_pieces())
    }

    fn flow_piece(&mut self, piece: &mut FlowPiece<'_>) {
        for s in &mut self.sinks {
            if s.wants_flow_pieces() {
                s.flow_piece(piece);
            }
        }
    }

    fn poll(&mut self) -> ControlFlow<()> {
        let mut flow = ControlFlow::Continue(());
        for s in &mut self.sinks {
            if s.poll().is_break() {
                flow = ControlFlow::Break(());
            }
        }
        flow
    }
}

/// Pushes a solution held in memory into `sink` in the order the engine
/// would: samples in order, each jump record right after its pre-jump
/// sample, then [`ArcSink::finish`] with the arc's termination (if set).
/// Use it to log an arc computed with `engine::simulate_arc`.
pub fn replay(arc: &HybridArc, sink: &mut dyn ArcSink) -> ControlFlow<()> {
    let mut jumps = arc.jumps().iter();
    for s in arc.samples() {
        sink.sample(s.at, s.x, s.kind)?;
        if s.kind == SampleKind::PreJump
            && let Some(jump) = jumps.next()
        {
            sink.jump(jump.at, jump.rule, &jump.pre, &jump.post)?;
        }
    }
    if let Some(termination) = arc.termination() {
        sink.finish(termination);
    }
    ControlFlow::Continue(())
}

/// Returns the first non-finite component of `x`, as (index, value).
pub(crate) fn first_non_finite(x: &[f64]) -> Option<(usize, f64)> {
    crate::num::first_non_finite(x).map(|k| (k, x[k]))
}

#[cfg(test)]
mod tests;
