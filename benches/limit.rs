//! hybsim against the hand-written limit (`../shared/limit`): the three
//! benchmarks written in `.hyb` (`benches/models/limit_*.hyb`, from the
//! limit's README and params.json), run as `hybsim run --no-mcap` runs them
//! (compiled model, every sample pushed to a sink that keeps nothing), on
//! the default settings and with `exact_affine` on and off, interleaved with
//! the limit's variants in the same minutes; the last column times the
//! default path with `solver = auto` instead of Dopri5 (the same arc on
//! these non-stiff flows, checked), to tell whether auto may be the
//! default. Prints CPU times (this
//! thread's, from /proc), the work done (jumps, end time, accuracy) and the
//! ratios. Results and the machine are in BENCHMARKS.md.
//!
//! Build the limit first (outside ../shared, which is read-only):
//!
//! ```text
//! CARGO_TARGET_DIR=target/limit cargo build --release --locked --manifest-path ../shared/limit/Cargo.toml
//! cargo bench --bench limit            # [-- ROUNDS] (default 3)
//! ```
//!
//! Without the limit binary only hybsim's side is timed.

mod common;
use common::{cpu_now, median};

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::process::Command;

use hybsim::arc::{ArcSink, HybridTime, SampleKind, Termination};
use hybsim::engine::{ExactAffine, Solver, simulate};
use hybsim::ir::CompiledModel;
use hybsim::lang;
use hybsim::source::SourceFile;
use serde_json::Value;

/// Keeps the counts and the last state only, like `--no-mcap`'s tally.
#[derive(Default)]
struct Tally {
    samples: u64,
    jumps: u64,
    last: Vec<f64>,
    end: Option<Termination>,
}

impl ArcSink for Tally {
    fn sample(&mut self, _: HybridTime, x: &[f64], kind: SampleKind) -> ControlFlow<()> {
        self.samples += 1;
        if kind == SampleKind::Final {
            self.last.clear();
            self.last.extend_from_slice(x);
        }
        ControlFlow::Continue(())
    }

    fn jump(&mut self, _: HybridTime, _: usize, _: &[f64], _: &[f64]) -> ControlFlow<()> {
        self.jumps += 1;
        ControlFlow::Continue(())
    }

    fn finish(&mut self, termination: &Termination) {
        self.end = Some(termination.clone());
    }

    fn wants_dense_points(&self) -> bool {
        false
    }
}

/// One run of `m` with `mode` (and `solver = auto` instead of the model's
/// Dopri5 if `auto_solver`): its tally.
fn run(m: &CompiledModel, mode: ExactAffine, auto_solver: bool) -> Tally {
    let (x0, mut rng) = m.start(m.seed());
    let mut s = m.settings().exact_affine(mode);
    if auto_solver && let Some((rtol, atol)) = s.solver.tolerances() {
        s = s.solver(Solver::Auto { rtol, atol });
    }
    let mut tally = Tally::default();
    simulate(m, &x0, &s, &mut rng, &mut tally).expect("simulation");
    tally
}

/// CPU seconds per run: the median over 5 batches of the mean of runs
/// filling about `budget / 5` seconds each (batches average out the
/// clock's granularity on runs of tens of µs).
fn time(m: &CompiledModel, mode: ExactAffine, auto_solver: bool, budget: f64) -> f64 {
    let mut batches = Vec::new();
    for _ in 0..5 {
        let start = cpu_now();
        let mut n = 0u32;
        while n == 0 || (cpu_now() - start < budget / 5.0 && n < 10_000) {
            let _ = std::hint::black_box(run(m, mode, auto_solver));
            n += 1;
        }
        batches.push((cpu_now() - start) / f64::from(n));
    }
    median(batches)
}

