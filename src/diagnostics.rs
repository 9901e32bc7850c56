//! Diagnostics: what went wrong, where, and what to change. Every layer
//! converts its own error type into a [`Diagnostic`]; this module holds the
//! only renderer (codespan-reporting): `file:line:col`, the source line and
//! carets under the offending text.

use codespan_reporting::diagnostic as cs;
use codespan_reporting::files::SimpleFiles;
use codespan_reporting::term::{self, Config, termcolor};

use crate::source::{LineCol, SourceFile, SourceMap, Span};

/// How serious a diagnostic is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Severity {
    /// The model cannot be compiled or run.
    Error,
    /// Suspicious but accepted.
    Warning,
}

/// A span with a message: the primary label points at the error, secondary
/// labels at related places (e.g. the first of two definitions).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Label {
    /// Where.
    pub span: Span,
    /// What is there (may be empty).
    pub message: String,
    /// True for the main location of the diagnostic.
    pub primary: bool,
    /// The file the span is in when it is not the model's own text (a file
    /// brought in by `import`, set by [`Diagnostic::locate`]; the text of a
    /// `--set` override, set by [`Diagnostic::in_override`]).
    pub file: Option<std::sync::Arc<SourceFile>>,
}

/// Bytes of a `--set` argument shown whole in a diagnostic; a longer one
/// is shown around the error (see [`Diagnostic::in_set_argument`]).
pub const LONG_ARGUMENT: usize = 160;

/// One diagnostic: a stable code (e.g. `E0201`), a message, labelled source
/// locations, notes and an optional help sentence saying what to change.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Diagnostic {
    /// Error or warning.
    pub severity: Severity,
    /// Stable code, e.g. `E0201`; documented in LANGUAGE.md.
    pub code: &'static str,
    /// One plain sentence.
    pub message: String,
    /// Locations in the source, the primary one first.
    pub labels: Vec<Label>,
    /// Additional facts.
    pub notes: Vec<String>,
    /// What to change, if known.
    pub help: Option<String>,
}

impl Diagnostic {
    /// An error with code `code` and message `message`, without labels.
    pub fn error(code: &'static str, message: impl Into<String>) -> Self {
        Self {
            severity: Severity::Error,
            code,
            message: message.into(),
            labels: Vec::new(),
            notes: Vec::new(),
            help: None,
        }
    }

    /// A warning with code `code` and message `message`, without labels.
    pub fn warning(code: &'static str, message: impl Into<String>) -> Self {
        Self {
            severity: Severity::Warning,
            ..Self::error(code, message)
        }
    }

    /// Adds the primary label.
    pub fn primary(mut self, span: Span, message: impl Into<String>) -> Self {
        self.labels.push(Label {
            span,
            message: message.into(),
            primary: true,
            file: None,
        });
        self
    }

    /// Adds a secondary label.
    pub fn secondary(mut self, span: Span, message: impl Into<String>) -> Self {
        self.labels.push(Label {
            span,
            message: message.into(),
            primary: false,
            file: None,
        });
        self
    }

    /// Adds a note.
    pub fn note(mut self, note: impl Into<String>) -> Self {
        self.notes.push(note.into());
        self
    }

    /// Sets the help sentence.
    pub fn help(mut self, help: impl Into<String>) -> Self {
        self.help = Some(help.into());
        self
    }

    /// Points the labels into the override `--set name=value` instead of the model: `spans` are
    /// byte ranges of `value` (the override's expression was parsed from it alone). Renders as
    /// `┌─ --set name:1:col` with the caret under the value.
    pub fn in_override(self, name: &str, value: &str) -> Self {
        self.in_set_argument(name, &format!("{name}={value}"), name.len() + 1)
    }

    /// Points the labels into the `--set` argument `text` (as typed, or
    /// `name=value` rebuilt), named `--set name`: `spans` are byte ranges of
    /// `text` from byte `shift` on (0: the whole argument, e.g. to point at
    /// the name).
    ///
    /// An argument longer than [`LONG_ARGUMENT`] bytes is shown as a window
    /// around the primary label, its file named with the window's columns
    /// (`--set x (columns 1961–2081 of 40002)`), so that a 100 kB value
    /// does not flood the terminal.
    pub fn in_set_argument(self, name: &str, text: &str, shift: usize) -> Self {
        // Named after the override, so that two overrides are two files when rendered.
        let file = if name.is_empty() {
            "--set".to_string()
        } else {
            format!("--set {name}")
        };
        self.in_argument(file, text, shift)
    }

