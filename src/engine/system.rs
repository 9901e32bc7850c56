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
//! # Sets as boolean combinations of atoms
//!
//! A set is described to the engine by its *atoms* `g_k(t, x) ⋈ 0`
//! (`⋈` one of [`Cmp`]) and a monotone boolean structure over them
//! ([`SetExpr`]: `and`/`or` of atoms, negations already pushed into the
//! comparisons), returned by [`HybridSystem::set_atoms`] and evaluated by
//! [`HybridSystem::atom_values`]. An atom that cannot change during a flow
//! (it depends only on parameters, the jump counter or states whose flow is
//! zero) is marked `flows = false`: the engine evaluates it once per flow
//! segment and never root-finds on it. The engine watches every flowing
//! atom individually, localizes each change of its sign, and re-evaluates
//! the whole set at each candidate in time order (see the
//! [engine docs](super)).
//!
//! A system that does not describe its atoms (the default, `None`) is
//! watched through one atom per set, its guard ([`HybridSystem::jump_guard`]
//! ≥ 0, [`HybridSystem::flow_guard`] ≥ 0), and the predicates
//! ([`HybridSystem::jump_set`], [`HybridSystem::flow_set`]) decide
//! membership at each candidate. In both cases the predicates must agree
//! with the atoms.

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
    /// The part of its group the rule belongs to (`None`: a part of its
    /// own). A part is one subsystem of a composite system: its rules are
    /// alternatives, so when the group jumps at most one rule of each part
    /// fires (the first enabled in declaration order), and rules of one
    /// part may write the same components. Part numbers are arbitrary
    /// labels.
    pub part: Option<usize>,
    /// The state components the jump map may change; required (and
    /// disjoint between the rules of different parts of one group) for
    /// grouped rules, optional for a rule that fires alone (empty: any).
    /// When given, the engine checks only these components of the post-jump
    /// state for finiteness (the others are the pre-jump state's): a map
    /// that changes others breaks the promise.
    pub writes: Vec<usize>,
}

impl JumpRule {
    /// A rule that fires alone (no group).
    pub fn new(name: impl Into<String>, guard: GuardKind) -> Self {
        Self {
            name: name.into(),
            guard,
            group: None,
            part: None,
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

    /// The same rule in part `part` of its group (see [`Self::part`]).
    #[must_use]
    pub fn in_part(mut self, part: usize) -> Self {
        self.part = Some(part);
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
        /// Whether the timer also bounds the flow set: C lies where the
        /// timer has not passed its threshold (C ⊆ {τ ≤ threshold} for a
        /// rising timer), as HyEQ writes a sampling timer and as `.hyb`'s
        /// `every` rules and held `noise` are. Where the rule's jump set
        /// holds the solution then cannot flow, so the rule fires at its
        /// threshold under every [`Priority`](super::Priority). `false`: C
        /// is what [`HybridSystem::flow_set`] says alone (under
        /// [`Priority::Flows`](super::Priority::Flows) a timer whose C goes
        /// on is passed).
        bounds_flow: bool,
    },
}

/// How an atom compares its value `g` with zero.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Cmp {
    /// `g < 0`
    Lt,
    /// `g ≤ 0`
    Le,
    /// `g > 0`
    Gt,
    /// `g ≥ 0`
    Ge,
    /// `g = 0`
    Eq,
    /// `g ≠ 0`
    Ne,
}

impl Cmp {
    /// Whether `g ⋈ 0` holds exactly (`false` for NaN, except `≠`).
    #[inline]
    pub fn holds(self, g: f64) -> bool {
        match self {
            Cmp::Lt => g < 0.0,
            Cmp::Le => g <= 0.0,
            Cmp::Gt => g > 0.0,
            Cmp::Ge => g >= 0.0,
            Cmp::Eq => g == 0.0,
            Cmp::Ne => g != 0.0,
        }
    }

