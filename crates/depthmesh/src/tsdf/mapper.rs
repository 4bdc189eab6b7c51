//! The TSDF back-end behind the common [`Mapper`] interface: fuse, keep the
//! mesh of changed blocks up to date, predict depth by ray casting, and with
//! an active region hand out the mesh of blocks left behind.

use super::archive::{BlockArchive, SwapRegion};
use super::evict::ActiveRegion;
use super::mesh::{changed_since, extract_sets, MeshCache};
use super::raycast::RaycastImage;
use super::{TsdfConfig, TsdfVolume, ABOVE};
use crate::camera::{Intrinsics, Pose};
use crate::error::Result;
use crate::image::{DepthImage, Frame};
use crate::map::{IntegrateReport, MapStats, Mapper};
use crate::mesh::Mesh;
use glam::IVec3;
use std::time::Instant;

/// How a bounded map frees the blocks the camera left.
#[derive(Debug)]
enum Bounded {
    /// Meshed into [`TsdfMapper::take_evicted`], then forgotten.
    Chunks(ActiveRegion),
    /// Kept in an archive, brought back when the camera returns.
    Archive(SwapRegion),
}

impl Bounded {
    fn radius(&self) -> f32 {
        match self {
            Bounded::Chunks(a) => a.radius(),
            Bounded::Archive(a) => a.radius(),
        }
    }

    fn evicted_blocks(&self) -> usize {
        match self {
            Bounded::Chunks(a) => a.evicted_blocks(),
            Bounded::Archive(a) => a.evicted_blocks(),
        }
    }
}

/// TSDF fusion with marching cubes; the blocks changed since the last
/// re-mesh are re-meshed every `remesh_every` frames, or when the mesh is asked for.
#[derive(Debug)]
pub struct TsdfMapper {
    /// Re-mesh changed blocks every this many frames (0: only on demand).
    pub remesh_every: u32,
    intrinsics: Intrinsics,
    volume: TsdfVolume,
    cache: MeshCache,
    mesh: Mesh,
    /// Whether `mesh` reflects the cache.
    assembled: bool,
    /// Range of depths ray casting searches.
    range: (f32, f32),
    /// The pose and depth of the last fused frame.
    last_view: Option<(Pose, DepthImage)>,
    /// When set, blocks out of range are written out (or archived) and freed.
    active: Option<Bounded>,
    /// Triangles of blocks written out since the last [`TsdfMapper::take_evicted`].
    evicted_mesh: Mesh,
    /// Most blocks held at once.
    peak_blocks: usize,
    /// Frames fused when a viewer last asked what changed (`None`: no viewer follows).
    view_frame: Option<u32>,
}

impl TsdfMapper {
    /// An empty map for frames from `intrinsics`; ray casts look for surface
    /// between `near` and `far` metres.
    pub fn new(config: TsdfConfig, intrinsics: Intrinsics, near: f32, far: f32) -> Result<Self> {
        intrinsics.validate()?;
        Ok(TsdfMapper {
            remesh_every: 0,
            intrinsics,
            volume: TsdfVolume::new(config)?,
            cache: MeshCache::new(config.min_weight),
            mesh: Mesh::default(),
            assembled: true,
            range: (near, far),
            last_view: None,
            active: None,
            evicted_mesh: Mesh::default(),
            peak_blocks: 0,
            view_frame: None,
        })
    }

    /// Bounds memory: after each frame, blocks farther than `radius` metres
    /// from the camera are meshed into [`TsdfMapper::take_evicted`] and freed
    /// (see [`super::evict`]); [`Mapper::mesh`] then holds only the rest.
    pub fn set_active_radius(&mut self, radius: f32) -> Result<()> {
        self.active = Some(Bounded::Chunks(ActiveRegion::new(radius)?));
        self.volume.set_reach(radius);
        Ok(())
    }

