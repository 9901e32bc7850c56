use nalgebra::{DMatrix, dmatrix};

use super::*;
use crate::design::control::{StateSpace, dlyap, hinf_norm, lyap, tests::sweep_peak};

/// Both interior-point methods: every solver-level test below runs on each.
const BACKENDS: [Backend; 2] = [Backend::Clarabel, Backend::Schur];

fn with_backend(mut p: Problem, b: Backend) -> Problem {
    p.settings_mut().backend = b;
    p
}

fn solved(p: &Problem) -> Design {
    match p.solve().unwrap() {
        Outcome::Solved(d) => d,
        other => panic!("not solved: {other:?}"),
    }
}

#[test]
fn svec_round_trip_and_inner_product() {
    let s = dmatrix![1.0, 2.0, 3.0; 2.0, 4.0, 5.0; 3.0, 5.0, 6.0];
    let t = dmatrix![0.5, -1.0, 0.0; -1.0, 2.0, 0.25; 0.0, 0.25, 1.0];
    let v = svec(&s);
    let r2 = std::f64::consts::SQRT_2;
    assert_eq!(v.len(), 6);
    // Upper triangle column by column, off-diagonals times √2.
    let expected = [1.0, 2.0 * r2, 4.0, 3.0 * r2, 5.0 * r2, 6.0];
    assert!(v.iter().zip(expected).all(|(a, b)| (a - b).abs() < 1e-15));
    assert!((smat(&v).unwrap() - &s).amax() < 1e-14);
    let dot: f64 = v.iter().zip(svec(&t)).map(|(a, b)| a * b).sum();
    assert!((dot - (&s * &t).trace()).abs() < 1e-12);
    assert!(smat(&[1.0, 2.0]).is_none());
}

/// max x s.t. [[1, x], [x, 1]] ⪰ 0 has x = 1; a wrong √2 convention would give √2 or 1/√2.
#[test]
fn svec_convention_agrees_with_clarabel() {
    let mut p = Problem::new();
    let x = p.add_variable("x", VarKind::Scalar).unwrap();
    let m = Expr::blocks(&[
        vec![Some(Expr::scalar(1.0)), Some(x.clone())],
        vec![Some(x.clone()), Some(Expr::scalar(1.0))],
    ])
    .unwrap();
    p.constrain("psd", &m, Relation::PosSemiDef).unwrap();
    p.maximize(&x).unwrap();
    let d = solved(&p);
    assert!((d.objective - 1.0).abs() < 1e-7, "{}", d.objective);
    // Off-diagonal entry of a symmetric variable: max S01 s.t. S ⪰ 0, S00 = 1, S11 = 4 → 2.
    let mut p = Problem::new();
    let s = p.add_variable("S", VarKind::Symmetric(2)).unwrap();
    p.constrain("psd", &s, Relation::PosSemiDef).unwrap();
    p.constrain_between(
        "S00",
        &s.entry(0, 0).unwrap(),
        &Expr::scalar(1.0),
        Relation::Zero,
    )
    .unwrap();
    p.constrain_between(
        "S11",
        &s.entry(1, 1).unwrap(),
        &Expr::scalar(4.0),
        Relation::Zero,
    )
    .unwrap();
    p.maximize(&s.entry(0, 1).unwrap()).unwrap();
    let d = solved(&p);
    assert!((d.objective - 2.0).abs() < 1e-6, "{}", d.objective);
}

fn lyapunov_lhs(p: &Expr, a: &DMatrix<f64>, q: &DMatrix<f64>) -> Expr {
    p.left_mul(&a.transpose())
        .unwrap()
        .add(&p.right_mul(a).unwrap())
        .unwrap()
        .add(&Expr::constant(q.clone()))
        .unwrap()
}

/// min tr(P) s.t. AᵀP + PA + Q ⪯ 0 is attained at the Lyapunov solution AᵀP + PA + Q = 0.
#[test]
fn lyapunov_lmi_matches_lyap() {
    for backend in BACKENDS {
        lyapunov_lmi_matches_lyap_with(backend);
    }
}

