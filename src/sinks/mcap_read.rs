//! Reading back what [`McapSink`](super::mcap::McapSink) wrote: the
//! summary of a run's MCAP file (metadata records, channels and their
//! message counts, attachments), for `hybsim info` and other readers
//! ([`RunSummary`]); and its samples, state and outputs as flat vectors
//! structured by the layouts recorded in the file, for `hybsim plot`
//! ([`RunLog`]).

use std::collections::BTreeMap;

use serde_json::Value;

use super::json::RecordReader;
use super::mcap::{OUTPUTS_TOPIC, STATE_TOPIC};
use super::{RuleLog, RunInfo};
use crate::arc::{HybridTime, SampleKind};
use crate::layout::Layout;

/// Why a file is not a readable hybsim MCAP log.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// Not an MCAP file at all (no magic bytes).
    #[error("not an MCAP file (it does not start with MCAP's magic bytes)")]
    NotMcap,
    /// An MCAP file without its summary section: cut short (the run was
    /// killed, the copy is incomplete) or written without one.
    #[error(
        "the MCAP file has no summary section: it was cut short (killed run, incomplete copy) or not written by hybsim ({0})"
    )]
    Truncated(String),
    /// An MCAP file, but not written by hybsim (no `hybsim.run` metadata).
    #[error("an MCAP file, but not a hybsim run: it has no `hybsim.run` metadata")]
    Foreign,
    /// A hybsim run whose description or messages cannot be read back.
    #[error("a hybsim run that cannot be read back: {0}")]
    Damaged(String),
}

/// Checks every chunk the summary indexes before the mcap reader decodes
/// it: the record there is a chunk (its opcode, length, size and
/// compression those of the index; the reader skips a record whose opcode
/// is not a chunk's, so a flipped opcode lost the chunk's samples without
/// an error), its data decompress, bounded by its declared size, and match
/// its CRC, its records fill it exactly, and the chunks hold as many
/// messages as the statistics count. The reader reserves what a damaged
/// chunk's data claim, which can abort the process (one flipped byte in LZ4
/// data asked for 3·10¹⁸ bytes). A file without a readable summary is left
/// to the reader, which reports it. Returns the number of chunks checked.
pub fn check_chunks(bytes: &[u8]) -> Result<usize, ReadError> {
    use super::mcap_writer::op;
    use std::io::Read;
    let Ok(Some(summary)) = ::mcap::read::Summary::read(bytes) else {
        return Ok(0);
    };
    let mut messages = 0u64;
    for c in &summary.chunk_indexes {
        let damaged = |why: String| {
            ReadError::Damaged(format!("the chunk at byte {}: {why}", c.chunk_start_offset))
        };
        let span = |a: u64, n: u64| {
            let a = usize::try_from(a).ok()?;
            bytes.get(a..a.checked_add(usize::try_from(n).ok()?)?)
        };
        let record = span(c.chunk_start_offset, c.chunk_length)
            .ok_or_else(|| damaged("it lies outside the file".into()))?;
        // The record: opcode, length, start and end times, size, CRC,
        // compression (u32 length, name), data (u64 length, bytes).
        let name_len = c.compression.len();
        let head = 49 + name_len;
        let data = record
            .get(head..)
            .filter(|d| d.len() as u64 == c.compressed_size)
            .ok_or_else(|| damaged("its data do not fill the record".into()))?;
        let u64_at = |k: usize| u64::from_le_bytes(record[k..k + 8].try_into().expect("8 bytes"));
        if record[0] != op::CHUNK
            || u64_at(1) != c.chunk_length - 9
            || u64_at(25) != c.uncompressed_size
            || record[37..41] != (name_len as u32).to_le_bytes()
            || &record[41..41 + name_len] != c.compression.as_bytes()
            || u64_at(41 + name_len) != c.compressed_size
        {
            return Err(damaged(
                "the record there is not the chunk the index describes".into(),
            ));
        }
        let crc = u32::from_le_bytes(record[33..37].try_into().expect("four bytes"));
        let mut out = Vec::new();
        let bound = c.uncompressed_size.saturating_add(1);
        let read = match c.compression.as_str() {
            "" => {
                out.extend_from_slice(data);
                Ok(0)
            }
            "lz4" => lz4::Decoder::new(data).and_then(|d| d.take(bound).read_to_end(&mut out)),
            "zstd" => zstd::stream::read::Decoder::new(data)
                .and_then(|d| d.take(bound).read_to_end(&mut out)),
            other => return Err(damaged(format!("unknown compression `{other}`"))),
        };
        read.map_err(|e| damaged(format!("its data do not decompress: {e}")))?;
        if out.len() as u64 != c.uncompressed_size {
            return Err(damaged("its data do not decompress to its size".into()));
        }
        // 0: no CRC written.
        if crc != 0 && crc32fast::hash(&out) != crc {
            return Err(damaged("its CRC does not match its data".into()));
        }
        // Its records (opcode, u64 length, content) end where the data end.
        let mut at = 0usize;
        while at < out.len() {
            let len = out
                .get(at + 1..at + 9)
                .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")))
                .and_then(|n| usize::try_from(n).ok())
                .and_then(|n| (at + 9).checked_add(n))
                .filter(|&end| end <= out.len())
                .ok_or_else(|| damaged("its records overrun its data".into()))?;
            messages += u64::from(out[at] == op::MESSAGE);
            at = len;
        }
    }
    if let Some(stats) = &summary.stats
        && stats.message_count != messages
    {
        return Err(ReadError::Damaged(format!(
            "its chunks hold {messages} messages, its statistics count {}",
            stats.message_count
        )));
    }
    Ok(summary.chunk_indexes.len())
}

