//! The property-test runner: sample cases, run them in parallel, stop at
//! the first failure, shrink it to a minimal counterexample.

use std::sync::Mutex;

use rayon::prelude::*;

use super::monitor::{PropertySink, Verdict, Violation};
use super::property::Property;
use crate::arc::{ArcSink, Termination};
use crate::engine::{HybridSystem, SimError, SimRng, SimSettings, simulate};
use crate::num::Num;

/// A distribution of one sampled input (an initial value or a parameter).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Dist {
    /// Always this value.
    Fixed(f64),
    /// Uniform on `[lo, hi]`.
    Uniform {
        /// Lower end.
        lo: f64,
        /// Upper end (≥ `lo`).
        hi: f64,
    },
    /// Normal with mean `mean` and standard deviation `std` (≥ 0).
    Normal {
        /// Mean.
        mean: f64,
        /// Standard deviation.
        std: f64,
    },
}

impl Dist {
    /// One draw from `rng`.
    pub fn sample(&self, rng: &mut SimRng) -> f64 {
        match *self {
            Dist::Fixed(v) => v,
            Dist::Uniform { lo, hi } => rng.uniform(lo, hi),
            Dist::Normal { mean, std } => rng.normal(mean, std),
        }
    }

    /// The simplest value, toward which shrinking moves a failing input:
    /// zero if the range contains it, else the range's centre (the mean for
    /// a normal distribution, the value itself if fixed).
    pub fn shrink_target(&self) -> f64 {
        match *self {
            Dist::Fixed(v) => v,
            Dist::Uniform { lo, hi } if lo <= 0.0 && 0.0 <= hi => 0.0,
            _ => self.centre(),
        }
    }

    /// The centre of the distribution: the midpoint of a uniform range,
    /// the mean of a normal distribution, the value itself if fixed.
    pub fn centre(&self) -> f64 {
        match *self {
            Dist::Fixed(v) => v,
            Dist::Uniform { lo, hi } => lo + 0.5 * (hi - lo),
            Dist::Normal { mean, .. } => mean,
        }
    }

    /// `Err` with a reason if the parameters are not finite or ordered.
    pub fn validate(&self) -> Result<(), String> {
        match *self {
            Dist::Fixed(v) if v.is_finite() => Ok(()),
            Dist::Uniform { lo, hi } if lo.is_finite() && hi.is_finite() && lo <= hi => Ok(()),
            Dist::Normal { mean, std } if mean.is_finite() && std.is_finite() && std >= 0.0 => {
                Ok(())
            }
            Dist::Fixed(v) => Err(format!("the value {v} is not finite")),
            Dist::Uniform { lo, hi } => Err(format!(
                "uniform({lo}, {hi}) needs finite bounds with lo ≤ hi"
            )),
            Dist::Normal { mean, std } => Err(format!(
                "normal({mean}, {std}) needs a finite mean and a finite std ≥ 0"
            )),
        }
    }
}

impl std::fmt::Display for Dist {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Dist::Fixed(v) => write!(f, "{}", Num(*v)),
            Dist::Uniform { lo, hi } => write!(f, "uniform({}, {})", Num(*lo), Num(*hi)),
            Dist::Normal { mean, std } => write!(f, "normal({}, {})", Num(*mean), Num(*std)),
        }
    }
}

/// A named sampled input of a [`Subject`].
#[derive(Debug, Clone, PartialEq)]
pub struct Input {
    /// Name (a state or a parameter of the model).
    pub name: String,
    /// Its distribution.
    pub dist: Dist,
}

impl Input {
    /// The input `name ~ dist`.
    pub fn new(name: impl Into<String>, dist: Dist) -> Self {
        Self {
            name: name.into(),
            dist,
        }
    }
}

/// One test case: the run's seed, one value per input, and optionally
/// shorter horizons than the subject's settings (set by shrinking).
#[derive(Debug, Clone, PartialEq)]
pub struct Case {
    /// Seed of the run's [`SimRng`] (set-valued jump maps, noise).
    pub seed: u64,
    /// One value per [`Subject::inputs`] entry, in order.
    pub values: Vec<f64>,
    /// Overrides `SimSettings::horizon_t` if set.
    pub horizon_t: Option<f64>,
    /// Overrides `SimSettings::horizon_j` if set.
    pub horizon_j: Option<u64>,
}

