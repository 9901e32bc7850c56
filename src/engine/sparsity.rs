//! The structural sparsity of the Jacobian ∂f/∂x, and what the implicit
//! solvers do with it: finite differences by column groups (Curtis, Powell
//! & Reid) when the system gives no exact entries, and the choice between
//! the dense and the sparse LU of the Newton matrices.
//!
//! A system declares its pattern with
//! [`HybridSystem::jacobian_pattern`](super::HybridSystem::jacobian_pattern)
//! (a compiled `.hyb` model derives it from its expression graph) and may
//! write the entries itself with
//! [`HybridSystem::jacobian_values`](super::HybridSystem::jacobian_values),
//! in the pattern's order (column by column, rows ascending).

use std::sync::Arc;

use faer::sparse::SymbolicSparseColMat;
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, SymmetricOrdering, factorize_symbolic_cholesky,
};

use super::error::SimError;
use super::settings::LinearSolver;
use super::system::HybridSystem;
use crate::arc::HybridTime;

/// Which entries of an n×n matrix can be nonzero, column by column
/// (compressed sparse columns: the rows of column c are
/// `row_idx[col_ptr[c]..col_ptr[c + 1]]`, ascending). Values that go with
/// a pattern are stored in the same order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SparsityPattern {
    n: usize,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
}

/// A pattern entry outside its matrix.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("entry ({row}, {col}) is outside the {n}×{n} matrix")]
pub struct PatternError {
    /// The entry's row.
    pub row: usize,
    /// The entry's column.
    pub col: usize,
    /// The matrix's size.
    pub n: usize,
}

impl SparsityPattern {
    /// The pattern of the n×n matrix whose possibly nonzero entries are
    /// `entries` (row, column), in any order, repeats allowed.
    pub fn new(
        n: usize,
        entries: impl IntoIterator<Item = (usize, usize)>,
    ) -> Result<Self, PatternError> {
        let mut cols: Vec<Vec<usize>> = vec![Vec::new(); n];
        for (row, col) in entries {
            if row >= n || col >= n {
                return Err(PatternError { row, col, n });
            }
            cols[col].push(row);
        }
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::new();
        col_ptr.push(0);
        for mut rows in cols {
            rows.sort_unstable();
            rows.dedup();
            row_idx.extend(rows);
            col_ptr.push(row_idx.len());
        }
        Ok(Self {
            n,
            col_ptr,
            row_idx,
        })
    }

    /// Every entry of an n×n matrix.
    pub fn dense(n: usize) -> Self {
        Self {
            n,
            col_ptr: (0..=n).map(|c| c * n).collect(),
            row_idx: (0..n * n).map(|k| k % n).collect(),
        }
    }

    /// The matrix's size n.
    pub fn n(&self) -> usize {
        self.n
    }

    /// The number of possibly nonzero entries.
    pub fn nnz(&self) -> usize {
        self.row_idx.len()
    }

    /// nnz / n² (1 for n = 0).
    pub fn density(&self) -> f64 {
        if self.n == 0 {
            1.0
        } else {
            self.nnz() as f64 / (self.n * self.n) as f64
        }
    }

    /// Column pointers (n + 1).
    pub fn col_ptr(&self) -> &[usize] {
        &self.col_ptr
    }

    /// Row of each entry, column by column.
    pub fn row_idx(&self) -> &[usize] {
        &self.row_idx
    }

    /// The rows of column `c`'s entries, ascending.
    pub fn rows_of(&self, c: usize) -> &[usize] {
        &self.row_idx[self.col_ptr[c]..self.col_ptr[c + 1]]
    }

    /// The position of entry (`row`, `col`) among the values, if it is in
    /// the pattern.
    pub fn position(&self, row: usize, col: usize) -> Option<usize> {
        if col >= self.n {
            return None;
        }
        let start = self.col_ptr[col];
        self.rows_of(col)
            .binary_search(&row)
            .ok()
            .map(|k| start + k)
    }

    /// The entries (row, column) in the order of the values.
    pub fn entries(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        (0..self.n).flat_map(move |c| self.rows_of(c).iter().map(move |&r| (r, c)))
    }

