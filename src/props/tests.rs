//! Semantics of each property kind on hand-built arcs, where the expected
//! failing point is known exactly.

use super::*;
use crate::arc::{ArcSink, HybridArc, HybridTime, SampleKind, Termination, TerminationCause};

/// Builds a scalar arc from flows and jumps, pushing exactly what the
/// engine pushes.
struct Builder {
    arc: HybridArc,
    t: f64,
    j: u64,
    x: f64,
}

impl Builder {
    fn new(x0: f64) -> Self {
        let mut arc = HybridArc::new(1, vec!["a".into(), "b".into()]);
        let _ = arc.sample(HybridTime::new(0.0, 0), &[x0], SampleKind::Initial);
        Self {
            arc,
            t: 0.0,
            j: 0,
            x: x0,
        }
    }

    /// Flow samples at the given (t, x) points.
    fn flow(mut self, points: &[(f64, f64)]) -> Self {
        for &(t, x) in points {
            let _ = self
                .arc
                .sample(HybridTime::new(t, self.j), &[x], SampleKind::Flow);
            (self.t, self.x) = (t, x);
        }
        self
    }

    fn jump(mut self, rule: usize, post: f64) -> Self {
        let at = HybridTime::new(self.t, self.j);
        let _ = self.arc.sample(at, &[self.x], SampleKind::PreJump);
        let _ = self.arc.jump(at, rule, &[self.x], &[post]);
        self.j += 1;
        self.x = post;
        let _ = self.arc.sample(
            HybridTime::new(self.t, self.j),
            &[post],
            SampleKind::PostJump,
        );
        self
    }

    fn end(mut self, cause: TerminationCause) -> HybridArc {
        let at = HybridTime::new(self.t, self.j);
        let _ = self.arc.sample(at, &[self.x], SampleKind::Final);
        self.arc.finish(&Termination { at, cause });
        self.arc
    }
}

/// 1 → flows down to 0.5 at t = 1, jumps (rule 0) to 2, jumps at once
/// (rule 1) to 0.9, flows to 0.4 at t = 2.
fn sawtooth() -> HybridArc {
    Builder::new(1.0)
        .flow(&[(0.5, 0.75), (1.0, 0.5)])
        .jump(0, 2.0)
        .jump(1, 0.9)
        .flow(&[(1.5, 0.6), (2.0, 0.4)])
        .end(TerminationCause::HorizonT)
}

fn at(t: f64, j: u64) -> HybridTime {
    HybridTime::new(t, j)
}

#[test]
fn always_sees_both_sides_of_jumps() {
    let arc = sawtooth();
    let v = Property::always("le 1.5", |_, x| x[0] <= 1.5)
        .check(&arc)
        .unwrap_err();
    assert_eq!(v.at, at(1.0, 1));
    assert_eq!(v.state, vec![2.0]);
    assert_eq!(
        v.detail,
        ViolationDetail::Predicate {
            kind: SampleKind::PostJump
        }
    );
    assert_eq!(
        Property::always("le 2", |_, x| x[0] <= 2.0).check(&arc),
        Ok(Conclusion::Holds)
    );
}

#[test]
fn during_flows_skips_points_passed_through_by_jumps() {
    let arc = sawtooth();
    // x = 2 lives only at (1, 1), between two jumps at the same t.
    assert_eq!(
        Property::during_flows("le 1", |_, x| x[0] <= 1.0).check(&arc),
        Ok(Conclusion::Holds)
    );
    // The start of a flow interval is a flow point: (1, 2) with x = 0.9.
    let v = Property::during_flows("le 0.8 after t=1", |t, x| t.t < 1.0 || x[0] <= 0.8)
        .check(&arc)
        .unwrap_err();
    assert_eq!((v.at, v.state.clone()), (at(1.0, 2), vec![0.9]));
    // Its end too: the pre-jump point (1, 0) with x = 0.5.
    let v = Property::during_flows("gt 0.5", |_, x| x[0] > 0.5)
        .check(&arc)
        .unwrap_err();
    assert_eq!(v.at, at(1.0, 0));
}