fn lyapunov_lmi_matches_lyap_with(backend: Backend) {
    let a = dmatrix![-1.0, 2.0, 0.0; -0.5, -1.5, 1.0; 0.2, 0.0, -2.0];
    let q = dmatrix![2.0, 0.5, 0.0; 0.5, 1.0, 0.0; 0.0, 0.0, 1.0];
    let mut prob = Problem::new();
    let p = prob.add_variable("P", VarKind::Symmetric(3)).unwrap();
    prob.constrain("lyap", &lyapunov_lhs(&p, &a, &q), Relation::NegSemiDef)
        .unwrap();
    prob.minimize(&p.trace().unwrap()).unwrap();
    let d = solved(&with_backend(prob, backend));
    assert_eq!(d.info.backend, backend);
    let exact = lyap(&a.transpose(), &q).unwrap();
    let got = d.value("P").unwrap();
    assert!(
        (got - &exact).amax() <= 1e-6 * exact.amax(),
        "{got} vs {exact}"
    );
    assert!(d.worst_margin >= -1e-6);
    assert!((d.objective - exact.trace()).abs() <= 1e-7 * exact.trace());
}

#[test]
fn infeasible_lmi_is_reported_infeasible() {
    for backend in BACKENDS {
        infeasible_and_unbounded_with(backend);
    }
}

fn infeasible_and_unbounded_with(backend: Backend) {
    // P ⪰ I and AᵀP + PA ⪯ 0 with an unstable A.
    let a = dmatrix![0.5, 1.0; 0.0, -1.0];
    let mut prob = Problem::new();
    let p = prob.add_variable("P", VarKind::Symmetric(2)).unwrap();
    prob.constrain_between("P >= I", &p, &Expr::identity(2), Relation::PosSemiDef)
        .unwrap();
    prob.constrain(
        "lyap",
        &lyapunov_lhs(&p, &a, &DMatrix::zeros(2, 2)),
        Relation::NegSemiDef,
    )
    .unwrap();
    let prob = with_backend(prob, backend);
    assert!(
        matches!(prob.solve().unwrap(), Outcome::Infeasible(_)),
        "{backend:?}: {:?}",
        prob.solve()
    );
    // Unbounded: maximize a free scalar.
    let mut prob = Problem::new();
    let t = prob.add_variable("t", VarKind::Scalar).unwrap();
    prob.constrain("t >= 0", &t, Relation::PosSemiDef).unwrap();
    prob.maximize(&t).unwrap();
    let prob = with_backend(prob, backend);
    assert!(
        matches!(prob.solve().unwrap(), Outcome::Unbounded(_)),
        "{backend:?}: {:?}",
        prob.solve()
    );
}

#[test]
fn malformed_constraints_are_errors() {
    let mut prob = Problem::new();
    let x = prob.add_variable("X", VarKind::Full(2, 2)).unwrap();
    assert!(matches!(
        prob.constrain("nonsym", &x, Relation::PosDef),
        Err(LmiError::NotSymmetric { .. })
    ));
    assert!(matches!(
        x.add(&Expr::identity(3)),
        Err(LmiError::Shape { op: "+", .. })
    ));
    assert!(matches!(x.mul(&x), Err(LmiError::Nonlinear)));
    assert!(matches!(
        prob.add_variable("X", VarKind::Scalar),
        Err(LmiError::DuplicateVariable { .. })
    ));
    assert!(matches!(
        prob.minimize(&x),
        Err(LmiError::ObjectiveNotScalar { .. })
    ));
}

/// Expression algebra against dense evaluation at a point.
#[test]
fn expression_algebra_evaluates_consistently() {
    let mut prob = Problem::new();
    let s = prob.add_variable("S", VarKind::Symmetric(2)).unwrap();
    let f = prob.add_variable("F", VarKind::Full(2, 3)).unwrap();
    let x: Vec<f64> = (0..prob.num_scalars())
        .map(|k| 0.3 * k as f64 - 1.0)
        .collect();
    let (sv, fv) = (s.eval(&x), f.eval(&x));
    assert_eq!(sv, sv.transpose());
    let l = dmatrix![1.0, 2.0; 0.0, -1.0; 3.0, 1.0];
    let k = dmatrix![1.0, -2.0; 0.5, 0.0];
    let e = s.left_mul(&l).unwrap().add(&f.transpose()).unwrap();
    assert!((e.eval(&x) - (&l * &sv + fv.transpose())).amax() < 1e-14);
    assert!((s.kron_left(&k).eval(&x) - k.kronecker(&sv)).amax() < 1e-14);
    assert!((s.kron_right(&k).eval(&x) - sv.kronecker(&k)).amax() < 1e-14);
    let b = Expr::blocks(&[
        vec![Some(s.clone()), Some(f.clone())],
        vec![None, Some(Expr::identity(3))],
    ])
    .unwrap();
    assert_eq!(b.shape(), (5, 5));
    assert!((b.block(0, 2, 2, 3).unwrap().eval(&x) - &fv).amax() == 0.0);
    assert!((b.trace().unwrap().eval(&x)[(0, 0)] - (sv.trace() + 3.0)).abs() < 1e-14);
    assert!(
        (f.inner(&l.transpose()).unwrap().eval(&x)[(0, 0)] - l.transpose().dot(&fv)).abs() < 1e-14
    );
}

