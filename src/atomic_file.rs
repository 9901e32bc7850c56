//! Output files that appear complete or not at all, and that never destroy
//! anything else.
//!
//! Every file hybsim writes (MCAP logs, CSV, SVG plots, `REPRODUCTION.md`)
//! goes through [`OutputFile`]. What happens depends on what the path names:
//!
//! | the path is | hybsim writes | on success | on failure, Ctrl-C, SIGTERM, SIGHUP, a panic |
//! |---|---|---|---|
//! | new, or a regular file with one link | a temporary file `.<name>.XXXXXX.tmp` in the same directory | renames it over the path | removes it; the old file is untouched |
//! | a regular file with several hard links | the same temporary file | copies it into the existing file (the links stay links) and removes it | removes it; the old file is untouched |
//! | a symbolic link | as above, for the file the link points to (followed to the end; the link stays) | | |
//! | a device, FIFO or socket (`/dev/null`, `/dev/stdout`, a named pipe) | directly, no temporary file, no rename | | what was written stays written |
//! | `-` | standard output, directly | | |
//! | a directory | nothing: an error | | |
//!
//! A new file gets the mode `0666` less the process's umask; a replaced file
//! keeps its mode (and, when run as root, its owner). SIGKILL (or a power
//! cut) cannot be caught: it leaves the old file untouched and may leave the
//! hidden `.<name>.XXXXXX.tmp` beside it, which is safe to delete.
//!
//! [`same_file`] tells whether two paths name the same file (following
//! links), so that a run can refuse an output path that is its model or
//! another output of the same run.

use std::fs::{self, File, OpenOptions};
use std::io::{self, Seek, SeekFrom, Write};
use std::os::unix::fs::{FileTypeExt, MetadataExt, PermissionsExt};
use std::path::{Component, Path, PathBuf};

use tempfile::NamedTempFile;

/// The path that means standard output.
pub const STDOUT: &str = "-";

/// Most symbolic links followed when resolving an output path (as Linux's
/// `MAXSYMLINKS`).
const MAX_LINKS: usize = 40;

/// A file being written; [`OutputFile::commit`] makes it appear at its
/// path. Dropping it without committing leaves the path as it was (for a
/// temporary file) and removes the temporary file.
#[derive(Debug)]
pub struct OutputFile {
    path: PathBuf,
    target: Target,
}

#[derive(Debug)]
enum Target {
    /// Written to `tmp`, then renamed (or, for hard links, copied) to `dest`.
    Temp {
        tmp: NamedTempFile,
        dest: PathBuf,
        in_place: bool,
    },
    /// A device, FIFO or socket, written as it goes; the bytes written so far.
    Direct(File, u64),
    /// Standard output; the bytes written so far.
    Stdout(io::Stdout, u64),
}

impl OutputFile {
    /// Opens an output at `path` (see the module documentation for what
    /// each kind of path means).
    pub fn create(path: &Path) -> io::Result<Self> {
        let target = if path.as_os_str() == STDOUT {
            Target::Stdout(io::stdout(), 0)
        } else {
            // `metadata` follows links (also the kernel's own, such as
            // `/dev/stdout` → `/proc/self/fd/1` → `pipe:[…]`).
            match fs::metadata(path) {
                Ok(meta) if meta.is_dir() => {
                    return Err(io::Error::new(
                        io::ErrorKind::IsADirectory,
                        "is a directory; give a file name",
                    ));
                }
                Ok(meta) if is_special(&meta.file_type()) => {
                    Target::Direct(OpenOptions::new().write(true).open(path)?, 0)
                }
                Ok(meta) => {
                    let dest = fs::canonicalize(path)?;
                    let tmp = temp_beside(&dest, Some(meta.mode() & 0o7777))?;
                    // Keep the owner of a file replaced by root (best effort:
                    // it fails, harmlessly, for anyone else).
                    let _ = std::os::unix::fs::fchown(
                        tmp.as_file(),
                        Some(meta.uid()),
                        Some(meta.gid()),
                    );
                    Target::Temp {
                        tmp,
                        dest,
                        in_place: meta.nlink() > 1,
                    }
                }
                Err(e) if e.kind() == io::ErrorKind::NotFound => {
                    // A new file, or a dangling link whose target is created.
                    let dest = resolve_links(path)?;
                    Target::Temp {
                        tmp: temp_beside(&dest, None)?,
                        dest,
                        in_place: false,
                    }
                }
                Err(e) => return Err(e),
            }
        };
        Ok(OutputFile {
            path: path.to_path_buf(),
            target,
        })
    }

