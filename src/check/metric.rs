//! Checking `metric` declarations: scalar reductions of a run.
//!
//! A metric is an expression over *reductions* (`count(rule)`, `mean(e)`,
//! `integral(e)`, `max(e)`, `min(e)`, `final(e)`, `period(e)`, each with an optional
//! window condition as last argument), parameters, constants and `t` (the
//! run's final time). The reduction arguments are lowered in the property
//! frame (see [`super::property`]: states, `j`, `t`, outputs); the metric
//! expression itself in the *metric frame*, where reduction `k` is
//! `State(base + k)` and `t` is the final time.

use std::collections::{HashMap, HashSet};

use super::Checker;
use super::dag::{Dag, Node, NodeId};
use super::error::CheckError;
use super::expr::{Ctx, Val, dims_words, key_label, suggest};
use super::rule_names::RuleNames;
use crate::source::Span;
use crate::syntax::ast::{Definition, Expr, ExprKind};

/// What a reduction computes over a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReductionKind {
    /// Number of jumps of the selected rules (window checked at the
    /// pre-jump point).
    Count,
    /// ∫ e dt over the flow intervals (trapezoid rule between consecutive
    /// samples of one flow interval).
    Integral,
    /// ∫ e dt / ∫ dt over the flow intervals inside the window.
    Mean,
    /// Largest value at a sample.
    Max,
    /// Smallest value at a sample.
    Min,
    /// Value at the last sample (in the window).
    Final,
    /// Asymptotic period of the values at the jumps (pre-jump points in
    /// the window), as [`crate::analysis::periodicity`] detects it.
    Period,
}

impl ReductionKind {
    /// The reduction called `name`, if it is one.
    pub fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "count" => Self::Count,
            "integral" => Self::Integral,
            "mean" => Self::Mean,
            "max" => Self::Max,
            "min" => Self::Min,
            "final" => Self::Final,
            "period" => Self::Period,
            _ => return None,
        })
    }

    /// The reductions' names, as written in a metric.
    const NAMES: [&'static str; 7] = ["count", "integral", "mean", "max", "min", "final", "period"];

    /// The reduction a user probably meant by the unknown function `name`
    /// in a metric: other tools' words for one (`last`, `avg`, `trapz`),
    /// else the closest reduction's name.
    pub(crate) fn meant(name: &str) -> Option<String> {
        let alias = match name.to_ascii_lowercase().as_str() {
            "last" | "end" | "terminal" | "at_end" => "final",
            "avg" | "average" | "time_average" => "mean",
            "int" | "integrate" | "trapz" | "cumsum" => "integral",
            "number" | "num" | "events" | "jumps" => "count",
            "maximum" | "sup" | "peak" => "max",
            "minimum" | "inf" => "min",
            _ => return suggest(name, Self::NAMES),
        };
        Some(alias.to_string())
    }
}

/// One reduction of a run; nodes are in the property frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Reduction {
    /// What it computes.
    pub kind: ReductionKind,
    /// The reduced expression (for `count`: none).
    pub arg: Option<NodeId>,
    /// For `count`: the rule indices counted.
    pub rules: Vec<usize>,
    /// Only samples (jumps, flow intervals) where this condition holds.
    pub window: Option<NodeId>,
}

/// A checked metric: a name and its value in the metric frame.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckedMetric {
    /// Name as shown (`rate`, `rate[2]`).
    pub name: String,
    /// The value, a node of the metric frame.
    pub node: NodeId,
    /// The declaration.
    pub span: Span,
}

/// A model's metrics and the reductions they read.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CheckedMetrics {
    /// Reductions in order; reduction `k` is `State(base + k)` in the
    /// metric frame.
    pub reductions: Vec<Reduction>,
    /// The metrics in declaration order.
    pub metrics: Vec<CheckedMetric>,
    /// First register of the reductions in the metric frame (beyond the
    /// property frame `2·n + 2`).
    pub base: usize,
}

/// The checker's state while a metric expression is lowered.
#[derive(Debug)]
pub(crate) struct MetricFrame {
    base: usize,
    rules: RuleNames,
    reductions: Vec<Reduction>,
}

const METRIC_CTX: Ctx = Ctx {
    random: false,
    wiener: false,
    place: "a metric",
};

