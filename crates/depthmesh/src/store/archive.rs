//! A map store as the archive of a bounded TSDF map (see
//! [`crate::tsdf::archive`]): blocks the camera leaves are kept in the
//! store's `blocks` table and read back from it when the camera returns.
//!
//! A block that leaves memory changed since the last checkpoint waits in
//! memory, as it is, for the next checkpoint, which commits it with the
//! rest (compressed on the commit's thread); one unchanged since is dropped
//! (the store holds it as it is). Reads look at what waits, then at what the
//! running commit writes, then at the store, so a block is always read back
//! as it was freed.

use super::{block_codec, store_error, BLOCKS};
use crate::error::{Error, Result};
use crate::tsdf::archive::BlockArchive;
use crate::tsdf::{Block, KeyMap};
use glam::IVec3;
use rayon::prelude::*;
use redb::{Database, ReadableDatabase, ReadableTable};
use std::path::PathBuf;
use std::sync::{Arc, Mutex, MutexGuard};

/// Blocks on their way to the store, by key.
pub(super) type Waiting = KeyMap<Block>;

/// What the store and its archive share: blocks on their way to the store.
#[derive(Debug, Default)]
pub(super) struct Shelf {
    /// Frames the map had fused at the last checkpoint: a block fused later
    /// is not in the store as it is.
    pub saved_frames: u32,
    /// Blocks freed since the last checkpoint that it did not hold as they are.
    pub pending: Waiting,
    /// Every block the running commit writes, until it has committed.
    pub committing: Arc<Waiting>,
}

/// The archive handed to a bounded map; shares the store's database.
#[derive(Debug)]
pub struct StoreArchive {
    pub(super) db: Arc<Database>,
    pub(super) path: PathBuf,
    pub(super) shelf: Arc<Mutex<Shelf>>,
    /// Whether the blocks hold colours.
    pub(super) color: bool,
}

impl StoreArchive {
    fn shelf(&self) -> MutexGuard<'_, Shelf> {
        // The shelf is only ever changed whole under the lock, so one left
        // by a panicking thread is still consistent.
        self.shelf.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn decode(&self, key: IVec3, bytes: &[u8]) -> Result<Block> {
        block_codec::decode(key, bytes, self.color).map_err(|e| {
            Error::format(
                &self.path,
                format!("block ({}, {}, {}): {e}", key.x, key.y, key.z),
            )
        })
    }
}

impl BlockArchive for StoreArchive {
    fn keys(&self) -> Result<Vec<IVec3>> {
        let read = || -> std::result::Result<Vec<IVec3>, redb::Error> {
            let txn = self.db.begin_read()?;
            let mut keys = Vec::new();
            for entry in txn.open_table(BLOCKS)?.iter()? {
                let (x, y, z) = entry?.0.value();
                keys.push(IVec3::new(x, y, z));
            }
            Ok(keys)
        };
        let mut keys = read().map_err(|e| store_error(&self.path, e))?;
        let shelf = self.shelf();
        keys.extend(shelf.pending.keys().chain(shelf.committing.keys()));
        keys.sort_unstable_by_key(|k| (k.x, k.y, k.z));
        keys.dedup();
        Ok(keys)
    }

    fn put(&mut self, blocks: Vec<(Block, u32)>) -> Result<()> {
        let mut shelf = self.shelf();
        let since = shelf.saved_frames;
        let changed = blocks.into_iter().filter(|(_, fused)| *fused > since);
        shelf.pending.extend(changed.map(|(b, _)| (b.key, b)));
        Ok(())
    }

    fn get(&self, keys: &[IVec3]) -> Result<Vec<Block>> {
        let mut blocks = Vec::with_capacity(keys.len());
        let mut rest = Vec::new();
        {
            let shelf = self.shelf();
            for &k in keys {
                match shelf.pending.get(&k).or_else(|| shelf.committing.get(&k)) {
                    Some(block) => blocks.push(block.clone()),
                    None => rest.push(k),
                }
            }
        }
        let mut found: Vec<(IVec3, Vec<u8>)> = Vec::with_capacity(rest.len());
        if !rest.is_empty() {
            let read = || -> std::result::Result<_, redb::Error> {
                let txn = self.db.begin_read()?;
                let table = txn.open_table(BLOCKS)?;
                let mut out = Vec::with_capacity(rest.len());
                for &k in &rest {
                    out.push((k, table.get((k.x, k.y, k.z))?.map(|v| v.value().to_vec())));
                }
                Ok(out)
            };
            for (k, bytes) in read().map_err(|e| store_error(&self.path, e))? {
                let bytes = bytes.ok_or_else(|| {
                    Error::format(
                        &self.path,
                        format!("block ({}, {}, {}) is not in the store", k.x, k.y, k.z),
                    )
                })?;
                found.push((k, bytes));
            }
        }
        let read: Vec<Block> = found
            .par_iter()
            .map(|(k, bytes)| self.decode(*k, bytes))
            .collect::<Result<_>>()?;
        blocks.extend(read);
        Ok(blocks)
    }
}
