//! Muehlebach & Trimpe, distributed event-based estimation (issue 7):
//! App. F two-agent example and the vehicle platoon of Sec. VII, through the
//! real pipeline (parse → check → compile → simulate). Reference numbers and
//! every modelling choice: REPRODUCTION.md, section Muehlebach–Trimpe.

use hybsim::arc::HybridArc;
use hybsim::design::control::{StateSpace, dlqr, h2_norm, hinf_norm};
use hybsim::engine::HybridSystem;
use hybsim::lang::CompiledModel;
use hybsim_papers::experiments::platoon::{Platoon, Window};
use nalgebra::DMatrix;

use crate::util::{ModelSweep, load, model_sweep, run};

/// Looks up flat state names (`x[2]`, `xh[1][3]`) in the model's layout.
fn index(m: &CompiledModel) -> impl Fn(&str) -> usize {
    let names = m.state_layout().flat_names(m.state_dim());
    move |name: &str| {
        names
            .iter()
            .position(|n| n == name)
            .unwrap_or_else(|| panic!("no state {name} in {names:?}"))
    }
}

/// Post-jump states, one per sampling instant k = 1, 2, ….
fn steps(arc: &HybridArc) -> Vec<Vec<f64>> {
    arc.jumps().iter().map(|j| j.post.clone()).collect()
}

/// One row of the appendix's step tables: u(k−1), x(k), x̂_i(k|k−1), who sent, x̂_i(k).
struct Step {
    u: [f64; 2],
    x: [f64; 2],
    pred1: [f64; 2],
    pred2: [f64; 2],
    tx: [f64; 2],
    xh1: [f64; 2],
    xh2: [f64; 2],
}

fn check_step(m: &CompiledModel, s: &[f64], k: usize, want: &Step) {
    let ix = index(m);
    let get = |name: &str| [s[ix(&format!("{name}[1]"))], s[ix(&format!("{name}[2]"))]];
    for (name, w) in [
        ("u", want.u),
        ("x", want.x),
        ("pred1", want.pred1),
        ("pred2", want.pred2),
        ("tx", want.tx),
        ("xh1", want.xh1),
        ("xh2", want.xh2),
    ] {
        // All quantities are small integers or 0.6·0: exact in binary floating point.
        assert_eq!(get(name), w, "step {k}: {name}");
    }
}

#[test]
fn appendix_f_inputs_communicated_is_unstable() {
    let m = load("appendix_f.hyb", &["share_inputs=1"]);
    let arc = run(&m);
    let s = steps(&arc);
    assert_eq!(s.len(), 30, "30 sampling instants in T = 30.5");
    // Step 1 and step 2 as printed in App. F.
    let step1 = Step {
        u: [-2.0, 0.0],
        x: [0.0, 2.0],
        pred1: [0.0, 0.0],
        pred2: [0.0, 2.0],
        tx: [0.0, 0.0],
        xh1: [0.0, 0.0],
        xh2: [0.0, 2.0],
    };
    check_step(&m, &s[0], 1, &step1);
    let step2 = Step {
        u: [0.0, 0.0],
        x: [0.0, 4.0],
        pred1: [0.0, 0.0],
        pred2: [0.0, 4.0],
        tx: [0.0, 0.0],
        xh1: [0.0, 0.0],
        xh2: [0.0, 4.0],
    };
    check_step(&m, &s[1], 2, &step2);
    // (62), corrected: x(n) = y(n) = x̂₂(n) = (0, 2ⁿ), u(n) = x̂₁(n) = 0; nobody ever sends.
    for (i, st) in s.iter().enumerate() {
        let k = i + 1;
        let p = 2f64.powi(k as i32);
        let want = Step {
            u: if k == 1 { [-2.0, 0.0] } else { [0.0, 0.0] },
            x: [0.0, p],
            pred1: [0.0, 0.0],
            pred2: [0.0, p],
            tx: [0.0, 0.0],
            xh1: [0.0, 0.0],
            xh2: [0.0, p],
        };
        check_step(&m, st, k, &want);
    }
}

#[test]
fn appendix_f_inputs_reconstructed_is_stable() {
    let m = load("appendix_f.hyb", &["share_inputs=0"]);
    let arc = run(&m);
    let s = steps(&arc);
    assert_eq!(s.len(), 30);
    // Step 1: agent 2 sends (|2 − 0| ≥ Δ₂ = 1), both estimates become (0, 2).
    let step1 = Step {
        u: [-2.0, 0.0],
        x: [0.0, 2.0],
        pred1: [0.0, 0.0],
        pred2: [0.0, 0.0],
        tx: [0.0, 1.0],
        xh1: [0.0, 2.0],
        xh2: [0.0, 2.0],
    };
    check_step(&m, &s[0], 1, &step1);
    // Step 2: u(1) = (F₁x̂₁(1), F₂x̂₂(1)) = (−4, 0) (the paper prints (0, −4), inconsistent with
    // its own x(2) = (0, 0)); from here on everything is zero and nobody sends.
    let zero = [0.0, 0.0];
    let step2 = Step {
        u: [-4.0, 0.0],
        x: zero,
        pred1: zero,
        pred2: zero,
        tx: zero,
        xh1: zero,
        xh2: zero,
    };
    check_step(&m, &s[1], 2, &step2);
    for (i, st) in s.iter().enumerate().skip(2) {
        let want = Step {
            u: zero,
            x: zero,
            pred1: zero,
            pred2: zero,
            tx: zero,
            xh1: zero,
            xh2: zero,
        };
        check_step(&m, st, i + 1, &want);
    }
}

/// A parameter of the compiled model (after overrides and `design` blocks).
fn param_matrix(m: &CompiledModel, name: &str) -> DMatrix<f64> {
    m.parameter(name)
        .unwrap_or_else(|| panic!("the model has no parameter `{name}`"))
}

/// The paper's printed thresholds (Sec. VII, M = 3, Cor. V.2, J_max = 0.38).
const PAPER_DELTA: [f64; 3] = [0.107, 0.092, 0.106];
const J_MAX: f64 = 0.38;