/// Collects the metrics of a model with `dim` state components and jump
/// rules `rules`, one definition at a time (in source order, loops
/// unrolled by the caller).
pub(crate) struct MetricCollector {
    seen: HashMap<String, Span>,
    out: CheckedMetrics,
    frame: Option<MetricFrame>,
    j_added: bool,
}

impl MetricCollector {
    /// Starts collecting; makes `j` visible (as in properties).
    pub(crate) fn new(c: &mut Checker, rules: RuleNames, dim: usize) -> Self {
        let j_added = !c.syms.contains_key("j");
        if j_added {
            let val = Val::scalar(c.dag.state(dim));
            c.syms.insert(
                "j".into(),
                super::Sym::Output {
                    val: val.into(),
                    span: Span::default(),
                },
            );
        }
        let base = 2 * dim + 2;
        Self {
            seen: HashMap::new(),
            out: CheckedMetrics {
                base,
                ..CheckedMetrics::default()
            },
            frame: Some(MetricFrame {
                base,
                rules,
                reductions: Vec::new(),
            }),
            j_added,
        }
    }

    /// Checks `metric d` (its target's index, if any, already bound by the
    /// enclosing loop).
    pub(crate) fn metric(&mut self, c: &mut Checker, d: &Definition) {
        let name = match d.target.indices.as_slice() {
            [] => d.target.name.name.clone(),
            [args] => {
                let Some(key) = c.family_key(args) else {
                    return;
                };
                let key: Vec<String> = key.iter().map(|k| k.to_string()).collect();
                format!("{}[{}]", d.target.name.name, key.join(","))
            }
            _ => {
                c.err(CheckError::Expected {
                    expected: "a name or `name[i]`".into(),
                    found: "several index lists".into(),
                    span: d.target.span,
                });
                return;
            }
        };
        if let Some(&first) = self.seen.get(&name) {
            c.err(CheckError::Duplicate {
                name,
                span: d.target.span,
                first,
            });
            return;
        }
        self.seen.insert(name.clone(), d.target.span);
        let frame = self.frame.take().expect("one metric at a time");
        let first = frame.reductions.len();
        c.metric_frame = Some(frame);
        let v = c.expr(&d.value, &METRIC_CTX);
        let mut frame = c.metric_frame.take().expect("restored by reduction calls");
        let node = v.and_then(|v| {
            if v.rows * v.cols != 1 {
                c.err(CheckError::Expected {
                    expected: "one number for a metric".into(),
                    found: dims_words(v.dims()),
                    span: d.value.span,
                });
                return None;
            }
            if reads_run(&c.dag, v.e[0], frame.base) {
                c.err(CheckError::Expected {
                    expected: "states, outputs and `j` inside a reduction in a metric \
                               (`mean(x)`, `final(x)`, `max(x)`, …)"
                        .into(),
                    found: "a value of the run outside any reduction".into(),
                    span: d.value.span,
                });
                return None;
            }
            Some(v.e[0])
        });
        match node {
            Some(node) => self.out.metrics.push(CheckedMetric {
                name,
                node,
                span: d.target.span,
            }),
            None => frame.reductions.truncate(first),
        }
        self.frame = Some(frame);
    }

    /// The metrics; removes `j` again.
    pub(crate) fn finish(mut self, c: &mut Checker) -> CheckedMetrics {
        if self.j_added {
            c.syms.remove("j");
        }
        self.out.reductions = self.frame.take().map(|f| f.reductions).unwrap_or_default();
        self.out
    }
}

/// True if `n` reads a state component, `j` or a post-jump value (a
/// register below `base`).
fn reads_run(dag: &Dag, n: NodeId, base: usize) -> bool {
    let mut seen = HashSet::new();
    let mut stack = vec![n];
    while let Some(n) = stack.pop() {
        if !seen.insert(n) {
            continue;
        }
        match dag.node(n) {
            Node::State(k) if (k as usize) < base => return true,
            Node::Wiener(_) | Node::Jumps => return true,
            Node::Const(_) | Node::State(_) | Node::Time | Node::Rand(..) => {}
            Node::Un(_, a) => stack.push(a),
            Node::Bin(_, a, b) => stack.extend([a, b]),
            Node::Lookup { row, col, when, .. } => stack.extend([row, col, when]),
            Node::Interp { x, .. } => stack.push(x),
            Node::Select(s, a, b) => stack.extend([s, a, b]),
            Node::BlockOut(b, _) => stack.extend(dag.block(b).inputs.iter().copied()),
        }
    }
    false
}

