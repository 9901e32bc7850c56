//! # hybsim-papers
//!
//! Reproductions of published results with [`hybsim`], kept beside the
//! library rather than in its public API: the library holds the general
//! mechanisms (engine, language, design, properties, sweeps, sinks), this
//! crate the per-paper algorithms and experiments built on them.
//!
//! * [`analysis`]: paper algorithms (the variance iteration of Trimpe and
//!   D'Andrea, the network matrices and certificate of Phillips–Erwin–Sanfelice)
//!   and [`analysis::reproduction`], the tables of `REPRODUCTION.md`.
//! * [`experiments`]: the papers' experiments run through the whole pipeline
//!   (`.hyb` → compile with overrides → simulate → per-step table), used by
//!   the reproduction tests (`tests/it/`) and the figure programs
//!   (`examples/`).
//!
//! The models are the repository's `models/*.hyb` ([`model_path`]); the
//! reproduction tests rewrite the repository's `REPRODUCTION.md`
//! ([`analysis::reproduction::committed_path`]).
#![warn(missing_docs)]

use std::path::{Path, PathBuf};

pub mod analysis;
pub mod experiments;

/// The repository's root: the directory of the workspace holding this crate
/// (`models/`, `REPRODUCTION.md`).
pub fn repo_root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("hybsim-papers sits in a subdirectory of the repository")
}

/// Path of a file relative to the repository's root, e.g.
/// `repo_path("models/platoon.hyb")`.
pub fn repo_path(relative: impl AsRef<Path>) -> PathBuf {
    repo_root().join(relative)
}

/// Path of a shipped model, e.g. `model_path("platoon.hyb")` for
/// `models/platoon.hyb`.
///
/// ```
/// let p = hybsim_papers::model_path("variance_triggering.hyb");
/// assert!(p.is_file(), "{}", p.display());
/// ```
pub fn model_path(name: &str) -> PathBuf {
    repo_root().join("models").join(name)
}
