//! Bounded memory for large scenes: KinfuLS's volume that follows the camera,
//! for a sparse block map.
//!
//! Only blocks that reach within the active radius of the camera are fused
//! (choose a radius beyond the sensor's reach to keep every measurement);
//! blocks wholly farther away are meshed, handed out as mesh in global
//! coordinates, and freed. Two rules keep the
//! handed-out mesh equal to what a full extraction of the unbounded map holds:
//!
//! - A block's triangles (the cubes it owns) depend on the voxels of the block
//!   and of its seven neighbours above (see [`super::mesh`]), so a block is
//!   *written* only when it and every resident neighbour above are out of range.
//! - A written block stays in memory while a resident block below it is
//!   unwritten, since that block's triangles still read its voxels; it is
//!   *evicted* once every resident block below is written.
//!
//! If the camera comes back, the region is allocated anew, empty, and its
//! new surface is written again later: chunks then overlap where the camera
//! revisits, as KinfuLS's exported clouds do. A written block that changes
//! before it is evicted (the camera turned back in time) is written again too.
//! Nothing is lost, but a revisited region's earlier measurements are not
//! fused with the new ones.

use super::mesh::{extract_blocks, MeshCache};
use super::{KeyMap, TsdfVolume, ABOVE};
use crate::error::{Error, Result};
use crate::mesh::Mesh;
use glam::{IVec3, Vec3};
use rayon::prelude::*;

/// The blocks kept in memory: those within `radius` of the camera, plus a
/// shell of written blocks still needed by their neighbours below.
#[derive(Debug)]
pub struct ActiveRegion {
    radius: f32,
    /// Resident blocks whose triangles were handed out, and the frame of it.
    written: KeyMap<u32>,
    evicted: usize,
}

impl ActiveRegion {
    /// Keeps blocks within `radius` metres of the camera; `radius` must be positive.
    pub fn new(radius: f32) -> Result<Self> {
        if !(radius.is_finite() && radius > 0.0) {
            return Err(Error::parameter(
                "active radius",
                format!("must be a positive distance in metres, got {radius}"),
            ));
        }
        Ok(ActiveRegion {
            radius,
            written: KeyMap::default(),
            evicted: 0,
        })
    }

    /// The radius in metres.
    pub fn radius(&self) -> f32 {
        self.radius
    }

    /// Blocks freed so far.
    pub fn evicted_blocks(&self) -> usize {
        self.evicted
    }

    /// After a frame taken at `camera`: writes the blocks that went out of
    /// range (returning their triangles, in global coordinates) and frees the
    /// written blocks no resident block needs any more (also from `cache`).
    pub fn update(&mut self, volume: &mut TsdfVolume, cache: &mut MeshCache, camera: Vec3) -> Mesh {
        let frame = volume.frames();
        let (index, changes) = (volume.index(), volume.changes());
        let min_weight = cache.min_weight();
        // Revisited before eviction: the block changed since it was written.
        self.written.retain(|k, at| {
            index
                .get(k)
                .is_some_and(|&i| changes[i as usize].affecting(0, min_weight) <= *at)
        });
        let far: Vec<bool> = volume
            .blocks()
            .par_iter()
            .map(|b| volume.block_distance(b.key, camera) > self.radius)
            .collect();
        let is_far = |k: IVec3| index.get(&k).is_none_or(|&i| far[i as usize]);
        let mut write: Vec<IVec3> = volume
            .blocks()
            .par_iter()
            .zip(&far)
            .filter(|(b, &f)| {
                f && !self.written.contains_key(&b.key) && ABOVE.iter().all(|&o| is_far(b.key + o))
            })
            .map(|(b, _)| b.key)
            .collect();
        write.sort_unstable_by_key(|k| (k.x, k.y, k.z));
        let mesh = extract_blocks(volume, &write, min_weight);
        self.written.extend(write.iter().map(|&k| (k, frame)));
        let written = &self.written;
        let evict: Vec<IVec3> = written
            .keys()
            .filter(|&&k| {
                ABOVE
                    .iter()
                    .all(|&o| !index.contains_key(&(k - o)) || written.contains_key(&(k - o)))
            })
            .copied()
            .collect();
        for k in &evict {
            self.written.remove(k);
        }
        cache.forget(&evict);
        volume.remove_blocks(&evict);
        self.evicted += evict.len();
        mesh
    }

    /// The triangles of the resident blocks not written yet, from `cache`
    /// (which must be up to date with the volume): the rest of the map.
    pub fn remainder(&self, volume: &TsdfVolume, cache: &MeshCache) -> Mesh {
        let mut keys: Vec<IVec3> = volume
            .blocks()
            .iter()
            .map(|b| b.key)
            .filter(|k| !self.written.contains_key(k))
            .collect();
        keys.sort_unstable_by_key(|k| (k.x, k.y, k.z));
        cache.assemble_blocks(&keys)
    }
}
