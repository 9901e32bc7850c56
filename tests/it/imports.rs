//! `import` (LANGUAGE.md, "Imports") and the standard library of subsystems
//! in `models/lib/`: each library subsystem against a closed form or an
//! independent computation; each refused import a located error.

use std::path::{Path, PathBuf};

use hybsim::arc::HybridArc;
use hybsim::engine::{check_arc, simulate_arc};
use hybsim::ir::CompiledModel;
use hybsim::lang;
use hybsim::source::SourceFile;

/// A model written beside `models/lib` (not on disk: its name places it).
fn beside_lib(text: &str) -> SourceFile {
    let path: PathBuf = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/test_model.hyb");
    SourceFile::new(path.display().to_string(), text)
}

fn compile(src: &SourceFile) -> CompiledModel {
    match lang::compile(src, &[]) {
        Ok(m) => m,
        Err(d) => panic!("{}", hybsim::diagnostics::render(&d, src, false)),
    }
}

fn run(m: &CompiledModel, seed: u64) -> HybridArc {
    let settings = m.settings();
    let (x0, mut rng) = m.start(seed);
    let arc = simulate_arc(m, &x0, &settings, &mut rng).expect("simulation runs");
    if let Err(v) = check_arc(m, &arc, &settings) {
        panic!("{v}");
    }
    arc
}

/// One (t, pre, post) per jump instant.
fn instants(arc: &HybridArc) -> Vec<(f64, Vec<f64>, Vec<f64>)> {
    let mut out: Vec<(u64, f64, Vec<f64>, Vec<f64>)> = Vec::new();
    for r in arc.jumps() {
        if out.last().is_none_or(|l| l.0 != r.at.j) {
            out.push((r.at.j, r.at.t, r.pre.clone(), r.post.clone()));
        }
    }
    out.into_iter().map(|(_, t, a, b)| (t, a, b)).collect()
}

/// `models/sampled_loop.hyb`, `LinearPlant` + `Adc` + `Zoh` with a gain on
/// the connection: the exact
/// discretisation x_{k+1} = e^{aT} x_k + (e^{aT} − 1)/a · b u_k with
/// u_k = −K x((k−1)T) (the hold takes the pre-jump sample).
#[test]
fn linear_plant_adc_and_zoh_match_the_exact_discretisation() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/sampled_loop.hyb");
    let src = SourceFile::read(path).unwrap();
    let m = compile(&src);
    let arc = run(&m, 1);
    let jumps = instants(&arc);
    assert_eq!(jumps.len(), 20);
    let (a, k, ts) = (0.5_f64, 1.5_f64, 0.1_f64);
    let phi = (a * ts).exp();
    let (mut x, mut xs, mut h) = (1.0_f64, 0.0_f64, 0.0_f64);
    for (t, pre, _) in &jumps {
        x = phi * x + (phi - 1.0) / a * h;
        assert!(
            (pre[0] - x).abs() < 1e-9 * x.abs().max(1.0),
            "x({t}) = {} vs {x}",
            pre[0]
        );
        h = -k * xs;
        xs = x;
    }

    // A matrix plant: the harmonic oscillator, y = cos t (to the default
    // tolerances of the adaptive solver).
    let src = beside_lib(
        "model osc
import \"lib/linear.hyb\"
p = LinearPlant(A = [0, 1; -1, 0], B = [0; 1], C = [1, 0], x0 = [1; 0], u = 0)
sim { T = 2 }
",
    );
    let m = compile(&src);
    let arc = run(&m, 1);
    let last = arc.last().unwrap();
    assert!((last.x[0] - 2.0_f64.cos()).abs() < 1e-6, "{:?}", last.x);
    assert!((last.x[1] + 2.0_f64.sin()).abs() < 1e-6, "{:?}", last.x);
    assert_eq!(m.output_names(), ["p.y"]);
}

