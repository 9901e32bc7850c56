//! Ordinary time along a run.

/// Ordinary time as a compensated (Neumaier) sum of segment lengths, so that
/// thousands of short segments do not accumulate rounding.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct TimeSum {
    sum: f64,
    comp: f64,
}

impl TimeSum {
    pub fn add(&mut self, x: f64) {
        let t = self.sum + x;
        if self.sum.abs() >= x.abs() {
            self.comp += (self.sum - t) + x;
        } else {
            self.comp += (x - t) + self.sum;
        }
        self.sum = t;
    }

    pub fn value(&self) -> f64 {
        self.sum + self.comp
    }

    /// The time `s` after this one, as [`add`](Self::add) then
    /// [`value`](Self::value) will give it: what the engine evaluates the
    /// sets at along a segment, so that an event found at local time `s`
    /// is recorded at exactly the time its sets were evaluated at.
    pub fn at(mut self, s: f64) -> f64 {
        self.add(s);
        self.value()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compensated_time_sum_does_not_drift() {
        let mut t = TimeSum::default();
        let mut naive = 0.0;
        for _ in 0..1_000_000 {
            t.add(0.1);
            naive += 0.1;
        }
        assert!((t.value() - 100_000.0).abs() < 1e-9);
        // The naive sum is off by ~1e-6: the compensated one is 1000x better.
        assert!((naive - 100_000.0_f64).abs() > 1e-7);
    }

    #[test]
    fn at_is_the_time_add_then_value_give() {
        let mut t = TimeSum::default();
        for k in 0..1000 {
            t.add(1e-4 * (1.0 + f64::from(k % 7)));
        }
        for s in [0.0, 1e-17, 3.3e-5, 0.1, 7.0] {
            let mut after = t;
            after.add(s);
            assert_eq!(t.at(s).to_bits(), after.value().to_bits());
        }
    }
}
