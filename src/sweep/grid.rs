//! Grid axes (`delta=0:5:80`, `Jmax=[0.2, 0.38, 1]`), shards (`k/n`) and
//! the seed of each run.

use std::str::FromStr;

use serde::{Deserialize, Serialize};

use super::SweepError;
use crate::num::Num;

/// Largest number of values on one axis (a typo such as `0:1e-9:1` is
/// reported instead of filling the memory).
pub const MAX_AXIS_VALUES: usize = 1_000_000;

/// One axis of a sweep grid: a parameter (or `sim` key, or initial value:
/// anything `--set` accepts) and its values.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Axis {
    /// The name set (`--set name=value`).
    pub name: String,
    /// The values in order.
    pub values: Vec<f64>,
}

impl FromStr for Axis {
    type Err = SweepError;

    /// Parses `name=a:step:b` (a, a + step, … up to b inclusive, within
    /// 1e-9·step), `name=[v1, v2, …]` or `name=v`.
    fn from_str(s: &str) -> Result<Self, SweepError> {
        let bad = |message: String| SweepError::Grid {
            text: s.to_string(),
            message,
        };
        let (name, spec) = s
            .split_once('=')
            .ok_or_else(|| bad("write `name=a:step:b`, `name=[v1, v2]` or `name=v`".into()))?;
        let name = name.trim();
        if name.is_empty()
            || !name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '.')
        {
            return Err(bad(format!("`{name}` is not a name")));
        }
        let spec = spec.trim();
        let number = |t: &str| -> Result<f64, SweepError> {
            let t = t.trim();
            match t.parse::<f64>() {
                Ok(x) if x.is_finite() => Ok(x),
                _ => Err(bad(format!("`{t}` is not a finite number"))),
            }
        };
        let values = if let Some(list) = spec.strip_prefix('[') {
            let list = list
                .strip_suffix(']')
                .ok_or_else(|| bad("a list ends with `]`".into()))?;
            list.split([',', ';'])
                .filter(|t| !t.trim().is_empty())
                .map(number)
                .collect::<Result<Vec<_>, _>>()?
        } else if spec.contains(':') {
            let parts: Vec<&str> = spec.split(':').collect();
            let [a, step, b] = parts.as_slice() else {
                return Err(bad("a range is `start:step:stop`".into()));
            };
            range_values(number(a)?, number(step)?, number(b)?).map_err(bad)?
        } else {
            vec![number(spec)?]
        };
        if values.is_empty() {
            return Err(bad("no values".into()));
        }
        Ok(Axis {
            name: name.to_string(),
            values,
        })
    }
}

/// The values `a, a + step, …` up to `b` inclusive (within 1e-9·step), as
/// `a + k·step` (no drift from repeated addition); the reason if the step
/// does not lead from `a` to `b` or gives more than [`MAX_AXIS_VALUES`].
/// The one expansion of `--grid name=a:step:b` and of `name in a:step:b`
/// in a model's `sweep` block.
pub fn range_values(a: f64, step: f64, b: f64) -> Result<Vec<f64>, String> {
    if !(a.is_finite() && step.is_finite() && b.is_finite()) {
        return Err("the start, step and stop must be finite".into());
    }
    if step == 0.0 || (b - a) * step < 0.0 {
        return Err(format!(
            "the step {} does not lead from {} to {}",
            Num(step),
            Num(a),
            Num(b)
        ));
    }
    let count = ((b - a) / step + 1e-9).floor() + 1.0;
    if count.is_nan() || count > MAX_AXIS_VALUES as f64 {
        // `0:1e-300:1` is about 1e300 values, not 300 digits of one.
        let count = if count < 1e15 {
            format!("{count}")
        } else {
            format!("about {count:.1e}")
        };
        return Err(format!(
            "{count} values (at most {MAX_AXIS_VALUES} per axis)"
        ));
    }
    Ok((0..count as usize).map(|k| a + k as f64 * step).collect())
}

/// A value that `values` holds twice, if any: a grid point given twice
/// would run twice, its rows duplicated (and its seeds repeated). Ranges
/// repeat a value where the step is below the spacing of the doubles
/// (`1e10:1e-7:1.000000000001e10`).
pub fn repeated_value(values: &[f64]) -> Option<f64> {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    sorted.windows(2).find(|w| w[0] == w[1]).map(|w| w[0])
}

