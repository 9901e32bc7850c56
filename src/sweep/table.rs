//! The results of a sweep as files, and the merge of shards.
//!
//! | file | content |
//! |---|---|
//! | `sweep.json` | the manifest: hybsim version, model path and SHA-256, `--set` values, axes, runs, base seed, metric names, `shard` (`k/n`) in a shard's directory, and `interrupted: true` if the sweep was stopped before its end |
//! | `runs.csv` | one row per run: `point, run, seed, <axes>, status, cause, <metrics>, message, command` (metrics empty unless the run completed; `command` replays the run) |
//! | `points.csv` | one row per grid point: `point, <axes>, runs, completed`, then `<metric>_mean, _std, _min, _max, _count` over its completed runs with a finite value (std with n − 1; NaN below two values) |
//! | `runs.parquet`, `points.parquet` | the same tables as Parquet ([`crate::sinks::parquet`]), typed: indices, counts and seeds as unsigned integers, values as floats, a run's metrics null unless it completed |
//! | `<metric>.svg` | per metric, when there are axes: mean ± std against the first axis, one line per value of the other axes |
//!
//! Every file is written whole or not at all ([`crate::atomic_file`]). An
//! interrupted sweep writes the runs that finished (marked `interrupted`
//! in `sweep.json`); [`merge`] refuses it until it is completed.
//!
//! A shard's directory holds `sweep.json` and its part of `runs.csv` and
//! `runs.parquet` (its runs, typed as in the whole sweep's; no point
//! statistics, since a shard holds only some runs of each grid point);
//! [`merge`] reads the shards' `runs.csv` and checks that the shards belong to one sweep and cover it once,
//! and writes exactly the files of an unsharded run. Numbers are written as
//! shortest round-trip decimals, so they read back bit for bit.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{Shard, SweepError, SweepSpec};
use crate::num::Num;
use crate::sinks::RunStatus;
use crate::sinks::parquet::{Column, Table, TableError};
use crate::sinks::plot::{Figure, Panel, Series};

/// One run of a sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct RunRow {
    /// Grid point index (grid order, last axis fastest).
    pub point: usize,
    /// Run index at that point, from 0.
    pub run: u64,
    /// The run's seed (`hybsim run --seed`).
    pub seed: u64,
    /// The axes' values.
    pub values: Vec<f64>,
    /// How the run ended.
    pub status: RunStatus,
    /// Stable cause (`horizon_t`, `zeno_suspected`, `error`, `model_error`, …).
    pub cause: String,
    /// One sentence (or the model's diagnostics for `model_error`).
    pub message: String,
    /// The metrics, if the run completed (else empty).
    pub metrics: Vec<f64>,
}

/// Summary statistics of one metric over runs (non-finite values are
/// left out and not counted).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stats {
    /// Mean.
    pub mean: f64,
    /// Sample standard deviation (n − 1); NaN below two values.
    pub std: f64,
    /// Smallest value.
    pub min: f64,
    /// Largest value.
    pub max: f64,
    /// Number of finite values.
    pub count: u64,
    m2: f64,
}

impl Default for Stats {
    fn default() -> Self {
        Self {
            mean: f64::NAN,
            std: f64::NAN,
            min: f64::NAN,
            max: f64::NAN,
            count: 0,
            m2: 0.0,
        }
    }
}

impl Stats {
    /// Adds a value (Welford's update; in row order, so deterministic).
    pub fn push(&mut self, x: f64) {
        if !x.is_finite() {
            return;
        }
        self.count += 1;
        if self.count == 1 {
            (self.mean, self.min, self.max, self.m2) = (x, x, x, 0.0);
            return;
        }
        let d = x - self.mean;
        self.mean += d / self.count as f64;
        self.m2 += d * (x - self.mean);
        self.min = self.min.min(x);
        self.max = self.max.max(x);
    }

    /// Sets `std` from the values pushed.
    pub fn finish(&mut self) {
        self.std = if self.count >= 2 {
            (self.m2 / (self.count - 1) as f64).sqrt()
        } else {
            f64::NAN
        };
    }
}