/// One channel of the file.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelInfo {
    /// Topic, e.g. `/hybsim/state`.
    pub topic: String,
    /// Schema name and encoding (`jsonschema`).
    pub schema: String,
    /// Message encoding (`json`).
    pub encoding: String,
    /// Number of messages.
    pub messages: u64,
}

/// The summary of a hybsim MCAP log.
#[derive(Debug, Clone, PartialEq)]
pub struct RunSummary {
    /// Metadata records by name (`hybsim.run`, `hybsim.parameters`,
    /// `hybsim.solver`, `hybsim.design`, `hybsim.metrics`, `hybsim.result`),
    /// each a map of key to its text.
    pub metadata: BTreeMap<String, BTreeMap<String, String>>,
    /// Channels in topic order.
    pub channels: Vec<ChannelInfo>,
    /// Attachment names and media types.
    pub attachments: Vec<(String, String)>,
}

impl RunSummary {
    /// Reads the summary of the MCAP file `bytes`.
    pub fn read(bytes: &[u8]) -> Result<Self, ReadError> {
        if !bytes.starts_with(::mcap::MAGIC) {
            return Err(ReadError::NotMcap);
        }
        let summary = match ::mcap::read::Summary::read(bytes) {
            Ok(Some(s)) => s,
            Ok(None) => return Err(ReadError::Truncated("no summary".into())),
            Err(e) => return Err(ReadError::Truncated(e.to_string())),
        };
        let mut metadata = BTreeMap::new();
        for idx in &summary.metadata_indexes {
            let m = ::mcap::read::metadata(bytes, idx)
                .map_err(|e| ReadError::Truncated(e.to_string()))?;
            metadata.insert(m.name, m.metadata);
        }
        if !metadata.contains_key("hybsim.run") {
            return Err(ReadError::Foreign);
        }
        let counts = summary
            .stats
            .as_ref()
            .map(|s| s.channel_message_counts.clone())
            .unwrap_or_default();
        let mut channels: Vec<ChannelInfo> = summary
            .channels
            .iter()
            .map(|(id, ch)| ChannelInfo {
                topic: ch.topic.clone(),
                schema: ch
                    .schema
                    .as_ref()
                    .map(|s| format!("{} ({})", s.name, s.encoding))
                    .unwrap_or_default(),
                encoding: ch.message_encoding.clone(),
                messages: counts.get(id).copied().unwrap_or(0),
            })
            .collect();
        channels.sort_by(|a, b| a.topic.cmp(&b.topic));
        let attachments = summary
            .attachment_indexes
            .iter()
            .map(|a| (a.name.clone(), a.media_type.clone()))
            .collect();
        Ok(Self {
            metadata,
            channels,
            attachments,
        })
    }

    /// Value of `key` in metadata record `record`, if present.
    pub fn get(&self, record: &str, key: &str) -> Option<&str> {
        self.metadata.get(record)?.get(key).map(String::as_str)
    }

