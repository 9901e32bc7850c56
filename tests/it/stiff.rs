//! Stiff flows on the implicit solver (`solver = radau5`), through the real
//! pipeline (parse → check → compile → simulate), against references that
//! do not come from hybsim: scipy's Radau at rtol 1e-12 (stored with its
//! generator in `tests/data/stiff_reference.*`) for Van der Pol and
//! Robertson, and a closed form for a thermostat with a fast sensor.
//!
//! Accuracy bound used throughout: a component of the final state is within
//! `10·(rtol·|ref| + atol)` of the reference (the global error of a
//! well-behaved run stays within a small multiple of the local tolerance).

use crate::util::simulate_arc;
use hybsim::arc::{HybridArc, HybridTime, SampleKind, TerminationCause};
use hybsim::engine::models::BouncingBall;
use hybsim::engine::{HybridSystem, SimError, SimRng, SimSettings, Solver, check_arc};
use hybsim::ir::CompiledModel;
use hybsim::lang;
use hybsim::source::SourceFile;
use serde_json::Value;

fn compile(src: &str) -> CompiledModel {
    let file = SourceFile::new("t.hyb", src);
    match lang::compile(&file, &[]) {
        Ok(m) => m,
        Err(d) => panic!("{}", hybsim::diagnostics::render(&d, &file, false)),
    }
}

fn run_with(m: &CompiledModel, settings: &SimSettings) -> Result<HybridArc, SimError> {
    let (x0, mut rng) = m.start(m.seed());
    let arc = simulate_arc(m, &x0, settings, &mut rng)?;
    if let Err(v) = check_arc(m, &arc, settings) {
        panic!("{v}");
    }
    Ok(arc)
}

fn reference(key: &str) -> Vec<f64> {
    let text = include_str!("../data/stiff_reference.json");
    let v: Value = serde_json::from_str(text).expect("reference JSON");
    v[key]["rtol_1e-12"]
        .as_array()
        .unwrap_or_else(|| panic!("no reference {key}"))
        .iter()
        .map(|x| x.as_f64().expect("number"))
        .collect()
}

fn final_state(arc: &HybridArc) -> Vec<f64> {
    arc.samples().last().expect("a final sample").x.to_vec()
}

/// Final state within 10·(rtol·|ref| + atol) per component.
fn assert_close(what: &str, got: &[f64], want: &[f64], rtol: f64, atol: f64) {
    assert_eq!(got.len(), want.len());
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        let bound = 10.0 * (rtol * w.abs() + atol);
        assert!(
            (g - w).abs() <= bound,
            "{what}: component {i} = {g}, reference {w} (error {:e} > {bound:e})",
            (g - w).abs()
        );
    }
}

const VAN_DER_POL: &str = "model van_der_pol
param mu = 1000
state x = 2, y = 0
flow {
    x' = y
    y' = mu * (1 - x^2) * y - x
}
sim { T = 3000; solver = radau5 }
";

/// Van der Pol with μ = 1000 to T = 3000 (almost two relaxation periods)
/// completes in a few thousand steps and ends at scipy's Radau reference,
/// at the default and at tight tolerances.
#[test]
fn van_der_pol_mu_1000_matches_the_reference() {
    let m = compile(VAN_DER_POL);
    let want = reference("van_der_pol_mu1000_t3000");
    for (rtol, atol) in [(1e-6, 1e-9), (1e-9, 1e-12)] {
        let settings = m.settings().solver(Solver::Radau5 { rtol, atol });
        let arc = run_with(&m, &settings).expect("Radau5 runs to T");
        assert_eq!(
            arc.termination().map(|t| t.cause.clone()),
            Some(TerminationCause::HorizonT)
        );
        let steps = arc.samples().filter(|s| s.kind == SampleKind::Flow).count();
        assert!(steps < 20_000, "rtol {rtol}: {steps} flow samples");
        assert_close(
            &format!("Van der Pol, rtol {rtol}"),
            &final_state(&arc),
            &want,
            rtol,
            atol,
        );
    }
}

/// The explicit default stops with the stiffness error, whose help names
/// the implicit solver.
#[test]
fn the_stiffness_error_recommends_radau5() {
    let m = compile(VAN_DER_POL);
    let settings = m.settings().solver(Solver::default());
    let err = run_with(&m, &settings).expect_err("Dopri5 gives up");
    assert!(matches!(err, SimError::Stiff { .. }), "{err}");
    assert!(err.help().contains("radau5"), "{}", err.help());
}

