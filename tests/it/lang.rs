//! The `.hyb` front end through the real pipeline: parse → check → compile →
//! simulate with the engine.

use crate::util::simulate_arc;
use hybsim::arc::{HybridArc, HybridTime};
use hybsim::engine::HybridSystem;
use hybsim::lang::{self, CompiledModel, Override};
use hybsim::source::SourceFile;

fn model_path(name: &str) -> String {
    format!("{}/models/{name}", env!("CARGO_MANIFEST_DIR"))
}

pub fn load(name: &str, overrides: &[&str]) -> CompiledModel {
    let src = SourceFile::read(model_path(name)).expect("model file");
    let ov: Vec<Override> = overrides.iter().map(|s| s.parse().unwrap()).collect();
    match lang::compile(&src, &ov) {
        Ok(m) => m,
        Err(d) => panic!("{}", hybsim::diagnostics::render(&d, &src, false)),
    }
}

pub fn run(m: &CompiledModel) -> HybridArc {
    let (x0, mut rng) = m.start(m.seed());
    simulate_arc(m, &x0, &m.settings(), &mut rng).expect("simulation")
}

#[test]
fn bouncing_ball_impacts_match_the_closed_form() {
    let m = load("bouncing_ball.hyb", &[]);
    assert_eq!(m.state_names(), vec!["h", "v"]);
    // The flow is affine (ḣ = v, v̇ = −g): the engine advances it exactly.
    assert!(matches!(
        m.flow_structure(),
        hybsim::engine::FlowStructure::Affine { .. }
    ));
    let arc = run(&m);
    let (g, lambda, h0) = (9.81_f64, 0.8_f64, 1.0_f64);
    let mut t = (2.0 * h0 / g).sqrt();
    let mut v = (2.0 * g * h0).sqrt();
    let jumps = arc.jumps();
    assert_eq!(jumps.len(), 6, "impacts before T = 3");
    for (k, jr) in jumps.iter().enumerate() {
        assert!((jr.at.t - t).abs() < 1e-9, "impact {k}: {} vs {t}", jr.at.t);
        assert!(
            (jr.pre[1] + v).abs() < 1e-9,
            "impact {k}: v {} vs {}",
            jr.pre[1],
            -v
        );
        assert!((jr.post[1] - lambda * v).abs() < 1e-9);
        t += 2.0 * lambda * v / g;
        v *= lambda;
    }
    // Outputs: energy at the start.
    let mut out = [0.0];
    m.outputs(HybridTime::new(0.0, 0), &[1.0, 0.0], &mut out);
    assert!((out[0] - g).abs() < 1e-12);
}

#[test]
fn overrides_change_parameters_and_settings() {
    let m = load(
        "bouncing_ball.hyb",
        &["h0=2", "lambda=0.5", "T=1.5", "seed=7"],
    );
    assert_eq!(m.seed(), 7);
    assert_eq!(m.settings().horizon_t, 1.5);
    let arc = run(&m);
    let t1 = (2.0 * 2.0 / 9.81_f64).sqrt();
    assert!((arc.jumps()[0].at.t - t1).abs() < 1e-9);
    assert_eq!(m.parameters_json()["lambda"], serde_json::json!(0.5));
}

/// Seeds are whole numbers up to 2^64 − 1, exactly as written in `sim { seed }`, in a `sweep`
/// block and in `--set seed=…` (they went through an `f64`: 12345678901234567891 became
/// 12345678901234567168, the same run as its neighbours, and 2^64 − 1 was refused as 2^64).
#[test]
fn seeds_above_two_to_the_53_are_kept_exactly() {
    let compile = |sim: &str, overrides: &[&str]| {
        let text = format!(
            "model s\nparam k = 1\nstate x ~ uniform(0, k)\nflow {{ x' = 0 }}\nsim {{ T = 1; {sim} }}\nsweep {{ k in [1, 2]; {sim} }}\n"
        );
        let src = SourceFile::new("s.hyb", text);
        let ov: Vec<Override> = overrides.iter().map(|s| s.parse().unwrap()).collect();
        lang::compile(&src, &ov)
            .unwrap_or_else(|d| panic!("{}", hybsim::diagnostics::render(&d, &src, false)))
    };
    for n in [12_345_678_901_234_567_891_u64, u64::MAX, (1 << 53) + 1] {
        let m = compile(&format!("seed = {n}"), &[]);
        assert_eq!(m.seed(), n);
        assert_eq!(m.sweep().unwrap().seed, Some(n));
        assert_eq!(compile("seed = 1", &[&format!("seed={n}")]).seed(), n);
        // Neighbours that one f64 holds give different initial draws.
        let (a, _) = m.start(m.seed());
        let (b, _) = m.start(n - 1);
        assert_ne!(a, b, "seed {n}");
    }
    // A seed computed by an expression is still a number (exact below 2^53).
    assert_eq!(compile("seed = 2^40 + 1", &[]).seed(), (1 << 40) + 1);
}

