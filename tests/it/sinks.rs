//! MCAP, CSV and SVG sinks, read back with the `mcap` and `csv` crates.

use std::collections::BTreeMap;
use std::path::Path;

use hybsim::arc::{ArcSink, HybridTime, SampleKind};
use hybsim::layout::Layout;
use hybsim::sinks::csv::CsvSink;
use hybsim::sinks::mcap::{Encoding, McapOptions, McapSink};
use hybsim::sinks::mcap_read::MessageDecoder;
use hybsim::sinks::plot::PlotSink;
use hybsim::sinks::{Decimation, Fanout, RuleLog, RunInfo, RunOutcome, RunStatus, SinkError};
use mcap::records::Record;
use serde_json::{Value, json};

use crate::util::{G, StopAfter, assert_conforms, ball_impacts, push_ball, temp_files};

const SOURCE: &str = "model ball\nparam g = 9.81\nstate h = 1, v = 0\n";

fn ball_info() -> RunInfo {
    let mut info = RunInfo::new("ball", &["h", "v"], &["impact"]);
    info.model_path = "models/ball.hyb".into();
    info.source = SOURCE.into();
    info.seed = 7;
    info.argv = vec!["hybsim".into(), "run".into(), "models/ball.hyb".into()];
    info.output_layout = Layout::scalars(&["E"]);
    info.output_dim = 1;
    info.parameters = json!({"g": G, "lambda": 0.8});
    info.solver = json!({"T": 10.0, "J": 20, "solver": "dopri5"});
    info
}

fn energy(_at: HybridTime, x: &[f64], y: &mut [f64]) {
    y[0] = G * x[0] + 0.5 * x[1] * x[1];
}

fn horizon() -> RunOutcome {
    RunOutcome {
        cause: "horizon_j".into(),
        message: "jump horizon J reached".into(),
        status: RunStatus::Completed,
    }
}

/// Writes the ball with `n` impacts to `path` and returns the file's bytes.
fn write_ball(path: &Path, n: usize, options: McapOptions) -> Vec<u8> {
    let info = ball_info();
    let mut sink = McapSink::create(path, &info, Some(&energy), options).unwrap();
    push_ball(&mut sink, 1.0, n, 0.01);
    let summary = sink.finish(&horizon()).unwrap();
    assert_eq!(summary.path, path);
    std::fs::read(path).unwrap()
}

struct Message {
    topic: String,
    log_time: u64,
    publish_time: u64,
    body: Value,
}

fn messages(bytes: &[u8]) -> Vec<Message> {
    let mut decoder = MessageDecoder::default();
    mcap::MessageStream::new(bytes)
        .unwrap()
        .map(|m| {
            let m = m.unwrap();
            Message {
                topic: m.channel.topic.clone(),
                log_time: m.log_time,
                publish_time: m.publish_time,
                body: decoder.decode(&m).unwrap(),
            }
        })
        .collect()
}

fn metadata(bytes: &[u8]) -> BTreeMap<String, BTreeMap<String, String>> {
    let summary = mcap::read::Summary::read(bytes).unwrap().unwrap();
    summary
        .metadata_indexes
        .iter()
        .map(|idx| {
            let m = mcap::read::metadata(bytes, idx).unwrap();
            (m.name, m.metadata)
        })
        .collect()
}

/// The default encoding: protobuf channels whose descriptor sets decode
/// every message into the records the JSON encoding writes.
#[test]
fn mcap_has_protobuf_channels_that_decode_to_the_json_records() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = write_ball(&dir.path().join("ball.mcap"), 5, McapOptions::default());
    let json = write_ball(
        &dir.path().join("json.mcap"),
        5,
        McapOptions::default().encoding(Encoding::Json),
    );
    let summary = mcap::read::Summary::read(&bytes).unwrap().unwrap();
    let mut topics = BTreeMap::new();
    for ch in summary.channels.values() {
        let schema = ch.schema.as_ref().expect("every channel has a schema");
        topics.insert(
            ch.topic.as_str(),
            (
                ch.message_encoding.as_str(),
                schema.encoding.as_str(),
                schema.name.as_str(),
            ),
        );
    }
    assert_eq!(
        topics,
        BTreeMap::from([
            (
                "/hybsim/jumps",
                ("protobuf", "protobuf", "hybsim.ball.Jump")
            ),
            ("/hybsim/log", ("json", "jsonschema", "foxglove.Log")),
            (
                "/hybsim/outputs",
                ("protobuf", "protobuf", "hybsim.ball.Outputs")
            ),
            (
                "/hybsim/state",
                ("protobuf", "protobuf", "hybsim.ball.State")
            ),
        ])
    );
    let (binary, text) = (messages(&bytes), messages(&json));
    assert_eq!(binary.len(), text.len());
    for (b, t) in binary.iter().zip(&text) {
        let mut record = b.body.clone();
        if record.get("index") == Some(&json!([])) {
            record.as_object_mut().unwrap().remove("index");
        }
        assert_eq!(
            (b.topic.as_str(), b.log_time, &record),
            (t.topic.as_str(), t.log_time, &t.body)
        );
    }
    // Protobuf is the smaller file (8 bytes a number).
    assert!(
        bytes.len() < json.len(),
        "{} vs {}",
        bytes.len(),
        json.len()
    );
}

