//! The `hybsim` binary: exit codes and files (values are read back from the
//! files; the library tests cover the rest).

use std::path::{Path, PathBuf};

use serde_json::Value;

use crate::util::temp_files;
use crate::util::{code, hybsim, mcap_metadata, stderr, stdout};

fn ball_model() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("models/bouncing_ball.hyb")
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn help_and_usage_errors() {
    let dir = tempfile::tempdir().unwrap();
    let help = hybsim(dir.path(), &["--help"]);
    assert_eq!(code(&help), 0);
    let text = String::from_utf8_lossy(&help.stdout);
    assert!(
        text.contains("Examples:") && text.contains("Exit codes:"),
        "{text}"
    );
    let run_help = hybsim(dir.path(), &["run", "--help"]);
    assert_eq!(code(&run_help), 0);
    assert!(String::from_utf8_lossy(&run_help.stdout).contains("--log-every"));
    assert_eq!(code(&hybsim(dir.path(), &["run"])), 2);
    assert_eq!(code(&hybsim(dir.path(), &["frobnicate"])), 2);
    assert_eq!(code(&hybsim(dir.path(), &["run", "missing.hyb"])), 2);
}

/// An output file in a folder that does not exist is named as asked for,
/// without the random name of the temporary file beside it (exit 1).
#[test]
fn an_unwritable_output_names_the_file_asked_for() {
    let dir = tempfile::tempdir().unwrap();
    let model = ball_model();
    for flag in ["--csv", "-o", "--parquet"] {
        let out = hybsim(
            dir.path(),
            &[
                "run",
                model.to_str().unwrap(),
                flag,
                "missing/run.out",
                "--T",
                "0.1",
            ],
        );
        assert_eq!(code(&out), 1, "{flag}");
        let text = stderr(&out);
        assert!(
            text.contains(
                "cannot write `missing/run.out`: cannot create a file in `missing`: No such file or directory"
            )
                && !text.contains(".tmp"),
            "{flag}: {text}"
        );
    }
}

