//! Property tests (issue 9) on Rust-defined systems: properties that hold
//! pass over many sampled cases; false ones are found, shrunk, and their
//! replay reproduces the failure exactly.

use hybsim::arc::{ArcSink, HybridArc, Termination};
use hybsim::engine::models::{BouncingBall, SampleAndHold};
use hybsim::engine::{SimError, SimRng, SimSettings, simulate};
use hybsim::props::{
    Case, Dist, Input, Outcome, Property, PropertySink, Scope, Subject, SystemSubject, TestConfig,
    Verdict, run_case, run_tests, strategy,
};
use nalgebra::DMatrix;
use proptest::prelude::*;

use crate::util::{G, LAMBDA};

fn ball(h: Dist, v: Dist, horizon: f64) -> SystemSubject<BouncingBall> {
    ball_with(h, v, SimSettings::default().horizon_t(horizon))
}

fn ball_with(h: Dist, v: Dist, settings: SimSettings) -> SystemSubject<BouncingBall> {
    SystemSubject::new(BouncingBall::new(G, LAMBDA), settings, vec![h, v]).expect("valid subject")
}

fn energy(x: &[f64]) -> f64 {
    0.5 * x[1] * x[1] + G * x[0]
}

#[test]
fn ball_properties_that_hold_pass_over_many_cases() {
    let subject = ball(
        Dist::Uniform { lo: 0.0, hi: 2.0 },
        Dist::Uniform { lo: -3.0, hi: 3.0 },
        5.0,
    );
    let props = [
        Property::always("above ground", |_, x| x[0] >= -1e-9),
        Property::nonincreasing("energy at jumps", Scope::Jumps, 0.0, |_, x| energy(x)),
        // Free fall is a polynomial flow: Dopri5 keeps the energy to rounding.
        Property::nonincreasing("energy during flows", Scope::Flows, 1e-9, |_, x| energy(x)),
        Property::at_jumps("impacts reverse v", |j| j.post[1] >= 0.0 && j.pre[1] <= 0.0),
    ];
    let report = run_tests(&subject, &props, &TestConfig::default().cases(300).seed(3));
    assert!(report.passed(), "{:?}", report.outcome);
    assert_eq!(report.cases_run, 300);
    assert_eq!(report.inconclusive, 0);
}

#[test]
fn ball_never_above_1_5_is_refuted_and_shrinks_to_1_5() {
    let subject = ball(Dist::Uniform { lo: 0.0, hi: 2.0 }, Dist::Fixed(0.0), 5.0);
    let props = [Property::always("never above 1.5", |_, x| x[0] <= 1.5)];
    let report = run_tests(&subject, &props, &TestConfig::default().cases(100).seed(11));
    let Outcome::Failed(cx) = report.outcome else {
        panic!("expected a counterexample, got {:?}", report.outcome)
    };
    assert!(cx.original.values[0] > 1.5);
    let h0 = cx.case.values[0];
    assert!(h0 > 1.5 && h0 - 1.5 <= 1e-11, "shrunk to h0 = {h0}");
    // … and to a short decimal, for a readable replay command.
    assert!(format!("{h0}").len() <= 16, "h0 = {h0}");
    // A drop from rest fails at its initial point, so no jump is needed.
    assert_eq!((cx.violation.at.t, cx.violation.at.j), (0.0, 0));
    assert_eq!(cx.case.horizon_j, Some(0));
    let text = cx.describe(subject.inputs(), &subject.state_names());
    assert!(
        text.contains("never above 1.5") && text.contains(&format!("--set h={h0}")),
        "{text}"
    );
    // Replaying the shrunk case gives the same violation.
    let again = run_case(&subject, &props, &cx.case).unwrap();
    assert_eq!(again.violation(), Some(&cx.violation));
}

