//! The Kronecker structure of affine expressions: F(x) = F₀ + Σ_f L_f X_f^(τ_f) R_fᵀ, where
//! X_f is a matrix decision variable (used transposed when τ_f) and L_f, R_f are constant.
//!
//! Why: the sparse (entry, scalar variable) form of [`super::Expr`] is what the solvers consume,
//! but it forgets that an LMI block like [P, P A; AᵀP, P] is a short sum of products L P Rᵀ.
//! The Schur-complement solver ([`super::ipm`]) forms its matrix from that structure with
//! small dense products instead of one sparse product per scalar variable (see
//! [`super::kron`]). Every operation of [`super::Expr`] that keeps the form updates the
//! factors alongside the sparse terms; the others (traces, inner products) drop them
//! (`None`), and a dropped structure only means the slower sparse formula.

use nalgebra::DMatrix;

/// Most terms an expression keeps in structured form; beyond, the structure is dropped (the
/// Schur formula would gain nothing over the sparse one).
const MAX_FACTORS: usize = 48;

/// Relative tolerance under which two factor matrices count as proportional when merging.
const MERGE_TOL: f64 = 1e-13;

/// Relative singular-value cutoff of [`compress`].
const RANK_TOL: f64 = 1e-13;

/// One structured term L · X^(τ) · Rᵀ.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Factor {
    /// Index of the variable among the problem's variables.
    pub var: usize,
    /// Whether the variable is symmetric (then Xᵀ = X and `transposed` stays false).
    pub symmetric: bool,
    /// Whether the term uses Xᵀ.
    pub transposed: bool,
    /// rows(F) × (rows of X^(τ)).
    pub l: DMatrix<f64>,
    /// cols(F) × (columns of X^(τ)).
    pub r: DMatrix<f64>,
}

/// The structured terms of an expression, or `None` when an operation lost the structure.
pub(crate) type Factors = Option<Vec<Factor>>;

impl Factor {
    /// The term of a whole variable (rows × cols): I · X · I.
    pub fn whole(var: usize, rows: usize, cols: usize, symmetric: bool) -> Factor {
        Factor {
            var,
            symmetric,
            transposed: false,
            l: DMatrix::identity(rows, rows),
            r: DMatrix::identity(cols, cols),
        }
    }

    fn same_kind(&self, o: &Factor) -> bool {
        self.var == o.var
            && self.transposed == o.transposed
            && self.l.shape() == o.l.shape()
            && self.r.shape() == o.r.shape()
    }
}

/// c with b ≈ c·a (relative [`MERGE_TOL`]), if any.
fn proportional(a: &DMatrix<f64>, b: &DMatrix<f64>) -> Option<f64> {
    let (p, amax) =
        a.iter().enumerate().fold(
            (0, 0.0f64),
            |(p, m), (i, v)| if v.abs() > m { (i, v.abs()) } else { (p, m) },
        );
    if amax == 0.0 {
        return None;
    }
    let c = b[p] / a[p];
    let bmax = b.amax();
    a.iter()
        .zip(b.iter())
        .all(|(x, y)| (y - c * x).abs() <= MERGE_TOL * bmax)
        .then_some(c)
}

/// Merges terms with proportional left (then right) factors and drops zero terms; `None` when
/// more than [`MAX_FACTORS`] remain.
pub(crate) fn tidy(fs: Vec<Factor>) -> Factors {
    let mut fs: Vec<Factor> = fs
        .into_iter()
        .filter(|f| f.l.amax() > 0.0 && f.r.amax() > 0.0)
        .collect();
    for by_left in [true, false, true] {
        let mut out: Vec<Factor> = Vec::with_capacity(fs.len());
        'next: for f in fs {
            for g in out.iter_mut() {
                if !g.same_kind(&f) {
                    continue;
                }
                if by_left {
                    if let Some(c) = proportional(&g.l, &f.l) {
                        g.r += &f.r * c;
                        continue 'next;
                    }
                } else if let Some(c) = proportional(&g.r, &f.r) {
                    g.l += &f.l * c;
                    continue 'next;
                }
            }
            out.push(f);
        }
        fs = out
            .into_iter()
            .filter(|f| f.l.amax() > 0.0 && f.r.amax() > 0.0)
            .collect();
    }
    (fs.len() <= MAX_FACTORS).then_some(fs)
}