/// A `--set` of a name the model declares sets that declaration only, not the `sim` key of
/// the same name: `param T` (a period), `state h` (a height), `param J` (an inertia) were also
/// taken as the horizon T, the fixed step h and the horizon J (`--set T=0.25` ended the run at
/// 0.25; `--set h=0` was refused as a step size). `sim.T` (and `horizon_t`) name the setting;
/// of several overrides of one setting, in any spelling, the last wins (`horizon_t` beside a
/// `sim { T = … }` was "declared twice").
#[test]
fn overrides_of_names_the_model_declares_leave_the_settings_of_that_name() {
    let text = "model clash\nparam T = 0.5, J = 2\nstate h = 1, n = 0\n\
                flow { h' = -1/J }\nevery T { n+ = n + 1 }\nsim { T = 10 }\n";
    let src = SourceFile::new("clash.hyb", text);
    let compile = |set: &[&str]| {
        let ov: Vec<Override> = set.iter().map(|s| s.parse().unwrap()).collect();
        lang::compile(&src, &ov)
            .unwrap_or_else(|d| panic!("{}", hybsim::diagnostics::render(&d, &src, false)))
    };
    let m = compile(&["T=0.25", "J=4", "h=0"]);
    let s = m.settings();
    assert_eq!(
        (s.horizon_t, s.horizon_j),
        (10.0, u64::MAX),
        "the settings kept"
    );
    assert_eq!(m.parameters_json()["T"], serde_json::json!(0.25));
    assert_eq!(m.parameters_json()["J"], serde_json::json!(4.0));
    let arc = run(&m);
    assert_eq!(arc.jumps().len(), 39, "every 0.25 up to t = 10");
    assert_eq!(arc.sample_at(0).unwrap().x[0], 0.0, "h(0) = 0");
    // The settings by their explicit names; the last of several spellings wins.
    let m = compile(&["sim.T=3", "T=0.25"]);
    assert_eq!(m.settings().horizon_t, 3.0);
    assert_eq!(run(&m).jumps().len(), 11);
    for set in [
        &["horizon_t=2"][..],
        &["sim.T=5", "horizon_t=2"],
        &["horizon_t=5", "sim.T=2"],
    ] {
        assert_eq!(compile(set).settings().horizon_t, 2.0, "{set:?}");
    }
    // A model without such a declaration: `T` is the setting, as before.
    let ball = load("bouncing_ball.hyb", &["T=1.5", "horizon_t=2"]);
    assert_eq!(ball.settings().horizon_t, 2.0);
    // An unknown `sim.` key is an unknown override.
    let ov: Vec<Override> = vec!["sim.TT=1".parse().unwrap()];
    let Err(d) = lang::compile(&src, &ov) else {
        panic!("`sim.TT` accepted")
    };
    assert!(d.iter().any(|d| d.message.contains("sim.TT")), "{d:?}");
}

#[test]
fn control_functions_compute_parameters() {
    let src = SourceFile::new(
        "c.hyb",
        "model c\nparam A = [0, 1; 0, 0], B = [0; 1]\nparam (Ad, Bd) = c2d(A, B, 0.1)\n\
         param K = dlqr(Ad, Bd, eye(2), 1)\nstate x = [1; 0]\nevery 0.1 { x+ = (Ad - Bd*K) * x }\n",
    );
    let m = lang::compile(&src, &[])
        .unwrap_or_else(|d| panic!("{}", hybsim::diagnostics::render(&d, &src, false)));
    let p = m.parameters_json();
    assert!((p["Ad"][0][1].as_f64().unwrap() - 0.1).abs() < 1e-12);
    assert!((p["Bd"][0].as_f64().unwrap() - 0.005).abs() < 1e-12);
    assert!(p["K"][0][0].as_f64().unwrap() > 0.0);
}

