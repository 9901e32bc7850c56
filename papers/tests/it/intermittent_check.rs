//! Issue 8: Proposition 3.5 as the `check prop_3_5` block of
//! models/intermittent_estimation.hyb — its matrices against
//! `analysis::intermittent_estimation::Network`, its verdict against `Network::check_prop_3_5` over all 2^N
//! vertices of the timer box, why all vertices are needed, and `hybsim
//! design` on the model (`hybsim run` skipping the check: tests/it/models.rs
//! of the library).

use std::path::PathBuf;

use hybsim::source::SourceFile;
use hybsim_papers::analysis::intermittent_estimation::{Network, Scenario, Vertices};
use hybsim_papers::experiments;
use nalgebra::DMatrix;

fn shipped() -> PathBuf {
    hybsim_papers::model_path("intermittent_estimation.hyb")
}

fn scenario_sets(s: Scenario) -> Vec<&'static str> {
    match s {
        Scenario::AllToAll => vec![],
        Scenario::EdgesRemoved => vec!["cut=1"],
        Scenario::Agent2Blind => vec!["blind2=1"],
    }
}

/// A matrix parameter of a compiled model.
fn matrix(json: &serde_json::Value, name: &str) -> DMatrix<f64> {
    let rows: Vec<Vec<f64>> =
        serde_json::from_value(json[name].clone()).unwrap_or_else(|e| panic!("{name}: {e}"));
    DMatrix::from_fn(rows.len(), rows[0].len(), |i, j| rows[i][j])
}

#[test]
fn the_models_closed_loop_matrix_is_network_a_f() {
    // A_f of (19) built in the .hyb (graph, gains, Laplacian, K_theta, ...)
    // equals `Network::a_f` in each scenario (edges in the same order).
    let src = SourceFile::read(shipped()).unwrap();
    for s in Scenario::ALL {
        let m = experiments::compile(&src, &scenario_sets(s)).unwrap();
        let json = m.parameters_json();
        let net = Network::paper_example(s);
        let a_f = matrix(&json, "A_f");
        let want = net.a_f();
        assert_eq!(a_f.shape(), want.shape(), "({})", s.letter());
        let err = (&a_f - &want).abs().max();
        assert!(
            err <= 1e-12,
            "({}): max |A_f - a_f()| = {err:e}",
            s.letter()
        );
        assert_eq!(json["nE"].as_f64(), Some(net.edges().len() as f64));
    }
}

#[test]
fn m_is_affine_in_the_vertex_weights_so_all_corners_are_needed() {
    // M(nu) is affine in w_k = exp(sigma nu_k): at any nu of the box it is
    // the combination of the 2^N vertex matrices with the multilinear
    // weights prod_k (theta_k or 1 - theta_k), theta_k = (w_k - 1)/(W_k - 1).
    // So M < 0 at the 8 vertices gives M < 0 on the box, and the paper's two
    // vertices (0 and T2) do not: the weights of the other six are nonzero.
    let net = Network::paper_example(Scenario::AllToAll);
    let (n, ne, d) = (net.n(), net.n() * net.agents(), net.edges().len());
    let sigma: f64 = 1.3;
    // Arbitrary symmetric P, R (affinity holds for any).
    let p = DMatrix::from_fn(ne, ne, |i, j| {
        ((i * 7 + j * 7) % 11) as f64 / 10.0 + if i == j { 3.0 } else { 0.0 }
    });
    let r: Vec<DMatrix<f64>> = (0..d)
        .map(|e| {
            DMatrix::from_fn(n, n, |i, j| {
                ((i + j + e) % 3) as f64 + if i == j { 2.0 } else { 0.0 }
            })
        })
        .collect();
    let corners = net.timer_points(&Vertices::Box);
    assert_eq!(corners.len(), 8);
    for paper in net.timer_points(&Vertices::Paper) {
        assert!(corners.contains(&paper));
    }
    let t2 = net.t2().to_vec();
    for nu in [
        vec![0.1_f64, 0.6, 0.35],
        vec![0.7, 0.0, 0.2],
        vec![0.33, 0.33, 0.5],
    ] {
        let theta: Vec<f64> = (0..3)
            .map(|k| ((sigma * nu[k]).exp() - 1.0) / ((sigma * t2[k]).exp() - 1.0))
            .collect();
        let mut combo = DMatrix::zeros(ne + n * d, ne + n * d);
        for v in &corners {
            let weight: f64 = (0..3)
                .map(|k| if v[k] > 0.0 { theta[k] } else { 1.0 - theta[k] })
                .product();
            combo += net.m_of(&p, &r, sigma, v) * weight;
        }
        let m = net.m_of(&p, &r, sigma, &nu);
        let err = (&m - &combo).abs().max() / m.abs().max();
        assert!(err < 1e-12, "nu = {nu:?}: relative error {err:e}");
    }
}

#[test]
fn the_check_block_agrees_with_network_check_prop_3_5() {
    // The model's `check prop_3_5` solved as `hybsim design` solves it
    // (lang::design_only) and `Network::check_prop_3_5` over all 8 vertices,
    // same sigma and eps: the same verdict.
    let src = SourceFile::read(shipped()).unwrap();
    let reports = hybsim::lang::design_only(&src, &[])
        .unwrap_or_else(|d| panic!("{}", hybsim::diagnostics::render(&d, &src, false)));
    let check = reports
        .iter()
        .find(|r| r.name == "prop_3_5")
        .expect("check prop_3_5");
    assert!(check.check);
    let hyb_feasible = !check.check_failed();
    assert_eq!(
        hyb_feasible,
        check.solve.is_some(),
        "{}",
        check.summary_line()
    );
    let net = Network::paper_example(Scenario::AllToAll);
    let lib = net
        .check_prop_3_5(1.0, &Vertices::Box, 1e-3)
        .expect("solves");
    println!(
        "{}\nNetwork::check_prop_3_5 (8 vertices): certified = {}, margin t* = {:?}",
        check.summary_line(),
        lib.certified(),
        lib.margin
    );
    assert_eq!(lib.certified(), hyb_feasible, "{}", check.summary_line());
}

#[test]
fn the_fig2_program_runs_and_writes_its_figures() {
    // What `cargo run --example intermittent_fig2 -- DIR 1 2` does, on a
    // short horizon: the three scenarios run and four SVGs are written.
    let src = SourceFile::read(shipped()).unwrap();
    let traces = hybsim_papers::experiments::intermittent::fig2(&src, 1, 2.0, 0.05).unwrap();
    assert_eq!(traces.len(), 3);
    for tr in &traces {
        let last = tr.enorm[tr.enorm.len() - 1];
        assert!(tr.jumps > 0 && last.0 == 2.0, "({}): {last:?}", tr.letter);
        assert!(tr.enorm.iter().all(|(_, e)| e.is_finite() && *e > 0.0));
    }
    let dir = tempfile::tempdir().unwrap();
    let figures = hybsim_papers::experiments::intermittent::fig2_figures(&traces, 1);
    let names: Vec<&str> = figures.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        names,
        ["fig2a.svg", "fig2b.svg", "fig2c.svg", "fig2_log.svg"]
    );
    for (name, fig) in figures {
        let path = dir.path().join(&name);
        fig.save(&path).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        assert!(svg.starts_with("<svg") && svg.len() > 1000, "{name}");
    }
}
