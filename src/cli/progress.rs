//! The progress bar on stderr, the Ctrl-C flag, and the counts behind the
//! one-line summary, all in one sink that sees every sample.

use std::ops::ControlFlow;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use hybsim::arc::{ArcSink, HybridTime, SampleKind, SolverSwitch};
use hybsim::sinks::Tally;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// Ticks of the progress bar (its length).
const TICKS: u64 = 1000;

/// Installs a handler of Ctrl-C (SIGINT), SIGTERM and SIGHUP that sets the
/// returned flag, so that the run stops at its next sample and every output
/// file is completed (once per process; later calls return a flag that is
/// never set).
pub fn interrupt_flag() -> Arc<AtomicBool> {
    let flag = Arc::new(AtomicBool::new(false));
    let f = flag.clone();
    // Fails only if a handler is already installed; the run then simply
    // cannot be interrupted gracefully.
    let _ = ctrlc::set_handler(move || f.store(true, Ordering::SeqCst));
    flag
}

/// Shows progress towards the horizons, stops the run on Ctrl-C, and
/// counts samples and jumps.
pub struct Progress {
    bar: ProgressBar,
    horizon_t: f64,
    horizon_j: u64,
    position: u64,
    /// Whether the bar is drawn (stderr a terminal and `show`): a hidden
    /// bar is not updated (its message was formatted at every tick).
    drawn: bool,
    interrupted: Arc<AtomicBool>,
    /// Samples and jumps of the run.
    pub tally: Tally,
}

impl Progress {
    /// A progress sink for a run with horizons `horizon_t`, `horizon_j` and
    /// `rules` jump rules. The bar is drawn on stderr only if it is a
    /// terminal and `show` is set.
    pub fn new(
        horizon_t: f64,
        horizon_j: u64,
        rules: usize,
        show: bool,
        interrupted: Arc<AtomicBool>,
    ) -> Self {
        let target = if show {
            ProgressDrawTarget::stderr_with_hz(10)
        } else {
            ProgressDrawTarget::hidden()
        };
        let bar = ProgressBar::with_draw_target(Some(TICKS), target);
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {wide_bar} {percent:>3}% {msg}",
            )
            .expect("a valid template"),
        );
        Self {
            drawn: !bar.is_hidden(),
            bar,
            horizon_t,
            horizon_j,
            position: 0,
            interrupted,
            tally: Tally::new(rules),
        }
    }

    /// Whether Ctrl-C stopped the run.
    pub fn was_interrupted(&self) -> bool {
        self.interrupted.load(Ordering::SeqCst)
    }

    /// Removes the bar.
    pub fn clear(&self) {
        self.bar.finish_and_clear();
    }

    fn update(&mut self, at: HybridTime) {
        if !self.drawn {
            return;
        }
        let ft = if self.horizon_t.is_finite() && self.horizon_t > 0.0 {
            at.t / self.horizon_t
        } else {
            0.0
        };
        let fj = if self.horizon_j > 0 && self.horizon_j < u64::MAX {
            at.j as f64 / self.horizon_j as f64
        } else {
            0.0
        };
        let position = (ft.max(fj).clamp(0.0, 1.0) * TICKS as f64) as u64;
        if position > self.position {
            self.position = position;
            self.bar.set_position(position);
            self.bar
                .set_message(format!("t = {:.6}, j = {}", at.t, at.j));
        }
    }
}

impl ArcSink for Progress {
    fn sample(&mut self, at: HybridTime, _x: &[f64], _kind: SampleKind) -> ControlFlow<()> {
        self.tally.sample(at);
        self.update(at);
        if self.interrupted.load(Ordering::Relaxed) {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    }

    fn jump(
        &mut self,
        _at: HybridTime,
        rule: usize,
        _pre: &[f64],
        _post: &[f64],
    ) -> ControlFlow<()> {
        self.tally.jump(rule);
        ControlFlow::Continue(())
    }

    fn solver_switch(&mut self, switch: &SolverSwitch) {
        self.tally.solver_switch(switch);
    }

    /// Counts only: a run without files computes no dense points.
    fn wants_dense_points(&self) -> bool {
        false
    }

    fn poll(&mut self) -> ControlFlow<()> {
        match self.interrupted.load(Ordering::Relaxed) {
            true => ControlFlow::Break(()),
            false => ControlFlow::Continue(()),
        }
    }
}
