//! `hybsim fmt`: every shipped model, formatted, compiles to a model that
//! gives the same arc bit for bit; the command rewrites, checks and refuses
//! as documented.

use std::path::Path;

use hybsim::lang::{self, Override};
use hybsim::source::SourceFile;
use hybsim::syntax::format_source;

use crate::util::{code, hybsim, simulate_arc, stderr, stdout};

/// The model's arc over a short horizon (the same for both texts).
fn short_arc(src: &SourceFile) -> Result<String, String> {
    let ov: Vec<Override> = ["T=0.5", "J=40"]
        .iter()
        .map(|s| s.parse().unwrap())
        .collect();
    let m = lang::compile(src, &ov).map_err(|d| hybsim::diagnostics::render(&d, src, false))?;
    let (x0, mut rng) = m.start(m.seed());
    let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng).map_err(|e| e.to_string())?;
    // Debug formatting prints every bit of every f64 (shortest round trip).
    Ok(format!("{arc:?}"))
}

#[test]
fn formatted_shipped_models_give_the_same_arcs() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("models");
    let mut n = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "hyb") {
            continue;
        }
        let src = SourceFile::read(&path).unwrap();
        let formatted = format_source(src.text()).unwrap();
        let fsrc = SourceFile::new(src.name(), formatted);
        assert_eq!(
            short_arc(&fsrc),
            short_arc(&src),
            "{}: formatting changed the arc",
            path.display()
        );
        n += 1;
    }
    assert!(n >= 8, "only {n} models");
}

#[test]
fn fmt_rewrites_checks_and_refuses_broken_files() {
    let dir = tempfile::tempdir().unwrap();
    let messy = dir.path().join("m.hyb");
    std::fs::write(&messy, "model m\nstate x=1   # decay\nflow{x'=-x}\n").unwrap();
    let m = messy.to_str().unwrap();
    let check = hybsim(dir.path(), &["fmt", "--check", m]);
    assert_eq!(code(&check), 1);
    assert!(
        stdout(&check).contains("would reformat"),
        "{}",
        stdout(&check)
    );
    assert_eq!(
        std::fs::read_to_string(&messy).unwrap(),
        "model m\nstate x=1   # decay\nflow{x'=-x}\n",
        "--check changed the file"
    );
    assert_eq!(code(&hybsim(dir.path(), &["fmt", m])), 0);
    assert_eq!(
        std::fs::read_to_string(&messy).unwrap(),
        // The comment keeps its column only where the wider code leaves two spaces.
        "model m\nstate x = 1  # decay\nflow { x' = -x }\n"
    );
    assert_eq!(code(&hybsim(dir.path(), &["fmt", "--check", m])), 0);

    let broken = dir.path().join("b.hyb");
    std::fs::write(&broken, "model b\nstate x = \n").unwrap();
    let out = hybsim(dir.path(), &["fmt", broken.to_str().unwrap(), m]);
    assert_eq!(code(&out), 2);
    assert!(stderr(&out).contains("b.hyb:"), "{}", stderr(&out));
    assert_eq!(
        std::fs::read_to_string(&broken).unwrap(),
        "model b\nstate x = \n"
    );
    assert_eq!(code(&hybsim(dir.path(), &["fmt"])), 2);
}

#[test]
fn every_shipped_model_is_fmt_clean() {
    // `hybsim fmt --check` passes on what the repository ships (the arcs of formatted models are
    // those of the originals: `formatted_shipped_models_give_the_same_arcs`).
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut n = 0;
    for dir in ["models", "models/lib", "benches/models", "tests/models"] {
        for entry in std::fs::read_dir(root.join(dir)).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_none_or(|e| e != "hyb") {
                continue;
            }
            let text = std::fs::read_to_string(&path).unwrap();
            let formatted = format_source(&text).unwrap();
            assert!(
                formatted == text,
                "{} is not fmt-clean:\n{formatted}",
                path.display()
            );
            n += 1;
        }
    }
    assert!(n >= 20, "only {n} models");
}

#[test]
fn a_parenthesis_after_a_property_word_keeps_its_space_as_after_a_keyword() {
    let model = |prop: &str| {
        format!("model m\nstate x = 1, j = 0\nflow {{ x' = -x }}\nproperty p: {prop}\n")
    };
    for prop in [
        "always (j / 3 - 1) >= -1",
        "always(j / 3 - 1) >= -1",
        "eventually within (2) x <= 1",
        "decreasing (x) during flows",
    ] {
        let text = model(prop);
        assert_eq!(format_source(&text).unwrap(), text, "{prop}");
    }
    // `then`/`else` starting a line continue the `if`: indented one step.
    let text = model("always if x > 0\nthen x <= 1\n        else x >= -1");
    assert_eq!(
        format_source(&text).unwrap(),
        model("always if x > 0\n    then x <= 1\n    else x >= -1")
    );
    // A name before `(` is a call, written without the space.
    assert_eq!(
        format_source(&model("always abs (x) >= 0")).unwrap(),
        model("always abs(x) >= 0")
    );
}
