//! Run-time failures of `.hyb` models point into the source: the flow
//! equation of the fastest-changing state when the step size collapses (of
//! the state the stiff mode moves most when the flow turns stiff:
//! `stiff::the_stiffness_error_names_the_component_of_the_stiff_mode`), the
//! jump whose map produced a non-finite value.

use hybsim::engine::SimError;

use crate::util::simulate_arc;
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

/// The hybrid time in a run-time label is written as in the message (`Num`:
/// `1e-150`), not as 150 digits (`0.000…01`), whatever the error:
/// `y' = y²` from 1e150 blows up at t = 1e-150.
#[test]
fn a_run_time_label_writes_a_tiny_time_compactly() {
    let (err, d, src) = fail("tiny.hyb", &BLOW.replace("y = 1\n", "y = 1e150\n"));
    let at = match err {
        SimError::StepSizeCollapse { at, .. } | SimError::NonFinite { at, .. } => at,
        e => panic!("expected a collapse or a non-finite state, got {e:?}"),
    };
    assert!(at.t > 0.0 && at.t < 1e-149, "{at}");
    let label = &d.labels[0].message;
    assert!(
        label.contains("(t, j) = (") && label.contains("e-15"),
        "{label}"
    );
    let text = hybsim::diagnostics::render(&[d], &src, false);
    assert!(!text.contains("0.0000000000"), "{text}");
}

/// A reset that computes NaN is reported at its assignment (the rule's head a secondary
/// label), at the hybrid time of the jump attempted: (1, 0), where the run ends, as the
/// summary says (the post-jump point (1, 1) is not part of the solution).
#[test]
fn a_non_finite_reset_names_its_assignment_and_the_jump() {
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
    assert_eq!((component, rule, at.t, at.j), (1, Some(0), 1.0, 0));
    assert_eq!(d.code, "E0602");
    assert_eq!(
        d.message,
        "state `y` became -inf in the jump at (t = 1, j = 0)"
    );
    let lc = d.line_col(&src).unwrap();
    assert_eq!((lc.line, lc.col), (6, 5), "at `y+ = log(x)`");
    let text = hybsim::diagnostics::render(&[d], &src, false);
    for want in [
        "6 │     y+ = log(x)\n  │     ^^^^^^^^^^^ this assignment made `y` non-finite in the jump at (t, j) = (1, 0)",
        "4 │ jump reset when x <= 0 {\n  │ ---------------------- in this jump\n",
    ] {
        assert!(text.contains(want), "missing {want:?} in\n{text}");
    }
    // The summary line ends the run where the message says the jump failed.
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("nanjump.hyb"), NAN_JUMP).unwrap();
    let out = hybsim(dir.path(), &["run", "nanjump.hyb", "--no-mcap", "--json"]);
    assert_eq!(code(&out), 1);
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(summary["end"], serde_json::json!({"t": 1.0, "j": 0}));
    assert!(
        (summary["message"].as_str().unwrap()).contains("in the jump at (t = 1, j = 0)"),
        "{summary}"
    );
}