    /// The same pattern with the whole diagonal added.
    pub fn with_diagonal(&self) -> Self {
        Self::new(self.n, self.entries().chain((0..self.n).map(|i| (i, i))))
            .expect("the entries are in range")
    }

    /// Columns in groups that share no row (Curtis, Powell & Reid's greedy
    /// grouping, columns in order, each into the first group it fits):
    /// one evaluation of f with all columns of a group perturbed gives
    /// each column's entries. Returns the columns group by group and the
    /// group pointers (`cols[ptr[g]..ptr[g + 1]]`).
    pub fn column_groups(&self) -> (Vec<usize>, Vec<usize>) {
        let n = self.n;
        // Rows → columns, to find the groups a column's rows are used by.
        let mut row_ptr = vec![0usize; n + 1];
        for &r in &self.row_idx {
            row_ptr[r + 1] += 1;
        }
        for r in 0..n {
            row_ptr[r + 1] += row_ptr[r];
        }
        let mut fill = row_ptr.clone();
        let mut row_cols = vec![0usize; self.nnz()];
        for c in 0..n {
            for &r in self.rows_of(c) {
                row_cols[fill[r]] = c;
                fill[r] += 1;
            }
        }
        let mut group = vec![usize::MAX; n];
        // `taken[g] == c`: group g already has a column sharing a row with c.
        let mut taken: Vec<usize> = Vec::new();
        let mut groups = 0;
        for c in 0..n {
            for &r in self.rows_of(c) {
                for &other in &row_cols[row_ptr[r]..row_ptr[r + 1]] {
                    let g = group[other];
                    if g != usize::MAX {
                        taken[g] = c;
                    }
                }
            }
            let g = (0..groups).find(|&g| taken[g] != c).unwrap_or_else(|| {
                groups += 1;
                taken.push(usize::MAX);
                groups - 1
            });
            group[c] = g;
        }
        let mut ptr = vec![0usize; groups + 1];
        for &g in &group {
            ptr[g + 1] += 1;
        }
        for g in 0..groups {
            ptr[g + 1] += ptr[g];
        }
        let mut at = ptr.clone();
        let mut cols = vec![0usize; n];
        for (c, &g) in group.iter().enumerate() {
            cols[at[g]] = c;
            at[g] += 1;
        }
        (cols, ptr)
    }

    /// The density of the LU factors of a matrix of this pattern plus its
    /// diagonal, estimated by the symbolic Cholesky factorization of the
    /// symmetrized pattern under a minimum-degree ordering (faer's
    /// analysis): (2·nnz(L) − n) / n², the fill of a factorization that
    /// pivots on the diagonal, as the Newton matrices `μI − J` of stiff
    /// flows mostly do. `None` if the analysis fails.
    pub fn estimated_factor_density(&self) -> Option<f64> {
        let n = self.n;
        if n == 0 {
            return Some(1.0);
        }
        let upper = Self::new(
            n,
            self.entries()
                .map(|(r, c)| (r.min(c), r.max(c)))
                .chain((0..n).map(|i| (i, i))),
        )
        .expect("the entries are in range");
        let sym = SymbolicSparseColMat::new_checked(n, n, upper.col_ptr, None, upper.row_idx);
        let params = CholeskySymbolicParams {
            supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SIMPLICIAL,
            ..Default::default()
        };
        let chol = factorize_symbolic_cholesky(
            sym.as_ref(),
            faer::Side::Upper,
            SymmetricOrdering::Amd,
            params,
        )
        .ok()?;
        Some((2 * chol.len_val() - n) as f64 / (n * n) as f64)
    }
}

/// The sparse LU is used under [`LinearSolver::Auto`] from this many states
/// on (below it the dense elimination, which skips zero multipliers, is as
/// fast or faster: BENCHMARKS.md, "Sparse Jacobians").
pub const SPARSE_MIN_STATES: usize = 32;

