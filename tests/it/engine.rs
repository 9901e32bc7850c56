//! Engine tests: analytic models through `engine::simulate`, with stated
//! tolerances.

use crate::util::simulate_arc;
use hybsim::arc::{HybridArc, SampleKind, TerminationCause, ZenoDetail};
use hybsim::engine::models::{BouncingBall, OverlapDemo, RandomTimers, SampleAndHold};
use hybsim::engine::{ExactAffine, HybridSystem, Priority, SimRng, SimSettings, Solver};
use nalgebra::DMatrix;

fn run<S: HybridSystem>(sys: &S, x0: &[f64], s: &SimSettings, seed: u64) -> HybridArc {
    simulate_arc(sys, x0, s, &mut SimRng::seed_from(seed)).expect("simulation runs")
}

/// The first 10 impacts' times and velocities against the closed form,
/// within `tol` (relative).
fn check_ball_impacts(ball: &BouncingBall, settings: &SimSettings, tol: f64) {
    let arc = run(ball, &[1.0, 0.0], settings, 0);
    let exact = ball.impacts(1.0, 10);
    assert!(
        arc.jumps().len() >= 10,
        "only {} impacts",
        arc.jumps().len()
    );
    for (k, (jump, (t, v))) in arc.jumps().iter().zip(&exact).enumerate() {
        let et = (jump.at.t - t).abs() / t;
        let ev = (jump.pre[1] - v).abs() / v.abs();
        assert!(
            et <= tol,
            "impact {k}: t = {} vs {t} (rel {et:e})",
            jump.at.t
        );
        assert!(
            ev <= tol,
            "impact {k}: v = {} vs {v} (rel {ev:e})",
            jump.pre[1]
        );
        assert_eq!(jump.at.j, k as u64);
    }
}

#[test]
fn bouncing_ball_matches_closed_form_impacts() {
    let ball = BouncingBall::new(9.81, 0.8);
    check_ball_impacts(&ball, &SimSettings::default(), 1e-9);
    // Dop853 integrates the parabola exactly and locates the impacts on
    // its degree-7 interpolant, which holds it exactly too: rounding only
    // (6e-14 in t, 3e-13 in v measured).
    for (rtol, atol) in [(1e-8, 1e-10), (1e-12, 1e-14)] {
        let dop853 = SimSettings::default().solver(Solver::Dop853 { rtol, atol });
        check_ball_impacts(&ball, &dop853, 1e-12);
    }
    check_ball_impacts(
        &ball,
        &SimSettings::default().solver(Solver::Rk4 { h: 0.01 }),
        1e-9,
    );
    let mut affine = ball.clone();
    affine.affine = true;
    check_ball_impacts(&affine, &SimSettings::default(), 1e-9);
}

/// An affine flow whose `A` is nilpotent (the ball: height quadratic in
/// time) runs on its own polynomial under `exact_affine` auto and on: the
/// impacts are the closed form's to rounding, far inside the solver's
/// tolerance, and the guard is decided on the exact path.
#[test]
fn polynomial_flows_are_exact_at_their_events() {
    let mut ball = BouncingBall::new(9.81, 0.8);
    ball.affine = true;
    for mode in [ExactAffine::Auto, ExactAffine::On] {
        let arc = run(
            &ball,
            &[1.0, 0.0],
            &SimSettings::default().exact_affine(mode),
            0,
        );
        let exact = ball.impacts(1.0, 20);
        assert!(
            arc.jumps().len() >= 20,
            "{mode:?}: {} impacts",
            arc.jumps().len()
        );
        for (k, (jump, (t, v))) in arc.jumps().iter().zip(&exact).enumerate() {
            let et = (jump.at.t - t).abs() / t;
            let ev = (jump.pre[1] - v).abs() / v.abs();
            assert!(
                et <= 1e-13 && ev <= 1e-12,
                "{mode:?}, impact {k}: rel {et:e}, {ev:e}"
            );
            assert!(
                jump.pre[0].abs() <= 1e-13,
                "{mode:?}, impact {k}: h = {}",
                jump.pre[0]
            );
        }
    }
}

