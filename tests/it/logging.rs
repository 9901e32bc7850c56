//! Selective logging through the real binary: the model's `log { … }` block
//! and `--log-vars`/`--log-rules` choose what the MCAP and CSV files hold;
//! noise redraws are left out unless asked for; unknown names are located
//! errors (block) or usage errors (flags); CSV numbers read back bit for bit
//! equal to the MCAP values.

use std::collections::BTreeMap;
use std::path::Path;

use serde_json::Value;

use super::util::{code, hybsim, stderr};

/// Two agents with a vector state family, a scalar, a held noise redrawn
/// every 0.01, an output family and a plain output, a rule family.
const MODEL: &str = "model agents
param N = 2
noise v ~ normal(0, 1) every 0.01
state c = 0
for i in 1..N {
    state xh[i] = [i; 0]
    state k[i] = 0
    output e[i] = xh[i] - [1; 1]
}
output total = c + v
flow {
    for i in 1..N {
        xh[i]' = [xh[i][2]; -xh[i][1]]
        k[i]' = 1
    }
    c' = 1
}
for i in 1..N {
    jump fire[i] when xh[i][1] >= 0.5 && k[i] >= 0.03 * i { k[i]+ = 0 }
}
sim { T = 1; J = 1000; seed = 3 }
";

fn write_model(dir: &Path, extra: &str) -> String {
    let path = dir.join("agents.hyb");
    std::fs::write(&path, format!("{MODEL}{extra}")).unwrap();
    path.to_str().unwrap().to_string()
}

/// Runs `hybsim run MODEL -o out.mcap --csv out.csv --quiet ARGS`, expecting success.
fn run(dir: &Path, model: &str, args: &[&str]) -> (Vec<u8>, String) {
    let mut all = vec![
        "run", model, "-o", "out.mcap", "--csv", "out.csv", "--quiet",
    ];
    all.extend(args);
    let o = hybsim(dir, &all);
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    let mcap = std::fs::read(dir.join("out.mcap")).unwrap();
    let csv = std::fs::read_to_string(dir.join("out.csv")).unwrap();
    (mcap, csv)
}

/// Messages per topic, as JSON records (either encoding), and each topic's
/// JSON Schema (`null` for protobuf channels).
fn messages(bytes: &[u8]) -> (BTreeMap<String, Vec<Value>>, BTreeMap<String, Value>) {
    let mut topics: BTreeMap<String, Vec<Value>> = BTreeMap::new();
    let mut schemas = BTreeMap::new();
    let mut decoder = hybsim::sinks::mcap_read::MessageDecoder::default();
    for m in mcap::MessageStream::new(bytes).unwrap() {
        let m = m.unwrap();
        let schema = m.channel.schema.as_ref().unwrap();
        schemas.entry(m.channel.topic.clone()).or_insert_with(|| {
            if schema.encoding == "jsonschema" {
                serde_json::from_slice(&schema.data).unwrap()
            } else {
                Value::Null
            }
        });
        topics
            .entry(m.channel.topic.clone())
            .or_default()
            .push(decoder.decode(&m).unwrap());
    }
    (topics, schemas)
}

fn keys(v: &Value) -> Vec<String> {
    v.as_object().unwrap().keys().cloned().collect()
}

fn rules_of(topics: &BTreeMap<String, Vec<Value>>) -> BTreeMap<String, usize> {
    let mut n = BTreeMap::new();
    for r in topics.get("/hybsim/jumps").into_iter().flatten() {
        *n.entry(r["rule"].as_str().unwrap().to_string())
            .or_default() += 1;
    }
    n
}

/// Jumps per rule of the whole run (`hybsim.result`, every rule counted).
fn result_jumps(bytes: &[u8]) -> BTreeMap<String, u64> {
    let summary = mcap::Summary::read(bytes).unwrap().unwrap();
    for index in &summary.metadata_indexes {
        let meta = mcap::read::metadata(bytes, index).unwrap();
        if meta.name == "hybsim.result" {
            return serde_json::from_str(&meta.metadata["jumps"]).unwrap();
        }
    }
    panic!("no hybsim.result");
}

