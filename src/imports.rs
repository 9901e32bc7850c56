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
    #[error("import `{path}` is not allowed: {why}")]
    NotAllowed {
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
            ImportError::NotAllowed { span, .. } => d("E0801")
                .primary(*span, "not allowed")
                .help("import files by a relative path inside the model's folder, e.g. `import \"lib/zoh.hyb\"`"),
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
        root: Path::new(src.name())
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_default(),
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

fn canonical(p: &Path) -> PathBuf {
    std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf())
}

impl Resolver {
    /// Reads the imports of a file at `dir` (relative to the root).
    fn file(&mut self, dir: &Path, imports: &[(String, Span)]) {
        for (path, span) in imports {
            let Some(rel) = self.check(dir, path, *span) else {
                continue;
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
            // A symbolic link may lead out of the folder.
            if let (Ok(root), Ok(_)) = (std::fs::canonicalize(self.root_dir()), canon.metadata())
                && !canon.starts_with(&root)
            {
                self.errors.push(ImportError::NotAllowed {
                    path: path.clone(),
                    why: "it leads out of the model's folder (through a link)".into(),
                    span: *span,
                });
                continue;
            }
            let text = match std::fs::read_to_string(&full) {
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

    fn root_dir(&self) -> &Path {
        if self.root.as_os_str().is_empty() {
            Path::new(".")
        } else {
            &self.root
        }
    }

    /// The path relative to the root, or an error: absolute paths, URLs and
    /// paths above the root are refused.
    fn check(&mut self, dir: &Path, path: &str, span: Span) -> Option<PathBuf> {
        let refuse = |why: &str| ImportError::NotAllowed {
            path: path.to_string(),
            why: why.to_string(),
            span,
        };
        if path.contains("://") || path.starts_with("file:") {
            self.errors
                .push(refuse("a URL (only files beside the model)"));
            return None;
        }
        let p = Path::new(path);
        if path.is_empty() {
            self.errors.push(refuse("the path is empty"));
            return None;
        }
        if p.is_absolute() || path.starts_with('/') || path.starts_with('\\') || p.has_root() {
            self.errors
                .push(refuse("an absolute path (write it relative to the model)"));
            return None;
        }
        let mut rel = PathBuf::new();
        for c in dir.join(p).components() {
            match c {
                Component::Normal(s) => rel.push(s),
                Component::CurDir => {}
                Component::ParentDir => {
                    if !rel.pop() {
                        self.errors
                            .push(refuse("it leads out of the model's folder (`..`)"));
                        return None;
                    }
                }
                Component::RootDir | Component::Prefix(_) => {
                    self.errors.push(refuse("an absolute path"));
                    return None;
                }
            }
        }
        Some(rel)
    }
}
