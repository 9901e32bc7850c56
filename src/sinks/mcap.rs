//! The MCAP log of a run: protobuf messages with a per-model descriptor set
//! (or JSON messages with JSON Schemas, [`Encoding::Json`]), LZ4 chunks,
//! metadata and attachments that make the run reproducible from the file
//! alone. Opens in Foxglove and the official MCAP readers.
//!
//! # Layout of the file
//!
//! | record | content |
//! |---|---|
//! | metadata `hybsim.run` | `version`, `model` (path), `model_name`, `model_sha256`, `imports` (JSON `[{path, sha256}]` of the imported files), `tables` (JSON `[{path, sha256}]` of the files read by `table("…")`), `seed`, `state_names`, `output_names`, `rule_names`, `logged_rules` (logged in full), `marked_rules` (records only), `argv` (JSON arrays), `decimation`, `encoding`, `jump_states`, `blas_threads` (OpenBLAS threads, 1), `threads` (rayon's worker threads) |
//! | metadata `hybsim.parameters` | one entry per resolved parameter (JSON value) |
//! | metadata `hybsim.solver` | one entry per setting (JSON value) |
//! | metadata `hybsim.design` | design results, when the model has design blocks |
//! | attachment `<model file name>` | the model source (`text/plain`) |
//! | attachment `run.json` | the resolved run description (`application/json`) |
//! | attachment `<path>` | each imported file, under its path relative to the model's folder (`text/plain`) |
//! | channel `/hybsim/state` | one message per logged sample: `{t, j, <states>}` |
//! | channel `/hybsim/outputs` | one message per logged sample: `{t, j, <outputs>}` (if the model has outputs) |
//! | channel `/hybsim/jumps` | one message per jump: `{t, j, rule, rule_id, index?}`, with `pre, post` (the states) if [`McapOptions::jump_states`] |
//! | channel `/hybsim/log` | run start and end, and each change of integrator of `solver = auto` (`foxglove.Log`) |
//! | metadata `hybsim.result` | `termination`, `message`, `status` (`completed`, `ended`, `failed`), `t_end`, `j_end`, `jumps` (per rule), `jumps_total`, `samples` (the solution's, before the log's selection: README, "samples"); with `solver = auto` also `solver_switches` (JSON `[{at: {t, j}, to}]`, the first 1000) and `solver_switches_total` |
//! | metadata `hybsim.metrics` | one entry per `metric` of the model (its value), when it has any ([`McapSink::set_metrics`]) |
//!
//! `log_time = publish_time = round((t − t0)·10⁹)` ns, with t0 the time of
//! the first sample; every payload carries the exact `t` and `j`, because
//! samples closer than 1 ns share a log time. A jump writes the pre-jump
//! sample, the jump record and the post-jump sample in that order, with the
//! same log time. Nothing time-of-day dependent is written, so the same
//! seed and command line give a byte-identical file.

use std::collections::BTreeMap;
use std::io::BufWriter;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use crate::atomic_file::OutputFile;
use serde::Serialize;
use serde_json::{Value, json};

use super::json::{
    LogLevel, LogRecord, LogTimestamp, RecordWriter, jump_schema, log_schema, sample_schema,
};
pub use super::mcap_writer::Compression;
use super::mcap_writer::McapWriter;
use super::protobuf::ProtoWriter;
use super::{
    Decimation, LogFilter, LoggedOutputs, OutputFn, RunInfo, RunOutcome, RunStatus, SinkError,
    Tally, first_non_finite, rule_name,
};
use crate::arc::{ArcSink, HybridTime, SampleKind, SolverSwitch};
use crate::atomic_file;
use crate::layout::Layout;

/// Topic of state samples.
pub const STATE_TOPIC: &str = "/hybsim/state";
/// Topic of output samples.
pub const OUTPUTS_TOPIC: &str = "/hybsim/outputs";
/// Topic of jump records.
pub const JUMPS_TOPIC: &str = "/hybsim/jumps";
/// Topic of log messages (`foxglove.Log`).
pub const LOG_TOPIC: &str = "/hybsim/log";