/// One grid point's summary.
#[derive(Debug, Clone, PartialEq)]
pub struct PointRow {
    /// Grid point index.
    pub point: usize,
    /// The axes' values.
    pub values: Vec<f64>,
    /// Runs at this point.
    pub runs: u64,
    /// Runs that completed (reached a horizon).
    pub completed: u64,
    /// Per metric (empty if no run completed).
    pub stats: Vec<Stats>,
}

/// The description of a sweep stored beside its results (`sweep.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// hybsim's version.
    pub hybsim: String,
    /// The model file as given on the command line.
    pub model: String,
    /// SHA-256 of the model source (hex).
    pub model_sha256: String,
    /// Fixed `--set name=value` overrides, as given.
    pub sets: Vec<String>,
    /// Axes, runs, base seed.
    pub spec: SweepSpec,
    /// The model's metric names.
    pub metrics: Vec<String>,
    /// The shard these results are (absent for a whole sweep).
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub shard: Option<Shard>,
    /// Set when the sweep was interrupted (Ctrl-C, SIGTERM, SIGHUP): the
    /// files hold only the runs that finished (`--resume` completes them).
    #[serde(skip_serializing_if = "std::ops::Not::not", default)]
    pub interrupted: bool,
}

impl Manifest {
    /// The command that replays `row` alone.
    pub fn command(&self, row: &RunRow) -> String {
        let mut words = vec!["hybsim".to_string(), "run".into(), shell_word(&self.model)];
        let sets = self.sets.iter().cloned().chain(
            self.spec
                .axes
                .iter()
                .zip(&row.values)
                .map(|(a, v)| format!("{}={}", a.name, Num(*v))),
        );
        for s in sets {
            words.push("--set".into());
            words.push(shell_word(&s));
        }
        words.push("--seed".into());
        words.push(row.seed.to_string());
        words.join(" ")
    }
}

/// `s` quoted for a POSIX shell if it needs it.
fn shell_word(s: &str) -> String {
    let plain = !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./=:,+@%".contains(c));
    if plain {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', r"'\''"))
    }
}

fn num(x: f64) -> String {
    Num(x).to_string()
}

fn status_word(s: RunStatus) -> &'static str {
    match s {
        RunStatus::Completed => "completed",
        RunStatus::Ended => "ended",
        RunStatus::Failed => "failed",
    }
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> SweepError + '_ {
    move |source| SweepError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn csv_bytes(header: Vec<String>, rows: impl Iterator<Item = Vec<String>>) -> Vec<u8> {
    let mut w = csv::Writer::from_writer(Vec::new());
    w.write_record(&header).expect("writing to memory");
    for r in rows {
        w.write_record(&r).expect("writing to memory");
    }
    w.into_inner().expect("writing to memory")
}

/// `runs.csv` of `rows`.
pub fn runs_csv(m: &Manifest, rows: &[RunRow]) -> Vec<u8> {
    let mut header: Vec<String> = ["point", "run", "seed"].map(String::from).to_vec();
    header.extend(m.spec.axes.iter().map(|a| a.name.clone()));
    header.extend(["status", "cause"].map(String::from));
    header.extend(m.metrics.iter().cloned());
    header.extend(["message", "command"].map(String::from));
    let nm = m.metrics.len();
    csv_bytes(
        header,
        rows.iter().map(|r| {
            let mut rec = vec![r.point.to_string(), r.run.to_string(), r.seed.to_string()];
            rec.extend(r.values.iter().map(|&v| num(v)));
            rec.push(status_word(r.status).into());
            rec.push(r.cause.clone());
            if r.metrics.is_empty() {
                rec.extend(std::iter::repeat_n(String::new(), nm));
            } else {
                rec.extend(r.metrics.iter().map(|&v| num(v)));
            }
            rec.push(r.message.clone());
            rec.push(m.command(r));
            rec
        }),
    )
}

