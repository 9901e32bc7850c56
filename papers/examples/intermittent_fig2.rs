//! Fig. 2 of Phillips–Erwin–Sanfelice: |e| over t for the three scenarios
//! of Example 3.8, simulated from `models/intermittent_estimation.hyb`
//! (reconstructed gains, see the model file and REPRODUCTION.md).
//!
//! ```sh
//! cargo run --release --example intermittent_fig2 -- OUT_DIR [SEED [T]]
//! ```
//!
//! Writes `fig2a.svg`, `fig2b.svg`, `fig2c.svg` (|e| on a linear axis, one
//! scenario each, as in the paper) and `fig2_log.svg` (the three on a
//! logarithmic axis, where the rates can be compared); horizon T = 40 by
//! default. The data come from `hybsim_papers::experiments::intermittent::fig2`.

use std::path::PathBuf;

use hybsim::source::SourceFile;
use hybsim_papers::experiments::intermittent::{fig2, fig2_figures};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (dir, seed, horizon) = match args.as_slice() {
        [dir] => (PathBuf::from(dir), 1, 40.0),
        [dir, seed] => (PathBuf::from(dir), seed.parse()?, 40.0),
        [dir, seed, t] => (PathBuf::from(dir), seed.parse()?, t.parse()?),
        _ => anyhow::bail!("usage: intermittent_fig2 OUT_DIR [SEED [T]]"),
    };
    std::fs::create_dir_all(&dir)?;
    let path = hybsim_papers::model_path("intermittent_estimation.hyb");
    let src = SourceFile::read(&path)?;
    let traces = fig2(&src, seed, horizon, 0.02)?;
    for tr in &traces {
        let (first, last) = (tr.enorm[0], tr.enorm[tr.enorm.len() - 1]);
        println!(
            "({}) {} jumps, |e(0)| = {:.3}, |e({})| = {:.3e}",
            tr.letter, tr.jumps, first.1, last.0, last.1
        );
    }
    for (name, figure) in fig2_figures(&traces, seed) {
        let file = dir.join(name);
        figure.save(&file)?;
        println!("-> {}", file.display());
    }
    Ok(())
}
