//! Checking properties on a solution as it streams by: one monitor per
//! property, fed the engine's samples and jumps in hybrid-time order.

use std::fmt;
use std::ops::ControlFlow;

use super::property::{Kind, Monotonicity, Property, Scope};
use crate::arc::{ArcSink, HybridArc, HybridTime, SampleKind, Termination, TerminationCause};
use crate::num::Num;

/// What exactly went wrong where a property failed.
#[derive(Debug, Clone, PartialEq)]
pub enum ViolationDetail {
    /// The predicate was false at a sample.
    Predicate {
        /// Where on the domain the sample sits.
        kind: SampleKind,
    },
    /// The jump predicate was false at a jump of rule `rule`.
    Jump {
        /// Index of the rule.
        rule: usize,
        /// The post-jump state (the pre-jump state is
        /// [`Violation::state`]).
        post: Vec<f64>,
    },
    /// No sample with `t ≤ within` satisfied the predicate.
    NotWithin {
        /// The deadline T.
        within: f64,
        /// `true` if the solution ended (could neither flow nor jump)
        /// before reaching `t = T`.
        ended_early: bool,
    },
    /// A monotonicity property failed between two values of V.
    Monotone {
        /// Which monotonicity was required.
        how: Monotonicity,
        /// Along flows or across a jump.
        scope: Scope,
        /// Hybrid time of the earlier value.
        from_at: HybridTime,
        /// The earlier value.
        from: f64,
        /// The later value (at [`Violation::at`], or after the jump).
        to: f64,
        /// The tolerance.
        tol: f64,
    },
    /// The exponential bound failed.
    Bound {
        /// `|x(t, j)|_A`.
        value: f64,
        /// `κ e^{−α (t + j)} |x(0, 0)|_A + tol`.
        bound: f64,
    },
}

/// A property failing on a solution: which one, at which hybrid time, with
/// which state and why.
#[derive(Debug, Clone, PartialEq)]
pub struct Violation {
    /// Name of the property.
    pub property: String,
    /// Hybrid time of the failure (for jumps: the pre-jump point).
    pub at: HybridTime,
    /// The state there (for jumps: the pre-jump state).
    pub state: Vec<f64>,
    /// What failed.
    pub detail: ViolationDetail,
}

impl fmt::Display for Violation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "`{}` fails at {}", self.property, self.at)?;
        match &self.detail {
            ViolationDetail::Predicate { kind } => write!(f, " ({kind:?} sample)"),
            ViolationDetail::Jump { rule, .. } => write!(f, " (jump of rule {rule})"),
            ViolationDetail::NotWithin {
                within,
                ended_early,
            } => {
                if *ended_early {
                    write!(
                        f,
                        ": the solution ended before t = {} without satisfying it",
                        Num(*within)
                    )
                } else {
                    write!(f, ": not satisfied at any t ≤ {}", Num(*within))
                }
            }
            ViolationDetail::Monotone {
                how,
                scope,
                from_at,
                from,
                to,
                tol,
            } => {
                let what = match how {
                    Monotonicity::Decreasing => "did not decrease",
                    Monotonicity::Nonincreasing => "increased",
                };
                let place = match scope {
                    Scope::Flows => "during the flow",
                    Scope::Jumps => "across the jump",
                };
                write!(
                    f,
                    ": V {what} {place} from {} at {from_at} to {} (tolerance {})",
                    Num(*from),
                    Num(*to),
                    Num(*tol)
                )
            }
            ViolationDetail::Bound { value, bound } => {
                // `V`, as the monotone properties and the `.hyb` syntax
                // (`exponential V kappa κ alpha α`) name the measured value.
                write!(
                    f,
                    ": V = {} > its bound κ·e^(−α(t + j))·V(0, 0) + tol = {}",
                    Num(*value),
                    Num(*bound)
                )
            }
        }
    }
}

/// How a property ended on a solution without failing.
#[derive(Debug, Clone, PartialEq)]
pub enum Conclusion {
    /// It held on the whole solution.
    Holds,
    /// The solution was too short to decide (an `eventually` deadline not
    /// reached before a horizon, the Zeno guard or a sink ended it).
    Inconclusive {
        /// Why.
        reason: String,
    },
}

/// The running state of one property's check.
enum State {
    Stateless,
    Flows {
        /// Interval index and first sample of the current flow interval,
        /// kept until the interval is seen to have positive length.
        start: Option<(HybridTime, SampleKind)>,
        start_x: Vec<f64>,
        flowing: bool,
    },
    Eventually {
        satisfied: bool,
    },
    After {
        entered: bool,
    },
    Prev {
        prev: Option<(HybridTime, f64)>,
    },
    Bound {
        d0: Option<f64>,
    },
}

