//! Machine code (`jit = on`) against the interpreter (`jit = off`): the
//! same arcs, bit for bit, and the same values of every program the engine
//! calls (flow map, diffusion, set predicates and guards, the atoms of every
//! set, jump maps, outputs) along them, and the metrics of the runs. On
//! every shipped model, on models written for what the shipped ones do not
//! use (`j` in every kind of expression, `together` groups, boolean set
//! expressions with `==`/`!=`, the rounding functions, noise, metrics), and
//! on the random systems of the semantics reference test. Also: all sets'
//! atoms and all jump conditions evaluated at once (one program each)
//! against set by set.

use crate::util::simulate_arc;
use hybsim::arc::HybridTime;
use hybsim::engine::{HybridSystem, SetRef, SimError, SimRng};
use hybsim::lang::{self, CompiledModel, JitStatus, Override};
use hybsim::source::SourceFile;

fn compile(src: &SourceFile, jit: &str) -> CompiledModel {
    let ov: Vec<Override> = vec![format!("jit={jit}").parse().unwrap()];
    match lang::compile(src, &ov) {
        Ok(m) => m,
        Err(d) => panic!("{}", hybsim::diagnostics::render(&d, src, false)),
    }
}

fn bits(x: &[f64]) -> Vec<u64> {
    // NaN counts as one value: which NaN comes out of an operation on two
    // NaNs depends on the order of its operands (`src/ir/jit`).
    x.iter()
        .map(|v| if v.is_nan() { f64::NAN } else { *v }.to_bits())
        .collect()
}

