//! The example models of `models/` with known behaviour, through the real
//! pipeline (parse → check → compile → simulate), compared with closed forms
//! and known facts. One test per model also runs the `hybsim` binary.

use std::path::Path;
use std::process::Command;

use hybsim::engine::models::SampleAndHold;

use crate::util::simulate_arc;
use hybsim::engine::{FlowStructure, HybridSystem, Solver};
use nalgebra::{DMatrix, DVector};

use super::lang::{load, run};

const BIN: &str = env!("CARGO_BIN_EXE_hybsim");

fn model_path(name: &str) -> String {
    format!("{}/models/{name}", env!("CARGO_MANIFEST_DIR"))
}

/// Runs `hybsim run models/NAME --no-mcap --csv out.csv ARGS` and returns the
/// CSV as (header, rows).
fn run_cli_csv(name: &str, args: &[&str]) -> (Vec<String>, Vec<Vec<String>>) {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("out.csv");
    let out = Command::new(BIN)
        .args(["run", &model_path(name), "--no-mcap", "--quiet", "--csv"])
        .arg(&csv)
        .args(args)
        .current_dir(dir.path())
        .output()
        .expect("the binary runs");
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text
        .lines()
        .map(|l| l.split(',').map(String::from).collect());
    (lines.next().unwrap(), lines.collect())
}

// ------------------------------------------------------------ thermostat --

/// Closed-form switching instants of the thermostat from x0 (heater on,
/// xlo < x0 < xhi): first switch-off, then alternating half periods.
fn thermostat_switches(x0: f64, horizon: f64) -> Vec<(f64, &'static str, f64)> {
    let (a, xa, p, xlo, xhi) = (0.5_f64, 5.0, 12.0, 18.0, 22.0);
    let xinf = xa + p / a;
    let t_first = ((xinf - x0) / (xinf - xhi)).ln() / a;
    let t_on = ((xinf - xlo) / (xinf - xhi)).ln() / a;
    let t_off = ((xhi - xa) / (xlo - xa)).ln() / a;
    let mut out = vec![(t_first, "switch_off", xhi)];
    let mut t = t_first;
    loop {
        let (dt, name, x) = if out.len() % 2 == 1 {
            (t_off, "switch_on", xlo)
        } else {
            (t_on, "switch_off", xhi)
        };
        t += dt;
        if t > horizon {
            return out;
        }
        out.push((t, name, x));
    }
}

#[test]
fn thermostat_switches_at_the_closed_form_instants() {
    // x' = -a (x - xa) + p q is affine: advanced exactly (asked for: by
    // default the exact path is chosen by cost), switches localized.
    let m = load("thermostat.hyb", &["exact_affine=on"]);
    assert!(matches!(m.flow_structure(), FlowStructure::Affine { .. }));
    let arc = run(&m);
    let expect = thermostat_switches(20.0, 24.0);
    let jumps = arc.jumps();
    assert_eq!(jumps.len(), expect.len(), "switches before T = 24");
    for (k, (jr, &(t, name, x))) in jumps.iter().zip(&expect).enumerate() {
        assert_eq!(arc.rule_name(jr.rule), Some(name), "switch {k}");
        assert!(
            (jr.at.t - t).abs() < 1e-9,
            "switch {k}: t {} vs {t}",
            jr.at.t
        );
        assert!(
            (jr.pre[0] - x).abs() < 1e-9,
            "switch {k}: x {} vs {x}",
            jr.pre[0]
        );
        assert_eq!(jr.post[1], if name == "switch_on" { 1.0 } else { 0.0 });
    }
    // Between switches the temperature stays in the hysteresis band.
    for s in arc.samples().filter(|s| s.at.t > expect[0].0 + 1e-9) {
        assert!((18.0 - 1e-9..=22.0 + 1e-9).contains(&s.x[0]), "{:?}", s);
    }
    // The same with the general-purpose integrators (the flow as a black
    // box), events on their interpolants.
    let (rtol, atol) = (1e-10, 1e-12);
    for solver in [Solver::Dopri5 { rtol, atol }, Solver::Dop853 { rtol, atol }] {
        let s = m.settings().exact_affine(false).solver(solver);
        let (x0, mut rng) = m.start(m.seed());
        let arc = simulate_arc(&m, &x0, &s, &mut rng).unwrap();
        assert_eq!(arc.jumps().len(), expect.len());
        for (jr, &(t, _, _)) in arc.jumps().iter().zip(&expect) {
            assert!((jr.at.t - t).abs() < 1e-7, "{solver:?}: {} vs {t}", jr.at.t);
        }
    }
}

