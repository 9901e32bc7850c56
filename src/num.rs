//! Numbers: compact, lossless formatting for reports and messages, the
//! finiteness scan of state vectors, and the slot of a value's bits in a
//! small cache.

use std::fmt;

/// The slot of 64 bits in a table of `slots` entries (a power of two):
/// Fibonacci hashing, whose top bits depend on every bit of the key, so
/// keys that differ only in their low bits (t and t + h) spread out.
///
/// ```
/// use hybsim::num::hash_slot;
/// assert!(hash_slot(1.5f64.to_bits(), 16) < 16);
/// assert_eq!(hash_slot(7, 1), 0);
/// ```
#[inline]
pub fn hash_slot(bits: u64, slots: usize) -> usize {
    debug_assert!(slots.is_power_of_two());
    // `checked_shr`: one slot leaves no bits to take (a shift by 64).
    bits.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .checked_shr(64 - slots.trailing_zeros())
        .unwrap_or(0) as usize
}

/// The first non-finite component of `x`, if any.
///
/// A branch-free pass first (the engine runs this on every step's state
/// and jump, the sinks on every logged sample): `v − v` is +0 for finite
/// `v` and NaN for ±∞ and NaN, and a NaN stays in a sum. Eight independent
/// sums vectorize on any x86-64 (half the instructions of a bitwise test
/// of the exponent field, which needs 64-bit lane arithmetic).
///
/// ```
/// use hybsim::num::first_non_finite;
/// assert_eq!(first_non_finite(&[1.0, f64::MAX, -0.0]), None);
/// assert_eq!(first_non_finite(&[1.0, f64::NAN, f64::INFINITY]), Some(1));
/// ```
#[inline]
#[allow(clippy::eq_op)] // `v - v` is the test itself
pub fn first_non_finite(x: &[f64]) -> Option<usize> {
    let mut acc = [0.0f64; 8];
    let chunks = x.chunks_exact(8);
    let rest = chunks.remainder();
    for c in chunks {
        for k in 0..8 {
            acc[k] += c[k] - c[k];
        }
    }
    let mut sum: f64 = acc.iter().sum();
    for &v in rest {
        sum += v - v;
    }
    if sum == 0.0 {
        return None;
    }
    x.iter().position(|v| !v.is_finite())
}

/// Displays an `f64` compactly without losing precision: the shortest
/// decimal that reads back as the same number, in positional form for
/// magnitudes in `[1e-4, 1e15)` (and zero), in scientific form otherwise
/// (`1e-9`, `2.5e20` instead of `0.000000001`, `250000000000000000000`).
/// Non-finite values print as `NaN`, `inf`, `-inf`.
///
/// ```
/// use hybsim::num::Num;
/// assert_eq!(Num(1e-9).to_string(), "1e-9");
/// assert_eq!(Num(0.25).to_string(), "0.25");
/// assert_eq!(Num(-3.0).to_string(), "-3");
/// assert_eq!(Num(1.5e300).to_string(), "1.5e300");
/// assert_eq!(Num(1.0000000000000002).to_string(), "1.0000000000000002");
/// ```
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num(pub f64);

impl fmt::Display for Num {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let x = self.0;
        let a = x.abs();
        if !x.is_finite() || a == 0.0 || (1e-4..1e15).contains(&a) {
            // `{}` is the shortest round-trip form; `-0` prints as `-0`.
            write!(f, "{x}")
        } else {
            write!(f, "{x:e}")
        }
    }
}

/// `x` formatted by [`Num`].
pub fn fmt_num(x: f64) -> String {
    Num(x).to_string()
}

/// `xs` formatted by [`Num`], separated by `", "`.
pub fn fmt_nums(xs: &[f64]) -> String {
    xs.iter()
        .map(|&x| fmt_num(x))
        .collect::<Vec<_>>()
        .join(", ")
}

/// A `rows × cols` matrix stored row-major in `vals` as JSON: a number
/// (1×1), an array (a column), or an array of rows (also for zero columns:
/// `rows` empty arrays).
pub fn matrix_json(rows: usize, cols: usize, vals: &[f64]) -> serde_json::Value {
    match (rows, cols) {
        (1, 1) => serde_json::json!(vals[0]),
        (_, 1) => serde_json::json!(vals),
        (r, 0) => serde_json::json!(vec![Vec::<f64>::new(); r]),
        (_, c) => serde_json::json!(vals.chunks(c).collect::<Vec<_>>()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_finite_found_in_chunks_and_remainder() {
        for len in [0, 1, 7, 8, 9, 16, 23, 238] {
            let x: Vec<f64> = (0..len).map(|i| (i as f64 - 5.0) * 1e300).collect();
            assert_eq!(first_non_finite(&x), None, "len {len}");
            for k in 0..len {
                for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
                    let mut y = x.clone();
                    y[k] = bad;
                    if k + 1 < len {
                        y[len - 1] = f64::NAN;
                    }
                    assert_eq!(first_non_finite(&y), Some(k), "len {len}, at {k}");
                }
            }
        }
        assert_eq!(
            first_non_finite(&[f64::MAX, -f64::MAX, f64::MIN_POSITIVE, 5e-324]),
            None
        );
    }

    #[test]
    fn compact_and_lossless() {
        for x in [
            0.0,
            1e-4,
            9.99e-5,
            1e15,
            1e14,
            123.456,
            -7e-12,
            1.0 / 3.0,
            f64::MAX,
            f64::MIN_POSITIVE,
            5e-324,
        ] {
            let s = fmt_num(x);
            assert_eq!(s.parse::<f64>(), Ok(x), "{s}");
            assert!(s.len() <= 24, "{s}");
        }
        assert_eq!(fmt_num(9.99e-5), "9.99e-5");
        assert_eq!(fmt_num(1e15), "1e15");
        assert_eq!(fmt_num(1e14), "100000000000000");
        assert_eq!(fmt_num(f64::NAN), "NaN");
        assert_eq!(fmt_num(f64::NEG_INFINITY), "-inf");
        assert_eq!(fmt_nums(&[1.0, 2e-7]), "1, 2e-7");
    }
}