/// Every program of `a` and `b` at `(at, x)`: the same bits.
fn same_programs(name: &str, a: &CompiledModel, b: &CompiledModel, at: HybridTime, x: &[f64]) {
    let n = a.state_dim();
    let (mut va, mut vb) = (vec![0.0; n], vec![0.0; n]);
    a.flow_map(at, x, &mut va);
    b.flow_map(at, x, &mut vb);
    assert_eq!(bits(&va), bits(&vb), "{name}: flow map at {at}");
    let g = n * a.noise_dim();
    let (mut ga, mut gb) = (vec![0.0; g], vec![0.0; g]);
    a.diffusion(at, x, &mut ga);
    b.diffusion(at, x, &mut gb);
    assert_eq!(bits(&ga), bits(&gb), "{name}: diffusion at {at}");
    let (mut ya, mut yb) = (vec![0.0; a.output_dim()], vec![0.0; b.output_dim()]);
    a.outputs(at, x, &mut ya);
    b.outputs(at, x, &mut yb);
    assert_eq!(bits(&ya), bits(&yb), "{name}: outputs at {at}");

    assert_eq!(a.flow_set(at, x), b.flow_set(at, x), "{name}: C at {at}");
    assert_eq!(
        a.flow_guard(at, x).map(|g| bits(&[g])),
        b.flow_guard(at, x).map(|g| bits(&[g])),
        "{name}: C's guard at {at}"
    );
    let sets = std::iter::once(SetRef::Flow).chain((0..a.jump_rules().len()).map(SetRef::Jump));
    for set in sets {
        let atoms = a.set_atoms(set);
        assert_eq!(atoms, b.set_atoms(set), "{name}: atoms of {set:?}");
        let Some(atoms) = atoms else { continue };
        for flowing_only in [false, true] {
            let k = atoms.atoms.len();
            let (mut va, mut vb) = (vec![0.0; k], vec![0.0; k]);
            a.atom_values(set, at, x, flowing_only, &mut va);
            b.atom_values(set, at, x, flowing_only, &mut vb);
            assert_eq!(
                bits(&va),
                bits(&vb),
                "{name}: atoms of {set:?} (flowing only: {flowing_only}) at {at}"
            );
        }
    }
    // All sets at once: the machine code's and the interpreter's, and the
    // per-set values, agree.
    let sets: Vec<SetRef> = std::iter::once(SetRef::Flow)
        .chain((0..a.jump_rules().len()).map(SetRef::Jump))
        .collect();
    let total: usize = sets
        .iter()
        .filter_map(|&s| a.set_atoms(s))
        .map(|s| s.atoms.len())
        .sum();
    let (mut fa, mut fb) = (vec![0.0; total], vec![0.0; total]);
    assert!(a.all_atom_values(at, x, false, &mut fa));
    assert!(b.all_atom_values(at, x, false, &mut fb));
    assert_eq!(bits(&fa), bits(&fb), "{name}: all atoms at {at}");
    let mut per_set = Vec::new();
    for &set in &sets {
        if let Some(spec) = a.set_atoms(set) {
            let mut v = vec![0.0; spec.atoms.len()];
            a.atom_values(set, at, x, false, &mut v);
            per_set.extend(v);
        }
    }
    assert_eq!(bits(&fa), bits(&per_set), "{name}: all atoms vs set by set");
    // The jump conditions with all atoms in one evaluation: the same bits
    // as the two evaluations, and each rule's own predicate.
    let rules = a.jump_rules().len();
    let per_rule: Vec<bool> = (0..rules).map(|r| a.jump_set(r, at, x)).collect();
    for (sys, which) in [(a, "a"), (b, "b")] {
        // Filled with what they must not hold.
        let mut atoms = vec![f64::NAN; total];
        let mut inside: Vec<bool> = per_rule.iter().map(|b| !b).collect();
        assert!(sys.jump_sets_and_atoms(at, x, &mut inside, &mut atoms));
        assert_eq!(
            bits(&atoms),
            bits(&fa),
            "{name} ({which}): sets and atoms at {at}"
        );
        assert_eq!(
            inside, per_rule,
            "{name} ({which}): sets with atoms at {at}"
        );
    }
    let mut flowing = vec![f64::NAN; total];
    assert!(a.all_atom_values(at, x, true, &mut flowing));
    let mut k = 0;
    for &set in &sets {
        if let Some(spec) = a.set_atoms(set) {
            for atom in &spec.atoms {
                if atom.watched() {
                    assert_eq!(
                        bits(&[flowing[k]]),
                        bits(&[fa[k]]),
                        "{name}: flowing atom {k} at {at}"
                    );
                }
                k += 1;
            }
        }
    }
    for r in 0..a.jump_rules().len() {
        assert_eq!(a.jump_set(r, at, x), b.jump_set(r, at, x), "{name}: D_{r}");
        assert_eq!(
            bits(&[a.jump_guard(r, at, x)]),
            bits(&[b.jump_guard(r, at, x)]),
            "{name}: guard of rule {r} at {at}"
        );
        // As the engine calls it: the post-jump state starts as `x`.
        let (mut pa, mut pb) = (x.to_vec(), x.to_vec());
        a.jump_map(r, at, x, &mut SimRng::seed_from(3), &mut pa);
        b.jump_map(r, at, x, &mut SimRng::seed_from(3), &mut pb);
        assert_eq!(bits(&pa), bits(&pb), "{name}: map of rule {r} at {at}");
    }
}

/// Subsets of the outputs (what a log evaluates), natively and
/// interpreted, compute the outputs' values bit for bit at every `every`-th
/// sample of `arc`, and after every `every`-th jump from the pre-jump values
/// ([`hybsim::ir::OutputSubset::eval_after_jump`]).
fn same_output_subsets(
    name: &str,
    a: &CompiledModel,
    b: &CompiledModel,
    arc: &hybsim::arc::HybridArc,
    every: usize,
) {
    let dim = a.output_dim();
    let subsets: Vec<Vec<usize>> = vec![
        (0..dim).step_by(2).collect(),
        (1..dim).step_by(2).collect(),
        (dim.saturating_sub(1)..dim).collect(),
    ];
    let compiled: Vec<_> = subsets
        .iter()
        .map(|c| (c, [a.output_subset(c), b.output_subset(c)]))
        .collect();
    // Across each jump (the records of one simultaneous jump share their
    // pre-jump time): the post-jump values from the pre-jump ones.
    let jumps = arc.jumps();
    let mut first = 0;
    let mut groups = 0;
    while first < jumps.len() {
        let at = jumps[first].at;
        let last = first + jumps[first..].iter().take_while(|r| r.at == at).count();
        let rules: Vec<usize> = jumps[first..last].iter().map(|r| r.rule).collect();
        let (pre, post) = (&jumps[first].pre, &jumps[first].post);
        let after = hybsim::arc::HybridTime::new(at.t, at.j + 1);
        if groups % every == 0 {
            let mut all = vec![0.0; dim];
            a.outputs(after, post, &mut all);
            for (components, programs) in &compiled {
                for p in programs {
                    let mut y = vec![f64::NAN; dim];
                    p.eval(at, pre, &mut y);
                    p.eval_after_jump(&rules, after, post, &mut y);
                    for &k in components.iter() {
                        assert_eq!(
                            bits(&[y[k]]),
                            bits(&[all[k]]),
                            "{name}: output {k} of a subset after the jump of {rules:?} at {at}"
                        );
                    }
                }
            }
        }
        groups += 1;
        first = last;
    }
    for s in arc.samples().step_by(every) {
        let mut all = vec![0.0; dim];
        a.outputs(s.at, s.x, &mut all);
        for (components, programs) in &compiled {
            for p in programs {
                let mut y = vec![f64::NAN; dim];
                p.eval(s.at, s.x, &mut y);
                for &k in components.iter() {
                    assert_eq!(
                        bits(&[y[k]]),
                        bits(&[all[k]]),
                        "{name}: output {k} of a subset at {}",
                        s.at
                    );
                }
            }
        }
    }
}

