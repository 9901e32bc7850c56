//! Outputs of every shipped model through the real binary: MCAP schemas obey
//! Foxglove's JSON Schema rules, every message decodes (in Rust and with the
//! official Python `mcap` reader), the state topic shows no internal timers.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use hybsim::sinks::foxglove::check_schema;
use serde_json::Value;

use super::util::{assert_conforms, code, hybsim, stderr};

/// Every `.hyb` file in `models/`, so that a new model is covered as soon as
/// it is added.
pub fn shipped_models() -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("models");
    let mut models: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "hyb"))
        .collect();
    models.sort();
    assert!(models.len() >= 10, "{models:?}");
    models
}

/// Runs a short `hybsim run MODEL -o OUT ARGS` in `dir` (a few jumps of every
/// model) and returns the MCAP bytes.
pub fn short_run(dir: &Path, model: &Path, out: &str, args: &[&str]) -> Vec<u8> {
    let mut all = vec![
        "run",
        model.to_str().unwrap(),
        "-o",
        out,
        "--quiet",
        "--T",
        "2",
        "--J",
        "25",
    ];
    all.extend(args);
    let o = hybsim(dir, &all);
    assert_eq!(code(&o), 0, "{}: {}", model.display(), stderr(&o));
    std::fs::read(dir.join(out)).unwrap()
}

/// The Python interpreter with the official `mcap` package: `.venv` made by
/// `scripts/setup`, else `python3`. `None` only if there is no Python.
fn python() -> Option<PathBuf> {
    let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv/bin/python");
    if venv.exists() {
        return Some(venv);
    }
    let found = Command::new("python3").arg("--version").output().is_ok();
    found.then(|| PathBuf::from("python3"))
}

#[test]
fn every_model_writes_foxglove_valid_mcap_that_python_decodes() {
    let dir = tempfile::tempdir().unwrap();
    let mut files = Vec::new();
    for model in shipped_models() {
        let name = model.file_stem().unwrap().to_str().unwrap().to_string();
        let out = format!("{name}.mcap");
        let bytes = short_run(dir.path(), &model, &out, &["--log-encoding", "json"]);
        // The default (protobuf) encoding of the same run decodes to the same records.
        let binary_out = format!("{name}.protobuf.mcap");
        let binary = short_run(dir.path(), &model, &binary_out, &[]);
        let mut decoder = hybsim::sinks::mcap_read::MessageDecoder::default();
        let stream = |b| mcap::MessageStream::new(b).unwrap().map(Result::unwrap);
        let mut decoded = 0;
        for (p, j) in stream(&binary).zip(stream(&bytes)) {
            assert_eq!(p.channel.topic, j.channel.topic, "{name}");
            let mut record = decoder.decode(&p).unwrap();
            if record.get("index") == Some(&Value::Array(vec![])) {
                record.as_object_mut().unwrap().remove("index");
            }
            assert_eq!(
                record,
                decoder.decode(&j).unwrap(),
                "{name}: {}",
                p.channel.topic
            );
            decoded += 1;
        }
        assert_eq!(decoded, stream(&bytes).count(), "{name}");
        assert_eq!(decoded, stream(&binary).count(), "{name}");
        files.push(dir.path().join(binary_out));
        let mut schemas: BTreeMap<String, Value> = BTreeMap::new();
        let mut counts: BTreeMap<String, u64> = BTreeMap::new();
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            let m = m.unwrap();
            let schema = m
                .channel
                .schema
                .as_ref()
                .expect("every channel has a schema");
            assert_eq!(schema.encoding, "jsonschema");
            assert_eq!(m.channel.message_encoding, "json");
            let s = schemas
                .entry(m.channel.topic.clone())
                .or_insert_with(|| serde_json::from_slice(&schema.data).unwrap());
            if let Err(issues) = check_schema(s) {
                let list: Vec<String> = issues.iter().map(|i| i.to_string()).collect();
                panic!(
                    "{name}: schema of {} breaks Foxglove's rules:\n{}",
                    m.channel.topic,
                    list.join("\n")
                );
            }
            let body: Value = serde_json::from_slice(&m.data)
                .unwrap_or_else(|e| panic!("{name}: {} message: {e}", m.channel.topic));
            assert_conforms(&body, s, &format!("{name}{}", m.channel.topic));
            *counts.entry(m.channel.topic.clone()).or_default() += 1;
        }
        assert!(counts["/hybsim/state"] >= 2, "{name}: {counts:?}");
        // Timers of `every` and `noise` are internal: not logged.
        let state = &schemas["/hybsim/state"]["properties"];
        for key in state.as_object().unwrap().keys() {
            assert!(!key.contains('.') && !key.contains('['), "{name}: {key}");
        }
        files.push(dir.path().join(out));
    }

    let Some(python) = python() else {
        eprintln!(
            "SKIPPED: python3 is not installed, so the MCAP files were not decoded with the \
             official Python reader (install python3 and run scripts/setup)"
        );
        return;
    };
    let out = Command::new(&python)
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/mcap_check.py"))
        .args(&files)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "the Python `mcap` reader failed (run scripts/setup to install it into .venv): {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines = String::from_utf8(out.stdout).unwrap();
    assert_eq!(lines.lines().count(), files.len(), "{lines}");
    for line in lines.lines() {
        let v: Value = serde_json::from_str(line).unwrap();
        assert!(
            v["messages"]["/hybsim/state"].as_u64().unwrap() >= 2,
            "{line}"
        );
    }
}

