//! Hybrid time and hybrid arcs: the solution objects the engine produces.
//!
//! A solution of a hybrid system lives on a *hybrid time domain*: a union of
//! intervals `[t_j, t_{j+1}] × {j}`. Ordinary time `t` advances while the
//! solution flows; the jump counter `j` advances by one at each jump, with `t`
//! unchanged. A [`HybridArc`] stores samples `(t, j, x)` in domain order, the
//! record of every jump, and why the solution ended.

use serde::Serialize;

/// A point of a hybrid time domain: ordinary time `t` and jump count `j`.
#[derive(Debug, Clone, Copy, PartialEq, PartialOrd, Serialize)]
pub struct HybridTime {
    /// Ordinary (continuous) time.
    pub t: f64,
    /// Number of jumps taken so far.
    pub j: u64,
}

impl HybridTime {
    /// The hybrid time `(t, j)`.
    pub const fn new(t: f64, j: u64) -> Self {
        Self { t, j }
    }
}

impl std::fmt::Display for HybridTime {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "(t = {}, j = {})", self.t, self.j)
    }
}

/// Where a sample sits on the hybrid time domain.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SampleKind {
    /// The initial point (0, 0) of the solution.
    Initial,
    /// A point inside a flow interval (integrator step or output grid).
    Flow,
    /// The last point of a flow interval, just before a jump.
    PreJump,
    /// The first point after a jump.
    PostJump,
    /// The last point of the solution.
    Final,
}

/// One jump: which rule fired, where, and the state on both sides.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct JumpRecord {
    /// Hybrid time of the pre-jump point; the post-jump point is `(t, j + 1)`.
    pub at: HybridTime,
    /// Index of the rule in [`crate::engine::HybridSystem::jump_rules`].
    pub rule: usize,
    /// State before the jump.
    pub pre: Vec<f64>,
    /// State after the jump.
    pub post: Vec<f64>,
}

/// Receives a solution as it is computed. The engine pushes samples and
/// jumps in hybrid-time order; a sink may stop the run by returning
/// [`std::ops::ControlFlow::Break`].
pub trait ArcSink {
    /// A sample `(t, j, x)`.
    fn sample(&mut self, at: HybridTime, x: &[f64], kind: SampleKind) -> std::ops::ControlFlow<()>;
    /// A jump of rule `rule` (index into the system's jump rules) at the
    /// pre-jump time `at`, pushed between its `PreJump` and `PostJump`
    /// samples. Slices, not a [`JumpRecord`], so that sinks that do not keep
    /// jumps cost no allocation.
    fn jump(
        &mut self,
        at: HybridTime,
        rule: usize,
        pre: &[f64],
        post: &[f64],
    ) -> std::ops::ControlFlow<()>;
}
