//! `proptest` integration: cases of a [`Subject`] as a proptest
//! strategy, and a check that turns a violation into a test failure, so
//! that a `cargo test` can state properties of a `.hyb` model or a Rust
//! system next to its other tests.
//!
//! ```
//! use hybsim::engine::{models::BouncingBall, SimSettings};
//! use hybsim::props::{Dist, Property, SystemSubject, strategy};
//! use proptest::prelude::*;
//!
//! let ball = SystemSubject::new(
//!     BouncingBall::new(9.81, 0.8),
//!     SimSettings::default().horizon_t(3.0),
//!     vec![Dist::Uniform { lo: 0.0, hi: 2.0 }, Dist::Fixed(0.0)],
//! ).unwrap();
//! let props = [Property::always("above ground", |_, x| x[0] >= -1e-9)];
//! proptest!(ProptestConfig::with_cases(16), |(case in strategy::cases(&ball))| {
//!     strategy::check(&ball, &props, &case)?;
//! });
//! ```

use proptest::prelude::*;
use proptest::test_runner::TestCaseError;

use super::monitor::Verdict;
use super::property::Property;
use super::runner::{Case, Dist, Subject, run_case};

/// A strategy for one input. Uniform inputs are proptest float ranges
/// (which shrink toward zero, clamped to the range); normal inputs are
/// `mean + std·z` with `z` uniform on `[−4, 4]` (shrinking toward the mean):
/// proptest explores the ±4σ band evenly rather than drawing from the
/// normal law, which suits a search for counterexamples. For cases drawn
/// from the distributions themselves use [`run_tests`](super::run_tests).
pub fn value(dist: Dist) -> BoxedStrategy<f64> {
    match dist {
        Dist::Fixed(v) => Just(v).boxed(),
        // A range wider than the largest float (`uniform(-1e308, 1e308)`): proptest's range
        // over it drew ±inf; its halves on either side of 0 each have a finite width, and are
        // chosen in proportion to it.
        Dist::Uniform { lo, hi } if lo < hi && !(hi - lo).is_finite() => {
            let below = (0.5 * -lo / (0.5 * hi - 0.5 * lo) * 1000.0).round() as u32;
            let below = below.clamp(1, 999);
            prop_oneof![1000 - below => 0.0..=hi, below => lo..=0.0].boxed()
        }
        Dist::Uniform { lo, hi } if lo < hi => (lo..=hi).boxed(),
        Dist::Uniform { lo, .. } => Just(lo).boxed(),
        Dist::Normal { mean, std } if std > 0.0 => {
            (-4.0..=4.0f64).prop_map(move |z| mean + std * z).boxed()
        }
        Dist::Normal { mean, .. } => Just(mean).boxed(),
    }
}

/// Cases of `subject`: any seed, and each input from [`value`].
pub fn cases<S: Subject + ?Sized>(subject: &S) -> impl Strategy<Value = Case> + use<S> {
    let values: Vec<BoxedStrategy<f64>> = subject.inputs().iter().map(|i| value(i.dist)).collect();
    (any::<u64>(), values).prop_map(|(seed, values)| Case {
        seed,
        values,
        horizon_t: None,
        horizon_j: None,
    })
}

/// Runs `case` and checks `props`.
///
/// # Errors
/// A [`TestCaseError::Fail`] naming the violated property, its hybrid time
/// and the case, or the subject's error if the case could not run.
pub fn check<S: Subject + ?Sized>(
    subject: &S,
    props: &[Property],
    case: &Case,
) -> Result<(), TestCaseError> {
    match run_case(subject, props, case) {
        Ok(Verdict::Holds { .. }) => Ok(()),
        Ok(Verdict::Fails(v)) => Err(TestCaseError::fail(format!(
            "{v}; state {:?}; case {case:?}",
            v.state
        ))),
        Err(e) => Err(TestCaseError::fail(format!(
            "case {case:?} could not run: {e}"
        ))),
    }
}
