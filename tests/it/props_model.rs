//! Property tests of `.hyb` models (issue 9): random initial values as
//! inputs, the initial draws' own stream, and cases that replay exactly as
//! `hybsim run` would run them.

use hybsim::arc::HybridArc;
use hybsim::engine::simulate_arc;
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
