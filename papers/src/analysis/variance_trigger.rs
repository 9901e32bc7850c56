//! The variance iteration of event-based state estimation with
//! variance-based triggering (Trimpe and D'Andrea, "Event-based state
//! estimation with variance-based triggering").
//!
//! A sensor observes `x(k+1) = a x(k) + v(k)`, `y(k) = c x(k) + w(k)`
//! (`v ~ N(0, q)`, `w ~ N(0, r)`) and transmits `y(k)` to a remote Kalman
//! filter only when the measurement prediction variance exceeds the
//! steady-state one by δ. The prediction variance `p(k) = p(k|k−1)` then
//! obeys the switched Riccati iteration (1)–(3) of the paper:
//!
//! ```text
//!     p(k+1) = h(p(k)) = a² p + q − γ(p) a² c² p² / (c² p + r),
//!     γ(p)   = 1 if c² (p − p̄) ≥ δ, else 0,            p̄ = DARE(a, c, q, r).
//! ```
//!
//! The paper normalizes to `q = r = 1` in Sec. IV; this module keeps the
//! original coordinates (all quantities below are invariant under that
//! scaling except for the factor `q` on variances), so the threshold is
//! `t = p̄ + δ/c²` (the paper's `p̄ + δ` when `c = 1`).
//!
//! | paper | here |
//! |---|---|
//! | `g` (24), full-communication iteration | [`VarianceIteration::g`], `g′` = [`VarianceIteration::g_prime`] |
//! | `h` (23) | [`VarianceIteration::h`] |
//! | `p1 = h(p̄+δ)`, `p2 = a²(p̄+δ) + 1` (Prop. 1) | [`VarianceIteration::invariant_interval`] |
//! | `h⁻¹` and `dom(h⁻¹)` (28) | [`VarianceIteration::h_inv`], [`VarianceIteration::inverse_domain`] |
//! | Algorithm 1 (`d_i`, `N`) | [`VarianceIteration::algorithm1`] |
//! | intervals `I_i` (36)–(38), Assumption 2 | [`VarianceIteration::partition`] |
//! | bound on `d(h^N)/dp` as in (32) | [`Partition::contraction_bound`] |
//! | N-periodic points (Theorem 2) | [`VarianceIteration::periodic_orbit`] |
//!
//! Two details differ from the printed text and are recorded in
//! REPRODUCTION.md: the range of `h` on `[p1, p2]` is
//! `[p1, h(p2)] ∪ [h(p1), p2)` (the upper branch `g` is continuous on the
//! closed `[t, p2]`; the lower branch `a²p + q` on `[p1, t)` never reaches
//! `p2`), whereas (28) prints `[p1, h(p2)) ∪ [h(p1), p2]`; and for general
//! periods the (32)-style bound multiplies `a²` for each interval below `t`
//! and `g′(lower end)` for each interval above it, which for Example 1 is
//! the paper's `a⁴ g′(p̄ + δ)`.
//!
//! ```
//! use hybsim_papers::analysis::variance_trigger::VarianceIteration;
//! let it = VarianceIteration::new(1.2, 1.0, 1.0, 1.0, 3.0).unwrap(); // Example 1
//! let alg = it.algorithm1(1000);
//! assert_eq!(alg.period(), Some(3));
//! let (p1, p2) = it.invariant_interval();
//! assert!((p1 - 2.20).abs() < 0.005 && (p2 - 8.13).abs() < 0.005);
//! ```

use serde::Serialize;
use thiserror::Error;

/// Why a parameter set is outside the paper's assumptions
/// (`|a| > 1`, `c ≠ 0`, `q > 0`, `r > 0`, `δ ≥ 0`, all finite).
#[derive(Debug, Clone, PartialEq, Error)]
pub enum VarianceTriggerError {
    /// A parameter is NaN or infinite.
    #[error("parameter `{name}` = {value} is not finite")]
    NonFinite {
        /// Parameter name (`a`, `c`, `q`, `r`, `delta`, `p0`).
        name: &'static str,
        /// Its value.
        value: f64,
    },
    /// `|a| ≤ 1`: the analysis is for unstable processes.
    #[error("|a| = {a} is not greater than 1; the analysis assumes an unstable process")]
    StableProcess {
        /// The value of `a`.
        a: f64,
    },
    /// `c = 0`: the process is not detectable.
    #[error("c = 0: the process is not detectable")]
    ZeroC,
    /// `q ≤ 0` or `r ≤ 0`.
    #[error("noise variance `{name}` = {value} must be positive")]
    NonPositiveVariance {
        /// `q` or `r`.
        name: &'static str,
        /// Its value.
        value: f64,
    },
    /// `δ < 0` or `p0 < 0`.
    #[error("`{name}` = {value} must not be negative")]
    Negative {
        /// `delta` or `p0`.
        name: &'static str,
        /// Its value.
        value: f64,
    },
}