/// How the messages of samples and jumps are encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Encoding {
    /// Protobuf ([`super::protobuf`]), the default: 8 bytes per number and
    /// no text formatting, so logging costs a fraction of what JSON does.
    #[default]
    Protobuf,
    /// JSON with JSON Schemas ([`super::json`]): readable without a
    /// protobuf library.
    Json,
}

impl Encoding {
    /// The encoding named `name` (`protobuf` or `json`).
    pub fn parse(name: &str) -> Option<Self> {
        match name {
            "protobuf" => Some(Self::Protobuf),
            "json" => Some(Self::Json),
            _ => None,
        }
    }
}

/// Options of the MCAP sink.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct McapOptions {
    /// Which samples to write. Default: all.
    pub decimation: Decimation,
    /// Message encoding. Default: protobuf.
    pub encoding: Encoding,
    /// Chunk compression. Default: LZ4, the fastest (zstd level 1 makes
    /// files ~10 % smaller for about 2.5× the compression time).
    pub compression: Compression,
    /// Whether jump records carry the pre- and post-jump states. Default:
    /// no, since the pre- and post-jump samples on `/hybsim/state` around
    /// each jump record hold the same values (a third to a half of a
    /// jump-heavy log's bytes).
    pub jump_states: bool,
}

impl Default for McapOptions {
    fn default() -> Self {
        Self {
            decimation: Decimation::default(),
            encoding: Encoding::default(),
            compression: Compression::Lz4,
            jump_states: false,
        }
    }
}

impl McapOptions {
    /// Sets the decimation.
    pub fn decimation(self, decimation: Decimation) -> Self {
        Self { decimation, ..self }
    }

    /// Sets the message encoding.
    pub fn encoding(self, encoding: Encoding) -> Self {
        Self { encoding, ..self }
    }

    /// Sets the chunk compression.
    pub fn compression(self, compression: Compression) -> Self {
        Self {
            compression,
            ..self
        }
    }

    /// Sets whether jump records carry the pre- and post-jump states.
    pub fn jump_states(self, jump_states: bool) -> Self {
        Self {
            jump_states,
            ..self
        }
    }
}

/// The encoders of a run's sample and jump messages.
enum Records {
    Json {
        states: Box<RecordWriter>,
        outputs: Box<RecordWriter>,
    },
    Protobuf(Box<ProtoWriter>),
}

/// What [`McapSink::finish`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct McapSummary {
    /// The final file.
    pub path: PathBuf,
    /// Messages per topic.
    pub messages: BTreeMap<String, u64>,
    /// Samples and jumps seen.
    pub tally: Tally,
    /// The outcome written to `hybsim.result` (the caller's, or
    /// `non_finite` if this sink stopped the run on a non-finite value).
    pub outcome: RunOutcome,
    /// The non-finite value that stopped the run, if this sink did.
    pub stopped: Option<NonFiniteStop>,
}

/// A non-finite value that stopped a run ([`SinkError::NonFinite`]), for
/// a diagnostic at its definition.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NonFiniteStop {
    /// `state` or `output`.
    pub what: &'static str,
    /// The component's index in the state or the outputs.
    pub component: usize,
    /// The value.
    pub value: f64,
    /// Where on the hybrid time domain.
    pub at: HybridTime,
}

struct Channels {
    state: u16,
    outputs: Option<u16>,
    jumps: u16,
    log: u16,
}

