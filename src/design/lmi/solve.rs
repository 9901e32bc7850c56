//! Assembly of the conic program, scaling, solve (clarabel or [`super::ipm`]), and the
//! a-posteriori check.

use std::collections::HashMap;
use std::time::Instant;

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus as ClStatus, SupportedConeT,
};
use nalgebra::{DMatrix, DVector};

use super::ipm::{self, IpmOptions};
use super::kron::BlockTerm;
use super::{
    AUTO_SCHUR_ROWS, Backend, ConstraintCheck, Design, LmiError, Outcome, Problem, Relation,
    Rescale, SolveInfo, SolverStatus,
};

/// svec of a symmetric matrix in clarabel's convention (see the module docs): upper triangle
/// column by column, off-diagonals times √2. Uses (S_ij + S_ji)/2 for the off-diagonals.
pub fn svec(s: &DMatrix<f64>) -> Vec<f64> {
    let n = s.nrows().min(s.ncols());
    let mut v = Vec::with_capacity(n * (n + 1) / 2);
    for col in 0..n {
        for row in 0..=col {
            if row == col {
                v.push(s[(row, col)]);
            } else {
                v.push((s[(row, col)] + s[(col, row)]) * std::f64::consts::FRAC_1_SQRT_2);
            }
        }
    }
    v
}

/// Inverse of [`svec`]: the symmetric n×n matrix with svec(S) = v, or `None` when the length of
/// `v` is not a triangular number.
pub fn smat(v: &[f64]) -> Option<DMatrix<f64>> {
    let n = ((((8 * v.len() + 1) as f64).sqrt() - 1.0) / 2.0).round() as usize;
    if n * (n + 1) / 2 != v.len() {
        return None;
    }
    let mut s = DMatrix::zeros(n, n);
    let mut k = 0;
    for col in 0..n {
        for row in 0..=col {
            if row == col {
                s[(row, col)] = v[k];
            } else {
                s[(row, col)] = v[k] * std::f64::consts::FRAC_1_SQRT_2;
                s[(col, row)] = s[(row, col)];
            }
            k += 1;
        }
    }
    Some(s)
}

/// Scaling of one solve: per-constraint congruence diagonals and per-scalar variable scales.
pub(super) struct Scaling {
    /// For PSD constraints: D (length n); for `= 0` constraints: one factor (length 1).
    blocks: Vec<Vec<f64>>,
    vars: Vec<f64>,
}

/// The conic program handed to a solver: minimize qᵀx subject to
/// b − A x ∈ {0}^{zero_rows} × S₊^{blocks[0]} × S₊^{blocks[1]} × … (each block in svec
/// coordinates, see the module docs; a block of size 1 is a nonnegative scalar).
pub(crate) struct Conic {
    pub n: usize,
    pub zero_rows: usize,
    pub blocks: Vec<usize>,
    pub a: CscMatrix<f64>,
    pub b: Vec<f64>,
    pub q: Vec<f64>,
    /// Per PSD block: its variable part A_k(x) = smat(−A_k x) as Kronecker terms in the
    /// (scaled) matrix variables, when the constraint's structure is known.
    pub structure: Vec<Option<Vec<BlockTerm>>>,
}

impl Conic {
    /// Total svec rows of the PSD blocks.
    fn psd_rows(&self) -> usize {
        self.blocks.iter().map(|d| d * (d + 1) / 2).sum()
    }
}

struct Pass {
    status: SolverStatus,
    backend: Backend,
    x: Vec<f64>,
    solve_time: f64,
    iterations: u32,
    r_prim: f64,
    r_dual: f64,
    cone_rows: usize,
    nonzeros: usize,
}

fn map_status(s: ClStatus) -> SolverStatus {
    match s {
        ClStatus::Solved => SolverStatus::Solved,
        ClStatus::AlmostSolved => SolverStatus::AlmostSolved,
        ClStatus::PrimalInfeasible => SolverStatus::PrimalInfeasible,
        ClStatus::AlmostPrimalInfeasible => SolverStatus::AlmostPrimalInfeasible,
        ClStatus::DualInfeasible => SolverStatus::DualInfeasible,
        ClStatus::AlmostDualInfeasible => SolverStatus::AlmostDualInfeasible,
        ClStatus::MaxIterations => SolverStatus::MaxIterations,
        ClStatus::MaxTime => SolverStatus::MaxTime,
        ClStatus::NumericalError => SolverStatus::NumericalError,
        ClStatus::InsufficientProgress => SolverStatus::InsufficientProgress,
        _ => SolverStatus::Other,
    }
}

