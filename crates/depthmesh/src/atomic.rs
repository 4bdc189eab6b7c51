//! Writing files so that readers only ever see the old content or the complete new one.

use crate::error::{Error, Result};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Distinguishes temporary files of concurrent writers in one process; the
/// process id alone would let two threads writing the same target collide.
static SEQUENCE: AtomicU64 = AtomicU64::new(0);

/// Writes `path` by running `f` on a buffered temporary file in the same
/// directory, syncing it, renaming it over `path` and syncing the directory,
/// so that once this returns the new file survives a crash or power cut.
///
/// The temporary file is hidden and named after the target and the process, so
/// a crash leaves a recognisable leftover rather than a truncated target. On
/// any failure (including one returned by `f`) the temporary file is removed,
/// `path` keeps whatever it held before, and the error names `path`.
pub fn write_atomic<F>(path: &Path, f: F) -> Result<()>
where
    F: FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
{
    let temp = temp_path(path).map_err(|e| Error::io(path, e))?;
    let result = write_then_rename(&temp, path, f);
    if result.is_err() {
        // The original error matters more than a failure to tidy up.
        let _ = std::fs::remove_file(&temp);
    }
    result.map_err(|e| Error::io(path, e))
}

fn temp_path(path: &Path) -> std::io::Result<PathBuf> {
    let name = path
        .file_name()
        .ok_or_else(|| std::io::Error::new(std::io::ErrorKind::InvalidInput, "not a file name"))?;
    let mut temp_name = std::ffi::OsString::from(".");
    temp_name.push(name);
    temp_name.push(format!(
        ".{}.{}.tmp",
        std::process::id(),
        SEQUENCE.fetch_add(1, Ordering::Relaxed)
    ));
    // Same directory as the target, because a rename across file systems is a copy.
    Ok(path.with_file_name(temp_name))
}

fn write_then_rename<F>(temp: &Path, path: &Path, f: F) -> std::io::Result<()>
where
    F: FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
{
    let mut writer = BufWriter::new(File::create(temp)?);
    f(&mut writer)?;
    writer.flush()?;
    let file = writer.into_inner().map_err(|e| e.into_error())?;
    // Without this the rename can reach the disk before the data, and a power
    // cut would leave an empty file under the target's name.
    file.sync_all()?;
    drop(file);
    std::fs::rename(temp, path)?;
    sync_directory(path)
}

/// Makes the rename of `path` durable: a rename is an entry in the
/// directory, which the file's own sync does not write, so without this a
/// power cut soon after could leave the old file (or none) under the name.
#[cfg(unix)]
fn sync_directory(path: &Path) -> std::io::Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    File::open(dir)?.sync_all()
}

/// Elsewhere a directory cannot be opened to be synced; the rename stands
/// as the file system makes it durable.
#[cfg(not(unix))]
fn sync_directory(_path: &Path) -> std::io::Result<()> {
    Ok(())
}

/// Scratch directories for tests, removed when dropped.
#[cfg(test)]
pub(crate) mod scratch {
    use std::path::{Path, PathBuf};
    use std::sync::atomic::{AtomicU64, Ordering};

    static NEXT: AtomicU64 = AtomicU64::new(0);

    /// A fresh, empty directory under the system temporary directory.
    pub(crate) struct ScratchDir(PathBuf);

    impl ScratchDir {
        /// Tests run in parallel threads and possibly several processes, so the
        /// name carries the tag, the process id and a counter.
        pub(crate) fn new(tag: &str) -> Self {
            let dir = std::env::temp_dir().join(format!(
                "depthmesh-test-{tag}-{}-{}",
                std::process::id(),
                NEXT.fetch_add(1, Ordering::Relaxed)
            ));
            let _ = std::fs::remove_dir_all(&dir);
            std::fs::create_dir_all(&dir).expect("create scratch dir");
            ScratchDir(dir)
        }

        pub(crate) fn path(&self) -> &Path {
            &self.0
        }

        /// Names of the entries in the directory, sorted.
        pub(crate) fn entries(&self) -> Vec<String> {
            let mut names: Vec<String> = std::fs::read_dir(&self.0)
                .expect("list scratch dir")
                .map(|e| {
                    e.expect("dir entry")
                        .file_name()
                        .to_string_lossy()
                        .into_owned()
                })
                .collect();
            names.sort();
            names
        }
    }

    impl Drop for ScratchDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::scratch::ScratchDir;
    use super::*;
    use std::io::ErrorKind;

    #[test]
    fn writes_new_file_and_leaves_no_temp() {
        let dir = ScratchDir::new("atomic-new");
        let path = dir.path().join("out.txt");
        write_atomic(&path, |w| w.write_all(b"hello")).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"hello");
        assert_eq!(dir.entries(), vec!["out.txt".to_string()]);
    }

    #[test]
    fn replaces_existing_file() {
        let dir = ScratchDir::new("atomic-replace");
        let path = dir.path().join("out.txt");
        std::fs::write(&path, b"old content that is longer").unwrap();
        write_atomic(&path, |w| w.write_all(b"new")).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"new");
        assert_eq!(dir.entries(), vec!["out.txt".to_string()]);
    }

    #[test]
    fn failing_closure_creates_nothing() {
        let dir = ScratchDir::new("atomic-fail-new");
        let path = dir.path().join("out.txt");
        let err = write_atomic(&path, |w| {
            w.write_all(b"partial")?;
            Err(std::io::Error::other("generator broke"))
        })
        .unwrap_err();
        let message = err.to_string();
        assert!(message.contains("out.txt"), "{message}");
        assert!(message.contains("generator broke"), "{message}");
        assert!(dir.entries().is_empty(), "{:?}", dir.entries());
    }

    #[test]
    fn failing_closure_keeps_existing_file() {
        let dir = ScratchDir::new("atomic-fail-keep");
        let path = dir.path().join("out.txt");
        std::fs::write(&path, b"good").unwrap();
        let err = write_atomic(&path, |w| {
            // Larger than the buffer, so part of it really reaches the temp file.
            w.write_all(&vec![b'x'; 100_000])?;
            Err(std::io::Error::new(ErrorKind::InvalidData, "bad data"))
        })
        .unwrap_err();
        assert!(matches!(err, Error::Io { .. }));
        assert_eq!(std::fs::read(&path).unwrap(), b"good");
        assert_eq!(dir.entries(), vec!["out.txt".to_string()]);
    }

    #[test]
    fn missing_directory_is_an_io_error_naming_the_path() {
        let dir = ScratchDir::new("atomic-nodir");
        let path = dir.path().join("no-such-dir").join("out.txt");
        let err = write_atomic(&path, |w| w.write_all(b"x")).unwrap_err();
        assert!(err.to_string().contains("no-such-dir"), "{err}");
        assert!(dir.entries().is_empty());
    }

    #[test]
    fn path_without_file_name_is_rejected() {
        let err = write_atomic(Path::new("/"), |w| w.write_all(b"x")).unwrap_err();
        assert!(matches!(err, Error::Io { .. }));
    }
}
