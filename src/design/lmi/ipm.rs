//! hybsim's own primal–dual interior-point method for the block-diagonal SDPs of
//! [`super::Problem`], built on the Schur complement of the decision variables.
//!
//! Why a second solver: clarabel factors a KKT system in which every PSD cone of size d is a
//! dense block of size d(d+1)/2 and the blocks fill in across cones through the shared
//! variables; for the 20-vehicle platoon (21 blocks of 78×78, 2 380 variables) that is tens of
//! GB and hours. The Schur-complement approach of SDPT3, SDPA and CSDP instead eliminates the
//! matrix blocks analytically and factors one dense m×m matrix (m = number of scalar variables),
//! so memory is O(m² + Σ d²) and the cost per iteration is forming that matrix plus one Cholesky.
//!
//! The conic program is the one [`super::Problem`] assembles for clarabel ([`Conic`]):
//! minimize qᵀx subject to b − A x ∈ {0}^{m₀} × S₊^{d₁} × … in svec coordinates. Per block k,
//! S_k = C_k − A_k(x) with C_k = smat(b_k) and A_k(x) = Σᵢ xᵢ A_ki, A_ki = smat(column i).
//! The dual is maximize −b₀ᵀw − Σ⟨C_k, Z_k⟩ subject to A₀ᵀw + Σ A_kᵀ(Z_k) + q = 0, Z_k ⪰ 0.
//!
//! Method: infeasible-start path following with the HKM search direction and Mehrotra's
//! predictor–corrector (one factorization, two solves per iteration), separate primal and dual
//! step lengths. The Schur matrix is M_ij = Σ_k ⟨A_ki, S_k⁻¹ A_kj Z_k⟩, formed per block from the
//! sparse A_ki (only the rows a coefficient touches enter the dense products) in parallel over
//! blocks. Equality rows are kept as a saddle point solved through the Schur complement
//! A₀ M⁻¹ A₀ᵀ. Infeasibility and unboundedness are detected from the iterates' certificates
//! (‖Aᵀz‖ ≪ −bᵀz, resp. a diverging qᵀx with bounded residuals).

use std::borrow::Cow;
use std::time::Instant;

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::SolverStatus;
use super::kron::{self, KronVar};
use super::solve::{Conic, smat};

/// What the interior-point method returns (in the units of the conic program it was given).
pub(crate) struct IpmResult {
    pub status: SolverStatus,
    pub x: Vec<f64>,
    pub iterations: u32,
    pub solve_time: f64,
    /// Relative primal infeasibility ‖b − Ax − s‖/(1 + ‖b‖).
    pub r_prim: f64,
    /// Relative dual infeasibility ‖Aᵀz + q‖/(1 + ‖q‖).
    pub r_dual: f64,
}

/// Options of one run.
pub(crate) struct IpmOptions {
    pub tol: f64,
    pub max_iter: u32,
    pub verbose: bool,
    /// The point only sets the scaling of a second solve: stop once it is primal feasible
    /// with a relative gap below [`SCALING_GAP`] (reported as [`SolverStatus::AlmostSolved`]).
    pub scaling_only: bool,
}

/// Relative gap at which a scaling-only solve stops (its magnitudes are then settled).
const SCALING_GAP: f64 = 5e-2;

/// Relative accuracy of an infeasibility or unboundedness certificate: ‖Aᵀz‖ ≤ ε·(−bᵀz), resp.
/// ‖b − (Ax + s)‖ ≤ ε·(−qᵀx). Looser than the optimality tolerance because a diverging iterate
/// carries the rounding of its own size (the data are normalized, so a feasible, bounded problem
/// would need an optimal value near 1/ε to trigger it).
const INFEAS_TOL: f64 = 1e-7;

/// One PSD block (d = 1 is a nonnegative scalar) with its data in matrix form.
struct Block {
    d: usize,
    /// C_k = smat(b_k).
    c: DMatrix<f64>,
    /// Global indices of the variables that appear in the block, increasing.
    vars: Vec<usize>,
    /// Per local variable: the upper-triangle entries (row ≤ col, value) of A_ki.
    coefs: Vec<Vec<(usize, usize, f64)>>,
    /// Per local variable: the rows its coefficient touches (sorted, distinct).
    rows: Vec<Vec<usize>>,
    /// All coefficients by position for ⟨A_ki, G⟩ = Σ a·(G + Gᵀ)[p]: for each column-major
    /// position p of a d×d matrix, `by_pos[pos_start[p]..pos_start[p + 1]]` lists (local
    /// variable, value halved on the diagonal), variables increasing.
    by_pos: Vec<(usize, f64)>,
    pos_start: Vec<usize>,
    /// The matrix variables whose Schur entries come from the Kronecker formula ([`kron`]).
    kron: Vec<KronVar>,
    /// Per local variable: whether it belongs to one of `kron`.
    structured: Vec<bool>,
}

impl Block {
    /// A_k(x) = Σ xᵢ A_ki.
    fn apply(&self, x: &[f64]) -> DMatrix<f64> {
        let mut out = DMatrix::zeros(self.d, self.d);
        for (li, &g) in self.vars.iter().enumerate() {
            let xi = x[g];
            if xi == 0.0 {
                continue;
            }
            for &(r, c, v) in &self.coefs[li] {
                out[(r, c)] += xi * v;
                if r != c {
                    out[(c, r)] += xi * v;
                }
            }
        }
        out
    }