impl Case {
    /// `settings` with this case's horizons.
    pub fn apply(&self, settings: &SimSettings) -> SimSettings {
        let mut s = settings.clone();
        if let Some(t) = self.horizon_t {
            s.horizon_t = t;
        }
        if let Some(j) = self.horizon_j {
            s.horizon_j = j;
        }
        s
    }
}

/// What property tests run on: a model with sampled inputs. Implemented
/// for Rust systems by [`SystemSubject`] and for `.hyb` models by the
/// language; implement it for a parameterized Rust system of your own.
pub trait Subject: Sync {
    /// Why a case could not run.
    type Error: std::error::Error + Send + Sync + 'static;

    /// The sampled inputs, in order.
    fn inputs(&self) -> &[Input];

    /// The names of the state components, in order.
    fn state_names(&self) -> Vec<String>;

    /// The names a counterexample's report shows, in component order: an
    /// empty name leaves its component out (a `.hyb` model's timers of
    /// `every` rules and held noise, which no log shows either). Default:
    /// [`state_names`](Self::state_names).
    fn report_names(&self) -> Vec<String> {
        self.state_names()
    }

    /// The simulation settings (before a case's horizon overrides).
    fn settings(&self) -> &SimSettings;

    /// Runs one case into `sink`: the same case must give the same
    /// solution every time.
    ///
    /// # Errors
    /// If the case cannot be simulated.
    fn run(&self, case: &Case, sink: &mut dyn ArcSink) -> Result<Termination, Self::Error>;

    /// Runs one case and checks `props` on it, stopping at the first
    /// violation. The default feeds [`run`](Self::run) into a
    /// [`PropertySink`]; a subject whose properties depend on the case (a
    /// `.hyb` model with random parameters folded into its properties)
    /// overrides it.
    ///
    /// # Errors
    /// If the case cannot be simulated.
    fn run_checked(&self, case: &Case, props: &[Property]) -> Result<Verdict, Self::Error> {
        let mut sink = PropertySink::new(props);
        self.run(case, &mut sink)?;
        Ok(sink.verdict())
    }
}

/// A Rust [`HybridSystem`] whose initial state is sampled component by
/// component.
#[derive(Debug, Clone)]
pub struct SystemSubject<S> {
    system: S,
    settings: SimSettings,
    inputs: Vec<Input>,
}

impl<S: HybridSystem + Sync> SystemSubject<S> {
    /// `system` simulated with `settings` from initial states drawn
    /// componentwise from `initial` (one [`Dist`] per state component).
    ///
    /// # Errors
    /// [`SimError::StateDimension`] if `initial` has the wrong length,
    /// [`SimError::InvalidSettings`] if a distribution or the settings are
    /// invalid.
    pub fn new(system: S, settings: SimSettings, initial: Vec<Dist>) -> Result<Self, SimError> {
        if initial.len() != system.state_dim() {
            return Err(SimError::StateDimension {
                expected: system.state_dim(),
                found: initial.len(),
            });
        }
        settings.validate()?;
        for d in &initial {
            d.validate().map_err(|reason| SimError::InvalidSettings {
                field: "initial",
                reason,
            })?;
        }
        let inputs = system
            .state_names()
            .into_iter()
            .zip(initial)
            .map(|(name, dist)| Input { name, dist })
            .collect();
        Ok(Self {
            system,
            settings,
            inputs,
        })
    }

    /// The system.
    pub fn system(&self) -> &S {
        &self.system
    }
}

impl<S: HybridSystem + Sync> Subject for SystemSubject<S> {
    type Error = SimError;

    fn inputs(&self) -> &[Input] {
        &self.inputs
    }

    fn state_names(&self) -> Vec<String> {
        self.system.state_names()
    }

    fn settings(&self) -> &SimSettings {
        &self.settings
    }

    fn run(&self, case: &Case, sink: &mut dyn ArcSink) -> Result<Termination, SimError> {
        let settings = case.apply(&self.settings);
        let mut rng = SimRng::seed_from(case.seed);
        simulate(&self.system, &case.values, &settings, &mut rng, sink)
    }
}