#[test]
fn thermostat_from_the_cli_logs_the_closed_form_switches() {
    let (header, rows) = run_cli_csv(
        "thermostat.hyb",
        &["--set", "x0=19", "--exact-affine", "on"],
    );
    assert_eq!(header, ["t", "j", "kind", "x", "q", "heating"]);
    let pre: Vec<(f64, f64)> = rows
        .iter()
        .filter(|r| r[2] == "pre_jump")
        .map(|r| (r[0].parse().unwrap(), r[3].parse().unwrap()))
        .collect();
    let expect = thermostat_switches(19.0, 24.0);
    assert_eq!(pre.len(), expect.len());
    for (&(t, x), &(te, _, xe)) in pre.iter().zip(&expect) {
        assert!(
            (t - te).abs() < 1e-9 && (x - xe).abs() < 1e-9,
            "{t} {x} vs {te} {xe}"
        );
    }
}

// ------------------------------------------------------- sample and hold --

/// The plant of models/sample_and_hold.hyb written out entry by entry.
fn ring_plant(blocks: usize, m: usize) -> (DMatrix<f64>, DMatrix<f64>) {
    let n = 3 * blocks;
    let mut a = DMatrix::zeros(n, n);
    let mut b = DMatrix::zeros(n, m);
    for blk in 0..blocks {
        let i = 3 * blk;
        let w = 1.0 + 0.25 * blk as f64;
        a[(i, i + 1)] = 1.0;
        a[(i + 1, i)] = w * w;
        a[(i + 1, i + 2)] = 1.0;
        a[(i + 2, i + 2)] = -(0.5 + 0.1 * blk as f64);
        a[(i + 1, 3 * ((blk + 1) % blocks))] += 0.05;
        b[(i + 2, blk % m)] = 1.0;
    }
    (a, b)
}

