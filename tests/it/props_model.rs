//! Property tests of `.hyb` models (issue 9): random initial values as
//! inputs, the initial draws' own stream, and cases that replay exactly as
//! `hybsim run` would run them.

use crate::util::simulate_arc;
use hybsim::arc::HybridArc;
use hybsim::lang::{self, CompiledModel, Override};
use hybsim::props::{
    Dist, ModelSubject, Outcome, Property, Subject, TestConfig, run_tests, sample_case,
};
use hybsim::source::SourceFile;

pub fn test_model(name: &str) -> String {
    format!("{}/tests/models/{name}", env!("CARGO_MANIFEST_DIR"))
}

fn compile(name: &str, overrides: &[String]) -> CompiledModel {
    let src = SourceFile::read(test_model(name)).expect("model file");
    let ov: Vec<Override> = overrides.iter().map(|s| s.parse().unwrap()).collect();
    lang::compile(&src, &ov)
        .unwrap_or_else(|d| panic!("{}", hybsim::diagnostics::render(&d, &src, false)))
}

/// What `hybsim run` does after compiling.
fn run(m: &CompiledModel, seed: u64) -> HybridArc {
    let (x0, mut rng) = m.start(seed);
    simulate_arc(m, &x0, &m.settings(), &mut rng).expect("simulation")
}

#[test]
fn random_initial_values_are_inputs_with_their_distribution() {
    let m = compile("random_ball.hyb", &[]);
    let inputs = m.random_inputs();
    assert_eq!(inputs.len(), 1);
    assert_eq!(inputs[0].name, "h");
    assert_eq!(inputs[0].dist, Dist::Uniform { lo: 0.0, hi: 2.0 });
    // Pinned by an override, it is no longer an input.
    assert!(
        compile("random_ball.hyb", &["h=1".into()])
            .random_inputs()
            .is_empty()
    );
    // An override may make a fixed initial value random (`hybsim test --set`).
    let m = compile("random_ball.hyb", &["v=normal(0, 0.5)".into()]);
    assert_eq!(m.random_inputs()[1].name, "v");
    assert_eq!(
        m.random_inputs()[1].dist,
        Dist::Normal {
            mean: 0.0,
            std: 0.5
        }
    );
}

#[test]
fn pinning_the_initial_value_leaves_the_runs_own_draws_unchanged() {
    let m = compile("random_ball.hyb", &[]);
    for seed in [0, 1, 17, 123_456] {
        let free = run(&m, seed);
        let h0 = free.sample_at(0).unwrap().x[0];
        let pinned = compile("random_ball.hyb", &[format!("h={h0}")]);
        let replay = run(&pinned, seed);
        // Random restitutions at every impact: identical arcs only if
        // pinning h consumed nothing from the run's stream.
        assert!(free.jumps().len() >= 3);
        assert_eq!(free, replay, "seed {seed}");
    }
}

#[test]
fn a_sampled_case_is_what_the_model_draws_with_its_seed() {
    let subject = ModelSubject::new(
        SourceFile::read(test_model("random_ball.hyb")).unwrap(),
        Vec::new(),
    )
    .unwrap();
    for index in 0..5 {
        let case = sample_case(subject.inputs(), 9, index);
        let (x0, _) = subject.model().start(case.seed);
        assert_eq!(x0[0], case.values[0]);
        // Through the subject (compiled with h pinned) = `hybsim run --seed S`.
        let mut arc = HybridArc::new(2, subject.model().rule_names());
        subject.run(&case, &mut arc).unwrap();
        assert_eq!(arc, run(subject.model(), case.seed));
    }
}

#[test]
fn a_false_height_bound_on_a_model_is_refuted_and_shrunk_to_1_5() {
    let subject = ModelSubject::new(
        SourceFile::read(test_model("random_ball.hyb")).unwrap(),
        Vec::new(),
    )
    .unwrap();
    let props = [Property::always("below 1.5", |_, x| x[0] <= 1.5)];
    let report = run_tests(&subject, &props, &TestConfig::default().cases(50).seed(2));
    let Outcome::Failed(cx) = report.outcome else {
        panic!("expected a counterexample, got {:?}", report.outcome)
    };
    let h0 = cx.case.values[0];
    assert!(h0 > 1.5 && h0 - 1.5 <= 1e-11, "shrunk to {h0}");
    assert_eq!((cx.violation.at.t, cx.violation.at.j), (0.0, 0));
}

