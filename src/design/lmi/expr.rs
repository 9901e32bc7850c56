//! Affine matrix expressions F(x) = F₀ + Σₖ xₖ Fₖ over the scalar decision variables xₖ.

use nalgebra::DMatrix;

use super::LmiError;
use super::factor::{self, Factors};

/// One coefficient: entry (row, col) of the expression depends on scalar variable `var` with
/// weight `coef`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Term {
    pub row: usize,
    pub col: usize,
    pub var: usize,
    pub coef: f64,
}

/// A matrix-valued affine function of the decision variables.
///
/// Stored sparsely: a dense constant part and a list of (entry, scalar variable, coefficient)
/// terms, so an entry that depends on few variables costs few terms and products by constant
/// matrices never lift to a dense (entries × variables) array. Build expressions from
/// [`super::Problem::var`] and [`Expr::constant`]; combine them with the methods below. All
/// operations check shapes and return [`LmiError::Shape`] on mismatch.
#[derive(Debug, Clone, PartialEq)]
pub struct Expr {
    pub(crate) constant: DMatrix<f64>,
    pub(crate) terms: Vec<Term>,
    /// The same variable part as `terms`, as a short sum Σ L X Rᵀ over matrix variables
    /// (see [`factor`]); `None` once an operation has lost that form.
    pub(crate) factors: Factors,
}

fn shape_err(op: &'static str, left: (usize, usize), right: (usize, usize)) -> LmiError {
    LmiError::Shape { op, left, right }
}

impl Expr {
    /// A constant expression.
    pub fn constant(m: DMatrix<f64>) -> Self {
        Expr {
            constant: m,
            terms: Vec::new(),
            factors: Some(Vec::new()),
        }
    }

    /// A constant scalar (1×1) expression.
    pub fn scalar(v: f64) -> Self {
        Self::constant(DMatrix::from_element(1, 1, v))
    }

    /// The zero matrix of the given shape.
    pub fn zeros(rows: usize, cols: usize) -> Self {
        Self::constant(DMatrix::zeros(rows, cols))
    }

    /// The n×n identity.
    pub fn identity(n: usize) -> Self {
        Self::constant(DMatrix::identity(n, n))
    }

    pub(crate) fn from_terms(rows: usize, cols: usize, terms: Vec<Term>, factors: Factors) -> Self {
        Expr {
            constant: DMatrix::zeros(rows, cols),
            terms,
            factors,
        }
    }

    /// (rows, columns).
    pub fn shape(&self) -> (usize, usize) {
        self.constant.shape()
    }

    /// Whether no decision variable appears.
    pub fn is_constant(&self) -> bool {
        self.terms.is_empty()
    }

    /// The constant part F₀.
    pub fn constant_part(&self) -> &DMatrix<f64> {
        &self.constant
    }

    /// Number of stored (entry, variable) coefficients.
    pub fn nnz(&self) -> usize {
        self.terms.len()
    }

    /// Sorts terms by (column, row, variable), merges duplicates and drops zeros.
    pub(crate) fn canonical(mut self) -> Self {
        self.terms.sort_unstable_by_key(|t| (t.col, t.row, t.var));
        let mut out: Vec<Term> = Vec::with_capacity(self.terms.len());
        for t in self.terms {
            match out.last_mut() {
                Some(last) if last.row == t.row && last.col == t.col && last.var == t.var => {
                    last.coef += t.coef
                }
                _ => out.push(t),
            }
        }
        out.retain(|t| t.coef != 0.0);
        self.terms = out;
        self
    }

    /// self + other.
    pub fn add(&self, other: &Expr) -> Result<Expr, LmiError> {
        if self.shape() != other.shape() {
            return Err(shape_err("+", self.shape(), other.shape()));
        }
        let mut terms = self.terms.clone();
        terms.extend_from_slice(&other.terms);
        Ok(Expr {
            constant: &self.constant + &other.constant,
            terms,
            factors: factor::sum(&self.factors, &other.factors),
        }
        .canonical())
    }

