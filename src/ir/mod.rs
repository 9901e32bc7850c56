//! The compiled model: a checked model turned into register programs that
//! implement [`HybridSystem`].
//!
//! | piece of the model | program |
//! |---|---|
//! | flow equations (f, with noise set to 0) | `flow` |
//! | diffusion g (coefficients of the white noise) | `diffusion` |
//! | flow set C and its guard | `flow_set`, `flow_guard` |
//! | rule i: D_i, its guard, G_i | `rules[i].set`, `.guard`, `.map` |
//! | initial values, outputs | `init`, `outputs` |
//! | ∂f/∂x (nonzero entries), for the implicit solver | `jacobian` (compiled on first use) |
//!
//! Each program runs on a thread-local register file sized once, so the hot
//! path (flow map, guards) neither allocates nor looks anything up by name.
//! Unless the model says `jit = off`, every program (and every property
//! predicate) is also compiled to machine code ([`jit`]), which
//! `Program::run` then executes instead of interpreting.

mod analysis;
mod describe;
mod inputs;
mod interval;
mod jacobian;
pub mod jit;
pub mod metric;
mod outputs;
mod program;
mod property;

use std::cell::RefCell;
use std::collections::HashMap;
use std::sync::{Arc, OnceLock};
use std::time::Duration;

use crate::arc::{HybridTime, Termination, TerminationCause};
use crate::check::dag::{Dag, Node, NodeId};
use crate::check::{CheckedModel, StateField};
use crate::diagnostics::Diagnostic;
use crate::engine::{
    AffineAtom, Atom, FlowStructure, GuardKind, HybridSystem, JumpRule, SetAtoms, SetInputs,
    SetRef, SimError, SimRng, SimSettings, SparsityPattern, Threshold, finite_difference_jacobian,
};
use crate::layout::{Declared, Layout, Shape};
use crate::num::Num;
use crate::source::{SourceFile, SourceMap, Span};
use interval::{Interval, IntervalRegs};
pub use outputs::OutputSubset;
use program::{Frame, Program};

thread_local! {
    static REGS: RefCell<Vec<f64>> = const { RefCell::new(Vec::new()) };
}

thread_local! {
    /// The interval register file of [`HybridSystem::atom_bounds`], its
    /// state box and its results.
    static INTERVALS: RefCell<(IntervalRegs, Vec<Interval>, Vec<Interval>)> =
        RefCell::default();
}

/// Runs `f` with a register file of at least `need` registers.
#[inline]
fn with_regs<R>(need: usize, f: impl FnOnce(&mut [f64]) -> R) -> R {
    // The cell's address from a closure small enough to be inlined, the work
    // outside it: `LocalKey::with` around the whole call was at times
    // compiled out of line (~3 % of a small model's run).
    let cell: *const RefCell<Vec<f64>> = REGS.with(std::ptr::from_ref);
    // SAFETY: a thread-local lives until its thread ends, and this call runs
    // on the thread that took the address, before returning.
    let cell = unsafe { &*cell };
    // `f` called in one place, so that it is inlined: the engine's calls of
    // a model are this and a jump into machine code.
    let (mut guard, mut private);
    let regs: &mut [f64] = match cell.try_borrow_mut() {
        Ok(regs) => {
            guard = regs;
            if guard.len() < need {
                grow(&mut guard, need);
            }
            &mut guard
        }
        // Re-entrant use (not expected): a private register file.
        Err(_) => {
            private = private_regs(need);
            &mut private
        }
    };
    f(regs)
}

/// [`Program::run_into`] with the thread's register file of `nregs`
/// registers, or without one where the program's machine code needs none
/// (no loop over long sums, no block call, no noise: most flow maps, jump
/// maps and atoms): then the call is a jump into that code.
#[inline(always)]
fn run_into(
    p: &Program,
    nregs: usize,
    at: HybridTime,
    x: &[f64],
    rng: Option<&mut SimRng>,
    out: &mut [f64],
) {
    match p.native_without_regs() {
        Some(native) => native.run_into_without_regs(x, rng, out, Program::clock(at)),
        None => run_into_with_regs(p, nregs, at, x, rng, out),
    }
}

/// [`run_into`] with the thread's register file: out of line, so that the
/// call without one needs no frame.
#[inline(never)]
fn run_into_with_regs(
    p: &Program,
    nregs: usize,
    at: HybridTime,
    x: &[f64],
    rng: Option<&mut SimRng>,
    out: &mut [f64],
) {
    with_regs(nregs, |regs| p.run_into(regs, at, x, rng, out));
}

/// A register file of `need` zeros, out of line (see [`with_regs`]).
#[cold]
#[inline(never)]
fn private_regs(need: usize) -> Vec<f64> {
    vec![0.0; need]
}

/// Grows the register file (once per thread and model size): out of line,
/// so that the calls keep a small frame.
#[cold]
#[inline(never)]
fn grow(regs: &mut Vec<f64>, need: usize) {
    regs.resize(need, 0.0);
}

/// A set compiled for the engine: its predicate, its continuous guard, and
/// its atoms (all of them; only the flowing ones) with their structure.
#[derive(Debug, Clone)]
struct SetCode {
    cond: Program,
    guard: Program,
    atoms: SetAtoms,
    all: Program,
    /// `all`'s outputs, then `cond`'s ([`HybridSystem::jump_set_and_atoms`]).
    joint: Program,
    /// What the set reads ([`HybridSystem::set_inputs`]).
    inputs: Option<SetInputs>,
    flowing: Program,
    /// Atom index of each output of `flowing`.
    flowing_idx: Vec<usize>,
    /// Source-like text of each atom (only for the flow set).
    atom_text: Vec<String>,
    /// The node of each atom.
    nodes: Vec<NodeId>,
    /// The node of the set's condition.
    cond_node: NodeId,
    /// `(atom, program)`: the threshold of each timer atom whose threshold
    /// is [`Threshold::PerSegment`].
    thresholds: Vec<(usize, Program)>,
}

impl SetCode {
    /// The code of the set `cond`; with `names` (state names), the text of
    /// each atom too, for messages.
    /// `timers[k]`: state `k` has a constant nonzero rate along every flow
    /// (its atoms `x[k] <= c`, `x[k] >= c` are timer atoms).
    fn new(
        dag: &mut Dag,
        frame: Frame,
        cond: NodeId,
        varying: &mut analysis::Varying,
        timers: &[bool],
        names: Option<&[String]>,
    ) -> Self {
        let g = analysis::guard_of(dag, cond);
        let mut ca = analysis::atoms_of(dag, cond);
        // Timer atoms written as `x − θ`, so that the engine can schedule
        // them; a θ that is not a constant is evaluated at each segment's
        // start by its own program.
        let mut thresholds = Vec::new();
        // The atoms as written, for messages.
        let written = names.map(|_| ca.atoms.clone());
        let varies = varying.of(dag);
        let timer: Vec<Option<(usize, Threshold)>> = ca
            .atoms
            .iter_mut()
            .enumerate()
            .map(|(k, a)| {
                let (cmp, node, index, threshold) =
                    analysis::timer_atom(dag, a.0, a.1, timers, varies)?;
                *a = (cmp, node);
                Some((
                    index,
                    match threshold {
                        analysis::TimerThreshold::Const(c) => Threshold::Const(c),
                        analysis::TimerThreshold::Node(n) => {
                            thresholds.push((k, n));
                            Threshold::PerSegment
                        }
                    },
                ))
            })
            .collect();
        let thresholds = thresholds
            .into_iter()
            .map(|(k, n)| (k, Program::compile(dag, frame, &[n])))
            .collect();
        let varying = varying.of(dag);
        let atoms: Vec<Atom> = ca
            .atoms
            .iter()
            .zip(timer)
            .map(|(&(cmp, n), timer)| Atom {
                cmp,
                flows: varying[n as usize],
                // The graph is hash-consed: equal functions are one node.
                g_id: Some(u64::from(n)),
                timer,
            })
            .collect();
        let nodes: Vec<NodeId> = ca.atoms.iter().map(|&(_, n)| n).collect();
        // What the engine evaluates along flows: the atoms it watches.
        let flowing_idx: Vec<usize> = (0..atoms.len()).filter(|&k| atoms[k].watched()).collect();
        let fnodes: Vec<NodeId> = flowing_idx.iter().map(|&k| nodes[k]).collect();
        let atom_text = match (names, written) {
            (Some(names), Some(written)) => written
                .iter()
                .map(|&(cmp, g)| describe::atom_text(dag, cmp, g, names))
                .collect(),
            _ => Vec::new(),
        };
        let (cond_p, guard) = (
            Program::compile(dag, frame, &[cond]),
            Program::compile(dag, frame, &[g]),
        );
        let all = Program::compile(dag, frame, &nodes).into_buffer();
        let inputs = set_inputs(frame, [&cond_p, &guard, &all]);
        let joint_nodes: Vec<NodeId> = nodes.iter().copied().chain([cond]).collect();
        SetCode {
            atom_text,
            cond: cond_p,
            guard,
            all,
            joint: Program::compile(dag, frame, &joint_nodes).into_buffer(),
            inputs,
            flowing: Program::compile(dag, frame, &fnodes).scatter_to(&flowing_idx),
            flowing_idx,
            nodes,
            cond_node: cond,
            thresholds,
            atoms: SetAtoms {
                atoms,
                expr: ca.expr,
            },
        }
    }