/// `points.csv` of `points`.
pub fn points_csv(m: &Manifest, points: &[PointRow]) -> Vec<u8> {
    let mut header: Vec<String> = vec!["point".into()];
    header.extend(m.spec.axes.iter().map(|a| a.name.clone()));
    header.extend(["runs", "completed"].map(String::from));
    for name in &m.metrics {
        for s in ["mean", "std", "min", "max", "count"] {
            header.push(format!("{name}_{s}"));
        }
    }
    csv_bytes(
        header,
        points.iter().map(|p| {
            let mut rec = vec![p.point.to_string()];
            rec.extend(p.values.iter().map(|&v| num(v)));
            rec.push(p.runs.to_string());
            rec.push(p.completed.to_string());
            for k in 0..m.metrics.len() {
                let s = p.stats.get(k).copied().unwrap_or_default();
                rec.extend([num(s.mean), num(s.std), num(s.min), num(s.max)]);
                rec.push(s.count.to_string());
            }
            rec
        }),
    )
}

/// `runs.parquet` of `rows`: [`runs_table`] as Parquet.
pub fn runs_parquet(m: &Manifest, rows: &[RunRow]) -> Result<Vec<u8>, TableError> {
    runs_table(m, rows).to_parquet()
}

/// The table of `rows`: the columns of `runs.csv`, typed (`point`, `run`,
/// `seed` unsigned; axes and metrics floats, metrics null unless the run
/// completed; the rest text).
pub fn runs_table(m: &Manifest, rows: &[RunRow]) -> Table {
    let mut t = Table::new()
        .column(
            "point",
            Column::U64(rows.iter().map(|r| r.point as u64).collect()),
        )
        .column("run", Column::U64(rows.iter().map(|r| r.run).collect()))
        .column("seed", Column::U64(rows.iter().map(|r| r.seed).collect()));
    for (k, a) in m.spec.axes.iter().enumerate() {
        t = t.column(&a.name, floats(rows.iter().map(|r| Some(r.values[k]))));
    }
    t = t
        .column("status", texts(rows.iter().map(|r| status_word(r.status))))
        .column("cause", texts(rows.iter().map(|r| r.cause.as_str())));
    for (k, name) in m.metrics.iter().enumerate() {
        t = t.column(name, floats(rows.iter().map(|r| r.metrics.get(k).copied())));
    }
    t.column("message", texts(rows.iter().map(|r| r.message.as_str())))
        .column(
            "command",
            Column::Text(rows.iter().map(|r| m.command(r)).collect()),
        )
}

/// `points.parquet` of `points`: [`points_table`] as Parquet.
pub fn points_parquet(m: &Manifest, points: &[PointRow]) -> Result<Vec<u8>, TableError> {
    points_table(m, points).to_parquet()
}

/// The table of `points`: the columns of `points.csv`, typed (`point`,
/// `runs`, `completed`, `<metric>_count` unsigned; the rest floats, NaN
/// where `points.csv` has NaN).
pub fn points_table(m: &Manifest, points: &[PointRow]) -> Table {
    let mut t = Table::new().column(
        "point",
        Column::U64(points.iter().map(|p| p.point as u64).collect()),
    );
    for (k, a) in m.spec.axes.iter().enumerate() {
        t = t.column(&a.name, floats(points.iter().map(|p| Some(p.values[k]))));
    }
    t = t
        .column("runs", Column::U64(points.iter().map(|p| p.runs).collect()))
        .column(
            "completed",
            Column::U64(points.iter().map(|p| p.completed).collect()),
        );
    for (k, name) in m.metrics.iter().enumerate() {
        let stats: Vec<Stats> = points
            .iter()
            .map(|p| p.stats.get(k).copied().unwrap_or_default())
            .collect();
        let pick = |f: fn(&Stats) -> f64| floats(stats.iter().map(|s| Some(f(s))));
        t = t
            .column(format!("{name}_mean"), pick(|s| s.mean))
            .column(format!("{name}_std"), pick(|s| s.std))
            .column(format!("{name}_min"), pick(|s| s.min))
            .column(format!("{name}_max"), pick(|s| s.max))
            .column(
                format!("{name}_count"),
                Column::U64(stats.iter().map(|s| s.count).collect()),
            );
    }
    t
}