/// Writes a run to an MCAP file; see the module documentation for the
/// layout. Create it before the run, push the run into it, then call
/// [`finish`](Self::finish): only then does the file appear at its path.
pub struct McapSink<'a> {
    path: PathBuf,
    writer: Option<McapWriter<BufWriter<OutputFile>>>,
    info: &'a RunInfo,
    /// The logged outputs (evaluated only when the outputs channel exists).
    outputs: LoggedOutputs<'a>,
    channels: Channels,
    tally: Tally,
    t0: Option<f64>,
    last_log_time: u64,
    sequence: u32,
    records: Records,
    filter: LogFilter,
    /// Runs (first component, count) of the state components the records
    /// carry: those checked for non-finite values.
    logged: Vec<(usize, usize)>,
    /// The same for the output components (the others are not evaluated).
    logged_outputs: Vec<(usize, usize)>,
    /// Whether jump records carry the pre- and post-jump states.
    jump_states: bool,
    error: Option<SinkError>,
    metrics: Vec<(String, f64)>,
}

fn meta_entries<I, K>(entries: I) -> BTreeMap<String, String>
where
    I: IntoIterator<Item = (K, Value)>,
    K: Into<String>,
{
    entries
        .into_iter()
        .map(|(k, v)| {
            let s = match v {
                Value::String(s) => s,
                other => other.to_string(),
            };
            (k.into(), s)
        })
        .collect()
}

/// One metadata entry per key of a JSON object, or a single `value` entry.
fn object_entries(v: &Value) -> BTreeMap<String, String> {
    match v {
        Value::Object(map) => meta_entries(map.iter().map(|(k, v)| (k.clone(), v.clone()))),
        other => meta_entries([("value", other.clone())]),
    }
}