/// Compiles `src` with and without machine code, runs both for at most
/// `horizon` units of t, and compares the arcs (samples, jumps,
/// termination) and, at up to `probes` samples spread over the arc, every
/// program.
pub(crate) fn assert_bit_identical(name: &str, src: &SourceFile, horizon: f64, probes: usize) {
    let (native, interpreted) = (compile(src, "on"), compile(src, "off"));
    // Every program as machine code from the start (by default each is
    // compiled when it becomes hot).
    native.compile_machine_code();
    if hybsim::ir::jit::supported() {
        assert!(
            matches!(native.jit(), JitStatus::Native { interpreted: 0, .. }),
            "{name}: {:?}",
            native.jit()
        );
    }
    assert_eq!(interpreted.jit(), JitStatus::Off);
    let mut settings = native.settings();
    settings.horizon_t = settings.horizon_t.min(horizon);
    let arc = |m: &CompiledModel| {
        let (x0, mut rng) = m.start(m.seed());
        simulate_arc(m, &x0, &settings, &mut rng).expect("simulation")
    };
    let (a, b) = (arc(&native), arc(&interpreted));
    assert_eq!(a.len(), b.len(), "{name}: samples");
    assert!(a.len() > 1, "{name}");
    let every = (a.len() / probes.max(1)).max(1);
    for (k, (sa, sb)) in a.samples().zip(b.samples()).enumerate() {
        assert_eq!(
            sa.at.t.to_bits(),
            sb.at.t.to_bits(),
            "{name}: t of sample {k}"
        );
        assert_eq!(sa.at.j, sb.at.j, "{name}: j of sample {k}");
        assert_eq!(bits(sa.x), bits(sb.x), "{name}: x of sample {k}");
        if k % every == 0 {
            same_programs(name, &native, &interpreted, sa.at, sa.x);
        }
    }
    assert_eq!(a.jumps(), b.jumps(), "{name}: jumps");
    assert_eq!(a.termination(), b.termination(), "{name}: termination");
    same_output_subsets(name, &native, &interpreted, &a, every);
    let metrics = |m: &CompiledModel| {
        let (x0, mut rng) = m.start(m.seed());
        let mut sink = m.metrics().sink();
        hybsim::engine::simulate(m, &x0, &settings, &mut rng, &mut sink).expect("simulation");
        sink.values()
    };
    assert_eq!(
        bits(&metrics(&native)),
        bits(&metrics(&interpreted)),
        "{name}: metrics"
    );
}

/// Every model of `models/`: the arcs (samples, jumps, termination) and the
/// programs along them are bit-identical with and without machine code.
#[test]
fn every_shipped_model_runs_bit_identically_as_machine_code() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models");
    let mut paths: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "hyb"))
        .collect();
    paths.sort();
    assert!(paths.len() >= 10, "models found: {paths:?}");
    for path in &paths {
        let src = SourceFile::read(path).expect("model file");
        // A few seconds of every model cover its flows, jumps and draws.
        assert_bit_identical(&path.display().to_string(), &src, 4.0, 50);
    }
}