    /// Its programs, the one the engine evaluates most often first (the
    /// flowing atoms, at every guard check).
    fn programs(&self) -> [&Program; 5] {
        [
            &self.flowing,
            &self.guard,
            &self.cond,
            &self.all,
            &self.joint,
        ]
    }

    fn nregs(&self) -> usize {
        let thresholds = self.thresholds.iter().map(|(_, p)| p);
        (self.programs().into_iter().chain(thresholds))
            .map(|p| p.nregs)
            .max()
            .unwrap_or(0)
    }
}

/// What the programs of a set read, together; `None` if one draws.
fn set_inputs<const N: usize>(frame: Frame, programs: [&Program; N]) -> Option<SetInputs> {
    let mut inputs = SetInputs::default();
    for p in programs {
        let (states, jumps) = p.inputs(frame)?;
        inputs.states.extend(states);
        inputs.jumps |= jumps;
    }
    inputs.states.sort_unstable();
    inputs.states.dedup();
    Some(inputs)
}

/// The atoms of every set in one program (C's first, then each rule's, as
/// [`HybridSystem::all_atom_values`] lays them out), so that what several
/// sets share (the reference trajectory's `sin(0.5 t)` in the triggers of
/// five nodes) is computed once per point.
#[derive(Debug, Clone)]
struct AllAtoms {
    all: Program,
    /// The watched atoms, each written to its position in the layout.
    flowing: Program,
    /// Each jump rule's condition, in rule order (the engine's choice of
    /// the rule to fire at a point, the five triggers' shared terms once).
    conds: Program,
    /// `all`'s outputs, then `conds`': the choice and the atoms a flow
    /// segment from the point starts with, in one run.
    sets: Program,
}

impl AllAtoms {
    fn new<'a>(
        dag: &Dag,
        frame: Frame,
        sets: impl Iterator<Item = &'a SetCode>,
        rules: &[RuleCode],
    ) -> Self {
        let (mut all, mut flowing, mut flowing_pos) = (Vec::new(), Vec::new(), Vec::new());
        let conds: Vec<NodeId> = rules.iter().map(|rc| rc.set.cond_node).collect();
        let mut joint = Vec::new();
        for code in sets {
            let off = all.len();
            all.extend_from_slice(&code.nodes);
            for &k in &code.flowing_idx {
                flowing.push(code.nodes[k]);
                flowing_pos.push(off + k);
            }
        }
        joint.extend_from_slice(&all);
        joint.extend_from_slice(&conds);
        AllAtoms {
            sets: Program::compile(dag, frame, &joint).into_buffer(),
            all: Program::compile(dag, frame, &all).into_buffer(),
            flowing: Program::compile(dag, frame, &flowing).scatter_to(&flowing_pos),
            conds: Program::compile(dag, frame, &conds),
        }
    }
}

#[derive(Debug, Clone)]
struct RuleCode {
    set: SetCode,
    map: Program,
    /// State component of each output of `map`.
    targets: Vec<usize>,
    /// The assignment computing each of `targets`.
    target_spans: Vec<Span>,
    span: Span,
}

/// The exact Jacobian of the flow: a program computing its entries that
/// are not constant, and the constant ones, in the order of its pattern.
#[derive(Debug)]
struct JacobianCode {
    program: Program,
    /// Position among the pattern's values of each output of `program`.
    entries: Vec<usize>,
    /// The pattern's values with the constant ones filled in.
    constants: Vec<f64>,
}

/// The flow's Jacobian: its sparsity pattern and, where derived, its code.
#[derive(Debug)]
struct JacobianInfo {
    pattern: SparsityPattern,
    code: Option<JacobianCode>,
}

/// The model's graph, kept to derive the Jacobian on first use (only the
/// implicit solver asks for it) and to compile subsets of the outputs
/// ([`CompiledModel::output_subset`]).
#[derive(Debug)]
struct JacobianSource {
    dag: Dag,
    /// The flow (noise set to 0), one node per state.
    drift: Vec<NodeId>,
    /// One node per output component.
    outputs: Vec<NodeId>,
    /// The model's machine-code generator, if it has one (then the
    /// Jacobian's program gets machine code too).
    jit: Option<Arc<jit::Jit>>,
    info: OnceLock<Option<JacobianInfo>>,
}

impl JacobianSource {
    /// The pattern and code (`None`: the graph is too large even for the
    /// pattern; the Jacobian is then dense by finite differences).
    fn info(&self, frame: Frame) -> Option<&JacobianInfo> {
        self.info
            .get_or_init(|| {
                let n = self.drift.len();
                let mut dag = self.dag.clone();
                let d = jacobian::derivative(&mut dag, &self.drift, n)?;
                let Some(nodes) = d.nodes else {
                    return Some(JacobianInfo {
                        pattern: d.pattern,
                        code: None,
                    });
                };
                let mut constants = vec![0.0; nodes.len()];
                let mut entries = Vec::new();
                let mut outputs = Vec::new();
                for (e, &node) in nodes.iter().enumerate() {
                    match dag.as_const(node) {
                        Some(v) => constants[e] = v,
                        None => {
                            entries.push(e);
                            outputs.push(node);
                        }
                    }
                }
                let program = Program::compile(&dag, frame, &outputs).scatter_to(&entries);
                if let Some(jit) = &self.jit {
                    jit.attach(&program, true);
                }
                Some(JacobianInfo {
                    pattern: d.pattern,
                    code: Some(JacobianCode {
                        program,
                        entries,
                        constants,
                    }),
                })
            })
            .as_ref()
    }

    fn code(&self, frame: Frame) -> Option<&JacobianCode> {
        self.info(frame)?.code.as_ref()
    }
}

/// A `.hyb` model compiled for the engine. Build with
/// [`crate::lang::compile`].
#[derive(Debug, Clone)]
pub struct CompiledModel {
    name: String,
    source: SourceFile,
    /// The files the model imports (where spans beyond its text are).
    imports: SourceMap,
    frame: Frame,
    nregs: usize,
    names: Vec<String>,
    state_layout: Layout,
    output_layout: Layout,
    output_dim: usize,
    /// Each output's first component and its definition, in order.
    output_spans: Vec<(usize, Span)>,
    fields: Vec<StateField>,
    flow: Program,
    diffusion: Program,
    flow_set: Option<(SetCode, Span)>,
    rules: Vec<JumpRule>,
    rule_code: Vec<RuleCode>,
    atoms: AllAtoms,
    init: Program,
    outputs: Program,
    structure: FlowStructure,
    /// For [`FlowStructure::SwitchedAffine`]: its coefficients' program.
    mode_code: Option<ModeCode>,
    flow_spans: Vec<Option<Span>>,
    /// The `model` header's name.
    name_span: Span,
    block_spans: Vec<Span>,
    /// The files read by `table("…")`.
    tables: Vec<crate::tables::TableFile>,
    settings: SimSettings,
    /// The `sim` block's solver keys as given (for a solver chosen later).
    solver_keys: crate::check::SolverKeys,
    /// The resource limits the model was checked with.
    limits: crate::check::limits::Limits,
    seed: u64,
    params: Vec<(String, (usize, usize), Vec<f64>)>,
    inputs: Vec<crate::props::Input>,
    /// How many of `inputs` (the first ones) are random parameters.
    param_inputs: usize,
    /// Draws of the initial-value stream that belong to random parameters
    /// (skipped by `start`, see [`lang::compile_run`](crate::lang::compile_run)).
    param_draws: Vec<crate::props::Dist>,
    /// Whether a draw in an initial value or a reset (held noise's redraws
    /// too) is in the model.
    draws: bool,
    designs: Vec<crate::check::DesignReport>,
    properties: Vec<(crate::props::Property, Span)>,
    /// The properties' predicates (also held by `properties`).
    predicates: Vec<Arc<property::Eval>>,
    metrics: metric::Metrics,
    jit: Machine,
    sweep: Option<crate::check::sweep::SweepDecl>,
    log: crate::check::LogDecl,
    jacobian: Arc<JacobianSource>,
    /// Each set's atoms as affine forms of the state where they are one
    /// (C's, then each rule's), found on the first request
    /// ([`HybridSystem::atom_affine`]).
    affine_atoms: OnceLock<Vec<Vec<Option<AffineAtom>>>>,
    /// The states whose flow is identically zero ([`HybridSystem::still_states`]).
    still: Vec<usize>,
}

/// How a model's programs get machine code.
#[derive(Debug, Clone)]
enum Machine {
    /// `jit = off`.
    Off,
    /// Wanted, but this machine has no Cranelift backend.
    Unavailable(jit::JitError),
    /// Each program is compiled when it becomes hot.
    On(Arc<jit::Jit>),
}

/// Whether a compiled model runs machine code ([`CompiledModel::jit`]).
#[derive(Debug, Clone, PartialEq)]
pub enum JitStatus {
    /// The programs get machine code when they become hot
    /// ([`jit::TIER_UP_CALLS`]): so far `compiled` of them have it and
    /// `interpreted` (not run often enough yet, or beyond the JIT's size
    /// limits, see [`jit::MAX_TOTAL_OPS`]) do not.
    Native {
        /// Programs that run without the interpreter: compiled to machine
        /// code (property predicates included) or computing nothing.
        compiled: usize,
        /// Programs interpreted so far.
        interpreted: usize,
        /// Time spent generating the code so far (at compile time with
        /// [`CompiledModel::compile_machine_code`], else during runs).
        time: Duration,
    },
    /// `jit = off`: interpreted.
    Off,
    /// The JIT was wanted but could not run (unsupported machine, code
    /// generation error): interpreted (programs compiled before an error
    /// keep their code).
    Unavailable(jit::JitError),
}

