//! Propagators of a switched affine flow ([`FlowStructure::SwitchedAffine`]):
//! `ẋ = A(q) x + b(q)` with `q` components that do not move along flows, so
//! each flow is affine with constant coefficients, those of its mode. One
//! [`Affine`] per mode met (keyed by the bits of the mode components), the
//! current one held by the flow's [`Method`](super::flow::Method); a mode met
//! again finds its propagators (and the auto choice's bookkeeping) as it
//! left them.
//!
//! [`FlowStructure::SwitchedAffine`]: super::FlowStructure::SwitchedAffine

use super::HybridSystem;
use super::error::SimError;
use super::flow::Affine;
use crate::arc::HybridTime;

/// Modes whose propagators are kept besides the current one (the oldest is
/// dropped first): a mode that takes continuous values (a held sample in a
/// nonlinear coefficient) would otherwise grow without bound.
const KEPT_MODES: usize = 32;

/// The switched flow's modes met so far.
pub(crate) struct ModeAffines {
    /// The mode components of the state.
    modes: Vec<usize>,
    /// The bits of the mode components of the current mode.
    key: Vec<u64>,
    /// Other modes met, with their propagators, oldest first.
    others: Vec<(Vec<u64>, Box<Affine>)>,
    /// Buffers for `A` (n×n) and `b`, filled by the system for a new mode.
    a: Vec<f64>,
    b: Vec<f64>,
    /// Modes whose coefficients were computed (new ones and ones dropped and met again).
    made: usize,
}

impl ModeAffines {
    /// Modes the auto choice computes coefficients for before it leaves
    /// the flow to the solver.
    pub const AUTO_MODES: usize = 2 * KEPT_MODES;

    /// The propagators of the mode of `x` (the current one, at `at`) and
    /// the bookkeeping of `modes`.
    pub fn new<S: HybridSystem + ?Sized>(
        sys: &S,
        modes: Vec<usize>,
        at: HybridTime,
        x: &[f64],
    ) -> Result<(Self, Box<Affine>), SimError> {
        let n = sys.state_dim();
        let mut m = Self {
            key: modes.iter().map(|&k| x[k].to_bits()).collect(),
            modes,
            others: Vec::new(),
            a: Vec::new(),
            b: Vec::new(),
            made: 0,
        };
        m.a.resize(n * n, 0.0);
        m.b.resize(n, 0.0);
        let aff = m.affine_at(sys, at, x)?;
        Ok((m, aff))
    }

    /// How many modes' coefficients have been computed.
    pub fn made(&self) -> usize {
        self.made
    }

    /// Makes `current` the propagators of the mode of `x` (at `at`;
    /// unchanged if it is the current mode: a comparison of the mode
    /// components).
    pub fn select<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        at: HybridTime,
        x: &[f64],
        current: &mut Box<Affine>,
    ) -> Result<(), SimError> {
        let is_mode = |key: &[u64]| {
            key.iter()
                .zip(&self.modes)
                .all(|(&b, &k)| x[k].to_bits() == b)
        };
        if is_mode(&self.key) {
            return Ok(());
        }
        match self.others.iter().position(|(key, _)| is_mode(key)) {
            Some(p) => {
                let (key, aff) = &mut self.others[p];
                std::mem::swap(key, &mut self.key);
                std::mem::swap(aff, current);
                // The mode left is now the most recent of the others.
                let left = self.others.remove(p);
                self.others.push(left);
            }
            None => {
                let aff = self.affine_at(sys, at, x)?;
                let mut key = if self.others.len() >= KEPT_MODES {
                    self.others.remove(0).0
                } else {
                    Vec::with_capacity(self.modes.len())
                };
                key.clear();
                key.extend(self.modes.iter().map(|&k| x[k].to_bits()));
                std::mem::swap(&mut key, &mut self.key);
                let left = std::mem::replace(current, aff);
                self.others.push((key, left));
            }
        }
        Ok(())
    }

    /// The propagators of the mode of `x`, from the system's coefficients.
    /// A non-finite coefficient (`x' = -x/q` at `q = 0`) is the state's
    /// rate becoming non-finite at `at`, reported as the solver's path
    /// reports it.
    fn affine_at<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        at: HybridTime,
        x: &[f64],
    ) -> Result<Box<Affine>, SimError> {
        self.made += 1;
        self.a.fill(0.0);
        self.b.fill(0.0);
        sys.affine_coefficients(at, x, &mut self.a, &mut self.b);
        // A failed evaluation (a table index out of range) is the flow's.
        if let Some(f) = sys.take_fault() {
            return Err(f.into());
        }
        let n = x.len();
        let bad_row = (0..n).find(|&r| {
            !self.b[r].is_finite() || self.a[r * n..(r + 1) * n].iter().any(|v| !v.is_finite())
        });
        if let Some(row) = bad_row {
            sys.flow_map(at, x, &mut self.b);
            let rate = self.b[row];
            return Err(SimError::NonFinite {
                at,
                component: row,
                name: sys.state_names().get(row).cloned().unwrap_or_default(),
                value: if rate.is_finite() { f64::NAN } else { rate },
                rule: None,
            });
        }
        Ok(Box::new(Affine::new(n, &self.a, &self.b)?))
    }
}
