//! Cost of a timer reset read from a table (issue 23): the agents benchmark
//! of `../shared/limit` with its pre-drawn timers as a run-time index
//! (`benches/models/limit_agents.hyb`: `tau[k]+ = draws[n[k] + 1, k]`)
//! against the workaround before run-time indices
//! (`benches/models/limit_agents_sum.hyb`: a sum of 2 513 conditionals
//! `if n[k] == r then draws[r + 1, k] else 0`).
//!
//! Per reset: the jump map of each `transmit[k]` at a state with the
//! counters mid-table (n = 1250), 20 000 calls per batch. Per run: the
//! whole run to T = 1000 (7 458 jumps) into a sink that keeps nothing, as
//! `hybsim run --no-mcap`. The two models interleaved, `ROUNDS` rounds
//! (`cargo bench --bench tables [-- ROUNDS]`, default 5); this thread's CPU
//! time (`CLOCK_THREAD_CPUTIME_ID`); medians; the load average before and
//! after.

mod common;
use common::{cpu_now, median};

use std::hint::black_box;
use std::ops::ControlFlow;
use std::path::Path;

use hybsim::arc::{ArcSink, HybridTime, SampleKind, Termination};
use hybsim::engine::{HybridSystem, simulate};
use hybsim::ir::CompiledModel;
use hybsim::lang;
use hybsim::source::SourceFile;

/// Counts the jumps, keeps nothing else.
#[derive(Default)]
struct Tally {
    jumps: u64,
}

impl ArcSink for Tally {
    fn sample(&mut self, _: HybridTime, _: &[f64], _: SampleKind) -> ControlFlow<()> {
        ControlFlow::Continue(())
    }

    fn jump(&mut self, _: HybridTime, _: usize, _: &[f64], _: &[f64]) -> ControlFlow<()> {
        self.jumps += 1;
        ControlFlow::Continue(())
    }

    fn finish(&mut self, _: &Termination) {}
}

fn load() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_default()
}

const CALLS: usize = 20_000;

/// Seconds per reset: every `transmit[k]` map at the model's initial
/// state with the counters `n` set to 1250.
fn per_reset(m: &CompiledModel) -> f64 {
    let (mut x, mut rng) = m.start(m.seed());
    let names = m.state_names();
    for (k, name) in names.iter().enumerate() {
        if name.starts_with("n[") {
            x[k] = 1250.0;
        }
    }
    let mut out = vec![0.0; x.len()];
    let at = HybridTime::new(500.0, 3749);
    let rules = m.jump_rules().len();
    let t0 = cpu_now();
    for c in 0..CALLS {
        m.jump_map(c % rules, at, black_box(&x), &mut rng, &mut out);
        black_box(&out);
    }
    (cpu_now() - t0) / CALLS as f64
}

/// Seconds of one whole run, and its jumps.
fn per_run(m: &CompiledModel) -> (f64, u64) {
    let (x0, mut rng) = m.start(m.seed());
    let mut tally = Tally::default();
    let t0 = cpu_now();
    simulate(m, &x0, &m.settings(), &mut rng, &mut tally).expect("runs");
    (cpu_now() - t0, tally.jumps)
}

fn main() {
    let rounds: usize = std::env::args()
        .skip(1)
        .find_map(|a| a.parse().ok())
        .unwrap_or(5);
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/models");
    let compile = |name: &str| {
        let src = SourceFile::read(dir.join(name)).expect("model");
        lang::compile(&src, &[]).unwrap_or_else(|d| {
            panic!("{}", hybsim::diagnostics::render(&d, &src, false));
        })
    };
    let (table, sum) = (compile("limit_agents.hyb"), compile("limit_agents_sum.hyb"));
    println!("load before: {}", load());
    let (mut reset, mut run) = ([vec![], vec![]], [vec![], vec![]]);
    let mut jumps = [0, 0];
    for r in 0..rounds {
        for (side, m) in [&table, &sum].into_iter().enumerate() {
            reset[side].push(per_reset(m));
            let (s, j) = per_run(m);
            run[side].push(s);
            jumps[side] = j;
        }
        println!(
            "round {r}: reset table {:.3} µs, sum {:.3} µs; run table {:.2} ms, sum {:.2} ms",
            reset[0][r] * 1e6,
            reset[1][r] * 1e6,
            run[0][r] * 1e3,
            run[1][r] * 1e3
        );
    }
    let [rt, rs] = reset.map(median);
    let [ut, us] = run.map(median);
    println!(
        "median per reset: table {:.3} µs, sum of conditionals {:.3} µs ({:.0}x)",
        rt * 1e6,
        rs * 1e6,
        rs / rt
    );
    println!(
        "median per run: table {:.2} ms ({} jumps, {:.2} µs/jump), sum {:.2} ms ({} jumps, {:.2} µs/jump)",
        ut * 1e3,
        jumps[0],
        ut * 1e6 / jumps[0] as f64,
        us * 1e3,
        jumps[1],
        us * 1e6 / jumps[1] as f64
    );
    println!("load after: {}", load());
}
