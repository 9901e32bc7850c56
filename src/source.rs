//! Source text of a model: [`SourceFile`] (name, text, line index) and
//! [`Span`] (a byte range into the text).

use std::fmt;
use std::path::Path;

/// A byte range `start..end` into a [`SourceFile`]'s text.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Span {
    /// First byte.
    pub start: usize,
    /// One past the last byte.
    pub end: usize,
}

impl Span {
    /// The span `start..end`.
    pub fn new(start: usize, end: usize) -> Self {
        Self { start, end }
    }

    /// The smallest span covering `self` and `other`.
    pub fn to(self, other: Span) -> Span {
        Span::new(self.start.min(other.start), self.end.max(other.end))
    }
}

impl From<pest::Span<'_>> for Span {
    fn from(s: pest::Span<'_>) -> Self {
        Span::new(s.start(), s.end())
    }
}

/// A 1-based line and column (column counted in characters).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LineCol {
    /// Line number, from 1.
    pub line: usize,
    /// Column number in characters, from 1.
    pub col: usize,
}

impl fmt::Display for LineCol {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.line, self.col)
    }
}

/// The largest model text hybsim reads (16 MiB; the shipped models are under 20 KB). Checking
/// takes about 200 bytes of memory and 0.6 s per megabyte of text, and reading stops here, so a
/// path such as `/dev/zero` or a runaway generated file is an error at once rather than a read
/// that never ends or fills the memory.
pub const MAX_SOURCE_BYTES: u64 = 16 << 20;

/// The UTF-8 text `reader` gives, refused with [`std::io::ErrorKind::FileTooLarge`] past
/// [`MAX_SOURCE_BYTES`] (without reading more than one byte beyond it), and with
/// [`std::io::ErrorKind::InvalidData`] naming the line and column of the first byte that is not
/// UTF-8.
pub fn read_text(reader: impl std::io::Read) -> std::io::Result<String> {
    let mut bytes = Vec::new();
    std::io::Read::read_to_end(&mut reader.take(MAX_SOURCE_BYTES + 1), &mut bytes)?;
    let text = String::from_utf8(bytes).map_err(|e| {
        let valid = &e.as_bytes()[..e.utf8_error().valid_up_to()];
        // The valid prefix is text: its lines and characters place the bad byte.
        let prefix = std::str::from_utf8(valid).unwrap_or_default();
        let line = prefix.matches('\n').count() + 1;
        let col = prefix.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
        let byte = e.as_bytes()[valid.len()];
        std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "line {line}, column {col}: byte 0x{byte:02x} is not UTF-8 (save the file as UTF-8)"
            ),
        )
    })?;
    if text.len() as u64 > MAX_SOURCE_BYTES {
        return Err(std::io::Error::new(
            std::io::ErrorKind::FileTooLarge,
            format!(
                "more than {} MiB, the limit for a model's text",
                MAX_SOURCE_BYTES >> 20
            ),
        ));
    }
    Ok(text)
}

/// A named source text with an index of line starts.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SourceFile {
    name: String,
    text: String,
    line_starts: Vec<usize>,
}

impl SourceFile {
    /// A source named `name` (usually its path) with contents `text` (a leading UTF-8
    /// byte-order mark removed).
    pub fn new(name: impl Into<String>, text: impl Into<String>) -> Self {
        let mut text = text.into();
        // A UTF-8 byte-order mark (editors on Windows write one) is not part of the text.
        if text.starts_with('\u{feff}') {
            text.drain(..'\u{feff}'.len_utf8());
        }
        Self::verbatim(name, text)
    }

    /// A source holding `text` exactly, a leading byte-order mark included: for texts whose
    /// spans were measured before any mark was removed (a `--set` argument, a table's data).
    pub fn verbatim(name: impl Into<String>, text: impl Into<String>) -> Self {
        let text = text.into();
        let line_starts = std::iter::once(0)
            .chain(text.match_indices('\n').map(|(i, _)| i + 1))
            .collect();
        Self {
            name: name.into(),
            text,
            line_starts,
        }
    }

