//! Exact flows of affine systems `ẋ = A x + b` whose solutions are
//! polynomials in time: `A` structurally nilpotent (no cycle in the graph
//! of its nonzero entries: a bouncing ball, chains of integrators, clocks).
//! Then `x(s₀ + h) = Σₖ hᵏ/k! Gᵏ [x(s₀); 1]` with `G = [[A, b], [0, 0]]`
//! ends at the longest chain of dependencies, so a step is a few sparse
//! products instead of a matrix exponential or a solver's stages, its path
//! is exact, and its Bernstein control points let the watcher decide every
//! affine guard on the step exactly.

use super::events::{MAX_CONTROL, StepPath, at_step_end, bernstein_points};

/// The exact polynomial flow of `ẋ = A x + b` with `A` structurally
/// nilpotent, and the coefficients of its current step.
#[derive(Debug, Clone)]
pub(crate) struct PolynomialFlow {
    n: usize,
    /// Degree of the solution in time: the longest chain of dependencies
    /// (`xᵣ` on `x꜀` for `A[r, c] ≠ 0`, on a constant for `b[r] ≠ 0`).
    degree: usize,
    /// Nonzero entries of `A`, row after row: `(row, column, value)`.
    a: Vec<(usize, usize, f64)>,
    /// Nonzero entries of `b`.
    b: Vec<(usize, f64)>,
    /// Rows of `A` or `b` with a nonzero entry (the components that move).
    active: Vec<usize>,
    /// The current step's coefficients in the step's own variable
    /// `u = (s − s₀)/h ∈ [0, 1]`, component after component (each one's
    /// polynomial contiguous, as Horner's rule and the control points read
    /// it): `d[i·(degree + 1) + k] = hᵏ/k! (Gᵏ [x(s₀); 1])ᵢ` (zero for
    /// k ≥ 1 outside `active`).
    d: Vec<f64>,
}

impl PolynomialFlow {
    /// The polynomial flow of `ẋ = A x + b` (`a` row-major n × n), if `A`
    /// is structurally nilpotent and the solutions have degree below
    /// [`MAX_CONTROL`]; `None` otherwise (a cycle, such as an oscillator or
    /// a decay `ẋ = −x`, makes the solution a true exponential).
    #[cfg(test)]
    pub fn new(n: usize, a: &[f64], b: &[f64]) -> Option<Self> {
        debug_assert_eq!((a.len(), b.len()), (n * n, n));
        let entries: Vec<(usize, usize, f64)> = (0..n)
            .flat_map(|r| (0..=n).map(move |c| (r, c)))
            .filter_map(|(r, c)| {
                let v = if c < n { a[r * n + c] } else { b[r] };
                (v != 0.0).then_some((r, c, v))
            })
            .collect();
        Self::from_entries(n, &entries)
    }

    /// The same from the nonzero entries `(row, column, value)` of
    /// `[A, b]` (column n is b), row after row.
    pub fn from_entries(n: usize, entries: &[(usize, usize, f64)]) -> Option<Self> {
        let (a, b): (Vec<_>, Vec<_>) = entries.iter().partition(|&&(_, c, _)| c < n);
        let b: Vec<(usize, f64)> = b.into_iter().map(|(r, _, v)| (r, v)).collect();
        let degree = chain_degrees(n, &a, &b)?;
        let max = degree.iter().copied().max().unwrap_or(0);
        if max >= MAX_CONTROL {
            return None;
        }
        let active = (0..n).filter(|&r| degree[r] > 0).collect();
        Some(Self {
            n,
            degree: max,
            a,
            b,
            active,
            d: vec![0.0; (max + 1) * n],
        })
    }

    /// Degree of the solutions in time.
    #[cfg(test)]
    pub fn degree(&self) -> usize {
        self.degree
    }

    /// Sets the step of length `h` from `y0`: its Taylor coefficients
    /// `d₀ = y0`, `d₁ = h (A y0 + b)`, `dₖ₊₁ = h/(k+1) · A dₖ`.
    pub fn set_step(&mut self, y0: &[f64], h: f64) {
        // As `eval_at`: the common degrees with rows of a constant length.
        match self.degree {
            1 => self.set_step_of(2, y0, h),
            2 => self.set_step_of(3, y0, h),
            3 => self.set_step_of(4, y0, h),
            _ => self.set_step_of(self.degree + 1, y0, h),
        }
    }