fn shape(rows: usize, cols: usize) -> Shape {
    match (rows, cols) {
        (1, 1) => Shape::Scalar,
        (r, 1) => Shape::Vector(r),
        (rows, cols) => Shape::Matrix { rows, cols },
    }
}

/// The coefficients of a switched affine flow `ẋ = A(q) x + b(q)`
/// ([`FlowStructure::SwitchedAffine`]): one program computing each entry of
/// `A` and `b` that is not identically zero from the state's modes.
#[derive(Debug, Clone)]
struct ModeCode {
    program: Program,
    /// Where each output of `program` goes: `(row, column)` of `A`, column
    /// n for `b`.
    entries: Vec<(usize, usize)>,
    n: usize,
}

impl ModeCode {
    /// The coefficients' program of the flow `drift` if it is switched
    /// affine in the states that are not `still`, and the modes it reads.
    fn new(
        dag: &mut Dag,
        frame: Frame,
        drift: &[NodeId],
        still: &[bool],
    ) -> Option<(Self, Vec<usize>)> {
        let forms = analysis::affine_in_modes(dag, drift, still)?;
        let n = drift.len();
        let (mut entries, mut nodes) = (Vec::new(), Vec::new());
        for (row, l) in forms.iter().enumerate() {
            let terms = l.terms.iter().map(|&(k, c)| (k as usize, c));
            for (col, c) in terms.chain([(n, l.c)]) {
                if dag.as_const(c) != Some(0.0) {
                    entries.push((row, col));
                    nodes.push(c);
                }
            }
        }
        let reach = dag.reachable(&nodes);
        let modes: Vec<usize> = (0..n)
            .filter(|&k| still[k] && reach.get(dag.state(k) as usize) == Some(&true))
            .collect();
        // Without modes the flow would have been affine (only a fold the
        // constant analysis does not make, such as `if` on constants).
        if modes.is_empty() {
            return None;
        }
        let program = Program::compile(dag, frame, &nodes).into_buffer();
        Some((
            Self {
                program,
                entries,
                n,
            },
            modes,
        ))
    }

    /// `A` and `b` at `x` (the buffers zeroed; `at` locates a fault).
    fn fill(&self, nregs: usize, at: HybridTime, x: &[f64], a: &mut [f64], b: &mut [f64]) {
        let mut values = vec![0.0; self.entries.len()];
        run_into_with_regs(
            &self.program,
            nregs.max(self.program.nregs),
            at,
            x,
            None,
            &mut values,
        );
        for (&(row, col), v) in self.entries.iter().zip(values) {
            if col == self.n {
                b[row] = v;
            } else {
                a[row * self.n + col] = v;
            }
        }
    }
}

impl CompiledModel {
    /// Compiles a checked model (`source` is kept for diagnostics and logs).
    pub fn new(mut m: CheckedModel, source: SourceFile) -> Self {
        let draws = m.dag.has_draws();
        let frame = Frame {
            n: m.dim,
            m: m.wiener_dim,
        };
        // Flow: drift (noise = 0) and diffusion columns.
        let noisy = analysis::on_wiener(&m.dag);
        let mut memo = HashMap::new();
        let drift: Vec<_> = m
            .flow
            .iter()
            .map(|&f| analysis::substitute_wiener(&mut m.dag, f, &|_| 0.0, &noisy, &mut memo))
            .collect();
        let mut diff = Vec::with_capacity(m.dim * m.wiener_dim);
        for (i, &f) in m.flow.iter().enumerate() {
            for k in 0..m.wiener_dim as u32 {
                let mut memo = HashMap::new();
                let unit = move |j: u32| if j == k { 1.0 } else { 0.0 };
                let with = analysis::substitute_wiener(&mut m.dag, f, &unit, &noisy, &mut memo);
                diff.push(m.dag.bin(crate::check::dag::BinFn::Sub, with, drift[i]));
            }
        }
        // States whose flow is identically zero (modes, counters, held
        // values): atoms of them alone do not change along a flow.
        let still: Vec<bool> = (0..m.dim)
            .map(|k| {
                m.dag.as_const(drift[k]) == Some(0.0)
                    && diff[k * m.wiener_dim..(k + 1) * m.wiener_dim]
                        .iter()
                        .all(|&d| m.dag.as_const(d) == Some(0.0))
            })
            .collect();
        let mut mode_code = None;
        let structure = if m.wiener_dim == 0 && m.dim <= MAX_EXACT_AFFINE_DIM {
            match analysis::affine_forms(&m.dag, &drift) {
                Some(forms) => {
                    let n = m.dim;
                    let mut a = vec![0.0; n * n];
                    let mut b = vec![0.0; n];
                    for (i, l) in forms.iter().enumerate() {
                        b[i] = l.c;
                        for &(k, v) in &l.terms {
                            a[i * n + k as usize] += v;
                        }
                    }
                    FlowStructure::Affine { a, b }
                }
                None => match ModeCode::new(&mut m.dag, frame, &drift, &still) {
                    Some((code, modes)) => {
                        mode_code = Some(code);
                        FlowStructure::SwitchedAffine { modes }
                    }
                    None => FlowStructure::General,
                },
            }
        } else {
            FlowStructure::General
        };
        // States with a constant nonzero rate along every flow: timers.
        let timer_states: Vec<bool> = (0..m.dim)
            .map(|k| {
                m.dag
                    .as_const(drift[k])
                    .is_some_and(|r| r != 0.0 && r.is_finite())
                    && diff[k * m.wiener_dim..(k + 1) * m.wiener_dim]
                        .iter()
                        .all(|&d| m.dag.as_const(d) == Some(0.0))
            })
            .collect();
        let still_states: Vec<usize> = (0..m.dim).filter(|&k| still[k]).collect();
        let mut varying = analysis::Varying::new(still);
        let names = self::state_layout(&m.fields, true).flat_names(m.dim);
        let flow_set = m.flow_set.map(|(cond, span)| {
            let code = SetCode::new(
                &mut m.dag,
                frame,
                cond,
                &mut varying,
                &timer_states,
                Some(&names),
            );
            (code, span)
        });
        let mut rules = Vec::new();
        let mut rule_code = Vec::new();
        for r in &m.rules {
            let kind = match r.timer {
                // An `every` rule (or a held noise's redraw): its timer is
                // HyEQ's sampling timer, which no flow passes.
                Some((index, threshold)) => GuardKind::Timer {
                    index,
                    threshold,
                    bounds_flow: true,
                },
                None => detect_timer(&m, r.guard).unwrap_or(GuardKind::General),
            };
            rules.push(JumpRule {
                name: r.name.clone(),
                guard: kind,
                group: r.group,
                part: r.part,
                writes: r.resets.iter().map(|&(k, _)| k).collect(),
            });
            let values: Vec<_> = r.resets.iter().map(|&(_, n)| n).collect();
            let writes: Vec<usize> = r.resets.iter().map(|&(k, _)| k).collect();
            rule_code.push(RuleCode {
                set: SetCode::new(
                    &mut m.dag,
                    frame,
                    r.guard,
                    &mut varying,
                    &timer_states,
                    None,
                ),
                map: Program::compile(&m.dag, frame, &values).scatter_to(&writes),
                targets: writes,
                target_spans: r.reset_spans.clone(),
                span: r.span,
            });
        }
        let out_nodes: Vec<_> = m.outputs.iter().flat_map(|o| o.nodes.clone()).collect();
        let flow = Program::compile(&m.dag, frame, &drift).into_buffer();
        let flow_nodes = drift.clone();
        let diffusion = Program::compile(&m.dag, frame, &diff).into_buffer();
        let init = Program::compile(&m.dag, frame, &m.init);
        let outputs = Program::compile(&m.dag, frame, &out_nodes);
        let atoms = AllAtoms::new(
            &m.dag,
            frame,
            flow_set
                .iter()
                .map(|(c, _)| c)
                .chain(rule_code.iter().map(|rc| &rc.set)),
            &rule_code,
        );
        let mut nregs = [
            &flow,
            &diffusion,
            &init,
            &outputs,
            &atoms.all,
            &atoms.flowing,
            &atoms.conds,
            &atoms.sets,
        ]
        .iter()
        .map(|p| p.nregs)
        .max()
        .unwrap_or(0);
        for rc in &rule_code {
            nregs = nregs.max(rc.set.nregs()).max(rc.map.nregs);
        }
        if let Some((code, _)) = &flow_set {
            nregs = nregs.max(code.nregs());
        }
        nregs = nregs.max(frame.fixed());
        let state_layout = state_layout(&m.fields, false);
        let (output_layout, output_dim) = output_layout(&m.outputs);
        let output_spans = (m.outputs.iter())
            .scan(0, |first, o| {
                let at = *first;
                *first += o.rows * o.cols;
                Some((at, o.span))
            })
            .collect();
        let inputs = inputs::random_inputs(&m);
        let param_inputs = m.random_params.len();
        let param_draws = m.random_params.iter().map(|i| i.dist).collect();
        let jit = if m.jit.unwrap_or(true) {
            match jit::Jit::new(jit::TIER_UP_CALLS) {
                Ok(jit) => Machine::On(jit),
                Err(e) => Machine::Unavailable(e),
            }
        } else {
            Machine::Off
        };
        let generator = match &jit {
            Machine::On(jit) => Some(jit),
            _ => None,
        };
        let (properties, predicates) =
            property::compile(&m.dag, &m.properties, m.dim, &source, generator);
        let writes: Vec<Vec<usize>> = rule_code.iter().map(|rc| rc.targets.clone()).collect();
        let metrics = metric::Metrics::compile(&m.dag, &m.metrics, m.dim, &writes);
        let jacobian = Arc::new(JacobianSource {
            dag: std::mem::take(&mut m.dag),
            drift: flow_nodes,
            outputs: out_nodes,
            jit: generator.cloned(),
            info: OnceLock::new(),
        });
        let model = CompiledModel {
            name: m.name,
            source,
            imports: SourceMap::default(),
            frame,
            nregs,
            names,
            state_layout,
            output_layout,
            output_dim,
            output_spans,
            fields: m.fields,
            flow,
            diffusion,
            flow_set,
            rules,
            rule_code,
            atoms,
            init,
            outputs,
            structure,
            mode_code,
            flow_spans: m.flow_spans,
            name_span: m.name_span,
            block_spans: m.block_spans,
            tables: m.tables,
            settings: m.settings,
            solver_keys: m.solver_keys,
            limits: m.limits,
            seed: m.seed,
            params: m.params,
            inputs,
            param_inputs,
            param_draws,
            draws,
            designs: m.designs,
            properties,
            predicates,
            metrics,
            jit,
            sweep: m.sweep,
            log: m.log,
            jacobian,
            affine_atoms: OnceLock::new(),
            still: still_states,
        };
        if let Machine::On(jit) = &model.jit {
            let (programs, hot) = model.programs();
            for (k, p) in programs.into_iter().enumerate() {
                jit.attach(p, k < hot);
            }
        }
        model
    }