/// The reset of a member of a family inside `for`: the assignment of that member.
#[test]
fn a_non_finite_reset_in_a_loop_names_its_assignment() {
    let text = "model loop
state x = 1
for i in 1..3 { state y[i] = 1 }
flow { x' = -1 }
jump reset when x <= 0 {
    x+ = 1
    for i in 1..3 { y[i]+ = log(abs(i - 2) + x) }
}
sim { T = 3 }
";
    let (err, d, src) = fail("loop.hyb", text);
    assert!(
        matches!(err, SimError::NonFinite { rule: Some(0), .. }),
        "{err:?}"
    );
    let lc = d.line_col(&src).unwrap();
    assert_eq!((lc.line, lc.col), (7, 21), "at `y[i]+ = log(…)`");
    assert!(
        d.labels[0].message.contains("made `y[2]` non-finite"),
        "{:?}",
        d.labels
    );
}

/// The flow of `z` is NaN past t = 1.2 (`sqrt` of a negative number); `x` and `y` are
/// declared first, `y` the fastest.
const NAN_FLOW: &str = "model nanflow
state x = 0, y = 1, z = 0
flow {
    x' = 1
    y' = -50 * y
    z' = sqrt(1.2 - t) + 0 * x
}
sim { T = 3 }
";

/// A flow that turns NaN is that error, at the flow equation that produced it, whatever the
/// adaptive solver: the steps shrank to nothing in front of the NaN and the run was reported
/// as a step-size collapse blamed on the fastest state (`y`, another line).
#[test]
fn a_flow_that_turns_nan_names_its_equation_on_every_adaptive_solver() {
    for solver in ["dopri5", "radau5", "bdf", "auto"] {
        let text = NAN_FLOW.replace("T = 3", &format!("T = 3; solver = {solver}"));
        let (err, d, src) = fail("nanflow.hyb", &text);
        let SimError::NonFinite {
            at,
            component,
            rule,
            value,
            ..
        } = err
        else {
            panic!("{solver}: expected a non-finite flow, got {err:?}")
        };
        assert_eq!((component, rule, at.j), (2, None, 0), "{solver}");
        assert!(value.is_nan(), "{solver}: {value}");
        assert!((at.t - 1.2).abs() < 1e-6, "{solver}: {at}");
        assert_eq!(d.code, "E0602", "{solver}");
        let lc = d.line_col(&src).unwrap();
        assert_eq!(lc.line, 6, "{solver}: at `z' = …`");
    }
}

/// A relay, `x' = -sign(x)` from 1: x = 1 − t reaches 0 at t = 1, where the
/// solution slides (x = 0, a Filippov solution the flow map does not give).
/// The explicit solvers accepted steps of about `atol` across x = 0 for ever
/// (Dopri5 1.4·10⁷ steps per unit of t, Dop853 1.2·10⁸: `T = 10` took 80 s
/// and a sliding-mode controller's `T = 100` a quarter of an hour); now
/// they stop just past t = 1 with the chatter error at the relay's
/// equation, also under `auto` (not handed to Radau5 as a stiff flow, where
/// the steps collapse). `c` is a clock declared first.
const RELAY: &str = "model relay
state c = 0, x = 1
flow {
    c' = 1
    x' = -sign(x)
}
sim { T = 3 }
";

#[test]
fn a_relay_that_chatters_stops_at_its_switching_surface() {
    for solver in ["dopri5", "dop853", "auto"] {
        let text = RELAY.replace("T = 3", &format!("T = 3; solver = {solver}"));
        let (err, d, src) = fail("relay.hyb", &text);
        let SimError::Chatter {
            at,
            component,
            ref name,
            h,
        } = err
        else {
            panic!("{solver}: expected the chatter error, got {err:?}")
        };
        assert_eq!((component, name.as_str(), at.j), (1, "x", 0), "{solver}");
        // 10 000 steps of at most 1e-7 past the switch.
        assert!(at.t > 1.0 && at.t < 1.01, "{solver}: {at}");
        assert!(h > 0.0 && h < 1e-6, "{solver}: {h}");
        assert_eq!(d.code, "E0601", "{solver}");
        assert!(
            d.message.starts_with("the flow chatters at (t = 1.0")
                && d.message.contains("the rate of `x` changed sign"),
            "{solver}: {}",
            d.message
        );
        let lc = d.line_col(&src).unwrap();
        assert_eq!((lc.line, lc.col), (5, 5), "{solver}: at `x' = -sign(x)`");
        assert!(
            d.help.as_deref().unwrap_or("").contains("hysteresis"),
            "{d:?}"
        );
    }
    // Smooth flows whose rates turn around often do not chatter: 40
    // oscillators of distinct phases and frequencies at tight tolerances,
    // and a rate near 0 that changes sign fast (below any tolerance).
    let mut text = String::from("model many\nstate z = 0\n");
    for k in 1..=40 {
        text += &format!("state p{k} = {}, q{k} = 0\n", 1.0 + k as f64 / 40.0);
        text += &format!(
            "flow {{ p{k}' = q{k}; q{k}' = -{w}*p{k} }}\n",
            w = 1.0 + k as f64
        );
    }
    text += "flow { z' = 1e-300*sin(1e3*t) }\nsim { T = 20; rtol = 1e-10; atol = 1e-12 }\n";
    let m = crate::util::compile(&text);
    let (x0, mut rng) = m.start(m.seed());
    let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng).expect("a smooth flow runs");
    assert_eq!(arc.last().unwrap().at.t, 20.0);
}