    /// Reads the file at `path` (at most [`MAX_SOURCE_BYTES`]); its name is the path as given.
    pub fn read(path: impl AsRef<Path>) -> std::io::Result<Self> {
        let path = path.as_ref();
        let text = read_text(std::fs::File::open(path)?)?;
        Ok(Self::new(path.display().to_string(), text))
    }

    /// The file's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The whole text.
    pub fn text(&self) -> &str {
        &self.text
    }

    /// The text covered by `span` (empty if the span is out of bounds or
    /// not on character boundaries).
    pub fn slice(&self, span: Span) -> &str {
        self.text.get(span.start..span.end).unwrap_or("")
    }

    /// Start offsets of the lines, for the renderer.
    pub fn line_starts(&self) -> &[usize] {
        &self.line_starts
    }

    /// Line and column of byte offset `offset` (clamped to the text).
    pub fn line_col(&self, offset: usize) -> LineCol {
        let mut offset = offset.min(self.text.len());
        while !self.text.is_char_boundary(offset) {
            offset -= 1;
        }
        let line = match self.line_starts.binary_search(&offset) {
            Ok(l) => l,
            Err(l) => l - 1,
        };
        let col = self.text[self.line_starts[line]..offset].chars().count() + 1;
        LineCol {
            line: line + 1,
            col,
        }
    }
}

/// Where the spans of a model's imported files are: a model and the files
/// it imports share one offset space (the model's text first, each imported
/// file after it at its `base`), so that a [`Span`] of the AST says in which
/// file it is. [`crate::diagnostics::Diagnostic::locate`] moves a diagnostic's
/// labels into their files.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct SourceMap {
    /// Imported files in order of their bases.
    files: Vec<(usize, std::sync::Arc<SourceFile>)>,
}

impl SourceMap {
    /// The first offset after everything mapped so far, given the model's
    /// text length: where the next imported file starts (one past the end,
    /// so that an end-of-file span stays in its file).
    pub fn next_base(&self, model_len: usize) -> usize {
        match self.files.last() {
            Some((base, f)) => base + f.text().len() + 1,
            None => model_len + 1,
        }
    }

    /// Adds `file` at `base` (from [`Self::next_base`]).
    pub fn push(&mut self, base: usize, file: SourceFile) {
        self.files.push((base, std::sync::Arc::new(file)));
    }

    /// The imported files with their bases.
    pub fn files(&self) -> impl Iterator<Item = (usize, &SourceFile)> {
        self.files.iter().map(|(b, f)| (*b, f.as_ref()))
    }

    /// The imported file `span` is in and the span within it; `None` for a
    /// span of the model's own text.
    pub fn locate(&self, span: Span) -> Option<(std::sync::Arc<SourceFile>, Span)> {
        let k = self.files.partition_point(|(b, _)| *b <= span.start);
        let (base, file) = self.files.get(k.checked_sub(1)?)?;
        Some((
            file.clone(),
            Span::new(span.start - base, span.end.saturating_sub(*base)),
        ))
    }
}

/// The SHA-256 of `bytes` as 64 lowercase hex digits: how run files and
/// sweep manifests identify a model, an imported file or a table.
pub fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_col_counts_from_one() {
        let f = SourceFile::new("m.hyb", "ab\ncd\n\néf");
        assert_eq!(f.line_col(0), LineCol { line: 1, col: 1 });
        assert_eq!(f.line_col(4), LineCol { line: 2, col: 2 });
        assert_eq!(f.line_col(7), LineCol { line: 4, col: 1 });
        assert_eq!(f.line_col(9), LineCol { line: 4, col: 2 });
        assert_eq!(f.line_col(999), LineCol { line: 4, col: 3 });
    }

    #[test]
    fn text_that_is_not_utf8_is_refused_at_its_line_and_column() {
        let e = read_text(&b"model m\n# caf\xc3\xa9 \xff\n"[..]).unwrap_err();
        assert_eq!(e.kind(), std::io::ErrorKind::InvalidData);
        assert!(
            e.to_string()
                .starts_with("line 2, column 8: byte 0xff is not UTF-8"),
            "{e}"
        );
        assert_eq!(read_text(&b"a\nb"[..]).unwrap(), "a\nb");
    }
}
