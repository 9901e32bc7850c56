use nalgebra::{DMatrix, dmatrix};

use super::*;

fn max_abs(m: &DMatrix<f64>) -> f64 {
    m.iter().fold(0.0f64, |a, v| a.max(v.abs()))
}

/// A 4-state, 2-input test system with an unstable mode and a complex pair.
fn plant4() -> (DMatrix<f64>, DMatrix<f64>) {
    let a = dmatrix![
        0.2, 1.0, 0.0, 0.3;
        -1.5, -0.1, 0.4, 0.0;
        0.0, 0.5, -0.7, 1.2;
        0.1, 0.0, -0.9, 0.05
    ];
    let b = dmatrix![1.0, 0.0; 0.0, 0.0; 0.3, 1.0; 0.0, 0.5];
    (a, b)
}

#[test]
fn expm_of_rotation_generator_and_nilpotent() {
    let t = 0.7f64;
    let e = expm(&dmatrix![0.0, t; -t, 0.0]).unwrap();
    let expected = dmatrix![t.cos(), t.sin(); -t.sin(), t.cos()];
    assert!(max_abs(&(e - expected)) < 1e-14);
    let e = expm(&dmatrix![0.0, 1.0, 0.0; 0.0, 0.0, 1.0; 0.0, 0.0, 0.0]).unwrap();
    assert!(max_abs(&(e - dmatrix![1.0, 1.0, 0.5; 0.0, 1.0, 1.0; 0.0, 0.0, 1.0])) < 1e-15);
}

#[test]
fn c2d_double_integrator_closed_form() {
    let ts = 0.02;
    let (ad, bd) = c2d(&dmatrix![0.0, 1.0; 0.0, 0.0], &dmatrix![0.0; 1.0], ts).unwrap();
    assert!(max_abs(&(ad - dmatrix![1.0, ts; 0.0, 1.0])) < 1e-15);
    assert!(max_abs(&(bd - dmatrix![ts * ts / 2.0; ts])) < 1e-16);
    // First-order lag ẋ = −a x + u: Ad = e^{−aT}, Bd = (1 − e^{−aT})/a.
    let (a, t) = (3.0f64, 0.25);
    let (ad, bd) = c2d(&dmatrix![-a], &dmatrix![1.0], t).unwrap();
    assert!((ad[(0, 0)] - (-a * t).exp()).abs() < 1e-15);
    assert!((bd[(0, 0)] - (1.0 - (-a * t).exp()) / a).abs() < 1e-15);
}

#[test]
fn bad_inputs_are_errors() {
    let a = dmatrix![1.0, 2.0; 3.0, 4.0];
    let wrong_b = c2d(&a, &dmatrix![1.0; 2.0; 3.0], 0.1).unwrap_err();
    assert!(matches!(
        wrong_b,
        ControlError::ShapeMismatch { name: "B", .. }
    ));
    // Only B's rows are fixed by A: the message asks for them alone.
    assert_eq!(wrong_b.to_string(), "B must have 2 rows, found 3×1");
    let wrong_q = lyap(&a, &dmatrix![1.0, 0.0, 0.0; 0.0, 1.0, 0.0]).unwrap_err();
    assert_eq!(wrong_q.to_string(), "Q must have 2 columns, found 2×3");
    let wrong_q = lyap(&a, &DMatrix::identity(3, 3)).unwrap_err();
    assert_eq!(wrong_q.to_string(), "Q must be 2×2, found 3×3");
    assert!(matches!(
        c2d(&a, &dmatrix![1.0; 2.0], -1.0),
        Err(ControlError::BadSamplingTime { .. })
    ));
    assert!(matches!(
        expm(&dmatrix![1.0, 2.0]),
        Err(ControlError::NotSquare { name: "A", .. })
    ));
    assert!(matches!(
        lyap(&a, &dmatrix![f64::NAN, 0.0; 0.0, 1.0]),
        Err(ControlError::NonFinite { name: "Q" })
    ));
    let i2 = DMatrix::<f64>::identity(2, 2);
    assert!(matches!(
        care(&a, &i2, &a, &i2),
        Err(ControlError::NotSymmetric { name: "Q", .. })
    ));
    assert!(matches!(
        dare(&a, &i2, &i2, &(-&i2)),
        Err(ControlError::NotPositiveDefinite { name: "R" })
    ));
}

