//! What a jump can change, for evaluations repeated on both sides of it.
//!
//! A jump keeps `t` and changes only `j` and the state components its
//! rules write. A graph node that reads none of those (nor a random draw or
//! the noise) has the same inputs on both sides, so the same instructions
//! give it the same value: an evaluation after the jump keeps it and
//! computes only the others ([`changed_nodes`]). Which nodes a rule
//! changes is analysed once the rule has jumped [`DECIDE_AFTER`] times
//! ([`Decision`]): a rule that fires a few times in a run with thousands of
//! rules costs no analysis of the graph and no compilation.
//!
//! Two evaluations use it: the logged outputs ([`super::OutputSubset`])
//! and every set's atoms with the jump conditions ([`AtomsAfterJump`], the
//! engine's choice between flowing and jumping after each jump).

use std::sync::OnceLock;
use std::sync::atomic::{AtomicU32, Ordering};

use super::program::{Frame, Program};
use super::{JacobianSource, jit, with_regs};
use crate::arc::HybridTime;
use crate::check::dag::{Dag, Node, NodeId};

/// Jumps of a set of rules after which it is analysed (see the module).
pub(crate) const DECIDE_AFTER: u32 = 16;

/// What the jumps of one set of rules evaluate, decided on the
/// [`DECIDE_AFTER`]-th.
#[derive(Debug)]
pub(super) struct Decision<T> {
    /// Jumps so far (counted up to [`DECIDE_AFTER`]).
    seen: AtomicU32,
    what: OnceLock<T>,
}

impl<T> Default for Decision<T> {
    fn default() -> Self {
        Self {
            seen: AtomicU32::new(0),
            what: OnceLock::new(),
        }
    }
}

impl<T> Decision<T> {
    /// What this jump evaluates: decided by `decide` at the
    /// [`DECIDE_AFTER`]-th jump; `None` (everything) before.
    #[inline]
    pub fn get(&self, decide: impl FnOnce() -> T) -> Option<&T> {
        if let Some(what) = self.what.get() {
            return Some(what);
        }
        self.decide(decide)
    }

    /// [`get`](Self::get) before the decision: out of line.
    #[cold]
    #[inline(never)]
    fn decide(&self, decide: impl FnOnce() -> T) -> Option<&T> {
        if self.seen.fetch_add(1, Ordering::Relaxed) + 1 < DECIDE_AFTER {
            return None;
        }
        Some(self.what.get_or_init(decide))
    }
}

/// Per node of `dag`: whether a jump that writes the state components
/// `written` (per component; one beyond its length counts as written) can
/// change its value.
pub(super) fn changed_nodes(dag: &Dag, written: &[bool]) -> Vec<bool> {
    // Nodes are created after their inputs, so one pass in id order
    // settles every node.
    let mut dirty = vec![false; dag.len()];
    for id in 0..dag.len() {
        let node = id as NodeId;
        dirty[id] = match dag.node(node) {
            Node::State(k) => written.get(k as usize).copied().unwrap_or(true),
            Node::Jumps | Node::Rand(..) | Node::Wiener(_) => true,
            _ => {
                let mut any = false;
                dag.inputs(node, |i| {
                    debug_assert!(i < node, "a node's inputs precede it");
                    any |= dirty[i as usize];
                });
                any
            }
        };
    }
    dirty
}

/// The components rule `r`'s jumps write, per component of a state of
/// dimension `n` (`None` for a rule not in `writes`).
pub(super) fn written_by(writes: &[Vec<usize>], rules: &[usize], n: usize) -> Option<Vec<bool>> {
    let mut written = vec![false; n];
    for &r in rules {
        for &k in writes.get(r)? {
            *written.get_mut(k)? = true;
        }
    }
    Some(written)
}

/// The atoms and jump conditions a jump of one rule can change, in one
/// program.
#[derive(Debug)]
pub(super) struct Changed {
    program: Program,
    /// Registers the program needs.
    nregs: usize,
    /// How many of its outputs (the first) are atoms; the others are jump
    /// conditions.
    atoms: usize,
    /// Position of each output: among all atoms, then among the rules.
    positions: Vec<usize>,
}

