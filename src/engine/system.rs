//! The hybrid-system trait: the only thing the engine knows about a model.
//!
//! A hybrid system in the Goebel–Sanfelice–Teel form
//!
//! ```text
//!     ẋ = f(x)      while x ∈ C          (flow)
//!     x⁺ ∈ G(x)     when  x ∈ D          (jump)
//! ```
//!
//! Every method also receives the hybrid time `(t, j)` ([`HybridTime`]), as
//! HyEQ's f(x, t, j), C(x, t, j), g(x, t, j), D(x, t, j): models that do not
//! depend on time ignore it.
//!
//! maps to the methods of [`HybridSystem`]:
//!
//! | symbol | method |
//! |---|---|
//! | dimension of x | [`HybridSystem::state_dim`], names in [`HybridSystem::state_names`] |
//! | f | [`HybridSystem::flow_map`] |
//! | C | [`HybridSystem::flow_set`] (predicate) + [`HybridSystem::flow_guard`] (continuous, ≥ 0 inside C) |
//! | D = ∪ D_i | one [`JumpRule`] per `i`: [`HybridSystem::jump_set`] (predicate) + [`HybridSystem::jump_guard`] (continuous, ≥ 0 on D_i's side) |
//! | G = G_i on D_i | [`HybridSystem::jump_map`], set-valued through the seeded [`SimRng`] |
//!
//! Guards are continuous functions whose zero crossings mark the boundary of
//! a set, so that the engine can localize the first time a flow reaches `D_i`
//! (or leaves `C`) by root finding. The predicates are authoritative for
//! membership; the guards only tell the engine where to look.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::arc::HybridTime;

/// A named jump rule: one piece `D_i`, `G_i` of the jump set and jump map.
#[derive(Debug, Clone, PartialEq)]
pub struct JumpRule {
    /// Name used in logs, jump records and error messages (e.g. `impact`,
    /// `transmit[2]`).
    pub name: String,
    /// How the engine may find this rule's events; see [`GuardKind`].
    pub guard: GuardKind,
    /// The group of simultaneous rules this rule belongs to (`None`: fires
    /// alone). When a rule of group `g` fires, every rule of `g` whose jump
    /// set holds at the same pre-jump point fires with it as **one** jump
    /// (j + 1): each jump map is evaluated at the pre-jump state, and the
    /// post-jump state takes component `k` from the rule whose
    /// [`writes`](Self::writes) contains `k` (the others keep their value),
    /// as HyEQ's `CompositeHybridSystem`. Group numbers are arbitrary
    /// labels.
    pub group: Option<usize>,
    /// The state components the jump map may change; required (and
    /// disjoint between the rules of one group) for grouped rules, ignored
    /// otherwise.
    pub writes: Vec<usize>,
}

impl JumpRule {
    /// A rule that fires alone (no group).
    pub fn new(name: impl Into<String>, guard: GuardKind) -> Self {
        Self {
            name: name.into(),
            guard,
            group: None,
            writes: Vec::new(),
        }
    }

    /// The same rule in group `group`, writing components `writes`.
    #[must_use]
    pub fn together(mut self, group: usize, writes: Vec<usize>) -> Self {
        self.group = Some(group);
        self.writes = writes;
        self
    }
}

/// What the engine knows about the shape of a jump rule's guard.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum GuardKind {
    /// A general continuous guard: events are localized by root finding.
    General,
    /// The rule fires when state `index` (a timer with constant rate during
    /// flow) reaches `threshold` from above if its rate is negative or from
    /// below if positive. The event time is computed exactly, without root
    /// finding. `jump_guard` must still be consistent with it.
    Timer {
        /// Index of the timer state in x.
        index: usize,
        /// Value at which the rule fires.
        threshold: f64,
    },
}

/// Structure of the flow map that lets the engine advance flows exactly.
#[derive(Debug, Clone, PartialEq)]
pub enum FlowStructure {
    /// Nothing known: integrate numerically.
    General,
    /// `ẋ = A x + b` with constant `A` (row-major, n×n) and `b`; the engine
    /// advances it exactly with a matrix exponential. Timers and held
    /// constants are the special case `A = 0`.
    Affine {
        /// Row-major n×n matrix A.
        a: Vec<f64>,
        /// Constant drift b.
        b: Vec<f64>,
    },
}

