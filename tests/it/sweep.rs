//! Metrics in the model (`metric …`) and `hybsim sweep`: values against
//! closed forms, located errors, the MCAP record, replay of a row,
//! determinism over threads and shards, failing grid points.

use std::path::Path;

use hybsim::lang;
use hybsim::source::SourceFile;

use crate::util::{code, hybsim, stderr, stdout};

/// x' = 1 from 0 over [0, 10] sampled every 0.1, a timer firing every 1
/// (the sample at t = 3 is 30·0.1 = 3.0000000000000004, outside `t <= 3`).
const RAMP: &str = "model ramp
state x = 0
flow { x' = 1 }
every 1 { }
jump reset_never when x >= 100 { x+ = 0 }
output sq = x * x
metric area = integral(x), avg = mean(x), late = mean(x, t >= 5)
metric top = max(x), bottom = min(x - 3), last = final(x), ticks = count(step)
metric late_ticks = count(step, t > 4.5), per_time = count(step) / t
metric area_sq = integral(sq, t <= 3), scaled = 2 * final(x) + mean(x)
metric at_2 = final(x, t <= 2.05), never = final(x, t > 100)
sim { T = 10; dt_out = 0.1 }
";

fn metrics_of(text: &str) -> Vec<(String, f64)> {
    let src = SourceFile::new("m.hyb", text);
    let model = lang::compile(&src, &[]).unwrap_or_else(|d| {
        panic!("{}", hybsim::diagnostics::render(&d, &src, false));
    });
    let (x0, mut rng) = model.start(model.seed());
    let mut sink = model.metrics().sink();
    hybsim::engine::simulate(&model, &x0, &model.settings(), &mut rng, &mut sink).unwrap();
    sink.named_values()
}

#[test]
fn metrics_match_closed_forms() {
    let m = metrics_of(RAMP);
    let get = |n: &str| m.iter().find(|(k, _)| k == n).unwrap().1;
    let close = |a: f64, b: f64| (a - b).abs() < 1e-9 * (1.0 + b.abs());
    assert!(close(get("area"), 50.0), "{m:?}");
    assert!(close(get("avg"), 5.0));
    assert!(close(get("late"), 7.5));
    assert!(close(get("top"), 10.0));
    assert!(close(get("bottom"), -3.0));
    assert!(close(get("last"), 10.0));
    // The timer fires at t = 1, …, 9; the run ends at T = 10 before the tenth.
    assert_eq!(get("ticks"), 9.0);
    assert_eq!(get("late_ticks"), 5.0);
    assert!(close(get("per_time"), 0.9));
    // ∫_0^3 x² dt = 9 on the steps' paths, whatever the sample grid (the
    // trapezoid rule on the 0.1 grid gave 9 + 3·0.1²/6).
    assert!(close(get("area_sq"), 9.0), "{}", get("area_sq"));
    assert!(close(get("scaled"), 25.0));
    // The window's last point: where it closes, between two samples; NaN if
    // there is none.
    assert!(close(get("at_2"), 2.05), "{}", get("at_2"));
    assert!(get("never").is_nan());
    let names: Vec<&str> = m.iter().map(|(k, _)| k.as_str()).collect();
    assert_eq!(names[..3], ["area", "avg", "late"]);
}

/// Integrals, means and windows on long steps (exact timer, polynomial and exponential flows,
/// no `dt_out`: one or a few steps per flow interval) follow the path between the samples: the
/// trapezoid rule between step ends gave `integral(x, t >= 2.5)` = 0 (the step [2, 4] straddles
/// the window's start) and `mean(x^2)` = 2 on the saw-tooth below.
#[test]
fn integrals_means_and_windows_follow_the_path_between_samples() {
    let close = |a: f64, b: f64| (a - b).abs() < 1e-9 * (1.0 + b.abs());
    let m = metrics_of(
        "model saw
state x = 0
flow { x' = 1 }
jump reset when x >= 2 { x+ = 0 }
metric late = integral(x, t >= 2.5), sq = mean(x^2), band = integral(1, x >= 0.5 && x <= 1.25)
metric upto = final(x, t <= 2.5), top = max(x, t <= 1.5), low = min(x, t >= 2.25)
sim { T = 4; J = 10 }
",
    );
    // `band` opens and closes inside each one-step tooth: 0.75 of each.
    let want = [1.875, 4.0 / 3.0, 1.5, 0.5, 1.5, 0.25];
    for ((name, got), want) in m.iter().zip(want) {
        assert!(close(*got, want), "{name} = {got}, want {want}: {m:?}");
    }
    // A bouncing ball's exact polynomial flights: ∫h and the mean of h after t = 1 in closed form.
    let m = metrics_of(
        "model ball
state h = 1, v = 0
flow { h' = v; v' = -9.81 }
jump bounce when h <= 0 && v <= 0 { v+ = -0.8 * v }
metric area = integral(h), late = mean(h, t >= 1)
sim { T = 3; J = 100 }
",
    );
    let (g, horizon) = (9.81, 3.0);
    let (mut t, mut h, mut v, mut area, mut late) = (0.0_f64, 1.0_f64, 0.0_f64, 0.0, 0.0);
    while t < horizon {
        let flight = (v + (v * v + 2.0 * g * h).sqrt()) / g;
        let height = |s: f64| h * s + v * s * s / 2.0 - g * s * s * s / 6.0;
        let end = (t + flight).min(horizon);
        area += height(end - t);
        if end > 1.0 {
            late += height(end - t) - height((1.0_f64 - t).max(0.0));
        }
        (t, h, v) = (t + flight, 0.0, -0.8 * (v - g * flight));
    }
    assert!(close(m[0].1, area), "{m:?} against {area}");
    assert!(close(m[1].1, late / 2.0), "{m:?} against {}", late / 2.0);
    // An exponential decay in long exact steps and on Dopri5's steps.
    for exact in ["on", "off"] {
        let m = metrics_of(&format!(
            "model decay
state x = 1
flow {{ x' = -x }}
metric area = integral(x), late = mean(x, t >= 1)
sim {{ T = 5; exact_affine = {exact}; rtol = 1e-10; atol = 1e-12 }}
"
        ));
        let e = |t: f64| (-t).exp();
        assert!(close(m[0].1, 1.0 - e(5.0)), "{exact}: {m:?}");
        assert!(close(m[1].1, (e(1.0) - e(5.0)) / 4.0), "{exact}: {m:?}");
    }
}

#[test]
fn metric_families_and_rule_families() {
    let m = metrics_of(
        "model fam
param N = 3
for i in 1..N {
  state x[i] = i / 10
  flow { x[i]' = 1 }
  jump fire[i] when x[i] >= i { x[i]+ = 0 }
  metric rate[i] = count(fire[i]) / t
}
metric total = count(fire), empty = mean(x[1], t > 100)
sim { T = 12 }
",
    );
    let names: Vec<&str> = m.iter().map(|(k, _)| k.as_str()).collect();
    assert_eq!(names, ["rate[1]", "rate[2]", "rate[3]", "total", "empty"]);
    // fire[i] every i time units, the first after i − i/10.
    let counts = [12.0, 6.0, 4.0];
    for (k, c) in counts.iter().enumerate() {
        assert!((m[k].1 * 12.0 - c).abs() < 1e-9, "{m:?}");
    }
    assert_eq!(m[3].1, 22.0);
    assert!(m[4].1.is_nan(), "a mean over no time is NaN");
}

/// A family of rules over an empty range (`--set N=0`) is declared, with no member: `count` of
/// it is 0, for a plain family and for a family of instances' rules (`f.fire`) alike (it was
/// E0201 "unknown name"); an undeclared name is still that error.
#[test]
fn count_over_an_empty_family_is_zero() {
    let text = "model empty
param N = 2
subsystem Clock(p = 1) {
    state tau = 0
    flow { tau' = 1 }
    jump fire when tau >= p { tau+ = 0 }
}
for i in 1..N {
    f[i] = Clock(p = i)
    state x[i] = 0
    flow { x[i]' = 1 }
    jump tick[i] when x[i] >= 1 { x[i]+ = 0 }
}
state z = 0
flow { z' = 1 }
metric fires = count(f.fire), ticks = count(tick), late = count(f.fire, t > 2.5)
sim { T = 3.5 }
";
    let metrics = |set: &[&str]| {
        let src = SourceFile::new("m.hyb", text);
        let set: Vec<lang::Override> = set.iter().map(|s| s.parse().unwrap()).collect();
        let model = lang::compile(&src, &set).unwrap_or_else(|d| {
            panic!("{}", hybsim::diagnostics::render(&d, &src, false));
        });
        let (x0, mut rng) = model.start(model.seed());
        let mut sink = model.metrics().sink();
        hybsim::engine::simulate(&model, &x0, &model.settings(), &mut rng, &mut sink).unwrap();
        sink.named_values()
    };
    let values = |m: Vec<(String, f64)>| m.into_iter().map(|(_, v)| v).collect::<Vec<_>>();
    // Clocks of periods 1 and 2 over 3.5: 3 + 1 jumps, 1 after t = 2.5; ticks at 1, 2, 3 each.
    assert_eq!(values(metrics(&[])), [4.0, 6.0, 1.0]);
    assert_eq!(values(metrics(&["N=0"])), [0.0, 0.0, 0.0]);
    let src = SourceFile::new("m.hyb", text.replace("count(tick)", "count(tock)"));
    let d = lang::check_only(&src, &["N=0".parse().unwrap()]);
    assert_eq!(d.len(), 1, "{d:?}");
    assert_eq!(
        (d[0].code, d[0].message.as_str()),
        ("E0201", "unknown name `tock`")
    );
}

#[test]
fn samples_after_jumps_that_leave_the_metrics_unchanged_give_the_same_metrics() {
    // The sink reuses the pre-jump values after a jump writing nothing its
    // program reads (`tick` for the metrics of x); a jump writing x
    // (`reset`) or any jump for a metric of j or y must re-evaluate.
    let model = |metrics: &str| {
        format!(
            "model reuse
state x = 0, y = 0
flow {{ x' = 1; y' = 0 }}
jump reset when x >= 1 {{ x+ = 0 }}
every 0.3 {{ y+ = y + 1 }}
{metrics}
sim {{ T = 3.95 }}
"
        )
    };
    let close = |a: f64, b: f64| (a - b).abs() < 1e-9 * (1.0 + b.abs());
    // Saw-tooth x: ∫ = 3 teeth of 1/2 and 0.95²/2; min after the first reset is 0.
    let m = metrics_of(&model(
        "metric area = integral(x), low = min(x, t > 0.5), last = final(x)
metric top = max(x), avg = mean(x)",
    ));
    let area = 1.5 + 0.95 * 0.95 / 2.0;
    assert!(close(m[0].1, area), "{m:?}");
    assert_eq!(m[1].1, 0.0, "{m:?}");
    assert!(close(m[2].1, 0.95), "{m:?}");
    // The resets start from x = 1 (an event reached exactly).
    assert_eq!(m[3].1, 1.0, "{m:?}");
    assert!(close(m[4].1, area / 3.95), "{m:?}");
    // y counts the ticks at 0.3 k (k = 1…13); j counts them and the resets
    // at 1, 2, 3: each adds 1 from its time on.
    let ticks: Vec<f64> = (1..=13).map(|k| 0.3 * f64::from(k)).collect();
    let after = |times: &[f64]| times.iter().map(|t| 3.95 - t).sum::<f64>();
    let m = metrics_of(&model(
        "metric ys = integral(y), js = integral(j), jl = final(j)",
    ));
    assert!(close(m[0].1, after(&ticks)), "{m:?}");
    let mut all = ticks.clone();
    all.extend([1.0, 2.0, 3.0]);
    assert!(close(m[1].1, after(&all)), "{m:?}");
    assert_eq!(m[2].1, 16.0, "{m:?}");
}

#[test]
fn period_is_the_asymptotic_period_of_the_values_at_the_jumps() {
    // x cycles 0, 1, 2 from the start; z settles geometrically on the cycle
    // 1, 4 (period 2 only once the transient is below the detector's 1e-9);
    // y never repeats; w is constant (period 1).
    let m = metrics_of(
        "model cyc
state x = 0, y = 0, z = 5, w = 7, s = 0
every 1 {
  x+ = if x >= 2 then 0 else x + 1
  y+ = y + 1
  z+ = if s == 0 then 1 + (z - 4) / 2 else 4 + (z - 1) / 2
  s+ = 1 - s
  w+ = w
}
metric px = period(x), py = period(y), pz = period(z), pw = period(w)
metric late = period(x, t >= 50), early = period(x, t < 3), short = period(x, t > 199)
sim { T = 200.5 }
",
    );
    let get = |n: &str| m.iter().find(|(k, _)| k == n).unwrap().1;
    assert_eq!(get("px"), 3.0, "{m:?}");
    assert!(get("py").is_nan(), "{m:?}");
    assert_eq!(get("pz"), 2.0, "{m:?}");
    assert_eq!(get("pw"), 1.0, "{m:?}");
    assert_eq!(get("late"), 3.0, "{m:?}");
    // Too few values in the window to see 4 repeats: not periodic.
    assert!(get("early").is_nan() && get("short").is_nan(), "{m:?}");
}

#[test]
fn metric_errors_are_located() {
    let src = SourceFile::new(
        "bad.hyb",
        "model bad
state h = 1, v = 0
flow { h' = v; v' = -9.81 } in h >= 0
jump impact when h <= 0 && v <= 0 { v+ = -0.8 * v }
metric a = h + 1
metric b = count(impakt)
metric c = mean([h; v])
metric d = mean(h, 3)
metric e = final(h, t > 1, 2)
metric f = max()
",
    );
    let diags = lang::check_only(&src, &[]);
    let text = hybsim::diagnostics::render(&diags, &src, false);
    for (code, at) in [
        ("E0304", "bad.hyb:5:12"),
        ("E0201", "bad.hyb:6:18"),
        ("E0304", "bad.hyb:7:17"),
        ("E0304", "bad.hyb:8:20"),
        ("E0303", "bad.hyb:9:12"),
        ("E0303", "bad.hyb:10:12"),
    ] {
        assert!(
            text.contains(&format!("error[{code}]")) && text.contains(at),
            "{code} at {at}:\n{text}"
        );
    }
    assert!(text.contains("did you mean `impact`"), "{text}");
    // Outside metrics, `count`/`mean`/`final` are not functions and `max` is the usual one.
    let src = SourceFile::new("m.hyb", "model m\nstate x = 1\noutput y = count(x)\n");
    let text = hybsim::diagnostics::render(&lang::check_only(&src, &[]), &src, false);
    assert!(text.contains("E0203"), "{text}");
}

#[test]
fn run_prints_metrics_and_stores_them_in_the_mcap() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("ramp.hyb"), RAMP).unwrap();
    let out = hybsim(dir.path(), &["run", "ramp.hyb", "-o", "r.mcap"]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let text = stdout(&out);
    let top: f64 = text
        .lines()
        .find_map(|l| l.trim().strip_prefix("metric top = "))
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no `metric top` in {text}"));
    assert!((top - 10.0).abs() < 1e-12, "{text}");
    assert!(text.contains("metric ticks = 9"), "{text}");
    let bytes = std::fs::read(dir.path().join("r.mcap")).unwrap();
    let summary = mcap::read::Summary::read(&bytes).unwrap().unwrap();
    let metrics = summary
        .metadata_indexes
        .iter()
        .map(|i| mcap::read::metadata(&bytes, i).unwrap())
        .find(|m| m.name == "hybsim.metrics")
        .expect("a hybsim.metrics record");
    assert_eq!(metrics.metadata["ticks"], "9");
    assert_eq!(metrics.metadata.len(), 13);
}

const BALL: &str = "model ball
param g = 9.81, lambda = 0.8
state h ~ uniform(0.5, 1.5), v = 0
flow { h' = v; v' = -g } in h >= 0
jump impact when h <= 0 && v <= 0 { v+ = -lambda * v }
output energy = 0.5*v^2 + g*h
metric bounces = count(impact), e_mean = mean(energy), hmax = max(h)
sim { T = 2; dt_out = 0.01 }
";

fn sweep(dir: &Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec![
        "sweep",
        "ball.hyb",
        "--grid",
        "lambda=0.6:0.1:0.9",
        "--grid",
        "g=[9.81, 3.7]",
        "--runs",
        "3",
        "--seed",
        "5",
        "-q",
    ];
    args.extend_from_slice(extra);
    let out = hybsim(dir, &args);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    out
}

fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            (
                e.file_name().to_string_lossy().into_owned(),
                std::fs::read(e.path()).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

#[test]
fn sweeps_are_deterministic_over_threads_and_shards() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("ball.hyb"), BALL).unwrap();
    sweep(d, &["-o", "all", "--threads", "2"]);
    sweep(d, &["-o", "one", "--threads", "1"]);
    for k in 1..=3 {
        sweep(d, &["-o", &format!("s{k}"), "--shard", &format!("{k}/3")]);
    }
    let all = files(&d.join("all"));
    let names: Vec<&str> = all.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        names,
        [
            "bounces.svg",
            "e_mean.svg",
            "hmax.svg",
            "points.csv",
            "points.parquet",
            "runs.csv",
            "runs.parquet",
            "sweep.json"
        ]
    );
    assert_eq!(all, files(&d.join("one")), "1 thread vs 2 threads");
    // A shard writes its runs as CSV and Parquet (the same table), and no
    // point statistics: its points are incomplete.
    let shard = files(&d.join("s2"));
    let names: Vec<&str> = shard.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["runs.csv", "runs.parquet", "sweep.json"]);
    assert_eq!(csv_rows(&shard[0].1), parquet_as_csv(&shard[1].1));
    assert_eq!(csv_rows(&shard[0].1).len(), 1 + 8, "runs 1, 4, …, 22 of 24");
    let out = hybsim(d, &["sweep", "--merge", "s3", "s1", "s2", "-o", "merged"]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    assert_eq!(
        all,
        files(&d.join("merged")),
        "sharded + merged vs unsharded"
    );
    // A missing or repeated shard is refused.
    let out = hybsim(d, &["sweep", "--merge", "s1", "s2", "-o", "x"]);
    assert_eq!(code(&out), 1);
    assert!(stderr(&out).contains("3/3 missing"), "{}", stderr(&out));
    let out = hybsim(d, &["sweep", "--merge", "s1", "s1", "s2", "-o", "x"]);
    assert!(stderr(&out).contains("twice"), "{}", stderr(&out));
    // The output is not one of the shards (it replaced that shard's files,
    // and a merge redone from the shards then failed).
    let before = files(&d.join("s2"));
    let out = hybsim(d, &["sweep", "--merge", "s1", "s2", "s3", "-o", "./s2/"]);
    assert_eq!(code(&out), 1);
    assert!(
        stderr(&out).contains("`-o ./s2/` is the shard s2 given to merge"),
        "{}",
        stderr(&out)
    );
    assert_eq!(before, files(&d.join("s2")));

    // 8 points × 3 runs; the points table has the statistics of each point.
    let runs = String::from_utf8(all[5].1.clone()).unwrap();
    assert_eq!(runs.lines().count(), 1 + 24);
    let points = String::from_utf8(all[3].1.clone()).unwrap();
    let header: Vec<&str> = points.lines().next().unwrap().split(',').collect();
    assert_eq!(header[..5], ["point", "lambda", "g", "runs", "completed"]);
    assert!(header.contains(&"e_mean_std") && header.contains(&"hmax_count"));
    assert_eq!(points.lines().count(), 1 + 8);
}

#[test]
fn a_row_replays_alone_with_its_command() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("ball.hyb"), BALL).unwrap();
    sweep(d, &["-o", "out"]);
    let text = std::fs::read_to_string(d.join("out/runs.csv")).unwrap();
    let mut reader = csv::Reader::from_reader(text.as_bytes());
    let headers = reader.headers().unwrap().clone();
    let col = |n: &str| headers.iter().position(|h| h == n).unwrap();
    let rows: Vec<csv::StringRecord> = reader.records().map(|r| r.unwrap()).collect();
    let row = rows
        .iter()
        .find(|r| &r[col("status")] == "completed" && &r[col("run")] == "2")
        .expect("a completed run");
    let command = &row[col("command")];
    assert!(
        command.starts_with("hybsim run ball.hyb --set lambda="),
        "{command}"
    );
    let words: Vec<&str> = command.split(' ').skip(1).chain(["--no-mcap"]).collect();
    let out = hybsim(d, &words);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let text = stdout(&out);
    for m in ["bounces", "e_mean", "hmax"] {
        let line = format!("metric {m} = {}", &row[col(m)]);
        assert!(text.contains(&line), "{line} in\n{text}");
    }
}

#[test]
fn failing_grid_points_are_rows_and_the_others_complete() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("ball.hyb"), BALL).unwrap();
    // lambda = 0.3: Zeno suspected before T; T = -1: the model does not compile.
    let out = hybsim(
        d,
        &[
            "sweep",
            "ball.hyb",
            "--grid",
            "lambda=[0.3, 0.8]",
            "--grid",
            "T=[-1, 2]",
            "--runs",
            "2",
            "-o",
            "out",
            "-q",
        ],
    );
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    assert!(
        stdout(&out).contains("2 completed, 6 did not"),
        "{}",
        stdout(&out)
    );
    let text = std::fs::read_to_string(d.join("out/runs.csv")).unwrap();
    let causes: Vec<String> = csv::Reader::from_reader(text.as_bytes())
        .records()
        .map(|r| {
            let r = r.unwrap();
            format!("{},{},{}", &r[3], &r[4], &r[6])
        })
        .collect();
    assert_eq!(
        causes,
        [
            "0.3,-1,model_error",
            "0.3,-1,model_error",
            "0.3,2,zeno_suspected",
            "0.3,2,zeno_suspected",
            "0.8,-1,model_error",
            "0.8,-1,model_error",
            "0.8,2,horizon_t",
            "0.8,2,horizon_t",
        ]
    );
    assert!(
        text.contains("E0506"),
        "the model error is in the row:\n{text}"
    );
    let points = std::fs::read_to_string(d.join("out/points.csv")).unwrap();
    assert!(
        points.lines().nth(4).unwrap().starts_with("3,0.8,2,2,2,"),
        "{points}"
    );
}

#[test]
fn bad_sweep_arguments_are_reported() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("ball.hyb"), BALL).unwrap();
    // An unknown grid name is an error before anything runs (E0204).
    for (args, needle) in [
        (&["--grid", "lambda=1:0:2"][..], "invalid grid axis"),
        (&["--grid", "lambda=[1", "--runs", "2"][..], "ends with `]`"),
        (&["--shard", "3/2"][..], "invalid shard"),
        (&["--grid", "g=[1]", "--set", "g=2"][..], "set twice"),
        (&["--grid", "nosuch=[1, 2]"][..], "E0204"),
        // Located in the grid axis the user gave, not in a `--set` they did not type.
        (
            &["--grid", "nosuch=[1, 2]"][..],
            "unknown setting `nosuch` in `--grid nosuch=1`",
        ),
        (&["--grid", "nosuch=[1, 2]"][..], "┌─ --grid:1:8"),
        (&["--grid", "nosuch=[1, 2]"][..], "--grid names a parameter"),
        // A value twice would be a grid point run twice (duplicate rows).
        (
            &["--grid", "lambda=[0.5, 0.8, 0.5]"][..],
            "invalid grid axis `lambda`: the value 0.5 is given twice",
        ),
    ] {
        let mut all = vec!["sweep", "ball.hyb", "-o", "out", "-q"];
        all.extend_from_slice(args);
        let out = hybsim(d, &all);
        assert_eq!(code(&out), 2, "{args:?}");
        assert!(stderr(&out).contains(needle), "{args:?}: {}", stderr(&out));
        assert!(!stderr(&out).contains("--set nosuch"), "{}", stderr(&out));
    }
    // Thousands of worker threads on a few cores spend their time looking for work
    // (`--threads 10000` on 2 cores: over a minute for 2 runs): refused before anything runs.
    let started = std::time::Instant::now();
    let out = hybsim(
        d,
        &[
            "sweep",
            "ball.hyb",
            "-o",
            "threads",
            "-q",
            "--threads",
            "10000",
        ],
    );
    assert_eq!(code(&out), 2, "{}", stderr(&out));
    assert!(
        stderr(&out).contains("10000 worker threads: a sweep takes from 1 to 1024"),
        "{}",
        stderr(&out)
    );
    assert!(started.elapsed().as_secs() < 10 && !d.join("threads").exists());
    // Within the limit, no more threads than runs are started.
    let pool = hybsim::sweep::thread_pool(Some(1024), 3).unwrap().unwrap();
    assert_eq!(pool.current_num_threads(), 3);
    assert!(hybsim::sweep::thread_pool(None, 3).unwrap().is_none());
    let out = hybsim(
        d,
        &[
            "sweep",
            "ball.hyb",
            "-o",
            "threads",
            "-q",
            "--threads",
            "1024",
            "--runs",
            "2",
        ],
    );
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    // A grid value that makes its point invalid is that point's row, whose message names
    // the grid axis.
    let out = hybsim(
        d,
        &[
            "sweep",
            "ball.hyb",
            "-o",
            "out",
            "-q",
            "--grid",
            "sim.T=[-1, 1]",
        ],
    );
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let runs = std::fs::read_to_string(d.join("out/runs.csv")).unwrap();
    let failed = runs.lines().nth(1).unwrap();
    assert!(failed.contains(",failed,"), "{runs}");
    assert!(failed.contains("in `--grid sim.T=-1`"), "{runs}");
    assert!(runs.contains("fix the value given with --grid"), "{runs}");
}