#[test]
fn mcap_has_channels_with_json_schemas() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = write_ball(
        &dir.path().join("ball.mcap"),
        5,
        McapOptions::default().encoding(Encoding::Json),
    );
    let summary = mcap::read::Summary::read(&bytes).unwrap().unwrap();
    let mut topics: BTreeMap<String, (String, String, String)> = BTreeMap::new();
    for ch in summary.channels.values() {
        let schema = ch.schema.as_ref().expect("every channel has a schema");
        let parsed: Value = serde_json::from_slice(&schema.data).unwrap();
        assert_eq!(parsed["type"], "object", "{}", schema.name);
        assert!(parsed["properties"].is_object());
        topics.insert(
            ch.topic.clone(),
            (
                ch.message_encoding.clone(),
                schema.encoding.clone(),
                schema.name.clone(),
            ),
        );
    }
    let expect = |enc: &str, name: &str| ("json".to_string(), enc.to_string(), name.to_string());
    assert_eq!(
        topics,
        BTreeMap::from([
            (
                "/hybsim/jumps".to_string(),
                expect("jsonschema", "hybsim.ball.Jump")
            ),
            (
                "/hybsim/log".to_string(),
                expect("jsonschema", "foxglove.Log")
            ),
            (
                "/hybsim/outputs".to_string(),
                expect("jsonschema", "hybsim.ball.Outputs")
            ),
            (
                "/hybsim/state".to_string(),
                expect("jsonschema", "hybsim.ball.State")
            ),
        ])
    );

    // Every message conforms to its channel's schema.
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let schema: Value =
            serde_json::from_slice(&m.channel.schema.as_ref().unwrap().data).unwrap();
        let body: Value = serde_json::from_slice(&m.data).unwrap();
        assert_conforms(&body, &schema, &m.channel.topic);
    }
}

#[test]
fn mcap_orders_pre_jump_record_post_and_times_match_closed_form() {
    for jump_states in [false, true] {
        jump_records_between_their_samples(jump_states);
    }
}

/// The pre-jump sample, the jump record and the post-jump sample, in that
/// order, at the impacts' times; the record's `pre`/`post` (with
/// `jump_states`) are the samples' values.
fn jump_records_between_their_samples(jump_states: bool) {
    let dir = tempfile::tempdir().unwrap();
    let n = 6;
    let options = McapOptions::default().jump_states(jump_states);
    let bytes = write_ball(&dir.path().join("ball.mcap"), n, options);
    let msgs = messages(&bytes);
    let impacts = ball_impacts(1.0, n);

    let jumps: Vec<usize> = (0..msgs.len())
        .filter(|&k| msgs[k].topic == "/hybsim/jumps")
        .collect();
    assert_eq!(jumps.len(), n);
    for (i, &k) in jumps.iter().enumerate() {
        let jump = &msgs[k].body;
        assert_eq!(jump["rule"], "impact");
        assert_eq!(jump["rule_id"], 0);
        // JSON leaves the index of a plain rule out; protobuf writes it empty.
        assert!(jump.get("index").is_none_or(|i| *i == json!([])), "{jump}");
        assert_eq!(jump["j"], i as u64);
        let t = jump["t"].as_f64().unwrap();
        assert!((t - impacts[i]).abs() < 1e-12, "impact {i}: {t}");
        assert_eq!(msgs[k].log_time, (t * 1e9).round() as u64);

        // The state messages around the jump record: pre at (t, j), post at (t, j+1).
        let state_before = msgs[..k]
            .iter()
            .rev()
            .find(|m| m.topic == "/hybsim/state")
            .unwrap();
        let state_after = msgs[k + 1..]
            .iter()
            .find(|m| m.topic == "/hybsim/state")
            .unwrap();
        assert_eq!(state_before.body["t"].as_f64(), Some(t));
        assert_eq!(state_before.body["j"], i as u64);
        assert_eq!(state_after.body["t"].as_f64(), Some(t));
        assert_eq!(state_after.body["j"], i as u64 + 1);
        if jump_states {
            for (x, m) in [("pre", state_before), ("post", state_after)] {
                for v in ["h", "v"] {
                    assert_eq!(m.body[v], jump[x][v], "{x}.{v}");
                }
            }
        } else {
            assert!(
                jump.get("pre").is_none() && jump.get("post").is_none(),
                "{jump}"
            );
        }
        for m in [state_before, state_after] {
            assert_eq!(m.log_time, msgs[k].log_time);
        }
        let (pre, post) = (
            state_before.body["v"].as_f64().unwrap(),
            state_after.body["v"].as_f64().unwrap(),
        );
        assert!((post + 0.8 * pre).abs() < 1e-12);
    }

    // Times: log_time = publish_time = round(t·1e9); non-decreasing in file order.
    let mut last = 0;
    for m in &msgs {
        assert_eq!(m.log_time, m.publish_time);
        if let Some(t) = m.body.get("t").and_then(Value::as_f64) {
            assert_eq!(m.log_time, (t * 1e9).round() as u64, "{}", m.body);
        }
        assert!(m.log_time >= last);
        last = m.log_time;
    }

    // Outputs: one per state sample, same (t, j), E = g h + v²/2 conserved during flight.
    let states: Vec<&Message> = msgs.iter().filter(|m| m.topic == "/hybsim/state").collect();
    let outputs: Vec<&Message> = msgs
        .iter()
        .filter(|m| m.topic == "/hybsim/outputs")
        .collect();
    assert_eq!(states.len(), outputs.len());
    for (s, o) in states.iter().zip(&outputs) {
        assert_eq!(s.body["t"], o.body["t"]);
        assert_eq!(s.body["j"], o.body["j"]);
        let (h, v) = (s.body["h"].as_f64().unwrap(), s.body["v"].as_f64().unwrap());
        assert_eq!(o.body["E"].as_f64(), Some(G * h + 0.5 * v * v));
    }
    let e_after_first_bounce = outputs.iter().find(|o| o.body["j"] == 1).unwrap().body["E"]
        .as_f64()
        .unwrap();
    assert!((e_after_first_bounce - 0.64 * G).abs() < 1e-9);

    // The log: start and end only, the end after every sample.
    let logs: Vec<&Message> = msgs.iter().filter(|m| m.topic == "/hybsim/log").collect();
    assert_eq!(logs.len(), 2);
    assert_eq!(logs[0].body["level"], 2);
    assert!(
        logs[1].body["message"]
            .as_str()
            .unwrap()
            .contains("jump horizon J reached")
    );
    assert_eq!(msgs.last().unwrap().topic, "/hybsim/log");
}

