//! The hybrid loop: decide between flowing and jumping, run flow segments,
//! apply jump maps, watch the horizons and the Zeno guards.

use std::collections::VecDeque;

use super::HybridSystem;
use super::affine_modes::ModeAffines;
use super::clock::TimeSum;
use super::error::SimError;
use super::events::{EventKind, FlowSetTest, Watcher};
use super::flow::{
    Affine, EndWhy, Flows, JumpChecks, Method, Output, check_finite, check_jump_finite,
};
use super::settings::{ExactAffine, JumpChoice, Priority, SimSettings, Solver};
use super::system::{Cmp, FlowStructure, GuardKind, SetExpr, SetRef, SimRng, Threshold};
use crate::arc::{
    ArcSink, HybridArc, HybridTime, SampleKind, Termination, TerminationCause, ZenoDetail,
};

/// The Zeno guards: the times of the last `window` jumps made, to estimate
/// the jump rate, and the jump budget. Both apply only when the horizon J
/// is unbounded: a finite J is itself the budget, and the run reaches it.
struct ZenoWatch {
    times: VecDeque<f64>,
    window: usize,
    max_rate: f64,
    max_total: u64,
    active: bool,
}

impl ZenoWatch {
    fn new(s: &SimSettings) -> Self {
        let window = s.zeno_window as usize;
        Self {
            // Grown as jumps come: a window may be as long as `u32::MAX`
            // (34 GB of times allocated up front aborted the process), and
            // the run ends after `max_total_jumps` anyway.
            times: VecDeque::with_capacity(window.min(64) + 1),
            window,
            max_rate: s.zeno_max_rate,
            max_total: s.max_total_jumps,
            active: s.horizon_j == u64::MAX,
        }
    }

    /// Called before jump number `j + 1` at time `t`, `j` jumps having been
    /// made: Zeno is suspected if `j` reached the budget, or if the last
    /// `window` jumps and this one all happen within less than
    /// `window / max_rate` units of t.
    fn check(&self, t: f64, j: u64) -> Option<ZenoDetail> {
        if !self.active {
            return None;
        }
        if j >= self.max_total {
            return Some(ZenoDetail::TotalJumps {
                limit: self.max_total,
            });
        }
        let first = *self.times.front()?;
        let within = t - first;
        if self.times.len() == self.window && within < self.window as f64 / self.max_rate {
            return Some(ZenoDetail::Rate {
                jumps: self.window as u32,
                within,
            });
        }
        None
    }

    /// Records a jump made at time `t`.
    #[inline]
    fn jumped(&mut self, t: f64) {
        if !self.active {
            return;
        }
        self.times.push_back(t);
        if self.times.len() > self.window {
            self.times.pop_front();
        }
    }
}

/// How the flows of a run from `x0` are advanced, and a switched affine
/// flow's modes.
fn method_for<S: HybridSystem + ?Sized>(
    sys: &S,
    settings: &SimSettings,
    x0: &[f64],
) -> Result<(Method, Option<ModeAffines>), SimError> {
    if let Solver::EulerMaruyama { h } = settings.solver {
        return Ok((Method::EulerMaruyama { h }, None));
    }
    settings.solver.suits(sys)?;
    if settings.exact_affine == ExactAffine::Off {
        return Ok((Method::Ode(settings.solver), None));
    }
    let (aff, modes) = match sys.flow_structure() {
        FlowStructure::Affine { a, b } => (Box::new(Affine::new(sys.state_dim(), &a, &b)?), None),
        FlowStructure::SwitchedAffine { modes } => {
            match ModeAffines::new(sys, modes, HybridTime::new(0.0, 0), x0) {
                Ok((modes, aff)) => (aff, Some(modes)),
                // The initial mode's coefficients cannot be had: the auto
                // choice leaves the flow to the solver (`Flows::select_mode`).
                Err(_) if settings.exact_affine == ExactAffine::Auto => {
                    return Ok((Method::Ode(settings.solver), None));
                }
                Err(e) => return Err(e),
            }
        }
        FlowStructure::General => return Ok((Method::Ode(settings.solver), None)),
    };
    let method = match settings.exact_affine {
        ExactAffine::On => Method::Affine(aff),
        _ => Method::Auto(settings.solver, aff),
    };
    Ok((method, modes))
}