impl Problem {
    fn validate_settings(&self) -> Result<(), LmiError> {
        let s = &self.settings;
        for (field, value, ok) in [
            (
                "strict_margin",
                s.strict_margin,
                s.strict_margin >= 0.0 && s.strict_margin.is_finite(),
            ),
            (
                "check_tol",
                s.check_tol,
                s.check_tol > 0.0 && s.check_tol.is_finite(),
            ),
            (
                "solver_tol",
                s.solver_tol,
                s.solver_tol > 0.0 && s.solver_tol < 1.0,
            ),
            ("max_iter", s.max_iter as f64, s.max_iter > 0),
        ] {
            if !ok {
                return Err(LmiError::BadSetting { field, value });
            }
        }
        Ok(())
    }

    /// Data-based scaling: D_i = 1/√(largest magnitude in row i of the block's data).
    pub(super) fn data_scaling(&self) -> Scaling {
        let blocks = self
            .constraints
            .iter()
            .map(|c| {
                let (r, _) = c.expr.shape();
                if c.relation == Relation::Zero {
                    return vec![1.0 / c.expr.magnitude().max(1e-300)];
                }
                let mut row: Vec<f64> = (0..r).map(|i| c.expr.constant.row(i).amax()).collect();
                for t in &c.expr.terms {
                    row[t.row] = row[t.row].max(t.coef.abs());
                }
                row.iter()
                    .map(|&m| if m > 0.0 { 1.0 / m.sqrt() } else { 1.0 })
                    .collect()
            })
            .collect();
        Scaling {
            blocks,
            vars: vec![1.0; self.n_scalars],
        }
    }

    /// Solution-based scaling: D = diag(G(x))^{-1/2}, s_V = max |V| per matrix variable.
    fn solution_scaling(&self, x: &[f64], fallback: &Scaling) -> Scaling {
        let mut vars = vec![1.0; self.n_scalars];
        for v in &self.vars {
            let range = v.offset..v.offset + v.kind.count();
            let m = x[range.clone()].iter().fold(0.0f64, |a, b| a.max(b.abs()));
            if m > 0.0 && m.is_finite() {
                vars[range].iter_mut().for_each(|s| *s = m);
            }
        }
        let blocks = self
            .constraints
            .iter()
            .zip(&fallback.blocks)
            .map(|(c, fb)| {
                if c.relation == Relation::Zero {
                    return fb.clone();
                }
                let g = c.expr.eval(x);
                let dmax = g.diagonal().amax();
                (0..g.nrows())
                    .map(|i| {
                        let d = g[(i, i)];
                        if d.is_finite() && d > 1e-12 * dmax && d > 0.0 {
                            1.0 / d.sqrt()
                        } else {
                            fb[i]
                        }
                    })
                    .collect()
            })
            .collect();
        Scaling { blocks, vars }
    }

