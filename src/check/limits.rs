//! Resource limits: every size that grows with a model's parameters is estimated by the checker
//! before anything of that size is allocated, and refused (E0308) with the quantity, its
//! estimate, the limit and the construct that caused it.
//!
//! The defaults fit a 2-core, 24 GB machine: each keeps the allocation it guards to a few GB and
//! the work to minutes at most. A limit is raised (or lowered) with `max_<name> = N` (a number)
//! in the model's `sim` block, or `--set max_<name>=N` on the command line.

use std::fmt;

/// The quantities with a limit, in the order of [`Limits::TABLE`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Quantity {
    /// Scalar decision variables of one `design` block.
    DesignVars,
    /// Constraint blocks (LMIs) of one `design` block.
    LmiBlocks,
    /// Rows of one LMI block.
    LmiSize,
    /// Conic rows of one `design` block: Σ d(d+1)/2 over its LMI blocks (the solvers' work per
    /// iteration grows with it).
    LmiRows,
    /// Scalar states of the model.
    States,
    /// Entries of one matrix: limited for `eye`, `zeros`, `ones` and `table("…")`; for a
    /// product, `kron`, `diag` or `blkdiag` (whose work `ops` bounds) only against the memory.
    Elements,
    /// Members of one family (`param`, `state`, `output` families) or iterations of one loop.
    Iterations,
    /// Scalar operations the checker may perform (unrolled loops, matrix products).
    Ops,
    /// Samples on the output grid (T / dt_out).
    OutputPoints,
    /// Integrator steps forced by `max_step` or a fixed-step solver's `h` (T / max_step, T / h).
    Steps,
}

impl Quantity {
    /// The name of the limit (`max_<name>` in `sim` and `--set`).
    pub fn key(self) -> &'static str {
        Limits::TABLE[self as usize].1
    }

    /// What is counted, in words.
    pub fn words(self) -> &'static str {
        Limits::TABLE[self as usize].2
    }

    /// A lower bound of the bytes that `n` of this quantity take once built (the checker's
    /// nodes and the run's vectors), for the quantities that are held in memory; `None` for the
    /// budgets of time (`ops`, `step_count`) and what is streamed (`output_points`).
    pub fn bytes(self, n: f64) -> Option<f64> {
        match self {
            // The design's Schur matrix: m² doubles.
            Quantity::DesignVars => Some(8.0 * n * n),
            // A dense block: d² doubles.
            Quantity::LmiSize => Some(8.0 * n * n),
            // The checker's nodes and the engine's state vectors (state, steps, buffers).
            Quantity::States => Some(200.0 * n),
            // A node id per entry, and as much again to walk them.
            Quantity::Elements => Some(8.0 * n),
            // A member's index list.
            Quantity::Iterations => Some(32.0 * n),
            Quantity::LmiBlocks
            | Quantity::LmiRows
            | Quantity::Ops
            | Quantity::OutputPoints
            | Quantity::Steps => None,
        }
    }

    /// What makes it smaller.
    pub fn remedy(self) -> &'static str {
        match self {
            Quantity::OutputPoints => "a larger `dt_out` (or a shorter horizon T)",
            Quantity::Steps => "a larger `max_step` or `h` (or a shorter horizon T)",
            Quantity::Iterations => "a shorter range",
            _ => "smaller dimensions or fewer family members",
        }
    }
}

impl fmt::Display for Quantity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.words())
    }
}

/// The limits of one check (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    values: [u64; 10],
}

impl Default for Limits {
    fn default() -> Self {
        let mut values = [0; 10];
        for (i, row) in Self::TABLE.iter().enumerate() {
            values[i] = row.3;
        }
        Self { values }
    }
}

impl Limits {
    /// (quantity, key, words, default). Sizes: a design's Schur matrix is m² doubles
    /// (20 000 variables: 3.2 GB per copy); a dense LMI block of 2 000 rows is 32 MB and its
    /// eigen-decompositions seconds; the implicit solver's Jacobian is n² doubles (20 000
    /// states: 3.2 GB).
    pub const TABLE: [(Quantity, &'static str, &'static str, u64); 10] = [
        (
            Quantity::DesignVars,
            "design_vars",
            "scalar decision variables of a design",
            20_000,
        ),
        (
            Quantity::LmiBlocks,
            "lmi_blocks",
            "constraint blocks of a design",
            4_096,
        ),
        (
            Quantity::LmiSize,
            "lmi_size",
            "rows of one constraint block",
            2_000,
        ),
        (
            Quantity::LmiRows,
            "lmi_rows",
            "conic rows (Σ d(d+1)/2 over the constraint blocks) of a design",
            200_000,
        ),
        (Quantity::States, "states", "scalar states", 20_000),
        (
            Quantity::Elements,
            "matrix_elements",
            "entries of one matrix",
            1_000_000,
        ),
        (
            Quantity::Iterations,
            "iterations",
            "family members or loop iterations",
            1_000_000,
        ),
        (
            Quantity::Ops,
            "ops",
            "scalar operations to compile",
            50_000_000,
        ),
        (
            Quantity::OutputPoints,
            "output_points",
            "output grid points (T / dt_out)",
            10_000_000,
        ),
        (
            Quantity::Steps,
            "step_count",
            "integrator steps forced by max_step or a fixed step h (T / max_step, T / h)",
            1_000_000_000,
        ),
    ];

