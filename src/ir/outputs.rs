//! Some of a model's output components compiled on their own
//! ([`OutputSubset`]), and re-evaluated after a jump only where the jump can
//! change them.
//!
//! A log writes the outputs at the pre-jump and at the post-jump sample of
//! every logged jump. Both samples are at the same `t`; the jump changes
//! only the components its rules write and the counter `j`. An output
//! component that reads none of those (nor a random draw) has the same
//! inputs on both sides, so the same instructions give the same value: the
//! post-jump sample keeps it and evaluates only the others, with a program
//! compiled for the rules that fired when that program is at most half the
//! size of the whole subset's (a smaller saving does not repay its
//! compilation). A set of rules is analysed once it has jumped
//! [`DECIDE_AFTER`] times (until then every component is evaluated): a
//! rule that fires a few times in a run with thousands of rules costs no
//! analysis of the graph and no compilation.

use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex, OnceLock};

use super::program::{Frame, Program};
use super::{JacobianSource, jit, with_regs};
use crate::arc::{HybridTime, OutputMap};
use crate::check::dag::{Node, NodeId};

/// Most sets of two or more simultaneously firing rules whose post-jump
/// evaluation a subset keeps; jumps of other sets evaluate every component
/// (a model whose rules fire in many combinations would pay a compilation
/// for each).
const MAX_JUMP_SETS: usize = 64;

/// Jumps of a set of rules after which it is analysed (see the module).
pub(crate) const DECIDE_AFTER: u32 = 16;

/// A set of simultaneously firing rules (sorted) and its decision.
type RuleSet = (Box<[usize]>, Arc<Decision>);

/// What the jumps of one set of rules evaluate, once decided.
#[derive(Debug, Default)]
struct Decision {
    /// Jumps so far (counted up to [`DECIDE_AFTER`]).
    seen: AtomicU32,
    what: OnceLock<AfterJump>,
}

impl Decision {
    /// What this jump evaluates: decided by `decide` at the
    /// [`DECIDE_AFTER`]-th jump, everything before.
    fn get(&self, decide: impl FnOnce() -> AfterJump) -> AfterJump {
        if let Some(what) = self.what.get() {
            return what.clone();
        }
        if self.seen.fetch_add(1, Ordering::Relaxed) + 1 < DECIDE_AFTER {
            return AfterJump::All;
        }
        self.what.get_or_init(decide).clone()
    }
}

/// Output components computed by one program.
#[derive(Debug)]
struct Code {
    program: Program,
    /// The output components computed, in the program's output order.
    components: Vec<usize>,
    nregs: usize,
}

impl Code {
    fn new(source: &JacobianSource, frame: Frame, components: Vec<usize>) -> Self {
        let nodes: Vec<NodeId> = components.iter().map(|&k| source.outputs[k]).collect();
        let program = Program::compile(&source.dag, frame, &nodes);
        Self {
            nregs: program.nregs.max(frame.fixed()),
            program,
            components,
        }
    }

    /// Gives the program machine code when it becomes hot (it runs at
    /// logged samples), if the model's programs get machine code.
    fn attach(&self, source: &JacobianSource) {
        if let Some(jit) = &source.jit {
            jit::Jit::attach(jit, &self.program, true);
        }
    }

    fn eval(&self, at: HybridTime, x: &[f64], out: &mut [f64]) {
        with_regs(self.nregs, |regs| {
            self.program.run_at(regs, at, x, None);
            for (&k, &r) in self.components.iter().zip(&self.program.outs) {
                out[k] = regs[r as usize];
            }
        });
    }
}

/// What a post-jump sample evaluates.
#[derive(Debug, Clone)]
enum AfterJump {
    /// Nothing: the jump changes no component of the subset.
    Nothing,
    /// The components of this program.
    Some(Arc<Code>),
    /// Every component.
    All,
}

/// Some of a model's output components, compiled on their own
/// ([`super::CompiledModel::output_subset`]).
#[derive(Debug)]
pub struct OutputSubset {
    all: Code,
    source: Arc<JacobianSource>,
    frame: Frame,
    /// The state components each jump rule writes.
    writes: Vec<Vec<usize>>,
    /// What a jump of one rule evaluates, by rule.
    after_rule: Box<[Decision]>,
    /// The same for simultaneous jumps, by set of rules (sorted).
    after_rules: Mutex<Vec<RuleSet>>,
}

impl OutputSubset {
    pub(super) fn new(
        source: Arc<JacobianSource>,
        frame: Frame,
        components: Vec<usize>,
        writes: Vec<Vec<usize>>,
    ) -> Self {
        let all = Code::new(&source, frame, components);
        all.attach(&source);
        Self {
            all,
            source,
            frame,
            after_rule: writes.iter().map(|_| Decision::default()).collect(),
            writes,
            after_rules: Mutex::new(Vec::new()),
        }
    }

    /// Evaluates the subset's components at hybrid time `at` and state `x`
    /// into their places in `out` (the whole output vector); other entries
    /// are left as they are.
    pub fn eval(&self, at: HybridTime, x: &[f64], out: &mut [f64]) {
        self.all.eval(at, x, out);
    }