#[test]
fn at_jumps_sees_pre_and_post_and_filters_rules() {
    let arc = sawtooth();
    let up = |j: &JumpView<'_>| j.post[0] >= j.pre[0];
    let v = Property::at_jumps("up", up).check(&arc).unwrap_err();
    // The second jump (rule 1, 2 → 0.9) goes down; it is reported at its
    // pre-jump time (1, 1).
    assert_eq!(v.at, at(1.0, 1));
    assert_eq!(
        v.detail,
        ViolationDetail::Jump {
            rule: 1,
            post: vec![0.9]
        }
    );
    assert!(Property::at_jumps_of("up a", 0, up).check(&arc).is_ok());
    assert!(Property::at_jumps_of("up b", 1, up).check(&arc).is_err());
}

#[test]
fn eventually_within_fails_past_the_deadline_and_is_inconclusive_when_cut_short() {
    let arc = sawtooth();
    assert_eq!(
        Property::eventually_within("low", 1.0, |_, x| x[0] <= 0.5).check(&arc),
        Ok(Conclusion::Holds)
    );
    let v = Property::eventually_within("very low", 1.2, |_, x| x[0] <= 0.45)
        .check(&arc)
        .unwrap_err();
    assert_eq!(v.at, at(1.5, 2));
    assert_eq!(
        v.detail,
        ViolationDetail::NotWithin {
            within: 1.2,
            ended_early: false
        }
    );
    // Deadline after the end: inconclusive if a horizon ended the run …
    let later = Property::eventually_within("later", 5.0, |_, x| x[0] <= 0.1);
    assert!(matches!(
        later.check(&arc),
        Ok(Conclusion::Inconclusive { .. })
    ));
    // … a failure if the solution is maximal there.
    let stuck = Builder::new(1.0)
        .flow(&[(1.0, 0.5)])
        .end(TerminationCause::CannotFlowOrJump {
            leaving: false,
            failed: Vec::new(),
            state: vec![0.5],
            flow_from: 1.0,
        });
    let v = later.check(&stuck).unwrap_err();
    assert_eq!(v.at, at(1.0, 0));
    assert_eq!(
        v.detail,
        ViolationDetail::NotWithin {
            within: 5.0,
            ended_early: true
        }
    );
}

#[test]
fn always_after_starts_at_the_entering_sample() {
    let arc = sawtooth();
    let p = Property::always_after(
        "stays below 1 once below 0.8",
        |_, x| x[0] < 0.8,
        |_, x| x[0] < 1.0,
    );
    let v = p.check(&arc).unwrap_err();
    assert_eq!((v.at, v.state.clone()), (at(1.0, 1), vec![2.0]));
    let never = Property::always_after("never entered", |_, x| x[0] < 0.0, |_, _| false);
    assert!(never.check(&arc).is_ok());
}

#[test]
fn monotonicity_during_flows_and_at_jumps() {
    let arc = sawtooth();
    let v = |_: HybridTime, x: &[f64]| x[0];
    assert!(
        Property::decreasing("flows", Scope::Flows, 0.0, v)
            .check(&arc)
            .is_ok()
    );
    let e = Property::nonincreasing("jumps", Scope::Jumps, 0.0, v)
        .check(&arc)
        .unwrap_err();
    assert_eq!(e.at, at(1.0, 0));
    assert_eq!(
        e.detail,
        ViolationDetail::Monotone {
            how: Monotonicity::Nonincreasing,
            scope: Scope::Jumps,
            from_at: at(1.0, 0),
            from: 0.5,
            to: 2.0,
            tol: 0.0
        }
    );
    // A tolerance of 1.5 covers the jump from 0.5 to 2.
    assert!(
        Property::nonincreasing("jumps", Scope::Jumps, 1.5, v)
            .check(&arc)
            .is_ok()
    );
    // A flat stretch is nonincreasing but not decreasing, unless within tol.
    let flat = Builder::new(0.3)
        .flow(&[(1.0, 0.3)])
        .end(TerminationCause::HorizonT);
    assert!(
        Property::nonincreasing("n", Scope::Flows, 0.0, v)
            .check(&flat)
            .is_ok()
    );
    let e = Property::decreasing("d", Scope::Flows, 0.0, v)
        .check(&flat)
        .unwrap_err();
    assert_eq!(e.at, at(1.0, 0));
    assert!(
        Property::decreasing("d", Scope::Flows, 0.3, v)
            .check(&flat)
            .is_ok()
    );
}