/// Robertson's chemical kinetics (rates over 9 orders of magnitude) at the
/// classic t = 40 (y ≈ 0.7158, 9.185e-6, 0.2842) and at t = 1e5, against
/// scipy's Radau at rtol 1e-12.
#[test]
fn robertson_matches_the_reference() {
    let m = compile(
        "model robertson
state y1 = 1, y2 = 0, y3 = 0
flow {
    y1' = -0.04 * y1 + 1e4 * y2 * y3
    y2' = 0.04 * y1 - 1e4 * y2 * y3 - 3e7 * y2^2
    y3' = 3e7 * y2^2
}
sim { T = 40; solver = radau5; rtol = 1e-6; atol = 1e-12 }
",
    );
    for (t_end, key) in [(40.0, "robertson_t40"), (1e5, "robertson_t100000")] {
        let want = reference(key);
        for (rtol, atol) in [(1e-6, 1e-12), (1e-9, 1e-14)] {
            let settings = m
                .settings()
                .horizon_t(t_end)
                .solver(Solver::Radau5 { rtol, atol });
            let arc = run_with(&m, &settings).expect("Radau5 runs to T");
            let x = final_state(&arc);
            assert_close(
                &format!("Robertson to {t_end}, rtol {rtol}"),
                &x,
                &want,
                rtol,
                atol,
            );
            // Mass is conserved by the flow (a linear invariant, kept by
            // any Runge–Kutta method up to the Newton tolerance).
            let mass: f64 = x.iter().sum();
            assert!((mass - 1.0).abs() < 1e-9, "mass {mass}");
        }
    }
    // The classic values (y ≈ 0.7158271, 9.185535e-6, 0.2841637), to half
    // a unit of their last digit.
    let classic = [(0.7158271, 5e-8), (9.185535e-6, 5e-13), (0.2841637, 5e-8)];
    let x = final_state(&run_with(&m, &m.settings()).unwrap());
    for (g, (c, tol)) in x.iter().zip(classic) {
        assert!((g - c).abs() <= tol, "{g} vs classic {c}");
    }
}

/// A thermostat whose hysteresis relay reads a sensor with time constant
/// τ = 1e-5 h on a room with time constant 2 h (stiffness ratio 2·10⁵).
/// With X the room's equilibrium in the current mode, the sensor follows
/// z(t) = X + (x(t₀) − X) e^{−a(t−t₀)} / (1 − aτ) plus a transient
/// e^{−(t−t₀)/τ} that is below 1e-300 at the next switch, so each switch
/// comes after d = ln((x(t₀) − X) / ((1 − aτ)(θ − X))) / a at the threshold
/// θ. The jump times match the closed form to 1e-8, each jump starts from a
/// point of D ([`check_arc`]), and the explicit solver gives up.
#[test]
fn stiff_thermostat_switches_at_the_closed_form_times() {
    let (a, xa, p, xlo, xhi, tau) = (0.5, 5.0, 12.0, 18.0, 22.0, 1e-5);
    let m = compile(&format!(
        "model stiff_thermostat
param a = {a}, xa = {xa}, p = {p}, xlo = {xlo}, xhi = {xhi}, tau = {tau}
state x = 20, z = 20, q = 1
flow {{
    x' = -a * (x - xa) + p * q
    z' = (x - z) / tau
}} in (q == 1 && z <= xhi) || (q == 0 && z >= xlo)
jump switch_off when q == 1 && z >= xhi {{ q+ = 0 }}
jump switch_on  when q == 0 && z <= xlo {{ q+ = 1 }}
sim {{ T = 24; solver = radau5; rtol = 1e-10; atol = 1e-12; exact_affine = off }}
"
    ));
    let arc = run_with(&m, &m.settings()).expect("Radau5 runs to T");
    let (mut x, mut q, mut t) = (20.0f64, 1.0, 0.0);
    let mut expected = Vec::new();
    loop {
        let big_x = xa + p * q / a;
        let theta = if q == 1.0 { xhi } else { xlo };
        let d = ((x - big_x) / ((1.0 - a * tau) * (theta - big_x))).ln() / a;
        if t + d >= 24.0 {
            break;
        }
        t += d;
        x = big_x + (x - big_x) * (-a * d).exp();
        q = 1.0 - q;
        expected.push(t);
    }
    let got: Vec<f64> = arc.jumps().iter().map(|r| r.at.t).collect();
    assert_eq!(got.len(), expected.len(), "{got:?} vs {expected:?}");
    for (k, (g, e)) in got.iter().zip(&expected).enumerate() {
        assert!(
            (g - e).abs() <= 1e-8,
            "switch {k} at {g}, closed form {e} (error {:e})",
            (g - e).abs()
        );
    }
    assert!(expected.len() >= 30, "{} switches", expected.len());
    // Explicit Dopri5 needs steps of order τ and gives up.
    let explicit = m.settings().solver(Solver::default());
    assert!(matches!(
        run_with(&m, &explicit),
        Err(SimError::Stiff { .. })
    ));
}

