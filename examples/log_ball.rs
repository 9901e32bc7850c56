//! Logs a bouncing ball defined in Rust (no `.hyb` file) to MCAP, CSV and
//! SVG with the library's sinks:
//!
//! ```sh
//! cargo run --release --example log_ball -- ball.mcap ball.csv ball.svg
//! ```

use hybsim::arc::HybridTime;
use hybsim::engine::models::BouncingBall;
use hybsim::engine::{SimRng, SimSettings, simulate};
use hybsim::layout::Layout;
use hybsim::sinks::csv::CsvSink;
use hybsim::sinks::mcap::{McapOptions, McapSink};
use hybsim::sinks::plot::PlotSink;
use hybsim::sinks::{Decimation, Fanout, RunInfo, RunOutcome};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [mcap, csv, svg] = args.as_slice() else {
        anyhow::bail!("usage: log_ball OUT.mcap OUT.csv OUT.svg");
    };
    let ball = BouncingBall::new(9.81, 0.8);
    let mut info = RunInfo::new("bouncing_ball", &["h", "v"], &["impact"]);
    info.parameters = serde_json::json!({"g": ball.g, "lambda": ball.lambda});
    info.output_layout = Layout::scalars(&["energy"]);
    info.output_dim = 1;
    let energy =
        |_at: HybridTime, x: &[f64], y: &mut [f64]| y[0] = ball.g * x[0] + 0.5 * x[1] * x[1];

    let settings = SimSettings::default().horizon_j(20).dt_out(Some(0.01));
    let mut mcap_sink = McapSink::create(mcap, &info, Some(&energy), McapOptions::default())?;
    let mut csv_sink = CsvSink::create(csv, &info, Some(&energy), Decimation::all())?;
    let select = vec!["h".to_string(), "v".to_string(), "energy".to_string()];
    let mut plot_sink = PlotSink::new(svg, &info, Some(&energy), &select, Decimation::all())?;
    let termination = {
        let mut fan = Fanout::new(vec![&mut mcap_sink, &mut csv_sink, &mut plot_sink]);
        simulate(
            &ball,
            &[1.0, 0.0],
            &settings,
            &mut SimRng::seed_from(0),
            &mut fan,
        )?
    };
    let summary = mcap_sink.finish(&RunOutcome::from_termination(&termination))?;
    csv_sink.finish()?;
    plot_sink.finish()?;
    println!("{termination}; messages per topic: {:?}", summary.messages);
    Ok(())
}