/// SplitMix64: a bijective mix of 64 bits, to derive independent seeds.
fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The generator of the initial draws of a run with seed `seed`, separate
/// from the run's own stream `SimRng::seed_from(seed)`: pinning an initial
/// value (`--set h=1.5`) then leaves every later draw of the run unchanged.
/// [`sample_case`] draws a case's inputs from it, and so does
/// [`CompiledModel::start`](crate::lang::CompiledModel::start) for the
/// random initial values of a `.hyb` model.
pub fn input_stream(seed: u64) -> SimRng {
    SimRng::seed_from(splitmix64(seed))
}

/// Case number `index` of a test with master seed `master`: its run seed
/// is `splitmix64(master + index)`, its input values are drawn from a
/// generator seeded with `splitmix64(seed)` (a stream separate from the
/// run's). Every case is thus reproducible on its own, whatever the order
/// in which cases run.
pub fn sample_case(inputs: &[Input], master: u64, index: u64) -> Case {
    let seed = splitmix64(master.wrapping_add(index));
    let mut rng = input_stream(seed);
    Case {
        seed,
        values: inputs.iter().map(|i| i.dist.sample(&mut rng)).collect(),
        horizon_t: None,
        horizon_j: None,
    }
}

/// Runs one case and checks `props` on it, stopping at the first violation.
///
/// # Errors
/// The subject's error if the case cannot be simulated.
pub fn run_case<S: Subject + ?Sized>(
    subject: &S,
    props: &[Property],
    case: &Case,
) -> Result<Verdict, S::Error> {
    subject.run_checked(case, props)
}

/// How many cases to run, from which master seed, and how hard to shrink.
#[derive(Debug, Clone, PartialEq)]
pub struct TestConfig {
    /// Number of cases. Default 100.
    pub cases: usize,
    /// Master seed from which every case's seed is derived. Default 0.
    pub seed: u64,
    /// Largest number of runs spent shrinking a counterexample (0: no
    /// shrinking). Default 400.
    pub max_shrink_runs: usize,
}

impl Default for TestConfig {
    fn default() -> Self {
        Self {
            cases: 100,
            seed: 0,
            max_shrink_runs: 400,
        }
    }
}

impl TestConfig {
    /// Sets the number of cases.
    pub fn cases(mut self, cases: usize) -> Self {
        self.cases = cases;
        self
    }

    /// Sets the master seed.
    pub fn seed(mut self, seed: u64) -> Self {
        self.seed = seed;
        self
    }

    /// Sets the shrinking budget (runs).
    pub fn max_shrink_runs(mut self, runs: usize) -> Self {
        self.max_shrink_runs = runs;
        self
    }
}

/// A failing case, as found and after shrinking.
#[derive(Debug, Clone, PartialEq)]
pub struct Counterexample {
    /// Index of the failing case among those sampled.
    pub index: usize,
    /// The case as sampled.
    pub original: Case,
    /// Its violation.
    pub original_violation: Violation,
    /// The shrunk case (equal to `original` if nothing simpler failed).
    pub case: Case,
    /// The violation of the shrunk case (same property).
    pub violation: Violation,
    /// Runs spent shrinking.
    pub shrink_runs: usize,
}

/// How a property test ended.
#[derive(Debug)]
pub enum Outcome<E> {
    /// Every case passed.
    Passed,
    /// A property failed: the first failing case (lowest index), shrunk.
    Failed(Box<Counterexample>),
    /// A case could not be simulated.
    Error {
        /// Index of the case.
        index: usize,
        /// The case.
        case: Case,
        /// Why it could not run.
        error: E,
    },
}

/// The result of [`run_tests`].
#[derive(Debug)]
pub struct TestReport<E> {
    /// Cases up to the first failing one in case order (all of them when
    /// every case passed); cases after it that ran in parallel are not
    /// counted, so the count does not depend on the thread count.
    pub cases_run: usize,
    /// Cases among those on which some property was inconclusive.
    pub inconclusive: usize,
    /// The outcome.
    pub outcome: Outcome<E>,
}

impl<E> TestReport<E> {
    /// `true` if every case passed.
    pub fn passed(&self) -> bool {
        matches!(self.outcome, Outcome::Passed)
    }
}

enum CaseResult<E> {
    Failed(Case, Violation),
    Error(Case, E),
}

