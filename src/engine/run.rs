//! The hybrid loop: decide between flowing and jumping, run flow segments,
//! apply jump maps, watch the horizons and the Zeno guards.

use std::collections::VecDeque;

use super::HybridSystem;
use super::error::SimError;
use super::events::EventKind;
use super::flow::{Affine, EndWhy, Flows, Method, Output, check_finite};
use super::settings::{Priority, SimSettings, Solver};
use super::system::{FlowStructure, GuardKind, SimRng};
use crate::arc::{
    ArcSink, HybridArc, HybridTime, SampleKind, Termination, TerminationCause, ZenoDetail,
};

/// Ordinary time as a compensated (Neumaier) sum of segment lengths, so that
/// thousands of short segments do not accumulate rounding.
#[derive(Debug, Clone, Copy, Default)]
struct TimeSum {
    sum: f64,
    comp: f64,
}

impl TimeSum {
    fn add(&mut self, x: f64) {
        let t = self.sum + x;
        if self.sum.abs() >= x.abs() {
            self.comp += (self.sum - t) + x;
        } else {
            self.comp += (x - t) + self.sum;
        }
        self.sum = t;
    }

    fn value(&self) -> f64 {
        self.sum + self.comp
    }
}

/// The last `window` jump times, to estimate the jump rate.
struct ZenoWatch {
    times: VecDeque<f64>,
    window: usize,
    max_rate: f64,
    max_total: u64,
}

impl ZenoWatch {
    fn new(s: &SimSettings) -> Self {
        let window = s.zeno_window as usize;
        Self {
            times: VecDeque::with_capacity(window + 1),
            window,
            max_rate: s.zeno_max_rate,
            max_total: s.max_total_jumps,
        }
    }

