use super::*;

fn spectral_abscissa(m: &DMatrix<f64>) -> f64 {
    m.complex_eigenvalues()
        .iter()
        .map(|z| z.re)
        .fold(f64::NEG_INFINITY, f64::max)
}

fn test_state(net: &Network) -> Vec<f64> {
    // A deterministic, non-symmetric state.
    (0..net.layout().dim())
        .map(|i| ((i as f64) * 0.77).sin() + 0.1 * i as f64 % 1.3)
        .collect()
}

fn chi(net: &Network, z: &[f64]) -> DVector<f64> {
    let (e, theta) = net.error_coordinates(z);
    let mut v = DVector::zeros(e.len() + theta.len());
    v.rows_mut(0, e.len()).copy_from(&e);
    v.rows_mut(e.len(), theta.len()).copy_from(&theta);
    v
}

#[test]
fn a_f_is_the_flow_of_the_error_coordinates() {
    // χ(exp(F t) z) = exp(A_f t) χ(z) for the original flow F (timers aside).
    for s in Scenario::ALL {
        let net = Network::paper_example(s);
        let (f, _) = net.flow_matrix();
        let z = test_state(&net);
        let t = 0.37;
        let zt = (f * t).exp() * DVector::from_column_slice(&z);
        let lhs = chi(&net, zt.as_slice());
        let rhs = (net.a_f() * t).exp() * chi(&net, &z);
        let err = (lhs - &rhs).amax();
        assert!(err <= 1e-12 * rhs.amax().max(1.0), "{s:?}: {err:e}");
    }
}

#[test]
fn spectra_of_a_theta_match_the_independent_computation() {
    // Reference values computed with numpy for the same reconstruction.
    let expected = [-0.20289, -0.20307, -0.21440];
    for (s, want) in Scenario::ALL.into_iter().zip(expected) {
        let got = spectral_abscissa(&Network::paper_example(s).a_theta());
        assert!((got - want).abs() <= 1e-4, "{s:?}: {got} vs {want}");
    }
}

#[test]
fn flow_in_error_coordinates_is_similar_to_the_eta_flow() {
    // With T = [[I, 0], [K_θ, −I]] mapping (e, η) to (e, θ), A_f T = T A_eη where
    // A_eη = [[I⊗A, 𝒟], [0, h]]: A_f has the eigenvalues ±i, 0 of I⊗A and the
    // h_ik, so the flow alone is only marginally stable.
    for s in Scenario::ALL {
        let net = Network::paper_example(s);
        let (kt, d, h) = (net.k_theta(), net.d_cal(), net.h_matrix());
        let (ne, nt) = (kt.ncols(), kt.nrows());
        let mut t = DMatrix::zeros(ne + nt, ne + nt);
        t.view_mut((0, 0), (ne, ne)).fill_with_identity();
        t.view_mut((ne, 0), (nt, ne)).copy_from(&kt);
        t.view_mut((ne, ne), (nt, nt))
            .copy_from(&(-DMatrix::<f64>::identity(nt, nt)));
        let mut aeta = DMatrix::zeros(ne + nt, ne + nt);
        aeta.view_mut((0, 0), (ne, ne))
            .copy_from(&DMatrix::<f64>::identity(net.agents(), net.agents()).kronecker(net.a()));
        aeta.view_mut((0, ne), (ne, nt)).copy_from(&d);
        aeta.view_mut((ne, ne), (nt, nt)).copy_from(&h);
        let err = (net.a_f() * &t - &t * aeta).amax();
        assert!(err <= 1e-12, "{s:?}: {err:e}");
    }
}

