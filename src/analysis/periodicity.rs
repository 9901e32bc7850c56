//! Asymptotic period and periodic points of a logged sequence.
//!
//! A sequence `x(0), x(1), …, x(L−1)` (one or several channels of equal
//! length, e.g. `p(k)` and `γ(k)` of a discrete-time run) is called
//! *numerically N-periodic at its end* if, for every channel and every index
//! `k` of the last `repeats · N` samples,
//!
//! ```text
//!     |x(k) − x(k − N)| ≤ abs_tol + rel_tol · max(|x(k)|, |x(k − N)|).
//! ```
//!
//! [`detect_period`] returns the smallest such `N ≤ max_period` (the
//! *asymptotic period*), the last full cycle (the *periodic points*, in time
//! order), the index from which the whole remaining sequence satisfies the
//! test (`settled_at`), and the largest mismatch seen in the checked window.
//! This is the practical counterpart of "asymptotically N-periodic"
//! (lim_m x(k + mN) exists for every k): a run that converges slowly or is
//! too short is reported as [`PeriodOutcome::NotPeriodic`] or
//! [`PeriodOutcome::TooShort`], never guessed.
//!
//! Choosing tolerances: the defaults (`abs_tol = rel_tol = 1e-9`,
//! `repeats = 4`) suit deterministic iterations that converge geometrically,
//! such as the switched Riccati iteration of the variance-based trigger,
//! simulated long enough (a few hundred periods). For noisy signals raise
//! the tolerances above the noise level.
//!
//! ```
//! use hybsim::analysis::periodicity::{detect_period_scalar, PeriodOutcome, PeriodSettings};
//! let x: Vec<f64> = (0..60).map(|k| [1.0, 2.0, 5.0][k % 3] + 0.5f64.powi(k as i32)).collect();
//! match detect_period_scalar(&x, &PeriodSettings::default()) {
//!     PeriodOutcome::Periodic(orbit) => assert_eq!(orbit.period, 3),
//!     other => panic!("{other:?}"),
//! }
//! ```

use crate::arc::HybridArc;

/// Tolerances and search bounds of [`detect_period`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PeriodSettings {
    /// Largest period searched. Default 500.
    pub max_period: usize,
    /// Number of full periods at the end of the sequence that must repeat
    /// the period before them. Default 4; at least 1.
    pub repeats: usize,
    /// Absolute tolerance of the comparison `|x(k) − x(k − N)|`, in the unit
    /// of the sequence. Default 1e-9.
    pub abs_tol: f64,
    /// Relative tolerance, scaled by `max(|x(k)|, |x(k − N)|)`. Default 1e-9.
    pub rel_tol: f64,
}

impl Default for PeriodSettings {
    fn default() -> Self {
        Self {
            max_period: 500,
            repeats: 4,
            abs_tol: 1e-9,
            rel_tol: 1e-9,
        }
    }
}

impl PeriodSettings {
    /// Sets [`max_period`](Self::max_period).
    pub fn max_period(mut self, value: usize) -> Self {
        self.max_period = value;
        self
    }
    /// Sets [`repeats`](Self::repeats).
    pub fn repeats(mut self, value: usize) -> Self {
        self.repeats = value;
        self
    }
    /// Sets [`abs_tol`](Self::abs_tol).
    pub fn abs_tol(mut self, value: f64) -> Self {
        self.abs_tol = value;
        self
    }
    /// Sets [`rel_tol`](Self::rel_tol).
    pub fn rel_tol(mut self, value: f64) -> Self {
        self.rel_tol = value;
        self
    }

    fn tol(&self, x: f64, y: f64) -> f64 {
        self.abs_tol + self.rel_tol * x.abs().max(y.abs())
    }
}

/// A periodic end of a sequence found by [`detect_period`].
#[derive(Debug, Clone, PartialEq)]
pub struct PeriodicOrbit {
    /// The smallest period N that passes the test.
    pub period: usize,
    /// Index of the first sample of the last full cycle (`len − N`).
    pub cycle_start: usize,
    /// The last full cycle, per channel, in time order: `points[c][i]` is
    /// channel `c` at index `cycle_start + i`.
    pub points: Vec<Vec<f64>>,
    /// Smallest index `k0` such that every `k ≥ k0 + N` passes the test:
    /// from `k0` on the sequence is N-periodic within tolerance.
    pub settled_at: usize,
    /// Largest `|x(k) − x(k − N)|` over the checked window and channels.
    pub max_mismatch: f64,
}