/// c* and the H∞ norm of s₁ → e from the model's own matrices, computed independently of the
/// synthesis: c* = H₂ norm of e(k) = Â e(k−1) + B̂₂ s₂(k) (Lyapunov equation), Â = (I − LC)A,
/// B̂₂ = [−L W^½, (I − LC) B Σ_u^½]; ‖(zI − Â)⁻¹ L Δ‖∞ by the level-set iteration.
fn platoon_norms(m: &CompiledModel, delta: &[f64]) -> (f64, f64) {
    let (a, b, c, l) = (
        param_matrix(m, "A"),
        param_matrix(m, "B"),
        param_matrix(m, "C"),
        param_matrix(m, "L"),
    );
    let aw = param_matrix(m, "a_w")[(0, 0)];
    let au = param_matrix(m, "a_u")[(0, 0)];
    let (n, p) = (a.nrows(), c.nrows());
    let ilc = DMatrix::identity(n, n) - &l * &c;
    let ahat = &ilc * &a;
    // Uniform on [−a, a]: variance a²/3.
    let wh = &l * (-aw / 3f64.sqrt());
    let vh = &ilc * &b * (au / 3f64.sqrt());
    let mut b2 = DMatrix::zeros(n, p + b.ncols());
    b2.view_mut((0, 0), (n, p)).copy_from(&wh);
    b2.view_mut((0, p), (n, b.ncols())).copy_from(&vh);
    let ts = param_matrix(m, "Ts")[(0, 0)];
    let eye = DMatrix::identity(n, n);
    let sys2 = StateSpace::discrete(
        ahat.clone(),
        b2,
        eye.clone(),
        DMatrix::zeros(n, p + b.ncols()),
        ts,
    )
    .unwrap();
    let cstar = h2_norm(&sys2).unwrap();
    let ld = &l * DMatrix::from_diagonal(&nalgebra::DVector::from_column_slice(delta));
    let sys1 = StateSpace::discrete(ahat, ld, eye, DMatrix::zeros(n, p), ts).unwrap();
    (cstar, hinf_norm(&sys1).unwrap().value)
}

#[test]
fn platoon_thresholds_meet_step_two_bound_and_differ_from_paper_by_a_uniform_factor() {
    let m = load("platoon.hyb", &[]);
    let delta: Vec<f64> = param_matrix(&m, "Delta").iter().copied().collect();
    let (cstar, hinf) = platoon_norms(&m, &delta);
    let n_agents: f64 = 3.0;
    let bound = (J_MAX - cstar) / n_agents.sqrt();
    println!(
        "c* = {cstar:.7}, J_max/c* = {:.2}, H∞ = {hinf:.7}, √γ = {bound:.7}",
        J_MAX / cstar
    );
    // Step 1 reference value (scipy/cvxpy+Clarabel synthesis, REPRODUCTION.md): c* = 0.0102048.
    assert!((cstar - 0.0102048).abs() < 1e-6, "c* = {cstar}");
    // Paper: "J_max roughly 35 times" c*.
    assert!(
        (30.0..40.0).contains(&(J_MAX / cstar)),
        "J_max / c* = {}",
        J_MAX / cstar
    );
    // Step 2 maximizes tr Δ, so its H∞ constraint is active: ‖G₁‖∞ = √γ.
    assert!((hinf / bound - 1.0).abs() < 1e-5, "H∞ {hinf} vs √γ {bound}");
    // The paper's Δ: feasible, and a uniform factor below ours (printed to 3 digits: ±0.5 %).
    let (_, hinf_paper) = platoon_norms(&m, &PAPER_DELTA);
    assert!(hinf_paper < bound);
    let ratios: Vec<f64> = PAPER_DELTA.iter().zip(&delta).map(|(p, d)| p / d).collect();
    let mean = ratios.iter().sum::<f64>() / 3.0;
    for r in &ratios {
        assert!((r / mean - 1.0).abs() < 0.005, "ratios {ratios:?}");
    }
    assert!((mean - 0.869).abs() < 0.005, "uniform factor {mean}");
}

#[test]
fn platoon_feedback_is_dlqr_of_the_zoh_model() {
    let m = load("platoon.hyb", &[]);
    let (a, b, f) = (
        param_matrix(&m, "A"),
        param_matrix(&m, "B"),
        param_matrix(&m, "F"),
    );
    let (n, k) = (a.nrows(), b.ncols());
    // ZOH of (41): A = I + Ac·Ts exactly (Ac nilpotent of index 2).
    let ac = param_matrix(&m, "Ac");
    let ts = param_matrix(&m, "Ts")[(0, 0)];
    assert!((&a - (DMatrix::identity(n, n) + &ac * ts)).amax() < 1e-15);
    let lqr = dlqr(
        &a,
        &b,
        &DMatrix::identity(n, n),
        &(DMatrix::identity(k, k) * 100.0),
    )
    .unwrap();
    let diff = (&f + &lqr.k).amax();
    assert!(diff < 1e-7, "F + K = {diff}");
}

/// Closed-loop statistics of the M = 3 platoon at J_max = 0.38, as
/// `hybsim sweep models/platoon.hyb --grid Jmax=0.38 --runs 20 [--set …]`
/// gives them: 20 noise realizations × 1000 s, the model's metrics over
/// t ≥ 100 s (`rate_ss[i]`, `dmax`, `epow[i]`).
fn platoon_sweep(sets: &[&str]) -> ModelSweep {
    let s = model_sweep("platoon.hyb", sets, &["Jmax=0.38"], Some(20));
    assert_eq!(s.incomplete(), 0, "every run reaches T");
    s
}

/// Per-vehicle means and standard deviations (n − 1) of the steady-state
/// rates over the runs of grid point 0.
fn rates(s: &ModelSweep) -> (Vec<f64>, Vec<f64>) {
    let m = s
        .metrics
        .iter()
        .filter(|n| n.starts_with("rate_ss["))
        .count();
    (1..=m)
        .map(|i| {
            let st = s.stats(0, &format!("rate_ss[{i}]"));
            (st.mean, st.std)
        })
        .unzip()
}

/// The paper's Δ as a `--set` override of the design result.
const PAPER_DELTA_SET: &str = "Delta=[0.107; 0.092; 0.106]";

fn designed_stats() -> &'static ModelSweep {
    static S: std::sync::OnceLock<ModelSweep> = std::sync::OnceLock::new();
    S.get_or_init(|| platoon_sweep(&[]))
}

