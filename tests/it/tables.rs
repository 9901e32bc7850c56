//! Data tables: `param tk = table("file.csv")` (reading, header, path rules,
//! located errors, the size limit, SHA-256 in the MCAP metadata), run-time
//! indices `tk[k]` (in flows, guards, jump maps and outputs; machine code
//! against the interpreter; out of range → E0604 at (t, j)), and
//! `interp(xs, ys, x)` (values, clamping, its derivative in the Jacobian,
//! refused abscissae).

use std::path::Path;

use hybsim::arc::HybridTime;
use hybsim::diagnostics::Diagnostic;
use hybsim::engine::{HybridSystem, SimError, finite_difference_jacobian};
use hybsim::lang::{self, CompiledModel, Override};
use hybsim::source::SourceFile;

use crate::util::{code, hybsim, simulate_arc, stderr};

/// Writes `files` (name, text) into `dir` and returns the model `m.hyb`.
fn write(dir: &Path, model: &str, files: &[(&str, &str)]) -> SourceFile {
    for (name, text) in files {
        let p = dir.join(name);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, text).unwrap();
    }
    let path = dir.join("m.hyb");
    std::fs::write(&path, model).unwrap();
    SourceFile::read(&path).unwrap()
}

fn compile(src: &SourceFile, set: &[&str]) -> CompiledModel {
    let ov: Vec<Override> = set.iter().map(|s| s.parse().unwrap()).collect();
    match lang::compile(src, &ov) {
        Ok(m) => m,
        Err(d) => panic!("{}", hybsim::diagnostics::render(&d, src, false)),
    }
}

fn errors(src: &SourceFile) -> Vec<Diagnostic> {
    let d = lang::check_only(src, &[]);
    assert!(!d.is_empty(), "expected errors");
    assert_eq!(
        lang::compile(src, &[]).expect_err("refused").len(),
        d.len(),
        "compile and check agree"
    );
    d
}

/// (file name, line, column) of the primary label.
fn at(d: &Diagnostic, src: &SourceFile) -> (String, usize, usize) {
    let lc = d.line_col(src).unwrap();
    let file = Path::new(d.primary_file(src))
        .file_name()
        .unwrap()
        .to_string_lossy()
        .into_owned();
    (file, lc.line, lc.col)
}

fn outputs(m: &CompiledModel, at: HybridTime, x: &[f64]) -> Vec<f64> {
    let mut y = vec![0.0; m.output_dim()];
    m.outputs(at, x, &mut y);
    y
}

