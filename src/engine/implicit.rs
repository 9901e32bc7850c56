//! What the engine's implicit steppers ([`Radau5`](super::radau5::Radau5)
//! and [`Bdf`](super::bdf::Bdf)) share: the Jacobian callback and its
//! cache, the in-place LU factorization of their Newton matrices
//! `μ·I − J`, the scaled RMS norm, the Newton tolerance and the initial
//! step estimate.

// Row and column indices are written as in the formulas.
#![allow(clippy::needless_range_loop)]

use nalgebra::{ComplexField, DMatrix};

use super::dopri5::Rhs;

/// The Jacobian in local time: `jac(s, y, j)` writes ∂f/∂y at (s, y) into
/// `j`, row-major n×n.
pub(crate) type Jac<'a> = dyn FnMut(f64, &[f64], &mut [f64]) + 'a;

/// The last Jacobian an implicit stepper evaluated, kept across steps,
/// segments and jumps (Newton iterations converge with an outdated one,
/// only slower; a stepper refreshes it when they stop converging).
pub(crate) struct Jacobian {
    /// ∂f/∂y, row-major.
    pub m: Vec<f64>,
    /// Whether `m` was evaluated at the current step's start (or
    /// prediction): refreshing it again cannot help.
    pub fresh: bool,
    any: bool,
    /// Evaluations so far.
    pub evals: u64,
}

impl Jacobian {
    pub fn new(n: usize) -> Self {
        Self {
            m: vec![0.0; n * n],
            fresh: false,
            any: false,
            evals: 0,
        }
    }

    /// Evaluates it at (`s`, `y`).
    pub fn refresh(&mut self, s: f64, y: &[f64], jac: &mut Jac<'_>) {
        jac(s, y, &mut self.m);
        self.evals += 1;
        self.any = true;
        self.fresh = true;
    }

    /// Evaluates it at (`s`, `y`) if none was evaluated yet; returns
    /// whether it did.
    pub fn ensure(&mut self, s: f64, y: &[f64], jac: &mut Jac<'_>) -> bool {
        if self.any {
            return false;
        }
        self.refresh(s, y, jac);
        true
    }

    /// The norm `max_i Σ_j |J_ij|·w_j / w_i` (the operator norm of the
    /// max-norm weighted by `w`, the error scales): an upper bound of J's
    /// spectral radius, which bounds the step an explicit method can take.
    pub fn weighted_norm(&self, w: &[f64]) -> f64 {
        let n = w.len();
        let mut best: f64 = 0.0;
        for r in 0..n {
            let row: f64 = (0..n).map(|c| self.m[r * n + c].abs() * w[c]).sum();
            best = best.max(row / w[r]);
        }
        best
    }
}

/// An in-place LU factorization with partial pivoting of a square matrix,
/// reused across factorizations (no allocation after construction;
/// nalgebra's `LU` consumes its matrix and allocates a permutation per
/// factorization).
pub(crate) struct DenseLu<T: ComplexField<RealField = f64> + Copy> {
    pub m: DMatrix<T>,
    piv: Vec<usize>,
    /// The rows below the pivot with a nonzero multiplier (scratch).
    rows: Vec<usize>,
}

impl<T: ComplexField<RealField = f64> + Copy> DenseLu<T> {
    pub fn new(n: usize) -> Self {
        Self {
            m: DMatrix::from_element(n, n, T::zero()),
            piv: vec![0; n],
            rows: Vec::with_capacity(n),
        }
    }

    /// Factorizes `mu·I − J` (`jac` row-major, n×n), the Newton matrix of
    /// an implicit method; `false` if it is singular.
    pub fn factor_shifted(&mut self, mu: T, jac: &[f64]) -> bool {
        let n = self.piv.len();
        for r in 0..n {
            for c in 0..n {
                let v = T::from_real(-jac[r * n + c]);
                self.m[(r, c)] = if r == c { mu + v } else { v };
            }
        }
        self.factor()
    }

