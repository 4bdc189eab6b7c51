//! One factory for the map back-ends: a [`MapConfig`] names the back-end
//! and carries its settings; [`Backend`] keeps the built mapper concrete, so
//! front ends can show what only one back-end has (MABDI's expected image,
//! the TSDF's ray cast) while the session drives it through [`Mapper`].

use super::Changed;
use crate::camera::Intrinsics;
use crate::error::{Error, Result};
use crate::mabdi::{MabdiConfig, MabdiMapper, NaiveMapper};
use crate::map::{IntegrateReport, Mapper};
use crate::planes::{PlanesConfig, PlanesMapper};
use crate::tsdf::mapper::TsdfMapper;
use crate::tsdf::{TsdfConfig, BLOCK_VOXELS};
use serde_json::{json, Map, Value};
use std::time::Instant;

/// Settings of the TSDF back-end.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TsdfSettings {
    /// Voxel size, truncation, weights, colour.
    pub config: TsdfConfig,
    /// Depths ray casting searches, metres: `(near, far)`.
    pub range: (f32, f32),
    /// Re-mesh changed blocks every this many frames (0: only on demand).
    pub remesh_every: u32,
    /// Bounded memory: keep and fuse only blocks within this many metres
    /// of the camera; the rest is meshed and handed out (see
    /// [`TsdfMapper::set_active_radius`]).
    pub active_radius: Option<f32>,
}

/// Settings of the voxel-planes back-end.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlanesSettings {
    /// Voxel and cell sizes, ε.
    pub config: PlanesConfig,
    /// Re-mesh changed windows every this many frames (0: only on demand).
    pub remesh_every: u32,
}

/// Which back-end a session maps with, and its settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MapConfig {
    /// MABDI mesh addition (its `intrinsics` are replaced by the session's).
    Mabdi(MabdiConfig),
    /// The thesis's traditional method: every frame's whole surface
    /// (its `intrinsics` are replaced by the session's).
    Naive(MabdiConfig),
    /// TSDF fusion with marching cubes.
    Tsdf(TsdfSettings),
    /// Voxel planes.
    Planes(PlanesSettings),
}

impl MapConfig {
    /// The back-end's name, as in files and summaries.
    pub fn name(&self) -> &'static str {
        match self {
            MapConfig::Mabdi(_) => "mabdi",
            MapConfig::Naive(_) => "naive",
            MapConfig::Tsdf(_) => "tsdf",
            MapConfig::Planes(_) => "planes",
        }
    }

    /// Builds the back-end for frames from `intrinsics`; settings that
    /// cannot work are errors naming the field.
    pub fn build(&self, intrinsics: Intrinsics) -> Result<Backend> {
        intrinsics.validate()?;
        Ok(match *self {
            MapConfig::Mabdi(c) => {
                Backend::Mabdi(Box::new(MabdiMapper::new(MabdiConfig { intrinsics, ..c })?))
            }
            MapConfig::Naive(c) => {
                Backend::Naive(Box::new(NaiveMapper::new(MabdiConfig { intrinsics, ..c })?))
            }
            MapConfig::Tsdf(s) => {
                let (near, far) = s.range;
                if !(near >= 0.0 && far > near && far.is_finite()) {
                    return Err(Error::parameter(
                        "range",
                        format!("need 0 ≤ near < far, got {near} and {far}"),
                    ));
                }
                let mut mapper = TsdfMapper::new(s.config, intrinsics, near, far)?;
                mapper.remesh_every = s.remesh_every;
                if let Some(r) = s.active_radius {
                    mapper.set_active_radius(r)?;
                }
                Backend::Tsdf(Box::new(mapper))
            }
            MapConfig::Planes(s) => {
                let mut mapper = PlanesMapper::new(s.config, intrinsics)?;
                mapper.remesh_every = s.remesh_every;
                Backend::Planes(Box::new(mapper))
            }
        })
    }
}

/// A built back-end, kept concrete for what only one of them offers.
#[derive(Debug)]
pub enum Backend {
    /// MABDI mesh addition.
    Mabdi(Box<MabdiMapper>),
    /// The traditional method.
    Naive(Box<NaiveMapper>),
    /// TSDF fusion.
    Tsdf(Box<TsdfMapper>),
    /// Voxel planes.
    Planes(Box<PlanesMapper>),
}