fn check_system<S: HybridSystem + ?Sized>(sys: &S, x0: &[f64]) -> Result<(), SimError> {
    let n = sys.state_dim();
    if n == 0 {
        return Err(SimError::InvalidSystem {
            what: "the state has no component".into(),
        });
    }
    if x0.len() != n {
        return Err(SimError::StateDimension {
            expected: n,
            found: x0.len(),
        });
    }
    let rules = sys.jump_rules();
    for (i, rule) in rules.iter().enumerate() {
        if let Some(&k) = rule.writes.iter().find(|&&k| k >= n) {
            return Err(SimError::InvalidSystem {
                what: format!(
                    "rule {i} (`{}`) writes component {k}, which is out of range (n = {n})",
                    rule.name
                ),
            });
        }
        if let Some(g) = rule.group {
            // Rules of one part are alternatives and may share components.
            let same_part = |o: &super::JumpRule| rule.part.is_some() && o.part == rule.part;
            let clash = rule.writes.iter().find(|&&k| {
                k >= n
                    || rules[..i]
                        .iter()
                        .any(|o| o.group == Some(g) && !same_part(o) && o.writes.contains(&k))
            });
            if let Some(&k) = clash {
                return Err(SimError::InvalidSystem {
                    what: format!(
                        "rule {i} (`{}`) of group {g} writes component {k}, which is out of \
                         range (n = {n}) or written by another rule of the group",
                        rule.name
                    ),
                });
            }
        }
        if let GuardKind::Timer {
            index, threshold, ..
        } = rule.guard
            && (index >= n || !threshold.is_finite())
        {
            return Err(SimError::InvalidSystem {
                what: format!(
                    "rule {i} (`{}`): timer index {index} must be < {n} and threshold finite \
                     (got {threshold})",
                    rule.name
                ),
            });
        }
    }
    if let Some(e) = check_finite(sys, HybridTime::new(0.0, 0), x0, None) {
        return Err(e);
    }
    Ok(())
}

/// Every rule's jump set, when each is one timer atom `x[index] − threshold
/// ⋈ 0` ([`Atom::timer`](super::Atom::timer), exact by its contract): its
/// membership is that comparison, decided without evaluating the system's
/// sets (sample-and-hold loops, networks of agents' clocks).
struct TimerSets(Vec<(usize, f64, Cmp)>);

impl TimerSets {
    fn new<S: HybridSystem + ?Sized>(sys: &S) -> Option<Self> {
        let sets = (0..sys.jump_rules().len())
            .map(|r| {
                let spec = sys.set_atoms(SetRef::Jump(r))?;
                match (&spec.expr, &spec.atoms[..]) {
                    (SetExpr::Atom(0), [atom]) => match atom.timer {
                        Some((k, Threshold::Const(c))) => Some((k, c, atom.cmp)),
                        // Read from the system: its set is evaluated.
                        _ => None,
                    },
                    _ => None,
                }
            })
            .collect::<Option<Vec<_>>>()?;
        (!sets.is_empty()).then_some(Self(sets))
    }

    /// Whether rule `r`'s jump set holds `x`.
    fn holds(&self, r: usize, x: &[f64]) -> bool {
        let (k, c, cmp) = self.0[r];
        cmp.holds(x[k] - c)
    }
}

/// Whether rule `r`'s jump set holds `x` at `at`: with `timer_sets` its
/// comparison (a group of N clocks would otherwise evaluate N compiled sets
/// at each jump), else the system's evaluation.
fn jump_set_holds<S: HybridSystem + ?Sized>(
    sys: &S,
    timer_sets: Option<&TimerSets>,
    r: usize,
    at: HybridTime,
    x: &[f64],
) -> bool {
    match timer_sets {
        Some(sets) => sets.holds(r, x),
        None => sys.jump_set(r, at, x),
    }
}