    /// With an active radius, keeps the blocks the camera leaves in
    /// `archive` instead of meshing them out, and brings them back when it
    /// returns (see [`super::archive`]); the map is then the resident blocks
    /// and the archived ones ([`TsdfMapper::mesh_all`]). Blocks `archive`
    /// holds already (a continued map) count as the map's.
    pub fn set_archive(&mut self, archive: Box<dyn BlockArchive>) -> Result<()> {
        let radius = match &self.active {
            Some(Bounded::Chunks(a)) if a.evicted_blocks() == 0 => a.radius(),
            Some(_) => {
                return Err(crate::error::Error::parameter(
                    "archive",
                    "set before any block is freed",
                ))
            }
            None => {
                return Err(crate::error::Error::parameter(
                    "archive",
                    "needs an active radius",
                ))
            }
        };
        self.active = Some(Bounded::Archive(SwapRegion::new(
            radius,
            archive,
            &self.volume,
        )?));
        Ok(())
    }

    /// Whether freed blocks go to an archive ([`TsdfMapper::set_archive`]).
    pub fn archived(&self) -> bool {
        matches!(self.active, Some(Bounded::Archive(_)))
    }

    /// The whole map's triangles, a slab at a time (see
    /// [`super::archive::mesh_slabs`]): with an archive, of the resident and
    /// the archived blocks; otherwise [`Mapper::mesh`] in one piece.
    pub fn mesh_all(&mut self, mut f: impl FnMut(Mesh) -> Result<()>) -> Result<()> {
        match &self.active {
            Some(Bounded::Archive(a)) => a.mesh_all(&self.volume, f),
            _ => f(self.mesh().clone()),
        }
    }

