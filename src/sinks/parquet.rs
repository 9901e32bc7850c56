//! Tables as Apache Parquet files, written by the `parquet` crate's Arrow
//! writer: typed columns (unsigned integers, nullable floats, text) that
//! pandas, polars, DuckDB or Arrow read without parsing. Uncompressed (no
//! codec is built in); one row group per table. The bytes depend only on
//! the table (no timestamps), so equal tables give equal files.
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

use std::sync::Arc;

use ::parquet::arrow::ArrowWriter;
use arrow_array::{ArrayRef, Float64Array, RecordBatch, StringArray, UInt64Array};
use arrow_schema::{DataType, Field, Schema};

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

    /// The table as the bytes of a Parquet file.
    pub fn to_parquet(&self) -> Result<Vec<u8>, TableError> {
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
        let err = |e: &dyn std::fmt::Display| TableError::Parquet(e.to_string());
        let batch = if arrays.is_empty() {
            RecordBatch::new_empty(schema.clone())
        } else {
            RecordBatch::try_new(schema.clone(), arrays).map_err(|e| err(&e))?
        };
        let mut bytes = Vec::new();
        let mut writer = ArrowWriter::try_new(&mut bytes, schema, None).map_err(|e| err(&e))?;
        writer.write(&batch).map_err(|e| err(&e))?;
        writer.close().map_err(|e| err(&e))?;
        Ok(bytes)
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