/// A pendulum (not affine: stepped, no exact propagator) with a metric;
/// `T = 1e6` (10⁹ steps, the step limit) is a run that does not end within any test.
const PENDULUM: &str = "model pendulum
state x = 1, v = 0
flow { x' = v; v' = -sin(x) }
metric top = max(x), last = final(v)
sim { T = 0.5; solver = rk4; h = 1e-3 }
";

#[test]
fn an_interrupted_sweep_keeps_the_runs_that_finished() {
    use std::process::{Command, Stdio};
    use std::time::Duration;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("p.hyb"), PENDULUM).unwrap();
    // One thread takes the runs in grid order: three short ones, then one
    // that cannot end before the signal.
    let grid = "T=[0.5, 0.6, 0.7, 1e6]";
    let child = Command::new(crate::util::BIN)
        .args(["sweep", "p.hyb", "--grid", grid, "--threads", "1", "-q"])
        .args(["-o", "part"])
        .current_dir(d)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_secs(2));
    // SAFETY: signalling our own child by its process id.
    unsafe {
        libc::kill(child.id() as i32, libc::SIGINT);
    }
    let out = child.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(130), "{}", stderr(&out));
    assert!(
        stderr(&out).contains("interrupted: 3 of 4 runs written"),
        "{}",
        stderr(&out)
    );
    let part = d.join("part");
    assert!(crate::util::temp_files(&part).is_empty());
    let manifest = std::fs::read_to_string(part.join("sweep.json")).unwrap();
    assert!(manifest.contains("\"interrupted\": true"), "{manifest}");
    // The rows written are those of the same runs in a sweep that ends.
    let short = hybsim(
        d,
        &[
            "sweep",
            "p.hyb",
            "--grid",
            "T=[0.5, 0.6, 0.7]",
            "-q",
            "-o",
            "short",
        ],
    );
    assert_eq!(code(&short), 0, "{}", stderr(&short));
    let lines = |p: &Path| -> Vec<String> {
        let text = std::fs::read_to_string(p).unwrap();
        text.lines().skip(1).map(String::from).collect()
    };
    assert_eq!(
        lines(&part.join("runs.csv")),
        lines(&d.join("short/runs.csv"))
    );
    // An interrupted shard cannot be merged.
    let out = hybsim(d, &["sweep", "--merge", "part", "-o", "m"]);
    assert_eq!(code(&out), 1);
    assert!(stderr(&out).contains("interrupted"), "{}", stderr(&out));
}

