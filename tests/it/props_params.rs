//! Issue 9, second part: random parameters (`param g ~ uniform(a, b)`) in
//! `hybsim test` and `hybsim run`, `post(…)` inside `sum(…)`, property
//! texts without trailing comments, and compact numbers in reports — all
//! through the binary.

use crate::util::{code, hybsim, stdout, test_model, test_property};
use std::path::Path;

/// The number printed right after `key` in `text`.
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

/// The first data row of a CSV written by `hybsim run --csv`, by column.
fn first_row(path: &Path) -> Vec<(String, String)> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header = lines.next().unwrap().split(',');
    let row = lines.next().unwrap().split(',');
    header
        .zip(row)
        .map(|(h, v)| (h.to_string(), v.to_string()))
        .collect()
}

fn column(row: &[(String, String)], name: &str) -> f64 {
    row.iter()
        .find(|(h, _)| h == name)
        .unwrap_or_else(|| panic!("no column {name}"))
        .1
        .parse()
        .unwrap()
}

/// `hybsim run MODEL ARGS --csv NAME --no-mcap -q` in `dir`: its first row.
fn run_row(dir: &Path, m: &Path, args: &[&str], csv: &str) -> Vec<(String, String)> {
    let mut all = vec!["run", m.to_str().unwrap()];
    all.extend_from_slice(args);
    all.extend(["--csv", csv, "--no-mcap", "-q"]);
    let out = hybsim(dir, &all);
    assert_eq!(code(&out), 0, "{}", String::from_utf8_lossy(&out.stderr));
    first_row(&dir.join(csv))
}

#[test]
fn a_random_parameter_is_sampled_shrunk_toward_its_centre_and_replayed() {
    let dir = tempfile::tempdir().unwrap();
    let m = test_model("random_param.hyb");
    let out = test_property(dir.path(), &m, "60", "slow");
    let text = stdout(&out);
    assert_eq!(code(&out), 1, "{text}");
    assert!(
        text.contains("sampled: g ~ uniform(5, 15), h ~ uniform(1, 2)"),
        "{text}"
    );
    // The property's text is its source span: no trailing comment line.
    assert!(text.contains("FAILED  slow: always g <= 12\n"), "{text}");
    // g fails above 12; shrinking moves it toward the centre 10, so it ends
    // just above 12; h (not involved) goes to its centre 1.5.
    let g = value_after(&text, "input g = ");
    assert!(g > 12.0 && g - 12.0 < 1e-9, "{text}");
    assert_eq!(value_after(&text, "input h = "), 1.5, "{text}");
    let g0 = value_after(&text, "(~ uniform(5, 15); sampled ");
    let h0 = value_after(&text, "(~ uniform(1, 2); sampled ");
    assert!(g0 > 12.0 && g0 <= 15.0, "{text}");
    // The replay command pins g and reproduces it; the derived parameter
    // half_g = g / 2 is recomputed from it.
    let seed: u64 = {
        let i = text.find("(seed ").expect("seed") + "(seed ".len();
        let digits: String = text[i..]
            .chars()
            .take_while(|c| c.is_ascii_digit())
            .collect();
        digits.parse().unwrap()
    };
    let replay: Vec<String> = text
        .lines()
        .find_map(|l| l.strip_prefix("replay: "))
        .expect("replay line")
        .split_whitespace()
        .map(String::from)
        .collect();
    assert!(replay.contains(&format!("g={g}")), "{replay:?}");
    let words: Vec<&str> = replay[3..]
        .iter()
        .map(|s| s.as_str())
        .filter(|w| *w != "-o" && *w != "replay.mcap")
        .collect();
    let row = run_row(dir.path(), &m, &words, "replay.csv");
    assert_eq!(column(&row, "g_out"), g);
    assert_eq!(column(&row, "half_out"), g / 2.0);
    // Without --set, `hybsim run --seed S` draws the case's sampled values:
    // parameters first, then initial values, from the same stream.
    let seed_s = seed.to_string();
    let row = run_row(dir.path(), &m, &["--seed", &seed_s], "seeded.csv");
    assert_eq!(column(&row, "g_out"), g0);
    assert_eq!(column(&row, "half_out"), g0 / 2.0);
    assert_eq!(column(&row, "h"), h0);
    // Other seeds draw other values, all in range.
    let gs: Vec<f64> = (1..=5)
        .map(|s| {
            let s = s.to_string();
            column(&run_row(dir.path(), &m, &["--seed", &s], "s.csv"), "g_out")
        })
        .collect();
    assert!(gs.iter().all(|g| (5.0..=15.0).contains(g)), "{gs:?}");
    assert!(gs.windows(2).all(|w| w[0] != w[1]), "{gs:?}");
}

