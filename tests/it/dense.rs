//! Dense output and the exact-affine choice: the default samples draw each
//! flow faithfully (`HybridArc::value_at` follows the solution between
//! samples), and `exact_affine = auto | on | off` give the same arcs within
//! the solver's tolerance on every shipped model.

use std::ops::ControlFlow;

use crate::util::simulate_arc;
use hybsim::arc::{ArcSink, HybridArc, HybridTime, SampleKind};
use hybsim::engine::models::BouncingBall;
use hybsim::engine::{ExactAffine, HybridSystem, SimRng, SimSettings, simulate};

use super::lang::load;

/// Height of the ball (h0 = 1, λ = 0.8) at (t, j) in closed form.
fn ball_height(t: f64, j: u64) -> f64 {
    let (g, lam) = (9.81_f64, 0.8_f64);
    let t1 = (2.0 / g).sqrt();
    if j == 0 {
        return 1.0 - 0.5 * g * t * t;
    }
    // Impact k at t1 + Σ_{i<k} 2 λ^i v1 / g with v1 = g t1.
    let mut tk = t1;
    let mut v = g * t1;
    for _ in 1..j {
        v *= lam;
        tk += 2.0 * v / g;
    }
    let v_post = lam * v;
    let s = t - tk;
    v_post * s - 0.5 * g * s * s
}

/// A run's whole arc, and the same run through a sink that declines dense
/// output's points (`StepEnds`).
fn whole_and_step_ends(m: &hybsim::ir::CompiledModel, s: &SimSettings) -> (HybridArc, HybridArc) {
    let (x0, mut rng) = m.start(m.seed());
    let full = simulate_arc(m, &x0, s, &mut rng).unwrap();
    let (x0, mut rng) = m.start(m.seed());
    let mut ends = StepEnds(HybridArc::new(
        m.state_dim(),
        vec![String::new(); m.jump_rules().len()],
    ));
    simulate(m, &x0, s, &mut rng, &mut ends).unwrap();
    (full, ends.0)
}

#[test]
fn value_at_follows_the_ball_between_samples() {
    let mut ball = BouncingBall::new(9.81, 0.8);
    ball.affine = true;
    for mode in [ExactAffine::Auto, ExactAffine::On, ExactAffine::Off] {
        let s = SimSettings::default().horizon_t(3.0).exact_affine(mode);
        let arc = simulate_arc(&ball, &[1.0, 0.0], &s, &mut SimRng::seed_from(0)).unwrap();
        // The example of issue 16: 0.639 at (0.8, 1).
        let h = arc.value_at(HybridTime::new(0.8, 1)).unwrap()[0];
        assert!((h - ball_height(0.8, 1)).abs() < 1e-6, "{mode:?}: {h}");
        let mut worst: f64 = 0.0;
        for r in 0..arc.jumps().len().saturating_sub(1).min(8) {
            let (a, b) = (arc.jumps()[r].at.t, arc.jumps()[r + 1].at.t);
            for k in 1..50 {
                let t = a + (b - a) * k as f64 / 50.0;
                let j = r as u64 + 1;
                let x = arc.value_at(HybridTime::new(t, j)).unwrap();
                worst = worst.max((x[0] - ball_height(t, j)).abs());
            }
        }
        assert!(worst < 1e-6, "{mode:?}: value_at off by {worst:e}");
        // Faithful, not exhaustive: tens of samples per bounce.
        let flows = arc.samples().filter(|x| x.kind == SampleKind::Flow).count();
        let bounces = arc.jumps().len() + 1;
        assert!(
            flows >= 4 * bounces && flows <= 200 * bounces,
            "{mode:?}: {flows} flow samples for {bounces} flow intervals"
        );
        // The polyline through the samples stays within 1e-3 of the apex.
        for w in arc.samples().collect::<Vec<_>>().windows(2) {
            let (p, q) = (&w[0], &w[1]);
            if p.at.j != q.at.j || q.at.t <= p.at.t {
                continue;
            }
            let tm = 0.5 * (p.at.t + q.at.t);
            let line = 0.5 * (p.x[0] + q.x[0]);
            let d = (line - ball_height(tm, p.at.j)).abs();
            assert!(d < 2e-3, "{mode:?}: chord off by {d} at t = {tm}");
        }
    }
}

