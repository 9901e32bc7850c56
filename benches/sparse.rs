//! Sparse Jacobians: the implicit solvers on a large sparse stiff hybrid
//! model, `benches/models/heat_chain.hyb` (a rod in N cells heated by a
//! thermostat with hysteresis; tridiagonal Jacobian, fastest mode ≈ 4N²),
//! with `linear_solver = dense` and `sparse` (and which one `auto` takes),
//! for N = 50, 100, 200, 400 on `radau5` and `bdf`. CPU time of this
//! thread per run (compiled model, every sample pushed to a sink that keeps
//! the final state and the jump times, as `hybsim run --no-mcap`), median
//! of 5 batches; the largest difference of the switching times and of the
//! final state between the two paths. Results and the machine are in
//! BENCHMARKS.md ("Sparse Jacobians").
//!
//! ```text
//! cargo bench --bench sparse
//! ```

mod common;
use common::{Keep, cpu_now, median};

use std::path::PathBuf;

use hybsim::engine::{HybridSystem, LinearSolver, Solver, simulate, use_sparse_lu};
use hybsim::ir::CompiledModel;
use hybsim::lang;
use hybsim::source::SourceFile;

fn run(m: &CompiledModel, solver: Solver, linear: LinearSolver) -> Keep {
    let (x0, mut rng) = m.start(m.seed());
    let mut keep = Keep::default();
    let settings = m.settings().solver(solver).linear_solver(linear);
    simulate(m, &x0, &settings, &mut rng, &mut keep).expect("simulation");
    keep
}

/// CPU seconds per run: the median over 5 batches of the mean of runs
/// filling about 0.2 s each.
fn time(m: &CompiledModel, solver: Solver, linear: LinearSolver) -> f64 {
    let mut batches = Vec::new();
    for _ in 0..5 {
        let start = cpu_now();
        let mut n = 0u32;
        while n == 0 || (cpu_now() - start < 0.2 && n < 10_000) {
            let _ = std::hint::black_box(run(m, solver, linear));
            n += 1;
        }
        batches.push((cpu_now() - start) / f64::from(n));
    }
    median(batches)
}

fn main() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("benches/models/heat_chain.hyb"))
        .expect("benches/models/heat_chain.hyb");
    println!(
        "| N (states) | solver | dense LU | sparse LU | dense / sparse | auto takes | jumps | switch times, max diff | final state, max diff |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for cells in [50usize, 100, 200, 400] {
        let src = SourceFile::new(
            "heat_chain.hyb",
            text.replace("param N = 200", &format!("param N = {cells}")),
        );
        let m = lang::compile(&src, &[])
            .unwrap_or_else(|d| panic!("{}", hybsim::diagnostics::render(&d, &src, false)));
        let auto = if use_sparse_lu(m.jacobian_pattern().as_ref(), LinearSolver::Auto) {
            "sparse"
        } else {
            "dense"
        };
        let (rtol, atol) = m.settings().solver.tolerances().expect("adaptive");
        for name in ["radau5", "bdf"] {
            let solver = Solver::adaptive(name, rtol, atol).expect("a solver");
            let dense = run(&m, solver, LinearSolver::Dense);
            let sparse = run(&m, solver, LinearSolver::Sparse);
            assert_eq!(dense.jumps.len(), sparse.jumps.len(), "{name}: jumps");
            let dt = dense
                .jumps
                .iter()
                .zip(&sparse.jumps)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            let dx = dense
                .last
                .iter()
                .zip(&sparse.last)
                .map(|(a, b)| (a - b).abs() / (atol + rtol * a.abs()))
                .fold(0.0, f64::max);
            let (td, ts) = (
                time(&m, solver, LinearSolver::Dense),
                time(&m, solver, LinearSolver::Sparse),
            );
            println!(
                "| {cells} ({}) | `{name}` | {:.2} ms | {:.2} ms | {:.1}× | {auto} | {} | {dt:.1e} | {dx:.1e} tol |",
                m.state_dim(),
                td * 1e3,
                ts * 1e3,
                td / ts,
                dense.jumps.len(),
            );
        }
    }
}