    /// Factorizes the matrix in `self.m`; `false` if it is singular.
    pub fn factor(&mut self) -> bool {
        let n = self.piv.len();
        let m = &mut self.m;
        for k in 0..n {
            let (mut p, mut best) = (k, -1.0);
            for r in k..n {
                let v = m[(r, k)].norm1();
                if v > best {
                    (p, best) = (r, v);
                }
            }
            if !(best > 0.0 && best.is_finite()) {
                return false;
            }
            self.piv[k] = p;
            if p != k {
                m.swap_rows(k, p);
            }
            let inv = T::one() / m[(k, k)];
            // Only rows with a nonzero multiplier are updated: the Newton
            // matrices of models with families (each state coupled to a
            // few others) are mostly structural zeros, and so are their
            // factors away from the fill-in.
            self.rows.clear();
            for r in k + 1..n {
                if m[(r, k)] != T::zero() {
                    m[(r, k)] *= inv;
                    self.rows.push(r);
                }
            }
            if self.rows.is_empty() {
                continue;
            }
            let dense = self.rows.len() == n - k - 1;
            for c in k + 1..n {
                let u = m[(k, c)];
                if u == T::zero() {
                    continue;
                }
                if dense {
                    for r in k + 1..n {
                        let l = m[(r, k)];
                        m[(r, c)] -= l * u;
                    }
                } else {
                    for &r in &self.rows {
                        let l = m[(r, k)];
                        m[(r, c)] -= l * u;
                    }
                }
            }
        }
        true
    }

    /// Solves `M x = b` in place.
    pub fn solve(&self, b: &mut [T]) {
        let n = self.piv.len();
        let m = &self.m;
        for k in 0..n {
            b.swap(k, self.piv[k]);
        }
        for c in 0..n {
            let v = b[c];
            if v != T::zero() {
                for r in c + 1..n {
                    b[r] -= m[(r, c)] * v;
                }
            }
        }
        for c in (0..n).rev() {
            b[c] /= m[(c, c)];
            let v = b[c];
            if v != T::zero() {
                for r in 0..c {
                    b[r] -= m[(r, c)] * v;
                }
            }
        }
    }
}

/// The RMS norm of `v / scale` (0 for no components).
pub(crate) fn rms_scaled(v: &[f64], scale: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let sum: f64 = v.iter().zip(scale).map(|(a, s)| (a / s).powi(2)).sum();
    (sum / v.len() as f64).sqrt()
}

/// The tolerance of the Newton iterations on the scaled increments, as
/// RADAU5 and scipy's implicit methods choose it.
pub(crate) fn newton_tol(rtol: f64) -> f64 {
    (10.0 * f64::EPSILON / rtol).max(rtol.sqrt().min(0.03))
}