struct Monitor<'p> {
    prop: &'p Property,
    state: State,
    last: Option<HybridTime>,
}

impl<'p> Monitor<'p> {
    fn new(prop: &'p Property) -> Self {
        let state = match &prop.kind {
            Kind::Always(_) | Kind::AtJumps { .. } => State::Stateless,
            Kind::DuringFlows(_) => State::Flows {
                start: None,
                start_x: Vec::new(),
                flowing: false,
            },
            Kind::EventuallyWithin { .. } => State::Eventually { satisfied: false },
            Kind::AlwaysAfter { .. } => State::After { entered: false },
            Kind::Monotone { .. } => State::Prev { prev: None },
            Kind::ExponentialBound { .. } => State::Bound { d0: None },
        };
        Self {
            prop,
            state,
            last: None,
        }
    }

    fn violation(&self, at: HybridTime, x: &[f64], detail: ViolationDetail) -> Violation {
        violation(self.prop, at, x, detail)
    }

    fn sample(&mut self, at: HybridTime, x: &[f64], kind: SampleKind) -> Result<(), Violation> {
        self.last = Some(at);
        let predicate = |ok: bool| {
            if ok {
                Ok(())
            } else {
                Err(ViolationDetail::Predicate { kind })
            }
        };
        let prop = self.prop;
        let result = match (&prop.kind, &mut self.state) {
            (Kind::Always(p), _) => predicate(p(at, x)),
            (
                Kind::DuringFlows(p),
                State::Flows {
                    start,
                    start_x,
                    flowing,
                },
            ) => match start {
                Some((s, s_kind)) if s.j == at.j => {
                    if at.t > s.t && !*flowing {
                        // The interval has positive length: its first point
                        // is a flow point too.
                        *flowing = true;
                        if !p(*s, start_x) {
                            return Err(violation(
                                prop,
                                *s,
                                start_x,
                                ViolationDetail::Predicate { kind: *s_kind },
                            ));
                        }
                    }
                    if *flowing {
                        predicate(p(at, x))
                    } else {
                        Ok(())
                    }
                }
                _ => {
                    *start = Some((at, kind));
                    start_x.clear();
                    start_x.extend_from_slice(x);
                    *flowing = false;
                    Ok(())
                }
            },
            (Kind::EventuallyWithin { within, pred }, State::Eventually { satisfied }) => {
                if *satisfied {
                    Ok(())
                } else if at.t <= *within {
                    *satisfied = pred(at, x);
                    Ok(())
                } else {
                    Err(ViolationDetail::NotWithin {
                        within: *within,
                        ended_early: false,
                    })
                }
            }
            (Kind::AlwaysAfter { enter, pred }, State::After { entered }) => {
                if !*entered {
                    *entered = enter(at, x);
                }
                if *entered {
                    predicate(pred(at, x))
                } else {
                    Ok(())
                }
            }
            (
                Kind::Monotone {
                    v,
                    how,
                    scope: Scope::Flows,
                    tol,
                },
                State::Prev { prev },
            ) => {
                let now = v(at, x);
                let result = match *prev {
                    Some((p_at, p_v)) if p_at.j == at.j && at.t > p_at.t => {
                        monotone_ok(*how, p_v, now, *tol).map_err(|()| ViolationDetail::Monotone {
                            how: *how,
                            scope: Scope::Flows,
                            from_at: p_at,
                            from: p_v,
                            to: now,
                            tol: *tol,
                        })
                    }
                    _ => Ok(()),
                };
                *prev = Some((at, now));
                result
            }
            (
                Kind::ExponentialBound {
                    dist,
                    kappa,
                    alpha,
                    tol,
                },
                State::Bound { d0 },
            ) => {
                let d = dist(at, x);
                let d0 = *d0.get_or_insert(d);
                let bound = kappa * (-alpha * (at.t + at.j as f64)).exp() * d0 + tol;
                if d <= bound {
                    Ok(())
                } else {
                    Err(ViolationDetail::Bound { value: d, bound })
                }
            }
            _ => Ok(()),
        };
        result.map_err(|detail| self.violation(at, x, detail))
    }