#[test]
fn redraws_are_left_out_by_default_and_logged_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    let model = write_model(dir.path(), "");
    let (bytes, csv) = run(dir.path(), &model, &[]);
    let (topics, _) = messages(&bytes);
    let jumps = result_jumps(&bytes);
    assert!(jumps["v.redraw"] >= 99, "{jumps:?}");
    let logged = rules_of(&topics);
    assert!(!logged.contains_key("v.redraw"), "{logged:?}");
    // Every jump of the fire rules is logged, with its pre- and post-jump samples.
    let fires = jumps["fire[1]"] + jumps["fire[2]"];
    assert!(fires >= 2, "{jumps:?}");
    assert_eq!(logged.values().sum::<usize>() as u64, fires);
    let states = &topics["/hybsim/state"];
    let kinds: Vec<&str> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(2).unwrap())
        .collect();
    assert_eq!(kinds.len(), states.len());
    assert_eq!(
        kinds.iter().filter(|k| **k == "pre_jump").count() as u64,
        fires
    );
    assert_eq!(
        kinds.iter().filter(|k| **k == "post_jump").count() as u64,
        fires
    );
    // j counts every jump, the hidden ones too.
    let j_end = states.last().unwrap()["j"].as_u64().unwrap();
    assert_eq!(j_end, jumps.values().sum::<u64>());

    let (bytes, csv) = run(dir.path(), &model, &["--log-rules", "v.redraw,fire"]);
    let (topics, _) = messages(&bytes);
    let logged = rules_of(&topics);
    assert_eq!(logged["v.redraw"] as u64, jumps["v.redraw"]);
    assert_eq!(
        logged.values().sum::<usize>() as u64,
        jumps.values().sum::<u64>()
    );
    let post = csv.lines().filter(|l| l.contains(",post_jump,")).count() as u64;
    assert!(post >= jumps["v.redraw"], "{post}");

    // No jump at all; the same seed gives the same file.
    let (none, _) = run(dir.path(), &model, &["--log-rules", ""]);
    let (topics, _) = messages(&none);
    assert!(!topics.contains_key("/hybsim/jumps"));
    let (again, _) = run(dir.path(), &model, &["--log-rules", ""]);
    assert_eq!(none, again);
}

#[test]
fn log_block_and_flags_select_states_outputs_and_rules() {
    let dir = tempfile::tempdir().unwrap();
    let model = write_model(
        dir.path(),
        "log { vars = [xh[2], total]; rules = [fire[1]]; every = 2; encoding = json }\n",
    );
    let (bytes, csv) = run(dir.path(), &model, &[]);
    let (topics, schemas) = messages(&bytes);
    let state = &topics["/hybsim/state"][0];
    assert_eq!(keys(state), ["j", "t", "xh"]);
    assert_eq!(
        state["xh"].as_array().unwrap().len(),
        1,
        "one member: {state}"
    );
    assert_eq!(keys(&topics["/hybsim/outputs"][0]), ["j", "t", "total"]);
    assert_eq!(
        keys(&schemas["/hybsim/state"]["properties"]),
        ["j", "t", "xh"]
    );
    assert_eq!(rules_of(&topics).keys().collect::<Vec<_>>(), ["fire[1]"]);
    let header = csv.lines().next().unwrap();
    assert_eq!(header, "t,j,kind,xh[2][1],xh[2][2],total");

    // Flags replace the block's lists.
    let (bytes, csv) = run(
        dir.path(),
        &model,
        &["--log-vars", "c,e", "--log-rules", "fire"],
    );
    let (topics, _) = messages(&bytes);
    assert_eq!(keys(&topics["/hybsim/state"][0]), ["c", "j", "t"]);
    assert_eq!(keys(&topics["/hybsim/outputs"][0]), ["e", "j", "t"]);
    let logged = rules_of(&topics);
    assert!(
        logged.contains_key("fire[1]") && logged.contains_key("fire[2]"),
        "{logged:?}"
    );
    assert!(
        csv.starts_with("t,j,kind,c,e[1][1],e[1][2],e[2][1],e[2][2]\n"),
        "{csv}"
    );
    // Only states: no output channel at all.
    let (bytes, _) = run(dir.path(), &model, &["--log-vars", "xh"]);
    let (topics, _) = messages(&bytes);
    assert!(!topics.contains_key("/hybsim/outputs"));
}

