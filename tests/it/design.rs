//! `design` blocks (issue 5) through the real pipeline: parse → check →
//! lower onto `design::lmi` → solve → results as parameters.

use hybsim::arc::HybridTime;
use hybsim::design::control::lyap;
use hybsim::diagnostics::Diagnostic;
use hybsim::lang::{self, CompiledModel, Override};
use hybsim::source::SourceFile;
use nalgebra::{DMatrix, dmatrix};

fn compile(text: &str, overrides: &[&str]) -> Result<CompiledModel, (Vec<Diagnostic>, SourceFile)> {
    let src = SourceFile::new("d.hyb", text);
    let ov: Vec<Override> = overrides.iter().map(|s| s.parse().unwrap()).collect();
    lang::compile(&src, &ov).map_err(|d| (d, src))
}

fn ok(text: &str, overrides: &[&str]) -> CompiledModel {
    match compile(text, overrides) {
        Ok(m) => m,
        Err((d, src)) => panic!("{}", hybsim::diagnostics::render(&d, &src, false)),
    }
}

/// The single error of a model: (code, "line:col", message).
fn error(text: &str) -> (String, String, String) {
    let Err((d, src)) = compile(text, &[]) else {
        panic!("expected an error")
    };
    assert_eq!(
        d.len(),
        1,
        "{}",
        hybsim::diagnostics::render(&d, &src, false)
    );
    let lc = d[0].line_col(&src).expect("located");
    (
        d[0].code.to_string(),
        format!("{}:{}", lc.line, lc.col),
        d[0].message.clone(),
    )
}

/// A parameter of the compiled model (after overrides and `design` blocks).
fn param(m: &CompiledModel, name: &str) -> DMatrix<f64> {
    m.parameter(name)
        .unwrap_or_else(|| panic!("the model has no parameter `{name}`"))
}