impl Changed {
    /// Writes the atoms and conditions it computes at (`at`, `x`) into
    /// their places in `atoms` and `inside` (`nregs`: the model's register
    /// count).
    #[inline]
    pub fn eval(
        &self,
        at: HybridTime,
        x: &[f64],
        nregs: usize,
        inside: &mut [bool],
        atoms: &mut [f64],
    ) {
        let len = self.positions.len();
        with_regs(nregs.max(self.nregs) + len, |regs| {
            let (regs, out) = regs.split_at_mut(regs.len() - len);
            self.program.run_into(regs, at, x, None, out);
            let (vals, conds) = out.split_at(self.atoms);
            let (at_atoms, at_rules) = self.positions.split_at(self.atoms);
            for (&p, &v) in at_atoms.iter().zip(vals) {
                atoms[p] = v;
            }
            for (&p, &c) in at_rules.iter().zip(conds) {
                inside[p] = c != 0.0;
            }
        });
    }
}

/// What the evaluation after a jump of one rule computes.
#[derive(Debug)]
pub(super) enum AfterJump {
    /// Nothing: the jump changes no atom and no condition.
    Nothing,
    /// What this program computes.
    Some(Box<Changed>),
    /// Everything (the program would be more than half of it).
    All,
}

/// Every set's atoms and every rule's condition after a jump of one rule
/// ([`HybridSystem::jump_sets_and_atoms_after_jump`](crate::engine::HybridSystem::jump_sets_and_atoms_after_jump)):
/// what the rule can change, by a program of its own when that is at most
/// half the size of the whole evaluation's.
#[derive(Debug)]
pub(super) struct AtomsAfterJump {
    /// Every set's atoms (in the layout of `all_atom_values`), then each
    /// rule's condition: the whole evaluation's outputs.
    nodes: Vec<NodeId>,
    /// How many of `nodes` are atoms.
    atoms: usize,
    /// Size of the whole evaluation's program.
    whole: usize,
    /// The state components each rule writes.
    writes: Vec<Vec<usize>>,
    frame: Frame,
    after_rule: Box<[Decision<AfterJump>]>,
}

impl AtomsAfterJump {
    /// For the whole evaluation `sets` (outputs: the atoms `atoms`, then
    /// the rules' conditions `conds`) of a model whose rules write
    /// `writes`.
    pub fn new(
        frame: Frame,
        sets: &Program,
        atoms: &[NodeId],
        conds: &[NodeId],
        writes: Vec<Vec<usize>>,
    ) -> Self {
        Self {
            nodes: atoms.iter().chain(conds).copied().collect(),
            atoms: atoms.len(),
            whole: sets.len(),
            after_rule: writes.iter().map(|_| Decision::default()).collect(),
            writes,
            frame,
        }
    }

    /// What the evaluation at the post-jump point of a jump of `rules`
    /// computes, from the values at its pre-jump point; `None`:
    /// everything (several rules, or one not analysed yet).
    #[inline]
    pub fn after(&self, source: &JacobianSource, rules: &[usize]) -> Option<&AfterJump> {
        let [r] = rules else {
            return None;
        };
        self.after_rule.get(*r)?.get(|| self.decide(source, *r))
    }