#[test]
fn bouncing_ball_stops_at_zeno_time() {
    let ball = BouncingBall::new(9.81, 0.8);
    let arc = run(&ball, &[1.0, 0.0], &SimSettings::default(), 0);
    let term = arc.termination().expect("terminated");
    match &term.cause {
        TerminationCause::ZenoSuspected {
            rule,
            rule_name,
            detail: ZenoDetail::Rate { .. },
        } => {
            assert_eq!(*rule, 0);
            assert_eq!(rule_name, "impact");
        }
        other => panic!("expected Zeno, got {other:?}"),
    }
    let tz = ball.zeno_time(1.0);
    assert!(
        (term.at.t - tz).abs() < 1e-4,
        "stopped at {} vs Zeno time {tz}",
        term.at.t
    );
    assert!(term.to_string().contains("impact"));
}

#[test]
fn random_timer_resets_stay_in_range_and_follow_the_seed() {
    let (t1, t2) = (0.1, 0.7);
    let sys = RandomTimers::new(3, t1, t2);
    let x0 = [0.3, 0.5, 0.05];
    let settings = SimSettings::default().horizon_t(50.0);
    for exact in [true, false] {
        let s = settings.clone().exact_affine(exact);
        let arc = run(&sys, &x0, &s, 7);
        assert_eq!(arc.termination().unwrap().cause, TerminationCause::HorizonT);
        for (rule, &x0_rule) in x0.iter().enumerate() {
            let times = arc.jump_times(rule);
            assert!(times.len() > 50, "rule {rule}: {} jumps", times.len());
            for w in times.windows(2) {
                let d = w[1] - w[0];
                assert!(
                    d >= t1 - 1e-12 && d <= t2 + 1e-12,
                    "rule {rule}: inter-jump time {d}"
                );
            }
            // The first jump happens when the initial timer runs out.
            assert!((times[0] - x0_rule).abs() < 1e-15);
        }
        // Same seed, same arc bit for bit; another seed, another arc.
        assert_eq!(arc, run(&sys, &x0, &s, 7));
        let other = run(&sys, &x0, &s, 8);
        assert_ne!(arc.jump_times(0), other.jump_times(0));
    }
}

fn sample_and_hold_loop() -> SampleAndHold {
    // A lightly damped oscillator and an integrator, two inputs.
    let a = DMatrix::from_row_slice(3, 3, &[0.0, 1.0, 0.0, -4.0, -0.2, 0.0, 1.0, 0.0, 0.0]);
    let b = DMatrix::from_row_slice(3, 2, &[0.0, 0.0, 1.0, 0.0, 0.0, 1.0]);
    let k = DMatrix::from_row_slice(2, 3, &[1.0, 0.8, 0.1, 0.0, 0.1, 0.5]);
    SampleAndHold::new(a, b, k, 0.1)
}

fn check_sample_and_hold(sys: &SampleAndHold, settings: &SimSettings) {
    let x0 = [1.0, -0.5, 0.25];
    let steps = 100;
    let exact = sys.exact_samples(&x0, steps);
    let s = settings.clone().horizon_t(steps as f64 * sys.ts + 0.05);
    let arc = run(sys, &sys.initial_state(&x0), &s, 0);
    assert_eq!(arc.jumps().len(), steps);
    for (k, jump) in arc.jumps().iter().enumerate() {
        assert!(
            (jump.at.t - (k + 1) as f64 * sys.ts).abs() < 1e-12,
            "sample {k} at {}",
            jump.at.t
        );
        let xk = &exact[k + 1];
        let scale = xk.amax().max(1e-3);
        for i in 0..3 {
            let e = (jump.pre[i] - xk[i]).abs();
            assert!(
                e <= 1e-8 * scale,
                "sample {}: x[{i}] = {} vs {} ({e:e})",
                k + 1,
                jump.pre[i],
                xk[i]
            );
        }
    }
}