/// An `-o` that cannot hold the results is an error before any run: it was found when the
/// results were written, after every run (here a run that does not end, which hung).
#[test]
fn an_output_directory_that_cannot_be_written_is_refused_before_the_runs() {
    use std::process::{Command, Stdio};
    use std::time::{Duration, Instant};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("p.hyb"), PENDULUM).unwrap();
    for (out_dir, says) in [
        ("p.hyb", "a file of that name exists; give a directory"),
        ("p.hyb/results", "Not a directory"),
    ] {
        let mut child = Command::new(crate::util::BIN)
            .args(["sweep", "p.hyb", "--grid", "T=[1e6]", "-q", "-o", out_dir])
            .current_dir(d)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let start = Instant::now();
        while child.try_wait().unwrap().is_none() && start.elapsed() < Duration::from_secs(30) {
            std::thread::sleep(Duration::from_millis(20));
        }
        if child.try_wait().unwrap().is_none() {
            child.kill().unwrap();
            panic!("`-o {out_dir}`: the sweep ran instead of refusing its output directory");
        }
        let out = child.wait_with_output().unwrap();
        assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
        assert!(
            stderr(&out).contains(&format!(
                "cannot write the results into `{out_dir}`: {says}"
            )),
            "{}",
            stderr(&out)
        );
    }
    assert_eq!(std::fs::read_to_string(d.join("p.hyb")).unwrap(), PENDULUM);
    assert_eq!(crate::util::temp_files(d), Vec::<String>::new());
}