    /// Every program of the model (the Jacobian's and output subsets'
    /// aside), the one the engine evaluates most often first, and how many
    /// of the first get the better register allocator: those evaluated at
    /// every integrator stage (the flow, the diffusion, the atoms the
    /// engine watches at every step: all sets' at once, then each set's)
    /// and the jump conditions with all sets' atoms (at each point where
    /// the engine chooses between flowing and jumping: after every jump,
    /// so at every step of a model whose noise or sampling jumps at every
    /// step); then all sets' atoms, the sets' other programs (evaluated at
    /// event candidates and jumps), the jump conditions, outputs, metrics,
    /// initial values, jump maps and property predicates.
    fn programs(&self) -> (Vec<&Program>, usize) {
        let mut programs = vec![&self.flow, &self.diffusion, &self.atoms.flowing];
        let mut sets = Vec::new();
        let codes = self.flow_set.iter().map(|(c, _)| c);
        for code in codes.chain(self.rule_code.iter().map(|rc| &rc.set)) {
            let [flowing, rest @ ..] = code.programs();
            programs.push(flowing);
            sets.extend(rest);
        }
        programs.push(&self.atoms.sets);
        let hot = programs.len();
        programs.push(&self.atoms.all);
        programs.extend(sets);
        programs.push(&self.atoms.conds);
        programs.extend([&self.outputs, self.metrics.sample(), &self.init]);
        programs.extend(self.rule_code.iter().map(|rc| &rc.map));
        programs.extend(self.predicates.iter().map(|e| e.program()));
        (programs, hot)
    }

    /// Compiles every program to machine code now (hottest first, within
    /// [`jit::MAX_TOTAL_OPS`]) instead of when each becomes hot, and so
    /// every program compiled later (the Jacobian's, output subsets) when
    /// it is made; no effect with `jit = off`. For tests comparing machine
    /// code with the interpreter, and for measuring the JIT on a whole
    /// model.
    pub fn compile_machine_code(&self) {
        if let Machine::On(jit) = &self.jit {
            jit.compile_all(self.programs().0);
        }
    }

    /// Whether ∂f/∂x is derived symbolically (compiled on first call):
    /// false when the flow reaches a matrix block (`inv`, `solve`, `expm`,
    /// `norm2`) of the state or is too large, in which case
    /// [`HybridSystem::jacobian`] takes finite differences (the engine:
    /// on the pattern, by column groups).
    pub fn has_exact_jacobian(&self) -> bool {
        self.jacobian.code(self.frame).is_some()
    }

    /// Whether the model's programs run as machine code, how many have it
    /// so far, and how long generating it took.
    pub fn jit(&self) -> JitStatus {
        match &self.jit {
            Machine::Off => JitStatus::Off,
            Machine::Unavailable(e) => JitStatus::Unavailable(e.clone()),
            Machine::On(jit) => match jit.error() {
                Some(e) => JitStatus::Unavailable(e.clone()),
                None => {
                    let (compiled, attached) = jit.counts();
                    JitStatus::Native {
                        compiled,
                        interpreted: attached - compiled,
                        time: jit.time(),
                    }
                }
            },
        }
    }

    /// The model's name (`model NAME`).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The source it was compiled from.
    pub fn source(&self) -> &SourceFile {
        &self.source
    }

    /// Simulation settings from the `sim` block after overrides.
    pub fn settings(&self) -> SimSettings {
        self.settings.clone()
    }

    /// The `sim` block's `rtol`, `atol` and `h` as given (after overrides),
    /// also those its solver does not use: a solver chosen after the check
    /// (`--solver rk4`, Python's `solver="rk4"`) takes the model's step, or
    /// its tolerances, before the defaults.
    pub fn solver_keys(&self) -> crate::check::SolverKeys {
        self.solver_keys
    }

    /// `settings` changed after the check (run flags, Python keywords) held to the limits the
    /// model was checked with: the first size over its limit as (`sim` key, message).
    pub fn over_limit(&self, settings: &SimSettings) -> Option<(&'static str, String)> {
        use crate::check::limits::forced_sizes;
        forced_sizes(settings)
            .into_iter()
            .find_map(|(key, q, estimate)| {
                let limit = self.limits.get(q);
                (estimate > limit as f64).then(|| {
                    (
                        key,
                        format!(
                            "{estimate:.3e} {q}: over the limit of {limit}; use {}, or raise the \
                         limit (`max_{} = N` in `sim` or `--set max_{}=N`)",
                            q.remedy(),
                            q.key(),
                            q.key()
                        ),
                    )
                })
            })
    }

    /// The run's seed (`sim { seed = N }`, default 0).
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// Structure of the state vector.
    pub fn state_layout(&self) -> &Layout {
        &self.state_layout
    }

    /// Structure of the output vector.
    pub fn output_layout(&self) -> &Layout {
        &self.output_layout
    }

    /// Number of output components.
    pub fn output_dim(&self) -> usize {
        self.output_dim
    }

    /// One name per output component (`e`, `err[2]`).
    pub fn output_names(&self) -> Vec<String> {
        self.output_layout.flat_names(self.output_dim)
    }

    /// Names of the jump rules, in order.
    pub fn rule_names(&self) -> Vec<String> {
        self.rules.iter().map(|r| r.name.clone()).collect()
    }

    /// Span of rule `rule`'s declaration.
    pub fn rule_span(&self, rule: usize) -> Option<Span> {
        self.rule_code.get(rule).map(|r| r.span)
    }

    /// The flow equation of state component `k`, if it has one.
    pub fn flow_span(&self, k: usize) -> Option<Span> {
        self.flow_spans.get(k).copied().flatten()
    }

    /// Number of instructions of the flow map (for benchmarks and tests).
    pub fn flow_instructions(&self) -> usize {
        self.flow.len()
    }

    /// The inputs `hybsim test` samples and `--set name=value` pins: the
    /// random parameters ([`random_params`](Self::random_params)), then the
    /// scalar states whose initial value is a draw `uniform(lo, hi)` or
    /// `normal(mean, std)` (constant arguments), each in declaration order.
    pub fn random_inputs(&self) -> &[crate::props::Input] {
        &self.inputs
    }

    /// The random parameters (`param g ~ uniform(a, b)` or `--set
    /// g=uniform(a, b)`, not pinned), in declaration order. This model
    /// gives each its distribution's centre;
    /// [`lang::compile_run`](crate::lang::compile_run) draws them.
    pub fn random_params(&self) -> &[crate::props::Input] {
        &self.inputs[..self.param_inputs]
    }

    /// Whether a run of the model draws random numbers: random parameters,
    /// random initial values, draws in resets, noise, `priority = random`
    /// or `jump_choice = random`. Runs of a model that does not are the
    /// same for every seed.
    pub fn is_random(&self) -> bool {
        self.draws
            || !self.inputs.is_empty()
            || self.frame.m > 0
            || self.settings.priority == crate::engine::Priority::Random
            || self.settings.jump_choice == crate::engine::JumpChoice::Random
    }

    /// Marks the random parameters of the model this one was compiled from
    /// as drawn: [`start`](Self::start) skips their draws.
    pub(crate) fn set_param_draws(&mut self, draws: Vec<crate::props::Dist>) {
        self.param_draws = draws;
    }

    /// The model's `property` declarations, in order, ready for
    /// [`props::run_tests`](crate::props::run_tests) or a
    /// [`PropertySink`](crate::props::PropertySink).
    pub fn properties(&self) -> Vec<crate::props::Property> {
        self.properties.iter().map(|(p, _)| p.clone()).collect()
    }

