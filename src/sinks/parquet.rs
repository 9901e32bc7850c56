//! Tables as Apache Parquet files, written by the `parquet` crate's Arrow
//! writer: typed columns (unsigned integers, nullable floats, text) that
//! pandas, polars, DuckDB or Arrow read without parsing. Uncompressed (no
//! codec is built in). The bytes depend only on the table (no
//! timestamps), so equal tables give equal files.
//!
//! - [`Table`]: a whole table in memory, one row group (a sweep's results).
//! - [`TableWriter`]: a table written in batches of rows, in bounded memory.
//! - [`ParquetSink`]: a run as two tables, its samples (`t, j, kind`, one
//!   column per state and output component, named as in CSV) and its jumps
//!   (`t, j, rule, rule_id`, then `pre.<component>` and `post.<component>`
//!   for every state component); see [`ParquetSink::create`].
//!
//! ```
//! use hybsim::sinks::parquet::{Column, Table};
//!
//! let bytes = Table::new()
//!     .column("run", Column::U64(vec![0, 1]))
//!     .column("rate", Column::F64(vec![Some(0.5), None]))
//!     .column("cause", Column::Text(vec!["horizon_t".into(), "error".into()]))
//!     .to_parquet()
//!     .unwrap();
//! assert!(bytes.starts_with(b"PAR1") && bytes.ends_with(b"PAR1"));
//! ```

use std::io::{BufWriter, Write};
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use ::parquet::arrow::ArrowWriter;
use ::parquet::file::properties::WriterProperties;
use arrow_array::{ArrayRef, Float64Array, RecordBatch, StringArray, UInt64Array};
use arrow_schema::{DataType, Field, Schema, SchemaRef};

use super::csv::{FIXED_COLUMNS, kind_name};
use super::{Decimation, LogFilter, LoggedOutputs, OutputFn, RunInfo, SinkError, Tally, rule_name};
use crate::arc::{ArcSink, HybridTime, SampleKind};
use crate::atomic_file::{self, OutputFile};

/// One column's values.
#[derive(Debug, Clone, PartialEq)]
pub enum Column {
    /// Unsigned integers (indices, counts, seeds).
    U64(Vec<u64>),
    /// Floats; `None` is a missing value (null), NaN stays NaN.
    F64(Vec<Option<f64>>),
    /// Text.
    Text(Vec<String>),
}

impl Column {
    fn len(&self) -> usize {
        match self {
            Column::U64(v) => v.len(),
            Column::F64(v) => v.len(),
            Column::Text(v) => v.len(),
        }
    }
}

/// Why a table could not be written.
#[derive(Debug, thiserror::Error)]
pub enum TableError {
    /// Columns of different lengths.
    #[error("column `{name}` has {len} values, the first column {first}")]
    Length {
        /// The column.
        name: String,
        /// Its length.
        len: usize,
        /// The first column's length.
        first: usize,
    },
    /// The Arrow or Parquet writer failed.
    #[error("Parquet: {0}")]
    Parquet(String),
}

/// A table: named columns of equal length, in order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Table {
    columns: Vec<(String, Column)>,
}

impl Table {
    /// An empty table.
    pub fn new() -> Self {
        Self::default()
    }

    /// The table with column `name` appended.
    pub fn column(mut self, name: impl Into<String>, values: Column) -> Self {
        self.columns.push((name.into(), values));
        self
    }

    /// The columns, in order.
    pub fn columns(&self) -> &[(String, Column)] {
        &self.columns
    }

    /// The columns, in order, taken out of the table.
    pub fn into_columns(self) -> Vec<(String, Column)> {
        self.columns
    }

