//! Distributed state estimation under intermittent, asynchronous
//! transmissions (Phillips, Erwin, Sanfelice): the network data, the
//! matrices of the error/θ coordinates and the matrix inequality of
//! Theorem 3.4.
//!
//! A plant `ẋ = A x` is observed by `N` agents over a directed graph with
//! self-loops; edge `(i, k)` means that agent `i` *receives from* agent `k`.
//! Agent `k` has a timer `τ_k` (`τ̇_k = −1`, reset into `[T1, T2]` when it
//! reaches 0). At that jump it measures `y_k = H_k x` and sends `y_k` and
//! its estimate `x̂_k` to every `i` with `(i, k) ∈ E`, whose memory state
//! jumps by (9):
//!
//! ```text
//! η_ik⁺ = K_ik (H_k x̂_k − y_k) + γ (x̂_i − x̂_k)
//! ```
//!
//! Between jumps `x̂̇_i = A x̂_i + Σ_k η_ik` and `η̇_ik = h_ik η_ik` (6), (8).
//!
//! In the coordinates (10) `e_i = x̂_i − x`,
//! `θ_ik = K_ik H_k e_k + γ (e_i − e_k) − η_ik` the flow is linear,
//! `χ̇ = A_f χ` with `χ = (e, θ)` and (19)
//!
//! ```text
//! A_f = [ A_θ                 −𝒟         ]
//!       [ K_θ A_θ − h K_θ     h − K_θ 𝒟  ]
//! ```
//!
//! and a jump of agent `k` keeps `e` and sets `θ_ik = 0` for its receivers.
//! Here `L` is the ordinary Laplacian (self-loops do not enter it: the
//! self-loop term `γ (e_i − e_i)` of (11) vanishes), `𝒟` sums the θ's of
//! each agent, and θ is stacked by `i`, then by `k` ascending (Example 3.1).
//!
//! The state of the hybrid system in original coordinates is laid out as
//! `[x, x̂_1 … x̂_N, η_e for e in edges(), τ_1 … τ_N]`; see [`Layout`].

use nalgebra::{DMatrix, DVector};
use thiserror::Error;

mod certificate;
pub use certificate::{Prop35, Vertices};

/// Wrong shapes or values in the data of a [`Network`].
#[derive(Debug, Clone, PartialEq, Error)]
pub enum NetworkError {
    /// `A` is not square.
    #[error("the plant matrix A is {rows}×{cols}, not square")]
    PlantNotSquare {
        /// Rows of A.
        rows: usize,
        /// Columns of A.
        cols: usize,
    },
    /// A matrix has the wrong shape.
    #[error("{what} is {found:?} (rows × cols), expected {expected:?}")]
    Shape {
        /// Which matrix (e.g. `H_2`, `K_13`).
        what: String,
        /// Expected (rows, cols).
        expected: (usize, usize),
        /// Found (rows, cols).
        found: (usize, usize),
    },
    /// The graph lacks the self-loop of agent `agent` (1-based).
    #[error("the graph has no self-loop at agent {agent}; the protocol needs (i, i) ∈ E")]
    MissingSelfLoop {
        /// Agent (1-based).
        agent: usize,
    },
    /// Timer bounds not `0 < T1 ≤ T2` (finite) for agent `agent` (1-based).
    #[error("agent {agent}: timer bounds T1 = {t1}, T2 = {t2} must satisfy 0 < T1 ≤ T2 < ∞")]
    TimerBounds {
        /// Agent (1-based).
        agent: usize,
        /// Lower bound.
        t1: f64,
        /// Upper bound.
        t2: f64,
    },
    /// A gain, rate or matrix entry is NaN or infinite.
    #[error("{what} is not finite")]
    NotFinite {
        /// Which value.
        what: String,
    },
}

/// The three scenarios of Example 3.8 / Fig. 2.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scenario {
    /// (a) all-to-all graph.
    AllToAll,
    /// (b) edges (2, 1) and (3, 2) removed (`g_21 = g_32 = 0`).
    EdgesRemoved,
    /// (c) all-to-all, but agent 2 measures nothing (`H_2 = 0`).
    Agent2Blind,
}

impl Scenario {
    /// All three, in the order of Fig. 2.
    pub const ALL: [Scenario; 3] = [
        Scenario::AllToAll,
        Scenario::EdgesRemoved,
        Scenario::Agent2Blind,
    ];

    /// The letter of the sub-figure: `a`, `b` or `c`.
    pub fn letter(self) -> char {
        match self {
            Scenario::AllToAll => 'a',
            Scenario::EdgesRemoved => 'b',
            Scenario::Agent2Blind => 'c',
        }
    }
}