    /// The model's `metric` declarations, compiled: a
    /// [`MetricSink`](metric::MetricSink) per run reduces it as it streams.
    pub fn metrics(&self) -> &metric::Metrics {
        &self.metrics
    }

    /// The model's `sweep { … }` block (the grid and settings `hybsim
    /// sweep` runs without `--grid`), if it has one.
    pub fn sweep(&self) -> Option<&crate::check::sweep::SweepDecl> {
        self.sweep.as_ref()
    }

    /// What `hybsim run` logs: the model's `log { … }` block, or the
    /// defaults (every state and output, every rule but the noise redraws).
    pub fn log_decl(&self) -> &crate::check::LogDecl {
        &self.log
    }

    /// Span of the declaration of property `name`.
    pub fn property_span(&self, name: &str) -> Option<Span> {
        self.properties
            .iter()
            .find(|(p, _)| p.name() == name)
            .map(|&(_, s)| s)
    }

    /// How every run of the model starts (`hybsim run`, `hybsim test`):
    /// the initial state, its random values drawn from
    /// [`props::input_stream(seed)`](crate::props::input_stream) (after
    /// one draw per random parameter: parameters come first, as in a
    /// `hybsim test` case), and the
    /// run's own generator `SimRng::seed_from(seed)` for everything drawn
    /// later (resets, noise, random priority). The two streams are separate,
    /// so pinning an initial value with `--set` changes no later draw.
    pub fn start(&self, seed: u64) -> (Vec<f64>, SimRng) {
        let mut inputs = crate::props::input_stream(seed);
        for d in &self.param_draws {
            d.sample(&mut inputs);
        }
        let x0 = self.initial_state(&mut inputs);
        (x0, SimRng::seed_from(seed))
    }

    /// Draws an initial state (random initial values use `rng`); runs use
    /// [`start`](Self::start).
    pub fn initial_state(&self, rng: &mut SimRng) -> Vec<f64> {
        let mut x0 = vec![0.0; self.frame.n];
        let zero = vec![0.0; self.frame.n];
        with_regs(self.nregs, |regs| {
            self.init
                .run_at(regs, HybridTime::new(0.0, 0), &zero, Some(rng));
            for (o, &r) in x0.iter_mut().zip(&self.init.outs) {
                *o = regs[r as usize];
            }
        });
        x0
    }

    /// Evaluates the outputs at hybrid time `at` and state `x` into `out`
    /// (length [`output_dim`](Self::output_dim)).
    pub fn outputs(&self, at: HybridTime, x: &[f64], out: &mut [f64]) {
        with_regs(self.nregs, |regs| {
            self.outputs.run_at(regs, at, x, None);
            for (o, &r) in out.iter_mut().zip(&self.outputs.outs) {
                *o = regs[r as usize];
            }
        });
    }

    /// A program computing only the output components `components`
    /// (indices into the output vector, as [`output_layout`](Self::output_layout)
    /// numbers them; indices past [`output_dim`](Self::output_dim) are
    /// ignored), as machine code when the model's programs are: a log that
    /// keeps some outputs evaluates only what those need. Its values are
    /// those of [`outputs`](Self::outputs), bit for bit.
    ///
    /// ```
    /// use hybsim::{arc::HybridTime, lang, source::SourceFile};
    /// let src = SourceFile::new("m.hyb", "model m\nstate x = 2\noutput a = x^2, b = sin(x)\n");
    /// let model = lang::compile(&src, &[]).unwrap();
    /// let mut y = [0.0; 2];
    /// model.output_subset(&[1]).eval(HybridTime::new(0.0, 0), &[2.0], &mut y);
    /// assert_eq!(y, [0.0, 2f64.sin()]);
    /// ```
    pub fn output_subset(&self, components: &[usize]) -> OutputSubset {
        let components: Vec<usize> = components
            .iter()
            .copied()
            .filter(|&k| k < self.jacobian.outputs.len())
            .collect();
        let writes = self.rules.iter().map(|r| r.writes.clone()).collect();
        OutputSubset::new(self.jacobian.clone(), self.frame, components, writes)
    }

    /// The `design` blocks' reports in source order (solver figures, results).
    pub fn design_reports(&self) -> &[crate::check::DesignReport] {
        &self.designs
    }

    /// The design reports as JSON, `{block name: report}` (the MCAP metadata
    /// `hybsim.design`); `None` without `design` blocks.
    pub fn design_json(&self) -> Option<serde_json::Value> {
        if self.designs.is_empty() {
            return None;
        }
        let blocks: serde_json::Map<String, serde_json::Value> = self
            .designs
            .iter()
            .map(|d| (d.name.clone(), d.to_json()))
            .collect();
        Some(serde_json::Value::Object(blocks))
    }

    /// The resolved value of parameter `name` (after overrides and `design`
    /// blocks) as a matrix (a scalar is 1×1, a vector a column), or `None`
    /// if the model has no such parameter.
    ///
    /// ```
    /// use hybsim::{lang, source::SourceFile};
    /// let src = SourceFile::new("m.hyb", "model m\nparam K = [1, 2; 3, 4]\nstate x = 0\n");
    /// let model = lang::compile(&src, &[]).unwrap();
    /// let k = model.parameter("K").unwrap();
    /// assert_eq!((k.nrows(), k.ncols(), k[(1, 0)]), (2, 2, 3.0));
    /// assert!(model.parameter("L").is_none());
    /// ```
    pub fn parameter(&self, name: &str) -> Option<nalgebra::DMatrix<f64>> {
        self.params
            .iter()
            .find(|(n, _, _)| n == name)
            .map(|(_, (rows, cols), vals)| nalgebra::DMatrix::from_row_slice(*rows, *cols, vals))
    }

    /// Resolved parameters as JSON: `{name: number | [..] | [[..], ..]}`.
    pub fn parameters_json(&self) -> serde_json::Value {
        let mut map = serde_json::Map::new();
        for (name, (rows, cols), vals) in &self.params {
            let v = crate::num::matrix_json(*rows, *cols, vals);
            map.insert(name.clone(), v);
        }
        serde_json::Value::Object(map)
    }

    /// A warning for a run that ended because it could neither flow nor
    /// jump (W0603): which case holds, the flow set's source with the atoms
    /// that fail there and their values, and the state; or for a run that
    /// spent its jump budget `max_total_jumps` (W0605), or one stopped by the
    /// Zeno guard with all its last jumps at one t (W0606, a discrete-time
    /// system without `J`): the rule about to fire. `None` for other endings.
    pub fn termination_diagnostic(&self, term: &Termination) -> Option<Diagnostic> {
        if let TerminationCause::ZenoSuspected {
            rule,
            rule_name,
            detail: crate::arc::ZenoDetail::TotalJumps { limit },
        } = &term.cause
        {
            // The jump budget ran out (a model chattering under the Zeno rate): say where.
            let d = Diagnostic::warning(
                "W0605",
                format!(
                    "the run stopped at {}: {limit} jumps in total, the budget \
                     `max_total_jumps`; rule `{rule_name}` was about to fire again",
                    term.at
                ),
            )
            .help(
                "if the model is meant to jump this often, raise `max_total_jumps` (or set `J`); \
                 otherwise check this rule's guard and reset",
            );
            return Some(match self.rule_span(*rule) {
                Some(span) => d.primary(span, "this rule").locate(&self.imports),
                None => d,
            });
        }
        if let TerminationCause::ZenoSuspected {
            rule,
            rule_name,
            detail: crate::arc::ZenoDetail::Rate { jumps, within },
        } = &term.cause
            && *within == 0.0
        {
            // The Zeno guard on a model that jumps without time passing (a
            // discrete-time system without `J`): say what to write.
            let d = Diagnostic::warning(
                "W0606",
                format!(
                    "the run stopped at {}: the Zeno guard saw {jumps} jumps at the same t, \
                     and rule `{rule_name}` was about to fire again",
                    term.at
                ),
            )
            .note(
                "without a jump horizon `J`, a run ends when jumps come faster than `zeno_rate` \
                 per unit of t over the last `zeno_window` jumps (LANGUAGE.md, \"Zeno guard\")",
            )
            .help(
                "a discrete-time system (one that only jumps) needs a jump horizon: `J = 100` in \
                 its `sim` block (or `--J 100`); to make it jump at one instant without `J`, \
                 `zeno_rate = inf` with a budget `max_total_jumps = N` (or `--zeno-rate inf \
                 --max-total-jumps N`)",
            )
            .note(
                "a system meant to flow here is instead chattering at one instant: each jump \
                 lands in a jump set again (guards that meet, such as `x <= 0` and `x >= 0`, or \
                 a reset that does not leave its own guard); check the guards and resets of the \
                 rules that fire at this t",
            );
            return Some(match self.rule_span(*rule) {
                Some(span) => d.primary(span, "this rule").locate(&self.imports),
                None => d,
            });
        }
        let TerminationCause::CannotFlowOrJump {
            leaving,
            failed,
            state,
            flow_from,
        } = &term.cause
        else {
            return None;
        };
        let at = term.at;
        let case = if *leaving {
            "the flow leaves the flow set C there (the state is on its boundary, the flow points out)"
        } else {
            "the state is outside the flow set C"
        };
        let mut d = Diagnostic::warning(
            "W0603",
            format!(
                "the solution can neither flow nor jump at {at}: {case}, and it is in no jump set"
            ),
        )
        .help(term.help());
        if let Some((code, span)) = &self.flow_set {
            let fails: Vec<String> = failed
                .iter()
                .map(|a| {
                    let text = code.atom_text.get(a.index).map_or("?", String::as_str);
                    format!("`{text}` fails ({:e})", a.value)
                })
                .collect();
            let label = if fails.is_empty() {
                "the flow set".to_string()
            } else {
                format!("{} at {at}", fails.join(", "))
            };
            d = d.primary(*span, label);
        }
        // A flow that left C just past the `set_tol` its atoms were relaxed
        // by started within `set_tol` of C's boundary (atoms are relaxed
        // only there; an exit across the boundary from inside fails by a
        // rounding error instead). Either it pointed out of C from that
        // start (a jump landed on the boundary where the flow leaves C):
        // the state has then barely moved; or it ran along the boundary
        // (tangent to it, as a rotation on the circle bounding C), where the
        // integrator's error alone carries it out.
        let set_tol = self.settings().set_tol;
        if *leaving
            && set_tol > 0.0
            && failed
                .iter()
                .any(|a| (set_tol..=1e3 * set_tol).contains(&a.value.abs()))
        {
            let flowed = at.t - flow_from;
            let note = if self.barely_moved(at, state, flowed, 1e3 * set_tol) {
                format!(
                    "C fails by just over `set_tol` = {}, the tolerance its atoms were relaxed by \
                     where this flow started, within `set_tol` of C's boundary, at t = {} \
                     ({} earlier): the flow points out of C there, so the solution of the exact \
                     sets ends at that point (with `set_tol = 0` it ends there); to flow on, the \
                     state must land inside C (check the jump map or initial value that put it on \
                     C's boundary) or in a jump set",
                    describe::number(set_tol),
                    describe::number(*flow_from),
                    describe::number(flowed)
                )
            } else {
                format!(
                    "C fails by just over `set_tol` = {}, the tolerance its atoms were relaxed by \
                     where this flow started, within `set_tol` of C's boundary, at t = {}: a \
                     solution running along C's boundary (a flow tangent to it) leaves C by the \
                     integrator's error; if the exact solution stays in C, tighten `rtol` and \
                     `atol` or raise `set_tol`",
                    describe::number(set_tol),
                    describe::number(*flow_from)
                )
            };
            d = d.note(note);
        }
        let names = self.state_names();
        let values: Vec<String> = state
            .iter()
            .enumerate()
            .map(|(k, v)| match names.get(k) {
                Some(n) => format!("{n} = {}", describe::number(*v)),
                None => format!("x[{k}] = {}", describe::number(*v)),
            })
            .collect();
        Some(d.note(format!("the state there: {}", values.join(", "))))
    }

