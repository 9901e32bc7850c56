//! # hybsim
//!
//! Simulation, design and property testing of hybrid dynamical systems
//! (flows in a set C, jumps in a set D, solutions on hybrid time domains).
#![warn(missing_docs)]

// clarabel's SDP support links BLAS/LAPACK; this pulls in the system OpenBLAS.
extern crate openblas_src;

pub mod analysis;
pub mod arc;
pub mod atomic_file;
pub mod check;
pub mod design;
pub mod diagnostics;
pub mod engine;
pub mod fuzz;
pub mod imports;
pub mod ir;
pub mod lang;
pub mod layout;
pub mod linalg;
pub mod num;
pub mod props;
pub mod sinks;
pub mod source;
pub mod sweep;
pub mod syntax;
pub mod tables;