    /// self − other.
    pub fn sub(&self, other: &Expr) -> Result<Expr, LmiError> {
        if self.shape() != other.shape() {
            return Err(shape_err("-", self.shape(), other.shape()));
        }
        self.add(&other.scale(-1.0))
    }

    /// α · self.
    pub fn scale(&self, alpha: f64) -> Expr {
        let mut e = self.clone();
        e.constant *= alpha;
        for t in &mut e.terms {
            t.coef *= alpha;
        }
        if alpha == 0.0 {
            e.terms.clear();
        }
        e.factors = factor::scale(&self.factors, alpha);
        e
    }

    /// −self.
    pub fn neg(&self) -> Expr {
        self.scale(-1.0)
    }

    /// selfᵀ.
    pub fn transpose(&self) -> Expr {
        Expr {
            constant: self.constant.transpose(),
            terms: self
                .terms
                .iter()
                .map(|t| Term {
                    row: t.col,
                    col: t.row,
                    ..*t
                })
                .collect(),
            factors: factor::transpose(&self.factors),
        }
        .canonical()
    }

    /// L · self for a constant L.
    pub fn left_mul(&self, l: &DMatrix<f64>) -> Result<Expr, LmiError> {
        let (r, c) = self.shape();
        if l.ncols() != r {
            return Err(shape_err("*", l.shape(), (r, c)));
        }
        let mut terms = Vec::new();
        for t in &self.terms {
            for a in 0..l.nrows() {
                let la = l[(a, t.row)];
                if la != 0.0 {
                    terms.push(Term {
                        row: a,
                        col: t.col,
                        var: t.var,
                        coef: la * t.coef,
                    });
                }
            }
        }
        Ok(Expr {
            constant: l * &self.constant,
            terms,
            factors: factor::left_mul(&self.factors, l),
        }
        .canonical())
    }

    /// self · R for a constant R.
    pub fn right_mul(&self, rm: &DMatrix<f64>) -> Result<Expr, LmiError> {
        let (r, c) = self.shape();
        if rm.nrows() != c {
            return Err(shape_err("*", (r, c), rm.shape()));
        }
        let mut terms = Vec::new();
        for t in &self.terms {
            for b in 0..rm.ncols() {
                let rb = rm[(t.col, b)];
                if rb != 0.0 {
                    terms.push(Term {
                        row: t.row,
                        col: b,
                        var: t.var,
                        coef: t.coef * rb,
                    });
                }
            }
        }
        Ok(Expr {
            constant: &self.constant * rm,
            terms,
            factors: factor::right_mul(&self.factors, rm),
        }
        .canonical())
    }

    /// self · other, where at least one factor is constant (the product of two affine
    /// expressions in the variables is not affine: [`LmiError::Nonlinear`]). 1×1 factors act
    /// as scalars.
    pub fn mul(&self, other: &Expr) -> Result<Expr, LmiError> {
        if other.is_constant() {
            if other.shape() == (1, 1) && self.shape().1 != 1 {
                return Ok(self.scale(other.constant[(0, 0)]));
            }
            if self.shape() == (1, 1) && other.shape().0 != 1 {
                return Ok(self.kron_left(&other.constant));
            }
            self.right_mul(&other.constant)
        } else if self.is_constant() {
            if self.shape() == (1, 1) && other.shape().0 != 1 {
                return Ok(other.scale(self.constant[(0, 0)]));
            }
            if other.shape() == (1, 1) && self.shape().1 != 1 {
                return Ok(other.kron_left(&self.constant));
            }
            other.left_mul(&self.constant)
        } else {
            Err(LmiError::Nonlinear)
        }
    }