    /// ⟨A_ki, Y⟩ for local variable li (Y need not be symmetric).
    fn inner(&self, li: usize, y: &DMatrix<f64>) -> f64 {
        self.coefs[li]
            .iter()
            .map(|&(r, c, v)| {
                if r == c {
                    v * y[(r, r)]
                } else {
                    v * (y[(r, c)] + y[(c, r)])
                }
            })
            .sum()
    }

    /// Adds A_kᵀ(Y) into `out` (global indexing).
    fn adjoint_into(&self, y: &DMatrix<f64>, out: &mut [f64]) {
        for (li, &g) in self.vars.iter().enumerate() {
            out[g] += self.inner(li, y);
        }
    }

    /// Adds this block's part of the Schur matrix, M_ij += ⟨A_ki, S⁻¹ A_kj Z⟩, into the lower
    /// triangle of `m`.
    fn add_schur(&self, sinv: &DMatrix<f64>, z: &DMatrix<f64>, m: &mut DMatrix<f64>) {
        let zl: Vec<Vec<DMatrix<f64>>> = self
            .kron
            .iter()
            .map(|v| kron::left_products(v, z))
            .collect();
        let sl: Vec<Vec<DMatrix<f64>>> = self
            .kron
            .iter()
            .map(|v| kron::left_products(v, sinv))
            .collect();
        // The variables are in increasing order: the earlier one of a pair gives the columns.
        for (a, va) in self.kron.iter().enumerate() {
            for (b, vb) in self.kron.iter().enumerate().skip(a) {
                kron::add_pair(va, vb, a == b, &zl[a], &sl[b], m);
            }
        }
        let d = self.d;
        let n = m.nrows();
        let nv = self.vars.len();
        let sparse: Vec<usize> = (0..nv).filter(|&li| !self.structured[li]).collect();
        if sparse.is_empty() {
            return;
        }
        let mixed = !self.kron.is_empty();
        let mut w = DMatrix::<f64>::zeros(d, d);
        // (G + Gᵀ) of SCHUR_BATCH variables side by side: row p (a column-major position in
        // d×d) holds the batch contiguously, so ⟨A_ki, ·⟩ over the batch is a vectorizable
        // axpy per coefficient of A_ki instead of a gather per (i, j) pair.
        let mut gs = vec![0.0; d * d * SCHUR_BATCH];
        let mut acc = vec![0.0; nv * SCHUR_BATCH];
        for batch in sparse.chunks(SCHUR_BATCH) {
            let width = batch.len();
            for (jb, &lj) in batch.iter().enumerate() {
                let rows = &self.rows[lj];
                // W = Z A_kj, nonzero only in the columns `rows` (column-major friendly).
                for &r in rows {
                    w.column_mut(r).fill(0.0);
                }
                for &(r, c, v) in &self.coefs[lj] {
                    w.column_mut(c).axpy(v, &z.column(r), 1.0);
                    if r != c {
                        w.column_mut(r).axpy(v, &z.column(c), 1.0);
                    }
                }
                // G = W S⁻¹ = W[:, rows] S⁻¹[rows, :] = (S⁻¹ A_kj Z)ᵀ; ⟨A_ki, ·⟩ is the same
                // for both, and equals ⟨A_ki, G + Gᵀ⟩/2 (the halved diagonal is in flat_val).
                let g = if rows.len() == d {
                    &w * sinv
                } else {
                    w.select_columns(rows.iter()) * sinv.select_rows(rows.iter())
                };
                for c in 0..d {
                    for r in 0..d {
                        gs[(r + c * d) * SCHUR_BATCH + jb] = g[(r, c)] + g[(c, r)];
                    }
                }
            }
            // M[i, batch] for every i up to the batch's last variable (M is symmetric; with
            // structured variables, which only meet the others here, every i), streaming
            // through the positions p once: each row of `gs` is read once and scattered into the
            // accumulators of the variables with a coefficient at p.
            let limit = if mixed { nv } else { batch[width - 1] + 1 };
            acc[..limit * SCHUR_BATCH].fill(0.0);
            for p in 0..d * d {
                let row = &gs[p * SCHUR_BATCH..(p + 1) * SCHUR_BATCH];
                for &(li, a) in &self.by_pos[self.pos_start[p]..self.pos_start[p + 1]] {
                    if li >= limit {
                        break;
                    }
                    let dst = &mut acc[li * SCHUR_BATCH..(li + 1) * SCHUR_BATCH];
                    for (x, g) in dst.iter_mut().zip(row) {
                        *x += a * g;
                    }
                }
            }
            // Lower triangle only: column min(gi, gj), row max(gi, gj); the Cholesky reads no
            // more. Pairs of unstructured variables once (li ≤ lj), with structured ones always.
            let ms = m.as_mut_slice();
            for li in 0..limit {
                let gi = self.vars[li];
                let row = &acc[li * SCHUR_BATCH..(li + 1) * SCHUR_BATCH];
                for (&v, &lj) in row.iter().zip(batch) {
                    if self.structured[li] || li <= lj {
                        let gj = self.vars[lj];
                        ms[gi.min(gj) * n + gi.max(gj)] += v;
                    }
                }
            }
        }
    }