#[test]
fn sample_and_hold_matches_exact_discretization() {
    let mut sys = sample_and_hold_loop();
    check_sample_and_hold(
        &sys,
        &SimSettings::default().solver(Solver::Dopri5 {
            rtol: 1e-11,
            atol: 1e-13,
        }),
    );
    sys.affine = true;
    let exact = SimSettings::default().exact_affine(ExactAffine::On);
    check_sample_and_hold(&sys, &exact);
    check_sample_and_hold(&sys, &exact.dt_out(Some(0.03)));
}

#[test]
fn overlap_of_flow_and_jump_sets_follows_the_priority() {
    let sys = OverlapDemo::default();
    let s = SimSettings::default().horizon_t(5.5);
    // Jumps first: reset as soon as x reaches 1, at t = 1, 2, 3, 4, 5.
    let jumps = run(&sys, &[0.0], &s, 0);
    let t_jumps: Vec<f64> = jumps.jump_times(0);
    assert_eq!(t_jumps.len(), 5);
    for (k, (t, rec)) in t_jumps.iter().zip(jumps.jumps()).enumerate() {
        assert!((t - (k + 1) as f64).abs() < 1e-12, "jump {k} at {t}");
        assert!((rec.pre[0] - 1.0).abs() < 1e-12 && rec.post[0] == 0.0);
    }
    // Flows first: flow on through C ∩ D until x = 2 leaves C, reset at t = 2, 4.
    let flows = run(&sys, &[0.0], &s.clone().priority(Priority::Flows), 0);
    let t_flows = flows.jump_times(0);
    assert_eq!(t_flows.len(), 2, "{t_flows:?}");
    for (k, (t, rec)) in t_flows.iter().zip(flows.jumps()).enumerate() {
        assert!((t - 2.0 * (k + 1) as f64).abs() < 1e-12, "jump {k} at {t}");
        assert!((rec.pre[0] - 2.0).abs() < 1e-12 && rec.post[0] == 0.0);
    }
    assert_eq!(
        jumps.termination().unwrap().cause,
        TerminationCause::HorizonT
    );
    assert_eq!(
        flows.termination().unwrap().cause,
        TerminationCause::HorizonT
    );
}

#[test]
fn leaving_c_outside_d_ends_the_solution() {
    // From x = 2.5 the state is in D but not in C: it must jump at t = 0.
    let sys = OverlapDemo::default();
    let arc = run(&sys, &[2.5], &SimSettings::default().horizon_t(1.5), 0);
    assert_eq!(arc.jumps().len(), 2);
    assert_eq!(arc.jumps()[0].at.t, 0.0);
    // From x = -1 the state is in neither set.
    let stuck = run(&sys, &[-1.0], &SimSettings::default(), 0);
    assert!(matches!(
        stuck.termination().unwrap().cause,
        TerminationCause::CannotFlowOrJump { leaving: false, .. }
    ));
    assert_eq!(stuck.last().unwrap().kind, SampleKind::Final);
}

mod invariants {
    use super::*;
    use hybsim::arc::Sample;
    use proptest::prelude::*;

    /// Domain invariants of any arc: t and j non-decreasing, consecutive
    /// samples either share j (t non-decreasing) or are a jump (same t,
    /// j + 1, PreJump then PostJump, matching the jump record), and the
    /// record's pre/post states are the samples' states.
    fn check_domain(arc: &HybridArc) {
        let samples: Vec<Sample<'_>> = arc.samples().collect();
        assert_eq!(samples[0].kind, SampleKind::Initial);
        assert_eq!((samples[0].at.t, samples[0].at.j), (0.0, 0));
        let mut jumps = arc.jumps().iter();
        for w in samples.windows(2) {
            let (a, b) = (&w[0], &w[1]);
            assert!(b.at.t >= a.at.t, "t decreased: {} -> {}", a.at, b.at);
            if b.at.j == a.at.j {
                assert_ne!(b.kind, SampleKind::PostJump);
            } else {
                assert_eq!(b.at.j, a.at.j + 1, "j skipped: {} -> {}", a.at, b.at);
                assert_eq!(
                    b.at.t, a.at.t,
                    "t changed across a jump: {} -> {}",
                    a.at, b.at
                );
                assert_eq!(
                    (a.kind, b.kind),
                    (SampleKind::PreJump, SampleKind::PostJump)
                );
                let rec = jumps.next().expect("a record per jump");
                assert_eq!(rec.at, a.at);
                assert_eq!((rec.pre.as_slice(), rec.post.as_slice()), (a.x, b.x));
            }
        }
        assert!(jumps.next().is_none(), "more records than jumps");
        assert_eq!(samples.last().unwrap().kind, SampleKind::Final);
    }

