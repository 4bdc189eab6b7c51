//! Bounded memory that remembers: KinfuLS's world model for a sparse block
//! map. Blocks the camera leaves go to an archive (a map store) and come
//! back when it returns, so a revisited region continues from what was fused
//! there, and the map made from memory and archive together equals the
//! unbounded map.
//!
//! Fusion reaches only blocks within the active radius of the camera (see
//! [`super::TsdfVolume::set_reach`]), so before each frame every archived
//! block within the radius of the frame's pose is brought back; after it,
//! resident blocks farther than the radius plus one block side are archived
//! and freed (the extra side keeps a camera that jitters on a block's border
//! from moving it to and fro every frame).

use super::mesh::{extract_blocks, extract_sets, MeshCache};
use super::{Block, KeyMap, TsdfConfig, TsdfVolume, ABOVE, BLOCK};
use crate::error::Result;
use crate::mesh::Mesh;
use glam::{IVec3, Vec3};
use rayon::prelude::*;

/// Where a bounded map keeps the blocks it frees.
pub trait BlockArchive: Send + Sync + std::fmt::Debug {
    /// The keys of every block archived.
    fn keys(&self) -> Result<Vec<IVec3>>;
    /// Keeps blocks leaving memory, each with the frame fusion last changed
    /// it ([`super::changes::Changes::fused`]: 0 when it has not changed
    /// since it came from the archive, which then need not write it again).
    fn put(&mut self, blocks: Vec<(Block, u32)>) -> Result<()>;
    /// The archived blocks with these keys; a key not archived is an error.
    fn get(&self, keys: &[IVec3]) -> Result<Vec<Block>>;
}

/// The active region of a bounded map with an archive.
#[derive(Debug)]
pub struct SwapRegion {
    radius: f32,
    archive: Box<dyn BlockArchive>,
    /// Archived blocks not in memory.
    away: KeyMap<()>,
    evicted: usize,
    loaded: usize,
}

impl SwapRegion {
    /// Keeps blocks within `radius` metres of the camera in `volume`, the
    /// rest in `archive` (which may hold blocks already: a continued map).
    pub fn new(radius: f32, archive: Box<dyn BlockArchive>, volume: &TsdfVolume) -> Result<Self> {
        let away = archive
            .keys()?
            .into_iter()
            .filter(|k| !volume.index().contains_key(k))
            .map(|k| (k, ()))
            .collect();
        Ok(SwapRegion {
            radius,
            archive,
            away,
            evicted: 0,
            loaded: 0,
        })
    }

    /// The radius in metres.
    pub fn radius(&self) -> f32 {
        self.radius
    }

    /// Blocks archived and freed so far.
    pub fn evicted_blocks(&self) -> usize {
        self.evicted
    }

    /// Blocks brought back so far.
    pub fn loaded_blocks(&self) -> usize {
        self.loaded
    }

    /// Before a frame taken at `camera`: brings back the archived blocks it
    /// can fuse into; returns how many.
    pub fn bring_back(&mut self, volume: &mut TsdfVolume, camera: Vec3) -> Result<usize> {
        let mut keys: Vec<IVec3> = self
            .away
            .keys()
            .filter(|&&k| volume.block_distance(k, camera) <= self.radius)
            .copied()
            .collect();
        if keys.is_empty() {
            return Ok(0);
        }
        keys.sort_unstable_by_key(|k| (k.x, k.y, k.z));
        volume.load(self.archive.get(&keys)?)?;
        for k in &keys {
            self.away.remove(k);
        }
        self.loaded += keys.len();
        Ok(keys.len())
    }

    /// After a frame taken at `camera`: archives and frees the blocks out of
    /// range (also from `cache`); returns how many.
    pub fn evict(
        &mut self,
        volume: &mut TsdfVolume,
        cache: &mut MeshCache,
        camera: Vec3,
    ) -> Result<usize> {
        let limit = self.radius + volume.config().voxel * BLOCK as f32;
        let mut keys: Vec<IVec3> = volume
            .blocks()
            .par_iter()
            .filter(|b| volume.block_distance(b.key, camera) > limit)
            .map(|b| b.key)
            .collect();
        if keys.is_empty() {
            return Ok(0);
        }
        keys.sort_unstable_by_key(|k| (k.x, k.y, k.z));
        self.archive.put(volume.take_blocks(&keys))?;
        cache.forget(&keys);
        self.away.extend(keys.iter().map(|&k| (k, ())));
        self.evicted += keys.len();
        Ok(keys.len())
    }

    /// Whether block `key` is archived and not in memory.
    pub fn is_away(&self, key: IVec3) -> bool {
        self.away.contains_key(&key)
    }

    /// Every block of the map: resident, then archived.
    pub fn keys(&self, volume: &TsdfVolume) -> Vec<IVec3> {
        let held = volume.blocks().iter().map(|b| b.key);
        held.chain(self.away.keys().copied()).collect()
    }