/// Models for the language the shipped ones do not exercise: `j` in flows,
/// sets, guards, resets, outputs and metrics; `together` groups in a `for`; sets
/// made of `&&`, `||`, `!`, `if`, `==` and `!=` atoms over modes and
/// flowing states; the rounding functions; random resets; white noise.
#[test]
fn jumps_counter_groups_and_atom_sets_run_bit_identically() {
    let models = [
        (
            "j everywhere",
            "model jcount
state x = 0, y = 0, z = 0
flow { x' = 1 + 0.1 * rem(j, 3); y' = 0; z' = j } in x <= 2 + j || !(y >= 0)
jump r when x >= 1 + 0.5 * j && y != 7 { x+ = frac(0.3 * j); y+ = y + round(10 * x) + ceil(0.5 * j) }
output jo = [2 * j + 0.5, hypot(x, j), clamp(z - j, -1, 1)]
metric resets = count(r), late = mean(x + j, t >= 5), top = max(z * j)
sim { T = 20 }
",
        ),
        (
            "together fireflies",
            "model fireflies
param eps = 0.3
state tau[1] = 0.9
state tau[2] = 0.5
state tau[3] = 0.1
for i in 1..3 { flow { tau[i]' = 1 } }
together { for i in 1..3 {
    jump fire[i] when max(tau[1], max(tau[2], tau[3])) >= 1 {
        tau[i]+ = if tau[i] >= max(tau[1], max(tau[2], tau[3])) then 0 else min(1, (1 + eps) * tau[i])
    }
} }
sim { T = 12 }
",
        ),
        (
            "modes and equality atoms",
            "model modes
param lo = 18, hi = 22
state temp = 20, q = 1, k = 0, m = 0
flow { temp' = if q == 1 then 0.3 * (30 - temp) else -0.2 * temp; q' = 0; k' = 0; m' = 0 } in (q == 1 && temp <= hi) || (q != 1 && !(temp < lo))
jump off when q == 1 && temp >= hi { q+ = 0; k+ = k + 1 }
jump on when q == 0 && (temp <= lo || k > 100) { q+ = 1; k+ = k + uniform(0, 1) }
jump mark when temp == 21 && q == 1 && m <= k { m+ = m + 1 }
output e = [temp - 20, q]
sim { T = 30; priority = jumps }
",
        ),
        (
            "noise and draws",
            "model noisy
state x = normal(0, 1), tau = 0
noise w ~ wiener(1)
flow { x' = -x + 0.2 * w + 0.01 * j; tau' = 1 }
jump kick when tau >= 0.25 && (x > -10 || x < 10) { x+ = x + normal(0, 0.1); tau+ = 0 }
sim { T = 3; solver = euler_maruyama; h = 1e-3; seed = 5 }
",
        ),
    ];
    for (name, text) in models {
        let src = SourceFile::new("m.hyb", text);
        assert_bit_identical(name, &src, f64::INFINITY, 200);
    }
}

/// The random systems of the semantics reference test (flow sets and jump
/// sets of strict, non-strict and equality atoms under `&&`, `||`, `!` and
/// `if`, over modes and flowing states, both priorities).
#[test]
fn random_systems_run_bit_identically() {
    let mut rng = SimRng::seed_from(18);
    for case in 0..200 {
        let text = crate::semantics::reference::random_model(&mut rng);
        let src = SourceFile::new("r.hyb", &text);
        assert_bit_identical(&format!("case {case}:\n{text}"), &src, f64::INFINITY, 20);
    }
}

/// The model seen set by set: everything but [`HybridSystem::all_atom_values`]
/// (so the engine evaluates the sets one by one) and the sets' inputs (so
/// it evaluates every set after each jump).
struct SetBySet<'a>(&'a CompiledModel);

impl HybridSystem for SetBySet<'_> {
    fn state_dim(&self) -> usize {
        self.0.state_dim()
    }
    fn state_names(&self) -> Vec<String> {
        self.0.state_names()
    }
    fn flow_map(&self, at: HybridTime, x: &[f64], dx: &mut [f64]) {
        self.0.flow_map(at, x, dx)
    }
    fn flow_set(&self, at: HybridTime, x: &[f64]) -> bool {
        self.0.flow_set(at, x)
    }
    fn flow_guard(&self, at: HybridTime, x: &[f64]) -> Option<f64> {
        self.0.flow_guard(at, x)
    }
    fn jump_rules(&self) -> &[hybsim::engine::JumpRule] {
        self.0.jump_rules()
    }
    fn jump_set(&self, rule: usize, at: HybridTime, x: &[f64]) -> bool {
        self.0.jump_set(rule, at, x)
    }
    fn jump_guard(&self, rule: usize, at: HybridTime, x: &[f64]) -> f64 {
        self.0.jump_guard(rule, at, x)
    }
    fn jump_map(&self, rule: usize, at: HybridTime, x: &[f64], rng: &mut SimRng, xp: &mut [f64]) {
        self.0.jump_map(rule, at, x, rng, xp)
    }
    fn set_atoms(&self, set: SetRef) -> Option<hybsim::engine::SetAtoms> {
        self.0.set_atoms(set)
    }
    fn atom_values(&self, set: SetRef, at: HybridTime, x: &[f64], flowing: bool, out: &mut [f64]) {
        self.0.atom_values(set, at, x, flowing, out)
    }
    fn atom_affine(&self, set: SetRef, atom: usize) -> Option<hybsim::engine::AffineAtom> {
        self.0.atom_affine(set, atom)
    }
    fn timer_threshold(&self, set: SetRef, atom: usize, at: HybridTime, x: &[f64]) -> f64 {
        self.0.timer_threshold(set, atom, at, x)
    }
    fn atom_text(&self, set: SetRef, atom: usize) -> Option<String> {
        self.0.atom_text(set, atom)
    }
    fn flow_structure(&self) -> hybsim::engine::FlowStructure {
        self.0.flow_structure()
    }
    fn affine_coefficients(&self, at: HybridTime, x: &[f64], a: &mut [f64], b: &mut [f64]) {
        self.0.affine_coefficients(at, x, a, b)
    }
    fn noise_dim(&self) -> usize {
        self.0.noise_dim()
    }
    fn diffusion(&self, at: HybridTime, x: &[f64], g: &mut [f64]) {
        self.0.diffusion(at, x, g)
    }
}

/// The engine's checkpoints evaluate all sets of a compiled model in one
/// program, and its choice of the rule to fire all jump conditions in one
/// (shared subexpressions once), after a jump only the sets reading what it
/// writes (the others kept): the arcs are those of evaluating the sets one
/// by one and all of them at every point, bit for bit, on the shipped
/// models and the random systems.
#[test]
fn all_sets_at_once_give_the_arcs_of_set_by_set() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models");
    let mut sources: Vec<(String, SourceFile)> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "hyb"))
        .map(|p| (p.display().to_string(), SourceFile::read(&p).unwrap()))
        .collect();
    sources.sort_by(|a, b| a.0.cmp(&b.0));
    let mut rng = SimRng::seed_from(19);
    for case in 0..100 {
        let text = crate::semantics::reference::random_model(&mut rng);
        sources.push((
            format!("case {case}:\n{text}"),
            SourceFile::new("r.hyb", &text),
        ));
    }
    for (name, src) in &sources {
        let m = compile(src, "on");
        let mut settings = m.settings();
        settings.horizon_t = settings.horizon_t.min(4.0);
        let run = |sys: &dyn HybridSystem| {
            let (x0, mut rng) = m.start(m.seed());
            simulate_arc(sys, &x0, &settings, &mut rng).expect("simulation")
        };
        let (a, b) = (run(&m), run(&SetBySet(&m)));
        assert_eq!(a.len(), b.len(), "{name}: samples");
        for (k, (sa, sb)) in a.samples().zip(b.samples()).enumerate() {
            assert_eq!(sa.at.t.to_bits(), sb.at.t.to_bits(), "{name}: t of {k}");
            assert_eq!(sa.at.j, sb.at.j, "{name}: j of {k}");
            assert_eq!(bits(sa.x), bits(sb.x), "{name}: x of {k}");
        }
        assert_eq!(a.jumps(), b.jumps(), "{name}: jumps");
        assert_eq!(a.termination(), b.termination(), "{name}: termination");
    }
}