    fn priority() -> impl Strategy<Value = Priority> {
        prop_oneof![
            Just(Priority::Jumps),
            Just(Priority::Flows),
            Just(Priority::Random)
        ]
    }

    fn grid() -> impl Strategy<Value = Option<f64>> {
        prop_oneof![Just(None), (0.01f64..0.5).prop_map(Some)]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        #[test]
        fn bouncing_ball_arcs(h0 in 0.0f64..5.0, v0 in -5.0f64..5.0, p in priority(),
                              dt in grid(), affine in any::<bool>(), seed in any::<u64>()) {
            let mut ball = BouncingBall::new(9.81, 0.7);
            ball.affine = affine;
            let s = SimSettings::default().horizon_t(4.0).priority(p).dt_out(dt);
            let arc = run(&ball, &[h0, v0], &s, seed);
            check_domain(&arc);
            for x in arc.samples().filter(|s| s.kind == SampleKind::Flow) {
                prop_assert!(x.x[0] >= -1e-9, "flow sample outside C at {}: {:?}", x.at, x.x);
            }
            for r in arc.jumps() {
                prop_assert!(r.pre[0] <= 1e-9 && r.pre[1] <= 0.0, "jump outside D at {}: {:?}", r.at, r.pre);
            }
        }

        #[test]
        fn overlap_demo_arcs(x0 in -0.5f64..2.5, p in priority(), dt in grid(), seed in any::<u64>()) {
            let sys = OverlapDemo::default();
            let s = SimSettings::default().horizon_t(6.0).priority(p).dt_out(dt);
            let arc = run(&sys, &[x0], &s, seed);
            check_domain(&arc);
            for x in arc.samples().filter(|s| s.kind == SampleKind::Flow) {
                prop_assert!((-1e-9..=2.0 + 1e-9).contains(&x.x[0]), "flow sample outside C: {:?}", x.x);
            }
            for r in arc.jumps() {
                prop_assert!(r.pre[0] >= 1.0 - 1e-9, "jump outside D at {}: {:?}", r.at, r.pre);
            }
            if x0 < 0.0 {
                let stuck = matches!(
                    arc.termination().unwrap().cause,
                    TerminationCause::CannotFlowOrJump { .. }
                );
                prop_assert!(stuck, "expected a stuck solution");
            }
        }

        #[test]
        fn random_timer_arcs(x0 in proptest::collection::vec(0.0f64..1.0, 1..4), dt in grid(),
                             exact in any::<bool>(), seed in any::<u64>()) {
            let sys = RandomTimers::new(x0.len(), 0.1, 0.7);
            let s = SimSettings::default().horizon_t(5.0).dt_out(dt).exact_affine(exact);
            let arc = run(&sys, &x0, &s, seed);
            check_domain(&arc);
            for x in arc.samples() {
                prop_assert!(x.x.iter().all(|&v| (0.0..=1.0).contains(&v)), "timer out of range: {:?}", x.x);
            }
            for r in arc.jumps() {
                prop_assert!(r.pre[r.rule] == 0.0, "timer not exactly at 0: {:?}", r.pre);
                prop_assert!((0.1..=0.7).contains(&r.post[r.rule]));
            }
        }
    }
}

