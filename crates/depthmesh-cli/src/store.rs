//! `--store`, `--checkpoint-every`, `--resume`: a run that writes its map to
//! a store as it goes and can continue after a crash (see
//! [`depthmesh::store`]).

use anyhow::{bail, Context, Result};
use clap::Args;
use depthmesh::dataset::Dataset;
use depthmesh::session::{Session, SessionConfig};
use depthmesh::store::{self, MapStore};
use serde_json::{json, Map, Value};
use std::path::{Path, PathBuf};

/// The store flags.
#[derive(Args, Debug, Clone)]
pub struct StoreArgs {
    /// Write the map to this store (one file) in checkpoints, to continue
    /// it with --resume after a crash (TSDF maps for now). With
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

/// The store of a run, if it has one, and what its checkpoints cost.
pub struct StoreRun {
    store: Option<MapStore>,
    every: u32,
    total: usize,
    since: u32,
    checkpoints: usize,
    blocks: usize,
    bytes: usize,
    ms: f64,
    resumed_at: Option<usize>,
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
        let mut run = StoreRun {
            store: None,
            every: self.checkpoint_every,
            total,
            since: 0,
            checkpoints: 0,
            blocks: 0,
            bytes: 0,
            ms: 0.0,
            resumed_at: None,
        };
        let Some(path) = &self.store else {
            return Ok((Session::new(config)?, run, 0));
        };
        if self.checkpoint_every == 0 {
            bail!("--checkpoint-every must be at least 1");
        }
        let identity = store::identity(&config, source()?)
            .with_context(|| format!("--store {}", path.display()))?;
        if !self.resume {
            let store = MapStore::create(path, &identity)?;
            let mut session = Session::new(config)?;
            keep_freed_blocks(&mut session, &store)?;
            run.store = Some(store);
            return Ok((session, run, 0));
        }
        let (opened, saved) = MapStore::open(path)?;
        store::check_identity(path, &saved.identity, &identity)?;
        if saved.position > total {
            bail!(
                "--store {}: it has read {} frames but the run has {total}",
                path.display(),
                saved.position,
            );
        }
        let position = saved.position;
        let mut session = Session::resume(config, saved.session)?;
        keep_freed_blocks(&mut session, &opened)?;
        run.store = Some(opened);
        run.resumed_at = Some(position);
        Ok((session, run, position))
    }
}

/// With bounded memory (`--active-radius`), the blocks the camera leaves
/// go to the store and come back from it when the camera returns.
fn keep_freed_blocks(session: &mut Session, store: &MapStore) -> Result<()> {
    if let Some(t) = session.backend_mut().tsdf_mut() {
        if t.active_radius().is_some() {
            t.set_archive(Box::new(store.archive()))?;
        }
    }
    Ok(())
}

impl StoreRun {
    /// After a frame (`position` selected frames read): commits a
    /// checkpoint when one is due, and after the last frame.
    pub fn after_frame(&mut self, session: &Session, position: usize) -> Result<()> {
        let Some(store) = &mut self.store else {
            return Ok(());
        };
        self.since += 1;
        if self.since < self.every && position < self.total {
            return Ok(());
        }
        let c = store.checkpoint(session, position)?;
        self.since = 0;
        self.checkpoints += 1;
        self.blocks += c.blocks;
        self.bytes += c.bytes;
        self.ms += c.ms;
        Ok(())
    }

    /// Waits for the last commit and adds the store's figures to a run's
    /// summary.
    pub fn summarise(&mut self, summary: &mut Map<String, Value>) -> Result<()> {
        let Some(store) = &mut self.store else {
            return Ok(());
        };
        store.finish()?;
        summary.insert(
            "store".into(),
            json!({
                "checkpoints": self.checkpoints,
                "blocks_written": self.blocks,
                "bytes_written": self.bytes,
                "stall_ms_mean": self.ms / self.checkpoints.max(1) as f64,
                "stall_ms_total": self.ms,
                "resumed_at_position": self.resumed_at,
            }),
        );
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