    /// Whether `g` is within `tol ≥ 0` of the set `{g ⋈ 0}`: `g ≥ −tol`
    /// for `≥`, `g > −tol` for `>`, `|g| ≤ tol` for `=`; `≠` is not relaxed
    /// (a point exactly on its excluded level set is not a rounding case).
    #[inline]
    pub fn holds_within(self, g: f64, tol: f64) -> bool {
        if tol <= 0.0 {
            return self.holds(g);
        }
        match self {
            Cmp::Lt => g < tol,
            Cmp::Le => g <= tol,
            Cmp::Gt => g > -tol,
            Cmp::Ge => g >= -tol,
            Cmp::Eq => g.abs() <= tol,
            Cmp::Ne => g != 0.0,
        }
    }
}

/// One atom `g(t, x) ⋈ 0` of a set.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Atom {
    /// The comparison with zero.
    pub cmp: Cmp,
    /// Whether `g` can change along a flow (it depends on `t` or on a state
    /// whose flow is not identically zero). Atoms with `flows = false` are
    /// evaluated once per flow segment.
    pub flows: bool,
    /// An identity of the function `g`, if the system knows one: atoms (of
    /// any sets) with the same `Some` value have the same `g`, so the engine
    /// localizes their common zero once (`x >= 0` in C and `x <= 0` in D).
    pub g_id: Option<u64>,
    /// `Some((index, threshold))`: `g = x[index] − threshold` exactly, the
    /// comparison is an inequality, and state `index` has a constant rate
    /// along every flow (a timer). The engine then computes when `g`
    /// reaches zero instead of watching it: a flow segment ends there, with
    /// `x[index]` set to `threshold`, as for [`GuardKind::Timer`] rules (a
    /// strict atom that holds past its threshold, `tau > Ts` with `tau`
    /// rising: to the first float past it, where it holds).
    pub timer: Option<(usize, Threshold)>,
}

/// The threshold of a timer atom ([`Atom::timer`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Threshold {
    /// A constant.
    Const(f64),
    /// A function of the jump count and of states whose flow is
    /// identically zero (a mode's dwell time `d[q]`, a deadline drawn at
    /// the last jump): constant along each flow segment. The engine reads
    /// it from [`HybridSystem::timer_threshold`] at each segment's start;
    /// `g` must be `x[index]` minus exactly that value.
    PerSegment,
}

impl Atom {
    /// Whether `g` is within `tol` of the atom's set as C's atoms are tested
    /// ([`Cmp::holds_within`]), except that a strict comparison that cannot
    /// change along a flow (`k < 3` with `k` a counter, `j < 3`) is tested
    /// exactly: on its boundary it fails on the whole flow, not by rounding,
    /// and relaxed it would make `<` a `<=` for every integer-valued mode.
    #[inline]
    pub fn holds_within(&self, g: f64, tol: f64) -> bool {
        if !self.flows && matches!(self.cmp, Cmp::Lt | Cmp::Gt) {
            self.cmp.holds(g)
        } else {
            self.cmp.holds_within(g, tol)
        }
    }

    /// Whether the engine watches the atom along flows (at checkpoints,
    /// localizing its sign changes): it can change along a flow and is not
    /// a [`timer`](Self::timer).
    #[inline]
    pub fn watched(&self) -> bool {
        self.flows && self.timer.is_none()
    }
}

/// An atom's function as an affine form of the state, `g(x) = c₀ + Σ cₖ·x[k]`
/// (see [`HybridSystem::atom_affine`]).
#[derive(Debug, Clone, PartialEq)]
pub struct AffineAtom {
    /// `(k, cₖ)`: the state components and their coefficients.
    pub terms: Vec<(usize, f64)>,
    /// `c₀`.
    pub constant: f64,
}

/// A monotone boolean combination of the atoms of one set.
#[derive(Debug, Clone, PartialEq)]
pub enum SetExpr {
    /// Always true or always false.
    Const(bool),
    /// Atom `k` of the set's [`SetAtoms::atoms`].
    Atom(usize),
    /// All of them hold.
    And(Vec<SetExpr>),
    /// At least one of them holds.
    Or(Vec<SetExpr>),
}

impl SetExpr {
    /// The value of the combination given the truth of each atom.
    pub fn eval(&self, truth: &[bool]) -> bool {
        self.eval_with(&|k| truth[k])
    }