/// Diagnostics of `hybsim check` for a ball model with `extra` appended:
/// (code, line:col of the primary label) of each.
fn property_errors(extra: &str) -> Vec<(String, String)> {
    let text = format!(
        "model b\nparam g = 9.81, alpha = 1, tol = 2\nstate h ~ uniform(0, 2), v = 0\n\
         flow {{ h' = v; v' = -g }} in h >= 0\njump impact when h <= 0 && v <= 0 {{ v+ = -0.8 * v }}\n{extra}\n"
    );
    let src = SourceFile::new("b.hyb", text);
    lang::check_only(&src, &[])
        .iter()
        .map(|d| {
            let lc = d.line_col(&src).map(|lc| format!("{}:{}", lc.line, lc.col));
            (d.code.to_string(), lc.unwrap_or_default())
        })
        .collect()
}

#[test]
fn property_declarations_are_checked_with_located_diagnostics() {
    // Valid: contextual words as parameter names, rule names, post(), t, j.
    assert_eq!(
        property_errors(
            "property a: always h >= -tol * alpha\nproperty b: at jumps impact post(v) >= 0\n\
             property c: exponential abs(v) kappa alpha alpha alpha tol tol\n\
             property d: eventually within 2 * alpha t >= 1 || j >= 1\n\
             property e: after h <= 1 always h <= 1 + tol"
        ),
        vec![]
    );
    let one = |s: &str| property_errors(s);
    assert_eq!(
        one("property p: always hh >= 0"),
        [("E0201".into(), "6:20".into())]
    );
    assert_eq!(
        one("property p: always h + 1"),
        [("E0304".into(), "6:20".into())]
    );
    assert_eq!(
        one("property p: always [h; v] >= 0"),
        [("E0304".into(), "6:20".into())]
    );
    assert_eq!(
        one("property p: decreasing [h; v] during flows"),
        [("E0304".into(), "6:24".into())]
    );
    assert_eq!(
        one("property p: always post(h) >= 0"),
        [("E0304".into(), "6:20".into())]
    );
    assert_eq!(
        one("property p: at jumps bounce post(v) >= 0"),
        [("E0201".into(), "6:22".into())]
    );
    assert_eq!(
        one("property p: eventually within h h >= 0"),
        [("E0305".into(), "6:31".into())]
    );
    assert_eq!(
        one("property p: nonincreasing h at jumps tol -1"),
        [("E0304".into(), "6:42".into())]
    );
    assert_eq!(
        one("property p: always h >= 0\nproperty p: always v >= 0"),
        [("E0202".into(), "7:10".into())]
    );
    assert_eq!(one("property p: sometimes h >= 0")[0].0, "E0101");
}

#[test]
fn declared_properties_compile_onto_props_properties() {
    let src = SourceFile::read(test_model("ball_props.hyb")).unwrap();
    let m = lang::compile(&src, &[]).unwrap();
    let props = m.properties();
    let names: Vec<&str> = props.iter().map(|p| p.name()).collect();
    assert_eq!(names[..3], ["ground", "flows_above", "energy_jumps"]);
    assert_eq!(
        props[3].text(),
        Some("at jumps post(energy) <= energy + 1e-9")
    );
    // One run from h = 1: every property but `below` holds.
    let (x0, mut rng) = compile("ball_props.hyb", &["h=1".into()]).start(0);
    let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng).unwrap();
    for p in &props {
        assert!(p.check(&arc).is_ok(), "{p}");
    }
    // From h = 1.6, `below` fails at the start, and `energy_post` with a
    // wrong sign fails at the first impact, whose (t, j) it reports.
    let wrong = SourceFile::new(
        "w.hyb",
        src.text()
            .replace("post(energy) <= energy + 1e-9", "post(energy) >= energy"),
    );
    let w = lang::compile(&wrong, &["h=1.6".parse().unwrap()]).unwrap();
    let (x0, mut rng) = w.start(0);
    let arc = simulate_arc(&w, &x0, &w.settings(), &mut rng).unwrap();
    let ps = w.properties();
    let below = ps.iter().find(|p| p.name() == "below").unwrap();
    assert_eq!(below.check(&arc).unwrap_err().at.t, 0.0);
    let post = ps.iter().find(|p| p.name() == "energy_post").unwrap();
    let v = post.check(&arc).unwrap_err();
    let t1 = (2.0 * 1.6 / 9.81_f64).sqrt();
    assert!((v.at.t - t1).abs() < 1e-9 && v.at.j == 0, "{v}");
}