#[test]
fn unknown_names_are_located_errors_in_the_block_and_usage_errors_in_flags() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (
            "log { vars = [xhat] }\n",
            "unknown name `xhat`",
            "did you mean `xh`?",
        ),
        ("log { vars = [xh[3]] }\n", "xh", "E0402"),
        ("log { vars = [N] }\n", "a parameter", "E0304"),
        (
            "log { rules = [fir] }\n",
            "unknown name `fir`",
            "did you mean `fire`?",
        ),
        (
            "log { rules = [v.redrw] }\n",
            "unknown name `v.redrw`",
            "E0201",
        ),
        (
            "log { rulez = [fire] }\n",
            "unknown setting `rulez`",
            "E0204",
        ),
        ("log { encoding = yaml }\n", "protobuf or json", "E0506"),
        ("log { compression = 3 }\n", "lz4, zstd or none", "E0506"),
        ("log { jump_states = 1 }\n", "true or false", "E0506"),
        (
            "log { rules = [fire]; marks = [fire[2]] }\n",
            "`fire[2]` is in `rules` too",
            "E0506",
        ),
        ("log { marks = [fir] }\n", "unknown name `fir`", "E0201"),
    ];
    for (block, message, detail) in cases {
        let model = write_model(dir.path(), block);
        let o = hybsim(dir.path(), &["check", &model]);
        let err = stderr(&o);
        assert_ne!(code(&o), 0, "{block}");
        assert!(
            err.contains(message) && err.contains(detail),
            "{block}: {err}"
        );
        // Located: file, line and column of the name (the block is the last line).
        let line = MODEL.lines().count() + 1;
        assert!(
            err.contains(&format!("agents.hyb:{line}:")),
            "{block}: {err}"
        );
    }
    let model = write_model(dir.path(), "");
    for (flag, value) in [
        ("--log-vars", "xh,nope"),
        ("--log-vars", "xh[3]"),
        ("--log-rules", "fire,nope"),
        ("--log-rules", "fire[9]"),
        ("--log-marks", "nope"),
    ] {
        let o = hybsim(
            dir.path(),
            &["run", &model, "-o", "x.mcap", "-q", flag, value],
        );
        assert_eq!(code(&o), 2, "{flag} {value}: {}", stderr(&o));
        assert!(stderr(&o).contains(&format!("`{flag} ")), "{}", stderr(&o));
        assert!(!dir.path().join("x.mcap").exists());
    }
}

/// A marked rule's jumps leave their records alone: no pre- or post-jump
/// sample in MCAP, CSV or Parquet, the records on `/hybsim/jumps` and in the
/// Parquet jumps table; from the block or from `--log-marks`, and a rule
/// logged in full keeps its samples beside it.
#[test]
fn marked_rules_leave_records_without_samples() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let kinds = |csv: &str, kind: &str| {
        csv.lines()
            .skip(1)
            .filter(|l| l.split(',').nth(2) == Some(kind))
            .count()
    };
    for (extra, args) in [
        ("log { marks = [fire] }\n", &[][..]),
        ("", &["--log-marks", "fire"][..]),
        ("log { rules = [fire] }\n", &["--log-marks", "fire"][..]),
    ] {
        let model = write_model(d, extra);
        let (bytes, csv) = run(d, &model, &[args, &["--parquet", "out.parquet"]].concat());
        let (topics, _) = messages(&bytes);
        let jumps = result_jumps(&bytes);
        let fires = jumps["fire[1]"] + jumps["fire[2]"];
        assert!(fires >= 2, "{extra}{args:?}: {jumps:?}");
        let logged = rules_of(&topics);
        assert_eq!(logged.values().sum::<usize>() as u64, fires, "{logged:?}");
        assert!(!logged.contains_key("v.redraw"));
        assert_eq!(
            kinds(&csv, "pre_jump") + kinds(&csv, "post_jump"),
            0,
            "{extra}{args:?}"
        );
        // Every sample is a flow sample (or the first or last), one per hybrid time.
        let states = &topics["/hybsim/state"];
        let times: Vec<(u64, u64)> = states
            .iter()
            .map(|m| (m["t"].as_f64().unwrap().to_bits(), m["j"].as_u64().unwrap()))
            .collect();
        let mut distinct = times.clone();
        distinct.dedup();
        assert_eq!(distinct, times);
        assert_eq!(kinds(&csv, "flow") + 2, states.len());
        // The Parquet jumps table has the records.
        use parquet::file::reader::{FileReader, SerializedFileReader};
        let table = std::fs::File::open(d.join("out.jumps.parquet")).unwrap();
        let table = SerializedFileReader::new(table).unwrap();
        assert_eq!(table.metadata().file_metadata().num_rows() as u64, fires);
        let o = hybsim(d, &["info", "out.mcap"]);
        assert_eq!(code(&o), 0, "{}", stderr(&o));
        let run_meta = mcap::Summary::read(&bytes).unwrap().unwrap();
        let run_json = run_meta
            .metadata_indexes
            .iter()
            .map(|i| mcap::read::metadata(&bytes, i).unwrap())
            .find(|m| m.name == "hybsim.run")
            .unwrap();
        assert_eq!(
            run_json.metadata["marked_rules"],
            r#"["fire[1]","fire[2]"]"#
        );
        assert_eq!(run_json.metadata["logged_rules"], "[]");
    }
    // `--log-rules` wins over the block's marks; one rule in both flags is
    // a usage error.
    let model = write_model(d, "log { marks = [fire] }\n");
    let (bytes, csv) = run(d, &model, &["--log-rules", "fire[1]"]);
    let jumps = result_jumps(&bytes);
    assert_eq!(kinds(&csv, "post_jump") as u64, jumps["fire[1]"]);
    assert_eq!(
        rules_of(&messages(&bytes).0).values().sum::<usize>() as u64,
        jumps["fire[1]"] + jumps["fire[2]"]
    );
    let o = hybsim(
        d,
        &[
            "run",
            &model,
            "-o",
            "y.mcap",
            "-q",
            "--log-rules",
            "fire",
            "--log-marks",
            "fire[2]",
        ],
    );
    assert_eq!(code(&o), 2, "{}", stderr(&o));
    assert!(
        stderr(&o).contains("`fire[2]` is in both"),
        "{}",
        stderr(&o)
    );
    assert!(!d.join("y.mcap").exists());
}

