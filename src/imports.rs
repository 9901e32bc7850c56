//! `import "lib/zoh.hyb"`: the subsystems of other files.
//!
//! A path is relative to the importing file and must stay inside the folder
//! of the model being compiled (its root): no absolute paths, no URLs, no
//! `..` above the root (also not through a symbolic link). An imported file
//! holds `import` and `subsystem` declarations only; each file is read once
//! (a file imported twice brings its subsystems once) and a cycle of
//! imports is an error. Imported files are placed in the model's offset
//! space ([`SourceMap`]): every span of their AST, and of their syntax
//! errors, names its file, so diagnostics point into the right file.

use std::path::{Component, Path, PathBuf};

use crate::diagnostics::Diagnostic;
use crate::source::{SourceFile, SourceMap, Span};
use crate::syntax::ast::{Item, Model};
use crate::syntax::{SyntaxError, parse_library};

/// Why an import failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ImportError {
    /// An absolute path, a URL, or a path leaving the model's folder.
    #[error("{kind} `{path}` is not allowed: {why}")]
    NotAllowed {
        /// What names the file: `import` or `table`.
        kind: &'static str,
        /// The path as written.
        path: String,
        /// Why, in words.
        why: String,
        /// The string literal.
        span: Span,
    },
    /// The file cannot be read.
    #[error("cannot read `{path}` ({resolved}): {reason}")]
    Unreadable {
        /// The path as written.
        path: String,
        /// The path it resolves to.
        resolved: String,
        /// The system's reason.
        reason: String,
        /// The string literal.
        span: Span,
    },
    /// Files importing each other.
    #[error("import cycle: {}", chain.join(" → "))]
    Cycle {
        /// The files from the first back to it.
        chain: Vec<String>,
        /// The import that closes the cycle.
        span: Span,
    },
    /// A syntax error in an imported file.
    #[error(transparent)]
    Syntax(#[from] SyntaxError),
}

impl ImportError {
    /// The error as a diagnostic (codes E0801 not allowed, E0802 cannot
    /// read, E0803 cycle; syntax errors keep their E01xx code).
    pub fn to_diagnostic(&self) -> Diagnostic {
        let d = |code| Diagnostic::error(code, self.to_string());
        match self {
            ImportError::NotAllowed { span, kind, .. } => d("E0801")
                .primary(*span, "not allowed")
                .help(if *kind == "table" {
                    "name data files by a relative path inside the model's folder, e.g. `table(\"data/timers.csv\")`"
                } else {
                    "import files by a relative path inside the model's folder, e.g. `import \"lib/zoh.hyb\"`"
                }),
            ImportError::Unreadable { span, .. } => d("E0802")
                .primary(*span, "cannot be read")
                .help("paths are relative to the importing file"),
            ImportError::Cycle { span, .. } => d("E0803")
                .primary(*span, "this import closes the cycle")
                .help("files cannot import each other; move the shared subsystems to a third file"),
            ImportError::Syntax(e) => e.to_diagnostic(),
        }
    }
}

/// Reads the files `model` imports (transitively) and appends their
/// subsystem declarations to it; returns the map of the imported files.
/// `src` is the model's source; its name is its path.
pub fn resolve(src: &SourceFile, model: &mut Model) -> Result<SourceMap, Vec<Diagnostic>> {
    let mut r = Resolver {
        root: model_root(src),
        map: SourceMap::default(),
        model_len: src.text().len(),
        stack: vec![canonical(Path::new(src.name()))],
        loaded: Vec::new(),
        items: Vec::new(),
        errors: Vec::new(),
    };
    let imports: Vec<(String, Span)> = imports_of(&model.items);
    if imports.is_empty() {
        return Ok(r.map);
    }
    r.file(Path::new(""), &imports);
    if !r.errors.is_empty() {
        let map = r.map;
        return Err(r
            .errors
            .iter()
            .map(|e| e.to_diagnostic().locate(&map))
            .collect());
    }
    model.items.append(&mut r.items);
    Ok(r.map)
}

struct Resolver {
    /// The model's folder.
    root: PathBuf,
    map: SourceMap,
    model_len: usize,
    /// Canonical paths of the files being read, the model first.
    stack: Vec<PathBuf>,
    /// Canonical paths of the files read.
    loaded: Vec<PathBuf>,
    items: Vec<Item>,
    errors: Vec<ImportError>,
}

fn imports_of(items: &[Item]) -> Vec<(String, Span)> {
    items
        .iter()
        .filter_map(|it| match it {
            Item::Import(i) => Some((i.path.clone(), i.span)),
            _ => None,
        })
        .collect()
}