    /// The sub-block of `rows`×`cols` starting at (`row0`, `col0`).
    pub fn block(
        &self,
        row0: usize,
        col0: usize,
        rows: usize,
        cols: usize,
    ) -> Result<Expr, LmiError> {
        let (r, c) = self.shape();
        if row0 + rows > r || col0 + cols > c {
            return Err(LmiError::Index {
                shape: (r, c),
                row: row0 + rows,
                col: col0 + cols,
            });
        }
        Ok(Expr {
            constant: self.constant.view((row0, col0), (rows, cols)).into_owned(),
            terms: self
                .terms
                .iter()
                .filter(|t| {
                    t.row >= row0 && t.row < row0 + rows && t.col >= col0 && t.col < col0 + cols
                })
                .map(|t| Term {
                    row: t.row - row0,
                    col: t.col - col0,
                    ..*t
                })
                .collect(),
            factors: factor::block(&self.factors, row0, col0, rows, cols),
        })
    }

    /// Entry (i, j) as a 1×1 expression.
    pub fn entry(&self, i: usize, j: usize) -> Result<Expr, LmiError> {
        self.block(i, j, 1, 1)
    }

    /// tr(self) as a 1×1 expression (self square).
    pub fn trace(&self) -> Result<Expr, LmiError> {
        let (r, c) = self.shape();
        if r != c {
            return Err(LmiError::NotSquare { shape: (r, c) });
        }
        Ok(Expr {
            constant: DMatrix::from_element(1, 1, self.constant.trace()),
            terms: self
                .terms
                .iter()
                .filter(|t| t.row == t.col)
                .map(|t| Term {
                    row: 0,
                    col: 0,
                    ..*t
                })
                .collect(),
            factors: None,
        }
        .canonical())
    }

    /// ⟨C, self⟩ = tr(Cᵀ self) as a 1×1 expression (a general linear functional).
    pub fn inner(&self, c: &DMatrix<f64>) -> Result<Expr, LmiError> {
        if c.shape() != self.shape() {
            return Err(shape_err("inner", c.shape(), self.shape()));
        }
        Ok(Expr {
            constant: DMatrix::from_element(1, 1, c.dot(&self.constant)),
            terms: self
                .terms
                .iter()
                .map(|t| Term {
                    row: 0,
                    col: 0,
                    var: t.var,
                    coef: c[(t.row, t.col)] * t.coef,
                })
                .collect(),
            factors: None,
        }
        .canonical())
    }

    /// Block matrix from rows of blocks. Every block in a row has the same number of rows, every
    /// block in a column the same number of columns; `None` is a zero block whose shape is taken
    /// from the others in its row and column.
    pub fn blocks(rows: &[Vec<Option<Expr>>]) -> Result<Expr, LmiError> {
        let nr = rows.len();
        let nc = rows.first().map_or(0, |r| r.len());
        if rows.iter().any(|r| r.len() != nc) {
            return Err(LmiError::BlockLayout {
                detail: "rows of blocks have different lengths".into(),
            });
        }
        let mut heights = vec![None::<usize>; nr];
        let mut widths = vec![None::<usize>; nc];
        for (i, row) in rows.iter().enumerate() {
            for (j, b) in row.iter().enumerate() {
                if let Some(b) = b {
                    let (h, w) = b.shape();
                    for (slot, v, what) in
                        [(&mut heights[i], h, "rows"), (&mut widths[j], w, "columns")]
                    {
                        match slot {
                            Some(prev) if *prev != v => {
                                return Err(LmiError::BlockLayout {
                                    detail: format!(
                                        "block ({}, {}) has {v} {what}, its neighbours {prev}",
                                        i + 1,
                                        j + 1
                                    ),
                                });
                            }
                            _ => *slot = Some(v),
                        }
                    }
                }
            }
        }
        let unknown = |k: usize, what: &str| LmiError::BlockLayout {
            detail: format!(
                "{what} {} holds only zero blocks; its size is unknown",
                k + 1
            ),
        };
        let heights: Vec<usize> = heights
            .iter()
            .enumerate()
            .map(|(i, h)| h.ok_or_else(|| unknown(i, "block row")))
            .collect::<Result<_, _>>()?;
        let widths: Vec<usize> = widths
            .iter()
            .enumerate()
            .map(|(j, w)| w.ok_or_else(|| unknown(j, "block column")))
            .collect::<Result<_, _>>()?;
        let total_r: usize = heights.iter().sum();
        let total_c: usize = widths.iter().sum();
        let mut constant = DMatrix::zeros(total_r, total_c);
        let mut terms = Vec::new();
        let mut factors = Some(Vec::new());
        let mut r0 = 0;
        for (i, row) in rows.iter().enumerate() {
            let mut c0 = 0;
            for (j, b) in row.iter().enumerate() {
                if let Some(b) = b {
                    constant
                        .view_mut((r0, c0), (heights[i], widths[j]))
                        .copy_from(&b.constant);
                    terms.extend(b.terms.iter().map(|t| Term {
                        row: t.row + r0,
                        col: t.col + c0,
                        ..*t
                    }));
                    let placed = factor::embed(&b.factors, r0, c0, total_r, total_c);
                    factors = factors.zip(placed).map(|(mut a, p)| {
                        a.extend(p);
                        a
                    });
                }
                c0 += widths[j];
            }
            r0 += heights[i];
        }
        let factors = factors.and_then(factor::tidy);
        Ok(Expr {
            constant,
            terms,
            factors,
        }
        .canonical())
    }

