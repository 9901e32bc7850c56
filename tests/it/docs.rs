//! The API documentation builds without a rustdoc warning (broken or private intra-doc links,
//! bad HTML, bare URLs, …): `cargo doc -p hybsim --no-deps` with `RUSTDOCFLAGS=-D warnings`.
//!
//! rustdoc's lints run only in rustdoc, so no attribute at the crate root makes `cargo build`
//! enforce them, and rustdoc needs the dependencies' metadata of its own (check) build. The run
//! shares the target folder and profile of this test binary, so it costs ~10 s where `cargo
//! clippy` of the same profile already ran (the fast profile of the edit-test cycle), and about
//! 3 minutes once on a fresh target folder (2 loaded cores), e.g. the first `cargo test --release`.

use std::path::PathBuf;
use std::process::Command;

/// (target folder, profile) of the running test binary (`target/PROFILE/deps/it-…`).
fn target_and_profile() -> (PathBuf, String) {
    let exe = std::env::current_exe().unwrap();
    let profile_dir = exe.parent().and_then(|d| d.parent()).unwrap();
    let name = profile_dir
        .file_name()
        .unwrap()
        .to_string_lossy()
        .into_owned();
    let profile = if name == "debug" { "dev".into() } else { name };
    (profile_dir.parent().unwrap().to_path_buf(), profile)
}

#[test]
fn the_api_docs_build_without_warnings() {
    let (target, profile) = target_and_profile();
    let out = Command::new(env!("CARGO"))
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