fn floats(v: impl Iterator<Item = Option<f64>>) -> Column {
    Column::F64(v.collect())
}

fn texts<'a>(v: impl Iterator<Item = &'a str>) -> Column {
    Column::Text(v.map(String::from).collect())
}

/// Reads a `runs.csv` written for manifest `m`.
pub fn read_runs(path: &Path, m: &Manifest) -> Result<Vec<RunRow>, SweepError> {
    let bytes = std::fs::read(path).map_err(io_err(path))?;
    let bad = |message: String| SweepError::Format {
        path: path.to_path_buf(),
        message,
    };
    let mut r = csv::Reader::from_reader(bytes.as_slice());
    let na = m.spec.axes.len();
    let nm = m.metrics.len();
    let width = 3 + na + 2 + nm + 2;
    let header = r.headers().map_err(|e| bad(e.to_string()))?;
    if header.len() != width {
        return Err(bad(format!(
            "{} columns, expected {width} for this sweep.json",
            header.len()
        )));
    }
    let mut rows = Vec::new();
    for (line, rec) in r.records().enumerate() {
        let rec = rec.map_err(|e| bad(e.to_string()))?;
        let at = |what: &str| format!("row {}: bad {what}", line + 1);
        let int = |k: usize| rec[k].parse::<u64>().map_err(|_| bad(at(&rec[k])));
        let float = |k: usize| rec[k].parse::<f64>().map_err(|_| bad(at(&rec[k])));
        let status = match &rec[3 + na] {
            "completed" => RunStatus::Completed,
            "ended" => RunStatus::Ended,
            "failed" => RunStatus::Failed,
            s => return Err(bad(at(s))),
        };
        let metrics = if rec[5 + na].is_empty() && nm > 0 {
            Vec::new()
        } else {
            (0..nm)
                .map(|k| float(5 + na + k))
                .collect::<Result<_, _>>()?
        };
        let row = RunRow {
            point: int(0)? as usize,
            run: int(1)?,
            seed: int(2)?,
            values: (0..na).map(|k| float(3 + k)).collect::<Result<_, _>>()?,
            status,
            cause: rec[4 + na].to_string(),
            message: rec[5 + na + nm].to_string(),
            metrics,
        };
        // A row that is not the run its point and run index name (an edited
        // or mixed-up file) would be merged or resumed as that run.
        let ours = row.point < m.spec.points()
            && row.run < m.spec.runs
            && m.shard
                .unwrap_or(Shard::ALL)
                .contains(row.point as u64 * m.spec.runs + row.run)
            && row.seed == m.spec.seed_of(row.point, row.run)
            && row.values == m.spec.point(row.point);
        if !ours {
            return Err(bad(format!(
                "row {}: point {}, run {} (seed {}) is not a run of this sweep.json: \
                 its seed, grid values or shard differ",
                line + 1,
                row.point,
                row.run,
                row.seed
            )));
        }
        rows.push(row);
    }
    Ok(rows)
}

/// The figure of metric `k`: mean ± std (dashed bars) against the first
/// axis, one line per combination of the other axes' values.
pub fn metric_figure(m: &Manifest, points: &[PointRow], k: usize) -> Option<Figure> {
    let first = m.spec.axes.first()?;
    let name = m.metrics.get(k)?;
    let mut series: Vec<(String, Series)> = Vec::new();
    for p in points {
        let label = m.spec.axes[1..]
            .iter()
            .zip(&p.values[1..])
            .map(|(a, v)| format!("{}={}", a.name, Num(*v)))
            .collect::<Vec<_>>()
            .join(", ");
        let s = p.stats.get(k).copied().unwrap_or_default();
        if s.count == 0 {
            continue;
        }
        let i = match series.iter().position(|(l, _)| *l == label) {
            Some(i) => i,
            None => {
                let shown = if label.is_empty() {
                    name.clone()
                } else {
                    label.clone()
                };
                series.push((label, Series::line(shown, Vec::new()).markers(true)));
                series.len() - 1
            }
        };
        let x = p.values[0];
        let ser = &mut series[i].1;
        ser.pieces[0].push((x, s.mean));
        if s.std.is_finite() {
            ser.connectors
                .push([(x, s.mean - s.std), (x, s.mean + s.std)]);
        }
    }
    let mut panel = Panel::new(format!("{name} (mean ± std over runs)"))
        .x_label(first.name.clone())
        .y_label(name.clone());
    for (_, s) in series {
        panel = panel.series(s);
    }
    Some(Figure::new().panel(panel))
}