#[test]
fn sample_and_hold_matches_the_exact_discretisation() {
    let m = load("sample_and_hold.hyb", &["exact_affine=on"]);
    assert_eq!(m.state_dim(), 39 + 3 + 1, "plant, held input, timer");
    let p = |name| m.parameter(name).expect("a parameter of the model");
    let (a, b, k) = (p("A"), p("B"), p("K"));
    let (a_ref, b_ref) = ring_plant(13, 3);
    assert_eq!(a, a_ref, "A built in the model");
    assert_eq!(b, b_ref, "B built in the model");
    // The plant is unstable, the sampled loop with the model's dlqr gain is
    // stable: spectral radius of Ad - Bd K below 1.
    let max_re = a
        .complex_eigenvalues()
        .iter()
        .map(|l| l.re)
        .fold(f64::MIN, f64::max);
    assert!(max_re > 3.9, "unstable plant, largest eigenvalue {max_re}");
    let acl = p("Ad") - p("Bd") * &k;
    let rho = acl
        .complex_eigenvalues()
        .iter()
        .map(|l| l.norm())
        .fold(0.0, f64::max);
    assert!(rho < 1.0, "closed-loop spectral radius {rho}");

    let reference = SampleAndHold::new(a, b, k.clone(), 0.02);
    let x0 = vec![0.1; 39];
    let steps = 499; // samples at t = 0.02 k before T = 10
    let exact = reference.exact_samples(&x0, steps);
    // The flow is affine: the engine propagates it exactly between samples.
    assert!(matches!(m.flow_structure(), FlowStructure::Affine { .. }));
    let arc = run(&m);
    let (x_init, _) = m.start(m.seed());
    assert_eq!(x_init, reference.initial_state(&x0), "[x0, -K x0, 0]");
    assert_eq!(arc.jumps().len(), steps);
    let mut worst: f64 = 0.0;
    for (kk, jr) in arc.jumps().iter().enumerate() {
        assert!((jr.at.t - 0.02 * (kk + 1) as f64).abs() < 1e-9);
        let x = DVector::from_column_slice(&jr.pre[..39]);
        let e = &exact[kk + 1];
        worst = worst.max((&x - e).norm() / e.norm().max(1e-3));
        let u = -(&k * &x);
        for r in 0..3 {
            assert!((jr.post[39 + r] - u[r]).abs() < 1e-9 * (1.0 + u[r].abs()));
        }
    }
    assert!(
        worst < 1e-9,
        "relative deviation from x(k+1) = Φ x(k) + Γ u(k): {worst:e}"
    );
    // The same with Dopri5 (no affine shortcut), tolerance from rtol.
    let s = m.settings().exact_affine(false).solver(Solver::Dopri5 {
        rtol: 1e-10,
        atol: 1e-12,
    });
    let (x0, mut rng) = m.start(m.seed());
    let arc = simulate_arc(&m, &x0, &s, &mut rng).unwrap();
    let last = arc.jumps().last().unwrap();
    let e = &exact[steps];
    let dev = (DVector::from_column_slice(&last.pre[..39]) - e).norm() / e.norm();
    assert!(dev < 1e-6, "dopri5 deviation at t = 9.98: {dev:e}");
}

#[test]
fn sample_and_hold_is_parameterised_by_the_number_of_blocks() {
    // N = 2 blocks: 6 plant states, still stabilized by the model's gain.
    let (header, rows) = run_cli_csv("sample_and_hold.hyb", &["--set", "N=2", "--T", "40"]);
    assert_eq!(
        &header[3..9],
        ["x[1]", "x[2]", "x[3]", "x[4]", "x[5]", "x[6]"]
    );
    assert_eq!(header.last().map(String::as_str), Some("xnorm"));
    let xnorm: Vec<f64> = rows
        .iter()
        .map(|r| r.last().unwrap().parse().unwrap())
        .collect();
    let first = xnorm[0];
    let last = *xnorm.last().unwrap();
    assert!((first - 0.1 * 6f64.sqrt()).abs() < 1e-12);
    assert!(last < 1e-3 * first, "decays: {first} -> {last}");
}

// ------------------------------------------------------------- fireflies --

/// The firefly system solved event by event: the next flash is the largest
/// clock reaching 1 (lowest index first, as the engine orders rules).
/// Returns (t, firefly, clocks after the flash).
fn fireflies_reference(tau0: &[f64], eps: f64, horizon: f64) -> Vec<(f64, usize, Vec<f64>)> {
    let mut tau = tau0.to_vec();
    let mut t = 0.0;
    let mut out = Vec::new();
    loop {
        let top = tau.iter().cloned().fold(f64::MIN, f64::max);
        let dt = 1.0 - top;
        if t + dt > horizon {
            return out;
        }
        t += dt;
        let i = tau.iter().position(|&x| x == top).unwrap();
        for x in &mut tau {
            *x += dt;
        }
        let pre = tau.clone();
        for (k, x) in tau.iter_mut().enumerate() {
            *x = if k == i || (1.0 + eps) * pre[k] >= 1.0 {
                0.0
            } else {
                (1.0 + eps) * pre[k]
            };
        }
        out.push((t, i, tau.clone()));
    }
}