    /// The combination's value when atom `k` has truth `truth(k)`.
    pub fn eval_with(&self, truth: &impl Fn(usize) -> bool) -> bool {
        match self {
            SetExpr::Const(b) => *b,
            SetExpr::Atom(k) => truth(*k),
            SetExpr::And(v) => v.iter().all(|e| e.eval_with(truth)),
            SetExpr::Or(v) => v.iter().any(|e| e.eval_with(truth)),
        }
    }

    /// The combination's truth table when it refers only to atoms 0–5:
    /// bit `m` is its value when atom `k` holds exactly if bit `k` of `m`
    /// is set (see [`TruthTable`]). Built by bitwise `and`/`or` of the
    /// atoms' columns, in one pass over the tree.
    pub(crate) fn truth_table(&self) -> Option<TruthTable> {
        /// Column of atom k: bit m set iff bit k of m is.
        const COLUMNS: [u64; 6] = [
            0xAAAA_AAAA_AAAA_AAAA,
            0xCCCC_CCCC_CCCC_CCCC,
            0xF0F0_F0F0_F0F0_F0F0,
            0xFF00_FF00_FF00_FF00,
            0xFFFF_0000_FFFF_0000,
            0xFFFF_FFFF_0000_0000,
        ];
        Some(TruthTable(match self {
            SetExpr::Const(b) => 0u64.wrapping_sub(u64::from(*b)),
            SetExpr::Atom(k) => *COLUMNS.get(*k)?,
            SetExpr::And(v) => v
                .iter()
                .try_fold(!0, |acc, e| Some(acc & e.truth_table()?.0))?,
            SetExpr::Or(v) => v
                .iter()
                .try_fold(0, |acc, e| Some(acc | e.truth_table()?.0))?,
        }))
    }

    /// The atoms whose failure makes the combination fail, given the truth
    /// of each atom (for diagnostics): for a failing `and`, the failing
    /// conjuncts' atoms; for a failing `or`, every alternative's.
    pub fn failing_atoms(&self, truth: &[bool], out: &mut Vec<usize>) {
        match self {
            SetExpr::Const(_) => {}
            SetExpr::Atom(k) => {
                if !truth[*k] {
                    out.push(*k);
                }
            }
            SetExpr::And(v) | SetExpr::Or(v) => {
                for e in v {
                    if !e.eval(truth) {
                        e.failing_atoms(truth, out);
                    }
                }
            }
        }
    }
}

/// A [`SetExpr`] of at most six atoms as a table of its 64 values: one
/// shift per evaluation instead of a walk of the tree (the engine asks
/// for a set's value at every event candidate and for whether it depends
/// on an atom at every sign change).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct TruthTable(u64);

impl TruthTable {
    /// The most atoms a table covers.
    pub const MAX_ATOMS: usize = 6;

    /// The value when atom `k` holds exactly if bit `k` of `mask` is set.
    #[inline]
    pub fn value(self, mask: u32) -> bool {
        (self.0 >> mask) & 1 != 0
    }

    /// The bit mask of the truth of `n` atoms.
    #[inline]
    pub fn mask(n: usize, truth: impl Fn(usize) -> bool) -> u32 {
        (0..n).fold(0, |m, k| m | (u32::from(truth(k)) << k))
    }
}

/// The atoms of a set and their boolean structure; see the module docs.
#[derive(Debug, Clone, PartialEq)]
pub struct SetAtoms {
    /// The atoms, indexed by [`SetExpr::Atom`].
    pub atoms: Vec<Atom>,
    /// The set as a monotone combination of the atoms.
    pub expr: SetExpr,
}

/// What a set's atoms, guard and predicate read
/// ([`HybridSystem::set_inputs`]). The time is not listed: a jump keeps it.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SetInputs {
    /// The state components read (increasing).
    pub states: Vec<usize>,
    /// Whether the jump count `j` is read.
    pub jumps: bool,
}