/// The numbers of one JSON text in order, as written (strings skipped),
/// without the `rows`/`cols` of matrices: the values of a record.
fn numbers(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut chars = text.char_indices().peekable();
    let mut last_key = String::new();
    while let Some((i, ch)) = chars.next() {
        match ch {
            '"' => {
                let mut s = String::new();
                for (_, c) in chars.by_ref() {
                    if c == '"' {
                        break;
                    }
                    s.push(c);
                }
                last_key = s;
            }
            '-' | '0'..='9' => {
                let mut end = i + 1;
                while let Some(&(k, c)) = chars.peek() {
                    if c.is_ascii_digit() || "+-.eE".contains(c) {
                        chars.next();
                        end = k + 1;
                    } else {
                        break;
                    }
                }
                if last_key != "rows" && last_key != "cols" {
                    out.push(text[i..end].to_string());
                }
                last_key.clear();
            }
            _ => {}
        }
    }
    out
}

/// The JSON encoding's numbers are the CSV's, bit for bit; the protobuf
/// encoding's messages decode to exactly the JSON encoding's records.
#[test]
fn csv_values_equal_the_mcap_values_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/consensus_estimation.hyb");
    let args = [
        "--T",
        "0.02",
        "--log-vars",
        "*",
        "--log-rules",
        "event,v.redraw",
        "--log-dt",
        "0",
    ];
    let (binary, _) = run(dir.path(), model.to_str().unwrap(), &args);
    let json_args = [&args[..], &["--log-encoding", "json"]].concat();
    let (bytes, csv) = run(dir.path(), model.to_str().unwrap(), &json_args);
    let (mut from_protobuf, _) = messages(&binary);
    let (from_json, _) = messages(&bytes);
    // JSON leaves out the index of a rule without one; protobuf writes every field.
    for jump in from_protobuf.get_mut("/hybsim/jumps").unwrap() {
        if jump["index"] == serde_json::json!([]) {
            jump.as_object_mut().unwrap().remove("index");
        }
    }
    assert!(from_json["/hybsim/jumps"].len() > 10);
    assert_eq!(from_protobuf, from_json);

    let mut states = Vec::new();
    let mut outputs = Vec::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let text = std::str::from_utf8(&m.data).unwrap().to_string();
        match m.channel.topic.as_str() {
            "/hybsim/state" => states.push(numbers(&text)),
            "/hybsim/outputs" => outputs.push(numbers(&text)),
            _ => {}
        }
    }
    let rows: Vec<Vec<&str>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    assert!(rows.len() > 200, "{}", rows.len());
    assert_eq!((rows.len(), outputs.len()), (states.len(), states.len()));
    for ((row, s), o) in rows.iter().zip(&states).zip(&outputs) {
        // t, j, then the state values; the outputs message repeats t, j.
        let mcap: Vec<&String> = s.iter().chain(o.iter().skip(2)).collect();
        let cells: Vec<&&str> = row[..2].iter().chain(row[3..].iter()).collect();
        assert_eq!(mcap.len(), cells.len());
        for (a, b) in mcap.iter().zip(cells) {
            let (a, b): (f64, f64) = (a.parse().unwrap(), b.parse().unwrap());
            assert_eq!(a.to_bits(), b.to_bits(), "{a} {b}");
        }
        // Shortest form: at most 17 digits, a sign, a point and an
        // exponent, never tens of positional zeros.
        assert!(row.iter().all(|c| c.len() <= 24), "{row:?}");
    }
}