    /// Rough flop count of [`Block::add_schur`], for balancing the parallel work: the products
    /// G = W S⁻¹ plus the inner products (about half of the variables per coefficient).
    fn schur_cost(&self) -> usize {
        let sparse = self.structured.iter().filter(|s| !**s).count();
        let mut cost = self
            .rows
            .iter()
            .zip(&self.structured)
            .filter(|(_, s)| !**s)
            .map(|(r, _)| 2 * self.d * self.d * r.len())
            .sum::<usize>()
            + sparse * self.by_pos.len() / 2;
        for (a, va) in self.kron.iter().enumerate() {
            for vb in &self.kron[..=a] {
                cost += va.pair_cost(vb);
            }
        }
        cost
    }
}

/// Variables per batch of the Schur-matrix inner products ([`Block::add_schur`]).
const SCHUR_BATCH: usize = 32;

/// Groups of blocks whose Schur parts are formed in parallel (each its own m×m matrix) and then
/// added in group order. Independent of the thread count so that M's rounding is too; 4 keeps
/// the extra memory at 3 m² doubles while using 4 cores.
const SCHUR_GROUPS: usize = 4;

/// Reduced-accuracy thresholds (clarabel's defaults): a run that stops early with its best
/// iterate within these is [`SolverStatus::AlmostSolved`].
const REDUCED_FEAS: f64 = 1e-4;
const REDUCED_GAP: f64 = 5e-5;

/// The best iterate so far (smallest max of the relative residuals and gap).
struct Best {
    merit: f64,
    x: DVector<f64>,
    r_prim: f64,
    r_dual: f64,
    gap: f64,
}

/// Iterations without a 10 % improvement of the best merit after which the method stops.
const STALL_ITERS: u32 = 8;

/// Refinement steps of each Newton solve.
const REFINE_STEPS: usize = 2;

/// out += sign·Σ_k A_kᵀ(Y_k) for per-block matrices computed in parallel by `y`, added block by
/// block in order (the same rounding as a sequential loop, whatever the thread schedule).
fn adjoint_add<'a, F>(blocks: &[Block], out: &mut DVector<f64>, sign: f64, y: F)
where
    F: Fn(usize) -> Cow<'a, DMatrix<f64>> + Sync,
{
    let n = out.len();
    let parts: Vec<Vec<f64>> = (0..blocks.len())
        .into_par_iter()
        .map(|k| {
            let mut part = vec![0.0; n];
            blocks[k].adjoint_into(&y(k), &mut part);
            part
        })
        .collect();
    for part in parts {
        for (o, p) in out.iter_mut().zip(part) {
            *o += sign * p;
        }
    }
}

/// Σ_k A_kᵀ(S_k⁻¹ A_k(v) Z_k): the Schur operator applied block by block (no rounding of M).
fn schur_apply(
    blocks: &[Block],
    sinv: &[DMatrix<f64>],
    z: &[DMatrix<f64>],
    v: &DVector<f64>,
) -> DVector<f64> {
    let mut out = DVector::zeros(v.len());
    adjoint_add(blocks, &mut out, 1.0, |k| {
        Cow::Owned(&sinv[k] * blocks[k].apply(v.as_slice()) * &z[k])
    });
    out
}

/// The largest α ≥ 0 with X + α ΔX ⪰ 0 (∞ if ΔX does not decrease λ_min), given chol(X) = L Lᵀ.
fn max_step(l: &DMatrix<f64>, dx: &DMatrix<f64>) -> f64 {
    if l.nrows() == 1 {
        let ratio = dx[(0, 0)] / (l[(0, 0)] * l[(0, 0)]);
        return if ratio < 0.0 {
            -1.0 / ratio
        } else {
            f64::INFINITY
        };
    }
    // λ_min(L⁻¹ ΔX L⁻ᵀ)
    let Some(a) = l.solve_lower_triangular(dx) else {
        return 0.0;
    };
    let Some(b) = l.solve_lower_triangular(&a.transpose()) else {
        return 0.0;
    };
    let b = (&b + b.transpose()) * 0.5;
    // Non-finite: no step (as when L is singular).
    let Some(eig) = crate::linalg::symmetric_eigenvalues(&b) else {
        return 0.0;
    };
    let lmin = eig.iter().fold(f64::INFINITY, |m, v| m.min(*v));
    if lmin < 0.0 {
        -1.0 / lmin
    } else {
        f64::INFINITY
    }
}

fn sym(a: &DMatrix<f64>) -> DMatrix<f64> {
    (a + a.transpose()) * 0.5
}

/// svec row t of a block → (row, col) of the upper triangle (column by column).
fn svec_pos(t: usize) -> (usize, usize) {
    let mut col = ((((8 * t + 1) as f64).sqrt() - 1.0) / 2.0) as usize;
    while col * (col + 1) / 2 > t {
        col -= 1;
    }
    while (col + 1) * (col + 2) / 2 <= t {
        col += 1;
    }
    (t - col * (col + 1) / 2, col)
}

