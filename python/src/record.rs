//! The sink a Python run writes into: flat column buffers that become numpy
//! arrays without a copy, and the Ctrl-C check.

use std::ops::ControlFlow;
use std::time::{Duration, Instant};

use hybsim::arc::{ArcSink, HybridTime, SampleKind, SolverSwitch, Termination};
use hybsim::lang::CompiledModel;
use pyo3::prelude::*;

/// Names of the sample kinds, indexed by the codes of [`kind_code`] (the
/// CSV sink's words).
pub const SAMPLE_KINDS: [&str; 5] = ["initial", "flow", "pre_jump", "post_jump", "final"];

/// The code of a sample kind (index into [`SAMPLE_KINDS`]).
pub fn kind_code(kind: SampleKind) -> u8 {
    match kind {
        SampleKind::Initial => 0,
        SampleKind::Flow => 1,
        SampleKind::PreJump => 2,
        SampleKind::PostJump => 3,
        SampleKind::Final => 4,
    }
}

/// How often a detached run looks for a pending Ctrl-C: every this many
/// samples it reads the clock, and at most every [`POLL_EVERY`] it takes the
/// GIL to run Python's signal handlers.
const POLL_SAMPLES: u32 = 256;
const POLL_EVERY: Duration = Duration::from_millis(50);

/// Polls Python's signal handlers from a thread that released the GIL.
pub struct Interrupt {
    countdown: u32,
    last: Instant,
    /// The exception a handler raised (KeyboardInterrupt), if any.
    pub raised: Option<PyErr>,
}

impl Interrupt {
    pub fn new() -> Self {
        Self {
            countdown: POLL_SAMPLES,
            last: Instant::now(),
            raised: None,
        }
    }

    /// `Break` once a signal handler raised.
    pub fn poll(&mut self) -> ControlFlow<()> {
        self.countdown -= 1;
        if self.countdown > 0 {
            return ControlFlow::Continue(());
        }
        self.countdown = POLL_SAMPLES;
        if self.last.elapsed() < POLL_EVERY {
            return ControlFlow::Continue(());
        }
        self.last = Instant::now();
        match Python::attach(|py| py.check_signals()) {
            Ok(()) => ControlFlow::Continue(()),
            Err(e) => {
                self.raised = Some(e);
                ControlFlow::Break(())
            }
        }
    }
}

/// A solution as columns: what `Model.run` turns into numpy arrays.
pub struct Recorder {
    /// The state components recorded, in order: the user's states (see [`user_states`]).
    pub columns: Vec<usize>,
    /// `columns` is every component in state order (no timers): rows are copied whole.
    whole: bool,
    pub t: Vec<f64>,
    pub j: Vec<i64>,
    pub kind: Vec<u8>,
    pub x: Vec<f64>,
    pub jump_rule: Vec<i64>,
    pub jump_t: Vec<f64>,
    pub jump_j: Vec<i64>,
    /// Row (sample index) of each jump's pre-jump sample; its post-jump
    /// sample is the next row. The engine sends `PreJump`, the jumps, then
    /// `PostJump`, with the jumps' pre and post states equal to those
    /// samples, so the states are not stored twice (on the 10-s consensus
    /// run that copy was half a gigabyte).
    pub jump_row: Vec<i64>,
    pub termination: Option<Termination>,
    /// The integrator changes of `solver = auto`, in order.
    pub switches: Vec<SolverSwitch>,
    pub interrupt: Interrupt,
    /// The samples stopped fitting in memory: the run was stopped there (a failed allocation
    /// would abort the interpreter).
    pub out_of_memory: bool,
}

/// The state components a solution shows and their names, as `hybsim run --csv` writes them:
/// the model's state layout, which leaves out the timers the language adds for `every` and held
/// `noise`, and groups the members of instance families.
pub fn user_states(model: &CompiledModel) -> (Vec<usize>, Vec<String>) {
    model.state_layout().components().into_iter().unzip()
}

impl Recorder {
    /// Records the state components `columns` of a system with `dim` of them.
    pub fn new(columns: Vec<usize>, dim: usize) -> Self {
        let whole = columns.len() == dim && columns.iter().enumerate().all(|(i, &k)| i == k);
        Self {
            columns,
            whole,
            t: Vec::new(),
            j: Vec::new(),
            kind: Vec::new(),
            x: Vec::new(),
            jump_rule: Vec::new(),
            jump_t: Vec::new(),
            jump_j: Vec::new(),
            jump_row: Vec::new(),
            termination: None,
            switches: Vec::new(),
            interrupt: Interrupt::new(),
            out_of_memory: false,
        }
    }

    /// Room for one more sample in every column, or `false` if the memory is not there.
    fn room(&mut self) -> bool {
        self.t.try_reserve(1).is_ok()
            && self.j.try_reserve(1).is_ok()
            && self.kind.try_reserve(1).is_ok()
            && self.x.try_reserve(self.columns.len()).is_ok()
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t.len()
    }
}

impl ArcSink for Recorder {
    fn sample(&mut self, at: HybridTime, x: &[f64], kind: SampleKind) -> ControlFlow<()> {
        if self.out_of_memory || !self.room() {
            self.out_of_memory = true;
            return ControlFlow::Break(());
        }
        self.t.push(at.t);
        // numpy's default integer; j < 2^63 always.
        self.j.push(at.j as i64);
        self.kind.push(kind_code(kind));
        if self.whole {
            self.x.extend_from_slice(x);
        } else {
            self.x.extend(self.columns.iter().map(|&k| x[k]));
        }
        self.interrupt.poll()
    }

    fn jump(&mut self, at: HybridTime, rule: usize, pre: &[f64], _post: &[f64]) -> ControlFlow<()> {
        let room = self.jump_rule.try_reserve(1).is_ok()
            && self.jump_t.try_reserve(1).is_ok()
            && self.jump_j.try_reserve(1).is_ok()
            && self.jump_row.try_reserve(1).is_ok();
        if self.out_of_memory || !room {
            self.out_of_memory = true;
            return ControlFlow::Break(());
        }
        self.jump_rule.push(rule as i64);
        self.jump_t.push(at.t);
        self.jump_j.push(at.j as i64);
        // The pre-jump sample is the last row; the post-jump sample comes next.
        let row = self.t.len().saturating_sub(1);
        debug_assert!(
            self.x[row * self.columns.len()..]
                .iter()
                .zip(self.columns.iter().map(|&k| pre[k]))
                .all(|(a, b)| a.to_bits() == b.to_bits())
        );
        self.jump_row.push(row as i64);
        ControlFlow::Continue(())
    }

    fn finish(&mut self, termination: &Termination) {
        self.termination = Some(termination.clone());
    }

    fn solver_switch(&mut self, switch: &SolverSwitch) {
        self.switches.push(*switch);
    }

    fn poll(&mut self) -> ControlFlow<()> {
        self.interrupt.poll()
    }
}