/// The members of each group of simultaneous rules, in declaration order.
struct Groups {
    /// (group label, members), sorted by label.
    members: Vec<(usize, Vec<usize>)>,
}

impl Groups {
    fn new(rules: &[super::JumpRule]) -> Self {
        let mut members: Vec<(usize, Vec<usize>)> = Vec::new();
        for (r, rule) in rules.iter().enumerate() {
            if let Some(g) = rule.group {
                match members.binary_search_by_key(&g, |(l, _)| *l) {
                    Ok(i) => members[i].1.push(r),
                    Err(i) => members.insert(i, (g, vec![r])),
                }
            }
        }
        Self { members }
    }

    /// The rules of `rule`'s group (including it), or `None` if it fires
    /// alone.
    #[inline]
    fn members_of(&self, rules: &[super::JumpRule], rule: usize) -> Option<&[usize]> {
        let g = rules[rule].group?;
        let i = self.members.binary_search_by_key(&g, |(l, _)| *l).ok()?;
        Some(&self.members[i].1)
    }
}

/// Simulates `sys` from `x0` at hybrid time (0, 0), pushing the solution
/// into `sink`; returns where and why it ended. See the
/// [module docs](super) for the semantics.
///
/// # Errors
/// [`SimError`] if the settings or the system are invalid, the state
/// becomes non-finite, or the integrator gives up. A run that reaches a
/// horizon, suspects Zeno behaviour, gets stuck or is stopped by the sink
/// is not an error: see [`TerminationCause`].
pub fn simulate<S: HybridSystem + ?Sized>(
    sys: &S,
    x0: &[f64],
    settings: &SimSettings,
    rng: &mut SimRng,
    sink: &mut dyn ArcSink,
) -> Result<Termination, SimError> {
    settings.validate()?;
    check_system(sys, x0)?;
    // A fault left by an evaluation outside a run is not this run's.
    let _ = sys.take_fault();
    let (method, modes) = method_for(sys, settings, x0)?;
    let n = x0.len();
    let rules = sys.jump_rules();
    // (rule, timer index, threshold) of the timer rules, if events are
    // watched; with flows first, of those whose timer bounds C (the flow
    // stops at their threshold whatever the priority).
    let timers: Vec<(usize, usize, f64)> = rules
        .iter()
        .enumerate()
        .filter_map(|(r, rule)| match rule.guard {
            GuardKind::Timer {
                index,
                threshold,
                bounds_flow,
            } if bounds_flow || settings.priority != Priority::Flows => Some((r, index, threshold)),
            _ => None,
        })
        .collect();
    // The rules whose timer bounds C: where one's jump set holds, no flow.
    let bounding: Vec<usize> = (0..rules.len())
        .filter(|&r| {
            matches!(
                rules[r].guard,
                GuardKind::Timer {
                    bounds_flow: true,
                    ..
                }
            )
        })
        .collect();
    let groups = Groups::new(rules);
    let jump_checks = JumpChecks::new(rules, n);
    let timer_sets = TimerSets::new(sys);
    let mut flow_set = FlowSetTest::new(sys);
    let mut flows = Flows::new(sys, settings, method, modes, x0)?;
    let accuracy = settings
        .solver
        .tolerances()
        .map_or(f64::NAN, |(rtol, _)| rtol);
    let mut out = Output::new(sink, settings.dt_out, x0, accuracy);
    let mut zeno = ZenoWatch::new(settings);
    let mut x = x0.to_vec();
    let mut x_plus = vec![0.0; n];
    let mut x_rule = vec![0.0; n];
    let mut firing: Vec<usize> = Vec::new();
    // The rules enabled at a point, for `JumpChoice::Random`.
    let mut choices: Vec<usize> = Vec::new();
    // The rule of the last jump, if it fired alone and no flow has moved
    // `x` since: `x_plus` then holds the pre-jump state, which differs from
    // `x` only where the rule writes (when it says where), and the next
    // jump refreshes only those components instead of copying the state.
    let mut last_alone: Option<usize> = None;
    let mut time = TimeSum::default();
    let mut j: u64 = 0;
    // Rule whose jump set the last flow segment reached (an equality atom
    // met inside the event bracket need not hold exactly at its end);
    // whether the last segment ended leaving C.
    let mut pending: Option<usize> = None;
    // Whether `pending` comes from a localized event, whose sets the flow's
    // watcher decided on the event's bracket.
    let mut from_event = false;
    let mut cannot_flow = false;
    let mut at_horizon = false;
    let mut timer_d = vec![f64::INFINITY; timers.len()];
    let mut timer_slack = vec![0.0; timers.len()];
    let mut inside = vec![false; rules.len()];

    // Every run that ends has a final sample of the state where it ended, a run a sink stopped
    // too (Ctrl-C): the sample that stopped it may lie before that point (a grid or dense point
    // of the last step) or be thinned out of a log. A run a sink failed has none, as a run the
    // engine fails.
    let finish = |out: &mut Output<'_>, at: HybridTime, x: &[f64], cause: TerminationCause| {
        let term = Termination { at, cause };
        if !out.sink.failed() {
            let _ = out.sink.sample(at, x, SampleKind::Final);
        }
        // The final sample's outputs.
        if let Some(f) = sys.take_fault() {
            return Err(f.into());
        }
        out.sink.finish(&term);
        Ok(term)
    };

    // Where the last flow started (W0603 tells a flow that left C where it
    // started from one that ran along C's boundary for a while).
    let mut flow_from = 0.0;
    // The last segment stopped at a chunk's end: the flow goes on.
    let mut flow_goes_on = false;
    if out
        .sink
        .sample(HybridTime::new(0.0, 0), &x, SampleKind::Initial)
        .is_break()
    {
        return finish(
            &mut out,
            HybridTime::new(0.0, 0),
            &x,
            TerminationCause::StoppedBySink,
        );
    }
    loop {
        // What the last segment or jump (its guards, maps, samples'
        // outputs) could not evaluate.
        if let Some(f) = sys.take_fault() {
            return Err(f.into());
        }
        let t = time.value();
        let at = HybridTime::new(t, j);
        if at_horizon || t >= settings.horizon_t {
            return finish(&mut out, at, &x, TerminationCause::HorizonT);
        }
        if j >= settings.horizon_j {
            return finish(&mut out, at, &x, TerminationCause::HorizonJ);
        }
        let was_pending = pending;
        let enabled = first_enabled(
            sys,
            at,
            &x,
            pending,
            last_alone,
            &mut inside,
            &mut flows.watcher,
            timer_sets.as_ref(),
        );
        pending = None;
        let after_event = std::mem::take(&mut from_event);
        let left_flow_set = std::mem::take(&mut cannot_flow);
        // An enabled rule with jumps first: the jump is taken whatever C
        // says, which is then not evaluated.
        let must_jump = enabled.is_some() && settings.priority == Priority::Jumps;
        // With no rule enabled the flow starts here if it may: C's atoms
        // are then read from the evaluation of every set that the
        // segment's start makes anyway.
        // On the threshold of a timer that bounds C: no flow from here.
        let on_bound = || {
            enabled.is_some()
                && bounding.iter().any(|&r| {
                    Some(r) == enabled || jump_set_holds(sys, timer_sets.as_ref(), r, at, &x)
                })
        };
        let can_flow = !left_flow_set && !must_jump && !on_bound() && {
            let known = match enabled {
                None => flows.watcher.prefetch(sys, at, &x),
                Some(_) => None,
            };
            flow_set.contains(sys, at, &x, settings.set_tol, known)
        };
        let jump = enabled.is_some()
            && (must_jump
                || !can_flow
                || match settings.priority {
                    Priority::Jumps => true,
                    Priority::Flows => false,
                    Priority::Random => rng.bernoulli(0.5),
                });
        if let (true, Some(first)) = (jump, enabled) {
            // Whether rule `r` is enabled here (`first` and `pending` known
            // to be; a set reached at the other end of an event's bracket,
            // the same instant within the event tolerance, counts), as the
            // members of a group are decided.
            let holds = |r: usize| {
                r == first
                    || Some(r) == was_pending
                    || (after_event && flows.watcher.reached_at_event(r))
                    || jump_set_holds(sys, timer_sets.as_ref(), r, at, &x)
            };
            let rule = match settings.jump_choice {
                JumpChoice::First => first,
                JumpChoice::Random => {
                    choices.clear();
                    choices.extend((0..rules.len()).filter(|&r| holds(r)));
                    draw_jump(rules, &choices, rng)
                }
            };
            if let Some(detail) = zeno.check(t, j) {
                let cause = TerminationCause::ZenoSuspected {
                    rule,
                    rule_name: rules[rule].name.clone(),
                    detail,
                };
                return finish(&mut out, at, &x, cause);
            }
            let post = HybridTime::new(t, j + 1);
            if out.sink.sample(at, &x, SampleKind::PreJump).is_break() {
                return finish(&mut out, at, &x, TerminationCause::StoppedBySink);
            }
            match last_alone.map(|r| &rules[r].writes) {
                Some(writes) if !writes.is_empty() => {
                    for &k in writes {
                        x_plus[k] = x[k];
                    }
                }
                _ => x_plus.copy_from_slice(&x),
            }
            firing.clear();
            match groups.members_of(rules, rule) {
                // One simultaneous jump: every enabled rule of the group,
                // each map on the pre-jump state, each writing its own
                // components.
                Some(members) => {
                    // A member is enabled at the pre-jump point, or at the
                    // other end of the event bracket (the same instant
                    // within the event tolerance).
                    // At most one rule per part: the enabling rule, then
                    // the first enabled of each other part (`first`), or
                    // one drawn among each part's enabled rules (`random`).
                    let part = |r: usize| rules[r].part;
                    match settings.jump_choice {
                        JumpChoice::First => {
                            firing.extend(members.iter().copied().filter(|&r| {
                                r == rule
                                    || (part(r).is_none_or(|p| Some(p) != part(rule))
                                        && (jump_set_holds(sys, timer_sets.as_ref(), r, at, &x)
                                            || (after_event && flows.watcher.reached_at_event(r))))
                            }));
                            let mut taken: Vec<usize> = Vec::new();
                            firing.retain(|&r| match part(r) {
                                None => true,
                                Some(p) if r == rule || !taken.contains(&p) => {
                                    taken.push(p);
                                    true
                                }
                                Some(_) => false,
                            });
                        }
                        // Every enabled member, then one drawn per part.
                        JumpChoice::Random => {
                            firing.extend(members.iter().copied().filter(|r| choices.contains(r)));
                            draw_parts(rules, &mut firing, rng);
                        }
                    }
                    for &r in &firing {
                        x_rule.copy_from_slice(&x);
                        sys.jump_map(r, at, &x, rng, &mut x_rule);
                        if let Some(f) = sys.take_fault() {
                            return Err(f.into());
                        }
                        if !jump_checks.finite(r, &x_rule)
                            && let Some(e) = check_jump_finite(sys, at, &x_rule, r)
                        {
                            return Err(e);
                        }
                        for &k in &rules[r].writes {
                            x_plus[k] = x_rule[k];
                        }
                    }
                }
                None => {
                    firing.push(rule);
                    sys.jump_map(rule, at, &x, rng, &mut x_plus);
                    if let Some(f) = sys.take_fault() {
                        return Err(f.into());
                    }
                    if !jump_checks.finite(rule, &x_plus)
                        && let Some(e) = check_jump_finite(sys, at, &x_plus, rule)
                    {
                        return Err(e);
                    }
                }
            }
            // One jump record per firing rule, all at (t, j) with the same
            // pre- and post-jump states.
            let mut stop = std::ops::ControlFlow::Continue(());
            for &r in &firing {
                if stop.is_continue() {
                    stop = out.sink.jump(at, r, &x, &x_plus);
                }
            }
            std::mem::swap(&mut x, &mut x_plus);
            last_alone = match firing[..] {
                [r] => Some(r),
                _ => None,
            };
            j += 1;
            zeno.jumped(t);
            if stop.is_break() || out.sink.sample(post, &x, SampleKind::PostJump).is_break() {
                return finish(&mut out, post, &x, TerminationCause::StoppedBySink);
            }
            continue;
        }
        if !can_flow {
            let cause = TerminationCause::CannotFlowOrJump {
                leaving: left_flow_set,
                failed: flow_set.failed_atoms(sys, at, &x),
                state: x.clone(),
                flow_from: if left_flow_set { flow_from } else { t },
            };
            return finish(&mut out, at, &x, cause);
        }

        // Flow until the next timer event, the horizon, or a localized event.
        let f0 = flows.start(sys, time, j, &x)?;
        let mut d_end = settings.horizon_t - t;
        let mut horizon_bound = true;
        for (k, &(_, index, threshold)) in timers.iter().enumerate() {
            let (v, rate) = (x[index], f0[index]);
            let d = if (rate > 0.0 && v < threshold) || (rate < 0.0 && v > threshold) {
                (threshold - v) / rate
            } else {
                f64::INFINITY
            };
            timer_d[k] = d;
            timer_slack[k] = super::events::timer_slack(v, threshold, rate);
            if d < d_end {
                d_end = d;
                horizon_bound = false;
            }
        }
        // The sets' timer atoms: when the first reaches its threshold, or
        // C left at once.
        match flows.schedule_timers(&x) {
            None => {
                cannot_flow = true;
                continue;
            }
            Some(d) if d < d_end => {
                d_end = d;
                horizon_bound = false;
            }
            Some(_) => {}
        }
        if horizon_bound {
            d_end = to_horizon(time, settings.horizon_t);
        }
        // The flow moves `x` (`x_plus` is no longer one jump from it).
        last_alone = None;
        // A failed evaluation in the flow map makes its NaN an integrator
        // failure; the fault says why.
        if !std::mem::take(&mut flow_goes_on) {
            flow_from = t;
        }
        out.segment_end(time.at(d_end));
        let end = flows
            .segment(sys, &mut out, rng, t, j, &mut x, d_end)
            .map_err(|e| sys.take_fault().map_or(e, SimError::from))?;
        time.add(end.s);
        match end.why {
            EndWhy::Reached if horizon_bound => at_horizon = true,
            EndWhy::Reached => {
                // The timers that fire now land exactly on their threshold,
                // those due within the rounding of their schedule too (each
                // then fires at this `t`, in declaration order); so do those
                // of grouped rules due within the event tolerance, which
                // fire in the same simultaneous jump.
                // (Read by grouped rules only.)
                let tol = || {
                    settings
                        .event_tol
                        .max(4.0 * f64::EPSILON * time.value().abs())
                };
                for (k, &(r, index, threshold)) in timers.iter().enumerate() {
                    let late = timer_d[k] - d_end;
                    let grouped = rules[r].group.is_some() && late <= tol();
                    if late <= timer_slack[k] || grouped {
                        x[index] = threshold;
                        // On its threshold, the rule's set holds.
                        pending = Some(pending.map_or(r, |p| p.min(r)));
                    }
                }
                for (index, threshold) in flows.watcher.timers_due(d_end) {
                    x[index] = threshold;
                }
            }
            EndWhy::Partial => flow_goes_on = true,
            EndWhy::Event(kind) => {
                match kind {
                    EventKind::Jump(r) => {
                        pending = Some(r);
                        // Met where the flow leaves C: no flow from there,
                        // so `Priority::Random`'s coin cannot choose one
                        // (it flowed on through C's relaxation, `set_tol`
                        // outside C, before jumping).
                        cannot_flow = flows.watcher.left_at_event();
                    }
                    EventKind::LeftFlowSet => {
                        cannot_flow = true;
                        pending = flows.watcher.rule_at_event();
                    }
                }
                from_event = true;
                // Timers due at the event's time within the rounding of
                // their schedule expire there too (their rules are then
                // enabled at this point, in declaration order).
                for (k, &(_, index, threshold)) in timers.iter().enumerate() {
                    let late = timer_d[k] - end.s;
                    if (0.0..=timer_slack[k]).contains(&late) {
                        x[index] = threshold;
                    }
                }
                for (index, threshold) in flows.watcher.timers_due(end.s) {
                    x[index] = threshold;
                }
            }
            EndWhy::Stopped => {
                let at = HybridTime::new(time.value(), j);
                return finish(&mut out, at, &x, TerminationCause::StoppedBySink);
            }
        }
    }
}

