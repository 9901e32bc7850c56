//! A run as CSV: one row per logged sample, columns
//! `t, j, kind, <state components>, <output components>`, named by the
//! layouts' flat names (`h`, `x[2]`, `P[1,2]`, `agent[3].xhat[1]`; names
//! with commas are quoted). Numbers are written in Rust's shortest
//! round-trip form, so reading a file back gives the exact values.

use std::fmt::Write as _;
use std::fs::File;
use std::io::BufWriter;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use super::{Decimation, Decimator, OutputFn, RunInfo, SinkError, Tally, commit_file, temp_path};
use crate::arc::{ArcSink, HybridTime, SampleKind};

/// Column names of the fixed leading columns.
pub const FIXED_COLUMNS: [&str; 3] = ["t", "j", "kind"];

/// The `kind` column's word for a sample kind.
pub fn kind_name(kind: SampleKind) -> &'static str {
    match kind {
        SampleKind::Initial => "initial",
        SampleKind::Flow => "flow",
        SampleKind::PreJump => "pre_jump",
        SampleKind::PostJump => "post_jump",
        SampleKind::Final => "final",
    }
}

/// Writes logged samples as CSV rows to `<path>.tmp`, renamed to `path` by
/// [`finish`](Self::finish).
pub struct CsvSink<'a> {
    path: PathBuf,
    tmp: PathBuf,
    writer: Option<::csv::Writer<BufWriter<File>>>,
    outputs: Option<OutputFn<'a>>,
    decimator: Decimator,
    tally: Tally,
    y: Vec<f64>,
    cell: String,
    error: Option<SinkError>,
}

impl<'a> CsvSink<'a> {
    /// Creates `<path>.tmp` and writes the header. Output columns are
    /// written if `info.output_dim > 0` and `outputs` is given.
    pub fn create(
        path: impl AsRef<Path>,
        info: &RunInfo,
        outputs: Option<OutputFn<'a>>,
        decimation: Decimation,
    ) -> Result<Self, SinkError> {
        let path = path.as_ref().to_path_buf();
        info.validate()?;
        decimation.validate()?;
        let outputs = outputs.filter(|_| info.output_dim > 0);
        let tmp = temp_path(&path);
        let file = File::create(&tmp).map_err(|e| SinkError::io(&tmp, e))?;
        let mut writer = ::csv::Writer::from_writer(BufWriter::new(file));
        let mut header: Vec<String> = FIXED_COLUMNS.iter().map(|s| s.to_string()).collect();
        header.extend(info.state_names());
        if outputs.is_some() {
            header.extend(info.output_names());
        }
        writer
            .write_record(&header)
            .map_err(|source| SinkError::Csv {
                path: tmp.clone(),
                source,
            })?;
        Ok(Self {
            path,
            tmp,
            writer: Some(writer),
            y: vec![
                0.0;
                if outputs.is_some() {
                    info.output_dim
                } else {
                    0
                }
            ],
            outputs,
            decimator: Decimator::new(decimation),
            tally: Tally::new(info.rule_names.len()),
            cell: String::new(),
            error: None,
        })
    }

    fn write_row(
        &mut self,
        at: HybridTime,
        x: &[f64],
        kind: SampleKind,
    ) -> Result<(), ::csv::Error> {
        if let Some(outputs) = self.outputs {
            outputs(at.t, x, &mut self.y);
        }
        let w = self
            .writer
            .as_mut()
            .expect("the writer is present until finish");
        let cell = &mut self.cell;
        let mut put = |v: &dyn std::fmt::Display| {
            cell.clear();
            write!(cell, "{v}").expect("writing to a String cannot fail");
            w.write_field(cell.as_bytes())
        };
        put(&at.t)?;
        put(&at.j)?;
        put(&kind_name(kind))?;
        for v in x.iter().chain(&self.y) {
            put(v)?;
        }
        w.write_record(None::<&[u8]>)
    }

    /// Samples and jumps seen so far.
    pub fn tally(&self) -> &Tally {
        &self.tally
    }

    /// Flushes, syncs and renames the file into place.
    pub fn finish(mut self) -> Result<PathBuf, SinkError> {
        let csv_err = |source| SinkError::Csv {
            path: self.tmp.clone(),
            source,
        };
        let result = match self.error.take() {
            Some(e) => Err(e),
            None => {
                let writer = self.writer.take().expect("finish is called once");
                writer
                    .into_inner()
                    .map_err(|e| csv_err(e.into_error().into()))
                    .and_then(|buf| {
                        buf.into_inner()
                            .map_err(|e| SinkError::io(&self.tmp, e.into_error()))
                    })
                    .and_then(|file| commit_file(file, &self.tmp, &self.path))
            }
        };
        match result {
            Ok(()) => Ok(self.path.clone()),
            Err(e) => {
                self.writer = None;
                let _ = std::fs::remove_file(&self.tmp);
                Err(e)
            }
        }
    }
}

impl Drop for CsvSink<'_> {
    fn drop(&mut self) {
        if self.writer.is_some() {
            // Dropped without finish: remove the partial file.
            self.writer = None;
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

impl ArcSink for CsvSink<'_> {
    fn sample(&mut self, at: HybridTime, x: &[f64], kind: SampleKind) -> ControlFlow<()> {
        if self.error.is_some() {
            return ControlFlow::Break(());
        }
        self.tally.sample(at);
        if !self.decimator.keep(at, kind) {
            return ControlFlow::Continue(());
        }
        match self.write_row(at, x, kind) {
            Ok(()) => ControlFlow::Continue(()),
            Err(source) => {
                self.error = Some(SinkError::Csv {
                    path: self.tmp.clone(),
                    source,
                });
                ControlFlow::Break(())
            }
        }
    }

    fn jump(
        &mut self,
        _at: HybridTime,
        rule: usize,
        _pre: &[f64],
        _post: &[f64],
    ) -> ControlFlow<()> {
        self.tally.jump(rule);
        ControlFlow::Continue(())
    }
}
