//! `hybsim test` as a process: exit codes, the printed counterexample, and
//! the printed replay command run for real, its CSV read back.

use crate::util::{code, hybsim, stdout, test_model, test_property};
use std::path::Path;

/// The words of the printed `replay: hybsim run …` line (no quoting needed
/// for these models).
fn replay_words(text: &str) -> Vec<String> {
    let line = text
        .lines()
        .find_map(|l| l.strip_prefix("replay: "))
        .unwrap_or_else(|| panic!("no replay line in:\n{text}"));
    line.split_whitespace().map(|s| s.to_string()).collect()
}

/// Rows of a CSV written by `hybsim run --csv`: header and numeric rows
/// (`kind` column dropped).
fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<f64>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    let kind = header.iter().position(|h| h == "kind").unwrap();
    let rows = lines
        .map(|l| {
            l.split(',')
                .enumerate()
                .filter(|(i, _)| *i != kind)
                .map(|(_, v)| v.parse::<f64>().unwrap())
                .collect()
        })
        .collect();
    let header = header.into_iter().filter(|h| h != "kind").collect();
    (header, rows)
}

fn value_after(text: &str, key: &str) -> f64 {
    let i = text
        .find(key)
        .unwrap_or_else(|| panic!("no `{key}` in:\n{text}"))
        + key.len();
    let num: String = text[i..]
        .chars()
        .take_while(|c| c.is_ascii_digit() || "-+.eE".contains(*c))
        .collect();
    num.parse()
        .unwrap_or_else(|_| panic!("no number after `{key}` in:\n{text}"))
}

#[test]
fn properties_that_hold_pass_with_exit_0() {
    let dir = tempfile::tempdir().unwrap();
    let m = test_model("ball_props.hyb");
    let mut args = vec!["test", m.to_str().unwrap(), "--cases", "200", "--seed", "4"];
    for p in [
        "ground",
        "flows_above",
        "energy_jumps",
        "energy_post",
        "bounce",
        "energy_flow",
        "lands",
        "few_jumps",
        "decay",
        "stays_low",
    ] {
        args.extend(["--property", p]);
    }
    let out = hybsim(dir.path(), &args);
    let text = stdout(&out);
    assert_eq!(
        code(&out),
        0,
        "{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("h ~ uniform(0, 2)"), "{text}");
    assert!(text.contains("passed: 200 cases, 0 inconclusive"), "{text}");
    assert!(
        text.contains("ok  energy_post: at jumps post(energy) <= energy + 1e-9"),
        "{text}"
    );
}

#[test]
fn the_ball_above_1_5_is_refuted_shrunk_and_replayed_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let m = test_model("ball_props.hyb");
    let out = test_property(dir.path(), &m, "100", "below");
    let text = stdout(&out);
    assert_eq!(code(&out), 1, "{text}");
    assert!(text.contains("`below` fails at (t = 0, j = 0)"), "{text}");
    let h0 = value_after(&text, "input h = ");
    assert!(h0 > 1.5 && h0 - 1.5 <= 1e-11, "shrunk to {h0}:\n{text}");
    // Run the printed command (with a CSV too) and read the failure back.
    let mut words = replay_words(&text);
    assert_eq!(&words[..2], ["hybsim", "run"]);
    assert!(words.contains(&format!("h={h0}")), "{words:?}");
    words.extend(["--csv".into(), "replay.csv".into()]);
    let replay = hybsim(
        dir.path(),
        &words[1..].iter().map(|s| s.as_str()).collect::<Vec<_>>(),
    );
    assert_eq!(
        code(&replay),
        0,
        "{}",
        String::from_utf8_lossy(&replay.stderr)
    );
    assert!(dir.path().join("replay.mcap").exists());
    let (header, rows) = read_csv(&dir.path().join("replay.csv"));
    let h = header.iter().position(|c| c == "h").unwrap();
    assert_eq!((rows[0][0], rows[0][1]), (0.0, 0.0));
    assert_eq!(
        rows[0][h], h0,
        "the replay starts at the printed height, bit for bit"
    );
    assert!(rows[0][h] > 1.5);
}