/// The blocks of a conic program in matrix form, plus the dense equality rows A₀ (m₀ × n).
fn split(conic: &Conic) -> (Vec<Block>, DMatrix<f64>) {
    let n = conic.n;
    let m0 = conic.zero_rows;
    let mut offsets = Vec::with_capacity(conic.blocks.len());
    let mut o = m0;
    for &d in &conic.blocks {
        offsets.push(o);
        o += d * (d + 1) / 2;
    }
    let mut blocks: Vec<Block> = conic
        .blocks
        .iter()
        .zip(&offsets)
        .map(|(&d, &o)| {
            // C_k = smat(b_k): the svec rows always have a triangular length.
            let c = smat(&conic.b[o..o + d * (d + 1) / 2]).unwrap_or_else(|| DMatrix::zeros(d, d));
            Block {
                d,
                c,
                vars: Vec::new(),
                coefs: Vec::new(),
                rows: Vec::new(),
                by_pos: Vec::new(),
                pos_start: Vec::new(),
                kron: Vec::new(),
                structured: Vec::new(),
            }
        })
        .collect();
    let mut a0 = DMatrix::zeros(m0, n);
    let a = &conic.a;
    for j in 0..n {
        for k in a.colptr[j]..a.colptr[j + 1] {
            let row = a.rowval[k];
            let v = a.nzval[k];
            if row < m0 {
                a0[(row, j)] += v;
                continue;
            }
            let b = offsets.partition_point(|&o| o <= row) - 1;
            let (r, c) = svec_pos(row - offsets[b]);
            let val = if r == c {
                v
            } else {
                v * std::f64::consts::FRAC_1_SQRT_2
            };
            let blk = &mut blocks[b];
            if blk.vars.last() != Some(&j) {
                blk.vars.push(j);
                blk.coefs.push(Vec::new());
            }
            if let Some(last) = blk.coefs.last_mut() {
                last.push((r, c, val));
            }
        }
    }
    for (blk, terms) in blocks.iter_mut().zip(&conic.structure) {
        blk.kron = terms
            .as_deref()
            .map(KronVar::from_terms)
            .unwrap_or_default();
        blk.structured = blk
            .vars
            .iter()
            .map(|g| blk.kron.iter().any(|v| v.range.contains(g)))
            .collect();
        let dd = blk.d * blk.d;
        let mut count = vec![0usize; dd + 1];
        for cs in &blk.coefs {
            for &(r, c, _) in cs {
                count[r + c * blk.d + 1] += 1;
            }
        }
        for p in 0..dd {
            count[p + 1] += count[p];
        }
        let mut fill = count.clone();
        blk.by_pos = vec![(0, 0.0); count[dd]];
        for (li, cs) in blk.coefs.iter().enumerate() {
            for &(r, c, v) in cs {
                let p = r + c * blk.d;
                blk.by_pos[fill[p]] = (li, if r == c { 0.5 * v } else { v });
                fill[p] += 1;
            }
        }
        blk.pos_start = count;
        blk.rows = blk
            .coefs
            .iter()
            .map(|cs| {
                let mut rows: Vec<usize> = cs.iter().flat_map(|&(r, c, _)| [r, c]).collect();
                rows.sort_unstable();
                rows.dedup();
                rows
            })
            .collect();
    }
    (blocks, a0)
}

/// A dense Cholesky factorization through LAPACK (`dpotrf`/`dpotrs`).
struct Chol {
    n: usize,
    /// The factor in the lower triangle, column-major.
    l: Vec<f64>,
}

impl Chol {
    /// Factors a symmetric positive definite matrix (lower triangle read), or `None`.
    fn new(a: &DMatrix<f64>) -> Option<Chol> {
        let n = a.nrows();
        let mut l = a.as_slice().to_vec();
        let mut info = 0;
        // SAFETY: `l` holds n·n column-major entries with leading dimension n.
        unsafe { lapack::dpotrf(b'L', n as i32, &mut l, n.max(1) as i32, &mut info) };
        (info == 0).then_some(Chol { n, l })
    }

    /// A⁻¹ B for a matrix B with n rows.
    fn solve(&self, b: &DMatrix<f64>) -> DMatrix<f64> {
        let mut x = b.clone();
        let nrhs = b.ncols();
        if self.n == 0 || nrhs == 0 {
            return x;
        }
        let mut info = 0;
        // SAFETY: `l` is an n×n factor from dpotrf, `x` is n×nrhs column-major.
        unsafe {
            lapack::dpotrs(
                b'L',
                self.n as i32,
                nrhs as i32,
                &self.l,
                self.n as i32,
                x.as_mut_slice(),
                self.n as i32,
                &mut info,
            )
        };
        x
    }

    fn solve_vec(&self, b: &DVector<f64>) -> DVector<f64> {
        let x = self.solve(&DMatrix::from_column_slice(b.len(), 1, b.as_slice()));
        DVector::from_column_slice(x.as_slice())
    }
}

/// Factors a symmetric positive semidefinite matrix, adding the smallest diagonal shift (from
/// 1e-13 of its largest diagonal entry, up to 1e-4) that makes it numerically definite.
fn factor_shifted(mut m: DMatrix<f64>) -> Option<Chol> {
    let n = m.nrows();
    let scale = (0..n)
        .fold(0.0f64, |s, i| s.max(m[(i, i)].abs()))
        .max(1e-300);
    // A variable in no block has a zero row: a tiny shift keeps the factorization defined
    // (its step then comes from the equality rows or is zero).
    for i in 0..n {
        if m[(i, i)] <= 1e-14 * scale {
            m[(i, i)] += 1e-12 * scale;
        }
    }
    let mut shift = 0.0;
    loop {
        if let Some(c) = Chol::new(&m) {
            return Some(c);
        }
        let s = if shift == 0.0 {
            1e-13 * scale
        } else {
            shift * 100.0
        };
        if s > 1e-4 * scale {
            return None;
        }
        for i in 0..n {
            m[(i, i)] += s - shift;
        }
        shift = s;
    }
}