    /// The conic program of this problem under a scaling.
    pub(super) fn assemble(&self, scaling: &Scaling) -> Conic {
        let n = self.n_scalars;
        let margin = self.settings.strict_margin;
        let mut rows_i = Vec::new();
        let mut cols_j = Vec::new();
        let mut vals = Vec::new();
        let mut b = Vec::new();
        let mut blocks = Vec::new();
        let mut zero_rows = 0usize;
        // Equalities first (one zero cone), then one PSD cone per block.
        for (c, d) in self.constraints.iter().zip(&scaling.blocks) {
            if c.relation != Relation::Zero {
                continue;
            }
            let (r, cc) = c.expr.shape();
            let w = d[0];
            for j in 0..cc {
                for i in 0..r {
                    b.push(w * c.expr.constant[(i, j)]);
                }
            }
            for t in &c.expr.terms {
                rows_i.push(zero_rows + t.row + r * t.col);
                cols_j.push(t.var);
                vals.push(-w * t.coef * scaling.vars[t.var]);
            }
            zero_rows += r * cc;
        }
        let mut row0 = zero_rows;
        let mut structure = Vec::new();
        for (c, d) in self.constraints.iter().zip(&scaling.blocks) {
            if c.relation == Relation::Zero {
                continue;
            }
            // −D L X (s D R)ᵀ: the congruence, the variable's scale and the conic sign.
            structure.push(c.expr.factors.as_ref().map(|fs| {
                let dm = nalgebra::DVector::from_column_slice(d);
                fs.iter()
                    .map(|f| {
                        let v = &self.vars[f.var];
                        let s = scaling.vars[v.offset];
                        let mut l = f.l.clone();
                        let mut r = f.r.clone();
                        for (i, di) in dm.iter().enumerate() {
                            l.row_mut(i).scale_mut(-di);
                            r.row_mut(i).scale_mut(s * di);
                        }
                        BlockTerm {
                            offset: v.offset,
                            kind: v.kind,
                            transposed: f.transposed,
                            l,
                            r,
                        }
                    })
                    .collect()
            }));
            let m = c.expr.shape().0;
            let eps = if matches!(c.relation, Relation::PosDef | Relation::NegDef) {
                margin
            } else {
                0.0
            };
            let weight = |i: usize, j: usize| {
                d[i] * d[j]
                    * if i == j {
                        1.0
                    } else {
                        std::f64::consts::SQRT_2
                    }
            };
            for col in 0..m {
                for row in 0..=col {
                    let g0 = c.expr.constant[(row, col)] - if row == col { eps } else { 0.0 };
                    b.push(weight(row, col) * g0);
                }
            }
            for t in &c.expr.terms {
                if t.row <= t.col {
                    rows_i.push(row0 + t.col * (t.col + 1) / 2 + t.row);
                    cols_j.push(t.var);
                    vals.push(-weight(t.row, t.col) * t.coef * scaling.vars[t.var]);
                }
            }
            row0 += m * (m + 1) / 2;
            blocks.push(m);
        }
        let a = csc_from_triplets(row0, n, rows_i, cols_j, vals);
        let mut q = vec![0.0; n];
        if let Some((obj, sign)) = &self.objective {
            for t in &obj.terms {
                q[t.var] += sign * t.coef * scaling.vars[t.var];
            }
        }
        let qscale = q.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if qscale > 0.0 {
            q.iter_mut().for_each(|v| *v /= qscale);
        }
        Conic {
            n,
            zero_rows,
            blocks,
            a,
            b,
            q,
            structure,
        }
    }

    /// One solve. `scaling_only`: the point only serves to rescale a second solve, so the
    /// Schur backend may stop once it is primal feasible with a rough gap.
    fn run_pass(&self, scaling: &Scaling, scaling_only: bool) -> Result<Pass, LmiError> {
        let conic = self.assemble(scaling);
        let backend = match self.settings.backend {
            Backend::Auto if conic.psd_rows() > AUTO_SCHUR_ROWS => Backend::Schur,
            Backend::Auto => Backend::Clarabel,
            b => b,
        };
        let mut pass = match backend {
            Backend::Schur => {
                let r = ipm::solve(
                    &conic,
                    &IpmOptions {
                        tol: self.settings.solver_tol,
                        max_iter: self.settings.max_iter,
                        verbose: self.settings.verbose,
                        scaling_only,
                    },
                );
                Pass {
                    status: r.status,
                    backend,
                    x: r.x,
                    solve_time: r.solve_time,
                    iterations: r.iterations,
                    r_prim: r.r_prim,
                    r_dual: r.r_dual,
                    cone_rows: 0,
                    nonzeros: 0,
                }
            }
            _ => self.run_clarabel(&conic)?,
        };
        pass.cone_rows = conic.zero_rows + conic.psd_rows();
        pass.nonzeros = conic.a.nzval.len();
        for (v, s) in pass.x.iter_mut().zip(&scaling.vars) {
            *v *= s;
        }
        Ok(pass)
    }