    /// Copies of the blocks `keys` (each resident or archived).
    pub fn fetch(&self, volume: &TsdfVolume, keys: &[IVec3]) -> Result<Vec<Block>> {
        let (held, away): (Vec<IVec3>, Vec<IVec3>) =
            keys.iter().partition(|k| volume.index().contains_key(k));
        let mut blocks = self.archive.get(&away)?;
        blocks.extend(held.iter().filter_map(|&k| volume.block(k).cloned()));
        Ok(blocks)
    }

    /// The whole map, resident and archived, meshed a slab at a time (see
    /// [`mesh_slabs`]).
    pub fn mesh_all(&self, volume: &TsdfVolume, f: impl FnMut(Mesh) -> Result<()>) -> Result<()> {
        let fetch = |keys: &[IVec3]| self.fetch(volume, keys);
        mesh_slabs(*volume.config(), self.keys(volume), fetch, f)
    }

    /// The triangles each block of `keys` owns, resident or archived,
    /// meshed with the blocks above it from wherever they are, a slab at a
    /// time (see [`for_slabs`]); `None` for a block not in the map, and for
    /// all of them when the archive cannot be read.
    pub fn block_meshes(&self, volume: &TsdfVolume, keys: &[IVec3]) -> Vec<Option<Mesh>> {
        let known = |k: &IVec3| volume.index().contains_key(k) || self.is_away(*k);
        let needed: Vec<IVec3> = keys
            .iter()
            .flat_map(|&k| ABOVE.map(|o| k + o))
            .filter(known)
            .collect();
        let slot: KeyMap<usize> = keys.iter().enumerate().map(|(i, &k)| (k, i)).collect();
        let mut out = vec![None; keys.len()];
        let min_weight = volume.config().min_weight;
        let visited = for_slabs(
            *volume.config(),
            needed,
            |keys| self.fetch(volume, keys),
            |slab, keys| {
                let wanted: Vec<Vec<IVec3>> = keys
                    .iter()
                    .filter(|k| slot.contains_key(k))
                    .map(|&k| vec![k])
                    .collect();
                for (set, mesh) in wanted.iter().zip(extract_sets(slab, &wanted, min_weight)) {
                    out[slot[&set[0]]] = Some(mesh);
                }
                Ok(())
            },
        );
        match visited {
            Ok(()) => out,
            Err(_) => vec![None; keys.len()],
        }
    }
}

/// Block layers (along x) meshed at a time by [`mesh_slabs`].
const SLAB: i32 = 4;

/// Meshes the map of blocks `keys`, which `fetch` hands out, a slab at a
/// time (see [`for_slabs`]), handing each slab's triangles to `f`: a map
/// larger than memory is meshed holding two slabs. The pieces together
/// hold exactly the triangles of a full extraction (vertices on a border
/// between slabs come in both).
pub fn mesh_slabs(
    config: TsdfConfig,
    keys: Vec<IVec3>,
    fetch: impl FnMut(&[IVec3]) -> Result<Vec<Block>>,
    mut f: impl FnMut(Mesh) -> Result<()>,
) -> Result<()> {
    for_slabs(config, keys, fetch, |volume, keys| {
        f(extract_blocks(volume, keys, config.min_weight))
    })
}

/// Visits the blocks `keys`, which `fetch` hands out, a slab of four
/// block layers along x at a time: `f` gets a volume holding the slab's
/// blocks and the first layer of the next slab (which holds vertices of the
/// slab's last layer), and the slab's keys, so what it meshes of them is
/// what a full extraction holds.
pub fn for_slabs(
    config: TsdfConfig,
    mut keys: Vec<IVec3>,
    mut fetch: impl FnMut(&[IVec3]) -> Result<Vec<Block>>,
    mut f: impl FnMut(&TsdfVolume, &[IVec3]) -> Result<()>,
) -> Result<()> {
    keys.sort_unstable_by_key(|k| (k.x, k.y, k.z));
    keys.dedup();
    let slab = |k: &IVec3| k.x.div_euclid(SLAB);
    let slabs: Vec<&[IVec3]> = keys.chunk_by(|a, b| slab(a) == slab(b)).collect();
    let mut volume = TsdfVolume::new(config)?;
    let mut loaded = 0;
    for (i, keys) in slabs.iter().enumerate() {
        let next = slabs
            .get(i + 1)
            .filter(|next| slab(&next[0]) == slab(&keys[0]) + 1);
        let wanted = if next.is_some() { i + 2 } else { i + 1 };
        while loaded < wanted {
            volume.restore(fetch(slabs[loaded])?, 0)?;
            loaded += 1;
        }
        f(&volume, keys)?;
        volume.remove_blocks(keys);
    }
    Ok(())
}