mod semantics {
    use super::*;
    use crate::util::simulate_arc;
    use hybsim::arc::HybridTime;
    use hybsim::engine::{GuardKind, JumpRule, SimError, simulate};

    /// `ẋ = rate`, C the whole space, one rule whose jump set is the thin
    /// band `|x - 0.5| ≤ 0.01`, reset to `x⁺ = 2`. Optional blow-up flow
    /// `ẋ = x²` and optional non-finite jump map.
    struct Band {
        rules: Vec<JumpRule>,
        blow_up: bool,
        nan_jump: bool,
        noise: f64,
    }

    impl Band {
        fn new() -> Self {
            Self {
                rules: vec![JumpRule {
                    name: "band".into(),
                    group: None,
                    part: None,
                    writes: Vec::new(),
                    guard: GuardKind::General,
                }],
                blow_up: false,
                nan_jump: false,
                noise: 0.0,
            }
        }
    }

    impl HybridSystem for Band {
        fn state_dim(&self) -> usize {
            1
        }
        fn state_names(&self) -> Vec<String> {
            vec!["x".into()]
        }
        fn flow_map(&self, _at: HybridTime, x: &[f64], dx: &mut [f64]) {
            dx[0] = if self.blow_up { x[0] * x[0] } else { 1.0 };
        }
        fn jump_rules(&self) -> &[JumpRule] {
            &self.rules
        }
        fn jump_set(&self, _r: usize, _at: HybridTime, x: &[f64]) -> bool {
            (x[0] - 0.5).abs() <= 0.01
        }
        fn jump_guard(&self, _r: usize, _at: HybridTime, x: &[f64]) -> f64 {
            0.01 - (x[0] - 0.5).abs()
        }
        fn jump_map(
            &self,
            _r: usize,
            _at: HybridTime,
            _x: &[f64],
            _rng: &mut SimRng,
            xp: &mut [f64],
        ) {
            xp[0] = if self.nan_jump { f64::NAN } else { 2.0 };
        }
        fn noise_dim(&self) -> usize {
            usize::from(self.noise > 0.0)
        }
        fn diffusion(&self, _at: HybridTime, _x: &[f64], g: &mut [f64]) {
            g[0] = self.noise;
        }
    }

    #[test]
    fn guard_crossing_and_recrossing_within_one_step_is_caught() {
        // One Rk4 step of length 1 jumps over the band [0.49, 0.51]: the
        // step ends see no sign change, the interior checks do.
        let s = SimSettings::default()
            .horizon_t(3.0)
            .solver(Solver::Rk4 { h: 1.0 });
        let arc = run(&Band::new(), &[0.0], &s, 0);
        assert_eq!(arc.jumps().len(), 1);
        assert!(
            (arc.jumps()[0].at.t - 0.49).abs() < 1e-12,
            "{}",
            arc.jumps()[0].at
        );
        // The documented limit: without interior checks the band is missed.
        let missed = run(&Band::new(), &[0.0], &s.clone().guard_checks(0), 0);
        assert!(missed.jumps().is_empty());
    }

