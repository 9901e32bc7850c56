//! Cost of logging: 10⁴ samples of a 40-float state (one jump every 100
//! samples) pushed into the MCAP and CSV sinks, files in a temporary
//! directory. The engine's own benchmarks run with logging off.

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
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

criterion_group!(benches, logging);
criterion_main!(benches);