    /// The command line of the run (from `hybsim.run`'s `argv`), empty for
    /// library use.
    pub fn argv(&self) -> Vec<String> {
        self.get("hybsim.run", "argv")
            .and_then(|a| serde_json::from_str(a).ok())
            .unwrap_or_default()
    }

    /// Everything as one JSON object: metadata records (values parsed as
    /// JSON where they are JSON), channels and attachments.
    pub fn to_json(&self) -> Value {
        let parse = |v: &String| serde_json::from_str(v).unwrap_or(Value::String(v.clone()));
        let metadata: serde_json::Map<String, Value> = self
            .metadata
            .iter()
            .map(|(name, m)| {
                let entries = m.iter().map(|(k, v)| (k.clone(), parse(v))).collect();
                (name.clone(), Value::Object(entries))
            })
            .collect();
        serde_json::json!({
            "metadata": metadata,
            "channels": self.channels.iter().map(|c| serde_json::json!({
                "topic": c.topic, "schema": c.schema, "encoding": c.encoding,
                "messages": c.messages,
            })).collect::<Vec<_>>(),
            "attachments": self.attachments.iter().map(|(n, m)| serde_json::json!({
                "name": n, "media_type": m,
            })).collect::<Vec<_>>(),
        })
    }
}

/// A run's MCAP file read back: what the sinks knew about the run (model
/// name, layouts of the logged states and outputs, rule names; from the
/// `run.json` attachment) and its samples ([`replay`](Self::replay)).
///
/// ```no_run
/// use hybsim::sinks::mcap_read::RunLog;
/// let bytes = std::fs::read("ball.mcap").unwrap();
/// let log = RunLog::read(&bytes).unwrap();
/// let mut heights = Vec::new();
/// log.replay(&bytes, |at, _kind, x, _y| heights.push((at.t, x[0]))).unwrap();
/// ```
#[derive(Debug, Clone)]
pub struct RunLog {
    /// The run as the sinks described it, restricted to what was logged:
    /// `state_layout` and `output_layout` are the logged entries (over the
    /// full dimensions), `parameters`, `solver` and the rest as recorded.
    pub info: RunInfo,
    /// The file's summary.
    pub summary: RunSummary,
}

impl RunLog {
    /// Reads the summary and the run description of the MCAP file `bytes`.
    pub fn read(bytes: &[u8]) -> Result<Self, ReadError> {
        let summary = RunSummary::read(bytes)?;
        let index = ::mcap::read::Summary::read(bytes)
            .ok()
            .flatten()
            .and_then(|s| {
                s.attachment_indexes
                    .into_iter()
                    .find(|a| a.name == "run.json")
            })
            .ok_or_else(|| ReadError::Damaged("it has no `run.json` attachment".into()))?;
        let attachment = ::mcap::read::attachment(bytes, &index)
            .map_err(|e| ReadError::Damaged(format!("`run.json`: {e}")))?;
        let run: Value = serde_json::from_slice(&attachment.data)
            .map_err(|e| ReadError::Damaged(format!("`run.json`: {e}")))?;
        let info = run_info(&run).map_err(|e| ReadError::Damaged(format!("`run.json`: {e}")))?;
        // Every sample is read into vectors of these lengths: a damaged
        // `run.json` (`dim` 10¹³) aborted the process allocating them.
        for (what, dim) in [("state", info.state_dim), ("outputs", info.output_dim)] {
            if Vec::<f64>::new().try_reserve_exact(dim).is_err() {
                return Err(ReadError::Damaged(format!(
                    "`run.json`: `{what}.dim` is {dim}: a sample of that many numbers does not \
                     fit in memory"
                )));
            }
        }
        info.validate()
            .map_err(|e| ReadError::Damaged(format!("`run.json`: {e}")))?;
        Ok(Self { info, summary })
    }

    /// Whether the file has an outputs channel.
    fn has_outputs(&self) -> bool {
        self.summary
            .channels
            .iter()
            .any(|c| c.topic == OUTPUTS_TOPIC)
    }

