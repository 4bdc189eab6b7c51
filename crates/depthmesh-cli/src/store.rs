//! `--store`, `--checkpoint-every`, `--resume`: a run that writes its map to
//! a store as it goes and can continue after a crash (see
//! [`depthmesh::store`]).

use anyhow::{bail, Context, Result};
use clap::Args;
use depthmesh::dataset::Dataset;
use depthmesh::session::{Session, SessionConfig};
use depthmesh::store::checkpoints::{self, Checkpoints};
use serde_json::{json, Map, Value};
use std::path::{Path, PathBuf};

/// The store flags.
#[derive(Args, Debug, Clone)]
pub struct StoreArgs {
    /// Write the map to this store (one file) in checkpoints, to continue
    /// it with --resume after a crash (tsdf, planes and mabdi maps). With
    /// --active-radius, blocks the camera leaves go to the store and come
    /// back when it returns.
    #[arg(long)]
    pub store: Option<PathBuf>,
    /// Commit a checkpoint every this many frames (about a second of a 30
    /// frames/s sensor).
    #[arg(long, default_value_t = DEFAULT_CHECKPOINT_EVERY)]
    pub checkpoint_every: u32,
    /// Continue the run whose store --store names from its last checkpoint
    /// (same settings and dataset; --out is replaced).
    #[arg(long, requires = "store")]
    pub resume: bool,
}

impl Default for StoreArgs {
    /// No store (the flags' defaults).
    fn default() -> Self {
        StoreArgs {
            store: None,
            checkpoint_every: DEFAULT_CHECKPOINT_EVERY,
            resume: false,
        }
    }
}

/// Frames between checkpoints unless told: about a second of a sensor.
const DEFAULT_CHECKPOINT_EVERY: u32 = 30;

/// The store of a run, if it has one (see [`depthmesh::store::checkpoints`]).
pub struct StoreRun {
    checkpoints: Option<Checkpoints>,
    total: usize,
    /// Dataset frames read so far.
    position: usize,
}

impl StoreArgs {
    /// The session to run (continued from the store with --resume), its
    /// store, and how many of the run's `total` frames to skip. `source`
    /// says where the frames come from (see [`dataset_identity`]): a store
    /// is continued only on the frames it was written from.
    pub fn open(
        &self,
        config: SessionConfig,
        source: impl FnOnce() -> Result<Value>,
        total: usize,
    ) -> Result<(Session, StoreRun, usize)> {
        let Some(path) = &self.store else {
            let run = StoreRun {
                checkpoints: None,
                total,
                position: 0,
            };
            return Ok((Session::new(config)?, run, 0));
        };
        if self.checkpoint_every == 0 {
            bail!("--checkpoint-every must be at least 1");
        }
        let (session, checkpoints, position) =
            checkpoints::start(path, config, source()?, self.checkpoint_every, self.resume)
                .with_context(|| format!("--store {}", path.display()))?;
        if position > total {
            bail!(
                "--store {}: it has read {position} frames but the run has {total}",
                path.display(),
            );
        }
        let run = StoreRun {
            checkpoints: Some(checkpoints),
            total,
            position,
        };
        Ok((session, run, position))
    }
}

impl StoreRun {
    /// After a frame (`position` selected frames read): commits a
    /// checkpoint when one is due, and after the last frame.
    pub fn after_frame(&mut self, session: &Session, position: usize) -> Result<()> {
        self.position = position;
        match &mut self.checkpoints {
            Some(c) => Ok(c.after_frame(session, position, position >= self.total)?),
            None => Ok(()),
        }
    }

    /// Waits for the last commit and adds the store's figures to a run's
    /// summary.
    pub fn summarise(&mut self, session: &Session, summary: &mut Map<String, Value>) -> Result<()> {
        if let Some(c) = &mut self.checkpoints {
            summary.insert("store".into(), c.finish(session, self.position)?);
        }
        Ok(())
    }
}

/// Where a run's frames come from: a dataset's folder and selection.
pub fn dataset_identity(path: &Path, dataset: &Dataset) -> Result<Value> {
    let path = path
        .canonicalize()
        .with_context(|| format!("{}", path.display()))?;
    let last = dataset.len().saturating_sub(1);
    Ok(json!({
        "path": path.display().to_string(),
        "selected": dataset.len(),
        "first": dataset.frame_info(0)?.index,
        "last": dataset.frame_info(last)?.index,
    }))
}