#[test]
fn a_failure_after_jumps_shrinks_to_a_locally_minimal_case() {
    // Thrown up or down from [0, 2] with |v0| ≤ 8: some cases rise above 1.5
    // only after an impact.
    // Properties see samples only: a grid of dt_out = 0.01 makes the sampled
    // height a continuous function of the inputs.
    let subject = ball_with(
        Dist::Uniform { lo: 0.0, hi: 2.0 },
        Dist::Uniform { lo: -8.0, hi: 8.0 },
        SimSettings::default().horizon_t(4.0).dt_out(Some(0.01)),
    );
    let props = [Property::always("never above 1.5", |_, x| x[0] <= 1.5)];
    let report = run_tests(&subject, &props, &TestConfig::default().cases(64).seed(5));
    let Outcome::Failed(cx) = report.outcome else {
        panic!("expected a counterexample, got {:?}", report.outcome)
    };
    let fails = |case: &Case| {
        run_case(&subject, &props, case)
            .unwrap()
            .violation()
            .is_some()
    };
    assert!(fails(&cx.case));
    // Each input is as close to 0 as failing allows: nudging it 1e-9 (relative) toward 0 passes
    // (or it is 0 already).
    for k in 0..2 {
        let v = cx.case.values[k];
        if v != 0.0 {
            let mut nudged = cx.case.clone();
            nudged.values[k] = v - 1e-9 * v.abs().max(1.0) * v.signum();
            assert!(!fails(&nudged), "input {k} = {v} could shrink further");
        }
    }
    // The horizon was cut to the failure (a failure during the flow after
    // jump j needs the horizon J = j + 1).
    let j = cx.violation.at.j;
    assert!(cx.case.horizon_j == Some(j) || cx.case.horizon_j == Some(j + 1));
    assert!(cx.case.horizon_t.is_none_or(|t| t >= cx.violation.at.t));
    // The failing sample is just above 1.5.
    let h = cx.violation.state[0];
    assert!(h > 1.5 && h < 1.5 + 1e-6, "h = {h} at {}", cx.violation.at);
}

/// A sampled-data loop with its plant state drawn from a box; the held
/// input starts consistent (`u(0) = -K x(0)`), so this subject is written
/// by hand, as a user would for a parameterized system.
struct SampledLoop {
    sys: SampleAndHold,
    inputs: Vec<Input>,
    settings: SimSettings,
}

impl SampledLoop {
    fn new() -> Self {
        // Double integrator, K = [1, 1.7], ts = 0.2: a stable sampled loop.
        let a = DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0]);
        let b = DMatrix::from_row_slice(2, 1, &[0.0, 1.0]);
        let k = DMatrix::from_row_slice(1, 2, &[1.0, 1.7]);
        Self {
            sys: SampleAndHold::new(a, b, k, 0.2),
            inputs: vec![
                Input::new("x1", Dist::Uniform { lo: -1.0, hi: 1.0 }),
                Input::new("x2", Dist::Uniform { lo: -1.0, hi: 1.0 }),
            ],
            settings: SimSettings::default().horizon_t(10.0).dt_out(Some(0.01)),
        }
    }
}

impl Subject for SampledLoop {
    type Error = SimError;
    fn inputs(&self) -> &[Input] {
        &self.inputs
    }
    fn state_names(&self) -> Vec<String> {
        use hybsim::engine::HybridSystem;
        self.sys.state_names()
    }
    fn settings(&self) -> &SimSettings {
        &self.settings
    }
    fn run(&self, case: &Case, sink: &mut dyn ArcSink) -> Result<Termination, SimError> {
        let x0 = self.sys.initial_state(&case.values);
        let mut rng = SimRng::seed_from(case.seed);
        simulate(&self.sys, &x0, &case.apply(&self.settings), &mut rng, sink)
    }
}

#[test]
fn a_wrong_lyapunov_candidate_for_sample_and_hold_is_refuted_and_replays_exactly() {
    let subject = SampledLoop::new();
    // |x|² is not a Lyapunov function of this loop: along flows
    // d/dt |x|² = 2 x1 x2 + 2 x2 u changes sign.
    let wrong = [Property::decreasing(
        "|x|^2 decreases",
        Scope::Flows,
        1e-12,
        |_, x| x[0] * x[0] + x[1] * x[1],
    )];
    let report = run_tests(&subject, &wrong, &TestConfig::default().cases(50).seed(1));
    let Outcome::Failed(cx) = report.outcome else {
        panic!("expected a counterexample, got {:?}", report.outcome)
    };
    // Shrinking moved the inputs toward 0.
    for k in 0..2 {
        assert!(cx.case.values[k].abs() <= cx.original.values[k].abs());
    }
    // Replay: simulating the shrunk case into an arc reproduces the
    // violation bit for bit, and the arc holds the failing state there.
    let mut arc = HybridArc::new(4, vec!["sample".into()]);
    let mut sink = PropertySink::forwarding(&wrong, &mut arc);
    subject.run(&cx.case, &mut sink).unwrap();
    let replayed = sink.violation().cloned().expect("the replay fails too");
    assert_eq!(replayed, cx.violation);
    assert_eq!(arc.value_at(replayed.at).unwrap(), replayed.state);

    // The sampled loop is nevertheless exponentially stable: its plant
    // state obeys |x| ≤ κ e^{−α (t + j)} |x(0,0)| with the rate of the
    // discretized loop (spectral radius ≈ 0.84 per period of t + j = 1.2).
    let exp = [Property::exponential_bound(
        "exponential decay",
        3.0,
        0.1,
        1e-12,
        |_, x| x[0].hypot(x[1]),
    )];
    let report = run_tests(&subject, &exp, &TestConfig::default().cases(100).seed(2));
    assert!(report.passed(), "{:?}", report.outcome);
}