/// Bounded-real lemma: ‖G‖∞ < γ iff ∃P ≻ 0 with
/// [[AᵀP + PA, PB, Cᵀ], [BᵀP, −γI, Dᵀ], [C, D, −γI]] ≺ 0; minimize γ.
fn brl_hinf(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    c: &DMatrix<f64>,
    d: &DMatrix<f64>,
    backend: Backend,
) -> f64 {
    let (n, m, p) = (a.nrows(), b.ncols(), c.nrows());
    let mut prob = Problem::new();
    let pv = prob.add_variable("P", VarKind::Symmetric(n)).unwrap();
    let g = prob.add_variable("gamma", VarKind::Scalar).unwrap();
    let tl = pv
        .left_mul(&a.transpose())
        .unwrap()
        .add(&pv.right_mul(a).unwrap())
        .unwrap();
    let pb = pv.right_mul(b).unwrap();
    let lmi = Expr::blocks(&[
        vec![
            Some(tl),
            Some(pb.clone()),
            Some(Expr::constant(c.transpose())),
        ],
        vec![
            Some(pb.transpose()),
            Some(g.kron_left(&DMatrix::identity(m, m)).neg()),
            Some(Expr::constant(d.transpose())),
        ],
        vec![
            Some(Expr::constant(c.clone())),
            Some(Expr::constant(d.clone())),
            Some(g.kron_left(&DMatrix::identity(p, p)).neg()),
        ],
    ])
    .unwrap();
    prob.constrain("brl", &lmi, Relation::NegSemiDef).unwrap();
    prob.constrain("P > 0", &pv, Relation::PosSemiDef).unwrap();
    prob.minimize(&g).unwrap();
    solved(&with_backend(prob, backend)).objective
}

#[test]
fn bounded_real_lemma_matches_sweep_and_hinf_norm() {
    let systems = [
        (
            dmatrix![0.0, 1.0; -4.0, -0.4],
            dmatrix![0.0; 4.0],
            dmatrix![1.0, 0.0],
            dmatrix![0.0],
        ),
        (dmatrix![-2.0], dmatrix![1.0], dmatrix![3.0], dmatrix![0.5]),
        (
            dmatrix![-0.2, 1.0, 0.0; -1.0, -0.3, 0.5; 0.0, 0.0, -1.0],
            dmatrix![1.0, 0.0; 0.0, 0.0; 0.3, 1.0],
            dmatrix![1.0, 0.0, 1.0; 0.0, 1.0, -1.0],
            dmatrix![0.0, 0.1; 0.2, 0.0],
        ),
    ];
    for (a, b, c, d) in systems {
        let g = StateSpace::continuous(a.clone(), b.clone(), c.clone(), d.clone()).unwrap();
        let sweep = sweep_peak(&g, 1e-3, 1e3);
        let exact = hinf_norm(&g).unwrap().value;
        for backend in BACKENDS {
            let lmi = brl_hinf(&a, &b, &c, &d, backend);
            assert!(
                (lmi - sweep).abs() <= 1e-4 * sweep,
                "{backend:?}: BRL {lmi} vs sweep {sweep}"
            );
            assert!(
                (lmi - exact).abs() <= 1e-4 * exact,
                "{backend:?}: BRL {lmi} vs hinf_norm {exact}"
            );
        }
    }
}

