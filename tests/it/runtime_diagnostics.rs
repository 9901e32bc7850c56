//! Run-time failures of `.hyb` models point into the source: the flow
//! equation of the fastest-changing state when the integrator gives up, the
//! jump whose map produced a non-finite value.

use hybsim::engine::{SimError, simulate_arc};
use hybsim::lang;
use hybsim::source::SourceFile;

use crate::util::{code, hybsim, stderr};

/// `y' = y²` from 1 blows up at t = 1; `x` is a slow clock declared first.
const BLOW: &str = "model blow
state x = 0, y = 1
flow {
    x' = 1
    y' = y^2
}
sim { T = 2 }
";

/// The reset of `y` takes the log of 0 at the first jump (t = 1).
const NAN_JUMP: &str = "model nanjump
state x = 1, y = 1
flow { x' = -1; y' = 0 }
jump reset when x <= 0 {
    x+ = 1
    y+ = log(x)
}
sim { T = 3 }
";

fn fail(name: &str, text: &str) -> (SimError, hybsim::diagnostics::Diagnostic, SourceFile) {
    let src = SourceFile::new(name, text);
    let m = lang::compile(&src, &[]).expect("compiles");
    let (x0, mut rng) = m.start(m.seed());
    let err = simulate_arc(&m, &x0, &m.settings(), &mut rng).expect_err("the run fails");
    let d = m.runtime_diagnostic(&err);
    (err, d, src)
}

#[test]
fn a_step_size_collapse_names_the_flow_equation_of_the_fastest_state() {
    let (err, d, src) = fail("blow.hyb", BLOW);
    let SimError::StepSizeCollapse {
        at,
        component,
        ref name,
        ..
    } = err
    else {
        panic!("expected a step-size collapse, got {err:?}")
    };
    assert_eq!((component, name.as_str()), (1, "y"));
    assert!((at.t - 1.0).abs() < 1e-3 && at.j == 0, "{at}");
    assert_eq!(d.code, "E0601");
    assert!(
        d.message.contains("fastest-changing state: `y`"),
        "{}",
        d.message
    );
    let lc = d.line_col(&src).unwrap();
    assert_eq!((lc.line, lc.col), (5, 5), "at `y' = y^2`");
    assert!(
        d.labels[0].message.contains("(t, j) = (1"),
        "{:?}",
        d.labels
    );
}

#[test]
fn a_non_finite_reset_names_the_jump() {
    let (err, d, src) = fail("nanjump.hyb", NAN_JUMP);
    let SimError::NonFinite {
        at,
        component,
        rule,
        ..
    } = err
    else {
        panic!("expected a non-finite state, got {err:?}")
    };
    assert_eq!((component, rule, at.j), (1, Some(0), 1));
    assert_eq!(d.code, "E0602");
    let lc = d.line_col(&src).unwrap();
    assert_eq!(lc.line, 4, "at the jump `reset`");
    assert!(
        d.labels[0]
            .message
            .contains("this jump made `y` non-finite"),
        "{:?}",
        d.labels
    );
}

#[test]
fn the_cli_prints_file_line_and_caret() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("blow.hyb"), BLOW).unwrap();
    let out = hybsim(dir.path(), &["run", "blow.hyb", "--no-mcap", "-q"]);
    assert_eq!(code(&out), 1);
    let err = stderr(&out);
    assert!(
        err.contains("error[E0601]: the step size collapsed at (t = 1")
            && err.contains("blow.hyb:5:5")
            && err.contains("y' = y^2")
            && err.contains("`y` changes fastest here"),
        "{err}"
    );
}
