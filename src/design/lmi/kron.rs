//! The Schur matrix of the structured part of a block, from its Kronecker form.
//!
//! A block whose variable part is A(x) = Σ_t L_t X^(τ_t) R_tᵀ in a matrix variable X (see
//! [`super::factor`]) has, for two scalar variables i (of X) and j (of Y) with basis matrices
//! E_i = Σ e_a e_bᵀ and E_j = Σ e_c e_dᵀ,
//!
//! ⟨A_i, S⁻¹ A_j Z⟩ = Σ_{t,u} Σ (R_tᵀ S⁻¹ L_u)[b, c] · (R_uᵀ Z L_t)[d, a]
//!
//! (indices swapped for transposed terms). So one iteration needs only the small matrices
//! Φ_tu = R_tᵀ S⁻¹ L_u and Ψ_ut = R_uᵀ Z L_t, a few dense products of size d × n, instead of
//! one sparse d×d product per scalar variable. For a fixed i, the entries over the scalars j of
//! one column d of Y are a row of Φ times Ψ[d, a] (plus the mirrored term for a symmetric Y), so
//! a column of the Schur matrix is filled by contiguous vector updates. This is the formula
//! SDPT3 and SDPA use for low-rank data, applied to whole matrix variables.

use std::ops::Range;

use nalgebra::DMatrix;

use super::VarKind;

/// Most terms a variable may have in a block for the Kronecker formula to pay off (the cost
/// grows with the product of the term counts of the two variables).
const MAX_TERMS: usize = 8;

/// One structured term of a conic block, in the solver's units: the block's A_k(x) contains
/// L X^(τ) Rᵀ, X the matrix of the variable's scalars `offset..offset + kind.count()`.
pub(crate) struct BlockTerm {
    pub offset: usize,
    pub kind: VarKind,
    pub transposed: bool,
    pub l: DMatrix<f64>,
    pub r: DMatrix<f64>,
}

/// One term restricted to the variable's active rows and columns.
struct Term {
    transposed: bool,
    /// d × (active pre-indices): the rows of X^(τ).
    l: DMatrix<f64>,
    /// d × (active post-indices): the columns of X^(τ).
    r: DMatrix<f64>,
}

/// A scalar variable of X: its global index and the entries (row, column) of its basis matrix
/// in active-local coordinates (one entry, or two for an off-diagonal symmetric entry).
struct Scalar {
    global: usize,
    comps: [(usize, usize); 2],
    ncomp: usize,
}

/// A matrix variable of one block in Kronecker form.
pub(super) struct KronVar {
    /// Global indices of all the variable's scalars.
    pub range: Range<usize>,
    terms: Vec<Term>,
    scalars: Vec<Scalar>,
    symmetric: bool,
    /// The scalars column by column of X: `scalars[start..start + len]` are the entries
    /// (c, d) with c = 0, 1, … in column d (active-local), so a column of the Schur matrix is
    /// filled by contiguous vector operations.
    runs: Vec<Run>,
}

/// One column d of the variable in [`KronVar::scalars`].
struct Run {
    start: usize,
    len: usize,
    d: usize,
}

/// Positions of the nonzero columns of `m` (as indices of the variable), merged into `set`.
fn mark_columns(m: &DMatrix<f64>, set: &mut [bool]) {
    for (j, col) in m.column_iter().enumerate() {
        if col.iter().any(|v| *v != 0.0) {
            set[j] = true;
        }
    }
}

fn positions(set: &[bool]) -> (Vec<usize>, Vec<Option<usize>>) {
    let list: Vec<usize> = (0..set.len()).filter(|&i| set[i]).collect();
    let mut pos = vec![None; set.len()];
    for (k, &i) in list.iter().enumerate() {
        pos[i] = Some(k);
    }
    (list, pos)
}

impl KronVar {
    /// The variables of a block that are worth the Kronecker formula, from its terms.
    pub(super) fn from_terms(terms: &[BlockTerm]) -> Vec<KronVar> {
        let mut offsets: Vec<usize> = terms.iter().map(|t| t.offset).collect();
        offsets.sort_unstable();
        offsets.dedup();
        offsets
            .into_iter()
            .filter_map(|o| {
                let mine: Vec<&BlockTerm> = terms.iter().filter(|t| t.offset == o).collect();
                KronVar::new(&mine)
            })
            .collect()
    }

    fn new(terms: &[&BlockTerm]) -> Option<KronVar> {
        let first = terms.first()?;
        let (kind, offset) = (first.kind, first.offset);
        if matches!(kind, VarKind::Scalar) || terms.len() > MAX_TERMS {
            return None;
        }
        let (nr, nc) = kind.shape();
        let symmetric = matches!(kind, VarKind::Symmetric(_));
        // Active rows and columns of X: where some term's L or R has a nonzero column.
        let mut rows = vec![false; nr];
        let mut cols = vec![false; nc];
        for t in terms {
            let (pre, post) = if t.transposed {
                (&mut cols, &mut rows)
            } else {
                (&mut rows, &mut cols)
            };
            mark_columns(&t.l, pre);
            mark_columns(&t.r, post);
        }
        if symmetric {
            for (r, c) in rows.iter_mut().zip(cols.iter_mut()) {
                *r |= *c;
                *c = *r;
            }
        }
        let (row_list, row_pos) = positions(&rows);
        let (col_list, col_pos) = positions(&cols);
        let restricted = terms
            .iter()
            .map(|t| {
                let (pre, post) = if t.transposed {
                    (&col_list, &row_list)
                } else {
                    (&row_list, &col_list)
                };
                Term {
                    transposed: t.transposed,
                    l: t.l.select_columns(pre.iter()),
                    r: t.r.select_columns(post.iter()),
                }
            })
            .collect();
        let mut scalars = Vec::new();
        match kind {
            VarKind::Symmetric(_) => {
                for &b in &row_list {
                    for &a in row_list.iter().take_while(|&&a| a <= b) {
                        let (ia, ib) = (row_pos[a]?, row_pos[b]?);
                        scalars.push(Scalar {
                            global: offset + b * (b + 1) / 2 + a,
                            comps: [(ia, ib), (ib, ia)],
                            ncomp: if a == b { 1 } else { 2 },
                        });
                    }
                }
            }
            _ => {
                for &b in &col_list {
                    for &a in &row_list {
                        scalars.push(Scalar {
                            global: offset + a + nr * b,
                            comps: [(row_pos[a]?, col_pos[b]?); 2],
                            ncomp: 1,
                        });
                    }
                }
            }
        }
        let mut runs: Vec<Run> = Vec::new();
        for (k, sc) in scalars.iter().enumerate() {
            let d = sc.comps[0].1;
            match runs.last_mut() {
                Some(r) if r.d == d => r.len += 1,
                _ => runs.push(Run {
                    start: k,
                    len: 1,
                    d,
                }),
            }
        }
        Some(KronVar {
            range: offset..offset + kind.count(),
            terms: restricted,
            scalars,
            symmetric,
            runs,
        })
    }