/// The rule to fire is the first enabled one, and the sets after it are not
/// evaluated: a set that cannot be evaluated there (an index out of range)
/// does not stop the run, though the model's jump conditions are evaluated
/// together (the engine then asks rule by rule). Where no earlier rule is
/// enabled, the fault stops the run with its location.
#[test]
fn a_set_after_the_enabled_rule_that_cannot_be_evaluated_is_not_an_error() {
    let text = |horizon: f64| {
        format!(
            "model order
param k = [1, 2]
state x = 0, n = 1
flow {{ x' = 1; n' = 0 }}
jump a when x >= 1 && n < 4 {{ n+ = n + 1 }}
jump c when n >= 4 {{ x+ = 0; n+ = 1 }}
jump b when k[n] >= 5 {{ n+ = 1 }}
sim {{ T = {horizon} }}
"
        )
    };
    for jit in ["on", "off"] {
        let m = compile(&SourceFile::new("order.hyb", text(3.5)), jit);
        assert_eq!(
            m.jump_rules()
                .iter()
                .map(|r| r.name.as_str())
                .collect::<Vec<_>>(),
            ["a", "c", "b"]
        );
        let (x0, mut rng) = m.start(m.seed());
        let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng).expect("no fault");
        // At t = 1, 2, 3: a, a, a (n = 2, 3, 4), then c.
        let rules: Vec<usize> = arc.jumps().iter().map(|j| j.rule).collect();
        assert_eq!(rules, [0, 0, 0, 1].repeat(3), "jit {jit}");
        assert_eq!(
            arc.termination().map(|t| &t.cause),
            Some(&hybsim::arc::TerminationCause::HorizonT)
        );
    }
    // Without `c`, the point n = 4 has no enabled rule before `b`.
    let faulty = text(3.5).replace("jump c when n >= 4", "jump c when n >= 40");
    let m = compile(&SourceFile::new("order.hyb", faulty), "on");
    let (x0, mut rng) = m.start(m.seed());
    let err = simulate_arc(&m, &x0, &m.settings(), &mut rng).unwrap_err();
    assert!(matches!(err, SimError::Fault { .. }), "{err}");
}

