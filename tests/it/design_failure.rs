//! A failed `design` block gives one error naming the block, not a cascade
//! of errors in everything computed from its results.

use hybsim::diagnostics::render;
use hybsim::lang;
use hybsim::source::SourceFile;

use crate::util::{code, hybsim, stderr};

/// `observer` is infeasible (P ⪰ 0 and P ⪯ −I); everything after it uses
/// its results, directly or through other parameters, a second design, a
/// check, a state's initial value, flows, jumps and outputs.
const CASCADE: &str = "model cascade
param A = [0, 1; -1, 0]
design observer {
    sym P[2]
    P >= 0
    P + eye(2) <= 0
    param L = inv(P) * [1; 1]
    for k in 1..2 {
        param K[k] = k * P
    }
}
param Ahat = (eye(2) - L * [1, 0]) * A
param K2 = K[2] + eye(2)
design second {
    sym Q[2]
    Q >= Ahat + Ahat'
    param Qd = Q
}
check cert {
    sym R[2]
    R >= K2
}
state x = Ahat * [1; 0]
state z = 1
flow { x' = Ahat * x + Qd * x; z' = K2[1, 1] }
jump j when x[1] >= L[1] { x+ = K[1] * x }
output y = Qd * x
sim { T = 1 }
";

#[test]
fn a_failed_design_is_one_error_listing_what_was_not_evaluated() {
    let src = SourceFile::new("cascade.hyb", CASCADE);
    let d = lang::check_only(&src, &[]);
    let shown = render(&d, &src, false);
    assert_eq!(d.len(), 1, "{shown}");
    assert_eq!(d[0].code, "E0705", "{shown}");
    assert!(d[0].message.contains("design `observer` is infeasible"));
    assert_eq!(d[0].line_col(&src).unwrap().line, 3, "at the block's name");
    assert_eq!(
        d[0].notes,
        vec![
            "not evaluated because design `observer` failed: `L`, `K[1]`, `K[2]`, `Ahat`, \
             `K2`, design `second`, `Qd`, check `cert`, state `x`"
                .to_string()
        ],
        "{shown}"
    );
    assert!(d[0].help.is_some());
    // `hybsim design` (which also solves the check) says the same.
    let Err(d2) = lang::design_only(&src, &[]) else {
        panic!("the design must fail")
    };
    assert_eq!(d2, d);
}

#[test]
fn errors_unrelated_to_the_failed_design_are_still_reported() {
    // A real shape error in a parameter that does not use the design, and
    // a real error in one that does (an unknown name next to `L`): both
    // are reported; the uses of `L` themselves are not.
    let text = CASCADE.replace(
        "param K2 = K[2] + eye(2)",
        "param K2 = K[2] + eye(2)\nparam bad = [1, 2] + [1; 2]\nparam worse = L + nope",
    );
    let src = SourceFile::new("cascade.hyb", &text);
    let d = lang::check_only(&src, &[]);
    let shown = render(&d, &src, false);
    let codes: Vec<&str> = d.iter().map(|d| d.code).collect();
    assert_eq!(codes, ["E0705", "E0301", "E0201"], "{shown}");
    assert!(d[2].message.contains("`nope`"), "{shown}");
}

#[test]
fn a_feasible_design_is_unaffected() {
    // Same model with the infeasible constraint relaxed: compiles and runs.
    let text = CASCADE.replace("P + eye(2) <= 0", "P <= eye(2)");
    let src = SourceFile::new("cascade.hyb", &text);
    let m = lang::compile(&src, &[]).unwrap_or_else(|d| panic!("{}", render(&d, &src, false)));
    assert!(m.parameter("Ahat").is_some());
}

#[test]
fn the_cli_prints_the_one_error() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("cascade.hyb"), CASCADE).unwrap();
    for cmd in ["run", "design", "check"] {
        let out = hybsim(dir.path(), &[cmd, "cascade.hyb"]);
        assert_eq!(code(&out), 2, "{cmd}");
        let err = stderr(&out);
        assert_eq!(err.matches("error[").count(), 1, "{cmd}: {err}");
        assert!(
            err.contains("error[E0705]: design `observer` is infeasible")
                && err.contains("not evaluated because design `observer` failed")
                && err.contains("cascade.hyb:3:8"),
            "{cmd}: {err}"
        );
    }
}