/// Runs `config.cases` sampled cases of `subject` in parallel (rayon),
/// checking `props` on each; the first failing case in case order (not
/// completion order, so the result does not depend on scheduling) is
/// shrunk with [`shrink`].
pub fn run_tests<S: Subject + ?Sized>(
    subject: &S,
    props: &[Property],
    config: &TestConfig,
) -> TestReport<S::Error> {
    // Indices of the inconclusive cases: the counts reported are those of the cases up to the
    // first failure in case order, which all ran whatever the thread count (later cases may
    // have run too, depending on scheduling, and are not counted).
    let inconclusive = Mutex::new(Vec::new());
    let first = (0..config.cases)
        .into_par_iter()
        .map(|index| {
            let case = sample_case(subject.inputs(), config.seed, index as u64);
            match run_case(subject, props, &case) {
                Ok(Verdict::Fails(v)) => Some((index, CaseResult::Failed(case, v))),
                Ok(Verdict::Holds { inconclusive: inc }) => {
                    if !inc.is_empty() {
                        inconclusive
                            .lock()
                            .unwrap_or_else(|e| e.into_inner())
                            .push(index);
                    }
                    None
                }
                Err(e) => Some((index, CaseResult::Error(case, e))),
            }
        })
        .find_map_first(|r| r);
    let counted = first.as_ref().map_or(config.cases, |(index, _)| index + 1);
    let inconclusive = inconclusive
        .into_inner()
        .unwrap_or_else(|e| e.into_inner())
        .into_iter()
        .filter(|&i| i < counted)
        .count();
    let outcome = match first {
        None => Outcome::Passed,
        Some((index, CaseResult::Error(case, error))) => Outcome::Error { index, case, error },
        Some((index, CaseResult::Failed(case, violation))) => {
            let (shrunk, shrunk_violation, runs) =
                shrink(subject, props, &case, &violation, config.max_shrink_runs);
            Outcome::Failed(Box::new(Counterexample {
                index,
                original: case,
                original_violation: violation,
                case: shrunk,
                violation: shrunk_violation,
                shrink_runs: runs,
            }))
        }
    };
    TestReport {
        cases_run: counted,
        inconclusive,
        outcome,
    }
}

/// [`run_tests`] until every property has passed or failed. A case stops at
/// its first violation, so after each counterexample the properties not yet
/// failed are tested again without the one that failed. The reports in
/// order: one per failed property (its counterexample), then the last one
/// (the remaining properties passed, or an error stopped the search).
pub fn run_tests_each<S: Subject + ?Sized>(
    subject: &S,
    props: &[Property],
    config: &TestConfig,
) -> Vec<TestReport<S::Error>> {
    let mut remaining = props.to_vec();
    let mut reports = Vec::new();
    loop {
        let report = run_tests(subject, &remaining, config);
        let failed = match &report.outcome {
            Outcome::Failed(cx) => Some(cx.violation.property.clone()),
            Outcome::Passed | Outcome::Error { .. } => None,
        };
        reports.push(report);
        match failed {
            Some(name) => {
                remaining.retain(|p| p.name() != name);
                if remaining.is_empty() {
                    return reports;
                }
            }
            None => return reports,
        }
    }
}

/// Runs candidate cases for the shrinker within a budget; a candidate is
/// accepted if the *same* property still fails on it.
struct Shrinker<'a, S: Subject + ?Sized> {
    subject: &'a S,
    props: &'a [Property],
    property: String,
    runs: usize,
    budget: usize,
}

impl<S: Subject + ?Sized> Shrinker<'_, S> {
    fn fails(&mut self, case: &Case) -> Option<Violation> {
        if self.runs >= self.budget {
            return None;
        }
        self.runs += 1;
        match run_case(self.subject, self.props, case) {
            Ok(Verdict::Fails(v)) if v.property == self.property => Some(v),
            _ => None,
        }
    }
}

