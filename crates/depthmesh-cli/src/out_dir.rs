//! The output folder of a mapping run: one run per folder. A new or empty
//! folder is used as it is; a folder that holds an earlier run is replaced
//! only with `--force` (and anything else is never deleted); a run that
//! fails removes what it created, so no folder is left empty or mixed.

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};

/// Files by which a folder is known to hold a run's output.
const RUN_FILES: &[&str] = &[
    MARK,
    "summary.json",
    "mesh.ply",
    "stats.csv",
    "trajectory.txt",
];

/// An empty file made first in every run's folder: a run killed before it
/// wrote any of its files (say, to continue it from its store) still left a
/// folder known as a run's.
const MARK: &str = ".depthmesh-run";

/// A run's output folder, removed again unless [`OutDir::keep`] is called.
#[derive(Debug)]
pub struct OutDir {
    path: PathBuf,
    kept: bool,
}

/// Checks that `path` can take a run: new, empty, or (with `force`) an
/// earlier run's folder. Nothing is changed.
pub fn check(path: &Path, force: bool) -> Result<()> {
    if !path.exists() {
        return Ok(());
    }
    if !path.is_dir() {
        bail!("--out {}: exists and is not a folder", path.display());
    }
    let mut entries =
        std::fs::read_dir(path).with_context(|| format!("--out {}", path.display()))?;
    if entries.next().is_none() {
        return Ok(());
    }
    let is_run = RUN_FILES.iter().any(|f| path.join(f).exists());
    match (is_run, force) {
        (true, true) => Ok(()),
        (true, false) => bail!(
            "--out {} holds an earlier run: choose a new folder, or pass --force to replace it",
            path.display()
        ),
        (false, _) => bail!(
            "--out {} holds files that are not a run's: choose a new or empty folder",
            path.display()
        ),
    }
}

impl OutDir {
    /// Prepares `path` for a run (see [`check`]): an earlier run there is
    /// removed whole, so none of its files (status images, dashboards,
    /// chunks) stays beside the new run's.
    pub fn prepare(path: &Path, force: bool) -> Result<Self> {
        check(path, force)?;
        if path.exists() {
            std::fs::remove_dir_all(path)
                .with_context(|| format!("--out {}: cannot replace it", path.display()))?;
        }
        std::fs::create_dir_all(path).with_context(|| format!("--out {}", path.display()))?;
        std::fs::write(path.join(MARK), b"")
            .with_context(|| format!("--out {}", path.display()))?;
        Ok(OutDir {
            path: path.to_path_buf(),
            kept: false,
        })
    }

    /// The run finished: its files stay.
    pub fn keep(mut self) {
        self.kept = true;
    }
}

impl Drop for OutDir {
    fn drop(&mut self) {
        if !self.kept {
            // The folder was new or emptied for this run: all of it is the
            // failed run's. Nothing to report if it cannot go.
            let _ = std::fs::remove_dir_all(&self.path);
        }
    }
}
