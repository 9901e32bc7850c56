//! The cargo-fuzz targets' bodies (`hybsim::fuzz::Target`) on their seed
//! corpus, on the stable toolchain: every model shipped or used by the tests
//! (`models/`, `models/lib/`, `benches/models/`, `tests/models/`) and every
//! input kept in `fuzz/regressions/` (what fuzzing or the mutation test
//! found, minimized), through each target; and a bounded coverage-guided
//! search with libFuzzer (`scripts/fuzz`, README "Hostile input") on the
//! `run` target.

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
/// `fuzz/fuzz_targets/` must be exactly this: the fuzz crate is not a default member of the
/// workspace, so the root's `cargo clippy` does not lint it, and its lint would need a check build
/// of hybsim and libFuzzer; with the bodies in `hybsim::fuzz` (linted at the root), the targets
/// hold only this template (checked lint-clean with `cargo clippy --release -p hybsim-fuzz`,
/// README).
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

/// Seconds of coverage-guided search per `cargo test` (README, "Hostile input"); `HYBSIM_FUZZ_SECS`
/// changes it.
const SEARCH_SECS: u64 = 60;

/// Edges instrumented at least: hybsim's (94 000 in the release profile), not only the target's.
const MIN_EDGES: u64 = 40_000;
/// Edges the seeds cover at least (17 000 in the release profile).
const MIN_SEED_COVERAGE: u64 = 8_000;
/// The crates the search may compile: hybsim and the target (instrumented) and libFuzzer; every
/// other is the test build's (fuzz/Cargo.toml), which keeps the search's cost in CI to one
/// compilation of hybsim.
const COMPILED: &[&str] = &["hybsim", "hybsim-fuzz", "libfuzzer-sys", "arbitrary"];

/// A libFuzzer status line's counter `name` (`#81\tINITED cov: 5678 ft: 12345 corp: …`).
fn status(line: &str, name: &str) -> Option<u64> {
    let mut words = line.split_whitespace();
    words.find(|w| *w == format!("{name}:"))?;
    words.next()?.parse().ok()
}

#[test]
fn a_bounded_coverage_guided_search_finds_no_failure() {
    // scripts/fuzz on the `run` target (check, compile and a bounded run: the stages of the other
    // three targets too), built in this test binary's target folder and profile: only hybsim and
    // the target are compiled again, instrumented (scripts/fuzz-rustc). A fresh corpus folder, so
    // that the search starts from the seeds on every run.
    let secs: u64 = std::env::var("HYBSIM_FUZZ_SECS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(SEARCH_SECS);
    let (target, profile) = crate::util::target_and_profile();
    let corpus = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = crate::util::nested_cargo(root.join("scripts/fuzz"))
        .args([&secs.to_string(), "run"])
        .env("CARGO_TARGET_DIR", &target)
        .env("HYBSIM_FUZZ_PROFILE", &profile)
        .env("HYBSIM_FUZZ_CORPUS", corpus.path())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    let tail: Vec<&str> = err
        .lines()
        .rev()
        .take(80)
        .collect::<Vec<_>>()
        .into_iter()
        .rev()
        .collect();
    let tail = tail.join("\n");
    // An input over libFuzzer's 20-s limit is a hang: the targets' resource limits
    // (hybsim::fuzz::Budget::instrumented) refuse the sizes that instrumentation makes slow.
    // A failing input: its path and how to reproduce it are in the last lines (scripts/fuzz).
    assert!(out.status.success(), "scripts/fuzz failed:\n{tail}");
    let compiled: Vec<&str> = err
        .lines()
        .filter_map(|l| {
            l.trim_start()
                .strip_prefix("Compiling ")?
                .split_whitespace()
                .next()
        })
        .collect();
    assert!(
        compiled.iter().all(|c| COMPILED.contains(c)),
        "the fuzz build compiled dependencies again ({compiled:?}): make fuzz/Cargo.toml enable \
         the features the test build enables on them"
    );
    // The coverage counters are live: hybsim itself is instrumented (94 000 edges in the release
    // profile; the target's own code is a few lines), the seeds reach many of them, and the search
    // found inputs with new coverage.
    let edges = err
        .lines()
        .find_map(|l| {
            let rest = l.strip_prefix("INFO: Loaded 1 modules")?;
            rest.trim_start()
                .trim_start_matches('(')
                .split_whitespace()
                .next()?
                .parse::<u64>()
                .ok()
        })
        .unwrap_or(0);
    let line = |tag: &str| err.lines().find(|l| l.contains(tag)).unwrap_or("");
    let (inited, done) = (line("INITED"), line("DONE"));
    let stat = |name: &str| {
        err.lines()
            .find_map(|l| l.strip_prefix(&format!("stat::{name}:")))
            .and_then(|v| v.trim().parse::<u64>().ok())
            .unwrap_or(0)
    };
    let seeds = seeds().len() as u64;
    eprintln!(
        "coverage-guided search, {secs} s: {edges} edges instrumented; {inited}; {done}; {} runs, {} new inputs",
        stat("number_of_executed_units"),
        stat("new_units_added")
    );
    assert!(
        edges >= MIN_EDGES,
        "{edges} edges: hybsim not instrumented?\n{tail}"
    );
    let (cov0, ft0) = (status(inited, "cov"), status(inited, "ft"));
    let (cov1, ft1) = (status(done, "cov"), status(done, "ft"));
    assert!(
        cov0.is_some_and(|c| c >= MIN_SEED_COVERAGE),
        "{inited}\n{tail}"
    );
    assert!(
        ft1 > ft0 && cov1 >= cov0,
        "no new coverage: {inited} -> {done}"
    );
    assert!(stat("new_units_added") > 0, "{tail}");
    assert!(stat("number_of_executed_units") > 2 * seeds, "{tail}");
}

/// The fuzz targets' own resource limits (`Budget::instrumented`) refuse, with a limit's located
/// error, the designs that instrumentation makes slow (the shipped platoon model went over
/// libFuzzer's 20-s limit on a loaded machine), and still solve the small ones.
#[test]
fn the_fuzz_targets_refuse_the_slow_designs_at_once() {
    use hybsim::lang::{self, CheckOptions};
    let options = CheckOptions {
        limits: Budget::instrumented().limits,
        ..CheckOptions::default()
    };
    let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("models");
    for (name, refused) in [
        ("platoon.hyb", true),
        ("intermittent_estimation.hyb", true),
        ("cooperative_estimation.hyb", false),
        ("appendix_f.hyb", false),
    ] {
        let path = models.join(name);
        let src = hybsim::source::SourceFile::read(&path).unwrap();
        let diags = lang::check_only_with(&src, &[], &options);
        assert_eq!(
            diags.iter().any(|d| d.code == "E0307"),
            refused,
            "{name}: {diags:?}"
        );
        assert_eq!(diags.is_empty(), !refused, "{name}: {diags:?}");
        let outcome = Target::Run.exercise(&std::fs::read(&path).unwrap());
        assert_eq!(
            matches!(outcome, Ok(Outcome::Rejected { .. })),
            refused,
            "{name}: {outcome:?}"
        );
    }
}
