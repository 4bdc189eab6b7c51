//! The map in parts, for viewers that keep a copy of it up to date.
//!
//! A viewer (the browser view of `depthmesh serve`) holds the map as keyed
//! parts and is sent only the parts that changed, each whole, so that the
//! newest version of a part replaces any older one still waiting to be
//! sent. What a part is follows how each back-end changes:
//!
//! | back-end | part | key |
//! |---|---|---|
//! | TSDF | the triangles of the cubes 2³ blocks own (see [`crate::tsdf::mesh`]; one block with an active radius) | block coordinates ÷ 2 |
//! | voxel planes | the patches of a group of [`WINDOW_GROUP`]³ windows | group coordinates |
//! | MABDI | a patch: one iteration's novel surface, as removal and simplification left it | `[patch, 0, 0]` |
//! | traditional | runs of [`RUN`] triangles (it only appends) | `[run, 0, 0]` |
//!
//! Joined, the parts are the map's mesh, triangle for triangle (the TSDF's
//! border vertices appear in each block that uses them). Following costs
//! nothing until a viewer asks: [`Session::follow_parts`] starts it.

use super::{Backend, Session};
use crate::mesh::Mesh;
pub use crate::planes::mapper::WINDOW_GROUP;
use glam::IVec3;

/// A part's key (see the module docs for what it means per back-end).
pub type PartKey = [i32; 3];

/// Triangles per part of the traditional method's mesh.
pub const RUN: usize = 1 << 16;

impl Session {
    /// Starts following the map's parts for a viewer; returns the key of
    /// every part it has now (re-meshing what is due first). Calling it
    /// again starts over.
    pub fn follow_parts(&mut self) -> Vec<PartKey> {
        match &mut self.backend {
            Backend::Tsdf(t) => to_keys(t.follow_parts()),
            Backend::Planes(p) => to_keys(p.follow_groups()),
            Backend::Mabdi(m) => to_ids(m.follow_patches()),
            Backend::Naive(n) => {
                let triangles = n.mesh_ref().triangle_count();
                self.view_seen = Some(triangles);
                runs(0, triangles)
            }
        }
    }

    /// How many low bits of its parts' keys a viewer may drop to gather
    /// parts into drawn meshes about 64 cm (TSDF at 1 cm), eight patches
    /// (MABDI) or 32 plane windows across: a few hundred draw calls for a room.
    pub fn part_group_bits(&self) -> u32 {
        match &self.backend {
            Backend::Tsdf(t) => 3 - t.part_blocks().trailing_zeros(),
            Backend::Mabdi(_) => 3,
            Backend::Planes(_) => 2,
            Backend::Naive(_) => 0,
        }
    }

    /// The parts changed since the last call (or [`Session::follow_parts`]);
    /// empty while not followed.
    pub fn changed_parts(&mut self) -> Vec<PartKey> {
        match &mut self.backend {
            Backend::Tsdf(t) => to_keys(t.changed_parts()),
            Backend::Planes(p) => to_keys(p.changed_groups()),
            Backend::Mabdi(m) => to_ids(m.changed_patches()),
            Backend::Naive(n) => {
                let Some(seen) = self.view_seen else {
                    return Vec::new();
                };
                let triangles = n.mesh_ref().triangle_count();
                self.view_seen = Some(triangles);
                runs(seen, triangles)
            }
        }
    }

    /// The mesh of each part now: empty for a part that is gone, `None`
    /// for one the map no longer holds in memory (a TSDF block evicted by
    /// bounded memory, whose triangles stay part of the map).
    pub fn part_meshes(&self, keys: &[PartKey]) -> Vec<Option<Mesh>> {
        match &self.backend {
            Backend::Tsdf(t) => {
                let parts: Vec<IVec3> = keys.iter().map(|&k| k.into()).collect();
                t.part_meshes(&parts)
            }
            Backend::Planes(p) => {
                let groups: Vec<IVec3> = keys.iter().map(|&k| k.into()).collect();
                p.group_meshes(&groups).into_iter().map(Some).collect()
            }
            Backend::Mabdi(m) => {
                let ids: Vec<u32> = keys.iter().map(|k| k[0] as u32).collect();
                m.patch_meshes(&ids).into_iter().map(Some).collect()
            }
            Backend::Naive(n) => {
                let mesh = n.mesh_ref();
                let count = mesh.triangle_count();
                keys.iter()
                    .map(|k| {
                        let start = (k[0].max(0) as usize * RUN).min(count);
                        Some(mesh.triangle_range(start..(start + RUN).min(count)))
                    })
                    .collect()
            }
        }
    }
}

fn to_keys(keys: Vec<IVec3>) -> Vec<PartKey> {
    keys.into_iter().map(|k| k.to_array()).collect()
}

fn to_ids(ids: Vec<u32>) -> Vec<PartKey> {
    ids.into_iter().map(|id| [id as i32, 0, 0]).collect()
}

/// The runs holding triangles `from..to` of an append-only mesh.
fn runs(from: usize, to: usize) -> Vec<PartKey> {
    if to <= from {
        return Vec::new();
    }
    (from / RUN..to.div_ceil(RUN))
        .map(|r| [r as i32, 0, 0])
        .collect()
}
