//! Engine tests: analytic models through `engine::simulate`, with stated
//! tolerances.

use hybsim::arc::{HybridArc, SampleKind, TerminationCause, ZenoDetail};
use hybsim::engine::models::{BouncingBall, OverlapDemo, RandomTimers, SampleAndHold};
use hybsim::engine::{HybridSystem, Priority, SimRng, SimSettings, Solver, simulate_arc};
use nalgebra::DMatrix;

fn run<S: HybridSystem>(sys: &S, x0: &[f64], s: &SimSettings, seed: u64) -> HybridArc {
    simulate_arc(sys, x0, s, &mut SimRng::seed_from(seed)).expect("simulation runs")
}

fn check_ball_impacts(ball: &BouncingBall, settings: &SimSettings) {
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
            et <= 1e-9,
            "impact {k}: t = {} vs {t} (rel {et:e})",
            jump.at.t
        );
        assert!(
            ev <= 1e-9,
            "impact {k}: v = {} vs {v} (rel {ev:e})",
            jump.pre[1]
        );
        assert_eq!(jump.at.j, k as u64);
    }
}

#[test]
fn bouncing_ball_matches_closed_form_impacts() {
    let ball = BouncingBall::new(9.81, 0.8);
    check_ball_impacts(&ball, &SimSettings::default());
    check_ball_impacts(
        &ball,
        &SimSettings::default().solver(Solver::Dop853 {
            rtol: 1e-8,
            atol: 1e-10,
        }),
    );
    check_ball_impacts(
        &ball,
        &SimSettings::default().solver(Solver::Rk4 { h: 0.01 }),
    );
    let mut affine = ball.clone();
    affine.affine = true;
    check_ball_impacts(&affine, &SimSettings::default());
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
    check_sample_and_hold(&sys, &SimSettings::default());
    check_sample_and_hold(&sys, &SimSettings::default().dt_out(Some(0.03)));
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
    assert_eq!(
        stuck.termination().unwrap().cause,
        TerminationCause::CannotFlowOrJump
    );
    assert_eq!(stuck.last().unwrap().kind, SampleKind::Final);
}