#[test]
fn families_of_vectors_and_outputs_are_arrays_of_objects() {
    let dir = tempfile::tempdir().unwrap();
    let src = "model fam
        for i in 1..3 { state x[i] = [i; 0], z[i] = i }
        for i in 1..2 { state odd[i] = zeros(i, 1) }
        state k = 0
        for i in 1..3 { output e[i] = x[i] * 2, s[i] = z[i] }
        flow { for i in 1..3 { x[i]' = [0; 1]
                               z[i]' = 1 } }
        every 0.5 { k+ = k + 1 }
        sim { T = 1 }
    ";
    std::fs::write(dir.path().join("fam.hyb"), src).unwrap();
    let o = hybsim(
        dir.path(),
        &[
            "run",
            "fam.hyb",
            "-o",
            "fam.mcap",
            "--quiet",
            "--log-encoding",
            "json",
        ],
    );
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    let bytes = std::fs::read(dir.path().join("fam.mcap")).unwrap();
    let mut seen = BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let schema: Value =
            serde_json::from_slice(&m.channel.schema.as_ref().unwrap().data).unwrap();
        check_schema(&schema).unwrap();
        seen.insert(
            m.channel.topic.clone(),
            serde_json::from_slice::<Value>(&m.data).unwrap(),
        );
    }
    // The last sample, at t = 1.
    let state = &seen["/hybsim/state"];
    let x3: Vec<f64> = state["x"][2]["data"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(x3.len(), 2, "{state}");
    assert_eq!(x3[0], 3.0, "{state}");
    assert!((x3[1] - 1.0).abs() < 1e-12, "{state}");
    assert_eq!(state["z"][0], serde_json::json!(2.0), "{state}");
    assert_eq!(state["odd"][1]["rows"], 2, "{state}");
    assert!(
        state.get("k").is_some() && state.as_object().unwrap().len() == 6,
        "{state}"
    );
    let outputs = &seen["/hybsim/outputs"];
    assert_eq!(
        outputs["e"][0]["data"].as_array().unwrap().len(),
        2,
        "{outputs}"
    );
    assert!(outputs["s"][2].is_number(), "{outputs}");
}

#[test]
fn plot_vars_select_family_members_and_unknown_names_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/intermittent_estimation.hyb");
    let model = model.to_str().unwrap();
    let o = hybsim(
        dir.path(),
        &[
            "run",
            model,
            "--no-mcap",
            "--quiet",
            "--T",
            "1",
            "--plot",
            "p.svg",
            "--plot-vars",
            "xhat[2],x,theta[1,2]",
        ],
    );
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    let svg = std::fs::read_to_string(dir.path().join("p.svg")).unwrap();
    assert!(
        svg.contains("xhat[2][1]") && !svg.contains("xhat[1][1]"),
        "one member"
    );
    // A member of a family with two indices (the comma inside brackets is no separator).
    assert!(
        svg.contains("theta[1,2][1]") && !svg.contains("theta[2,1][1]"),
        "theta[1,2]"
    );
    let o = hybsim(
        dir.path(),
        &[
            "run",
            model,
            "--no-mcap",
            "--quiet",
            "--plot",
            "q.svg",
            "--plot-vars",
            "nope",
        ],
    );
    assert_eq!(code(&o), 2, "{}", stderr(&o));
    assert!(stderr(&o).contains("`--plot-vars nope`"), "{}", stderr(&o));
    assert!(!dir.path().join("q.svg").exists());
}