    /// Whether a flow of duration `flowed` ending at `x` moved each state
    /// component by at most `tol` relative to its size (at least 1),
    /// estimated from the flow's rate at the end: a flow that left C where
    /// it started, rather than one that ran along C's boundary.
    fn barely_moved(&self, at: HybridTime, x: &[f64], flowed: f64, tol: f64) -> bool {
        if flowed.is_nan() || flowed < 0.0 || x.len() != self.state_dim() {
            return false;
        }
        let mut dx = vec![0.0; x.len()];
        self.flow_map(at, x, &mut dx);
        // A fault here (a table index) only means no estimate.
        if self.take_fault().is_some() {
            return false;
        }
        x.iter()
            .zip(&dx)
            .all(|(v, r)| flowed * r.abs() <= tol * v.abs().max(1.0))
    }

    /// A diagnostic for a simulation error that points into the model: the
    /// flow equation of a component that became non-finite (or the jump
    /// whose map made it so), the flow equation of the fastest-changing
    /// component when the integrator gave up (step-size collapse,
    /// stiffness), or the matrix operation that failed, with the hybrid
    /// time.
    pub fn runtime_diagnostic(&self, err: &SimError) -> Diagnostic {
        self.runtime_diagnostic_here(err).locate(&self.imports)
    }

    /// The files the model read with `table("…")`: path and SHA-256.
    pub fn table_files(&self) -> &[crate::tables::TableFile] {
        &self.tables
    }

    /// The files the model imports (see [`crate::imports`]).
    pub fn imports(&self) -> &SourceMap {
        &self.imports
    }

    /// The model with the map of the files it imports, so that run-time
    /// diagnostics point into them.
    #[must_use]
    pub fn with_imports(mut self, imports: SourceMap) -> Self {
        self.imports = imports;
        self
    }

    /// The diagnostic of a run stopped because output component `k` had
    /// the non-finite `value` at `at` (a log that holds finite numbers only
    /// stopped it): E0602 at the output's definition.
    pub fn non_finite_output_diagnostic(&self, k: usize, value: f64, at: HybridTime) -> Diagnostic {
        let name = self.output_names().get(k).cloned().unwrap_or_default();
        let d = Diagnostic::error(
            "E0602",
            format!("output `{name}` is not finite ({value}) at {at}"),
        )
        .help(
            "the MCAP log holds finite numbers only: check the output's definition there, \
             or log without it (`--log-vars`)",
        );
        // The last output starting at or before k defines it.
        let span = self
            .output_spans
            .iter()
            .rev()
            .find(|(first, _)| *first <= k);
        match span {
            Some(&(_, span)) => d
                .primary(
                    span,
                    format!("not finite at (t, j) = ({}, {})", Num(at.t), at.j),
                )
                .locate(&self.imports),
            None => d,
        }
    }

    fn runtime_diagnostic_here(&self, err: &SimError) -> Diagnostic {
        let mut d = Diagnostic::error("E0601", err.to_string()).help(err.help());
        if self.state_dim() == 0 {
            // Only a model of `design` blocks passes the checker without
            // states (for `hybsim design`).
            return d.primary(
                self.name_span,
                "this model has no state to simulate; its `design` blocks run with `hybsim design`",
            );
        }
        if let SimError::Fault { at, site, .. } = err {
            d.code = "E0604";
            if let Some(&span) = self.block_spans.get(*site) {
                d = d.primary(
                    span,
                    format!("evaluated here at (t, j) = ({}, {})", Num(at.t), at.j),
                );
            }
            return d;
        }
        if let Some(origin) = program::take_fault()
            && let Some(&span) = self.block_spans.get(origin as usize)
        {
            d = d.primary(span, "this matrix was singular during the run");
        }
        if let SimError::NonFinite {
            component,
            at,
            rule: Some(rule),
            ..
        } = err
            && let Some(code) = self.rule_code.get(*rule)
        {
            // The jump map made it non-finite: point at the assignment that computed it, and at
            // the rule.
            d.code = "E0602";
            let name = self
                .state_names()
                .get(*component)
                .cloned()
                .unwrap_or_default();
            let assignment = (code.targets.iter().position(|k| k == component))
                .and_then(|i| code.target_spans.get(i).copied());
            let (span, what) = match assignment {
                Some(span) => (span, "assignment"),
                None => (code.span, "jump"),
            };
            let label = format!(
                "this {what} made `{name}` non-finite in the jump at (t, j) = ({}, {})",
                Num(at.t),
                at.j
            );
            d = if d.labels.is_empty() {
                d.primary(span, label)
            } else {
                d.secondary(span, label)
            };
            if assignment.is_some() {
                d = d.secondary(code.span, "in this jump");
            }
            return d;
        }
        let located = match err {
            SimError::StepSizeCollapse {
                component,
                at,
                name,
                ..
            } => Some((component, "changes fastest", at, name)),
            SimError::Stiff {
                component,
                at,
                name,
                ..
            } => Some((component, "is moved most by the stiff mode", at, name)),
            SimError::Chatter {
                component,
                at,
                name,
                ..
            } => Some((component, "has a rate that keeps changing sign", at, name)),
            SimError::Discontinuous {
                component,
                at,
                name,
                ..
            } => Some((component, "has a rate that jumps", at, name)),
            _ => None,
        };
        if let Some((component, how, at, name)) = located {
            let label = format!("`{name}` {how} here at (t, j) = ({}, {})", Num(at.t), at.j);
            let span = self
                .flow_span(*component)
                .or_else(|| self.field_of(*component).map(|f| f.span));
            if let Some(span) = span {
                return if d.labels.is_empty() {
                    d.primary(span, label)
                } else {
                    d.secondary(span, label)
                };
            }
        }
        if let SimError::NonFinite { component, at, .. } = err {
            d.code = "E0602";
            if let Some(span) = self.flow_span(*component) {
                let label = format!("became non-finite at (t, j) = ({}, {})", Num(at.t), at.j);
                d = if d.labels.is_empty() {
                    d.primary(span, label)
                } else {
                    d.secondary(span, label)
                };
            } else if let Some(f) = self.field_of(*component) {
                d = d.primary(f.span, "this state became non-finite");
            }
        }
        d
    }

    /// The state field holding component `k`.
    fn field_of(&self, k: usize) -> Option<&StateField> {
        self.fields
            .iter()
            .find(|f| k >= f.offset && k < f.offset + f.rows * f.cols)
    }