/// The file's encoding and compression: protobuf and LZ4 by default, the
/// `log` block's choice, and the flags over the block; the same records
/// whatever the choice.
#[test]
fn log_block_and_flags_choose_encoding_and_compression() {
    let dir = tempfile::tempdir().unwrap();
    let encodings = |bytes: &[u8]| {
        let summary = mcap::read::Summary::read(bytes).unwrap().unwrap();
        let state = summary
            .channels
            .values()
            .find(|c| c.topic == "/hybsim/state")
            .unwrap()
            .clone();
        let compressions: std::collections::BTreeSet<String> = summary
            .chunk_indexes
            .iter()
            .map(|c| c.compression.clone())
            .collect();
        (
            state.message_encoding.clone(),
            compressions.into_iter().collect::<Vec<_>>(),
        )
    };
    let model = write_model(dir.path(), "");
    let (default, _) = run(dir.path(), &model, &[]);
    assert_eq!(
        encodings(&default),
        ("protobuf".to_string(), vec!["lz4".to_string()])
    );
    let model = write_model(dir.path(), "log { encoding = json; compression = zstd }\n");
    let (block, _) = run(dir.path(), &model, &[]);
    assert_eq!(
        encodings(&block),
        ("json".to_string(), vec!["zstd".to_string()])
    );
    let (flags, _) = run(
        dir.path(),
        &model,
        &["--log-encoding", "protobuf", "--log-compression", "none"],
    );
    assert_eq!(
        encodings(&flags),
        ("protobuf".to_string(), vec![String::new()])
    );
    let strip = |bytes: &[u8]| {
        let (mut topics, _) = messages(bytes);
        for jump in topics.get_mut("/hybsim/jumps").into_iter().flatten() {
            if jump["index"] == serde_json::json!([]) {
                jump.as_object_mut().unwrap().remove("index");
            }
        }
        topics
    };
    assert_eq!(strip(&default), strip(&block));
    assert_eq!(strip(&default), strip(&flags));
}

/// Jump records carry the pre- and post-jump states only when asked (`log
/// { jump_states = true }` or `--log-jump-states`, the flag over the block),
/// in both encodings; they are then the samples written around the record.
#[test]
fn jump_states_are_logged_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    let has_states = |bytes: &[u8]| {
        let (topics, _) = messages(bytes);
        let jumps = &topics["/hybsim/jumps"];
        assert!(jumps.len() > 10);
        let with: Vec<bool> = jumps.iter().map(|r| r.get("pre").is_some()).collect();
        assert!(with.iter().all(|&w| w == with[0]), "{with:?}");
        if with[0] {
            // The state samples around each record hold its pre and post:
            // the last sample at (t, j) and the first at (t, j + 1) (a
            // jump's post-jump sample and the next one's pre-jump sample
            // may share a hybrid time).
            let states = &topics["/hybsim/state"];
            for r in jumps {
                let (t, j) = (&r["t"], r["j"].as_u64().unwrap());
                let at = |j: u64| move |s: &&Value| s["t"] == *t && s["j"] == j;
                let pre = states.iter().rfind(at(j)).unwrap();
                let post = states.iter().find(at(j + 1)).unwrap();
                for (key, s) in [("pre", pre), ("post", post)] {
                    for (name, v) in r[key].as_object().unwrap() {
                        assert_eq!(&s[name], v, "{key}.{name} at ({t}, {j})");
                    }
                }
            }
        }
        with[0]
    };
    let plain = write_model(dir.path(), "");
    assert!(!has_states(&run(dir.path(), &plain, &[]).0));
    assert!(has_states(
        &run(dir.path(), &plain, &["--log-jump-states"]).0
    ));
    let json = ["--log-jump-states", "--log-encoding", "json"];
    assert!(has_states(&run(dir.path(), &plain, &json).0));
    let model = write_model(dir.path(), "log { jump_states = true }\n");
    assert!(has_states(&run(dir.path(), &model, &[]).0));
    let off = ["--log-jump-states=false"];
    assert!(!has_states(&run(dir.path(), &model, &off).0));
}

