//! The compiled `.hyb` models against the same models written in Rust on
//! the engine trait (`engine::models::{BouncingBall, SampleAndHold}`): same
//! engine, settings and initial state, so the ratio is the cost of the
//! compiled register programs against hand-written flow, guard and jump
//! functions. Results and the machine are in BENCHMARKS.md.
//!
//! `cargo bench --bench lang`

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use hybsim::engine::models::{BouncingBall, SampleAndHold};
use hybsim::engine::{HybridSystem, SimRng, SimSettings, Solver, simulate_arc};
use hybsim::lang::{self, CompiledModel};
use hybsim::source::SourceFile;

fn load(name: &str, overrides: &[&str]) -> CompiledModel {
    let path = format!("{}/models/{name}", env!("CARGO_MANIFEST_DIR"));
    let src = SourceFile::read(path).expect("model file");
    let ov: Vec<lang::Override> = overrides.iter().map(|s| s.parse().unwrap()).collect();
    lang::compile(&src, &ov).expect("the model compiles")
}

/// The Rust twin of models/sample_and_hold.hyb, from the model's own
/// resolved parameters (A, B, K, Ts).
fn hold_twin(m: &CompiledModel) -> SampleAndHold {
    let p = |name| m.parameter(name).expect("a parameter of the model");
    SampleAndHold::new(p("A"), p("B"), p("K"), p("Ts")[(0, 0)])
}

fn run(sys: &dyn HybridSystem, x0: &[f64], s: &SimSettings) -> (usize, Vec<f64>) {
    let arc = simulate_arc(sys, x0, s, &mut SimRng::seed_from(0)).expect("run");
    (arc.jumps().len(), arc.last().unwrap().x.to_vec())
}

/// A named pair (compiled, hand-written) with its initial state and settings.
type Pair<'a> = (
    &'a str,
    &'a dyn HybridSystem,
    &'a dyn HybridSystem,
    &'a [f64],
    &'a SimSettings,
);

/// Before timing: each pair computes the same solution.
fn agree(pairs: &[Pair]) {
    for (name, hyb, rust, x0, s) in pairs {
        let (ja, xa) = run(*hyb, x0, s);
        let (jb, xb) = run(*rust, x0, s);
        assert_eq!(ja, jb, "{name}: jump counts");
        let dev = xa
            .iter()
            .zip(&xb)
            .map(|(a, b)| (a - b).abs() / (1.0 + b.abs()))
            .fold(0.0, f64::max);
        assert!(dev < 1e-9, "{name}: final states differ by {dev:e}");
    }
}

fn benches(c: &mut Criterion) {
    let dopri5 = SimSettings::default().solver(Solver::Dopri5 {
        rtol: 1e-6,
        atol: 1e-9,
    });

    // Bouncing ball from h = 1 up to the Zeno guard.
    let ball_hyb = load("bouncing_ball.hyb", &[]);
    let mut ball_rust = BouncingBall::new(9.81, 0.8);
    let x_ball = [1.0, 0.0];
    let s_ball = dopri5.clone().horizon_t(20.0);
    let s_ball_general = s_ball.clone().exact_affine(false);
    ball_rust.affine = true;
    let ball_rust_affine = ball_rust.clone();
    ball_rust.affine = false;

    // 39-state sample-and-hold loop, 100 s (5000 samples).
    let hold_hyb = load("sample_and_hold.hyb", &[]);
    let mut hold_rust = hold_twin(&hold_hyb);
    let x_hold = hold_hyb.initial_state(&mut SimRng::seed_from(0));
    assert_eq!(x_hold, hold_rust.initial_state(&vec![0.1; 39]));
    let s_hold = dopri5.clone().horizon_t(100.0 + 0.01);
    let s_hold_general = s_hold.clone().exact_affine(false);
    hold_rust.affine = true;
    let hold_rust_affine = hold_rust.clone();
    hold_rust.affine = false;

    agree(&[
        (
            "ball, dopri5",
            &ball_hyb,
            &ball_rust,
            &x_ball,
            &s_ball_general,
        ),
        (
            "ball, exact",
            &ball_hyb,
            &ball_rust_affine,
            &x_ball,
            &s_ball,
        ),
        (
            "hold, dopri5",
            &hold_hyb,
            &hold_rust,
            &x_hold,
            &s_hold_general,
        ),
        (
            "hold, exact",
            &hold_hyb,
            &hold_rust_affine,
            &x_hold,
            &s_hold,
        ),
    ]);

    let mut g = c.benchmark_group("lang");
    g.sample_size(10);
    let cases: [(&str, &dyn HybridSystem, &[f64], &SimSettings); 8] = [
        (
            "bouncing_ball_dopri5/hyb",
            &ball_hyb,
            &x_ball,
            &s_ball_general,
        ),
        (
            "bouncing_ball_dopri5/rust",
            &ball_rust,
            &x_ball,
            &s_ball_general,
        ),
        ("bouncing_ball_exact/hyb", &ball_hyb, &x_ball, &s_ball),
        (
            "bouncing_ball_exact/rust",
            &ball_rust_affine,
            &x_ball,
            &s_ball,
        ),
        (
            "sample_and_hold_39_dopri5/hyb",
            &hold_hyb,
            &x_hold,
            &s_hold_general,
        ),
        (
            "sample_and_hold_39_dopri5/rust",
            &hold_rust,
            &x_hold,
            &s_hold_general,
        ),
        ("sample_and_hold_39_exact/hyb", &hold_hyb, &x_hold, &s_hold),
        (
            "sample_and_hold_39_exact/rust",
            &hold_rust_affine,
            &x_hold,
            &s_hold,
        ),
    ];
    for (name, sys, x0, s) in cases {
        g.bench_function(name, |b| {
            b.iter(|| simulate_arc(sys, black_box(x0), s, &mut SimRng::seed_from(0)))
        });
    }
    g.finish();
}

criterion_group!(lang_benches, benches);
criterion_main!(lang_benches);