impl<'a> McapSink<'a> {
    /// Creates the temporary file and writes the run's metadata, attachments,
    /// schemas and channels. `outputs` evaluates the model's outputs for
    /// each logged sample (required if `info.output_dim > 0`).
    pub fn create(
        path: impl AsRef<Path>,
        info: &'a RunInfo,
        outputs: Option<OutputFn<'a>>,
        options: McapOptions,
    ) -> Result<Self, SinkError> {
        let path = path.as_ref().to_path_buf();
        info.validate()?;
        options.decimation.validate()?;
        if info.output_dim > 0 && outputs.is_none() {
            return Err(SinkError::Option {
                option: "outputs",
                message: "the model has outputs but no output function was given".into(),
            });
        }
        let file = atomic_file::create(&path).map_err(|e| SinkError::io(&path, e))?;
        let mcap_err = |source| SinkError::Mcap {
            path: path.clone(),
            source,
        };
        let mut writer = McapWriter::new(
            BufWriter::new(file),
            "",
            &format!("hybsim {}", env!("CARGO_PKG_VERSION")),
            options.compression,
        )
        .map_err(mcap_err)?;

        let state_names = info.state_names();
        let output_names = info.output_names();
        let run = meta_entries([
            ("version", json!(env!("CARGO_PKG_VERSION"))),
            ("model", json!(info.model_path)),
            ("model_name", json!(info.model_name)),
            ("model_sha256", json!(info.source_sha256())),
            (
                "imports",
                Value::String(json!(imports_json(info)).to_string()),
            ),
            ("tables", Value::String(json!(info.tables).to_string())),
            ("seed", json!(info.seed.to_string())),
            ("state_names", Value::String(json!(state_names).to_string())),
            (
                "output_names",
                Value::String(json!(output_names).to_string()),
            ),
            (
                "rule_names",
                Value::String(json!(info.rule_names).to_string()),
            ),
            (
                "logged_rules",
                Value::String(json!(info.logged_rule_names()).to_string()),
            ),
            (
                "marked_rules",
                Value::String(json!(info.marked_rule_names()).to_string()),
            ),
            ("argv", Value::String(json!(info.argv).to_string())),
            (
                "decimation",
                Value::String(json!(options.decimation).to_string()),
            ),
            ("encoding", json!(options.encoding)),
            ("jump_states", json!(options.jump_states)),
            // The threads the design layer ran on: BLAS is pinned (design::blas), rayon's
            // pool follows the machine (the designs' numbers do not).
            ("blas_threads", json!(crate::design::blas::threads())),
            ("threads", json!(rayon_threads())),
        ]);
        let mut records = vec![
            ("hybsim.run", run),
            ("hybsim.parameters", object_entries(&info.parameters)),
            ("hybsim.solver", object_entries(&info.solver)),
        ];
        if let Some(design) = &info.design {
            records.push(("hybsim.design", object_entries(design)));
        }
        for (name, metadata) in records {
            writer.write_metadata(name, &metadata).map_err(mcap_err)?;
        }

        let source_name = Path::new(&info.model_path)
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .filter(|n| !n.is_empty())
            .unwrap_or_else(|| format!("{}.hyb", info.model_name));
        let description = json!({
            "hybsim_version": env!("CARGO_PKG_VERSION"),
            "model": {"name": info.model_name, "path": info.model_path,
                      "sha256": info.source_sha256(), "attachment": source_name,
                      "imports": imports_json(info), "tables": info.tables},
            "seed": info.seed,
            "argv": info.argv,
            "overrides": info.overrides,
            "parameters": info.parameters,
            "solver": info.solver,
            "design": info.design,
            "decimation": options.decimation,
            "encoding": options.encoding,
            "jump_states": options.jump_states,
            "state": {"dim": info.state_dim, "layout": info.state_layout, "names": state_names},
            "outputs": {"dim": info.output_dim, "layout": info.output_layout, "names": output_names},
            "rules": info.rule_names,
            "logged_rules": info.logged_rule_names(),
            "marked_rules": info.marked_rule_names(),
        });
        let description =
            serde_json::to_vec_pretty(&description).expect("a JSON value always serializes");
        // Imported files are attached under their path relative to the
        // model's folder (`lib/zoh.hyb`), so that the file alone rebuilds
        // the model.
        let folder = Path::new(&info.model_path)
            .parent()
            .unwrap_or(Path::new(""));
        let imports = info.imports.iter().map(|(path, text)| {
            let name = Path::new(path)
                .strip_prefix(folder)
                .map_or_else(|_| path.clone(), |p| p.to_string_lossy().into_owned());
            (name, "text/plain", text.as_bytes().to_vec())
        });
        for (name, media_type, data) in [
            (source_name, "text/plain", info.source.as_bytes().to_vec()),
            ("run.json".to_string(), "application/json", description),
        ]
        .into_iter()
        .chain(imports)
        {
            writer
                .attach(0, 0, &name, media_type, &data)
                .map_err(mcap_err)?;
        }

        // (schema name, schema encoding, schema data) of the state, outputs and jump channels.
        let model = &info.model_name;
        let has_outputs = info.output_dim > 0 && !info.output_layout.entries.is_empty();
        let (records, schemas) = match options.encoding {
            Encoding::Json => {
                let json_schema = |title: String, schema: Value| {
                    let data = serde_json::to_vec(&schema).expect("a JSON value always serializes");
                    (title, data)
                };
                let state = format!("hybsim.{model}.State");
                let outputs = format!("hybsim.{model}.Outputs");
                let jump = format!("hybsim.{model}.Jump");
                let schemas = [
                    json_schema(state.clone(), sample_schema(&state, &info.state_layout)),
                    json_schema(
                        outputs.clone(),
                        sample_schema(&outputs, &info.output_layout),
                    ),
                    json_schema(
                        jump.clone(),
                        jump_schema(&jump, &info.state_layout, options.jump_states),
                    ),
                ];
                let records = Records::Json {
                    states: Box::new(
                        RecordWriter::new(&info.state_layout, &info.rule_names)
                            .with_jump_states(options.jump_states),
                    ),
                    outputs: Box::new(RecordWriter::new(&info.output_layout, &[])),
                };
                (records, schemas)
            }
            Encoding::Protobuf => {
                let (writer, s) = ProtoWriter::new(
                    model,
                    &info.state_layout,
                    &info.output_layout,
                    &info.rule_names,
                    options.jump_states,
                );
                let data = s.descriptor_set;
                let schemas = [
                    (s.state, data.clone()),
                    (s.outputs, data.clone()),
                    (s.jump, data),
                ];
                (Records::Protobuf(Box::new(writer)), schemas)
            }
        };
        let (schema_encoding, message_encoding) = match options.encoding {
            Encoding::Json => ("jsonschema", "json"),
            Encoding::Protobuf => ("protobuf", "protobuf"),
        };
        let mut channel = |topic: &str, (name, data): &(String, Vec<u8>)| {
            let schema_id = writer.add_schema(name, schema_encoding, data)?;
            writer.add_channel(schema_id, topic, message_encoding, &BTreeMap::new())
        };
        let [state_schema, outputs_schema, jump_schema] = &schemas;
        let state = channel(STATE_TOPIC, state_schema).map_err(mcap_err)?;
        let outputs_channel = if has_outputs {
            Some(channel(OUTPUTS_TOPIC, outputs_schema).map_err(mcap_err)?)
        } else {
            None
        };
        let jumps = channel(JUMPS_TOPIC, jump_schema).map_err(mcap_err)?;
        // The log stays JSON: Foxglove's Log panel finds `foxglove.Log` by name
        // in either encoding, and a few messages cost nothing.
        let log_data = serde_json::to_vec(&log_schema()).expect("a JSON value always serializes");
        let log_schema_id = writer
            .add_schema("foxglove.Log", "jsonschema", &log_data)
            .map_err(mcap_err)?;
        let log = writer
            .add_channel(log_schema_id, LOG_TOPIC, "json", &BTreeMap::new())
            .map_err(mcap_err)?;

        Ok(Self {
            path,
            writer: Some(writer),
            info,
            outputs: LoggedOutputs::new(
                outputs.filter(|_| outputs_channel.is_some()),
                info.output_dim,
            ),
            channels: Channels {
                state,
                outputs: outputs_channel,
                jumps,
                log,
            },
            tally: Tally::new(info.rule_names.len()),
            t0: None,
            last_log_time: 0,
            sequence: 0,
            records,
            filter: LogFilter::new(&info.logged_rules, options.decimation),
            logged: component_runs(&info.state_layout),
            logged_outputs: component_runs(&info.output_layout),
            jump_states: options.jump_states,
            error: None,
            metrics: Vec::new(),
        })
    }