/// `t` and `j` name the hybrid time in every logged record, so a state or
/// output of that name is a located error of `check` (not a file with two
/// fields of one name).
#[test]
fn states_and_outputs_named_t_or_j_are_located_errors() {
    let dir = tempfile::tempdir().unwrap();
    for (src, line) in [
        ("model m\nstate j = 0\nflow { j' = 1 }\nsim { T = 1 }\n", 2),
        (
            "model m\nstate x = 0, t = 1\nflow { x' = 1\n t' = 0 }\nsim { T = 1 }\n",
            2,
        ),
        (
            "model m\nstate x = 0\noutput j = 2 * x\nflow { x' = 1 }\nsim { T = 1 }\n",
            3,
        ),
    ] {
        std::fs::write(dir.path().join("m.hyb"), src).unwrap();
        for cmd in ["check", "run"] {
            let o = hybsim(
                dir.path(),
                &[cmd, "m.hyb", "-q"][..if cmd == "run" { 3 } else { 2 }],
            );
            let err = stderr(&o);
            assert_eq!(code(&o), 2, "{cmd} {src}: {err}");
            assert!(
                err.contains("E0304") && err.contains(&format!("m.hyb:{line}:")),
                "{err}"
            );
            assert!(!dir.path().join("m.mcap").exists());
        }
    }
}

/// The rules of a family of subsystem instances (`f.fire[1]`, `f.fire[2]`)
/// are selected as a family, `f.fire`, and one member as `f.fire[2]` or as
/// the language reads it, `f[2].fire`: in `--log-rules`, `--log-marks` and a
/// `log` block alike (`f.fire` was refused as "no jump rule of the model has
/// that name" while `count(f.fire)` counted them).
#[test]
fn rules_of_a_family_of_instances_are_selected_as_a_family() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let model = "model flock
subsystem Clock(p = 0.1) {
    state tau = 0
    flow { tau' = 1 }
    jump fire when tau >= p { tau+ = 0 }
}
solo = Clock(p = 0.25)
for i in 1..2 { f[i] = Clock(p = 0.15 * i) }
sim { T = 1; J = 1000 }
";
    let path = d.join("flock.hyb");
    std::fs::write(&path, model).unwrap();
    let path = path.to_str().unwrap();
    let all = result_jumps(&run(d, path, &[]).0);
    assert_eq!((all["f.fire[1]"], all["f.fire[2]"]), (6, 3), "{all:?}");
    let logged = |args: &[&str]| rules_of(&messages(&run(d, path, args).0).0);
    let family = logged(&["--log-rules", "f.fire"]);
    let expect: BTreeMap<String, usize> = ["f.fire[1]", "f.fire[2]"]
        .iter()
        .map(|r| (r.to_string(), all[*r] as usize))
        .collect();
    assert_eq!(family, expect);
    for member in ["f.fire[2]", "f[2].fire", "f[ 2 ].fire"] {
        let one = logged(&["--log-rules", member]);
        assert_eq!(one.keys().collect::<Vec<_>>(), ["f.fire[2]"], "{member}");
    }
    // Marks: the family's records stay, alone.
    let marked = logged(&["--log-rules", "solo.fire", "--log-marks", "f.fire"]);
    assert_eq!(marked.len(), 3, "{marked:?}");
    // The same names in a `log` block.
    std::fs::write(
        d.join("flock.hyb"),
        format!("{model}log {{ rules = [f.fire] }}\n"),
    )
    .unwrap();
    assert_eq!(logged(&[]), expect);
    std::fs::write(
        d.join("flock.hyb"),
        format!("{model}log {{ rules = [f[2].fire] }}\n"),
    )
    .unwrap();
    assert_eq!(logged(&[]).keys().collect::<Vec<_>>(), ["f.fire[2]"]);
}

