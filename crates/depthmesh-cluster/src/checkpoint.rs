//! A shard's checkpoint: a manifest in the `shards` bucket (the stream
//! position it includes, how many frames it fused, its segments) and
//! segments in the object store (the blocks changed since the segment
//! before, compressed as the map store compresses them).
//!
//! A checkpoint adds one segment of what changed; loading applies the
//! segments in order, a later block replacing an earlier one. When a
//! shard has several segments, the next checkpoint writes the whole shard
//! as one segment instead and the older ones are deleted. The manifest is replaced by compare-and-set on its revision,
//! so of two workers that both believe they own a shard (one stalled past
//! its lease) only one can commit, and the history stays one line.

use crate::error::{ClusterError, Result};
use crate::site::Site;
use async_nats::jetstream::kv;
use depthmesh::store::block_codec;
use depthmesh::tsdf::{Block, KeyMap};
use glam::IVec3;
use serde::{Deserialize, Serialize};
use tokio::io::AsyncReadExt;

/// Magic of a segment object.
const SEGMENT_MAGIC: &[u8; 4] = b"DMC1";

/// A shard's committed state.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// The last stream sequence number included.
    pub seq: u64,
    /// Posed frames fused into the shard (each frame once, whether it
    /// touched the shard's blocks or not).
    pub frames: u64,
    /// Posed frames that could not be read (skipped by every shard alike).
    pub rejected: u64,
    /// Segment objects, oldest first.
    pub segments: Vec<String>,
    /// Blocks the shard holds.
    pub blocks: u64,
    /// Bytes of its segments.
    pub segment_bytes: u64,
    /// The worker that committed it.
    pub writer: String,
}

/// The key of shard `shard` in the `leases` and `shards` buckets.
pub fn shard_key(shard: u32) -> String {
    format!("shard.{shard}")
}

/// A segment: magic, block count, then per block its key (3 × `i32`), the
/// length of its compressed voxels (`u32`) and those bytes; little-endian.
pub fn encode_segment<'a>(blocks: impl Iterator<Item = &'a Block>) -> Vec<u8> {
    let mut out = SEGMENT_MAGIC.to_vec();
    out.extend_from_slice(&0u32.to_le_bytes());
    let mut scratch = Vec::new();
    let mut count = 0u32;
    for b in blocks {
        block_codec::encode(b, &mut scratch);
        for c in [b.key.x, b.key.y, b.key.z] {
            out.extend_from_slice(&c.to_le_bytes());
        }
        out.extend_from_slice(&(scratch.len() as u32).to_le_bytes());
        out.extend_from_slice(&scratch);
        count += 1;
    }
    out[4..8].copy_from_slice(&count.to_le_bytes());
    out
}

/// The blocks of a segment, into `into` (replacing blocks of the same key).
pub fn decode_segment(bytes: &[u8], into: &mut KeyMap<Block>) -> Result<(), String> {
    let take = |at: &mut usize, n: usize| -> Result<&[u8], String> {
        let s = bytes
            .get(*at..*at + n)
            .ok_or_else(|| format!("ends at byte {} of {}", *at, bytes.len()))?;
        *at += n;
        Ok(s)
    };
    let mut at = 0;
    if take(&mut at, 4)? != SEGMENT_MAGIC {
        return Err("not a checkpoint segment".into());
    }
    let u32_at = |at: &mut usize| -> Result<u32, String> {
        Ok(u32::from_le_bytes(
            take(at, 4)?.try_into().expect("4 bytes"),
        ))
    };
    let count = u32_at(&mut at)?;
    for _ in 0..count {
        let mut key = [0i32; 3];
        for c in &mut key {
            *c = u32_at(&mut at)? as i32;
        }
        let len = u32_at(&mut at)? as usize;
        let key = IVec3::from_array(key);
        let block = block_codec::decode(key, take(&mut at, len)?, false)
            .map_err(|e| format!("block {key}: {e}"))?;
        into.insert(key, block);
    }
    if at != bytes.len() {
        return Err(format!("{} bytes after its last block", bytes.len() - at));
    }
    Ok(())
}

/// Shard `shard`'s manifest and its revision, if it was ever checkpointed.
pub async fn read_manifest(site: &Site, shard: u32) -> Result<Option<(Manifest, u64)>> {
    let entry = site
        .shards
        .entry(shard_key(shard))
        .await
        .map_err(|e| ClusterError::bus("cannot read a shard's checkpoint", e))?;
    let Some(entry) = entry.filter(|e| !e.value.is_empty()) else {
        return Ok(None);
    };
    let manifest = serde_json::from_slice(&entry.value).map_err(|e| {
        ClusterError::site(
            &site.name,
            format!("shard {shard}: unreadable checkpoint: {e}"),
        )
    })?;
    Ok(Some((manifest, entry.revision)))
}

