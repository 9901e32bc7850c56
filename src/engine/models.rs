//! Small hybrid systems written directly in Rust, with what is known about
//! their solutions. They serve as examples of implementing
//! [`HybridSystem`], as the engine's test models, and as benchmark models.

use nalgebra::{DMatrix, DVector, DVectorView, DVectorViewMut};

use super::{FlowStructure, GuardKind, HybridSystem, JumpRule, SimRng};
use crate::arc::HybridTime;

/// A ball bouncing on the ground: height `h`, velocity `v`,
/// `ḣ = v, v̇ = -g` in C = {h ≥ 0}, `v⁺ = -λ v` in D = {h ≤ 0, v ≤ 0}.
#[derive(Debug, Clone)]
pub struct BouncingBall {
    /// Gravity (m/s²).
    pub g: f64,
    /// Restitution coefficient λ ∈ (0, 1).
    pub lambda: f64,
    /// Report the flow as affine (`ẋ = A x + b`) so that the engine can
    /// advance it exactly.
    pub affine: bool,
    rules: Vec<JumpRule>,
}

impl BouncingBall {
    /// A ball with gravity `g` and restitution `lambda`, one rule `impact`.
    pub fn new(g: f64, lambda: f64) -> Self {
        Self {
            g,
            lambda,
            affine: false,
            rules: vec![JumpRule {
                name: "impact".into(),
                group: None,
                part: None,
                writes: Vec::new(),
                guard: GuardKind::General,
            }],
        }
    }

    /// Closed form for a drop from rest at height `h0`: the first `k`
    /// impact times and the impact (pre-jump) velocities.
    pub fn impacts(&self, h0: f64, k: usize) -> Vec<(f64, f64)> {
        let v0 = (2.0 * self.g * h0).sqrt();
        let mut t = (2.0 * h0 / self.g).sqrt();
        let mut out = Vec::with_capacity(k);
        for i in 0..k {
            let v = self.lambda.powi(i as i32) * v0;
            out.push((t, -v));
            t += 2.0 * self.lambda * v / self.g;
        }
        out
    }

    /// The Zeno time of a drop from rest at height `h0`:
    /// `t₁ + 2λ√(2h₀/g)/(1 − λ)`.
    pub fn zeno_time(&self, h0: f64) -> f64 {
        let t1 = (2.0 * h0 / self.g).sqrt();
        t1 + 2.0 * self.lambda * t1 / (1.0 - self.lambda)
    }
}

impl HybridSystem for BouncingBall {
    fn state_dim(&self) -> usize {
        2
    }
    fn state_names(&self) -> Vec<String> {
        vec!["h".into(), "v".into()]
    }
    fn flow_map(&self, _at: HybridTime, x: &[f64], dx: &mut [f64]) {
        dx[0] = x[1];
        dx[1] = -self.g;
    }
    fn flow_set(&self, _at: HybridTime, x: &[f64]) -> bool {
        x[0] >= 0.0
    }
    fn flow_guard(&self, _at: HybridTime, x: &[f64]) -> Option<f64> {
        Some(x[0])
    }
    fn jump_rules(&self) -> &[JumpRule] {
        &self.rules
    }
    fn jump_set(&self, _rule: usize, _at: HybridTime, x: &[f64]) -> bool {
        x[0] <= 0.0 && x[1] <= 0.0
    }
    fn jump_guard(&self, _rule: usize, _at: HybridTime, x: &[f64]) -> f64 {
        -x[0]
    }
    fn jump_map(
        &self,
        _rule: usize,
        _at: HybridTime,
        x: &[f64],
        _rng: &mut SimRng,
        xp: &mut [f64],
    ) {
        xp[0] = x[0];
        xp[1] = -self.lambda * x[1];
    }
    fn flow_structure(&self) -> FlowStructure {
        if self.affine {
            FlowStructure::Affine {
                a: vec![0.0, 1.0, 0.0, 0.0],
                b: vec![0.0, -self.g],
            }
        } else {
            FlowStructure::General
        }
    }
}