#[test]
fn resume_completes_an_interrupted_sweep_into_the_same_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("ball.hyb"), BALL).unwrap();
    sweep(d, &["-o", "full"]);
    // What an interruption after 10 of the 24 runs (not in grid order)
    // leaves: those rows, marked interrupted.
    let part = d.join("part");
    std::fs::create_dir(&part).unwrap();
    let runs = std::fs::read_to_string(d.join("full/runs.csv")).unwrap();
    let mut lines = runs.lines();
    let mut kept = vec![lines.next().unwrap()];
    kept.extend(lines.enumerate().filter(|(i, _)| i % 5 < 2).map(|(_, l)| l));
    std::fs::write(part.join("runs.csv"), kept.join("\n") + "\n").unwrap();
    let manifest = std::fs::read_to_string(d.join("full/sweep.json")).unwrap();
    let interrupted = manifest.replacen("{", "{\n  \"interrupted\": true,", 1);
    std::fs::write(part.join("sweep.json"), interrupted).unwrap();
    let out = sweep(d, &["-o", "part", "--resume"]);
    assert!(stdout(&out).contains("; 14 run now)"), "{}", stdout(&out));
    assert_eq!(files(&d.join("full")), files(&part));
    // Resuming a finished sweep runs nothing; another sweep is refused.
    let out = sweep(d, &["-o", "part", "--resume"]);
    assert!(stdout(&out).contains("; 0 run now)"), "{}", stdout(&out));
    let out = hybsim(
        d,
        &[
            "sweep", "ball.hyb", "--runs", "2", "-q", "-o", "part", "--resume",
        ],
    );
    assert_eq!(code(&out), 1);
    assert!(stderr(&out).contains("another sweep"), "{}", stderr(&out));
}

