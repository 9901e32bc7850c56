//! Scale benchmark of the design layer: step 1 of the Muehlebach–Trimpe synthesis (observer
//! gains minimizing tr(X) under (39) with the inter-agent conditions of Cor. V.3) for a platoon
//! of M vehicles, model (41) discretized by ZOH at 20 ms.
//!
//! ```sh
//! cargo run --release --example platoon_design -- 3
//! /usr/bin/time -v cargo run --release --example platoon_design -- 20
//! ```
//!
//! H of Cor. V.3 is eliminated exactly: (26) only gets easier as H decreases and (25) bounds H
//! below by S₀ = [[P, P(A+BF)], [*, P]], so H = S₀ is optimal.

use std::time::Instant;

use hybsim::design::control::{c2d, dlqr};
use hybsim::design::lmi::{Expr, Outcome, Problem, Relation, VarKind};
use nalgebra::DMatrix;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let m: usize = std::env::args().nth(1).map_or(Ok(3), |s| s.parse())?;
    let start = Instant::now();
    let n = 2 * m - 1;
    // x = (p1, d1, p2, d2, ..., p_{M-1}, d_{M-1}, p_M); d_i = r_i − r_{i+1}.
    let mut ac = DMatrix::<f64>::zeros(n, n);
    let mut bc = DMatrix::<f64>::zeros(n, m);
    for i in 0..m {
        bc[(2 * i, i)] = 1.0;
        if i + 1 < m {
            ac[(2 * i + 1, 2 * i)] = 1.0;
            ac[(2 * i + 1, 2 * i + 2)] = -1.0;
        }
    }
    let (a, b) = c2d(&ac, &bc, 0.02)?;
    // Measurements: vehicle 1 its velocity, vehicle i ≥ 2 the distance to vehicle i − 1.
    let mut c = DMatrix::<f64>::zeros(m, n);
    c[(0, 0)] = 1.0;
    for i in 1..m {
        c[(i, 2 * (i - 1) + 1)] = 1.0;
    }
    let lqr = dlqr(
        &a,
        &b,
        &DMatrix::identity(n, n),
        &(DMatrix::identity(m, m) * 100.0),
    )?;
    let acl0 = &a - &b * &lqr.k; // A + BF with F = −K
    // Uniform noise: w ∈ [−0.1, 0.1] (variance 0.2²/12), input noise ∈ [−0.01, 0.01].
    let w_half = DMatrix::<f64>::identity(m, m) * (0.2f64.powi(2) / 12.0).sqrt();
    let v_half = &b * (0.02f64.powi(2) / 12.0).sqrt(); // V = B Σ_u Bᵀ, V^{1/2} = B σ_u (n×M)

    let mut prob = Problem::new();
    let p = prob.add_variable("P", VarKind::Symmetric(n))?;
    let u = prob.add_variable("U", VarKind::Full(n, m))?; // U = P L, column m = U_m = P L_m
    let x = prob.add_variable("X", VarKind::Symmetric(2 * m))?;
    let eye_n = Expr::identity(n);
    // P Â = P A − U C A
    let p_ahat = p.right_mul(&a)?.sub(&u.right_mul(&(&c * &a))?)?;
    let lmi1 = Expr::blocks(&[
        vec![Some(eye_n.clone()), None, Some(eye_n.clone())],
        vec![None, Some(p.clone()), Some(p_ahat.clone())],
        vec![
            Some(eye_n.clone()),
            Some(p_ahat.transpose()),
            Some(p.clone()),
        ],
    ])?;
    prob.constrain("(39) performance/stability", &lmi1, Relation::PosDef)?;
    // P B̂₂ = [−U W^{1/2}, (P − U C) V^{1/2}]
    let p_b2 = Expr::blocks(&[vec![
        Some(u.right_mul(&w_half)?.neg()),
        Some(p.right_mul(&v_half)?.sub(&u.right_mul(&(&c * &v_half))?)?),
    ]])?;
    let lmi2 = Expr::blocks(&[
        vec![Some(p.clone()), Some(p_b2.clone())],
        vec![Some(p_b2.transpose()), Some(x.clone())],
    ])?;
    prob.constrain("(39) H2 bound", &lmi2, Relation::PosDef)?;
    let s0_off = p.right_mul(&acl0)?;
    let s0 = Expr::blocks(&[
        vec![Some(p.clone()), Some(s0_off.clone())],
        vec![Some(s0_off.transpose()), Some(p.clone())],
    ])?;
    prob.constrain("(25) S0 > 0", &s0, Relation::PosDef)?;
    let factor = (m as f64 - 1.0) / m as f64;
    for k in 0..m {
        let mut ek = DMatrix::<f64>::zeros(m, 1);
        ek[(k, 0)] = 1.0;
        let u_k = u.right_mul(&ek)?; // n×1
        let off = p
            .sub(&u_k.right_mul(&c.rows(k, 1).into_owned())?)?
            .right_mul(&acl0)?;
        let sk = Expr::blocks(&[
            vec![Some(p.clone()), Some(off.clone())],
            vec![Some(off.transpose()), Some(p.clone())],
        ])?;
        prob.constrain(
            &format!("(26) m = {}", k + 1),
            &sk.sub(&s0.scale(factor))?,
            Relation::PosDef,
        )?;
    }
    prob.minimize(&x.trace()?)?;
    let built = start.elapsed().as_secs_f64();
    println!("M = {m}: {}", prob.summary());
    println!("assembly of expressions: {built:.2} s");
    match prob.solve()? {
        Outcome::Solved(d) => {
            let i = &d.info;
            println!(
                "status {:?}; tr(X) = {:.6e}, c* = sqrt(tr X) = {:.6e}; worst relative margin {:.3e}",
                i.status,
                d.objective,
                d.objective.sqrt(),
                d.worst_margin
            );
            println!(
                "variables {}, cone rows {}, nonzeros {}, passes {}, iterations {}, solve {:.2} s, total {:.2} s",
                i.variables,
                i.cone_rows,
                i.nonzeros,
                i.passes,
                i.iterations,
                i.solve_time,
                i.total_time
            );
            let pm = d.value("P").ok_or("P")?;
            let um = d.value("U").ok_or("U")?;
            let l = pm.clone().lu().solve(um).ok_or("P singular")?;
            println!("max |P| = {:.3e}, max |L| = {:.3e}", pm.amax(), l.amax());
            if m <= 3 {
                println!("L = {l:.5}");
            }
        }
        other => println!("outcome: {other:?}"),
    }
    Ok(())
}