/// The discrete H2 LMIs [[P, P B], [Bᵀ P, X]] ⪰ 0 and AᵀPA − P + I ⪯ 0 (no objective yet);
/// returns the problem and the expressions of P and X.
fn discrete_h2_problem(a: &DMatrix<f64>, b: &DMatrix<f64>) -> (Problem, Expr, Expr) {
    let (n, k) = b.shape();
    let mut prob = Problem::new();
    let p = prob.add_variable("P", VarKind::Symmetric(n)).unwrap();
    let x = prob.add_variable("X", VarKind::Symmetric(k)).unwrap();
    let pb = p.right_mul(b).unwrap();
    let h2 = Expr::blocks(&[
        vec![Some(p.clone()), Some(pb.clone())],
        vec![Some(pb.transpose()), Some(x.clone())],
    ])
    .unwrap();
    prob.constrain("h2", &h2, Relation::PosSemiDef).unwrap();
    let lyap_lhs = p
        .left_mul(&a.transpose())
        .unwrap()
        .right_mul(a)
        .unwrap()
        .sub(&p)
        .unwrap()
        .add(&Expr::identity(n))
        .unwrap();
    prob.constrain("lyap", &lyap_lhs, Relation::NegSemiDef)
        .unwrap();
    (prob, p, x)
}

/// Badly scaled H2-type problem: P ≈ 1e3 (slow discrete dynamics) against noise of 1e-3.
/// min tr(X) s.t. [[P, PB], [BᵀP, X]] ⪰ 0, AᵀPA − P + I ⪯ 0 has tr(X) = tr(BᵀP*B) with
/// P* = dlyap(Aᵀ, I).
#[test]
fn badly_scaled_h2_problem_is_accurate() {
    for backend in BACKENDS {
        badly_scaled_h2_with(backend);
    }
}

fn badly_scaled_h2_with(backend: Backend) {
    let a = dmatrix![0.998, 0.005, 0.0; 0.0, 0.997, 0.002; 0.0, 0.0, 0.995];
    let b = dmatrix![0.03, 0.0; 0.0, 0.05; 0.02, 0.03]; // covariances B Bᵀ ≈ 1e-3
    let pstar = dlyap(&a.transpose(), &DMatrix::identity(3, 3)).unwrap();
    assert!(pstar.amax() > 1e2 && pstar.amax() < 1e4, "{}", pstar.amax());
    let (mut prob, _, x) = discrete_h2_problem(&a, &b);
    prob.minimize(&x.trace().unwrap()).unwrap();
    let d = solved(&with_backend(prob, backend));
    let exact = (b.transpose() * &pstar * &b).trace();
    assert!(
        (d.objective - exact).abs() <= 1e-5 * exact,
        "{backend:?}: {} vs {exact}",
        d.objective
    );
}

/// Appendix F of Muehlebach–Trimpe: P = I certifies Cor. V.2, i.e.
/// [[P, P A_cl(Π)], [A_cl(Π)ᵀ P, P]] ≻ 0 for all Π ⊆ {1, 2}, A_cl(Π) = (I − Σ_{m∈Π} L_m C_m)(A + BF).
#[test]
fn muehlebach_trimpe_appendix_f_identity_certifies_cor_v2() {
    let a = dmatrix![0.5, 0.0; 0.0, 2.0];
    let b = dmatrix![0.0, 1.0; 1.0, 0.0];
    let c = DMatrix::<f64>::identity(2, 2);
    let f = dmatrix![0.0, -2.0; 0.1, 0.0];
    let l = DMatrix::<f64>::identity(2, 2);
    let abf = &a + &b * &f;
    let mut prob = Problem::new();
    let p = prob.add_variable("P", VarKind::Symmetric(2)).unwrap();
    prob.constrain_between("P = I", &p, &Expr::identity(2), Relation::Zero)
        .unwrap();
    let mut expected_margin = f64::INFINITY;
    for subset in 0..4u32 {
        let mut lc = DMatrix::<f64>::zeros(2, 2);
        for m in 0..2 {
            if subset & (1 << m) != 0 {
                lc += l.column(m) * c.row(m);
            }
        }
        let acl = (DMatrix::<f64>::identity(2, 2) - lc) * &abf;
        // At P = I the block's smallest eigenvalue is 1 − σ_max(A_cl).
        expected_margin = expected_margin.min(1.0 - acl.singular_values().max());
        let pa = p.right_mul(&acl).unwrap();
        let lmi = Expr::blocks(&[
            vec![Some(p.clone()), Some(pa.clone())],
            vec![Some(pa.transpose()), Some(p.clone())],
        ])
        .unwrap();
        prob.constrain(
            &format!("Cor. V.2, Π = {subset:02b}"),
            &lmi,
            Relation::PosDef,
        )
        .unwrap();
    }
    let d = solved(&prob);
    assert!((d.value("P").unwrap() - DMatrix::<f64>::identity(2, 2)).amax() < 1e-8);
    let worst = d
        .checks
        .iter()
        .filter(|c| c.relation == Relation::PosDef)
        .map(|c| c.min_eig)
        .fold(f64::INFINITY, f64::min);
    assert!(
        (worst - expected_margin).abs() < 1e-7,
        "{worst} vs {expected_margin}"
    );
    assert!((expected_margin - 0.4).abs() < 1e-12); // A + BF = diag(0.6, 0)
}