    #[test]
    fn errors_name_where_and_what() {
        let mut blow = Band::new();
        blow.blow_up = true;
        // ẋ = x² from 1 blows up at t = 1.
        match simulate_arc(
            &blow,
            &[1.0],
            &SimSettings::default(),
            &mut SimRng::seed_from(0),
        ) {
            Err(e @ (SimError::StepSizeCollapse { .. } | SimError::NonFinite { .. })) => {
                let at = match &e {
                    SimError::StepSizeCollapse { at, .. } | SimError::NonFinite { at, .. } => *at,
                    _ => unreachable!(),
                };
                assert!((at.t - 1.0).abs() < 1e-3, "{e}");
                assert!(!e.help().is_empty());
            }
            other => panic!("expected a blow-up error, got {other:?}"),
        }
        let mut nan = Band::new();
        nan.nan_jump = true;
        // max_step keeps the thin band from hiding between guard checks.
        let s = SimSettings::default().max_step(0.05);
        let e = simulate_arc(&nan, &[0.0], &s, &mut SimRng::seed_from(0)).unwrap_err();
        match e {
            SimError::NonFinite {
                at,
                component,
                ref name,
                ..
            } => {
                // At the jump attempted, (0.49, 0), where the solution ends (not at the
                // post-jump point it never reached).
                assert_eq!((at.j, component, name.as_str()), (0, 0, "x"));
                assert!((at.t - 0.49).abs() < 1e-9);
            }
            other => panic!("{other:?}"),
        }
        let e = simulate_arc(
            &Band::new(),
            &[0.0, 1.0],
            &SimSettings::default(),
            &mut SimRng::seed_from(0),
        );
        assert_eq!(
            e.unwrap_err(),
            SimError::StateDimension {
                expected: 1,
                found: 2
            }
        );
        for (settings, field) in [
            (SimSettings::default().horizon_t(f64::INFINITY), "horizon_t"),
            (
                SimSettings::default().solver(Solver::Dopri5 {
                    rtol: 0.0,
                    atol: 1e-9,
                }),
                "solver.rtol",
            ),
            // A pure relative tolerance: no step meets it on a state that is 0 (Dopri5's first
            // step came out NaN and the run went on with NaN steps).
            (
                SimSettings::default().solver(Solver::Dopri5 {
                    rtol: 1e-6,
                    atol: 0.0,
                }),
                "solver.atol",
            ),
            (
                SimSettings::default().solver(Solver::Rk4 { h: -1.0 }),
                "solver.h",
            ),
            (SimSettings::default().dt_out(Some(0.0)), "dt_out"),
            (SimSettings::default().max_step(f64::NAN), "max_step"),
            (SimSettings::default().zeno_window(1), "zeno_window"),
        ] {
            match simulate_arc(&Band::new(), &[0.0], &settings, &mut SimRng::seed_from(0)) {
                Err(SimError::InvalidSettings { field: f, .. }) => assert_eq!(f, field),
                other => panic!("{field}: {other:?}"),
            }
        }
        let mut noisy = Band::new();
        noisy.noise = 0.1;
        assert_eq!(
            simulate_arc(
                &noisy,
                &[0.0],
                &SimSettings::default(),
                &mut SimRng::seed_from(0)
            )
            .unwrap_err(),
            SimError::NoiseNeedsEulerMaruyama { noise_dim: 1 }
        );
    }

    #[test]
    fn euler_maruyama_is_seeded_and_jumps_from_d() {
        let mut noisy = Band::new();
        noisy.noise = 0.3;
        let s = SimSettings::default()
            .horizon_t(2.0)
            .solver(Solver::EulerMaruyama { h: 1e-3 });
        let a = run(&noisy, &[0.0], &s, 3);
        assert_eq!(a, run(&noisy, &[0.0], &s, 3));
        assert_ne!(
            a.last().unwrap().x,
            run(&noisy, &[0.0], &s, 4).last().unwrap().x
        );
        for r in a.jumps() {
            assert!((r.pre[0] - 0.5).abs() <= 0.01 + 1e-9, "{:?}", r.pre);
        }
    }

    #[test]
    fn horizons_and_sink_stop() {
        let ball = BouncingBall::new(9.81, 0.8);
        let arc = run(&ball, &[1.0, 0.0], &SimSettings::default().horizon_j(3), 0);
        assert_eq!(arc.jumps().len(), 3);
        let term = arc.termination().unwrap();
        assert_eq!(
            (term.cause.clone(), term.at.j),
            (TerminationCause::HorizonJ, 3)
        );

        let mut sink = crate::util::StopAfter::new(5);
        let s = SimSettings::default();
        let term = simulate(&ball, &[1.0, 0.0], &s, &mut SimRng::seed_from(0), &mut sink).unwrap();
        assert_eq!(term.cause, TerminationCause::StoppedBySink);
        assert_eq!(sink.termination, Some(term));
    }