/// Every shipped model, its horizon cut to 5, run with the exact path
/// chosen by cost, always and never: same jumps (rules, times) and states.
#[test]
fn exact_affine_auto_on_off_agree_on_every_model() {
    let dir = format!("{}/models", env!("CARGO_MANIFEST_DIR"));
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .filter(|n| n.ends_with(".hyb"))
        .collect();
    names.sort();
    assert!(names.len() >= 10);
    for name in &names {
        let m = load(name, &[]);
        let (x0, _) = m.start(m.seed());
        let base = m.settings();
        let horizon = base.horizon_t.min(5.0);
        let arcs: Vec<HybridArc> = [ExactAffine::Auto, ExactAffine::On, ExactAffine::Off]
            .iter()
            .map(|&mode| {
                let s = base.clone().horizon_t(horizon).exact_affine(mode);
                let (_, mut rng) = m.start(m.seed());
                simulate_arc(&m, &x0, &s, &mut rng)
                    .unwrap_or_else(|e| panic!("{name} {mode:?}: {e}"))
            })
            .collect();
        let scale: Vec<f64> = (0..m.state_dim())
            .map(|i| arcs[2].samples().map(|x| x.x[i].abs()).fold(1.0, f64::max))
            .collect();
        for (k, arc) in arcs.iter().enumerate().take(2) {
            let other = &arcs[2];
            assert_eq!(arc.jumps().len(), other.jumps().len(), "{name} mode {k}");
            for (a, b) in arc.jumps().iter().zip(other.jumps()) {
                assert_eq!(a.rule, b.rule, "{name} mode {k} at {}", a.at);
                assert!(
                    (a.at.t - b.at.t).abs() <= 1e-4 * (1.0 + b.at.t),
                    "{name} mode {k}: jump at {} vs {}",
                    a.at,
                    b.at
                );
            }
            let (xa, xb) = (arc.last().unwrap().x, other.last().unwrap().x);
            for i in 0..xa.len() {
                assert!(
                    (xa[i] - xb[i]).abs() <= 1e-4 * scale[i],
                    "{name} mode {k}: x[{i}] = {} vs {}",
                    xa[i],
                    xb[i]
                );
            }
        }
    }
}

/// A sink that keeps the arc but wants no dense points (as `hybsim run`
/// without files): step ends only.
struct StepEnds(HybridArc);

impl ArcSink for StepEnds {
    fn sample(&mut self, at: HybridTime, x: &[f64], kind: SampleKind) -> ControlFlow<()> {
        self.0.sample(at, x, kind)
    }

    fn jump(&mut self, at: HybridTime, rule: usize, pre: &[f64], post: &[f64]) -> ControlFlow<()> {
        self.0.jump(at, rule, pre, post)
    }

    fn wants_dense_points(&self) -> bool {
        false
    }
}

/// A sink that declines dense points gets a subset of the samples, each
/// bit-identical, with every non-flow sample and every jump: the points are
/// output only, never steps. On the three paths (exact polynomial, exact
/// exponential, Dopri5) of curved flows, where dense output adds points.
#[test]
fn declining_dense_points_drops_only_points_between_step_ends() {
    let key = |at: HybridTime, x: &[f64], kind: SampleKind| {
        let mut k = vec![at.t.to_bits(), at.j, kind as u64];
        k.extend(x.iter().map(|v| v.to_bits()));
        k
    };
    for (name, mode) in [
        ("bouncing_ball.hyb", ExactAffine::Auto),
        ("sample_and_hold.hyb", ExactAffine::On),
        ("sample_and_hold.hyb", ExactAffine::Off),
        ("thermostat.hyb", ExactAffine::Off),
    ] {
        let m = load(name, &[]);
        let s = m.settings().exact_affine(mode);
        let (full, ends) = whole_and_step_ends(&m, &s);
        let all: std::collections::HashSet<_> =
            full.samples().map(|p| key(p.at, p.x, p.kind)).collect();
        assert!(
            ends.samples()
                .all(|p| all.contains(&key(p.at, p.x, p.kind))),
            "{name} {mode:?}: a step-end sample differs"
        );
        let not_flow = |a: &HybridArc| a.samples().filter(|p| p.kind != SampleKind::Flow).count();
        assert_eq!(not_flow(&ends), not_flow(&full), "{name} {mode:?}");
        assert_eq!(ends.jumps(), full.jumps(), "{name} {mode:?}");
        assert!(
            ends.samples().len() < full.samples().len(),
            "{name} {mode:?}: {} step ends against {} samples: no dense points declined",
            ends.samples().len(),
            full.samples().len()
        );
    }
}