/// The switched Riccati iteration (1)–(3) for one parameter set.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct VarianceIteration {
    a: f64,
    c: f64,
    q: f64,
    r: f64,
    delta: f64,
    p_bar: f64,
}

/// The domain of `h⁻¹`: the range of `h` on `[p1, p2]`, two disjoint pieces.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct InverseDomain {
    /// `[p1, h(p2)]`, image of the transmitting branch `g` on `[t, p2]`
    /// (closed at both ends).
    pub transmit: (f64, f64),
    /// `[h(p1), p2)`, image of the silent branch `a²p + q` on `[p1, t)`
    /// (closed below, open above).
    pub silent: (f64, f64),
}

impl InverseDomain {
    /// `y ∈ dom(h⁻¹)`.
    pub fn contains(&self, y: f64) -> bool {
        (self.transmit.0..=self.transmit.1).contains(&y)
            || (self.silent.0..self.silent.1).contains(&y)
    }
}

/// Why Algorithm 1 stopped.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "outcome", rename_all = "snake_case")]
pub enum Algorithm1Outcome {
    /// Some `d_m ∉ dom(h⁻¹)`: the algorithm terminated with period `n = m + 1`.
    Terminated {
        /// The period N.
        n: usize,
    },
    /// `max_points` points were computed and all were in `dom(h⁻¹)`:
    /// Assumption 1 could not be confirmed within the bound.
    NotTerminated {
        /// The bound that was reached.
        max_points: usize,
    },
    /// δ = 0: `d_1 = p̄` is a fixed point of `h⁻¹`, so in exact arithmetic
    /// the algorithm never terminates (the iteration is the full Kalman
    /// filter, with no switching). Reported without iterating, since in
    /// floating point the repelling fixed point would be left by rounding.
    FullCommunication,
}

/// Result of Algorithm 1: the discontinuity points `d_1, d_2, …` and the outcome.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Algorithm1 {
    /// `d_1 = t = p̄ + δ/c²`, `d_{i+1} = h⁻¹(d_i)`; `d[0]` is `d_1`.
    pub d: Vec<f64>,
    /// Whether it terminated, and with which N.
    pub outcome: Algorithm1Outcome,
}

impl Algorithm1 {
    /// The period N if the algorithm terminated.
    pub fn period(&self) -> Option<usize> {
        match self.outcome {
            Algorithm1Outcome::Terminated { n } => Some(n),
            Algorithm1Outcome::NotTerminated { .. } | Algorithm1Outcome::FullCommunication => None,
        }
    }
}

/// One of the intervals `I_i = [lower, upper)` of (36)–(38).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Subinterval {
    /// Index i (1-based, as in the paper): `I_i` has lower bound `d_i` for
    /// `i ≤ N−1`; `I_N` has lower bound `p1`.
    pub index: usize,
    /// Closed lower bound.
    pub lower: f64,
    /// Open upper bound.
    pub upper: f64,
    /// `true` if the interval lies in `[t, p2)`, where a measurement is sent.
    pub transmits: bool,
    /// Upper bound of `|h′|` on the interior: `a²` on silent intervals,
    /// `g′(lower)` on transmitting ones (`g′` is decreasing).
    pub slope_bound: f64,
}

/// The partition of `[p1, p2)` by a terminated Algorithm 1 (Sec. IV-C).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Partition {
    /// The period N.
    pub n: usize,
    /// `I_1, …, I_N` in the paper's numbering (`intervals[i-1]` is `I_i`).
    pub intervals: Vec<Subinterval>,
    /// `h(p2)`.
    pub h_p2: f64,
    /// `d_{N−1}`, the last point of Algorithm 1.
    pub d_last: f64,
    /// Assumption 2: `h(p2) < d_{N−1}`.
    pub assumption2: bool,
}

impl Partition {
    /// The bound on `|d(h^N)/dp|` on the interiors of the intervals, as in
    /// (32): along one period a point visits every interval once
    /// (Prop. 4), so the bound is the product of all slope bounds. For
    /// Example 1 this is `a⁴ g′(p̄ + δ)`. Theorem 2's contraction argument
    /// goes through directly when it is below 1.
    pub fn contraction_bound(&self) -> f64 {
        self.intervals.iter().map(|i| i.slope_bound).product()
    }

