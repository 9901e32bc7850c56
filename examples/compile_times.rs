//! Compile times of `.hyb` models: source to checked model to register
//! programs (everything `lang::compile` does) with and without machine
//! code for every program (`CompiledModel::compile_machine_code`; runs
//! compile each program only when it becomes hot), and the JIT's own share
//! (`CompiledModel::jit`). Numbers in
//! BENCHMARKS.md ("Compiling models").
//!
//! `cargo run --release --example compile_times -- models/*.hyb`
//! `cargo run --release --example compile_times -- models/fireflies.hyb --set N=1000`
//!
//! Each model is compiled `REPS` times (default 3, environment variable
//! `REPS`); the minimum is printed.

use std::time::{Duration, Instant};

use hybsim::lang::{self, JitStatus, Override};
use hybsim::source::SourceFile;

fn main() -> anyhow::Result<()> {
    let mut paths = Vec::new();
    let mut sets = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        if a == "--set" {
            sets.push(
                args.next()
                    .ok_or_else(|| anyhow::anyhow!("--set needs NAME=VALUE"))?,
            );
        } else {
            paths.push(a);
        }
    }
    let reps: usize = std::env::var("REPS")
        .ok()
        .and_then(|r| r.parse().ok())
        .unwrap_or(3);
    println!("model\toverrides\tcompile (jit off) s\tcompile (jit on) s\tjit s\tprograms");
    for path in &paths {
        let src = SourceFile::read(path)?;
        let time = |jit: &str| -> anyhow::Result<(Duration, JitStatus)> {
            let mut best = (Duration::MAX, JitStatus::Off);
            for _ in 0..reps {
                let mut ov: Vec<Override> = sets
                    .iter()
                    .map(|s| s.parse().map_err(|_| anyhow::anyhow!("bad --set {s}")))
                    .collect::<Result<_, _>>()?;
                ov.push(format!("jit={jit}").parse().expect("an override"));
                let start = Instant::now();
                let m = lang::compile(&src, &ov)
                    .map_err(|_| anyhow::anyhow!("{path} does not compile"))?;
                // Every program now, not when it becomes hot in a run.
                m.compile_machine_code();
                let t = start.elapsed();
                if t < best.0 {
                    best = (t, m.jit());
                }
            }
            Ok(best)
        };
        let (off, _) = time("off")?;
        let (on, status) = time("on")?;
        let (jit, programs) = match status {
            JitStatus::Native {
                time,
                compiled,
                interpreted,
            } => (
                format!("{:.4}", time.as_secs_f64()),
                format!("{compiled} native, {interpreted} interpreted"),
            ),
            other => ("-".into(), format!("{other:?}")),
        };
        println!(
            "{path}\t{}\t{:.4}\t{:.4}\t{jit}\t{programs}",
            sets.join(" "),
            off.as_secs_f64(),
            on.as_secs_f64()
        );
    }
    Ok(())
}
