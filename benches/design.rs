//! Design benchmarks: the Muehlebach–Trimpe platoon synthesis for M = 3
//! (step 1 with Cor. V.2, 2³ subset LMIs; step 2 thresholds), once from the
//! `.hyb` file (parse, check, ZOH/dlqr in the model, both `design` blocks)
//! and once written directly against `design::lmi` from the same matrices.
//! Results and the machine are in BENCHMARKS.md.
//!
//! `cargo bench --bench design`

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use hybsim::design::lmi::{Expr, Outcome, Problem, Relation, Rescale, Settings, VarKind};
use hybsim::lang;
use hybsim::source::SourceFile;
use nalgebra::DMatrix;

fn model() -> SourceFile {
    SourceFile::read(concat!(env!("CARGO_MANIFEST_DIR"), "/models/platoon.hyb")).unwrap()
}

/// A parameter of the compiled model (after overrides and `design` blocks).
fn param(m: &lang::CompiledModel, name: &str) -> DMatrix<f64> {
    m.parameter(name)
        .unwrap_or_else(|| panic!("the model has no parameter `{name}`"))
}

struct Data {
    a: DMatrix<f64>,
    c: DMatrix<f64>,
    af: DMatrix<f64>,
    wh: DMatrix<f64>,
    vh: DMatrix<f64>,
    jmax: f64,
}

fn solved(p: &Problem) -> hybsim::design::lmi::Design {
    match p.solve().unwrap() {
        Outcome::Solved(d) => d,
        other => panic!("{other:?}"),
    }
}

/// The same two problems as the model's `design` blocks, with the same settings.
fn rust_design(d: &Data) -> DMatrix<f64> {
    let settings = Settings {
        rescale: Rescale::Always,
        ..Settings::default()
    };
    let (n, p) = (d.a.nrows(), d.c.nrows());
    let mut s1 = Problem::new().with_settings(settings.clone());
    let pv = s1.add_variable("P", VarKind::Symmetric(n)).unwrap();
    let u = s1.add_variable("U", VarKind::Full(n, p)).unwrap();
    let x = s1.add_variable("X", VarKind::Symmetric(2 * p)).unwrap();
    let p_uc = pv.sub(&u.right_mul(&d.c).unwrap()).unwrap();
    let pa = p_uc.right_mul(&d.a).unwrap();
    let eye = Expr::identity(n);
    let gram = Expr::blocks(&[
        vec![Some(eye.clone()), None, Some(eye.clone())],
        vec![None, Some(pv.clone()), Some(pa.clone())],
        vec![Some(eye), Some(pa.transpose()), Some(pv.clone())],
    ])
    .unwrap();
    s1.constrain("gramian", &gram, Relation::PosSemiDef)
        .unwrap();
    let pb2 = Expr::blocks(&[vec![
        Some(u.right_mul(&d.wh).unwrap().neg()),
        Some(p_uc.right_mul(&d.vh).unwrap()),
    ]])
    .unwrap();
    let h2 = Expr::blocks(&[
        vec![Some(pv.clone()), Some(pb2.clone())],
        vec![Some(pb2.transpose()), Some(x.clone())],
    ])
    .unwrap();
    s1.constrain("h2", &h2, Relation::PosSemiDef).unwrap();
    for subset in 0..(1u32 << p) {
        let mut pacl = pv.clone();
        for m in (0..p).filter(|m| subset & (1 << m) != 0) {
            let um = u.block(0, m, n, 1).unwrap();
            pacl = pacl
                .sub(&um.right_mul(&d.c.rows(m, 1).into_owned()).unwrap())
                .unwrap();
        }
        let pacl = pacl.right_mul(&d.af).unwrap();
        let lmi = Expr::blocks(&[
            vec![Some(pv.clone()), Some(pacl.clone())],
            vec![Some(pacl.transpose()), Some(pv.clone())],
        ])
        .unwrap();
        s1.constrain(&format!("corV2 {subset}"), &lmi, Relation::PosSemiDef)
            .unwrap();
    }
    s1.minimize(&x.trace().unwrap()).unwrap();
    let r1 = solved(&s1);
    let l = r1
        .value("P")
        .unwrap()
        .clone()
        .lu()
        .solve(r1.value("U").unwrap())
        .unwrap();
    let cstar = r1.objective.sqrt();
    let ahat = (DMatrix::identity(n, n) - &l * &d.c) * &d.a;
    let gamma = (d.jmax - cstar).powi(2) / p as f64;
    let mut s2 = Problem::new().with_settings(settings);
    let q = s2.add_variable("Q", VarKind::Symmetric(n)).unwrap();
    let dv = s2.add_variable("D", VarKind::Full(p, 1)).unwrap();
    let mut ld = Expr::zeros(n, p);
    for j in 0..p {
        let mut e = DMatrix::zeros(n, p);
        e.set_column(j, &l.column(j));
        ld = ld.add(&dv.entry(j, 0).unwrap().kron_left(&e)).unwrap();
    }
    let aq = q.left_mul(&ahat).unwrap();
    let brl = Expr::blocks(&[
        vec![Some(q.clone()), Some(aq.clone()), Some(ld.clone()), None],
        vec![Some(aq.transpose()), Some(q.clone()), None, Some(q.clone())],
        vec![Some(ld.transpose()), None, Some(Expr::identity(p)), None],
        vec![
            None,
            Some(q.clone()),
            None,
            Some(Expr::identity(n).scale(gamma)),
        ],
    ])
    .unwrap();
    s2.constrain("brl", &brl, Relation::PosSemiDef).unwrap();
    let mut tr = dv.entry(0, 0).unwrap();
    for j in 1..p {
        tr = tr.add(&dv.entry(j, 0).unwrap()).unwrap();
    }
    s2.maximize(&tr).unwrap();
    solved(&s2).value("D").unwrap().clone()
}

fn platoon(c: &mut Criterion) {
    let src = model();
    let m = lang::compile(&src, &[]).unwrap();
    let sqrt3 = 3f64.sqrt();
    let data = Data {
        a: param(&m, "A"),
        c: param(&m, "C"),
        af: param(&m, "AF"),
        wh: DMatrix::identity(3, 3) * (param(&m, "a_w")[(0, 0)] / sqrt3),
        vh: param(&m, "B") * (param(&m, "a_u")[(0, 0)] / sqrt3),
        jmax: param(&m, "Jmax")[(0, 0)],
    };
    // Both routes give the same thresholds to the design's accuracy: the
    // model forms L = inv(P) U, this file an LU solve, and step 2's optimum
    // is flat in Δ, so the two differ by about 1e-5 relative.
    let ours = rust_design(&data);
    let model_delta = param(&m, "Delta");
    let gap = (&ours - &model_delta).amax() / model_delta.amax();
    assert!(gap < 1e-4, "thresholds differ by {gap:e} (relative)");
    let mut g = c.benchmark_group("platoon_M3_design");
    g.sample_size(10);
    g.bench_function("hyb_file", |b| {
        b.iter(|| black_box(lang::design_only(&src, &[]).unwrap()))
    });
    g.bench_function("rust_api", |b| b.iter(|| black_box(rust_design(&data))));
    g.finish();
}

criterion_group!(benches, platoon);
criterion_main!(benches);
