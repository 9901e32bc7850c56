//! Links OpenBLAS (which clarabel's SDP cones and `design::lmi` use) from its
//! static archive when the system has one.
//!
//! `openblas-src` links the shared library. Loading it costs every process
//! ~8 M cycles (2–3 ms) before `main`: its ~14 000 symbolic relocations (the
//! kernel tables of every CPU it supports) are resolved one by one, more than
//! a small model's whole run. Linked from the archive they are resolved by
//! the linker. The archive's objects come before the shared library on the
//! link line, so the linker takes every symbol from them and `--as-needed`
//! drops the shared library. Without an archive (or pkg-config) nothing
//! changes: the shared library is linked as before.
use std::path::Path;

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-env-changed=HYBSIM_SHARED_OPENBLAS");
    if std::env::var_os("HYBSIM_SHARED_OPENBLAS").is_some()
        || std::env::var("CARGO_CFG_TARGET_OS").as_deref() != Ok("linux")
    {
        return;
    }
    let Ok(dir) = pkg_config::get_variable("openblas", "libdir") else {
        return;
    };
    let dir = dir.trim_end_matches('/');
    if dir.is_empty() || !Path::new(dir).join("libopenblas.a").is_file() {
        return;
    }
    println!("cargo:rustc-link-search=native={dir}");
    println!("cargo:rustc-link-lib=static:-bundle=openblas");
    // The archive's own dependencies (its LAPACK is Fortran), which the
    // shared library would have brought.
    println!("cargo:rustc-link-lib=dylib=gfortran");
    println!("cargo:rustc-link-lib=dylib=pthread");
    println!("cargo:rustc-link-lib=dylib=m");
}
