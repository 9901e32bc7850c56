//! Analyses of logged solutions and paper algorithms.
//!
//! * [`intermittent_estimation`]: the network data, error/θ coordinates and
//!   matrix inequality of distributed estimation under intermittent
//!   asynchronous transmissions (Phillips–Erwin–Sanfelice).
//!
//! This module depends only on [`crate::arc`] and nalgebra.

pub mod intermittent_estimation;