/// A relay in a 2-D loop, `x' = y - sign(x); y' = -x` from (1, 0): x
/// reaches 0 at t = π/4 with y = −(√2 − 1), where the solution slides
/// (x' is +0.59 below the surface and −1.41 above, so the steps cross it
/// every second to fourth step, which the chatter test does not count).
/// Dopri5's stiffness test fired there and the run ended as "stiff"; under
/// `auto` that handed the flow to Radau5 and back, and the run crawled at
/// steps of 1e-8 (`T = 10`: half an hour). The Jacobian there, [[0, 1],
/// [-1, 0]], cannot make a step of 1e-8 stiff: both stop at once with the
/// discontinuity, at the relay's equation.
#[test]
fn a_sliding_mode_that_looks_stiff_stops_as_a_discontinuous_flow() {
    let text =
        "model relay2\nstate x = 1, y = 0\nflow { x' = y - sign(x); y' = -x }\nsim { T = 10 }\n";
    for solver in ["dopri5", "auto"] {
        let text = text.replace("T = 10", &format!("T = 10; solver = {solver}"));
        let (err, d, src) = fail("relay2.hyb", &text);
        let SimError::Discontinuous {
            at,
            component,
            ref name,
            h,
        } = err
        else {
            panic!("{solver}: expected the discontinuity, got {err:?}")
        };
        assert_eq!((component, name.as_str(), at.j), (0, "x", 0), "{solver}");
        let quarter = std::f64::consts::FRAC_PI_4;
        assert!(at.t > quarter && at.t < quarter + 1e-4, "{solver}: {at}");
        assert!(h > 0.0 && h < 1e-6, "{solver}: {h}");
        assert_eq!(d.code, "E0601", "{solver}");
        let lc = d.line_col(&src).unwrap();
        assert_eq!((lc.line, lc.col), (3, 8), "{solver}: at `x' = y - sign(x)`");
        assert!(
            d.help.as_deref().unwrap_or("").contains("hysteresis"),
            "{d:?}"
        );
    }
}