/// A member of a family of instances' state is selected as the language
/// reads it, `f[2].tau`, or as the model names it, `f.tau[2]`, in
/// `--log-vars` and a `log` block (`f[2].tau` was refused in both).
#[test]
fn a_member_of_a_family_of_instances_is_logged_by_either_name() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let model = "model flock
subsystem Clock(p = 0.1) {
    state tau = 0
    flow { tau' = 1 }
    jump fire when tau >= p { tau+ = 0 }
}
for i in 1..3 { f[i] = Clock(p = 0.15 * i) }
sim { T = 1 }
";
    let path = d.join("flock.hyb");
    std::fs::write(&path, model).unwrap();
    let path = path.to_str().unwrap();
    let header = |csv: &str| csv.lines().next().unwrap().to_string();
    for name in ["f[2].tau", "f.tau[2]"] {
        let (_, csv) = run(d, path, &["--log-vars", name]);
        assert_eq!(header(&csv), "t,j,kind,f.tau[2]", "{name}");
    }
    std::fs::write(
        d.join("flock.hyb"),
        format!("{model}log {{ vars = [f[2].tau] }}\n"),
    )
    .unwrap();
    let (_, csv) = run(d, path, &[]);
    assert_eq!(header(&csv), "t,j,kind,f.tau[2]");
}

/// A subsystem instance's name selects all of its states and outputs, and a
/// member of a family of instances all of that member's (`--log-vars b1`,
/// `--plot-vars b1` and `vars = [b1]` were refused: "neither a state nor an
/// output"), a family inside it whole for that member (`f[2].c`).
#[test]
fn an_instance_is_logged_and_plotted_by_its_name() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let model = "model pair
subsystem Osc(w = 1) {
    state x = 1, v = 0
    for m in 1..2 { state c[m] = m }
    flow { x' = v; v' = -w^2*x }
    output e = x^2 + v^2
}
subsystem Ramp(k = 2) { output y = k*t }
b1 = Osc(w = 2)
ramp = Ramp()
b10 = Osc(w = 3)
for i in 1..2 { f[i] = Osc(w = i) }
sim { T = 0.5 }
";
    let path = d.join("pair.hyb");
    std::fs::write(&path, model).unwrap();
    let path = path.to_str().unwrap();
    let header = |csv: &str| csv.lines().next().unwrap().to_string();
    let cases = [
        ("b1", "t,j,kind,b1.x,b1.v,b1.c[1],b1.c[2],b1.e"),
        (
            "f[2]",
            "t,j,kind,f.x[2],f.v[2],\"f.c[2,1]\",\"f.c[2,2]\",f.e[2]",
        ),
        ("f[2].c", "t,j,kind,\"f.c[2,1]\",\"f.c[2,2]\""),
        ("f.v,b10.e", "t,j,kind,f.v[1],f.v[2],b10.e"),
        // An instance with outputs alone.
        ("ramp", "t,j,kind,ramp.y"),
    ];
    for (name, expected) in cases {
        let (_, csv) = run(d, path, &["--log-vars", name]);
        assert_eq!(header(&csv), expected, "--log-vars {name}");
    }
    // The plot draws a panel per entry of the instance.
    let o = hybsim(
        d,
        &[
            "run",
            path,
            "--no-mcap",
            "--quiet",
            "--plot",
            "b1.svg",
            "--plot-vars",
            "b1",
        ],
    );
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    let svg = std::fs::read_to_string(d.join("b1.svg")).unwrap();
    for panel in ["b1.x", "b1.v", "b1.c[1]", "b1.e"] {
        assert!(svg.contains(panel), "{panel} missing from the plot");
    }
    // A single instance has no members; nothing else is taken for an instance.
    for bad in ["b1[1]", "f[3]", "b"] {
        let o = hybsim(
            d,
            &[
                "run",
                path,
                "--no-mcap",
                "--csv",
                "x.csv",
                "--log-vars",
                bad,
            ],
        );
        assert_eq!(code(&o), 2, "--log-vars {bad}: {}", stderr(&o));
    }
    // The same names in a `log` block.
    for (name, expected) in cases.iter().filter(|(n, _)| !n.contains(',')) {
        std::fs::write(
            d.join("pair.hyb"),
            format!("{model}log {{ vars = [{name}] }}\n"),
        )
        .unwrap();
        let (_, csv) = run(d, path, &[]);
        assert_eq!(header(&csv), *expected, "vars = [{name}]");
    }
    for (bad, code_) in [("b1[1]", "E0304"), ("f[3]", "E0402"), ("b", "E0201")] {
        std::fs::write(
            d.join("pair.hyb"),
            format!("{model}log {{ vars = [{bad}] }}\n"),
        )
        .unwrap();
        let o = hybsim(d, &["check", path]);
        assert_eq!(code(&o), 2, "vars = [{bad}]");
        assert!(stderr(&o).contains(code_), "vars = [{bad}]: {}", stderr(&o));
    }
}