#[test]
fn exponential_bound_uses_t_plus_j() {
    // x = e^{-t} during flow, halved at a jump at t = 1.
    let arc = Builder::new(1.0)
        .flow(&[(0.5, (-0.5f64).exp()), (1.0, (-1.0f64).exp())])
        .jump(0, 0.5 * (-1.0f64).exp())
        .end(TerminationCause::HorizonT);
    let dist = |_: HybridTime, x: &[f64]| x[0].abs();
    // e^{-1}/2 ≤ e^{-(1+1)} · κ needs κ ≥ e/2 ≈ 1.36.
    assert!(
        Property::exponential_bound("k=1.4", 1.4, 1.0, 0.0, dist)
            .check(&arc)
            .is_ok()
    );
    let v = Property::exponential_bound("k=1.3", 1.3, 1.0, 0.0, dist)
        .check(&arc)
        .unwrap_err();
    assert_eq!(v.at, at(1.0, 1));
    let ViolationDetail::Bound { value, bound } = v.detail else {
        panic!("{v}")
    };
    assert!((value - 0.5 * (-1.0f64).exp()).abs() < 1e-15);
    assert!((bound - 1.3 * (-2.0f64).exp()).abs() < 1e-15);
}

#[test]
fn sink_stops_at_first_violation_and_forwards() {
    use crate::engine::{SimRng, SimSettings, models::BouncingBall, simulate};
    let ball = BouncingBall::new(9.81, 0.8);
    let props = [
        Property::always("ground", |_, x| x[0] >= -1e-9),
        Property::always("below 0.5", |t, x| t.j == 0 || x[0] <= 0.5),
    ];
    let mut arc = HybridArc::new(2, vec!["impact".into()]);
    let mut sink = PropertySink::forwarding(&props, &mut arc);
    let term = simulate(
        &ball,
        &[1.0, 0.0],
        // A fine output grid: properties are checked at samples, and an
        // integrator may cross a whole flight (free fall is a polynomial) in one step.
        &SimSettings::default().dt_out(Some(0.01)),
        &mut SimRng::seed_from(0),
        &mut sink,
    )
    .unwrap();
    let v = sink.violation().cloned().unwrap();
    // After the first impact the ball rises to λ²·1 = 0.64 > 0.5.
    assert_eq!(v.property, "below 0.5");
    assert_eq!(v.at.j, 1);
    assert!(v.state[0] > 0.5 && v.state[0] <= 0.64 + 1e-9);
    assert_eq!(term.cause, TerminationCause::StoppedBySink);
    // The forwarded arc ends at the violating sample.
    assert_eq!(arc.last().unwrap().at, v.at);
}

#[test]
fn dist_targets_and_validation() {
    assert_eq!(Dist::Uniform { lo: -1.0, hi: 2.0 }.shrink_target(), 0.0);
    assert_eq!(Dist::Uniform { lo: 1.0, hi: 2.0 }.shrink_target(), 1.5);
    assert_eq!(
        Dist::Normal {
            mean: 3.0,
            std: 1.0
        }
        .shrink_target(),
        3.0
    );
    assert!(Dist::Uniform { lo: 2.0, hi: 1.0 }.validate().is_err());
    assert!(
        Dist::Normal {
            mean: 0.0,
            std: -1.0
        }
        .validate()
        .is_err()
    );
    assert!(Dist::Fixed(f64::NAN).validate().is_err());
}

#[test]
fn sampled_cases_are_reproducible_and_in_range() {
    let inputs = [
        Input::new("h", Dist::Uniform { lo: 0.0, hi: 2.0 }),
        Input::new("v", Dist::Fixed(0.0)),
    ];
    let a = sample_case(&inputs, 42, 7);
    assert_eq!(a, sample_case(&inputs, 42, 7));
    assert_ne!(a.seed, sample_case(&inputs, 42, 8).seed);
    for i in 0..100 {
        let c = sample_case(&inputs, 1, i);
        assert!((0.0..=2.0).contains(&c.values[0]) && c.values[1] == 0.0);
    }
}

#[test]
fn short_decimals_stay_in_the_bracket_shortest_first() {
    use super::runner::short_decimals_between;
    let c = short_decimals_between(1.4999999999996, 1.5000000000004547);
    assert_eq!(c[..2], [1.5, 1.5000000000004]);
    let c = short_decimals_between(1.5, 1.5000000000013636);
    assert_eq!(c[..2], [1.500000000001, 1.5000000000013]);
    let c = short_decimals_between(-1.5, -1.5000000000004547);
    assert_eq!(c[0], -1.5000000000004);
    assert!(short_decimals_between(1.5, 1.5000000000000002).is_empty());
    assert_eq!(short_decimals_between(0.0, 0.012345)[0], 0.01);
}
