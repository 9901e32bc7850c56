//! Runs of a model after its first (warm: machine code compiled, buffers
//! grown), for profilers: the runs after the first are the calls of
//! `measured`, so a profile of steady-state runs is
//!
//! ```text
//! cargo build --profile profiling --example warm_runs
//! valgrind --tool=callgrind --toggle-collect='*warm_runs::measured*' \
//!     target/profiling/examples/warm_runs benches/models/limit_bb.hyb 10
//! ```
//!
//! Usage: `warm_runs MODEL [RUNS] [--set NAME=VALUE]...` (RUNS default 10);
//! prints the jumps and samples of the last run. Every sample goes to a sink
//! that keeps nothing, as `hybsim run --no-mcap` does.

use std::ops::ControlFlow;

use hybsim::arc::{ArcSink, HybridTime, SampleKind};
use hybsim::engine::{SimSettings, simulate};
use hybsim::ir::CompiledModel;
use hybsim::lang::{self, Override};
use hybsim::source::SourceFile;

/// Counts samples and jumps.
#[derive(Default)]
struct Count {
    samples: u64,
    jumps: u64,
}

impl ArcSink for Count {
    fn sample(&mut self, _: HybridTime, _: &[f64], _: SampleKind) -> ControlFlow<()> {
        self.samples += 1;
        ControlFlow::Continue(())
    }

    fn jump(&mut self, _: HybridTime, _: usize, _: &[f64], _: &[f64]) -> ControlFlow<()> {
        self.jumps += 1;
        ControlFlow::Continue(())
    }

    fn wants_dense_points(&self) -> bool {
        false
    }
}

fn run(m: &CompiledModel, settings: &SimSettings) -> anyhow::Result<Count> {
    let (x0, mut rng) = m.start(m.seed());
    let mut count = Count::default();
    simulate(m, &x0, settings, &mut rng, &mut count)?;
    Ok(count)
}

#[inline(never)]
fn measured(m: &CompiledModel, settings: &SimSettings, runs: usize) -> anyhow::Result<Count> {
    let mut last = Count::default();
    for _ in 0..runs {
        last = run(m, settings)?;
    }
    Ok(last)
}

fn main() -> anyhow::Result<()> {
    // As the `hybsim` binary: OpenBLAS's idle workers would spin beside
    // the measured runs.
    hybsim::design::blas::pin();
    let mut args = std::env::args().skip(1);
    let (mut path, mut runs, mut sets) = (None, 10, Vec::new());
    while let Some(a) = args.next() {
        if a == "--set" {
            let set = args
                .next()
                .ok_or_else(|| anyhow::anyhow!("--set needs NAME=VALUE"))?;
            sets.push(
                set.parse::<Override>()
                    .map_err(|d| anyhow::anyhow!("--set {set}: {}", d.message))?,
            );
        } else if path.is_none() {
            path = Some(a);
        } else {
            runs = a.parse()?;
        }
    }
    let path = path.ok_or_else(|| anyhow::anyhow!("usage: warm_runs MODEL [RUNS]"))?;
    let src = SourceFile::read(&path)?;
    let m = lang::compile(&src, &sets)
        .map_err(|d| anyhow::anyhow!("{}", hybsim::diagnostics::render(&d, &src, false)))?;
    let settings = m.settings();
    run(&m, &settings)?;
    let last = measured(&m, &settings, runs)?;
    println!(
        "{runs} runs; the last: {} jumps, {} samples",
        last.jumps, last.samples
    );
    Ok(())
}