const LYAP: &str = "model lyap_design
param A = [-1, 2; 0, -3]
design lyapunov {
    sym P[2]
    minimize trace(P)
    decay: A' * P + P * A + eye(2) <= 0
    param Pd = P, trP = trace(P)
}
param twice = 2 * Pd
state x = [1; 0]
flow { x' = A * x }
output V = x' * Pd * x
sim { T = 1 }
";

#[test]
fn lyapunov_lmi_matches_the_lyapunov_equation() {
    let m = ok(LYAP, &[]);
    // min tr P s.t. AᵀP + PA + I ⪯ 0 is attained at AᵀP + PA + I = 0: P = lyap(Aᵀ, I).
    let a = dmatrix![-1.0, 2.0; 0.0, -3.0];
    let want = lyap(&a.transpose(), &DMatrix::identity(2, 2)).unwrap();
    let p = param(&m, "Pd");
    assert!((&p - &want).amax() < 1e-6, "P = {p}, lyap = {want}");
    assert!((param(&m, "trP")[(0, 0)] - want.trace()).abs() < 1e-6);
    // Results are parameters like any other: later params and outputs use them.
    assert!((param(&m, "twice") - &p * 2.0).amax() < 1e-15);
    let mut out = [0.0];
    m.outputs(HybridTime::new(0.0, 0), &[1.0, 0.0], &mut out);
    assert!((out[0] - p[(0, 0)]).abs() < 1e-15);
    // The report: solved, constraints verified.
    let reports = m.design_reports();
    assert_eq!(reports.len(), 1);
    let r = &reports[0];
    assert_eq!(r.name, "lyapunov");
    let s = r.solve.as_ref().unwrap();
    assert!((s.objective - want.trace()).abs() < 1e-6);
    assert!(s.worst_margin > -1e-6, "{}", s.worst_margin);
    assert_eq!(s.variables, 3);
    assert_eq!(r.results.len(), 2);
    let json = m.design_json().unwrap();
    assert_eq!(json["lyapunov"]["name"], "lyapunov");
    assert!(json["lyapunov"]["results"]["Pd"].is_array());
    // The design variable itself is local to the block.
    let (code, at, _) = error(&LYAP.replace("2 * Pd", "2 * P"));
    assert_eq!((code.as_str(), at.as_str()), ("E0201", "9:19"));
}

#[test]
fn set_replaces_a_design_result_and_skips_a_fully_given_block() {
    let m = ok(LYAP, &["Pd=[1, 0; 0, 1]"]);
    assert_eq!(param(&m, "Pd"), DMatrix::identity(2, 2));
    assert_eq!(param(&m, "twice"), DMatrix::identity(2, 2) * 2.0);
    // trP is still computed, so the block was solved.
    assert!(m.design_reports()[0].solve.is_some());
    let m = ok(LYAP, &["Pd=[1, 0; 0, 1]", "trP=0"]);
    assert!(m.design_reports()[0].solve.is_none(), "nothing to solve");
    assert!(m.design_reports()[0].summary_line().contains("not solved"));
}

/// A block whose results are all given is not even assembled: its LMIs
/// (here 2^20 of them, beyond the limit of `subsets`) are never built, and
/// what they would report does not stop the model.
#[test]
fn a_fully_given_block_is_not_assembled() {
    let text = "model m
param M = 20
design huge {
    sym P[1]
    for S in subsets(1..M) {
        stable: P >= 1
    }
    param K = P
}
state x = 0
flow { x' = -K * x }
";
    let (code, _, message) = error(text);
    assert_eq!(code, "E0304", "{message}");
    let m = ok(text, &["K=2"]);
    assert_eq!(param(&m, "K")[(0, 0)], 2.0);
    assert!(m.design_reports()[0].solve.is_none());
}

#[test]
fn infeasible_and_unbounded_designs_are_errors_naming_the_block() {
    let infeasible = "model m
param A = [1, 0; 0, 2]
design unstable {
    sym P[2]
    P >= eye(2)
    A' * P * A - P <= -eye(2)
}
";
    let (code, at, msg) = error(infeasible);
    assert_eq!(code, "E0705");
    assert_eq!(at, "3:8", "at the block's name");
    assert!(msg.contains("design `unstable` is infeasible"), "{msg}");
    let unbounded = "model m
design up {
    scalar g
    maximize g
    g >= 1
}
";
    let (code, _, msg) = error(unbounded);
    assert_eq!(code, "E0705");
    assert!(msg.contains("design `up` is unbounded"), "{msg}");
}

#[test]
fn malformed_design_blocks_are_located() {
    // A product of two decision variables.
    let (code, at, _) = error("model m\ndesign d {\n    sym P[2]\n    P * P > 0\n}\n");
    assert_eq!((code.as_str(), at.as_str()), ("E0701", "4:5"));
    // A non-affine function of a variable.
    let (code, at, _) = error("model m\ndesign d {\n    sym P[2]\n    inv(P) > 0\n}\n");
    assert_eq!((code.as_str(), at.as_str()), ("E0701", "4:5"));
    // A non-symmetric matrix in an inequality.
    let (code, at, _) =
        error("model m\ndesign d {\n    sym P[2]\n    [P, eye(2); zeros(2, 2), P] > 0\n}\n");
    assert_eq!((code.as_str(), at.as_str()), ("E0702", "4:5"));
    // Shape mismatch.
    let (code, at, _) = error("model m\ndesign d {\n    sym P[2]\n    P + eye(3) > 0\n}\n");
    assert_eq!((code.as_str(), at.as_str()), ("E0301", "4:5"));
    // A non-square matrix inequality.
    let (code, at, _) = error("model m\ndesign d {\n    full U[2, 3]\n    U >= 0\n}\n");
    assert_eq!((code.as_str(), at.as_str()), ("E0703", "4:5"));
    // A matrix objective.
    let (code, at, _) = error("model m\ndesign d {\n    sym P[2]\n    minimize P\n    P > 0\n}\n");
    assert_eq!((code.as_str(), at.as_str()), ("E0704", "4:14"));
    // `*` whose mirror is `*` too.
    let (code, at, _) = error("model m\ndesign d {\n    sym P[2]\n    [P, *; *, P] > 0\n}\n");
    assert_eq!((code.as_str(), at.as_str()), ("E0304", "4:5"));
    // A variable named like a parameter.
    let (code, at, _) = error("model m\nparam P = 1\ndesign d {\n    sym P[2]\n}\n");
    assert_eq!((code.as_str(), at.as_str()), ("E0202", "4:9"));
    // A syntax error inside a design block.
    let (code, at, _) = error("model m\ndesign d {\n    sym P[2]\n    P >\n}\n");
    assert_eq!((code.as_str(), at.as_str()), ("E0101", "5:1"));
}

#[test]
fn loops_over_subsets_give_one_constraint_per_subset() {
    // Cor. V.2 of Muehlebach–Trimpe for App. F: with L = I, every switched
    // closed loop (I − Σ_{m∈S} L_m C_m)(A + BF) has P = I as a common
    // Lyapunov matrix; the feasibility problem over P (normalized by P >= I)
    // has one LMI per subset S ⊆ {1, 2}.
    let text = "model appf
param A = [0.5, 0; 0, 2]
param B = [0, 1; 1, 0]
param C = eye(2)
param F = [0, -2; 0.1, 0]
param L = eye(2)
param N = 2
design corV2 {
    sym P[2]
    P >= eye(2)
    for S in subsets(1..N) {
        switched: [P, P * (eye(2) - sum(m in S: L[:, m] * C[m, :])) * (A + B * F); *, P] > 0
    }
    param Pc = P
}
";
    let m = ok(text, &[]);
    let s = m.design_reports()[0].solve.clone().unwrap();
    assert_eq!(s.constraints, 1 + 4, "P >= I and 2^2 subsets");
    let r = &m.design_reports()[0];
    assert_eq!(r.results[0].0, "Pc");
    // Three agents: 2^3 = 8.
    let m = ok(
        &text
            .replace("param N = 2", "param N = 2\nparam N3 = 3")
            .replace("subsets(1..N)", "subsets(1..N3 - 1)"),
        &[],
    );
    assert_eq!(m.design_reports()[0].solve.as_ref().unwrap().constraints, 5);
    // A third agent that measures nothing (L₃C₃ = 0): 2^3 subsets.
    let three = text
        .replace("param N = 2", "param N = 3")
        .replace("param C = eye(2)", "param C = [eye(2); zeros(1, 2)]")
        .replace("param L = eye(2)", "param L = [eye(2), zeros(2, 1)]");
    let m = ok(&three, &[]);
    assert_eq!(
        m.design_reports()[0].solve.as_ref().unwrap().constraints,
        1 + 8
    );
    // And loops over indices.
    let m = ok(
        &text
            .replace("for S in subsets(1..N) {", "for k in 1..3 {")
            .replace("sum(m in S: L[:, m] * C[m, :])", "k / 4 * L * C"),
        &[],
    );
    assert_eq!(
        m.design_reports()[0].solve.as_ref().unwrap().constraints,
        1 + 3
    );
}

#[test]
fn cli_design_prints_reports_and_run_records_them() {
    use std::process::Command;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lyap.hyb");
    std::fs::write(&path, LYAP).unwrap();
    let bin = env!("CARGO_BIN_EXE_hybsim");
    let out = Command::new(bin)
        .args(["design", path.to_str().unwrap()])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("design lyapunov: solved"), "{stdout}");
    assert!(stdout.contains("worst margin"), "{stdout}");
    assert!(stdout.contains("Pd = ["), "{stdout}");
    // `--set` on a result: the block is still solved for `trP`, Pd is the given value.
    let out = Command::new(bin)
        .args([
            "design",
            path.to_str().unwrap(),
            "--set",
            "Pd=eye(2)",
            "--json",
        ])
        .output()
        .unwrap();
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["lyapunov"]["results"]["Pd"][0][0], 1.0);
    // An infeasible design: exit 2, located at the block.
    let bad = dir.path().join("bad.hyb");
    std::fs::write(
        &bad,
        "model m\ndesign nope {\n    scalar g\n    g >= 1\n    g <= 0\n}\n",
    )
    .unwrap();
    let out = Command::new(bin)
        .args(["design", bad.to_str().unwrap()])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("bad.hyb:2:8") && err.contains("`nope` is infeasible"),
        "{err}"
    );
    // `hybsim run` prints the report and stores the results in the MCAP metadata, byte-identically.
    let run = || {
        let out = Command::new(bin)
            .args(["run", path.to_str().unwrap(), "-o", "l.mcap"])
            .current_dir(dir.path())
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(0));
        assert!(String::from_utf8_lossy(&out.stderr).contains("design lyapunov: solved"));
        std::fs::read(dir.path().join("l.mcap")).unwrap()
    };
    let first = run();
    assert!(first == run(), "same command, different bytes");
    let summary = mcap::read::Summary::read(&first).unwrap().unwrap();
    let design = summary
        .metadata_indexes
        .iter()
        .map(|i| mcap::read::metadata(&first, i).unwrap())
        .find(|m| m.name == "hybsim.design")
        .expect("hybsim.design metadata");
    let block: serde_json::Value = serde_json::from_str(&design.metadata["lyapunov"]).unwrap();
    assert_eq!(block["status"], "Solved");
    assert!((block["results"]["trP"].as_f64().unwrap() - 0.8333333).abs() < 1e-6);
}