/// Which set of the system: the flow set C or the jump set D_i of a rule.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SetRef {
    /// The flow set C.
    Flow,
    /// The jump set of rule `i`.
    Jump(usize),
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
    /// `ẋ = A(q) x + b(q)`: affine in the state, with `A` and `b` functions
    /// of the components `modes`, which do not move along flows (their rows
    /// of A and b are zero): a switched linear system whose mode is a state.
    /// [`HybridSystem::affine_coefficients`] gives `A` and `b` at a state;
    /// the engine advances each flow exactly with the exponential of its
    /// mode's `A` (propagators kept per mode).
    SwitchedAffine {
        /// The components A and b depend on (sorted).
        modes: Vec<usize>,
    },
}

/// A failed evaluation reported by [`HybridSystem::take_fault`].
#[derive(Debug, Clone, PartialEq)]
pub struct SystemFault {
    /// The hybrid time of the evaluation.
    pub at: HybridTime,
    /// The system's own index of what failed (a compiled model: the
    /// expression), for its diagnostics.
    pub site: usize,
    /// What failed, in words.
    pub what: String,
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

    /// A failure the system met while evaluating its maps, sets or outputs
    /// that no value can carry (a table index out of range at run time: its
    /// NaN would read as "false" in a guard), taken (and cleared) by the
    /// engine after every flow segment and jump map; the run then stops
    /// with [`SimError::Fault`](super::SimError::Fault). Default: none.
    fn take_fault(&self) -> Option<SystemFault> {
        None
    }

    /// Membership of x in the jump set D_i of rule `rule` at hybrid time `at`.
    fn jump_set(&self, rule: usize, at: HybridTime, x: &[f64]) -> bool;

    /// Writes [`jump_set`](Self::jump_set) of every rule at once into
    /// `inside` (one entry per rule) and returns `true`; or returns `false`
    /// (the default) to have the engine ask rule by rule. A system whose
    /// sets share subexpressions computes them once here. The engine asks
    /// at each point where it chooses between flowing and jumping. A fault
    /// reported after this call (a rule's set that cannot be evaluated)
    /// makes the engine discard it and ask rule by rule in order, so that
    /// only the rules before the first enabled one are evaluated, as then.
    fn jump_sets(&self, _at: HybridTime, _x: &[f64], _inside: &mut [bool]) -> bool {
        false
    }

    /// A continuous function that is ≥ 0 on D_i's side of its boundary and
    /// < 0 away from it; a zero crossing from below is a candidate event.
    fn jump_guard(&self, rule: usize, at: HybridTime, x: &[f64]) -> f64;

    /// The jump map G_i of rule `rule` at pre-jump state `x` and pre-jump
    /// hybrid time `at` (HyEQ's g(x, t, j)): writes one element of G_i(x)
    /// into `x_plus`. The engine passes `x_plus` holding a copy of `x`, so
    /// a map need only write the components it changes. Set-valued maps
    /// draw from `rng`, so that a seed reproduces a run exactly.
    fn jump_map(
        &self,
        rule: usize,
        at: HybridTime,
        x: &[f64],
        rng: &mut SimRng,
        x_plus: &mut [f64],
    );

    /// The atoms and boolean structure of `set`, or `None` (the default)
    /// to have the engine watch the set's guard as its only atom. Called
    /// once per run.
    fn set_atoms(&self, _set: SetRef) -> Option<SetAtoms> {
        None
    }

    /// The function of atom `atom` of `set` as an affine form of the state,
    /// if it is one (no time, jump count or noise in it), or `None` (the
    /// default). Called once per run for each watched atom. The engine
    /// uses the form to prove, from the control points of a step's
    /// polynomial interpolant, that the atom keeps its sign over the whole
    /// step, and then evaluates it at the step's end only instead of at
    /// every checkpoint; it allows for rounding, so the form must equal
    /// what [`atom_values`](Self::atom_values) computes up to rounding.
    fn atom_affine(&self, _set: SetRef, _atom: usize) -> Option<AffineAtom> {
        None
    }

    /// The threshold at (`at`, `x`) of atom `atom` of `set`, a timer atom
    /// whose [`Threshold`] is [`PerSegment`](Threshold::PerSegment). Called
    /// at the start of each flow segment; the default, for systems that
    /// declare none, is NaN (a timer that never expires).
    fn timer_threshold(&self, _set: SetRef, _atom: usize, _at: HybridTime, _x: &[f64]) -> f64 {
        f64::NAN
    }

