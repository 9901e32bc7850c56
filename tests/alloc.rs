//! The engine's hot path allocates nothing per step, segment or jump: a
//! counting global allocator (per thread) sees the same number of
//! allocations for a run and for the same run twice as long. A separate
//! test binary, since it replaces the global allocator.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::ops::ControlFlow;

use hybsim::arc::{ArcSink, HybridTime, SampleKind};
use hybsim::engine::models::{BouncingBall, HeatChain, RandomTimers, SampleAndHold};
use hybsim::engine::{
    ExactAffine, HybridSystem, LinearSolver, SimRng, SimSettings, Solver, simulate,
};
use nalgebra::DMatrix;

struct Counting;

thread_local! {
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

fn count() {
    // `try_with`: thread-local storage may be gone while a thread exits.
    let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
}

// SAFETY: forwards to the system allocator; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Counts samples and jumps without keeping them.
#[derive(Default)]
struct Tally {
    samples: u64,
    jumps: u64,
}

impl ArcSink for Tally {
    fn sample(&mut self, _: HybridTime, _: &[f64], _: SampleKind) -> ControlFlow<()> {
        self.samples += 1;
        ControlFlow::Continue(())
    }

    fn jump(&mut self, _: HybridTime, _: usize, _: &[f64], _: &[f64]) -> ControlFlow<()> {
        self.jumps += 1;
        ControlFlow::Continue(())
    }
}

/// Allocations of one run to horizon `t`, and its tally.
fn run<S: HybridSystem>(sys: &S, x0: &[f64], s: &SimSettings, t: f64) -> (u64, Tally) {
    let mut tally = Tally::default();
    let s = s.clone().horizon_t(t);
    let mut rng = SimRng::seed_from(3);
    let before = ALLOCATIONS.with(Cell::get);
    simulate(sys, x0, &s, &mut rng, &mut tally).expect("simulation");
    (ALLOCATIONS.with(Cell::get) - before, tally)
}

/// Same allocations for horizons `t` and `2t`, with many more steps and
/// jumps in the longer run.
fn check<S: HybridSystem>(what: &str, sys: &S, x0: &[f64], s: &SimSettings, t: f64) {
    // A first run warms up whatever is allocated once per process.
    run(sys, x0, s, t);
    let (a1, t1) = run(sys, x0, s, t);
    let (a2, t2) = run(sys, x0, s, 2.0 * t);
    assert!(
        t2.samples > t1.samples + 10 && t2.jumps > t1.jumps + 5,
        "{what}: the longer run must do more work ({} / {} samples, {} / {} jumps)",
        t1.samples,
        t2.samples,
        t1.jumps,
        t2.jumps
    );
    assert_eq!(
        a1,
        a2,
        "{what}: {a1} allocations to t = {t}, {a2} to t = {}: the hot path allocates",
        2.0 * t
    );
}

#[test]
fn hot_path_allocates_nothing_per_step_segment_or_jump() {
    // Guards on the engine's Dopri5 (the ball, to t = 4 close to its Zeno
    // time: many impacts in the second half).
    let mut ball = BouncingBall::new(9.81, 0.8);
    ball.affine = true;
    let s = SimSettings::default().zeno_max_rate(f64::INFINITY);
    check("ball, dopri5", &ball, &[1.0, 0.0], &s, 2.0);
    // Periodic sampling: auto (exact after a few periods), on, off; and the
    // solver with an output grid. (The exact path localizing events or
    // cutting steps at grid points computes exponentials of one-off
    // durations, which nalgebra allocates.)
    let a = DMatrix::from_row_slice(3, 3, &[0.0, 1.0, 0.0, -4.0, -0.2, 0.0, 1.0, 0.0, 0.0]);
    let b = DMatrix::from_row_slice(3, 2, &[0.0, 0.0, 1.0, 0.0, 0.0, 1.0]);
    let k = DMatrix::from_row_slice(2, 3, &[1.0, 0.8, 0.1, 0.0, 0.1, 0.5]);
    let mut sh = SampleAndHold::new(a, b, k, 0.1);
    sh.affine = true;
    let x0 = sh.initial_state(&[1.0, -0.5, 0.25]);
    for mode in [ExactAffine::Auto, ExactAffine::On, ExactAffine::Off] {
        let s = SimSettings::default().exact_affine(mode);
        check(&format!("sample-and-hold, {mode:?}"), &sh, &x0, &s, 5.0);
    }
    let s = SimSettings::default()
        .exact_affine(ExactAffine::Off)
        .dt_out(Some(0.03));
    check("sample-and-hold, dopri5, dt_out", &sh, &x0, &s, 5.0);
    // The implicit solvers and auto (on a stiff plant, where auto turns
    // to Radau5), with the system's own Jacobian.
    let a = DMatrix::from_row_slice(2, 2, &[-1000.0, 1.0, 0.0, -1.0]);
    let b = DMatrix::from_row_slice(2, 1, &[0.0, 1.0]);
    let k = DMatrix::from_row_slice(1, 2, &[0.5, 2.0]);
    let stiff = SampleAndHold::new(a, b, k, 0.1);
    let x0 = stiff.initial_state(&[1.0, -1.0]);
    for solver in ["radau5", "bdf", "auto"] {
        let s = SimSettings::default()
            .exact_affine(ExactAffine::Off)
            .solver(Solver::adaptive(solver, 1e-6, 1e-9).expect("a solver"));
        check(
            &format!("stiff sample-and-hold, {solver}"),
            &stiff,
            &x0,
            &s,
            3.0,
        );
    }
    // The sparse path: faer's LU of the Newton matrices (its factors and
    // workspace are allocated at the first factorization and reused), the
    // Jacobian as the entries of its pattern, exact or by grouped
    // differences (buffers kept).
    let mut chain = HeatChain::new(40);
    chain.pattern = true;
    let x0 = chain.initial_state();
    for exact in [false, true] {
        chain.exact = exact;
        for solver in ["radau5", "bdf"] {
            let s = SimSettings::default()
                .linear_solver(LinearSolver::Sparse)
                .solver(Solver::adaptive(solver, 1e-6, 1e-9).expect("a solver"));
            check(
                &format!("heat chain, {solver}, sparse, exact {exact}"),
                &chain,
                &x0,
                &s,
                8.0,
            );
        }
    }
    // The compiled heat chain: its symbolic Jacobian's program on the
    // pattern derived from the expression graph, sparse LU by default.
    let src = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/models/heat_chain.hyb"),
    )
    .expect("benches/models/heat_chain.hyb")
    .replace("param N = 200", "param N = 40");
    let file = hybsim::source::SourceFile::new("heat_chain.hyb", src.as_str());
    let m = hybsim::lang::compile(&file, &[]).expect("the heat chain compiles");
    // Machine code for every program now: by default each is compiled
    // (allocating) when it has run often enough, which may happen in any
    // run until then; that is warm-up, not the hot path.
    m.compile_machine_code();
    let (x0, _) = m.start(m.seed());
    for solver in ["radau5", "bdf"] {
        let s = m
            .settings()
            .solver(Solver::adaptive(solver, 1e-6, 1e-9).expect("a solver"));
        check(&format!("compiled heat chain, {solver}"), &m, &x0, &s, 8.0);
    }
    // Timers with random resets.
    let timers = RandomTimers::new(3, 0.1, 0.7);
    check(
        "random timers",
        &timers,
        &[0.3, 0.5, 0.05],
        &SimSettings::default(),
        10.0,
    );
}
