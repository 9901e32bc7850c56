//! `check NAME { … }` blocks: design problems without results whose verdict
//! is reported — solved by `hybsim design` (exit 1 when there is no
//! solution), left unsolved by `hybsim run`, which still works.

use crate::util::hybsim;

const MODEL: &str = "model checks
param A = [-1, 2; 0, -3]
param B = [1, 0; 0, 2]          # unstable: no Lyapunov matrix exists
check stable_a {
    sym P[2]
    P >= eye(2)
    A' * P + P * A <= -eye(2)
}
check stable_b {
    sym P[2]
    P >= eye(2)
    B' * P + P * B <= -eye(2)
}
state x = [1; 1]
flow { x' = A * x }
sim { T = 1 }
";

#[test]
fn checks_are_reported_by_design_and_skipped_by_run() {
    let dir = tempfile::tempdir().unwrap();
    let m = dir.path().join("checks.hyb");
    std::fs::write(&m, MODEL).unwrap();
    let out = hybsim(dir.path(), &["design", m.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("check stable_a: feasible (solved)"), "{text}");
    assert!(
        text.contains("check stable_b: infeasible (solver status"),
        "{text}"
    );
    assert_eq!(
        out.status.code(),
        Some(1),
        "a check without solution: exit 1"
    );
    // JSON carries the verdicts too.
    let out = hybsim(dir.path(), &["design", m.to_str().unwrap(), "--json"]);
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["stable_b"]["status"], "infeasible");
    assert_eq!(json["stable_a"]["status"], "Solved");
    // Without the unstable check: exit 0.
    let ok = dir.path().join("ok.hyb");
    let text = MODEL.replace("B' * P + P * B", "A' * P + P * A");
    std::fs::write(&ok, text).unwrap();
    assert_eq!(
        hybsim(dir.path(), &["design", ok.to_str().unwrap()])
            .status
            .code(),
        Some(0)
    );
    // `hybsim run` needs neither check and runs.
    let run = hybsim(dir.path(), &["run", m.to_str().unwrap(), "--no-mcap", "-q"]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(0), "{err}");
    assert!(err.contains("check stable_b: not solved here"), "{err}");
}

#[test]
fn a_check_has_no_results() {
    let dir = tempfile::tempdir().unwrap();
    let m = dir.path().join("bad.hyb");
    std::fs::write(
        &m,
        "model bad\ncheck c {\n    scalar g\n    g >= 1\n    param G = g\n}\n",
    )
    .unwrap();
    let out = hybsim(dir.path(), &["check", m.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("in a `check` block (use `design`)"), "{err}");
}
