//! `jump_choice` (README, Engine semantics): which of several enabled rules
//! fires. `first` (the default) the first declared; `random` a uniform draw
//! from the run's `SimRng` among the enabled jumps (a set-valued jump map
//! G(x) = G₁(x) ∪ G₂(x) written as rules with overlapping jump sets). The
//! frequencies are checked against 1/2 within 5 standard deviations of the
//! binomial (fixed seeds: the checks are deterministic, and a uniform draw
//! would leave those bounds with probability < 1e-6).

use crate::util::{compile, simulate_arc};
use hybsim::arc::HybridArc;
use hybsim::engine::{JumpChoice, SimSettings, check_arc};
use hybsim::ir::CompiledModel;
use hybsim::lang;
use hybsim::source::SourceFile;

/// The model's run with seed `seed` under `settings`, its set invariants
/// checked.
fn run_seed(m: &CompiledModel, settings: &SimSettings, seed: u64) -> HybridArc {
    let (x0, mut rng) = m.start(seed);
    let arc = simulate_arc(m, &x0, settings, &mut rng).expect("simulation runs");
    if let Err(v) = check_arc(m, &arc, settings) {
        panic!("{v}");
    }
    arc
}

/// How many of the arc's jump records are by rule `name`.
fn count(arc: &HybridArc, name: &str) -> usize {
    arc.jumps()
        .iter()
        .filter(|r| arc.rule_name(r.rule) == Some(name))
        .count()
}

/// `k` successes in `n` draws of probability `p`, within 5 standard deviations.
fn assert_binomial(k: usize, n: usize, p: f64, what: &str) {
    let (n_f, k_f) = (n as f64, k as f64);
    let sigma = (n_f * p * (1.0 - p)).sqrt();
    assert!(
        (k_f - n_f * p).abs() <= 5.0 * sigma,
        "{what}: {k} of {n}, expected {} ± {:.1} (5σ)",
        n_f * p,
        5.0 * sigma
    );
}

/// A discrete-time system (C empty) whose two rules are enabled at every
/// point: x⁺ ∈ {x + 1, x − 1}, a simple random walk.
const WALK: &str = "model walk
state x = 0, ups = 0
jump up when true { x+ = x + 1; ups+ = ups + 1 }
jump down when true { x+ = x - 1 }
sim { J = 2000; jump_choice = random }
";

#[test]
fn random_choice_draws_each_of_two_overlapping_rules_half_of_the_time() {
    let m = compile(WALK);
    assert_eq!(m.settings().jump_choice, JumpChoice::Random);
    let settings = m.settings();
    for seed in [1, 2, 3] {
        let arc = run_seed(&m, &settings, seed);
        assert_eq!(arc.jumps().len(), 2000);
        let ups = count(&arc, "up");
        assert_eq!(ups + count(&arc, "down"), 2000);
        assert_binomial(ups, 2000, 0.5, &format!("seed {seed}"));
        // The states agree with the records: x = ups − downs.
        let last = arc.last().unwrap();
        assert_eq!(last.x[1], ups as f64);
        assert_eq!(last.x[0], 2.0 * ups as f64 - 2000.0);
    }
}