/// By default a program gets machine code once it has run
/// `ir::jit::TIER_UP_CALLS` times: a model fresh from the compiler has
/// none, a run compiles the programs it evaluates at every step but not
/// those it evaluates once (initial values, a rule that fires once) or
/// never (outputs no sink asks for), and its arc is the interpreter's,
/// bit for bit.
#[test]
fn programs_get_machine_code_when_they_become_hot() {
    if !hybsim::ir::jit::supported() {
        return;
    }
    let src = SourceFile::new(
        "tiers.hyb",
        "model tiers
state x = 1, n = 0
flow { x' = -sin(x) - 0.1 * x; n' = 0 }
jump once when n <= 0 && x <= 0.5 { n+ = n + 1 }
output y = x^2 + n
sim { T = 5 }
",
    );
    let (lazy, interpreted) = (compile(&src, "on"), compile(&src, "off"));
    let status = |m: &CompiledModel| match m.jit() {
        JitStatus::Native {
            compiled,
            interpreted,
            time,
        } => (compiled, interpreted, time),
        other => panic!("{other:?}"),
    };
    let (fresh, waiting, time) = status(&lazy);
    assert_eq!(time, std::time::Duration::ZERO, "nothing compiled yet");
    assert!(waiting > 0);
    let arc = |m: &CompiledModel| {
        let (x0, mut rng) = m.start(m.seed());
        simulate_arc(m, &x0, &m.settings(), &mut rng).expect("simulation")
    };
    let (a, b) = (arc(&lazy), arc(&interpreted));
    assert_eq!(a.jumps().len(), 1, "the rule fires once");
    assert!(a.len() > 10, "{} samples", a.len());
    let (hot, cold, time) = status(&lazy);
    assert!(hot > fresh, "the flow is compiled: {fresh} → {hot}");
    assert!(time > std::time::Duration::ZERO);
    assert!(
        cold >= 3,
        "initial values, the jump map and the outputs stay interpreted: {cold}"
    );
    for (sa, sb) in a.samples().zip(b.samples()) {
        assert_eq!(sa.at.t.to_bits(), sb.at.t.to_bits());
        assert_eq!(bits(sa.x), bits(sb.x), "x at {}", sa.at);
    }
    assert_eq!(a.len(), b.len());
    assert_eq!(a.jumps(), b.jumps());
    lazy.compile_machine_code();
    assert_eq!(status(&lazy).1, 0, "every program compiled now");
}