    /// The Arrow schema and record batch of the table.
    fn batch(&self) -> Result<(SchemaRef, RecordBatch), TableError> {
        let first = self.columns.first().map_or(0, |(_, c)| c.len());
        let mut fields = Vec::with_capacity(self.columns.len());
        let mut arrays: Vec<ArrayRef> = Vec::with_capacity(self.columns.len());
        for (name, c) in &self.columns {
            if c.len() != first {
                return Err(TableError::Length {
                    name: name.clone(),
                    len: c.len(),
                    first,
                });
            }
            let (ty, nullable, array): (DataType, bool, ArrayRef) = match c {
                Column::U64(v) => (
                    DataType::UInt64,
                    false,
                    Arc::new(UInt64Array::from(v.clone())),
                ),
                Column::F64(v) => (
                    DataType::Float64,
                    true,
                    Arc::new(Float64Array::from(v.clone())),
                ),
                Column::Text(v) => (
                    DataType::Utf8,
                    false,
                    Arc::new(StringArray::from_iter_values(v)),
                ),
            };
            fields.push(Field::new(name.as_str(), ty, nullable));
            arrays.push(array);
        }
        let schema = Arc::new(Schema::new(fields));
        let batch = if arrays.is_empty() {
            RecordBatch::new_empty(schema.clone())
        } else {
            RecordBatch::try_new(schema.clone(), arrays).map_err(|e| parquet_err(&e))?
        };
        Ok((schema, batch))
    }

    /// The table as the bytes of a Parquet file.
    pub fn to_parquet(&self) -> Result<Vec<u8>, TableError> {
        let (schema, batch) = self.batch()?;
        let mut bytes = Vec::new();
        let mut writer =
            ArrowWriter::try_new(&mut bytes, schema, None).map_err(|e| parquet_err(&e))?;
        writer.write(&batch).map_err(|e| parquet_err(&e))?;
        writer.close().map_err(|e| parquet_err(&e))?;
        Ok(bytes)
    }
}

fn parquet_err(e: &dyn std::fmt::Display) -> TableError {
    TableError::Parquet(e.to_string())
}

/// Rows per row group of a [`TableWriter`]: it holds at most this many
/// rows in memory, encoded.
pub const ROW_GROUP_ROWS: usize = 1 << 16;

/// A Parquet file written in batches of rows: each [`write`](Self::write)
/// appends a [`Table`] with the columns (names and types) of the first.
///
/// ```
/// use hybsim::sinks::parquet::{Column, Table, TableWriter};
/// let batch = |k: u64| Table::new().column("k", Column::U64(vec![k, k + 1]));
/// let mut w = TableWriter::new(Vec::new(), &batch(0)).unwrap();
/// w.write(&batch(2)).unwrap();
/// let bytes = w.finish().unwrap();
/// assert!(bytes.starts_with(b"PAR1"));
/// ```
pub struct TableWriter<W: Write + Send> {
    writer: ArrowWriter<W>,
    schema: SchemaRef,
}

impl<W: Write + Send> TableWriter<W> {
    /// A writer to `out` of tables shaped like `like` (its rows are not
    /// written).
    pub fn new(out: W, like: &Table) -> Result<Self, TableError> {
        let (schema, _) = like.batch()?;
        let properties = WriterProperties::builder()
            .set_max_row_group_row_count(Some(ROW_GROUP_ROWS))
            .build();
        let writer = ArrowWriter::try_new(out, schema.clone(), Some(properties))
            .map_err(|e| parquet_err(&e))?;
        Ok(Self { writer, schema })
    }

    /// Appends the rows of `table`.
    pub fn write(&mut self, table: &Table) -> Result<(), TableError> {
        let (schema, batch) = table.batch()?;
        if schema != self.schema {
            return Err(TableError::Parquet(
                "a batch's columns differ from the first's".into(),
            ));
        }
        self.writer.write(&batch).map_err(|e| parquet_err(&e))
    }

    /// Writes the footer and returns the output.
    pub fn finish(self) -> Result<W, TableError> {
        self.writer.into_inner().map_err(|e| parquet_err(&e))
    }
}

/// Rows a [`ParquetSink`] collects before writing them as one batch.
const BATCH_ROWS: usize = 4096;

/// The path of the jumps table beside the samples table `path`:
/// `run.parquet` → `run.jumps.parquet`; `None` for standard output and for
/// devices (`/dev/null`), which hold one stream.
pub fn jumps_path(path: &Path) -> Option<PathBuf> {
    if path.as_os_str() == atomic_file::STDOUT {
        return None;
    }
    if std::fs::metadata(path).is_ok_and(|m| !m.is_file() && !m.is_dir()) {
        return None;
    }
    let stem = path.file_stem()?.to_string_lossy().into_owned();
    Some(path.with_file_name(format!("{stem}.jumps.parquet")))
}