fn paper_stats() -> &'static ModelSweep {
    static S: std::sync::OnceLock<ModelSweep> = std::sync::OnceLock::new();
    S.get_or_init(|| platoon_sweep(&[PAPER_DELTA_SET]))
}

#[test]
fn platoon_closed_loop_with_designed_thresholds() {
    let s = designed_stats();
    let (mean, std) = rates(s);
    let max = s.stats(0, "dmax").max;
    println!("designed Δ: rates {mean:?} ± {std:?}; max |d| {max:.4}");
    // Paper: distance errors within ±0.1 m in steady state.
    assert!(max < 0.15, "max |d| = {max}");
    // Our thresholds (J_max = 0.38 as printed) lie above the noise amplitude 0.1 for all three
    // vehicles, so all rates stay low (paper: 8 % for vehicle 2, see the next test).
    assert!(mean[0] < 0.01, "vehicle 1 rate {}", mean[0]);
    for (i, r) in mean.iter().enumerate().skip(1) {
        assert!((0.01..0.035).contains(r), "vehicle {} rate {r}", i + 1);
    }
}

#[test]
fn platoon_closed_loop_with_paper_thresholds_matches_fig5() {
    let s = paper_stats();
    let (mean, std) = rates(s);
    let max = s.stats(0, "dmax").max;
    println!("paper Δ: rates {mean:?} ± {std:?}; max |d| {max:.4}");
    assert!(max < 0.1, "max |d| {max}");
    // Paper: vehicle 2 "around 8 %", vehicles 1 and 3 "below 4 %".
    assert!(
        (0.07..0.09).contains(&mean[1]),
        "vehicle 2 rate {}",
        mean[1]
    );
    assert!(mean[0] < 0.04 && mean[2] < 0.04, "rates {mean:?}");
    assert!(std.iter().all(|s| *s < 0.005), "spread over runs {std:?}");
}

/// Independent cross-check of the model's `design` blocks: step 1 of Sec. VI-B with Cor. V.2 written
/// directly against the Rust API `design::lmi`: minimize tr X over P, U = P L, X.
/// Covariances scaled by 1e4 (L is invariant; c* scales with 100) — unscaled, the interior-point
/// solution is off by several percent (REPRODUCTION.md). Returns (L, c*).
fn platoon_step1(m: &CompiledModel) -> (DMatrix<f64>, f64) {
    use hybsim::design::lmi::{Expr, Outcome, Problem, Relation, VarKind};
    let (a, b, c, f) = (
        param_matrix(m, "A"),
        param_matrix(m, "B"),
        param_matrix(m, "C"),
        param_matrix(m, "F"),
    );
    let (aw, au) = (
        param_matrix(m, "a_w")[(0, 0)],
        param_matrix(m, "a_u")[(0, 0)],
    );
    let kappa: f64 = 1e4;
    let (n, p, k) = (a.nrows(), c.nrows(), b.ncols());
    let wh = DMatrix::identity(p, p) * (aw / 3f64.sqrt() * kappa.sqrt());
    let vh = &b * (au / 3f64.sqrt() * kappa.sqrt());
    let af = &a + &b * &f;
    let mut prob = Problem::new();
    let pv = prob.add_variable("P", VarKind::Symmetric(n)).unwrap();
    let u = prob.add_variable("U", VarKind::Full(n, p)).unwrap();
    let x = prob.add_variable("X", VarKind::Symmetric(p + k)).unwrap();
    // P Â = (P − U C) A, P B̂₂ = [−U W^½, (P − U C) V^½].
    let p_uc = pv.sub(&u.right_mul(&c).unwrap()).unwrap();
    let pa = p_uc.right_mul(&a).unwrap();
    let pb2 = Expr::blocks(&[vec![
        Some(u.right_mul(&wh).unwrap().neg()),
        Some(p_uc.right_mul(&vh).unwrap()),
    ]])
    .unwrap();
    let eye = Expr::identity(n);
    let perf = Expr::blocks(&[
        vec![Some(eye.clone()), None, Some(eye.clone())],
        vec![None, Some(pv.clone()), Some(pa.clone())],
        vec![Some(eye.clone()), Some(pa.transpose()), Some(pv.clone())],
    ])
    .unwrap();
    prob.constrain("H2 gramian", &perf, Relation::PosSemiDef)
        .unwrap();
    let h2 = Expr::blocks(&[
        vec![Some(pv.clone()), Some(pb2.clone())],
        vec![Some(pb2.transpose()), Some(x.clone())],
    ])
    .unwrap();
    prob.constrain("H2 bound", &h2, Relation::PosSemiDef)
        .unwrap();
    // Cor. V.2: one LMI per subset of agents.
    for subset in 0..(1u32 << p) {
        let mut pacl = pv.clone();
        for mm in 0..p {
            if subset & (1 << mm) != 0 {
                let um = u.block(0, mm, n, 1).unwrap();
                pacl = pacl
                    .sub(&um.right_mul(&c.rows(mm, 1).into_owned()).unwrap())
                    .unwrap();
            }
        }
        let pacl = pacl.right_mul(&af).unwrap();
        let lmi = Expr::blocks(&[
            vec![Some(pv.clone()), Some(pacl.clone())],
            vec![Some(pacl.transpose()), Some(pv.clone())],
        ])
        .unwrap();
        prob.constrain(
            &format!("Cor V.2 subset {subset}"),
            &lmi,
            Relation::PosSemiDef,
        )
        .unwrap();
    }
    prob.minimize(&x.trace().unwrap()).unwrap();
    let Outcome::Solved(d) = prob.solve().unwrap() else {
        panic!("step 1 not solved")
    };
    let (pm, um) = (d.value("P").unwrap(), d.value("U").unwrap());
    let l = pm.clone().lu().solve(um).unwrap();
    (l, (d.objective / kappa).sqrt())
}