    /// The compiled code of a set (`None`: C is the whole space).
    fn set_code(&self, set: SetRef) -> Option<&SetCode> {
        match set {
            SetRef::Flow => self.flow_set.as_ref().map(|(c, _)| c),
            SetRef::Jump(r) => self.rule_code.get(r).map(|c| &c.set),
        }
    }

    /// The affine forms of all sets' atoms, in one pass over the graph.
    fn affine_atoms(&self) -> &[Vec<Option<AffineAtom>>] {
        self.affine_atoms.get_or_init(|| {
            let sets: Vec<&SetCode> = (self.flow_set.iter().map(|(c, _)| c))
                .chain(self.rule_code.iter().map(|c| &c.set))
                .collect();
            let nodes: Vec<NodeId> = sets.iter().flat_map(|c| c.nodes.iter().copied()).collect();
            let mut forms =
                analysis::affine_in(&self.jacobian.dag, &nodes, analysis::Vars::State).into_iter();
            sets.iter()
                .map(|c| {
                    (forms.by_ref().take(c.nodes.len()))
                        .map(|form| {
                            // A non-finite coefficient (`x <= -1/0`) gives
                            // no usable form.
                            let finite = |l: &analysis::Lin| {
                                l.c.is_finite() && l.terms.iter().all(|t| t.1.is_finite())
                            };
                            form.filter(finite).map(|l| AffineAtom {
                                terms: l.terms.iter().map(|&(k, c)| (k as usize, c)).collect(),
                                constant: l.c,
                            })
                        })
                        .collect()
                })
                .collect()
        })
    }

    #[inline]
    fn scalar(&self, p: &Program, at: HybridTime, x: &[f64]) -> f64 {
        with_regs(self.nregs, |regs| {
            p.run_at(regs, at, x, None);
            regs[p.outs[0] as usize]
        })
    }
}

/// The layout of the state fields (`generated: false` leaves out the
/// timers the language adds for `every` and `noise`, which the logs do not
/// show): plain fields, and one `Family` entry per state family.
fn state_layout(fields: &[StateField], generated: bool) -> Layout {
    Layout::from_declared(
        fields
            .iter()
            .filter(|f| generated || !f.generated)
            .map(|f| Declared {
                name: &f.name,
                shape: shape(f.rows, f.cols),
                offset: f.offset,
                family: f.family.as_ref().map(|(n, l)| (n.as_str(), l.as_str())),
            }),
    )
}

/// The layout of the outputs (families grouped like state families) and
/// their total dimension.
fn output_layout(outputs: &[crate::check::OutputField]) -> (Layout, usize) {
    let mut off = 0;
    let declared: Vec<Declared> = outputs
        .iter()
        .map(|o| {
            let d = Declared {
                name: &o.name,
                shape: shape(o.rows, o.cols),
                offset: off,
                family: o.family.as_ref().map(|(n, l)| (n.as_str(), l.as_str())),
            };
            off += o.rows * o.cols;
            d
        })
        .collect();
    (Layout::from_declared(declared), off)
}

/// Errors of a checked model that need the IR's analyses: flow equations
/// in which white noise does not enter affinely (the diffusion is computed
/// as f(x, e_k) − f(x, 0), which is only right for `f(x) + G(x) w`).
pub fn structural_errors(m: &CheckedModel) -> Vec<crate::check::CheckError> {
    let mut errors = if m.wiener_dim == 0 {
        non_finite_flows(m)
    } else {
        flow_equation_errors(
            m,
            analysis::Vars::Wiener,
            |form| form.is_none(),
            |target, span| crate::check::CheckError::NoiseNotAffine { target, span },
        )
    };
    errors.extend(nan_conditions(m));
    errors
}

/// Sets (the flow set, each rule's jump set) whose condition reads a NaN constant (a parameter
/// `0/0`, `inf - inf`): a comparison with NaN never holds, so such a set would silently be
/// empty. `inf` is allowed (`x >= inf` is a rule that never fires, on purpose).
fn nan_conditions(m: &CheckedModel) -> Vec<crate::check::CheckError> {
    let is_nan = |n: Node| matches!(n, Node::Const(b) if f64::from_bits(b).is_nan());
    let sets: Vec<(NodeId, Span, String)> = m
        .flow_set
        .iter()
        .map(|&(cond, span)| (cond, span, "the flow set".to_string()))
        .chain(
            m.rules
                .iter()
                .map(|r| (r.guard, r.span, format!("the jump set of `{}`", r.name))),
        )
        .collect();
    // One pass over all conditions; the sets one by one only when one of them has a NaN.
    let roots: Vec<NodeId> = sets.iter().map(|s| s.0).collect();
    if !m.dag.any_reachable(&roots, is_nan) {
        return Vec::new();
    }
    sets.into_iter()
        .filter(|(cond, ..)| m.dag.any_reachable(&[*cond], is_nan))
        .map(|(_, span, set)| crate::check::CheckError::NanCondition { set, span })
        .collect()
}

/// Flow equations affine in the state with a coefficient or constant that is not finite
/// (`x' = (1/0)*x`, a parameter that overflowed): located here, before the engine would reject
/// the flow as a whole.
fn non_finite_flows(m: &CheckedModel) -> Vec<crate::check::CheckError> {
    flow_equation_errors(
        m,
        analysis::Vars::State,
        |form| {
            form.is_some_and(|f| !(f.c.is_finite() && f.terms.iter().all(|(_, v)| v.is_finite())))
        },
        |target, span| crate::check::CheckError::NonFiniteFlow { target, span },
    )
}

/// One error per flow equation (a vector equation covers many components) with a component
/// whose affine form in `vars` is `bad`, made by `error` from the equation's target (`x'`) and span.
fn flow_equation_errors(
    m: &CheckedModel,
    vars: analysis::Vars,
    bad: impl Fn(Option<&analysis::Lin>) -> bool,
    error: impl Fn(String, crate::source::Span) -> crate::check::CheckError,
) -> Vec<crate::check::CheckError> {
    let forms = analysis::affine_in(&m.dag, &m.flow, vars);
    let mut seen = Vec::new();
    let mut errors = Vec::new();
    for (k, form) in forms.iter().enumerate() {
        if !bad(form.as_ref()) {
            continue;
        }
        let Some(span) = m.flow_spans[k] else {
            continue;
        };
        if seen.contains(&span) {
            continue;
        }
        seen.push(span);
        let field = m
            .fields
            .iter()
            .find(|f| k >= f.offset && k < f.offset + f.rows * f.cols);
        errors.push(error(
            format!("{}'", field.map_or("x", |f| f.name.as_str())),
            span,
        ));
    }
    errors
}

/// Largest state dimension whose affine flow is handed to the engine as a dense n×n matrix for
/// exact propagation: above it the matrix alone is tens of MB and its exponential minutes of
/// work, while the compiled flow costs O(nonzeros) per evaluation; such flows are integrated.
pub const MAX_EXACT_AFFINE_DIM: usize = 2000;

/// A `when` rule whose condition is `x[k] >= c` (or `<=`) for a state with
/// constant rate in the right direction is a timer.
fn detect_timer(m: &CheckedModel, cond: crate::check::dag::NodeId) -> Option<GuardKind> {
    use crate::check::dag::BinFn;
    let Node::Bin(f, a, b) = m.dag.node(cond) else {
        return None;
    };
    let Node::State(k) = m.dag.node(a) else {
        return None;
    };
    let threshold = m.dag.as_const(b)?;
    let rate = m.dag.as_const(*m.flow.get(k as usize)?)?;
    // Only non-strict comparisons: the timer is set exactly on its
    // threshold, where a strict one does not hold yet.
    let ok = match f {
        BinFn::Ge => rate > 0.0,
        BinFn::Le => rate < 0.0,
        _ => false,
    };
    // A non-finite threshold (`tau >= inf`) is not a timer the engine can schedule: such a
    // guard is evaluated as written (a NaN one is refused by the check, E0515).
    // The model's C is what it says: a timer it does not bound may be passed.
    (ok && m.wiener_dim == 0 && threshold.is_finite()).then_some(GuardKind::Timer {
        index: k as usize,
        threshold,
        bounds_flow: false,
    })
}

/// The engine's fault of a run-time index failure (into a table or another
/// constant vector or matrix).
#[cold]
fn index_fault(f: program::IndexFault) -> crate::engine::SystemFault {
    let show = |v: f64| describe::number(v);
    let why = |i: f64, n: usize| {
        if i.fract() == 0.0 {
            format!("{} is out of range 1..{n}", show(i))
        } else {
            format!("{} is not an integer", show(i))
        }
    };
    let ok = |i: f64, n: usize| i >= 1.0 && i <= n as f64 && i.fract() == 0.0;
    // The indexed constant is a `table("…")` or any constant vector or
    // matrix (`param d = [0.1; 0.2]`): named by its shape, as E0401 does
    // at compile time, not called a table.
    let what = if f.cols == 1 && f.bad.col == 1.0 {
        format!("index {}", why(f.bad.row, f.rows))
    } else if !ok(f.bad.row, f.rows) {
        format!(
            "row index {} ({}×{} matrix)",
            why(f.bad.row, f.rows),
            f.rows,
            f.cols
        )
    } else {
        format!(
            "column index {} ({}×{} matrix)",
            why(f.bad.col, f.cols),
            f.rows,
            f.cols
        )
    };
    crate::engine::SystemFault {
        at: HybridTime::new(f.t, f.j as u64),
        site: f.origin as usize,
        what,
    }
}

