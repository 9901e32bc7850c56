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

/// The README's Rust code blocks, each the text between `// README begin` and `// README end` of
/// an example that `cargo test` compiles (`examples/readme_*.rs`), so that neither can change
/// without the other; the examples' binaries are run too where this build made them (a whole
/// `cargo test`, as CI runs it) and must succeed.
#[test]
fn the_readme_rust_blocks_are_compiled_examples() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
    let blocks: Vec<String> = readme
        .split("```rust\n")
        .skip(1)
        .map(|b| b.split("```").next().unwrap().to_string())
        .collect();
    let mut shown = Vec::new();
    for name in ["readme_property_tests.rs", "readme_rust_system.rs"] {
        let src = std::fs::read_to_string(root.join("examples").join(name)).unwrap();
        let body = src
            .split("// README begin\n")
            .nth(1)
            .and_then(|r| r.split("    // README end").next())
            .unwrap_or_else(|| panic!("{name}: no README markers"));
        let code: String = body
            .lines()
            .map(|l| format!("{}\n", l.strip_prefix("    ").unwrap_or(l)))
            .collect();
        assert!(
            blocks.contains(&code),
            "README.md shows no ```rust block equal to examples/{name}'s:\n{code}"
        );
        shown.push(code);
        let exe = std::env::current_exe().unwrap();
        let profile_dir = exe.parent().and_then(|d| d.parent()).unwrap();
        let bin = profile_dir
            .join("examples")
            .join(name.trim_end_matches(".rs"));
        if bin.exists() {
            let out = std::process::Command::new(&bin).output().unwrap();
            assert!(
                out.status.success(),
                "{}:\n{}",
                bin.display(),
                String::from_utf8_lossy(&out.stderr)
            );
        }
    }
    for b in &blocks {
        assert!(
            shown.contains(b),
            "README.md's ```rust block is no example's:\n{b}"
        );
    }
}
