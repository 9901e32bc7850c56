//! Stiff flows on the implicit solvers (`solver = radau5`, `solver = bdf`),
//! through the real pipeline (parse → check → compile → simulate), against references that
//! do not come from hybsim: scipy's Radau at rtol 1e-12 (stored with its
//! generator in `tests/data/stiff_reference.*`) for Van der Pol and
//! Robertson, and a closed form for a thermostat with a fast sensor.
//!
//! Accuracy bound used throughout: a component of the final state is within
//! `c·(rtol·|ref| + atol)` of the reference (the global error of a
//! well-behaved run stays within a small multiple of the local tolerance):
//! c = 10 for the Runge–Kutta methods (Radau5, Dopri5 under `auto`), c =
//! 50 for BDF, whose global error is a larger multiple of its local
//! tolerance: scipy 1.17's own BDF ends Van der Pol at 15 (rtol 1e-6) and
//! 33 (rtol 1e-9) times the tolerance, Robertson at 6 and 20 times
//! (hybsim's BDF: 21, 31, and at most 20).

use crate::util::{compile, simulate_arc};
use hybsim::arc::{HybridArc, HybridTime, SampleKind, TerminationCause};
use hybsim::engine::models::{BouncingBall, HeatChain, OverlapDemo, SampleAndHold};
use hybsim::engine::{
    HybridSystem, LinearSolver, Priority, SimError, SimRng, SimSettings, Solver, check_arc,
    use_sparse_lu,
};
use hybsim::ir::CompiledModel;
use hybsim::lang;
use hybsim::source::SourceFile;
use nalgebra::DMatrix;
use serde_json::Value;

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

/// The implicit solvers, by name, with these tolerances.
const IMPLICIT: [&str; 2] = ["radau5", "bdf"];

fn implicit(name: &str, rtol: f64, atol: f64) -> Solver {
    Solver::adaptive(name, rtol, atol).expect("an adaptive solver")
}

fn final_state(arc: &HybridArc) -> Vec<f64> {
    arc.samples().last().expect("a final sample").x.to_vec()
}