/// A larger multi-block problem with an equality row, solved by both backends: discrete H2
/// design min tr X s.t. [[P, P B], [Bᵀ P, X]] ⪰ 0, AᵀPA − P + I ⪯ 0, P₀₁ = P₁₀ = 0 (a
/// structural constraint), plus a scalar bound tr P ≤ t. The two solutions must agree.
#[test]
fn backends_agree_on_a_multi_block_problem_with_equalities() {
    let n = 9;
    let k = 3;
    // A deterministic, stable, coupled A and a full B.
    let a = DMatrix::from_fn(n, n, |i, j| {
        if i == j {
            0.9 - 0.03 * i as f64
        } else if j == i + 1 {
            0.2
        } else if i == j + 2 {
            -0.05
        } else {
            0.0
        }
    });
    let b = DMatrix::from_fn(n, k, |i, j| ((i + 2 * j) % 5) as f64 * 0.1 - 0.15);
    let build = |backend: Backend| {
        let (mut prob, p, x) = discrete_h2_problem(&a, &b);
        let t = prob.add_variable("t", VarKind::Scalar).unwrap();
        prob.constrain("p01", &p.entry(0, 1).unwrap(), Relation::Zero)
            .unwrap();
        prob.constrain_between("trace", &t, &p.trace().unwrap(), Relation::PosSemiDef)
            .unwrap();
        prob.minimize(&x.trace().unwrap().add(&t.scale(1e-3)).unwrap())
            .unwrap();
        solved(&with_backend(prob, backend))
    };
    let c = build(Backend::Clarabel);
    let s = build(Backend::Schur);
    assert_eq!(s.info.backend, Backend::Schur);
    let rel = (c.objective - s.objective).abs() / c.objective.abs();
    assert!(rel < 1e-6, "objective {} vs {}", c.objective, s.objective);
    let (pc, ps) = (c.value("P").unwrap(), s.value("P").unwrap());
    assert!(ps[(0, 1)].abs() <= 1e-7 * ps.amax(), "P01 = {}", ps[(0, 1)]);
    assert!(
        (pc - ps).amax() <= 1e-4 * pc.amax(),
        "P differs by {}",
        (pc - ps).amax()
    );
}

/// `Backend::Auto` keeps clarabel for small problems and switches above AUTO_SCHUR_ROWS.
#[test]
fn auto_backend_switches_on_problem_size() {
    let solve = |n: usize| {
        let mut prob = Problem::new();
        let p = prob.add_variable("P", VarKind::Symmetric(n)).unwrap();
        let a = DMatrix::from_fn(n, n, |i, j| {
            if i == j {
                -1.0
            } else if j == i + 1 {
                0.5
            } else {
                0.0
            }
        });
        prob.constrain(
            "lyap",
            &lyapunov_lhs(&p, &a, &DMatrix::identity(n, n)),
            Relation::NegSemiDef,
        )
        .unwrap();
        prob.minimize(&p.trace().unwrap()).unwrap();
        let d = solved(&prob);
        let exact = lyap(&a.transpose(), &DMatrix::identity(n, n)).unwrap();
        assert!((d.value("P").unwrap() - &exact).amax() <= 1e-6 * exact.amax());
        d.info.backend
    };
    assert_eq!(solve(4), Backend::Clarabel);
    // 50·51/2 = 1275 svec rows > AUTO_SCHUR_ROWS.
    const { assert!(50 * 51 / 2 > AUTO_SCHUR_ROWS) };
    assert_eq!(solve(50), Backend::Schur);
}
