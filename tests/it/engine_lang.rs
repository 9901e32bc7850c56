//! Issue 16 (language half), through the real pipeline (`.hyb` → compile →
//! simulate): simultaneous jumps (`together`), the Zeno guard and its knobs,
//! the jump counter `j` in expressions, the functions `round`, `ceil`,
//! `frac`, `rem`, `hypot`, `clamp`. Each answer is checked against a closed
//! form or a recursion written out here.

use crate::util::simulate_arc;
use hybsim::arc::{HybridArc, HybridTime, TerminationCause, ZenoDetail};
use hybsim::engine::{GuardKind, HybridSystem, JumpRule, SimRng, SimSettings};
use hybsim::lang::{self, CompiledModel};
use hybsim::source::SourceFile;

fn compile(text: &str) -> CompiledModel {
    let src = SourceFile::new("m.hyb", text);
    match lang::compile(&src, &[]) {
        Ok(m) => m,
        Err(d) => panic!("{}", hybsim::diagnostics::render(&d, &src, false)),
    }
}

fn run(m: &CompiledModel) -> HybridArc {
    let (x0, mut rng) = m.start(m.seed());
    simulate_arc(m, &x0, &m.settings(), &mut rng).expect("simulation")
}

fn end(arc: &HybridArc) -> (HybridTime, Vec<f64>) {
    let last = arc.last().expect("a sample");
    (last.at, last.x.to_vec())
}

// ---- simultaneous jumps -----------------------------------------------------

