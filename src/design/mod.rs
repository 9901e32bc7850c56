//! Design layer: Riccati equations, LQR, system norms, and LMI/SDP synthesis.
//!
//! This module knows nothing of the `.hyb` language; the language calls it.
//!
//! - [`control`]: dense linear-algebra utilities on [`nalgebra::DMatrix<f64>`]:
//!   [`control::expm`], [`control::c2d`], [`control::lyap`], [`control::dlyap`],
//!   [`control::care`], [`control::dare`], [`control::lqr`], [`control::dlqr`],
//!   [`control::h2_norm`], [`control::hinf_norm`].
//! - [`lmi`]: a builder for linear matrix inequality problems (decision variables created by name
//!   and shape at run time, affine matrix expressions, semidefinite constraints, linear objective)
//!   solved with clarabel's positive semidefinite cone, with an a-posteriori check of every
//!   constraint at the returned point.
//! - [`blas`]: OpenBLAS pinned to one thread (the same digits on every machine).

pub mod blas;
pub mod control;
pub mod lmi;