    /// What a jump of rule `r` evaluates.
    fn decide(&self, source: &JacobianSource, r: usize) -> AfterJump {
        let Some(written) = written_by(&self.writes, &[r], self.frame.n) else {
            return AfterJump::All;
        };
        let dirty = changed_nodes(&source.dag, &written);
        let outputs: Vec<usize> = (0..self.nodes.len())
            .filter(|&k| dirty[self.nodes[k] as usize])
            .collect();
        if outputs.is_empty() {
            return AfterJump::Nothing;
        }
        let nodes: Vec<NodeId> = outputs.iter().map(|&k| self.nodes[k]).collect();
        let program = Program::compile(&source.dag, self.frame, &nodes).into_buffer();
        if 2 * program.len() > self.whole {
            return AfterJump::All;
        }
        if let Some(jit) = &source.jit {
            jit::Jit::attach(jit, &program, true);
        }
        let atoms = outputs.partition_point(|&k| k < self.atoms);
        let positions = (outputs.iter())
            .map(|&k| if k < self.atoms { k } else { k - self.atoms })
            .collect();
        AfterJump::Some(Box::new(Changed {
            nregs: program.nregs.max(self.frame.fixed()),
            program,
            atoms,
            positions,
        }))
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::AtomsAfterJump;
    use crate::arc::HybridArc;
    use crate::engine::{HybridSystem, simulate_arc};
    use crate::ir::CompiledModel;
    use crate::lang::{self, Override};
    use crate::source::SourceFile;

    /// `model` with the evaluation after a jump of rule `r` told that the
    /// rule writes `writes(r)` instead of what it writes.
    fn with_writes(model: &CompiledModel, writes: impl Fn(usize) -> Vec<usize>) -> CompiledModel {
        let mut model = model.clone();
        let old = &model.atoms.after_jump;
        let writes = (0..old.writes.len()).map(writes).collect();
        model.atoms.after_jump = Arc::new(AtomsAfterJump::new(
            old.frame,
            &model.atoms.sets,
            &old.nodes[..old.atoms],
            &old.nodes[old.atoms..],
            writes,
        ));
        model
    }

    /// The model with every rule writing every component: every jump
    /// evaluates all atoms and conditions.
    fn whole(model: &CompiledModel) -> CompiledModel {
        let n = model.state_dim();
        with_writes(model, |_| (0..n).collect())
    }

    fn arc(model: &CompiledModel) -> HybridArc {
        let (x0, mut rng) = model.start(model.seed());
        let mut settings = model.settings();
        // A subset that misses an atom may leave a rule enabled for ever.
        settings.horizon_j = settings.horizon_j.min(5000);
        simulate_arc(model, &x0, &settings, &mut rng).unwrap()
    }

    fn compile(text: &str, sets: &[&str]) -> CompiledModel {
        let sets: Vec<Override> = sets.iter().map(|s| s.parse().unwrap()).collect();
        lang::compile(&SourceFile::new("m.hyb", text), &sets).unwrap()
    }

    /// A clock `x` whose rule `tick` sets `k`, which enables `count` at
    /// once: `count` jumps from the point where the engine chose it, and
    /// the evaluation after it starts from that one (`y` is watched, so
    /// that the engine evaluates all sets at once).
    const CHAIN: &str = "model m\n\
        state x = 0, k = 0, n = 0, y = 1\n\
        flow { x' = 1\n y' = 0.01 * y }\n\
        jump tick when x >= 1 { x+ = 0\n k+ = 1 }\n\
        jump count when k >= 1 && y <= 2 { k+ = 0\n n+ = n + 1 }\n\
        sim { T = 40; J = 1000 }\n";

    #[test]
    fn the_sets_after_a_jump_give_the_arc_of_their_whole_evaluation() {
        let consensus = include_str!("../../models/consensus_estimation.hyb");
        // 500 steps: every node's trigger fires far more often than the
        // jumps after which its rule is analysed.
        for jit in ["on", "off"] {
            let jit = format!("jit={jit}");
            for model in [
                compile(CHAIN, &[&jit]),
                compile(consensus, &["Tf=0.05", &jit]),
            ] {
                let (subsets, all) = (arc(&model), arc(&whole(&model)));
                assert!(subsets.jumps().len() > 60, "{}", subsets.jumps().len());
                assert_eq!(subsets, all, "{jit}");
            }
        }
    }

    #[test]
    fn a_subset_that_misses_an_atom_changes_the_arc() {
        let model = compile(CHAIN, &[]);
        let counts = |arc: &HybridArc| arc.jumps().iter().filter(|j| j.rule == 1).count();
        let fired = counts(&arc(&model));
        assert!(fired >= 39, "{fired}");
        // `count` said to write only `n`: after it, its atom `k >= 1` and
        // its condition keep their pre-jump values (true), so once it has
        // been analysed it fires again at once.
        let blind = with_writes(&model, |r| if r == 1 { vec![2] } else { vec![0, 1] });
        let blind = counts(&arc(&blind));
        assert!(
            blind > fired,
            "{blind} jumps of `count`, {fired} when evaluated"
        );
        // The consensus with its rules said to write nothing: a node's
        // trigger, analysed, holds again after its event.
        let consensus = include_str!("../../models/consensus_estimation.hyb");
        let model = compile(consensus, &["Tf=0.05"]);
        let jumps = arc(&model).jumps().len();
        let blind = arc(&with_writes(&model, |_| Vec::new())).jumps().len();
        assert!(blind > jumps, "{blind} jumps, {jumps} when evaluated");
    }
}