/// A guard-free exact flow at an equilibrium ends its segment in one step
/// (as a solver's steps grow there): `x' = -x` reaches 0 (after some 745
/// steps of 1/‖A‖∞) and then a horizon of 1e300 at once; `x' = 1 - x` from
/// its equilibrium takes a single step.
#[test]
fn exact_flow_at_rest_reaches_a_far_horizon() {
    for (flow, x0, most) in [("-x", 1.0, 800), ("1 - x", 1.0, 3)] {
        let text = format!(
            "model m\nstate x = {x0}\nflow {{ x' = {flow} }}\nsim {{ T = 1e300; exact_affine = on }}\n"
        );
        let src = hybsim::source::SourceFile::new("m.hyb", text);
        let m = hybsim::lang::compile(&src, &[]).unwrap();
        let (x0, mut rng) = m.start(m.seed());
        let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng).unwrap();
        let last = arc.last().unwrap();
        assert_eq!(last.at.t, 1e300, "x' = {flow}");
        assert_eq!(last.x[0], if flow == "-x" { 0.0 } else { 1.0 });
        assert!(
            arc.samples().len() <= most,
            "x' = {flow}: {} samples",
            arc.samples().len()
        );
    }
}

/// A grid point `k·dt_out` at a jump's time is the jump's pre-jump sample
/// alone. A timer's event (`x >= c` on `x' = 1`) is met at the grid time
/// itself, while the grid's local time, `k·dt` less the segment's start,
/// rounds a few ulps short of it: the flow there was also logged, a second
/// sample at the pre-jump sample's (t, j) with x a rounding short of c
/// (`0.4, 3, flow, 0.09999999999999998` before `0.4, 3, pre_jump, 0.1`).
#[test]
fn a_grid_point_at_a_jump_is_not_also_a_flow_sample() {
    // A PWM boost converter (switched affine, exact), its clock `tau`
    // reset every Ts = dt_out: the timer's expiry lands a few ulps past the
    // grid point, on a step of its own.
    let boost = "model boost
param Vin = 5, L = 1e-4, C = 1e-4, R = 10, Ts = 1e-5, D = 0.5
state iL = 0, vC = 0, tau = 0, q = 1
flow {
  iL' = if q == 1 then Vin/L else (Vin - vC)/L
  vC' = if q == 1 then -vC/(R*C) else (iL - vC/R)/C
  tau' = 1
}
jump off when q == 1 && tau >= D*Ts { q+ = 0 }
jump on when tau >= Ts { q+ = 1; tau+ = 0 }
sim { T = 0.002; dt_out = 1e-5 }
"
    .to_string();
    let ticks = [
        ("0.1", "dopri5"),
        ("0.2", "dopri5"),
        ("0.1", "rk4"),
        ("0.25", "radau5"),
    ]
    .map(|(c, solver)| {
        (
            format!("x >= {c}, {solver}"),
            format!(
                "model tick\nstate x = 0\nflow {{ x' = 1 }}\njump reset when x >= {c} {{ x+ = 0 }}\n\
                 sim {{ T = 2; dt_out = 0.1; solver = {solver} }}\n"
            ),
        )
    });
    for (c, src) in ticks.into_iter().chain([("boost".to_string(), boost)]) {
        let m = crate::util::compile(&src);
        let (x0, mut rng) = m.start(m.seed());
        let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng).unwrap();
        assert!(arc.jumps().len() >= 7, "{c}");
        let samples: Vec<_> = arc.samples().collect();
        for w in samples.windows(2) {
            let (a, b) = (&w[0], &w[1]);
            assert!(
                a.at != b.at || a.x == b.x,
                "{c}: two states at {}: {:?} {:?} then {:?} {:?}",
                a.at,
                a.kind,
                a.x,
                b.kind,
                b.x
            );
        }
        let jump_times: Vec<HybridTime> = arc.jumps().iter().map(|r| r.at).collect();
        assert!(
            samples
                .iter()
                .all(|s| s.kind != SampleKind::Flow || !jump_times.contains(&s.at)),
            "{c}: a flow sample at a jump's time"
        );
    }
}

