//! The TSDF back-end behind the common [`Mapper`] interface: fuse, keep the
//! mesh of changed blocks up to date, predict depth by ray casting.

use super::mesh::MeshCache;
use super::raycast::RaycastImage;
use super::{TsdfConfig, TsdfVolume};
use crate::camera::{Intrinsics, Pose};
use crate::error::Result;
use crate::image::{DepthImage, Frame};
use crate::map::{IntegrateReport, MapStats, Mapper};
use crate::mesh::Mesh;
use std::time::Instant;

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
            cache: MeshCache::new(1),
            mesh: Mesh::default(),
            assembled: true,
            range: (near, far),
            last_view: None,
        })
    }

    /// The fused volume.
    pub fn volume(&self) -> &TsdfVolume {
        &self.volume
    }

    /// A full marching-cubes extraction from scratch (what the kept,
    /// incrementally updated mesh equals).
    pub fn extract_mesh(&self) -> Mesh {
        let mut cache = MeshCache::new(1);
        cache.update(&self.volume);
        cache.assemble()
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
        self.volume
            .integrate(&frame.depth, frame.color.as_ref(), &self.intrinsics, pose)?;
        let integrated = start.elapsed();
        let (at, depth) = self.last_view.get_or_insert_with(Default::default);
        *at = *pose;
        depth.reset(frame.depth.width, frame.depth.height);
        depth.data.copy_from_slice(&frame.depth.data);
        let due = self.remesh_every > 0 && self.volume.frames().is_multiple_of(self.remesh_every);
        let remeshed = if due {
            self.cache.update(&self.volume)
        } else {
            0
        };
        let meshed = start.elapsed() - integrated;
        self.assembled = false;
        Ok(IntegrateReport {
            // The map's elements are voxels, allocated a block at a time.
            new_elements: (self.volume.blocks().len() - blocks_before) * super::BLOCK_VOXELS,
            removed_elements: 0,
            extra: vec![
                ("blocks", self.volume.blocks().len() as f64),
                ("remeshed_blocks", remeshed as f64),
                ("integrate_ms", integrated.as_secs_f64() * 1e3),
                ("remesh_ms", meshed.as_secs_f64() * 1e3),
            ],
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
            self.mesh = self.cache.assemble();
            self.assembled = true;
        }
        &self.mesh
    }

    fn stats(&self) -> MapStats {
        MapStats {
            elements: self.volume.blocks().len() * super::BLOCK_VOXELS,
            vertices: self.mesh.vertex_count(),
            bytes: self.volume.voxel_bytes(),
        }
    }
}
