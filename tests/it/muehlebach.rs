//! Muehlebach & Trimpe, distributed event-based estimation (issue 7):
//! App. F two-agent example and the vehicle platoon of Sec. VII, through the
//! real pipeline (parse → check → compile → simulate). Reference numbers and
//! every modelling choice: REPRODUCTION.md, section Muehlebach–Trimpe.

use hybsim::arc::HybridArc;
use hybsim::engine::HybridSystem;
use hybsim::lang::CompiledModel;

use crate::lang::{load, run};

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

/// Scratch: compiles the model in MT_MODEL with overrides MT_SET (comma-free, `;`-separated)
/// and prints diagnostics, parameters and the first steps. Ignored; for model development.
#[test]
#[ignore]
fn mt_scratch() {
    let name = std::env::var("MT_MODEL").unwrap_or_else(|_| "platoon.hyb".into());
    let sets = std::env::var("MT_SET").unwrap_or_default();
    let ov: Vec<&str> = sets.split(';').filter(|s| !s.is_empty()).collect();
    let path = format!("{}/models/{name}", env!("CARGO_MANIFEST_DIR"));
    let src = hybsim::source::SourceFile::read(&path).expect("model file");
    let ov: Vec<hybsim::lang::Override> = ov.iter().map(|s| s.parse().unwrap()).collect();
    let m = match hybsim::lang::compile(&src, &ov) {
        Ok(m) => m,
        Err(d) => {
            println!("{}", hybsim::diagnostics::render(&d, &src, false));
            panic!("diagnostics");
        }
    };
    println!("params {}", m.parameters_json());
    let t0 = std::time::Instant::now();
    let arc = run(&m);
    println!("jumps {} in {:?}", arc.jumps().len(), t0.elapsed());
    let names = m.state_layout().flat_names(m.state_dim());
    if let Some(last) = arc.last() {
        for (n, v) in names.iter().zip(last.x) {
            print!("{n}={v:.4} ");
        }
        println!();
    }
}