/// ... and when the LU factors' estimated density
/// ([`SparsityPattern::estimated_factor_density`]) is at most this: beyond
/// it the fill-in makes the sparse factorization slower than the dense one.
pub const SPARSE_MAX_FACTOR_DENSITY: f64 = 0.2;

/// Whether the implicit solvers factorize their Newton matrices as sparse
/// matrices of `pattern` (n states) under `mode`: [`LinearSolver::Dense`]
/// never, [`LinearSolver::Sparse`] whenever there is a pattern,
/// [`LinearSolver::Auto`] when n ≥ [`SPARSE_MIN_STATES`] and the factors'
/// estimated density is at most [`SPARSE_MAX_FACTOR_DENSITY`].
pub fn use_sparse_lu(pattern: Option<&SparsityPattern>, mode: LinearSolver) -> bool {
    let Some(p) = pattern else {
        return false;
    };
    match mode {
        LinearSolver::Dense => false,
        LinearSolver::Sparse => true,
        LinearSolver::Auto => {
            p.n() >= SPARSE_MIN_STATES
                && p.density() <= SPARSE_MAX_FACTOR_DENSITY
                && p.estimated_factor_density()
                    .is_some_and(|d| d <= SPARSE_MAX_FACTOR_DENSITY)
        }
    }
}

/// The system's pattern, checked against its dimension.
pub(crate) fn system_pattern<S: HybridSystem + ?Sized>(
    sys: &S,
) -> Result<Option<Arc<SparsityPattern>>, SimError> {
    let n = sys.state_dim();
    match sys.jacobian_pattern() {
        Some(p) if p.n() != n => Err(SimError::InvalidSystem {
            what: format!(
                "jacobian_pattern is {}×{} but the state has {n} components",
                p.n(),
                p.n()
            ),
        }),
        p => Ok(p.map(Arc::new)),
    }
}

/// How the engine evaluates the Jacobian for the implicit solvers: the
/// system's dense [`jacobian`](super::HybridSystem::jacobian) (no pattern),
/// or the entries of its pattern, from
/// [`jacobian_values`](super::HybridSystem::jacobian_values) or by finite
/// differences of grouped columns (buffers kept: no allocation).
pub(crate) enum JacobianEval {
    Dense,
    Pattern {
        pattern: Arc<SparsityPattern>,
        /// Column groups ([`SparsityPattern::column_groups`]).
        cols: Vec<usize>,
        ptr: Vec<usize>,
        xp: Vec<f64>,
        f0: Vec<f64>,
        f1: Vec<f64>,
    },
}

impl JacobianEval {
    pub fn new(pattern: Option<Arc<SparsityPattern>>) -> Self {
        match pattern {
            None => Self::Dense,
            Some(pattern) => {
                let n = pattern.n();
                let (cols, ptr) = pattern.column_groups();
                Self::Pattern {
                    pattern,
                    cols,
                    ptr,
                    xp: vec![0.0; n],
                    f0: vec![0.0; n],
                    f1: vec![0.0; n],
                }
            }
        }
    }

    /// The length of [`eval`](Self::eval)'s output for `n` states.
    pub fn len(&self, n: usize) -> usize {
        match self {
            Self::Dense => n * n,
            Self::Pattern { pattern, .. } => pattern.row_idx.len(),
        }
    }