#[test]
fn lyap_and_dlyap_residuals() {
    let (a, b) = plant4();
    let a = a - DMatrix::<f64>::identity(4, 4) * 2.0; // stable, complex pairs remain
    let q = &b * b.transpose() + DMatrix::<f64>::identity(4, 4) * 0.1;
    let x = lyap(&a, &q).unwrap();
    assert!(max_abs(&(&a * &x + &x * a.transpose() + &q)) < 1e-12);
    assert!(max_abs(&(&x - x.transpose())) < 1e-12);
    // Non-symmetric right-hand side also works.
    let q2 =
        dmatrix![1.0, 2.0, 0.0, 0.0; 0.0, 1.0, 0.5, 0.0; 0.0, 0.0, 3.0, 1.0; 1.0, 0.0, 0.0, 1.0];
    let x2 = lyap(&a, &q2).unwrap();
    assert!(max_abs(&(&a * &x2 + &x2 * a.transpose() + &q2)) < 1e-12);
    let ad = &a * 0.2;
    let xd = dlyap(&ad, &q2).unwrap();
    assert!(max_abs(&(&ad * &xd * ad.transpose() - &xd + &q2)) < 1e-12);
    // Singular: A = diag(1, −1) has λ1 + λ2 = 0.
    assert!(matches!(
        lyap(&dmatrix![1.0, 0.0; 0.0, -1.0], &DMatrix::identity(2, 2)),
        Err(ControlError::Singular { .. })
    ));
}

#[test]
fn care_and_lqr_scalar_closed_form() {
    for &(a, b, q, r) in &[
        (1.0f64, 1.0f64, 1.0f64, 1.0f64),
        (-2.0, 0.5, 3.0, 0.1),
        (0.3, 2.0, 1e-3, 5.0),
    ] {
        let p_exact = r * (a + (a * a + b * b * q / r).sqrt()) / (b * b);
        let sol = lqr(&dmatrix![a], &dmatrix![b], &dmatrix![q], &dmatrix![r]).unwrap();
        assert!(
            (sol.p[(0, 0)] - p_exact).abs() <= 1e-12 * p_exact,
            "{a} {b} {q} {r}"
        );
        assert!((sol.k[(0, 0)] - b * p_exact / r).abs() <= 1e-12 * sol.k[(0, 0)].abs());
        assert!(sol.poles[0].re < 0.0);
    }
}

#[test]
fn dare_and_dlqr_scalar_closed_form() {
    for &(a, b, q, r) in &[
        (1.2f64, 1.0f64, 1.0f64, 1.0f64),
        (0.5, 0.5, 3.0, 0.1),
        (-2.0, 2.0, 1e-3, 5.0),
    ] {
        let lin = (a * a - 1.0) * r + q * b * b;
        let p_exact = (lin + (lin * lin + 4.0 * b * b * q * r).sqrt()) / (2.0 * b * b);
        let sol = dlqr(&dmatrix![a], &dmatrix![b], &dmatrix![q], &dmatrix![r]).unwrap();
        assert!(
            (sol.p[(0, 0)] - p_exact).abs() <= 1e-12 * p_exact,
            "{a} {b} {q} {r}"
        );
        let k_exact = a * b * p_exact / (r + b * b * p_exact);
        assert!((sol.k[(0, 0)] - k_exact).abs() <= 1e-12 * k_exact.abs());
        assert!(sol.poles[0].norm() < 1.0);
    }
}

#[test]
fn care_matrix_residual_and_stability() {
    let (a, b) = plant4();
    let q =
        dmatrix![2.0, 0.5, 0.0, 0.0; 0.5, 1.0, 0.0, 0.0; 0.0, 0.0, 1.0, 0.0; 0.0, 0.0, 0.0, 0.5];
    let r = dmatrix![1.0, 0.2; 0.2, 0.5];
    let sol = lqr(&a, &b, &q, &r).unwrap();
    assert!(care_residual(&a, &b, &q, &r, &sol.p).unwrap() <= 1e-9);
    assert!(sol.poles.iter().all(|l| l.re < 0.0));
    // P ≻ 0 (Q ≻ 0), symmetric.
    assert!(sol.p.clone().cholesky().is_some());
    assert!(max_abs(&(&sol.p - sol.p.transpose())) == 0.0);
    // Optimal cost-to-go check: the closed loop satisfies the Lyapunov equation of the cost.
    let acl = &a - &b * &sol.k;
    let cost = lyap(&acl.transpose(), &(&q + sol.k.transpose() * &r * &sol.k)).unwrap();
    assert!(max_abs(&(cost - &sol.p)) <= 1e-9);
}