/// The limit's JSON lines for `bench` (all variants), if its binary exists.
fn limit(bin: &Path, bench: &str) -> Vec<Value> {
    let Ok(out) = Command::new(bin)
        .args([bench, "--budget", "0.5", "--min-reps", "5"])
        .output()
    else {
        return Vec::new();
    };
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

fn main() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let rounds: usize = std::env::args()
        .skip(1)
        .find_map(|a| a.parse().ok())
        .unwrap_or(3);
    let limit_bin = root.join("target/limit/release/hybsim-limit");
    let have_limit = limit_bin.exists();
    if !have_limit {
        eprintln!(
            "no {} (see this file's docs): timing hybsim only",
            limit_bin.display()
        );
    }
    let params: Value = serde_json::from_str(
        &std::fs::read_to_string(root.join("../shared/limit/params.json")).unwrap_or_default(),
    )
    .unwrap_or(Value::Null);
    let modes = [ExactAffine::Auto, ExactAffine::On, ExactAffine::Off];
    println!(
        "| benchmark | hybsim auto | hybsim on | hybsim off | limit-Dopri5 | limit-expm | auto / Dopri5 | off / Dopri5 | on / expm | jumps (hybsim / limit) | hybsim auto, `solver = auto` / Dopri5 |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for bench in ["bb", "sh", "agents"] {
        let path = root.join(format!("benches/models/limit_{bench}.hyb"));
        let src = SourceFile::read(&path).expect("benchmark model");
        let m = lang::compile(&src, &[])
            .unwrap_or_else(|d| panic!("{}", hybsim::diagnostics::render(&d, &src, false)));
        // Same work on every path: jumps and the end state.
        let tallies: Vec<Tally> = modes.iter().map(|&mode| run(&m, mode, false)).collect();
        // `solver = auto` on these non-stiff flows: Dopri5's arc, at what cost.
        let auto_solver = run(&m, ExactAffine::Auto, true);
        assert_eq!(
            (auto_solver.jumps, auto_solver.samples, &auto_solver.last),
            (tallies[0].jumps, tallies[0].samples, &tallies[0].last),
            "{bench}: solver = auto must give Dopri5's arc"
        );
        for (mode, t) in modes.iter().zip(&tallies) {
            let end = t.end.as_ref().map(|e| e.to_string()).unwrap_or_default();
            eprintln!(
                "{bench} {mode:?}: {} jumps, {} samples, {end}",
                t.jumps, t.samples
            );
        }
        if bench == "sh"
            && let Some(exact) = params["sh"]["xp_T_exact"].as_array()
        {
            for (mode, t) in modes.iter().zip(&tallies) {
                let err = exact
                    .iter()
                    .zip(&t.last)
                    .map(|(e, x)| (e.as_f64().unwrap_or(f64::NAN) - x).abs())
                    .fold(0.0, f64::max);
                eprintln!("sh {mode:?}: max |xp(100) - exact| = {err:.2e}");
            }
        }
        let mut ours = vec![Vec::new(); modes.len()];
        let mut ours_auto_solver = Vec::new();
        let mut dopri = Vec::new();
        let mut expm = Vec::new();
        let mut limit_jumps = None;
        for _ in 0..rounds {
            for (k, &mode) in modes.iter().enumerate() {
                // The exact path on every segment of the agents costs seconds.
                if bench == "agents" && mode == ExactAffine::On {
                    continue;
                }
                ours[k].push(time(&m, mode, false, 0.5));
            }
            ours_auto_solver.push(time(&m, ExactAffine::Auto, true, 0.5));
            if have_limit {
                for line in limit(&limit_bin, bench) {
                    let cpu = line["cpu_median_s"].as_f64().unwrap_or(f64::NAN);
                    match line["peer"].as_str() {
                        Some("limit-Dopri5") => {
                            dopri.push(cpu);
                            limit_jumps = line["jumps"]
                                .as_u64()
                                .or_else(|| line["accuracy"]["jumps"].as_u64())
                                .or(limit_jumps);
                        }
                        Some("limit-expm") => expm.push(cpu),
                        _ => {}
                    }
                }
            }
        }
        let ms = |v: &Vec<f64>| {
            if v.is_empty() {
                f64::NAN
            } else {
                median(v.clone()) * 1e3
            }
        };
        let (auto, on, off) = (ms(&ours[0]), ms(&ours[1]), ms(&ours[2]));
        let (d, e) = (ms(&dopri), ms(&expm));
        let auto_solver = ms(&ours_auto_solver);
        println!(
            "| {bench} | {auto:.3} ms | {on:.3} ms | {off:.3} ms | {d:.3} ms | {e:.3} ms | {:.2} | {:.2} | {:.2} | {} / {} | {auto_solver:.3} ms, {:.3} |",
            auto / d,
            off / d,
            on / e,
            tallies[0].jumps,
            limit_jumps.map_or("?".into(), |j| j.to_string()),
            auto_solver / auto
        );
    }
}