/// `n` independent countdown timers `τ_i` (`τ̇_i = -1`), each with its own
/// rule `reset[i]`: when `τ_i` reaches 0 it is reset to a value drawn
/// uniformly from `[t1, t2]`. Timer guards: events are exact.
#[derive(Debug, Clone)]
pub struct RandomTimers {
    /// Lower bound of the reset interval.
    pub t1: f64,
    /// Upper bound of the reset interval.
    pub t2: f64,
    rules: Vec<JumpRule>,
}

impl RandomTimers {
    /// `n` timers reset in `[t1, t2]`.
    pub fn new(n: usize, t1: f64, t2: f64) -> Self {
        let rules = (0..n)
            .map(|i| JumpRule {
                name: format!("reset[{i}]"),
                group: None,
                part: None,
                writes: Vec::new(),
                guard: GuardKind::Timer {
                    index: i,
                    threshold: 0.0,
                    bounds_flow: false,
                },
            })
            .collect();
        Self { t1, t2, rules }
    }
}

impl HybridSystem for RandomTimers {
    fn state_dim(&self) -> usize {
        self.rules.len()
    }
    fn state_names(&self) -> Vec<String> {
        (0..self.rules.len()).map(|i| format!("tau[{i}]")).collect()
    }
    fn flow_map(&self, _at: HybridTime, _x: &[f64], dx: &mut [f64]) {
        dx.fill(-1.0);
    }
    fn jump_rules(&self) -> &[JumpRule] {
        &self.rules
    }
    fn jump_set(&self, rule: usize, _at: HybridTime, x: &[f64]) -> bool {
        x[rule] <= 0.0
    }
    fn jump_guard(&self, rule: usize, _at: HybridTime, x: &[f64]) -> f64 {
        -x[rule]
    }
    fn jump_map(&self, rule: usize, _at: HybridTime, x: &[f64], rng: &mut SimRng, xp: &mut [f64]) {
        xp.copy_from_slice(x);
        xp[rule] = rng.uniform(self.t1, self.t2);
    }
    fn flow_structure(&self) -> FlowStructure {
        let n = self.rules.len();
        FlowStructure::Affine {
            a: vec![0.0; n * n],
            b: vec![-1.0; n],
        }
    }
}

/// A linear plant `ẋ = A x + B u` under sample-and-hold state feedback
/// `u = -K x` with period `ts`. State: `[x (n), u (m), τ]`, with the timer
/// `τ̇ = 1` and rule `sample`: when `τ = ts`, `u⁺ = -K x`, `τ⁺ = 0`.
#[derive(Debug, Clone)]
pub struct SampleAndHold {
    a: DMatrix<f64>,
    b: DMatrix<f64>,
    k: DMatrix<f64>,
    /// Sampling period.
    pub ts: f64,
    /// Report the flow as affine so that the engine advances it exactly.
    pub affine: bool,
    rules: Vec<JumpRule>,
}

impl SampleAndHold {
    /// The loop of plant `(a, b)` (n×n, n×m) and gain `k` (m×n) sampled
    /// every `ts`.
    pub fn new(a: DMatrix<f64>, b: DMatrix<f64>, k: DMatrix<f64>, ts: f64) -> Self {
        let index = a.nrows() + b.ncols();
        let rules = vec![JumpRule {
            name: "sample".into(),
            group: None,
            part: None,
            writes: Vec::new(),
            guard: GuardKind::Timer {
                index,
                threshold: ts,
                bounds_flow: false,
            },
        }];
        Self {
            a,
            b,
            k,
            ts,
            affine: false,
            rules,
        }
    }

    /// Plant dimension n.
    pub fn n(&self) -> usize {
        self.a.nrows()
    }

    /// Input dimension m.
    pub fn m(&self) -> usize {
        self.b.ncols()
    }

    /// Initial state `[x0, -K x0, 0]`: the first input is computed at t = 0.
    pub fn initial_state(&self, x0: &[f64]) -> Vec<f64> {
        let u0 = -(&self.k * DVector::from_column_slice(x0));
        let mut s = x0.to_vec();
        s.extend(u0.iter());
        s.push(0.0);
        s
    }

