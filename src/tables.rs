//! `param tk = table("timers.csv")`: constant matrices read from CSV files
//! beside the model.
//!
//! The path follows the rules of `import` ([`crate::imports`]): relative to
//! the model, inside its folder. [`resolve`] checks the paths when the
//! model is parsed; the checker reads each file once ([`read`]), with its
//! size estimated before anything of that size is allocated (the resource
//! limit `max_matrix_elements`), and records its path and SHA-256 (the MCAP
//! metadata of a run names the data it used).
//!
//! Format: one row per line, fields separated by `,`, spaces around a
//! field ignored; blank lines and lines starting with `#` are skipped; the
//! first row may be a header of names (every field not a number), which is
//! skipped. Every other field must be a finite number in Rust's `f64`
//! syntax (`1`, `-2.5`, `1e-3`; not `inf`, `nan`, `0x1`, an empty field) and
//! every row must have as many fields as the first. One column gives a
//! column vector, several a matrix (rows × columns).

use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::diagnostics::Diagnostic;
use crate::imports::{self, ImportError};
use crate::source::{SourceFile, Span};
use crate::syntax::ast::{Item, Model};

/// A table read from its file.
#[derive(Debug, Clone, PartialEq)]
pub struct TableData {
    /// Rows (data lines).
    pub rows: usize,
    /// Columns (fields per line).
    pub cols: usize,
    /// Entries, row-major.
    pub data: Vec<f64>,
    /// The file as read.
    pub file: TableFile,
}

/// The file a table was read from: what the MCAP metadata records.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct TableFile {
    /// The path it was opened by (the model's folder joined with the path
    /// as written).
    pub path: String,
    /// Hex SHA-256 of its bytes.
    pub sha256: String,
}

/// Why the contents of a table file were refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DataError {
    /// A field that is not a number.
    #[error("`{0}` is not a number")]
    NotANumber(String),
    /// A number that is not finite (`inf`, `nan`, `1e999`).
    #[error("`{0}` is not a finite number")]
    NotFinite(String),
    /// An empty field (`1,,2`, a trailing comma).
    #[error("an empty field")]
    Empty,
    /// A row with another number of fields than the first.
    #[error("a row of {found} fields where the first has {expected}")]
    Ragged {
        /// Fields of this row.
        found: usize,
        /// Fields of the first row.
        expected: usize,
    },
    /// No data row.
    #[error("no data (only blank lines, comments or a header)")]
    NoData,
    /// Bytes that are not UTF-8.
    #[error("the file is not UTF-8 text")]
    NotUtf8,
}

/// Why a table could not be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TableError {
    /// The path breaks the rules of `import` (E0801) or the file cannot be
    /// read (E0802).
    #[error(transparent)]
    Path(#[from] ImportError),
    /// Bad contents (E0804), at `at` (a byte range of `text`) in `file`.
    #[error("table `{path}`: {why}")]
    Data {
        /// The path as written.
        path: String,
        /// What is wrong.
        why: DataError,
        /// The file (its text up to the error's line and that line).
        file: Arc<SourceFile>,
        /// Where in `file`.
        at: Span,
        /// The `table(…)` call.
        call: Span,
    },
    /// More entries (estimated from the file's separators and size, before
    /// reading it) than the limit `max_matrix_elements`.
    #[error("table `{path}`: about {estimate} entries, over the limit of {limit}")]
    TooLarge {
        /// The path as written.
        path: String,
        /// The estimated number of entries.
        estimate: u64,
        /// The limit in force.
        limit: u64,
        /// The `table(…)` call.
        call: Span,
    },
}

impl TableError {
    /// The stable code: E0801/E0802 (path), E0804 (contents), E0307 (size).
    pub fn code(&self) -> &'static str {
        match self {
            TableError::Path(ImportError::NotAllowed { .. }) => "E0801",
            TableError::Path(_) => "E0802",
            TableError::Data { .. } => "E0804",
            TableError::TooLarge { .. } => "E0307",
        }
    }

    /// The primary span in the model (the path or the call).
    pub fn span(&self) -> Span {
        match self {
            TableError::Path(ImportError::NotAllowed { span, .. })
            | TableError::Path(ImportError::Unreadable { span, .. })
            | TableError::Path(ImportError::Cycle { span, .. }) => *span,
            TableError::Path(ImportError::Syntax(e)) => e.span(),
            TableError::Data { call, .. } | TableError::TooLarge { call, .. } => *call,
        }
    }

    /// The error as a diagnostic: a contents error points at the file's
    /// line and column, with the `table(…)` call as second label.
    pub fn to_diagnostic(&self) -> Diagnostic {
        match self {
            TableError::Path(e) => {
                let mut d = e.to_diagnostic();
                if let ImportError::Unreadable { .. } = e {
                    d = d.help("paths are relative to the model's file");
                }
                d
            }
            TableError::Data {
                why,
                file,
                at,
                call,
                ..
            } => {
                let mut d = Diagnostic::error(self.code(), self.to_string())
                    .primary(*at, why.to_string())
                    .secondary(*call, "read here");
                d.labels[0].file = Some(file.clone());
                d.help(match why {
                    DataError::NotANumber(_) => {
                        "a table holds numbers separated by `,`; only its first row may be a \
                         header of names"
                    }
                    DataError::Ragged { .. } => "give every row the same number of fields",
                    DataError::NotFinite(_) => "tables hold finite numbers only",
                    _ => "a table holds rows of numbers separated by `,`",
                })
            }
            TableError::TooLarge { call, .. } => Diagnostic::error(self.code(), self.to_string())
                .primary(*call, "read here")
                .help(
                    "use a smaller table, or raise the limit: `max_matrix_elements = N` in `sim` \
                     or `--set max_matrix_elements=N`",
                ),
        }
    }
}