    /// The path the file was opened with.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Flushes the data and makes the file appear at its path: renames the
    /// temporary file over it (or copies it into a hard-linked file). For
    /// devices, pipes and standard output this only flushes.
    pub fn commit(self) -> io::Result<()> {
        match self.target {
            Target::Temp {
                tmp,
                dest,
                in_place: false,
            } => {
                tmp.as_file().sync_all()?;
                tmp.persist(&dest).map(drop).map_err(|e| e.error)
            }
            Target::Temp {
                mut tmp,
                dest,
                in_place: true,
            } => {
                tmp.as_file_mut().seek(SeekFrom::Start(0))?;
                let mut out = OpenOptions::new().write(true).truncate(true).open(&dest)?;
                io::copy(tmp.as_file_mut(), &mut out)?;
                out.sync_all()?;
                Ok(())
            }
            Target::Direct(mut f, _) => f.flush(),
            Target::Stdout(mut s, _) => s.flush(),
        }
    }

    /// Whether [`Seek`] can move backwards: true for files written through
    /// a temporary file, false for devices, pipes and standard output
    /// (formats that seek to patch headers must then do without).
    pub fn seekable(&self) -> bool {
        matches!(self.target, Target::Temp { .. })
    }
}

impl Write for OutputFile {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        match &mut self.target {
            Target::Temp { tmp, .. } => tmp.as_file_mut().write(buf),
            Target::Direct(f, pos) => {
                let n = f.write(buf)?;
                *pos += n as u64;
                Ok(n)
            }
            Target::Stdout(s, pos) => {
                let n = s.write(buf)?;
                *pos += n as u64;
                Ok(n)
            }
        }
    }

    fn flush(&mut self) -> io::Result<()> {
        match &mut self.target {
            Target::Temp { tmp, .. } => tmp.as_file_mut().flush(),
            Target::Direct(f, _) => f.flush(),
            Target::Stdout(s, _) => s.flush(),
        }
    }
}

/// Seeking works anywhere in the temporary file (regular outputs). On
/// devices, pipes and standard output only the current position can be
/// asked (`SeekFrom::Current(0)`, or a seek to where the stream is);
/// anything else is `Unsupported`.
impl Seek for OutputFile {
    fn seek(&mut self, to: SeekFrom) -> io::Result<u64> {
        match &mut self.target {
            Target::Temp { tmp, .. } => tmp.as_file_mut().seek(to),
            Target::Direct(_, pos) | Target::Stdout(_, pos) => match to {
                SeekFrom::Current(0) => Ok(*pos),
                SeekFrom::Start(p) if p == *pos => Ok(*pos),
                _ => Err(io::Error::new(
                    io::ErrorKind::Unsupported,
                    "cannot seek in a device, pipe or standard output",
                )),
            },
        }
    }
}

/// Opens the output at `path` (shorthand for [`OutputFile::create`]).
pub fn create(path: &Path) -> io::Result<OutputFile> {
    OutputFile::create(path)
}

/// Makes `file` appear at its path (shorthand for [`OutputFile::commit`];
/// `_path` is the path it was created with).
pub fn commit(file: OutputFile, _path: &Path) -> io::Result<()> {
    file.commit()
}

/// Writes `bytes` to `path` as one output file.
pub fn write(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let mut file = OutputFile::create(path)?;
    file.write_all(bytes)?;
    file.commit()
}

/// Whether `a` and `b` name the same file: the same inode when both exist
/// (links followed), else the same absolute path after following links of
/// the parts that exist. `-` (standard output) is the same only as `-`.
pub fn same_file(a: &Path, b: &Path) -> bool {
    let stdout = |p: &Path| p.as_os_str() == STDOUT;
    if stdout(a) || stdout(b) {
        return stdout(a) && stdout(b);
    }
    if let (Ok(ma), Ok(mb)) = (fs::metadata(a), fs::metadata(b)) {
        return ma.dev() == mb.dev() && ma.ino() == mb.ino();
    }
    match (absolute_resolved(a), absolute_resolved(b)) {
        (Some(x), Some(y)) => x == y,
        _ => false,
    }
}

