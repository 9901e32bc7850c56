//! Subsystems (LANGUAGE.md, "Subsystems"): models composed of instances of
//! reusable hybrid systems, through the real pipeline, against closed forms
//! and independent computations; the same system written flat gives the
//! same arc bit for bit; the composition errors point into the source.

use crate::util::compile;
use hybsim::arc::HybridArc;
use hybsim::engine::{check_arc, simulate_arc};
use hybsim::ir::CompiledModel;
use hybsim::lang;
use hybsim::source::SourceFile;

/// The rendered diagnostics of a model that must not compile.
fn errors(src: &str) -> String {
    let file = SourceFile::new("t.hyb", src);
    match lang::compile(&file, &[]) {
        Ok(_) => panic!("compiled:\n{src}"),
        Err(d) => hybsim::diagnostics::render(&d, &file, false),
    }
}

fn run(m: &CompiledModel) -> HybridArc {
    let settings = m.settings();
    let (x0, mut rng) = m.start(m.seed());
    let arc = simulate_arc(m, &x0, &settings, &mut rng).expect("simulation runs");
    if let Err(v) = check_arc(m, &arc, &settings) {
        panic!("{v}");
    }
    arc
}

/// The instants of the jumps (one per simultaneous jump, whatever the
/// number of rules that fired in it).
fn jump_instants(arc: &HybridArc) -> Vec<(f64, Vec<f64>)> {
    let mut out: Vec<(u64, f64, Vec<f64>)> = Vec::new();
    for r in arc.jumps() {
        if out.last().is_none_or(|l| l.0 != r.at.j) {
            out.push((r.at.j, r.at.t, r.pre.clone()));
        }
    }
    out.into_iter().map(|(_, t, x)| (t, x)).collect()
}

/// Every sample and every jump record, bit for bit.
fn assert_same_arc(a: &HybridArc, b: &HybridArc) {
    assert_eq!(a.len(), b.len(), "number of samples");
    for (sa, sb) in a.samples().zip(b.samples()) {
        assert_eq!(sa.at.j, sb.at.j);
        assert_eq!(sa.at.t.to_bits(), sb.at.t.to_bits(), "t at j = {}", sa.at.j);
        assert_eq!(sa.kind, sb.kind);
        let bits = |x: &[f64]| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(sa.x), bits(sb.x), "x at ({}, {})", sa.at.t, sa.at.j);
    }
    assert_eq!(a.jumps().len(), b.jumps().len(), "jump records");
    for (ja, jb) in a.jumps().iter().zip(b.jumps()) {
        assert_eq!(
            (ja.at.t.to_bits(), ja.at.j, ja.rule),
            (jb.at.t.to_bits(), jb.at.j, jb.rule)
        );
        assert_eq!(ja.post, jb.post);
    }
}