    /// `round((t − t0)·10⁹)` ns, clamped to the u64 range.
    fn log_time(&mut self, t: f64) -> u64 {
        let t0 = *self.t0.get_or_insert(t);
        let ns = ((t - t0) * 1e9).round();
        let ns = if ns.is_nan() || ns <= 0.0 {
            0
        } else if ns >= u64::MAX as f64 {
            u64::MAX
        } else {
            ns as u64
        };
        self.last_log_time = ns;
        ns
    }

    /// Writes a message on `channel` whose payload `encode` appends (given
    /// the record writers and the current outputs).
    fn write_message(
        &mut self,
        channel: u16,
        log_time: u64,
        encode: impl FnOnce(&Records, &[f64], &mut Vec<u8>),
    ) -> Result<(), SinkError> {
        let writer = self
            .writer
            .as_mut()
            .expect("the writer is present until finish");
        self.sequence = self.sequence.wrapping_add(1);
        let (records, y) = (&self.records, self.outputs.values());
        writer
            .message(channel, self.sequence, log_time, |out| {
                encode(records, y, out)
            })
            .map_err(|source| SinkError::Mcap {
                path: self.path.clone(),
                source,
            })
    }

    fn write_log(
        &mut self,
        level: LogLevel,
        message: &str,
        log_time: u64,
    ) -> Result<(), SinkError> {
        let file = self.info.model_path.clone();
        let record = LogRecord {
            timestamp: LogTimestamp::from_nanos(log_time),
            level: level as u8,
            message,
            name: "hybsim",
            file: &file,
            line: 0,
        };
        self.write_message(self.channels.log, log_time, |_, _, out| {
            serde_json::to_writer(out, &record).expect("a log record serializes")
        })
    }