    /// Number of transmissions per period (intervals above the threshold).
    pub fn transmissions_per_period(&self) -> usize {
        self.intervals.iter().filter(|i| i.transmits).count()
    }

    /// The interval `I_i` containing `p`, if `p ∈ [p1, p2)`.
    pub fn locate(&self, p: f64) -> Option<&Subinterval> {
        self.intervals
            .iter()
            .find(|i| (i.lower..i.upper).contains(&p))
    }
}

fn finite(name: &'static str, value: f64) -> Result<f64, VarianceTriggerError> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(VarianceTriggerError::NonFinite { name, value })
    }
}

/// The positive solution of the scalar DARE (6),
/// `c² p² − (a² r + q c² − r) p − q r = 0`, in a cancellation-free form.
fn scalar_dare(a: f64, c: f64, q: f64, r: f64) -> f64 {
    let c2 = c * c;
    let b = a * a * r + q * c2 - r;
    let disc = (b * b + 4.0 * c2 * q * r).sqrt();
    if b >= 0.0 {
        (b + disc) / (2.0 * c2)
    } else {
        2.0 * q * r / (disc - b)
    }
}

impl VarianceIteration {
    /// The iteration for parameters `a, c, q, r, δ`, checked against the
    /// paper's assumptions (`δ = 0` is allowed: the full Kalman filter).
    pub fn new(a: f64, c: f64, q: f64, r: f64, delta: f64) -> Result<Self, VarianceTriggerError> {
        let a = finite("a", a)?;
        let c = finite("c", c)?;
        let q = finite("q", q)?;
        let r = finite("r", r)?;
        let delta = finite("delta", delta)?;
        if a.abs() <= 1.0 {
            return Err(VarianceTriggerError::StableProcess { a });
        }
        if c == 0.0 {
            return Err(VarianceTriggerError::ZeroC);
        }
        for (name, value) in [("q", q), ("r", r)] {
            if value <= 0.0 {
                return Err(VarianceTriggerError::NonPositiveVariance { name, value });
            }
        }
        if delta < 0.0 {
            return Err(VarianceTriggerError::Negative {
                name: "delta",
                value: delta,
            });
        }
        Ok(Self {
            a,
            c,
            q,
            r,
            delta,
            p_bar: scalar_dare(a, c, q, r),
        })
    }

    /// The same process with another threshold δ.
    pub fn with_delta(&self, delta: f64) -> Result<Self, VarianceTriggerError> {
        Self::new(self.a, self.c, self.q, self.r, delta)
    }

    /// Process gain a.
    pub fn a(&self) -> f64 {
        self.a
    }
    /// Output gain c.
    pub fn c(&self) -> f64 {
        self.c
    }
    /// Process noise variance q.
    pub fn q(&self) -> f64 {
        self.q
    }
    /// Measurement noise variance r.
    pub fn r(&self) -> f64 {
        self.r
    }
    /// Threshold δ on the measurement prediction variance.
    pub fn delta(&self) -> f64 {
        self.delta
    }

    /// `p̄ = DARE(a, c, q, r)`, the steady-state prediction variance of the
    /// full-communication Kalman filter (6) (closed form of the scalar
    /// equation).
    pub fn p_bar(&self) -> f64 {
        self.p_bar
    }

    /// The transmit threshold `t = p̄ + δ/c²` on `p` (`d_1` of Algorithm 1).
    pub fn threshold(&self) -> f64 {
        self.p_bar + self.delta / (self.c * self.c)
    }

    /// The trigger (3): `c² (p − p̄) ≥ δ`.
    pub fn transmits(&self, p: f64) -> bool {
        self.c * self.c * (p - self.p_bar) >= self.delta
    }

    /// The full-communication Riccati map (24), `g(p) = a²p + q − a²c²p²/(c²p + r)`.
    pub fn g(&self, p: f64) -> f64 {
        let (a2, c2) = (self.a * self.a, self.c * self.c);
        a2 * p + self.q - a2 * c2 * p * p / (c2 * p + self.r)
    }

    /// `g′(p) = a² r² / (c² p + r)²`, positive and decreasing for `p ≥ 0`.
    pub fn g_prime(&self, p: f64) -> f64 {
        let s = self.c * self.c * p + self.r;
        self.a * self.a * self.r * self.r / (s * s)
    }

