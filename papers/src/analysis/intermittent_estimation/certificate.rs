//! The matrix inequalities of Theorem 3.4 / Proposition 3.5 as LMI problems
//! in `P` and `R_ik` for fixed gains and σ, solved with
//! [`hybsim::design::lmi`].
//!
//! `M(ν) = He(diag(P, R(ν)) A_f) − σ diag(0, R(ν))` is affine in
//! `(P, R_ik)` for fixed ν. Proposition 3.5 imposes `M(ν) ≺ 0` at `ν = 0`
//! and `ν = T2`. (`M` is affine in `(e^{σν_1}, …, e^{σν_N})`, so `M ≺ 0` on
//! the whole box 𝒯 needs all `2^N` vertices; the paper's two diagonal
//! vertices suffice for `N = 1`. Both sets are offered, see [`Vertices`].)
//!
//! Two problems are solved, because the inequalities are homogeneous in
//! `(P, R)`:
//! - **feasibility**: `P ⪰ I`, `R_ik ⪰ I`, `M(ν) ⪯ −ε I` at every vertex (a
//!   solution scales to any other; ε > 0 makes it strict);
//! - **margin**: minimize `t` subject to `M(ν) ⪯ t I`, `P ⪰ 0`, `R_ik ⪰ 0`,
//!   `tr P + Σ tr R_ik = 1`. The optimum `t*` is negative exactly when a
//!   strict solution exists; its size says how far from (in)feasible.

use nalgebra::DMatrix;

use super::Network;
use hybsim::design::lmi::{Expr, LmiError, Outcome, Problem, Relation, SolverStatus, VarKind};

/// Where in the timer box 𝒯 the inequality `M(ν) ≺ 0` is imposed.
#[derive(Debug, Clone, PartialEq)]
pub enum Vertices {
    /// Proposition 3.5: `ν = 0` and `ν = T2 = (T2^1, …, T2^N)`.
    Paper,
    /// All `2^N` vertices of 𝒯 (each `ν_k ∈ {0, T2^k}`).
    Box,
    /// The given points only.
    Points(Vec<Vec<f64>>),
}

/// The result of [`Network::check_prop_3_5`] at one σ.
#[derive(Debug, Clone, PartialEq)]
pub struct Prop35 {
    /// σ.
    pub sigma: f64,
    /// The feasibility problem (`P ⪰ I`, `R_ik ⪰ I`, `M ⪯ −ε I`): a verified
    /// [`Outcome::Solved`] design (variables `P`, `R1`, `R2`, … in edge
    /// order) or the solver's infeasibility certificate / failure.
    pub feasibility: Outcome,
    /// Optimal `t*` of the trace-normalized margin problem (`None` when that
    /// solve did not reach an optimum; see `margin_status`).
    pub margin: Option<f64>,
    /// Solver status of the margin problem.
    pub margin_status: SolverStatus,
}

impl Prop35 {
    /// The feasibility problem was solved: a certificate `(P, R_ik)` exists.
    pub fn certified(&self) -> bool {
        matches!(self.feasibility, Outcome::Solved(_))
    }
}

impl Network {
    /// The points ν of `vertices`, each a vector of N timer values.
    pub fn timer_points(&self, vertices: &Vertices) -> Vec<Vec<f64>> {
        let n = self.agents();
        match vertices {
            Vertices::Paper => vec![vec![0.0; n], self.t2().to_vec()],
            Vertices::Box => (0..1usize << n)
                .map(|mask| {
                    (0..n)
                        .map(|k| {
                            if mask >> k & 1 == 1 {
                                self.t2()[k]
                            } else {
                                0.0
                            }
                        })
                        .collect()
                })
                .collect(),
            Vertices::Points(p) => p.clone(),
        }
    }