/// The first output that would overwrite an input or an earlier output, as
/// a sentence: `inputs` and `outputs` are (what it is, path) pairs, e.g.
/// `("the model", "m.hyb")` and `("--csv", "out.csv")`.
pub fn clash(inputs: &[(&str, &Path)], outputs: &[(&str, &Path)]) -> Option<String> {
    for (k, (flag, path)) in outputs.iter().enumerate() {
        for (what, input) in inputs {
            if same_file(path, input) {
                return Some(format!(
                    "`{flag} {}` would overwrite {what} `{}`; choose another output path",
                    path.display(),
                    input.display()
                ));
            }
        }
        // Several outputs may go to one device (`/dev/null`), not to one file.
        let device = fs::metadata(path).is_ok_and(|m| is_special(&m.file_type()));
        for (other, earlier) in &outputs[..k] {
            if !device && same_file(path, earlier) {
                return Some(format!(
                    "`{flag} {}` and `{other} {}` are the same file; give each output its own path",
                    path.display(),
                    earlier.display()
                ));
            }
        }
    }
    None
}

fn is_special(ft: &fs::FileType) -> bool {
    ft.is_char_device() || ft.is_block_device() || ft.is_fifo() || ft.is_socket()
}

/// `path` with symbolic links in its last component followed to the file
/// they finally name (which need not exist yet).
fn resolve_links(path: &Path) -> io::Result<PathBuf> {
    let mut p = path.to_path_buf();
    for _ in 0..MAX_LINKS {
        match fs::symlink_metadata(&p) {
            Ok(m) if m.file_type().is_symlink() => {
                let link = fs::read_link(&p)?;
                p = if link.is_absolute() {
                    link
                } else {
                    parent_dir(&p).join(link)
                };
            }
            _ => return Ok(p),
        }
    }
    Err(io::Error::other(format!(
        "more than {MAX_LINKS} symbolic links to follow"
    )))
}