/// A hybrid system the engine can simulate. See the module docs for the
/// mapping from the mathematics to the methods.
///
/// All state arguments are slices of length [`state_dim`](Self::state_dim).
/// Methods must not allocate on the hot path (flow map, guards) if the
/// system is to run at full speed.
pub trait HybridSystem {
    /// Dimension n of the state x.
    fn state_dim(&self) -> usize;

    /// One name per state component, in order (e.g. `h`, `v`, `P[1,2]`).
    fn state_names(&self) -> Vec<String>;

    /// The flow map: writes f(x, t, j) into `dx`. `at.j` is constant along
    /// a flow; `at.t` advances with it.
    fn flow_map(&self, at: HybridTime, x: &[f64], dx: &mut [f64]);

    /// Membership in the flow set C at hybrid time `at`. Default: C is the
    /// whole space.
    fn flow_set(&self, _at: HybridTime, _x: &[f64]) -> bool {
        true
    }

    /// A continuous function ≥ 0 inside C whose zero crossing marks C's
    /// boundary, or `None` if C is the whole space.
    fn flow_guard(&self, _at: HybridTime, _x: &[f64]) -> Option<f64> {
        None
    }

    /// The jump rules, in declaration order.
    fn jump_rules(&self) -> &[JumpRule];

    /// Membership of x in the jump set D_i of rule `rule` at hybrid time `at`.
    fn jump_set(&self, rule: usize, at: HybridTime, x: &[f64]) -> bool;

    /// A continuous function that is ≥ 0 on D_i's side of its boundary and
    /// < 0 away from it; a zero crossing from below is a candidate event.
    fn jump_guard(&self, rule: usize, at: HybridTime, x: &[f64]) -> f64;

    /// The jump map G_i of rule `rule` at pre-jump state `x` and pre-jump
    /// hybrid time `at` (HyEQ's g(x, t, j)): writes one element of G_i(x)
    /// into `x_plus`. Set-valued maps draw
    /// from `rng`, so that a seed reproduces a run exactly.
    fn jump_map(
        &self,
        rule: usize,
        at: HybridTime,
        x: &[f64],
        rng: &mut SimRng,
        x_plus: &mut [f64],
    );

    /// Structure of the flow map; [`FlowStructure::General`] by default.
    fn flow_structure(&self) -> FlowStructure {
        FlowStructure::General
    }

    /// Diffusion for flows driven by white noise, `dx = f dt + g(x) dW`
    /// with `g` of shape n×m: returns `m`, the number of independent Wiener
    /// processes (0 for an ODE flow, the default).
    fn noise_dim(&self) -> usize {
        0
    }

    /// Writes g(x, t, j) (row-major n×m) into `g`. Called only if
    /// [`noise_dim`](Self::noise_dim) > 0.
    fn diffusion(&self, _at: HybridTime, _x: &[f64], _g: &mut [f64]) {}
}

/// The run's seeded random source, passed to jump maps (and to the
/// stochastic integrator). ChaCha8 so that the same seed gives the same
/// stream on every platform and version of `rand`.
#[derive(Debug, Clone)]
pub struct SimRng(ChaCha8Rng);

impl SimRng {
    /// A generator seeded with `seed`.
    pub fn seed_from(seed: u64) -> Self {
        Self(ChaCha8Rng::seed_from_u64(seed))
    }

    /// A uniform draw from `[lo, hi]`.
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        let u = (self.0.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
        lo + (hi - lo) * u
    }

    /// A standard normal draw.
    pub fn standard_normal(&mut self) -> f64 {
        StandardNormal.sample(&mut self.0)
    }

    /// A normal draw with mean `mean` and standard deviation `std`.
    pub fn normal(&mut self, mean: f64, std: f64) -> f64 {
        mean + std * self.standard_normal()
    }

    /// A Bernoulli draw: `true` with probability `p`.
    pub fn bernoulli(&mut self, p: f64) -> bool {
        self.uniform(0.0, 1.0) < p
    }

    /// The underlying generator, for distributions not wrapped here.
    pub fn inner(&mut self) -> &mut ChaCha8Rng {
        &mut self.0
    }
}
