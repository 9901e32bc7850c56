//! Language features through the real pipeline, each against what it must
//! compute: families and graphs, `every`, held and white noise, matrix
//! states, outputs, and the run-time diagnostics.

use crate::util::simulate_arc;
use hybsim::arc::HybridTime;
use hybsim::diagnostics::render;
use hybsim::engine::{FlowStructure, HybridSystem, SimRng};
use hybsim::lang::{self, CompiledModel};
use hybsim::source::SourceFile;
use nalgebra::{DMatrix, Matrix2};

fn compile(text: &str) -> CompiledModel {
    let src = SourceFile::new("t.hyb", text);
    lang::compile(&src, &[]).unwrap_or_else(|d| panic!("{}", render(&d, &src, false)))
}

fn errors(text: &str) -> Vec<(String, String, String)> {
    let src = SourceFile::new("t.hyb", text);
    lang::check_only(&src, &[])
        .iter()
        .map(|d| {
            let at = d
                .line_col(&src)
                .map(|lc| lc.to_string())
                .unwrap_or_default();
            (d.code.to_string(), at, d.message.clone())
        })
        .collect()
}

fn outputs(m: &CompiledModel, x: &[f64]) -> Vec<f64> {
    let mut y = vec![0.0; m.output_dim()];
    m.outputs(HybridTime::new(0.0, 0), x, &mut y);
    y
}