    /// Calls `visit(at, kind, x, y)` for every logged sample in the order of
    /// the run, with `x` the state and `y` the outputs (flat vectors of the
    /// run's dimensions; components that were not logged are NaN), and
    /// returns the number of samples. The kind is not stored in the file:
    /// it is read from the hybrid times (the first sample is `Initial`, the
    /// last `Final`, a sample followed by a larger j `PreJump`, one after a
    /// smaller j `PostJump`, the others `Flow`).
    pub fn replay(
        &self,
        bytes: &[u8],
        mut visit: impl FnMut(HybridTime, SampleKind, &[f64], &[f64]),
    ) -> Result<u64, ReadError> {
        let info = &self.info;
        let states = RecordReader::new(&info.state_layout, info.state_dim);
        let outputs = RecordReader::new(&info.output_layout, info.output_dim);
        let with_outputs = self.has_outputs();
        check_chunks(bytes)?;
        // With the chunks' CRCs checked: a damaged chunk often still
        // decompresses, into wrong numbers that would be plotted.
        let stream = ::mcap::MessageStream::new_with_options(
            bytes,
            ::mcap::read::Options::ValidateChunkCrcs.into(),
        )
        .map_err(|e| ReadError::Damaged(e.to_string()))?;
        let mut decoders = MessageDecoder::default();
        // The sample being completed (its outputs follow its state), the one
        // before it (its kind needs the next j) and the j before that.
        let mut building: Option<(HybridTime, Vec<f64>)> = None;
        let mut held: Option<(HybridTime, Vec<f64>, Vec<f64>)> = None;
        let mut before: Option<u64> = None;
        let mut count = 0u64;
        let mut emit = |sample: (HybridTime, Vec<f64>, Vec<f64>),
                        held: &mut Option<(HybridTime, Vec<f64>, Vec<f64>)>,
                        before: &mut Option<u64>| {
            if let Some((at, x, y)) = held.take() {
                let kind = if before.is_none() {
                    SampleKind::Initial
                } else if sample.0.j > at.j {
                    SampleKind::PreJump
                } else if before.is_some_and(|b| b < at.j) {
                    SampleKind::PostJump
                } else {
                    SampleKind::Flow
                };
                visit(at, kind, &x, &y);
                *before = Some(at.j);
            }
            *held = Some(sample);
        };
        for message in stream {
            let message = message.map_err(|e| ReadError::Damaged(e.to_string()))?;
            let topic = message.channel.topic.as_str();
            if topic != STATE_TOPIC && topic != OUTPUTS_TOPIC {
                continue;
            }
            let record = decoders.decode(&message)?;
            let at = record_time(&record).ok_or_else(|| {
                ReadError::Damaged(format!(
                    "a message on `{topic}` has no number `t` and integer `j`"
                ))
            })?;
            let bad = |e: String| ReadError::Damaged(format!("message on `{topic}` at {at}: {e}"));
            if topic == STATE_TOPIC {
                if building.is_some() {
                    return Err(bad(
                        "the previous state sample has no outputs message".into()
                    ));
                }
                let mut x = vec![f64::NAN; info.state_dim];
                states.read(&record, &mut x).map_err(bad)?;
                if with_outputs {
                    building = Some((at, x));
                } else {
                    count += 1;
                    emit((at, x, Vec::new()), &mut held, &mut before);
                }
            } else {
                let (state_at, x) = building
                    .take()
                    .ok_or_else(|| bad("an outputs message without its state message".into()))?;
                if state_at != at {
                    return Err(bad(format!("the state message before it is at {state_at}")));
                }
                let mut y = vec![f64::NAN; info.output_dim];
                outputs.read(&record, &mut y).map_err(bad)?;
                count += 1;
                emit((at, x, y), &mut held, &mut before);
            }
        }
        if let Some((at, _)) = building {
            return Err(ReadError::Damaged(format!(
                "the last state sample (at {at}) has no outputs message"
            )));
        }
        if let Some((at, x, y)) = held {
            let kind = if before.is_none() {
                SampleKind::Initial
            } else {
                SampleKind::Final
            };
            visit(at, kind, &x, &y);
        }
        Ok(count)
    }
}