impl HybridSystem for CompiledModel {
    fn state_dim(&self) -> usize {
        self.frame.n
    }

    fn state_names(&self) -> Vec<String> {
        self.names.clone()
    }

    fn flow_map(&self, at: HybridTime, x: &[f64], dx: &mut [f64]) {
        run_into(&self.flow, self.nregs, at, x, None, dx);
    }

    /// The symbolic Jacobian (see [`CompiledModel::has_exact_jacobian`]),
    /// or finite differences.
    fn jacobian(&self, at: HybridTime, x: &[f64], jac: &mut [f64]) {
        let Some(info) = self.jacobian.info(self.frame) else {
            finite_difference_jacobian(self, at, x, jac);
            return;
        };
        let Some(code) = &info.code else {
            finite_difference_jacobian(self, at, x, jac);
            return;
        };
        let n = info.pattern.n();
        jac.fill(0.0);
        for ((r, c), &v) in info.pattern.entries().zip(&code.constants) {
            jac[r * n + c] = v;
        }
        let (rows, ptr) = (info.pattern.row_idx(), info.pattern.col_ptr());
        with_regs(self.nregs.max(code.program.nregs), |regs| {
            code.program.run_at(regs, at, x, None);
            for (&e, &reg) in code.entries.iter().zip(&code.program.outs) {
                // The entry's column: the last pointer at or before it.
                let c = ptr.partition_point(|&p| p <= e) - 1;
                jac[rows[e] * n + c] = regs[reg as usize];
            }
        });
    }

    /// The structural pattern of ∂f/∂x from the flow's expression graph
    /// (which states reach which flow equations through differentiable
    /// operations; `None` only for graphs too large to analyze).
    fn jacobian_pattern(&self) -> Option<SparsityPattern> {
        self.jacobian
            .info(self.frame)
            .map(|info| info.pattern.clone())
    }

    /// The symbolic Jacobian's entries, or `false` (finite differences on
    /// the pattern) where it has none.
    fn jacobian_values(&self, at: HybridTime, x: &[f64], values: &mut [f64]) -> bool {
        let Some(code) = self.jacobian.code(self.frame) else {
            return false;
        };
        values.copy_from_slice(&code.constants);
        let nregs = self.nregs.max(code.program.nregs);
        run_into(&code.program, nregs, at, x, None, values);
        true
    }

    #[inline]
    fn flow_set(&self, at: HybridTime, x: &[f64]) -> bool {
        match &self.flow_set {
            Some((code, _)) => self.scalar(&code.cond, at, x) != 0.0,
            None => true,
        }
    }

    fn flow_guard(&self, at: HybridTime, x: &[f64]) -> Option<f64> {
        self.flow_set
            .as_ref()
            .map(|(code, _)| self.scalar(&code.guard, at, x))
    }

    fn set_atoms(&self, set: SetRef) -> Option<SetAtoms> {
        self.set_code(set).map(|c| c.atoms.clone())
    }

    fn atom_text(&self, set: SetRef, atom: usize) -> Option<String> {
        self.set_code(set)?.atom_text.get(atom).cloned()
    }

    fn timer_threshold(&self, set: SetRef, atom: usize, at: HybridTime, x: &[f64]) -> f64 {
        let code = self
            .set_code(set)
            .and_then(|c| c.thresholds.iter().find(|t| t.0 == atom));
        code.map_or(f64::NAN, |(_, p)| self.scalar(p, at, x))
    }

    fn atom_affine(&self, set: SetRef, atom: usize) -> Option<AffineAtom> {
        let index = match set {
            SetRef::Flow => self.flow_set.as_ref().map(|_| 0)?,
            SetRef::Jump(r) => r + usize::from(self.flow_set.is_some()),
        };
        self.affine_atoms().get(index)?.get(atom)?.clone()
    }

    fn atom_values(
        &self,
        set: SetRef,
        at: HybridTime,
        x: &[f64],
        flowing_only: bool,
        out: &mut [f64],
    ) {
        let Some(code) = self.set_code(set) else {
            return;
        };
        let p = if flowing_only {
            &code.flowing
        } else {
            &code.all
        };
        run_into(p, self.nregs, at, x, None, out);
    }

    fn all_atom_values(
        &self,
        at: HybridTime,
        x: &[f64],
        flowing_only: bool,
        out: &mut [f64],
    ) -> bool {
        let atoms = &self.atoms;
        let p = if flowing_only {
            &atoms.flowing
        } else {
            &atoms.all
        };
        run_into(p, self.nregs, at, x, None, out);
        true
    }

    fn atom_bounds(&self, t: (f64, f64), j: u64, x: &[(f64, f64)], out: &mut [(f64, f64)]) -> bool {
        let p = &self.atoms.flowing;
        INTERVALS.with(|cell| {
            let Ok(mut cell) = cell.try_borrow_mut() else {
                return false;
            };
            let (file, xs, bounds) = &mut *cell;
            xs.clear();
            xs.extend(x.iter().map(|&(lo, hi)| Interval::new(lo, hi, false)));
            bounds.clear();
            bounds.resize(out.len(), Interval::ENTIRE);
            p.bound_into(file, Interval::new(t.0, t.1, false), j as f64, xs, bounds);
            for (o, b) in out.iter_mut().zip(bounds.iter()) {
                *o = if b.nan {
                    (f64::NEG_INFINITY, f64::INFINITY)
                } else {
                    (b.lo, b.hi)
                };
            }
            true
        })
    }

    fn atom_bound_inputs(&self) -> Option<Vec<usize>> {
        Some(self.atoms.flowing.state_reads())
    }

    fn still_states(&self) -> Vec<usize> {
        self.still.clone()
    }

    fn jump_sets(&self, at: HybridTime, x: &[f64], inside: &mut [bool]) -> bool {
        let conds = &self.atoms.conds;
        // One rule too: as cheap as its own program, and the engine then
        // makes one call instead of two.
        if conds.outs.is_empty() {
            return false;
        }
        with_regs(self.nregs, |regs| {
            conds.run_at(regs, at, x, None);
            for (b, &r) in inside.iter_mut().zip(&conds.outs) {
                *b = regs[r as usize] != 0.0;
            }
        });
        true
    }

    fn jump_sets_and_atoms(
        &self,
        at: HybridTime,
        x: &[f64],
        inside: &mut [bool],
        atoms: &mut [f64],
    ) -> bool {
        let p = &self.atoms.sets;
        // The outputs written in place after the registers (machine code
        // stores each once), the atoms then copied in one piece.
        let len = p.outs.len();
        with_regs(self.nregs + len, |regs| {
            let (regs, out) = regs.split_at_mut(self.nregs);
            let out = &mut out[..len];
            p.run_into(regs, at, x, None, out);
            let (vals, conds) = out.split_at(len - inside.len());
            let k = atoms.len().min(vals.len());
            atoms[..k].copy_from_slice(&vals[..k]);
            for (b, &c) in inside.iter_mut().zip(conds) {
                *b = c != 0.0;
            }
        });
        true
    }

    fn set_inputs(&self, set: SetRef) -> Option<SetInputs> {
        self.set_code(set)?.inputs.clone()
    }

    fn jump_set_and_atoms(
        &self,
        rule: usize,
        at: HybridTime,
        x: &[f64],
        atoms: &mut [f64],
    ) -> bool {
        let p = &self.rule_code[rule].set.joint;
        // As `jump_sets_and_atoms`: the outputs in place after the registers.
        let len = p.outs.len();
        with_regs(self.nregs + len, |regs| {
            let (regs, out) = regs.split_at_mut(self.nregs);
            let out = &mut out[..len];
            p.run_into(regs, at, x, None, out);
            let (vals, cond) = out.split_at(len - 1);
            atoms.copy_from_slice(vals);
            cond[0] != 0.0
        })
    }

    #[inline]
    fn take_fault(&self) -> Option<crate::engine::SystemFault> {
        // Polled after every segment and jump map: the usual answer, none,
        // without the frame of the description.
        program::take_index_fault().map(index_fault)
    }

    fn jump_rules(&self) -> &[JumpRule] {
        &self.rules
    }

    fn jump_set(&self, rule: usize, at: HybridTime, x: &[f64]) -> bool {
        self.scalar(&self.rule_code[rule].set.cond, at, x) != 0.0
    }

    fn jump_guard(&self, rule: usize, at: HybridTime, x: &[f64]) -> f64 {
        self.scalar(&self.rule_code[rule].set.guard, at, x)
    }

    fn jump_map(
        &self,
        rule: usize,
        at: HybridTime,
        x: &[f64],
        rng: &mut SimRng,
        x_plus: &mut [f64],
    ) {
        let code = &self.rule_code[rule];
        // `x_plus` holds `x` (the engine's contract): only the targets.
        run_into(&code.map, self.nregs, at, x, Some(rng), x_plus);
    }

    fn flow_structure(&self) -> FlowStructure {
        self.structure.clone()
    }

    fn affine_coefficients(&self, at: HybridTime, x: &[f64], a: &mut [f64], b: &mut [f64]) {
        if let Some(code) = &self.mode_code {
            code.fill(self.nregs, at, x, a, b);
        }
    }

    fn noise_dim(&self) -> usize {
        self.frame.m
    }

    fn diffusion(&self, at: HybridTime, x: &[f64], g: &mut [f64]) {
        run_into(&self.diffusion, self.nregs, at, x, None, g);
    }
}