    /// Writes ∂f/∂x at (`at`, `x`) into `out`: n×n row-major without a
    /// pattern, the pattern's entries with one.
    pub fn eval<S: HybridSystem + ?Sized>(
        &mut self,
        sys: &S,
        at: HybridTime,
        x: &[f64],
        out: &mut [f64],
    ) {
        match self {
            Self::Dense => sys.jacobian(at, x, out),
            Self::Pattern {
                pattern,
                cols,
                ptr,
                xp,
                f0,
                f1,
            } => {
                if sys.jacobian_values(at, x, out) {
                    return;
                }
                // Forward differences, δ_c = √ε·max(|x_c|, 1) as
                // `finite_difference_jacobian`, one evaluation per group.
                sys.flow_map(at, x, f0);
                xp.copy_from_slice(x);
                for g in 0..ptr.len() - 1 {
                    let group = &cols[ptr[g]..ptr[g + 1]];
                    for &c in group {
                        xp[c] = x[c] + f64::EPSILON.sqrt() * x[c].abs().max(1.0);
                    }
                    sys.flow_map(at, xp, f1);
                    for &c in group {
                        // The step actually taken (rounding of x + δ).
                        let delta = xp[c] - x[c];
                        let range = pattern.col_ptr[c]..pattern.col_ptr[c + 1];
                        for (o, &r) in out[range.clone()].iter_mut().zip(&pattern.row_idx[range]) {
                            *o = (f1[r] - f0[r]) / delta;
                        }
                        xp[c] = x[c];
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patterns_sort_dedup_and_check_their_entries() {
        let p = SparsityPattern::new(3, [(2, 0), (0, 0), (2, 0), (1, 2)]).unwrap();
        assert_eq!(p.col_ptr(), &[0, 2, 2, 3]);
        assert_eq!(p.row_idx(), &[0, 2, 1]);
        assert_eq!(p.position(2, 0), Some(1));
        assert_eq!(p.position(1, 1), None);
        assert_eq!(p.entries().collect::<Vec<_>>(), [(0, 0), (2, 0), (1, 2)]);
        assert_eq!(
            SparsityPattern::new(2, [(0, 2)]),
            Err(PatternError {
                row: 0,
                col: 2,
                n: 2
            })
        );
        let d = p.with_diagonal();
        assert_eq!(d.nnz(), 5);
        assert_eq!(SparsityPattern::dense(3).nnz(), 9);
        assert_eq!(SparsityPattern::dense(3).position(2, 1), Some(5));
    }

    /// A tridiagonal pattern needs 3 groups whatever n; no two columns of
    /// a group share a row; a dense one needs n.
    #[test]
    fn column_groups_share_no_row() {
        for n in [1, 2, 5, 40] {
            let p = SparsityPattern::new(
                n,
                (0..n).flat_map(|i| [(i, i), (i, (i + 1).min(n - 1)), ((i + 1).min(n - 1), i)]),
            )
            .unwrap();
            let (cols, ptr) = p.column_groups();
            let mut seen = cols.clone();
            seen.sort_unstable();
            assert_eq!(seen, (0..n).collect::<Vec<_>>());
            assert_eq!(ptr.len() - 1, n.min(3), "n = {n}");
            for g in 0..ptr.len() - 1 {
                let mut rows: Vec<usize> = cols[ptr[g]..ptr[g + 1]]
                    .iter()
                    .flat_map(|&c| p.rows_of(c).to_vec())
                    .collect();
                let len = rows.len();
                rows.sort_unstable();
                rows.dedup();
                assert_eq!(rows.len(), len, "n = {n}: group {g} shares a row");
            }
        }
        assert_eq!(SparsityPattern::dense(6).column_groups().1.len() - 1, 6);
    }

    /// f_i = sin(x_{i−1}) + x_i² − 3 x_{i+1} (a chain): its Jacobian by
    /// grouped differences (1 + 3 evaluations for any n), and the exact one
    /// when the system gives its values.
    struct Chain {
        n: usize,
        evals: std::cell::Cell<u32>,
        exact: bool,
    }

    impl HybridSystem for Chain {
        fn state_dim(&self) -> usize {
            self.n
        }
        fn state_names(&self) -> Vec<String> {
            (0..self.n).map(|i| format!("x{i}")).collect()
        }
        fn flow_map(&self, _at: HybridTime, x: &[f64], dx: &mut [f64]) {
            self.evals.set(self.evals.get() + 1);
            for i in 0..self.n {
                let left = if i > 0 { x[i - 1].sin() } else { 0.0 };
                let right = if i + 1 < self.n { x[i + 1] } else { 0.0 };
                dx[i] = left + x[i] * x[i] - 3.0 * right;
            }
        }
        fn jump_rules(&self) -> &[crate::engine::JumpRule] {
            &[]
        }
        fn jump_set(&self, _: usize, _: HybridTime, _: &[f64]) -> bool {
            false
        }
        fn jump_guard(&self, _: usize, _: HybridTime, _: &[f64]) -> f64 {
            -1.0
        }
        fn jump_map(
            &self,
            _: usize,
            _: HybridTime,
            _: &[f64],
            _: &mut crate::engine::SimRng,
            _: &mut [f64],
        ) {
        }
        fn jacobian_pattern(&self) -> Option<SparsityPattern> {
            SparsityPattern::new(
                self.n,
                (0..self.n).flat_map(|i| {
                    [
                        (i, i),
                        (i, (i + 1).min(self.n - 1)),
                        ((i + 1).min(self.n - 1), i),
                    ]
                }),
            )
            .ok()
        }
        fn jacobian_values(&self, _at: HybridTime, x: &[f64], values: &mut [f64]) -> bool {
            if self.exact {
                let p = self.jacobian_pattern().unwrap();
                for (k, (r, c)) in p.entries().enumerate() {
                    values[k] = exact(r, c, x);
                }
            }
            self.exact
        }
    }

    fn exact(r: usize, c: usize, x: &[f64]) -> f64 {
        if r == c {
            2.0 * x[c]
        } else if c + 1 == r {
            x[c].cos()
        } else {
            -3.0
        }
    }

    #[test]
    fn grouped_differences_match_the_exact_jacobian() {
        for exact_values in [false, true] {
            let sys = Chain {
                n: 30,
                evals: std::cell::Cell::new(0),
                exact: exact_values,
            };
            let p = Arc::new(sys.jacobian_pattern().unwrap());
            let mut eval = JacobianEval::new(Some(p.clone()));
            let x: Vec<f64> = (0..30).map(|i| (i as f64 * 0.7).cos() * 2.0).collect();
            let mut out = vec![0.0; p.nnz()];
            eval.eval(&sys, HybridTime::new(0.0, 0), &x, &mut out);
            assert_eq!(sys.evals.get(), if exact_values { 0 } else { 4 });
            for (k, (r, c)) in p.entries().enumerate() {
                let want = exact(r, c, &x);
                let tol = if exact_values {
                    0.0
                } else {
                    1e-6 * want.abs().max(1.0)
                };
                assert!(
                    (out[k] - want).abs() <= tol,
                    "({r}, {c}): {} vs {want}",
                    out[k]
                );
            }
        }
    }

    /// The fill estimate: none for a chain, all for an arrow pointing the
    /// wrong way is avoided by the ordering, a dense pattern is dense.
    #[test]
    fn factor_density_estimate() {
        let n = 100;
        let chain =
            SparsityPattern::new(n, (0..n - 1).flat_map(|i| [(i, i + 1), (i + 1, i)])).unwrap();
        let d = chain.estimated_factor_density().unwrap();
        assert!(
            (d - (3 * n - 2) as f64 / (n * n) as f64).abs() < 1e-12,
            "{d}"
        );
        // An arrow (first row and column full): the ordering eliminates the
        // hub last, so no fill.
        let arrow = SparsityPattern::new(n, (1..n).flat_map(|i| [(0, i), (i, 0)])).unwrap();
        assert!(arrow.estimated_factor_density().unwrap() < 0.03);
        assert_eq!(
            SparsityPattern::dense(8).estimated_factor_density(),
            Some(1.0)
        );
        assert!(use_sparse_lu(Some(&chain), LinearSolver::Auto));
        assert!(!use_sparse_lu(Some(&chain), LinearSolver::Dense));
        assert!(!use_sparse_lu(
            Some(&SparsityPattern::dense(40)),
            LinearSolver::Auto
        ));
        assert!(use_sparse_lu(
            Some(&SparsityPattern::dense(4)),
            LinearSolver::Sparse
        ));
        assert!(!use_sparse_lu(None, LinearSolver::Sparse));
        let small = SparsityPattern::new(8, (0..8).map(|i| (i, i))).unwrap();
        assert!(!use_sparse_lu(Some(&small), LinearSolver::Auto));
    }
}