#[test]
fn set_pins_a_random_parameter_or_makes_a_fixed_one_random() {
    let dir = tempfile::tempdir().unwrap();
    let m = test_model("random_param.hyb");
    let row = run_row(dir.path(), &m, &["--set", "g=9"], "pinned.csv");
    assert_eq!(column(&row, "g_out"), 9.0);
    assert_eq!(column(&row, "half_out"), 4.5);
    // `--set g=normal(2, 0)` replaces the draw; the test header shows it.
    let row = run_row(dir.path(), &m, &["--set", "g=normal(2, 0)"], "n.csv");
    assert_eq!(column(&row, "g_out"), 2.0);
    let out = hybsim(
        dir.path(),
        &[
            "test",
            m.to_str().unwrap(),
            "--cases",
            "20",
            "--set",
            "g=uniform(1, 3)",
            "--property",
            "slow",
        ],
    );
    let text = stdout(&out);
    assert_eq!(code(&out), 0, "{text}");
    assert!(text.contains("g ~ uniform(1, 3)"), "{text}");
    // A fixed value: no longer sampled.
    let out = hybsim(
        dir.path(),
        &["test", m.to_str().unwrap(), "--cases", "5", "--set", "g=13"],
    );
    let text = stdout(&out);
    assert!(text.contains("sampled: h ~ uniform(1, 2)"), "{text}");
    assert_eq!(code(&out), 1, "{text}");
}

#[test]
fn post_inside_sum_reads_the_post_jump_state() {
    // `counts`: at every jump, sum over i of post(c[i]) - c[i] is 1 + 2.
    let dir = tempfile::tempdir().unwrap();
    let m = test_model("random_param.hyb");
    let out = test_property(dir.path(), &m, "30", "counts");
    let text = stdout(&out);
    assert_eq!(code(&out), 0, "{text}");
    assert!(
        text.contains(
            "ok  counts: at jumps sum(i in 1..2: post(c[i]) - c[i]) == 3 && post(v) >= 0\n"
        ),
        "{text}"
    );
    // The same with a wrong total is refuted at the first jump.
    let src = std::fs::read_to_string(&m).unwrap().replace("== 3", "== 4");
    let wrong = dir.path().join("wrong.hyb");
    std::fs::write(&wrong, src).unwrap();
    let out = test_property(dir.path(), &wrong, "5", "counts");
    let text = stdout(&out);
    assert_eq!(code(&out), 1, "{text}");
    assert!(text.contains("`counts` fails at (t = "), "{text}");
    assert!(text.contains(", j = 0) (jump of rule `impact`)"), "{text}");
    assert!(text.contains("post-jump state: "), "{text}");
    // post(…) outside `at jumps` is an error that says so.
    let src = std::fs::read_to_string(&m).unwrap().replace(
        "property tiny: nonincreasing 1e-12 * t during flows",
        "property tiny: always post(h) >= 0",
    );
    std::fs::write(&wrong, src).unwrap();
    let out = hybsim(dir.path(), &["check", wrong.to_str().unwrap()]);
    assert_eq!(code(&out), 2);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("only in `at jumps` properties"), "{err}");
}

#[test]
fn violation_messages_print_numbers_compactly() {
    let dir = tempfile::tempdir().unwrap();
    let m = test_model("random_param.hyb");
    let out = test_property(dir.path(), &m, "5", "tiny");
    let text = stdout(&out);
    assert_eq!(code(&out), 1, "{text}");
    // V = 1e-12 t at the first output sample t = 0.1: 1e-13, not 0.0000000000001.
    assert!(
        text.contains(
            "V increased during the flow from 0 at (t = 0, j = 0) to 1e-13 (tolerance 0)"
        ),
        "{text}"
    );
    assert!(!text.contains("0.0000"), "{text}");
}