impl Resolver {
    /// Reads the imports of a file at `dir` (relative to the root).
    fn file(&mut self, dir: &Path, imports: &[(String, Span)]) {
        for (path, span) in imports {
            let rel = match relative_path(dir, path, *span, "import") {
                Ok(rel) => rel,
                Err(e) => {
                    self.errors.push(e);
                    continue;
                }
            };
            let full = self.root.join(&rel);
            let canon = canonical(&full);
            if let Some(pos) = self.stack.iter().position(|p| *p == canon) {
                let mut chain: Vec<String> = self.stack[pos..]
                    .iter()
                    .map(|p| p.display().to_string())
                    .collect();
                chain.push(canon.display().to_string());
                self.errors.push(ImportError::Cycle { chain, span: *span });
                continue;
            }
            if self.loaded.contains(&canon) {
                continue;
            }
            if let Err(e) = inside_root(&self.root, &canon, path, *span, "import") {
                self.errors.push(e);
                continue;
            }
            let text = match std::fs::File::open(&full).and_then(crate::source::read_text) {
                Ok(t) => t,
                Err(e) => {
                    self.errors.push(ImportError::Unreadable {
                        path: path.clone(),
                        resolved: full.display().to_string(),
                        reason: e.to_string(),
                        span: *span,
                    });
                    continue;
                }
            };
            self.loaded.push(canon.clone());
            let base = self.map.next_base(self.model_len);
            // Parsed at its place in the offset space (preceded by blanks),
            // so that every span of the AST and of a syntax error is global.
            let items = parse_library(&format!("{}{text}", " ".repeat(base)));
            self.map
                .push(base, SourceFile::new(full.display().to_string(), text));
            let items = match items {
                Ok(items) => items,
                Err(e) => {
                    self.errors.push(e.into());
                    continue;
                }
            };
            let nested = imports_of(&items);
            self.stack.push(canon);
            let sub = rel.parent().map(Path::to_path_buf).unwrap_or_default();
            self.file(&sub, &nested);
            self.stack.pop();
            self.items.extend(
                items
                    .into_iter()
                    .filter(|it| matches!(it, Item::Subsystem(_))),
            );
        }
    }
}

/// The path `path` (as written in a file at `dir`, relative to the model's
/// folder) relative to the model's folder, or an error: absolute paths,
/// URLs and paths above the folder are refused. `kind` names what uses the
/// path (`import`, `table`) in the message.
pub(crate) fn relative_path(
    dir: &Path,
    path: &str,
    span: Span,
    kind: &'static str,
) -> Result<PathBuf, ImportError> {
    let refuse = |why: &str| ImportError::NotAllowed {
        kind,
        path: path.to_string(),
        why: why.to_string(),
        span,
    };
    if path.contains("://") || path.starts_with("file:") {
        return Err(refuse("a URL (only files beside the model)"));
    }
    let p = Path::new(path);
    if path.is_empty() {
        return Err(refuse("the path is empty"));
    }
    if p.is_absolute() || path.starts_with('/') || path.starts_with('\\') || p.has_root() {
        return Err(refuse("an absolute path (write it relative to the model)"));
    }
    let mut rel = PathBuf::new();
    for c in dir.join(p).components() {
        match c {
            Component::Normal(s) => rel.push(s),
            Component::CurDir => {}
            Component::ParentDir => {
                if !rel.pop() {
                    return Err(refuse("it leads out of the model's folder (`..`)"));
                }
            }
            Component::RootDir | Component::Prefix(_) => return Err(refuse("an absolute path")),
        }
    }
    Ok(rel)
}

/// Refuses an existing file `canon` (canonical) outside the model's folder
/// `root`: a symbolic link may lead out of it.
pub(crate) fn inside_root(
    root: &Path,
    canon: &Path,
    path: &str,
    span: Span,
    kind: &'static str,
) -> Result<(), ImportError> {
    let root = if root.as_os_str().is_empty() {
        Path::new(".")
    } else {
        root
    };
    if let (Ok(root), Ok(_)) = (std::fs::canonicalize(root), canon.metadata())
        && !canon.starts_with(&root)
    {
        return Err(ImportError::NotAllowed {
            kind,
            path: path.to_string(),
            why: "it leads out of the model's folder (through a link)".into(),
            span,
        });
    }
    Ok(())
}

/// The model's folder (empty for a model named without a folder: the
/// current one).
pub(crate) fn model_root(src: &SourceFile) -> PathBuf {
    Path::new(src.name())
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_default()
}

/// The canonical form of `p` (itself if it cannot be resolved).
pub(crate) fn canonical(p: &Path) -> PathBuf {
    std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf())
}
