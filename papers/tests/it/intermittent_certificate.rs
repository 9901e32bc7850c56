//! Issue 8: Theorem 3.4 through Proposition 3.5 with `design::lmi`, for the
//! reconstructed gains of Example 3.8, over a σ grid; with positive controls
//! showing that the LMI machinery does find certificates where they exist.

use hybsim::design::lmi::Outcome;
use hybsim_papers::analysis::intermittent_estimation::{
    EdgeGains, Network, Prop35, Scenario, Vertices,
};
use nalgebra::DMatrix;

/// ε of the feasibility problem (`M ⪯ −ε I` with `P, R_ik ⪰ I`).
pub const EPS: f64 = 1e-3;

/// Largest eigenvalue of `M(ν)` over `points` at a returned design,
/// recomputed with `Network::m_of` (independent of the LMI assembly).
fn worst_eig(net: &Network, res: &Prop35, points: &[Vec<f64>]) -> f64 {
    let Outcome::Solved(d) = &res.feasibility else {
        panic!("no design")
    };
    let p = d.value("P").expect("P").clone();
    let r: Vec<DMatrix<f64>> = (1..=net.edges().len())
        .map(|e| d.value(&format!("R{e}")).expect("R").clone())
        .collect();
    points
        .iter()
        .map(|nu| {
            net.m_of(&p, &r, res.sigma, nu)
                .symmetric_eigenvalues()
                .max()
        })
        .fold(f64::NEG_INFINITY, f64::max)
}

#[test]
fn each_vertex_alone_is_feasible_for_large_sigma() {
    // Positive control: the single inequalities M(0) < 0 and M(T2) < 0 each
    // have solutions once σ exceeds 2 max Re eig(h − K_θ 𝒟) ≈ 4.25; only
    // their conjunction (one P, R for both) fails.
    for s in Scenario::ALL {
        let net = Network::paper_example(s);
        for nu in [vec![0.0; 3], vec![0.7; 3]] {
            if s != Scenario::AllToAll && nu[0] > 0.0 {
                continue; // one vertex per scenario keeps the test short
            }
            let points = Vertices::Points(vec![nu.clone()]);
            let res = net.check_prop_3_5(6.0, &points, EPS).expect("solves");
            assert!(
                res.certified(),
                "({}) ν = {nu:?}: {:?}",
                s.letter(),
                res.feasibility
            );
            let worst = worst_eig(&net, &res, std::slice::from_ref(&nu));
            assert!(
                worst < 0.0,
                "({}) ν = {nu:?}: λ_max(M) = {worst}",
                s.letter()
            );
            assert!(res.margin.is_some_and(|t| t < 0.0));
        }
    }
}

/// A single agent with an intermittently sampled oscillator (the setting of
/// Ferrante et al. [13], Remark 3.6): `A = [0 −1; 1 0]`, `H = [1 0]`,
/// `K = [−1; −0.5]`, `h = −2`, `T1 = 0.1`.
fn single_agent(t2: f64) -> Network {
    Network::new(
        DMatrix::from_row_slice(2, 2, &[0.0, -1.0, 1.0, 0.0]),
        vec![DMatrix::from_row_slice(1, 2, &[1.0, 0.0])],
        vec![EdgeGains {
            i: 0,
            k: 0,
            k_gain: DMatrix::from_column_slice(2, 1, &[-1.0, -0.5]),
            h: -2.0,
        }],
        0.0,
        vec![0.1],
        vec![t2],
    )
    .expect("valid network")
}

#[test]
fn single_agent_observer_is_certified() {
    // Positive control for the whole Prop. 3.5 problem (N = 1, where the two
    // vertices are the whole box): certified, verified independently.
    for (t2, sigma) in [(0.1, 1.0), (0.7, 1.0)] {
        let net = single_agent(t2);
        let res = net
            .check_prop_3_5(sigma, &Vertices::Paper, EPS)
            .expect("solves");
        assert!(res.certified(), "T2 = {t2}: {:?}", res.feasibility);
        let worst = worst_eig(&net, &res, &net.timer_points(&Vertices::Box));
        assert!(worst < 0.0, "T2 = {t2}: λ_max = {worst}");
        let t = res.margin.expect("optimum");
        println!("N = 1, T2 = {t2}, σ = {sigma}: t* = {t:.4e}, λ_max(M) = {worst:.3e}");
        assert!(t < 0.0);
    }
}
