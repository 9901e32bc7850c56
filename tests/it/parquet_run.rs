//! `hybsim run --parquet`: the samples table holds the CSV's rows and
//! columns with the same values bit for bit, the jumps table one row per
//! logged jump with the pre- and post-jump states of the samples table.

use std::fs::File;
use std::path::{Path, PathBuf};

use arrow_array::{Array, Float64Array, RecordBatch, StringArray, UInt64Array};
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;

use super::util::{code, hybsim, stderr};

fn model(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("models")
        .join(name)
}

/// A Parquet file as (column names, rows of cells as text for text and
/// integer columns, bits for float columns).
fn read_parquet(path: &Path) -> (Vec<String>, Vec<Vec<Cell>>) {
    let reader = ParquetRecordBatchReaderBuilder::try_new(File::open(path).unwrap())
        .unwrap()
        .build()
        .unwrap();
    let batches: Vec<RecordBatch> = reader.map(|b| b.unwrap()).collect();
    let names = batches
        .first()
        .map(|b| {
            b.schema()
                .fields()
                .iter()
                .map(|f| f.name().clone())
                .collect()
        })
        .unwrap_or_default();
    let mut rows = Vec::new();
    for b in &batches {
        for r in 0..b.num_rows() {
            let row = b
                .columns()
                .iter()
                .map(|c| {
                    if let Some(f) = c.as_any().downcast_ref::<Float64Array>() {
                        assert!(!f.is_null(r));
                        Cell::Float(f.value(r).to_bits())
                    } else if let Some(u) = c.as_any().downcast_ref::<UInt64Array>() {
                        Cell::Text(u.value(r).to_string())
                    } else {
                        let s = c.as_any().downcast_ref::<StringArray>().unwrap();
                        Cell::Text(s.value(r).to_string())
                    }
                })
                .collect();
            rows.push(row);
        }
    }
    (names, rows)
}

#[derive(Debug, Clone, PartialEq)]
enum Cell {
    Float(u64),
    Text(String),
}

/// A CSV file as (header, rows of cells: `t` and the values as float bits,
/// `j` and `kind` as text).
fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<Cell>>) {
    let mut r = csv::Reader::from_path(path).unwrap();
    let names: Vec<String> = r.headers().unwrap().iter().map(str::to_string).collect();
    let rows = r
        .records()
        .map(|rec| {
            rec.unwrap()
                .iter()
                .enumerate()
                .map(|(k, cell)| {
                    if k == 1 || k == 2 {
                        Cell::Text(cell.to_string())
                    } else {
                        Cell::Float(cell.parse::<f64>().unwrap().to_bits())
                    }
                })
                .collect()
        })
        .collect();
    (names, rows)
}

#[test]
fn parquet_holds_the_csv_values_bit_for_bit_and_the_jumps() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (m, args, rules) in [
        ("bouncing_ball.hyb", vec!["--J", "12"], vec!["impact"]),
        // Families of vectors, outputs, a log selection and noise redraws
        // left out of the log.
        (
            "intermittent_estimation.hyb",
            vec!["--T", "0.6", "--log-vars", "x,xhat[2],e,enorm"],
            vec![],
        ),
        // Its events in full (its `log` block marks them).
        (
            "consensus_estimation.hyb",
            vec!["--T", "0.3", "--log-every", "3", "--log-rules", "event"],
            vec![],
        ),
    ] {
        let path = model(m);
        let mut all = vec![
            "run",
            path.to_str().unwrap(),
            "-q",
            "--no-mcap",
            "--csv",
            "r.csv",
            "--parquet",
            "r.parquet",
        ];
        all.extend(&args);
        let out = hybsim(d, &all);
        assert_eq!(code(&out), 0, "{m}: {}", stderr(&out));
        let (csv_names, csv_rows) = read_csv(&d.join("r.csv"));
        let (names, rows) = read_parquet(&d.join("r.parquet"));
        assert_eq!(names, csv_names, "{m}");
        assert!(rows.len() > 10, "{m}: {} rows", rows.len());
        assert!(
            rows == csv_rows,
            "{m}: the Parquet values differ from the CSV's"
        );
        // The jumps: one row per logged jump record, between the pre- and
        // post-jump samples of the samples table.
        let (jnames, jrows) = read_parquet(&d.join("r.jumps.parquet"));
        let states: Vec<&String> = names[3..]
            .iter()
            .filter(|n| jnames.contains(&format!("pre.{n}")))
            .collect();
        assert!(!states.is_empty(), "{m}: {jnames:?}");
        assert_eq!(&jnames[..4], ["t", "j", "rule", "rule_id"], "{m}");
        let pre_rows: Vec<&Vec<Cell>> = rows
            .iter()
            .filter(|r| r[2] == Cell::Text("pre_jump".into()))
            .collect();
        assert!(!jrows.is_empty() && jrows.len() >= pre_rows.len(), "{m}");
        for jr in &jrows {
            if let Cell::Text(rule) = &jr[2] {
                assert!(
                    rules.is_empty() || rules.contains(&rule.as_str()),
                    "{m}: {rule}"
                );
                assert!(!rule.ends_with(".redraw"), "{m}: redraws are not logged");
            }
            // The sample row at the jump's (t, j) marked pre_jump has the same values.
            let pre = pre_rows
                .iter()
                .find(|r| r[0] == jr[0] && r[1] == jr[1])
                .unwrap_or_else(|| panic!("{m}: no pre_jump row for {jr:?}"));
            for n in &states {
                let col = names.iter().position(|x| x == *n).unwrap();
                let jcol = jnames
                    .iter()
                    .position(|x| *x == format!("pre.{n}"))
                    .unwrap();
                assert_eq!(pre[col], jr[jcol], "{m}: pre.{n}");
            }
        }
    }
}

/// `--parquet -` writes the samples table to standard output (no jumps
/// table); a path that clashes with another output exits 2.
#[test]
fn parquet_to_stdout_and_clashes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ball = model("bouncing_ball.hyb");
    let out = hybsim(
        d,
        &[
            "run",
            ball.to_str().unwrap(),
            "-q",
            "--no-mcap",
            "--parquet",
            "-",
        ],
    );
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    assert!(out.stdout.starts_with(b"PAR1") && out.stdout.ends_with(b"PAR1"));
    std::fs::write(d.join("s.parquet"), &out.stdout).unwrap();
    let (names, rows) = read_parquet(&d.join("s.parquet"));
    assert_eq!(names, ["t", "j", "kind", "h", "v", "energy"]);
    assert!(rows.len() > 20);
    assert!(
        std::fs::read_dir(d).unwrap().count() == 1,
        "nothing else written"
    );
    let out = hybsim(
        d,
        &[
            "run",
            ball.to_str().unwrap(),
            "-q",
            "--no-mcap",
            "--parquet",
            "a.parquet",
            "--csv",
            "a.jumps.parquet",
        ],
    );
    assert_eq!(code(&out), 2, "{}", stderr(&out));
    assert!(stderr(&out).contains("same file"), "{}", stderr(&out));
}