/// Two pulse-coupled fireflies written as the HyEQ composite system: one
/// rule per firefly, each in D when any clock reaches 1; the one that
/// flashes (the largest clock) resets to 0, the other advances to
/// min(1, (1 + eps) tau).
fn fireflies(together: bool) -> String {
    let rules = "for i in 1..2 {
        jump fire[i] when max(tau[1], tau[2]) >= 1 {
            tau[i]+ = if tau[i] >= max(tau[1], tau[2]) then 0 else min(1, (1 + eps) * tau[i])
        }
    }";
    let rules = if together {
        format!("together {{ {rules} }}")
    } else {
        rules.to_string()
    };
    format!(
        "model fireflies
param eps = 0.5
state tau[1] = 0.9
state tau[2] = 0.5
for i in 1..2 {{ flow {{ tau[i]' = 1 }} }}
{rules}
sim {{ T = 10 }}
"
    )
}

#[test]
fn together_fireflies_make_the_composite_jumps() {
    let m = compile(&fireflies(true));
    let arc = run(&m);
    // By hand (eps = 0.5, tau = (0.9, 0.5)):
    //  t = 0.1: tau[1] flashes, tau[2] = 0.6 → 0.9           (j = 1)
    //  t = 0.2: tau[2] flashes, tau[1] = 0.1 → 0.15          (j = 2)
    //  t = 1.05: tau[1] flashes, tau[2] = 0.85 → 1 (clamped) (j = 3)
    //  t = 1.05: tau[2] = 1 flashes, tau[1] = 0 stays 0      (j = 4)
    //  then synchronised: both flash in ONE jump at 2.05, ..., 9.05.
    let mut expected = vec![(0.1, vec![0.0, 0.9]), (0.2, vec![0.15, 0.0])];
    expected.push((1.05, vec![0.0, 1.0]));
    expected.push((1.05, vec![0.0, 0.0]));
    for k in 2..=9 {
        expected.push((k as f64 + 0.05, vec![0.0, 0.0]));
    }
    // One jump = one j; the records of a simultaneous jump share (t, j).
    let mut js: Vec<u64> = arc.jumps().iter().map(|r| r.at.j).collect();
    js.dedup();
    assert_eq!(js.len(), expected.len(), "jumps: {:?}", arc.jumps());
    assert_eq!(end(&arc).0.j, expected.len() as u64);
    for (j, (t, post)) in expected.iter().enumerate() {
        let recs: Vec<_> = arc.jumps().iter().filter(|r| r.at.j == j as u64).collect();
        assert!(!recs.is_empty());
        for r in &recs {
            assert!((r.at.t - t).abs() < 1e-9, "jump {j}: t = {} vs {t}", r.at.t);
            for (a, b) in r.post.iter().zip(post) {
                assert!(
                    (a - b).abs() < 1e-9,
                    "jump {j}: post {:?} vs {post:?}",
                    r.post
                );
            }
        }
        // Synchronised flashes are one jump of both rules.
        if j >= 4 {
            let rules: Vec<usize> = recs.iter().map(|r| r.rule).collect();
            assert_eq!(rules, vec![0, 1], "jump {j}");
        }
    }
}

#[test]
fn without_together_the_composite_rules_fire_one_after_the_other() {
    // Sequential semantics (the default): at t = 0.1 only fire[1] fires
    // (the clocks leave D before fire[2] is looked at), so tau[2] never
    // advances; at t = 0.5 fire[1] keeps firing on the state it left while
    // tau[2] = 1 holds D, and the Zeno guard ends the run there: the reason
    // composite systems need `together`.
    let arc = run(&compile(&fireflies(false)));
    let first = &arc.jumps()[0];
    assert!((first.at.t - 0.1).abs() < 1e-9);
    assert!((first.post[0]).abs() < 1e-12 && (first.post[1] - 0.6).abs() < 1e-9);
    let term = arc.termination().unwrap();
    assert!(
        matches!(term.cause, TerminationCause::ZenoSuspected { rule: 0, .. }),
        "{term:?}"
    );
    assert!((term.at.t - 0.5).abs() < 1e-9, "{term}");
}

/// A plant ẋ = −x + u sampled by an ADC (`xs+ = x`) and driven by a ZOH
/// (`u+ = −K xs`), both every Ts. Together, the ZOH holds the previous
/// sample (one-step delay): u_k = −K x_{k−1}. The flow is advanced exactly
/// so that the samples match the sampled system's recursion to 1e-12.
fn adc_zoh(together: bool) -> String {
    let rules = "jump adc every Ts { xs+ = x }
    jump zoh every Ts { u+ = -K * xs }";
    let rules = if together {
        format!("together {{ {rules} }}")
    } else {
        rules.to_string()
    };
    format!(
        "model adc_zoh
param Ts = 0.1, K = 2
state x = 1, xs = 0, u = 0
flow {{ x' = -x + u; xs' = 0; u' = 0 }}
{rules}
sim {{ T = 1.05; exact_affine = on }}
"
    )
}

#[test]
fn together_adc_and_zoh_sample_at_the_same_instants() {
    let m = compile(&adc_zoh(true));
    let arc = run(&m);
    let (ts, k) = (0.1_f64, 2.0_f64);
    let a = (-ts).exp();
    // Recursion of the sampled system: x_{k+1} = a x_k + (1 − a) u_k.
    let (mut x, mut xs, mut u) = (1.0_f64, 0.0_f64, 0.0_f64);
    let names = m.state_names();
    let ix = |n: &str| names.iter().position(|s| s == n).unwrap();
    let (ix_x, ix_xs, ix_u) = (ix("x"), ix("xs"), ix("u"));
    let mut js: Vec<u64> = arc.jumps().iter().map(|r| r.at.j).collect();
    js.dedup();
    assert_eq!(js.len(), 10, "one jump per sampling instant");
    for step in 1..=10u64 {
        x = a * x + (1.0 - a) * u;
        let (xs_new, u_new) = (x, -k * xs);
        let recs: Vec<_> = arc.jumps().iter().filter(|r| r.at.j == step - 1).collect();
        assert_eq!(recs.len(), 2, "both rules in jump {step}");
        for r in recs {
            assert!((r.at.t - step as f64 * ts).abs() < 1e-9);
            assert!((r.pre[ix_x] - x).abs() < 1e-9, "x at sample {step}");
            assert!((r.post[ix_xs] - xs_new).abs() < 1e-12);
            assert!((r.post[ix_u] - u_new).abs() < 1e-12);
        }
        xs = xs_new;
        u = u_new;
    }
    // Without `together`: two jumps per instant, and the ZOH sees the new
    // sample (no delay).
    let seq = run(&compile(&adc_zoh(false)));
    assert_eq!(seq.jumps().len(), 20);
    assert_eq!(end(&seq).0.j, 20);
    let first_zoh = &seq.jumps()[1];
    assert!((first_zoh.post[ix_u] - (-k * a)).abs() < 1e-9);
}

#[test]
fn together_in_rust_systems_is_validated() {
    // The engine checks the declared writes of grouped rules.
    struct Two(Vec<JumpRule>);
    impl HybridSystem for Two {
        fn state_dim(&self) -> usize {
            2
        }
        fn state_names(&self) -> Vec<String> {
            vec!["a".into(), "b".into()]
        }
        fn flow_map(&self, _at: HybridTime, _x: &[f64], dx: &mut [f64]) {
            dx.fill(1.0);
        }
        fn jump_rules(&self) -> &[JumpRule] {
            &self.0
        }
        fn jump_set(&self, r: usize, _at: HybridTime, x: &[f64]) -> bool {
            x[r] >= 1.0
        }
        fn jump_guard(&self, r: usize, _at: HybridTime, x: &[f64]) -> f64 {
            x[r] - 1.0
        }
        fn jump_map(
            &self,
            r: usize,
            _at: HybridTime,
            x: &[f64],
            _rng: &mut SimRng,
            x_plus: &mut [f64],
        ) {
            x_plus[r] = 0.0;
            // Writes the other component too, but declares only its own:
            // the engine takes only the declared one.
            x_plus[1 - r] = -x[1 - r];
        }
    }
    let rules = |w0: Vec<usize>, w1: Vec<usize>| {
        Two(vec![
            JumpRule::new("a", GuardKind::General).together(7, w0),
            JumpRule::new("b", GuardKind::General).together(7, w1),
        ])
    };
    let s = SimSettings::default().horizon_t(2.5);
    let ok = rules(vec![0], vec![1]);
    let arc = simulate_arc(&ok, &[0.0, 0.0], &s, &mut SimRng::seed_from(1)).unwrap();
    // Both clocks reach 1 together at t = 1 and 2: one jump each time.
    assert_eq!(end(&arc).0.j, 2);
    assert_eq!(arc.jumps().len(), 4);
    for r in arc.jumps() {
        assert_eq!(r.post, vec![0.0, 0.0]);
    }
    let bad = rules(vec![0, 1], vec![1]);
    let err = simulate_arc(&bad, &[0.0, 0.0], &s, &mut SimRng::seed_from(1)).unwrap_err();
    assert!(err.to_string().contains("written by another rule"), "{err}");
}

// ---- Zeno guard -------------------------------------------------------------

const COUNTER: &str = "model counter
state k = 0
jump step when k >= 0 { k+ = k + 1 }
";

#[test]
fn a_discrete_system_runs_to_a_finite_jump_horizon() {
    // All jumps at t = 0: the Zeno guard must not end it before J.
    let m = compile(&format!("{COUNTER}sim {{ J = 100 }}\n"));
    let arc = run(&m);
    let term = arc.termination().unwrap();
    assert_eq!(term.cause, TerminationCause::HorizonJ);
    assert_eq!(term.at, HybridTime::new(0.0, 100));
    assert_eq!(end(&arc).1, vec![100.0]);
}

#[test]
fn the_zeno_guard_counts_the_jumps_it_reports() {
    // J unbounded: the rate guard stops it after zeno_window = 10 jumps, at
    // j = 10, and says so.
    let arc = run(&compile(COUNTER));
    let term = arc.termination().unwrap();
    assert!(
        matches!(
            term.cause,
            TerminationCause::ZenoSuspected {
                detail: ZenoDetail::Rate { jumps: 10, .. },
                ..
            }
        ),
        "{term:?}"
    );
    assert_eq!(term.at.j, 10);
    assert_eq!(end(&arc).1, vec![10.0]);
    assert!(term.to_string().contains("after 10 jumps"), "{term}");
}

#[test]
fn zeno_knobs_are_sim_keys() {
    let arc = run(&compile(&format!("{COUNTER}sim {{ zeno_window = 4 }}\n")));
    let term = arc.termination().unwrap();
    assert_eq!(term.at.j, 4);
    // The budget holds even with the rate guard off.
    let arc = run(&compile(&format!(
        "{COUNTER}sim {{ zeno_max_rate = inf; max_total_jumps = 250 }}\n"
    )));
    let term = arc.termination().unwrap();
    assert!(
        matches!(
            term.cause,
            TerminationCause::ZenoSuspected {
                detail: ZenoDetail::TotalJumps { limit: 250 },
                ..
            }
        ),
        "{term:?}"
    );
    assert_eq!(term.at.j, 250);
    // The default budget of a run with unbounded J.
    assert_eq!(SimSettings::default().max_total_jumps, 10_000_000);
}

#[test]
fn the_zeno_ball_still_stops_near_its_zeno_time() {
    let m = compile(
        "model ball
param g = 9.81, lambda = 0.8
state h = 1, v = 0
flow { h' = v; v' = -g } in h >= 0
jump impact when h <= 0 && v <= 0 { v+ = -lambda * v }
sim { T = 10 }
",
    );
    let arc = run(&m);
    let term = arc.termination().unwrap();
    assert!(
        matches!(term.cause, TerminationCause::ZenoSuspected { .. }),
        "{term:?}"
    );
    // Zeno time of the ball: t1 (1 + λ)/(1 − λ), t1 = √(2 h0 / g).
    let tz = (2.0_f64 / 9.81).sqrt() * 1.8 / 0.2;
    assert!((term.at.t - tz).abs() < 1e-3, "{} vs {tz}", term.at.t);
}

// ---- the jump counter j --------------------------------------------------------

#[test]
fn j_in_guards_resets_flows_and_outputs() {
    let m = compile(
        "model jcount
state x = 0, y = 0, z = 0
flow { x' = 1; y' = 0; z' = j }
jump r when x >= 1 + j { x+ = 0; y+ = y + 10 * j }
output jo = 2 * j + 0.5
sim { T = 9 }
",
    );
    let arc = run(&m);
    // x restarts from 0 and must reach 1 + j: jumps at t = 1, 3, 6 (the
    // next would be at 10, after T = 9).
    let times: Vec<f64> = arc.jumps().iter().map(|r| r.at.t).collect();
    assert_eq!(times.len(), 3, "{times:?}");
    for (t, want) in times.iter().zip([1.0, 3.0, 6.0]) {
        assert!((t - want).abs() < 1e-9, "{t} vs {want}");
    }
    // Resets see the pre-jump j: y = 10·(0 + 1 + 2).
    let (at, x) = end(&arc);
    assert_eq!(at.j, 3);
    assert!((x[1] - 30.0).abs() < 1e-12);
    // z' = j: ∫ = 0·1 + 1·2 + 2·3 + 3·3 = 17.
    assert!((x[2] - 17.0).abs() < 1e-6, "z = {}", x[2]);
    let mut y = [0.0];
    m.outputs(HybridTime::new(0.0, 7), &[0.0; 3], &mut y);
    assert_eq!(y[0], 14.5);
    // `j` stays an ordinary name where the model declares one.
    let m = compile("model k\nparam j = 4\nstate x = 0\nflow { x' = j }\nsim { T = 1 }\n");
    assert!((end(&run(&m)).1[0] - 4.0).abs() < 1e-9);
}

// ---- functions -----------------------------------------------------------------

#[test]
fn rounding_and_geometry_functions() {
    let m = compile(
        "model f
param p = [round(2.5), round(-2.5), ceil(1.2), frac(-1.25), rem(-7, 3), mod(-7, 3), hypot(3, 4), clamp(5, 0, 1)]
state a = 0
output y = [round(a), ceil(a), frac(a), rem(a, 0.75), hypot(a, 1e200), clamp(a, -1, 1)]
output pp = p
",
    );
    let mut y = vec![0.0; m.output_dim()];
    let eval = |a: f64, y: &mut [f64]| m.outputs(HybridTime::new(0.0, 0), &[a], y);
    eval(-2.5, &mut y);
    let expect = [
        -3.0, -2.0, 0.5, -0.25, 1e200, -1.0, 3.0, -3.0, 2.0, 0.75, -1.0, 2.0, 5.0, 1.0,
    ];
    assert_eq!(y.len(), expect.len());
    for (k, (a, b)) in y.iter().zip(expect).enumerate() {
        assert!((a - b).abs() <= 1e-15 * b.abs().max(1.0), "{k}: {a} vs {b}");
    }
    eval(0.6, &mut y);
    assert_eq!(&y[..6], &[1.0, 1.0, 0.6, 0.6, 1e200, 0.6]);
    // In a flow: ẋ = hypot(3, 4) − clamp(x, 0, 1) from 0 to T = 1 is
    // ẋ = 5 − x while x ≤ 1 … and 4 after: x(t) = 5(1 − e^{−t}) up to x = 1.
    let m = compile(
        "model g\nstate x = 0\nflow { x' = hypot(3, 4) - clamp(x, 0, 1) }\nsim { T = 0.1; rtol = 1e-10; atol = 1e-12 }\n",
    );
    let x = end(&run(&m)).1[0];
    assert!((x - 5.0 * (1.0 - (-0.1_f64).exp())).abs() < 1e-8, "{x}");
}

/// `asin`, `acos`, `sinh`, `cosh`: values (NaN outside asin's and acos's
/// domain), a jump set on `cosh(y) >= 2` reached at y = acosh 2 after each
/// reset, the same with the implicit solver (their derivatives in the
/// Jacobian), and the same bits interpreted and compiled.
#[test]
fn inverse_trigonometric_and_hyperbolic_functions() {
    let m = compile("model f\nstate a = 0\noutput y = [asin(a), acos(a), sinh(a), cosh(a)]\n");
    let mut y = vec![0.0; 4];
    for a in [-1.0, -0.3, 0.0, 0.5, 1.0, 2.5] {
        m.outputs(HybridTime::new(0.0, 0), &[a], &mut y);
        let want = [f64::asin(a), f64::acos(a), f64::sinh(a), f64::cosh(a)];
        for (k, (v, w)) in y.iter().zip(want).enumerate() {
            assert!(
                v.to_bits() == w.to_bits() || v.is_nan() && w.is_nan(),
                "{k} at {a}: {v} vs {w}"
            );
        }
    }
    let src = |solver: &str| {
        format!(
            "model g\nstate x = 0.5, y = 0, n = 0\noutput s = asin(x) + acos(x)\n\
             flow {{ x' = -0.1 * cos(asin(x)); y' = 1 + 0 * sinh(x) }}\n\
             jump hit when cosh(y) >= 2 {{ y+ = 0; n+ = n + 1 }}\n\
             sim {{ T = 5; solver = {solver}; rtol = 1e-10; atol = 1e-12 }}\n"
        )
    };
    for solver in ["dopri5", "radau5"] {
        let arc = run(&compile(&src(solver)));
        let times: Vec<f64> = arc.jumps().iter().map(|r| r.at.t).collect();
        assert_eq!(times.len(), 3, "{solver}: {times:?}");
        for (k, t) in times.iter().enumerate() {
            let want = (k + 1) as f64 * 2f64.acosh();
            assert!(
                (t - want).abs() < 1e-9,
                "{solver}: jump {k} at {t}, want {want}"
            );
        }
        // x' = −0.1 √(1 − x²): x = sin(asin(0.5) − 0.1 t).
        let x = end(&arc).1[0];
        let want = (0.5f64.asin() - 0.5).sin();
        assert!((x - want).abs() < 1e-8, "{solver}: x(5) = {x}, want {want}");
    }
}

// ---- brief crossings --------------------------------------------------------

/// A thrown stone whose apex clears the line `x = 1` by `d`: it is above the
/// line for 2·√(2d) of time, inside one integrator step (the solvers are
/// exact on the parabola and take long steps), between the step's
/// checkpoints. The guard is affine, so the watcher finds the crossing from
/// the step's control points, however brief, at the closed-form time, with
/// every solver whose steps give them; a stone that stays below the line
/// (d < 0) does not jump.
#[test]
fn a_crossing_inside_one_step_is_found_for_affine_guards() {
    let cases = ["dopri5", "dop853", "rk4", "radau5"]
        .into_iter()
        .flat_map(|s| [1e-3_f64, 1e-6, 1e-10, -1e-10].map(|d| (s, d)));
    for (solver, d) in cases {
        let m = compile(&format!(
            "model graze
             param d = {d}
             state x = 0, v = sqrt(2 * (1 + d)), n = 0
             flow {{
                 x' = v
                 v' = -1
                 n' = 0
             }}
             jump hit when x >= 1 && n == 0 {{
                 n+ = 1
             }}
             sim {{ T = 3; solver = {solver} }}"
        ));
        let arc = run(&m);
        let jumps = arc.jumps();
        if d < 0.0 {
            assert!(jumps.is_empty(), "{solver}, d = {d}: {jumps:?}");
            continue;
        }
        assert_eq!(jumps.len(), 1, "{solver}, d = {d}");
        // x(t) = v0 t − t²/2 reaches 1 at v0 − √(v0² − 2); near the apex
        // x changes by √(2d) per unit time, so an error δ in x moves t by
        // δ/√(2d): ~ε/√d for Dopri5 (its quartic holds the parabola
        // exactly), more for solvers whose steps carry rounding of their
        // stages (1.2e-12 at d = 1e-3 measured).
        let v0 = (2.0 * (1.0 + d)).sqrt();
        let t = v0 - (2.0 * d).sqrt();
        let err = (jumps[0].at.t - t).abs();
        let allowed = if solver == "dopri5" { 1e-15 } else { 1e-13 } / d.sqrt() + 1e-14;
        assert!(
            err <= allowed,
            "{solver}, d = {d}: {} vs {t}",
            jumps[0].at.t
        );
    }
}

/// The components whose boxes the atoms' bounds read include a state that
/// is an atom by itself (`x >= 0`: the atom's value is `x`'s register, read
/// by no instruction), beside those read by instructions.
#[test]
fn atom_bounds_read_a_state_that_is_an_atom_by_itself() {
    let m = compile(
        "model m\nstate x = 1, y = 1, z = 2, w = 0\n\
         flow { x' = -y; y' = z; z' = 1; w' = 1 } in x >= 0 || y * z >= 1\n",
    );
    assert_eq!(m.atom_bound_inputs(), Some(vec![0, 1, 2]));
}

/// Which atoms are timers the engine schedules: a timer against a constant,
/// or against terms that change only at jumps (parameters indexed by a mode,
/// states without flow, `j`): the threshold is then read at each segment's
/// start. Terms that move along flows (another state, `t`) or a scaled
/// timer leave the atom watched.
#[test]
fn timer_atoms_against_terms_fixed_between_jumps_are_scheduled() {
    use hybsim::engine::{SetRef, Threshold};
    let m = compile(
        "model timers
param d = [0.3, 0.7]
state x = 1, q = 2, T = 0.25, tau = 0.1
flow { x' = -x; tau' = 1 }
jump a when tau >= 0.5 { tau+ = 0 }
jump b when tau >= d[q] { tau+ = 0 }
jump c when d[q] + T - tau <= j { tau+ = 0 }
jump e when tau >= x { tau+ = 0 }
jump f when tau >= d[q] + t { tau+ = 0 }
jump g when 2 * tau >= d[q] { tau+ = 0 }
sim { T = 1 }
",
    );
    let timer = |r: usize| m.set_atoms(SetRef::Jump(r)).expect("atoms").atoms[0].timer;
    assert_eq!(timer(0), Some((3, Threshold::Const(0.5))));
    assert_eq!(timer(1), Some((3, Threshold::PerSegment)));
    assert_eq!(timer(2), Some((3, Threshold::PerSegment)));
    for r in 3..6 {
        assert_eq!(timer(r), None, "rule {r}");
    }
    let x = [1.0, 2.0, 0.25, 0.1];
    let at = HybridTime::new(0.0, 3);
    assert_eq!(m.timer_threshold(SetRef::Jump(1), 0, at, &x), 0.7);
    assert_eq!(
        m.timer_threshold(SetRef::Jump(2), 0, at, &x),
        0.7 + 0.25 - 3.0
    );
}