/// File name of metric `name`'s plot (characters outside `[A-Za-z0-9_-]`
/// become `_`).
pub fn plot_file(name: &str) -> String {
    let stem: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    format!("{stem}.svg")
}

/// Creates the results directory `dir` if needed and checks that files can
/// be created in it, before a sweep runs: a path that cannot hold the
/// results was found only when they were written, after every run.
pub fn prepare_dir(dir: &Path) -> Result<(), SweepError> {
    let fail = |source: std::io::Error| SweepError::OutputDir {
        path: dir.to_path_buf(),
        source,
    };
    if dir.exists() && !dir.is_dir() {
        return Err(fail(std::io::Error::new(
            std::io::ErrorKind::AlreadyExists,
            "a file of that name exists; give a directory",
        )));
    }
    std::fs::create_dir_all(dir).map_err(fail)?;
    // Removed when dropped.
    tempfile::Builder::new()
        .prefix(".hybsim-sweep-")
        .tempfile_in(dir)
        .map(drop)
        .map_err(fail)
}

/// Writes the results of the runs `rows` of manifest `m` into `dir`: a
/// shard's part (`m.shard` set: `sweep.json`, `runs.csv`, `runs.parquet`)
/// or the whole sweep (also `points.csv`, `points.parquet` and the plots).
/// Returns the files written.
pub fn write(dir: &Path, m: &Manifest, rows: &[RunRow]) -> Result<Vec<PathBuf>, SweepError> {
    std::fs::create_dir_all(dir).map_err(io_err(dir))?;
    let mut written = Vec::new();
    let mut put = |name: &str, bytes: &[u8]| -> Result<(), SweepError> {
        let path = dir.join(name);
        crate::atomic_file::write(&path, bytes).map_err(io_err(&path))?;
        written.push(path);
        Ok(())
    };
    let mut json = serde_json::to_vec_pretty(m).expect("a manifest serializes");
    json.push(b'\n');
    put("sweep.json", &json)?;
    let parquet = |name: &str, bytes: Result<Vec<u8>, TableError>| {
        bytes.map_err(|e| SweepError::Format {
            path: dir.join(name),
            message: e.to_string(),
        })
    };
    put("runs.csv", &runs_csv(m, rows))?;
    put(
        "runs.parquet",
        &parquet("runs.parquet", runs_parquet(m, rows))?,
    )?;
    // A shard holds only some runs of each grid point: no point statistics.
    if m.shard.is_none() {
        let points = super::aggregate(&m.spec, rows);
        put("points.csv", &points_csv(m, &points))?;
        put(
            "points.parquet",
            &parquet("points.parquet", points_parquet(m, &points))?,
        )?;
        for k in 0..m.metrics.len() {
            if let Some(fig) = metric_figure(m, &points, k) {
                let svg = fig.to_svg_string().map_err(|e| SweepError::Format {
                    path: dir.join(plot_file(&m.metrics[k])),
                    message: e.0,
                })?;
                put(&plot_file(&m.metrics[k]), svg.as_bytes())?;
            }
        }
    }
    Ok(written)
}

/// Reads a results directory: its manifest and rows.
pub fn read(dir: &Path) -> Result<(Manifest, Vec<RunRow>), SweepError> {
    let path = dir.join("sweep.json");
    let bytes = std::fs::read(&path).map_err(io_err(&path))?;
    let m: Manifest = serde_json::from_slice(&bytes).map_err(|e| SweepError::Format {
        path: path.clone(),
        message: e.to_string(),
    })?;
    let rows = read_runs(&dir.join("runs.csv"), &m)?;
    Ok((m, rows))
}