/// Step 2 (40) through `design::lmi`: maximize tr Δ subject to the bounded-real LMI, solved in
/// balanced coordinates of (Â, L, I) with γ normalized to 1 (Δ scales with √γ).
fn platoon_step2(m: &CompiledModel, l: &DMatrix<f64>, cstar: f64, jmax: f64) -> Vec<f64> {
    use hybsim::design::control::dlyap;
    use hybsim::design::lmi::{Expr, Outcome, Problem, Relation, VarKind};
    let (a, c) = (param_matrix(m, "A"), param_matrix(m, "C"));
    let (n, p) = (a.nrows(), c.nrows());
    let ahat = (DMatrix::identity(n, n) - l * &c) * &a;
    // Balanced realization: Wc = R Rᵀ, Rᵀ Wo R = U Σ² Uᵀ, T = R U Σ^{-1/2}.
    let wc = dlyap(&ahat, &(l * l.transpose())).unwrap();
    let wo = dlyap(&ahat.transpose(), &DMatrix::identity(n, n)).unwrap();
    let r = wc.cholesky().unwrap().l();
    let eig = (r.transpose() * &wo * &r).symmetric_eigen();
    let t =
        &r * &eig.eigenvectors * DMatrix::from_diagonal(&eig.eigenvalues.map(|s| s.powf(-0.25)));
    let ti = t.clone().try_inverse().unwrap();
    let (ab, lb) = (&ti * &ahat * &t, &ti * l);
    let mut prob = Problem::new();
    let q = prob.add_variable("Q", VarKind::Symmetric(n)).unwrap();
    let dv = prob.add_variable("Delta", VarKind::Full(p, 1)).unwrap();
    // L Δ with Δ = diag(δ): column j is L_j δ_j.
    let mut ld: Option<Expr> = None;
    for j in 0..p {
        let col = dv
            .entry(j, 0)
            .unwrap()
            .left_mul(&lb.columns(j, 1).into_owned())
            .unwrap();
        let mut e = DMatrix::zeros(1, p);
        e[(0, j)] = 1.0;
        let term = col.right_mul(&e).unwrap();
        ld = Some(match ld {
            None => term,
            Some(s) => s.add(&term).unwrap(),
        });
    }
    let ld = ld.unwrap();
    let aq = q.left_mul(&ab).unwrap();
    let cq = q.left_mul(&t).unwrap();
    let brl = Expr::blocks(&[
        vec![Some(q.clone()), Some(aq.clone()), Some(ld.clone()), None],
        vec![
            Some(aq.transpose()),
            Some(q.clone()),
            None,
            Some(cq.transpose()),
        ],
        vec![Some(ld.transpose()), None, Some(Expr::identity(p)), None],
        vec![None, Some(cq.clone()), None, Some(Expr::identity(n))],
    ])
    .unwrap();
    prob.constrain("bounded real", &brl, Relation::PosSemiDef)
        .unwrap();
    // tr Δ = Σ δ_j.
    let mut trace = dv.entry(0, 0).unwrap();
    for j in 1..p {
        trace = trace.add(&dv.entry(j, 0).unwrap()).unwrap();
    }
    prob.maximize(&trace).unwrap();
    let Outcome::Solved(d) = prob.solve().unwrap() else {
        panic!("step 2 not solved")
    };
    let scale = (jmax - cstar) / (p as f64).sqrt();
    d.value("Delta")
        .unwrap()
        .iter()
        .map(|v| v * scale)
        .collect()
}

#[test]
fn platoon_two_step_synthesis_reproduces_model_design() {
    let m = load("platoon.hyb", &[]);
    let (l, cstar) = platoon_step1(&m);
    let delta = platoon_step2(&m, &l, cstar, J_MAX);
    let (cstar_lyap, _) = platoon_norms(&m, &[1.0, 1.0, 1.0]);
    println!(
        "step 1: c* = {cstar:.7} (model's L: {cstar_lyap:.7}); step 2: Δ = {delta:.5?}; paper (0.107, 0.092, 0.106)"
    );
    // c* from tr X equals the H₂ norm of the model's (reference) gains to solver accuracy.
    assert!(
        (cstar / cstar_lyap - 1.0).abs() < 1e-4,
        "c* {cstar} vs {cstar_lyap}"
    );
    let model_delta: Vec<f64> = param_matrix(&m, "Delta").iter().copied().collect();
    for (d, md) in delta.iter().zip(&model_delta) {
        assert!(
            (d / md - 1.0).abs() < 2e-3,
            "Δ {delta:?} vs model {model_delta:?}"
        );
    }
}

/// Reference synthesis (scipy/cvxpy + Clarabel, scaled; computed outside this repository):
/// M = 3, Cor. V.2, J_max = 0.38.
const REF_CSTAR: f64 = 0.01020482;
const REF_DELTA: [f64; 3] = [0.123265016, 0.105805407, 0.121960215];

#[test]
fn platoon_design_blocks_reproduce_the_reference_synthesis() {
    let m = load("platoon.hyb", &[]);
    let reports = m.design_reports();
    assert_eq!(reports.len(), 2);
    let (obs, thr) = (&reports[0], &reports[1]);
    assert_eq!(
        (obs.name.as_str(), thr.name.as_str()),
        ("observer", "thresholds")
    );
    let s1 = obs.solve.as_ref().unwrap();
    // gramian, h2 and 2^3 subset LMIs of Cor. V.2.
    assert_eq!(s1.constraints, 2 + 8);
    assert_eq!(s1.variables, 15 + 15 + 21);
    assert!(s1.worst_margin > -1e-6 && thr.solve.as_ref().unwrap().worst_margin > -1e-6);
    let cstar = param_matrix(&m, "cstar")[(0, 0)];
    let delta: Vec<f64> = param_matrix(&m, "Delta").iter().copied().collect();
    println!(
        "design blocks: c* = {cstar:.8}, Δ = {delta:.6?}; {}; {}",
        obs.summary_line(),
        thr.summary_line()
    );
    // c* = √tr X equals the H₂ norm of the designed error system (Lyapunov equation).
    let (cstar_lyap, hinf) = platoon_norms(&m, &delta);
    assert!(
        (cstar / cstar_lyap - 1.0).abs() < 1e-5,
        "c* {cstar} vs H₂ {cstar_lyap}"
    );
    assert!(
        (cstar / REF_CSTAR - 1.0).abs() < 1e-5,
        "c* {cstar} vs reference {REF_CSTAR}"
    );
    // Step 2's H∞ constraint is active: ‖(zI − Â)⁻¹LΔ‖∞ = √γ = (J_max − c*)/√3.
    let bound = (J_MAX - cstar) / 3f64.sqrt();
    assert!((hinf / bound - 1.0).abs() < 1e-5, "H∞ {hinf} vs √γ {bound}");
    for (d, r) in delta.iter().zip(&REF_DELTA) {
        assert!(
            (d / r - 1.0).abs() < 1e-3,
            "Δ {delta:?} vs reference {REF_DELTA:?}"
        );
    }
    // `--set` replaces the designed Δ (the closed-loop test with the paper's values).
    let paper = load("platoon.hyb", &[PAPER_DELTA_SET]);
    let pd: Vec<f64> = param_matrix(&paper, "Delta").iter().copied().collect();
    assert_eq!(pd, PAPER_DELTA);
}

