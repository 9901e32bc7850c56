//! A run as CSV: one row per logged sample, columns
//! `t, j, kind, <state components>, <output components>`, named by the
//! layouts' flat names (`h`, `x[2]`, `P[1,2]`, `agent[3].xhat[1]`; names
//! with commas are quoted). Numbers are written in shortest round-trip form
//! (`0.1`, `2.220446049250313e-16`, `1e+300`: the fewest digits that read
//! back as exactly the same value, with an exponent for very small and very
//! large magnitudes), so reading a file back gives the exact values.
//!
//! Jumps of rules that are not logged ([`RunInfo::logged_rules`]) leave
//! their pre-jump sample as a `flow` row and no `post_jump` row (see
//! [`super::LogFilter`]).

use std::io::BufWriter;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use crate::atomic_file::OutputFile;

use super::{Decimation, LogFilter, LoggedOutputs, OutputFn, RunInfo, SinkError, Tally};
use crate::arc::{ArcSink, HybridTime, SampleKind};
use crate::atomic_file;

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

/// Writes logged samples as CSV rows to a temporary file, renamed to `path`
/// by [`finish`](Self::finish); dropped unfinished, it leaves no file.
pub struct CsvSink<'a> {
    path: PathBuf,
    writer: Option<::csv::Writer<BufWriter<OutputFile>>>,
    outputs: LoggedOutputs<'a>,
    tally: Tally,
    state_cols: Vec<usize>,
    output_cols: Vec<usize>,
    filter: LogFilter,
    error: Option<SinkError>,
}

/// The text of a number in a CSV cell: shortest round-trip form, `NaN`,
/// `inf` and `-inf` for non-finite values (which `pandas.read_csv` reads).
pub fn number_text(v: f64, buf: &mut zmij::Buffer) -> &str {
    buf.format(v)
}

impl<'a> CsvSink<'a> {
    /// Creates the temporary file and writes the header. Output columns are
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
        // Outputs are evaluated only when some are logged.
        let outputs =
            outputs.filter(|_| info.output_dim > 0 && !info.output_layout.entries.is_empty());
        let file = atomic_file::create(&path).map_err(|e| SinkError::io(&path, e))?;
        let mut writer = ::csv::Writer::from_writer(BufWriter::new(file));
        let mut header: Vec<String> = FIXED_COLUMNS.iter().map(|s| s.to_string()).collect();
        let (state_cols, names): (Vec<usize>, Vec<String>) =
            info.state_layout.components().into_iter().unzip();
        header.extend(names);
        let mut output_cols = Vec::new();
        if outputs.is_some() {
            let (cols, names): (Vec<usize>, Vec<String>) =
                info.output_layout.components().into_iter().unzip();
            output_cols = cols;
            header.extend(names);
        }
        writer
            .write_record(&header)
            .map_err(|source| SinkError::Csv {
                path: path.clone(),
                source,
            })?;
        Ok(Self {
            path,
            writer: Some(writer),
            outputs: LoggedOutputs::new(outputs, info.output_dim),
            state_cols,
            output_cols,
            tally: Tally::new(info.rule_names.len()),
            filter: LogFilter::new(&info.logged_rules, decimation),
            error: None,
        })
    }

    fn write_row(
        &mut self,
        at: HybridTime,
        x: &[f64],
        kind: SampleKind,
    ) -> Result<(), ::csv::Error> {
        let y = self.outputs.at(at, x);
        let w = self
            .writer
            .as_mut()
            .expect("the writer is present until finish");
        let mut num = zmij::Buffer::new();
        w.write_field(number_text(at.t, &mut num))?;
        w.write_field(itoa::Buffer::new().format(at.j))?;
        w.write_field(kind_name(kind))?;
        for &k in &self.state_cols {
            w.write_field(number_text(x[k], &mut num))?;
        }
        for &k in &self.output_cols {
            w.write_field(number_text(y[k], &mut num))?;
        }
        w.write_record(None::<&[u8]>)
    }

    /// Stores the first error and stops the run.
    fn settle(&mut self, r: Result<(), ::csv::Error>) -> ControlFlow<()> {
        match r {
            Ok(()) => ControlFlow::Continue(()),
            Err(source) => {
                self.error = Some(SinkError::Csv {
                    path: self.path.clone(),
                    source,
                });
                ControlFlow::Break(())
            }
        }
    }

    /// Samples and jumps seen so far.
    pub fn tally(&self) -> &Tally {
        &self.tally
    }

    /// Flushes, syncs and renames the file into place.
    pub fn finish(mut self) -> Result<PathBuf, SinkError> {
        if let Some(e) = self.error.take() {
            return Err(e);
        }
        // A run that ended between a held pre-jump sample and its jump.
        if let Some((at, x)) = self.filter.take_unfinished() {
            self.write_row(at, &x, SampleKind::PreJump)
                .map_err(|source| SinkError::Csv {
                    path: self.path.clone(),
                    source,
                })?;
        }
        let path = &self.path;
        let writer = self.writer.take().expect("finish is called once");
        let file = writer
            .into_inner()
            .map_err(|e| SinkError::Csv {
                path: path.clone(),
                source: e.into_error().into(),
            })?
            .into_inner()
            .map_err(|e| SinkError::io(path, e.into_error()))?;
        atomic_file::commit(file, path).map_err(|e| SinkError::io(path, e))?;
        Ok(self.path)
    }
}

impl ArcSink for CsvSink<'_> {
    fn failed(&self) -> bool {
        self.error.is_some()
    }

    fn sample(&mut self, at: HybridTime, x: &[f64], kind: SampleKind) -> ControlFlow<()> {
        if self.error.is_some() {
            return ControlFlow::Break(());
        }
        self.tally.sample(at);
        let r = LogFilter::write_sample(
            self,
            |s| &mut s.filter,
            Self::write_row,
            (at, x, kind),
            Ok(()),
        );
        self.settle(r)
    }

    fn jump(&mut self, at: HybridTime, rule: usize, pre: &[f64], _post: &[f64]) -> ControlFlow<()> {
        if self.error.is_some() {
            return ControlFlow::Break(());
        }
        self.tally.jump(rule);
        self.outputs.jump(at, rule);
        let r = match self.filter.route_jump(rule) {
            (_, Some(at)) => self.write_row(at, pre, SampleKind::PreJump),
            (_, None) => Ok(()),
        };
        self.settle(r)
    }
}