const BALL: &str = "
subsystem Ball(g = 9.81, lambda = 0.8, h0 = 1) {
    input p, vp = 0                  # height and velocity of the floor
    state h = h0, v = 0
    flow { h' = v; v' = -g } in h >= p
    jump impact when h <= p && v <= vp { v+ = vp - lambda * (v - vp) }
    output height = h
}
subsystem Platform(speed = 0.5) {
    state z = 0
    flow { z' = speed }
    output y = z, v = speed
}
";

/// A ball bouncing on a platform rising at constant speed s: in the
/// platform's (inertial) frame it is a bouncing ball with relative speed u,
/// so the impacts are t1 = (−s + √(s² + 2 g h0)) / g, then flights of
/// 2 λ^k |u1| / g with u1 = −s − g t1.
#[test]
fn ball_on_a_moving_platform_bounces_at_the_closed_form_times() {
    let (g, lambda, h0, s) = (9.81_f64, 0.7_f64, 2.0_f64, 0.3_f64);
    let src = format!(
        "model ball_on_platform\n{BALL}
plat = Platform(speed = {s})
ball = Ball(lambda = {lambda}, h0 = {h0}, p = plat.y, vp = plat.v)
output gap = ball.h - plat.z
sim {{ T = 3; J = 8 }}
"
    );
    let m = compile(&src);
    assert_eq!(m.rule_names(), ["ball.impact"]);
    let names = m.output_names();
    assert!(
        names.iter().any(|n| n == "ball.height") && names.iter().any(|n| n == "plat.y"),
        "{names:?}"
    );
    let arc = run(&m);
    let t1 = (-s + (s * s + 2.0 * g * h0).sqrt()) / g;
    let u1 = (-s - g * t1).abs();
    let mut expected = vec![t1];
    let mut t = t1;
    for k in 1..8 {
        t += 2.0 * lambda.powi(k) * u1 / g;
        if t >= 3.0 {
            break;
        }
        expected.push(t);
    }
    let got: Vec<f64> = jump_instants(&arc).iter().map(|(t, _)| *t).collect();
    assert_eq!(got.len(), expected.len(), "{got:?} vs {expected:?}");
    for (a, b) in got.iter().zip(&expected) {
        assert!((a - b).abs() < 1e-9, "{got:?} vs {expected:?}");
    }

    // The same system written flat: the same arc, bit for bit.
    let flat = compile(&format!(
        "model flat
param speed = {s}, g = 9.81, lambda = {lambda}, h0 = {h0}
state z = 0
state h = h0, v = 0
flow {{ z' = speed }}
flow {{ h' = v; v' = -g }} in h >= z
together {{ jump impact when h <= z && v <= speed {{ v+ = speed - lambda * (v - speed) }} }}
sim {{ T = 3; J = 8 }}
"
    ));
    assert_same_arc(&arc, &run(&flat));
}

const LOOP: &str = "
subsystem Plant(a = 0.5, b = 1, x0 = 1) {
    input u
    state x = x0
    flow { x' = a * x + b * u }
    output y = x
}
subsystem Adc(Ts) {
    input u
    state xs = 0
    every Ts { xs+ = u }
    output y = xs
}
subsystem Gain(K = 1) {
    input u
    output y = -K * u
}
subsystem Zoh(Ts) {
    input u
    state h = 0
    every Ts { h+ = u }
    output y = h
}
";

/// Plant + ADC + controller + ZOH: at each sampling instant kT one jump in
/// which the ADC samples x(kT) and the ZOH takes the controller's output
/// on the pre-jump (previous) sample: u_k = −K x((k−1)T). Checked against
/// the exact discretisation x_{k+1} = e^{aT} x_k + (e^{aT} − 1)/a · b u_k.
#[test]
fn sampled_data_loop_matches_its_exact_discretisation_and_its_flat_form() {
    let (a, b, k, ts) = (0.5_f64, 1.0_f64, 1.5_f64, 0.1_f64);
    let src = format!(
        "model sampled\n{LOOP}
plant = Plant(a = {a}, b = {b}, u = zoh.y)
adc = Adc(Ts = {ts}, u = plant.y)
ctrl = Gain(K = {k}, u = adc.y)
zoh = Zoh(Ts = {ts}, u = ctrl.y)
sim {{ T = 2.05 }}
"
    );
    let m = compile(&src);
    assert_eq!(m.rule_names(), ["adc.step", "zoh.step"]);
    let arc = run(&m);
    let instants = jump_instants(&arc);
    assert_eq!(instants.len(), 20, "one jump per sampling instant");
    assert_eq!(arc.jumps().len(), 40, "both rules fire in each jump");
    let (mut x, mut xs, mut h) = (1.0_f64, 0.0_f64, 0.0_f64);
    let phi = (a * ts).exp();
    for (n, (t, pre)) in instants.iter().enumerate() {
        x = phi * x + (phi - 1.0) / a * b * h;
        assert!((t - (n + 1) as f64 * ts).abs() < 1e-12, "t = {t}");
        assert!(
            (pre[0] - x).abs() < 1e-9 * x.abs().max(1.0),
            "x({t}) = {} vs {x}",
            pre[0]
        );
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs().max(1.0);
        assert!(
            close(pre[1], xs) && close(pre[2], h),
            "held values before the jump at {t}: {pre:?} vs {xs} {h}"
        );
        h = -k * xs;
        xs = x;
    }

    let flat = compile(&format!(
        "model flat
param a = {a}, b = {b}, Ts = {ts}, K = {k}
state x = 1
state xs = 0
state h = 0
flow {{ x' = a * x + b * h }}
together {{
    jump adc every Ts {{ xs+ = x }}
    jump zoh every Ts {{ h+ = -K * xs }}
}}
sim {{ T = 2.05 }}
"
    ));
    assert_same_arc(&arc, &run(&flat));
}

/// N fireflies as N instances of one subsystem coupled through the largest
/// clock each sees: when a clock reaches 1 it flashes (back to 0) and in the
/// same jump every other advances to (1 + ε)τ, or flashes with it. Checked
/// against an event-by-event computation of the same map.
#[test]
fn fireflies_as_instances_match_an_event_by_event_computation() {
    let n = 6;
    let eps = 0.1;
    let init: Vec<f64> = (1..=n)
        .map(|i| 0.9 * (i as f64) / (n as f64 + 1.0))
        .collect();
    let column: Vec<String> = init.iter().map(|v| format!("{v:?}")).collect();
    let column = column.join("; ");
    let src = format!(
        "model swarm
subsystem Firefly(eps = 0.1, tau0 = 0) {{
    input seen = 0                   # the largest clock this firefly sees
    state tau = tau0
    flow {{ tau' = 1 }} in tau <= 1
    jump flash when tau >= 1 {{ tau+ = 0 }}
    jump nudge when seen >= 1 && tau < 1 {{
        tau+ = if (1 + eps) * tau < 1 then (1 + eps) * tau else 0
    }}
    output clock = tau
}}
param N = {n}, T0 = [{column}]
graph G = ones(N, N) - eye(N)
param E = eye(N)
for i in 1..N {{
    f[i] = Firefly(eps = {eps}, tau0 = T0[i],
                   seen = max(sum(k in in(G, i): f[k].clock * E[:, k])))
}}
output spread = max(sum(i in 1..N: f[i].clock * E[:, i])) - min(sum(i in 1..N: f[i].clock * E[:, i]))
sim {{ T = 12; J = 200 }}
"
    );
    let m = compile(&src);
    assert_eq!(m.rule_names().len(), 2 * n);
    assert_eq!(m.rule_names()[0], "f.flash[1]");
    let arc = run(&m);
    // Event by event: the next flash is when the largest clock reaches 1.
    let mut tau = init.clone();
    let mut t = 0.0_f64;
    let mut expected = Vec::new();
    loop {
        let top = tau.iter().cloned().fold(f64::MIN, f64::max);
        let dt = 1.0 - top;
        if t + dt >= 12.0 {
            break;
        }
        t += dt;
        expected.push(t);
        for x in tau.iter_mut() {
            *x += dt;
            *x = if *x >= 1.0 - 1e-12 {
                0.0
            } else if (1.0 + eps) * *x < 1.0 {
                (1.0 + eps) * *x
            } else {
                0.0
            };
        }
    }
    let got: Vec<f64> = jump_instants(&arc).iter().map(|(t, _)| *t).collect();
    assert_eq!(got.len(), expected.len(), "{got:?}\n{expected:?}");
    for (a, b) in got.iter().zip(&expected) {
        assert!((a - b).abs() < 1e-9, "{got:?}\n{expected:?}");
    }
    // They synchronise: the last flashes are one unit of time apart.
    let last = &expected[expected.len() - 2..];
    assert!((last[1] - last[0] - 1.0).abs() < 1e-9, "{expected:?}");
}

#[test]
fn an_algebraic_loop_is_an_error_naming_the_loop_at_its_place() {
    let text = errors(&format!(
        "model m\n{LOOP}\nplant = Plant(u = a.y)\na = Gain(u = b.y)\nb = Gain(u = a.y)\n"
    ));
    assert!(text.contains("error[E0511]"), "{text}");
    assert!(
        text.contains("algebraic loop: `a.u` → `b.y` → `b.u` → `a.y` → `a.u`"),
        "{text}"
    );
    // The loop is shown from a's connection, `u = b.y` on line 27.
    assert!(text.contains("t.hyb:27:14"), "{text}");
    assert_eq!(
        text.matches("error[").count(),
        1,
        "one error, no cascade: {text}"
    );
}

#[test]
fn composition_errors_point_at_the_instance_or_the_subsystem() {
    let model = |rest: &str| format!("model m\n{LOOP}\n{rest}\n");
    let cases: &[(&str, &str, &str)] = &[
        (
            "plant = Plant()",
            "E0512",
            "input `u` of `plant` (Plant) is not connected",
        ),
        (
            "plant = Plant(u = 0, gain = 2)",
            "E0512",
            "`gain` is neither a parameter nor an input of subsystem `Plant`",
        ),
        (
            "adc = Adc(u = 1)",
            "E0512",
            "parameter `Ts` of `adc` (Adc) has no value",
        ),
        ("p = Plnt(u = 0)", "E0201", "did you mean `Plant`?"),
        (
            "plant = Plant(u = 0, u = 1)",
            "E0202",
            "`u` is declared twice",
        ),
    ];
    for (rest, code, words) in cases {
        let text = errors(&model(rest));
        assert!(text.contains(&format!("error[{code}]")), "{rest}: {text}");
        assert!(text.contains(words), "{rest}: {text}");
        assert!(text.contains("t.hyb:"), "{text}");
    }
    // A subsystem sees only its own names: the model's `k` is unknown in it.
    let text = errors(
        "model m\nparam k = 2\nsubsystem S() {\n  state x = 0\n  flow { x' = k }\n}\ns = S()\n",
    );
    assert!(text.contains("unknown name `s.k`"), "{text}");
    assert!(text.contains("t.hyb:5:15"), "{text}");
    // A subsystem containing itself.
    let text = errors(
        "model m\nsubsystem A() { b = B() }\nsubsystem B() { state y = 0; a = A() }\na = A()\n",
    );
    assert!(text.contains("error[E0513]"), "{text}");
    assert!(text.contains("A → B → A"), "{text}");
}

/// One mistake, one error: an unconnected input's uses in the subsystem
/// were also "unknown name `p.u`" (with a "did you mean `p.y`?" pointing
/// elsewhere), and an instance name given twice also declared each of its
/// members twice (six errors for one repeated line).
#[test]
fn composition_errors_do_not_cascade() {
    let sub = "subsystem P(a) {\n  input u\n  state x = 0\n  flow { x' = a*x + u }\n  \
               jump r when x >= 1 { x+ = u }\n  output y = x\n}\n";
    let cases: &[(&str, &str, &str)] = &[
        (
            "p = P(a = -1)",
            "error[E0512]: input `u` of `p` (P) is not connected",
            "t.hyb:9:1",
        ),
        (
            "for i in 1..3 { f[i] = P(a = -i) }\noutput s = f[2].y",
            "error[E0512]: input `u` of `f` (P) is not connected",
            "t.hyb:9:17",
        ),
        (
            "p = P(a = 1, u = 0)\np = P(a = 2, u = 0)",
            "error[E0202]: `p` is declared twice",
            "t.hyb:10:1",
        ),
    ];
    for (rest, error, at) in cases {
        let text = errors(&format!("model m\n{sub}{rest}\n"));
        assert!(text.contains(error), "{rest}: {text}");
        assert!(text.contains(at), "{rest}: {text}");
        assert_eq!(text.matches("error[").count(), 1, "{rest}: {text}");
    }
}

/// Overrides reach an instance's parameters by their prefixed name, and a
/// family of instances sizes its families by the loop.
#[test]
fn instance_parameters_are_overridable_and_families_are_indexed_by_instance() {
    let src =
        format!("model m\n{BALL}\nplat = Platform()\nball = Ball(p = plat.y)\nsim {{ T = 0.1 }}\n");
    let file = SourceFile::new("t.hyb", src);
    let o: Vec<lang::Override> = vec!["ball.h0=3".parse().unwrap()];
    let m = lang::compile(&file, &o).unwrap();
    let (x0, _) = m.start(m.seed());
    assert_eq!(x0[1], 3.0);

    let m = compile(
        "model m
subsystem Cell(r = 1) { state x = r; flow { x' = -x } }
for i in 1..3 { c[i] = Cell(r = i) }
",
    );
    let (x0, _) = m.start(m.seed());
    assert_eq!(x0, [1.0, 2.0, 3.0]);
    let names: Vec<String> = m.state_layout().flat_names(3);
    assert_eq!(names, ["c.x[1]", "c.x[2]", "c.x[3]"]);

    // Rules of one instance are alternatives (both reset `q`: no E0510).
    let m = compile(
        "model m
subsystem Toggle(T = 1) {
    state q = 0, x = 0
    flow { x' = 1 } in x <= T
    jump on when x >= T && q == 0 { q+ = 1; x+ = 0 }
    jump off when x >= T && q == 1 { q+ = 0; x+ = 0 }
}
a = Toggle(T = 1)
b = Toggle(T = 0.75)
sim { T = 2.1 }
",
    );
    let arc = run(&m);
    let instants: Vec<f64> = jump_instants(&arc).iter().map(|(t, _)| *t).collect();
    assert_eq!(instants.len(), 4, "{instants:?}");
    for (t, e) in instants.iter().zip([0.75, 1.0, 1.5, 2.0]) {
        assert!((t - e).abs() < 1e-12, "{instants:?}");
    }
    let last = arc.last().unwrap();
    // a toggled twice (t = 1, 2), b twice (t = 0.75, 1.5).
    assert_eq!((last.x[0], last.x[2]), (0.0, 0.0));
    let rules: Vec<&str> = arc
        .jumps()
        .iter()
        .map(|r| arc.rule_name(r.rule).unwrap())
        .collect();
    assert_eq!(rules, ["b.on", "a.on", "b.off", "a.off"]);
}

/// Instances are objects in MCAP (schemas valid for Foxglove, names
/// reachable by message paths: `/hybsim/state.ball.h`), prefixed names in
/// CSV columns and jump records.
#[test]
fn outputs_name_instance_members_in_every_format() {
    use hybsim::sinks::foxglove::check_schema;
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("m.hyb");
    std::fs::write(
        &model,
        format!(
            "model m\n{BALL}
plat = Platform(speed = 0.3)
ball = Ball(p = plat.y, vp = plat.v)
subsystem Cell(r = 1) {{ state x = r; flow {{ x' = -x }}; output twice = 2 * x }}
for i in 1..2 {{ c[i] = Cell(r = i) }}
"
        ),
    )
    .unwrap();
    let bytes =
        super::outputs::short_run(dir.path(), &model, "m.mcap", &["--log-encoding", "json"]);
    let mut seen = std::collections::BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let schema: serde_json::Value =
            serde_json::from_slice(&m.channel.schema.as_ref().unwrap().data).unwrap();
        if let Err(issues) = check_schema(&schema) {
            panic!("{}: {issues:?}", m.channel.topic);
        }
        let body: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
        super::util::assert_conforms(&body, &schema, &m.channel.topic);
        seen.entry(m.channel.topic.clone()).or_insert(body);
    }
    let state = &seen["/hybsim/state"];
    assert!(state["ball"]["h"].is_number(), "{state}");
    assert!(state["plat"]["z"].is_number(), "{state}");
    assert_eq!(state["c"]["x"].as_array().unwrap().len(), 2, "{state}");
    let outputs = &seen["/hybsim/outputs"];
    assert!(outputs["ball"]["height"].is_number(), "{outputs}");
    assert!(outputs["c"]["twice"].as_array().is_some(), "{outputs}");
    let jump = &seen["/hybsim/jumps"];
    assert_eq!(jump["rule"], "ball.impact", "{jump}");

    let o = super::util::hybsim(
        dir.path(),
        &[
            "run",
            "m.hyb",
            "--no-mcap",
            "--csv",
            "m.csv",
            "--quiet",
            "--T",
            "1",
        ],
    );
    assert_eq!(super::util::code(&o), 0, "{}", super::util::stderr(&o));
    let csv = std::fs::read_to_string(dir.path().join("m.csv")).unwrap();
    let header = csv.lines().next().unwrap();
    for col in ["ball.h", "ball.v", "plat.z", "c.x[1]", "c.x[2]"] {
        assert!(header.split(',').any(|c| c == col), "{col} in {header}");
    }
}