    /// The exact discretization: plant states at the sample instants
    /// `k·ts`, k = 0..=steps, from `x0` (`x_{k+1} = Φ x_k + Γ u_k`,
    /// `u_k = -K x_k`, Φ and Γ from the exponential of `[[A, B], [0, 0]]`).
    pub fn exact_samples(&self, x0: &[f64], steps: usize) -> Vec<DVector<f64>> {
        let (n, m) = (self.n(), self.m());
        let mut aug = DMatrix::zeros(n + m, n + m);
        aug.view_mut((0, 0), (n, n)).copy_from(&self.a);
        aug.view_mut((0, n), (n, m)).copy_from(&self.b);
        let e = (aug * self.ts).exp();
        let phi = e.view((0, 0), (n, n)).into_owned();
        let gamma = e.view((0, n), (n, m)).into_owned();
        let mut x = DVector::from_column_slice(x0);
        let mut out = vec![x.clone()];
        for _ in 0..steps {
            let u = -(&self.k * &x);
            x = &phi * &x + &gamma * u;
            out.push(x.clone());
        }
        out
    }

    /// The flow map without the trait indirection (shared with the
    /// hand-written benchmark reference): `dx = [A x + B u, 0, 1]`.
    pub fn flow(&self, x: &[f64], dx: &mut [f64]) {
        let (n, m) = (self.n(), self.m());
        let (dxp, rest) = dx.split_at_mut(n);
        rest.fill(0.0);
        rest[m] = 1.0;
        let mut out = DVectorViewMut::from_slice(dxp, n);
        out.gemv(1.0, &self.a, &DVectorView::from_slice(&x[..n], n), 0.0);
        out.gemv(1.0, &self.b, &DVectorView::from_slice(&x[n..n + m], m), 1.0);
    }

    /// The jump map without the trait indirection: `u⁺ = -K x`, `τ⁺ = 0`.
    pub fn sample(&self, x: &[f64], xp: &mut [f64]) {
        let (n, m) = (self.n(), self.m());
        xp.copy_from_slice(x);
        for r in 0..m {
            let acc: f64 = x[..n]
                .iter()
                .enumerate()
                .map(|(c, xc)| self.k[(r, c)] * xc)
                .sum();
            xp[n + r] = -acc;
        }
        xp[n + m] = 0.0;
    }
}

impl HybridSystem for SampleAndHold {
    fn state_dim(&self) -> usize {
        self.n() + self.m() + 1
    }
    fn state_names(&self) -> Vec<String> {
        let mut v: Vec<String> = (0..self.n()).map(|i| format!("x[{i}]")).collect();
        v.extend((0..self.m()).map(|i| format!("u[{i}]")));
        v.push("tau".into());
        v
    }
    fn flow_map(&self, _at: HybridTime, x: &[f64], dx: &mut [f64]) {
        self.flow(x, dx);
    }
    /// The constant ∂f/∂x = `[[A, B, 0], [0, 0, 0], [0, 0, 0]]`, for the
    /// implicit solvers.
    fn jacobian(&self, _at: HybridTime, _x: &[f64], jac: &mut [f64]) {
        let (n, m) = (self.n(), self.m());
        let d = n + m + 1;
        jac.fill(0.0);
        for r in 0..n {
            for c in 0..n {
                jac[r * d + c] = self.a[(r, c)];
            }
            for c in 0..m {
                jac[r * d + n + c] = self.b[(r, c)];
            }
        }
    }
    fn jump_rules(&self) -> &[JumpRule] {
        &self.rules
    }
    fn jump_set(&self, _rule: usize, _at: HybridTime, x: &[f64]) -> bool {
        x[self.n() + self.m()] >= self.ts
    }
    fn jump_guard(&self, _rule: usize, _at: HybridTime, x: &[f64]) -> f64 {
        x[self.n() + self.m()] - self.ts
    }
    fn jump_map(
        &self,
        _rule: usize,
        _at: HybridTime,
        x: &[f64],
        _rng: &mut SimRng,
        xp: &mut [f64],
    ) {
        self.sample(x, xp);
    }
    fn flow_structure(&self) -> FlowStructure {
        if !self.affine {
            return FlowStructure::General;
        }
        let (n, m) = (self.n(), self.m());
        let d = n + m + 1;
        let mut a = vec![0.0; d * d];
        for r in 0..n {
            for c in 0..n {
                a[r * d + c] = self.a[(r, c)];
            }
            for c in 0..m {
                a[r * d + n + c] = self.b[(r, c)];
            }
        }
        let mut b = vec![0.0; d];
        b[n + m] = 1.0;
        FlowStructure::Affine { a, b }
    }
}