    /// The farthest a fused voxel can be from the camera: the far depth along
    /// the image's corner rays, plus the truncation. An active radius below
    /// this drops the farthest measurements.
    pub fn reach(&self) -> f32 {
        let k = &self.intrinsics;
        let (w, h) = (k.width as f32, k.height as f32);
        let corner = [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)]
            .map(|(u, v)| k.back_project(u, v, 1.0).length())
            .into_iter()
            .fold(1.0f32, f32::max);
        self.range.1 * corner + self.volume.config().truncation
    }

    /// The triangles of the blocks written out since the last call (global
    /// coordinates; empty without an active radius).
    pub fn take_evicted(&mut self) -> Mesh {
        std::mem::take(&mut self.evicted_mesh)
    }

    /// Blocks freed so far by the active region.
    pub fn evicted_blocks(&self) -> usize {
        self.active.as_ref().map_or(0, Bounded::evicted_blocks)
    }

    /// Blocks brought back from the archive so far (`None` without one).
    pub fn loaded_blocks(&self) -> Option<usize> {
        match &self.active {
            Some(Bounded::Archive(a)) => Some(a.loaded_blocks()),
            _ => None,
        }
    }

    /// The active radius, when memory is bounded.
    pub fn active_radius(&self) -> Option<f32> {
        self.active.as_ref().map(Bounded::radius)
    }

    /// Most blocks held in memory at once (after a frame's integration).
    pub fn peak_blocks(&self) -> usize {
        self.peak_blocks
    }

    /// Puts back the blocks of a map saved after `frames` fused frames (see
    /// [`TsdfVolume::restore`]).
    pub fn restore(&mut self, blocks: Vec<super::Block>, frames: u32) -> Result<()> {
        self.volume.restore(blocks, frames)?;
        self.peak_blocks = self.peak_blocks.max(self.volume.blocks().len());
        self.assembled = false;
        Ok(())
    }

    /// The pose and depth of the last fused frame (ray casting for
    /// tracking starts from it), to save.
    pub fn last_view(&self) -> Option<&(Pose, DepthImage)> {
        self.last_view.as_ref()
    }

    /// Puts back a saved [`TsdfMapper::last_view`].
    pub fn set_last_view(&mut self, view: (Pose, DepthImage)) {
        self.last_view = Some(view);
    }

    /// The fused volume.
    pub fn volume(&self) -> &TsdfVolume {
        &self.volume
    }

    /// A full marching-cubes extraction from scratch (what the kept,
    /// incrementally updated mesh equals); with an active radius, of the
    /// blocks not written out yet.
    pub fn extract_mesh(&self) -> Mesh {
        let mut cache = MeshCache::new(self.volume.config().min_weight);
        cache.update(&self.volume);
        self.assemble(&cache)
    }

    fn assemble(&self, cache: &MeshCache) -> Mesh {
        match &self.active {
            Some(Bounded::Chunks(active)) => active.remainder(&self.volume, cache),
            _ => cache.assemble(),
        }
    }

    /// Blocks per side of a viewer's part: 2 (a part of 2³ blocks carries
    /// its codecs' fixed costs once for eight blocks), or 1 with an active
    /// radius (a part must be held whole or not at all: a block written out
    /// would otherwise vanish from a viewer's copy when its neighbours change).
    pub fn part_blocks(&self) -> i32 {
        if self.active.is_some() {
            1
        } else {
            2
        }
    }

    /// The viewer's part holding block `key`.
    fn part_of(&self, key: IVec3) -> IVec3 {
        key.div_euclid(IVec3::splat(self.part_blocks()))
    }

    /// Starts noting changed parts for a viewer (see
    /// [`TsdfMapper::part_blocks`]); returns every part the volume holds
    /// blocks of (those without surface have an empty mesh).
    pub fn follow_parts(&mut self) -> Vec<IVec3> {
        self.view_frame = Some(self.volume.frames());
        let keys: Vec<IVec3> = match &self.active {
            // A viewer who joins late sees the archived blocks too.
            Some(Bounded::Archive(a)) => a.keys(&self.volume),
            _ => self.volume.blocks().iter().map(|b| b.key).collect(),
        };
        self.parts_of(keys)
    }

    /// The parts whose mesh may have changed since the last call (or
    /// [`TsdfMapper::follow_parts`]); empty while not followed. Nothing is
    /// meshed: a viewer meshes only what it sends
    /// ([`TsdfMapper::part_meshes`]), so following costs the mapping
    /// nothing between sends.
    pub fn changed_parts(&mut self) -> Vec<IVec3> {
        let Some(since) = self.view_frame else {
            return Vec::new();
        };
        self.view_frame = Some(self.volume.frames());
        let keys = changed_since(&self.volume, since, self.cache.min_weight());
        self.parts_of(keys)
    }

    fn parts_of(&self, keys: Vec<IVec3>) -> Vec<IVec3> {
        let mut parts: Vec<IVec3> = keys.into_iter().map(|k| self.part_of(k)).collect();
        parts.sort_unstable_by_key(|k| (k.x, k.y, k.z));
        parts.dedup();
        parts
    }

    /// The triangles the blocks of each part own now, meshed from the
    /// volume (what the assembled mesh holds for them), and with an
    /// archive from the archived blocks too; `None` for a part none of
    /// whose blocks is held (evicted by bounded memory without an archive:
    /// its triangles stay part of the map) or whose archived blocks cannot
    /// be read.
    pub fn part_meshes(&self, parts: &[IVec3]) -> Vec<Option<Mesh>> {
        if let Some(Bounded::Archive(a)) = &self.active {
            // A part is one block here. When some part is archived or reads
            // an archived block above it, the parts are meshed from memory
            // and archive together.
            let archived = |&k: &IVec3| ABOVE.iter().any(|&o| a.is_away(k + o));
            if parts.iter().any(archived) {
                return a.block_meshes(&self.volume, parts);
            }
        }
        let n = self.part_blocks();
        let sets: Vec<Vec<IVec3>> = parts
            .iter()
            .map(|&part| {
                (0..n * n * n)
                    .map(|i| part * n + IVec3::new(i % n, (i / n) % n, i / (n * n)))
                    .filter(|k| self.volume.index().contains_key(k))
                    .collect()
            })
            .collect();
        let meshes = extract_sets(&self.volume, &sets, self.cache.min_weight());
        sets.iter()
            .zip(meshes)
            .map(|(blocks, mesh)| (!blocks.is_empty()).then_some(mesh))
            .collect()
    }

    /// Ray casts the volume from `pose` (depth, points, normals).
    pub fn raycast(&self, intrinsics: &Intrinsics, pose: &Pose, out: &mut RaycastImage) {
        self.volume
            .raycast(intrinsics, pose, self.range.0, self.range.1, out);
    }
}