/// Sampled-data loops whose segments are one exponential step with nothing
/// watched or sampled inside them take a short path (`Flows::segment`'s
/// one exact step) when the sink declines dense points, and the general
/// step machinery when it wants them: the same steps, so the same jumps,
/// bit for bit, and the same samples at the step ends. Each model varies
/// one condition of that path: exact or auto, a held input through a
/// switched affine flow (its modes), a non-timer guard watched (the short
/// path declined both ways), periods longer than one step (several steps a
/// segment), an output grid (its points inside the segments).
#[test]
fn one_step_exact_segments_give_the_general_steps() {
    let key = |at: HybridTime, x: &[f64], kind: SampleKind| {
        let mut k = vec![at.t.to_bits(), at.j, kind as u64];
        k.extend(x.iter().map(|v| v.to_bits()));
        k
    };
    let loop_model = |extra: &str, ts: f64, sim: &str| {
        format!(
            "model m\n\
             param A = [0, 1; -1, -0.2]\nparam B = [0; 1]\nparam K = [0.3, 0.05]\n\
             state xp = [1; 0], u = 0, tau = 0, q = 1\n\
             flow {{ xp' = A * xp + B * u; tau' = 1 }}\n\
             jump sample when tau >= {ts} {{ u+ = -K * xp; tau+ = 0 }}\n\
             {extra}\n\
             sim {{ T = 20; J = 100000; {sim} }}\n"
        )
    };
    let switched = "model m\nstate x = 1, q = 1, tau = 0\n\
                    flow { x' = -q * x + 0.5; tau' = 1 }\n\
                    jump s when tau >= 0.05 { q+ = 3 - q; tau+ = 0 }\n\
                    sim { T = 10; J = 100000 }\n";
    let limit_sh = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/models/limit_sh.hyb"),
    )
    .expect("benches/models/limit_sh.hyb");
    let cases = [
        ("on", loop_model("", 0.01, ""), ExactAffine::On),
        ("auto", loop_model("", 0.01, ""), ExactAffine::Auto),
        ("switched", switched.to_string(), ExactAffine::On),
        ("switched auto", switched.to_string(), ExactAffine::Auto),
        (
            "non-timer guard",
            loop_model("jump far when xp[1] >= 5 { q+ = q + 1 }", 0.01, ""),
            ExactAffine::On,
        ),
        ("long periods", loop_model("", 2.5, ""), ExactAffine::On),
        (
            "grid",
            loop_model("", 0.01, "dt_out = 0.003"),
            ExactAffine::On,
        ),
        ("limit_sh on", limit_sh.clone(), ExactAffine::On),
        ("limit_sh auto", limit_sh, ExactAffine::Auto),
    ];
    for (name, text, mode) in cases {
        let src = hybsim::source::SourceFile::new("m.hyb", text);
        let m = match hybsim::lang::compile(&src, &[]) {
            Ok(m) => m,
            Err(d) => panic!("{}", hybsim::diagnostics::render(&d, &src, false)),
        };
        let s = m.settings().exact_affine(mode);
        let (full, ends) = whole_and_step_ends(&m, &s);
        assert!(
            ends.jumps().len() > 3,
            "{name}: {} jumps",
            ends.jumps().len()
        );
        assert_eq!(ends.jumps(), full.jumps(), "{name}");
        let all: std::collections::HashSet<_> =
            full.samples().map(|p| key(p.at, p.x, p.kind)).collect();
        assert!(
            ends.samples()
                .all(|p| all.contains(&key(p.at, p.x, p.kind))),
            "{name}: a step-end sample differs"
        );
        let not_flow = |a: &HybridArc| a.samples().filter(|p| p.kind != SampleKind::Flow).count();
        assert_eq!(not_flow(&ends), not_flow(&full), "{name}");
        assert_eq!(ends.last().unwrap().x, full.last().unwrap().x, "{name}");
    }
}
