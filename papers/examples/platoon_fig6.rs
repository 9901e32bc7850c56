//! Fig. 6 of Muehlebach & Trimpe: steady-state communication rate of every vehicle of the
//! platoon (mean ± standard deviation over seeds), with the stability condition of Cor. V.3.
//!
//! ```sh
//! cargo run --release --example platoon_fig6 -- OUT_DIR [M] [SEEDS] [T] [NAME=VALUE ...]
//! ```
//!
//! Defaults: M = 20, 20 seeds, T = 1000 s (as in the paper), steady state t ≥ 100 s.
//! J_max: the paper gives no value for M = 20 ("the design procedure is repeated"); the
//! procedure for M = 3 chose J_max "roughly 35 times" the full-communication power c*, so
//! the default is `Jmax=35*cstar` (c* from step 1 of this design). Extra `NAME=VALUE`
//! arguments are model overrides, e.g. `Jmax=0.38` for the M = 3 value; an extra argument
//! `ref=FILE.json` takes L, c* and Δ from a synthesis done elsewhere instead of the model's
//! design blocks (`ref=tests/data/platoon_m20_cor_v3.json`: M = 20, Cor. V.3, J_max = 35 c*,
//! solved with CSDP).
//!
//! Writes `OUT_DIR/fig6.csv` (vehicle, rate mean, rate std, max |d| of the distance the
//! vehicle measures, ‖e_i‖ power) and `OUT_DIR/fig6.svg`; prints the table and timings.

use std::error::Error;
use std::fmt::Write as _;
use std::time::Instant;

use hybsim::sinks::plot::{Bar, BarChart};
use hybsim_papers::experiments::platoon::{Platoon, Window, synthesis_overrides};

fn main() -> Result<(), Box<dyn Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let out = args.first().cloned().unwrap_or_else(|| ".".into());
    let m: usize = args.get(1).map_or(Ok(20), |s| s.parse())?;
    let seeds: u64 = args.get(2).map_or(Ok(20), |s| s.parse())?;
    let t: f64 = args.get(3).map_or(Ok(1000.0), |s| s.parse())?;
    let window = Window::default();
    if t.is_nan() || t <= window.t_ss {
        return Err(format!(
            "T = {t} must exceed the steady-state start {} s",
            window.t_ss
        )
        .into());
    }
    // One jump per 20 ms step; J must not stop the run before T.
    let mut sets = vec![
        format!("M={m}"),
        "corollary=3".to_string(),
        "Jmax=35*cstar".to_string(),
        format!("T={t}"),
        format!("J={}", (t / 0.02).ceil() as u64 + 10),
    ];
    for a in args.iter().skip(4) {
        match a.strip_prefix("ref=") {
            Some(file) => sets.extend(synthesis_overrides(file)?),
            None => sets.push(a.clone()),
        }
    }
    let path = hybsim_papers::model_path("platoon.hyb");
    let start = Instant::now();
    let platoon = Platoon::read(&path, &sets)?;
    let design_time = start.elapsed().as_secs_f64();
    let model = platoon.model();
    let scalar = |name: &str| model.parameter(name).map_or(f64::NAN, |p| p[(0, 0)]);
    println!(
        "M = {m}, Cor. V.3: c* = {:.6}, J_max = {:.5} (J_max/c* = {:.1}); compile + design {design_time:.1} s",
        scalar("cstar"),
        scalar("Jmax"),
        scalar("Jmax") / scalar("cstar")
    );
    for r in model.design_reports() {
        println!("  {}", r.summary_line());
    }
    if let Some(delta) = model.parameter("Delta") {
        println!("  Delta = {:.4?}", delta.iter().collect::<Vec<_>>());
    }
    let start = Instant::now();
    let e = platoon.ensemble(1..=seeds, &window)?;
    let wall = start.elapsed().as_secs_f64();
    println!(
        "{seeds} seeds × {t} s: {wall:.1} s wall ({:.2} s per run, {} threads)",
        wall / seeds as f64,
        rayon::current_num_threads()
    );
    let mut csv = String::from("vehicle,rate_mean,rate_std,max_abs_d,error_power\n");
    println!("vehicle  rate mean ± std   max |d| (m)   ‖e_i‖");
    for i in 0..m {
        // Vehicle i + 1 measures d_i (distance to the vehicle ahead); vehicle 1 its velocity.
        let d = if i == 0 {
            String::new()
        } else {
            e.distance_max[i - 1].to_string()
        };
        writeln!(
            csv,
            "{},{},{},{d},{}",
            i + 1,
            e.rate_mean[i],
            e.rate_std[i],
            e.error_power[i]
        )?;
        println!(
            "{:7}  {:6.3} % ± {:5.3}  {:>10}  {:.4}",
            i + 1,
            100.0 * e.rate_mean[i],
            100.0 * e.rate_std[i],
            if i == 0 {
                "—".to_string()
            } else {
                format!("{:.4}", e.distance_max[i - 1])
            },
            e.error_power[i]
        );
    }
    println!(
        "steady state: max |d| = {:.4} m, {} % quantile {:.4} m; mean rate vehicles 1–5 {:.3} %, last five {:.3} %",
        e.distance_max_all(),
        100.0 * window.quantile,
        e.distance_quantile_all,
        100.0 * e.mean_rate_of(1..=5.min(m)),
        100.0 * e.mean_rate_of(m.saturating_sub(4).max(1)..=m)
    );
    std::fs::create_dir_all(&out)?;
    std::fs::write(format!("{out}/fig6.csv"), csv)?;
    let bars = (0..m)
        .map(|i| Bar {
            label: (i + 1).to_string(),
            value: e.rate_mean[i],
            error: e.rate_std[i],
        })
        .collect();
    BarChart::new(
        format!(
            "Platoon M = {m}, Cor. V.3: communication at steady state ({seeds} seeds × {t} s, t ≥ {} s)",
            window.t_ss
        ),
        bars,
    )
    .x_label("vehicle")
    .y_label("communication rate (mean ± std)")
    .save(format!("{out}/fig6.svg"))?;
    println!("wrote {out}/fig6.csv and {out}/fig6.svg");
    Ok(())
}