/// Observer gains of one edge `(i, k)`.
#[derive(Debug, Clone, PartialEq)]
pub struct EdgeGains {
    /// Receiving agent `i` (0-based).
    pub i: usize,
    /// Sending agent `k` (0-based).
    pub k: usize,
    /// `K_ik`, n × p_k.
    pub k_gain: DMatrix<f64>,
    /// `h_ik`, the decay rate of `η_ik` between jumps.
    pub h: f64,
}

/// Where each part of the state sits in the original coordinates
/// `[x, x̂_1 … x̂_N, η_e (e in edge order), τ_1 … τ_N]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layout {
    /// Plant dimension n.
    pub n: usize,
    /// Number of agents N.
    pub agents: usize,
    /// Number of edges |E| (self-loops included).
    pub edges: usize,
}

impl Layout {
    /// Index of the first component of `x`.
    pub fn x(&self) -> usize {
        0
    }
    /// Index of the first component of `x̂_i` (0-based agent).
    pub fn xhat(&self, i: usize) -> usize {
        self.n * (1 + i)
    }
    /// Index of the first component of `η` of edge number `e`.
    pub fn eta(&self, e: usize) -> usize {
        self.n * (1 + self.agents + e)
    }
    /// Index of `τ_i` (0-based agent).
    pub fn tau(&self, i: usize) -> usize {
        self.n * (1 + self.agents + self.edges) + i
    }
    /// Total state dimension.
    pub fn dim(&self) -> usize {
        self.n * (1 + self.agents + self.edges) + self.agents
    }
}

/// The data of the estimation network: plant, outputs, graph, gains and
/// timer bounds. Build with [`Network::new`] (validated) or
/// [`Network::paper_example`].
#[derive(Debug, Clone, PartialEq)]
pub struct Network {
    a: DMatrix<f64>,
    outputs: Vec<DMatrix<f64>>,
    /// Edges `(i, k)` in θ order (by `i`, then `k` ascending), with gains.
    edges: Vec<EdgeGains>,
    gamma: f64,
    t1: Vec<f64>,
    t2: Vec<f64>,
}

impl Network {
    /// A network with plant `a` (n×n), output matrices `outputs[k]` (p_k×n),
    /// edges with their gains (any order; self-loops required), consensus
    /// gain `gamma` and timer bounds `t1[k] ≤ t2[k]`.
    pub fn new(
        a: DMatrix<f64>,
        outputs: Vec<DMatrix<f64>>,
        mut edges: Vec<EdgeGains>,
        gamma: f64,
        t1: Vec<f64>,
        t2: Vec<f64>,
    ) -> Result<Self, NetworkError> {
        let n = a.nrows();
        if a.ncols() != n {
            return Err(NetworkError::PlantNotSquare {
                rows: n,
                cols: a.ncols(),
            });
        }
        finite("A", a.iter())?;
        finite("γ", [gamma].iter())?;
        let agents = outputs.len();
        for (k, h) in outputs.iter().enumerate() {
            if h.ncols() != n {
                return Err(NetworkError::Shape {
                    what: format!("H_{}", k + 1),
                    expected: (h.nrows(), n),
                    found: h.shape(),
                });
            }
            finite(&format!("H_{}", k + 1), h.iter())?;
        }
        for (which, v) in [("T1", &t1), ("T2", &t2)] {
            if v.len() != agents {
                return Err(NetworkError::Shape {
                    what: which.into(),
                    expected: (agents, 1),
                    found: (v.len(), 1),
                });
            }
        }
        for k in 0..agents {
            if !(t1[k] > 0.0 && t1[k] <= t2[k] && t2[k].is_finite()) {
                return Err(NetworkError::TimerBounds {
                    agent: k + 1,
                    t1: t1[k],
                    t2: t2[k],
                });
            }
        }
        for e in &edges {
            let name = format!("K_{}{}", e.i + 1, e.k + 1);
            if e.i >= agents || e.k >= agents {
                return Err(NetworkError::Shape {
                    what: format!("edge ({}, {})", e.i + 1, e.k + 1),
                    expected: (agents, agents),
                    found: (e.i + 1, e.k + 1),
                });
            }
            let expected = (n, outputs[e.k].nrows());
            if e.k_gain.shape() != expected {
                return Err(NetworkError::Shape {
                    what: name,
                    expected,
                    found: e.k_gain.shape(),
                });
            }
            finite(&name, e.k_gain.iter())?;
            finite(&format!("h_{}{}", e.i + 1, e.k + 1), [e.h].iter())?;
        }
        edges.sort_by_key(|e| (e.i, e.k));
        edges.dedup_by_key(|e| (e.i, e.k));
        for i in 0..agents {
            if !edges.iter().any(|e| e.i == i && e.k == i) {
                return Err(NetworkError::MissingSelfLoop { agent: i + 1 });
            }
        }
        Ok(Self {
            a,
            outputs,
            edges,
            gamma,
            t1,
            t2,
        })
    }