    /// The first non-finite state component the records carry, as (index,
    /// value). Only those: the file must hold none, and the engine has
    /// checked the whole state already (a selective log of a wide state
    /// would otherwise scan all of it per sample).
    fn non_finite_state(&self, x: &[f64]) -> Option<(usize, f64)> {
        first_non_finite_in(&self.logged, x)
    }

    fn write_sample(&mut self, at: HybridTime, x: &[f64]) -> Result<ControlFlow<()>, SinkError> {
        if let Some((k, value)) = self.non_finite_state(x) {
            return Err(SinkError::NonFinite {
                what: "state",
                component: k,
                name: self.info.component_name("state", k),
                value,
                at,
            });
        }
        // A solution has one state per hybrid time: a sample there again
        // (the pre-jump sample of a second jump at one instant, after the
        // first one's post-jump sample) keeps the outputs.
        let y = self.outputs.at(at, x);
        if let Some((k, value)) = first_non_finite_in(&self.logged_outputs, y) {
            return Err(SinkError::NonFinite {
                what: "output",
                component: k,
                name: self.info.component_name("output", k),
                value,
                at,
            });
        }
        let first = self.t0.is_none();
        let log_time = self.log_time(at.t);
        if first {
            let message = format!(
                "run of model `{}` ({}) started at {at} with seed {}",
                self.info.model_name, self.info.model_path, self.info.seed
            );
            self.write_log(LogLevel::Info, &message, log_time)?;
        }
        self.write_message(self.channels.state, log_time, |r, _, out| match r {
            Records::Json { states, .. } => states.sample(out, at, x),
            Records::Protobuf(p) => p.sample(out, at, x),
        })?;
        if let Some(channel) = self.channels.outputs {
            self.write_message(channel, log_time, |r, y, out| match r {
                Records::Json { outputs, .. } => outputs.sample(out, at, y),
                Records::Protobuf(p) => p.outputs(out, at, y),
            })?;
        }
        Ok(ControlFlow::Continue(()))
    }

    fn write_jump(
        &mut self,
        at: HybridTime,
        rule: usize,
        pre: &[f64],
        post: &[f64],
    ) -> Result<ControlFlow<()>, SinkError> {
        // Without the states, the samples around the record carry them
        // (and are checked when written).
        let states: &[&[f64]] = if self.jump_states { &[pre, post] } else { &[] };
        for x in states {
            if let Some((k, value)) = self.non_finite_state(x) {
                return Err(SinkError::NonFinite {
                    what: "state",
                    component: k,
                    name: self.info.component_name("state", k),
                    value,
                    at,
                });
            }
        }
        let log_time = self.log_time(at.t);
        let name = if rule < self.info.rule_names.len() {
            String::new()
        } else {
            rule_name(&self.info.rule_names, rule)
        };
        self.write_message(self.channels.jumps, log_time, |r, _, out| match r {
            Records::Json { states, .. } => states.jump(out, at, rule, &name, pre, post),
            Records::Protobuf(p) => p.jump(out, at, rule, &name, pre, post),
        })?;
        Ok(ControlFlow::Continue(()))
    }

    /// Stores the first error and stops the run.
    fn settle(&mut self, r: Result<ControlFlow<()>, SinkError>) -> ControlFlow<()> {
        match r {
            Ok(flow) => flow,
            Err(e) => {
                self.error.get_or_insert(e);
                ControlFlow::Break(())
            }
        }
    }

    /// The tally so far.
    pub fn tally(&self) -> &Tally {
        &self.tally
    }