/// `Adc` with a quantum: each sample is q·round(t/q) of the input t.
#[test]
fn adc_quantizes_its_samples() {
    let src = beside_lib(
        "model q\nimport \"lib/adc.hyb\"\nstate s = 0\nflow { s' = 1 }\n\
         a = Adc(Ts = 0.5, q = 0.3, u = t)\nsim { T = 4.2 }\n",
    );
    let m = compile(&src);
    let arc = run(&m, 1);
    let jumps = instants(&arc);
    assert_eq!(jumps.len(), 8);
    for (t, _, post) in &jumps {
        let want = 0.3 * (t / 0.3).round();
        assert!(
            (post[1] - want).abs() < 1e-12,
            "sample at {t}: {} vs {want}",
            post[1]
        );
    }
}

/// `RandomTimer`: every period in [T1, T2], `count` counts them, and the
/// mean period over 200 expirations is (T1 + T2)/2 within 5 standard
/// errors.
#[test]
fn random_timer_draws_its_periods_in_its_interval() {
    let src = beside_lib(
        "model timers\nimport \"lib/timer.hyb\"\nclock = RandomTimer(T1 = 1, T2 = 2)\n\
         sim { T = 300; J = 1000 }\n",
    );
    let m = compile(&src);
    for seed in [1, 2] {
        let arc = run(&m, seed);
        let first = arc.samples().next().unwrap().x[0];
        assert!((1.0..=2.0).contains(&first), "{first}");
        let jumps = instants(&arc);
        let mut prev = 0.0;
        let mut periods = Vec::new();
        for (k, (t, pre, post)) in jumps.iter().enumerate() {
            if k > 0 {
                periods.push(t - prev);
            }
            prev = *t;
            assert!(pre[0].abs() < 1e-9, "expires at 0: {pre:?}");
            assert!(
                (1.0..=2.0).contains(&post[0]),
                "redrawn in [1, 2]: {post:?}"
            );
            assert_eq!(post[1], (k + 1) as f64, "count");
        }
        assert!(
            periods
                .iter()
                .all(|p| (1.0 - 1e-9..=2.0 + 1e-9).contains(p))
        );
        let n = periods.len() as f64;
        assert!(n > 150.0, "{n}");
        let mean = periods.iter().sum::<f64>() / n;
        let se = (1.0_f64 / 12.0).sqrt() / n.sqrt();
        assert!((mean - 1.5).abs() < 5.0 * se, "mean period {mean}");
    }
}

/// `LossyLink`: a packet (the input t at the sample) is received with
/// probability 1 − p_drop, else the output keeps the last one received.
#[test]
fn lossy_link_delivers_with_one_minus_the_drop_probability() {
    let model = |p: f64| {
        beside_lib(&format!(
            "model net\nimport \"lib/link.hyb\"\nstate s = 0\nflow {{ s' = 1 }}\n\
             l = LossyLink(Ts = 0.1, p_drop = {p}, u = t)\nsim {{ T = 100.05; J = 2000 }}\n"
        ))
    };
    for (p, lo, hi) in [(0.0, 1.0, 1.0), (1.0, 0.0, 0.0), (0.3, 0.64, 0.76)] {
        let m = compile(&model(p));
        let arc = run(&m, 7);
        let jumps = instants(&arc);
        assert_eq!(jumps.len(), 1000);
        let mut delivered = 0;
        for (t, pre, post) in &jumps {
            if post[1] == *t {
                delivered += 1;
            } else {
                assert_eq!(post[1], pre[1], "a lost packet keeps the output");
            }
        }
        let rate = delivered as f64 / 1000.0;
        assert!((lo..=hi).contains(&rate), "p_drop = {p}: delivered {rate}");
    }
}

/// A folder with a model importing `rest` and the files `files`.
fn folder(files: &[(&str, &str)]) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    for (name, text) in files {
        let p = dir.path().join(name);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, text).unwrap();
    }
    dir
}

fn errors_of(path: &Path) -> String {
    let src = SourceFile::read(path).unwrap();
    let d = lang::check_only(&src, &[]);
    assert!(!d.is_empty(), "no error for {}", path.display());
    hybsim::diagnostics::render(&d, &src, false)
}