/// Concatenation (the factors of a sum).
pub(crate) fn sum(a: &Factors, b: &Factors) -> Factors {
    let (a, b) = (a.as_ref()?, b.as_ref()?);
    tidy(a.iter().chain(b).cloned().collect())
}

/// The factors of α·F.
pub(crate) fn scale(fs: &Factors, alpha: f64) -> Factors {
    let fs = fs.as_ref()?;
    if alpha == 0.0 {
        return Some(Vec::new());
    }
    Some(
        fs.iter()
            .map(|f| Factor {
                r: &f.r * alpha,
                ..f.clone()
            })
            .collect(),
    )
}

/// The factors of Fᵀ: (L X Rᵀ)ᵀ = R Xᵀ Lᵀ.
pub(crate) fn transpose(fs: &Factors) -> Factors {
    Some(
        fs.as_ref()?
            .iter()
            .map(|f| Factor {
                var: f.var,
                symmetric: f.symmetric,
                // Xᵀ = X for a symmetric variable.
                transposed: if f.symmetric {
                    f.transposed
                } else {
                    !f.transposed
                },
                l: f.r.clone(),
                r: f.l.clone(),
            })
            .collect(),
    )
}

/// The factors of C·F.
pub(crate) fn left_mul(fs: &Factors, c: &DMatrix<f64>) -> Factors {
    let fs = fs.as_ref()?;
    tidy(
        fs.iter()
            .map(|f| Factor {
                l: c * &f.l,
                ..f.clone()
            })
            .collect(),
    )
}

/// The factors of F·C: L X Rᵀ C = L X (Cᵀ R)ᵀ.
pub(crate) fn right_mul(fs: &Factors, c: &DMatrix<f64>) -> Factors {
    let fs = fs.as_ref()?;
    tidy(
        fs.iter()
            .map(|f| Factor {
                r: c.tr_mul(&f.r),
                ..f.clone()
            })
            .collect(),
    )
}

/// The factors of the sub-block `rows`×`cols` at (`row0`, `col0`).
pub(crate) fn block(fs: &Factors, row0: usize, col0: usize, rows: usize, cols: usize) -> Factors {
    let fs = fs.as_ref()?;
    tidy(
        fs.iter()
            .map(|f| Factor {
                l: f.l.rows(row0, rows).into_owned(),
                r: f.r.rows(col0, cols).into_owned(),
                ..f.clone()
            })
            .collect(),
    )
}

/// The factors of F placed at (`row0`, `col0`) of a `rows`×`cols` zero matrix.
pub(crate) fn embed(fs: &Factors, row0: usize, col0: usize, rows: usize, cols: usize) -> Factors {
    let fs = fs.as_ref()?;
    Some(
        fs.iter()
            .map(|f| {
                let mut l = DMatrix::zeros(rows, f.l.ncols());
                l.rows_mut(row0, f.l.nrows()).copy_from(&f.l);
                let mut r = DMatrix::zeros(cols, f.r.ncols());
                r.rows_mut(col0, f.r.nrows()).copy_from(&f.r);
                Factor { l, r, ..f.clone() }
            })
            .collect(),
    )
}

