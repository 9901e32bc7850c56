//! The API documentation builds without a rustdoc warning (broken or private intra-doc links,
//! bad HTML, bare URLs, …): `cargo doc -p hybsim --no-deps` with `RUSTDOCFLAGS=-D warnings`.
//!
//! rustdoc's lints run only in rustdoc, so no attribute at the crate root makes `cargo build`
//! enforce them, and rustdoc needs the dependencies' metadata of its own (check) build. The run
//! shares the target folder and profile of this test binary, so it costs ~10 s where `cargo
//! clippy` of the same profile already ran (the fast profile of the edit-test cycle), and about
//! 3 minutes once on a fresh target folder (2 loaded cores), e.g. the first `cargo test --release`.

use crate::util::{nested_cargo, target_and_profile};

#[test]
fn the_api_docs_build_without_warnings() {
    let (target, profile) = target_and_profile();
    let out = nested_cargo(env!("CARGO"))
        .args(["doc", "-p", "hybsim", "--no-deps", "--profile", &profile])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env("CARGO_TARGET_DIR", &target)
        .env("RUSTDOCFLAGS", "-D warnings")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "cargo doc failed:\n{err}");
    assert!(!err.contains("warning"), "{err}");
}