/// The directory of `path` (`.` for a bare file name).
fn parent_dir(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// The absolute form of `path` with links followed where they exist.
fn absolute_resolved(path: &Path) -> Option<PathBuf> {
    let p = resolve_links(path).ok()?;
    if let Ok(c) = fs::canonicalize(&p) {
        return Some(c);
    }
    let name = p.file_name()?;
    if matches!(p.components().next_back(), Some(Component::ParentDir)) {
        return None;
    }
    Some(fs::canonicalize(parent_dir(&p)).ok()?.join(name))
}

/// A temporary file in `dest`'s directory named after it, with `mode`
/// (an existing file's) or `0666` less the umask.
fn temp_beside(dest: &Path, mode: Option<u32>) -> io::Result<NamedTempFile> {
    let name = dest
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = tempfile::Builder::new()
        .prefix(&format!(".{name}."))
        .suffix(".tmp")
        .permissions(fs::Permissions::from_mode(0o666))
        .tempfile_in(parent_dir(dest))
        .map_err(without_path)?;
    if let Some(mode) = mode {
        tmp.as_file()
            .set_permissions(fs::Permissions::from_mode(mode))?;
    }
    Ok(tmp)
}

/// `tempfile`'s error without the path it appends (`… at path
/// "dir/.x.csv.7co0Ld.tmp"`; its wrapper is private, so by its text):
/// callers name the file asked for, and the temporary file's random name
/// would make the message differ per run.
fn without_path(e: io::Error) -> io::Error {
    let text = e.to_string();
    match text.split_once(" at path \"") {
        Some((message, _)) if e.get_ref().is_some() => io::Error::new(e.kind(), message),
        _ => e,
    }
}

#[cfg(test)]
mod tests {
    use std::os::unix::fs::symlink;

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
        let out = create(Path::new("hybsim-atomic-file-test.tmpcheck")).unwrap();
        drop(out);
        assert!(!Path::new("hybsim-atomic-file-test.tmpcheck").exists());
    }

    #[test]
    fn symlink_is_kept_and_its_target_written() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("real.txt");
        let link = dir.path().join("link.txt");
        std::fs::write(&target, b"old").unwrap();
        symlink("real.txt", &link).unwrap();
        write(&link, b"new").unwrap();
        assert!(
            std::fs::symlink_metadata(&link)
                .unwrap()
                .file_type()
                .is_symlink()
        );
        assert_eq!(std::fs::read(&target).unwrap(), b"new");
        // A dangling link creates its target.
        let dangling = dir.path().join("dangling.txt");
        symlink("made.txt", &dangling).unwrap();
        write(&dangling, b"made").unwrap();
        assert_eq!(std::fs::read(dir.path().join("made.txt")).unwrap(), b"made");
        assert_eq!(
            names(dir.path()),
            ["dangling.txt", "link.txt", "made.txt", "real.txt"]
        );
    }

    #[test]
    fn hard_links_stay_links() {
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("a.txt");
        let b = dir.path().join("b.txt");
        std::fs::write(&a, b"old contents").unwrap();
        std::fs::hard_link(&a, &b).unwrap();
        write(&a, b"new").unwrap();
        assert_eq!(std::fs::read(&b).unwrap(), b"new");
        assert_eq!(std::fs::metadata(&a).unwrap().nlink(), 2);
        assert_eq!(names(dir.path()), ["a.txt", "b.txt"]);
    }

    #[test]
    fn modes_follow_the_umask_or_the_old_file() {
        let dir = tempfile::tempdir().unwrap();
        let old = dir.path().join("old.txt");
        std::fs::write(&old, b"x").unwrap();
        std::fs::set_permissions(&old, fs::Permissions::from_mode(0o640)).unwrap();
        write(&old, b"y").unwrap();
        assert_eq!(std::fs::metadata(&old).unwrap().mode() & 0o777, 0o640);
        // A new file: 0666 less the umask, read back from a file the OS creates.
        let probe = dir.path().join("probe");
        std::fs::File::create(&probe).unwrap();
        let expected = std::fs::metadata(&probe).unwrap().mode() & 0o777;
        let new = dir.path().join("new.txt");
        write(&new, b"z").unwrap();
        assert_eq!(std::fs::metadata(&new).unwrap().mode() & 0o777, expected);
    }

    #[test]
    fn devices_and_fifos_are_written_directly() {
        write(Path::new("/dev/null"), b"nothing").unwrap();
        assert!(
            std::fs::metadata("/dev/null")
                .unwrap()
                .file_type()
                .is_char_device()
        );
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("pipe");
        let status = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(status.success());
        let reader = {
            let fifo = fifo.clone();
            std::thread::spawn(move || std::fs::read(fifo).unwrap())
        };
        write(&fifo, b"through the pipe").unwrap();
        assert_eq!(reader.join().unwrap(), b"through the pipe");
        assert!(std::fs::metadata(&fifo).unwrap().file_type().is_fifo());
        assert_eq!(names(dir.path()), ["pipe"]);
    }

    #[test]
    fn directories_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let e = create(dir.path()).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::IsADirectory);
    }

    #[test]
    fn same_file_sees_links_and_relative_paths() {
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("a.txt");
        std::fs::write(&a, b"x").unwrap();
        let link = dir.path().join("l.txt");
        symlink(&a, &link).unwrap();
        assert!(same_file(&a, &link));
        assert!(same_file(&a, &dir.path().join(".").join("a.txt")));
        let new = dir.path().join("new.mcap");
        assert!(same_file(&new, &dir.path().join(".").join("new.mcap")));
        assert!(!same_file(&new, &a));
        assert!(same_file(Path::new("-"), Path::new("-")));
        assert!(!same_file(Path::new("-"), &a));
    }

    #[test]
    fn clashes_name_both_sides() {
        let dir = tempfile::tempdir().unwrap();
        let model = dir.path().join("m.hyb");
        std::fs::write(&model, b"model m").unwrap();
        let out = dir.path().join("m.mcap");
        let dot_model = dir.path().join(".").join("m.hyb");
        let e = clash(
            &[("the model", &model)],
            &[("-o", &out), ("--csv", &dot_model)],
        )
        .unwrap();
        assert!(
            e.contains("--csv") && e.contains("would overwrite the model"),
            "{e}"
        );
        let e = clash(&[("the model", &model)], &[("-o", &out), ("--csv", &out)]).unwrap();
        assert!(e.contains("same file"), "{e}");
        let null = Path::new("/dev/null");
        assert_eq!(
            clash(&[("the model", &model)], &[("-o", null), ("--csv", null)]),
            None
        );
        assert!(clash(&[], &[("-o", Path::new("-")), ("--csv", Path::new("-"))]).is_some());
    }
}