/// The factorized Newton system [[M, A₀ᵀ], [A₀, 0]].
struct Newton {
    chol: Chol,
    /// M⁻¹A₀ᵀ and the factor of A₀ M⁻¹ A₀ᵀ (absent without equality rows).
    eq: Option<(DMatrix<f64>, Chol)>,
}

impl Newton {
    fn factor(m: DMatrix<f64>, a0: &DMatrix<f64>) -> Option<Newton> {
        let chol = factor_shifted(m)?;
        let eq = if a0.nrows() > 0 {
            let minv_a0t = chol.solve(&a0.transpose());
            let k = a0 * &minv_a0t;
            Some((minv_a0t, factor_shifted(sym(&k))?))
        } else {
            None
        };
        Some(Newton { chol, eq })
    }

    /// Solves M Δx + A₀ᵀ Δw = rhs, A₀ Δx = re.
    fn solve(
        &self,
        a0: &DMatrix<f64>,
        rhs: &DVector<f64>,
        re: &DVector<f64>,
    ) -> (DVector<f64>, DVector<f64>) {
        let u = self.chol.solve_vec(rhs);
        match &self.eq {
            None => (u, DVector::zeros(0)),
            Some((minv_a0t, kchol)) => {
                // A₀ (u − M⁻¹A₀ᵀ Δw) = re  ⇒  (A₀ M⁻¹ A₀ᵀ) Δw = A₀ u − re.
                let dw = kchol.solve_vec(&(a0 * &u - re));
                let dx = u - minv_a0t * &dw;
                (dx, dw)
            }
        }
    }
}

