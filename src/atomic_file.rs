//! Files that appear complete or not at all.
//!
//! Every file hybsim writes (MCAP logs, CSV, SVG plots, `REPRODUCTION.md`)
//! is first written to a uniquely named temporary file in the destination's
//! directory (`.<name>.XXXXXX.tmp`), synced, and renamed over the
//! destination only when complete. A writer that fails or is dropped early
//! (an error, Ctrl-C, a panic) leaves the previous file untouched and no
//! temporary file behind: [`tempfile::NamedTempFile`] removes itself on drop.

use std::io::{self, Write};
use std::path::Path;

use tempfile::NamedTempFile;

/// Creates the temporary file that [`commit`] will rename to `path`.
pub(crate) fn create(path: &Path) -> io::Result<NamedTempFile> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    tempfile::Builder::new()
        .prefix(&format!(".{name}."))
        .suffix(".tmp")
        .tempfile_in(dir)
}

/// Syncs `file` and renames it to `path`, replacing any previous file.
pub(crate) fn commit(file: NamedTempFile, path: &Path) -> io::Result<()> {
    file.as_file().sync_all()?;
    file.persist(path).map(drop).map_err(|e| e.error)
}

/// Writes `bytes` to `path` through a temporary file.
pub(crate) fn write(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let mut file = create(path)?;
    file.write_all(bytes)?;
    commit(file, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn commit_replaces_and_leaves_nothing_else() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.txt");
        write(&path, b"first").unwrap();
        write(&path, b"second").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"second");
        assert_eq!(names(dir.path()), ["out.txt"]);
    }

    #[test]
    fn dropped_file_is_removed_and_old_file_kept() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.txt");
        write(&path, b"old").unwrap();
        {
            let mut tmp = create(&path).unwrap();
            tmp.write_all(b"partial").unwrap();
            let listed = names(dir.path());
            assert_eq!(listed.len(), 2, "{listed:?}");
            assert!(listed[0].starts_with(".out.txt.") && listed[0].ends_with(".tmp"));
        }
        assert_eq!(names(dir.path()), ["out.txt"]);
        assert_eq!(std::fs::read(&path).unwrap(), b"old");
    }

    #[test]
    fn bare_file_name_uses_current_directory() {
        // `Path::new("x.mcap").parent()` is `Some("")`, which must mean ".".
        let tmp = create(Path::new("hybsim-atomic-file-test.tmpcheck")).unwrap();
        assert!(tmp.path().exists());
    }
}