/// Runs `hybsim test` with `args` in `dir`, expects property `prop`
/// (`decreasing` with output `v_col` as V) refuted, runs the printed replay
/// command with a CSV and finds the two printed values of V, bit for bit, at
/// consecutive samples of the failing flow interval.
fn refute_decrease_and_replay(dir: &Path, args: &[&str], prop: &str, v_col: &str) {
    let out = hybsim(dir, args);
    let text = stdout(&out);
    assert_eq!(code(&out), 1, "{text}");
    assert!(
        text.contains(&format!("FAILED  {prop}: decreasing")),
        "{text}"
    );
    // "`P` fails at (t = T, j = J): V did not decrease during the flow
    // from A at (t = T0, j = J) to B (tolerance ε)"
    let msg = &text[text
        .find(&format!("`{prop}` fails at"))
        .expect("violation line")..];
    let t = value_after(msg, "fails at (t = ");
    let j = value_after(msg, ", j = ");
    let from = value_after(msg, "did not decrease during the flow from ");
    let to = value_after(&msg[msg.find("did not decrease").unwrap()..], ") to ");
    assert!(to >= from, "{text}");
    let mut words = replay_words(&text);
    words.extend(["--csv".into(), "replay.csv".into()]);
    let replay = hybsim(
        dir,
        &words[1..].iter().map(|s| s.as_str()).collect::<Vec<_>>(),
    );
    assert_eq!(
        code(&replay),
        0,
        "{}",
        String::from_utf8_lossy(&replay.stderr)
    );
    assert!(dir.join("replay.mcap").exists());
    let (header, rows) = read_csv(&dir.join("replay.csv"));
    let v = header.iter().position(|c| c == v_col).unwrap();
    let k = rows
        .iter()
        .position(|r| r[0] == t && r[1] == j && r[v] == to)
        .unwrap_or_else(|| panic!("no sample at ({t}, {j}) with V = {to}:\n{text}"));
    assert!(
        k > 0 && rows[k - 1][1] == j && rows[k - 1][v] == from,
        "{:?}\n{text}",
        &rows[k - 1]
    );
}

#[test]
fn a_wrong_lyapunov_candidate_is_refuted_and_the_replay_shows_the_increase() {
    let dir = tempfile::tempdir().unwrap();
    let m = test_model("sample_hold.hyb");
    let args = ["test", m.to_str().unwrap(), "--cases", "50", "--seed", "1"];
    refute_decrease_and_replay(dir.path(), &args, "lyapunov", "V");
}

#[test]
fn the_norm_is_no_lyapunov_function_of_the_sample_and_hold_model() {
    // models/sample_and_hold.hyb (unstable ring plant, sampled LQR) with a
    // naive candidate appended: |x| must not decrease along every flow.
    let dir = tempfile::tempdir().unwrap();
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/sample_and_hold.hyb");
    let text = std::fs::read_to_string(shipped).unwrap()
        + "\noutput naive_v = norm(x)\nproperty naive: decreasing naive_v during flows\n";
    let m = dir.path().join("sh.hyb");
    std::fs::write(&m, text).unwrap();
    let args = ["test", m.to_str().unwrap(), "--cases", "8", "--set", "N=2"];
    refute_decrease_and_replay(dir.path(), &args, "naive", "naive_v");
    // The shipped property (the held input is -K x at every sample) holds.
    let out = hybsim(
        dir.path(),
        &[
            "test",
            m.to_str().unwrap(),
            "--set",
            "N=2",
            "--property",
            "hold",
        ],
    );
    assert_eq!(code(&out), 0, "{}", stdout(&out));
}

#[test]
fn model_errors_and_unknown_properties_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.hyb");
    std::fs::write(
        &bad,
        "model bad\nstate h ~ uniform(0, 1)\nflow { h' = -1 }\nproperty p: always hh >= 0\n",
    )
    .unwrap();
    let out = hybsim(dir.path(), &["test", bad.to_str().unwrap()]);
    assert_eq!(code(&out), 2);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("unknown name `hh`") && err.contains("bad.hyb:4:20"),
        "{err}"
    );
    let m = test_model("ball_props.hyb");
    let out = hybsim(
        dir.path(),
        &["test", m.to_str().unwrap(), "--property", "nope"],
    );
    assert_eq!(code(&out), 2);
    assert!(String::from_utf8_lossy(&out.stderr).contains("no property `nope`"));
    let none = dir.path().join("none.hyb");
    std::fs::write(&none, "model none\nstate h = 1\nflow { h' = -1 }\n").unwrap();
    assert_eq!(
        code(&hybsim(dir.path(), &["test", none.to_str().unwrap()])),
        2
    );
}

/// `--property ground --property ground` tested and listed `ground` twice ("testing 2
/// properties").
#[test]
fn a_property_named_twice_is_tested_once() {
    let dir = tempfile::tempdir().unwrap();
    let m = test_model("ball_props.hyb");
    let m = m.to_str().unwrap();
    let out = hybsim(
        dir.path(),
        &[
            "test",
            m,
            "--cases",
            "5",
            "--property",
            "ground",
            "--property",
            "ground",
        ],
    );
    let text = stdout(&out);
    assert_eq!(code(&out), 0, "{text}");
    assert!(text.starts_with("testing 1 property of"), "{text}");
    assert_eq!(text.matches("ok  ground:").count(), 1, "{text}");
}

#[test]
fn one_case_is_counted_in_the_singular() {
    let dir = tempfile::tempdir().unwrap();
    let out = test_property(dir.path(), &test_model("ball_props.hyb"), "1", "ground");
    let text = stdout(&out);
    assert_eq!(code(&out), 0, "{text}");
    assert!(text.contains(" on 1 case (master seed"), "{text}");
    assert!(text.contains("passed: 1 case, 0 inconclusive"), "{text}");
}

