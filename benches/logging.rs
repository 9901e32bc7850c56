//! Cost of logging.
//!
//! First, the budget of issue 19 on real runs: `hybsim run MODEL` with its
//! MCAP file against `--no-mcap`, for the consensus model and the
//! sample-and-hold model and benchmark, as CPU time of the whole process
//! (user + system of all its threads, `getrusage` of the child) and as wall
//! time, the two sides interleaved, medians of `HYBSIM_BENCH_ROUNDS` rounds
//! (default 5); prints the ratios (target: CPU at most 1.5) and the load
//! average. Then 10⁴ samples of a 40-float state
//! (one jump every 100 samples) pushed into the MCAP and CSV sinks (criterion).
//! Files go to a temporary directory. The engine's own benchmarks run with
//! logging off.

use std::hint::black_box;
use std::path::Path;
use std::process::Command;

use criterion::{Criterion, Throughput, criterion_group};
use hybsim::arc::{ArcSink, HybridTime, SampleKind};
use hybsim::layout::{Entry, Field, Layout, Shape};
use hybsim::sinks::csv::CsvSink;
use hybsim::sinks::mcap::{McapOptions, McapSink};
use hybsim::sinks::{Decimation, RunInfo, RunOutcome};

const DIM: usize = 40;
const SAMPLES: usize = 10_000;

fn info() -> RunInfo {
    let mut info = RunInfo::new::<&str>("bench", &[], &["tick"]);
    info.state_layout = Layout {
        entries: vec![Entry::Field(Field {
            name: "x".into(),
            shape: Shape::Vector(DIM),
            offset: 0,
        })],
    };
    info.state_dim = DIM;
    info
}

/// A deterministic trajectory with a jump every 100 samples.
fn push(sink: &mut dyn ArcSink) {
    let mut x: Vec<f64> = (0..DIM).map(|k| (k as f64).sin()).collect();
    let mut j = 0;
    for k in 0..SAMPLES {
        let t = k as f64 * 1e-3;
        for (i, xi) in x.iter_mut().enumerate() {
            *xi = (*xi * 0.999 + 1e-3 * (t + i as f64).cos()).clamp(-1e3, 1e3);
        }
        if k % 100 == 99 {
            let at = HybridTime::new(t, j);
            let post: Vec<f64> = x.iter().map(|v| -v).collect();
            let _ = sink.sample(at, &x, SampleKind::PreJump);
            let _ = sink.jump(at, 0, &x, &post);
            j += 1;
            x = post;
            let _ = sink.sample(HybridTime::new(t, j), &x, SampleKind::PostJump);
        } else {
            let kind = if k == 0 {
                SampleKind::Initial
            } else {
                SampleKind::Flow
            };
            let _ = sink.sample(HybridTime::new(t, j), &x, kind);
        }
    }
}

fn logging(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("a temporary directory");
    let info = info();
    let done = RunOutcome::failed("bench", "benchmark");
    let mut group = c.benchmark_group("logging_40_floats");
    group.sample_size(10);
    group.throughput(Throughput::Elements(SAMPLES as u64));
    group.bench_function("mcap", |b| {
        b.iter(|| {
            let mut sink = McapSink::create(
                dir.path().join("b.mcap"),
                &info,
                None,
                McapOptions::default(),
            )
            .expect("sink");
            push(&mut sink);
            black_box(sink.finish(&done).expect("finished"));
        })
    });
    group.bench_function("mcap_every_10", |b| {
        b.iter(|| {
            let options = McapOptions::default().decimation(Decimation::all().every(10));
            let mut sink =
                McapSink::create(dir.path().join("d.mcap"), &info, None, options).expect("sink");
            push(&mut sink);
            black_box(sink.finish(&done).expect("finished"));
        })
    });
    group.bench_function("csv", |b| {
        b.iter(|| {
            let mut sink =
                CsvSink::create(dir.path().join("b.csv"), &info, None, Decimation::all())
                    .expect("sink");
            push(&mut sink);
            black_box(sink.finish().expect("finished"));
        })
    });
    group.finish();
}

/// CPU time (user + system) of the finished children of this process, in seconds.
fn children_cpu() -> f64 {
    // SAFETY: getrusage writes the struct it is given.
    let mut r: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut r) };
    let secs = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    secs(r.ru_utime) + secs(r.ru_stime)
}

/// CPU time and wall time of one `hybsim run MODEL ARGS`.
fn run_times(model: &Path, args: &[&str], dir: &Path) -> (f64, f64) {
    let before = children_cpu();
    let start = std::time::Instant::now();
    let status = Command::new(env!("CARGO_BIN_EXE_hybsim"))
        .arg("run")
        .arg(model)
        .args(args)
        .arg("--quiet")
        .current_dir(dir)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status()
        .expect("hybsim runs");
    assert!(status.success(), "{} {args:?}", model.display());
    (children_cpu() - before, start.elapsed().as_secs_f64())
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// MCAP against `--no-mcap` on the models of the logging budget.
fn ratios() {
    let rounds: usize = std::env::var("HYBSIM_BENCH_ROUNDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(5);
    let dir = tempfile::tempdir().expect("a temporary directory");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!("logging budget (MCAP / --no-mcap CPU time, median of {rounds}; load {load:.14})");
    for (name, model, extra) in [
        ("consensus", "models/consensus_estimation.hyb", &[][..]),
        (
            "consensus, events with their samples",
            "models/consensus_estimation.hyb",
            &["--log-rules", "event"][..],
        ),
        (
            "consensus, everything logged",
            "models/consensus_estimation.hyb",
            &["--log-vars", "*", "--log-rules", "*"][..],
        ),
        ("sample-and-hold", "models/sample_and_hold.hyb", &[][..]),
        (
            "sample-and-hold benchmark",
            "benches/models/limit_sh.hyb",
            &[][..],
        ),
    ] {
        let model = root.join(model);
        let (mut off, mut on) = (Vec::new(), Vec::new());
        for _ in 0..rounds {
            off.push(run_times(&model, &["--no-mcap"], dir.path()));
            let mut args = vec!["-o", "run.mcap"];
            args.extend(extra);
            on.push(run_times(&model, &args, dir.path()));
        }
        let size = std::fs::metadata(dir.path().join("run.mcap")).map_or(0, |m| m.len());
        let cpu = |v: &[(f64, f64)]| median(v.iter().map(|t| t.0).collect());
        let wall = |v: &[(f64, f64)]| median(v.iter().map(|t| t.1).collect());
        println!(
            "  {name:<30} CPU: --no-mcap {:8.4} s  MCAP {:8.4} s  ratio {:5.2}   wall: ratio {:5.2}   file {:.1} MB",
            cpu(&off),
            cpu(&on),
            cpu(&on) / cpu(&off),
            wall(&on) / wall(&off),
            size as f64 / 1e6
        );
    }
}

criterion_group!(benches, logging);

fn main() {
    ratios();
    benches();
    Criterion::default().configure_from_args().final_summary();
}