/// The initial step for a method whose error estimate is of order
/// `err_order` (the local error ~ h^(err_order+1)), from the scaled sizes
/// of y, f(y) and an estimate of f's derivative (one evaluation of f, with
/// `y1`, `f1` as buffers), as Hairer & Wanner's and scipy's starters.
#[allow(clippy::too_many_arguments)]
pub(crate) fn initial_step(
    y: &[f64],
    f0: &[f64],
    f: &mut Rhs<'_>,
    rtol: f64,
    atol: f64,
    err_order: i32,
    y1: &mut [f64],
    f1: &mut [f64],
) -> f64 {
    let n = y.len();
    if n == 0 {
        return 1.0;
    }
    let sk = |i: usize| atol + rtol * y[i].abs();
    let rms =
        |g: &dyn Fn(usize) -> f64| ((0..n).map(|i| g(i).powi(2)).sum::<f64>() / n as f64).sqrt();
    let d0 = rms(&|i| y[i] / sk(i));
    let d1 = rms(&|i| f0[i] / sk(i));
    let h0 = if d0 < 1e-5 || d1 < 1e-5 {
        1e-6
    } else {
        0.01 * d0 / d1
    };
    for i in 0..n {
        y1[i] = y[i] + h0 * f0[i];
    }
    f(h0, y1, f1);
    let d2 = rms(&|i| (f1[i] - f0[i]) / sk(i)) / h0;
    let h1 = if d1 <= 1e-15 && d2 <= 1e-15 {
        (h0 * 1e-3).max(1e-6)
    } else {
        (0.01 / d1.max(d2)).powf(1.0 / f64::from(err_order + 1))
    };
    let h = (100.0 * h0).min(h1);
    if h.is_finite() && h > 0.0 { h } else { 1e-6 }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Complex;

    #[test]
    fn dense_lu_solves_real_and_complex_systems() {
        let mut lu = DenseLu::<f64>::new(3);
        let m = [[0.0, 2.0, 1.0], [1.0, -1.0, 0.5], [4.0, 0.0, -2.0]];
        for r in 0..3 {
            for c in 0..3 {
                lu.m[(r, c)] = m[r][c];
            }
        }
        assert!(lu.factor());
        let x = [1.0, -2.0, 0.5];
        let mut b: Vec<f64> = (0..3)
            .map(|r| (0..3).map(|c| m[r][c] * x[c]).sum())
            .collect();
        lu.solve(&mut b);
        for i in 0..3 {
            assert!((b[i] - x[i]).abs() < 1e-14);
        }
        let mut cx = DenseLu::<Complex<f64>>::new(2);
        let i1 = Complex::new(0.0, 1.0);
        let mm = [
            [Complex::new(2.0, 1.0), i1],
            [Complex::new(1.0, 0.0), Complex::new(0.0, -3.0)],
        ];
        for r in 0..2 {
            for c in 0..2 {
                cx.m[(r, c)] = mm[r][c];
            }
        }
        assert!(cx.factor());
        let xs = [Complex::new(1.0, -1.0), Complex::new(0.5, 2.0)];
        let mut bs: Vec<Complex<f64>> = (0..2)
            .map(|r| mm[r][0] * xs[0] + mm[r][1] * xs[1])
            .collect();
        cx.solve(&mut bs);
        assert!((bs[0] - xs[0]).norm() < 1e-14 && (bs[1] - xs[1]).norm() < 1e-14);
        let mut sing = DenseLu::<f64>::new(2);
        assert!(!sing.factor(), "the zero matrix is singular");
    }

    /// A sparse matrix (a chain of couplings plus one dense row and
    /// column, with fill-in) and a permuted one solve exactly like their
    /// dense definition.
    #[test]
    fn dense_lu_solves_sparse_systems() {
        let n = 9;
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            a[i * n + i] = 4.0 + i as f64;
            if i + 1 < n {
                a[i * n + i + 1] = -1.0;
                a[(i + 1) * n + i] = 0.5 * (i as f64 - 3.0);
            }
            a[i * n + n - 1] += 0.3;
            a[(n - 1) * n + i] += 0.7;
        }
        // A zero first pivot: the factorization swaps rows.
        a.swap(0, 2 * n);
        let x: Vec<f64> = (0..n).map(|i| (i as f64).sin() + 1.0).collect();
        let mut lu = DenseLu::<f64>::new(n);
        for r in 0..n {
            for c in 0..n {
                lu.m[(r, c)] = a[r * n + c];
            }
        }
        assert!(lu.factor());
        let mut b: Vec<f64> = (0..n)
            .map(|r| (0..n).map(|c| a[r * n + c] * x[c]).sum())
            .collect();
        lu.solve(&mut b);
        for i in 0..n {
            assert!((b[i] - x[i]).abs() < 1e-13, "x[{i}] = {} vs {}", b[i], x[i]);
        }
    }

    /// `factor_shifted` factorizes μI − J: solving with it inverts that
    /// matrix, and the weighted norm bounds the spectral radius.
    #[test]
    fn shifted_factorization_and_weighted_norm() {
        let jac = [-3.0, 1.0, 0.5, -2.0];
        let mut lu = DenseLu::<f64>::new(2);
        assert!(lu.factor_shifted(4.0, &jac));
        // (4I − J) x = b with x = (1, 2): 4I − J = [[7, −1], [−0.5, 6]].
        let mut b = [7.0 - 2.0, -0.5 + 12.0];
        lu.solve(&mut b);
        assert!((b[0] - 1.0).abs() < 1e-14 && (b[1] - 2.0).abs() < 1e-14);
        let mut j = Jacobian::new(2);
        j.m.copy_from_slice(&jac);
        assert_eq!(j.weighted_norm(&[1.0, 1.0]), 4.0);
        // Scaling the second component by 10: rows 3 + 10, (0.5/10 + 2).
        assert_eq!(j.weighted_norm(&[1.0, 10.0]), 13.0);
    }
}