/// Two agents with their own Lyapunov matrices P[k] (a variable family),
/// coupled through one constraint on both; results per agent (a parameter
/// family declared inside the block's loop).
const FAMILY: &str = "model fam
param N = 2
param A[1] = [-1, 2; 0, -3]
param A[2] = [-2, 0; 1, -1]
design lyap {
    for k in 1..N { sym P[k][2] }
    scalar g
    minimize g
    for k in 1..N {
        lyap: A[k]'*P[k] + P[k]*A[k] + eye(2) == 0
        P[k][1, 1] <= g
    }
    sum(k in 1..N: P[k]) >= 0
    for k in 1..N { param X[k] = P[k] }
    param gmax = g
}
state x = 0
flow { x' = -x }
output y = X[2][1, 1]
";

#[test]
fn variable_families_are_declared_per_member_and_give_result_families() {
    let m = ok(FAMILY, &[]);
    for (k, a) in [
        (1, dmatrix![-1.0, 2.0; 0.0, -3.0]),
        (2, dmatrix![-2.0, 0.0; 1.0, -1.0]),
    ] {
        let want = lyap(&a.transpose(), &DMatrix::identity(2, 2)).unwrap();
        let got = param(&m, &format!("X[{k}]"));
        assert!((&got - &want).norm() < 1e-6, "X[{k}] = {got}, want {want}");
    }
    let g = param(&m, "gmax")[(0, 0)];
    let x11 = param(&m, "X[1]")[(0, 0)].max(param(&m, "X[2]")[(0, 0)]);
    assert!((g - x11).abs() < 1e-6);
    let labels: Vec<String> = m.design_reports()[0]
        .results
        .iter()
        .map(|r| r.0.clone())
        .collect();
    assert_eq!(labels, ["X[1]", "X[2]", "gmax"]);
    // Errors: a member outside the family, the family without an index, a
    // member declared twice.
    let bad = FAMILY.replace("P[k][1, 1] <= g", "P[k + 1][1, 1] <= g");
    let Err((d, src)) = compile(&bad, &[]) else {
        panic!("expected an error")
    };
    assert_eq!(
        d[0].code,
        "E0402",
        "{}",
        hybsim::diagnostics::render(&d, &src, false)
    );
    assert!(d[0].message.contains("P"), "{}", d[0].message);
    let (code, at, _) = error(&FAMILY.replace("sum(k in 1..N: P[k]) >= 0", "P >= 0"));
    assert_eq!((code.as_str(), at.as_str()), ("E0403", "13:5"));
    let Err((d, _)) = compile(&FAMILY.replace("{ sym P[k][2] }", "{ sym P[1][2] }"), &[]) else {
        panic!("expected an error")
    };
    assert_eq!(d[0].code, "E0202", "{}", d[0].message);
    assert!(d[0].message.contains("`P[1]`"), "{}", d[0].message);
}