/// Checks the path of every `table("…")` of `model` (the rules of
/// `import`, relative to the model `src`) and records the file it names;
/// every refused path is a diagnostic.
pub fn resolve(src: &SourceFile, model: &mut Model) -> Result<(), Vec<Diagnostic>> {
    let root = imports::model_root(src);
    let mut errors = Vec::new();
    for it in &mut model.items {
        let Item::Table(t) = it else { continue };
        match file_of(&root, &t.path, t.path_span) {
            Ok(file) => t.file = Some(file),
            Err(e) => errors.push(TableError::from(e).to_diagnostic()),
        }
    }
    if errors.is_empty() {
        Ok(())
    } else {
        Err(errors)
    }
}

fn file_of(root: &Path, path: &str, span: Span) -> Result<PathBuf, ImportError> {
    let rel = imports::relative_path(Path::new(""), path, span, "table")?;
    let full = root.join(rel);
    imports::inside_root(root, &imports::canonical(&full), path, span, "table")?;
    Ok(full)
}

/// Bytes of a file per entry it may hold: a number written in full
/// (17 significant digits, sign, point, exponent) and its separator fit.
const BYTES_PER_ENTRY: u64 = 64;

/// Reads the table at `file` (`path` as written, `call` the `table(…)`
/// call); refuses a file estimated to hold more than `max_entries`
/// entries before reading it.
pub fn read(
    file: &Path,
    path: &str,
    call: Span,
    max_entries: u64,
) -> Result<TableData, TableError> {
    let unreadable = |e: std::io::Error| {
        TableError::Path(ImportError::Unreadable {
            path: path.to_string(),
            resolved: file.display().to_string(),
            reason: e.to_string(),
            span: call,
        })
    };
    let mut f = std::fs::File::open(file).map_err(unreadable)?;
    // The estimate: separators and line ends, streamed (no allocation of
    // the file's size), and the size itself.
    let (mut separators, mut bytes) = (1u64, 0u64);
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = f.read(&mut buf).map_err(unreadable)?;
        if n == 0 {
            break;
        }
        bytes += n as u64;
        separators += buf[..n]
            .iter()
            .filter(|&&b| b == b',' || b == b'\n')
            .count() as u64;
        // Stop as soon as the limit is passed: `/dev/zero` never ends.
        if separators.max(bytes / BYTES_PER_ENTRY) > max_entries {
            break;
        }
    }
    let estimate = separators.max(bytes / BYTES_PER_ENTRY);
    if estimate > max_entries {
        return Err(TableError::TooLarge {
            path: path.to_string(),
            estimate,
            limit: max_entries,
            call,
        });
    }
    let raw = std::fs::read(file).map_err(unreadable)?;
    let sha256 = crate::source::sha256_hex(&raw);
    let name = file.display().to_string();
    // Spans are offsets in the text without its byte-order mark; the `SourceFile` showing an
    // error holds that text verbatim (a second mark would be data).
    let bom = if raw.starts_with("\u{feff}".as_bytes()) {
        3
    } else {
        0
    };
    let text = match String::from_utf8(raw[bom..].to_vec()) {
        Ok(t) => t,
        Err(e) => {
            let valid = e.utf8_error().valid_up_to();
            let text = String::from_utf8_lossy(&e.into_bytes()[..valid]).into_owned();
            let at = Span::new(valid, valid);
            return Err(TableError::Data {
                path: path.to_string(),
                why: DataError::NotUtf8,
                file: Arc::new(SourceFile::verbatim(name, text)),
                at,
                call,
            });
        }
    };
    let (rows, cols, data) = parse(&text).map_err(|(at, why)| TableError::Data {
        path: path.to_string(),
        why,
        file: Arc::new(SourceFile::verbatim(name.clone(), text.clone())),
        at,
        call,
    })?;
    Ok(TableData {
        rows,
        cols,
        data,
        file: TableFile { path: name, sha256 },
    })
}

