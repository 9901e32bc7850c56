//! The cargo-fuzz targets' bodies (`hybsim::fuzz::Target`) on their seed
//! corpus, on the stable toolchain: every model shipped or used by the tests
//! (`models/`, `models/lib/`, `benches/models/`, `tests/models/`) and every
//! input kept in `fuzz/regressions/` (what fuzzing or the mutation test
//! found, minimized), through each target. The coverage-guided search itself
//! needs `cargo fuzz` (README, "Hostile input").

use std::path::{Path, PathBuf};

use hybsim::fuzz::Target;

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
fn the_fuzz_crate_has_one_target_per_stage() {
    // fuzz/Cargo.toml and fuzz/fuzz_targets/ name the same targets as hybsim::fuzz::Target.
    let fuzz = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz");
    let manifest = std::fs::read_to_string(fuzz.join("Cargo.toml")).unwrap();
    for target in Target::ALL {
        let name = target.name();
        assert!(manifest.contains(&format!("name = \"{name}\"")), "{name}");
        let body = std::fs::read_to_string(fuzz.join(format!("fuzz_targets/{name}.rs"))).unwrap();
        assert!(
            body.contains(&format!("{target:?}.exercise(data)")),
            "{name}"
        );
    }
}