/// A deterministic part of a sweep: shard `k` of `n` (1 ≤ k ≤ n) runs the
/// runs whose index `i` (in grid order, runs of a point consecutive) has
/// `i mod n = k − 1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    /// Which shard, from 1.
    pub k: u64,
    /// How many shards.
    pub n: u64,
}

impl Shard {
    /// The whole sweep.
    pub const ALL: Shard = Shard { k: 1, n: 1 };

    /// True if run index `i` belongs to this shard.
    pub fn contains(&self, i: u64) -> bool {
        i % self.n == self.k - 1
    }
}

impl FromStr for Shard {
    type Err = SweepError;

    /// Parses `k/n` with 1 ≤ k ≤ n.
    fn from_str(s: &str) -> Result<Self, SweepError> {
        let bad = || SweepError::Shard(s.to_string());
        let (k, n) = s.split_once('/').ok_or_else(bad)?;
        let k: u64 = k.trim().parse().map_err(|_| bad())?;
        let n: u64 = n.trim().parse().map_err(|_| bad())?;
        if k == 0 || n == 0 || k > n {
            return Err(bad());
        }
        Ok(Shard { k, n })
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.k, self.n)
    }
}

/// The seed of run `run` at the grid point written `point` (`delta=5,Jmax=0.2`,
/// see [`super::SweepSpec::point_label`]) of a sweep with base seed `base`:
/// the first 8 bytes (little endian) of
/// SHA-256(`hybsim-sweep/{base}/{point}/{run}`). It depends on the point's
/// values, not on its position, so adding values to an axis keeps the
/// seeds of the other points.
pub fn run_seed(base: u64, point: &str, run: u64) -> u64 {
    use sha2::Digest;
    let digest = sha2::Sha256::digest(format!("hybsim-sweep/{base}/{point}/{run}").as_bytes());
    let mut b = [0u8; 8];
    b.copy_from_slice(&digest[..8]);
    u64::from_le_bytes(b)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axes_parse() {
        let a: Axis = "delta=0:5:80".parse().unwrap();
        assert_eq!(a.values.len(), 17);
        assert_eq!(a.values[16], 80.0);
        let a: Axis = "x=0:0.1:0.3".parse().unwrap();
        assert_eq!(a.values, [0.0, 0.1, 0.2, 0.30000000000000004]);
        let a: Axis = "Jmax=[0.2, 0.38, 1]".parse().unwrap();
        assert_eq!(
            (a.name.as_str(), a.values.as_slice()),
            ("Jmax", &[0.2, 0.38, 1.0][..])
        );
        assert_eq!("k=3".parse::<Axis>().unwrap().values, [3.0]);
        let a: Axis = "d=10:-5:0".parse().unwrap();
        assert_eq!(a.values, [10.0, 5.0, 0.0]);
        for bad in [
            "x",
            "=1",
            "x=1:0:2",
            "x=0:1:-1",
            "x=[1, a]",
            "x=[1",
            "x=1:2",
            "x=nan",
            "x=0:1e-9:1e9",
        ] {
            assert!(bad.parse::<Axis>().is_err(), "{bad}");
        }
    }

    #[test]
    fn a_range_of_too_many_values_says_how_many_compactly() {
        // Was the count's 301 digits (`9999999999999999000…0 values`).
        let err = "x=0:1e-300:1".parse::<Axis>().unwrap_err().to_string();
        assert!(
            err.ends_with("about 1.0e300 values (at most 1000000 per axis)"),
            "{err}"
        );
        let err = "x=0:1e-12:1".parse::<Axis>().unwrap_err().to_string();
        assert!(
            err.ends_with(": 1000000000001 values (at most 1000000 per axis)"),
            "{err}"
        );
    }

    #[test]
    fn shards_partition_the_runs() {
        let shards: Vec<Shard> = (1..=3).map(|k| format!("{k}/3").parse().unwrap()).collect();
        for i in 0..20 {
            assert_eq!(shards.iter().filter(|s| s.contains(i)).count(), 1);
        }
        for bad in ["0/2", "3/2", "1", "a/b", "1/0"] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
    }

    #[test]
    fn seeds_are_stable_and_distinct() {
        assert_eq!(run_seed(1, "a=1", 0), run_seed(1, "a=1", 0));
        let mut seen: Vec<u64> = (0..100).map(|r| run_seed(1, "a=1", r)).collect();
        seen.extend((0..100).map(|r| run_seed(2, "a=1", r)));
        seen.sort();
        seen.dedup();
        assert_eq!(seen.len(), 200);
    }
}