#[test]
fn transmit_keeps_e_and_zeroes_the_receivers_theta() {
    for s in Scenario::ALL {
        let net = Network::paper_example(s);
        let z = test_state(&net);
        let mut zp = vec![0.0; z.len()];
        for k in 0..net.agents() {
            net.transmit(k, &z, 0.5, &mut zp);
            let (e0, th0) = net.error_coordinates(&z);
            let (e1, th1) = net.error_coordinates(&zp);
            assert_eq!(e0, e1, "{s:?}: e changed at a jump of agent {k}");
            for (r, edge) in net.edges().iter().enumerate() {
                let n = net.n();
                let (a, b) = (th0.rows(r * n, n), th1.rows(r * n, n));
                if edge.k == k {
                    assert!(b.amax() <= 1e-14, "{s:?}: θ of {edge:?} not reset");
                } else {
                    assert_eq!(a, b, "{s:?}: θ of {edge:?} changed");
                }
            }
            assert_eq!(zp[net.layout().tau(k)], 0.5);
        }
    }
}

#[test]
fn m_of_nu_equals_the_block_form_of_22() {
    let net = Network::paper_example(Scenario::EdgesRemoved);
    let (at, d, kt, h) = (net.a_theta(), net.d_cal(), net.k_theta(), net.h_matrix());
    let n = net.n();
    let p = DMatrix::from_fn(9, 9, |i, j| {
        if i == j {
            2.0
        } else {
            0.1 / (1 + i + j) as f64
        }
    });
    let r: Vec<DMatrix<f64>> = (0..net.edges().len())
        .map(|q| DMatrix::identity(n, n) * (1.0 + q as f64))
        .collect();
    let (sigma, nu) = (0.8, [0.7, 0.0, 0.3]);
    let rn = net.r_of(&r, sigma, &nu);
    let b11 = &p * &at + at.transpose() * &p;
    let b12 = -(&p * &d) + (&kt * &at - &h * &kt).transpose() * &rn;
    let x = &h - &kt * &d;
    let b22 = &rn * &x + x.transpose() * &rn - &rn * sigma;
    let m = net.m_of(&p, &r, sigma, &nu);
    let (ne, nt) = (b11.nrows(), b22.nrows());
    assert!((m.view((0, 0), (ne, ne)) - b11).amax() <= 1e-12);
    assert!((m.view((0, ne), (ne, nt)) - &b12).amax() <= 1e-12);
    assert!((m.view((ne, 0), (nt, ne)) - b12.transpose()).amax() <= 1e-12);
    assert!((m.view((ne, ne), (nt, nt)) - b22).amax() <= 1e-12);
}

#[test]
fn scenarios_change_the_graph_and_outputs() {
    let b = Network::paper_example(Scenario::EdgesRemoved);
    assert_eq!(b.edges().len(), 7);
    assert!(!b.has_edge(1, 0) && !b.has_edge(2, 1) && b.has_edge(0, 1));
    let c = Network::paper_example(Scenario::Agent2Blind);
    assert_eq!(c.output(1).amax(), 0.0);
    assert_eq!(c.edges().len(), 9);
}

#[test]
fn bad_data_is_an_error() {
    let net = Network::paper_example(Scenario::AllToAll);
    let edges = net.edges().to_vec();
    let ok = |edges: Vec<EdgeGains>, t1: f64| {
        Network::new(
            net.a().clone(),
            (0..3).map(|k| net.output(k).clone()).collect(),
            edges,
            -0.3,
            vec![t1; 3],
            vec![0.7; 3],
        )
    };
    assert!(ok(edges.clone(), 0.1).is_ok());
    assert_eq!(
        ok(edges.clone(), 0.0).unwrap_err(),
        NetworkError::TimerBounds {
            agent: 1,
            t1: 0.0,
            t2: 0.7
        }
    );
    let no_loop: Vec<_> = edges
        .iter()
        .filter(|e| (e.i, e.k) != (1, 1))
        .cloned()
        .collect();
    assert_eq!(
        ok(no_loop, 0.1).unwrap_err(),
        NetworkError::MissingSelfLoop { agent: 2 }
    );
    let mut bad = edges.clone();
    bad[0].k_gain = DMatrix::zeros(2, 1);
    assert!(matches!(
        ok(bad, 0.1).unwrap_err(),
        NetworkError::Shape { .. }
    ));
    let mut nan = edges;
    nan[3].h = f64::NAN;
    assert!(matches!(
        ok(nan, 0.1).unwrap_err(),
        NetworkError::NotFinite { .. }
    ));
}