/// A model that draws no random number is tested on one case unless
/// `--cases` asks for more; one that does (a draw in a reset alone) on 100.
#[test]
fn a_deterministic_model_is_tested_on_one_case() {
    let dir = tempfile::tempdir().unwrap();
    let model = |reset: &str| {
        format!(
            "model d\nstate h = 1, v = 0\nflow {{ h' = v; v' = -9.81 }} in h >= 0\n\
             jump impact when h <= 0 && v <= 0 {{ v+ = {reset} }}\n\
             property ground: always h >= -1e-9\nsim {{ T = 1 }}\n"
        )
    };
    std::fs::write(dir.path().join("d.hyb"), model("-0.8 * v")).unwrap();
    std::fs::write(dir.path().join("r.hyb"), model("-uniform(0.7, 0.9) * v")).unwrap();
    let out = hybsim(dir.path(), &["test", "d.hyb"]);
    let text = stdout(&out);
    assert_eq!(code(&out), 0, "{text}");
    assert!(
        text.contains(" on 1 case (deterministic model: no random draw"),
        "{text}"
    );
    assert!(
        text.contains("passed: 1 case (deterministic model), 0 inconclusive"),
        "{text}"
    );
    let out = hybsim(dir.path(), &["test", "d.hyb", "--cases", "3"]);
    let text = stdout(&out);
    assert!(text.contains("passed: 3 cases, 0 inconclusive"), "{text}");
    let out = hybsim(dir.path(), &["test", "r.hyb"]);
    let text = stdout(&out);
    assert!(text.contains(" on 100 cases (master seed"), "{text}");
    assert!(text.contains("passed: 100 cases, 0 inconclusive"), "{text}");
}

/// A counterexample's state lists the model's states, not the timers the
/// language adds for an `every` rule or a held noise (no log shows them).
#[test]
fn a_counterexample_leaves_out_the_timers_the_language_adds() {
    let dir = tempfile::tempdir().unwrap();
    let model = "model ev
state x = 1
noise v ~ normal(0, 1) every 0.25
flow { x' = -x + 0.01 * v }
jump tick every 0.5 { x+ = x + 1 }
property small: always x <= 1.5
sim { T = 3 }
";
    std::fs::write(dir.path().join("ev.hyb"), model).unwrap();
    let out = hybsim(dir.path(), &["test", "ev.hyb", "--cases", "1"]);
    let text = stdout(&out);
    assert_eq!(code(&out), 1, "{text}");
    let state = text
        .lines()
        .find_map(|l| l.trim().strip_prefix("state: "))
        .unwrap_or_else(|| panic!("no state line in:\n{text}"));
    assert!(state.starts_with("x = "), "{text}");
    assert!(state.contains("v = "), "{text}");
    assert!(!state.contains("timer"), "{text}");
    assert_eq!(state.matches(" = ").count(), 2, "{text}");
}

/// Every failing property is reported, each with its own shrunk
/// counterexample and replay command, and the passing ones are listed: the
/// run stopped at the first failure (`below`) and said nothing of `slow`,
/// which fails too, nor of the two that hold.
#[test]
fn every_failing_property_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    let model = "model pt
param g = 9.81
state h ~ uniform(0, 2), v = 0
flow { h' = v; v' = -g } in h >= 0
jump impact when h <= 0 && v <= 0 { v+ = -0.8 * v }
property ground: always h >= -1e-9
property below: always h <= 1.5
property slow: always v >= -3
property bounce: at jumps impact post(v) >= 0
sim { T = 2 }
";
    std::fs::write(dir.path().join("pt.hyb"), model).unwrap();
    let out = hybsim(
        dir.path(),
        &["test", "pt.hyb", "--cases", "50", "--seed", "1"],
    );
    let text = stdout(&out);
    assert_eq!(code(&out), 1, "{text}");
    for line in [
        "FAILED  below: always h <= 1.5\n",
        "FAILED  slow: always v >= -3\n",
        "  ok  ground: always h >= -1e-9\n",
        "  ok  bounce: at jumps impact post(v) >= 0\n",
    ] {
        assert!(text.contains(line), "{line:?} in:\n{text}");
    }
    assert_eq!(text.matches("replay: hybsim run").count(), 2, "{text}");
    assert!(
        text.lines()
            .last()
            .unwrap()
            .starts_with("2 counterexamples: "),
        "{text}"
    );
}

/// A jump property that fails names the rule that jumped, as the model does: the report said
/// "(jump of rule 1)", the index among the model's rules, which no user has seen.
#[test]
fn a_failing_jump_property_names_the_rule() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("r.hyb"),
        "model r\nstate x = 0, n = 0\nflow { x' = 1 }\nevery 0.5 { n+ = n + 1 }\n\
         jump reset when x >= 1 { x+ = 0 }\nproperty small: at jumps post(n) <= 2\nsim { T = 3 }\n",
    )
    .unwrap();
    let out = hybsim(dir.path(), &["test", "r.hyb"]);
    let text = stdout(&out);
    assert_eq!(code(&out), 1, "{text}");
    // n reaches 3 at the third tick, t = 1.5: a jump of the `every` rule, `step`.
    assert!(
        text.contains("`small` fails at (t = 1.5, j = 3) (jump of rule `step`)"),
        "{text}"
    );
}