    #[test]
    fn output_grid_and_queries() {
        let ball = BouncingBall::new(9.81, 0.8);
        let dt = 0.05;
        let s = SimSettings::default().horizon_t(2.0).dt_out(Some(dt));
        let arc = run(&ball, &[1.0, 0.0], &s, 0);
        let flows: Vec<_> = arc
            .samples()
            .filter(|x| x.kind == SampleKind::Flow)
            .collect();
        assert!(flows.len() >= 38);
        for x in &flows {
            let k = (x.at.t / dt).round();
            assert_eq!(x.at.t, k * dt, "grid sample off the grid");
            // Free fall before the first impact: h = 1 - g t²/2 (cubic Hermite is exact).
            if x.at.j == 0 {
                assert!((x.x[0] - (1.0 - 0.5 * 9.81 * x.at.t * x.at.t)).abs() < 1e-12);
            }
        }
        // Pre- and post-jump points are always present.
        assert_eq!(
            arc.samples()
                .filter(|x| x.kind == SampleKind::PreJump)
                .count(),
            arc.jumps().len()
        );
        // value_at: exact at samples, interpolated between, None off the domain.
        let j0 = arc.jumps()[0].at;
        assert_eq!(arc.value_at(j0).unwrap(), arc.jumps()[0].pre);
        assert_eq!(
            arc.value_at(HybridTime::new(j0.t, 1)).unwrap(),
            arc.jumps()[0].post
        );
        assert!(arc.value_at(HybridTime::new(j0.t + 0.1, 0)).is_none());
        let mid = arc.value_at(HybridTime::new(0.125, 0)).unwrap();
        assert!((mid[0] - (1.0 - 0.5 * 9.81 * 0.125 * 0.125)).abs() < 0.02);
        assert_eq!(arc.jump_times(0).len(), arc.jumps().len());
        assert_eq!(arc.rule_name(0), Some("impact"));
    }

    #[test]
    fn random_priority_is_seeded() {
        let sys = OverlapDemo::default();
        let s = SimSettings::default()
            .horizon_t(20.0)
            .priority(Priority::Random);
        let runs: Vec<Vec<f64>> = (0..8)
            .map(|seed| run(&sys, &[0.0], &s, seed).jump_times(0))
            .collect();
        assert_eq!(runs[0], run(&sys, &[0.0], &s, 0).jump_times(0));
        assert!(
            runs.iter().any(|r| r != &runs[0]),
            "the coin never changed the arc"
        );
        // Every jump is at x = 1 (jump chosen on entering D) or x = 2 (flow chosen).
        for seed in 0..8 {
            for r in run(&sys, &[0.0], &s, seed).jumps() {
                assert!((r.pre[0] - 1.0).abs() < 1e-12 || (r.pre[0] - 2.0).abs() < 1e-12);
            }
        }
    }
}

/// A lossless ball integrates exactly (constant acceleration), so with a far
/// horizon the controller's steps grow far past each flight; Hairer's
/// estimate of h·λ then reads the Jacobian's norm (1) times a long step as
/// stiffness. Such error-free steps do not count: the run reaches its jump
/// horizon (it stopped with "the flow became stiff" at j = 17 031 before).
#[test]
fn an_exactly_integrated_flow_is_not_stiff() {
    let ball = BouncingBall::new(9.81, 1.0);
    let settings = SimSettings::default()
        .horizon_t(1e9)
        .horizon_j(25_000)
        .dt_out(Some(100.0));
    let arc = run(&ball, &[1.0, 0.0], &settings, 0);
    assert_eq!(arc.termination().unwrap().cause, TerminationCause::HorizonJ);
    assert_eq!(arc.jumps().len(), 25_000);
    // Energy is kept: every impact at the speed of the first, √(2 g).
    let v = (2.0 * 9.81f64).sqrt();
    let last = arc.jumps().last().expect("it bounces");
    assert!((last.pre[1] + v).abs() < 1e-6 * v, "v = {}", last.pre[1]);
}