    /// How atom `atom` of `set` reads in the model (`x <= 1`), for
    /// messages: the ending of a solution that can neither flow nor jump
    /// names C's failing atoms by it. `None` (the default): they are named
    /// by index.
    fn atom_text(&self, _set: SetRef, _atom: usize) -> Option<String> {
        None
    }

    /// Writes the value `g_k(t, j, x)` of each atom of `set` into `out`
    /// (length: the number of atoms of [`set_atoms`](Self::set_atoms)).
    /// With `flowing_only`, only the atoms the engine watches
    /// ([`Atom::watched`]) need be written. Called only for sets that have
    /// atoms.
    fn atom_values(
        &self,
        _set: SetRef,
        _at: HybridTime,
        _x: &[f64],
        _flowing_only: bool,
        _out: &mut [f64],
    ) {
    }

    /// The Jacobian ∂f/∂x of the flow map at (`at`, `x`): writes the n×n
    /// matrix row-major into `jac` (`jac[r·n + c] = ∂f_r/∂x_c`). Used by the
    /// implicit solvers ([`Solver::Radau5`](super::Solver::Radau5),
    /// [`Solver::Bdf`](super::Solver::Bdf), [`Solver::Auto`](super::Solver::Auto)). The
    /// default takes forward differences of [`flow_map`](Self::flow_map)
    /// ([`finite_difference_jacobian`]: n + 1 evaluations, about half the
    /// digits); override it with the exact derivative where known.
    fn jacobian(&self, at: HybridTime, x: &[f64], jac: &mut [f64]) {
        finite_difference_jacobian(self, at, x, jac);
    }

    /// The structural sparsity of ∂f/∂x: the entries that can be nonzero
    /// at some state and time (`None`, the default: dense). With a pattern
    /// the implicit solvers take the Jacobian from
    /// [`jacobian_values`](Self::jacobian_values), or by finite
    /// differences of grouped columns (columns that share no row are
    /// perturbed together: a chain needs 4 evaluations of f, not n + 1),
    /// and never call [`jacobian`](Self::jacobian); large sparse systems
    /// get a sparse LU ([`SimSettings::linear_solver`](super::SimSettings::linear_solver)).
    /// Called once per run.
    fn jacobian_pattern(&self) -> Option<super::SparsityPattern> {
        None
    }

    /// Writes the entries of ∂f/∂x at (`at`, `x`) in the order of
    /// [`jacobian_pattern`](Self::jacobian_pattern)'s values (column by
    /// column, rows ascending) and returns `true`; or returns `false` (the
    /// default) to have the engine take finite differences on the pattern.
    /// Called only when there is a pattern.
    fn jacobian_values(&self, _at: HybridTime, _x: &[f64], _values: &mut [f64]) -> bool {
        false
    }

    /// Writes the atoms of every set that has atoms at once, in the order
    /// C, D_0, D_1, … (sets without atoms left out), each set's atoms as
    /// [`atom_values`](Self::atom_values) writes them, one set after the
    /// other into `out` (length: the total number of atoms; with
    /// `flowing_only`, only the watched atoms need be written). Returns
    /// `false` (the default) if the system does not offer this; the engine
    /// then evaluates the sets one by one. A system whose sets share
    /// subexpressions evaluates them once here (the compiled model runs one
    /// program for all sets): the engine uses it at the points where it
    /// looks at all watched sets. The values must equal `atom_values`'
    /// to the last bit.
    fn all_atom_values(
        &self,
        _at: HybridTime,
        _x: &[f64],
        _flowing_only: bool,
        _out: &mut [f64],
    ) -> bool {
        false
    }