    /// Example 3.8 with the reconstructed gains (the printed list is garbled;
    /// see `models/intermittent_estimation.hyb` and `REPRODUCTION.md`):
    /// every `K_ik` entry ≤ 0 (the printed positive entries 1.2, 0.3 of
    /// `K_11`, 1 of `K_22` and 0.4 of `K_33` read as having lost their minus
    /// sign), `h_11 = −1`, `h_21 = −0.5`, `h_23 = −0.4`, all other
    /// `h_ik = −0.1`, `γ = −0.3`, `T1 = 0.1`, `T2 = 0.7`.
    pub fn paper_example(scenario: Scenario) -> Self {
        let a = DMatrix::from_row_slice(3, 3, &[0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        let mut outputs = vec![
            DMatrix::from_row_slice(1, 3, &[1.0, 1.0, 0.0]),
            DMatrix::from_row_slice(1, 3, &[0.0, 1.0, 0.0]),
            DMatrix::from_row_slice(1, 3, &[0.0, 0.0, 1.0]),
        ];
        if scenario == Scenario::Agent2Blind {
            outputs[1] = DMatrix::zeros(1, 3);
        }
        let gains: [((usize, usize), [f64; 3], f64); 9] = [
            ((1, 1), [-1.2, -0.9, -0.3], -1.0),
            ((1, 2), [0.0, -0.1, -0.3], -0.1),
            ((1, 3), [-0.1, -0.4, -0.1], -0.1),
            ((2, 1), [-0.5, -0.1, -0.1], -0.5),
            ((2, 2), [-1.0, -0.1, -0.4], -0.1),
            ((2, 3), [-0.3, -0.1, -0.3], -0.4),
            ((3, 1), [-0.2, -0.5, -1.0], -0.1),
            ((3, 2), [-0.2, -0.1, -0.1], -0.1),
            ((3, 3), [-0.4, -0.2, -0.1], -0.1),
        ];
        let removed = |i: usize, k: usize| {
            scenario == Scenario::EdgesRemoved && matches!((i, k), (2, 1) | (3, 2))
        };
        let edges = gains
            .iter()
            .filter(|((i, k), _, _)| !removed(*i, *k))
            .map(|&((i, k), kk, h)| EdgeGains {
                i: i - 1,
                k: k - 1,
                k_gain: DMatrix::from_column_slice(3, 1, &kk),
                h,
            })
            .collect();
        Self::new(a, outputs, edges, -0.3, vec![0.1; 3], vec![0.7; 3])
            .expect("the paper's example is well formed")
    }

    /// Plant dimension n.
    pub fn n(&self) -> usize {
        self.a.nrows()
    }
    /// Number of agents N.
    pub fn agents(&self) -> usize {
        self.outputs.len()
    }
    /// The plant matrix A.
    pub fn a(&self) -> &DMatrix<f64> {
        &self.a
    }
    /// Output matrix `H_k` (0-based agent).
    pub fn output(&self, k: usize) -> &DMatrix<f64> {
        &self.outputs[k]
    }
    /// Edges with gains, in θ order (by receiver `i`, then sender `k`).
    pub fn edges(&self) -> &[EdgeGains] {
        &self.edges
    }
    /// The consensus gain γ.
    pub fn gamma(&self) -> f64 {
        self.gamma
    }
    /// Lower timer bounds `T1^i`.
    pub fn t1(&self) -> &[f64] {
        &self.t1
    }
    /// Upper timer bounds `T2^i`.
    pub fn t2(&self) -> &[f64] {
        &self.t2
    }
    /// Where each part of the original state sits.
    pub fn layout(&self) -> Layout {
        Layout {
            n: self.n(),
            agents: self.agents(),
            edges: self.edges.len(),
        }
    }
    /// Whether `(i, k) ∈ E` (0-based).
    pub fn has_edge(&self, i: usize, k: usize) -> bool {
        self.edges.iter().any(|e| e.i == i && e.k == k)
    }

    /// The Laplacian L (N×N) of the graph without self-loops:
    /// `ℓ_ii = Σ_{k≠i} g_ik`, `ℓ_ik = −g_ik`.
    pub fn laplacian(&self) -> DMatrix<f64> {
        let mut l = DMatrix::zeros(self.agents(), self.agents());
        for e in self.edges.iter().filter(|e| e.i != e.k) {
            l[(e.i, e.i)] += 1.0;
            l[(e.i, e.k)] -= 1.0;
        }
        l
    }

    /// `A_θ = I ⊗ A + K_𝒢 + γ (L ⊗ I)` (nN × nN) of (12): `ė = A_θ e − 𝒟 θ`.
    pub fn a_theta(&self) -> DMatrix<f64> {
        let n = self.n();
        let mut m = self.laplacian().kronecker(&DMatrix::identity(n, n)) * self.gamma;
        for i in 0..self.agents() {
            let mut b = m.view_mut((i * n, i * n), (n, n));
            b += &self.a;
        }
        for e in &self.edges {
            let mut b = m.view_mut((e.i * n, e.k * n), (n, n));
            b += &e.k_gain * &self.outputs[e.k];
        }
        m
    }

    /// `𝒟` (nN × n|E|): row block `i` sums the θ_ik of agent `i`.
    pub fn d_cal(&self) -> DMatrix<f64> {
        let n = self.n();
        let mut m = DMatrix::zeros(n * self.agents(), n * self.edges.len());
        for (r, e) in self.edges.iter().enumerate() {
            m.view_mut((e.i * n, r * n), (n, n))
                .copy_from(&DMatrix::identity(n, n));
        }
        m
    }

    /// `K_θ = K̄ H + γ Π` (n|E| × nN) of (13): `θ = K_θ e − η`.
    pub fn k_theta(&self) -> DMatrix<f64> {
        let n = self.n();
        let mut m = DMatrix::zeros(n * self.edges.len(), n * self.agents());
        let g = DMatrix::<f64>::identity(n, n) * self.gamma;
        for (r, e) in self.edges.iter().enumerate() {
            let mut b = m.view_mut((r * n, e.k * n), (n, n));
            b += &e.k_gain * &self.outputs[e.k];
            b -= &g;
            let mut b = m.view_mut((r * n, e.i * n), (n, n));
            b += &g;
        }
        m
    }

    /// `h = diag(h_ik I_n)` (n|E| × n|E|).
    pub fn h_matrix(&self) -> DMatrix<f64> {
        let n = self.n();
        let diag: Vec<f64> = self
            .edges
            .iter()
            .flat_map(|e| std::iter::repeat_n(e.h, n))
            .collect();
        DMatrix::from_diagonal(&DVector::from_vec(diag))
    }

    /// `A_f` of (19): the flow matrix of `χ = (e, θ)`.
    pub fn a_f(&self) -> DMatrix<f64> {
        let (at, d, kt, h) = (
            self.a_theta(),
            self.d_cal(),
            self.k_theta(),
            self.h_matrix(),
        );
        let (ne, nt) = (at.nrows(), h.nrows());
        let mut m = DMatrix::zeros(ne + nt, ne + nt);
        m.view_mut((0, 0), (ne, ne)).copy_from(&at);
        m.view_mut((0, ne), (ne, nt)).copy_from(&(-&d));
        m.view_mut((ne, 0), (nt, ne))
            .copy_from(&(&kt * &at - &h * &kt));
        m.view_mut((ne, ne), (nt, nt)).copy_from(&(&h - &kt * &d));
        m
    }

    /// The flow matrix F of the original coordinates, `ż = F z + b` with
    /// `b = −1` on the timers and 0 elsewhere (returned as `(F, b)`).
    pub fn flow_matrix(&self) -> (DMatrix<f64>, DVector<f64>) {
        let l = self.layout();
        let n = l.n;
        let mut f = DMatrix::zeros(l.dim(), l.dim());
        for block in 0..=l.agents {
            f.view_mut((block * n, block * n), (n, n))
                .copy_from(&self.a);
        }
        for (r, e) in self.edges.iter().enumerate() {
            for c in 0..n {
                f[(l.xhat(e.i) + c, l.eta(r) + c)] = 1.0;
                f[(l.eta(r) + c, l.eta(r) + c)] = e.h;
            }
        }
        let mut b = DVector::zeros(l.dim());
        for i in 0..l.agents {
            b[l.tau(i)] = -1.0;
        }
        (f, b)
    }

    /// The jump map G_k of (5), (9) in original coordinates: agent `k`
    /// (0-based) transmits; `tau_plus` is the chosen element of `[T1, T2]`.
    /// Writes `z⁺` into `out` (same length as `z`).
    pub fn transmit(&self, k: usize, z: &[f64], tau_plus: f64, out: &mut [f64]) {
        let l = self.layout();
        let n = l.n;
        out.copy_from_slice(z);
        let x = DVector::from_column_slice(&z[l.x()..l.x() + n]);
        let xk = DVector::from_column_slice(&z[l.xhat(k)..l.xhat(k) + n]);
        let innovation = &self.outputs[k] * &xk - &self.outputs[k] * &x;
        for (r, e) in self.edges.iter().enumerate().filter(|(_, e)| e.k == k) {
            let xi = DVector::from_column_slice(&z[l.xhat(e.i)..l.xhat(e.i) + n]);
            let eta = &e.k_gain * &innovation + (&xi - &xk) * self.gamma;
            out[l.eta(r)..l.eta(r) + n].copy_from_slice(eta.as_slice());
        }
        out[l.tau(k)] = tau_plus;
    }

    /// The coordinates (10) of an original state `z`: `(e, θ)`.
    pub fn error_coordinates(&self, z: &[f64]) -> (DVector<f64>, DVector<f64>) {
        let l = self.layout();
        let n = l.n;
        let x = DVector::from_column_slice(&z[..n]);
        let mut e = DVector::zeros(n * l.agents);
        for i in 0..l.agents {
            let xi = DVector::from_column_slice(&z[l.xhat(i)..l.xhat(i) + n]);
            e.rows_mut(i * n, n).copy_from(&(xi - &x));
        }
        let eta = DVector::from_column_slice(&z[l.eta(0)..l.eta(0) + n * l.edges]);
        let theta = self.k_theta() * &e - eta;
        (e, theta)
    }

    /// `R(ν)` of Theorem 3.4: block-diagonal with `exp(σ ν_k) R_ik` for edge
    /// `(i, k)` (the exponent uses the *sender's* timer: θ_ik is reset when
    /// τ_k reaches 0). `r` holds one n×n block per edge, in edge order.
    pub fn r_of(&self, r: &[DMatrix<f64>], sigma: f64, nu: &[f64]) -> DMatrix<f64> {
        let n = self.n();
        let mut m = DMatrix::zeros(n * self.edges.len(), n * self.edges.len());
        for (idx, e) in self.edges.iter().enumerate() {
            m.view_mut((idx * n, idx * n), (n, n))
                .copy_from(&(&r[idx] * (sigma * nu[e.k]).exp()));
        }
        m
    }

    /// `M(ν)` of (22) for given `P`, `R_ik`, σ:
    /// `He(diag(P, R(ν)) A_f) − σ diag(0, R(ν))`.
    pub fn m_of(
        &self,
        p: &DMatrix<f64>,
        r: &[DMatrix<f64>],
        sigma: f64,
        nu: &[f64],
    ) -> DMatrix<f64> {
        let rn = self.r_of(r, sigma, nu);
        let (ne, nt) = (p.nrows(), rn.nrows());
        let mut w = DMatrix::zeros(ne + nt, ne + nt);
        w.view_mut((0, 0), (ne, ne)).copy_from(p);
        w.view_mut((ne, ne), (nt, nt)).copy_from(&rn);
        let wa = &w * self.a_f();
        let mut m = &wa + wa.transpose();
        let mut b = m.view_mut((ne, ne), (nt, nt));
        b -= rn * sigma;
        m
    }

    /// The Lyapunov function (21) at original state `z`:
    /// `V = eᵀ P e + θᵀ R(τ) θ`.
    pub fn lyapunov(&self, p: &DMatrix<f64>, r: &[DMatrix<f64>], sigma: f64, z: &[f64]) -> f64 {
        let l = self.layout();
        let tau: Vec<f64> = (0..l.agents).map(|i| z[l.tau(i)]).collect();
        let (e, theta) = self.error_coordinates(z);
        let rn = self.r_of(r, sigma, &tau);
        (e.transpose() * p * &e)[(0, 0)] + (theta.transpose() * rn * &theta)[(0, 0)]
    }
}

fn finite<'a>(what: &str, values: impl Iterator<Item = &'a f64>) -> Result<(), NetworkError> {
    let mut values = values;
    if values.any(|v| !v.is_finite()) {
        return Err(NetworkError::NotFinite { what: what.into() });
    }
    Ok(())
}

#[cfg(test)]
mod tests;