/// The compiled model counted: how often the engine asks for all jump
/// conditions, alone and with all atoms, and how often it asks again for
/// all atoms at the point of the last joint evaluation before a checkpoint
/// of a flow step (an event bracket may start at that point).
struct Counting<'a> {
    m: &'a CompiledModel,
    /// Whether the sets' inputs are given ([`HybridSystem::set_inputs`]).
    inputs: bool,
    /// Evaluations of one set after a jump.
    single: std::cell::Cell<usize>,
    joint: std::cell::Cell<usize>,
    conds: std::cell::Cell<usize>,
    again: std::cell::Cell<usize>,
    last: std::cell::RefCell<Option<(HybridTime, Vec<f64>)>>,
}

impl<'a> Counting<'a> {
    /// `m` with its counters at zero, giving its sets' inputs if `inputs`.
    fn new(m: &'a CompiledModel, inputs: bool) -> Self {
        Self {
            m,
            inputs,
            single: Default::default(),
            joint: Default::default(),
            conds: Default::default(),
            again: Default::default(),
            last: Default::default(),
        }
    }
}

impl HybridSystem for Counting<'_> {
    fn state_dim(&self) -> usize {
        self.m.state_dim()
    }
    fn state_names(&self) -> Vec<String> {
        self.m.state_names()
    }
    fn flow_map(&self, at: HybridTime, x: &[f64], dx: &mut [f64]) {
        self.m.flow_map(at, x, dx)
    }
    fn flow_set(&self, at: HybridTime, x: &[f64]) -> bool {
        self.m.flow_set(at, x)
    }
    fn flow_guard(&self, at: HybridTime, x: &[f64]) -> Option<f64> {
        self.m.flow_guard(at, x)
    }
    fn jump_rules(&self) -> &[hybsim::engine::JumpRule] {
        self.m.jump_rules()
    }
    fn jump_set(&self, rule: usize, at: HybridTime, x: &[f64]) -> bool {
        self.m.jump_set(rule, at, x)
    }
    fn jump_sets(&self, at: HybridTime, x: &[f64], inside: &mut [bool]) -> bool {
        self.conds.set(self.conds.get() + 1);
        self.m.jump_sets(at, x, inside)
    }
    fn jump_sets_and_atoms(
        &self,
        at: HybridTime,
        x: &[f64],
        inside: &mut [bool],
        atoms: &mut [f64],
    ) -> bool {
        self.joint.set(self.joint.get() + 1);
        *self.last.borrow_mut() = Some((at, x.to_vec()));
        self.m.jump_sets_and_atoms(at, x, inside, atoms)
    }
    fn set_inputs(&self, set: SetRef) -> Option<hybsim::engine::SetInputs> {
        self.m.set_inputs(set).filter(|_| self.inputs)
    }
    fn jump_set_and_atoms(
        &self,
        rule: usize,
        at: HybridTime,
        x: &[f64],
        atoms: &mut [f64],
    ) -> bool {
        self.single.set(self.single.get() + 1);
        self.m.jump_set_and_atoms(rule, at, x, atoms)
    }
    fn all_atom_values(&self, at: HybridTime, x: &[f64], flowing: bool, out: &mut [f64]) -> bool {
        let same = |(t, y): &(HybridTime, Vec<f64>)| *t == at && bits(y) == bits(x);
        if flowing {
            *self.last.borrow_mut() = None;
        } else if self.last.borrow().as_ref().is_some_and(same) {
            self.again.set(self.again.get() + 1);
        }
        self.m.all_atom_values(at, x, flowing, out)
    }
    fn jump_guard(&self, rule: usize, at: HybridTime, x: &[f64]) -> f64 {
        self.m.jump_guard(rule, at, x)
    }
    fn jump_map(&self, rule: usize, at: HybridTime, x: &[f64], rng: &mut SimRng, xp: &mut [f64]) {
        self.m.jump_map(rule, at, x, rng, xp)
    }
    fn set_atoms(&self, set: SetRef) -> Option<hybsim::engine::SetAtoms> {
        self.m.set_atoms(set)
    }
    fn atom_values(&self, set: SetRef, at: HybridTime, x: &[f64], flowing: bool, out: &mut [f64]) {
        // A checkpoint (one source: set by set).
        *self.last.borrow_mut() = None;
        self.m.atom_values(set, at, x, flowing, out)
    }
    fn atom_affine(&self, set: SetRef, atom: usize) -> Option<hybsim::engine::AffineAtom> {
        self.m.atom_affine(set, atom)
    }
    fn timer_threshold(&self, set: SetRef, atom: usize, at: HybridTime, x: &[f64]) -> f64 {
        self.m.timer_threshold(set, atom, at, x)
    }
    fn atom_text(&self, set: SetRef, atom: usize) -> Option<String> {
        self.m.atom_text(set, atom)
    }
    fn flow_structure(&self) -> hybsim::engine::FlowStructure {
        self.m.flow_structure()
    }
    fn affine_coefficients(&self, at: HybridTime, x: &[f64], a: &mut [f64], b: &mut [f64]) {
        self.m.affine_coefficients(at, x, a, b)
    }
    fn noise_dim(&self) -> usize {
        self.m.noise_dim()
    }
    fn diffusion(&self, at: HybridTime, x: &[f64], g: &mut [f64]) {
        self.m.diffusion(at, x, g)
    }
    fn take_fault(&self) -> Option<hybsim::engine::SystemFault> {
        self.m.take_fault()
    }
}