    /// One step of (1)–(3): `h(p) = g(p)` if the trigger fires, else `a²p + q`.
    pub fn h(&self, p: f64) -> f64 {
        if self.transmits(p) {
            self.g(p)
        } else {
            self.a * self.a * p + self.q
        }
    }

    /// `p(0), …, p(steps)` of (22) from `p0`.
    pub fn iterate(&self, p0: f64, steps: usize) -> Vec<f64> {
        let mut out = Vec::with_capacity(steps + 1);
        let mut p = p0;
        out.push(p);
        for _ in 0..steps {
            p = self.h(p);
            out.push(p);
        }
        out
    }

    /// The invariant interval `[p1, p2]` of Proposition 1:
    /// `p1 = h(t) = g(t)`, `p2 = a² t + q`.
    pub fn invariant_interval(&self) -> (f64, f64) {
        let t = self.threshold();
        (self.g(t), self.a * self.a * t + self.q)
    }

    /// The domain of `h⁻¹`, i.e. the range of `h` on `[p1, p2]`.
    pub fn inverse_domain(&self) -> InverseDomain {
        let (p1, p2) = self.invariant_interval();
        InverseDomain {
            transmit: (p1, self.h(p2)),
            silent: (self.h(p1), p2),
        }
    }

    /// `h⁻¹(y) ∈ [p1, p2]` with `h(h⁻¹(y)) = y`, or `None` if
    /// `y ∉ dom(h⁻¹)`. On the transmitting piece `h⁻¹ = g⁻¹`,
    /// `g⁻¹(y) = r (y − q) / (a² r + q c² − c² y)`; on the silent piece
    /// `h⁻¹(y) = (y − q)/a²`.
    pub fn h_inv(&self, y: f64) -> Option<f64> {
        let dom = self.inverse_domain();
        let (a2, c2) = (self.a * self.a, self.c * self.c);
        if (dom.transmit.0..=dom.transmit.1).contains(&y) {
            Some(self.r * (y - self.q) / (a2 * self.r + self.q * c2 - c2 * y))
        } else if (dom.silent.0..dom.silent.1).contains(&y) {
            Some((y - self.q) / a2)
        } else {
            None
        }
    }

    /// Algorithm 1: `d_1 = t`, `d_{i+1} = h⁻¹(d_i)` while `d_i ∈ dom(h⁻¹)`,
    /// `N = i + 1`. At most `max_points` points are computed; if all of
    /// them lie in `dom(h⁻¹)` the outcome is
    /// [`Algorithm1Outcome::NotTerminated`]; δ = 0 gives
    /// [`Algorithm1Outcome::FullCommunication`] with `d = [p̄]`.
    pub fn algorithm1(&self, max_points: usize) -> Algorithm1 {
        let mut d = vec![self.threshold()];
        if self.delta == 0.0 {
            return Algorithm1 {
                d,
                outcome: Algorithm1Outcome::FullCommunication,
            };
        }
        loop {
            let last = d[d.len() - 1];
            match self.h_inv(last) {
                None => {
                    let n = d.len() + 1;
                    return Algorithm1 {
                        d,
                        outcome: Algorithm1Outcome::Terminated { n },
                    };
                }
                Some(_) if d.len() >= max_points => {
                    return Algorithm1 {
                        d,
                        outcome: Algorithm1Outcome::NotTerminated { max_points },
                    };
                }
                Some(next) => d.push(next),
            }
        }
    }

    /// The intervals `I_1, …, I_N` of (36)–(38) and Assumption 2, or `None`
    /// if Algorithm 1 did not terminate.
    pub fn partition(&self, alg: &Algorithm1) -> Option<Partition> {
        let n = alg.period()?;
        let (p1, p2) = self.invariant_interval();
        let t = self.threshold();
        let mut order: Vec<usize> = (0..alg.d.len()).collect();
        order.sort_by(|&i, &j| alg.d[i].total_cmp(&alg.d[j]));
        let make = |index: usize, lower: f64, upper: f64| {
            let transmits = lower >= t;
            Subinterval {
                index,
                lower,
                upper,
                transmits,
                slope_bound: if transmits {
                    self.g_prime(lower)
                } else {
                    self.a * self.a
                },
            }
        };
        let mut intervals = vec![None; n];
        for (rank, &i) in order.iter().enumerate() {
            let upper = order.get(rank + 1).map_or(p2, |&k| alg.d[k]);
            intervals[i] = Some(make(i + 1, alg.d[i], upper));
        }
        intervals[n - 1] = Some(make(n, p1, alg.d[order[0]]));
        let intervals: Vec<Subinterval> = intervals.into_iter().flatten().collect();
        let h_p2 = self.h(p2);
        let d_last = alg.d[alg.d.len() - 1];
        Some(Partition {
            n,
            intervals,
            h_p2,
            d_last,
            assumption2: h_p2 < d_last,
        })
    }

