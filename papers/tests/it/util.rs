//! Helpers shared by the reproduction tests.

use hybsim::arc::HybridArc;
use hybsim::engine::{HybridSystem, SimError, SimRng, SimSettings};
use hybsim::lang::{self, CompiledModel, Override};
use hybsim::source::SourceFile;

/// `hybsim::engine::simulate_arc`, and every arc it returns checked with
/// `engine::check_arc` (each jump starts from a point of D, each flow in C
/// within `set_tol`), as the library's integration tests do.
pub fn simulate_arc<S: HybridSystem + ?Sized>(
    sys: &S,
    x0: &[f64],
    settings: &SimSettings,
    rng: &mut SimRng,
) -> Result<HybridArc, SimError> {
    let arc = hybsim::engine::simulate_arc(sys, x0, settings, rng)?;
    if let Err(violation) = hybsim::engine::check_arc(sys, &arc, settings) {
        panic!("the arc breaks the engine's invariants: {violation}");
    }
    Ok(arc)
}

/// Compiles the shipped model `models/NAME` with `--set` overrides; panics
/// with the rendered diagnostics if it does not compile.
pub fn load(name: &str, overrides: &[&str]) -> CompiledModel {
    let src = SourceFile::read(hybsim_papers::model_path(name)).expect("model file");
    let ov: Vec<Override> = overrides.iter().map(|s| s.parse().unwrap()).collect();
    match lang::compile(&src, &ov) {
        Ok(m) => m,
        Err(d) => panic!("{}", hybsim::diagnostics::render(&d, &src, false)),
    }
}

/// Runs `m` from its initial state with its own seed and settings.
pub fn run(m: &CompiledModel) -> HybridArc {
    let (x0, mut rng) = m.start(m.seed());
    simulate_arc(m, &x0, &m.settings(), &mut rng).expect("simulation")
}