#[test]
fn eventually_properties_are_inconclusive_when_the_horizon_is_short() {
    let subject = ball(Dist::Uniform { lo: 0.5, hi: 1.0 }, Dist::Fixed(0.0), 0.1);
    let props = [Property::eventually_within("hits ground", 1.0, |_, x| {
        x[0] <= 1e-9
    })];
    let report = run_tests(&subject, &props, &TestConfig::default().cases(20));
    assert!(report.passed());
    assert_eq!(report.inconclusive, 20);
    let long = ball(Dist::Uniform { lo: 0.5, hi: 1.0 }, Dist::Fixed(0.0), 3.0);
    let report = run_tests(&long, &props, &TestConfig::default().cases(20));
    assert!(report.passed());
    assert_eq!(report.inconclusive, 0);
    // Dropped from up to 6 m the ball needs up to 1.1 s to land: refuted.
    let high = ball(Dist::Uniform { lo: 0.5, hi: 6.0 }, Dist::Fixed(0.0), 3.0);
    let report = run_tests(&high, &props, &TestConfig::default().cases(50));
    let Outcome::Failed(cx) = report.outcome else {
        panic!("expected a counterexample, got {:?}", report.outcome)
    };
    // Landing at t = 1 needs h0 = g/2; shrinking toward the range's centre
    // stops just above it.
    assert!((cx.case.values[0] - G / 2.0).abs() < 1e-6, "{:?}", cx.case);
    assert!(matches!(
        run_case(&high, &props, &cx.case).unwrap(),
        Verdict::Fails(_)
    ));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]
    /// The proptest helper: a user's own `cargo test` over a Rust system.
    #[test]
    fn proptest_helper_checks_the_ball(case in strategy::cases(&ball(
        Dist::Uniform { lo: 0.0, hi: 2.0 }, Dist::Normal { mean: 0.0, std: 1.0 }, 3.0)))
    {
        let subject = ball(Dist::Uniform { lo: 0.0, hi: 2.0 }, Dist::Normal { mean: 0.0, std: 1.0 }, 3.0);
        prop_assert!((0.0..=2.0).contains(&case.values[0]));
        prop_assert!(case.values[1].abs() <= 4.0);
        strategy::check(&subject, &[Property::always("above ground", |_, x| x[0] >= -1e-9)], &case)?;
    }
}

#[test]
fn the_proptest_helper_reports_a_false_property() {
    let subject = ball(Dist::Uniform { lo: 1.6, hi: 2.0 }, Dist::Fixed(0.0), 1.0);
    let props = [Property::always("never above 1.5", |_, x| x[0] <= 1.5)];
    let mut runner = proptest::test_runner::TestRunner::deterministic();
    let result = runner.run(&strategy::cases(&subject), |case| {
        strategy::check(&subject, &props, &case)
    });
    let err = result.unwrap_err().to_string();
    assert!(err.contains("never above 1.5"), "{err}");
}

#[test]
fn the_counterexample_does_not_depend_on_the_number_of_threads() {
    let subject = ball(
        Dist::Uniform { lo: 0.0, hi: 2.0 },
        Dist::Uniform { lo: -8.0, hi: 8.0 },
        4.0,
    );
    let props = [Property::always("never above 1.5", |_, x| x[0] <= 1.5)];
    let config = TestConfig::default().cases(64).seed(9);
    let with = |threads| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        match pool
            .install(|| run_tests(&subject, &props, &config))
            .outcome
        {
            Outcome::Failed(cx) => cx,
            other => panic!("expected a counterexample, got {other:?}"),
        }
    };
    assert_eq!(with(1), with(3));
}

/// A uniform input over a range wider than the largest float
/// (`uniform(-1e308, 1e308)`): proptest's float range over it drew ±inf,
/// a case that could not run; both halves of the range are searched.
#[test]
fn strategy_values_over_the_widest_uniform_range_are_finite() {
    use proptest::strategy::ValueTree;
    let strategy = strategy::value(Dist::Uniform {
        lo: -1e308,
        hi: 1.5e308,
    });
    let mut runner = proptest::test_runner::TestRunner::deterministic();
    let values: Vec<f64> = (0..400)
        .map(|_| strategy.new_tree(&mut runner).unwrap().current())
        .collect();
    assert!(
        values.iter().all(|v| (-1e308..=1.5e308).contains(v)),
        "{values:?}"
    );
    let below = values.iter().filter(|v| **v < 0.0).count();
    // 40 % of the range is below 0.
    assert!((110..=210).contains(&below), "{below} of 400 below 0");
}