fn distinct(x: &[f64]) -> usize {
    let mut v = x.to_vec();
    v.sort_by(f64::total_cmp);
    v.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    v.len()
}

#[test]
fn fireflies_follow_the_event_map_and_synchronise() {
    for seed in 0..10u64 {
        let m = load("fireflies.hyb", &[&format!("seed={seed}"), "T=60"]);
        assert_eq!(
            m.rule_names(),
            ["flash[1]", "flash[2]", "flash[3]", "flash[4]", "flash[5]"]
        );
        let (x0, mut rng) = m.start(m.seed());
        let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng).unwrap();
        let reference = fireflies_reference(&x0, 0.1, 60.0);
        let jumps = arc.jumps();
        assert_eq!(
            jumps.len(),
            reference.len(),
            "seed {seed}: number of flashes"
        );
        let mut groups = distinct(&x0);
        for (jr, (t, i, post)) in jumps.iter().zip(&reference) {
            assert!(
                (jr.at.t - t).abs() < 1e-9,
                "seed {seed}: {} vs {t}",
                jr.at.t
            );
            assert_eq!(jr.rule, *i, "seed {seed} at t = {t}");
            for (a, b) in jr.post.iter().zip(post) {
                assert!((a - b).abs() < 1e-9, "seed {seed} at t = {t}: {a} vs {b}");
            }
            // Fireflies that flashed together never separate.
            let now = distinct(&jr.post);
            assert!(
                now <= groups,
                "seed {seed} at t = {t}: {groups} -> {now} groups"
            );
            groups = now;
        }
        // Synchronised (Mirollo–Strogatz): one group, one flash per unit time.
        assert_eq!(groups, 1, "seed {seed}: not synchronised by t = 60");
        let tail: Vec<f64> = jumps.iter().rev().take(5).map(|j| j.at.t).collect();
        for w in tail.windows(2) {
            assert!(
                (w[0] - w[1] - 1.0).abs() < 1e-9,
                "seed {seed}: period {}",
                w[0] - w[1]
            );
        }
    }
}

#[test]
fn fireflies_from_the_cli_end_with_zero_spread() {
    let (header, rows) = run_cli_csv("fireflies.hyb", &[]);
    assert_eq!(
        &header[3..8],
        ["tau[1]", "tau[2]", "tau[3]", "tau[4]", "tau[5]"]
    );
    assert_eq!(header.last().map(String::as_str), Some("spread"));
    let spread = |r: &Vec<String>| -> f64 { r.last().unwrap().parse().unwrap() };
    assert!(spread(&rows[0]) > 0.1, "random initial clocks");
    assert!(
        spread(rows.last().unwrap()).abs() < 1e-9,
        "synchronised by T = 30"
    );
    let flashes = rows.iter().filter(|r| r[2] == "post_jump").count();
    assert!((30..=60).contains(&flashes), "{flashes} flashes");
}

#[test]
fn example_models_pass_hybsim_check() {
    for name in ["thermostat.hyb", "sample_and_hold.hyb", "fireflies.hyb"] {
        let out = Command::new(BIN)
            .args(["check", &model_path(name)])
            .current_dir(Path::new(env!("CARGO_MANIFEST_DIR")))
            .output()
            .unwrap();
        assert_eq!(
            out.status.code(),
            Some(0),
            "{name}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
}

#[test]
fn hybsim_run_does_not_need_the_check() {
    // `hybsim run` does not solve a model's `check` blocks (here the LMI of
    // intermittent_estimation's `check prop_3_5`) and says so.
    let dir = tempfile::tempdir().unwrap();
    let run = Command::new(BIN)
        .args([
            "run",
            &model_path("intermittent_estimation.hyb"),
            "--T",
            "1",
            "--no-mcap",
            "-q",
        ])
        .current_dir(dir.path())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(0), "{err}");
    assert!(err.contains("check prop_3_5: not solved here"), "{err}");
}