    /// Rough flop count of [`add_pair`] with `other`.
    pub(super) fn pair_cost(&self, other: &KronVar) -> usize {
        4 * self.terms.len() * other.terms.len() * self.scalars.len() * other.scalars.len()
    }
}

/// (pre, post) indices of a basis entry (row a, column b) of X under a term's transposition.
#[inline]
fn pre_post(comp: (usize, usize), transposed: bool) -> (usize, usize) {
    if transposed { (comp.1, comp.0) } else { comp }
}

/// Adds ⟨A_i, S⁻¹ A_j Z⟩ for the scalars i of `x` and j of `y` into the lower triangle of `m`
/// (with `x` = `y` each pair once). `x` must not come after `y` in the variable order, so that
/// every entry lands in column g_i, row g_j ≥ g_i, and the inner loop runs down a column.
/// `zl` and `sl` are Z L_t for the terms of `x` and S⁻¹ L_u for those of `y`.
pub(super) fn add_pair(
    x: &KronVar,
    y: &KronVar,
    same: bool,
    zl: &[DMatrix<f64>],
    sl: &[DMatrix<f64>],
    m: &mut DMatrix<f64>,
) {
    debug_assert!(x.range.start <= y.range.start);
    // Φᵀ = (S⁻¹L_u)ᵀ R_t: column b is Φ[b, ·]; Ψ = R_uᵀ Z L_t: column a is Ψ[·, a].
    let mut pairs = Vec::with_capacity(x.terms.len() * y.terms.len());
    for (tx, zl_t) in x.terms.iter().zip(zl) {
        for (ty, sl_u) in y.terms.iter().zip(sl) {
            pairs.push((
                sl_u.tr_mul(&tx.r),
                ty.r.tr_mul(zl_t),
                tx.transposed,
                ty.transposed,
            ));
        }
    }
    let n = m.nrows();
    let ms = m.as_mut_slice();
    // One column of M at a time, summed over the term pairs in a short buffer first: M itself
    // is too large to be swept once per pair.
    let mut col = vec![0.0; y.scalars.len()];
    for (i, si) in x.scalars.iter().enumerate() {
        let first = if same { i } else { 0 };
        let col = &mut col[first..];
        col.fill(0.0);
        for (phi_t, psi_m, tx, ty) in &pairs {
            for &ci in &si.comps[..si.ncomp] {
                let (pre_i, post_i) = pre_post(ci, *tx);
                // φ[c] = Φ[post_i, c] over the pre-indices of Y, ψ[d] = Ψ[d, pre_i] over its
                // post-indices; entry (c, d) of Y contributes φ[pre] ψ[post].
                let phi = phi_t.column(post_i);
                let psi = psi_m.column(pre_i);
                let (phi, psi) = (phi.as_slice(), psi.as_slice());
                for run in &y.runs {
                    if run.start + run.len <= first {
                        continue;
                    }
                    let c0 = first.saturating_sub(run.start);
                    let seg = &mut col[run.start + c0 - first..run.start + run.len - first];
                    let d = run.d;
                    let range = c0..run.len;
                    if y.symmetric {
                        // (c, d) and (d, c): φ[c] ψ[d] + φ[d] ψ[c], once on the diagonal.
                        let (a, b) = (psi[d], phi[d]);
                        for ((v, f), p) in seg.iter_mut().zip(&phi[range.clone()]).zip(&psi[range])
                        {
                            *v += a * f + b * p;
                        }
                        // A symmetric run ends on the diagonal (len = d + 1).
                        if let Some(v) = seg.last_mut() {
                            *v -= phi[d] * psi[d];
                        }
                    } else if !*ty {
                        let a = psi[d];
                        for (v, f) in seg.iter_mut().zip(&phi[range]) {
                            *v += a * f;
                        }
                    } else {
                        let b = phi[d];
                        for (v, p) in seg.iter_mut().zip(&psi[range]) {
                            *v += b * p;
                        }
                    }
                }
            }
        }
        let out = &mut ms[si.global * n..(si.global + 1) * n];
        for (c, sj) in col.iter().zip(&y.scalars[first..]) {
            out[sj.global] += c;
        }
    }
}

/// Z L_t (or S⁻¹ L_t) for every term of `v`.
pub(super) fn left_products(v: &KronVar, w: &DMatrix<f64>) -> Vec<DMatrix<f64>> {
    v.terms.iter().map(|t| w * &t.l).collect()
}