const READ: &str = "model m
param v = table(\"v.csv\")
param M = table(\"data/m.csv\")
state x = 0
flow { x' = 1 }
output a = v[3], b = M[2, 3], r = rows(M), c = cols(M), n = length(v)
";

#[test]
fn a_one_column_file_is_a_vector_and_a_file_with_a_header_a_matrix() {
    let dir = tempfile::tempdir().unwrap();
    let src = write(
        dir.path(),
        READ,
        &[
            ("v.csv", "1\n2.5\n-3e-2\n\n# the end\n"),
            ("data/m.csv", "\u{feff}a, b, c\r\n1, 2, 3\r\n4, 5, 6.25\r\n"),
        ],
    );
    let m = compile(&src, &[]);
    let y = outputs(&m, HybridTime::new(0.0, 0), &[0.0]);
    assert_eq!(y, vec![-3e-2, 6.25, 2.0, 3.0, 3.0]);
    let files = m.table_files();
    assert_eq!(files.len(), 2);
    assert!(files[1].path.ends_with("m.csv"), "{files:?}");
    // `--set` replaces a table without reading its file.
    std::fs::remove_file(dir.path().join("v.csv")).unwrap();
    let m = compile(&src, &["v=[7; 8; 9]"]);
    assert_eq!(outputs(&m, HybridTime::new(0.0, 0), &[0.0])[0], 9.0);
}

/// Every refused table: its code and where it points (the data file's
/// line:col for its contents, with the `table(…)` call as second label).
#[test]
fn refused_tables_are_located() {
    // (path, file text, code, (file, line, column) of the primary label)
    type Case<'a> = (&'a str, &'a str, &'a str, (&'a str, usize, usize));
    let cases: &[Case] = &[
        ("missing.csv", "", "E0802", ("m.hyb", 2, 11)),
        ("../v.csv", "", "E0801", ("m.hyb", 2, 17)),
        ("/etc/passwd", "", "E0801", ("m.hyb", 2, 17)),
        ("https://x.org/v.csv", "", "E0801", ("m.hyb", 2, 17)),
        ("v.csv", "1,2\n3,4,5\n", "E0804", ("v.csv", 2, 5)),
        ("v.csv", "1,2\n3\n", "E0804", ("v.csv", 2, 2)),
        ("v.csv", "t, x\n0, 1\n1, one\n", "E0804", ("v.csv", 3, 4)),
        ("v.csv", "1\nnan\n", "E0804", ("v.csv", 2, 1)),
        ("v.csv", "1\n  1e999\n", "E0804", ("v.csv", 2, 3)),
        ("v.csv", "1,,2\n", "E0804", ("v.csv", 1, 3)),
        ("v.csv", "a, b\n", "E0804", ("v.csv", 2, 1)),
        // A byte-order mark is not counted in the columns (found by the mutation test: the
        // label was 3 bytes off, past the end of the file).
        ("v.csv", "\u{feff}1,x\n", "E0804", ("v.csv", 1, 3)),
        ("v.csv", "\u{feff}time, g", "E0804", ("v.csv", 1, 8)),
        (
            "v.csv",
            "1\n2\n3\n4\n5\n6\n7\n8\n9\n10\n",
            "E0307",
            ("m.hyb", 2, 11),
        ),
    ];
    for (path, text, want, (file, line, col)) in cases {
        let dir = tempfile::tempdir().unwrap();
        let model = format!(
            "model m\nparam v = table(\"{path}\")\nstate x = v[1]\nflow {{ x' = 1 }}\nsim {{ max_matrix_elements = 9 }}\n"
        );
        let sub = dir.path().join("sub");
        std::fs::create_dir(&sub).unwrap();
        std::fs::write(dir.path().join("v.csv"), "1\n").unwrap();
        let files: Vec<(&str, &str)> = if text.is_empty() {
            vec![]
        } else {
            vec![("v.csv", *text)]
        };
        let src = write(&sub, &model, &files);
        let d = errors(&src);
        assert_eq!(d.len(), 1, "{path}: {d:?}");
        assert_eq!(d[0].code, *want, "{path} {text:?}: {}", d[0].message);
        assert_eq!(
            at(&d[0], &src),
            (file.to_string(), *line, *col),
            "{path} {text:?}: {}",
            d[0].message
        );
        if *want == "E0804" {
            let primary = d[0].labels.iter().find(|l| l.primary).unwrap();
            let file = primary.file.as_deref().unwrap();
            let shown = file.text().get(primary.span.start..primary.span.end);
            assert!(
                shown.is_some(),
                "{text:?}: {:?} outside the file",
                primary.span
            );
            let call = d[0].labels.iter().find(|l| !l.primary).expect("the call");
            assert_eq!(src.slice(call.span), format!("table(\"{path}\")"));
        }
    }
}

/// A link out of the model's folder is refused as for `import`.
#[cfg(unix)]
#[test]
fn a_link_out_of_the_folder_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("outside.csv"), "1\n").unwrap();
    let sub = dir.path().join("m");
    std::fs::create_dir(&sub).unwrap();
    std::os::unix::fs::symlink(dir.path().join("outside.csv"), sub.join("v.csv")).unwrap();
    let src = write(
        &sub,
        "model m\nparam v = table(\"v.csv\")\nstate x = v[1]\nflow { x' = 1 }\n",
        &[],
    );
    let d = errors(&src);
    assert_eq!(d[0].code, "E0801");
    assert!(d[0].message.contains("through a link"), "{}", d[0].message);
}

/// Durations, rates and levels read at run time with the counter `k` (a
/// state changed by jumps only): the timer rate in the flow, the threshold
/// in the guard, the reset, an output and a matrix row by a run-time index.
const RUN: &str = "model m
param dur = table(\"dur.csv\")
param rate = [1; 2; 4; 8]
param P = [1, 10; 2, 20; 3, 30; 4, 40]
state tau = 0, k = 1, y = 0
flow { tau' = rate[k]; y' = P[k, 2] }
jump next when tau >= dur[k] && k < 4 { tau+ = 0; k+ = k + 1; y+ = y + P[k, 1] }
output level = dur[k], row = P[k, :]
sim { T = 10 }
";

#[test]
fn run_time_indices_in_flows_guards_resets_and_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let src = write(dir.path(), RUN, &[("dur.csv", "0.5\n3\n2\n4\n")]);
    let m = compile(&src, &[]);
    let (x0, mut rng) = m.start(m.seed());
    let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng).expect("runs");
    // Segment k lasts dur[k] / rate[k]: 0.5, 1.5, 0.5 (then k = 4 flows on).
    let times: Vec<f64> = arc.jumps().iter().map(|j| j.at.t).collect();
    let expect = [0.5, 2.0, 2.5];
    assert_eq!(times.len(), 3, "{times:?}");
    for (t, e) in times.iter().zip(expect) {
        assert!((t - e).abs() < 1e-12, "{times:?}");
    }
    // y: the flow adds 10 k per unit time, each jump P[k, 1] = k.
    let last = arc.samples().last().unwrap();
    let y_end = 10.0 * 0.5 + 1.0 + 20.0 * 1.5 + 2.0 + 30.0 * 0.5 + 3.0 + 40.0 * 7.5;
    assert!((last.x[2] - y_end).abs() < 1e-9, "{} vs {y_end}", last.x[2]);
    let y = outputs(&m, last.at, last.x);
    assert_eq!(y, vec![4.0, 4.0, 40.0]);
    crate::jit::assert_bit_identical("tables", &src, 10.0, 50);
}

/// A countdown reset from a table by a counter is still an exact timer
/// (its jumps land on 0 to the last bit, at the draws' running sums), and
/// an atom reading `d[k]` with `k` constant along flows is evaluated once
/// per flow, not watched.
#[test]
fn table_driven_timers_stay_exact_and_constant_atoms_are_not_watched() {
    let dir = tempfile::tempdir().unwrap();
    let src = write(
        dir.path(),
        "model m
param d = table(\"d.csv\")
state tau = d[1], k = 1, s = 0
flow { tau' = -1; s' = 1 }
jump next when tau <= 0 { tau+ = d[k + 1]; k+ = k + 1 }
jump mark when s >= 10 && d[k] > 0.2 { s+ = 0 }
sim { T = 1.2 }
",
        &[("d.csv", "0.1\n0.3\n0.7\n0.2\n0.5\n")],
    );
    let m = compile(&src, &[]);
    assert!(
        matches!(
            m.jump_rules()[0].guard,
            hybsim::engine::GuardKind::Timer { .. }
        ),
        "{:?}",
        m.jump_rules()[0].guard
    );
    let atoms = m.set_atoms(hybsim::engine::SetRef::Jump(1)).unwrap();
    let flows: Vec<bool> = atoms.atoms.iter().map(|a| a.flows).collect();
    assert_eq!(flows, vec![true, false], "{atoms:?}");
    let (x0, mut rng) = m.start(m.seed());
    let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng).expect("runs");
    let jumps = arc.jumps();
    assert_eq!(jumps.len(), 3);
    let mut sum = 0.0;
    for (jump, d) in jumps.iter().zip([0.1, 0.3, 0.7]) {
        sum += d;
        assert_eq!(jump.pre[0], 0.0);
        assert!(
            (jump.at.t - sum).abs() <= 4.0 * f64::EPSILON,
            "{} vs {sum}",
            jump.at.t
        );
    }
}

/// A vehicle with three gears: the gear `q` (a state without flow) picks
/// the force and the shift speeds by run-time index. Every solver's path
/// between step ends keeps `q` an integer to the bit (the cubic Hermite
/// interpolant of RK4, and of Dop853 before its own, once gave
/// 2.9999999999999996 mid-step, and the index stopped the run with E0604),
/// and the shifts come at the closed-form times of v' = F[q] − c·v.
#[test]
fn a_mode_read_as_an_index_stays_an_integer_on_every_solver() {
    let (f, c, vu, vd) = ([3.0, 2.0, 1.0], 0.1, [10.0, 15.0, 1e9], [-1.0, 8.0, 12.0]);
    let (mut t, mut v, mut q, mut shifts) = (0.0_f64, 0.0_f64, 0_usize, vec![]);
    while shifts.len() < 14 {
        let vinf = f[q] / c;
        let (target, up) = if vinf > vu[q] {
            (vu[q], true)
        } else {
            (vd[q], false)
        };
        t -= ((vinf - target) / (vinf - v)).ln() / c;
        (v, q) = (target, if up { q + 1 } else { q - 1 });
        shifts.push(t);
    }
    for (solver, tol) in [
        ("dopri5", 1e-4),
        ("dop853", 1e-3),
        ("rk4", 1e-6),
        ("radau5", 1e-4),
        ("bdf", 1e-2),
        ("auto", 1e-4),
    ] {
        let src = SourceFile::new(
            "gears.hyb",
            format!(
                "model gears
param m = 1, c = 0.1, F = [3; 2; 1], vu = [10; 15; 1e9], vd = [-1; 8; 12]
state v = 0, q = 1
flow {{ v' = (F[q] - c*v)/m }}
jump up when q < 3 && v >= vu[q] {{ q+ = q + 1 }}
jump down when q > 1 && v <= vd[q] {{ q+ = q - 1 }}
sim {{ T = 100; solver = {solver}; h = 0.01 }}
"
            ),
        );
        let m = compile(&src, &[]);
        let (x0, mut rng) = m.start(m.seed());
        let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng)
            .unwrap_or_else(|e| panic!("{solver}: {e}"));
        let mut s = arc.samples();
        assert!(
            s.all(|p| p.x[1].fract() == 0.0),
            "{solver}: a gear off an integer"
        );
        let times: Vec<f64> = arc.jumps().iter().map(|j| j.at.t).collect();
        assert_eq!(times.len(), shifts.len(), "{solver}: {times:?}");
        for (t, e) in times.iter().zip(&shifts) {
            assert!((t - e).abs() < tol, "{solver}: {t} vs {e}");
        }
    }
}

/// A dwell time picked by the mode, `tau^2 >= d[q]^2` (squared: `tau >=
/// d[q]` is a timer atom, scheduled, not watched): over a step's box, where
/// the mode `q` (constant along flows) is its value widened by a few
/// roundings, the atom's bound reads the one entry the mode can index, so
/// the search between checkpoints proves the atom's sign on every step but
/// the last of a dwell. The bound was unbounded (an index box that is not a
/// point counted as possibly NaN): every step spent the search's whole
/// budget, and a 10-s run of 16 dwells took 1 s instead of 2 ms. The
/// switching times are the partial sums of the dwells.
#[test]
fn a_dwell_time_indexed_by_a_mode_is_bounded_on_every_step() {
    let src = SourceFile::new(
        "dwell.hyb",
        "model dwell
param d = [0.3; 1.1; 0.45]
state tau = 0, q = 1, x = 1
flow { tau' = 1; x' = -0.1*q*x }
jump switch when tau^2 >= d[q]^2 { tau+ = 0; q+ = mod(q, 3) + 1 }
sim { T = 10; rtol = 1e-12; atol = 1e-15 }
",
    );
    let m = compile(&src, &[]);
    let atoms = m.set_atoms(hybsim::engine::SetRef::Jump(0)).unwrap();
    assert_eq!(atoms.atoms.len(), 1, "{atoms:?}");
    assert!(atoms.atoms[0].watched(), "{atoms:?}");
    let widen = 8.0 * f64::EPSILON;
    let mut out = [(0.0, 0.0)];
    // tau in [0, 0.5] in mode 2 (d = 1.1): the atom stays 0.96 to 1.21
    // from zero.
    let x = [(0.0, 0.5), (2.0 - widen, 2.0 + widen), (0.1, 0.2)];
    assert!(m.atom_bounds((1.0, 1.5), 3, &x, &mut out));
    let (lo, hi) = out[0];
    assert!(
        lo.is_finite() && hi.is_finite() && (hi < -0.55 || lo > 0.55) && hi - lo < 0.6,
        "{out:?}"
    );
    let (x0, mut rng) = m.start(m.seed());
    let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng).expect("runs");
    let want = crate::util::cyclic_switch_times(&[0.3, 1.1, 0.45], 10.0);
    let times: Vec<f64> = arc.jumps().iter().map(|j| j.at.t).collect();
    assert_eq!(times.len(), want.len(), "{times:?}");
    for (t, e) in times.iter().zip(&want) {
        assert!((t - e).abs() < 1e-13, "{t} vs {e}");
    }
    // x decays at rate q/10 in mode q.
    let last = arc.last().unwrap();
    let (mut t, mut expo) = (0.0, 0.0);
    for (k, &s) in want.iter().enumerate() {
        expo += 0.1 * (k % 3 + 1) as f64 * (s - t);
        t = s;
    }
    expo += 0.1 * (want.len() % 3 + 1) as f64 * (10.0 - t);
    assert!(
        (last.x[2] / (-expo).exp() - 1.0).abs() < 1e-9,
        "{} vs {}",
        last.x[2],
        (-expo).exp()
    );
}

/// `k < 4 && tau >= d[k]` and `if k < 4 then d[k] else inf` never read
/// d[4]: an index is checked only where its value is needed (the right
/// operand of `&&` where the left holds, the branch of `if` taken).
#[test]
fn an_index_is_checked_only_where_its_value_is_needed() {
    for guard in [
        "k < 4 && tau >= d[k]",
        "!(k >= 4 || tau < d[k])",
        "tau >= (if k < 4 then d[k] else inf)",
    ] {
        let dir = tempfile::tempdir().unwrap();
        let src = write(
            dir.path(),
            &format!(
                "model m
param d = table(\"d.csv\")
state tau = 0, k = 1
flow {{ tau' = 1 }}
jump next when {guard} {{ tau+ = 0; k+ = k + 1 }}
sim {{ T = 2 }}
"
            ),
            &[("d.csv", "0.25\n0.25\n0.25\n")],
        );
        for jit in ["on", "off"] {
            let m = compile(&src, &[&format!("jit={jit}")]);
            let (x0, mut rng) = m.start(m.seed());
            let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng)
                .unwrap_or_else(|e| panic!("{guard}: {e}"));
            assert_eq!(arc.jumps().len(), 3, "{guard}");
        }
    }
}

/// The run-time error of `src` (it must fail).
fn run_error(src: &SourceFile) -> (SimError, Diagnostic) {
    let m = compile(src, &[]);
    let (x0, mut rng) = m.start(m.seed());
    let err = simulate_arc(&m, &x0, &m.settings(), &mut rng).expect_err("the run fails");
    let d = m.runtime_diagnostic(&err);
    (err, d)
}

/// An index out of range or not an integer stops the run with E0604 at the
/// indexing expression and the (t, j) of the evaluation, wherever it is:
/// a guard (whose NaN alone would read as "false"), a flow, a reset; with
/// machine code and with the interpreter. `d` has 3 entries; the timer
/// fires every 0.25.
#[test]
fn a_bad_run_time_index_is_e0604_at_t_j() {
    let cases: &[(&str, &str, &str, f64, u64)] = &[
        // (what, model body, the indexing expression, t, j)
        (
            "guard",
            "state tau = 0, k = 1\nflow { tau' = 1 }\njump next when tau >= d[k] { tau+ = 0; k+ = k + 1 }\n",
            "d[k]",
            0.75,
            3,
        ),
        (
            "flow",
            "state tau = 0, k = 1, y = 0\nflow { tau' = 1; y' = d[k] }\njump next when tau >= 0.25 { tau+ = 0; k+ = k + 1 }\n",
            "d[k]",
            0.75,
            3,
        ),
        (
            "reset",
            "state tau = 0, k = 1, y = 0\nflow { tau' = 1 }\njump next when tau >= 0.25 { tau+ = 0; k+ = k + 1; y+ = d[k + 1] }\n",
            "d[k + 1]",
            0.75,
            2,
        ),
        (
            "not an integer",
            "state tau = 0, k = 1\nflow { tau' = 1 }\njump next when tau >= d[k] { tau+ = 0; k+ = k + 0.5 }\n",
            "d[k]",
            0.25,
            1,
        ),
    ];
    for jit in ["on", "off"] {
        for (what, body, marker, t, j) in cases {
            let dir = tempfile::tempdir().unwrap();
            let model = format!(
                "model m\nparam d = table(\"d.csv\")\n{body}sim {{ T = 5; jit = {jit} }}\n"
            );
            let src = write(dir.path(), &model, &[("d.csv", "0.25\n0.25\n0.25\n")]);
            let (err, d) = run_error(&src);
            let SimError::Fault { at, .. } = &err else {
                panic!("{what}: {err:?}")
            };
            assert!(
                (at.t - t).abs() < 1e-12 && at.j == *j,
                "{what} (jit {jit}): {err}"
            );
            assert_eq!(d.code, "E0604", "{what}: {}", d.message);
            let span = d.primary_span().unwrap();
            assert_eq!(src.slice(span), *marker, "{what}");
            let wrong = if *what == "not an integer" {
                "1.5 is not an integer"
            } else {
                "4 is out of range 1..3"
            };
            assert!(d.message.contains(wrong), "{what}: {}", d.message);
            assert!(
                d.labels[0]
                    .message
                    .contains(&format!("(t, j) = ({}, {})", at.t, at.j)),
                "{:?}",
                d.labels
            );
        }
    }
}

/// The CLI: exit 1 and the located diagnostic, also for an index in an
/// output (evaluated by the files' sinks).
#[test]
fn the_cli_reports_a_bad_index() {
    let dir = tempfile::tempdir().unwrap();
    write(
        dir.path(),
        "model m\nparam d = [1; 2]\nstate k = 1\nflow { k' = 0 }\njump up when d[k] > 0 { k+ = k + 1 }\n",
        &[],
    );
    let o = hybsim(dir.path(), &["run", "m.hyb", "--no-mcap"]);
    assert_eq!(code(&o), 1, "{}", stderr(&o));
    let e = stderr(&o);
    assert!(e.contains("E0604") && e.contains("m.hyb:5:14"), "{e}");
    // `d` is a parameter, not a `table("…")`: the message does not call it one.
    assert!(
        e.contains("error[E0604]: index 3 is out of range 1..2"),
        "{e}"
    );
    write(
        dir.path(),
        "model m\nparam d = [1; 2]\nstate tau = 0, k = 1\nflow { tau' = 1 }\njump up when tau >= 1 { tau+ = 0; k+ = k + 1 }\noutput o = d[k]\n",
        &[],
    );
    let o = hybsim(dir.path(), &["run", "m.hyb", "--no-mcap", "--csv", "m.csv"]);
    assert_eq!(code(&o), 1, "{}", stderr(&o));
    let e = stderr(&o);
    assert!(e.contains("E0604") && e.contains("m.hyb:6:12"), "{e}");
    assert!(e.contains("(t, j) = (2, 2)"), "{e}");
}

/// Constant indices keep their compile-time check; a run-time index into a
/// vector that is not constant is refused.
#[test]
fn run_time_indices_read_constants_only() {
    let dir = tempfile::tempdir().unwrap();
    let src = write(
        dir.path(),
        "model m\nstate x = [1; 2], k = 1\nflow { x' = x[k] }\n",
        &[],
    );
    let d = errors(&src);
    assert_eq!(d[0].code, "E0305");
    assert_eq!(at(&d[0], &src), ("m.hyb".into(), 3, 15));
    let src = write(
        dir.path(),
        "model m\nparam d = [1; 2]\nstate k = 1\nflow { k' = d[3] }\n",
        &[],
    );
    assert_eq!(errors(&src)[0].code, "E0401");
}

const INTERP: &str = "model m
param xs = [0, 1, 3], ys = [2, 4, 0]
state x = 0
flow { x' = interp(xs, ys, t) }
output at_x = interp(xs, ys, [-1, 0, 0.5, 1, 2, 3, 7])
sim { T = 4; dt_out = 0.5; rtol = 1e-10; atol = 1e-12 }
";

#[test]
fn interp_is_piecewise_linear_and_clamped() {
    let dir = tempfile::tempdir().unwrap();
    let src = write(dir.path(), INTERP, &[]);
    let m = compile(&src, &[]);
    let y = outputs(&m, HybridTime::new(0.0, 0), &[0.0]);
    assert_eq!(y, vec![2.0, 2.0, 3.0, 4.0, 2.0, 0.0, 0.0]);
    // ∫₀⁴: 3 (0..1) + 4 (1..3, from 4 to 0) + 0 (clamped at 0 past 3).
    let (x0, mut rng) = m.start(m.seed());
    let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng).expect("runs");
    let last = arc.samples().last().unwrap();
    assert!((last.x[0] - 7.0).abs() < 1e-7, "{}", last.x[0]);
    crate::jit::assert_bit_identical("interp", &src, 4.0, 20);
}

/// In a flow of the state, `interp` has the derivative of its segment in
/// the symbolic Jacobian of the implicit solver (0 where clamped).
#[test]
fn interp_has_its_slope_in_the_jacobian() {
    let dir = tempfile::tempdir().unwrap();
    let src = write(
        dir.path(),
        "model m
param xs = [0, 1, 3], ys = [2, 4, 0]
state x = 0.5, y = 1
flow { x' = -interp(xs, ys, x) * y; y' = interp(xs, ys, 2 * x) }
sim { solver = radau5; T = 1 }
",
        &[],
    );
    let m = compile(&src, &[]);
    assert!(m.has_exact_jacobian());
    for x in [-0.5, 0.25, 0.75, 1.2, 2.5, 4.0] {
        let at = HybridTime::new(0.0, 0);
        let state = [x, 1.5];
        let mut exact = vec![0.0; 4];
        m.jacobian(at, &state, &mut exact);
        let mut fd = vec![0.0; 4];
        finite_difference_jacobian(&m, at, &state, &mut fd);
        for (e, f) in exact.iter().zip(&fd) {
            assert!((e - f).abs() < 1e-5, "x = {x}: {exact:?} vs {fd:?}");
        }
    }
    let (x0, mut rng) = m.start(m.seed());
    simulate_arc(&m, &x0, &m.settings(), &mut rng).expect("radau5 runs");
}

#[test]
fn interp_refuses_bad_abscissae() {
    let cases = [
        (
            "interp([0, 1, 1], [1, 2, 3], t)",
            "E0304",
            "strictly increasing",
        ),
        (
            "interp([0, 2, 1], [1, 2, 3], t)",
            "E0304",
            "xs[3] = 1 after xs[2] = 2",
        ),
        ("interp([0, 1], [1, 2, 3], t)", "E0301", "one length"),
        ("interp([0, x], [1, 2], t)", "E0305", "`interp`'s xs"),
        ("interp([0, 1], [1, x], t)", "E0305", "`interp`'s ys"),
        ("interp([0, 1], [1, 2])", "E0303", "3 arguments"),
    ];
    for (call, want, words) in cases {
        let dir = tempfile::tempdir().unwrap();
        let src = write(
            dir.path(),
            &format!("model m\nstate x = 0\nflow {{ x' = {call} }}\n"),
            &[],
        );
        let d = errors(&src);
        assert_eq!(d[0].code, want, "{call}: {}", d[0].message);
        let text = format!("{} {:?}", d[0].message, d[0].labels);
        assert!(text.contains(words), "{call}: {text}");
    }
}

/// `hybsim run` records each table's path and SHA-256 next to the model's.
#[test]
fn mcap_metadata_records_the_tables() {
    let dir = tempfile::tempdir().unwrap();
    let text = "0.5\n0.25\n1\n";
    write(
        dir.path(),
        "model m\nparam d = table(\"data/d.csv\")\nstate x = d[2]\nflow { x' = 1 }\n",
        &[("data/d.csv", text)],
    );
    let bytes = super::outputs::short_run(dir.path(), &dir.path().join("m.hyb"), "m.mcap", &[]);
    let run = super::util::mcap_metadata(&bytes, "hybsim.run");
    let tables: serde_json::Value = serde_json::from_str(&run["tables"]).unwrap();
    let list = tables.as_array().unwrap();
    assert_eq!(list.len(), 1, "{tables}");
    assert!(list[0]["path"].as_str().unwrap().ends_with("data/d.csv"));
    assert_eq!(list[0]["sha256"], super::util::sha256_hex(text.as_bytes()));
}

/// `hybsim fmt` leaves a model with tables, run-time indices and `interp`
/// compiling to the same arc, and is idempotent on it.
#[test]
fn fmt_keeps_tables_and_indices() {
    let dir = tempfile::tempdir().unwrap();
    let src = write(
        dir.path(),
        "model m\nparam  tk=table( \"dur.csv\" )\nparam rate = [1; 2; 4; 8]\nparam P = [1, 10; 2, 20; 3, 30; 4, 40]\nstate tau = 0, k = 1, y = 0\nflow { tau' = rate[ k ]; y' = P[k,2]+interp([0,1],[1,2],t) }\njump next when tau >= tk[k] && k < 4 { tau+ = 0; k+ = k + 1 }\nsim { T = 5 }\n",
        &[("dur.csv", "0.5\n3\n2\n4\n")],
    );
    let formatted = hybsim::syntax::format_source(src.text()).unwrap();
    assert!(
        formatted.contains("param tk = table(\"dur.csv\")"),
        "{formatted}"
    );
    assert_eq!(
        hybsim::syntax::format_source(&formatted).unwrap(),
        formatted
    );
    let fsrc = SourceFile::new(src.name(), formatted);
    let arc = |s: &SourceFile| {
        let m = compile(s, &[]);
        let (x0, mut rng) = m.start(m.seed());
        format!(
            "{:?}",
            simulate_arc(&m, &x0, &m.settings(), &mut rng).unwrap()
        )
    };
    assert_eq!(arc(&fsrc), arc(&src));
}

/// The agents benchmark of `../shared/limit` with its pre-drawn timer table
/// (`benches/models/limit_agents_timers.csv`, params.json's `agents.draws`
/// verbatim, checked against params.json where `../shared` is beside the
/// repository): the reference's 7 458 jumps in [0, 1000] (per agent, the
/// draws whose running sum stays below 1000, as the reference's accuracy
/// check counts them), each agent's last jump at that running sum, and the
/// plant at T on the exact rotation.
#[test]
fn the_agents_benchmark_replays_the_reference_draws() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let (rows, cols, flat) = hybsim::tables::parse(
        &std::fs::read_to_string(root.join("benches/models/limit_agents_timers.csv")).unwrap(),
    )
    .unwrap();
    assert_eq!((rows, cols), (4000, 3));
    if let Ok(text) = std::fs::read_to_string(root.join("../shared/limit/params.json")) {
        let params: serde_json::Value = serde_json::from_str(&text).unwrap();
        let draws: Vec<Vec<f64>> =
            serde_json::from_value(params["agents"]["draws"].clone()).unwrap();
        let reference: Vec<f64> = draws.iter().flatten().copied().collect();
        assert_eq!(flat, reference, "the table is params.json's draws");
    }
    let src = SourceFile::read(root.join("benches/models/limit_agents.hyb")).unwrap();
    let m = compile(&src, &[]);
    let (x0, mut rng) = m.start(m.seed());
    let arc = simulate_arc(&m, &x0, &m.settings(), &mut rng).expect("runs");
    let names = m.rule_names();
    let mut total = 0;
    for k in 0..3 {
        // The reference's count and last jump: a plain running sum.
        let (mut sum, mut last, mut count) = (0.0, 0.0, 0);
        for row in flat.chunks(3) {
            sum += row[k];
            if sum >= 1000.0 {
                break;
            }
            (last, count) = (sum, count + 1);
        }
        let jumps: Vec<f64> = arc
            .jumps()
            .iter()
            .filter(|j| names[j.rule] == format!("transmit[{}]", k + 1))
            .map(|j| j.at.t)
            .collect();
        assert_eq!(jumps.len(), count, "agent {}", k + 1);
        let drift = (jumps.last().unwrap() - last).abs();
        assert!(drift < 1e-9, "agent {}: {drift}", k + 1);
        total += count;
    }
    assert_eq!(total, 7458);
    assert_eq!(arc.jumps().len(), 7458);
    let end = arc.samples().last().unwrap();
    let t = end.at.t;
    assert_eq!(t, 1000.0);
    let exact = [t.cos() + t.sin(), t.sin() - t.cos(), 0.5];
    for (r, e) in exact.iter().enumerate() {
        assert!((end.x[r] - e).abs() < 1e-3, "x[{r}] = {} vs {e}", end.x[r]);
    }
}

/// A table is read once, at the top level: inside `for` it is E0507 (once).
#[test]
fn a_table_inside_a_loop_is_refused_once() {
    let dir = tempfile::tempdir().unwrap();
    let src = write(
        dir.path(),
        "model m\nfor i in 1..3 {\n    param d = table(\"d.csv\")\n}\nstate x = 0\nflow { x' = 1 }\n",
        &[("d.csv", "1\n")],
    );
    let d = errors(&src);
    assert_eq!(d.len(), 1, "{d:?}");
    assert_eq!(d[0].code, "E0507");
    assert_eq!(at(&d[0], &src), ("m.hyb".into(), 3, 15));
}