/// The ball of the determinism test with its grid in the model.
fn ball_with_block() -> String {
    BALL.replace(
        "sim {",
        "sweep {\n  lambda in 0.6:0.1:0.9   # the first axis varies slowest\n  g in [9.81, 3.7]\n  \
         runs = 3; seed = 5\n}\nsim {",
    )
}

#[test]
fn a_sweep_block_is_the_grid_the_command_line_would_give() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Same model text in both files: the manifests (model SHA-256) agree.
    std::fs::write(d.join("ball.hyb"), ball_with_block()).unwrap();
    sweep(d, &["-o", "flags"]);
    let out = hybsim(d, &["sweep", "ball.hyb", "-q", "-o", "block"]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    assert!(
        stdout(&out).contains("24 runs (8 grid points × 3 runs"),
        "{}",
        stdout(&out)
    );
    assert_eq!(files(&d.join("flags")), files(&d.join("block")));
    // `hybsim run` ignores the block.
    let out = hybsim(d, &["run", "ball.hyb", "-q", "--no-mcap"]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    // --grid replaces the block's axes, --runs and --seed its settings.
    let out = hybsim(
        d,
        &[
            "sweep", "ball.hyb", "--grid", "g=[1, 2]", "--runs", "2", "-q", "-o", "cli",
        ],
    );
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let runs = std::fs::read_to_string(d.join("cli/runs.csv")).unwrap();
    assert!(runs.starts_with("point,run,seed,g,status"), "{runs}");
    assert_eq!(runs.lines().count(), 1 + 4);
    // A name the block sweeps and --set fixes is refused.
    let out = hybsim(d, &["sweep", "ball.hyb", "--set", "g=2", "-q", "-o", "x"]);
    assert_eq!(code(&out), 2);
    assert!(
        stderr(&out).contains("`g` is set twice"),
        "{}",
        stderr(&out)
    );
}

#[test]
fn sweep_block_errors_are_located() {
    let src = SourceFile::new(
        "bad.hyb",
        "model bad
param k = 2, step = -1
state x = 1
flow { x' = -k * x }
sweep {
  kk in [1, 2]
  k in 1:step:3
  x in [1, 2; 3, 4]
  k in [1]
  rnus = 3
  k = 4
  runs = 0
  seed = 0.5
}
sweep { runs = 2 }
for i in 1..2 { sweep { k in [1] } }
",
    );
    let diags = lang::check_only(&src, &[]);
    let text = hybsim::diagnostics::render(&diags, &src, false);
    for (code, at) in [
        ("E0204", "bad.hyb:6:3"),
        ("E0506", "bad.hyb:7:8"),
        ("E0304", "bad.hyb:8:8"),
        ("E0202", "bad.hyb:9:3"),
        ("E0204", "bad.hyb:10:3"),
        ("E0204", "bad.hyb:11:3"),
        ("E0506", "bad.hyb:12:10"),
        ("E0506", "bad.hyb:13:10"),
        ("E0202", "bad.hyb:15:1"),
        ("E0507", "bad.hyb:16:17"),
    ] {
        assert!(
            text.contains(&format!("error[{code}]")) && text.contains(at),
            "{code} at {at}:\n{text}"
        );
    }
    assert!(text.contains("did you mean `k`?"), "{text}");
    assert!(text.contains("did you mean `runs`?"), "{text}");
    assert!(text.contains("did you mean `k in [values]`?"), "{text}");
    assert!(text.contains("does not lead from 1 to 3"), "{text}");
    // A value twice (a grid point run twice), in a list or a range whose
    // step is below the doubles' spacing.
    for (axis, value) in [
        ("k in [1, 2, 1]", "1"),
        ("k in 1e10:1e-7:1.000000000001e10", "10000000000"),
    ] {
        let src = SourceFile::new(
            "dup.hyb",
            format!(
                "model dup\nparam k = 2\nstate x = 1\nflow {{ x' = -k * x }}\nsweep {{ {axis} }}\n"
            ),
        );
        let text = hybsim::diagnostics::render(&lang::check_only(&src, &[]), &src, false);
        assert!(
            text.contains("error[E0506]")
                && text.contains("dup.hyb:5:14")
                && text.contains(&format!("the value {value} is given twice")),
            "{axis}:\n{text}"
        );
    }
    // `sweep` stays usable as a name.
    let src = SourceFile::new(
        "ok.hyb",
        "model ok\nparam sweep = 2\nstate x = 1\nflow { x' = -sweep * x }\nsweep { sweep in 1:1:3 }\n",
    );
    let model = lang::compile(&src, &[]).unwrap_or_else(|d| {
        panic!("{}", hybsim::diagnostics::render(&d, &src, false));
    });
    let block = model.sweep().unwrap();
    assert_eq!(block.axes, [("sweep".to_string(), vec![1.0, 2.0, 3.0])]);
    assert_eq!((block.runs, block.seed), (None, None));
}

/// The columns of a Parquet file as text, each value as the CSV writes it
/// (floats as shortest round-trip decimals, null as empty).
fn parquet_as_csv(bytes: &[u8]) -> Vec<Vec<String>> {
    use arrow_array::{Array, Float64Array, StringArray, UInt64Array};
    use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
    use std::io::Write;
    let mut file = tempfile::tempfile().unwrap();
    file.write_all(bytes).unwrap();
    let reader = ParquetRecordBatchReaderBuilder::try_new(file)
        .unwrap()
        .build()
        .unwrap();
    let mut rows: Vec<Vec<String>> = Vec::new();
    for batch in reader {
        let batch = batch.unwrap();
        if rows.is_empty() {
            let schema = batch.schema();
            rows.push(schema.fields().iter().map(|f| f.name().clone()).collect());
        }
        for i in 0..batch.num_rows() {
            let row = batch
                .columns()
                .iter()
                .map(|c| {
                    let any = c.as_any();
                    if c.is_null(i) {
                        String::new()
                    } else if let Some(a) = any.downcast_ref::<UInt64Array>() {
                        a.value(i).to_string()
                    } else if let Some(a) = any.downcast_ref::<Float64Array>() {
                        hybsim::num::Num(a.value(i)).to_string()
                    } else {
                        let a = any.downcast_ref::<StringArray>().unwrap();
                        a.value(i).to_string()
                    }
                })
                .collect();
            rows.push(row);
        }
    }
    rows
}

fn csv_rows(bytes: &[u8]) -> Vec<Vec<String>> {
    let mut r = csv::ReaderBuilder::new()
        .has_headers(false)
        .from_reader(bytes);
    r.records()
        .map(|rec| rec.unwrap().iter().map(String::from).collect())
        .collect()
}

#[test]
fn parquet_tables_hold_the_values_of_the_csv_tables() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("ball.hyb"), BALL).unwrap();
    // Two grid points whose runs are Zeno-suspected: rows without metrics,
    // and statistics of no value (NaN).
    sweep(d, &["-o", "out"]);
    let read = |name: &str| std::fs::read(d.join("out").join(name)).unwrap();
    for table in ["runs", "points"] {
        let csv = csv_rows(&read(&format!("{table}.csv")));
        let parquet = parquet_as_csv(&read(&format!("{table}.parquet")));
        assert_eq!(csv, parquet, "{table}");
    }
    let runs = String::from_utf8(read("runs.csv")).unwrap();
    assert!(runs.contains("zeno_suspected"), "{runs}");
}