    /// The N-cycle of Theorem 2: the fixed point `p*` of `h^N` in `I_1`
    /// (found by iterating `h^N` from `t`, at most `max_cycles` times, until
    /// successive iterates agree to `1e-14` relative, then taking the point
    /// of that cycle in `I_1`), followed by
    /// `h(p*), …, h^{N−1}(p*)`. `None` if the iteration did not settle or a
    /// point of the cycle is not in the interval Proposition 4 puts it in
    /// (`h^k(p*) ∈ I_{N−k+1}`).
    pub fn periodic_orbit(&self, partition: &Partition, max_cycles: usize) -> Option<Vec<f64>> {
        let n = partition.n;
        let mut p = self.threshold();
        let mut settled = false;
        for _ in 0..max_cycles {
            let mut next = p;
            for _ in 0..n {
                next = self.h(next);
            }
            let done = (next - p).abs() <= 1e-14 * p.abs().max(1.0);
            p = next;
            if done {
                settled = true;
                break;
            }
        }
        if !settled {
            return None;
        }
        // Start the cycle at its point in I_1. (The iteration from t may
        // settle on another phase: in floating point t itself can test
        // below the threshold, c²(t − p̄) < δ by one rounding.)
        let start = self
            .iterate(p, n - 1)
            .into_iter()
            .find(|&pk| partition.locate(pk).map(|i| i.index) == Some(1))?;
        let cycle = self.iterate(start, n - 1);
        for (k, &pk) in cycle.iter().enumerate() {
            // h^k(p*) ∈ I_{N-k+1}, with I_{N+1} meaning I_1.
            let expected = if k == 0 { 1 } else { n - k + 1 };
            if partition.locate(pk).map(|i| i.index) != Some(expected) {
                return None;
            }
        }
        Some(cycle)
    }

    /// `|d(h^N)/dp|` at the N-cycle, `∏ h′(p_k)` over its points: the actual
    /// contraction factor of `h^N` near the cycle (≤ the bound of
    /// [`Partition::contraction_bound`]).
    pub fn cycle_multiplier(&self, cycle: &[f64]) -> f64 {
        cycle
            .iter()
            .map(|&p| {
                if self.transmits(p) {
                    self.g_prime(p)
                } else {
                    self.a * self.a
                }
            })
            .product()
    }

    /// All of the paper's quantities at once (Algorithm 1 with at most
    /// `max_points` points).
    pub fn analyze(&self, max_points: usize) -> Analysis {
        let algorithm1 = self.algorithm1(max_points);
        let partition = self.partition(&algorithm1);
        let orbit = partition
            .as_ref()
            .and_then(|p| self.periodic_orbit(p, 100_000));
        let (p1, p2) = self.invariant_interval();
        Analysis {
            delta: self.delta,
            p_bar: self.p_bar,
            threshold: self.threshold(),
            p1,
            p2,
            period: algorithm1.period(),
            assumption2: partition.as_ref().map(|p| p.assumption2),
            contraction_bound: partition.as_ref().map(Partition::contraction_bound),
            cycle_multiplier: orbit.as_ref().map(|o| self.cycle_multiplier(o)),
            orbit,
            algorithm1,
        }
    }
}

/// Summary of [`VarianceIteration::analyze`] for one δ.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Analysis {
    /// δ.
    pub delta: f64,
    /// `p̄`.
    pub p_bar: f64,
    /// `t = p̄ + δ/c²`.
    pub threshold: f64,
    /// Lower end of the invariant interval.
    pub p1: f64,
    /// Upper end of the invariant interval.
    pub p2: f64,
    /// N from Algorithm 1, if it terminated.
    pub period: Option<usize>,
    /// Assumption 2, if Algorithm 1 terminated.
    pub assumption2: Option<bool>,
    /// The (32)-style bound, if Algorithm 1 terminated.
    pub contraction_bound: Option<f64>,
    /// `|d(h^N)/dp|` at the cycle, if it was found.
    pub cycle_multiplier: Option<f64>,
    /// The N-cycle starting in `I_1`, if found.
    pub orbit: Option<Vec<f64>>,
    /// Algorithm 1's points and outcome.
    pub algorithm1: Algorithm1,
}