    /// The limit of `q`.
    pub fn get(&self, q: Quantity) -> u64 {
        self.values[q as usize]
    }

    /// Sets the limit of `q`.
    pub fn set(&mut self, q: Quantity, value: u64) {
        self.values[q as usize] = value;
    }

    /// The quantity named `key` (`design_vars`, …; also `max_design_vars`).
    pub fn quantity(key: &str) -> Option<Quantity> {
        let key = key.strip_prefix("max_").unwrap_or(key);
        Self::TABLE.iter().find(|r| r.1 == key).map(|r| r.0)
    }

    /// The limit names, comma-separated.
    pub fn names() -> String {
        Self::TABLE
            .iter()
            .map(|r| r.1)
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// The sizes a run's settings force relative to its horizon, as (`sim` key, quantity, estimate):
/// the output grid `T / dt_out`, the steps `T / max_step` and a fixed-step solver's `T / h`.
/// The checker limits them for the model's `sim` block and `--set`; settings changed after
/// the check (`hybsim run --solver/--step`, Python's `run(**kw)`) are held to the same limits.
pub fn forced_sizes(s: &crate::engine::SimSettings) -> Vec<(&'static str, Quantity, f64)> {
    use crate::engine::Solver;
    let fixed_step = match s.solver {
        Solver::Rk4 { h } | Solver::EulerMaruyama { h } => Some(h),
        _ => None,
    };
    [
        ("dt_out", Quantity::OutputPoints, s.dt_out),
        ("max_step", Quantity::Steps, Some(s.max_step)),
        ("h", Quantity::Steps, fixed_step),
    ]
    .into_iter()
    .filter_map(|(key, q, dt)| {
        let dt = dt.filter(|d| d.is_finite())?;
        Some((key, q, (s.horizon_t / dt).ceil()))
    })
    .collect()
}

/// The memory a check may plan for: the machine's physical memory, or the process's
/// address-space limit (`ulimit -v`) when lower; `None` where neither is known. A size whose
/// limit was raised past what this holds is refused (E0307) before it is allocated: an
/// allocation that fails aborts the process, one the system overcommits gets it killed.
pub(crate) fn memory_ceiling() -> Option<u64> {
    #[cfg(unix)]
    {
        // SAFETY: sysconf and getrlimit read process and system parameters into plain values.
        let (pages, page) = unsafe {
            (
                libc::sysconf(libc::_SC_PHYS_PAGES),
                libc::sysconf(libc::_SC_PAGESIZE),
            )
        };
        let ram = (pages > 0 && page > 0).then(|| (pages as u64).saturating_mul(page as u64));
        let mut rl = libc::rlimit {
            rlim_cur: 0,
            rlim_max: 0,
        };
        // SAFETY: `rl` is a valid rlimit for getrlimit to fill.
        let ok = unsafe { libc::getrlimit(libc::RLIMIT_AS, &mut rl) } == 0;
        let address_space = (ok && rl.rlim_cur != libc::RLIM_INFINITY).then_some(rl.rlim_cur);
        match (ram, address_space) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }
    #[cfg(not(unix))]
    {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_table() {
        let mut l = Limits::default();
        assert_eq!(l.get(Quantity::States), 20_000);
        assert_eq!(
            Limits::quantity("max_lmi_blocks"),
            Some(Quantity::LmiBlocks)
        );
        assert_eq!(Limits::quantity("max_step"), None, "a sim key, not a limit");
        l.set(Quantity::States, 100_000);
        assert_eq!(l.get(Quantity::States), 100_000);
        for (i, row) in Limits::TABLE.iter().enumerate() {
            assert_eq!(row.0 as usize, i, "TABLE in the order of Quantity");
            assert_eq!(row.0.key(), row.1);
            // Every default fits a few GB where the size is held in memory.
            let default = row.0.bytes(row.3 as f64).unwrap_or(0.0);
            assert!(default <= 4e9, "{}: {default} bytes", row.1);
        }
        assert!(memory_ceiling().is_some_and(|m| m > 1 << 28));
    }
}