/// Relays whose two sides have different speeds: x' = −1 above the
/// surface and +2 below (the solution slides at x = 0 from t = 1), and
/// x' = −sign(x) + sin(t)/2 (at x = 0 from t ≈ 1.4297). Dopri5 keeps x just
/// above 0 with stages across the surface (the end rates never change
/// sign, the state moves against them), Dop853 crosses it every few steps:
/// the chatter test missed both and the runs crawled at steps of 1e-8 (20
/// s per 0.2 of t) to the horizon. Rates that turn around every few steps where the
/// flow's Jacobian is small (h·‖J‖ < 1/20) now stop the run too; a smooth
/// fast oscillation whose rates turn around every few steps (x, y at 100
/// rad/s, z' forced at 300 rad/s, loose tolerances) runs to its end, as
/// its Jacobian explains the turns (it stopped as "chattering" at rtol
/// 1e-2 and 1e-3).
#[test]
fn lopsided_relays_stop_where_they_slide_and_fast_smooth_flows_run() {
    for (flow, slide) in [
        ("x' = if x > 0 then -1 else 2", 1.0),
        ("x' = -sign(x) + 0.5*sin(t)", 1.42967),
    ] {
        let text = format!("model lopsided\nstate x = 1\nflow {{ {flow} }}\nsim {{ T = 5 }}\n");
        for solver in ["dopri5", "dop853", "auto"] {
            let text = text.replace("T = 5", &format!("T = 5; solver = {solver}"));
            let (err, d, _) = fail("lopsided.hyb", &text);
            let SimError::Chatter { at, ref name, .. } = err else {
                panic!("{flow}, {solver}: expected the chatter error, got {err:?}")
            };
            assert_eq!(name, "x");
            // Dopri5 within 10⁴ steps of the slide's start; Dop853's
            // steps cross the surface less regularly on the second (its
            // windows restart for a while).
            assert!(at.t > slide && at.t < slide + 0.5, "{flow}, {solver}: {at}");
            assert_eq!(d.code, "E0601");
        }
    }
    for rtol in ["1e-1", "1e-2", "1e-3", "1e-6"] {
        let text = format!(
            "model osc\nstate x = 1, y = 0, z = 0\n\
             flow {{ x' = 100*y; y' = -100*x; z' = 1e-3*sin(300*t) }}\n\
             sim {{ T = 200; rtol = {rtol}; atol = 1e-9 }}\n"
        );
        for solver in ["dopri5", "dop853"] {
            let m =
                crate::util::compile(&text.replace("atol", &format!("solver = {solver}; atol")));
            let (x0, mut rng) = m.start(m.seed());
            let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng)
                .unwrap_or_else(|e| panic!("rtol {rtol}, {solver}: {e}"));
            assert_eq!(arc.last().unwrap().at.t, 200.0);
        }
    }
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

/// A ball whose floor is a flow set `h >= 0` with no jump: it lands at
/// t = 1 (from h = 4.905 with g = 9.81) and can neither flow nor jump.
const NO_BOUNCE: &str = "model nobounce
param g = 9.81
state h = 4.905, v = 0
flow { h' = v; v' = -g } in h >= 0 && v <= 100
sim { T = 3 }
";

#[test]
fn cannot_flow_or_jump_names_the_case_the_failing_atom_and_the_state() {
    // Leaving C: the flow points out of `h >= 0` at t = 1.
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("nb.hyb"), NO_BOUNCE).unwrap();
    let o = hybsim(dir.path(), &["run", "nb.hyb", "--no-mcap"]);
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    let err = stderr(&o);
    for want in [
        "warning[W0603]",
        "the flow leaves the flow set C there",
        "nb.hyb:4:",
        "`h >= 0` fails",
        "the state there: h = ",
        "v = -9.8",
    ] {
        assert!(err.contains(want), "missing {want:?} in\n{err}");
    }
    assert!(!err.contains("`v <= 100` fails"), "{err}");
    // The summary line (and so `--json`'s message and a sweep's runs.csv)
    // names the failing atom as written, not by its index.
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        out.contains("(failing: `h >= 0` with g = -"),
        "summary names the atom:\n{out}"
    );
    assert!(!out.contains("atom 0 of C"), "{out}");
    // Outside C from the start: the atom that fails and its value.
    let src = SourceFile::new(
        "out.hyb",
        "model outside\nstate x = -2, y = 1\nflow { x' = 1; y' = 0 } in y > 0 && x + y >= 0\n",
    );
    let m = lang::compile(&src, &[]).expect("compiles");
    let (x0, mut rng) = m.start(m.seed());
    let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng).expect("runs");
    let d = m
        .termination_diagnostic(arc.termination().unwrap())
        .expect("a diagnostic for a stuck solution");
    let text = hybsim::diagnostics::render(&[d], &src, false);
    for want in [
        "the state is outside the flow set C",
        "`x + y >= 0` fails (-1e0)",
        "out.hyb:3:",
        "x = -2, y = 1",
    ] {
        assert!(text.contains(want), "missing {want:?} in\n{text}");
    }
    assert!(!text.contains("`y > 0` fails"), "{text}");
}