fn shipped(name: &str, sets: &[&str]) -> ModelSubject {
    let path = format!("{}/models/{name}", env!("CARGO_MANIFEST_DIR"));
    let ov = sets.iter().map(|s| s.parse().unwrap()).collect();
    ModelSubject::new(SourceFile::read(path).unwrap(), ov).unwrap()
}

#[test]
fn the_shipped_models_properties_hold_over_many_cases() {
    for (name, sets, cases) in [
        ("thermostat.hyb", &["x=uniform(10, 28)"][..], 100),
        ("fireflies.hyb", &[][..], 100),
        ("sample_and_hold.hyb", &["N=2"][..], 10),
    ] {
        let s = shipped(name, sets);
        let props = s.model().properties();
        assert!(!props.is_empty(), "{name}");
        let report = run_tests(&s, &props, &TestConfig::default().cases(cases).seed(5));
        assert!(report.passed(), "{name}: {:?}", report.outcome);
        assert_eq!(report.inconclusive, 0, "{name}");
    }
    // The thermostat's sampled start is an input; fireflies' clocks (a
    // family) are drawn from each case's seed.
    assert_eq!(
        shipped("thermostat.hyb", &["x=uniform(10, 28)"])
            .inputs()
            .len(),
        1
    );
}

/// `at jumps RULE P` names the rules of subsystem instances as every output
/// names them: `ball.impact`, a member of an instance family `f.fire[2]`, or
/// as the language reads it, `f[2].fire` (these were parse errors: "`post(...)`
/// indexes in MATLAB").
#[test]
fn at_jumps_names_the_rules_of_subsystem_instances() {
    let text = "model flock
subsystem Clock(p = 0.1) {
    state tau = 0, n = 0
    flow { tau' = 1 }
    jump fire when tau >= p { tau+ = 0; n+ = n + 1 }
}
solo = Clock(p = 0.25)
for i in 1..2 { f[i] = Clock(p = 0.1 + 0.15 * i) }
property solo_resets: at jumps solo.fire post(solo.tau) == 0
property second: at jumps f.fire[2] post(f[2].n) == f[2].n + 1
property second_read: at jumps f[2].fire post(f.n[2]) == f.n[2] + 1
property wrong: at jumps f[2].fire post(f.n[1]) == f.n[1] + 1
sim { T = 1 }
";
    let m = lang::compile(&SourceFile::new("flock.hyb", text), &[])
        .unwrap_or_else(|d| panic!("{d:#?}"));
    let (x0, mut rng) = m.start(0);
    let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng).unwrap();
    let props = m.properties();
    let check = |name: &str| props.iter().find(|p| p.name() == name).unwrap().check(&arc);
    for name in ["solo_resets", "second", "second_read"] {
        assert!(check(name).is_ok(), "{name}");
    }
    // f[2] fires alone at t = 0.4 (f[1] at 0.25, 0.5): its own n moves, f[1]'s not.
    let v = check("wrong").unwrap_err();
    assert!((v.at.t - 0.4).abs() < 1e-9, "{v}");
    // A missing member is located, with the family's name as the model
    // writes it, as a state family's (E0402).
    let bad = text.replace(
        "at jumps f[2].fire post(f.n[1])",
        "at jumps f[3].fire post(f.n[1])",
    );
    let d = lang::check_only(&SourceFile::new("flock.hyb", &bad), &[]);
    assert_eq!(d.len(), 1, "{d:#?}");
    assert_eq!(d[0].code, "E0402");
    assert_eq!(d[0].message, "`f.fire` has no member [3]");
}