/// The column buffers of one table of a [`ParquetSink`].
#[derive(Default)]
struct Rows {
    t: Vec<f64>,
    j: Vec<u64>,
    /// `kind` (samples) or `rule` (jumps).
    text: Vec<String>,
    /// `rule_id` (jumps).
    ids: Vec<u64>,
    /// One buffer per value column.
    values: Vec<Vec<f64>>,
}

impl Rows {
    fn new(value_columns: usize) -> Self {
        Self {
            values: vec![Vec::new(); value_columns],
            ..Self::default()
        }
    }

    fn len(&self) -> usize {
        self.t.len()
    }

    /// The buffered rows as a table (and the buffers emptied): `t, j`, the
    /// text column, the id column if `ids`, then the value columns.
    fn take(&mut self, text: &str, ids: Option<&str>, names: &[String]) -> Table {
        let floats =
            |v: &mut Vec<f64>| Column::F64(std::mem::take(v).into_iter().map(Some).collect());
        let mut table = Table::new()
            .column(FIXED_COLUMNS[0], floats(&mut self.t))
            .column(FIXED_COLUMNS[1], Column::U64(std::mem::take(&mut self.j)))
            .column(text, Column::Text(std::mem::take(&mut self.text)));
        if let Some(ids) = ids {
            table = table.column(ids, Column::U64(std::mem::take(&mut self.ids)));
        }
        for (name, v) in names.iter().zip(&mut self.values) {
            table = table.column(name.as_str(), floats(v));
        }
        table
    }
}

type FileWriter = TableWriter<BufWriter<OutputFile>>;

/// Writes a run as Parquet: the samples table at `path` and the jumps
/// table beside it ([`jumps_path`]), both through temporary files renamed
/// by [`finish`](Self::finish); dropped unfinished, it leaves no file.
///
/// The samples table has the rows and columns of the CSV file
/// ([`super::csv`]): `t` (float), `j` (unsigned), `kind` (`initial`,
/// `flow`, `pre_jump`, `post_jump`, `final`), then one float column per
/// logged state component and per logged output component, named as in
/// CSV (`h`, `x[2]`, `P[1,2]`, `agent[3].xhat[1]`), with the same log
/// selection, jump filter and decimation. The jumps table has one row per
/// logged jump record: `t`, `j` (the pre-jump hybrid time), `rule`,
/// `rule_id`, then `pre.<name>` and `post.<name>` for every logged state
/// component. Values are stored exactly (NaN and infinities as such).
pub struct ParquetSink<'a> {
    path: PathBuf,
    jumps_path: Option<PathBuf>,
    samples: Option<FileWriter>,
    jumps: Option<FileWriter>,
    outputs: LoggedOutputs<'a>,
    state_cols: Vec<usize>,
    output_cols: Vec<usize>,
    sample_names: Vec<String>,
    jump_names: Vec<String>,
    rule_names: Vec<String>,
    sample_rows: Rows,
    jump_rows: Rows,
    filter: LogFilter,
    tally: Tally,
    error: Option<SinkError>,
}

