//! What the engine's implicit steppers ([`Radau5`](super::radau5::Radau5)
//! and [`Bdf`](super::bdf::Bdf)) share: the Jacobian callback and its
//! cache, the LU factorizations of their Newton matrices `μ·I − J` (dense
//! in place, or sparse by faer for large sparse systems), the scaled RMS
//! norm, the Newton tolerance and the initial step estimate.

// Row and column indices are written as in the formulas.
#![allow(clippy::needless_range_loop)]

use std::sync::Arc;

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::linalg::lu::{
    LuRef, LuSymbolicParams, NumericLu, SymbolicLu, factorize_symbolic_lu,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use faer::{Conj, MatMut, Par};
use nalgebra::{ComplexField, DMatrix};

use super::dopri5::Rhs;
use super::sparsity::SparsityPattern;

/// The Jacobian in local time: `jac(s, y, j)` writes ∂f/∂y at (s, y) into
/// `j`: n×n row-major, or the entries of the run's sparsity pattern
/// ([`LinearAlgebra::pattern`]).
pub(crate) type Jac<'a> = dyn FnMut(f64, &[f64], &mut [f64]) + 'a;

/// A scalar of the Newton matrices: f64 (real LU) or Complex<f64> (Radau5's
/// complex pair), for both the dense and faer's sparse LU.
pub(crate) trait Scalar:
    ComplexField<RealField = f64> + faer::traits::ComplexField + Copy
{
}

impl<T: ComplexField<RealField = f64> + faer::traits::ComplexField + Copy> Scalar for T {}

/// How a run's implicit steppers store the Jacobian and factorize their
/// Newton matrices, decided once per run
/// ([`use_sparse_lu`](super::sparsity::use_sparse_lu)).
#[derive(Clone)]
pub(crate) struct LinearAlgebra {
    n: usize,
    /// The Jacobian's pattern (values in its order), or `None`: n×n dense.
    pub pattern: Option<Arc<SparsityPattern>>,
    /// The sparse LU's structure, shared by the steppers' factorizations.
    sparse: Option<Arc<SparseStructure>>,
}

impl LinearAlgebra {
    /// Dense storage and LU for n states.
    #[cfg(test)]
    pub fn dense(n: usize) -> Self {
        Self {
            n,
            pattern: None,
            sparse: None,
        }
    }

    /// The Jacobian in `pattern` (n states; `None`: dense), factorized
    /// sparse if `sparse_lu` (and the symbolic analysis succeeds).
    pub fn new(n: usize, pattern: Option<Arc<SparsityPattern>>, sparse_lu: bool) -> Self {
        let sparse = match &pattern {
            Some(p) if sparse_lu => SparseStructure::new(p).map(Arc::new),
            _ => None,
        };
        Self { n, pattern, sparse }
    }

    /// Whether the Newton matrices are factorized sparse.
    #[cfg(test)]
    pub fn is_sparse(&self) -> bool {
        self.sparse.is_some()
    }
}

/// The last Jacobian an implicit stepper evaluated, kept across steps,
/// segments and jumps (Newton iterations converge with an outdated one,
/// only slower; a stepper refreshes it when they stop converging).
pub(crate) struct Jacobian {
    /// ∂f/∂y: row-major n×n, or the entries of `pattern`.
    pub m: Vec<f64>,
    pattern: Option<Arc<SparsityPattern>>,
    /// Row sums of the weighted norm (scratch).
    rows: Vec<f64>,
    /// Whether `m` was evaluated at the current step's start (or
    /// prediction): refreshing it again cannot help.
    pub fresh: bool,
    any: bool,
    /// Evaluations so far.
    pub evals: u64,
}

impl Jacobian {
    pub fn new(la: &LinearAlgebra) -> Self {
        let n = la.n;
        Self {
            m: vec![0.0; la.pattern.as_ref().map_or(n * n, |p| p.nnz())],
            pattern: la.pattern.clone(),
            rows: vec![0.0; n],
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
    pub fn weighted_norm(&mut self, w: &[f64]) -> f64 {
        let n = w.len();
        match &self.pattern {
            None => {
                for r in 0..n {
                    self.rows[r] = (0..n).map(|c| self.m[r * n + c].abs() * w[c]).sum();
                }
            }
            Some(p) => {
                self.rows.fill(0.0);
                for c in 0..n {
                    for k in p.col_ptr()[c]..p.col_ptr()[c + 1] {
                        self.rows[p.row_idx()[k]] += self.m[k].abs() * w[c];
                    }
                }
            }
        }
        (0..n).fold(0.0, |best: f64, r| best.max(self.rows[r] / w[r]))
    }
}

/// The LU factorization of a Newton matrix `μI − J`: dense or sparse, as
/// the run's [`LinearAlgebra`] says.
pub(crate) enum NewtonLu<T: Scalar> {
    Dense(DenseLu<T>),
    Sparse(Box<SparseLu<T>>),
}

impl<T: Scalar> NewtonLu<T> {
    pub fn new(la: &LinearAlgebra) -> Self {
        match &la.sparse {
            Some(st) => Self::Sparse(Box::new(SparseLu::new(st.clone()))),
            None => Self::Dense(DenseLu::new(la.n)),
        }
    }

    /// Factorizes `mu·I − J` for the Jacobian `jac`; `false` if it is
    /// singular (the sparse LU: structurally; a numerically singular one
    /// shows as non-finite Newton increments, which the steppers treat
    /// alike).
    pub fn factor_shifted(&mut self, mu: T, jac: &Jacobian) -> bool {
        match self {
            Self::Dense(lu) => lu.factor_shifted(mu, &jac.m, jac.pattern.as_deref()),
            Self::Sparse(lu) => lu.factor_shifted(mu, &jac.m),
        }
    }

    /// Solves `M x = b` in place.
    pub fn solve(&mut self, b: &mut [T]) {
        match self {
            Self::Dense(lu) => lu.solve(b),
            Self::Sparse(lu) => lu.solve(b),
        }
    }
}

/// What the sparse factorizations of a run share: the Newton matrix's
/// pattern (J's plus the diagonal), where J's entries and the diagonal go
/// in it, and faer's symbolic analysis (the fill-reducing column ordering).
pub(crate) struct SparseStructure {
    n: usize,
    matrix: SymbolicSparseColMat<usize>,
    /// Position in the Newton matrix's values of each of J's entries.
    jpos: Vec<usize>,
    /// Position of each diagonal entry.
    diag: Vec<usize>,
    symbolic: SymbolicLu<usize>,
}

impl SparseStructure {
    fn new(p: &SparsityPattern) -> Option<Self> {
        let n = p.n();
        let a = p.with_diagonal();
        let jpos = p
            .entries()
            .map(|(r, c)| {
                a.position(r, c)
                    .expect("J's entries are in the Newton matrix")
            })
            .collect();
        let diag = (0..n)
            .map(|i| {
                a.position(i, i)
                    .expect("the diagonal is in the Newton matrix")
            })
            .collect();
        let matrix = SymbolicSparseColMat::new_checked(
            n,
            n,
            a.col_ptr().to_vec(),
            None,
            a.row_idx().to_vec(),
        );
        // Simplicial (left-looking, column by column): it reuses its
        // factors' storage from one factorization to the next, and suits
        // the narrow fill of the family models that get the sparse path.
        let params = LuSymbolicParams {
            supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SIMPLICIAL,
            ..Default::default()
        };
        let symbolic = factorize_symbolic_lu(matrix.as_ref(), params).ok()?;
        Some(Self {
            n,
            matrix,
            jpos,
            diag,
            symbolic,
        })
    }
}

/// faer's sparse LU with partial pivoting of a Newton matrix, its values,
/// factors and workspace kept across factorizations: after the first, a
/// factorization allocates only if a new pivot order needs more fill than
/// any before (the factors' vectors grow, as a `Vec` does); solves never.
pub(crate) struct SparseLu<T: Scalar> {
    st: Arc<SparseStructure>,
    values: Vec<T>,
    numeric: NumericLu<usize, T>,
    mem: MemBuffer,
}

impl<T: Scalar> SparseLu<T> {
    fn new(st: Arc<SparseStructure>) -> Self {
        let req = st
            .symbolic
            .factorize_numeric_lu_scratch::<T>(Par::Seq, Default::default())
            .or(st.symbolic.solve_in_place_scratch::<T>(1, Par::Seq));
        Self {
            values: vec![T::from_real(0.0); st.matrix.row_idx().len()],
            numeric: NumericLu::new(),
            mem: MemBuffer::new(req),
            st,
        }
    }

    fn factor_shifted(&mut self, mu: T, jac: &[f64]) -> bool {
        let st = &*self.st;
        self.values.fill(T::from_real(0.0));
        for &k in &st.diag {
            self.values[k] = mu;
        }
        for (&k, &v) in st.jpos.iter().zip(jac) {
            self.values[k] -= T::from_real(v);
        }
        let a = SparseColMatRef::new(st.matrix.as_ref(), &self.values);
        st.symbolic
            .factorize_numeric_lu(
                &mut self.numeric,
                a,
                Par::Seq,
                MemStack::new(&mut self.mem),
                Default::default(),
            )
            .is_ok()
    }

    fn solve(&mut self, b: &mut [T]) {
        let st = &*self.st;
        let lu = LuRef::new_unchecked(&st.symbolic, &self.numeric);
        lu.solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(b, st.n, 1),
            Par::Seq,
            MemStack::new(&mut self.mem),
        );
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

    /// Factorizes `mu·I − J` (`jac` row-major n×n, or the entries of
    /// `pattern`), the Newton matrix of an implicit method; `false` if it
    /// is singular.
    pub fn factor_shifted(
        &mut self,
        mu: T,
        jac: &[f64],
        pattern: Option<&SparsityPattern>,
    ) -> bool {
        let n = self.piv.len();
        match pattern {
            None => {
                for r in 0..n {
                    for c in 0..n {
                        self.m[(r, c)] = T::from_real(-jac[r * n + c]);
                    }
                }
            }
            Some(p) => {
                self.m.fill(T::zero());
                for ((r, c), &v) in p.entries().zip(jac) {
                    self.m[(r, c)] = T::from_real(-v);
                }
            }
        }
        for i in 0..n {
            self.m[(i, i)] += mu;
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
/// Returns the step and the probe `h0` (0 if none was taken): then `f1`
/// holds `f(h0, y + h0·f0)`, so `(f1 − f0) / h0` estimates y''.
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
) -> (f64, f64) {
    let n = y.len();
    if n == 0 {
        return (1.0, 0.0);
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
    (if h.is_finite() && h > 0.0 { h } else { 1e-6 }, h0)
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

    /// The sparse LU (faer's) solves μI − J like the dense one, real and
    /// complex, for a J with a zero and a nonzero pivot pattern (a chain,
    /// one dense row and column, a diagonal entry missing from J's
    /// pattern); the values are J's in the pattern's order.
    #[test]
    fn sparse_lu_solves_like_the_dense_lu() {
        let n = 40;
        let entries: Vec<(usize, usize)> = (0..n)
            .flat_map(|i| {
                let mut e = vec![(i, n - 1), (n - 1, i)];
                if i + 1 < n {
                    e.extend([(i, i + 1), (i + 1, i)]);
                }
                if i % 3 != 0 {
                    e.push((i, i));
                }
                e
            })
            .collect();
        let p = Arc::new(SparsityPattern::new(n, entries).unwrap());
        let la = LinearAlgebra::new(n, Some(p.clone()), true);
        assert!(la.is_sparse());
        let mut jac = Jacobian::new(&la);
        for (k, (r, c)) in p.entries().enumerate() {
            jac.m[k] = ((r * 7 + c * 3) % 11) as f64 - 5.0 + if r == c { -30.0 } else { 0.0 };
        }
        let dense_la = LinearAlgebra::new(n, Some(p.clone()), false);
        assert!(!dense_la.is_sparse());
        let b: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin()).collect();
        let mu = 2.5;
        let (mut sparse, mut dense) = (NewtonLu::<f64>::new(&la), NewtonLu::<f64>::new(&dense_la));
        assert!(sparse.factor_shifted(mu, &jac) && dense.factor_shifted(mu, &jac));
        let (mut xs, mut xd) = (b.clone(), b.clone());
        sparse.solve(&mut xs);
        dense.solve(&mut xd);
        for i in 0..n {
            assert!(
                (xs[i] - xd[i]).abs() < 1e-12,
                "x[{i}]: {} vs {}",
                xs[i],
                xd[i]
            );
        }
        // The complex shift of Radau5, refactorized with another J.
        for v in &mut jac.m {
            *v *= -1.5;
        }
        let mu = Complex::new(3.0, -2.0);
        let mut sparse = NewtonLu::<Complex<f64>>::new(&la);
        let mut dense = NewtonLu::<Complex<f64>>::new(&dense_la);
        for _ in 0..2 {
            assert!(sparse.factor_shifted(mu, &jac) && dense.factor_shifted(mu, &jac));
        }
        let bc: Vec<Complex<f64>> = b.iter().map(|&v| Complex::new(v, 1.0 - v)).collect();
        let (mut xs, mut xd) = (bc.clone(), bc);
        sparse.solve(&mut xs);
        dense.solve(&mut xd);
        for i in 0..n {
            assert!(
                (xs[i] - xd[i]).norm() < 1e-12,
                "x[{i}]: {} vs {}",
                xs[i],
                xd[i]
            );
        }
        // The weighted norm from the pattern's entries equals the dense one.
        let w: Vec<f64> = (0..n).map(|i| 1.0 + i as f64).collect();
        let mut dj = Jacobian::new(&LinearAlgebra::dense(n));
        for (k, (r, c)) in p.entries().enumerate() {
            dj.m[r * n + c] = jac.m[k];
        }
        assert!((jac.weighted_norm(&w) - dj.weighted_norm(&w)).abs() < 1e-9);
    }

    /// `factor_shifted` factorizes μI − J: solving with it inverts that
    /// matrix, and the weighted norm bounds the spectral radius.
    #[test]
    fn shifted_factorization_and_weighted_norm() {
        let jac = [-3.0, 1.0, 0.5, -2.0];
        let mut lu = DenseLu::<f64>::new(2);
        assert!(lu.factor_shifted(4.0, &jac, None));
        // (4I − J) x = b with x = (1, 2): 4I − J = [[7, −1], [−0.5, 6]].
        let mut b = [7.0 - 2.0, -0.5 + 12.0];
        lu.solve(&mut b);
        assert!((b[0] - 1.0).abs() < 1e-14 && (b[1] - 2.0).abs() < 1e-14);
        let mut j = Jacobian::new(&LinearAlgebra::dense(2));
        j.m.copy_from_slice(&jac);
        assert_eq!(j.weighted_norm(&[1.0, 1.0]), 4.0);
        // Scaling the second component by 10: rows 3 + 10, (0.5/10 + 2).
        assert_eq!(j.weighted_norm(&[1.0, 10.0]), 13.0);
    }
}