/// The first rule (in declaration order) whose jump set holds `x` at `at`,
/// `pending` (a rule known to hold: a timer on its threshold, a localized
/// event) counting as holding. With a pending rule, the rules before it are
/// asked one by one (none, for the first rule: a noise redraw); otherwise
/// all sets at once if the system offers it (`inside` its scratch, which
/// keeps the sets a jump by `jumped` alone, the last step, cannot change;
/// with the atoms a flow segment started here reads, kept by `watcher`),
/// else, or if that evaluation reported a fault, rule by rule. With
/// `timer_sets` every set is a comparison, made here unless the sets'
/// evaluation also serves the segment's start.
#[allow(clippy::too_many_arguments)]
fn first_enabled<S: HybridSystem + ?Sized>(
    sys: &S,
    at: HybridTime,
    x: &[f64],
    pending: Option<usize>,
    jumped: Option<usize>,
    inside: &mut [bool],
    watcher: &mut Watcher,
    timer_sets: Option<&TimerSets>,
) -> Option<usize> {
    let holds = |r: usize| jump_set_holds(sys, timer_sets, r, at, x);
    if let Some(p) = pending {
        return (0..p).find(|&r| holds(r)).or(Some(p));
    }
    if timer_sets.is_some() && !watcher.prefetches() {
        return (0..inside.len()).find(|&r| holds(r));
    }
    // On a fault, a set after the first enabled one may be what failed.
    if (watcher.prefetch_sets(sys, at, x, inside, jumped) || sys.jump_sets(at, x, inside))
        && sys.take_fault().is_none()
    {
        return (0..inside.len()).find(|&r| inside[r]);
    }
    watcher.forget_prefetch();
    (0..inside.len()).find(|&r| sys.jump_set(r, at, x))
}