    /// Writes the final log message and `hybsim.result`, finishes the MCAP
    /// file, syncs it and renames it into place. If this sink stopped the
    /// run on a non-finite value, the file is still completed and its
    /// result (and the returned [`McapSummary::outcome`]) names that cause;
    /// if writing failed, the temporary file is removed and the error
    /// returned.
    pub fn finish(mut self, outcome: &RunOutcome) -> Result<McapSummary, SinkError> {
        let error = self.error.take();
        let outcome = match &error {
            Some(e @ SinkError::NonFinite { .. }) => {
                RunOutcome::failed("non_finite", e.to_string())
            }
            _ => outcome.clone(),
        };
        if let Some(e) = error {
            if !matches!(e, SinkError::NonFinite { .. }) {
                // The writer itself failed: the file cannot be trusted.
                self.discard();
                return Err(e);
            }
            self.error = Some(e);
        }
        self.complete(&outcome).inspect_err(|_| self.discard())
    }

    /// The run's metrics (name, value), written to `hybsim.metrics` by
    /// [`finish`](Self::finish) (values as shortest round-trip decimals).
    pub fn set_metrics(&mut self, metrics: Vec<(String, f64)>) {
        self.metrics = metrics;
    }

    /// Why this sink stopped the run, if it did (a write error or a
    /// non-finite value).
    pub fn stopped_by(&self) -> Option<&SinkError> {
        self.error.as_ref()
    }

    fn complete(&mut self, outcome: &RunOutcome) -> Result<McapSummary, SinkError> {
        // A run that ended between a held pre-jump sample and its jump.
        if let Some((at, x)) = self.filter.take_unfinished() {
            let _ = self.write_sample(at, &x)?;
        }
        let level = match outcome.status {
            RunStatus::Completed => LogLevel::Info,
            RunStatus::Ended => LogLevel::Warning,
            RunStatus::Failed => LogLevel::Error,
        };
        let end = self.tally.end;
        let log_time = self.last_log_time;
        let message = match end {
            Some(end) => format!("run ended at {end}: {}", outcome.message),
            None => format!("run ended before its first sample: {}", outcome.message),
        };
        self.write_log(level, &message, log_time)?;
        let jumps = self.tally.per_rule(&self.info.rule_names);
        let mut result = meta_entries([
            ("termination", json!(outcome.cause)),
            ("message", json!(outcome.message)),
            (
                "status",
                serde_json::to_value(outcome.status).expect("an enum serializes"),
            ),
            (
                "t_end",
                json!(end.map(|e| e.t.to_string()).unwrap_or_default()),
            ),
            (
                "j_end",
                json!(end.map(|e| e.j.to_string()).unwrap_or_default()),
            ),
            ("jumps", Value::String(json!(jumps).to_string())),
            ("jumps_total", json!(self.tally.total_jumps().to_string())),
            ("samples", json!(self.tally.samples.to_string())),
        ]);
        if self.info.solver["solver"]["method"] == "auto" {
            result.extend(meta_entries([
                (
                    "solver_switches",
                    Value::String(json!(self.tally.solver_switches).to_string()),
                ),
                (
                    "solver_switches_total",
                    json!(self.tally.solver_switches_total.to_string()),
                ),
            ]));
        }
        let path = self.path.clone();
        let mcap_err = |source| SinkError::Mcap {
            path: path.clone(),
            source,
        };
        let mut writer = self.writer.take().expect("finish is called once");
        if !self.metrics.is_empty() {
            let metadata = self
                .metrics
                .iter()
                .map(|(k, v)| (k.clone(), crate::num::Num(*v).to_string()))
                .collect();
            writer
                .write_metadata("hybsim.metrics", &metadata)
                .map_err(mcap_err)?;
        }
        writer
            .write_metadata("hybsim.result", &result)
            .map_err(mcap_err)?;
        let (out, summary) = writer.finish().map_err(mcap_err)?;
        let file = out
            .into_inner()
            .map_err(|e| SinkError::io(&self.path, e.into_error()))?;
        atomic_file::commit(file, &self.path).map_err(|e| SinkError::io(&self.path, e))?;
        Ok(McapSummary {
            path: self.path.clone(),
            messages: summary.messages,
            tally: self.tally.clone(),
            outcome: outcome.clone(),
            stopped: match self.error {
                Some(SinkError::NonFinite {
                    what,
                    component,
                    value,
                    at,
                    ..
                }) => Some(NonFiniteStop {
                    what,
                    component,
                    value,
                    at,
                }),
                _ => None,
            },
        })
    }

