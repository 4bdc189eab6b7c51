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
        std::fs::create_dir_all(path).with_context(|| format!("--out {}", path.display()))?;
        // The mark comes first and stays: a run killed while it clears an
        // earlier run (as a resumed run does) leaves a folder still known as
        // a run's, never a half-emptied one that no later run will take.
        std::fs::write(path.join(MARK), b"")
            .with_context(|| format!("--out {}", path.display()))?;
        clear_all_but_mark(path, remove_entry)
            .with_context(|| format!("--out {}: cannot replace it", path.display()))?;
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

/// Removes every entry of `path` but the mark with `remove`, stopping at
/// the first that fails.
fn clear_all_but_mark(
    path: &Path,
    mut remove: impl FnMut(&Path) -> std::io::Result<()>,
) -> std::io::Result<()> {
    for entry in std::fs::read_dir(path)? {
        let entry = entry?.path();
        if entry.file_name() != Some(MARK.as_ref()) {
            remove(&entry)?;
        }
    }
    Ok(())
}

/// Removes a file or a whole folder; a link is removed, never followed.
fn remove_entry(entry: &Path) -> std::io::Result<()> {
    if entry.symlink_metadata()?.is_dir() {
        std::fs::remove_dir_all(entry)
    } else {
        std::fs::remove_file(entry)
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A scratch folder holding an earlier run, killed before it wrote any
    /// of its files but the mark: chunks and a status image.
    fn killed_run(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("depthmesh-out-dir-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("chunks")).unwrap();
        std::fs::write(dir.join("chunks/0.ply"), b"ply").unwrap();
        for file in [MARK, "status.png", "status.json", "dashboard.html"] {
            std::fs::write(dir.join(file), b"").unwrap();
        }
        dir
    }

    /// A scratch folder holding a finished earlier run: all its files.
    fn earlier_run(name: &str) -> PathBuf {
        let dir = killed_run(name);
        for file in RUN_FILES {
            std::fs::write(dir.join(file), b"").unwrap();
        }
        dir
    }

    #[test]
    fn a_replaced_run_leaves_only_the_new_runs_mark() {
        let dir = earlier_run("replaced");
        assert!(check(&dir, false).is_err());
        OutDir::prepare(&dir, true).unwrap().keep();
        let left: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(left, [MARK]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_replacement_cut_short_still_leaves_a_runs_folder() {
        // Stopped after each number of removals, as a killed run would be:
        // the folder is still an earlier run's, so the next run takes it.
        let counted = killed_run("count");
        let removals = std::fs::read_dir(&counted).unwrap().count() - 1;
        std::fs::remove_dir_all(&counted).unwrap();
        for allowed in 0..removals {
            let dir = killed_run(&format!("cut-{allowed}"));
            let mut removed = 0;
            let cut = clear_all_but_mark(&dir, |entry| {
                if removed == allowed {
                    return Err(std::io::Error::other("killed"));
                }
                removed += 1;
                remove_entry(entry)
            });
            assert!(cut.is_err(), "{allowed} removals finished the folder");
            let refused = check(&dir, false).unwrap_err().to_string();
            assert!(refused.contains("holds an earlier run"), "{refused}");
            OutDir::prepare(&dir, true).unwrap().keep();
            std::fs::remove_dir_all(&dir).unwrap();
        }
    }
}