/// A planned sweep reuses the grid point it compiled while planning (a
/// compile solves the design blocks): the rows are those of a sweep that
/// compiles every point itself, with the axes given, from the model's
/// block, and without axes; a grid point that does not compile is a row.
#[test]
fn a_planned_sweep_gives_the_rows_of_an_unplanned_one() {
    use hybsim::sweep::{self, Axis, Shard};
    let src = SourceFile::new(
        "ball.hyb",
        format!("{BALL}sweep {{ lambda in [0.6, 0.9]; runs = 2 }}\n"),
    );
    let grids: [Option<Vec<Axis>>; 4] = [
        Some(vec!["lambda=[0.5, 0.7]".parse().unwrap()]),
        None,
        Some(Vec::new()),
        // T = -1 is refused (E0506): point 0's rows are failed.
        Some(vec!["T=[-1, 2]".parse().unwrap()]),
    ];
    for axes in grids {
        let plan = sweep::plan(&src, &[], axes.clone(), None, Some(3), &Default::default())
            .unwrap_or_else(|_| panic!("{axes:?} plans"));
        let planned = sweep::run_plan(
            &src,
            &[],
            &plan,
            Shard::ALL,
            &Default::default(),
            Default::default(),
        );
        let unplanned = sweep::run(
            &src,
            &[],
            &plan.spec,
            Shard::ALL,
            &Default::default(),
            Default::default(),
        );
        assert_eq!(planned, unplanned, "{axes:?}");
        assert_eq!(planned.len() as u64, plan.spec.total_runs());
        if plan.spec.axes.first().is_some_and(|a| a.name == "T") {
            assert_eq!(planned[0].cause, "model_error", "{:?}", planned[0]);
            assert_ne!(planned[2].cause, "model_error", "{:?}", planned[2]);
        }
    }
}