    /// Bounds of the watched atoms over a box of hybrid time: for `t` in
    /// `[t.0, t.1]`, jump count `j` and each state component `x[k]` in
    /// `[x[k].0, x[k].1]`, writes into `out`, in the layout of
    /// [`all_atom_values`](Self::all_atom_values) (only the watched atoms
    /// need be written), an interval `(lo, hi)` that contains the value
    /// `all_atom_values` computes at every point of the box, to the last
    /// bit — `(−∞, ∞)` where it may be NaN; points where the evaluation
    /// records a fault ([`take_fault`](Self::take_fault): the run stops
    /// there) excepted — and returns `true`; or
    /// returns `false` (the default) if the system cannot bound them. The
    /// engine uses it after a step on which no watched atom without an
    /// affine form changed sign at the checkpoints, to prove that none did
    /// between them (or to find where one did: a sawtooth `mod(t, 1)`, a
    /// brief dip of `sin(t)`), on the steps whose path is a polynomial.
    fn atom_bounds(
        &self,
        _t: (f64, f64),
        _j: u64,
        _x: &[(f64, f64)],
        _out: &mut [(f64, f64)],
    ) -> bool {
        false
    }

    /// The state components whose boxes [`atom_bounds`](Self::atom_bounds)
    /// reads (increasing); the others' boxes may be anything, and the
    /// engine computes none for them. `None` (the default): all of them.
    fn atom_bound_inputs(&self) -> Option<Vec<usize>> {
        None
    }

    /// The state components whose flow is identically zero (modes,
    /// counters, held samples): every integrator keeps them exactly along a
    /// step, so the engine gives [`atom_bounds`](Self::atom_bounds) each
    /// one's value as a point instead of the hull of its path's control
    /// points widened by their rounding (a mode `q` widened by a few ulps
    /// leaves `q == 1` undecided and `d[q]` reading no single entry, so no
    /// atom that reads it was ever proved). Default: none.
    fn still_states(&self) -> Vec<usize> {
        Vec::new()
    }

    /// [`jump_sets`](Self::jump_sets) and [`all_atom_values`](Self::all_atom_values)
    /// (all atoms) at one point in one evaluation: each rule's membership
    /// into `inside`, every set's atoms into `atoms` in `all_atom_values`'
    /// layout, and `true`; or `false` (the default: nothing written) to have
    /// the engine make the two calls. The engine asks where it chooses
    /// between flowing and jumping and would start a flow segment from the
    /// point if no rule is enabled: a system whose sets share
    /// subexpressions computes them once for both. The results must equal
    /// the two calls' to the last bit; a fault is handled as for
    /// `jump_sets`.
    fn jump_sets_and_atoms(
        &self,
        _at: HybridTime,
        _x: &[f64],
        _inside: &mut [bool],
        _atoms: &mut [f64],
    ) -> bool {
        false
    }

    /// What `set`'s atoms, guard and predicate read, or `None` (the
    /// default): anything. Called at most once per run. After a jump by
    /// one rule from a point where it evaluated every set, the engine
    /// evaluates again only the sets that read `j` or a component the rule
    /// writes ([`JumpRule::writes`]; a rule without them writes any), and
    /// keeps the others' atoms and membership from the pre-jump point,
    /// which has the same `t`: the inputs must cover everything the values
    /// depend on besides `t`.
    fn set_inputs(&self, _set: SetRef) -> Option<SetInputs> {
        None
    }

    /// [`jump_set`](Self::jump_set) of rule `rule` as the return value and
    /// its atoms ([`atom_values`](Self::atom_values), all of them) into
    /// `atoms`, in one evaluation; the engine's re-evaluation of one set
    /// after a jump ([`set_inputs`](Self::set_inputs)). The default makes
    /// the two calls; a system whose predicate and atoms share
    /// subexpressions computes them once. The results must equal the two
    /// calls' to the last bit.
    fn jump_set_and_atoms(
        &self,
        rule: usize,
        at: HybridTime,
        x: &[f64],
        atoms: &mut [f64],
    ) -> bool {
        self.atom_values(SetRef::Jump(rule), at, x, false, atoms);
        self.jump_set(rule, at, x)
    }

    /// Structure of the flow map; [`FlowStructure::General`] by default.
    fn flow_structure(&self) -> FlowStructure {
        FlowStructure::General
    }

