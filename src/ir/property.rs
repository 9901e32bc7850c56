//! A model's `property` declarations compiled into register programs and
//! wrapped as [`props::Property`](crate::props::Property) values.
//!
//! Register file of a property program: `[x (n) | j | x⁺ (n) | t | j | temporaries]`
//! (the property frame of [`crate::check::property`], then the time and
//! jump-counter registers of [`Frame`]: `j` is loaded twice, as the
//! property's own `j` and for model outputs that use `j`); outside jumps
//! `x⁺ = x`.

use std::sync::Arc;

use super::jit::Jit;
use super::program::{Frame, Program};
use super::with_regs;
use crate::arc::HybridTime;
use crate::check::dag::{Dag, NodeId};
use crate::check::property::{CheckedProperty, PropertyKind};
use crate::props::{Monotonicity, Property, Scope};
use crate::source::{SourceFile, Span};

/// One compiled property expression.
#[derive(Debug)]
pub(super) struct Eval {
    prog: Program,
    nregs: usize,
    n: usize,
}

impl Eval {
    /// The program of `node`, given to `jit` (compiled when it is hot).
    fn new(dag: &Dag, node: NodeId, n: usize, jit: Option<&Arc<Jit>>) -> Arc<Self> {
        let frame = Frame { n: 2 * n + 1, m: 0 };
        let prog = Program::compile(dag, frame, &[node]);
        if let Some(jit) = jit {
            jit.attach(&prog, false);
        }
        let nregs = prog.nregs.max(frame.fixed());
        Arc::new(Self { prog, nregs, n })
    }

    /// Its program.
    pub(super) fn program(&self) -> &Program {
        &self.prog
    }

    /// The value at `(t, j)` for state `x` (and post-jump state `post`).
    fn eval(&self, at: HybridTime, x: &[f64], post: Option<&[f64]>) -> f64 {
        let n = self.n;
        with_regs(self.nregs, |regs| {
            regs[..n].copy_from_slice(&x[..n]);
            regs[n] = at.j as f64;
            regs[n + 1..2 * n + 1].copy_from_slice(&post.unwrap_or(x)[..n]);
            regs[2 * n + 1] = at.t;
            regs[2 * n + 2] = at.j as f64;
            self.prog.run(regs, None);
            regs[self.prog.outs[0] as usize]
        })
    }

    fn holds(&self, at: HybridTime, x: &[f64], post: Option<&[f64]>) -> bool {
        self.eval(at, x, post) != 0.0
    }
}

/// The properties of a model with `n` state components; their text is
/// taken from `source`. Their predicates are given to `jit`; the second
/// result holds them.
pub(crate) fn compile(
    dag: &Dag,
    props: &[CheckedProperty],
    n: usize,
    source: &SourceFile,
    jit: Option<&Arc<Jit>>,
) -> (Vec<(Property, Span)>, Vec<Arc<Eval>>) {
    let evals = std::cell::RefCell::new(Vec::new());
    let eval = |node: NodeId| {
        let e = Eval::new(dag, node, n, jit);
        evals.borrow_mut().push(e.clone());
        e
    };
    let props = props
        .iter()
        .map(|p| {
            let name = p.name.clone();
            let prop = match p.kind {
                PropertyKind::Always(e) => {
                    let e = eval(e);
                    Property::always(name, move |at, x| e.holds(at, x, None))
                }
                PropertyKind::DuringFlows(e) => {
                    let e = eval(e);
                    Property::during_flows(name, move |at, x| e.holds(at, x, None))
                }
                PropertyKind::AlwaysAfter { enter, pred } => {
                    let (e, p) = (eval(enter), eval(pred));
                    Property::always_after(
                        name,
                        move |at, x| e.holds(at, x, None),
                        move |at, x| p.holds(at, x, None),
                    )
                }
                PropertyKind::AtJumps { rule, pred } => {
                    let e = eval(pred);
                    let f = move |jv: &crate::props::JumpView<'_>| {
                        e.holds(jv.at, jv.pre, Some(jv.post))
                    };
                    match rule {
                        Some(r) => Property::at_jumps_of(name, r, f),
                        None => Property::at_jumps(name, f),
                    }
                }
                PropertyKind::EventuallyWithin { within, pred } => {
                    let e = eval(pred);
                    Property::eventually_within(name, within, move |at, x| e.holds(at, x, None))
                }
                PropertyKind::Monotone {
                    decreasing,
                    jumps,
                    v,
                    tol,
                } => {
                    let e = eval(v);
                    let how = if decreasing {
                        Monotonicity::Decreasing
                    } else {
                        Monotonicity::Nonincreasing
                    };
                    let scope = if jumps { Scope::Jumps } else { Scope::Flows };
                    Property::monotone(name, how, scope, tol, move |at, x| e.eval(at, x, None))
                }
                PropertyKind::Exponential {
                    v,
                    kappa,
                    alpha,
                    tol,
                } => {
                    let e = eval(v);
                    Property::exponential_bound(name, kappa, alpha, tol, move |at, x| {
                        e.eval(at, x, None)
                    })
                }
            };
            // The body's source text, comments dropped, on one line.
            let text = source
                .text()
                .get(p.body_span.start..p.body_span.end)
                .unwrap_or_default()
                .lines()
                .flat_map(|l| l.split('#').next().unwrap_or_default().split_whitespace())
                .collect::<Vec<_>>()
                .join(" ");
            (prop.with_text(text), p.span)
        })
        .collect();
    (props, evals.into_inner())
}
