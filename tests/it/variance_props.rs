//! Issue 6 (property tests of Trimpe & D'Andrea): the `property`
//! declarations of models/variance_triggering.hyb — Prop. 1 (the invariant
//! interval [p1, p2] and entering it), the trigger γ(k) = 1 ⟺ c²(p(k) − p̄)
//! ≥ δ, and convergence to p̄ for δ = 0 — checked by `hybsim test` on random
//! (a, c, q, r, δ, p0), and a wrong bound refuted and replayed.

use crate::util::{hybsim, stdout};
use std::path::{Path, PathBuf};

fn shipped() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("models/variance_triggering.hyb")
}

/// Ranges satisfying the paper's assumptions (|a| > 1, c ≠ 0, q, r > 0,
/// δ ≥ 0, p0 ≥ 0) around Example 1 (a = 1.2, c = q = r = 1, δ = 3); only
/// a², c² enter the variance iteration, so positive a, c cover the signs.
const RANGES: [&str; 6] = [
    "a=uniform(1.05, 2)",
    "c=uniform(0.5, 2)",
    "q=uniform(0.5, 2)",
    "r=uniform(0.5, 2)",
    "delta=uniform(0, 5)",
    "p0=uniform(0, 20)",
];

fn test_args(model: &Path, cases: usize, extra: &[&str]) -> Vec<String> {
    let mut args = vec![
        "test".to_string(),
        model.display().to_string(),
        "--cases".into(),
        cases.to_string(),
        "--seed".into(),
        "6".into(),
    ];
    for r in RANGES {
        args.extend(["--set".to_string(), r.to_string()]);
    }
    args.extend(extra.iter().map(|s| s.to_string()));
    args
}

#[test]
fn proposition_1_and_the_trigger_hold_on_random_parameters() {
    let dir = tempfile::tempdir().unwrap();
    let out = hybsim(dir.path(), &test_args(&shipped(), 300, &[]));
    let text = stdout(&out);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for input in [
        "a ~ uniform(1.05, 2)",
        "c ~ uniform(0.5, 2)",
        "delta ~ uniform(0, 5)",
        "p0 ~ uniform(0, 20)",
    ] {
        assert!(text.contains(input), "{input}:\n{text}");
    }
    for p in ["invariant", "enters", "trigger", "kalman"] {
        assert!(text.contains(&format!("  ok  {p}: ")), "{p}:\n{text}");
    }
    assert!(text.contains("passed: 300 cases, 0 inconclusive"), "{text}");
}

#[test]
fn with_delta_zero_the_variance_converges_to_pbar() {
    // δ pinned to 0 (full communication): `kalman` is no longer vacuous.
    let dir = tempfile::tempdir().unwrap();
    let args = test_args(
        &shipped(),
        200,
        &[
            "--set",
            "delta=0",
            "--property",
            "kalman",
            "--property",
            "trigger",
        ],
    );
    let out = hybsim(dir.path(), &args);
    let text = stdout(&out);
    assert_eq!(out.status.code(), Some(0), "{text}");
    assert!(!text.contains("delta ~"), "{text}");
    assert!(text.contains("passed: 200 cases, 0 inconclusive"), "{text}");
    // And it is not vacuous: a tolerance far below what 50 steps reach fails.
    let src = std::fs::read_to_string(shipped())
        .unwrap()
        .replace("eventually within 50", "eventually within 2");
    let m = dir.path().join("vt.hyb");
    std::fs::write(&m, src).unwrap();
    let args = test_args(&m, 50, &["--set", "delta=0", "--property", "kalman"]);
    let out = hybsim(dir.path(), &args);
    assert_eq!(out.status.code(), Some(1), "{}", stdout(&out));
}

#[test]
fn a_too_small_invariant_interval_is_refuted_and_replayed() {
    // Dropping `+ q` from p2 = a² t + q: the silent branch a² p + q just
    // below the threshold t exceeds a² t, so some case leaves the interval.
    let dir = tempfile::tempdir().unwrap();
    let src = std::fs::read_to_string(shipped()).unwrap()
        + "\nproperty wrong: after p >= p1 - p_eps && p <= p2 + p_eps always p <= a^2 * pt\n";
    let m = dir.path().join("vt.hyb");
    std::fs::write(&m, src).unwrap();
    let out = hybsim(dir.path(), &test_args(&m, 300, &["--property", "wrong"]));
    let text = stdout(&out);
    assert_eq!(out.status.code(), Some(1), "{text}");
    assert!(text.contains("FAILED  wrong: after p >= p1"), "{text}");
    for name in ["a", "c", "q", "r", "delta", "p0"] {
        assert!(
            text.contains(&format!("  input {name} = ")),
            "{name}:\n{text}"
        );
    }
    let replay: Vec<String> = text
        .lines()
        .find_map(|l| l.strip_prefix("replay: "))
        .expect("replay line")
        .split_whitespace()
        .map(String::from)
        .collect();
    for name in ["a", "c", "q", "r", "delta", "p0"] {
        assert!(
            replay.iter().any(|w| w.starts_with(&format!("{name}="))),
            "{name}: {replay:?}"
        );
    }
    // The replay runs and its log shows p above a² t = a² (p̄ + δ/c²).
    let mut words = replay[1..].to_vec();
    words.extend(["--csv".into(), "replay.csv".into()]);
    let run = hybsim(dir.path(), &words);
    assert_eq!(
        run.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let value = |key: &str| -> f64 {
        let w = replay
            .iter()
            .find_map(|w| w.strip_prefix(&format!("{key}=")))
            .unwrap();
        w.parse().unwrap()
    };
    let (a, c, q, r, delta) = (
        value("a"),
        value("c"),
        value("q"),
        value("r"),
        value("delta"),
    );
    // p̄ = DARE(a', c', q, r), the steady-state prediction variance, as the
    // model's `param pbar` states it, from the library's Riccati solver.
    let scalar = |v: f64| nalgebra::DMatrix::from_element(1, 1, v);
    let pbar = hybsim::design::control::dare(&scalar(a), &scalar(c), &scalar(q), &scalar(r))
        .unwrap()[(0, 0)];
    let bound = a * a * (pbar + delta / (c * c));
    let csv = std::fs::read_to_string(dir.path().join("replay.csv")).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = header.iter().position(|h| *h == "p").unwrap();
    let max_p = lines
        .map(|l| l.split(',').nth(col).unwrap().parse::<f64>().unwrap())
        .fold(f64::NEG_INFINITY, f64::max);
    assert!(max_p > bound, "max p {max_p} <= a² t = {bound}\n{text}");
}