    /// Points the labels into the command-line flag `text` as typed (`--T 0`), named `flag`
    /// (`--T`): `spans` are byte ranges of `text`.
    pub fn in_flag(self, flag: &str, text: &str) -> Self {
        self.in_argument(flag.to_string(), text, 0)
    }

    /// Points the labels into the command-line argument `text`, shown as the file `file`
    /// (see [`in_set_argument`](Self::in_set_argument)).
    fn in_argument(mut self, mut file: String, text: &str, shift: usize) -> Self {
        let mut shown = text.to_string();
        // (start, end, bytes of the leading ellipsis) of the part shown.
        let mut window = None;
        if text.len() > LONG_ARGUMENT {
            let at = self.primary_span().or(self.labels.first().map(|l| l.span));
            let at = at.map_or(0, |s| (s.start + shift).min(text.len()));
            let floor = |mut i: usize| {
                while !text.is_char_boundary(i) {
                    i -= 1;
                }
                i
            };
            let a = floor(at.saturating_sub(40));
            let b = floor((at + 80).min(text.len()));
            let (lead, trail) = (
                if a > 0 { "…" } else { "" },
                if b < text.len() { "…" } else { "" },
            );
            shown = format!("{lead}{}{trail}", &text[a..b]);
            let cols = |i: usize| text[..i].chars().count();
            file = format!(
                "{file} (columns {}–{} of {})",
                cols(a) + 1,
                cols(b),
                cols(text.len())
            );
            window = Some((a, b, lead.len()));
        }
        let moved = |s: usize| match window {
            Some((a, b, lead)) => (s + shift).clamp(a, b) - a + lead,
            None => s + shift,
        };
        // Verbatim: a byte-order mark typed into the argument is part of it (the spans count it).
        let origin = std::sync::Arc::new(SourceFile::verbatim(file, shown));
        for l in &mut self.labels {
            l.span = Span::new(moved(l.span.start), moved(l.span.end));
            l.file = Some(origin.clone());
        }
        self
    }

    /// The primary span, if any.
    pub fn primary_span(&self) -> Option<Span> {
        self.labels.iter().find(|l| l.primary).map(|l| l.span)
    }

    /// Line and column of the primary span in `src` (or in the imported
    /// file the label is in, see [`Self::primary_file`]).
    pub fn line_col(&self, src: &SourceFile) -> Option<LineCol> {
        let l = self.labels.iter().find(|l| l.primary)?;
        Some(l.file.as_deref().unwrap_or(src).line_col(l.span.start))
    }

    /// The name of the file of the primary span: `src`'s, or the imported
    /// file's.
    pub fn primary_file<'a>(&'a self, src: &'a SourceFile) -> &'a str {
        match self.labels.iter().find(|l| l.primary) {
            Some(Label { file: Some(f), .. }) => f.name(),
            _ => src.name(),
        }
    }

    /// Moves the labels whose spans are in imported files (spans of the
    /// model's offset space, see [`SourceMap`]) into those files.
    #[must_use]
    pub fn locate(mut self, map: &SourceMap) -> Self {
        for l in &mut self.labels {
            if l.file.is_none()
                && let Some((file, span)) = map.locate(l.span)
            {
                l.file = Some(file);
                l.span = span;
            }
        }
        self
    }

    /// The diagnostic for codespan, with each label in its file: `src` is
    /// file 0 of `files`, imported files are added as labels need them.
    fn to_codespan(
        &self,
        src: &SourceFile,
        files: &mut SimpleFiles<String, String>,
        ids: &mut Vec<String>,
    ) -> cs::Diagnostic<usize> {
        let severity = match self.severity {
            Severity::Error => cs::Severity::Error,
            Severity::Warning => cs::Severity::Warning,
        };
        let labels = self
            .labels
            .iter()
            .map(|l| {
                let style = if l.primary {
                    cs::LabelStyle::Primary
                } else {
                    cs::LabelStyle::Secondary
                };
                let file = l.file.as_deref().unwrap_or(src);
                let id = match ids.iter().position(|n| n == file.name()) {
                    Some(id) => id,
                    None => {
                        ids.push(file.name().to_string());
                        files.add(file.name().to_string(), file.text().to_string())
                    }
                };
                let len = file.text().len();
                let start = l.span.start.min(len);
                let range = start..l.span.end.clamp(start, len);
                cs::Label::new(style, id, range).with_message(l.message.clone())
            })
            .collect();
        let mut notes = self.notes.clone();
        if let Some(h) = &self.help {
            notes.push(format!("help: {h}"));
        }
        cs::Diagnostic::new(severity)
            .with_code(self.code)
            .with_message(self.message.clone())
            .with_labels(labels)
            .with_notes(notes)
    }
}