/// Decodes the messages of a hybsim MCAP file to JSON records, whatever
/// their encoding: `json` messages are parsed; `protobuf` messages are
/// decoded with their channel's descriptor set into the same JSON (see
/// [`super::protobuf`]). Decoders are built once per schema.
///
/// ```no_run
/// use hybsim::sinks::mcap_read::MessageDecoder;
/// let bytes = std::fs::read("ball.mcap").unwrap();
/// let mut decoder = MessageDecoder::default();
/// for message in mcap::MessageStream::new(&bytes).unwrap() {
///     let record = decoder.decode(&message.unwrap()).unwrap();
///     println!("{}", record["t"]);
/// }
/// ```
#[derive(Debug, Default)]
pub struct MessageDecoder {
    protobuf: BTreeMap<u16, super::protobuf::Decoder>,
}

impl MessageDecoder {
    /// The JSON record of `message`.
    pub fn decode(&mut self, message: &::mcap::Message<'_>) -> Result<Value, ReadError> {
        let channel = &message.channel;
        let topic = &channel.topic;
        match channel.message_encoding.as_str() {
            "json" => serde_json::from_slice(&message.data).map_err(|e| {
                ReadError::Damaged(format!("a message on `{topic}` is not JSON: {e}"))
            }),
            "protobuf" => {
                let schema = channel.schema.as_ref().ok_or_else(|| {
                    ReadError::Damaged(format!("the protobuf channel `{topic}` has no schema"))
                })?;
                let decoder = match self.protobuf.entry(schema.id) {
                    std::collections::btree_map::Entry::Occupied(e) => e.into_mut(),
                    std::collections::btree_map::Entry::Vacant(e) => e.insert(
                        super::protobuf::Decoder::new(&schema.data, &schema.name)
                            .map_err(|e| ReadError::Damaged(format!("channel `{topic}`: {e}")))?,
                    ),
                };
                decoder
                    .to_json(&message.data)
                    .map_err(|e| ReadError::Damaged(format!("a message on `{topic}`: {e}")))
            }
            other => Err(ReadError::Damaged(format!(
                "channel `{topic}` has the message encoding `{other}` (hybsim writes `protobuf` or `json`)"
            ))),
        }
    }
}

/// `t` and `j` of a sample record.
fn record_time(record: &Value) -> Option<HybridTime> {
    Some(HybridTime::new(
        record.get("t")?.as_f64()?,
        record.get("j")?.as_u64()?,
    ))
}

/// The [`RunInfo`] described by `run.json` (see [`super::mcap`]).
fn run_info(run: &Value) -> Result<RunInfo, String> {
    let text = |v: &Value, what: &str| -> Result<String, String> {
        v.as_str()
            .map(str::to_string)
            .ok_or_else(|| format!("`{what}` is not text"))
    };
    let part = |name: &str| -> Result<(Layout, usize), String> {
        let p = &run[name];
        let layout: Layout = serde_json::from_value(p["layout"].clone())
            .map_err(|e| format!("`{name}.layout`: {e}"))?;
        let dim = p["dim"]
            .as_u64()
            .ok_or_else(|| format!("`{name}.dim` is not a count"))? as usize;
        Ok((layout, dim))
    };
    let (state_layout, state_dim) = part("state")?;
    let (output_layout, output_dim) = part("outputs")?;
    let rules: Vec<String> =
        serde_json::from_value(run["rules"].clone()).map_err(|e| format!("`rules`: {e}"))?;
    let logged: Vec<String> =
        serde_json::from_value(run["logged_rules"].clone()).unwrap_or_else(|_| rules.clone());
    let mut info = RunInfo::new(
        &text(&run["model"]["name"], "model.name")?,
        &[] as &[String],
        &rules,
    );
    info.model_path = text(&run["model"]["path"], "model.path").unwrap_or_default();
    info.seed = run["seed"].as_u64().unwrap_or(0);
    info.state_layout = state_layout;
    info.state_dim = state_dim;
    info.output_layout = output_layout;
    info.output_dim = output_dim;
    // Files written before marks existed have no `marked_rules`.
    let marked: Vec<String> =
        serde_json::from_value(run["marked_rules"].clone()).unwrap_or_default();
    info.logged_rules = RuleLog::combine(
        &rules.iter().map(|r| logged.contains(r)).collect::<Vec<_>>(),
        &rules.iter().map(|r| marked.contains(r)).collect::<Vec<_>>(),
    );
    info.parameters = run["parameters"].clone();
    info.solver = run["solver"].clone();
    info.argv = serde_json::from_value(run["argv"].clone()).unwrap_or_default();
    Ok(info)
}