impl<'a> ParquetSink<'a> {
    /// Creates the temporary files of both tables (only the samples table
    /// for standard output, `-`, or a device). Output columns are written
    /// if `info.output_dim > 0` and `outputs` is given.
    pub fn create(
        path: impl AsRef<Path>,
        info: &RunInfo,
        outputs: Option<OutputFn<'a>>,
        decimation: Decimation,
    ) -> Result<Self, SinkError> {
        let path = path.as_ref().to_path_buf();
        info.validate()?;
        decimation.validate()?;
        let outputs =
            outputs.filter(|_| info.output_dim > 0 && !info.output_layout.entries.is_empty());
        let (state_cols, state_names): (Vec<usize>, Vec<String>) =
            info.state_layout.components().into_iter().unzip();
        let (output_cols, output_names): (Vec<usize>, Vec<String>) = if outputs.is_some() {
            info.output_layout.components().into_iter().unzip()
        } else {
            Default::default()
        };
        let sample_names: Vec<String> = state_names.iter().chain(&output_names).cloned().collect();
        let jump_names: Vec<String> = ["pre", "post"]
            .iter()
            .flat_map(|side| state_names.iter().map(move |n| format!("{side}.{n}")))
            .collect();
        let mut sample_rows = Rows::new(sample_names.len());
        let mut jump_rows = Rows::new(jump_names.len());
        let open = |path: &Path, like: &Table| -> Result<FileWriter, SinkError> {
            let file = atomic_file::create(path).map_err(|e| SinkError::io(path, e))?;
            TableWriter::new(BufWriter::new(file), like).map_err(|e| SinkError::Table {
                path: path.to_path_buf(),
                source: e,
            })
        };
        let samples = open(&path, &sample_rows.take("kind", None, &sample_names))?;
        let jumps_path = jumps_path(&path);
        let jumps = match &jumps_path {
            Some(p) => Some(open(
                p,
                &jump_rows.take("rule", Some("rule_id"), &jump_names),
            )?),
            None => None,
        };
        Ok(Self {
            path,
            jumps_path,
            samples: Some(samples),
            jumps,
            outputs: LoggedOutputs::new(outputs, info.output_dim),
            state_cols,
            output_cols,
            sample_names,
            jump_names,
            rule_names: info.rule_names.clone(),
            sample_rows,
            jump_rows,
            filter: LogFilter::new(&info.logged_rules, decimation),
            tally: Tally::new(info.rule_names.len()),
            error: None,
        })
    }

    /// The path of the jumps table, if one is written.
    pub fn jumps_path(&self) -> Option<&Path> {
        self.jumps_path.as_deref()
    }

    /// Samples and jumps seen so far.
    pub fn tally(&self) -> &Tally {
        &self.tally
    }

    fn table_err(path: &Path, e: TableError) -> SinkError {
        SinkError::Table {
            path: path.to_path_buf(),
            source: e,
        }
    }

    /// Writes the buffered sample rows.
    fn flush_samples(&mut self) -> Result<(), SinkError> {
        let table = self.sample_rows.take("kind", None, &self.sample_names);
        let w = self
            .samples
            .as_mut()
            .expect("the writer is present until finish");
        w.write(&table).map_err(|e| Self::table_err(&self.path, e))
    }

    /// Writes the buffered jump rows.
    fn flush_jumps(&mut self) -> Result<(), SinkError> {
        let table = self
            .jump_rows
            .take("rule", Some("rule_id"), &self.jump_names);
        if let (Some(w), Some(path)) = (self.jumps.as_mut(), &self.jumps_path) {
            w.write(&table).map_err(|e| Self::table_err(path, e))?;
        }
        Ok(())
    }

    fn push_row(&mut self, at: HybridTime, x: &[f64], kind: SampleKind) -> Result<(), SinkError> {
        let y = self.outputs.at(at, x);
        let rows = &mut self.sample_rows;
        rows.t.push(at.t);
        rows.j.push(at.j);
        rows.text.push(kind_name(kind).to_string());
        let values = self.state_cols.iter().map(|&k| x[k]);
        let values = values.chain(self.output_cols.iter().map(|&k| y[k]));
        for (column, v) in rows.values.iter_mut().zip(values) {
            column.push(v);
        }
        if rows.len() >= BATCH_ROWS {
            self.flush_samples()?;
        }
        Ok(())
    }

    fn push_jump(
        &mut self,
        at: HybridTime,
        rule: usize,
        pre: &[f64],
        post: &[f64],
    ) -> Result<(), SinkError> {
        if self.jumps.is_none() {
            return Ok(());
        }
        let rows = &mut self.jump_rows;
        rows.t.push(at.t);
        rows.j.push(at.j);
        rows.text.push(rule_name(&self.rule_names, rule));
        rows.ids.push(rule as u64);
        let values = [pre, post]
            .into_iter()
            .flat_map(|x| self.state_cols.iter().map(move |&k| x[k]));
        for (column, v) in rows.values.iter_mut().zip(values) {
            column.push(v);
        }
        if rows.len() >= BATCH_ROWS {
            self.flush_jumps()?;
        }
        Ok(())
    }