    /// For [`FlowStructure::SwitchedAffine`]: `A` (row-major, n×n) and `b`
    /// of the flow `ẋ = A x + b` through `x` at `at` (they depend only on
    /// the mode components of `x`; `at` locates a fault). Both buffers are
    /// zeroed by the caller. Systems that declare no such structure are
    /// never asked.
    fn affine_coefficients(&self, at: HybridTime, x: &[f64], a: &mut [f64], b: &mut [f64]) {
        let _ = (at, x, a, b);
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

/// ∂f/∂x of `sys`'s flow map at (`at`, `x`) by forward differences, written
/// row-major into `jac`: column c is `(f(x + δ e_c) − f(x)) / δ` with
/// `δ = √ε · max(|x_c|, 1)`. Allocates three state-sized vectors.
pub fn finite_difference_jacobian<S: HybridSystem + ?Sized>(
    sys: &S,
    at: HybridTime,
    x: &[f64],
    jac: &mut [f64],
) {
    let n = x.len();
    let mut xp = x.to_vec();
    let mut f0 = vec![0.0; n];
    let mut f1 = vec![0.0; n];
    sys.flow_map(at, x, &mut f0);
    for c in 0..n {
        let delta = f64::EPSILON.sqrt() * x[c].abs().max(1.0);
        xp[c] = x[c] + delta;
        // The step actually taken (rounding of x + δ).
        let delta = xp[c] - x[c];
        sys.flow_map(at, &xp, &mut f1);
        for r in 0..n {
            jac[r * n + c] = (f1[r] - f0[r]) / delta;
        }
        xp[c] = x[c];
    }
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
        let span = hi - lo;
        if span.is_finite() {
            lo + span * u
        } else {
            // A range wider than the largest float (`uniform(-1e308, 1e308)`):
            // its span overflows, the weighted mean of the ends does not.
            lo * (1.0 - u) + hi * u
        }
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

    /// A uniform draw from `0..n` (`n` ≥ 1), without modulo bias: the
    /// draws of the top partial range of `u64` are rejected.
    ///
    /// # Panics
    /// If `n` is 0.
    pub fn index(&mut self, n: usize) -> usize {
        assert!(n > 0, "SimRng::index over an empty range");
        let n = n as u64;
        // 2^64 mod n draws at the top would favour the small residues.
        let last = u64::MAX - (u64::MAX - n + 1) % n;
        loop {
            let v = self.0.next_u64();
            if v <= last {
                return (v % n) as usize;
            }
        }
    }

    /// The underlying generator, for distributions not wrapped here.
    pub fn inner(&mut self) -> &mut ChaCha8Rng {
        &mut self.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Random monotone combinations of up to 6 atoms (constants included):
    /// the truth table agrees with the tree at every assignment.
    #[test]
    fn a_truth_table_agrees_with_its_tree() {
        fn random(rng: &mut SimRng, depth: u32) -> SetExpr {
            let pick = (rng.uniform(0.0, 1.0) * 10.0) as u32;
            match pick {
                0 => SetExpr::Const(rng.bernoulli(0.5)),
                1..=4 => SetExpr::Atom((rng.uniform(0.0, 1.0) * 6.0) as usize % 6),
                _ if depth == 0 => SetExpr::Atom(0),
                _ => {
                    let n = 1 + (rng.uniform(0.0, 1.0) * 3.0) as usize;
                    let v = (0..n).map(|_| random(rng, depth - 1)).collect();
                    if pick < 8 {
                        SetExpr::And(v)
                    } else {
                        SetExpr::Or(v)
                    }
                }
            }
        }
        let mut rng = SimRng::seed_from(7);
        for _ in 0..500 {
            let e = random(&mut rng, 3);
            let t = e.truth_table().expect("atoms below 6");
            for m in 0..64u32 {
                let truth: Vec<bool> = (0..6).map(|k| m >> k & 1 != 0).collect();
                assert_eq!(t.value(m), e.eval(&truth), "{e:?} at {m:06b}");
                assert_eq!(TruthTable::mask(6, |k| truth[k]), m);
            }
        }
        assert_eq!(SetExpr::Atom(6).truth_table(), None);
        let e = SetExpr::And(vec![SetExpr::Atom(0), SetExpr::Or(vec![SetExpr::Atom(7)])]);
        assert_eq!(e.truth_table(), None);
    }
}