/// The factors of K ⊗ F: with K = Σ_p e_p k_pᵀ (its rows),
/// K ⊗ (L X Rᵀ) = Σ_p (e_p ⊗ L) X (k_p ⊗ R)ᵀ.
pub(crate) fn kron_left(fs: &Factors, k: &DMatrix<f64>) -> Factors {
    let fs = fs.as_ref()?;
    let mut out = Vec::new();
    for p in 0..k.nrows() {
        if k.row(p).iter().all(|v| *v == 0.0) {
            continue;
        }
        for f in fs {
            let (lr, rr) = (f.l.nrows(), f.r.nrows());
            let mut l = DMatrix::zeros(k.nrows() * lr, f.l.ncols());
            l.rows_mut(p * lr, lr).copy_from(&f.l);
            let mut r = DMatrix::zeros(k.ncols() * rr, f.r.ncols());
            for q in 0..k.ncols() {
                r.rows_mut(q * rr, rr).copy_from(&(&f.r * k[(p, q)]));
            }
            out.push(Factor { l, r, ..f.clone() });
        }
        if out.len() > MAX_FACTORS {
            return None;
        }
    }
    tidy(out)
}

/// The factors of F ⊗ K: (L X Rᵀ) ⊗ (e_p k_pᵀ) = (L ⊗ e_p) X (R ⊗ k_p)ᵀ.
pub(crate) fn kron_right(fs: &Factors, k: &DMatrix<f64>) -> Factors {
    let fs = fs.as_ref()?;
    let (kr, kc) = k.shape();
    let mut out = Vec::new();
    for p in 0..kr {
        if k.row(p).iter().all(|v| *v == 0.0) {
            continue;
        }
        for f in fs {
            let mut l = DMatrix::zeros(f.l.nrows() * kr, f.l.ncols());
            for i in 0..f.l.nrows() {
                l.row_mut(i * kr + p).copy_from(&f.l.row(i));
            }
            let mut r = DMatrix::zeros(f.r.nrows() * kc, f.r.ncols());
            for j in 0..f.r.nrows() {
                for q in 0..kc {
                    r.row_mut(j * kc + q).copy_from(&(f.r.row(j) * k[(p, q)]));
                }
            }
            out.push(Factor { l, r, ..f.clone() });
        }
        if out.len() > MAX_FACTORS {
            return None;
        }
    }
    tidy(out)
}

/// The fewest terms with the same sum: per (variable, τ), Σ_f vec(L_f) vec(R_f)ᵀ is a matrix
/// of rank ≤ #terms; its SVD (through thin QRs of the two sides) gives a minimal set.
pub(crate) fn compress(fs: Vec<Factor>) -> Vec<Factor> {
    let mut groups: Vec<Vec<Factor>> = Vec::new();
    for f in fs {
        match groups.iter_mut().find(|g| g[0].same_kind(&f)) {
            Some(g) => g.push(f),
            None => groups.push(vec![f]),
        }
    }
    let mut out = Vec::new();
    for g in groups {
        if g.len() == 1 {
            out.extend(g);
            continue;
        }
        let (lshape, rshape) = (g[0].l.shape(), g[0].r.shape());
        let stack = |pick: &dyn Fn(&Factor) -> &DMatrix<f64>| {
            let cols: Vec<f64> = g.iter().flat_map(|f| pick(f).iter().copied()).collect();
            DMatrix::from_vec(cols.len() / g.len(), g.len(), cols)
        };
        let lq = stack(&|f| &f.l).qr();
        let rq = stack(&|f| &f.r).qr();
        let core = lq.r() * rq.r().transpose();
        // A non-finite or non-converging core: the terms stay as they are.
        let Some(svd) = crate::linalg::svd(&core, true, true) else {
            out.extend(g);
            continue;
        };
        let (Some(u), Some(vt)) = (svd.u.as_ref(), svd.v_t.as_ref()) else {
            out.extend(g);
            continue;
        };
        let smax = svd.singular_values.max();
        let (ql, qr) = (lq.q(), rq.q());
        for (s, &sv) in svd.singular_values.iter().enumerate() {
            if sv <= RANK_TOL * smax {
                continue;
            }
            let l = &ql * u.column(s) * sv;
            let r = &qr * vt.row(s).transpose();
            out.push(Factor {
                l: DMatrix::from_column_slice(lshape.0, lshape.1, l.as_slice()),
                r: DMatrix::from_column_slice(rshape.0, rshape.1, r.as_slice()),
                ..g[0].clone()
            });
        }
    }
    out
}