    fn run_clarabel(&self, conic: &Conic) -> Result<Pass, LmiError> {
        let n = conic.n;
        let mut cones = Vec::new();
        if conic.zero_rows > 0 {
            cones.push(SupportedConeT::ZeroConeT(conic.zero_rows));
        }
        for &m in &conic.blocks {
            cones.push(if m == 1 {
                SupportedConeT::NonnegativeConeT(1)
            } else {
                SupportedConeT::PSDTriangleConeT(m)
            });
        }
        let p = CscMatrix::zeros((n, n));
        let tol = self.settings.solver_tol;
        let settings = DefaultSettingsBuilder::default()
            .verbose(self.settings.verbose)
            .max_iter(self.settings.max_iter)
            .tol_gap_abs(tol)
            .tol_gap_rel(tol)
            .tol_feas(tol)
            .build()
            .map_err(|e| LmiError::Solver(e.to_string()))?;
        let mut solver = DefaultSolver::new(&p, &conic.q, &conic.a, &conic.b, &cones, settings)
            .map_err(|e| LmiError::Solver(e.to_string()))?;
        solver.solve();
        let sol = &solver.solution;
        Ok(Pass {
            status: map_status(sol.status),
            backend: Backend::Clarabel,
            x: sol.x.clone(),
            solve_time: sol.solve_time,
            iterations: sol.iterations,
            r_prim: sol.r_prim,
            r_dual: sol.r_dual,
            cone_rows: 0,
            nonzeros: 0,
        })
    }

    fn check(&self, x: &[f64]) -> Vec<ConstraintCheck> {
        let tol = self.settings.check_tol;
        self.constraints
            .iter()
            .map(|c| {
                let g = c.expr.eval(x);
                let (min_eig, norm) = if c.relation == Relation::Zero {
                    let worst = g.amax();
                    let mut abs_scale = c.expr.constant.abs();
                    for t in &c.expr.terms {
                        abs_scale[(t.row, t.col)] += (t.coef * x[t.var]).abs();
                    }
                    (-worst, abs_scale.amax())
                } else {
                    // A non-finite value fails the check (min NaN).
                    let eig = crate::linalg::symmetric_eigenvalues(&g)
                        .unwrap_or_else(|| DVector::from_element(1, f64::NAN));
                    let min = eig.iter().fold(f64::INFINITY, |m, v| m.min(*v));
                    let norm = eig.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                    (min, norm)
                };
                let holds = min_eig.is_finite()
                    && match c.relation {
                        Relation::PosDef | Relation::NegDef => min_eig > 0.0,
                        _ => min_eig >= -tol * (1.0 + norm),
                    };
                ConstraintCheck {
                    label: c.label.clone(),
                    relation: c.relation,
                    min_eig,
                    norm,
                    holds,
                }
            })
            .collect()
    }

