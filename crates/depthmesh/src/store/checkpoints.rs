//! A session kept in a store: started afresh or continued from the store's
//! last checkpoint, then checkpointed every so many frames. What every front
//! end (the commands' `--store`, the service's sessions) does with a store.

use super::{check_identity, identity, MapStore};
use crate::error::{Error, Result};
use crate::session::{Session, SessionConfig};
use serde_json::{json, Value};
use std::path::Path;

/// A session's store and its checkpoints.
pub struct Checkpoints {
    store: MapStore,
    every: u32,
    /// Frames since the last checkpoint.
    since: u32,
    count: usize,
    blocks: usize,
    /// Bytes copied on the frame thread for the commits (before compression).
    bytes: usize,
    ms: f64,
    /// The dataset position the session was continued from.
    resumed_at: Option<usize>,
}

/// A session kept in the store at `path`, checkpointed every `every` frames;
/// `dataset` says where its frames come from. A new store is made (one
/// already there is refused); with `resume` the store's session continues
/// from its last checkpoint (a store written with other settings or from
/// other frames is refused, naming what differs). Returns the session, its
/// checkpoints and how many of the dataset's frames the store has read.
pub fn start(
    path: &Path,
    config: SessionConfig,
    dataset: Value,
    every: u32,
    resume: bool,
) -> Result<(Session, Checkpoints, usize)> {
    if every == 0 {
        return Err(Error::parameter(
            "checkpoint every",
            "must be at least 1 frame",
        ));
    }
    let wanted = identity(&config, dataset)?;
    let (mut session, store, position) = if resume {
        let (store, saved) = MapStore::open(path)?;
        check_identity(path, &saved.identity, &wanted)?;
        let position = saved.position;
        (Session::resume(config, saved.session)?, store, position)
    } else {
        (Session::new(config)?, MapStore::create(path, &wanted)?, 0)
    };
    // With bounded memory the blocks the camera leaves go to the store and
    // come back from it.
    if let Some(t) = session.backend_mut().tsdf_mut() {
        if t.active_radius().is_some() {
            t.set_archive(Box::new(store.archive()))?;
        }
    }
    let checkpoints = Checkpoints {
        store,
        every,
        since: 0,
        count: 0,
        blocks: 0,
        bytes: 0,
        ms: 0.0,
        resumed_at: resume.then_some(position),
    };
    Ok((session, checkpoints, position))
}

impl Checkpoints {
    /// After a frame (`position` dataset frames read): commits a checkpoint
    /// when one is due, or when `last`.
    pub fn after_frame(&mut self, session: &Session, position: usize, last: bool) -> Result<()> {
        self.since += 1;
        if self.since < self.every && !last {
            return Ok(());
        }
        self.commit(session, position)
    }

    /// Commits what is not committed yet (a session that ends before its
    /// last frame, say) and waits for it; the checkpoints' figures.
    pub fn finish(&mut self, session: &Session, position: usize) -> Result<Value> {
        if self.since > 0 {
            self.commit(session, position)?;
        }
        // A MABDI map's checkpoints rewrite M from its first changed
        // triangle on, which leaves the file several times M's size (the
        // space is reused, so it stops growing): give it back at the end.
        // The other maps rewrite only what changed.
        let compact = matches!(session.backend(), crate::session::Backend::Mabdi(_));
        let (before, after) = if compact {
            self.store.compact()?
        } else {
            self.store.finish()?;
            let size = self.store.file_bytes()?;
            (size, size)
        };
        Ok(json!({
            "file_bytes_before_compaction": before,
            "file_bytes": after,
            "checkpoints": self.count,
            "blocks_written": self.blocks,
            "bytes_copied": self.bytes,
            "bytes_written": self.store.bytes_written(),
            "stall_ms_mean": self.ms / self.count.max(1) as f64,
            "stall_ms_total": self.ms,
            "resumed_at_position": self.resumed_at,
        }))
    }

    fn commit(&mut self, session: &Session, position: usize) -> Result<()> {
        let c = self.store.checkpoint(session, position)?;
        self.since = 0;
        self.count += 1;
        self.blocks += c.blocks;
        self.bytes += c.bytes;
        self.ms += c.ms;
        Ok(())
    }
}