/// Values with few significant digits in the half-open interval from
/// `pass` (excluded) to `fail` (included), other than `fail`, shortest
/// first: `fail` cut (toward zero) or rounded to 0, 1, 2, … digits after
/// the point of its scientific form.
pub(crate) fn short_decimals_between(pass: f64, fail: f64) -> Vec<f64> {
    let inside = |r: f64| {
        if pass < fail {
            pass < r && r < fail
        } else {
            fail < r && r < pass
        }
    };
    let full = format!("{:.16e}", fail.abs());
    let Some((mantissa, exponent)) = full.split_once('e') else {
        return Vec::new();
    };
    let sign = if fail < 0.0 { "-" } else { "" };
    let mut out: Vec<f64> = Vec::new();
    for digits in 0..17 {
        let cut = &mantissa[..if digits == 0 { 1 } else { 2 + digits }];
        let cut = format!("{sign}{cut}e{exponent}").parse::<f64>();
        let rounded = format!("{fail:.digits$e}").parse::<f64>();
        for r in [cut, rounded].into_iter().flatten() {
            if inside(r) && !out.contains(&r) {
                out.push(r);
            }
        }
    }
    out
}

/// Shrinks a failing case within `budget` runs: each input moves toward its
/// [`Dist::shrink_target`] (the target itself if it still fails, else the
/// failing value closest to it found by bisection, to a relative width of
/// 1e-12, then the shortest of a few short decimals in the last bracket that fails),
/// repeated while anything changes; then the horizons are cut to
/// the failure: `horizon_j` to the failing jump count (fewer jumps) and
/// `horizon_t` to the failing time. A candidate is kept only if the same
/// property still fails on it. Returns the shrunk case, its violation and
/// the runs spent.
pub fn shrink<S: Subject + ?Sized>(
    subject: &S,
    props: &[Property],
    case: &Case,
    violation: &Violation,
    budget: usize,
) -> (Case, Violation, usize) {
    let mut s = Shrinker {
        subject,
        props,
        property: violation.property.clone(),
        runs: 0,
        budget,
    };
    let mut best = case.clone();
    let mut best_v = violation.clone();
    let targets: Vec<f64> = subject
        .inputs()
        .iter()
        .map(|i| i.dist.shrink_target())
        .collect();
    for _pass in 0..3 {
        let mut changed = false;
        for (k, &target) in targets.iter().enumerate() {
            let current = best.values[k];
            if current == target {
                continue;
            }
            let mut candidate = best.clone();
            candidate.values[k] = target;
            if let Some(v) = s.fails(&candidate) {
                (best, best_v, changed) = (candidate, v, true);
                continue;
            }
            // Bisect between `target` (passes) and `current` (fails).
            let (mut pass, mut fail) = (target, current);
            loop {
                let mid = pass + 0.5 * (fail - pass);
                let width = (fail - pass).abs();
                if mid == pass || mid == fail || width <= 1e-12 * fail.abs().max(1.0) {
                    break;
                }
                candidate.values[k] = mid;
                match s.fails(&candidate) {
                    Some(v) => {
                        fail = mid;
                        (best, best_v, changed) = (candidate.clone(), v, true);
                    }
                    None if s.runs >= s.budget => break,
                    None => pass = mid,
                }
            }
            // The shortest decimal between the two, if it still fails: a
            // shorter `--set` value in the replay.
            for r in short_decimals_between(pass, fail).into_iter().take(4) {
                candidate.values[k] = r;
                if let Some(v) = s.fails(&candidate) {
                    (best, best_v, changed) = (candidate, v, true);
                    break;
                }
            }
        }
        if !changed || s.runs >= s.budget {
            break;
        }
    }
    // Fewer jumps, then a shorter horizon.
    let j_fail = best_v.at.j;
    for j in [j_fail, j_fail + 1] {
        if best.horizon_j.is_some_and(|h| h <= j) {
            break;
        }
        let candidate = Case {
            horizon_j: Some(j),
            ..best.clone()
        };
        if let Some(v) = s.fails(&candidate) {
            (best, best_v) = (candidate, v);
            break;
        }
    }
    let t_fail = best_v.at.t;
    if t_fail > 0.0 {
        let current = best.horizon_t.unwrap_or(subject.settings().horizon_t);
        for t in [t_fail, t_fail * (1.0 + 1e-9)] {
            if t >= current {
                break;
            }
            let candidate = Case {
                horizon_t: Some(t),
                ..best.clone()
            };
            if let Some(v) = s.fails(&candidate) {
                (best, best_v) = (candidate, v);
                break;
            }
        }
    }
    (best, best_v, s.runs)
}