    /// [`set_step`](Self::set_step) with rows of `w` coefficients (a
    /// constant where inlined).
    #[inline(always)]
    fn set_step_of(&mut self, w: usize, y0: &[f64], h: f64) {
        let d = &mut self.d;
        for (row, &y) in d.chunks_exact_mut(w).zip(&y0[..self.n]) {
            row[0] = y;
        }
        for k in 1..w {
            for &r in &self.active {
                d[r * w + k] = 0.0;
            }
            if k == 1 {
                for &(r, v) in &self.b {
                    d[r * w + 1] = v;
                }
            }
            for &(r, c, v) in &self.a {
                let term = v * d[c * w + k - 1];
                d[r * w + k] += term;
            }
            let scale = h / k as f64;
            for &r in &self.active {
                d[r * w + k] *= scale;
            }
        }
    }

    /// The step's state at `u ∈ [0, 1]` (Horner's rule), into `out`.
    /// Inlined into its callers (a checkpoint's state, a localization
    /// trial, a step's end): a few multiply-adds per component, fewer
    /// instructions than the call and its saved registers.
    #[inline(always)]
    pub fn eval_at(&self, u: f64, out: &mut [f64]) {
        // Rows of a constant length for the common degrees: the loops over
        // a row unroll (a loop of a few iterations per component costs
        // more than its arithmetic), the same operations in the same order.
        match self.degree {
            1 => self.eval_rows_of(2, u, out),
            2 => self.eval_rows_of(3, u, out),
            3 => self.eval_rows_of(4, u, out),
            _ => self.eval_rows_of(self.degree + 1, u, out),
        }
    }

    /// [`eval_at`](Self::eval_at) with rows of `w` coefficients (a
    /// constant where inlined).
    #[inline(always)]
    fn eval_rows_of(&self, w: usize, u: f64, out: &mut [f64]) {
        let rows = self.d.chunks_exact(w);
        for (o, row) in out[..self.n].iter_mut().zip(rows) {
            let (&top, lower) = row.split_last().expect("degree + 1 coefficients");
            *o = lower.iter().rev().fold(top, |v, &c| v * u + c);
        }
    }
}

/// The degree in time of each component's solution, `None` if the
/// dependencies have a cycle: `deg(r) = 0` for a row of zeros, else the
/// largest of 1 and `1 + deg(c)` over the columns `c` it reads. Kahn's
/// order over the dependencies, linear in the entries.
fn chain_degrees(
    n: usize,
    entries: &[(usize, usize, f64)],
    b: &[(usize, f64)],
) -> Option<Vec<usize>> {
    // readers[c]: the rows that read c; waiting[r]: columns r still waits for.
    let mut readers: Vec<Vec<usize>> = vec![Vec::new(); n];
    let mut waiting = vec![0usize; n];
    for &(r, c, _) in entries {
        readers[c].push(r);
        waiting[r] += 1;
    }
    let mut degree = vec![0; n];
    for &(r, _) in b {
        degree[r] = 1;
    }
    let mut ready: Vec<usize> = (0..n).filter(|&r| waiting[r] == 0).collect();
    let mut done = 0;
    while let Some(c) = ready.pop() {
        done += 1;
        for &r in &readers[c] {
            degree[r] = degree[r].max(degree[c] + 1);
            waiting[r] -= 1;
            if waiting[r] == 0 {
                ready.push(r);
            }
        }
    }
    (done == n).then_some(degree)
}

/// The exact path of one step of a [`PolynomialFlow`] (set by
/// [`PolynomialFlow::set_step`]), `[s0, s1]` in the segment's local time.
pub(crate) struct PolynomialPath<'a> {
    pub flow: &'a PolynomialFlow,
    pub s0: f64,
    pub s1: f64,
    pub y0: &'a [f64],
    pub y1: &'a [f64],
}