/// Parses the text of a table: (rows, columns, entries row-major), or the
/// first error with its byte range in `text`.
pub fn parse(text: &str) -> Result<(usize, usize, Vec<f64>), (Span, DataError)> {
    let mut data = Vec::new();
    let mut cols: Option<usize> = None;
    let mut first = true;
    let mut offset = 0;
    for line in text.split_inclusive('\n') {
        let start = offset;
        offset += line.len();
        // A byte-order mark is not part of the first field.
        let (body, skip) = match line.strip_prefix('\u{feff}') {
            Some(rest) if start == 0 => (rest, '\u{feff}'.len_utf8()),
            _ => (line, 0),
        };
        let body = body.trim_end_matches(['\n', '\r']);
        let trimmed = body.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            continue;
        }
        // Fields with their byte ranges in `text`.
        let mut fields = Vec::new();
        let mut at = start + skip;
        for f in body.split(',') {
            let lead = f.len() - f.trim_start().len();
            let s = f.trim();
            fields.push((s, Span::new(at + lead, at + lead + s.len())));
            at += f.len() + 1;
        }
        let numbers: Vec<Result<f64, DataError>> = fields.iter().map(|(s, _)| number(s)).collect();
        if first {
            first = false;
            // A header: names only (no field a number, none empty).
            let names = numbers
                .iter()
                .zip(&fields)
                .all(|(n, (s, _))| matches!(n, Err(DataError::NotANumber(_))) && !s.is_empty());
            if names {
                cols = Some(fields.len());
                continue;
            }
        }
        let expected = *cols.get_or_insert(fields.len());
        if fields.len() != expected {
            let at = match fields.get(expected) {
                Some((_, span)) => *span,
                None => Span::new(start + skip + body.len(), start + skip + body.len()),
            };
            return Err((
                at,
                DataError::Ragged {
                    found: fields.len(),
                    expected,
                },
            ));
        }
        for (n, (_, span)) in numbers.into_iter().zip(&fields) {
            data.push(n.map_err(|e| (*span, e))?);
        }
    }
    let Some(cols) = cols.filter(|_| !data.is_empty()) else {
        let end = text.len();
        return Err((Span::new(end, end), DataError::NoData));
    };
    Ok((data.len() / cols, cols, data))
}

/// A field as a finite number.
fn number(s: &str) -> Result<f64, DataError> {
    if s.is_empty() {
        return Err(DataError::Empty);
    }
    // Rust's syntax, without the words it also accepts (`inf`, `NaN`).
    let numeric = s
        .bytes()
        .all(|b| b.is_ascii_digit() || matches!(b, b'+' | b'-' | b'.' | b'e' | b'E'));
    match s.parse::<f64>() {
        Ok(v) if numeric && v.is_finite() => Ok(v),
        Ok(_) if numeric => Err(DataError::NotFinite(s.to_string())),
        Ok(_) => Err(DataError::NotFinite(s.to_string())),
        Err(_) => Err(DataError::NotANumber(s.to_string())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn err(text: &str) -> (String, DataError) {
        let (span, e) = parse(text).expect_err("refused");
        (text[span.start..span.end].to_string(), e)
    }

    #[test]
    fn vectors_matrices_headers_comments() {
        assert_eq!(
            parse("1\n2.5\n-3e-1\n").unwrap(),
            (3, 1, vec![1.0, 2.5, -0.3])
        );
        assert_eq!(
            parse("\u{feff}a, b\r\n# note\n\n1, 2\r\n3 ,4").unwrap(),
            (2, 2, vec![1.0, 2.0, 3.0, 4.0])
        );
        assert_eq!(parse("x,y,z\n1,2,3").unwrap(), (1, 3, vec![1.0, 2.0, 3.0]));
    }

    #[test]
    fn errors_name_the_field() {
        assert_eq!(
            err("1,2\n3,x\n"),
            ("x".into(), DataError::NotANumber("x".into()))
        );
        assert_eq!(
            err("1\ninf\n"),
            ("inf".into(), DataError::NotFinite("inf".into()))
        );
        assert_eq!(
            err("1\n1e999\n"),
            ("1e999".into(), DataError::NotFinite("1e999".into()))
        );
        assert_eq!(err("1,,2\n"), ("".into(), DataError::Empty));
        assert_eq!(
            err("1,2\n3,4,5\n"),
            (
                "5".into(),
                DataError::Ragged {
                    found: 3,
                    expected: 2
                }
            )
        );
        assert_eq!(
            err("1,2\n3\n").1,
            DataError::Ragged {
                found: 1,
                expected: 2
            }
        );
        // A header of names and numbers is data with a bad field.
        assert_eq!(
            err("a,1\n2,3\n"),
            ("a".into(), DataError::NotANumber("a".into()))
        );
        assert_eq!(err("a,b\n# only a header\n").1, DataError::NoData);
        assert_eq!(err("").1, DataError::NoData);
        assert_eq!(err("1\n0x10\n").1, DataError::NotANumber("0x10".into()));
    }
}