/// A system whose flow and jump sets overlap, to show the priorities:
/// `ẋ = 1` in C = [0, 2], jump `x⁺ = 0` in D = {x ≥ 1}. From x = 0, jumps
/// first resets at t = 1, 2, 3, …; flows first flows to x = 2 and resets at
/// t = 2, 4, 6, ….
#[derive(Debug, Clone)]
pub struct OverlapDemo {
    rules: Vec<JumpRule>,
}

impl Default for OverlapDemo {
    fn default() -> Self {
        Self {
            rules: vec![JumpRule {
                name: "reset".into(),
                group: None,
                part: None,
                writes: Vec::new(),
                guard: GuardKind::General,
            }],
        }
    }
}

impl HybridSystem for OverlapDemo {
    fn state_dim(&self) -> usize {
        1
    }
    fn state_names(&self) -> Vec<String> {
        vec!["x".into()]
    }
    fn flow_map(&self, _at: HybridTime, _x: &[f64], dx: &mut [f64]) {
        dx[0] = 1.0;
    }
    fn flow_set(&self, _at: HybridTime, x: &[f64]) -> bool {
        (0.0..=2.0).contains(&x[0])
    }
    fn flow_guard(&self, _at: HybridTime, x: &[f64]) -> Option<f64> {
        Some(x[0].min(2.0 - x[0]))
    }
    fn jump_rules(&self) -> &[JumpRule] {
        &self.rules
    }
    fn jump_set(&self, _rule: usize, _at: HybridTime, x: &[f64]) -> bool {
        x[0] >= 1.0
    }
    fn jump_guard(&self, _rule: usize, _at: HybridTime, x: &[f64]) -> f64 {
        x[0] - 1.0
    }
    fn jump_map(
        &self,
        _rule: usize,
        _at: HybridTime,
        _x: &[f64],
        _rng: &mut SimRng,
        xp: &mut [f64],
    ) {
        xp[0] = 0.0;
    }
}

/// A rod in `n` cells (the method of lines: `u̇ᵢ = k (uᵢ₋₁ − 2uᵢ + uᵢ₊₁) −
/// loss·uᵢ`, insulated ends) heated in cell 0 with power `power·n` while the
/// heater `q` (the last state) is on; a thermostat with hysteresis on cell
/// n/2 (counted from 1, as `benches/models/heat_chain.hyb`) switches it off at `hi` (rule `off`) and on at `lo` (rule `on`).
/// Stiff for a large conduction `k` (the fastest mode decays at ≈ 4k) and
/// sparse (tridiagonal plus the heater's column): the reference system of
/// the sparse Jacobian path. With `pattern` it declares its
/// [`jacobian_pattern`](HybridSystem::jacobian_pattern), with `exact` also
/// its entries ([`jacobian_values`](HybridSystem::jacobian_values), or the
/// dense [`jacobian`](HybridSystem::jacobian) without a pattern).
#[derive(Debug, Clone)]
pub struct HeatChain {
    /// Cells (≥ 2).
    pub n: usize,
    /// Conduction between neighbouring cells.
    pub k: f64,
    /// Heat loss to the ambient.
    pub loss: f64,
    /// Heater power per unit length.
    pub power: f64,
    /// The thermostat's thresholds.
    pub lo: f64,
    /// See `lo`.
    pub hi: f64,
    /// Declare the sparsity pattern.
    pub pattern: bool,
    /// Give the exact Jacobian.
    pub exact: bool,
    rules: Vec<JumpRule>,
}