impl Checker {
    /// True while a metric expression is lowered (outside reduction
    /// arguments) and `name` is a reduction.
    pub(crate) fn is_reduction_call(&self, name: &str) -> bool {
        self.metric_frame.is_some() && ReductionKind::from_name(name).is_some()
    }

    /// A reduction call in a metric: its arguments are lowered in the
    /// property frame (nested reductions are not allowed); the value is the
    /// reduction's register of the metric frame.
    pub(crate) fn reduction_call(&mut self, name: &str, args: &[Expr], span: Span) -> Option<Val> {
        let kind = ReductionKind::from_name(name)?;
        if args.is_empty() || args.len() > 2 {
            self.err(CheckError::Arity {
                func: name.to_string(),
                expected: "1 or 2 arguments (the value, and a window condition)".into(),
                found: args.len(),
                span,
            });
            return None;
        }
        let frame = self.metric_frame.take()?;
        let result = self.reduction_parts(kind, args, &frame.rules);
        let mut frame = frame;
        let out = result.map(|r| {
            frame.reductions.push(r);
            let k = frame.base + frame.reductions.len() - 1;
            Val::scalar(self.dag.state(k))
        });
        self.metric_frame = Some(frame);
        out
    }

    fn reduction_parts(
        &mut self,
        kind: ReductionKind,
        args: &[Expr],
        rules: &RuleNames,
    ) -> Option<Reduction> {
        let window = args.get(1).map(|w| self.metric_condition(w));
        let (arg, rule_set) = if kind == ReductionKind::Count {
            (None, self.count_rules(&args[0], rules))
        } else {
            (Some(self.metric_scalar(&args[0])), Some(Vec::new()))
        };
        let window = match window {
            Some(w) => Some(w?),
            None => None,
        };
        let arg = match arg {
            Some(a) => Some(a?),
            None => None,
        };
        Some(Reduction {
            kind,
            arg,
            rules: rule_set?,
            window,
        })
    }

    /// A scalar value of the run (property frame).
    fn metric_scalar(&mut self, e: &Expr) -> Option<NodeId> {
        let v = self.expr(e, &METRIC_CTX)?;
        if v.rows * v.cols != 1 {
            self.err(CheckError::Expected {
                expected: "a scalar to reduce (e.g. `norm(e)`)".into(),
                found: dims_words(v.dims()),
                span: e.span,
            });
            return None;
        }
        Some(v.e[0])
    }

    /// A window: one condition of the run (property frame).
    fn metric_condition(&mut self, e: &Expr) -> Option<NodeId> {
        let v = self.expr(e, &METRIC_CTX)?;
        if v.rows * v.cols != 1 || !v.boolean {
            let found = if v.rows * v.cols != 1 {
                dims_words(v.dims())
            } else {
                "a number".to_string()
            };
            self.err(CheckError::Expected {
                expected: "a window condition such as `t >= 100`".into(),
                found,
                span: e.span,
            });
            return None;
        }
        Some(v.e[0])
    }

    /// The rules `count(…)` names: `fire` (a rule, or every member of the
    /// family `fire`) or `fire[i]`.
    fn count_rules(&mut self, e: &Expr, rules: &RuleNames) -> Option<Vec<usize>> {
        let (base, key) = match &e.kind {
            ExprKind::Name(n) => (n.clone(), None),
            ExprKind::Index(inner, args) => match &inner.kind {
                ExprKind::Name(n) => (n.clone(), Some(key_label(&self.family_key(args)?))),
                _ => (String::new(), None),
            },
            _ => (String::new(), None),
        };
        if base.is_empty() {
            self.err(CheckError::Expected {
                expected: "a jump rule's name in `count(…)` (`count(fire)`, `count(fire[i])`)"
                    .into(),
                found: "an expression".into(),
                span: e.span,
            });
            return None;
        }
        let name = match &key {
            Some(k) => format!("{base}[{k}]"),
            None => base.clone(),
        };
        let found = rules.matching(&name);
        // A family over an empty range (`--set N=0`) is declared: its count is 0.
        if found.is_empty() && !rules.is_family(&name) {
            if rules.is_failed(&name) {
                return None;
            }
            let hints = self.hints.charge(rules.names().len());
            let error = rules.not_found(&base, key, e.span, |name| {
                hints.then(|| suggest(name, rules.names())).flatten()
            });
            self.err(error);
            return None;
        }
        Some(found)
    }
}