/// A δ grid for period sweeps: `steps + 1` equally spaced values on
/// `[lo, hi]`, then `levels` rounds of refinement in which every cell whose
/// two ends have different Algorithm 1 outcomes (period, or non-termination)
/// receives `per_cell` equally spaced interior points. Period windows
/// narrower than the grid spacing (the period-adding cascades between
/// neighbouring periods) are found this way without knowing where they are.
/// Values are sorted and finite; invalid δ (negative) are skipped.
pub fn refined_delta_grid(
    base: &VarianceIteration,
    lo: f64,
    hi: f64,
    steps: usize,
    levels: usize,
    per_cell: usize,
    max_points: usize,
) -> Vec<f64> {
    let steps = steps.max(1);
    let period = |d: f64| -> Option<Option<usize>> {
        Some(base.with_delta(d).ok()?.algorithm1(max_points).period())
    };
    let mut grid: Vec<(f64, Option<Option<usize>>)> = (0..=steps)
        .map(|i| lo + (hi - lo) * i as f64 / steps as f64)
        .filter(|d| d.is_finite())
        .map(|d| (d, period(d)))
        .collect();
    for _ in 0..levels {
        let mut next = Vec::with_capacity(grid.len());
        for w in grid.windows(2) {
            next.push(w[0]);
            if w[0].1 != w[1].1 {
                for k in 1..=per_cell {
                    let d = w[0].0 + (w[1].0 - w[0].0) * k as f64 / (per_cell + 1) as f64;
                    next.push((d, period(d)));
                }
            }
        }
        if let Some(&last) = grid.last() {
            next.push(last);
        }
        grid = next;
    }
    grid.into_iter()
        .filter(|(_, p)| p.is_some())
        .map(|(d, _)| d)
        .collect()
}

/// How a simulated period compares with Algorithm 1 for one δ.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(tag = "comparison", rename_all = "snake_case")]
pub enum Comparison {
    /// Algorithm 1 terminated, Assumption 2 holds, and the simulated
    /// sequence has period N: Theorem 2 confirmed.
    Agree {
        /// The common period.
        n: usize,
    },
    /// Algorithm 1 terminated and Assumption 2 holds, but the simulation
    /// found another period (or none): a genuine disagreement.
    Differ {
        /// N from Algorithm 1.
        algorithm1: usize,
        /// The simulated period, if one was detected.
        simulated: Option<usize>,
    },
    /// Assumption 2 fails, so Theorem 2 does not apply; both values shown.
    Assumption2Fails {
        /// N from Algorithm 1.
        algorithm1: usize,
        /// The simulated period, if one was detected.
        simulated: Option<usize>,
    },
    /// Algorithm 1 did not terminate within its bound (or δ = 0).
    NoAlgorithm1 {
        /// The simulated period, if one was detected.
        simulated: Option<usize>,
    },
}

impl Comparison {
    /// Compares Algorithm 1's result in `analysis` with a simulated period.
    pub fn of(analysis: &Analysis, simulated: Option<usize>) -> Self {
        match (analysis.period, analysis.assumption2) {
            (Some(n), Some(true)) if simulated == Some(n) => Comparison::Agree { n },
            (Some(algorithm1), Some(true)) => Comparison::Differ {
                algorithm1,
                simulated,
            },
            (Some(algorithm1), _) => Comparison::Assumption2Fails {
                algorithm1,
                simulated,
            },
            (None, _) => Comparison::NoAlgorithm1 { simulated },
        }
    }

    /// Short label for tables: `agree`, `DIFFER`, `assumption 2 fails`,
    /// `no algorithm 1`.
    pub fn label(&self) -> &'static str {
        match self {
            Comparison::Agree { .. } => "agree",
            Comparison::Differ { .. } => "DIFFER",
            Comparison::Assumption2Fails { .. } => "assumption 2 fails",
            Comparison::NoAlgorithm1 { .. } => "no algorithm 1",
        }
    }
}

