//! Fig. 6 of Perez-Salesa, Aldana-Lopez & Sagues, "Event-triggered consensus
//! for continuous-time distributed estimation", through the pipeline:
//! `models/consensus_estimation.hyb` is compiled for each threshold δ and
//! simulated with S seeds (T_f = 10, h = 1e-4); the error 𝓔 and the
//! normalised communication frequency 𝓕 of Sec. 5 are averaged per δ.
//!
//! Run: `cargo run --release --example consensus_tradeoff -- [OUT_DIR] [S] [DELTA_STEP]`
//! (defaults `consensus-out`, S = 20, δ = 0, 10, …, 80: 180 runs of about
//! 10 s each, spread over the cores). Writes `tradeoff.csv`
//! (`delta,runs,failed,error,frequency`) and `tradeoff.svg`, and prints the
//! table. The test `perez_salesa_reproduction` (tests/it/perez_salesa.rs)
//! checks the trend on δ ∈ {0, 25, 50, 80} with one seed.

use std::error::Error;
use std::path::PathBuf;

use hybsim_papers::experiments::consensus_estimation::{
    ConsensusModel, MODEL_PATH, tradeoff_csv, tradeoff_figure,
};

fn main() -> Result<(), Box<dyn Error>> {
    let mut args = std::env::args().skip(1);
    let out = PathBuf::from(args.next().unwrap_or_else(|| "consensus-out".into()));
    let seeds: u64 = args.next().map_or(Ok(20), |s| s.parse())?;
    let step: f64 = args.next().map_or(Ok(10.0), |s| s.parse())?;
    if step.is_nan() || step <= 0.0 {
        return Err("DELTA_STEP must be positive".into());
    }
    std::fs::create_dir_all(&out)?;
    let path = hybsim_papers::repo_path(MODEL_PATH);
    let model = ConsensusModel::read(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let deltas: Vec<f64> = (0..)
        .map(|k| k as f64 * step)
        .take_while(|&d| d <= 80.0 + 1e-9)
        .collect();
    let points = model.tradeoff(&deltas, seeds, &[] as &[&str])?;
    std::fs::write(out.join("tradeoff.csv"), tradeoff_csv(&points))?;
    tradeoff_figure(&points).save(out.join("tradeoff.svg"))?;
    println!("delta   runs  failed  error     frequency");
    for p in &points {
        println!(
            "{:6.1}  {:4}  {:6}  {:8.4}  {:.6}",
            p.delta, p.runs, p.failed, p.error, p.frequency
        );
    }
    println!("wrote {}", out.display());
    Ok(())
}