    /// Brings `out`, which holds the subset's values at the pre-jump point
    /// of a jump in which the rules `rules` fired (any order, repeats
    /// allowed), to the post-jump point `at`, `x`: the components that read
    /// no state component those rules write, neither `j` nor a random draw,
    /// keep their values. The result is that of [`eval`](Self::eval), bit
    /// for bit.
    ///
    /// ```
    /// use hybsim::{arc::HybridTime, lang, source::SourceFile};
    /// let src = SourceFile::new(
    ///     "m.hyb",
    ///     "model m\nstate x = 0, n = 0\nflow { x' = 1 }\n\
    ///      jump count when x >= 1 { n+ = n + 1 }\noutput a = sin(x), b = 2 * n\n",
    /// );
    /// let model = lang::compile(&src, &[]).unwrap();
    /// let outputs = model.output_subset(&[0, 1]);
    /// let mut y = [0.0; 2];
    /// outputs.eval(HybridTime::new(1.0, 0), &[1.0, 0.0], &mut y);
    /// // `count` writes n: only b can change.
    /// outputs.eval_after_jump(&[0], HybridTime::new(1.0, 1), &[1.0, 1.0], &mut y);
    /// assert_eq!(y, [1f64.sin(), 2.0]);
    /// ```
    pub fn eval_after_jump(&self, rules: &[usize], at: HybridTime, x: &[f64], out: &mut [f64]) {
        let one = match rules {
            [r] => self.after_rule.get(*r),
            _ => None,
        };
        let what = match one {
            Some(decision) => decision.get(|| self.decide(rules)),
            None => self.after_rules(rules),
        };
        match &what {
            AfterJump::Nothing => {}
            AfterJump::Some(code) => code.eval(at, x, out),
            AfterJump::All => self.all.eval(at, x, out),
        }
    }

    /// What a jump of several rules (or of an unknown one) evaluates.
    fn after_rules(&self, rules: &[usize]) -> AfterJump {
        let mut key: Vec<usize> = rules.to_vec();
        key.sort_unstable();
        key.dedup();
        // A poisoned lock only means that another thread panicked while
        // deciding: evaluate everything.
        let Ok(mut known) = self.after_rules.lock() else {
            return AfterJump::All;
        };
        let decision = match known.iter().find(|(k, _)| **k == *key) {
            Some((_, d)) => d.clone(),
            None if known.len() >= MAX_JUMP_SETS => return AfterJump::All,
            None => {
                let d = Arc::new(Decision::default());
                known.push((key.clone().into_boxed_slice(), d.clone()));
                d
            }
        };
        // Decided without the lock held (the analysis walks the graph).
        drop(known);
        decision.get(|| self.decide(&key))
    }

    /// What a jump of `rules` evaluates: the components it can change, by
    /// a program of their own when that is at most half the whole subset's.
    fn decide(&self, rules: &[usize]) -> AfterJump {
        let Some(changed) = self.changed_by(rules) else {
            return AfterJump::All;
        };
        if changed.is_empty() {
            return AfterJump::Nothing;
        }
        if changed.len() == self.all.components.len() {
            return AfterJump::All;
        }
        let code = Code::new(&self.source, self.frame, changed);
        if 2 * code.program.len() > self.all.program.len() {
            return AfterJump::All;
        }
        code.attach(&self.source);
        AfterJump::Some(Arc::new(code))
    }

    /// The components a jump of `rules` can change, in the subset's order;
    /// `None` for a rule the subset does not know.
    fn changed_by(&self, rules: &[usize]) -> Option<Vec<usize>> {
        let mut written = vec![false; self.frame.n];
        for &r in rules {
            for &k in self.writes.get(r)? {
                *written.get_mut(k)? = true;
            }
        }
        let dag = &self.source.dag;
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
        Some(
            self.all
                .components
                .iter()
                .copied()
                .filter(|&k| dirty[self.source.outputs[k] as usize])
                .collect(),
        )
    }
}

impl OutputMap for OutputSubset {
    fn eval(&self, at: HybridTime, x: &[f64], y: &mut [f64]) {
        OutputSubset::eval(self, at, x, y)
    }

    fn eval_after_jump(&self, rules: &[usize], at: HybridTime, x: &[f64], y: &mut [f64]) {
        OutputSubset::eval_after_jump(self, rules, at, x, y)
    }
}

#[cfg(test)]
mod tests {
    use super::{DECIDE_AFTER, OutputSubset};
    use crate::arc::HybridTime;
    use crate::lang;
    use crate::source::SourceFile;

    /// Jumps of `rules` until the next one is the first analysed (each
    /// evaluates everything, into a scratch vector).
    fn warm(outputs: &OutputSubset, rules: &[usize]) {
        let mut scratch = [0.0; 4];
        for _ in 1..DECIDE_AFTER {
            outputs.eval_after_jump(rules, HybridTime::new(0.0, 1), &[0.0; 4], &mut scratch);
        }
    }