impl PeriodicOrbit {
    /// The periodic points of channel `c` sorted increasingly (a phase-free
    /// description of the cycle), or `None` if there is no such channel.
    pub fn sorted_points(&self, c: usize) -> Option<Vec<f64>> {
        let mut v = self.points.get(c)?.clone();
        v.sort_by(f64::total_cmp);
        Some(v)
    }
}

/// What [`detect_period`] found.
#[derive(Debug, Clone, PartialEq)]
pub enum PeriodOutcome {
    /// The sequence ends N-periodic within tolerance.
    Periodic(PeriodicOrbit),
    /// No period up to `checked_up_to` passes the test. `checked_up_to` is
    /// `max_period`, or less when the sequence is too short for longer
    /// periods (`len ≥ (repeats + 1) · N` is needed).
    NotPeriodic {
        /// Largest period tested.
        checked_up_to: usize,
    },
    /// The sequence is too short to test even period 1.
    TooShort {
        /// Its length.
        len: usize,
        /// The length needed for period 1 (`repeats + 1`).
        needed: usize,
    },
    /// A channel holds a NaN or infinite value at `index`; nothing was tested.
    NonFinite {
        /// Channel.
        channel: usize,
        /// Index of the first non-finite value.
        index: usize,
    },
    /// The channels have different lengths (or there is none).
    BadChannels,
}

impl PeriodOutcome {
    /// The period, if one was found.
    pub fn period(&self) -> Option<usize> {
        match self {
            Self::Periodic(o) => Some(o.period),
            _ => None,
        }
    }
}

/// Detects the asymptotic period of a single sequence; see the module docs.
pub fn detect_period_scalar(x: &[f64], settings: &PeriodSettings) -> PeriodOutcome {
    detect_period(&[x], settings)
}

/// Detects the smallest period shared by all `channels` (equal lengths) at
/// the end of the sequence; see the module docs for the test.
pub fn detect_period(channels: &[&[f64]], settings: &PeriodSettings) -> PeriodOutcome {
    let Some(len) = channels.first().map(|c| c.len()) else {
        return PeriodOutcome::BadChannels;
    };
    if channels.iter().any(|c| c.len() != len) {
        return PeriodOutcome::BadChannels;
    }
    for (ci, c) in channels.iter().enumerate() {
        if let Some(index) = c.iter().position(|v| !v.is_finite()) {
            return PeriodOutcome::NonFinite { channel: ci, index };
        }
    }
    let repeats = settings.repeats.max(1);
    if len < repeats + 1 {
        return PeriodOutcome::TooShort {
            len,
            needed: repeats + 1,
        };
    }
    let longest = settings.max_period.min(len / (repeats + 1));
    let mismatch_ok = |n: usize, k: usize| {
        channels
            .iter()
            .all(|c| (c[k] - c[k - n]).abs() <= settings.tol(c[k], c[k - n]))
    };
    for n in 1..=longest {
        let window = len - repeats * n..len;
        if !window.clone().all(|k| mismatch_ok(n, k)) {
            continue;
        }
        let max_mismatch = window
            .flat_map(|k| channels.iter().map(move |c| (c[k] - c[k - n]).abs()))
            .fold(0.0, f64::max);
        // Walk back from the checked window while the test still holds.
        let mut first_ok = len - repeats * n;
        while first_ok > n && mismatch_ok(n, first_ok - 1) {
            first_ok -= 1;
        }
        return PeriodOutcome::Periodic(PeriodicOrbit {
            period: n,
            cycle_start: len - n,
            points: channels.iter().map(|c| c[len - n..].to_vec()).collect(),
            settled_at: first_ok - n,
            max_mismatch,
        });
    }
    PeriodOutcome::NotPeriodic {
        checked_up_to: longest,
    }
}