/// One δ of a period sweep: the theory and the simulation side by side.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SweepRow {
    /// Algorithm 1, Assumption 2, bound and Theorem 2's cycle for this δ.
    pub analysis: Analysis,
    /// Period of the simulated `p(k)` (see [`hybsim::analysis::periodicity`]).
    pub simulated_period: Option<usize>,
    /// Periodic points of the simulated `p(k)`, sorted, if periodic.
    pub simulated_points: Option<Vec<f64>>,
    /// Largest distance between the sorted simulated periodic points and
    /// Theorem 2's cycle, when both exist and have the same length.
    pub point_gap: Option<f64>,
    /// The verdict.
    pub comparison: Comparison,
}

impl SweepRow {
    /// Builds the row for `it` (Algorithm 1 with at most `max_points`
    /// points) from a simulated sequence `p(0), p(1), …` analysed with
    /// `settings`.
    pub fn new(
        it: &VarianceIteration,
        max_points: usize,
        simulated_p: &[f64],
        settings: &hybsim::analysis::periodicity::PeriodSettings,
    ) -> Self {
        use hybsim::analysis::periodicity::{PeriodOutcome, detect_period_scalar};
        let analysis = it.analyze(max_points);
        let (simulated_period, simulated_points) = match detect_period_scalar(simulated_p, settings)
        {
            PeriodOutcome::Periodic(o) => (Some(o.period), o.sorted_points(0)),
            _ => (None, None),
        };
        let point_gap = match (&simulated_points, &analysis.orbit) {
            (Some(sim), Some(orbit)) if sim.len() == orbit.len() => {
                let mut orbit = orbit.clone();
                orbit.sort_by(f64::total_cmp);
                Some(
                    sim.iter()
                        .zip(&orbit)
                        .map(|(a, b)| (a - b).abs())
                        .fold(0.0, f64::max),
                )
            }
            _ => None,
        };
        let comparison = Comparison::of(&analysis, simulated_period);
        Self {
            analysis,
            simulated_period,
            simulated_points,
            point_gap,
            comparison,
        }
    }

    /// CSV header matching [`SweepRow::csv_line`].
    pub const CSV_HEADER: &'static str = "delta,p_bar,p1,p2,algorithm1_n,assumption2,contraction_bound,cycle_multiplier,simulated_period,point_gap,comparison";