/// An instance's name selects its jump rules too (`--log-rules b1`, `--log-marks f[2]`,
/// `rules = [f]`; `b1` was refused: "no jump rule of the model has that name"), never another
/// instance's whose name it begins (`b10`).
#[test]
fn an_instance_selects_its_rules_by_its_name() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let model = "model clocks
subsystem Clock(period = 0.1) {
    state tau = 0
    flow { tau' = 1 }
    jump tick when tau >= period { tau+ = 0 }
}
b1 = Clock(period = 0.1)
b10 = Clock(period = 0.3)
for i in 1..2 { f[i] = Clock(period = 0.2 * i) }
sim { T = 1 }
";
    let path = d.join("clocks.hyb");
    std::fs::write(&path, model).unwrap();
    let path = path.to_str().unwrap();
    let logged = |args: &[&str]| {
        let (bytes, _) = run(d, path, args);
        rules_of(&messages(&bytes).0)
    };
    let names = |m: &BTreeMap<String, usize>| m.keys().cloned().collect::<Vec<_>>().join(" ");
    let cases = [
        ("b1", "b1.tick"),
        ("b10", "b10.tick"),
        ("f", "f.tick[1] f.tick[2]"),
        ("f[2]", "f.tick[2]"),
        ("b1,f[1]", "b1.tick f.tick[1]"),
    ];
    for (name, expected) in cases {
        let got = logged(&["--log-rules", name]);
        assert_eq!(names(&got), expected, "--log-rules {name}");
        assert!(got.values().all(|&n| n >= 2), "--log-rules {name}: {got:?}");
    }
    // The clock of period 0.1 ticks 10 times in [0, 1] (the last at t = 1 within rounding).
    assert!((9..=10).contains(&logged(&["--log-rules", "b1"])["b1.tick"]));
    // In a `log` block, and refused where nothing has the name.
    std::fs::write(
        d.join("clocks.hyb"),
        format!("{model}log {{ rules = [f] }}\n"),
    )
    .unwrap();
    assert_eq!(names(&logged(&[])), "f.tick[1] f.tick[2]");
    std::fs::write(d.join("clocks.hyb"), model).unwrap();
    for bad in ["b", "f[3]", "b1.tock"] {
        let o = hybsim(
            d,
            &["run", path, "--no-mcap", "--quiet", "--log-rules", bad],
        );
        assert_eq!(code(&o), 2, "--log-rules {bad}: {}", stderr(&o));
    }
}

/// `samples` (summary, `--json`, the MCAP's `hybsim.result`) counts the solution's samples before
/// the log's selection (README): `--log-every` thins the files, not the count.
#[test]
fn samples_counts_the_solution_not_the_log() {
    let dir = tempfile::tempdir().unwrap();
    let model = write_model(dir.path(), "");
    let summary = |args: &[&str]| -> (u64, Vec<u8>, String) {
        let mut all = vec![
            "run", &model, "-o", "out.mcap", "--csv", "out.csv", "--quiet", "--json",
        ];
        all.extend(args);
        let o = hybsim(dir.path(), &all);
        assert_eq!(code(&o), 0, "{}", stderr(&o));
        let v: Value = serde_json::from_slice(&o.stdout).unwrap();
        let mcap = std::fs::read(dir.path().join("out.mcap")).unwrap();
        let csv = std::fs::read_to_string(dir.path().join("out.csv")).unwrap();
        (v["samples"].as_u64().unwrap(), mcap, csv)
    };
    let (all, bytes, csv) = summary(&[]);
    let (thinned, thin_bytes, thin_csv) = summary(&["--log-every", "5"]);
    assert_eq!(all, thinned);
    let result = |bytes: &[u8]| -> String {
        let summary = mcap::Summary::read(bytes).unwrap().unwrap();
        (summary.metadata_indexes.iter())
            .map(|i| mcap::read::metadata(bytes, i).unwrap())
            .find(|m| m.name == "hybsim.result")
            .unwrap()
            .metadata["samples"]
            .clone()
    };
    assert_eq!(result(&thin_bytes), all.to_string());
    let states = |bytes: &[u8]| messages(bytes).0["/hybsim/state"].len();
    // Every sample is logged by default (redraws' sides as flow samples but the post-jump one).
    let rows = |csv: &str| csv.lines().count() - 1;
    assert!(states(&bytes) == rows(&csv) && rows(&csv) as u64 <= all);
    assert!(states(&thin_bytes) == rows(&thin_csv) && rows(&thin_csv) < rows(&csv));
}
