//! The editor grammar (`editors/vscode`): its annotated test files pass
//! `vscode-tmgrammar-test`, and it scopes every token of every shipped model.
//! The npm tools are installed by `scripts/setup`.

use std::path::{Path, PathBuf};
use std::process::Command;

fn editor_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("editors/vscode")
}

/// Runs `program args…` in the editor folder; panics with its output unless it succeeds.
fn run_ok(program: &str, args: &[String]) {
    let dir = editor_dir();
    assert!(
        dir.join("node_modules/vscode-tmgrammar-test").is_dir(),
        "the grammar's npm tools are missing: run scripts/setup"
    );
    let out = Command::new(program)
        .args(args)
        .current_dir(&dir)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {program}: {e} (run scripts/setup)"));
    assert!(
        out.status.success(),
        "{program} {args:?} failed:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Every `.hyb` file under `dir`, recursively.
fn hyb_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("readable folder") {
        let path = entry.expect("entry").path();
        if path.is_dir() {
            hyb_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "hyb") {
            out.push(path);
        }
    }
}

#[test]
fn grammar_passes_its_annotated_tests() {
    run_ok(
        "node_modules/.bin/vscode-tmgrammar-test",
        &[
            "-g".into(),
            "syntaxes/hyb.tmLanguage.json".into(),
            "tests/*.hyb".into(),
        ],
    );
}

#[test]
fn grammar_scopes_every_token_of_every_shipped_model() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    for dir in [
        "models",
        "benches/models",
        "tests/models",
        "editors/vscode/tests",
    ] {
        hyb_files(&root.join(dir), &mut files);
    }
    assert!(files.len() > 10, "found only {files:?}");
    let mut args = vec!["tests/coverage.js".to_string()];
    args.extend(files.iter().map(|f| f.display().to_string()));
    run_ok("node", &args);
}