/// A jump drawn uniformly among the enabled rules `enabled` (ascending,
/// not empty): a rule that fires alone counts once, a group once (for a
/// group, its first enabled member is returned; which rules of it fire is
/// drawn by [`draw_parts`]). Nothing is drawn when there is one jump.
fn draw_jump(rules: &[super::JumpRule], enabled: &[usize], rng: &mut SimRng) -> usize {
    // The first enabled rule of each jump.
    let mut jumps: Vec<usize> = Vec::with_capacity(enabled.len());
    for (i, &r) in enabled.iter().enumerate() {
        let g = rules[r].group;
        if g.is_none() || !enabled[..i].iter().any(|&o| rules[o].group == g) {
            jumps.push(r);
        }
    }
    match jumps[..] {
        [r] => r,
        _ => jumps[rng.index(jumps.len())],
    }
}

/// Keeps one rule per part among the enabled rules of a group `firing`
/// (ascending), drawn uniformly where a part has several (a part's rules
/// are its subsystem's alternatives); rules without a part all stay.
fn draw_parts(rules: &[super::JumpRule], firing: &mut Vec<usize>, rng: &mut SimRng) {
    let mut i = 0;
    while i < firing.len() {
        let Some(p) = rules[firing[i]].part else {
            i += 1;
            continue;
        };
        let same: Vec<usize> = firing[i..]
            .iter()
            .copied()
            .filter(|&r| rules[r].part == Some(p))
            .collect();
        let keep = match same[..] {
            [r] => r,
            _ => same[rng.index(same.len())],
        };
        firing.retain(|&r| r == keep || rules[r].part != Some(p));
        i = firing.iter().position(|&r| r == keep).map_or(i, |k| k + 1);
    }
}