/// The summary's final hybrid time is written as every other time of the
/// line (compact and lossless): a horizon of 1e-300 ends "at (t = 1e-300,
/// j = 0)", not at 300 digits of a decimal fraction.
#[test]
fn the_summary_writes_tiny_end_times_compactly() {
    let dir = tempfile::tempdir().unwrap();
    let model = write(
        dir.path(),
        "tiny.hyb",
        "model tiny\nstate x = 0\nflow { x' = 1 }\nsim { T = 1e-300 }\n",
    );
    let out = hybsim(dir.path(), &["run", model.to_str().unwrap(), "--no-mcap"]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let summary = String::from_utf8_lossy(&out.stdout);
    assert!(
        summary.starts_with("tiny: ended at (t = 1e-300, j = 0); "),
        "{summary}"
    );
}

/// `--J` takes what the `sim` block's `J` takes, checked the same way: a
/// whole number written as a float (`1e30`, saturating), `inf` for no bound;
/// other values get the block's located error, which says what J may be.
#[test]
fn the_jump_horizon_flag_takes_what_the_sim_block_takes() {
    let dir = tempfile::tempdir().unwrap();
    let model = write(
        dir.path(),
        "ticks.hyb",
        "model ticks\nstate x = 0\nflow { x' = 1 }\njump r when x >= 1 { x+ = 0 }\nsim { T = 3.5; J = inf }\n",
    );
    let m = model.to_str().unwrap();
    for (j, jumps) in [
        (None, "j = 3)"),
        (Some("1e30"), "j = 3)"),
        (Some("inf"), "j = 3)"),
        (Some("2"), "j = 2)"),
    ] {
        let mut args = vec!["run", m, "--no-mcap"];
        args.extend(j.iter().flat_map(|j| ["--J", *j]));
        let out = hybsim(dir.path(), &args);
        assert_eq!(code(&out), 0, "--J {j:?}: {}", stderr(&out));
        let summary = String::from_utf8_lossy(&out.stdout);
        assert!(summary.contains(jumps), "--J {j:?}: {summary}");
    }
    let out = hybsim(dir.path(), &["run", m, "--no-mcap", "--J", "2.5"]);
    assert_eq!(code(&out), 2);
    let err = stderr(&out);
    assert!(
        err.contains("E0506") && err.contains("a whole number of jumps ≥ 0, or inf"),
        "{err}"
    );
}

/// `nan` given to a number flag is refused as the value it is, at the value: it was turned
/// into the override `sim.T=NaN` and refused as an unknown name `NaN` (E0201), which the user
/// never typed; `--T -inf` was a usage error about a flag `-i`.
#[test]
fn a_nan_given_to_a_number_flag_is_an_invalid_value() {
    let dir = tempfile::tempdir().unwrap();
    let model = write(
        dir.path(),
        "decay.hyb",
        "model decay\nstate x = 1\nflow { x' = -x }\n",
    );
    let m = model.to_str().unwrap();
    for (flag, says) in [
        ("--T", "invalid `T`: NaN is out of range"),
        ("--J", "invalid `J`: NaN is out of range"),
        ("--dt-out", "invalid `dt_out`: NaN is out of range"),
        ("--max-step", "invalid `max_step`: NaN is out of range"),
        ("--zeno-rate", "invalid `zeno_rate`: NaN is out of range"),
    ] {
        let out = hybsim(
            dir.path(),
            &["run", m, "--no-mcap", "--color", "never", flag, "nan"],
        );
        assert_eq!(code(&out), 2, "{flag} nan");
        let err = stderr(&out);
        assert!(
            err.contains("E0506")
                && err.contains(says)
                && err.contains(&format!("in `{flag} nan`")),
            "{flag} nan: {err}"
        );
        assert!(!err.contains("unknown name"), "{flag} nan: {err}");
    }
    // `-inf` is a value too (clap took it for the short flags `-i…` and advised `-- -i`).
    let out = hybsim(
        dir.path(),
        &["run", m, "--no-mcap", "--color", "never", "--T", "-inf"],
    );
    assert_eq!(code(&out), 2);
    let err = stderr(&out);
    assert!(
        err.contains("in `--T -inf`: invalid `T`: -inf is out of range"),
        "--T -inf: {err}"
    );
}

/// A `--log-dt` that is not a time ≥ 0 is a usage error (exit 2) before anything runs: it was
/// exit 1 from the first sink that opened ("the run failed"), and with `--no-mcap` alone it
/// passed unseen.
#[test]
fn a_bad_log_dt_is_a_usage_error_with_or_without_files() {
    let dir = tempfile::tempdir().unwrap();
    let model = write(
        dir.path(),
        "decay.hyb",
        "model decay\nstate x = 1\nflow { x' = -x }\n",
    );
    let m = model.to_str().unwrap();
    for value in ["-1", "nan", "inf"] {
        for files in [&["--no-mcap"][..], &["--csv", "x.csv", "-o", "x.mcap"][..]] {
            let mut args = vec!["run", m, "--log-dt", value];
            args.extend_from_slice(files);
            let out = hybsim(dir.path(), &args);
            assert_eq!(code(&out), 2, "--log-dt {value} {files:?}");
            assert!(
                stderr(&out).contains("invalid option `--log-dt`"),
                "{}",
                stderr(&out)
            );
            assert!(stdout(&out).is_empty(), "nothing ran: {}", stdout(&out));
        }
    }
    assert!(!dir.path().join("x.csv").exists() && !dir.path().join("x.mcap").exists());
    let out = hybsim(dir.path(), &["run", m, "--log-dt", "0", "--no-mcap"]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
}

/// A bad `--seed` says what a seed is, in `run`, `test` and `sweep` alike: it was "invalid digit
/// found in string", and `sweep --seed -1` an unknown argument `-1` with the advice to write
/// `-- -1` (which would have made `-1` the model).
#[test]
fn a_bad_seed_says_what_a_seed_is() {
    let dir = tempfile::tempdir().unwrap();
    let m = ball_model();
    let m = m.to_str().unwrap();
    for seed in ["-1", "1.5", "1e3", "18446744073709551616", "abc"] {
        for args in [
            vec!["run", m, "--no-mcap"],
            vec!["test", m],
            vec!["sweep", m, "-o", "out"],
        ] {
            let mut args = args.clone();
            args.extend(["--seed", seed]);
            let out = hybsim(dir.path(), &args);
            assert_eq!(code(&out), 2, "{args:?}");
            let err = stderr(&out);
            assert!(
                err.contains(&format!(
                    "`{seed}`: a seed is a whole number from 0 to 2^64 - 1"
                )),
                "{args:?}: {err}"
            );
            assert!(!err.contains("-- -1"), "{args:?}: {err}");
        }
    }
    assert!(!dir.path().join("out").exists());
    let out = hybsim(
        dir.path(),
        &["run", m, "--no-mcap", "--seed", "18446744073709551615"],
    );
    assert_eq!(code(&out), 0, "{}", stderr(&out));
}

/// A bad count (`--runs`, `--threads`, `--cases`, `--max-shrink`, `--log-every`) says what a
/// count is: it was clap's "invalid digit found in string" (for `-1`, `1.5`, `1e3`); `1e3` is
/// taken as 1000, as the counts among the `sim` keys take it.
#[test]
fn a_bad_count_says_what_a_count_is() {
    let dir = tempfile::tempdir().unwrap();
    let m = ball_model();
    let m = m.to_str().unwrap();
    let commands: [(Vec<&str>, &str, &str); 5] = [
        (vec!["sweep", m, "-o", "out"], "--runs", "1"),
        (vec!["sweep", m, "-o", "out"], "--threads", "1"),
        (vec!["test", m], "--cases", "1"),
        (vec!["test", m], "--max-shrink", "0"),
        (vec!["run", m, "--no-mcap"], "--log-every", "1"),
    ];
    for (args, flag, min) in &commands {
        for bad in ["-1", "1.5", "abc", "inf"] {
            let mut args = args.clone();
            args.extend([*flag, bad]);
            let out = hybsim(dir.path(), &args);
            assert_eq!(code(&out), 2, "{args:?}");
            let err = stderr(&out);
            assert!(
                err.contains(&format!("`{bad}`: a whole number ≥ {min}")),
                "{args:?}: {err}"
            );
            assert!(!err.contains("invalid digit"), "{args:?}: {err}");
        }
    }
    assert!(!dir.path().join("out").exists());
    let out = hybsim(
        dir.path(),
        &[
            "run",
            m,
            "--no-mcap",
            "--csv",
            "b.csv",
            "--log-every",
            "1e1",
        ],
    );
    assert_eq!(code(&out), 0, "{}", stderr(&out));
}

/// `--set lambda 0.5` (a space for the `=`) names the fix in every command that takes `--set`:
/// it was clap's "unexpected argument '0.5' found".
#[test]
fn a_set_without_equals_says_how_to_write_it() {
    let dir = tempfile::tempdir().unwrap();
    let m = ball_model();
    let m = m.to_str().unwrap();
    for args in [
        vec!["run", m, "--no-mcap"],
        vec!["check", m],
        vec!["test", m],
        vec!["design", m],
        vec!["sweep", m, "-o", "out"],
    ] {
        let mut args = args.clone();
        args.extend(["--set", "lambda", "0.5"]);
        let out = hybsim(dir.path(), &args);
        assert_eq!(code(&out), 2, "{args:?}");
        let err = stderr(&out);
        assert!(
            err.contains("`--set lambda` has no value: write `--set lambda=VALUE`"),
            "{args:?}: {err}"
        );
        // The subcommand's usage, as clap's own errors show it.
        assert!(
            err.contains(&format!("Usage: hybsim {} ", args[0])),
            "{args:?}: {err}"
        );
    }
    let out = hybsim(dir.path(), &["check", m, "--set", "lambda=0.5"]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
}

/// `--T` and `--J` set the horizons, not the model's own `T` and `J`: a sampling period
/// `param T` became the horizon too (`--T 3` made a model that ticks every 0.5 end with no
/// tick), and a `--set` of the state `h` stays the state's when `hybsim test` replays it.
#[test]
fn horizon_flags_leave_parameters_named_t_and_j() {
    let dir = tempfile::tempdir().unwrap();
    let model = write(
        dir.path(),
        "tick.hyb",
        "model tick\nparam T = 0.5, J = 2\nstate h = 1, n = 0\nflow { h' = -1/J }\n\
         every T { n+ = n + 1 }\nsim { T = 10 }\n",
    );
    let m = model.to_str().unwrap();
    let out = hybsim(
        dir.path(),
        &["run", m, "--no-mcap", "--json", "--T", "3", "--set", "h=0"],
    );
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let v: Value = serde_json::from_str(&crate::util::stdout(&out)).unwrap();
    assert_eq!(v["end"]["t"], 3.0);
    assert_eq!(v["jumps"]["step"], 5, "ticks every 0.5 before t = 3");
    let out = hybsim(dir.path(), &["run", m, "--no-mcap", "--json", "--J", "3"]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let v: Value = serde_json::from_str(&crate::util::stdout(&out)).unwrap();
    assert_eq!(
        (v["end"]["t"].as_f64(), v["end"]["j"].as_u64()),
        (Some(1.5), Some(3))
    );
}

/// A `--solver` that cannot integrate the model's white noise is a usage
/// error naming the flag and the solver to use (exit 2), not a failed run
/// (it was exit 1 with "ended at (no sample)" and the Rust API's
/// `Solver::EulerMaruyama { h }` as help); `--solver euler-maruyama` runs.
#[test]
fn a_solver_flag_that_cannot_integrate_white_noise_is_a_usage_error() {
    let dir = tempfile::tempdir().unwrap();
    let model = write(
        dir.path(),
        "ou.hyb",
        "model ou\nnoise w ~ wiener(1)\nstate x = 0\nflow { x' = -x + w }\nsim { T = 0.1 }\n",
    );
    let m = model.to_str().unwrap();
    for solver in ["dopri5", "radau5", "rk4"] {
        let out = hybsim(dir.path(), &["run", m, "--no-mcap", "--solver", solver]);
        assert_eq!(code(&out), 2, "{solver}: {}", stderr(&out));
        let err = stderr(&out);
        assert!(
            err.contains(&format!("`--solver {solver}`"))
                && err.contains("`--solver euler-maruyama`")
                && !err.contains("Solver::"),
            "{err}"
        );
    }
    let out = hybsim(
        dir.path(),
        &["run", m, "--no-mcap", "--solver", "euler-maruyama"],
    );
    assert_eq!(code(&out), 0, "{}", stderr(&out));
}

/// `--solver rk4` without `--step` takes the `sim` block's default step
/// (1e-3), as `sim { solver = rk4 }` without `h` does: the same arc.
#[test]
fn a_fixed_step_solver_without_a_step_takes_the_default_step() {
    let dir = tempfile::tempdir().unwrap();
    let model = write(
        dir.path(),
        "decay.hyb",
        "model decay\nstate x = 1\nflow { x' = -x }\nsim { T = 0.5 }\n",
    );
    let m = model.to_str().unwrap();
    let csv = |name: &str, extra: &[&str]| {
        let path = dir.path().join(name);
        let mut args = vec![
            "run",
            m,
            "--no-mcap",
            "--csv",
            path.to_str().unwrap(),
            "--solver",
            "rk4",
        ];
        args.extend_from_slice(extra);
        let out = hybsim(dir.path(), &args);
        assert_eq!(code(&out), 0, "{extra:?}: {}", stderr(&out));
        std::fs::read_to_string(path).unwrap()
    };
    let default = csv("default.csv", &[]);
    assert_eq!(default, csv("explicit.csv", &["--step", "1e-3"]));
    assert!(default.lines().count() > 400, "steps of 1e-3 over 0.5");
}

/// `--solver` keeps what the model's `sim` block gave for the solver it
/// names, also beside another solver: `h = 0.01` on a Dopri5 model is the
/// step of `--solver rk4` (it took 1e-3, the default, though `--step` says
/// "default: the model's `h`"), `rtol`/`atol` on an RK4 model the
/// tolerances of `--solver dopri5`; a model's `h` too small for the step
/// limit is refused at `--solver`.
#[test]
fn a_solver_flag_takes_the_models_step_and_tolerances() {
    let dir = tempfile::tempdir().unwrap();
    let run = |name: &str, text: &str, extra: &[&str]| {
        let model = write(dir.path(), name, text);
        let csv = dir.path().join(format!("{name}.csv"));
        let mut args = vec![
            "run",
            model.to_str().unwrap(),
            "--no-mcap",
            "--csv",
            csv.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        let out = hybsim(dir.path(), &args);
        (out, std::fs::read_to_string(csv).unwrap_or_default())
    };
    let decay = |sim: &str| {
        format!("model decay\nstate x = 1\nflow {{ x' = -x }}\nsim {{ T = 0.5; {sim} }}\n")
    };
    let (out, given) = run("a.hyb", &decay("h = 0.01"), &["--solver", "rk4"]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let (_, stated) = run("b.hyb", &decay("solver = rk4; h = 0.01"), &[]);
    assert_eq!(given, stated, "the model's h = 0.01");
    // 50 steps: the initial sample, 50 step ends, the final repeat at most.
    assert!(
        given.lines().count() < 60,
        "{} lines",
        given.lines().count()
    );

    let (out, given) = run(
        "c.hyb",
        &decay("solver = rk4; rtol = 1e-11; atol = 1e-13"),
        &["--solver", "dopri5"],
    );
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let (_, stated) = run("d.hyb", &decay("rtol = 1e-11; atol = 1e-13"), &[]);
    assert_eq!(given, stated, "the model's rtol and atol");

    let (out, _) = run("e.hyb", &decay("h = 1e-300"), &["--solver", "rk4"]);
    assert_eq!(code(&out), 2, "{}", stderr(&out));
    assert!(
        stderr(&out).contains("`--solver`: 5.000e299 integrator steps"),
        "{}",
        stderr(&out)
    );
}

/// The summary line sums a large rule family (more than 8 members fired)
/// into one entry — 10⁴ agents' rules made a line of 200 kB — and lists a
/// small one rule by rule; `--json` keeps every rule.
#[test]
fn the_summary_sums_a_large_rule_family() {
    let dir = tempfile::tempdir().unwrap();
    let model = write(
        dir.path(),
        "clocks.hyb",
        "model clocks\nparam N = 20\nfor i in 1..N { state tau[i] = i/N }\n\
         flow { for i in 1..N { tau[i]' = 1 } }\n\
         for i in 1..N { jump fire[i] when tau[i] >= 1 { tau[i]+ = 0 } }\n\
         state s = 0\nflow { s' = 1 }\njump tick when s >= 0.5 { s+ = 0 }\nsim { T = 1.01 }\n",
    );
    let m = model.to_str().unwrap();
    let out = hybsim(dir.path(), &["run", m, "--no-mcap"]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let line = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        line.contains("jumps: fire[…] 21 (20 rules), tick 2;"),
        "{line}"
    );
    let out = hybsim(dir.path(), &["run", m, "--no-mcap", "--set", "N=3"]);
    let line = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        line.contains("jumps: fire[1] 1, fire[2] 1, fire[3] 2, tick 2;"),
        "{line}"
    );
    let out = hybsim(dir.path(), &["run", m, "--no-mcap", "--json"]);
    let summary: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(summary["jumps"]["fire[20]"], 2, "{summary}");
    assert_eq!(summary["jumps"].as_object().unwrap().len(), 21);
}

#[test]
fn run_writes_mcap_csv_and_svg_and_prints_a_summary() {
    let dir = tempfile::tempdir().unwrap();
    let model = ball_model();
    let out = hybsim(
        dir.path(),
        &[
            "run",
            model.to_str().unwrap(),
            "--csv",
            "ball.csv",
            "--plot",
            "ball.svg",
            "--dt-out",
            "0.01",
            "--J",
            "5",
        ],
    );
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let summary = String::from_utf8_lossy(&out.stdout);
    assert!(
        summary.starts_with("bouncing_ball: ended at (t = ") && summary.contains("j = 5)"),
        "{summary}"
    );
    assert!(
        summary.contains("jumps: impact 5") && summary.contains("wall"),
        "{summary}"
    );
    // Default MCAP name: the model's, in the current directory.
    for f in ["bouncing_ball.mcap", "ball.csv", "ball.svg"] {
        assert!(dir.path().join(f).exists(), "{f} missing");
    }
    assert_eq!(temp_files(dir.path()), Vec::<String>::new());

    // Impact times in the file against the closed form (g = 9.81, λ = 0.8, h0 = 1).
    let bytes = std::fs::read(dir.path().join("bouncing_ball.mcap")).unwrap();
    let mut impacts = Vec::new();
    let mut decoder = hybsim::sinks::mcap_read::MessageDecoder::default();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        if m.channel.topic == "/hybsim/jumps" {
            let body: Value = decoder.decode(&m).unwrap();
            impacts.push(body["t"].as_f64().unwrap());
        }
    }
    let (g, lambda) = (9.81_f64, 0.8_f64);
    let mut t = (2.0 / g).sqrt();
    let v0 = (2.0 * g).sqrt();
    assert_eq!(impacts.len(), 5);
    for (k, tk) in impacts.iter().enumerate() {
        assert!((tk - t).abs() < 1e-9, "impact {k}: {tk} vs {t}");
        t += 2.0 * lambda.powi(k as i32 + 1) * v0 / g;
    }
}

#[test]
fn same_seed_same_bytes_and_overrides_are_recorded() {
    let dir = tempfile::tempdir().unwrap();
    let model = ball_model();
    let args = [
        "run",
        model.to_str().unwrap(),
        "-o",
        "a.mcap",
        "--seed",
        "11",
        "--set",
        "lambda=0.5",
    ];
    assert_eq!(code(&hybsim(dir.path(), &args)), 0);
    let first = std::fs::read(dir.path().join("a.mcap")).unwrap();
    assert_eq!(code(&hybsim(dir.path(), &args)), 0);
    let second = std::fs::read(dir.path().join("a.mcap")).unwrap();
    assert!(first == second, "same seed and command, different bytes");

    let summary = mcap::read::Summary::read(&first).unwrap().unwrap();
    let meta: std::collections::BTreeMap<String, _> = summary
        .metadata_indexes
        .iter()
        .map(|i| {
            let m = mcap::read::metadata(&first, i).unwrap();
            (m.name, m.metadata)
        })
        .collect();
    assert_eq!(meta["hybsim.run"]["seed"], "11");
    assert_eq!(meta["hybsim.parameters"]["lambda"], "0.5");
    assert!(meta["hybsim.run"]["argv"].contains("lambda=0.5"));
    let source = std::fs::read_to_string(&model).unwrap();
    let attached = summary
        .attachment_indexes
        .iter()
        .map(|i| mcap::read::attachment(&first, i).unwrap())
        .find(|a| a.name == "bouncing_ball.hyb")
        .unwrap();
    assert_eq!(attached.data.as_ref(), source.as_bytes());
}

#[test]
fn model_errors_exit_2_with_located_diagnostics() {
    let dir = tempfile::tempdir().unwrap();
    let bad = write(
        dir.path(),
        "bad.hyb",
        "model bad\nstate x = 1\nflow { x' = y }\n",
    );
    for sub in ["check", "run"] {
        let out = hybsim(dir.path(), &[sub, bad.to_str().unwrap()]);
        assert_eq!(code(&out), 2, "{sub}");
        let err = stderr(&out);
        assert!(err.contains("bad.hyb:3:13"), "{sub}: {err}");
    }
    assert!(!dir.path().join("bad.mcap").exists());

    let model = ball_model();
    let ok = hybsim(dir.path(), &["check", model.to_str().unwrap()]);
    assert_eq!(code(&ok), 0, "{}", stderr(&ok));
    let unknown = hybsim(
        dir.path(),
        &["run", model.to_str().unwrap(), "--set", "nosuch=1"],
    );
    assert_eq!(code(&unknown), 2);
    let malformed = hybsim(
        dir.path(),
        &["run", model.to_str().unwrap(), "--set", "lambda=*"],
    );
    assert_eq!(code(&malformed), 2);
    let inconsistent = hybsim(
        dir.path(),
        &["run", model.to_str().unwrap(), "--step", "1e-3"],
    );
    assert_eq!(code(&inconsistent), 2);
    assert!(stderr(&inconsistent).contains("--step"));
}

#[test]
fn failed_runs_exit_1_and_still_leave_a_complete_file() {
    let dir = tempfile::tempdir().unwrap();
    // ẋ = x², x(0) = 1 blows up at t = 1.
    let model = write(
        dir.path(),
        "blowup.hyb",
        "model blowup\nstate x = 1\nflow { x' = x^2 }\nsim { T = 2 }\n",
    );
    let out = hybsim(
        dir.path(),
        &[
            "run",
            model.to_str().unwrap(),
            "--no-mcap",
            "--csv",
            "b.csv",
        ],
    );
    assert_eq!(code(&out), 1, "{}", stderr(&out));
    assert!(dir.path().join("b.csv").exists());
    assert!(!dir.path().join("blowup.mcap").exists());

    let out = hybsim(
        dir.path(),
        &["run", model.to_str().unwrap(), "-o", "b.mcap"],
    );
    assert_eq!(code(&out), 1);
    let bytes = std::fs::read(dir.path().join("b.mcap")).unwrap();
    let result = mcap_metadata(&bytes, "hybsim.result");
    assert_eq!(result["status"], "failed");
    let t_end: f64 = result["t_end"].parse().unwrap();
    assert!(
        (t_end - 1.0).abs() < 1e-3,
        "blow-up near t = 1, stopped at {t_end}"
    );
}

/// A logged output that turns NaN stops the run at the sample where the MCAP sink met it,
/// not at the end of the integrator step holding that sample: the summary, the MCAP
/// result and the CSV's last row (with or without an output grid) give the same point.
#[test]
fn a_non_finite_output_stops_every_file_at_the_same_sample() {
    let dir = tempfile::tempdir().unwrap();
    // x = 1/(1 - t) passes 2 (log(2 - x) is NaN) at t = 1/2, inside an integrator step.
    let model = write(
        dir.path(),
        "lg.hyb",
        "model lg\nstate x = 1\nflow { x' = x^2 }\noutput lg = log(2 - x)\nsim { T = 0.9 }\n",
    );
    for grid in [None, Some("0.01")] {
        let mut args = vec![
            "run",
            model.to_str().unwrap(),
            "-o",
            "b.mcap",
            "--csv",
            "b.csv",
        ];
        if let Some(dt) = grid {
            args.extend(["--dt-out", dt]);
        }
        let out = hybsim(dir.path(), &args);
        assert_eq!(code(&out), 1, "{}", stderr(&out));
        let bytes = std::fs::read(dir.path().join("b.mcap")).unwrap();
        let summary = mcap::read::Summary::read(&bytes).unwrap().unwrap();
        let result = mcap_metadata(&bytes, "hybsim.result");
        let t_end: f64 = result["t_end"].parse().unwrap();
        assert!((0.5..0.6).contains(&t_end), "{grid:?}: {t_end}");
        let csv = std::fs::read_to_string(dir.path().join("b.csv")).unwrap();
        let rows: Vec<(f64, &str)> = csv
            .lines()
            .skip(1)
            .map(|l| {
                let mut f = l.split(',');
                let t = f.next().unwrap().parse().unwrap();
                (t, f.nth(1).unwrap())
            })
            .collect();
        // A failed run: the CSV ends at the first NaN sample, without a
        // `final` one (README), ...
        let &(t_last, kind) = rows.last().unwrap();
        assert_eq!((t_last, kind), (t_end, "flow"), "{grid:?}\n{csv}");
        assert!(rows.iter().all(|r| r.1 != "final"), "{grid:?}\n{csv}");
        // ... and the summary, the MCAP and the CSV count the same samples
        // (the MCAP holds all but the NaN one).
        let samples = &result["samples"];
        assert_eq!(samples, &rows.len().to_string(), "{grid:?}\n{csv}");
        let states = summary
            .channels
            .values()
            .find(|c| c.topic == "/hybsim/state")
            .map(|c| summary.stats.as_ref().unwrap().channel_message_counts[&c.id])
            .unwrap();
        assert_eq!(states as usize, rows.len() - 1, "{grid:?}");
        let line = String::from_utf8_lossy(&out.stdout);
        assert!(
            line.contains(&format!(
                "ended at (t = {}, j = 0)",
                hybsim::num::Num(t_end)
            )) && line.contains(&format!("; {samples} samples;")),
            "{grid:?}: {line}"
        );
    }
}

#[test]
fn zeno_flags_of_run_and_test() {
    // Issue 16: the Zeno knobs are flags; the summary counts the jumps made.
    let dir = tempfile::tempdir().unwrap();
    let model = write(
        dir.path(),
        "counter.hyb",
        "model counter\nstate k = 0\njump step when k >= 0 { k+ = k + 1 }\n\
         property grows: at jumps post(k) == k + 1\n",
    );
    let m = model.to_str().unwrap();
    let out = hybsim(
        dir.path(),
        &["run", m, "--no-mcap", "--zeno-window", "4", "-q"],
    );
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let summary = String::from_utf8_lossy(&out.stdout);
    assert!(summary.contains("after 4 jumps"), "{summary}");
    // The counts take what their `sim` keys take: `1e7` as well as 10000000
    // (clap once refused `3e1`: "invalid digit found in string").
    for budget in ["30", "3e1"] {
        let out = hybsim(
            dir.path(),
            &[
                "run",
                m,
                "--no-mcap",
                "--zeno-rate",
                "inf",
                "--max-total-jumps",
                budget,
                "-q",
            ],
        );
        let summary = String::from_utf8_lossy(&out.stdout);
        assert!(summary.contains("30 jumps in total"), "{summary}");
    }
    for window in ["3", "3e0"] {
        let out = hybsim(
            dir.path(),
            &["test", m, "--cases", "2", "--zeno-window", window],
        );
        assert_eq!(code(&out), 0, "{}", stderr(&out));
    }
}

/// `hybsim check --message-format json`: one object per diagnostic and line on
/// stdout, with code, severity, file and 1-based line/column; nothing else.
#[test]
fn check_prints_diagnostics_as_json_lines() {
    let dir = tempfile::tempdir().unwrap();
    let bad = write(
        dir.path(),
        "bad.hyb",
        "model bad\nstate h = 1\nflow { h' = v }\noutput y = w\n",
    );
    let out = hybsim(
        dir.path(),
        &["check", bad.to_str().unwrap(), "--message-format", "json"],
    );
    assert_eq!(code(&out), 2);
    let text = crate::util::stdout(&out);
    let mut diags: Vec<Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    diags.sort_by_key(|d| d["line"].as_u64());
    assert_eq!(diags.len(), 2, "{text}");
    for (d, (line, col)) in diags.iter().zip([(3, 13), (4, 12)]) {
        assert_eq!(d["severity"], "error", "{d}");
        assert!(d["code"].as_str().unwrap().starts_with('E'), "{d}");
        assert!(d["file"].as_str().unwrap().ends_with("bad.hyb"), "{d}");
        assert_eq!(d["line"], line, "{d}");
        assert_eq!(d["column"], col, "{d}");
    }
    assert!(stderr(&out).is_empty(), "{}", stderr(&out));
    let good = hybsim(
        dir.path(),
        &[
            "check",
            ball_model().to_str().unwrap(),
            "--message-format",
            "json",
        ],
    );
    assert_eq!(code(&good), 0);
    assert!(crate::util::stdout(&good).is_empty());
    let missing = hybsim(
        dir.path(),
        &["check", "nope.hyb", "--message-format", "json"],
    );
    assert_eq!(code(&missing), 2);
    let v: Value = serde_json::from_str(crate::util::stdout(&missing).trim()).unwrap();
    assert!(
        v["message"].as_str().unwrap().contains("cannot read"),
        "{v}"
    );
}

/// `--color always|never` and `NO_COLOR`: ANSI escapes only when asked.
#[test]
fn color_follows_the_flag_and_no_color() {
    let dir = tempfile::tempdir().unwrap();
    let bad = write(dir.path(), "bad.hyb", "model bad\nstate h = x\n");
    let bad = bad.to_str().unwrap();
    let always = hybsim(dir.path(), &["check", bad, "--color", "always"]);
    assert!(stderr(&always).contains('\x1b'), "{}", stderr(&always));
    let never = hybsim(dir.path(), &["--color", "never", "check", bad]);
    assert!(!stderr(&never).contains('\x1b'));
    // `auto` never colours a pipe, whatever NO_COLOR says.
    let auto = std::process::Command::new(env!("CARGO_BIN_EXE_hybsim"))
        .args(["check", bad])
        .env("NO_COLOR", "1")
        .output()
        .unwrap();
    assert!(!stderr(&auto).contains('\x1b'));
    assert_eq!(
        code(&hybsim(dir.path(), &["check", bad, "--color", "blue"])),
        2
    );
}

/// `hybsim completions SHELL` prints a script that names the subcommands.
#[test]
fn completions_for_each_shell() {
    let dir = tempfile::tempdir().unwrap();
    for shell in ["bash", "zsh", "fish", "elvish", "powershell"] {
        let out = hybsim(dir.path(), &["completions", shell]);
        assert_eq!(code(&out), 0, "{shell}: {}", stderr(&out));
        let text = crate::util::stdout(&out);
        for word in ["run", "check", "sweep", "message-format"] {
            assert!(text.contains(word), "{shell} lacks {word}");
        }
    }
    assert_eq!(code(&hybsim(dir.path(), &["completions", "tcsh"])), 2);
}

/// `--plot-kind`: HyEQ's plots from a run, each with its axes and series
/// names; a phase plot of one component is a usage error.
#[test]
fn plot_kinds_draw_their_axes_and_series() {
    let dir = tempfile::tempdir().unwrap();
    let m = ball_model();
    let m = m.to_str().unwrap();
    // The texts of an SVG's `<text>` elements.
    let texts = |svg: &str| -> Vec<String> {
        svg.split("<text")
            .skip(1)
            .filter_map(|s| {
                let body = &s[s.find('>')? + 1..];
                Some(body[..body.find("</text>")?].trim().to_string())
            })
            .collect()
    };
    for (kind, vars, must) in [
        ("flows", "h,v", vec!["t", "h", "v"]),
        ("jumps", "h", vec!["j", "h"]),
        ("phase", "h,v", vec!["h", "v", "v vs h"]),
        ("domain", "h", vec!["t", "j", "(t, j)"]),
    ] {
        let svg = dir.path().join(format!("{kind}.svg"));
        let out = hybsim(
            dir.path(),
            &[
                "run",
                m,
                "--no-mcap",
                "-q",
                "--plot",
                svg.to_str().unwrap(),
                "--plot-kind",
                kind,
                "--plot-vars",
                vars,
            ],
        );
        assert_eq!(code(&out), 0, "{kind}: {}", stderr(&out));
        let text = std::fs::read_to_string(&svg).unwrap();
        let labels = texts(&text);
        for s in must {
            assert!(
                labels.iter().any(|l| l == s),
                "{kind}: no text `{s}` in {labels:?}"
            );
        }
        // Jumps are dashed: many short segments of the lighter colour.
        assert!(text.matches("<polyline").count() + text.matches("<path").count() > 10);
    }
    let out = hybsim(
        dir.path(),
        &[
            "run",
            m,
            "--no-mcap",
            "-q",
            "--plot",
            "p.svg",
            "--plot-kind",
            "phase",
            "--plot-vars",
            "h",
        ],
    );
    assert_eq!(code(&out), 2, "{}", stderr(&out));
    assert!(stderr(&out).contains("two components"), "{}", stderr(&out));
    assert!(!dir.path().join("p.svg").exists());
}

/// A discrete-time model with tens of thousands of jumps draws a bounded
/// SVG (jump samples thinned, dashes merged above `MAX_DASHED_JUMPS`).
#[test]
fn plots_of_many_jumps_stay_small() {
    let dir = tempfile::tempdir().unwrap();
    let m = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/platoon.hyb");
    let svg = dir.path().join("platoon.svg");
    let out = hybsim(
        dir.path(),
        &[
            "run",
            m.to_str().unwrap(),
            "--no-mcap",
            "-q",
            "--plot",
            svg.to_str().unwrap(),
        ],
    );
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let size = std::fs::metadata(&svg).unwrap().len();
    assert!(size < 5_000_000, "platoon SVG is {size} bytes");
}

/// `hybsim info`: what the file holds and a replay command that rebuilds
/// it byte for byte; truncated, empty and foreign files exit 2.
#[test]
fn info_describes_a_run_and_replays_it() {
    let dir = tempfile::tempdir().unwrap();
    let m = ball_model();
    let run = hybsim(
        dir.path(),
        &[
            "run",
            m.to_str().unwrap(),
            "-o",
            "a.mcap",
            "--seed",
            "3",
            "--set",
            "lambda=0.7",
            "-q",
        ],
    );
    assert_eq!(code(&run), 0, "{}", stderr(&run));
    std::fs::rename(dir.path().join("a.mcap"), dir.path().join("b.mcap")).unwrap();
    let info = hybsim(dir.path(), &["info", "b.mcap"]);
    assert_eq!(code(&info), 0, "{}", stderr(&info));
    let text = crate::util::stdout(&info);
    for s in [
        "bouncing_ball",
        "seed        3",
        "lambda = 0.7",
        "/hybsim/state",
        "/hybsim/jumps",
        "result",
    ] {
        assert!(text.contains(s), "no `{s}` in\n{text}");
    }
    let replay = text
        .lines()
        .find_map(|l| l.strip_prefix("replay      "))
        .expect("a replay line");
    let words: Vec<&str> = replay.split_whitespace().collect();
    assert_eq!(words[0], "hybsim");
    let again = hybsim(dir.path(), &words[1..]);
    assert_eq!(code(&again), 0, "{}", stderr(&again));
    assert!(
        std::fs::read(dir.path().join("a.mcap")).unwrap()
            == std::fs::read(dir.path().join("b.mcap")).unwrap(),
        "the replayed run differs"
    );
    let json = hybsim(dir.path(), &["info", "--json", "b.mcap"]);
    let v: Value = serde_json::from_str(&crate::util::stdout(&json)).unwrap();
    assert_eq!(v["metadata"]["hybsim.run"]["seed"], 3);

    let bytes = std::fs::read(dir.path().join("b.mcap")).unwrap();
    std::fs::write(dir.path().join("cut.mcap"), &bytes[..bytes.len() / 2]).unwrap();
    std::fs::write(dir.path().join("empty.mcap"), b"").unwrap();
    for (file, says) in [
        ("cut.mcap", "cut short"),
        ("empty.mcap", "not an MCAP file"),
        (m.to_str().unwrap(), "not an MCAP file"),
        ("missing.mcap", "cannot read"),
    ] {
        let out = hybsim(dir.path(), &["info", file]);
        assert_eq!(code(&out), 2, "{file}");
        assert!(stderr(&out).contains(says), "{file}: {}", stderr(&out));
    }
}

/// `-` is standard input for the model and standard output for `-o`/`--csv`
/// (and `hybsim fmt -` is a filter).
#[test]
fn dash_is_stdin_for_models_and_stdout_for_outputs() {
    use std::io::Write;
    use std::process::{Command, Stdio};
    let dir = tempfile::tempdir().unwrap();
    let source = std::fs::read_to_string(ball_model()).unwrap();
    let pipe = |args: &[&str], input: &str| {
        let mut child = Command::new(env!("CARGO_BIN_EXE_hybsim"))
            .args(args)
            .current_dir(dir.path())
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        child
            .stdin
            .take()
            .unwrap()
            .write_all(input.as_bytes())
            .unwrap();
        child.wait_with_output().unwrap()
    };
    let csv = pipe(&["run", "-", "--no-mcap", "--csv", "-", "-q"], &source);
    assert_eq!(code(&csv), 0, "{}", stderr(&csv));
    let text = crate::util::stdout(&csv);
    assert!(
        text.starts_with("t,j,kind,h,v"),
        "{}",
        &text[..text.len().min(80)]
    );
    assert!(!text.contains("ended at"), "the summary is not in the CSV");
    let mcap = pipe(&["run", "-", "-o", "-", "-q"], &source);
    assert_eq!(code(&mcap), 0, "{}", stderr(&mcap));
    // The file alone: the summary goes to stderr when stdout holds an output.
    assert!(mcap.stdout.starts_with(b"\x89MCAP0\r\n") && mcap.stdout.ends_with(b"\x89MCAP0\r\n"));
    assert!(
        stderr(&mcap).contains("bouncing_ball: ended at"),
        "{}",
        stderr(&mcap)
    );
    assert!(!dir.path().join("-").exists());
    let check = pipe(&["check", "-"], "model m\nstate x = y\n");
    assert_eq!(code(&check), 2);
    assert!(
        stderr(&check).contains("<stdin>:2:11"),
        "{}",
        stderr(&check)
    );
    let fmt = pipe(&["fmt", "-"], "model m\nstate x=1\n");
    assert_eq!(crate::util::stdout(&fmt), "model m\nstate x = 1\n");
    // The verdict names standard input as the diagnostics do (it said `-: no errors`).
    let check = pipe(&["check", "-"], "model m\nstate x = 1\n");
    assert_eq!(code(&check), 0);
    assert_eq!(stdout(&check), "<stdin>: no errors\n");
    let check = pipe(&["check", "-"], "model m\nstate x = y\n");
    assert!(
        stderr(&check).ends_with("<stdin>: 1 error\n"),
        "{}",
        stderr(&check)
    );
}

/// `hybsim design --json` prints JSON for a model without design blocks too (`{}`): it printed
/// the sentence `model.hyb: no design blocks`, which broke a reader of its standard output.
#[test]
fn design_json_of_a_model_without_blocks_is_an_empty_object() {
    let dir = tempfile::tempdir().unwrap();
    let out = hybsim(
        dir.path(),
        &["design", ball_model().to_str().unwrap(), "--json"],
    );
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let v: Value = serde_json::from_str(&stdout(&out)).expect("JSON on stdout");
    assert_eq!(v, serde_json::json!({}));
    let out = hybsim(dir.path(), &["design", ball_model().to_str().unwrap()]);
    assert!(stdout(&out).ends_with("bouncing_ball.hyb: no design blocks\n"));
}

/// `hybsim run --json`: the summary as one JSON object on stdout.
#[test]
fn run_prints_its_summary_as_json() {
    let dir = tempfile::tempdir().unwrap();
    let m = ball_model();
    let out = hybsim(
        dir.path(),
        &[
            "run",
            m.to_str().unwrap(),
            "--json",
            "-q",
            "--J",
            "5",
            "--csv",
            "b.csv",
            "--no-mcap",
        ],
    );
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let v: Value = serde_json::from_str(&crate::util::stdout(&out)).unwrap();
    assert_eq!(v["model"], "bouncing_ball");
    assert_eq!(v["status"], "completed");
    assert_eq!(v["cause"], "horizon_j");
    assert_eq!(v["end"]["j"], 5);
    assert_eq!(v["jumps"]["impact"], 5);
    assert_eq!(v["jumps_total"], 5);
    assert!(v["samples"].as_u64().unwrap() > 10);
    assert!(v["written"][0].as_str().unwrap().ends_with("b.csv"));
    assert!(!stderr(&out).contains("wrote"));
}

/// An error in a flag that is a `sim` key names the flag as the user typed it (`--T 0`), not
/// the override it is passed as (`sim.T=0e0`, all digits).
#[test]
fn an_invalid_flag_value_is_shown_as_typed() {
    let dir = tempfile::tempdir().unwrap();
    let ball = ball_model();
    let ball = ball.to_str().unwrap();
    for (args, says, at) in [
        (
            &["--T", "0"][..],
            "in `--T 0`: invalid `T`: 0 is out of range",
            "┌─ --T:1:5",
        ),
        (
            &["--T", "1e400"],
            "in `--T 1e400`: invalid `T`: inf",
            "┌─ --T:1:5",
        ),
        (
            &["--zeno-window", "1"],
            "in `--zeno-window 1`: invalid `zeno_window`",
            "┌─ --zeno-window:1:15",
        ),
        // A whole number past the range is named as such, not "not an integer".
        (
            &["--zeno-window", "1e20"],
            "in `--zeno-window 1e20`: invalid `zeno_window`: 1e20 is not a whole number in 2..=4294967295",
            "┌─ --zeno-window:1:15",
        ),
        // Negative numbers reach the checker (clap took `-1` for a flag and
        // suggested `-- -1`).
        (
            &["--J", "-1"],
            "in `--J -1`: invalid `J`: -1 is out of range",
            "┌─ --J:1:5",
        ),
        (
            &["--dt-out", "-0.5"],
            "in `--dt-out -0.5`: invalid `dt_out`: -0.5 is out of range",
            "┌─ --dt-out:1:10",
        ),
    ] {
        let mut all = vec!["run", ball, "--no-mcap"];
        all.extend(args);
        let out = hybsim(dir.path(), &all);
        assert_eq!(code(&out), 2, "{args:?}");
        let err = stderr(&out);
        assert!(err.contains(says) && err.contains(at), "{args:?}: {err}");
        assert!(!err.contains("sim.") && !err.contains("--set"), "{err}");
    }
}

/// A logged output that becomes non-finite stops a run logging to MCAP
/// (which holds finite numbers only) with a run-time error at the output's
/// definition and (t, j), as a non-finite state does (exit 1); the file
/// records the run up to there.
#[test]
fn a_non_finite_output_is_an_error_at_its_definition() {
    let dir = tempfile::tempdir().unwrap();
    let model = write(
        dir.path(),
        "nanout.hyb",
        "model nanout\nstate x = 3\noutput e[1] = x\noutput e[2] = log(x - 2)\n\
         flow { x' = -x }\nsim { T = 2 }\n",
    );
    let out = hybsim(
        dir.path(),
        &[
            "run",
            model.to_str().unwrap(),
            "-o",
            "run.mcap",
            "--color",
            "never",
        ],
    );
    assert_eq!(code(&out), 1);
    let text = stderr(&out);
    assert!(
        text.contains("error[E0602]: output `e[2]` is not finite (NaN) at (t = ")
            && text.contains("nanout.hyb:4:8")
            && text.contains("output e[2] = log(x - 2)"),
        "{text}"
    );
    assert!(dir.path().join("run.mcap").exists());
}
