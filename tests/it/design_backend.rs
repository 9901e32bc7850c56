//! Choosing the interior-point method of `design` blocks: `--sdp
//! auto|clarabel|schur` on `hybsim design|run|test`, `lang::CheckOptions`
//! in the library. Both methods must give the same design.

use hybsim::diagnostics::render;
use hybsim::lang::{self, Backend, CheckOptions};
use hybsim::source::SourceFile;
use serde_json::Value;

use crate::util::{code, hybsim, stderr};

/// A decay-rate Lyapunov design with a block constraint and a bound, so
/// that both the objective and the constraints are active.
const DECAY: &str = "model decay
param A = [-1, 2, 0; 0, -3, 1; 0.5, 0, -2]
design lyapunov {
    sym P[3]
    scalar g
    minimize trace(P) + g
    decay: A' * P + P * A + 0.5 * P + eye(3) <= 0
    bound: [P, eye(3); *, g * eye(3)] >= 0
    P >= 0.1 * eye(3)
    param Pd = P, gd = g
}
state x = [1; 0; 0]
flow { x' = A * x }
output V = x' * Pd * x
sim { T = 1 }
";

fn solve(backend: Backend) -> (f64, Backend, nalgebra::DMatrix<f64>) {
    let src = SourceFile::new("decay.hyb", DECAY);
    let options = CheckOptions {
        backend,
        ..CheckOptions::default()
    };
    let m = lang::compile_with(&src, &[], &options)
        .unwrap_or_else(|d| panic!("{}", render(&d, &src, false)));
    let s = m.design_reports()[0].solve.clone().expect("solved");
    (s.objective, s.backend, m.parameter("Pd").unwrap())
}

#[test]
fn every_backend_gives_the_same_design_and_the_report_names_it() {
    let (obj_c, ran_c, p_c) = solve(Backend::Clarabel);
    let (obj_s, ran_s, p_s) = solve(Backend::Schur);
    let (obj_a, ran_a, _) = solve(Backend::Auto);
    assert_eq!(ran_c, Backend::Clarabel);
    assert_eq!(ran_s, Backend::Schur);
    assert_eq!(
        ran_a,
        Backend::Clarabel,
        "auto: clarabel for a small problem"
    );
    assert!((obj_c - obj_s).abs() < 1e-6, "{obj_c} vs {obj_s}");
    assert!((obj_c - obj_a).abs() < 1e-9, "{obj_c} vs {obj_a}");
    assert!((&p_c - &p_s).amax() < 1e-5, "{p_c} vs {p_s}");
    // The bound is active: g = λmax(P⁻¹) > 0.
    assert!(obj_c > p_c.trace() + 1e-3);
}

#[test]
fn design_and_run_take_sdp() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("decay.hyb"), DECAY).unwrap();
    let mut objectives = Vec::new();
    for sdp in ["clarabel", "schur"] {
        let out = hybsim(dir.path(), &["design", "decay.hyb", "--sdp", sdp]);
        assert_eq!(code(&out), 0, "{}", stderr(&out));
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(
            text.contains(&format!("iterations ({sdp})")),
            "the report names the method: {text}"
        );
        let out = hybsim(dir.path(), &["design", "decay.hyb", "--sdp", sdp, "--json"]);
        assert_eq!(code(&out), 0, "{}", stderr(&out));
        let json: Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(json["lyapunov"]["backend"], sdp);
        objectives.push(json["lyapunov"]["objective"].as_f64().unwrap());
    }
    assert!(
        (objectives[0] - objectives[1]).abs() < 1e-6,
        "{objectives:?}"
    );
    let out = hybsim(
        dir.path(),
        &["run", "decay.hyb", "--sdp", "schur", "--no-mcap", "-q"],
    );
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    assert!(
        stderr(&out).contains("iterations (schur)"),
        "{}",
        stderr(&out)
    );
    // Default: auto, which takes clarabel for this size.
    let out = hybsim(dir.path(), &["design", "decay.hyb"]);
    assert!(String::from_utf8_lossy(&out.stdout).contains("iterations (clarabel)"));
    let out = hybsim(dir.path(), &["design", "decay.hyb", "--sdp", "mosek"]);
    assert_eq!(code(&out), 2);
    assert!(stderr(&out).contains("possible values: auto, clarabel, schur"));
}