/// Merges the shard directories `dirs` into `out`: the same files as one
/// unsharded run. Fails if the shards are of different sweeps (model,
/// sets, grid, runs, seed), if a shard is missing or given twice, or if
/// runs are missing.
pub fn merge(dirs: &[PathBuf], out: &Path) -> Result<Vec<PathBuf>, SweepError> {
    // The merged files would replace that shard's own, which a merge redone
    // later (or one that fails after writing them) still needs.
    if let Some(dir) = dirs.iter().find(|d| crate::atomic_file::same_file(d, out)) {
        return Err(SweepError::Merge(format!(
            "`-o {}` is the shard {} given to merge: its files would be replaced; write the \
             merged files to another directory",
            out.display(),
            dir.display()
        )));
    }
    let mut merged: Option<Manifest> = None;
    let mut shards: Vec<Shard> = Vec::new();
    let mut rows = Vec::new();
    for dir in dirs {
        let (m, r) = read(dir)?;
        let shard = m.shard.unwrap_or(Shard::ALL);
        if m.interrupted {
            return Err(SweepError::Merge(format!(
                "{} holds an interrupted shard {shard} ({} of its runs): complete it with \
                 the same command and --resume",
                dir.display(),
                r.len()
            )));
        }
        let whole = Manifest { shard: None, ..m };
        match &merged {
            None => merged = Some(whole),
            Some(first) if *first != whole => {
                return Err(SweepError::Merge(format!(
                    "{} is of another sweep than {} (model, --set, grid, runs, seed or \
                     hybsim version differ)",
                    dir.display(),
                    dirs[0].display()
                )));
            }
            Some(_) => {}
        }
        if shards.contains(&shard) {
            return Err(SweepError::Merge(format!(
                "shard {shard} is given twice ({})",
                dir.display()
            )));
        }
        if shards.first().is_some_and(|s| s.n != shard.n) {
            return Err(SweepError::Merge(format!(
                "{} is shard {shard}, the first is of {} shards",
                dir.display(),
                shards[0].n
            )));
        }
        shards.push(shard);
        rows.extend(r);
    }
    let Some(m) = merged else {
        return Err(SweepError::Merge("no directory given".into()));
    };
    let n = shards[0].n;
    if shards.len() as u64 != n {
        let missing: Vec<String> = (1..=n)
            .filter(|k| !shards.iter().any(|s| s.k == *k))
            .map(|k| format!("{k}/{n}"))
            .collect();
        return Err(SweepError::Merge(format!(
            "shard(s) {} missing",
            missing.join(", ")
        )));
    }
    rows.sort_by_key(|r| (r.point, r.run));
    let total = m.spec.total_runs();
    let complete = rows.len() as u64 == total
        && rows
            .iter()
            .enumerate()
            .all(|(i, r)| r.point as u64 * m.spec.runs + r.run == i as u64);
    if !complete {
        return Err(SweepError::Merge(format!(
            "the shards hold {} runs, the sweep has {total} (a shard did not finish?)",
            rows.len()
        )));
    }
    write(out, &m, &rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_match_the_formulas() {
        let mut s = Stats::default();
        for x in [1.0, 2.0, f64::NAN, 4.0] {
            s.push(x);
        }
        s.finish();
        assert_eq!((s.count, s.min, s.max), (3, 1.0, 4.0));
        assert!((s.mean - 7.0 / 3.0).abs() < 1e-15);
        let var = ((1.0f64 - 7.0 / 3.0).powi(2)
            + (2.0f64 - 7.0 / 3.0).powi(2)
            + (4.0f64 - 7.0 / 3.0).powi(2))
            / 2.0;
        assert!((s.std - var.sqrt()).abs() < 1e-15);
    }

    #[test]
    fn words_are_quoted_for_the_shell() {
        assert_eq!(shell_word("a=1"), "a=1");
        assert_eq!(shell_word("K=[1, 2]"), "'K=[1, 2]'");
        assert_eq!(shell_word("it's"), r"'it'\''s'");
    }
}