/// The blocks a manifest's segments hold.
pub async fn load_blocks(site: &Site, shard: u32, manifest: &Manifest) -> Result<KeyMap<Block>> {
    let mut blocks = KeyMap::default();
    for name in &manifest.segments {
        let mut object = site.checkpoints.get(name).await.map_err(|e| {
            ClusterError::bus(&format!("cannot read segment {name} of shard {shard}"), e)
        })?;
        let mut bytes = Vec::new();
        object
            .read_to_end(&mut bytes)
            .await
            .map_err(|e| ClusterError::bus(&format!("cannot read segment {name}"), e))?;
        decode_segment(&bytes, &mut blocks).map_err(|e| {
            ClusterError::site(&site.name, format!("shard {shard}, segment {name}: {e}"))
        })?;
    }
    Ok(blocks)
}

/// The blocks of shard `shard` as `manifest` (of revision `revision`)
/// says, or, when a segment it names is gone (the owner wrote the shard
/// whole and deleted the older segments meanwhile), as the newer manifest
/// says; with the manifest loaded and its revision, which a commit on top
/// of it must name.
pub async fn load_shard(
    site: &Site,
    shard: u32,
    manifest: Manifest,
    revision: Option<u64>,
) -> Result<(Manifest, Option<u64>, KeyMap<Block>)> {
    let (mut manifest, mut revision) = (manifest, revision);
    for _ in 0..3 {
        let failed = match load_blocks(site, shard, &manifest).await {
            Ok(blocks) => return Ok((manifest, revision, blocks)),
            Err(e) => e,
        };
        match read_manifest(site, shard).await? {
            Some((newer, r)) if newer != manifest => (manifest, revision) = (newer, Some(r)),
            _ => return Err(failed),
        }
    }
    let blocks = load_blocks(site, shard, &manifest).await?;
    Ok((manifest, revision, blocks))
}

/// Stores a segment under `name`.
pub async fn write_segment(site: &Site, name: &str, bytes: &[u8]) -> Result<()> {
    let mut reader = bytes;
    site.checkpoints
        .put(name, &mut reader)
        .await
        .map(|_| ())
        .map_err(|e| ClusterError::bus(&format!("cannot write segment {name}"), e))
}

/// Replaces shard `shard`'s manifest if its revision is still `revision`
/// (`None`: if it has none yet). The new revision, or `None` when another
/// worker committed in between: the shard is no longer this worker's.
pub async fn commit(
    site: &Site,
    shard: u32,
    manifest: &Manifest,
    revision: Option<u64>,
) -> Result<Option<u64>> {
    let bytes = serde_json::to_vec(manifest).expect("manifest serialises");
    let key = shard_key(shard);
    let lost =
        |e: &dyn std::fmt::Display| ClusterError::bus(&format!("cannot commit shard {shard}"), e);
    match revision {
        Some(r) => match site.shards.update(&key, bytes.into(), r).await {
            Ok(r) => Ok(Some(r)),
            Err(e) if e.kind() == kv::UpdateErrorKind::WrongLastRevision => Ok(None),
            Err(e) => Err(lost(&e)),
        },
        None => match site.shards.create(&key, bytes.into()).await {
            Ok(r) => Ok(Some(r)),
            Err(e) if e.kind() == kv::CreateErrorKind::AlreadyExists => Ok(None),
            Err(e) => Err(lost(&e)),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use depthmesh::tsdf::BLOCK_VOXELS;

    fn block(key: IVec3, v: i16) -> Block {
        Block {
            key,
            tsdf: Box::new([v; BLOCK_VOXELS]),
            weight: Box::new([7; BLOCK_VOXELS]),
            color: None,
        }
    }

    #[test]
    fn a_later_segment_replaces_blocks_of_an_earlier_one() {
        let first = encode_segment([block(IVec3::new(1, -2, 3), 5), block(IVec3::ZERO, 9)].iter());
        let second = encode_segment([block(IVec3::ZERO, -4)].iter());
        let mut blocks = KeyMap::default();
        decode_segment(&first, &mut blocks).unwrap();
        decode_segment(&second, &mut blocks).unwrap();
        assert_eq!(blocks.len(), 2);
        assert_eq!(blocks[&IVec3::ZERO].tsdf[3], -4);
        assert_eq!(blocks[&IVec3::new(1, -2, 3)].tsdf[0], 5);
    }

    #[test]
    fn a_damaged_segment_is_refused_never_read_short() {
        let bytes = encode_segment([block(IVec3::ONE, 1), block(IVec3::ZERO, 2)].iter());
        for cut in [0, 3, 8, 20, bytes.len() - 1] {
            let mut blocks = KeyMap::default();
            assert!(
                decode_segment(&bytes[..cut], &mut blocks).is_err(),
                "cut at {cut}"
            );
        }
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(decode_segment(&longer, &mut KeyMap::default()).is_err());
    }
}
