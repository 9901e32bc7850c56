//! The cargo-fuzz targets' bodies (`hybsim::fuzz::Target`) on their seed
//! corpus, on the stable toolchain: every model shipped or used by the tests
//! (`models/`, `models/lib/`, `benches/models/`, `tests/models/`) and every
//! input kept in `fuzz/regressions/` (what fuzzing or the mutation test
//! found, minimized), through each target. The coverage-guided search itself
//! needs `cargo fuzz` (README, "Hostile input").

use std::path::{Path, PathBuf};

use hybsim::fuzz::{Budget, Input, Outcome, Target};

fn seeds() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut out = Vec::new();
    for dir in [
        "models",
        "models/lib",
        "benches/models",
        "tests/models",
        "fuzz/regressions",
    ] {
        let mut found: Vec<PathBuf> = std::fs::read_dir(root.join(dir))
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.is_file())
            .collect();
        found.sort();
        out.extend(found);
    }
    out
}

#[test]
fn every_seed_passes_every_fuzz_target() {
    let seeds = seeds();
    assert!(seeds.len() >= 25, "{seeds:?}");
    let mut failures = Vec::new();
    for path in &seeds {
        let data = std::fs::read(path).unwrap();
        for target in Target::ALL {
            if let Err(v) = target.exercise(&data) {
                failures.push(format!("{} on {}: {v}", target.name(), path.display()));
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn seeds_carry_overrides_and_tables() {
    // The framed seeds (`%%set`, `%%table`; hybsim::fuzz::Input) reach the override and table
    // paths: a valid table runs, the hostile ones are refused with located errors.
    let inputs: Vec<(PathBuf, Input)> = seeds()
        .into_iter()
        .filter_map(|p| Input::from_bytes(&std::fs::read(&p).unwrap()).map(|i| (p, i)))
        .collect();
    assert!(
        inputs.iter().any(|(_, i)| i.overrides.len() >= 5),
        "no seed with overrides"
    );
    let tables: Vec<&(PathBuf, Input)> = inputs
        .iter()
        .filter(|(_, i)| !i.tables.is_empty())
        .collect();
    assert!(tables.len() >= 3, "{tables:?}");
    for (path, input) in tables {
        let r = input.run(&Budget::default());
        let ok = path.file_name().unwrap().to_string_lossy().contains("_ok");
        assert_eq!(
            matches!(r, Ok(Outcome::Ran { .. })),
            ok,
            "{}: {r:?}",
            path.display()
        );
        assert!(r.is_ok(), "{}: {r:?}", path.display());
    }
    // The framing reads back.
    let (_, i) = inputs.iter().find(|(_, i)| !i.tables.is_empty()).unwrap();
    assert_eq!(Input::from_bytes(&i.to_bytes()).as_ref(), Some(i));
}

/// The text of fuzz target `name`, calling `hybsim::fuzz::Target::{variant}`. Each file of
/// `fuzz/fuzz_targets/` must be exactly this: the fuzz crate is a workspace of its own, which the
/// root's `cargo clippy` does not lint and whose lint would need a second build of hybsim and
/// libFuzzer; with the bodies in `hybsim::fuzz` (linted at the root), the targets hold only this
/// template (checked lint-clean with `cargo clippy --manifest-path fuzz/Cargo.toml`, README).
fn target_text(name: &str, variant: &str) -> String {
    format!(
        "//! Fuzz target `{name}`: the input (a model, `%%set` overrides, `%%table` files: `hybsim::fuzz::Input`)
//! through `hybsim::fuzz::Target::{variant}` (the body the seed-corpus test in tests/it/fuzz_corpus.rs
//! runs on stable; this file is that test's template, so it holds nothing else to lint).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {{
    if let Err(v) = hybsim::fuzz::Target::{variant}.exercise(data) {{
        panic!(\"{{v}}\");
    }}
}});
"
    )
}

#[test]
fn the_fuzz_crate_has_one_target_per_stage() {
    // fuzz/Cargo.toml and fuzz/fuzz_targets/ name the same targets as hybsim::fuzz::Target, and
    // each target is the template.
    let fuzz = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz");
    let manifest = std::fs::read_to_string(fuzz.join("Cargo.toml")).unwrap();
    let files = std::fs::read_dir(fuzz.join("fuzz_targets"))
        .unwrap()
        .count();
    assert_eq!(files, Target::ALL.len());
    for target in Target::ALL {
        let name = target.name();
        assert!(manifest.contains(&format!("name = \"{name}\"")), "{name}");
        let body = std::fs::read_to_string(fuzz.join(format!("fuzz_targets/{name}.rs"))).unwrap();
        assert_eq!(body, target_text(name, &format!("{target:?}")), "{name}");
    }
}