    fn jump(
        &mut self,
        at: HybridTime,
        rule: usize,
        pre: &[f64],
        post: &[f64],
    ) -> Result<(), Violation> {
        let view = super::JumpView {
            at,
            rule,
            pre,
            post,
        };
        let detail = match &self.prop.kind {
            Kind::AtJumps { rule: only, pred } => {
                if only.is_some_and(|r| r != rule) || pred(&view) {
                    return Ok(());
                }
                ViolationDetail::Jump {
                    rule,
                    post: post.to_vec(),
                }
            }
            Kind::Monotone {
                v,
                how,
                scope: Scope::Jumps,
                tol,
            } => {
                let (before, after) = (v(at, pre), v(view.post_at(), post));
                if monotone_ok(*how, before, after, *tol).is_ok() {
                    return Ok(());
                }
                ViolationDetail::Monotone {
                    how: *how,
                    scope: Scope::Jumps,
                    from_at: at,
                    from: before,
                    to: after,
                    tol: *tol,
                }
            }
            _ => return Ok(()),
        };
        Err(self.violation(at, pre, detail))
    }

    fn finish(&mut self, termination: &Termination) -> Result<Conclusion, Violation> {
        if let (Kind::EventuallyWithin { within, .. }, State::Eventually { satisfied: false }) =
            (&self.prop.kind, &self.state)
        {
            let end = self.last.unwrap_or(termination.at);
            if end.t >= *within
                || matches!(termination.cause, TerminationCause::CannotFlowOrJump { .. })
            {
                return Err(self.violation(
                    end,
                    &[],
                    ViolationDetail::NotWithin {
                        within: *within,
                        ended_early: end.t < *within,
                    },
                ));
            }
            return Ok(Conclusion::Inconclusive {
                reason: format!("the solution stopped at {} ({termination})", end),
            });
        }
        Ok(Conclusion::Holds)
    }
}

fn violation(prop: &Property, at: HybridTime, x: &[f64], detail: ViolationDetail) -> Violation {
    Violation {
        property: prop.name().to_string(),
        at,
        state: x.to_vec(),
        detail,
    }
}

/// `Ok` if `to` follows `from` as `how` requires with tolerance `tol`
/// (NaN fails).
fn monotone_ok(how: Monotonicity, from: f64, to: f64, tol: f64) -> Result<(), ()> {
    let ok = match how {
        Monotonicity::Decreasing => to < from || to <= tol,
        Monotonicity::Nonincreasing => to <= from + tol,
    };
    if ok { Ok(()) } else { Err(()) }
}

/// The verdict of a set of properties on one solution.
#[derive(Debug, Clone, PartialEq)]
pub enum Verdict {
    /// Every property held (some possibly inconclusive: listed with the
    /// property's name).
    Holds {
        /// Inconclusive properties and why.
        inconclusive: Vec<(String, String)>,
    },
    /// The first property to fail, in hybrid-time order (ties: declaration
    /// order).
    Fails(Violation),
}

impl Verdict {
    /// The violation, if a property failed.
    pub fn violation(&self) -> Option<&Violation> {
        match self {
            Verdict::Fails(v) => Some(v),
            Verdict::Holds { .. } => None,
        }
    }
}

/// An [`ArcSink`] that checks properties while the engine runs and stops
/// the run at the first violation. Optionally forwards everything to an
/// inner sink (a file, an in-memory arc) first.
///
/// ```
/// use hybsim::engine::{models::BouncingBall, simulate, SimRng, SimSettings};
/// use hybsim::props::{Property, PropertySink, Verdict};
///
/// let props = [Property::always("low", |_, x| x[0] <= 1.5)];
/// let mut sink = PropertySink::new(&props);
/// let ball = BouncingBall::new(9.81, 0.8);
/// simulate(&ball, &[1.0, 0.0], &SimSettings::default(), &mut SimRng::seed_from(0), &mut sink)
///     .unwrap();
/// assert!(matches!(sink.verdict(), Verdict::Holds { .. }));
/// ```
pub struct PropertySink<'p, 'i> {
    monitors: Vec<Monitor<'p>>,
    inner: Option<&'i mut dyn ArcSink>,
    violation: Option<Violation>,
    conclusions: Vec<Conclusion>,
}

impl<'p, 'i> PropertySink<'p, 'i> {
    /// A sink checking `props`.
    pub fn new(props: &'p [Property]) -> Self {
        Self {
            monitors: props.iter().map(Monitor::new).collect(),
            inner: None,
            violation: None,
            conclusions: Vec::new(),
        }
    }

    /// A sink checking `props` that also forwards the solution to `inner`.
    pub fn forwarding(props: &'p [Property], inner: &'i mut dyn ArcSink) -> Self {
        Self {
            inner: Some(inner),
            ..Self::new(props)
        }
    }