    /// One CSV line (empty fields for absent values).
    pub fn csv_line(&self) -> String {
        fn opt<T: std::fmt::Display>(v: Option<T>) -> String {
            v.map(|v| v.to_string()).unwrap_or_default()
        }
        let a = &self.analysis;
        format!(
            "{},{},{},{},{},{},{},{},{},{},{}",
            a.delta,
            a.p_bar,
            a.p1,
            a.p2,
            opt(a.period),
            opt(a.assumption2),
            opt(a.contraction_bound),
            opt(a.cycle_multiplier),
            opt(self.simulated_period),
            opt(self.point_gap),
            self.comparison.label()
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example1() -> VarianceIteration {
        VarianceIteration::new(1.2, 1.0, 1.0, 1.0, 3.0).unwrap()
    }

    #[test]
    fn rejects_parameters_outside_the_paper() {
        use VarianceTriggerError as E;
        assert_eq!(
            VarianceIteration::new(0.9, 1.0, 1.0, 1.0, 1.0),
            Err(E::StableProcess { a: 0.9 })
        );
        assert_eq!(
            VarianceIteration::new(1.2, 0.0, 1.0, 1.0, 1.0),
            Err(E::ZeroC)
        );
        assert!(matches!(
            VarianceIteration::new(1.2, 1.0, 0.0, 1.0, 1.0),
            Err(E::NonPositiveVariance { name: "q", .. })
        ));
        assert!(matches!(
            VarianceIteration::new(1.2, 1.0, 1.0, -1.0, 1.0),
            Err(E::NonPositiveVariance { name: "r", .. })
        ));
        assert!(matches!(
            VarianceIteration::new(1.2, 1.0, 1.0, 1.0, -1.0),
            Err(E::Negative { name: "delta", .. })
        ));
        assert!(matches!(
            VarianceIteration::new(f64::NAN, 1.0, 1.0, 1.0, 1.0),
            Err(E::NonFinite { name: "a", .. })
        ));
    }

    #[test]
    fn p_bar_solves_the_dare() {
        for &(a, c, q, r) in &[
            (1.2, 1.0, 1.0, 1.0),
            (-3.0, 0.2, 5.0, 0.01),
            (1.01, 7.0, 0.1, 40.0),
        ] {
            let it = VarianceIteration::new(a, c, q, r, 0.0).unwrap();
            let p = it.p_bar();
            assert!(p > 0.0);
            assert!((it.g(p) - p).abs() <= 1e-12 * p.max(1.0), "{a} {c} {q} {r}");
        }
        // Example 1: p̄ solves p² − a² p − 1 = 0.
        let p = example1().p_bar();
        assert!((p - (1.44 + (1.44f64 * 1.44 + 4.0).sqrt()) / 2.0).abs() < 1e-14);
    }

    #[test]
    fn h_inverse_inverts_h_on_its_domain() {
        let it = example1();
        let (p1, p2) = it.invariant_interval();
        for i in 0..=1000 {
            let p = p1 + (p2 - p1) * i as f64 / 1000.0;
            let y = it.h(p);
            let back = it.h_inv(y).expect("h(p) is in dom(h⁻¹)");
            assert!((back - p).abs() <= 1e-12 * p, "p = {p}, back = {back}");
            assert!(it.inverse_domain().contains(y) || i == 1000);
        }
        // p2 itself is not in the range of h on [p1, p2].
        assert_eq!(it.h_inv(p2), None);
        assert_eq!(it.h_inv(p1 - 1e-9), None);
    }

    #[test]
    fn example1_quantities() {
        let it = example1();
        let (p1, p2) = it.invariant_interval();
        assert!((p1 - 2.20).abs() < 0.005, "{p1}");
        assert!((p2 - 8.13).abs() < 0.005, "{p2}");
        let alg = it.algorithm1(100);
        assert_eq!(alg.period(), Some(3));
        assert!((alg.d[0] - 4.95).abs() < 0.005);
        assert!((alg.d[1] - 2.74).abs() < 0.005, "{}", alg.d[1]);
        let part = it.partition(&alg).unwrap();
        assert!(part.assumption2);
        let bound = part.contraction_bound();
        let paper = it.a().powi(4) * it.g_prime(it.p_bar() + 3.0);
        assert!((bound - paper).abs() < 1e-15);
        assert!((bound - 0.084).abs() < 0.0005, "{bound}");
        // I_3 = [p1, d2), I_2 = [d2, d1), I_1 = [d1, p2).
        let iv = &part.intervals;
        assert_eq!(
            iv.iter()
                .map(|i| (i.index, i.lower, i.upper))
                .collect::<Vec<_>>(),
            vec![
                (1, alg.d[0], p2),
                (2, alg.d[1], alg.d[0]),
                (3, p1, alg.d[1])
            ]
        );
        let orbit = it.periodic_orbit(&part, 1000).unwrap();
        assert_eq!(orbit.len(), 3);
        assert!(it.cycle_multiplier(&orbit) < bound);
        // The simulated iteration from p̄ converges to the same cycle.
        let seq = it.iterate(it.p_bar(), 300);
        let tail = &seq[seq.len() - 3..];
        let mut a = tail.to_vec();
        let mut b = orbit.clone();
        a.sort_by(f64::total_cmp);
        b.sort_by(f64::total_cmp);
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() < 1e-12, "{a:?} vs {b:?}");
        }
    }

    #[test]
    fn delta_zero_never_terminates_and_converges_to_p_bar() {
        let it = VarianceIteration::new(1.2, 1.0, 1.0, 1.0, 0.0).unwrap();
        let alg = it.algorithm1(50);
        assert_eq!(alg.outcome, Algorithm1Outcome::FullCommunication);
        assert_eq!(alg.d, vec![it.p_bar()]);
        // A tiny δ does terminate, with a long sequence of d_i.
        let small = it.with_delta(1e-6).unwrap().algorithm1(100_000);
        assert!(small.period().is_some_and(|n| n > 5), "{:?}", small.outcome);
        let bounded = it.with_delta(1e-6).unwrap().algorithm1(5);
        assert_eq!(
            bounded.outcome,
            Algorithm1Outcome::NotTerminated { max_points: 5 }
        );
        assert_eq!(bounded.d.len(), 5);
        assert_eq!(it.partition(&alg), None);
        let seq = it.iterate(10.0, 200);
        assert!((seq[200] - it.p_bar()).abs() < 1e-12);
    }

    #[test]
    fn refined_grid_adds_points_only_at_transitions() {
        let it = example1();
        let grid = refined_delta_grid(&it, 1.0, 3.0, 4, 1, 3, 1000);
        // Coarse: 1.0 1.5 2.0 2.5 3.0 → N = 2 2 2 3 3: one transition cell.
        assert_eq!(grid.len(), 5 + 3);
        assert!(grid.windows(2).all(|w| w[0] < w[1]));
    }
}
