//! Helpers shared by the benches that compare CPU time with a reference in
//! the same minutes (`limit`, `tables`, `stiff`, `sparse`).

use std::ops::ControlFlow;
use std::time::Instant;

use hybsim::arc::{ArcSink, HybridTime, SampleKind, SolverSwitch};

/// CPU time of this thread in seconds. `CLOCK_THREAD_CPUTIME_ID` adds the
/// time since the last scheduler tick; `/proc/thread-self/schedstat` does
/// not, and moves in 4 ms steps on some kernels (too coarse for runs of
/// tens of µs).
pub fn cpu_now() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid timespec for clock_gettime to fill.
    if unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) } == 0 {
        return ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9;
    }
    thread_local!(static T0: Instant = Instant::now());
    T0.with(|t| t.elapsed().as_secs_f64())
}

/// The median of `v` (the upper one for an even count).
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The final state, the jump times and the solver switches.
#[derive(Default)]
#[allow(dead_code)] // each bench compiles this module; `limit` and `tables` keep their own tallies
pub struct Keep {
    pub last: Vec<f64>,
    pub jumps: Vec<f64>,
    pub switches: usize,
}

impl ArcSink for Keep {
    fn sample(&mut self, _: HybridTime, x: &[f64], kind: SampleKind) -> ControlFlow<()> {
        if kind == SampleKind::Final {
            self.last.clear();
            self.last.extend_from_slice(x);
        }
        ControlFlow::Continue(())
    }

    fn jump(&mut self, at: HybridTime, _: usize, _: &[f64], _: &[f64]) -> ControlFlow<()> {
        self.jumps.push(at.t);
        ControlFlow::Continue(())
    }

    fn solver_switch(&mut self, _: &SolverSwitch) {
        self.switches += 1;
    }
}