/// Final state within c·(rtol·|ref| + atol) per component (c: see the
/// module docs).
fn assert_close(what: &str, got: &[f64], want: &[f64], (rtol, atol): (f64, f64), solver: &str) {
    assert_eq!(got.len(), want.len());
    let c = if solver == "bdf" { 50.0 } else { 10.0 };
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        let bound = c * (rtol * w.abs() + atol);
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
/// at the default and at tight tolerances, on both implicit solvers.
#[test]
fn van_der_pol_mu_1000_matches_the_reference() {
    let m = compile(VAN_DER_POL);
    let want = reference("van_der_pol_mu1000_t3000");
    for (name, rtol, atol) in IMPLICIT
        .into_iter()
        .flat_map(|name| [(name, 1e-6, 1e-9), (name, 1e-9, 1e-12)])
    {
        let settings = m.settings().solver(implicit(name, rtol, atol));
        let arc = run_with(&m, &settings).expect("the implicit solver runs to T");
        assert_eq!(
            arc.termination().map(|t| t.cause.clone()),
            Some(TerminationCause::HorizonT)
        );
        let steps = arc.samples().filter(|s| s.kind == SampleKind::Flow).count();
        assert!(steps < 20_000, "{name} rtol {rtol}: {steps} flow samples");
        assert_close(
            &format!("Van der Pol, {name}, rtol {rtol}"),
            &final_state(&arc),
            &want,
            (rtol, atol),
            name,
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

/// The stiffness error names the component the stiff mode moves, not the
/// one changing fastest: `a` relaxes to 1 at rate 1e5 (stiff, and after
/// its transient it barely changes) while `b` grows at 1e6 per second
/// (relative to the tolerances the fastest by far, the component the
/// error named before). Both declaration orders, so the answer is no
/// index's luck.
#[test]
fn the_stiffness_error_names_the_component_of_the_stiff_mode() {
    for states in ["a = 0, b = 0", "b = 0, a = 0"] {
        let src = format!(
            "model stiff_mode\nstate {states}\nflow {{\n    a' = -1e5 * (a - 1)\n    \
             b' = 1e6\n}}\nsim {{ T = 10; solver = dopri5 }}\n"
        );
        let m = compile(&src);
        let err = run_with(&m, &m.settings()).expect_err("Dopri5 gives up");
        let SimError::Stiff { name, .. } = &err else {
            panic!("{states}: {err}");
        };
        assert_eq!(name, "a", "{states}: {err}");
        let shown = err.to_string();
        assert!(shown.contains("stiff mode moves `a` most"), "{shown}");
        // The diagnostic points at `a`'s flow equation.
        let d = m.runtime_diagnostic(&err);
        let lc = d.line_col(m.source()).expect("located");
        assert_eq!(lc.line, 4, "{states}: {:?}", d.labels);
        assert!(
            d.labels[0].message.contains("moved most by the stiff mode"),
            "{:?}",
            d.labels
        );
    }
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
        for (name, rtol, atol) in IMPLICIT
            .into_iter()
            .flat_map(|name| [(name, 1e-6, 1e-12), (name, 1e-9, 1e-14)])
        {
            let settings = m
                .settings()
                .horizon_t(t_end)
                .solver(implicit(name, rtol, atol));
            let arc = run_with(&m, &settings).expect("the implicit solver runs to T");
            let x = final_state(&arc);
            assert_close(
                &format!("Robertson to {t_end}, {name}, rtol {rtol}"),
                &x,
                &want,
                (rtol, atol),
                name,
            );
            // Mass is conserved by the flow (a linear invariant, kept by
            // Runge–Kutta and multistep methods up to the Newton tolerance).
            let mass: f64 = x.iter().sum();
            assert!((mass - 1.0).abs() < 1e-9, "{name}: mass {mass}");
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
/// θ. The jump times match the closed form to 1e-8 on both implicit
/// solvers and on `solver = auto` (which turns to Radau5 in the first flow
/// and stays there), each jump starts from a point of D ([`check_arc`]),
/// and the explicit solver gives up.
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
    assert!(expected.len() >= 30, "{} switches", expected.len());
    for name in IMPLICIT.into_iter().chain(["auto"]) {
        let settings = m.settings().solver(implicit(name, 1e-11, 1e-13));
        let arc = run_with(&m, &settings).expect("the implicit solver runs to T");
        if name == "auto" {
            let switches = arc.solver_switches();
            assert!(
                !switches.is_empty() && switches[0].to == "radau5" && switches[0].at.j == 0,
                "{switches:?}"
            );
        }
        let got: Vec<f64> = arc.jumps().iter().map(|r| r.at.t).collect();
        assert_eq!(got.len(), expected.len(), "{name}: {got:?} vs {expected:?}");
        for (k, (g, e)) in got.iter().zip(&expected).enumerate() {
            assert!(
                (g - e).abs() <= 1e-8,
                "{name}: switch {k} at {g}, closed form {e} (error {:e})",
                (g - e).abs()
            );
        }
    }
    // Explicit Dopri5 needs steps of order τ and gives up.
    let explicit = m.settings().solver(Solver::default());
    assert!(matches!(
        run_with(&m, &explicit),
        Err(SimError::Stiff { .. })
    ));
}

/// `solver = auto` on Van der Pol (μ = 1000): Dopri5 finds the flow stiff
/// within its first steps and hands it to Radau5, which hands it back in
/// the fast relaxations (where the flow is not stiff) and takes it again
/// after; the run ends at scipy's reference within the tolerance, in
/// fewer steps than Radau5 alone would need with Dopri5's.
#[test]
fn auto_switches_on_van_der_pol_and_matches_the_reference() {
    let m = compile(VAN_DER_POL);
    let want = reference("van_der_pol_mu1000_t3000");
    for (rtol, atol) in [(1e-6, 1e-9), (1e-9, 1e-12)] {
        let settings = m.settings().solver(Solver::Auto { rtol, atol });
        let arc = run_with(&m, &settings).expect("auto runs to T");
        let switches = arc.solver_switches();
        assert!(!switches.is_empty(), "rtol {rtol}: no switch");
        assert_eq!(switches[0].to, "radau5");
        assert!(switches[0].at.t < 1.0, "{:?}", switches[0]);
        // The switches alternate.
        for w in switches.windows(2) {
            assert_ne!(w[0].to, w[1].to, "{switches:?}");
            assert!(w[0].at.t <= w[1].at.t);
        }
        let steps = arc.samples().filter(|s| s.kind == SampleKind::Flow).count();
        assert!(steps < 40_000, "rtol {rtol}: {steps} flow samples");
        assert_close(
            &format!("Van der Pol, auto, rtol {rtol}"),
            &final_state(&arc),
            &want,
            (rtol, atol),
            "auto",
        );
    }
}

/// On flows that never turn stiff, `solver = auto` is Dopri5: the same arc
/// bit for bit (samples, jumps, termination) and no switch, on a damped
/// pendulum with impacts and a timer, and on the bouncing ball.
#[test]
fn auto_on_non_stiff_models_gives_the_dopri5_arc_exactly() {
    let pendulum = compile(
        "model pendulum_with_a_wall
param g = 9.81, l = 1, c = 0.2, e = 0.7
state th = 1, om = 0, tau = 0, k = 0
flow {
    th' = om
    om' = -g / l * sin(th) - c * om
    tau' = 1
    k' = 0
} in th >= -0.5
jump wall when th <= -0.5 && om < 0 { om+ = -e * om }
jump tick when tau >= 0.3 { tau+ = 0; k+ = k + 1 }
sim { T = 20; rtol = 1e-8; atol = 1e-10; exact_affine = off }
",
    );
    let ball_src = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/bouncing_ball.hyb"),
    )
    .unwrap();
    let ball = compile(&ball_src);
    for m in [&pendulum, &ball] {
        let (rtol, atol) = m.settings().solver.tolerances().unwrap();
        let explicit = run_with(m, &m.settings().solver(Solver::Dopri5 { rtol, atol })).unwrap();
        let auto = run_with(m, &m.settings().solver(Solver::Auto { rtol, atol })).unwrap();
        assert!(
            auto.solver_switches().is_empty(),
            "{:?}",
            auto.solver_switches()
        );
        assert!(explicit.jumps().len() > 3);
        assert_eq!(auto.jumps(), explicit.jumps());
        assert_eq!(auto.termination(), explicit.termination());
        let (a, e): (Vec<_>, Vec<_>) = (auto.samples().collect(), explicit.samples().collect());
        assert_eq!(a.len(), e.len());
        for (a, e) in a.iter().zip(&e) {
            assert_eq!((a.at, a.kind, a.x), (e.at, e.kind, e.x));
        }
    }
}

/// A run on `solver = auto` reports its switches: in the summary line of
/// `hybsim run`, in its `--json` summary and in the MCAP file (the
/// `hybsim.result` metadata and a log message per switch); a run that
/// never switches says so.
#[test]
fn auto_switches_are_in_the_summary_and_the_mcap_metadata() {
    use crate::util::{code, hybsim, stderr, stdout};
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("vdp.hyb");
    std::fs::write(&model, VAN_DER_POL.replace("T = 3000", "T = 100")).unwrap();
    let out = hybsim(
        dir.path(),
        &["run", "vdp.hyb", "--solver", "auto", "-q", "-o", "vdp.mcap"],
    );
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let line = stdout(&out) + &stderr(&out);
    assert!(
        line.contains("solver auto: ") && line.contains("radau5 at (t = "),
        "{line}"
    );
    let bytes = std::fs::read(dir.path().join("vdp.mcap")).unwrap();
    let result = crate::util::mcap_metadata(&bytes, "hybsim.result");
    let total: u64 = result["solver_switches_total"].parse().unwrap();
    let list: Value = serde_json::from_str(&result["solver_switches"]).unwrap();
    assert!(total >= 1, "{result:?}");
    assert_eq!(list.as_array().unwrap().len() as u64, total);
    assert_eq!(list[0]["to"], "radau5");
    assert!(list[0]["at"]["t"].as_f64().unwrap() < 1.0, "{list}");
    let solver = crate::util::mcap_metadata(&bytes, "hybsim.solver");
    assert!(solver["solver"].contains("auto"), "{solver:?}");
    let json = hybsim(
        dir.path(),
        &[
            "run",
            "vdp.hyb",
            "--solver",
            "auto",
            "-q",
            "--no-mcap",
            "--json",
        ],
    );
    assert_eq!(code(&json), 0, "{}", stderr(&json));
    let v: Value = serde_json::from_str(&stdout(&json)).unwrap();
    assert_eq!(v["solver"], "auto");
    assert_eq!(v["solver_switches_total"].as_u64(), Some(total));
    // A flow that is not stiff: Dopri5 throughout.
    std::fs::write(
        &model,
        VAN_DER_POL
            .replace("mu = 1000", "mu = 1")
            .replace("T = 3000", "T = 10"),
    )
    .unwrap();
    let out = hybsim(
        dir.path(),
        &["run", "vdp.hyb", "--solver", "auto", "-q", "--no-mcap"],
    );
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let line = stdout(&out) + &stderr(&out);
    assert!(line.contains("solver auto: dopri5 throughout"), "{line}");
}

/// `bdf` and `auto` are `solver` values of the `sim` block (tolerances
/// kept) and of `--solver` (which keeps the model's tolerances and takes
/// `--rtol`), named in the logs' settings.
#[test]
fn bdf_and_auto_are_sim_keys_and_flags() {
    use crate::util::{code, hybsim, stderr, stdout};
    for (name, want) in [
        (
            "bdf",
            Solver::Bdf {
                rtol: 1e-7,
                atol: 1e-11,
            },
        ),
        (
            "auto",
            Solver::Auto {
                rtol: 1e-7,
                atol: 1e-11,
            },
        ),
    ] {
        let src = VAN_DER_POL.replace(
            "solver = radau5",
            &format!("solver = {name}; rtol = 1e-7; atol = 1e-11"),
        );
        assert_eq!(compile(&src).settings().solver, want);
    }
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("vdp.hyb"),
        VAN_DER_POL.replace("T = 3000", "T = 10"),
    )
    .unwrap();
    for name in ["bdf", "auto"] {
        let out = hybsim(
            dir.path(),
            &[
                "run",
                "vdp.hyb",
                "--solver",
                name,
                "--rtol",
                "1e-7",
                "-q",
                "--no-mcap",
                "--json",
            ],
        );
        assert_eq!(code(&out), 0, "{}", stderr(&out));
        let v: Value = serde_json::from_str(&stdout(&out)).unwrap();
        assert_eq!(v["solver"], name);
        assert_eq!(v["cause"], "horizon_t", "{v}");
    }
}

/// Rust systems without a `jacobian` (finite differences by default; the
/// ball, the overlap demo) and with one (the sample-and-hold loop) on both
/// implicit solvers keep the hybrid semantics: the bouncing ball's
/// impacts at the closed-form times and values (its flow is quadratic in t,
/// which both dense outputs follow) and the Zeno guard (at its default
/// rate) ending the run at the Zeno time; the priorities on overlapping sets (jumps first resets at
/// t = 1, 2, 3, …, flows first at 2, 4, 6, …); and timers on a stiff
/// sampled-data loop (plant eigenvalues −1000 and −1), whose samples land
/// exactly on the sampling instants and match the exact discretization.
#[test]
fn implicit_solvers_keep_the_hybrid_semantics_of_rust_systems() {
    for name in IMPLICIT {
        let settings = SimSettings::default()
            .horizon_t(10.0)
            .exact_affine(false)
            .solver(implicit(name, 1e-10, 1e-12));
        let ball = BouncingBall::new(9.81, 0.8);
        let ball_settings = settings.clone();
        let arc = simulate_arc(
            &ball,
            &[1.0, 0.0],
            &ball_settings,
            &mut SimRng::seed_from(0),
        )
        .expect("simulation runs");
        if let Err(v) = check_arc(&ball, &arc, &ball_settings) {
            panic!("{name}: {v}");
        }
        let exact = ball.impacts(1.0, 10);
        assert!(
            arc.jumps().len() >= 10,
            "{name}: {} impacts, {:?}",
            arc.jumps().len(),
            arc.termination()
        );
        for (k, (jump, (t, v))) in arc.jumps().iter().zip(&exact).enumerate() {
            assert!(
                (jump.at.t - t).abs() <= 1e-9 * t,
                "{name}: impact {k}: t = {} vs {t}",
                jump.at.t
            );
            assert!(
                (jump.pre[1] - v).abs() <= 1e-9 * v.abs(),
                "{name}: impact {k}: v = {} vs {v}",
                jump.pre[1]
            );
        }
        let term = arc.termination().expect("terminated");
        assert!(
            matches!(term.cause, TerminationCause::ZenoSuspected { .. }),
            "{name}: {term}"
        );
        assert!((term.at.t - ball.zeno_time(1.0)).abs() < 1e-4);

        let demo = OverlapDemo::default();
        for (priority, period) in [(Priority::Jumps, 1.0), (Priority::Flows, 2.0)] {
            let settings = settings.clone().horizon_t(7.5).priority(priority);
            let arc = simulate_arc(&demo, &[0.0], &settings, &mut SimRng::seed_from(0))
                .expect("simulation runs");
            if let Err(v) = check_arc(&demo, &arc, &settings) {
                panic!("{name} {priority:?}: {v}");
            }
            let times: Vec<f64> = arc.jumps().iter().map(|r| r.at.t).collect();
            let want: Vec<f64> = (1..)
                .map(|k| k as f64 * period)
                .take_while(|&t| t < 7.5)
                .collect();
            assert_eq!(times.len(), want.len(), "{name} {priority:?}: {times:?}");
            for (g, w) in times.iter().zip(&want) {
                assert!(
                    (g - w).abs() <= 1e-12 * w,
                    "{name} {priority:?}: {g} vs {w}"
                );
            }
        }

        let a = DMatrix::from_row_slice(2, 2, &[-1000.0, 1.0, 0.0, -1.0]);
        let b = DMatrix::from_row_slice(2, 1, &[0.0, 1.0]);
        let k = DMatrix::from_row_slice(1, 2, &[0.5, 2.0]);
        let loop_ = SampleAndHold::new(a, b, k, 0.1);
        let x0 = loop_.initial_state(&[1.0, -1.0]);
        let settings = settings.clone().horizon_t(3.05);
        let arc = simulate_arc(&loop_, &x0, &settings, &mut SimRng::seed_from(0))
            .expect("simulation runs");
        if let Err(v) = check_arc(&loop_, &arc, &settings) {
            panic!("{name} sample-and-hold: {v}");
        }
        let exact = loop_.exact_samples(&[1.0, -1.0], 30);
        assert_eq!(arc.jumps().len(), 30, "{name}: one sample per period");
        for (kk, jump) in arc.jumps().iter().enumerate() {
            assert_eq!(jump.pre[3], 0.1, "{name}: the timer lands on its threshold");
            assert!(
                (jump.at.t - 0.1 * (kk + 1) as f64).abs() < 1e-12,
                "{name}: sample {kk} at {}",
                jump.at.t
            );
            let want = &exact[kk + 1];
            for i in 0..2 {
                assert!(
                    (jump.pre[i] - want[i]).abs() <= 1e-8 * (1.0 + want[i].abs()),
                    "{name}: sample {kk}, x[{i}] = {} vs {}",
                    jump.pre[i],
                    want[i]
                );
            }
        }
    }
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
/// shipped model, of the heat chain and of a model using every
/// differentiable function; its sparsity pattern holds every entry whose
/// differences do not vanish, and its values there are the dense ones.
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
    sources.push(("heat chain".into(), heat_chain_source(12)));
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
        let pattern = m.jacobian_pattern().expect("a pattern");
        assert_eq!(pattern.n(), n);
        let mut values = vec![0.0; pattern.nnz()];
        for _ in 0..20 {
            let x: Vec<f64> = x0
                .iter()
                .map(|v| v * rng.uniform(0.8, 1.2) + rng.uniform(-1.0, 1.0))
                .collect();
            let at = HybridTime::new(rng.uniform(0.0, 5.0), 0);
            m.jacobian(at, &x, &mut jac);
            let fd = central_differences(&m, at, &x);
            // The entries of the pattern are the dense Jacobian's there;
            // outside it the finite differences vanish.
            assert!(m.jacobian_values(at, &x, &mut values), "{name}: no values");
            for r in 0..n {
                let row = &fd[r * n..(r + 1) * n];
                let scale = row.iter().fold(1.0f64, |s, v| s.max(v.abs()));
                for c in 0..n {
                    match pattern.position(r, c) {
                        Some(k) => assert_eq!(values[k], jac[r * n + c], "{name}: ({r}, {c})"),
                        None => assert!(
                            jac[r * n + c] == 0.0 && fd[r * n + c].abs() <= 1e-7 * scale,
                            "{name}: ∂f{r}/∂x{c} = {} outside the pattern",
                            fd[r * n + c]
                        ),
                    }
                }
            }
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

/// The heat chain of `benches/models/heat_chain.hyb` with `n` cells.
fn heat_chain_source(n: usize) -> String {
    std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/models/heat_chain.hyb"),
    )
    .expect("benches/models/heat_chain.hyb")
    .replace("param N = 200", &format!("param N = {n}"))
}

/// Jump times and final states of two runs agree: the same jumps by the
/// same rules, each time within `tol_t`, the final states within
/// `tol·(1 + |x|)`.
fn assert_same_solution(what: &str, a: &HybridArc, b: &HybridArc, tol_t: f64, tol: f64) {
    assert_eq!(a.jumps().len(), b.jumps().len(), "{what}: jumps");
    assert!(a.jumps().len() >= 5, "{what}: {} jumps", a.jumps().len());
    for (ja, jb) in a.jumps().iter().zip(b.jumps()) {
        assert_eq!(ja.rule, jb.rule, "{what}");
        assert!(
            (ja.at.t - jb.at.t).abs() <= tol_t,
            "{what}: jump at {} vs {}",
            ja.at.t,
            jb.at.t
        );
    }
    let (xa, xb) = (final_state(a), final_state(b));
    for (i, (u, v)) in xa.iter().zip(&xb).enumerate() {
        assert!(
            (u - v).abs() <= tol * (1.0 + v.abs()),
            "{what}: final x[{i}] = {u} vs {v}"
        );
    }
}

/// The sparse path (the Jacobian as the entries of its pattern, faer's LU
/// of the Newton matrices) gives the dense path's solution within the
/// tolerance, on both implicit solvers: on the compiled heat chain (its
/// symbolic Jacobian on the pattern derived from the expression graph), and
/// on the Rust `HeatChain` with a declared pattern and exact entries, with
/// a pattern and finite differences by column groups, and with neither
/// (the dense reference). `linear_solver = auto` takes the sparse LU for
/// the 60-cell chain (n = 61, tridiagonal) and the dense one for Van der
/// Pol (n = 2).
#[test]
fn sparse_and_dense_linear_algebra_give_the_same_solution() {
    let m = compile(&heat_chain_source(60));
    let pattern = m
        .jacobian_pattern()
        .expect("a compiled model has a pattern");
    assert_eq!(pattern.n(), 61);
    // Tridiagonal (3·60 − 2) plus the heater's entry.
    assert_eq!(pattern.nnz(), 3 * 60 - 2 + 1);
    assert!(use_sparse_lu(Some(&pattern), LinearSolver::Auto));
    let vdp = compile(VAN_DER_POL);
    assert!(!use_sparse_lu(
        vdp.jacobian_pattern().as_ref(),
        LinearSolver::Auto
    ));
    let (rtol, atol) = (1e-8, 1e-10);
    for name in IMPLICIT {
        let base = m
            .settings()
            .horizon_t(4.0)
            .solver(implicit(name, rtol, atol));
        let dense = run_with(&m, &base.clone().linear_solver(LinearSolver::Dense)).unwrap();
        for mode in [LinearSolver::Sparse, LinearSolver::Auto] {
            let arc = run_with(&m, &base.clone().linear_solver(mode)).unwrap();
            assert_same_solution(&format!("{name} {mode:?}"), &arc, &dense, 1e-7, 1e-6);
        }
        // The Rust system: exact entries, finite differences on the
        // pattern, and the dense finite-difference Jacobian.
        let mut chain = HeatChain::new(60);
        let x0 = chain.initial_state();
        let settings = SimSettings::default()
            .horizon_t(4.0)
            .solver(implicit(name, rtol, atol));
        let run = |sys: &HeatChain, mode: LinearSolver| {
            let s = settings.clone().linear_solver(mode);
            let arc = simulate_arc(sys, &x0, &s, &mut SimRng::seed_from(0)).expect("runs");
            if let Err(v) = check_arc(sys, &arc, &s) {
                panic!("{v}");
            }
            arc
        };
        let reference = run(&chain, LinearSolver::Dense);
        assert_same_solution(
            &format!("{name}: compiled vs Rust"),
            &dense,
            &reference,
            1e-7,
            1e-6,
        );
        chain.pattern = true;
        let grouped = run(&chain, LinearSolver::Sparse);
        assert_same_solution(
            &format!("{name} grouped differences"),
            &grouped,
            &reference,
            1e-7,
            1e-6,
        );
        chain.exact = true;
        for mode in [LinearSolver::Sparse, LinearSolver::Dense] {
            let arc = run(&chain, mode);
            assert_same_solution(
                &format!("{name} exact {mode:?}"),
                &arc,
                &reference,
                1e-7,
                1e-6,
            );
        }
    }
}

/// A pattern of the wrong size is an error naming it, not a panic.
#[test]
fn a_pattern_of_the_wrong_size_is_an_invalid_system() {
    struct Wrong(HeatChain);
    impl HybridSystem for Wrong {
        fn state_dim(&self) -> usize {
            self.0.state_dim()
        }
        fn state_names(&self) -> Vec<String> {
            self.0.state_names()
        }
        fn flow_map(&self, at: HybridTime, x: &[f64], dx: &mut [f64]) {
            self.0.flow_map(at, x, dx);
        }
        fn jump_rules(&self) -> &[hybsim::engine::JumpRule] {
            self.0.jump_rules()
        }
        fn jump_set(&self, rule: usize, at: HybridTime, x: &[f64]) -> bool {
            self.0.jump_set(rule, at, x)
        }
        fn jump_guard(&self, rule: usize, at: HybridTime, x: &[f64]) -> f64 {
            self.0.jump_guard(rule, at, x)
        }
        fn jump_map(&self, r: usize, at: HybridTime, x: &[f64], rng: &mut SimRng, xp: &mut [f64]) {
            self.0.jump_map(r, at, x, rng, xp);
        }
        fn jacobian_pattern(&self) -> Option<hybsim::engine::SparsityPattern> {
            Some(hybsim::engine::SparsityPattern::dense(3))
        }
    }
    let sys = Wrong(HeatChain::new(8));
    let s = SimSettings::default().solver(implicit("bdf", 1e-6, 1e-9));
    match simulate_arc(&sys, &sys.0.initial_state(), &s, &mut SimRng::seed_from(0)) {
        Err(SimError::InvalidSystem { what }) => {
            assert!(what.contains("jacobian_pattern"), "{what}")
        }
        other => panic!("{other:?}"),
    }
}

/// At the default settings (Zeno rate 10⁶, tolerances 1e-6 and 1e-9) every
/// adaptive solver follows the bouncing ball to its Zeno time and ends at
/// the Zeno guard after the same number of impacts, BDF included: once the
/// bounces are short its segments start at order 2 and follow the
/// parabolas exactly (a start at order 1 lost energy at every bounce until
/// the ball sank through the floor: "cannot flow" at j = 55).
#[test]
fn every_solver_reaches_the_zeno_guard_of_the_bouncing_ball_at_the_defaults() {
    let ball = BouncingBall::new(9.81, 0.8);
    let zeno = ball.zeno_time(1.0);
    let mut counts = Vec::new();
    for name in ["dopri5", "radau5", "bdf", "auto"] {
        let settings = SimSettings::default()
            .horizon_t(10.0)
            .exact_affine(false)
            .solver(Solver::adaptive(name, 1e-6, 1e-9).expect("a solver"));
        let arc = simulate_arc(&ball, &[1.0, 0.0], &settings, &mut SimRng::seed_from(0))
            .expect("simulation runs");
        if let Err(v) = check_arc(&ball, &arc, &settings) {
            panic!("{name}: {v}");
        }
        let term = arc.termination().expect("terminated");
        assert!(
            matches!(term.cause, TerminationCause::ZenoSuspected { .. }),
            "{name}: {term}"
        );
        assert!((term.at.t - zeno).abs() < 1e-5, "{name}: {term}");
        // BDF starts its early flights at order 1 (the weighted norm of
        // the ball's Jacobian times the step is above 1 there): errors of
        // the tolerance's order, not exact parabolas.
        let tol = if name == "bdf" { 1e-5 } else { 1e-9 };
        let exact = ball.impacts(1.0, 30);
        for (k, (jump, (t, _))) in arc.jumps().iter().zip(&exact).enumerate() {
            assert!(
                (jump.at.t - t).abs() <= tol,
                "{name}: impact {k} at {} vs {t}",
                jump.at.t
            );
        }
        counts.push(arc.jumps().len());
    }
    assert!(counts.iter().all(|&c| c == counts[0]), "{counts:?}");
}