/// A Rust system without a `jacobian` (finite differences by default) on
/// the implicit path: the bouncing ball's impacts at the closed-form times
/// and values (its flow is quadratic in t, which the collocation
/// polynomial follows exactly), the Zeno guard ending the run at the Zeno
/// time.
#[test]
fn radau5_keeps_the_hybrid_semantics_of_a_rust_system() {
    let ball = BouncingBall::new(9.81, 0.8);
    let settings = SimSettings::default()
        .horizon_t(10.0)
        .exact_affine(false)
        .solver(Solver::Radau5 {
            rtol: 1e-10,
            atol: 1e-12,
        });
    let arc = simulate_arc(&ball, &[1.0, 0.0], &settings, &mut SimRng::seed_from(0))
        .expect("simulation runs");
    if let Err(v) = check_arc(&ball, &arc, &settings) {
        panic!("{v}");
    }
    let exact = ball.impacts(1.0, 10);
    assert!(
        arc.jumps().len() >= 10,
        "{} impacts, {:?}",
        arc.jumps().len(),
        arc.termination()
    );
    for (k, (jump, (t, v))) in arc.jumps().iter().zip(&exact).enumerate() {
        assert!(
            (jump.at.t - t).abs() <= 1e-9 * t,
            "impact {k}: t = {} vs {t}",
            jump.at.t
        );
        assert!(
            (jump.pre[1] - v).abs() <= 1e-9 * v.abs(),
            "impact {k}: v = {} vs {v}",
            jump.pre[1]
        );
    }
    let term = arc.termination().expect("terminated");
    assert!(
        matches!(term.cause, TerminationCause::ZenoSuspected { .. }),
        "{term}"
    );
    assert!((term.at.t - ball.zeno_time(1.0)).abs() < 1e-4);
}

/// ∂f/∂x at a perturbed state by central differences of the flow map, with
/// steps δ_c = ε^(1/3)·max(|x_c|, 1) (error ~1e-10 relative).
fn central_differences(m: &CompiledModel, at: HybridTime, x: &[f64]) -> Vec<f64> {
    let n = x.len();
    let mut jac = vec![0.0; n * n];
    let (mut xp, mut fp, mut fm) = (x.to_vec(), vec![0.0; n], vec![0.0; n]);
    for c in 0..n {
        let d = f64::EPSILON.cbrt() * x[c].abs().max(1.0);
        xp[c] = x[c] + d;
        m.flow_map(at, &xp, &mut fp);
        xp[c] = x[c] - d;
        m.flow_map(at, &xp, &mut fm);
        xp[c] = x[c];
        for r in 0..n {
            jac[r * n + c] = (fp[r] - fm[r]) / (2.0 * d);
        }
    }
    jac
}

/// The symbolic Jacobian equals central differences of the flow map to
/// 1e-7 (relative to the row's largest entry, at least 1) at 20 random
/// states (the initial state moved by up to 20 % plus ±1, seeded) of every
/// shipped model and of a model using every differentiable function.
#[test]
fn symbolic_jacobian_matches_finite_differences() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models");
    let mut sources: Vec<(String, String)> = std::fs::read_dir(&dir)
        .expect("models/")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "hyb"))
        .map(|p| {
            (
                p.display().to_string(),
                std::fs::read_to_string(&p).unwrap(),
            )
        })
        .collect();
    sources.sort();
    assert!(sources.len() >= 5);
    sources.push((
        "every function".into(),
        "model every_function
state a = 0.7, b = -1.3, c = 2.1, q = 1
flow {
    a' = sin(a) * cos(b) + tan(0.3 * c) - atan(a * b) + tanh(c - a) + exp(-a^2) * log(1 + c^2)
    b' = sqrt(1 + a^2) / (2 + b^2) + abs(b) * a^3 + hypot(a, c) - atan2(b, c) + c^(a / 3 + 1)
    c' = min(a, b) * max(b, c) + mod(a * c, 0.7) - rem(b * c, 0.4) + (if a > b then a * c else b^2) + sign(a) * floor(c) + q * a
    q' = 0
}
sim { T = 1 }
"
        .into(),
    ));
    let mut rng = SimRng::seed_from(22);
    for (name, src) in &sources {
        let file = SourceFile::new(name.as_str(), src.as_str());
        let m = lang::compile(&file, &[])
            .unwrap_or_else(|d| panic!("{}", hybsim::diagnostics::render(&d, &file, false)));
        assert!(m.has_exact_jacobian(), "{name}: no symbolic Jacobian");
        let (x0, _) = m.start(m.seed());
        let n = x0.len();
        let mut jac = vec![0.0; n * n];
        for _ in 0..20 {
            let x: Vec<f64> = x0
                .iter()
                .map(|v| v * rng.uniform(0.8, 1.2) + rng.uniform(-1.0, 1.0))
                .collect();
            let at = HybridTime::new(rng.uniform(0.0, 5.0), 0);
            m.jacobian(at, &x, &mut jac);
            let fd = central_differences(&m, at, &x);
            for r in 0..n {
                let row = &fd[r * n..(r + 1) * n];
                let scale = row.iter().fold(1.0f64, |s, v| s.max(v.abs()));
                for c in 0..n {
                    let (s, d) = (jac[r * n + c], fd[r * n + c]);
                    assert!(
                        (s - d).abs() <= 1e-7 * scale,
                        "{name}: ∂f{r}/∂x{c} = {s}, finite differences {d} at x = {x:?}"
                    );
                }
            }
        }
    }
}