    /// `M(ν)` of (22) as an affine expression in the variables `p` (nN×nN)
    /// and `r[e]` (n×n, one per edge in edge order).
    pub fn m_expr(&self, p: &Expr, r: &[Expr], sigma: f64, nu: &[f64]) -> Result<Expr, LmiError> {
        let edges = self.edges();
        let d = edges.len();
        let diag = |blocks: Vec<Expr>| -> Result<Expr, LmiError> {
            let m = blocks.len();
            let rows: Vec<Vec<Option<Expr>>> = blocks
                .into_iter()
                .enumerate()
                .map(|(i, b)| {
                    let mut row = vec![None; m];
                    row[i] = Some(b);
                    row
                })
                .collect();
            Expr::blocks(&rows)
        };
        let r_nu = diag(
            edges
                .iter()
                .zip(r)
                .map(|(e, ri)| ri.scale((sigma * nu[e.k]).exp()))
                .collect(),
        )?;
        debug_assert_eq!(r_nu.shape().0, d * self.n());
        let ne = p.shape().0;
        let w = diag(vec![p.clone(), r_nu.clone()])?;
        let wa = w.right_mul(&self.a_f())?;
        let s = Expr::blocks(&[
            vec![Some(Expr::zeros(ne, ne)), None],
            vec![None, Some(r_nu.scale(sigma))],
        ])?;
        wa.add(&wa.transpose())?.sub(&s)
    }

    /// Proposition 3.5 at one σ over `vertices`: the feasibility problem with
    /// strictness `eps` and the margin problem (see the module docs).
    pub fn check_prop_3_5(
        &self,
        sigma: f64,
        vertices: &Vertices,
        eps: f64,
    ) -> Result<Prop35, LmiError> {
        let points = self.timer_points(vertices);
        let (n, ne) = (self.n(), self.n() * self.agents());
        let d = self.edges().len();

        // Feasibility: P ⪰ I, R ⪰ I, M ⪯ −ε I.
        let mut prob = Problem::new();
        let p = prob.add_variable("P", VarKind::Symmetric(ne))?;
        let r = (1..=d)
            .map(|e| prob.add_variable(&format!("R{e}"), VarKind::Symmetric(n)))
            .collect::<Result<Vec<_>, _>>()?;
        prob.constrain_between("P ⪰ I", &p, &Expr::identity(ne), Relation::PosSemiDef)?;
        for (e, ri) in r.iter().enumerate() {
            prob.constrain_between(
                &format!("R{} ⪰ I", e + 1),
                ri,
                &Expr::identity(n),
                Relation::PosSemiDef,
            )?;
        }
        for nu in &points {
            let m = self.m_expr(&p, &r, sigma, nu)?;
            let dim = m.shape().0;
            prob.constrain_between(
                &format!("M({nu:?}) ⪯ −εI"),
                &m,
                &Expr::identity(dim).scale(-eps),
                Relation::NegSemiDef,
            )?;
        }
        let feasibility = prob.solve()?;

        // Margin: min t s.t. M ⪯ t I, P, R ⪰ 0, tr P + Σ tr R = 1.
        let mut prob = Problem::new();
        let p = prob.add_variable("P", VarKind::Symmetric(ne))?;
        let r = (1..=d)
            .map(|e| prob.add_variable(&format!("R{e}"), VarKind::Symmetric(n)))
            .collect::<Result<Vec<_>, _>>()?;
        let t = prob.add_variable("t", VarKind::Scalar)?;
        prob.constrain("P ⪰ 0", &p, Relation::PosSemiDef)?;
        let mut trace = p.trace()?;
        for (e, ri) in r.iter().enumerate() {
            prob.constrain(&format!("R{} ⪰ 0", e + 1), ri, Relation::PosSemiDef)?;
            trace = trace.add(&ri.trace()?)?;
        }
        prob.constrain_between("normalization", &trace, &Expr::scalar(1.0), Relation::Zero)?;
        for nu in &points {
            let m = self.m_expr(&p, &r, sigma, nu)?;
            let dim = m.shape().0;
            let t_i = t.kron_left(&DMatrix::identity(dim, dim));
            prob.constrain_between(&format!("M({nu:?}) ⪯ tI"), &m, &t_i, Relation::NegSemiDef)?;
        }
        prob.minimize(&t)?;
        let (margin, margin_status) = match prob.solve()? {
            Outcome::Solved(design) => (Some(design.objective), design.info.status),
            Outcome::Infeasible(i) | Outcome::Unbounded(i) | Outcome::Failed(i) => (None, i.status),
        };
        Ok(Prop35 {
            sigma,
            feasibility,
            margin,
            margin_status,
        })
    }
}