    /// The verdict so far (final once the run has finished).
    pub fn verdict(&self) -> Verdict {
        if let Some(v) = &self.violation {
            return Verdict::Fails(v.clone());
        }
        let inconclusive = self
            .monitors
            .iter()
            .zip(&self.conclusions)
            .filter_map(|(m, c)| match c {
                Conclusion::Inconclusive { reason } => {
                    Some((m.prop.name().to_string(), reason.clone()))
                }
                Conclusion::Holds => None,
            })
            .collect();
        Verdict::Holds { inconclusive }
    }

    /// The first violation, if any.
    pub fn violation(&self) -> Option<&Violation> {
        self.violation.as_ref()
    }

    fn record(&mut self, result: Result<(), Violation>) -> ControlFlow<()> {
        match result {
            Ok(()) => ControlFlow::Continue(()),
            Err(v) => {
                self.violation.get_or_insert(v);
                ControlFlow::Break(())
            }
        }
    }
}

impl ArcSink for PropertySink<'_, '_> {
    fn sample(&mut self, at: HybridTime, x: &[f64], kind: SampleKind) -> ControlFlow<()> {
        // The run ends at the violation: what the engine sends after it (the
        // final sample of the stopped run) is not forwarded.
        if self.violation.is_some() {
            return ControlFlow::Break(());
        }
        let inner = match &mut self.inner {
            Some(s) => s.sample(at, x, kind),
            None => ControlFlow::Continue(()),
        };
        let result = self
            .monitors
            .iter_mut()
            .try_for_each(|m| m.sample(at, x, kind));
        self.record(result)?;
        inner
    }

    fn jump(&mut self, at: HybridTime, rule: usize, pre: &[f64], post: &[f64]) -> ControlFlow<()> {
        // The run ends at the violation: what the engine sends after it (the
        // final sample of the stopped run) is not forwarded.
        if self.violation.is_some() {
            return ControlFlow::Break(());
        }
        let inner = match &mut self.inner {
            Some(s) => s.jump(at, rule, pre, post),
            None => ControlFlow::Continue(()),
        };
        let result = self
            .monitors
            .iter_mut()
            .try_for_each(|m| m.jump(at, rule, pre, post));
        self.record(result)?;
        inner
    }

    fn finish(&mut self, termination: &Termination) {
        if let Some(s) = &mut self.inner {
            s.finish(termination);
        }
        if self.violation.is_some() {
            return;
        }
        let mut conclusions = Vec::with_capacity(self.monitors.len());
        for m in &mut self.monitors {
            match m.finish(termination) {
                Ok(c) => conclusions.push(c),
                Err(v) => {
                    self.violation = Some(v);
                    return;
                }
            }
        }
        self.conclusions = conclusions;
    }
}

/// Checks `props` on a stored solution, replaying its samples and jumps in
/// hybrid-time order through a [`PropertySink`]. A solution without a
/// recorded termination is taken to end at its last sample, reached by the
/// horizon.
pub fn check_arc(arc: &HybridArc, props: &[Property]) -> Verdict {
    let mut sink = PropertySink::new(props);
    replay(arc, &mut sink);
    sink.verdict()
}

/// Pushes a stored solution into a sink as the engine did.
fn replay(arc: &HybridArc, sink: &mut dyn ArcSink) {
    let mut jumps = arc.jumps().iter();
    for s in arc.samples() {
        if sink.sample(s.at, s.x, s.kind).is_break() {
            return;
        }
        if s.kind == SampleKind::PreJump
            && let Some(r) = jumps.next()
            && sink.jump(r.at, r.rule, &r.pre, &r.post).is_break()
        {
            return;
        }
    }
    let termination = arc.termination().cloned().unwrap_or_else(|| Termination {
        at: arc.last().map_or(HybridTime::new(0.0, 0), |s| s.at),
        cause: TerminationCause::HorizonT,
    });
    sink.finish(&termination);
}

impl Property {
    /// Checks this property on a stored solution: `Ok` with how it ended
    /// (held, or inconclusive) or the first violation.
    ///
    /// # Errors
    /// The first [`Violation`] of the property on `arc`.
    pub fn check(&self, arc: &HybridArc) -> Result<Conclusion, Violation> {
        match check_arc(arc, std::slice::from_ref(self)) {
            Verdict::Fails(v) => Err(v),
            Verdict::Holds { inconclusive } => Ok(match inconclusive.into_iter().next() {
                Some((_, reason)) => Conclusion::Inconclusive { reason },
                None => Conclusion::Holds,
            }),
        }
    }
}