    /// Assembles, solves (with the [`Backend`] of the settings), checks every constraint at the returned point, and (per
    /// [`super::Settings::rescale`]) rescales from that point and solves again.
    pub fn solve(&self) -> Result<Outcome, LmiError> {
        let start = Instant::now();
        crate::design::blas::pin();
        self.validate_settings()?;
        // The solvers (clarabel's QDLDL) index into the first variable and
        // the first constraint: an empty problem never reaches them.
        if self.n_scalars == 0 {
            return Err(LmiError::Invalid {
                detail: "the problem has no decision variable: declare one (`sym P[n]`, `full K[m, n]`, `var t`)".into(),
            });
        }
        if self.constraints.is_empty() {
            return Err(LmiError::Invalid {
                detail: "the problem has no constraint: add one (`name: expr >= 0`)".into(),
            });
        }
        let data = self.data_scaling();
        // With `Rescale::Always` the first point only sets the scaling of the second solve.
        let first_scales = self.settings.rescale == Rescale::Always;
        let mut pass = self.run_pass(&data, first_scales)?;
        let mut passes = 1;
        let mut solve_time = pass.solve_time;
        let mut iterations = pass.iterations;
        let solved =
            |s: SolverStatus| matches!(s, SolverStatus::Solved | SolverStatus::AlmostSolved);
        let mut checks = self.check(&pass.x);
        let all_hold = |c: &[ConstraintCheck]| c.iter().all(|c| c.holds);
        let usable = pass.x.iter().all(|v| v.is_finite());
        let needs = match self.settings.rescale {
            Rescale::Never => false,
            Rescale::Always => usable,
            Rescale::IfNeeded => {
                usable
                    && matches!(
                        pass.status,
                        SolverStatus::Solved
                            | SolverStatus::AlmostSolved
                            | SolverStatus::MaxIterations
                            | SolverStatus::MaxTime
                            | SolverStatus::NumericalError
                            | SolverStatus::InsufficientProgress
                    )
                    && (pass.status != SolverStatus::Solved || !all_hold(&checks))
            }
        };
        if needs {
            let scaling = self.solution_scaling(&pass.x, &data);
            let second = self.run_pass(&scaling, false)?;
            passes += 1;
            solve_time += second.solve_time;
            iterations += second.iterations;
            let second_checks = self.check(&second.x);
            // Keep the second pass unless it is worse: not solved while the first was, and the
            // first is a design (verified, and a full solve, not the Schur method's rough
            // scaling-only pass). On a problem whose optimum is not attained (a bound approached
            // as a matrix variable grows or becomes singular), the first pass ends near the
            // infimum with reduced accuracy and the second, scaled by that point, can break
            // down: the verified first point is then the design. Which of the two breaks down
            // follows the last bits of BLAS, so dropping the first one made such designs fail
            // on some machines and not on others.
            let first_is_design = solved(pass.status)
                && all_hold(&checks)
                && !(first_scales && pass.backend == Backend::Schur);
            if solved(second.status) || !first_is_design {
                pass = second;
                checks = second_checks;
            }
        }
        let info = SolveInfo {
            status: pass.status,
            solve_time,
            total_time: start.elapsed().as_secs_f64(),
            iterations,
            primal_residual: pass.r_prim,
            dual_residual: pass.r_dual,
            backend: pass.backend,
            passes,
            variables: self.n_scalars,
            cone_rows: pass.cone_rows,
            nonzeros: pass.nonzeros,
        };
        match pass.status {
            SolverStatus::Solved | SolverStatus::AlmostSolved => {
                if let Some(worst) = checks.iter().find(|c| !c.holds) {
                    return Err(LmiError::Unverified {
                        status: pass.status,
                        worst: worst.clone(),
                    });
                }
                let worst_margin = checks
                    .iter()
                    .map(|c| c.min_eig / (1.0 + c.norm))
                    .fold(f64::INFINITY, f64::min);
                let objective = self
                    .objective
                    .as_ref()
                    .map_or(0.0, |(o, _)| o.eval(&pass.x)[(0, 0)]);
                let values = self
                    .vars
                    .iter()
                    .enumerate()
                    .map(|(i, v)| (v.name.clone(), self.var_value(i, &pass.x)))
                    .collect::<HashMap<_, _>>();
                Ok(Outcome::Solved(Design {
                    objective,
                    values,
                    checks,
                    worst_margin,
                    info,
                }))
            }
            SolverStatus::PrimalInfeasible | SolverStatus::AlmostPrimalInfeasible => {
                Ok(Outcome::Infeasible(info))
            }
            SolverStatus::DualInfeasible | SolverStatus::AlmostDualInfeasible => {
                Ok(Outcome::Unbounded(info))
            }
            _ => Ok(Outcome::Failed(info)),
        }
    }
}

/// CSC matrix from triplets, summing duplicates.
fn csc_from_triplets(
    m: usize,
    n: usize,
    rows: Vec<usize>,
    cols: Vec<usize>,
    vals: Vec<f64>,
) -> CscMatrix<f64> {
    let mut order: Vec<usize> = (0..vals.len()).collect();
    order.sort_unstable_by_key(|&k| (cols[k], rows[k]));
    let mut colptr = vec![0usize; n + 1];
    let mut rowval = Vec::with_capacity(vals.len());
    let mut nzval: Vec<f64> = Vec::with_capacity(vals.len());
    let mut last: Option<(usize, usize)> = None;
    for k in order {
        let key = (cols[k], rows[k]);
        if last == Some(key) {
            if let Some(v) = nzval.last_mut() {
                *v += vals[k];
            }
        } else {
            rowval.push(rows[k]);
            nzval.push(vals[k]);
            colptr[cols[k] + 1] += 1;
            last = Some(key);
        }
    }
    for j in 0..n {
        colptr[j + 1] += colptr[j];
    }
    CscMatrix::new(m, n, colptr, rowval, nzval)
}