/// An axis that changes the size of a metric family (`N` here) gives the
/// grid points whose metrics are not the sweep's failed rows, and the
/// tables are written (they have one column per metric of the model as
/// given).
#[test]
fn an_axis_that_resizes_a_metric_family_fails_those_points() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("fam.hyb"),
        "model fam
param N = 2
for i in 1..N {
  state x[i] = i
  flow { x[i]' = 1 }
  metric last[i] = final(x[i])
}
sim { T = 1 }
",
    )
    .unwrap();
    let out = hybsim(
        d,
        &["sweep", "fam.hyb", "--grid", "N=[2, 3]", "-q", "-o", "out"],
    );
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let runs = std::fs::read_to_string(d.join("out/runs.csv")).unwrap();
    let rows: Vec<&str> = runs.lines().collect();
    assert!(rows[0].starts_with("point,run,seed,N,status,cause,last[1],last[2],message"));
    assert!(rows[1].contains(",completed,"), "{runs}");
    assert!(
        rows[2].contains(",failed,model_error,")
            && rows[2].contains("an axis changes the size of a metric family"),
        "{runs}"
    );
}

/// A metric that is NaN by arithmetic (0/0 gives the NaN with the sign bit set
/// on x86) is stored as the NaN `runs.csv` reads back as: the sharded and
/// merged files, and the resumed ones, are byte for byte the unsharded ones
/// (the Parquet tables held the other NaN's bits).
#[test]
fn a_nan_metric_gives_the_same_tables_sharded_merged_or_resumed() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let model = BALL.replace(
        "metric bounces",
        "metric none = count(impact, t > 100) / count(impact, t > 100), bounces",
    );
    std::fs::write(d.join("ball.hyb"), model).unwrap();
    sweep(d, &["-o", "all"]);
    for k in 1..=2 {
        sweep(d, &["-o", &format!("s{k}"), "--shard", &format!("{k}/2")]);
    }
    let out = hybsim(d, &["sweep", "--merge", "s1", "s2", "-o", "merged"]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let all = files(&d.join("all"));
    let runs_csv = all.iter().find(|(n, _)| n == "runs.csv").unwrap();
    assert!(String::from_utf8_lossy(&runs_csv.1).contains(",NaN,"));
    assert_eq!(all, files(&d.join("merged")));
    // Resumed from the first half of the rows.
    let part = d.join("part");
    std::fs::create_dir(&part).unwrap();
    let runs = std::fs::read_to_string(d.join("all/runs.csv")).unwrap();
    let kept: Vec<&str> = runs.lines().take(13).collect();
    std::fs::write(part.join("runs.csv"), kept.join("\n") + "\n").unwrap();
    let manifest = std::fs::read_to_string(d.join("all/sweep.json")).unwrap();
    let interrupted = manifest.replacen("{", "{\n  \"interrupted\": true,", 1);
    std::fs::write(part.join("sweep.json"), interrupted).unwrap();
    sweep(d, &["-o", "part", "--resume"]);
    assert_eq!(all, files(&part));
}