#[test]
fn families_and_graph_neighbour_sets() {
    // G[i, k] != 0: i receives from k. A directed 3-cycle 1 <- 2 <- 3 <- 1,
    // plus 1 <- 3.
    let m = compile(
        "model g
         graph G = [0, 1, 1; 0, 0, 1; 1, 0, 0]
         for i in 1..3 { state x[i] = i }
         for (i, k) in edges(G) { state m[i, k] = 10 * i + k }
         output in1 = sum(k in in(G, 1): x[k]), out1 = sum(k in out(G, 1): x[k])
         output in3 = sum(k in in(G, 3): x[k]), out3 = sum(k in out(G, 3): x[k])
         output others2 = sum(k in 1..3 if k != 2: x[k])
         output nedges = sum((i, k) in edges(G): 1)
         output byexpr = sum(k in in(G + 0, 1): x[k]) + 10 * sum(k in out(1 * G, 3): x[k])
         flow { for i in 1..3 { x[i]' = sum(k in in(G, i): x[k] - x[i]) } }",
    );
    assert_eq!(
        m.state_names(),
        [
            "x[1]", "x[2]", "x[3]", "m[1,2]", "m[1,3]", "m[2,3]", "m[3,1]"
        ]
    );
    let x0 = m.initial_state(&mut SimRng::seed_from(0));
    assert_eq!(x0, [1.0, 2.0, 3.0, 12.0, 13.0, 23.0, 31.0]);
    // in(G, 1) = {2, 3}, out(G, 1) = {3}; in(G, 3) = {1}, out(G, 3) = {1, 2}
    // (the same for a graph given by a name, read in place, and by an
    // expression).
    assert_eq!(outputs(&m, &x0), [5.0, 3.0, 1.0, 3.0, 4.0, 4.0, 35.0]);
    // The consensus flow is affine: rows of the Laplacian.
    let FlowStructure::Affine { a, b } = m.flow_structure() else {
        panic!("affine flow expected")
    };
    assert_eq!(&a[..3], [-2.0, 1.0, 1.0]);
    assert_eq!(&a[7..10], [0.0, -1.0, 1.0]);
    assert!(b.iter().all(|&v| v == 0.0));
}

/// A `jump` without a name is named `jump1`, `jump2`, … in declaration
/// order (beside the `step`s of anonymous `every`), and a property can name it.
#[test]
fn jumps_without_a_name_are_numbered() {
    let m = compile(
        "model b
         state h = 1, v = 0
         flow { h' = v; v' = -9.81 }
         jump when h <= 0 && v <= 0 { v+ = -0.8 * v }
         every 0.5 { h+ = h }
         jump when h >= 2 { h+ = 0 }
         property bounce: at jumps jump1 post(v) >= 0
         sim { T = 1 }",
    );
    assert_eq!(m.rule_names(), ["jump1", "step", "jump2"]);
    let (x0, mut rng) = m.start(0);
    let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng).unwrap();
    assert!(!arc.jump_times(0).is_empty());
}

/// `max(k in S: e)` and `min(k in S: e)` fold like `sum`: elementwise, with
/// the fold's identity over an empty set; `max(a, b)` stays the function.
/// Over decision variables in a design block they are not affine.
#[test]
fn max_and_min_fold_over_index_sets() {
    let m = compile(
        "model g
         graph G = [0, 1, 1; 0, 0, 1; 1, 0, 0]
         for i in 1..3 { state x[i] = 4 - i }
         output hi = max(k in in(G, 1): x[k]), lo = min(k in 1..3 if k != 2: x[k] - 1)
         output pair = max(x[1], x[3]), none = max(k in 1..0: x[k]), nmin = min(k in 1..0: 1)
         output v = max(k in 1..2: [x[k]; -x[k]])
         flow { for i in 1..3 { x[i]' = min(k in in(G, i): x[k]) - x[i] } }
         jump r when max(k in 1..3: x[k]) <= 0 { x[1]+ = 1 }",
    );
    let x0 = m.initial_state(&mut SimRng::seed_from(0));
    assert_eq!(x0, [3.0, 2.0, 1.0]);
    let y = outputs(&m, &x0);
    assert_eq!(&y[..3], [2.0, 0.0, 3.0]);
    assert_eq!(y[3], f64::NEG_INFINITY);
    assert_eq!(y[4], f64::INFINITY);
    assert_eq!(&y[5..], [3.0, -2.0]);
    let errs = errors(
        "model d\nparam A = -eye(2)\ndesign b {\n    sym P[2]\n    \
         max(k in 1..2: P[k, k]) >= 1\n    param Q = P\n}\n",
    );
    assert!(
        errs.iter()
            .any(|(code, _, msg)| code == "E0701" && msg.contains("maximum")),
        "{errs:?}"
    );
}

#[test]
fn every_fires_at_exact_multiples_of_its_period() {
    let m = compile(
        "model e
         state c = 0, d = 0
         every 0.25 { c+ = c + 1 }
         jump tick every 0.4 { d+ = d + 2 }
         sim { T = 2.01 }",
    );
    assert_eq!(m.rule_names(), ["step", "tick"]);
    let (x0, mut rng) = m.start(0);
    let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng).unwrap();
    let step = arc.jump_times(0);
    let tick = arc.jump_times(1);
    assert_eq!(step.len(), 8);
    assert_eq!(tick.len(), 5);
    for (k, t) in step.iter().enumerate() {
        assert!((t - 0.25 * (k + 1) as f64).abs() < 1e-12, "step {k}: {t}");
    }
    for (k, t) in tick.iter().enumerate() {
        assert!((t - 0.4 * (k + 1) as f64).abs() < 1e-12, "tick {k}: {t}");
    }
    let last = arc.last().unwrap();
    assert_eq!((last.x[0], last.x[1]), (8.0, 10.0));
}

#[test]
fn held_noise_is_constant_between_redraws_and_has_its_distribution() {
    let m = compile(
        "model n
         noise v ~ normal(1, 2) every 0.1
         state s = 0, s2 = 0
         jump acc every 0.1 { s+ = s + v; s2+ = s2 + v^2 }
         sim { T = 400.05; seed = 3 }",
    );
    // Rules in declaration order: at a common instant the redraw (declared
    // first) fires first, so `acc` sees the new value.
    assert_eq!(m.rule_names(), ["v.redraw", "acc"]);
    let (x0, mut rng) = m.start(m.seed());
    let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng).unwrap();
    // Between redraws v does not move.
    let mut last_v = (x0[0], 0);
    for s in arc.samples() {
        if s.at.j == last_v.1 {
            assert_eq!(s.x[0], last_v.0, "v moved during a flow at {:?}", s.at);
        }
        last_v = (s.x[0], s.at.j);
    }
    // Redraws every 0.1, and acc sees the values of v: mean 1, std 2.
    let redraws = arc.jump_times(0);
    assert_eq!(redraws.len(), 4000);
    for (k, t) in redraws.iter().enumerate().step_by(97) {
        assert!((t - 0.1 * (k + 1) as f64).abs() < 1e-9);
    }
    let n = arc.jump_times(1).len() as f64;
    let end = arc.last().unwrap().x;
    let mean = end[1] / n;
    let var = end[2] / n - mean * mean;
    // 4000 draws: 5 standard errors.
    assert!((mean - 1.0).abs() < 5.0 * 2.0 / n.sqrt(), "mean {mean}");
    assert!(
        (var - 4.0).abs() < 5.0 * 4.0 * (2.0 / n).sqrt(),
        "variance {var}"
    );
}

/// `uniform(lo, hi)` over a range wider than the largest float (`hi − lo`
/// overflows) draws finite values inside it, in an initial value and in a
/// reset (machine code and interpreter alike); it drew ±inf or NaN, a
/// run-time error at the flow equation. Ordinary ranges draw as before.
#[test]
fn uniform_draws_over_the_widest_ranges_are_finite() {
    let m = compile(
        "model wide
         state x ~ uniform(-1e308, 1.5e308), y = 0, s = 0
         flow { s' = 1 }
         jump r when s >= 1 { s+ = 0; y+ = uniform(-1.7e308, 1.7e308) }
         sim { T = 400.5 }",
    );
    for seed in 0..50 {
        let (x0, _) = m.start(seed);
        assert!(
            x0[0].is_finite() && (-1e308..=1.5e308).contains(&x0[0]),
            "{x0:?}"
        );
    }
    let (x0, mut rng) = m.start(1);
    let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng).expect("finite draws");
    let ys: Vec<f64> = arc.jumps().iter().map(|r| r.post[1]).collect();
    assert_eq!(ys.len(), 400);
    assert!(ys.iter().all(|y| y.is_finite() && y.abs() <= 1.7e308));
    // Both signs, spread over the range.
    let positive = ys.iter().filter(|y| **y > 0.0).count();
    assert!(
        (150..=250).contains(&positive),
        "{positive} of 400 positive"
    );
    assert!(ys.iter().any(|y| y.abs() > 1e307));
    // A range whose span is finite: the draws are the ones they were.
    let mut a = SimRng::seed_from(9);
    let mut b = SimRng::seed_from(9);
    for _ in 0..100 {
        let u = b.uniform(0.0, 1.0);
        assert_eq!(a.uniform(-3.0, 5.0), -3.0 + 8.0 * u);
    }
}

#[test]
fn white_noise_enters_linearly_with_state_dependent_coefficients() {
    let m = compile(
        "model ou
         param a = 2, s = 0.5
         noise w ~ wiener(2)
         state x = 0, y = 1
         flow { x' = -a * x + s * w[1]; y' = -y + 0.5 * y * w[2] + x * w[1] }
         sim { solver = euler_maruyama; h = 1e-3; T = 200; seed = 5 }",
    );
    assert_eq!(m.noise_dim(), 2);
    let mut g = [0.0; 4];
    m.diffusion(HybridTime::new(0.0, 0), &[3.0, 4.0], &mut g);
    // Row-major n × m: dx = f dt + G dW.
    assert_eq!(g, [0.5, 0.0, 3.0, 2.0]);
    let mut f = [0.0; 2];
    m.flow_map(HybridTime::new(0.0, 0), &[3.0, 4.0], &mut f);
    assert_eq!(f, [-6.0, -4.0]);
    // Ornstein–Uhlenbeck: stationary variance s² / (2a) = 1/16.
    let (x0, mut rng) = m.start(m.seed());
    let s = m.settings().dt_out(Some(0.05));
    let arc = simulate_arc(&m, &x0, &s, &mut rng).unwrap();
    let xs: Vec<f64> = arc
        .samples()
        .filter(|s| s.at.t > 5.0)
        .map(|s| s.x[0])
        .collect();
    let n = xs.len() as f64;
    let mean = xs.iter().sum::<f64>() / n;
    let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
    assert!((var - 0.0625).abs() < 0.15 * 0.0625, "variance {var}");
    assert!(mean.abs() < 0.05, "mean {mean}");
}

#[test]
fn nonlinear_uses_of_white_noise_are_rejected_at_the_equation() {
    let e = errors(
        "model bad
         noise w ~ wiener(1)
         state x = 0, y = 0, z = 0
         flow {
           x' = w^2
           y' = -y + sin(x) * w
           z' = exp(-z * w)
         }
         sim { solver = euler_maruyama }",
    );
    let msg = |t: &str| format!("white noise must enter `{t}'` linearly");
    assert_eq!(
        e,
        [
            ("E0509".to_string(), "5:12".to_string(), msg("x")),
            ("E0509".to_string(), "7:12".to_string(), msg("z")),
        ]
    );
}

#[test]
fn matrix_states_follow_the_lyapunov_differential_equation() {
    let m = compile(
        "model lyap
         param A = [0, 1; -2, -3]
         state P = [2, 0.5; 0.5, 1]
         flow { P' = A * P + P * A' }
         output p12 = P[1, 2], tr = trace(P)
         sim { T = 1.5 }",
    );
    assert_eq!(m.state_names(), ["P[1,1]", "P[1,2]", "P[2,1]", "P[2,2]"]);
    assert_eq!(m.output_names(), ["p12", "tr"]);
    let (x0, mut rng) = m.start(0);
    // The flow is affine: exact to 1e-9 on the exact path (by default it is
    // chosen by cost, and a single non-repeating segment takes the solver).
    let s = m.settings().exact_affine(true);
    let arc = simulate_arc(&m, &x0, &s, &mut rng).unwrap();
    let end = arc.last().unwrap();
    let a = Matrix2::new(0.0, 1.0, -2.0, -3.0);
    let e = (a * end.at.t).exp();
    let p = e * Matrix2::new(2.0, 0.5, 0.5, 1.0) * e.transpose();
    for r in 0..2 {
        for c in 0..2 {
            assert!((end.x[2 * r + c] - p[(r, c)]).abs() < 1e-9, "P[{r},{c}]");
        }
    }
    let mut y = [0.0; 2];
    m.outputs(end.at, end.x, &mut y);
    assert_eq!(y, [end.x[1], end.x[0] + end.x[3]]);
}

#[test]
fn vector_and_matrix_outputs_have_component_names() {
    let m = compile(
        "model o
         state x = [1; 2; 3]
         output y = 2 * x, M = x * x', n = norm(x)",
    );
    assert_eq!(m.output_dim(), 3 + 9 + 1);
    let names = m.output_names();
    assert_eq!(&names[..4], ["y[1]", "y[2]", "y[3]", "M[1,1]"]);
    assert_eq!(names[5], "M[1,3]");
    assert_eq!(names[12], "n");
    let y = outputs(&m, &[1.0, 2.0, 3.0]);
    assert_eq!(&y[..3], [2.0, 4.0, 6.0]);
    assert_eq!(y[5], 3.0);
    assert!((y[12] - 14f64.sqrt()).abs() < 1e-15);
}

#[test]
fn runtime_failures_point_at_the_equation_with_the_hybrid_time() {
    let run = |text: &str| {
        let m = compile(text);
        let (x0, mut rng) = m.start(0);
        let err = simulate_arc(&m, &x0, &m.settings(), &mut rng).unwrap_err();
        let d = m.runtime_diagnostic(&err);
        let at = d.line_col(m.source()).unwrap().to_string();
        let labels: Vec<String> = d.labels.iter().map(|l| l.message.clone()).collect();
        (d.code, at, labels)
    };
    // y' = log(3 - c): after the third jump (t = 3, j = 3) log(0) = -inf;
    // the first rk4 step makes y non-finite.
    let (code, at, labels) = run("model r
state x = 1, c = 0, y = 0
flow { x' = -1; y' = log(3 - c) }
jump r when x <= 0 { x+ = 1; c+ = c + 1 }
sim { T = 10; solver = rk4; h = 0.01 }
");
    assert_eq!((code, at.as_str()), ("E0602", "3:17"));
    assert_eq!(labels, ["became non-finite at (t, j) = (3.01, 3)"]);

    // A singular matrix inside a flow, inv([1, 1; 1, x]) at x = 1: the
    // matrix is the primary label, the equation the secondary one.
    let singular = "model s
state x = 1
flow { x' = -x + trace(inv([1, 1; 1, x])) }
";
    let (code, at, labels) = run(&format!("{singular}sim {{ solver = rk4; h = 0.01 }}\n"));
    assert_eq!((code, at.as_str()), ("E0602", "3:24"));
    assert_eq!(
        labels,
        [
            "this matrix was singular during the run",
            "became non-finite at (t, j) = (0.01, 0)"
        ]
    );
    // With Dopri5 the flow is non-finite at its first point: the same error at (0, 0) (it was
    // a step-size collapse blamed on the fastest state), the matrix still named first.
    let (code, at, labels) = run(singular);
    assert_eq!((code, at.as_str()), ("E0602", "3:24"));
    assert_eq!(
        labels,
        [
            "this matrix was singular during the run",
            "became non-finite at (t, j) = (0, 0)"
        ]
    );
}

#[test]
fn matrix_parameters_from_control_functions_agree_with_design_control() {
    let m = compile(
        "model c
         param A = [0, 1; 2, -1], B = [0; 1]
         param (Ad, Bd) = c2d(A, B, 0.1)
         param K = dlqr(Ad, Bd, eye(2), 0.5)
         state x = [1; 0]",
    );
    let p = m.parameters_json();
    let a = DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 2.0, -1.0]);
    let b = DMatrix::from_row_slice(2, 1, &[0.0, 1.0]);
    let (ad, bd) = hybsim::design::control::c2d(&a, &b, 0.1).unwrap();
    let k = hybsim::design::control::dlqr(
        &ad,
        &bd,
        &DMatrix::identity(2, 2),
        &DMatrix::from_element(1, 1, 0.5),
    )
    .unwrap()
    .k;
    for c in 0..2 {
        assert_eq!(p["K"][0][c].as_f64().unwrap(), k[(0, c)]);
        assert_eq!(p["Bd"][c].as_f64().unwrap(), bd[(c, 0)]);
    }
}

#[test]
fn state_families_are_family_entries_of_the_layout() {
    use hybsim::layout::{Entry, Shape};
    let m = compile(
        "model f
         for i in 1..3 { state x[i] = [i; 0], z[i] = i }
         state h = 0
         for i in 1..2 { state odd[i] = zeros(i, 1) }",
    );
    let entries = &m.state_layout().entries;
    let Entry::Family {
        name,
        labels,
        members,
    } = &entries[0]
    else {
        panic!("{entries:?}")
    };
    assert_eq!(name, "x");
    assert_eq!(labels, &["1", "2", "3"]);
    assert_eq!(members[2][0].shape, Shape::Vector(2));
    assert_eq!(members[2][0].offset, 6, "x[1], z[1], x[2], z[2], x[3]");
    assert!(matches!(&entries[1], Entry::Family { name, .. } if name == "z"));
    // Members of different shapes are a family too (written as matrices).
    assert!(matches!(&entries[3], Entry::Family { name, .. } if name == "odd"));
    assert_eq!(
        m.state_names(),
        [
            "x[1][1]",
            "x[1][2]",
            "z[1]",
            "x[2][1]",
            "x[2][2]",
            "z[2]",
            "x[3][1]",
            "x[3][2]",
            "z[3]",
            "h",
            "odd[1]",
            "odd[2][1]",
            "odd[2][2]"
        ]
    );
    hybsim::sinks::check_layout(m.state_layout(), m.state_dim(), "state").unwrap();
    // In MCAP records a family of values is an array: `z: [1, 2, 3]`.
    let schema = hybsim::sinks::json::sample_schema("state", m.state_layout());
    let z = &schema["properties"]["z"];
    assert_eq!(z["type"], "array");
    assert_eq!(z["minItems"], 3);
    assert_eq!(z["items"]["type"], "number");
    let x = &schema["properties"]["x"]["items"];
    assert_eq!(
        x["type"], "object",
        "a family of vectors is an array of objects"
    );
    assert_eq!(x["properties"]["data"]["maxItems"], 2);
}