#[test]
fn dare_matrix_residual_and_value_iteration() {
    let (a, b) = plant4();
    let (ad, bd) = c2d(&a, &b, 0.1).unwrap();
    let q = DMatrix::<f64>::identity(4, 4);
    let r = dmatrix![1.0, 0.2; 0.2, 0.5];
    let sol = dlqr(&ad, &bd, &q, &r).unwrap();
    assert!(dare_residual(&ad, &bd, &q, &r, &sol.p).unwrap() <= 1e-9);
    assert!(sol.poles.iter().all(|l| l.norm() < 1.0));
    // The Riccati difference equation from P = Q converges to the stabilizing solution.
    let mut p = q.clone();
    for _ in 0..5000 {
        let k = (&r + bd.transpose() * &p * &bd)
            .lu()
            .solve(&(bd.transpose() * &p * &ad))
            .unwrap();
        p = ad.transpose() * &p * &ad - ad.transpose() * &p * &bd * k + &q;
    }
    assert!(max_abs(&(p - &sol.p)) <= 1e-8 * max_abs(&sol.p));
}

#[test]
fn riccati_not_stabilizable() {
    let i2 = DMatrix::<f64>::identity(2, 2);
    let b = dmatrix![1.0; 0.0];
    let r = dmatrix![1.0];
    assert!(matches!(
        care(&dmatrix![1.0, 0.0; 0.0, 2.0], &b, &i2, &r),
        Err(ControlError::NotStabilizable { .. })
    ));
    assert!(matches!(
        dare(&dmatrix![0.5, 0.0; 0.0, 2.0], &b, &i2, &r),
        Err(ControlError::NotStabilizable { .. })
    ));
}

