//! Reading back what [`McapSink`](super::mcap::McapSink) wrote: the
//! summary of a run's MCAP file (metadata records, channels and their
//! message counts, attachments), for `hybsim info` and other readers.

use std::collections::BTreeMap;

use serde_json::Value;

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