/// Overlapping jump sets reached by a flow: `x' = 1` from 0, both sets hold
/// from x = 1 on (the event localized on the first rule's atom), each reset
/// to 0. Every jump at t = k exactly, by either rule.
#[test]
fn random_choice_at_a_localized_event_draws_among_the_rules_reached() {
    let m = compile(
        "model saw
state x = 0, na = 0, nb = 0
flow { x' = 1 } in x <= 1
jump a when x >= 1 { x+ = 0; na+ = na + 1 }
jump b when x >= 1 && x <= 2 { x+ = 0; nb+ = nb + 1 }
sim { T = 1000.5; jump_choice = random }
",
    );
    let arc = run_seed(&m, &m.settings(), 5);
    let jumps = arc.jumps();
    assert_eq!(jumps.len(), 1000);
    for (k, r) in jumps.iter().enumerate() {
        let t = (k + 1) as f64;
        assert!((r.at.t - t).abs() <= 1e-9 * t, "jump {k} at {}", r.at.t);
    }
    let last = arc.last().unwrap();
    assert_eq!(last.x[1] + last.x[2], 1000.0);
    assert_binomial(count(&arc, "a"), 1000, 0.5, "rule a");
}

/// A simultaneous group is one jump: against a lone rule it is drawn half of
/// the time, however many of its members are enabled, and then all of them
/// fire.
#[test]
fn random_choice_counts_a_group_once_and_fires_all_its_enabled_members() {
    let m = compile(
        "model g
state a = 0, b = 0, c = 0
jump lone when true { a+ = a + 1 }
together {
    jump gb when true { b+ = b + 1 }
    jump gc when true { c+ = c + 1 }
}
sim { J = 2000; jump_choice = random }
",
    );
    let arc = run_seed(&m, &m.settings(), 11);
    let last = arc.last().unwrap();
    let (a, b, c) = (last.x[0], last.x[1], last.x[2]);
    assert_eq!(a + b, 2000.0);
    // Both members in every group jump.
    assert_eq!(b, c);
    assert_eq!(count(&arc, "gb"), count(&arc, "gc"));
    assert_binomial(a as usize, 2000, 0.5, "lone rule");
}

/// The rules of one subsystem instance are its alternatives: in the
/// instances' simultaneous jump each instance fires one of its enabled
/// rules, drawn uniformly.
#[test]
fn random_choice_draws_one_rule_per_instance_in_a_composite_jump() {
    let m = compile(
        "model parts
subsystem Coin() {
    state heads = 0, tails = 0, tau = 0
    flow { tau' = 1 } in tau <= 1
    jump head when tau >= 1 { heads+ = heads + 1; tau+ = 0 }
    jump tail when tau >= 1 { tails+ = tails + 1; tau+ = 0 }
}
p = Coin()
q = Coin()
sim { T = 1000.5; jump_choice = random }
",
    );
    let arc = run_seed(&m, &m.settings(), 3);
    let last = arc.last().unwrap();
    // Per instance: (heads, tails, tau); one toss per instance per second.
    let (ph, pt, qh, qt) = (last.x[0], last.x[1], last.x[3], last.x[4]);
    assert_eq!((ph + pt, qh + qt), (1000.0, 1000.0));
    // One composite jump per second, each with one rule of each instance.
    let mut js: Vec<u64> = arc.jumps().iter().map(|r| r.at.j).collect();
    js.dedup();
    assert_eq!(js.len(), 1000);
    assert_eq!(arc.jumps().len(), 2000);
    assert_binomial(ph as usize, 1000, 0.5, "p's heads");
    assert_binomial(qh as usize, 1000, 0.5, "q's heads");
}

#[test]
fn random_choice_gives_the_same_arc_for_the_same_seed() {
    let m = compile(WALK);
    let settings = m.settings().horizon_j(300);
    let key = |arc: &HybridArc| -> Vec<(u64, usize)> {
        arc.jumps().iter().map(|r| (r.at.j, r.rule)).collect()
    };
    let a = run_seed(&m, &settings, 42);
    let b = run_seed(&m, &settings, 42);
    assert_eq!(key(&a), key(&b));
    assert_eq!(a.last().unwrap().x, b.last().unwrap().x);
    // Another seed draws another sequence (2^-300 of being the same).
    assert_ne!(key(&a), key(&run_seed(&m, &settings, 43)));
    // The model draws: `hybsim test` samples it on many cases.
    assert!(m.is_random());
    assert!(!compile(&WALK.replace("jump_choice = random", "jump_choice = first")).is_random());
}

/// `jump_choice = first` (and no key at all) fire the first declared rule
/// whenever both are enabled, as before the key existed; with `random`,
/// rules that never overlap give the arc of `first` bit for bit (nothing is
/// drawn where one rule is enabled).
#[test]
fn first_choice_keeps_the_declaration_order() {
    for spelled in ["jump_choice = first", ""] {
        let m = compile(&WALK.replace("jump_choice = random", spelled));
        assert_eq!(m.settings().jump_choice, JumpChoice::First);
        let arc = run_seed(&m, &m.settings(), 1);
        assert_eq!(count(&arc, "up"), 2000, "{spelled:?}");
        assert_eq!(arc.last().unwrap().x[0], 2000.0);
    }
    let disjoint = "model ball
state h = 1, v = 0
flow { h' = v; v' = -9.81 } in h >= 0
jump impact when h <= 0 && v <= 0 { v+ = -0.8 * v }
jump never when h >= 5 { h+ = 0 }
sim { T = 3 }
";
    let m = compile(disjoint);
    let first = run_seed(&m, &m.settings(), 1);
    let random = run_seed(&m, &m.settings().jump_choice(JumpChoice::Random), 1);
    assert_eq!(first.len(), random.len());
    for (a, b) in first.samples().zip(random.samples()) {
        assert_eq!((a.at.t.to_bits(), a.at.j), (b.at.t.to_bits(), b.at.j));
        assert_eq!(a.x, b.x);
    }
}

/// A value other than `first` or `random` is a located error.
#[test]
fn a_bad_jump_choice_is_a_located_error() {
    let src = "model m\nstate x = 0\nflow { x' = 1 }\nsim { jump_choice = sometimes }\n";
    let file = SourceFile::new("t.hyb", src);
    let Err(d) = lang::compile(&file, &[]) else {
        panic!("compiled")
    };
    let text = hybsim::diagnostics::render(&d, &file, false);
    assert!(text.contains("write one of first, random"), "{text}");
    assert!(text.contains("t.hyb:4:21"), "{text}");
}