/// Where the engine chooses between flowing and jumping, the jump
/// conditions and all sets' atoms come from one evaluation, and a flow
/// segment started there does not evaluate the atoms again (each jump of
/// the bouncing ball and of the consensus model, whose noise redraws start
/// every step); the arc is the one of the separate evaluations
/// (`all_sets_at_once_give_the_arcs_of_set_by_set`).
#[test]
fn the_choice_and_the_segment_start_share_one_evaluation_of_the_sets() {
    for (model, horizon) in [("bouncing_ball", 3.0), ("consensus_estimation", 0.01)] {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("models")
            .join(format!("{model}.hyb"));
        let m = compile(&SourceFile::read(&path).unwrap(), "on");
        let mut settings = m.settings();
        settings.horizon_t = horizon;
        let sys = Counting::new(&m, false);
        let (x0, mut rng) = m.start(m.seed());
        let arc = simulate_arc(&sys, &x0, &settings, &mut rng).expect("simulation");
        let jumps = arc.jumps().len();
        assert!(jumps >= 3, "{model}: {jumps} jumps");
        assert!(
            sys.joint.get() >= jumps,
            "{model}: {} joint",
            sys.joint.get()
        );
        assert_eq!(sys.conds.get(), 0, "{model}: conditions alone");
        assert_eq!(sys.again.get(), 0, "{model}: atoms evaluated again");
    }
}

/// After a jump from a point where every set was evaluated, only the sets
/// that read what the jump writes are evaluated again (the consensus
/// model's node that fired; after the noise redraws, read by every node's
/// set, all are), with the arc of evaluating all of them.
#[test]
fn after_a_jump_only_the_sets_reading_what_it_writes_are_evaluated() {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/consensus_estimation.hyb");
    let m = compile(&SourceFile::read(&path).unwrap(), "on");
    let mut settings = m.settings();
    settings.horizon_t = 0.05;
    let run = |inputs: bool| {
        let sys = Counting::new(&m, inputs);
        let (x0, mut rng) = m.start(m.seed());
        let arc = simulate_arc(&sys, &x0, &settings, &mut rng).expect("simulation");
        (arc, sys.joint.get(), sys.single.get())
    };
    let ((a, joint_a, single_a), (b, joint_b, single_b)) = (run(false), run(true));
    let events = a.jumps().iter().filter(|jr| jr.rule != 0).count();
    assert!(events >= 10, "{events} events");
    // One set instead of all after the events found at a point where all
    // were evaluated (after a redraw; not those localized in a step).
    assert_eq!(single_a, 0);
    assert!(2 * single_b >= events, "{single_b} of {events} events");
    assert_eq!(joint_a, joint_b + single_b);
    assert_eq!(a.len(), b.len());
    for (sa, sb) in a.samples().zip(b.samples()) {
        assert_eq!(sa.at.t.to_bits(), sb.at.t.to_bits());
        assert_eq!(bits(sa.x), bits(sb.x), "x at {}", sa.at);
    }
    assert_eq!(a.jumps(), b.jumps());
}