/// `diag` as one JSON object for editors and scripts (`hybsim check
/// --message-format json`): `code`, `severity`, `message`, `file`, the
/// primary span's `line`/`column`/`end_line`/`end_column` (1-based; `null`
/// without a location), every `labels` entry with its own span, `notes` and
/// `help`.
pub fn to_json(diag: &Diagnostic, src: &SourceFile) -> serde_json::Value {
    use serde_json::json;
    let span_json = |l: &Label| {
        let f = l.file.as_deref().unwrap_or(src);
        let s = l.span;
        (f.line_col(s.start), f.line_col(s.end.max(s.start)))
    };
    let labels: Vec<serde_json::Value> = diag
        .labels
        .iter()
        .map(|l| {
            let (a, b) = span_json(l);
            let file = l.file.as_deref().unwrap_or(src).name();
            json!({
                "file": file, "line": a.line, "column": a.col, "end_line": b.line,
                "end_column": b.col, "message": l.message, "primary": l.primary,
            })
        })
        .collect();
    let primary = diag.labels.iter().find(|l| l.primary).map(span_json);
    json!({
        "code": diag.code,
        "severity": match diag.severity {
            Severity::Error => "error",
            Severity::Warning => "warning",
        },
        "message": diag.message,
        "file": diag.primary_file(src),
        "line": primary.map(|(a, _)| a.line),
        "column": primary.map(|(a, _)| a.col),
        "end_line": primary.map(|(_, b)| b.line),
        "end_column": primary.map(|(_, b)| b.col),
        "labels": labels,
        "notes": diag.notes,
        "help": diag.help,
    })
}

/// Renders `diags` against `src`: for each, `error[E0201]: message`, then
/// `┌─ file:line:col`, the source line with carets, notes and help. With
/// `color`, ANSI colour codes are included (for terminals).
pub fn render(diags: &[Diagnostic], src: &SourceFile, color: bool) -> String {
    let mut file = SimpleFiles::new();
    let mut ids = vec![src.name().to_string()];
    file.add(src.name().to_string(), src.text().to_string());
    let config = Config::default();
    let mut out = String::new();
    for d in diags {
        let cd = d.to_codespan(src, &mut file, &mut ids);
        if color {
            let mut buf = termcolor::Buffer::ansi();
            if term::emit_to_write_style(&mut buf, &config, &file, &cd).is_ok() {
                out.push_str(&String::from_utf8_lossy(buf.as_slice()));
                continue;
            }
        }
        if term::emit_to_string(&mut out, &config, &file, &cd).is_err() {
            // Rendering can only fail on spans outside the file, which
            // `to_codespan` clamps; fall back to a plain line regardless.
            out.push_str(&format!("error[{}]: {}\n", d.code, d.message));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renders_file_line_col_and_caret() {
        let src = SourceFile::new("ball.hyb", "model b\nstate h = x\n");
        let d = Diagnostic::error("E0201", "unknown name `x`")
            .primary(Span::new(18, 19), "not declared")
            .help("declare it with `param x = ...`");
        let text = render(&[d], &src, false);
        assert!(text.contains("error[E0201]: unknown name `x`"), "{text}");
        assert!(text.contains("ball.hyb:2:11"), "{text}");
        assert!(text.contains("state h = x"), "{text}");
        assert!(text.contains('^'), "{text}");
        assert!(text.contains("help: declare it"), "{text}");
    }

    #[test]
    fn json_has_the_primary_location_and_every_field() {
        let src = SourceFile::new("ball.hyb", "model b\nstate h = x\n");
        let d = Diagnostic::error("E0201", "unknown name `x`")
            .primary(Span::new(18, 19), "not declared")
            .note("names are declared before use")
            .help("declare it");
        let v = to_json(&d, &src);
        assert_eq!(v["code"], "E0201");
        assert_eq!(v["severity"], "error");
        assert_eq!(v["file"], "ball.hyb");
        assert_eq!(
            (v["line"].as_u64(), v["column"].as_u64()),
            (Some(2), Some(11))
        );
        assert_eq!(
            (v["end_line"].as_u64(), v["end_column"].as_u64()),
            (Some(2), Some(12))
        );
        assert_eq!(v["labels"][0]["message"], "not declared");
        assert_eq!(v["notes"][0], "names are declared before use");
        assert_eq!(v["help"], "declare it");
        let unlocated = to_json(&Diagnostic::warning("W0001", "w"), &src);
        assert!(unlocated["line"].is_null());
    }
}