    /// Called before jump number `j + 1` at time `t`.
    fn check(&mut self, t: f64, j: u64) -> Option<ZenoDetail> {
        if j >= self.max_total {
            return Some(ZenoDetail::TotalJumps {
                limit: self.max_total,
            });
        }
        self.times.push_back(t);
        if self.times.len() > self.window {
            self.times.pop_front();
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
}

fn method_for<S: HybridSystem + ?Sized>(
    sys: &S,
    settings: &SimSettings,
) -> Result<Method, SimError> {
    let noise_dim = sys.noise_dim();
    if let Solver::EulerMaruyama { h } = settings.solver {
        return Ok(Method::EulerMaruyama { h });
    }
    if noise_dim > 0 {
        return Err(SimError::NoiseNeedsEulerMaruyama { noise_dim });
    }
    if settings.exact_affine
        && let FlowStructure::Affine { a, b } = sys.flow_structure()
    {
        return Ok(Method::Affine(Box::new(Affine::new(
            sys.state_dim(),
            &a,
            &b,
        )?)));
    }
    Ok(Method::Ode(settings.solver))
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
    for (i, rule) in sys.jump_rules().iter().enumerate() {
        if let GuardKind::Timer { index, threshold } = rule.guard
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
    let method = method_for(sys, settings)?;
    let n = x0.len();
    let rules = sys.jump_rules();
    // (rule, timer index, threshold) of the timer rules, if events are watched.
    let timers: Vec<(usize, usize, f64)> = if settings.priority == Priority::Flows {
        Vec::new()
    } else {
        rules
            .iter()
            .enumerate()
            .filter_map(|(r, rule)| match rule.guard {
                GuardKind::Timer { index, threshold } => Some((r, index, threshold)),
                GuardKind::General => None,
            })
            .collect()
    };
    let mut flows = Flows::new(sys, settings, method, x0);
    let mut out = Output::new(sink, settings.dt_out, n);
    let mut zeno = ZenoWatch::new(settings);
    let mut x = x0.to_vec();
    let mut x_plus = vec![0.0; n];
    let mut time = TimeSum::default();
    let mut j: u64 = 0;
    // Rule localized by the last flow segment (its pre-crossing point may
    // sit a few ulp outside D); whether the last segment ended leaving C.
    let mut pending: Option<usize> = None;
    let mut cannot_flow = false;
    let mut at_horizon = false;
    let mut timer_d = vec![f64::INFINITY; timers.len()];

    let finish = |out: &mut Output<'_>, at: HybridTime, x: &[f64], cause: TerminationCause| {
        let term = Termination { at, cause };
        if term.cause != TerminationCause::StoppedBySink {
            let _ = out.sink.sample(at, x, SampleKind::Final);
        }
        out.sink.finish(&term);
        Ok(term)
    };

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
        let t = time.value();
        let at = HybridTime::new(t, j);
        if at_horizon || t >= settings.horizon_t {
            return finish(&mut out, at, &x, TerminationCause::HorizonT);
        }
        if j >= settings.horizon_j {
            return finish(&mut out, at, &x, TerminationCause::HorizonJ);
        }
        let enabled = (0..rules.len()).find(|&r| pending == Some(r) || sys.jump_set(r, t, &x));
        pending = None;
        let can_flow = !std::mem::take(&mut cannot_flow) && sys.flow_set(t, &x);
        let jump = enabled.is_some()
            && (!can_flow
                || match settings.priority {
                    Priority::Jumps => true,
                    Priority::Flows => false,
                    Priority::Random => rng.bernoulli(0.5),
                });
        if let (true, Some(rule)) = (jump, enabled) {
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
            x_plus.copy_from_slice(&x);
            sys.jump_map(rule, at, &x, rng, &mut x_plus);
            if let Some(e) = check_finite(sys, post, &x_plus, Some(rule)) {
                return Err(e);
            }
            let stop = out.sink.jump(at, rule, &x, &x_plus);
            std::mem::swap(&mut x, &mut x_plus);
            j += 1;
            if stop.is_break() || out.sink.sample(post, &x, SampleKind::PostJump).is_break() {
                return finish(&mut out, post, &x, TerminationCause::StoppedBySink);
            }
            continue;
        }
        if !can_flow {
            return finish(&mut out, at, &x, TerminationCause::CannotFlowOrJump);
        }

        // Flow until the next timer event, the horizon, or a localized event.
        let f0 = flows.start(sys, t, &x);
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
            if d < d_end {
                d_end = d;
                horizon_bound = false;
            }
        }
        let end = flows.segment(sys, &mut out, rng, t, j, &mut x, d_end)?;
        time.add(end.s);
        match end.why {
            EndWhy::Reached if horizon_bound => at_horizon = true,
            EndWhy::Reached => {
                // The timers that fire now land exactly on their threshold.
                for (k, &(_, index, threshold)) in timers.iter().enumerate() {
                    if timer_d[k] == d_end {
                        x[index] = threshold;
                    }
                }
            }
            EndWhy::Partial => {}
            EndWhy::Event(EventKind::Jump(r)) => pending = Some(r),
            EndWhy::Event(EventKind::LeftFlowSet) => {
                cannot_flow = true;
                let post = flows.event_post_state();
                let t_post = time.value();
                pending = (0..rules.len()).find(|&r| sys.jump_set(r, t_post, post));
            }
            EndWhy::Stopped => {
                let at = HybridTime::new(time.value(), j);
                return finish(&mut out, at, &x, TerminationCause::StoppedBySink);
            }
        }
    }
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
    fn compensated_time_sum_does_not_drift() {
        let mut t = TimeSum::default();
        let mut naive = 0.0;
        for _ in 0..1_000_000 {
            t.add(0.1);
            naive += 0.1;
        }
        assert!((t.value() - 100_000.0).abs() < 1e-9);
        // The naive sum is off by ~1e-6: the compensated one is 1000x better.
        assert!((naive - 100_000.0_f64).abs() > 1e-7);
    }

    #[test]
    fn zeno_watch_counts_rate_over_the_window_and_total() {
        let s = SimSettings::default()
            .zeno_window(3)
            .zeno_max_rate(10.0)
            .max_total_jumps(100);
        let mut z = ZenoWatch::new(&s);
        // The last 3 jumps must span at least 3/10 of ordinary time.
        assert_eq!(z.check(0.0, 0), None);
        assert_eq!(z.check(0.1, 1), None);
        assert_eq!(z.check(0.35, 2), None);
        assert_eq!(z.check(0.5, 3), None);
        assert!(
            matches!(z.check(0.6, 4), Some(ZenoDetail::Rate { jumps: 3, within }) if (within - 0.25).abs() < 1e-15)
        );
        assert_eq!(
            z.check(5.0, 100),
            Some(ZenoDetail::TotalJumps { limit: 100 })
        );
        // An infinite rate disables the rate guard, even for simultaneous jumps.
        let mut z = ZenoWatch::new(&s.clone().zeno_max_rate(f64::INFINITY));
        assert!((0..10).all(|j| z.check(1.0, j).is_none()));
    }
}