impl StepPath for PolynomialPath<'_> {
    fn eval(&mut self, s: f64, out: &mut [f64]) {
        if !at_step_end(s, (self.s0, self.y0), (self.s1, self.y1), out) {
            self.flow.eval_at((s - self.s0) / (self.s1 - self.s0), out);
        }
    }

    fn control_points(&self, i: usize, out: &mut [f64; MAX_CONTROL]) -> Option<(usize, f64)> {
        let w = self.flow.degree + 1;
        // `eval` is Horner's rule on the same coefficients: within the
        // bound of their sum, as the points are.
        Some(bernstein_points(&self.flow.d[i * w..(i + 1) * w], out))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ball: height quadratic in time, exact at any step length.
    #[test]
    fn a_falling_ball_is_a_parabola() {
        let g = 9.81;
        let mut flow = PolynomialFlow::new(2, &[0.0, 1.0, 0.0, 0.0], &[0.0, -g]).unwrap();
        assert_eq!(flow.degree(), 2);
        let y0 = [1.0, 0.5];
        let h = 0.75;
        flow.set_step(&y0, h);
        let mut y = [0.0; 2];
        for u in [0.0, 0.25, 0.5, 1.0] {
            flow.eval_at(u, &mut y);
            let s = u * h;
            let exact = [1.0 + 0.5 * s - 0.5 * g * s * s, 0.5 - g * s];
            for (v, e) in y.iter().zip(exact) {
                assert!(
                    (v - e).abs() <= 1e-15 * (1.0 + e.abs()),
                    "{v} vs {e} at {s}"
                );
            }
        }
    }

    /// Degrees follow the longest chain; cycles (oscillators, decays) and
    /// chains longer than the control points allow are refused.
    #[test]
    fn only_acyclic_short_chains_are_polynomial() {
        // Chain x0' = x1, x1' = x2, x2' = 1, clock x3' = 1, constant x4.
        let mut a = vec![0.0; 25];
        a[1] = 1.0;
        a[5 + 2] = 1.0;
        let b = [0.0, 0.0, 1.0, 1.0, 0.0];
        let flow = PolynomialFlow::new(5, &a, &b).unwrap();
        assert_eq!(flow.degree(), 3);
        assert_eq!(flow.active, vec![0, 1, 2, 3]);
        assert!(PolynomialFlow::new(2, &[0.0, 1.0, -1.0, 0.0], &[0.0; 2]).is_none());
        assert!(PolynomialFlow::new(1, &[-1.0], &[0.0]).is_none());
        // A chain of n integrators driven by a constant has degree n.
        let chain = |n: usize| {
            let mut a = vec![0.0; n * n];
            for r in 0..n - 1 {
                a[r * n + r + 1] = 1.0;
            }
            let mut b = vec![0.0; n];
            b[n - 1] = 1.0;
            PolynomialFlow::new(n, &a, &b)
        };
        assert_eq!(chain(MAX_CONTROL - 1).unwrap().degree(), MAX_CONTROL - 1);
        assert!(chain(MAX_CONTROL).is_none());
        // No motion at all: degree 0.
        assert_eq!(
            PolynomialFlow::new(2, &[0.0; 4], &[0.0; 2])
                .unwrap()
                .degree(),
            0
        );
    }

    /// The control points give back the path on the step (de Casteljau),
    /// within their bound.
    #[test]
    fn control_points_give_the_path() {
        let mut flow = PolynomialFlow::new(
            3,
            &[0.0, 2.0, 0.0, 0.0, 0.0, -1.5, 0.0, 0.0, 0.0],
            &[0.5, 0.0, 3.0],
        )
        .unwrap();
        let y0 = [1.0, -0.25, 0.5];
        let (s0, s1) = (0.3, 1.1);
        flow.set_step(&y0, s1 - s0);
        let mut y1 = [0.0; 3];
        flow.eval_at(1.0, &mut y1);
        let mut path = PolynomialPath {
            flow: &flow,
            s0,
            s1,
            y0: &y0,
            y1: &y1,
        };
        crate::engine::events::tests::assert_control_points(&mut path, 3, (s0, s1), 4);
    }
}