impl Mapper for TsdfMapper {
    fn name(&self) -> &'static str {
        "tsdf"
    }

    fn integrate(&mut self, frame: &Frame, pose: &Pose) -> Result<IntegrateReport> {
        let start = Instant::now();
        let blocks_before = self.volume.blocks().len();
        let evicted_before = self.evicted_blocks();
        let loaded = match &mut self.active {
            Some(Bounded::Archive(a)) => a.bring_back(&mut self.volume, pose.translation)?,
            _ => 0,
        };
        self.volume
            .integrate(&frame.depth, frame.color.as_ref(), &self.intrinsics, pose)?;
        let integrated = start.elapsed();
        let (at, depth) = self.last_view.get_or_insert_with(Default::default);
        *at = *pose;
        depth.reset(frame.depth.width, frame.depth.height);
        depth.data.copy_from_slice(&frame.depth.data);
        self.peak_blocks = self.peak_blocks.max(self.volume.blocks().len());
        match &mut self.active {
            Some(Bounded::Chunks(active)) => {
                let mesh = active.update(&mut self.volume, &mut self.cache, pose.translation);
                self.evicted_mesh.append(&mesh);
            }
            Some(Bounded::Archive(active)) => {
                active.evict(&mut self.volume, &mut self.cache, pose.translation)?;
            }
            None => {}
        }
        let evicted = start.elapsed() - integrated;
        let evicted_now = self.evicted_blocks() - evicted_before;
        let due = self.remesh_every > 0 && self.volume.frames().is_multiple_of(self.remesh_every);
        let remeshed = if due {
            self.cache.update(&self.volume)
        } else {
            0
        };
        let meshed = start.elapsed() - integrated - evicted;
        self.assembled = false;
        let mut extra = vec![
            ("blocks", self.volume.blocks().len() as f64),
            ("remeshed_blocks", remeshed as f64),
            ("integrate_ms", integrated.as_secs_f64() * 1e3),
            ("remesh_ms", meshed.as_secs_f64() * 1e3),
        ];
        if self.active.is_some() {
            extra.push(("evicted_blocks", self.evicted_blocks() as f64));
            extra.push(("evict_ms", evicted.as_secs_f64() * 1e3));
        }
        if self.archived() {
            extra.push(("loaded_blocks", loaded as f64));
        }
        let blocks = self.volume.blocks().len();
        Ok(IntegrateReport {
            // The map's elements are voxels, allocated a block at a time.
            // (Blocks brought back from an archive are not new.)
            new_elements: (blocks + evicted_now).saturating_sub(blocks_before + loaded)
                * super::BLOCK_VOXELS,
            // Evicted blocks leave memory, not the map: they are written out.
            removed_elements: 0,
            extra,
        })
    }

    fn render_depth(&self, intrinsics: &Intrinsics, pose: &Pose) -> DepthImage {
        let mut depth = DepthImage::default();
        // Tracking asks for the view of the frame just fused: start the
        // rays at what that frame measured.
        let hint = self
            .last_view
            .as_ref()
            .filter(|(at, _)| at == pose)
            .map(|(_, d)| (d, &self.intrinsics));
        self.volume
            .raycast_depth(intrinsics, pose, self.range, hint, &mut depth);
        depth
    }

    fn mesh(&mut self) -> &Mesh {
        if !self.assembled {
            self.cache.update(&self.volume);
            self.mesh = self.assemble(&self.cache);
            self.assembled = true;
        }
        &self.mesh
    }

    fn stats(&self) -> MapStats {
        MapStats {
            elements: self.volume.blocks().len() * super::BLOCK_VOXELS,
            vertices: self.assembled.then(|| self.mesh.vertex_count()),
            bytes: self.volume.voxel_bytes(),
        }
    }
}