    /// Stores the first error and stops the run.
    fn settle(&mut self, r: Result<(), SinkError>) -> ControlFlow<()> {
        match r {
            Ok(()) => ControlFlow::Continue(()),
            Err(e) => {
                self.error.get_or_insert(e);
                ControlFlow::Break(())
            }
        }
    }

    /// Writes the last rows and the footers, and renames both files into
    /// place; returns the paths written (samples, then jumps).
    pub fn finish(mut self) -> Result<Vec<PathBuf>, SinkError> {
        if let Some(e) = self.error.take() {
            return Err(e);
        }
        // A run that ended between a held pre-jump sample and its jump.
        if let Some((at, x)) = self.filter.take_unfinished() {
            self.push_row(at, &x, SampleKind::PreJump)?;
        }
        self.flush_samples()?;
        self.flush_jumps()?;
        let mut written = Vec::new();
        let files = [
            (self.samples.take(), Some(self.path.clone())),
            (self.jumps.take(), self.jumps_path.clone()),
        ];
        // Both files are completed before either is renamed into place.
        let mut done = Vec::new();
        for (writer, path) in files {
            if let (Some(writer), Some(path)) = (writer, path) {
                let file = writer
                    .finish()
                    .map_err(|e| Self::table_err(&path, e))?
                    .into_inner()
                    .map_err(|e| SinkError::io(&path, e.into_error()))?;
                done.push((file, path));
            }
        }
        for (file, path) in done {
            atomic_file::commit(file, &path).map_err(|e| SinkError::io(&path, e))?;
            written.push(path);
        }
        Ok(written)
    }
}

impl ArcSink for ParquetSink<'_> {
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
            Self::push_row,
            (at, x, kind),
            Ok(()),
        );
        self.settle(r)
    }

    fn jump(&mut self, at: HybridTime, rule: usize, pre: &[f64], post: &[f64]) -> ControlFlow<()> {
        if self.error.is_some() {
            return ControlFlow::Break(());
        }
        self.tally.jump(rule);
        self.outputs.jump(at, rule);
        let (record, flush) = self.filter.route_jump(rule);
        let mut r = match flush {
            Some(at) => self.push_row(at, pre, SampleKind::PreJump),
            None => Ok(()),
        };
        if record && r.is_ok() {
            r = self.push_jump(at, rule, pre, post);
        }
        self.settle(r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ::parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
    use arrow_array::Array;
    use std::io::Write;

    #[test]
    fn a_table_reads_back_with_its_types_nulls_and_nans() {
        let bytes = Table::new()
            .column("k", Column::U64(vec![1, u64::MAX]))
            .column("x", Column::F64(vec![Some(f64::NAN), None]))
            .column("s", Column::Text(vec!["a,b".into(), "é\n".into()]))
            .to_parquet()
            .unwrap();
        let mut file = tempfile::tempfile().unwrap();
        file.write_all(&bytes).unwrap();
        let reader = ParquetRecordBatchReaderBuilder::try_new(file)
            .unwrap()
            .build()
            .unwrap();
        let batches: Vec<RecordBatch> = reader.map(|b| b.unwrap()).collect();
        assert_eq!(batches.len(), 1);
        let b = &batches[0];
        let k = b.column(0).as_any().downcast_ref::<UInt64Array>().unwrap();
        assert_eq!(k.values().to_vec(), [1, u64::MAX]);
        let x = b.column(1).as_any().downcast_ref::<Float64Array>().unwrap();
        assert!(x.value(0).is_nan() && x.is_null(1));
        let s = b.column(2).as_any().downcast_ref::<StringArray>().unwrap();
        assert_eq!((s.value(0), s.value(1)), ("a,b", "é\n"));
    }

    #[test]
    fn columns_of_different_lengths_are_an_error() {
        let e = Table::new()
            .column("a", Column::U64(vec![1]))
            .column("b", Column::U64(vec![]))
            .to_parquet()
            .unwrap_err();
        assert!(e.to_string().contains("`b` has 0 values"), "{e}");
    }
}