#[test]
fn refused_imports_are_located_errors() {
    let sub = "subsystem S() { state x = 0; flow { x' = 1 } }\n";
    let dir = folder(&[
        ("m/lib/s.hyb", sub),
        ("outside.hyb", sub),
        ("m/abs.hyb", "model a\nimport \"/etc/passwd\"\n"),
        (
            "m/url.hyb",
            "model a\nimport \"https://example.org/s.hyb\"\n",
        ),
        ("m/up.hyb", "model a\nimport \"lib/../../outside.hyb\"\n"),
        ("m/missing.hyb", "model a\nimport \"lib/nope.hyb\"\n"),
        ("m/cycle.hyb", "model a\nimport \"lib/c1.hyb\"\n"),
        ("m/lib/c1.hyb", "import \"c2.hyb\"\n"),
        ("m/lib/c2.hyb", "\nimport \"c1.hyb\"\n"),
        ("m/bad.hyb", "model a\nimport \"lib/bad.hyb\"\nb = B()\n"),
        (
            "m/lib/bad.hyb",
            "# a subsystem with an error\nsubsystem B() {\n    state x = 0\n    flow { x' = y }\n}\n",
        ),
        ("m/syntax.hyb", "model a\nimport \"lib/syn.hyb\"\n"),
        ("m/lib/syn.hyb", "subsystem B() {\n    state x = = 0\n}\n"),
        (
            "m/ok.hyb",
            "model a\nimport \"./lib/s.hyb\"\nimport \"lib/s.hyb\"\ns = S()\n",
        ),
    ]);
    let m = dir.path().join("m");
    let cases = [
        ("abs.hyb", "E0801", "an absolute path", "abs.hyb:2:8"),
        ("url.hyb", "E0801", "a URL", "url.hyb:2:8"),
        ("up.hyb", "E0801", "out of the model's folder", "up.hyb:2:8"),
        (
            "missing.hyb",
            "E0802",
            "cannot read `lib/nope.hyb`",
            "missing.hyb:2:8",
        ),
        ("cycle.hyb", "E0803", "import cycle", "c2.hyb:2:8"),
        ("bad.hyb", "E0201", "unknown name `b.y`", "lib/bad.hyb:4:17"),
        ("syntax.hyb", "E0101", "unexpected `=`", "lib/syn.hyb:2:15"),
    ];
    for (file, code, words, at) in cases {
        let text = errors_of(&m.join(file));
        assert!(text.contains(&format!("error[{code}]")), "{file}: {text}");
        assert!(text.contains(words), "{file}: {text}");
        assert!(text.contains(at), "{file}: expected {at} in {text}");
    }
    // One file imported twice (by two spellings) brings its subsystem once.
    let src = SourceFile::read(m.join("ok.hyb")).unwrap();
    let model = compile(&src);
    assert_eq!(model.state_layout().flat_names(1), ["s.x"]);
}

/// The MCAP metadata records each imported file's SHA-256 next to the
/// model's.
#[test]
fn mcap_metadata_records_the_imported_files() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = tempfile::tempdir().unwrap();
    let model = root.join("models/sampled_loop.hyb");
    let bytes = super::outputs::short_run(dir.path(), &model, "l.mcap", &[]);
    let run = super::util::mcap_metadata(&bytes, "hybsim.run");
    let imports: serde_json::Value = serde_json::from_str(&run["imports"]).unwrap();
    let list = imports.as_array().unwrap();
    assert_eq!(list.len(), 3, "{imports}");
    for (entry, file) in list.iter().zip(["linear.hyb", "adc.hyb", "zoh.hyb"]) {
        let path = entry["path"].as_str().unwrap();
        assert!(path.ends_with(&format!("lib/{file}")), "{path}");
        let text = std::fs::read(root.join("models/lib").join(file)).unwrap();
        assert_eq!(entry["sha256"], super::util::sha256_hex(&text), "{file}");
    }
    // Each imported file is attached, so that the file alone rebuilds the model.
    let summary = mcap::read::Summary::read(&bytes).unwrap().unwrap();
    for file in ["linear.hyb", "adc.hyb", "zoh.hyb"] {
        let name = format!("lib/{file}");
        let index = summary
            .attachment_indexes
            .iter()
            .find(|a| a.name == name)
            .unwrap_or_else(|| panic!("no attachment {name}"));
        let attached = mcap::read::attachment(&bytes, index).unwrap();
        let text = std::fs::read(root.join("models/lib").join(file)).unwrap();
        assert_eq!(&attached.data[..], &text[..], "{name}");
        assert_eq!(attached.media_type, "text/plain");
    }
}