/// The discrete-time sequence of state component `component` in a hybrid
/// arc whose steps are jumps: its value at the first sample of each jump
/// index j = 0, 1, …, J (the initial point, then each post-jump point).
/// Returns `None` if the component does not exist. For a model that jumps
/// once per sampling instant this is `x(k)`, k = j.
pub fn per_jump_values(arc: &HybridArc, component: usize) -> Option<Vec<f64>> {
    if component >= arc.dim() {
        return None;
    }
    let mut out = Vec::new();
    let mut last_j = None;
    for s in arc.samples() {
        if last_j != Some(s.at.j) {
            last_j = Some(s.at.j);
            out.push(s.x[component]);
        }
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn periodic(pattern: &[f64], len: usize, decay: f64) -> Vec<f64> {
        (0..len)
            .map(|k| pattern[k % pattern.len()] + decay.powi(k as i32))
            .collect()
    }

    #[test]
    fn finds_smallest_period_and_points() {
        let x = periodic(&[1.0, 4.0, 2.0, 4.0, 1.0, 3.0], 200, 0.5);
        let out = detect_period_scalar(&x, &PeriodSettings::default());
        let PeriodOutcome::Periodic(o) = out else {
            panic!("{out:?}")
        };
        assert_eq!(o.period, 6);
        assert_eq!(o.cycle_start, 194);
        assert_eq!(o.points[0], x[194..].to_vec());
        // 0.5^k ≤ 1e-9·(1 + 4) + 1e-9 from k ≈ 30 on.
        assert!((25..=40).contains(&o.settled_at), "{}", o.settled_at);
        assert!(o.max_mismatch <= 1e-12);
        assert_eq!(
            o.sorted_points(0).unwrap().first().copied(),
            Some(x[194..].iter().copied().fold(f64::INFINITY, f64::min))
        );
    }

    #[test]
    fn constant_sequence_has_period_one() {
        let x = vec![2.5; 10];
        assert_eq!(
            detect_period_scalar(&x, &PeriodSettings::default()).period(),
            Some(1)
        );
    }

    #[test]
    fn channels_share_a_period() {
        // Channel 0 has period 2, channel 1 period 3: together 6.
        let a: Vec<f64> = (0..100).map(|k| (k % 2) as f64).collect();
        let b: Vec<f64> = (0..100).map(|k| (k % 3) as f64).collect();
        let out = detect_period(&[&a, &b], &PeriodSettings::default());
        assert_eq!(out.period(), Some(6));
    }

    #[test]
    fn aperiodic_and_short_and_bad_inputs() {
        let x: Vec<f64> = (0..300).map(|k| (k as f64).sqrt()).collect();
        assert_eq!(
            detect_period_scalar(&x, &PeriodSettings::default().max_period(20)),
            PeriodOutcome::NotPeriodic { checked_up_to: 20 }
        );
        assert_eq!(
            detect_period_scalar(&x[..50], &PeriodSettings::default()),
            PeriodOutcome::NotPeriodic { checked_up_to: 10 }
        );
        assert_eq!(
            detect_period_scalar(&[1.0, 1.0], &PeriodSettings::default()),
            PeriodOutcome::TooShort { len: 2, needed: 5 }
        );
        assert_eq!(
            detect_period_scalar(&[1.0, f64::NAN, 1.0], &PeriodSettings::default()),
            PeriodOutcome::NonFinite {
                channel: 0,
                index: 1
            }
        );
        assert_eq!(
            detect_period(&[&[1.0], &[1.0, 2.0]], &PeriodSettings::default()),
            PeriodOutcome::BadChannels
        );
        assert_eq!(
            detect_period(&[], &PeriodSettings::default()),
            PeriodOutcome::BadChannels
        );
    }

    #[test]
    fn tolerance_decides_slow_convergence() {
        // Converges like 0.9^k: with 1e-9 tolerances 150 samples are not
        // enough (0.9^140 ≈ 4e-7), with an absolute tolerance of 1e-3 they are.
        let x = periodic(&[0.0, 1.0], 150, 0.9);
        assert_eq!(
            detect_period_scalar(&x, &PeriodSettings::default()).period(),
            None
        );
        let loose = PeriodSettings::default().abs_tol(1e-3);
        assert_eq!(detect_period_scalar(&x, &loose).period(), Some(2));
    }

    #[test]
    fn per_jump_values_take_first_sample_of_each_j() {
        use crate::arc::{ArcSink, HybridTime, SampleKind};
        let mut arc = HybridArc::new(1, vec!["step".into()]);
        let _ = arc.sample(HybridTime::new(0.0, 0), &[1.0], SampleKind::Initial);
        let _ = arc.sample(HybridTime::new(0.5, 0), &[1.0], SampleKind::Flow);
        let _ = arc.sample(HybridTime::new(1.0, 0), &[1.0], SampleKind::PreJump);
        let _ = arc.jump(HybridTime::new(1.0, 0), 0, &[1.0], &[2.0]);
        let _ = arc.sample(HybridTime::new(1.0, 1), &[2.0], SampleKind::PostJump);
        let _ = arc.sample(HybridTime::new(1.0, 1), &[2.0], SampleKind::Final);
        assert_eq!(per_jump_values(&arc, 0), Some(vec![1.0, 2.0]));
        assert_eq!(per_jump_values(&arc, 1), None);
    }
}