impl HeatChain {
    /// `n` cells with conduction `n²` (a unit rod), loss 0.5, power 4,
    /// thresholds 0.3 and 0.5; no pattern, no exact Jacobian.
    pub fn new(n: usize) -> Self {
        let rule = |name: &str| JumpRule {
            name: name.into(),
            group: None,
            part: None,
            writes: Vec::new(),
            guard: GuardKind::General,
        };
        Self {
            n,
            k: (n * n) as f64,
            loss: 0.5,
            power: 4.0,
            lo: 0.3,
            hi: 0.5,
            pattern: false,
            exact: false,
            rules: vec![rule("off"), rule("on")],
        }
    }

    /// The initial state: a cold rod, the heater on.
    pub fn initial_state(&self) -> Vec<f64> {
        let mut x = vec![0.0; self.n + 1];
        x[self.n] = 1.0;
        x
    }

    /// The thermostat's cell (0-based; cell n/2 counted from 1).
    fn sensor(&self) -> usize {
        self.n / 2 - 1
    }

    /// The entries of ∂f/∂x, (row, column, value), column by column.
    fn entries(&self) -> impl Iterator<Item = (usize, usize, f64)> + '_ {
        let n = self.n;
        (0..n)
            .flat_map(move |c| {
                let diag = if c == 0 || c == n - 1 {
                    -self.k
                } else {
                    -2.0 * self.k
                } - self.loss;
                [
                    (c > 0).then(|| (c - 1, c, self.k)),
                    Some((c, c, diag)),
                    (c + 1 < n).then(|| (c + 1, c, self.k)),
                ]
                .into_iter()
                .flatten()
            })
            .chain(std::iter::once((0, n, self.power * n as f64)))
    }
}

impl HybridSystem for HeatChain {
    fn state_dim(&self) -> usize {
        self.n + 1
    }
    fn state_names(&self) -> Vec<String> {
        (0..self.n)
            .map(|i| format!("u[{}]", i + 1))
            .chain(std::iter::once("q".into()))
            .collect()
    }
    fn flow_map(&self, _at: HybridTime, x: &[f64], dx: &mut [f64]) {
        let n = self.n;
        for i in 0..n {
            let left = if i > 0 { x[i - 1] - x[i] } else { 0.0 };
            let right = if i + 1 < n { x[i + 1] - x[i] } else { 0.0 };
            dx[i] = self.k * (left + right) - self.loss * x[i];
        }
        dx[0] += self.power * n as f64 * x[n];
        dx[n] = 0.0;
    }
    fn jump_rules(&self) -> &[JumpRule] {
        &self.rules
    }
    fn jump_set(&self, rule: usize, at: HybridTime, x: &[f64]) -> bool {
        self.jump_guard(rule, at, x) >= 0.0
    }
    fn jump_guard(&self, rule: usize, _at: HybridTime, x: &[f64]) -> f64 {
        let (u, on) = (x[self.sensor()], x[self.n] > 0.5);
        match (rule, on) {
            (0, true) => u - self.hi,
            (1, false) => self.lo - u,
            _ => -1.0,
        }
    }
    fn jump_map(
        &self,
        _rule: usize,
        _at: HybridTime,
        x: &[f64],
        _rng: &mut SimRng,
        xp: &mut [f64],
    ) {
        xp.copy_from_slice(x);
        xp[self.n] = 1.0 - x[self.n];
    }
    fn jacobian(&self, at: HybridTime, x: &[f64], jac: &mut [f64]) {
        if !self.exact {
            super::finite_difference_jacobian(self, at, x, jac);
            return;
        }
        let m = self.n + 1;
        jac.fill(0.0);
        for (r, c, v) in self.entries() {
            jac[r * m + c] = v;
        }
    }
    fn jacobian_pattern(&self) -> Option<super::SparsityPattern> {
        self.pattern.then(|| {
            super::SparsityPattern::new(self.n + 1, self.entries().map(|(r, c, _)| (r, c)))
                .expect("entries in range")
        })
    }
    fn jacobian_values(&self, _at: HybridTime, _x: &[f64], values: &mut [f64]) -> bool {
        if !self.exact {
            return false;
        }
        // `entries` is column by column with rows ascending: the pattern's order.
        for (v, (_, _, e)) in values.iter_mut().zip(self.entries()) {
            *v = e;
        }
        true
    }
}