/// 1/(s + a) and ω²/(s² + 2ζω s + ω²) have H2² = 1/(2a) and ω/(4ζ).
#[test]
fn h2_closed_forms_and_frequency_integral() {
    let a = 3.0;
    let g =
        StateSpace::continuous(dmatrix![-a], dmatrix![1.0], dmatrix![1.0], dmatrix![0.0]).unwrap();
    assert!((h2_norm(&g).unwrap() - (1.0 / (2.0 * a)).sqrt()).abs() < 1e-14);
    let (w, z) = (2.0, 0.3);
    let g = StateSpace::continuous(
        dmatrix![0.0, 1.0; -w * w, -2.0 * z * w],
        dmatrix![0.0; w * w],
        dmatrix![1.0, 0.0],
        dmatrix![0.0],
    )
    .unwrap();
    assert!((h2_norm(&g).unwrap() - (w / (4.0 * z)).sqrt()).abs() < 1e-13);
    // MIMO: against (1/π) ∫₀^∞ ‖G(jω)‖_F² dω, by the substitution ω = tan θ and Simpson's rule.
    let (a4, b4) = plant4();
    let a4 = a4 - DMatrix::<f64>::identity(4, 4) * 1.5;
    let c4 = dmatrix![1.0, 0.0, 1.0, 0.0; 0.0, 1.0, 0.0, -1.0; 0.5, 0.0, 0.0, 1.0];
    let g = StateSpace::continuous(a4, b4, c4, DMatrix::zeros(3, 2)).unwrap();
    let n = 20000;
    let h = std::f64::consts::FRAC_PI_2 / n as f64;
    let cb = (&g.c * &g.b).norm_squared(); // limit of the integrand at θ = π/2
    let f = |th: f64| {
        if th >= std::f64::consts::FRAC_PI_2 {
            return cb;
        }
        let om = th.tan();
        let fr = g.freq_response(om).unwrap();
        fr.iter().map(|c| c.norm_sqr()).sum::<f64>() * (1.0 + om * om)
    };
    let mut integral = f(0.0) + f(std::f64::consts::FRAC_PI_2);
    for i in 1..n {
        integral += f(i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
    }
    integral *= h / 3.0 / std::f64::consts::PI;
    let h2 = h2_norm(&g).unwrap();
    assert!(
        (h2 * h2 - integral).abs() <= 1e-9 * integral,
        "{} vs {}",
        h2 * h2,
        integral
    );
    // D ≠ 0 makes the continuous H2 norm infinite.
    let gd = StateSpace::continuous(dmatrix![-1.0], dmatrix![1.0], dmatrix![1.0], dmatrix![1.0])
        .unwrap();
    assert_eq!(h2_norm(&gd), Err(ControlError::NonzeroFeedthrough));
}

#[test]
fn h2_discrete_against_impulse_response_sum() {
    let (a, b) = plant4();
    let (ad, bd) = c2d(&(a - DMatrix::<f64>::identity(4, 4)), &b, 0.2).unwrap();
    let c = dmatrix![1.0, 0.0, 1.0, 0.0; 0.0, 1.0, 0.0, -1.0];
    let d = dmatrix![0.1, 0.0; 0.0, 0.2];
    let g = StateSpace::discrete(ad.clone(), bd.clone(), c.clone(), d.clone(), 0.2).unwrap();
    let mut sum = d.norm_squared();
    let mut ak_b = bd.clone();
    for _ in 0..2000 {
        sum += (&c * &ak_b).norm_squared();
        ak_b = &ad * ak_b;
    }
    let h2 = h2_norm(&g).unwrap();
    assert!((h2 * h2 - sum).abs() <= 1e-12 * sum);
}

/// Maximum of σ_max over a dense log grid, refined by golden-section search around the best point.
pub(crate) fn sweep_peak(g: &StateSpace, lo: f64, hi: f64) -> f64 {
    let n = 20000;
    let grid: Vec<f64> = (0..=n)
        .map(|i| lo * (hi / lo).powf(i as f64 / n as f64))
        .collect();
    let vals: Vec<f64> = grid.iter().map(|&w| g.sigma_max(w).unwrap()).collect();
    let (imax, _) =
        vals.iter().enumerate().fold(
            (0, f64::MIN),
            |(bi, bv), (i, &v)| if v > bv { (i, v) } else { (bi, bv) },
        );
    let (mut a, mut b) = (grid[imax.saturating_sub(1)], grid[(imax + 1).min(n)]);
    let phi = (5f64.sqrt() - 1.0) / 2.0;
    for _ in 0..100 {
        let x1 = b - phi * (b - a);
        let x2 = a + phi * (b - a);
        if g.sigma_max(x1).unwrap() > g.sigma_max(x2).unwrap() {
            b = x2;
        } else {
            a = x1;
        }
    }
    vals.iter()
        .fold(g.sigma_max(0.5 * (a + b)).unwrap(), |m, &v| m.max(v))
        .max(g.sigma_max(0.0).unwrap())
}

#[test]
fn hinf_second_order_resonance_closed_form() {
    for &z in &[0.05, 0.2, 0.5] {
        let w = 3.0;
        let g = StateSpace::continuous(
            dmatrix![0.0, 1.0; -w * w, -2.0 * z * w],
            dmatrix![0.0; w * w],
            dmatrix![1.0, 0.0],
            dmatrix![0.0],
        )
        .unwrap();
        let h = hinf_norm(&g).unwrap();
        let exact = 1.0 / (2.0 * z * (1.0 - z * z).sqrt());
        assert!(
            (h.value - exact).abs() <= 1e-9 * exact,
            "ζ = {z}: {} vs {exact}",
            h.value
        );
        let w_peak = w * (1.0 - 2.0 * z * z).sqrt();
        assert!((h.peak_frequency - w_peak).abs() <= 1e-3 * w_peak);
    }
}

#[test]
fn hinf_mimo_continuous_and_discrete_against_sweep() {
    let (a, b) = plant4();
    let a = a - DMatrix::<f64>::identity(4, 4) * 0.4;
    let c = dmatrix![1.0, 0.0, 1.0, 0.0; 0.0, 1.0, 0.0, -1.0; 0.5, 0.0, 0.0, 1.0];
    let d = dmatrix![0.0, 0.1; 0.2, 0.0; 0.0, 0.0];
    let g = StateSpace::continuous(a.clone(), b.clone(), c.clone(), d.clone()).unwrap();
    let h = hinf_norm(&g).unwrap();
    let sweep = sweep_peak(&g, 1e-3, 1e3);
    assert!(
        (h.value - sweep).abs() <= 1e-6 * sweep,
        "{} vs {sweep}",
        h.value
    );
    assert!((g.sigma_max(h.peak_frequency).unwrap() - h.value).abs() <= 1e-12 * h.value);
    let ts = 0.3;
    let (ad, bd) = c2d(&a, &b, ts).unwrap();
    let gd = StateSpace::discrete(ad, bd, c, d, ts).unwrap();
    let hd = hinf_norm(&gd).unwrap();
    let sweep = sweep_peak(&gd, 1e-4, std::f64::consts::PI / ts);
    assert!(
        (hd.value - sweep).abs() <= 1e-6 * sweep,
        "{} vs {sweep}",
        hd.value
    );
    assert!((gd.sigma_max(hd.peak_frequency).unwrap() - hd.value).abs() <= 1e-9 * hd.value);
}

#[test]
fn norms_of_unstable_systems_are_errors() {
    let g =
        StateSpace::continuous(dmatrix![0.5], dmatrix![1.0], dmatrix![1.0], dmatrix![0.0]).unwrap();
    assert!(matches!(hinf_norm(&g), Err(ControlError::Unstable { .. })));
    assert!(matches!(h2_norm(&g), Err(ControlError::Unstable { .. })));
}

#[test]
fn are_with_indefinite_quadratic_term() {
    use super::{are, are_residual, care};
    // Scalar closed form: 2 a x − g x² + q = 0, stabilizing root x = (a + √(a² + g q))/g,
    // a − g x = −√(a² + g q) < 0; here g < 0 (more disturbance than control).
    let (a, g, q) = (-1.0, -0.5, 1.0);
    let x = are(&dmatrix![a], &dmatrix![g], &dmatrix![q]).unwrap()[(0, 0)];
    let want = (a + (a * a + g * q).sqrt()) / g;
    assert!((x - want).abs() < 1e-12, "{x} vs {want}");
    // With G = B R⁻¹ Bᵀ it is care.
    let (a, b) = plant4();
    let q = DMatrix::<f64>::identity(4, 4);
    let r = dmatrix![2.0, 0.0; 0.0, 1.0];
    let g = &b * r.clone().try_inverse().unwrap() * b.transpose();
    let x = are(&a, &g, &q).unwrap();
    assert!((&x - care(&a, &b, &q, &r).unwrap()).norm() < 1e-9 * x.norm());
    // An H∞-type G = B Bᵀ/λ² − Bw Bwᵀ/μ²: residual, stabilizing.
    let bw = dmatrix![0.0; 0.5; 0.0; 0.2];
    let g = &b * b.transpose() / 0.25 - &bw * bw.transpose() / 1.44;
    let x = are(&a, &g, &q).unwrap();
    assert!(are_residual(&a, &g, &q, &x).unwrap() < 1e-9 * (1.0 + x.norm()));
    let acl = &a - &g * &x;
    assert!(acl.complex_eigenvalues().iter().all(|l| l.re < 0.0));
    // No stabilizing solution: an unstable mode that G cannot reach.
    let e = are(
        &dmatrix![1.0, 0.0; 0.0, -1.0],
        &dmatrix![0.0, 0.0; 0.0, 1.0],
        &DMatrix::identity(2, 2),
    );
    assert!(
        matches!(e, Err(ControlError::NotStabilizable { .. })),
        "{e:?}"
    );
}

#[test]
fn detectability_from_the_unobservable_modes() {
    use super::{detectable, unobservable_modes};
    // Two integrators seen only through their difference: the common mode (0) is unobservable.
    let a = DMatrix::<f64>::zeros(2, 2);
    let c = dmatrix![1.0, -1.0];
    let modes = unobservable_modes(&a, &c).unwrap();
    assert_eq!(modes.len(), 1);
    assert!(modes[0].norm() < 1e-12);
    assert!(!detectable(&a, &c).unwrap());
    // Different dynamics make the common mode observable; a stable unobservable mode is fine.
    let a = dmatrix![0.0, 0.0; 0.0, -1.0];
    assert!(detectable(&a, &c).unwrap());
    let a = dmatrix![0.0, 0.0, 0.0; 0.0, -1.0, 0.0; 0.0, 0.0, -2.0];
    let c = dmatrix![1.0, 0.0, 0.0];
    assert!(detectable(&a, &c).unwrap());
    assert_eq!(unobservable_modes(&a, &c).unwrap().len(), 2);
    assert!(!detectable(&a.scale(-1.0), &c).unwrap());
    // A double integrator and a (0.1, 0) system seen through the difference of
    // positions: the shared eigenvalue 0 is unobservable (computed as ≈ −1e-16).
    let a =
        dmatrix![0.0, 1.0, 0.0, 0.0; 0.0, 0.0, 0.0, 0.0; 0.0, 0.0, 0.1, 1.0; 0.0, 0.0, 0.0, 0.0];
    let c = dmatrix![-1.0, 0.0, 1.0, 0.0];
    assert!(!detectable(&a, &c).unwrap());
}