/// Solves the conic program. Never panics on bad data: a failed factorization ends the run as
/// [`SolverStatus::NumericalError`].
pub(crate) fn solve(conic: &Conic, opts: &IpmOptions) -> IpmResult {
    let start = Instant::now();
    let n = conic.n;
    let m0 = conic.zero_rows;
    let (blocks, a0) = split(conic);
    let q = DVector::from_column_slice(&conic.q);
    let b0 = DVector::from_column_slice(&conic.b[..m0]);
    let nu: f64 = blocks.iter().map(|b| b.d as f64).sum::<f64>().max(1.0);
    let bnorm = conic.b.iter().map(|v| v * v).sum::<f64>().sqrt();
    let qnorm = q.norm();

    // Starting point (SDPT3's rule, in our primal/dual roles): S₀ = η I, Z₀ = ξ I.
    let mut x = DVector::<f64>::zeros(n);
    let mut w = DVector::<f64>::zeros(m0);
    let mut s: Vec<DMatrix<f64>> = Vec::with_capacity(blocks.len());
    let mut z: Vec<DMatrix<f64>> = Vec::with_capacity(blocks.len());
    for blk in &blocks {
        let d = blk.d as f64;
        let mut amax = 0.0f64;
        let mut xi = 0.0f64;
        for (li, &g) in blk.vars.iter().enumerate() {
            let fro = blk.coefs[li]
                .iter()
                .map(|&(r, c, v)| if r == c { v * v } else { 2.0 * v * v })
                .sum::<f64>()
                .sqrt();
            amax = amax.max(fro);
            xi = xi.max((1.0 + q[g].abs()) / (1.0 + fro));
        }
        let eta = 10f64.max(d.sqrt()).max(amax).max(blk.c.norm());
        let xi = 10f64.max(d.sqrt()).max(d * xi);
        s.push(DMatrix::identity(blk.d, blk.d) * eta);
        z.push(DMatrix::identity(blk.d, blk.d) * xi);
    }
    // Balance the Schur work over SCHUR_GROUPS contiguous groups of similar cost, summed in
    // group order: a fixed number (not the thread count), so the rounding of M, and the design,
    // is the same on every machine.
    let groups = {
        let costs: Vec<usize> = blocks.iter().map(Block::schur_cost).collect();
        let total: usize = costs.iter().sum::<usize>().max(1);
        let per = total.div_ceil(SCHUR_GROUPS);
        let mut groups: Vec<Vec<usize>> = vec![Vec::new()];
        let mut acc = 0;
        for (k, c) in costs.iter().enumerate() {
            if acc >= per && groups.len() < SCHUR_GROUPS {
                groups.push(Vec::new());
                acc = 0;
            }
            acc += c;
            if let Some(g) = groups.last_mut() {
                g.push(k);
            }
        }
        groups
    };

    // One Schur matrix per group, kept across iterations (they are large; fresh allocations
    // would page-fault every iteration).
    let mut schur_parts: Vec<DMatrix<f64>> = groups.iter().map(|_| DMatrix::zeros(n, n)).collect();
    let tol = opts.tol;
    let mut status = SolverStatus::MaxIterations;
    let mut iterations = 0;
    let mut r_prim = f64::INFINITY;
    let mut r_dual = f64::INFINITY;
    let mut stalls = 0;
    let mut best: Option<Best> = None;
    let mut best_it = 0;
    for it in 0..opts.max_iter {
        iterations = it;
        // Residuals and objectives.
        let rp: Vec<DMatrix<f64>> = blocks
            .par_iter()
            .zip(&s)
            .map(|(b, s)| &b.c - b.apply(x.as_slice()) - s)
            .collect();
        let re = &b0 - &a0 * &x;
        let mut aty = DVector::zeros(n);
        adjoint_add(&blocks, &mut aty, 1.0, |k| Cow::Borrowed(&z[k]));
        let aty = aty + a0.transpose() * &w;
        let rd = -(&q + &aty);
        let pobj = q.dot(&x);
        let dobj = -(b0.dot(&w)
            + blocks
                .iter()
                .zip(&z)
                .map(|(b, zk)| b.c.dot(zk))
                .sum::<f64>());
        let compl: f64 = s.iter().zip(&z).map(|(s, z)| s.dot(z)).sum();
        let mu = compl / nu;
        let pres = (rp.iter().map(|r| r.norm_squared()).sum::<f64>() + re.norm_squared()).sqrt();
        r_prim = pres / (1.0 + bnorm);
        r_dual = rd.norm() / (1.0 + qnorm);
        let gap = (pobj - dobj).abs() / (1.0 + pobj.abs() + dobj.abs());
        let rel_compl = compl / (1.0 + pobj.abs() + dobj.abs());
        if opts.verbose {
            eprintln!(
                "ipm {it:3} {:7.2}s pobj {pobj:+.8e}  dobj {dobj:+.8e}  pinf {r_prim:.2e}  dinf {r_dual:.2e}  gap {gap:.2e}  mu {mu:.2e}",
                start.elapsed().as_secs_f64()
            );
        }
        if !(pobj.is_finite() && dobj.is_finite() && mu.is_finite()) {
            status = SolverStatus::NumericalError;
            break;
        }
        let merit = r_prim.max(r_dual).max(gap.max(rel_compl));
        if best.as_ref().is_none_or(|b| merit < 0.9 * b.merit) {
            best = Some(Best {
                merit,
                x: x.clone(),
                r_prim,
                r_dual,
                gap: gap.max(rel_compl),
            });
            best_it = it;
        } else if it >= best_it + STALL_ITERS {
            // Rounding has stopped the progress (typically the dual residual near the
            // solution); keep the best iterate.
            status = SolverStatus::InsufficientProgress;
            break;
        }
        if r_prim <= tol && r_dual <= tol && gap.max(rel_compl) <= tol {
            status = SolverStatus::Solved;
            break;
        }
        if opts.scaling_only
            && r_prim <= 1e-6
            && r_dual <= 1e-6
            && gap.max(rel_compl) <= SCALING_GAP
        {
            status = SolverStatus::AlmostSolved;
            break;
        }
        // Certificates. Constraints infeasible: Z ⪰ 0 with ‖A₀ᵀw + ΣA_kᵀZ_k‖ ≪ −b₀ᵀw − Σ⟨C_k, Z_k⟩.
        if dobj > 0.0 && aty.norm() <= INFEAS_TOL * dobj && r_prim > REDUCED_FEAS {
            status = SolverStatus::PrimalInfeasible;
            break;
        }
        // Unbounded: qᵀx → −∞ with b − Ax − s bounded.
        let bounded = {
            let cr: f64 = blocks
                .iter()
                .zip(&rp)
                .map(|(b, r)| (&b.c - r).norm_squared())
                .sum::<f64>()
                + (&b0 - &re).norm_squared();
            cr.sqrt()
        };
        if pobj < 0.0 && bounded <= INFEAS_TOL * (-pobj) && r_dual > REDUCED_FEAS {
            status = SolverStatus::DualInfeasible;
            break;
        }

        // Factorizations: S_k = L Lᵀ, S_k⁻¹; Z_k = L Lᵀ (for step lengths).
        let factors: Option<Vec<_>> = s
            .par_iter()
            .zip(&z)
            .map(|(sk, zk)| {
                let cs = sk.clone().cholesky()?;
                let cz = zk.clone().cholesky()?;
                Some((sym(&cs.inverse()), cs.l(), cz.l()))
            })
            .collect();
        let Some(factors) = factors else {
            status = SolverStatus::NumericalError;
            break;
        };
        let (mut ls, mut lz, mut sinv) = (Vec::new(), Vec::new(), Vec::new());
        for (si, l_s, l_z) in factors {
            sinv.push(si);
            ls.push(l_s);
            lz.push(l_z);
        }
        schur_parts
            .par_iter_mut()
            .zip(&groups)
            .for_each(|(m, group)| {
                m.fill(0.0);
                for &k in group {
                    blocks[k].add_schur(&sinv[k], &z[k], m);
                }
            });
        let (schur, rest) = schur_parts.split_at_mut(1);
        for part in rest.iter() {
            schur[0] += part;
        }
        let Some(newton) = Newton::factor(schur[0].clone(), &a0) else {
            status = SolverStatus::NumericalError;
            break;
        };

        // S⁻¹ R_p Z, shared by predictor and corrector.
        let sinv_rp_z: Vec<DMatrix<f64>> = (0..blocks.len())
            .into_par_iter()
            .map(|k| &sinv[k] * &rp[k] * &z[k])
            .collect();
        // Right-hand side for a target μ and a second-order term (ΔS ΔZ of the predictor).
        let direction = |target: f64, corr: Option<&[DMatrix<f64>]>| {
            // T_k = μ S⁻¹ − Z − S⁻¹ R_p Z − S⁻¹ Corr   (its adjoint moves to the right side)
            let comp: Vec<DMatrix<f64>> = (0..blocks.len())
                .into_par_iter()
                .map(|k| {
                    let mut t = &sinv[k] * target - &z[k] - &sinv_rp_z[k];
                    if let Some(c) = corr {
                        t -= &sinv[k] * &c[k];
                    }
                    t
                })
                .collect();
            let mut rhs = rd.clone();
            adjoint_add(&blocks, &mut rhs, -1.0, |k| Cow::Borrowed(&comp[k]));
            let (mut dx, mut dw) = newton.solve(&a0, &rhs, &re);
            // Iterative refinement against the operator itself (M is ill-conditioned near the
            // solution; its rounding would otherwise come back as dual infeasibility).
            let rnorm = rhs.norm() + re.norm();
            for _ in 0..REFINE_STEPS {
                let mut r1 = &rhs - schur_apply(&blocks, &sinv, &z, &dx) - a0.transpose() * &dw;
                let r2 = &re - &a0 * &dx;
                if r1.norm() + r2.norm() <= 1e-15 * rnorm {
                    break;
                }
                r1.iter_mut()
                    .for_each(|v| *v = if v.is_finite() { *v } else { 0.0 });
                let (cx, cw) = newton.solve(&a0, &r1, &r2);
                dx += cx;
                dw += cw;
            }
            // ΔS = R_p − A(Δx);  ΔZ = sym(T + S⁻¹ A(Δx) Z)
            let (ds, dz): (Vec<DMatrix<f64>>, Vec<DMatrix<f64>>) = (0..blocks.len())
                .into_par_iter()
                .map(|k| {
                    let adx = blocks[k].apply(dx.as_slice());
                    let dzk = sym(&(&comp[k] + &sinv[k] * &adx * &z[k]));
                    (sym(&(&rp[k] - &adx)), dzk)
                })
                .unzip();
            (dx, dw, ds, dz)
        };
        let steps = |ds: &[DMatrix<f64>], dz: &[DMatrix<f64>]| {
            let (ap, ad): (Vec<f64>, Vec<f64>) = (0..blocks.len())
                .into_par_iter()
                .map(|k| (max_step(&ls[k], &ds[k]), max_step(&lz[k], &dz[k])))
                .unzip();
            (
                ap.into_iter().fold(f64::INFINITY, f64::min),
                ad.into_iter().fold(f64::INFINITY, f64::min),
            )
        };
        // Predictor (affine scaling).
        let (_, _, ds_a, dz_a) = direction(0.0, None);
        let (ap_a, ad_a) = steps(&ds_a, &dz_a);
        let (ap_a, ad_a) = (ap_a.min(1.0), ad_a.min(1.0));
        let mu_aff: f64 = (0..blocks.len())
            .map(|k| (&s[k] + &ds_a[k] * ap_a).dot(&(&z[k] + &dz_a[k] * ad_a)))
            .sum::<f64>()
            / nu;
        let expon = if ap_a.min(ad_a) > 0.5 { 3.0 } else { 2.0 };
        let sigma = if mu > 0.0 {
            (mu_aff / mu).max(0.0).powf(expon).min(1.0)
        } else {
            0.0
        };
        // Corrector.
        let corr: Vec<DMatrix<f64>> = (0..blocks.len()).map(|k| &ds_a[k] * &dz_a[k]).collect();
        let (dx, dw, ds, dz) = direction(sigma * mu, Some(&corr));
        let (ap, ad) = steps(&ds, &dz);
        let gamma = 0.9 + 0.09 * ap_a.min(ad_a);
        let ap = (gamma * ap).min(1.0);
        let ad = (gamma * ad).min(1.0);
        if !(ap.is_finite() && ad.is_finite()) {
            status = SolverStatus::NumericalError;
            break;
        }
        if ap.max(ad) < 1e-8 {
            stalls += 1;
            if stalls >= 3 {
                status = SolverStatus::InsufficientProgress;
                break;
            }
        } else {
            stalls = 0;
        }
        x += &dx * ap;
        if m0 > 0 {
            w += &dw * ad;
        }
        for k in 0..blocks.len() {
            s[k] = sym(&(&s[k] + &ds[k] * ap));
            z[k] = sym(&(&z[k] + &dz[k] * ad));
        }
        iterations = it + 1;
    }
    // Without convergence, keep the best iterate and call it almost solved if it is close
    // (clarabel's reduced tolerances).
    let mut xout = x;
    if !matches!(
        status,
        SolverStatus::Solved | SolverStatus::PrimalInfeasible | SolverStatus::DualInfeasible
    ) && let Some(b) = best
    {
        xout = b.x;
        r_prim = b.r_prim;
        r_dual = b.r_dual;
        if b.r_prim <= REDUCED_FEAS && b.r_dual <= REDUCED_FEAS && b.gap <= REDUCED_GAP {
            status = SolverStatus::AlmostSolved;
        }
    }
    IpmResult {
        status,
        x: xout.as_slice().to_vec(),
        iterations,
        solve_time: start.elapsed().as_secs_f64(),
        r_prim,
        r_dual,
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::DMatrix;

    use super::{Block, split, svec_pos};
    use crate::design::lmi::{Expr, Problem, Relation, VarKind};

    fn pseudo(r: usize, c: usize, seed: f64) -> DMatrix<f64> {
        DMatrix::from_fn(r, c, |i, j| ((i * 7 + j * 3) as f64 * 0.37 + seed).sin())
    }

    fn spd(d: usize, seed: f64) -> DMatrix<f64> {
        let b = pseudo(d, d, seed);
        &b * b.transpose() + DMatrix::identity(d, d)
    }

    /// The Schur matrix of every block, once from the Kronecker structure and once from the
    /// sparse coefficients alone, at arbitrary positive definite S⁻¹ and Z.
    fn both_ways(p: &Problem) -> Vec<(DMatrix<f64>, DMatrix<f64>, usize)> {
        let conic = p.assemble(&p.data_scaling());
        let (blocks, _) = split(&conic);
        blocks
            .iter()
            .enumerate()
            .map(|(k, b)| {
                let (sinv, z) = (spd(b.d, k as f64), spd(b.d, 10.0 + k as f64));
                let n = conic.n;
                let mut structured = DMatrix::zeros(n, n);
                b.add_schur(&sinv, &z, &mut structured);
                let plain = Block {
                    kron: Vec::new(),
                    structured: vec![false; b.vars.len()],
                    c: b.c.clone(),
                    vars: b.vars.clone(),
                    coefs: b.coefs.clone(),
                    rows: b.rows.clone(),
                    by_pos: b.by_pos.clone(),
                    pos_start: b.pos_start.clone(),
                    ..*b
                };
                let mut sparse = DMatrix::zeros(n, n);
                plain.add_schur(&sinv, &z, &mut sparse);
                (structured, sparse, b.kron.len())
            })
            .collect()
    }

    #[test]
    fn kronecker_and_sparse_schur_formulas_agree() {
        let mut p = Problem::new();
        let pv = p.add_variable("P", VarKind::Symmetric(4)).unwrap();
        let u = p.add_variable("U", VarKind::Full(4, 2)).unwrap();
        let x = p.add_variable("X", VarKind::Symmetric(3)).unwrap();
        let t = p.add_variable("t", VarKind::Scalar).unwrap();
        let (a, c, w) = (pseudo(4, 4, 1.0), pseudo(2, 4, 2.0), pseudo(2, 3, 3.0));
        let k = |e: &Expr, m: &DMatrix<f64>| e.right_mul(m).unwrap();
        // [P, (P − U C) A; *, P]
        let off = k(&pv.sub(&u.right_mul(&c).unwrap()).unwrap(), &a);
        let b1 = Expr::blocks(&[
            vec![Some(pv.clone()), Some(off.clone())],
            vec![Some(off.transpose()), Some(pv.clone())],
        ])
        .unwrap();
        p.constrain("b1", &b1, Relation::PosSemiDef).unwrap();
        // [X, (U W)ᵀ; U W, P] with a transposed full variable, plus t·I (sparse) mixed in.
        let uw = u.right_mul(&w).unwrap();
        let b2 = Expr::blocks(&[
            vec![Some(x.clone()), Some(uw.transpose())],
            vec![Some(uw), Some(pv.clone())],
        ])
        .unwrap()
        .add(&t.mul(&Expr::identity(7)).unwrap())
        .unwrap();
        p.constrain("b2", &b2, Relation::PosDef).unwrap();
        // I ⊗ P − Aᵀ P A ⪰ 0 written with Kronecker products, as ≺.
        let lyap = pv
            .kron_left(&DMatrix::identity(2, 2))
            .sub(
                &pv.left_mul(&a.transpose())
                    .unwrap()
                    .right_mul(&a)
                    .unwrap()
                    .kron_right(&DMatrix::from_element(2, 2, 0.5)),
            )
            .unwrap();
        p.constrain("b3", &lyap.neg(), Relation::NegDef).unwrap();
        // Parts of variables: one column of U, the leading 2×2 of P (partial active sets).
        let u1 = u
            .block(0, 1, 4, 1)
            .unwrap()
            .right_mul(&pseudo(1, 4, 4.0))
            .unwrap();
        let p2 = pv.block(0, 0, 2, 2).unwrap();
        let b4 = Expr::blocks(&[
            vec![Some(pv.sub(&u1).unwrap()), Some(Expr::zeros(4, 2))],
            vec![None, Some(p2.add(&x.block(1, 1, 2, 2).unwrap()).unwrap())],
        ])
        .unwrap()
        .sym()
        .unwrap();
        p.constrain("b4", &b4, Relation::PosSemiDef).unwrap();
        let results = both_ways(&p);
        assert!(
            results.iter().all(|r| r.2 > 0),
            "structure kept in every block"
        );
        for (k, (structured, sparse, _)) in results.iter().enumerate() {
            let scale = sparse.amax();
            let diff = (structured - sparse).amax();
            assert!(
                diff <= 1e-12 * scale,
                "block {k}: {diff:e} against {scale:e}"
            );
        }
    }

    #[test]
    fn svec_positions_follow_the_upper_triangle_column_by_column() {
        let mut t = 0;
        for col in 0..40 {
            for row in 0..=col {
                assert_eq!(svec_pos(t), (row, col), "t = {t}");
                t += 1;
            }
        }
    }
}