    /// A bouncing mass with a jump counter and a clock that a second rule
    /// resets: outputs reading x, n, the clock, j and t.
    const MODEL: &str = "model m\n\
        state x = 1, v = 0, n = 0, c = 0\n\
        flow { x' = v\n v' = -9.81\n n' = 0\n c' = 1 }\n\
        jump bounce when x <= 0 && v < 0 { v+ = -0.8 * v\n n+ = n + 1 }\n\
        jump tick when c >= 1 { c+ = 0 }\n\
        output height = exp(sin(t) + x) * cos(x), hits = 2 * n, count = j, clock = c\n";

    #[test]
    fn only_what_a_jump_writes_is_evaluated_again() {
        let model = lang::compile(&SourceFile::new("m.hyb", MODEL), &[]).unwrap();
        let outputs = model.output_subset(&[0, 1, 2, 3]);
        let (pre, post) = ([0.0, -3.0, 2.0, 0.5], [0.0, 2.4, 3.0, 0.5]);
        let at = HybridTime::new(0.75, 4);
        let after = HybridTime::new(0.75, 5);
        let full = |x: &[f64; 4]| {
            let mut y = [0.0; 4];
            outputs.eval(after, x, &mut y);
            y
        };
        // A sentinel where the pre-jump values are: the components the
        // jump cannot change keep it, the others are evaluated.
        let mut y = [f64::NAN; 4];
        outputs.eval(at, &pre, &mut y);
        y[0] = 123.0;
        y[3] = 456.0;
        warm(&outputs, &[0]);
        outputs.eval_after_jump(&[0], after, &post, &mut y);
        assert_eq!(y[0], 123.0, "bounce writes v and n, height reads x and t");
        assert_eq!(y[3], 456.0, "clock reads c");
        assert_eq!(y[1..3], full(&post)[1..3], "hits reads n, count reads j");
        // Both rules at once (repeated, out of order): the union.
        let post2 = [0.0, 2.4, 3.0, 0.0];
        y[3] = 456.0;
        warm(&outputs, &[0, 1]);
        outputs.eval_after_jump(&[1, 0, 1], after, &post2, &mut y);
        assert_eq!(y[0], 123.0);
        assert_eq!(y[1..], full(&post2)[1..]);
        // An unknown rule: everything.
        warm(&outputs, &[7]);
        outputs.eval_after_jump(&[7], after, &post, &mut y);
        assert_eq!(y, full(&post));
    }

    #[test]
    fn a_subset_without_components_a_jump_changes_evaluates_nothing() {
        let model = lang::compile(&SourceFile::new("m.hyb", MODEL), &[]).unwrap();
        let outputs = model.output_subset(&[3]);
        let mut y = [7.0; 4];
        warm(&outputs, &[0]);
        outputs.eval_after_jump(&[0], HybridTime::new(1.0, 1), &[0.0; 4], &mut y);
        assert_eq!(y, [7.0; 4]);
        // The clock after a tick is evaluated (c reset to 0).
        warm(&outputs, &[1]);
        outputs.eval_after_jump(&[1], HybridTime::new(1.0, 1), &[0.0; 4], &mut y);
        assert_eq!(y, [7.0, 7.0, 7.0, 0.0]);
    }

    #[test]
    fn a_jump_that_changes_most_of_the_work_evaluates_everything() {
        // A tick changes `clock` only, but `clock` is most of the work: one
        // program of everything rather than a second one of nearly as much.
        let src = MODEL.replace(
            "clock = c",
            "clock = exp(sin(c) * cos(c) + c^3) / (1 + c^2)",
        );
        let model = lang::compile(&SourceFile::new("m.hyb", &src), &[]).unwrap();
        let outputs = model.output_subset(&[1, 3]);
        let (at, x) = (HybridTime::new(1.0, 1), [0.5, 1.0, 2.0, 0.0]);
        let mut full = [0.0; 4];
        outputs.eval(at, &x, &mut full);
        let mut y = [7.0; 4];
        warm(&outputs, &[1]);
        outputs.eval_after_jump(&[1], at, &x, &mut y);
        assert_eq!(y, [7.0, full[1], 7.0, full[3]]);
    }

    #[test]
    fn a_rule_is_analysed_only_once_it_has_jumped_often() {
        let model = lang::compile(&SourceFile::new("m.hyb", MODEL), &[]).unwrap();
        let outputs = model.output_subset(&[3]);
        // `bounce` cannot change `clock`, but its first jumps evaluate it
        // (no analysis yet); from the DECIDE_AFTER-th on they do not.
        let mut y = [7.0; 4];
        for _ in 1..DECIDE_AFTER {
            y[3] = 7.0;
            outputs.eval_after_jump(&[0], HybridTime::new(1.0, 1), &[0.0; 4], &mut y);
            assert_eq!(y[3], 0.0);
        }
        y[3] = 7.0;
        outputs.eval_after_jump(&[0], HybridTime::new(1.0, 1), &[0.0; 4], &mut y);
        assert_eq!(y[3], 7.0);
    }
}
