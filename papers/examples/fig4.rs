//! Fig. 4 of Trimpe & D'Andrea, "Event-based state estimation with
//! variance-based triggering", through the pipeline: `models/variance_triggering.hyb`
//! is compiled with `--set` overrides for each δ (a = 1.2, c = q = r = 1) and
//! simulated; the asymptotic period of p(k) is detected in the log and set
//! against Algorithm 1 (`hybsim_papers::analysis::variance_trigger`).
//!
//! Run: `cargo run --release --example fig4 -- OUT_DIR` (default `fig4-out`). Writes
//! - `fig4.svg`: p(k) with the threshold p̄ + δ/c² and γ(k) for δ = 3 (Example 1) and the
//!   smallest δ of the sweep with period 5 and with period 19, as in Fig. 4 (a)–(c);
//! - `sweep.svg`: asymptotic period versus δ, simulated and from Algorithm 1;
//! - `sweep.csv`: one line per δ (Algorithm 1, Assumption 2, bounds, simulated period,
//!   verdict);
//!
//! and prints the three δ with their periods. The test `fig4_data_match_algorithm1`
//! (tests/it/variance_trigger.rs) checks the same data.

use std::error::Error;
use std::path::PathBuf;

use hybsim_papers::analysis::variance_trigger::VarianceIteration;
use hybsim_papers::experiments::variance_trigger::{
    MODEL_PATH, SweepSettings, VarianceTriggerModel,
};

/// Steps drawn per transmit sequence.
const TRACE_STEPS: usize = 60;

fn main() -> Result<(), Box<dyn Error>> {
    let out = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "fig4-out".into()));
    std::fs::create_dir_all(&out)?;
    let model_path = hybsim_papers::repo_path(MODEL_PATH);
    let model = VarianceTriggerModel::read(&model_path)
        .map_err(|e| format!("{}: {e}", model_path.display()))?;
    let example1 = VarianceIteration::new(1.2, 1.0, 1.0, 1.0, 3.0)?;
    let fig = model.fig4(&example1, &[5, 19], &SweepSettings::default(), TRACE_STEPS)?;

    fig.traces_figure().save(out.join("fig4.svg"))?;
    fig.sweep_figure().save(out.join("sweep.svg"))?;
    std::fs::write(out.join("sweep.csv"), fig.sweep_csv())?;

    println!("delta      simulated period  Algorithm 1  verdict");
    for tr in &fig.traces {
        let a = &tr.row.analysis;
        let show = |n: Option<usize>| n.map_or("none".to_string(), |n| n.to_string());
        println!(
            "{:<10} {:<17} {:<12} {}",
            a.delta,
            show(tr.row.simulated_period),
            show(a.period),
            tr.row.comparison.label()
        );
    }
    println!(
        "{} δ in the sweep; wrote fig4.svg, sweep.svg, sweep.csv to {}",
        fig.sweep.len(),
        out.display()
    );
    Ok(())
}