#[test]
fn mcap_stores_metadata_and_attachments_for_reproduction() {
    let dir = tempfile::tempdir().unwrap();
    let n = 4;
    let bytes = write_ball(&dir.path().join("ball.mcap"), n, McapOptions::default());
    let meta = metadata(&bytes);
    assert_eq!(
        meta.keys().collect::<Vec<_>>(),
        [
            "hybsim.parameters",
            "hybsim.result",
            "hybsim.run",
            "hybsim.solver"
        ]
    );
    let run = &meta["hybsim.run"];
    assert_eq!(run["version"], env!("CARGO_PKG_VERSION"));
    assert_eq!(run["model"], "models/ball.hyb");
    assert_eq!(run["seed"], "7");
    assert_eq!(run["state_names"], r#"["h","v"]"#);
    assert_eq!(run["output_names"], r#"["E"]"#);
    assert_eq!(run["argv"], r#"["hybsim","run","models/ball.hyb"]"#);
    // sha256 of SOURCE, computed independently with `sha256sum`.
    assert_eq!(
        run["model_sha256"],
        "5df5d40b2f9777af3a0bebc77d14786bc675a60bc58194bad0ab6dd5c8ded7d7"
    );
    assert_eq!(meta["hybsim.parameters"]["lambda"], "0.8");
    assert_eq!(meta["hybsim.solver"]["solver"], "dopri5");
    let result = &meta["hybsim.result"];
    assert_eq!(result["termination"], "horizon_j");
    assert_eq!(result["status"], "completed");
    assert_eq!(result["j_end"], n.to_string());
    assert_eq!(result["t_end"], ball_impacts(1.0, n)[n - 1].to_string());
    assert_eq!(result["jumps"], format!(r#"{{"impact":{n}}}"#));

    // Metadata around the data: run/parameters/solver before the first chunk, result after the last.
    let order: Vec<String> = mcap::read::LinearReader::new(&bytes)
        .unwrap()
        .filter_map(|r| match r.unwrap() {
            Record::Metadata(m) => Some(m.name),
            Record::Attachment { header, .. } => Some(format!("attachment {}", header.name)),
            Record::Chunk { .. } => Some("chunk".into()),
            _ => None,
        })
        .collect();
    let first_chunk = order.iter().position(|s| s == "chunk").unwrap();
    let last_chunk = order.iter().rposition(|s| s == "chunk").unwrap();
    assert_eq!(
        order[..first_chunk],
        [
            "hybsim.run",
            "hybsim.parameters",
            "hybsim.solver",
            "attachment ball.hyb",
            "attachment run.json"
        ]
    );
    assert_eq!(order[last_chunk + 1..], ["hybsim.result"]);

    let summary = mcap::read::Summary::read(&bytes).unwrap().unwrap();
    let mut attachments = BTreeMap::new();
    for idx in &summary.attachment_indexes {
        let a = mcap::read::attachment(&bytes, idx).unwrap();
        attachments.insert(a.name.clone(), (a.media_type.clone(), a.data.to_vec()));
    }
    let (media, source) = &attachments["ball.hyb"];
    assert_eq!(media, "text/plain");
    assert_eq!(source.as_slice(), SOURCE.as_bytes());
    let (media, description) = &attachments["run.json"];
    assert_eq!(media, "application/json");
    let d: Value = serde_json::from_slice(description).unwrap();
    assert_eq!(d["seed"], 7);
    assert_eq!(d["parameters"]["g"], G);
    assert_eq!(d["solver"]["J"], 20);
    assert_eq!(d["rules"], json!(["impact"]));
    assert_eq!(d["state"]["names"], json!(["h", "v"]));
    assert_eq!(d["model"]["sha256"], run["model_sha256"].as_str());
}

#[test]
fn mcap_same_input_gives_identical_bytes() {
    let a = tempfile::tempdir().unwrap();
    let b = tempfile::tempdir().unwrap();
    let first = write_ball(&a.path().join("x.mcap"), 8, McapOptions::default());
    let second = write_ball(&b.path().join("x.mcap"), 8, McapOptions::default());
    assert!(first.len() > 1000);
    assert!(first == second, "same run, different bytes");
    // No temporary file is left behind.
    assert_eq!(temp_files(a.path()), Vec::<String>::new());
}

#[test]
fn mcap_decimation_keeps_jump_samples() {
    let dir = tempfile::tempdir().unwrap();
    let n = 5;
    let full = messages(&write_ball(
        &dir.path().join("full.mcap"),
        n,
        McapOptions::default(),
    ));
    let thin = messages(&write_ball(
        &dir.path().join("thin.mcap"),
        n,
        McapOptions::default().decimation(Decimation::all().every(10)),
    ));
    let count = |msgs: &[Message], topic: &str| msgs.iter().filter(|m| m.topic == topic).count();
    assert_eq!(count(&thin, "/hybsim/jumps"), n);
    let (full_states, thin_states) = (count(&full, "/hybsim/state"), count(&thin, "/hybsim/state"));
    assert!(
        thin_states * 5 < full_states,
        "{thin_states} vs {full_states}"
    );
    // Every jump record is still immediately preceded and followed by its state samples.
    let topics: Vec<&str> = thin
        .iter()
        .filter(|m| m.topic != "/hybsim/outputs")
        .map(|m| m.topic.as_str())
        .collect();
    for (k, t) in topics.iter().enumerate() {
        if *t == "/hybsim/jumps" {
            assert_eq!(topics[k - 1], "/hybsim/state");
            assert_eq!(topics[k + 1], "/hybsim/state");
        }
    }
    let by_dt = messages(&write_ball(
        &dir.path().join("dt.mcap"),
        n,
        McapOptions::default().decimation(Decimation::all().dt(Some(0.1))),
    ));
    let flow_ts: Vec<f64> = by_dt
        .iter()
        .filter(|m| m.topic == "/hybsim/state")
        .map(|m| m.body["t"].as_f64().unwrap())
        .collect();
    assert!(flow_ts.len() < full_states / 5);
    assert_eq!(count(&by_dt, "/hybsim/jumps"), n);
}

#[test]
fn mcap_stops_the_run_before_writing_non_finite_values() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nan.mcap");
    let info = ball_info();
    let mut sink = McapSink::create(&path, &info, Some(&energy), McapOptions::default()).unwrap();
    assert!(
        sink.sample(HybridTime::new(0.0, 0), &[1.0, 0.0], SampleKind::Initial)
            .is_continue()
    );
    assert!(
        sink.sample(HybridTime::new(0.5, 0), &[f64::NAN, 0.0], SampleKind::Flow)
            .is_break()
    );
    assert!(matches!(
        sink.stopped_by(),
        Some(SinkError::NonFinite { name, .. }) if name == "h"
    ));
    let summary = sink.finish(&horizon()).unwrap();
    assert_eq!(summary.outcome.cause, "non_finite");
    assert_eq!(summary.outcome.status, RunStatus::Failed);
    let bytes = std::fs::read(&path).unwrap();
    let msgs = messages(&bytes);
    let states = msgs.iter().filter(|m| m.topic == "/hybsim/state").count();
    assert_eq!(states, 1);
    let end = msgs.last().unwrap();
    assert_eq!(end.topic, "/hybsim/log");
    assert_eq!(end.body["level"], 4, "an error-level log entry");
    let meta = metadata(&bytes);
    assert_eq!(meta["hybsim.result"]["termination"], "non_finite");
    assert!(meta["hybsim.result"]["message"].contains("`h` is not finite"));

    // A non-finite output stops the run too.
    let bad = |_: HybridTime, _: &[f64], y: &mut [f64]| y[0] = f64::INFINITY;
    let mut sink = McapSink::create(
        dir.path().join("inf.mcap"),
        &info,
        Some(&bad),
        McapOptions::default(),
    )
    .unwrap();
    assert!(
        sink.sample(HybridTime::new(0.0, 0), &[1.0, 0.0], SampleKind::Initial)
            .is_break()
    );
    assert!(matches!(
        sink.stopped_by(),
        Some(SinkError::NonFinite { what: "output", name, .. }) if name == "E"
    ));

    // Only the components the records carry are checked: with `v` alone
    // logged, a non-finite `h` is not in the file and does not stop the
    // sink (the engine checks the whole state); a non-finite `v` does.
    let (only_v, _) = info.select_vars(&["v"]);
    let path = dir.path().join("v.mcap");
    let mut sink = McapSink::create(&path, &only_v, Some(&energy), McapOptions::default()).unwrap();
    assert!(
        sink.sample(
            HybridTime::new(0.0, 0),
            &[f64::NAN, 2.0],
            SampleKind::Initial
        )
        .is_continue()
    );
    assert!(
        sink.sample(HybridTime::new(0.5, 0), &[1.0, f64::NAN], SampleKind::Flow)
            .is_break()
    );
    assert!(matches!(
        sink.stopped_by(),
        Some(SinkError::NonFinite { what: "state", name, .. }) if name == "v"
    ));
    sink.finish(&horizon()).unwrap();
    let msgs = messages(&std::fs::read(&path).unwrap());
    let states: Vec<&Value> = msgs
        .iter()
        .filter(|m| m.topic == "/hybsim/state")
        .map(|m| &m.body)
        .collect();
    assert_eq!(states, [&json!({"t": 0.0, "j": 0, "v": 2.0})]);

    // So are the outputs: an output left out of the log (`F`) may be
    // anything, a logged one (`E`) may not.
    let mut two = info.clone();
    two.output_layout = Layout::scalars(&["E", "F"]);
    two.output_dim = 2;
    let (only_e, _) = two.select_vars(&["h", "v", "E"]);
    let outputs = |_: HybridTime, x: &[f64], y: &mut [f64]| {
        y[0] = 1.0 / x[1];
        y[1] = f64::NAN;
    };
    let path = dir.path().join("e.mcap");
    let mut sink =
        McapSink::create(&path, &only_e, Some(&outputs), McapOptions::default()).unwrap();
    let t = |t| HybridTime::new(t, 0);
    assert!(
        sink.sample(t(0.0), &[1.0, 2.0], SampleKind::Initial)
            .is_continue()
    );
    assert!(
        sink.sample(t(0.5), &[1.0, 0.0], SampleKind::Final)
            .is_break()
    );
    assert!(matches!(
        sink.stopped_by(),
        Some(SinkError::NonFinite { what: "output", name, .. }) if name == "E"
    ));
}

#[test]
fn unfinished_sinks_leave_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("gone.mcap");
    let info = ball_info();
    {
        let mut sink =
            McapSink::create(&path, &info, Some(&energy), McapOptions::default()).unwrap();
        push_ball(&mut sink, 1.0, 2, 0.01);
        let partial = temp_files(dir.path());
        assert!(
            partial.len() == 1 && partial[0].starts_with(".gone.mcap."),
            "{partial:?}"
        );
    }
    assert!(!path.exists());
    assert_eq!(temp_files(dir.path()), Vec::<String>::new());
}

#[test]
fn bad_layouts_and_options_are_errors_not_panics() {
    let dir = tempfile::tempdir().unwrap();
    let mut info = ball_info();
    // The layout names components beyond the state's dimension (a layout may
    // leave components out, never name ones that do not exist).
    info.state_dim = 1;
    let e = McapSink::create(
        dir.path().join("a.mcap"),
        &info,
        Some(&energy),
        McapOptions::default(),
    )
    .err()
    .unwrap();
    assert!(
        matches!(
            e,
            SinkError::Layout {
                what: "state",
                dim: 1,
                ..
            }
        ),
        "{e}"
    );
    let info = ball_info();
    let e = McapSink::create(
        dir.path().join("b.mcap"),
        &info,
        None,
        McapOptions::default(),
    )
    .err()
    .unwrap();
    assert!(matches!(e, SinkError::Option { .. }), "{e}");
    let e = CsvSink::create(
        dir.path().join("c.csv"),
        &info,
        None,
        Decimation::all().every(0),
    )
    .err()
    .unwrap();
    assert!(e.to_string().contains("--log-every"), "{e}");
    let e = McapSink::create(
        dir.path().join("no/such/dir/d.mcap"),
        &info,
        Some(&energy),
        McapOptions::default(),
    )
    .err()
    .unwrap();
    assert!(matches!(e, SinkError::Io { .. }), "{e}");
    let e = PlotSink::new(
        dir.path().join("e.svg"),
        &info,
        Some(&energy),
        &["speed".to_string()],
        Decimation::all(),
    )
    .err()
    .unwrap();
    assert!(e.to_string().contains("known: h, v, E"), "{e}");
}

#[test]
fn csv_round_trips_exact_values() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ball.csv");
    let mut info = ball_info();
    // A matrix state, to check that names with commas are quoted.
    info.state_layout = Layout {
        entries: vec![hybsim::layout::Entry::Field(hybsim::layout::Field {
            name: "P".into(),
            shape: hybsim::layout::Shape::Matrix { rows: 1, cols: 2 },
            offset: 0,
        })],
    };
    let mut sink = CsvSink::create(&path, &info, Some(&energy), Decimation::all()).unwrap();
    let pushed = push_ball(&mut sink, 1.0, 3, 0.01);
    assert_eq!(sink.finish().unwrap(), path);

    let mut reader = csv::Reader::from_path(&path).unwrap();
    let header: Vec<String> = reader.headers().unwrap().iter().map(String::from).collect();
    assert_eq!(header, ["t", "j", "kind", "P[1,1]", "P[1,2]", "E"]);
    let rows: Vec<csv::StringRecord> = reader.records().map(Result::unwrap).collect();
    assert_eq!(rows.len(), pushed);

    // Compare against the same samples captured in memory.
    let mut expected = Recorder::default();
    push_ball(&mut expected, 1.0, 3, 0.01);
    for (row, (at, x, kind)) in rows.iter().zip(&expected.0) {
        assert_eq!(row[0].parse::<f64>().unwrap(), at.t);
        assert_eq!(row[1].parse::<u64>().unwrap(), at.j);
        assert_eq!(&row[2], hybsim::sinks::csv::kind_name(*kind));
        assert_eq!(row[3].parse::<f64>().unwrap(), x[0]);
        assert_eq!(row[4].parse::<f64>().unwrap(), x[1]);
        assert_eq!(row[5].parse::<f64>().unwrap(), G * x[0] + 0.5 * x[1] * x[1]);
    }
    let kinds: Vec<&str> = rows.iter().map(|r| r.get(2).unwrap()).collect();
    assert_eq!(kinds.iter().filter(|k| **k == "pre_jump").count(), 3);
    assert_eq!(kinds.iter().filter(|k| **k == "post_jump").count(), 3);
    assert_eq!(kinds.first(), Some(&"initial"));
    assert_eq!(kinds.last(), Some(&"final"));
    assert_eq!(temp_files(dir.path()), Vec::<String>::new());
}

#[derive(Default)]
struct Recorder(Vec<(HybridTime, Vec<f64>, SampleKind)>);

impl ArcSink for Recorder {
    fn sample(&mut self, at: HybridTime, x: &[f64], kind: SampleKind) -> std::ops::ControlFlow<()> {
        self.0.push((at, x.to_vec(), kind));
        std::ops::ControlFlow::Continue(())
    }
    fn jump(&mut self, _: HybridTime, _: usize, _: &[f64], _: &[f64]) -> std::ops::ControlFlow<()> {
        std::ops::ControlFlow::Continue(())
    }
}

#[test]
fn fanout_feeds_all_sinks_and_stops_when_one_asks() {
    let dir = tempfile::tempdir().unwrap();
    let info = ball_info();
    let mut csv =
        CsvSink::create(dir.path().join("f.csv"), &info, None, Decimation::all()).unwrap();
    let mut plot = PlotSink::new(
        dir.path().join("f.svg"),
        &info,
        Some(&energy),
        &["v".to_string(), "E".to_string()],
        Decimation::all(),
    )
    .unwrap();
    let mut stop = StopAfter::new(50);
    let pushed = {
        let mut fan = Fanout::new(vec![&mut csv, &mut plot, &mut stop]);
        push_ball(&mut fan, 1.0, 10, 0.01)
    };
    assert_eq!(pushed, 50);
    assert_eq!(csv.tally().samples, 50);
    csv.finish().unwrap();
    let svg_path = plot.finish().unwrap();
    let svg = std::fs::read_to_string(svg_path).unwrap();
    assert!(svg.starts_with("<svg"));
    assert!(svg.contains("ball: v") && svg.contains("ball: E"));
    let rows = csv::Reader::from_path(dir.path().join("f.csv"))
        .unwrap()
        .records()
        .count();
    assert_eq!(rows, 50);
}

/// The engine's bouncing ball, logged to MCAP and read back: impact times
/// against the closed form t₁ = √(2h₀/g), t_{k+1} = t_k + 2λ^k v₀/g.
#[test]
fn engine_run_logged_to_mcap_matches_closed_form_impacts() {
    use hybsim::engine::models::BouncingBall;
    use hybsim::engine::{SimRng, SimSettings, simulate};

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("engine.mcap");
    let info = ball_info();
    let ball = BouncingBall::new(G, 0.8);
    let n = 12;
    let options = McapOptions::default().jump_states(true);
    let mut sink = McapSink::create(&path, &info, Some(&energy), options).unwrap();
    let settings = SimSettings::default().horizon_j(n as u64);
    let term = simulate(
        &ball,
        &[1.0, 0.0],
        &settings,
        &mut SimRng::seed_from(7),
        &mut sink,
    )
    .unwrap();
    assert_eq!(term.at.j, n as u64);
    sink.finish(&horizon()).unwrap();

    let msgs = messages(&std::fs::read(&path).unwrap());
    let jumps: Vec<&Message> = msgs.iter().filter(|m| m.topic == "/hybsim/jumps").collect();
    let exact = ball.impacts(1.0, n);
    assert_eq!(jumps.len(), n);
    for (k, (m, (t, v))) in jumps.iter().zip(&exact).enumerate() {
        let tj = m.body["t"].as_f64().unwrap();
        let vj = m.body["pre"]["v"].as_f64().unwrap();
        assert!((tj - t).abs() < 1e-9, "impact {k}: {tj} vs {t}");
        assert!((vj - v).abs() < 1e-7, "impact velocity {k}: {vj} vs {v}");
        assert_eq!(m.body["j"], k as u64);
    }
    // Energy (an output) is conserved along each flow to the solver's tolerance.
    for m in msgs.iter().filter(|m| m.topic == "/hybsim/outputs") {
        let j = m.body["j"].as_u64().unwrap() as i32;
        let e = m.body["E"].as_f64().unwrap();
        let expected = G * 0.64_f64.powi(j);
        assert!((e - expected).abs() < 1e-5 * G, "E = {e} at j = {j}");
    }
}

/// Replaying an in-memory arc gives the same file as logging the run directly.
#[test]
fn replayed_arc_gives_the_same_mcap_as_a_direct_run() {
    use crate::util::simulate_arc;
    use hybsim::engine::models::BouncingBall;
    use hybsim::engine::{SimRng, SimSettings, simulate};

    let dir = tempfile::tempdir().unwrap();
    let info = ball_info();
    let ball = BouncingBall::new(G, 0.8);
    let settings = SimSettings::default().horizon_j(7).dt_out(Some(0.05));
    let x0 = [1.0, 0.0];

    let direct = dir.path().join("direct.mcap");
    let mut sink = McapSink::create(&direct, &info, Some(&energy), McapOptions::default()).unwrap();
    let term = simulate(&ball, &x0, &settings, &mut SimRng::seed_from(3), &mut sink).unwrap();
    sink.finish(&RunOutcome::from_termination(&term)).unwrap();

    let arc = simulate_arc(&ball, &x0, &settings, &mut SimRng::seed_from(3)).unwrap();
    let replayed = dir.path().join("replayed.mcap");
    let mut sink =
        McapSink::create(&replayed, &info, Some(&energy), McapOptions::default()).unwrap();
    assert!(hybsim::sinks::replay(&arc, &mut sink).is_continue());
    let summary = sink
        .finish(&RunOutcome::from_termination(arc.termination().unwrap()))
        .unwrap();
    assert_eq!(summary.messages["/hybsim/jumps"], 7);
    assert_eq!(summary.outcome.cause, "horizon_j");
    assert!(std::fs::read(&direct).unwrap() == std::fs::read(&replayed).unwrap());
}

/// Long runs are thinned in the plot sink, keeping every jump.
#[test]
fn plot_sink_thins_long_runs_but_keeps_jumps() {
    use hybsim::sinks::plot::MAX_PLOT_SAMPLES;
    let dir = tempfile::tempdir().unwrap();
    let info = ball_info();
    let mut plot = PlotSink::new(
        dir.path().join("long.svg"),
        &info,
        None,
        &[],
        Decimation::all(),
    )
    .unwrap();
    let pushed = push_ball(&mut plot, 1.0, 10, 1e-4);
    assert!(pushed > 3 * MAX_PLOT_SAMPLES, "{pushed}");
    assert!(plot.len() <= 2 * MAX_PLOT_SAMPLES && plot.len() >= MAX_PLOT_SAMPLES / 2);
    let figure = plot.figure();
    let v = &figure.panels[1].series[0];
    assert_eq!(v.connectors.len(), 10, "one dashed segment per jump");
    for (k, [pre, post]) in v.connectors.iter().enumerate() {
        assert_eq!(pre.0, post.0);
        assert!((post.1 + 0.8 * pre.1).abs() < 1e-12, "jump {k}");
    }
}

/// A solution has one state per hybrid time: the MCAP sink evaluates the
/// outputs once for the post-jump sample of one jump and the pre-jump
/// sample of the next at the same instant, and writes the same values.
#[test]
fn mcap_evaluates_outputs_once_per_hybrid_time() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("twice.mcap");
    let info = ball_info();
    let calls = std::cell::Cell::new(0);
    let counted = |at: HybridTime, x: &[f64], y: &mut [f64]| {
        calls.set(calls.get() + 1);
        energy(at, x, y);
    };
    let mut sink = McapSink::create(&path, &info, Some(&counted), McapOptions::default()).unwrap();
    let (x0, x1, x2) = ([0.0, -3.0], [0.0, 2.4], [0.0, -1.92]);
    let at = |j| HybridTime::new(0.5, j);
    let _ = sink.sample(at(0), &x0, SampleKind::PreJump);
    let _ = sink.jump(at(0), 0, &x0, &x1);
    let _ = sink.sample(at(1), &x1, SampleKind::PostJump);
    let _ = sink.sample(at(1), &x1, SampleKind::PreJump);
    let _ = sink.jump(at(1), 0, &x1, &x2);
    let _ = sink.sample(at(2), &x2, SampleKind::PostJump);
    sink.finish(&horizon()).unwrap();
    assert_eq!(calls.get(), 3, "one evaluation per hybrid time");
    let outputs: Vec<f64> = messages(&std::fs::read(&path).unwrap())
        .iter()
        .filter(|m| m.topic == "/hybsim/outputs")
        .map(|m| m.body["E"].as_f64().unwrap())
        .collect();
    let e = |x: [f64; 2]| G * x[0] + 0.5 * x[1] * x[1];
    assert_eq!(outputs, [e(x0), e(x1), e(x1), e(x2)]);
}

/// An output map that records how it is asked.
#[derive(Default)]
struct Asked(std::cell::RefCell<Vec<(HybridTime, Vec<usize>)>>);

impl hybsim::arc::OutputMap for Asked {
    fn eval(&self, at: HybridTime, x: &[f64], y: &mut [f64]) {
        self.0.borrow_mut().push((at, Vec::new()));
        energy(at, x, y);
    }

    fn eval_after_jump(&self, rules: &[usize], at: HybridTime, x: &[f64], y: &mut [f64]) {
        self.0.borrow_mut().push((at, rules.to_vec()));
        energy(at, x, y);
    }
}

/// The file sinks evaluate outputs once per hybrid time, and a post-jump
/// sample as the update of its pre-jump sample by the rules that fired
/// (all of them, logged or not).
#[test]
fn post_jump_outputs_are_updates_by_the_rules_that_fired() {
    let mut info = RunInfo::new("ball", &["h", "v"], &["impact", "redraw"]);
    info.output_layout = Layout::scalars(&["E"]);
    info.output_dim = 1;
    info.logged_rules = vec![RuleLog::Full, RuleLog::Off];
    let dir = tempfile::tempdir().unwrap();
    let paths = [dir.path().join("a.mcap"), dir.path().join("b.csv")];
    let (mcap_asked, csv_asked) = (Asked::default(), Asked::default());
    let mut mcap =
        McapSink::create(&paths[0], &info, Some(&mcap_asked), McapOptions::default()).unwrap();
    let mut csv = CsvSink::create(&paths[1], &info, Some(&csv_asked), Decimation::all()).unwrap();
    let mut sinks = Fanout::new(vec![&mut mcap, &mut csv]);
    let t = |t: f64, j: u64| HybridTime::new(t, j);
    let _ = sinks.sample(t(0.0, 0), &[1.0, 0.0], SampleKind::Initial);
    // An impact and a redraw at once, then a second impact at that instant.
    let _ = sinks.sample(t(0.5, 0), &[0.0, -4.0], SampleKind::PreJump);
    let _ = sinks.jump(t(0.5, 0), 1, &[0.0, -4.0], &[0.0, 3.0]);
    let _ = sinks.jump(t(0.5, 0), 0, &[0.0, -4.0], &[0.0, 3.0]);
    let _ = sinks.sample(t(0.5, 1), &[0.0, 3.0], SampleKind::PostJump);
    let _ = sinks.sample(t(0.5, 1), &[0.0, 3.0], SampleKind::PreJump);
    let _ = sinks.jump(t(0.5, 1), 0, &[0.0, 3.0], &[0.0, 2.0]);
    let _ = sinks.sample(t(0.5, 2), &[0.0, 2.0], SampleKind::PostJump);
    // A redraw alone (not logged) and a flow sample after it.
    let _ = sinks.sample(t(0.7, 2), &[1.0, 1.0], SampleKind::PreJump);
    let _ = sinks.jump(t(0.7, 2), 1, &[1.0, 1.0], &[1.0, 1.0]);
    let _ = sinks.sample(t(0.7, 3), &[1.0, 1.0], SampleKind::PostJump);
    let _ = sinks.sample(t(0.8, 3), &[1.5, 0.5], SampleKind::Final);
    drop(sinks);
    mcap.finish(&horizon()).unwrap();
    csv.finish().unwrap();
    let expected = vec![
        (t(0.0, 0), vec![]),
        (t(0.5, 0), vec![]),
        (t(0.5, 1), vec![1, 0]),
        (t(0.5, 2), vec![0]),
        (t(0.7, 2), vec![]),
        (t(0.8, 3), vec![]),
    ];
    assert_eq!(*mcap_asked.0.borrow(), expected);
    assert_eq!(*csv_asked.0.borrow(), expected);
}