/// The flow time from `time` to the horizon `horizon_t`, rounded so that the
/// clock lands on the horizon exactly (`horizon_t − t` alone can leave it an
/// ulp short after segments of rounded lengths, and the run would end at
/// 0.29999999999999993 for T = 0.3).
fn to_horizon(time: TimeSum, horizon_t: f64) -> f64 {
    let mut d = horizon_t - time.value();
    // The clock is monotone in d and moves by at least an ulp of the sum per
    // ulp of d near the horizon: a step or two settles it.
    for _ in 0..4 {
        let at = time.at(d);
        if at < horizon_t {
            d = d.next_up();
        } else if at > horizon_t && d.next_down() > 0.0 && time.at(d.next_down()) >= horizon_t {
            d = d.next_down();
        } else {
            break;
        }
    }
    d
}

/// Like [`simulate`], collecting the solution in memory.
///
/// # Errors
/// As [`simulate`].
pub fn simulate_arc<S: HybridSystem + ?Sized>(
    sys: &S,
    x0: &[f64],
    settings: &SimSettings,
    rng: &mut SimRng,
) -> Result<HybridArc, SimError> {
    let names = sys.jump_rules().iter().map(|r| r.name.clone()).collect();
    let mut arc = HybridArc::new(sys.state_dim(), names);
    simulate(sys, x0, settings, rng, &mut arc)?;
    Ok(arc)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zeno_watch_counts_rate_over_the_window_and_total() {
        let s = SimSettings::default()
            .zeno_window(3)
            .zeno_max_rate(10.0)
            .max_total_jumps(100);
        let mut z = ZenoWatch::new(&s);
        // The last 3 jumps made and the next one must span at least 3/10
        // of ordinary time.
        let mut j = 0;
        for t in [0.0, 0.1, 0.35, 0.5] {
            assert_eq!(z.check(t, j), None, "at {t}");
            z.jumped(t);
            j += 1;
        }
        // Jumps at 0.1, 0.35, 0.5 made, the next at 0.6: within 0.5 < 0.3? no.
        assert_eq!(z.check(0.6, j), None);
        z.jumped(0.6);
        j += 1;
        // Jumps at 0.35, 0.5, 0.6 made, the next at 0.62: 0.27 < 0.3.
        assert!(
            matches!(z.check(0.62, j), Some(ZenoDetail::Rate { jumps: 3, within }) if (within - 0.27).abs() < 1e-15)
        );
        assert_eq!(
            z.check(5.0, 100),
            Some(ZenoDetail::TotalJumps { limit: 100 })
        );
        // An infinite rate disables the rate guard, even for simultaneous jumps.
        let mut z = ZenoWatch::new(&s.clone().zeno_max_rate(f64::INFINITY));
        for j in 0..10 {
            assert!(z.check(1.0, j).is_none());
            z.jumped(1.0);
        }
        // A finite horizon J switches both guards off: J is the budget.
        let mut z = ZenoWatch::new(&s.clone().horizon_j(1000));
        for j in 0..500 {
            assert!(z.check(1.0, j).is_none());
            z.jumped(1.0);
        }
    }
}