/// A rotation on the unit circle with C the closed unit disk: the exact
/// solution runs along C's boundary, the integrator's (rtol 1e-6) drifts out
/// past `set_tol` (at t ≈ 0.17). W0603 says so, and what to change; a ball
/// landing across its floor (`NO_BOUNCE`) gets no such note.
#[test]
fn leaving_c_along_its_boundary_suggests_the_tolerances() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("circle.hyb"),
        "model circle\nstate x = 1, y = 0\nflow { x' = -y; y' = x } in x^2 + y^2 <= 1\n\
         sim { T = 10 }\n",
    )
    .unwrap();
    let o = hybsim(dir.path(), &["run", "circle.hyb", "--no-mcap"]);
    let err = stderr(&o);
    for want in [
        "warning[W0603]",
        "`x^2 + y^2 <= 1` fails",
        "C fails by just over `set_tol` = 1e-9",
        "tighten `rtol` and `atol` or raise `set_tol`",
    ] {
        assert!(err.contains(want), "missing {want:?} in\n{err}");
    }
    // As the note says: tighter tolerances keep the solution in C.
    let o = hybsim(
        dir.path(),
        &[
            "run",
            "circle.hyb",
            "--no-mcap",
            "--set",
            "rtol=1e-12",
            "--set",
            "atol=1e-12",
        ],
    );
    assert!(!stderr(&o).contains("W0603"), "{}", stderr(&o));
    std::fs::write(dir.path().join("nb.hyb"), NO_BOUNCE).unwrap();
    let o = hybsim(dir.path(), &["run", "nb.hyb", "--no-mcap"]);
    assert!(
        stderr(&o).contains("W0603") && !stderr(&o).contains("set_tol"),
        "{}",
        stderr(&o)
    );
}

/// A jump that lands on the boundary of a time-dependent C (`x+ = sin(w*t)`
/// in `x >= sin(w*t)`, a rounding outside it) where the flow points out:
/// the relaxed atom fails by `set_tol` 3.8e-10 after the jump, with x not
/// moved. W0603's note said the integrator's error had carried a flow
/// tangent to C out; it says that the flow points out of C where it started.
#[test]
fn leaving_c_where_a_jump_landed_on_its_boundary_is_not_blamed_on_the_integrator() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("edge.hyb"),
        "model edge\nparam w = 3\nstate x = 0.5, k = 0\nflow { x' = 0 } in x >= sin(w*t)\n\
         jump land when x <= sin(w*t) && k < 1 { x+ = sin(w*t); k+ = 1 }\nsim { T = 10 }\n",
    )
    .unwrap();
    let o = hybsim(dir.path(), &["run", "edge.hyb", "--no-mcap"]);
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    let err = stderr(&o);
    for want in [
        "warning[W0603]",
        "`x >= sin(3*t)` fails",
        "C fails by just over `set_tol` = 1e-9",
        // The jump's time, π/18.
        "where this flow started, within `set_tol` of C's boundary, at t = 0.174532925199",
        "the flow points out of C there",
        "check the jump map or initial value",
    ] {
        assert!(err.contains(want), "missing {want:?} in\n{err}");
    }
    assert!(!err.contains("integrator's error"), "{err}");
}

/// A model of `design` blocks alone checks (for `hybsim design`); run, it
/// has no state, and the error points at its name.
#[test]
fn a_model_without_states_run_points_at_its_name() {
    let text = "model designs_only\ndesign d {\n    scalar t\n    maximize t\n    t <= 1\n}\n";
    let (err, d, src) = fail("d.hyb", text);
    assert!(matches!(err, SimError::InvalidSystem { .. }), "{err:?}");
    let lc = d.line_col(&src).unwrap();
    assert_eq!((lc.line, lc.col), (1, 7), "at the model's name");
}