    fn discard(&mut self) {
        // Dropping the writer drops the temporary file, which removes it.
        self.writer = None;
    }
}

impl ArcSink for McapSink<'_> {
    fn failed(&self) -> bool {
        self.error.is_some()
    }

    fn solver_switch(&mut self, switch: &SolverSwitch) {
        self.tally.solver_switch(switch);
        if self.error.is_some() || self.tally.solver_switches_total > Tally::SWITCHES_KEPT as u64 {
            return;
        }
        let log_time = self.log_time(switch.at.t);
        let message = format!("solver switched to {} at {}", switch.to, switch.at);
        if let Err(e) = self.write_log(LogLevel::Info, &message, log_time) {
            self.error = Some(e);
        }
    }

    fn sample(&mut self, at: HybridTime, x: &[f64], kind: SampleKind) -> ControlFlow<()> {
        if self.error.is_some() {
            return ControlFlow::Break(());
        }
        self.tally.sample(at);
        let r = LogFilter::write_sample(
            self,
            |s| &mut s.filter,
            |s, at, x, _| s.write_sample(at, x),
            (at, x, kind),
            Ok(ControlFlow::Continue(())),
        );
        self.settle(r)
    }

    fn jump(&mut self, at: HybridTime, rule: usize, pre: &[f64], post: &[f64]) -> ControlFlow<()> {
        if self.error.is_some() {
            return ControlFlow::Break(());
        }
        self.tally.jump(rule);
        self.outputs.jump(at, rule);
        let (record, flush) = self.filter.route_jump(rule);
        let mut r = match flush {
            Some(at) => self.write_sample(at, pre),
            None => Ok(ControlFlow::Continue(())),
        };
        if record && matches!(r, Ok(ControlFlow::Continue(()))) {
            r = self.write_jump(at, rule, pre, post);
        }
        self.settle(r)
    }
}

/// The first non-finite component of `x` in `runs` (first, count), as
/// (index, value).
fn first_non_finite_in(runs: &[(usize, usize)], x: &[f64]) -> Option<(usize, f64)> {
    runs.iter().find_map(|&(first, n)| {
        let run = x.get(first..(first + n).min(x.len()))?;
        first_non_finite(run).map(|(k, v)| (first + k, v))
    })
}

/// The components `layout` covers, as runs (first, count) in index order.
fn component_runs(layout: &Layout) -> Vec<(usize, usize)> {
    let mut offsets: Vec<usize> = layout.components().into_iter().map(|c| c.0).collect();
    offsets.sort_unstable();
    offsets.dedup();
    let mut runs: Vec<(usize, usize)> = Vec::new();
    for k in offsets {
        match runs.last_mut() {
            Some((first, n)) if *first + *n == k => *n += 1,
            _ => runs.push((k, 1)),
        }
    }
    runs
}

/// The worker threads of rayon's global pool, without starting it: asking
/// rayon (`current_num_threads`) starts the pool, whose two idle workers
/// then spin on `sched_yield` for milliseconds, a quarter of the CPU time
/// of a short logged run that never uses them. rayon's documented default:
/// `RAYON_NUM_THREADS` if it is a positive integer, else the available
/// parallelism (what `hybsim run` uses: it never configures the pool).
fn rayon_threads() -> usize {
    std::env::var("RAYON_NUM_THREADS")
        .ok()
        .and_then(|v| v.trim().parse::<usize>().ok())
        .filter(|&n| n > 0)
        .or_else(|| std::thread::available_parallelism().ok().map(|n| n.get()))
        .unwrap_or(1)
}

/// The imported files of the run as `[{path, sha256}]`.
fn imports_json(info: &RunInfo) -> Value {
    Value::Array(
        info.imports_sha256()
            .into_iter()
            .map(|(path, sha)| json!({"path": path, "sha256": sha}))
            .collect(),
    )
}