#[test]
fn appendix_f_p_identity_certifies_corollary_v2_through_the_design_layer() {
    let m = load("appendix_f.hyb", &[]);
    let r = &m.design_reports()[0];
    let s = r.solve.as_ref().unwrap();
    // P == I and 2^2 subset LMIs.
    assert_eq!(s.constraints, 1 + 4);
    // Largest common margin t with [I, A_cl(S); *, I] ⪰ t I at P = I: 1 − max_S ‖A_cl(S)‖
    // = 1 − ‖diag(0.6, 0)‖ = 0.4 > 0, so P = I certifies Cor. V.2.
    let t = param_matrix(&m, "cert_margin")[(0, 0)];
    assert!((t - 0.4).abs() < 1e-6, "margin {t}");
}

use hybsim_papers::analysis::reproduction::{Row, Status, Table, sync_committed};

#[test]
fn muehlebach_trimpe_reproduction_table() {
    let m = load("platoon.hyb", &[]);
    let delta: Vec<f64> = param_matrix(&m, "Delta").iter().copied().collect();
    let cstar_design = param_matrix(&m, "cstar")[(0, 0)];
    let (cstar, hinf) = platoon_norms(&m, &delta);
    let (mean_d, std_d) = rates(designed_stats());
    let (mean_p, std_p) = rates(paper_stats());
    let max_d = designed_stats().stats(0, "dmax").max;
    let max_p = paper_stats().stats(0, "dmax").max;
    let (m20, m20_jmax) = m20_reference_stats();
    let (m20_rate, _) = rates(m20);
    let m20_mean_of = |v: std::ops::RangeInclusive<usize>| {
        v.clone().map(|i| m20_rate[i - 1]).sum::<f64>() / v.count() as f64
    };
    let m20_epow = (1..=20)
        .map(|i| m20.stats(0, &format!("epow[{i}]")).max)
        .fold(0.0, f64::max);
    let ratio: Vec<f64> = PAPER_DELTA.iter().zip(&delta).map(|(p, d)| p / d).collect();
    let mean_ratio = ratio.iter().sum::<f64>() / 3.0;
    let pct = |v: &[f64], s: &[f64]| {
        v.iter()
            .zip(s)
            .map(|(a, b)| format!("{:.1} ± {:.1}", 100.0 * a, 100.0 * b))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let table = Table::new(
        "muehlebach-trimpe",
        "Muehlebach & Trimpe, Distributed event-based state estimation: an LMI approach (issue 7)",
    )
    .preamble(
        "Regenerate: `HYBSIM_BLESS=1 cargo test --release muehlebach`. Platoon M = 3 (models/platoon.hyb): ZOH 20 ms, \
         dlqr Q = I, R = 100 I, noise variances a²/3, V^½ = a_u/√3·B; L and Δ from the model's `design` blocks \
         (step 1 (39) with Cor. V.2, step 2 (40)), `hybsim design models/platoon.hyb`. Closed loop: 20 runs × 1000 s, \
         10 % drops per transmission and receiver, statistics over t ≥ 100 s: the model's metrics `rate_ss[i]`, `dmax`, \
         `epow[i]` reduced by the sweep machinery of `hybsim sweep models/platoon.hyb --grid Jmax=0.38 --runs 20` (each \
         run's seed derived from seed 1, the grid point and the run; mean ± std with n − 1 over the runs).",
    )
    .row(
        Row::new(
            "App. F, inputs communicated: x(n) = (0, 2ⁿ), x̂₁(n) = 0, no communication",
            "(62)",
            "exact, n ≤ 30",
            Status::Differs,
        )
        .note("(62) prints x̂₁(n) = (0, 2ⁿ); the text says x̂₁ stays 0, as computed"),
    )
    .row(
        Row::new(
            "App. F, inputs reconstructed: agent 2 sends at k = 1, zero from k = 2",
            "u(1) = (0, −4)",
            "u(1) = (−4, 0)",
            Status::Differs,
        )
        .note("printed u(1) contradicts the printed x(2) = 0; all other values exact"),
    )
    .row(Row::new(
        "App. F: P = I certifies Cor. V.2",
        "stated",
        "margin 0.4 (design block `certificate`)",
        Status::Reproduced,
    ))
    .row(
        Row::new(
            "J_max / c* (full-communication bound)",
            "roughly 35",
            format!("{:.1}", J_MAX / cstar),
            Status::Reproduced,
        )
        .note(format!(
            "c* = √tr X = {cstar_design:.7}; H₂ by Lyapunov equation {cstar:.7}"
        )),
    )
    .row(
        Row::new(
            "Δ for J_max = 0.38",
            "(0.107, 0.092, 0.106)",
            format!("({:.4}, {:.4}, {:.4})", delta[0], delta[1], delta[2]),
            Status::Differs,
        )
        .note(format!(
            "uniform factor {mean_ratio:.3} (paper/ours {:.3}, {:.3}, {:.3}): the paper's Δ correspond to √γ = 0.1855 \
             instead of (J_max − c*)/√N = {hinf:.4}, i.e. J_max ≈ 0.331 or a divisor 4 instead of N = 3; recorded, not tuned",
            ratio[0], ratio[1], ratio[2]
        )),
    )
    .row(
        Row::new(
            "steady-state distance errors within ±0.1 m",
            "±0.1 m",
            format!("max {max_d:.4} m (paper Δ: max {max_p:.4} m)"),
            if max_d <= 0.1 && max_p <= 0.1 {
                Status::Reproduced
            } else {
                Status::Differs
            },
        )
        .note("largest |d_i| over t ≥ 100 s and the 20 runs (metric `dmax`)"),
    )
    .row(
        Row::new(
            "rates: vehicle 2 ≈ 8 %, vehicles 1, 3 < 4 % (Fig. 5)",
            "8 %, < 4 %",
            format!(
                "paper Δ: {} %; our Δ: {} %",
                pct(&mean_p, &std_p),
                pct(&mean_d, &std_d)
            ),
            Status::Differs,
        )
        .note("reproduced with the printed Δ (`--set 'Delta=[0.107; 0.092; 0.106]'`); with our Δ₂ = 0.106 > 0.1 (noise amplitude) vehicle 2 sends 2 %"),
    )
    .row(
        Row::new("M = 20, Cor. V.3: 1973 variables", "1973", "2380 (P, U, X)", Status::NotReproduced)
            .note("no natural parametrization gives 1973 (P, U, X: 2380; X of size n + p: 3330; with H: 5461; no sum of natural block sizes gives it); solved by the model's design block (Schur-complement backend, 315 s under load) and by CSDP: c* = 0.18912"),
    )
    .row(
        Row::new(
            "Fig. 6 (M = 20, Cor. V.3): rates higher for the leading vehicles",
            "higher for the leading vehicles",
            format!(
                "vehicle 1 {:.1} %, vehicles 2–20 {:.1}–{:.1} %; mean of 1–5 {:.1} %, of 16–20 {:.1} %",
                100.0 * m20_rate[0],
                100.0 * m20_rate[1..].iter().copied().fold(f64::INFINITY, f64::min),
                100.0 * m20_rate[1..].iter().copied().fold(0.0, f64::max),
                100.0 * m20_mean_of(1..=5),
                100.0 * m20_mean_of(16..=20)
            ),
            Status::Reproduced,
        )
        .note(format!(
            "J_max = 35 c* (not printed for M = 20; the M = 3 rule); L, Δ: tests/data/platoon_m20_cor_v3.json (CSDP); \
             `hybsim sweep models/platoon.hyb --set M=20 --set corollary=3 --set L=… --set cstar=… --set Delta=… \
             --grid Jmax={m20_jmax} --runs {M20_RUNS}`: sized down for CI from the paper's 20 runs to {M20_RUNS} × 1000 s. \
             Driven by vehicle 1 (Δ₁ = 0.014 < noise 0.1); among 2–20 the rate peaks at vehicle {}",
            (1..m20_rate.len())
                .max_by(|&a, &b| m20_rate[a].total_cmp(&m20_rate[b]))
                .map_or(0, |i| i + 1)
        )),
    )
    .row(
        Row::new(
            "M = 20: steady-state distance errors below 0.2 m",
            "< 0.2 m",
            format!(
                "max {:.2} m; ‖e_i‖ ≤ {:.2} (J_max {:.2})",
                m20.stats(0, "dmax").max,
                m20_epow,
                m20_jmax
            ),
            Status::NotReproduced,
        )
        .note("c* = √tr X = 0.189 is a conservative bound under Cor. V.3 (H₂ of the designed observer 0.033), so J_max = 35 c* = 6.6 and Δ₂…Δ₂₀ = 0.69–1.35 ≫ the 0.1 m noise; the guarantee ‖e_i‖ ≤ J_max holds (metric `epow[i]`: (mean over t ≥ 100 s of ‖x − x̂_i‖²)^½, largest over agents and runs)"),
    );
    sync_committed(&table).unwrap();
}

/// The streaming statistics of `experiments::platoon` (the figure programs) and the model's
/// metrics (`hybsim sweep`, the REPRODUCTION.md rows) against the same statistics computed from
/// the recorded arc of one run (M = 3, 200 s, t ≥ 100 s): counts, maxima and the pooled quantile
/// must be equal, the error power equal to rounding (the metric's time average to 1e-3: it
/// weighs the last step by its flow time up to T).
#[test]
fn platoon_runner_statistics_equal_those_of_the_recorded_arc() {
    use hybsim_papers::experiments::{StepTable, simulate_seeded};
    let m = load("platoon.hyb", &["T=200"]);
    let seed = 7;
    let arc = simulate_seeded(&m, seed).unwrap();
    let table = StepTable::from_arc(&m, &arc);
    let col = |name: &str| {
        table
            .column(name)
            .unwrap_or_else(|| panic!("no column {name}"))
    };
    // Rows k ≥ 1 are the post-jump states of step k, at the jump's time.
    let rows: Vec<usize> = (1..table.len())
        .filter(|&k| table.times()[k] >= 100.0)
        .collect();
    let steps = rows.len() as f64;
    let rate: Vec<f64> = (1..=3)
        .map(|i| {
            rows.iter()
                .map(|&k| col(&format!("tx[{i}]"))[k])
                .sum::<f64>()
                / steps
        })
        .collect();
    let mut d: Vec<f64> = Vec::new();
    let mut dmax = [0.0_f64; 2];
    for (i, mx) in dmax.iter_mut().enumerate() {
        for &k in &rows {
            let v = col(&format!("x[{}]", 4 + i))[k].abs();
            *mx = mx.max(v);
            d.push(v);
        }
    }
    d.sort_by(f64::total_cmp);
    let q = d[(d.len() as f64 * 0.999) as usize];
    let power: Vec<f64> = (1..=3)
        .map(|i| {
            let s: f64 = rows
                .iter()
                .map(|&k| {
                    (1..=5)
                        .map(|r| {
                            (col(&format!("x[{r}]"))[k] - col(&format!("XH[{r},{i}]"))[k]).powi(2)
                        })
                        .sum::<f64>()
                })
                .sum();
            (s / steps).sqrt()
        })
        .collect();
    let p = Platoon::new(m.clone()).unwrap();
    let e = p.ensemble([seed], &Window::default()).unwrap();
    let r = &e.runs[0];
    println!("rates {rate:?}, max |d| {dmax:?}, q99.9 {q}, ‖e_i‖ {power:?}");
    assert_eq!(r.steps as usize, rows.len());
    assert_eq!(r.rate, rate);
    assert_eq!(e.rate_mean, rate);
    assert!(e.rate_std.iter().all(|s| *s == 0.0), "one seed: no spread");
    assert_eq!(r.distance_max, dmax);
    assert_eq!(e.distance_quantile_all, q);
    for (a, b) in r.error_power.iter().zip(&power) {
        assert!((a / b - 1.0).abs() < 1e-12, "‖e‖ {a} vs {b}");
    }

    // The model's metrics of the same run.
    let (x0, mut rng) = m.start(seed);
    let mut sink = m.metrics().sink();
    hybsim::engine::simulate(&m, &x0, &m.settings(), &mut rng, &mut sink).unwrap();
    let metrics = sink.named_values();
    let metric = |name: &str| {
        metrics
            .iter()
            .find(|(n, _)| n == name)
            .unwrap_or_else(|| panic!("no metric {name}"))
            .1
    };
    for i in 1..=3 {
        assert_eq!(metric(&format!("rate_ss[{i}]")), rate[i - 1], "rate {i}");
        let p = metric(&format!("epow[{i}]"));
        assert!(
            (p / power[i - 1] - 1.0).abs() < 1e-3,
            "epow[{i}] {p} vs {power:?}"
        );
    }
    // `dmax` is the largest |d_i| at every sample at t ≥ 100 s, pre-jump samples included.
    let ix = index(&m);
    let (d1, d2) = (ix("x[4]"), ix("x[5]"));
    let at_samples = arc
        .samples()
        .filter(|s| s.at.t >= 100.0)
        .map(|s| s.x[d1].abs().max(s.x[d2].abs()))
        .fold(0.0, f64::max);
    assert_eq!(metric("dmax"), at_samples);
    assert!(metric("dmax") >= dmax[0].max(dmax[1]));
}

/// The M = 20 Cor. V.3 reference synthesis (tests/data/platoon_m20_cor_v3.json): step 1 by CSDP
/// (c* = 0.189124), step 2 for J_max = 35 c* by CSDP in balanced coordinates (H∞ checked by a
/// frequency sweep). Returns (c*, J_max, `--set` overrides for L, cstar and Delta).
fn m20_reference() -> (f64, f64, Vec<String>) {
    let path = hybsim_papers::repo_path("tests/data/platoon_m20_cor_v3.json");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    assert!(
        (v["hinf_gamma1"].as_f64().unwrap() - 1.0).abs() < 1e-4,
        "step 2 reference is feasible"
    );
    let sets = hybsim_papers::experiments::platoon::synthesis_overrides(&path).unwrap();
    (
        v["cstar"].as_f64().unwrap(),
        v["jmax"].as_f64().unwrap(),
        sets,
    )
}

/// Runs of the M = 20 closed loop in the tests (the paper: 20).
const M20_RUNS: u64 = 4;

/// Fig. 6 closed loop at M = 20 (Cor. V.3, J_max = 35 c*), reduced from the paper's 20 runs ×
/// 1000 s to 4 runs × 1000 s (t ≥ 100 s) to stay CI-sized (~13 s per run on one core; a 400-s
/// horizon is too short: the observer's slowest mode has a time constant of ~56 s), through the
/// sweep machinery (`hybsim sweep models/platoon.hyb --set M=20 --set corollary=3 … --runs 4`).
/// Checked: the design guarantee ‖e_i‖ ≤ J_max (metric `epow[i]`), and the paper's
/// "communication rates are higher for the leading vehicles" as a robust statistic: the mean
/// rate of vehicles 1–5 exceeds that of vehicles 16–20 in every run, and on average by more
/// than three standard errors of the per-run difference. NOT reproduced (printed, recorded in
/// the report): "the distance error remains below 0.2 m" — with our synthesis c* = 0.189 is a
/// conservative bound (the true full-communication H₂ norm is 0.033), J_max = 35 c* = 6.6 gives
/// Δ₂…Δ₂₀ ≈ 0.7–1.35 ≫ the noise amplitude 0.1, and |d| reaches ~2.3 m.
fn m20_fig6_checks(s: &ModelSweep, jmax: f64) {
    assert_eq!(s.incomplete(), 0, "every run reaches T");
    assert_eq!(s.rows.len() as u64, M20_RUNS);
    let (mean, std) = rates(s);
    let pct = |v: &[f64]| v.iter().map(|r| 100.0 * r).collect::<Vec<_>>();
    println!(
        "rates (%): {:.3?}\n± {:.3?}\nmax |d| {:.3}",
        pct(&mean),
        pct(&std),
        s.stats(0, "dmax").max,
    );
    for i in 1..=20 {
        let p = s.stats(0, &format!("epow[{i}]"));
        assert!(p.max <= jmax, "‖e_{i}‖ up to {} vs J_max {jmax}", p.max);
    }
    let run_rates: Vec<Vec<f64>> = (1..=20)
        .map(|i| s.values(0, &format!("rate_ss[{i}]")))
        .collect();
    let diffs: Vec<f64> = (0..s.rows.len())
        .map(|r| {
            let avg = |v: std::ops::Range<usize>| v.map(|i| run_rates[i][r]).sum::<f64>() / 5.0;
            avg(0..5) - avg(15..20)
        })
        .collect();
    let n = diffs.len() as f64;
    let m = diffs.iter().sum::<f64>() / n;
    let sd = (diffs.iter().map(|d| (d - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    println!("per-run differences of the mean rates of vehicles 1–5 and 16–20: {diffs:.5?}");
    assert!(diffs.iter().all(|d| *d > 0.0), "differences {diffs:?}");
    assert!(m > 3.0 * sd / n.sqrt(), "mean {m}, sd {sd}");
}

/// The reference synthesis' closed loop, 4 runs × 1000 s (computed once; also used by the
/// reproduction table), and its J_max.
fn m20_reference_stats() -> &'static (ModelSweep, f64) {
    static S: std::sync::OnceLock<(ModelSweep, f64)> = std::sync::OnceLock::new();
    S.get_or_init(|| {
        let (_, jmax, sets) = m20_reference();
        let mut all: Vec<&str> = vec!["M=20", "corollary=3"];
        all.extend(sets.iter().map(String::as_str));
        let m = load("platoon.hyb", &all);
        // Every design result is given: neither block is solved.
        assert!(m.design_reports().iter().all(|r| r.solve.is_none()));
        let delta: Vec<f64> = param_matrix(&m, "Delta").iter().copied().collect();
        println!("Δ = {delta:.4?}");
        let grid = format!("Jmax={jmax}");
        (
            model_sweep("platoon.hyb", &all, &[&grid], Some(M20_RUNS)),
            jmax,
        )
    })
}

#[test]
fn platoon_m20_fig6_with_the_reference_synthesis() {
    let (s, jmax) = m20_reference_stats();
    m20_fig6_checks(s, *jmax);
}

/// The same with the model's own `design` blocks: step 1 must reach the reference c* (CSDP
/// 6.2 on an SDPA export of the same problem, relative gap 2.6e-6: c* in [0.1891233, 0.1891238])
/// and step 2 its Δ.
#[test]
fn platoon_m20_corollary_v3_design_and_fig6() {
    let (cstar_ref, _, sets) = m20_reference();
    let m = load("platoon.hyb", &["M=20", "corollary=3", "Jmax=35*cstar"]);
    for r in m.design_reports() {
        println!("{}", r.summary_line());
    }
    let cstar = param_matrix(&m, "cstar")[(0, 0)];
    let jmax = param_matrix(&m, "Jmax")[(0, 0)];
    println!("c* = {cstar:.7} (reference {cstar_ref:.7}), J_max = {jmax:.5}");
    assert!(
        (cstar / cstar_ref - 1.0).abs() < 1e-3,
        "c* {cstar} vs {cstar_ref}"
    );
    let delta: Vec<f64> = param_matrix(&m, "Delta").iter().copied().collect();
    let ref_delta: Vec<f64> = sets[2]
        .trim_start_matches("Delta=[")
        .trim_end_matches(']')
        .split("; ")
        .map(|x| x.parse().unwrap())
        .collect();
    for (d, r) in delta.iter().zip(&ref_delta) {
        assert!(
            (d / r - 1.0).abs() < 1e-2,
            "Δ {delta:?} vs reference {ref_delta:?}"
        );
    }
    // The closed loop with this design's results as `--set` values (as the reference's), so
    // that the sweep's compiles do not solve the design blocks again.
    let sets = design_sets(&m);
    let mut all: Vec<&str> = vec!["M=20", "corollary=3"];
    all.extend(sets.iter().map(String::as_str));
    let grid = format!("Jmax={jmax}");
    m20_fig6_checks(
        &model_sweep("platoon.hyb", &all, &[&grid], Some(M20_RUNS)),
        jmax,
    );
}

/// `--set` overrides `L=[..]`, `cstar=..`, `Delta=[..]` with the design results of `m`
/// (shortest round-trip numbers: the same values).
fn design_sets(m: &CompiledModel) -> Vec<String> {
    let matrix = |name: &str| {
        let a = param_matrix(m, name);
        let rows: Vec<String> = a
            .row_iter()
            .map(|r| {
                r.iter()
                    .map(|x| hybsim::num::Num(*x).to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            })
            .collect();
        format!("{name}=[{}]", rows.join("; "))
    };
    let cstar = hybsim::num::Num(param_matrix(m, "cstar")[(0, 0)]);
    vec![matrix("L"), format!("cstar={cstar}"), matrix("Delta")]
}

/// Figs. 5–6 as the model's own declarations (`metric rate_ss[i]`,
/// `rate_all` and the `sweep { }` block, run by `hybsim sweep
/// models/platoon.hyb`): the block sweeps the J_max of Fig. 5 (right) with
/// 20 runs, and every run of the sweep machinery gives the Rust
/// experiment's steady-state rates ([`Platoon::run`], the REPRODUCTION.md
/// values) for the same seed, exactly: both count the steps at t ≥ 100 s in
/// which a vehicle sent. Short runs (T = 200 s, 2 per J_max, 3 of the 11
/// J_max) keep it quick; the design blocks are solved per J_max on both sides.
#[test]
fn platoon_rates_sweep_block_is_the_rust_experiment() {
    use hybsim::lang::Override;
    use hybsim::sinks::RunStatus;
    use hybsim::source::SourceFile;
    use hybsim::sweep::{self, Axis, Shard, SweepSpec};

    let base = load("platoon.hyb", &[]);
    let names: Vec<&str> = base.metrics().names().iter().map(String::as_str).collect();
    assert_eq!(
        names,
        [
            "rate_ss[1]",
            "rate_ss[2]",
            "rate_ss[3]",
            "rate_all",
            "dmax",
            "epow[1]",
            "epow[2]",
            "epow[3]"
        ]
    );
    let block = base.sweep().expect("a sweep block").clone();
    let jmax = [0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.33, 0.36, 0.38, 0.42, 0.5];
    assert_eq!(block.axes, [("Jmax".to_string(), jmax.to_vec())]);
    assert_eq!((block.runs, block.seed), (Some(20), Some(1)));

    let src = SourceFile::read(hybsim_papers::model_path("platoon.hyb")).unwrap();
    let fixed: Vec<Override> = vec!["T=200".parse().unwrap()];
    let axis = Axis {
        name: "Jmax".into(),
        values: vec![0.1, 0.3, 0.38],
    };
    let spec = SweepSpec::new(vec![axis], 2, 1);
    let rows = sweep::run(
        &src,
        &fixed,
        &spec,
        Shard::ALL,
        &Default::default(),
        Default::default(),
    );
    assert_eq!(rows.len(), 6);
    let window = Window::default();
    let tss = base.parameter("tss").expect("param tss")[(0, 0)];
    assert_eq!(window.t_ss, tss, "the same steady-state window");
    for row in &rows {
        assert_eq!(row.status, RunStatus::Completed, "{}", row.message);
        let jmax = format!("Jmax={}", row.values[0]);
        let p = Platoon::new(load("platoon.hyb", &["T=200", &jmax])).unwrap();
        let rust = p.run(row.seed, &window).unwrap();
        assert_eq!(row.metrics[..3], rust.rate[..], "{jmax}, seed {}", row.seed);
        let mean = rust.rate.iter().sum::<f64>() / 3.0;
        assert!((row.metrics[3] - mean).abs() <= 1e-15, "{jmax}: rate_all");
    }
    // Fig. 5 (right): the rates fall as J_max grows (more error allowed).
    let points = sweep::aggregate(&spec, &rows);
    let all: Vec<f64> = points.iter().map(|p| p.stats[3].mean).collect();
    assert!(all[0] > all[1] && all[1] > all[2], "{all:?}");
}
