//! Fig. 2 of Phillips–Erwin–Sanfelice: |e| over t for the three scenarios
//! of Example 3.8, simulated from `models/intermittent_estimation.hyb`
//! (reconstructed gains, see the model file and REPRODUCTION.md).
//!
//! ```sh
//! cargo run --release --example intermittent_fig2 -- OUT_DIR [SEED]
//! ```
//!
//! Writes `fig2a.svg`, `fig2b.svg`, `fig2c.svg` (|e| on a linear axis, one
//! scenario each, as in the paper) and `fig2_log.svg` (the three on a
//! logarithmic axis, where the rates can be compared).

use std::path::PathBuf;

use hybsim::diagnostics::render;
use hybsim::engine::simulate_arc;
use hybsim::lang::{self, Override};
use hybsim::sinks::plot::{Figure, Panel, Series};
use hybsim::source::SourceFile;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (dir, seed) = match args.as_slice() {
        [dir] => (PathBuf::from(dir), 1),
        [dir, seed] => (PathBuf::from(dir), seed.parse()?),
        _ => anyhow::bail!("usage: intermittent_fig2 OUT_DIR [SEED]"),
    };
    std::fs::create_dir_all(&dir)?;
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/models/intermittent_estimation.hyb"
    );
    let src = SourceFile::read(path)?;
    let scenarios = [
        ('a', "", "(a) all-to-all"),
        ('b', "cut=1", "(b) edges (2,1), (3,2) removed"),
        ('c', "blind2=1", "(c) all-to-all, H_2 = 0"),
    ];
    let mut log_panel = Panel::new(format!("|e| over t, seed {seed}"))
        .x_label("t")
        .y_label("|e|")
        .log_y(true);
    for (letter, set, title) in scenarios {
        let overrides: Vec<Override> = [set, "T=40", "dt_out=0.02"]
            .iter()
            .filter(|s| !s.is_empty())
            .map(|s| s.parse())
            .collect::<Result<_, _>>()
            .map_err(|d| anyhow::anyhow!("{}", render(&[d], &src, false)))?;
        let model = lang::compile(&src, &overrides)
            .map_err(|d| anyhow::anyhow!("{}", render(&d, &src, false)))?;
        let k = model
            .output_names()
            .iter()
            .position(|n| n == "enorm")
            .ok_or_else(|| anyhow::anyhow!("the model has no output `enorm`"))?;
        let (z0, mut rng) = model.start(seed);
        let arc = simulate_arc(&model, &z0, &model.settings(), &mut rng)?;
        let mut y = vec![0.0; model.output_dim()];
        let e: Vec<(f64, f64)> = arc
            .samples()
            .map(|s| {
                model.outputs(s.at.t, s.x, &mut y);
                (s.at.t, y[k])
            })
            .collect();
        let file = dir.join(format!("fig2{letter}.svg"));
        Figure::new()
            .panel(
                Panel::new(title)
                    .x_label("t")
                    .y_label("|e|")
                    .series(Series::line("|e|", e.clone())),
            )
            .save(&file)?;
        println!(
            "({letter}) {} jumps, |e(0)| = {:.3}, |e(40)| = {:.3e} -> {}",
            arc.jumps().len(),
            e[0].1,
            e[e.len() - 1].1,
            file.display()
        );
        log_panel = log_panel.series(Series::line(title, e));
    }
    let file = dir.join("fig2_log.svg");
    Figure::new().panel(log_panel).save(&file)?;
    println!("-> {}", file.display());
    Ok(())
}