    /// Kronecker product K ⊗ self with a constant K.
    pub fn kron_left(&self, k: &DMatrix<f64>) -> Expr {
        let (r, c) = self.shape();
        let mut terms = Vec::new();
        for p in 0..k.nrows() {
            for q in 0..k.ncols() {
                let kv = k[(p, q)];
                if kv != 0.0 {
                    terms.extend(self.terms.iter().map(|t| Term {
                        row: p * r + t.row,
                        col: q * c + t.col,
                        var: t.var,
                        coef: kv * t.coef,
                    }));
                }
            }
        }
        Expr {
            constant: k.kronecker(&self.constant),
            terms,
            factors: factor::kron_left(&self.factors, k),
        }
        .canonical()
    }

    /// Kronecker product self ⊗ K with a constant K.
    pub fn kron_right(&self, k: &DMatrix<f64>) -> Expr {
        let (kr, kc) = k.shape();
        let mut terms = Vec::new();
        for t in &self.terms {
            for p in 0..kr {
                for q in 0..kc {
                    let kv = k[(p, q)];
                    if kv != 0.0 {
                        terms.push(Term {
                            row: t.row * kr + p,
                            col: t.col * kc + q,
                            var: t.var,
                            coef: t.coef * kv,
                        });
                    }
                }
            }
        }
        Expr {
            constant: self.constant.kronecker(k),
            terms,
            factors: factor::kron_right(&self.factors, k),
        }
        .canonical()
    }

    /// (self + selfᵀ)/2.
    pub fn sym(&self) -> Result<Expr, LmiError> {
        let (r, c) = self.shape();
        if r != c {
            return Err(LmiError::NotSquare { shape: (r, c) });
        }
        Ok(self.add(&self.transpose())?.scale(0.5))
    }

    /// Evaluates the expression at the scalar variable values `x`.
    pub fn eval(&self, x: &[f64]) -> DMatrix<f64> {
        let mut m = self.constant.clone();
        for t in &self.terms {
            m[(t.row, t.col)] += t.coef * x[t.var];
        }
        m
    }

    /// Largest asymmetry max |F_ij − F_ji| over the constant part and the coefficients.
    pub(crate) fn asymmetry(&self) -> f64 {
        let mut worst = (&self.constant - self.constant.transpose()).amax();
        if let Ok(d) = self.sub(&self.transpose()) {
            for t in &d.terms {
                worst = worst.max(t.coef.abs());
            }
        }
        worst
    }

    /// Largest magnitude among the constant entries and coefficients (for relative tests).
    pub(crate) fn magnitude(&self) -> f64 {
        self.terms
            .iter()
            .fold(self.constant.amax(), |m, t| m.max(t.coef.abs()))
    }
}