/// A row of a shard that is not the run it names (its seed or grid values
/// edited, or copied from another shard) is refused by `--merge` and
/// `--resume`; it was merged as that run.
#[test]
fn merge_refuses_rows_that_are_not_the_runs_they_name() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("ball.hyb"), BALL).unwrap();
    for k in 1..=2 {
        sweep(d, &["-o", &format!("s{k}"), "--shard", &format!("{k}/2")]);
    }
    let runs = std::fs::read_to_string(d.join("s1/runs.csv")).unwrap();
    let first = runs.lines().nth(1).unwrap();
    let fields: Vec<&str> = first.splitn(5, ',').collect();
    let edits = [
        // Another seed.
        format!(
            "{},{},123,{},{}",
            fields[0], fields[1], fields[3], fields[4]
        ),
        // Another grid value.
        format!(
            "{},{},{},0.123,{}",
            fields[0], fields[1], fields[2], fields[4]
        ),
        // Run 1 of point 0 belongs to shard 2/2.
        format!("{},1,{},{},{}", fields[0], fields[2], fields[3], fields[4]),
    ];
    for edited in edits {
        std::fs::write(d.join("s1/runs.csv"), runs.replacen(first, &edited, 1)).unwrap();
        let out = hybsim(d, &["sweep", "--merge", "s1", "s2", "-o", "m"]);
        assert_eq!(code(&out), 1, "{edited}: {}", stderr(&out));
        assert!(
            stderr(&out).contains("row 1: point 0, run ")
                && stderr(&out).contains("is not a run of this sweep.json"),
            "{edited}: {}",
            stderr(&out)
        );
        assert!(!d.join("m").exists());
    }
}

/// Sweeps too large to hold their rows are refused before anything is
/// allocated (`--runs 1e10` ran until memory failed, three 1000-value axes
/// aborted allocating 32 GB), and non-finite axis values given as numbers
/// (Python, the library) are refused as `--grid` refuses them.
#[test]
fn sweeps_beyond_the_run_limit_and_non_finite_axes_are_refused() {
    use hybsim::sweep::{Axis, MAX_RUNS, SweepSpec};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("ball.hyb"), BALL).unwrap();
    let over = (MAX_RUNS + 1).to_string();
    for args in [
        &["--runs", &over][..],
        &["--runs", "10000000000"],
        &[
            "--grid",
            "lambda=0:1:999",
            "--grid",
            "g=0:1:999",
            "--grid",
            "T=1:1:1000",
        ],
    ] {
        let mut all = vec!["sweep", "ball.hyb", "-q", "-o", "out"];
        all.extend_from_slice(args);
        let (out, cpu) = crate::util::hybsim_cpu(d, &all);
        assert_eq!(code(&out), 2, "{args:?}: {}", stderr(&out));
        assert!(
            stderr(&out).contains(&format!("at most {MAX_RUNS} per sweep")),
            "{args:?}: {}",
            stderr(&out)
        );
        assert!(cpu < std::time::Duration::from_secs(2), "{cpu:?}");
        assert!(!d.join("out").exists());
    }
    for v in [f64::NAN, f64::INFINITY] {
        let axis = Axis {
            name: "lambda".into(),
            values: vec![0.5, v],
        };
        let err = SweepSpec::new(vec![axis], 1, 0).validate(&[]).unwrap_err();
        assert!(err.to_string().contains("is not a finite number"), "{err}");
    }
}

/// A grid of more points than are compiled at once (they are run in
/// batches, so that memory is bounded by the rows, not by the compiled
/// models of every point) gives the same files on 1 and 2 threads and in
/// shards.
#[test]
fn a_grid_of_many_points_runs_in_batches_with_the_same_results() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("ball.hyb"), BALL.replace("T = 2", "T = 0.2")).unwrap();
    let grid = |extra: &[&str]| {
        let mut args = vec![
            "sweep",
            "ball.hyb",
            "--grid",
            "lambda=0.5:0.001:0.8",
            "--seed",
            "2",
            "-q",
        ];
        args.extend_from_slice(extra);
        let out = hybsim(d, &args);
        assert_eq!(code(&out), 0, "{}", stderr(&out));
    };
    grid(&["-o", "one", "--threads", "1"]);
    grid(&["-o", "two", "--threads", "2"]);
    grid(&["-o", "s1", "--shard", "1/2"]);
    grid(&["-o", "s2", "--shard", "2/2"]);
    let out = hybsim(d, &["sweep", "--merge", "s1", "s2", "-o", "merged"]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let one = files(&d.join("one"));
    let runs = one.iter().find(|(n, _)| n == "runs.csv").unwrap();
    assert_eq!(String::from_utf8_lossy(&runs.1).lines().count(), 1 + 301);
    assert_eq!(one, files(&d.join("two")));
    assert_eq!(one, files(&d.join("merged")));
}
