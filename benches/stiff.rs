//! Stiff flows: hybsim's `radau5`, `bdf` and `auto` against scipy's `Radau`,
//! `BDF` and `LSODA` on Van der Pol (μ = 1000, T = 3000), Robertson (t = 1e5)
//! and the stiff relay (a thermostat reading a sensor with time constant
//! 1e-5 on a slow room, T = 24), at the same tolerances (those of
//! `benches/models/{van_der_pol,robertson,stiff_relay}.hyb`), in the same
//! minute: hybsim's runs are timed here (compiled model, every sample pushed
//! to a sink that keeps only the final state and the jump times, as
//! `hybsim run --no-mcap`; CPU time of this thread, median of 5 batches),
//! then `benches/stiff_scipy.py` times scipy's (best of 5). Accuracy on both
//! sides: the largest error of the final state relative to `rtol·|ref| +
//! atol` against `tests/data/stiff_reference.json` (scipy's Radau at rtol
//! 1e-12), and for the relay the largest error of the 35 switching times
//! against their closed form. Results and the machine are in BENCHMARKS.md.
//!
//! ```text
//! cargo bench --bench stiff        # scipy's side needs python3 with scipy (or $PYTHON)
//! ```

mod common;
use common::{Keep, cpu_now, median};

use std::path::PathBuf;
use std::process::Command;

use hybsim::engine::{Solver, simulate};
use hybsim::ir::CompiledModel;
use hybsim::lang;
use hybsim::source::SourceFile;
use serde_json::Value;

fn run(m: &CompiledModel, solver: Solver) -> Keep {
    let (x0, mut rng) = m.start(m.seed());
    let mut keep = Keep::default();
    simulate(m, &x0, &m.settings().solver(solver), &mut rng, &mut keep).expect("simulation");
    keep
}

/// CPU seconds per run: the median over 5 batches of the mean of runs
/// filling about 0.1 s each.
fn time(m: &CompiledModel, solver: Solver) -> f64 {
    let mut batches = Vec::new();
    for _ in 0..5 {
        let start = cpu_now();
        let mut n = 0u32;
        while n == 0 || (cpu_now() - start < 0.1 && n < 10_000) {
            let _ = std::hint::black_box(run(m, solver));
            n += 1;
        }
        batches.push((cpu_now() - start) / f64::from(n));
    }
    median(batches)
}

/// The relay's switching times in closed form (tests/it/stiff.rs derives
/// them): after each switch the sensor reaches the threshold θ after
/// d = ln((x − X) / ((1 − aτ)(θ − X))) / a.
fn relay_switch_times(m: &CompiledModel) -> Vec<f64> {
    let p = m.parameters_json();
    let g = |k: &str| p[k].as_f64().unwrap_or_else(|| panic!("parameter {k}"));
    let (a, xa, pw, xlo, xhi, tau) = (g("a"), g("xa"), g("p"), g("xlo"), g("xhi"), g("tau"));
    let horizon = m.settings().horizon_t;
    let (mut x, mut q, mut t) = (20.0f64, 1.0, 0.0);
    let mut out = Vec::new();
    loop {
        let big_x = xa + pw * q / a;
        let theta = if q == 1.0 { xhi } else { xlo };
        let d = ((x - big_x) / ((1.0 - a * tau) * (theta - big_x))).ln() / a;
        if t + d >= horizon {
            return out;
        }
        t += d;
        x = big_x + (x - big_x) * (-a * d).exp();
        q = 1.0 - q;
        out.push(t);
    }
}

fn main() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let reference: Value = serde_json::from_str(
        &std::fs::read_to_string(root.join("tests/data/stiff_reference.json")).expect("reference"),
    )
    .expect("reference JSON");
    println!(
        "| problem | solver | CPU time | error / tol (final state) | switch times, max error | solver switches |"
    );
    println!("|---|---|---|---|---|---|");
    for (problem, key) in [
        ("van_der_pol", Some("van_der_pol_mu1000_t3000")),
        ("robertson", Some("robertson_t100000")),
        ("stiff_relay", None),
    ] {
        let src = SourceFile::read(root.join(format!("benches/models/{problem}.hyb")))
            .expect("benchmark model");
        let m = lang::compile(&src, &[])
            .unwrap_or_else(|d| panic!("{}", hybsim::diagnostics::render(&d, &src, false)));
        let (rtol, atol) = m.settings().solver.tolerances().expect("adaptive");
        for name in ["radau5", "bdf", "auto"] {
            let solver = Solver::adaptive(name, rtol, atol).expect("a solver");
            let keep = run(&m, solver);
            let accuracy = match key {
                Some(key) => {
                    let want = reference[key]["rtol_1e-12"].as_array().expect("reference");
                    let worst = want
                        .iter()
                        .zip(&keep.last)
                        .map(|(w, g)| {
                            let w = w.as_f64().expect("number");
                            (g - w).abs() / (rtol * w.abs() + atol)
                        })
                        .fold(0.0, f64::max);
                    (format!("{worst:.2}"), "—".to_string())
                }
                None => {
                    let exact = relay_switch_times(&m);
                    assert_eq!(keep.jumps.len(), exact.len(), "{problem} {name}: switches");
                    let worst = keep
                        .jumps
                        .iter()
                        .zip(&exact)
                        .map(|(g, e)| (g - e).abs())
                        .fold(0.0, f64::max);
                    ("—".to_string(), format!("{worst:.1e}"))
                }
            };
            let cpu = time(&m, solver);
            println!(
                "| {problem} (rtol {rtol:e}, atol {atol:e}) | hybsim `{name}` | {:.3} ms | {} | {} | {} |",
                cpu * 1e3,
                accuracy.0,
                accuracy.1,
                keep.switches
            );
        }
    }
    let python = std::env::var("PYTHON").unwrap_or_else(|_| "python3".into());
    match Command::new(&python)
        .arg(root.join("benches/stiff_scipy.py"))
        .arg(root.join("tests/data/stiff_reference.json"))
        .output()
    {
        Ok(out) if out.status.success() => print!("{}", String::from_utf8_lossy(&out.stdout)),
        Ok(out) => eprintln!(
            "scipy's side failed ({python}): {}",
            String::from_utf8_lossy(&out.stderr)
        ),
        Err(e) => eprintln!("scipy's side not run ({python}: {e})"),
    }
}
