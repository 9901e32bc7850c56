//! The set invariants every solution the engine builds satisfies, as a
//! check usable on any arc (tests, property tests, users' own systems):
//!
//! - each jump starts from a point of its rule's jump set D_i: every
//!   inequality atom holds exactly at the pre-jump state; an equality atom
//!   `g = 0`, which the engine meets by a sign change inside an event
//!   bracket of width `event_tol` in t, is accepted when `|g| ≤ set_tol`;
//! - samples come in hybrid-time order (t and j nondecreasing), and
//!   samples at one hybrid time (t, j) hold one state (a solution is a
//!   function on its hybrid time domain);
//! - each flow starts in C within [`set_tol`](super::SimSettings::set_tol)
//!   on C's atoms (a flow starts at the initial point or after a jump when
//!   the next sample is later in t at the same j).
//!
//! Systems without atoms are checked through their predicates (a jump's
//! pre-jump state must satisfy [`HybridSystem::jump_set`]; a flow start
//! [`HybridSystem::flow_set`], or its guard ≥ −set_tol).

use thiserror::Error;

use super::events::FlowSetTest;
use super::settings::SimSettings;
use super::system::{Cmp, HybridSystem, SetRef};
use crate::arc::{HybridArc, HybridTime, SampleKind};

/// A violated invariant of an arc.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ArcViolation {
    /// A jump started from a point outside its rule's jump set.
    #[error("jump {index} (rule `{rule}`) at {at} starts outside its jump set: x = {x:?}")]
    JumpOutsideD {
        /// Index of the jump record.
        index: usize,
        /// Rule name.
        rule: String,
        /// Hybrid time of the pre-jump point.
        at: HybridTime,
        /// Pre-jump state.
        x: Vec<f64>,
    },
    /// A sample's hybrid time precedes the one before it (t or j
    /// decreasing along the arc).
    #[error("the sample at {at} comes after one at {before}: hybrid time runs backwards")]
    TimeBackwards {
        /// The earlier sample's hybrid time.
        before: HybridTime,
        /// The sample's hybrid time.
        at: HybridTime,
    },
    /// Two samples at one hybrid time hold different states.
    #[error("two samples at {at} hold different states: x = {x:?} ({kind}) and {y:?} ({next})")]
    TwoStates {
        /// Their hybrid time.
        at: HybridTime,
        /// The first state.
        x: Vec<f64>,
        /// The first sample's kind.
        kind: String,
        /// The second state.
        y: Vec<f64>,
        /// The second sample's kind.
        next: String,
    },
    /// A flow started from a point outside C (beyond `set_tol`).
    #[error("a flow starts outside the flow set at {at}: x = {x:?}")]
    FlowOutsideC {
        /// Hybrid time of the flow's start.
        at: HybridTime,
        /// State there.
        x: Vec<f64>,
    },
}

/// Checks the set invariants of `arc`, a solution of `sys` under
/// `settings` (see the module docs); returns the first violation.
///
/// # Errors
/// The first [`ArcViolation`] found, in hybrid-time order.
pub fn check_arc<S: HybridSystem + ?Sized>(
    sys: &S,
    arc: &HybridArc,
    settings: &SimSettings,
) -> Result<(), ArcViolation> {
    let tol = settings.set_tol;
    let names = arc.rule_names();
    for (index, rec) in arc.jumps().iter().enumerate() {
        if !in_jump_set(sys, rec.rule, rec.at, &rec.pre, tol) {
            return Err(ArcViolation::JumpOutsideD {
                index,
                rule: names.get(rec.rule).cloned().unwrap_or_default(),
                at: rec.at,
                x: rec.pre.clone(),
            });
        }
    }
    let mut flow_set = FlowSetTest::new(sys);
    let samples: Vec<_> = arc.samples().collect();
    for w in samples.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        if b.at.t < a.at.t || b.at.j < a.at.j {
            return Err(ArcViolation::TimeBackwards {
                before: a.at,
                at: b.at,
            });
        }
        let same = |p: &[f64], q: &[f64]| {
            p.iter()
                .zip(q)
                .all(|(u, v)| u == v || (u.is_nan() && v.is_nan()))
        };
        if b.at == a.at && !same(a.x, b.x) {
            return Err(ArcViolation::TwoStates {
                at: a.at,
                x: a.x.to_vec(),
                kind: format!("{:?}", a.kind),
                y: b.x.to_vec(),
                next: format!("{:?}", b.kind),
            });
        }
        let starts_flow = matches!(a.kind, SampleKind::Initial | SampleKind::PostJump)
            && b.at.j == a.at.j
            && b.at.t > a.at.t;
        if starts_flow && !flow_set.contains(sys, a.at, a.x, tol, None) {
            return Err(ArcViolation::FlowOutsideC {
                at: a.at,
                x: a.x.to_vec(),
            });
        }
    }
    Ok(())
}

/// Whether `x` is in D_rule: inequality atoms exactly, equality atoms
/// within `tol`.
fn in_jump_set<S: HybridSystem + ?Sized>(
    sys: &S,
    rule: usize,
    at: HybridTime,
    x: &[f64],
    tol: f64,
) -> bool {
    let set = SetRef::Jump(rule);
    let Some(spec) = sys.set_atoms(set) else {
        return sys.jump_set(rule, at, x);
    };
    let mut vals = vec![0.0; spec.atoms.len()];
    sys.atom_values(set, at, x, false, &mut vals);
    let truth: Vec<bool> = spec
        .atoms
        .iter()
        .zip(&vals)
        .map(|(a, &g)| match a.cmp {
            Cmp::Eq => g.abs() <= tol,
            c => c.holds(g),
        })
        .collect();
    spec.expr.eval(&truth)
}