impl Backend {
    /// The back-end behind the common interface.
    pub fn mapper(&self) -> &dyn Mapper {
        match self {
            Backend::Mabdi(m) => m.as_ref(),
            Backend::Naive(m) => m.as_ref(),
            Backend::Tsdf(m) => m.as_ref(),
            Backend::Planes(m) => m.as_ref(),
        }
    }

    /// The back-end behind the common interface, to change.
    pub fn mapper_mut(&mut self) -> &mut dyn Mapper {
        match self {
            Backend::Mabdi(m) => m.as_mut(),
            Backend::Naive(m) => m.as_mut(),
            Backend::Tsdf(m) => m.as_mut(),
            Backend::Planes(m) => m.as_mut(),
        }
    }

    /// The TSDF mapper, if this is one.
    pub fn tsdf(&self) -> Option<&TsdfMapper> {
        match self {
            Backend::Tsdf(t) => Some(t),
            _ => None,
        }
    }

    /// The TSDF mapper, if this is one, to change.
    pub fn tsdf_mut(&mut self) -> Option<&mut TsdfMapper> {
        match self {
            Backend::Tsdf(t) => Some(t),
            _ => None,
        }
    }

    /// What the last fused frame, which reported `report`, changed.
    pub fn changed(&self, report: &IntegrateReport) -> Changed {
        match self {
            Backend::Tsdf(t) => {
                let v = t.volume();
                let frame = v.frames();
                Changed::Blocks(
                    v.blocks()
                        .iter()
                        .zip(v.changes())
                        .filter(|(_, c)| c.values[0] == frame)
                        .map(|(b, _)| b.key)
                        .collect(),
                )
            }
            Backend::Mabdi(_) | Backend::Naive(_) => Changed::Triangles {
                appended: report.new_elements,
                removed: report.removed_elements,
            },
            Backend::Planes(_) => Changed::Everything,
        }
    }

    /// Adds the keys only this back-end has to a run's summary: for the
    /// TSDF, `mesh_seconds` (a full extraction from scratch, comparable
    /// with other tools'), sizes and, when bounded, the active region's
    /// figures; for voxel planes, the paper's counts and parameters.
    pub fn summarise(&mut self, summary: &mut Map<String, Value>) {
        match self {
            Backend::Tsdf(t) => {
                let start = Instant::now();
                let _ = t.extract_mesh();
                summary.insert("mesh_seconds".into(), json!(start.elapsed().as_secs_f64()));
                let v = t.volume();
                let voxels = v.blocks().len() * BLOCK_VOXELS;
                summary.insert("voxel".into(), json!(v.config().voxel));
                summary.insert("truncation".into(), json!(v.config().truncation));
                summary.insert("blocks".into(), json!(v.blocks().len()));
                summary.insert("voxels".into(), json!(voxels));
                summary.insert(
                    "bytes_per_voxel".into(),
                    json!(v.voxel_bytes() as f64 / voxels.max(1) as f64),
                );
                if let Some(radius) = t.active_radius() {
                    summary.insert("active_radius".into(), json!(radius));
                    summary.insert("sensor_reach".into(), json!(t.reach()));
                    summary.insert("evicted_blocks".into(), json!(t.evicted_blocks()));
                    summary.insert("peak_blocks".into(), json!(t.peak_blocks()));
                    if let Some(loaded) = t.loaded_blocks() {
                        summary.insert("loaded_blocks".into(), json!(loaded));
                    }
                }
            }
            Backend::Planes(p) => {
                // Meshes first, so the planar count is current: the windows
                // changed since the last re-mesh, then assembly.
                let start = Instant::now();
                p.mesh();
                summary.insert("mesh_seconds".into(), json!(start.elapsed().as_secs_f64()));
                let config = p.grid().config();
                summary.insert("plane_voxel".into(), json!(config.voxel));
                summary.insert("plane_cell".into(), json!(config.cell));
                summary.insert("epsilon".into(), json!(p.epsilon()));
                summary.insert("voxels".into(), json!(p.grid().occupied_count()));
                summary.insert("planar_voxels".into(), json!(p.planar_count()));
                summary.insert(
                    "representation_bytes".into(),
                    json!(p.representation_bytes()),
                );
            }
            Backend::Mabdi(_) | Backend::Naive(_) => {}
        }
    }
}
