//! Fig. 5 (right) of Muehlebach & Trimpe: steady-state estimation error ‖e_i‖_P versus
//! communication rate for the event-based platoon (M = 3) and for a centralized periodic
//! Kalman filter on the system re-sampled every m steps.
//!
//! Event-based points: the thresholds for a given J_max follow from the model's default Δ
//! (step 2 of the synthesis for J_max = 0.38) by homogeneity: with L fixed, (40) constrains
//! ‖(zI − Â)⁻¹ L Δ‖∞ < (J_max − c*)/√N, so the maximizer scales with J_max − c*.
//! c* is the H₂ norm of the full-communication error system.
//!
//! Run: `cargo run --release --example platoon_tradeoff -- OUT_DIR` (writes tradeoff.csv and
//! tradeoff.svg; prints the table).

use std::error::Error;
use std::fmt::Write as _;

use hybsim::design::control::{StateSpace, dare, h2_norm};
use hybsim::lang::{self, CompiledModel, Override};
use hybsim::sinks::plot::{Figure, Panel, Series};
use hybsim::source::SourceFile;
use hybsim_papers::experiments::platoon::{Platoon, Window};
use nalgebra::DMatrix;

/// A parameter of the compiled model (after overrides and `design` blocks).
fn param(m: &CompiledModel, name: &str) -> DMatrix<f64> {
    m.parameter(name)
        .unwrap_or_else(|| panic!("the model has no parameter `{name}`"))
}

fn compile(src: &SourceFile, sets: &[String]) -> Result<CompiledModel, Box<dyn Error>> {
    let ov: Vec<Override> = sets
        .iter()
        .map(|s| s.parse::<Override>())
        .collect::<Result<_, _>>()
        .map_err(|d| hybsim::diagnostics::render(&[d], src, false))?;
    lang::compile(src, &ov).map_err(|d| hybsim::diagnostics::render(&d, src, false).into())
}

/// Mean transmit rate (all agents) and ‖e_i‖_P (RMS over agents and steps), t ≥ 100 s, seeds
/// 1..=`seeds` × 400 s, through `experiments::platoon` (one compilation per Δ).
fn simulate(src: &SourceFile, delta: &[f64], seeds: u64) -> Result<(f64, f64), Box<dyn Error>> {
    let d = delta
        .iter()
        .map(|v| v.to_string())
        .collect::<Vec<_>>()
        .join("; ");
    let p = Platoon::compile(src, &[format!("Delta=[{d}]"), "T=400".into()])?;
    let e = p.ensemble(1..=seeds, &Window::default())?;
    let agents = e.rate_mean.len() as f64;
    let rate = e.rate_mean.iter().sum::<f64>() / agents;
    let power = (e.error_power.iter().map(|v| v * v).sum::<f64>() / agents).sqrt();
    Ok((rate, power))
}

fn main() -> Result<(), Box<dyn Error>> {
    let out = std::env::args().nth(1).unwrap_or_else(|| ".".into());
    let path = hybsim_papers::model_path("platoon.hyb");
    let src = SourceFile::read(&path)?;
    let m = compile(&src, &[])?;
    let (a, b, c, l) = (
        param(&m, "A"),
        param(&m, "B"),
        param(&m, "C"),
        param(&m, "L"),
    );
    let (aw, au, ts) = (
        param(&m, "a_w")[(0, 0)],
        param(&m, "a_u")[(0, 0)],
        param(&m, "Ts")[(0, 0)],
    );
    let delta0: Vec<f64> = param(&m, "Delta").iter().copied().collect();
    let (n, p, k) = (a.nrows(), c.nrows(), b.ncols());
    let w = DMatrix::identity(p, p) * (aw * aw / 3.0);
    let v = &b * b.transpose() * (au * au / 3.0);
    // c* of the designed gains.
    let ilc = DMatrix::identity(n, n) - &l * &c;
    let mut b2 = DMatrix::zeros(n, p + k);
    b2.view_mut((0, 0), (n, p))
        .copy_from(&(&l * (-aw / 3f64.sqrt())));
    b2.view_mut((0, p), (n, k))
        .copy_from(&(&ilc * &b * (au / 3f64.sqrt())));
    let cstar = h2_norm(&StateSpace::discrete(
        &ilc * &a,
        b2,
        DMatrix::identity(n, n),
        DMatrix::zeros(n, p + k),
        ts,
    )?)?;
    let j0 = 0.38;
    let mut csv = String::from("design,J_max_or_m,rate,e_P\n");
    let mut event = Vec::new();
    println!("c* = {cstar:.6}\nevent-based: J_max, Δ, rate, ‖e‖_P");
    for jmax in [0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.33, 0.36, 0.38, 0.42, 0.5] {
        let scale = (jmax - cstar) / (j0 - cstar);
        let delta: Vec<f64> = delta0.iter().map(|d| d * scale).collect();
        let (rate, ep) = simulate(&src, &delta, 4)?;
        println!("{jmax:5.2} {delta:.4?} {rate:.4} {ep:.5}");
        writeln!(csv, "event,{jmax},{rate},{ep}")?;
        event.push((rate, ep));
    }
    println!("centralized periodic KF: m, rate, ‖e‖_P");
    let mut periodic = Vec::new();
    for mm in [1usize, 2, 3, 4, 5, 7, 10, 15, 20, 30, 50] {
        // Re-sampled system: A^m, V_m = Σ_{i<m} A^i V A^iᵀ; inputs known to the filter.
        let mut am = DMatrix::identity(n, n);
        let mut vm = DMatrix::zeros(n, n);
        for _ in 0..mm {
            vm = &am * &v * am.transpose() + vm;
            am = &a * am;
        }
        let pm = dare(&am.transpose(), &c.transpose(), &vm, &w)?;
        let s = &c * &pm * c.transpose() + &w;
        let gain = &pm * c.transpose() * s.try_inverse().ok_or("singular innovation covariance")?;
        let mut sig = (DMatrix::identity(n, n) - gain * &c) * pm;
        let mut tr = 0.0;
        for _ in 0..mm {
            tr += sig.trace();
            sig = &a * sig * a.transpose() + &v;
        }
        let (rate, ep) = (1.0 / mm as f64, (tr / mm as f64).sqrt());
        println!("{mm:3} {rate:.4} {ep:.5}");
        writeln!(csv, "periodic,{mm},{rate},{ep}")?;
        periodic.push((rate, ep));
    }
    std::fs::create_dir_all(&out)?;
    std::fs::write(format!("{out}/tradeoff.csv"), csv)?;
    let fig = Figure::new().panel(
        Panel::new("Platoon M = 3: estimation error vs communication (Fig. 5 right)")
            .x_label("communication rate")
            .y_label("‖e_i‖_P")
            .log_y(true)
            .series(Series::line("event-based (Cor. V.2)", event).markers(true))
            .series(Series::line("centralized periodic KF", periodic).markers(true)),
    );
    fig.save(format!("{out}/tradeoff.svg"))?;
    println!("wrote {out}/tradeoff.csv and {out}/tradeoff.svg");
    Ok(())
}