/// A chain of three integrators driven by a constant jerk (a flow whose
/// solution is a cubic in time) reset at `x ≥ 1`: every reset at
/// `k·6^(1/3)` to rounding, on the default settings.
#[test]
fn a_constant_jerk_reaches_its_guard_at_the_cubic_root() {
    let src = SourceFile::new(
        "jerk.hyb",
        "model jerk\nstate x = 0, v = 0, a = 0\nflow {\n    x' = v\n    v' = a\n    a' = 1\n}\n\
         jump reset when x >= 1 {\n    x+ = 0\n    v+ = 0\n    a+ = 0\n}\nsim { T = 10 }\n",
    );
    let m = lang::compile(&src, &[])
        .unwrap_or_else(|d| panic!("{}", hybsim::diagnostics::render(&d, &src, false)));
    let arc = run(&m);
    let period = 6f64.cbrt();
    assert_eq!(arc.jumps().len(), 5);
    for (k, jr) in arc.jumps().iter().enumerate() {
        let t = (k + 1) as f64 * period;
        assert!(
            (jr.at.t - t).abs() <= 16.0 * f64::EPSILON * t,
            "reset {k}: {} vs {t}",
            jr.at.t
        );
        assert!(
            (jr.pre[0] - 1.0).abs() <= 1e-14,
            "reset {k}: x = {}",
            jr.pre[0]
        );
    }
}

/// A `param` list mixes definitions and draws as a `state` list does:
/// `param g = 9.81, lam ~ uniform(0.5, 0.9), k = 2 * lam` is the three
/// declarations one by one (it was refused at `~` as MATLAB's `!`), in
/// the same order: the same draws for a seed, `k` computed from the draw.
#[test]
fn a_param_list_mixes_definitions_and_draws() {
    let body = "state h = 1, v = 0\nflow { h' = v; v' = -g } in h >= 0\n\
                jump impact when h <= 0 && v <= 0 { v+ = -lam * v }\nsim { T = 3 }\n";
    let listed = SourceFile::new(
        "listed.hyb",
        format!(
            "model b\nparam g = 9.81, lam ~ uniform(0.5, 0.9), mu ~ normal(1, 0.1), k = 2 * lam\n{body}"
        ),
    );
    let apart = SourceFile::new(
        "apart.hyb",
        format!(
            "model b\nparam g = 9.81\nparam lam ~ uniform(0.5, 0.9)\nparam mu ~ normal(1, 0.1)\n\
             param k = 2 * lam\n{body}"
        ),
    );
    for seed in [1, 2, 3] {
        let compiled = |src: &SourceFile| match lang::compile_run(src, &[], Some(seed)) {
            Ok((m, _)) => m,
            Err(d) => panic!("{}", hybsim::diagnostics::render(&d, src, false)),
        };
        let (a, b) = (compiled(&listed), compiled(&apart));
        let p = a.parameters_json();
        assert_eq!(p, b.parameters_json(), "seed {seed}");
        let lam = p["lam"].as_f64().unwrap();
        assert!(
            (0.5..=0.9).contains(&lam) && lam != 0.7,
            "seed {seed}: {lam}"
        );
        assert_eq!(p["k"].as_f64(), Some(2.0 * lam));
        assert_eq!(run(&a).jumps(), run(&b).jumps(), "seed {seed}");
    }
    // In a subsystem (refused at `~` before), each instance draws its own.
    let src = SourceFile::new(
        "s.hyb",
        "model s\nsubsystem Ball(g = 9.81) {\n  param lam ~ uniform(0.5, 0.9), k = 2 * lam\n\
         state h = 1\n  flow { h' = -k }\n}\nb1 = Ball()\nb2 = Ball()\n",
    );
    let (m, _) = lang::compile_run(&src, &[], Some(5)).unwrap();
    let p = m.parameters_json();
    let (l1, l2) = (p["b1.lam"].as_f64().unwrap(), p["b2.lam"].as_f64().unwrap());
    assert!(
        l1 != l2 && (0.5..=0.9).contains(&l1) && (0.5..=0.9).contains(&l2),
        "{p}"
    );
    assert_eq!(p["b2.k"].as_f64(), Some(2.0 * l2));
    // Draws stay where they were refused: in a design block's results.
    let src = SourceFile::new(
        "d.hyb",
        "model d\ndesign p {\n  scalar s\n  maximize s\n  s <= 1\n  param r = s, q ~ uniform(0, 1)\n}\n\
         state x = 1\n",
    );
    let d = lang::compile(&src, &[]).map(|_| ()).unwrap_err();
    let text = hybsim::diagnostics::render(&d, &src, false);
    assert!(
        text.contains("a random draw") && text.contains("d.hyb:6:"),
        "{text}"
    );
}
