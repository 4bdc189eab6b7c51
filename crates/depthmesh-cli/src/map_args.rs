//! The map flags shared by `reconstruct` and `serve`: which back-end, its
//! sizes, the depth range and bounded memory, turned into the library's
//! [`MapConfig`] once the camera is known.

use crate::bounded::ActiveRadiusArgs;
use crate::planes::PlanesArgs;
use anyhow::{bail, Result};
use clap::{Args, ValueEnum};
use depthmesh::mabdi::MabdiConfig;
use depthmesh::session::{MapConfig, PlanesSettings, TsdfSettings};
use depthmesh::tsdf::TsdfConfig;
use depthmesh::Intrinsics;

/// The back-ends a recorded or streamed sequence can be mapped with.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum RealMap {
    /// TSDF fusion with marching cubes.
    Tsdf,
    /// MABDI mesh addition.
    Mabdi,
    /// Voxel planes: per-voxel statistics, a plane patch per planar 2×2×2 window.
    Planes,
}

/// The TSDF's sizes and the depth range frames are read with: flags of the
/// commands that map, and a cluster site's settings.
#[derive(Args, Debug, Clone)]
pub struct TsdfArgs {
    /// Voxel size in metres (tsdf).
    #[arg(long, default_value_t = 0.01, allow_negative_numbers = true)]
    pub voxel: f32,
    /// Truncation distance in metres (tsdf; default 4 voxels).
    #[arg(long, allow_negative_numbers = true)]
    pub trunc: Option<f32>,
    /// Mesh only voxels fused from at least this many frames (tsdf; Open3D's
    /// weight threshold; 1 meshes all observed surface).
    #[arg(long, default_value_t = 1)]
    pub min_weight: u16,
    /// Nearer depths are dropped (metres).
    #[arg(long, default_value_t = 0.1, allow_negative_numbers = true)]
    pub depth_min: f32,
    /// Farther depths are dropped (metres).
    #[arg(long, default_value_t = 4.0, allow_negative_numbers = true)]
    pub depth_max: f32,
}

impl TsdfArgs {
    /// The TSDF settings (colour off).
    pub fn config(&self) -> TsdfConfig {
        let mut config = TsdfConfig::new(self.voxel);
        if let Some(t) = self.trunc {
            config.truncation = t;
        }
        config.min_weight = self.min_weight;
        config
    }

    /// Rejects a depth range that keeps nothing.
    pub fn check(&self) -> Result<()> {
        if !(self.depth_min >= 0.0 && self.depth_max > self.depth_min && self.depth_max.is_finite())
        {
            bail!(
                "need 0 ≤ --depth-min < --depth-max, got {} and {}",
                self.depth_min,
                self.depth_max
            );
        }
        Ok(())
    }
}

/// Flags that choose and size the map.
#[derive(Args, Debug, Clone)]
pub struct MapArgs {
    /// Map back-end.
    #[arg(long, value_enum, default_value_t = RealMap::Tsdf)]
    pub map: RealMap,
    #[command(flatten)]
    pub tsdf: TsdfArgs,
    /// Keep colour from the colour images (tsdf; 3 more bytes per voxel).
    #[arg(long)]
    pub color: bool,
    #[command(flatten)]
    pub planes: PlanesArgs,
    /// Re-mesh the changed blocks (tsdf) or windows (planes) every N frames (0: once, at the end).
    #[arg(long, default_value_t = 0)]
    pub remesh_every: u32,
    #[command(flatten)]
    pub bounded: ActiveRadiusArgs,
    /// Mesh novel surface from the measured depth as it came, not smoothed
    /// on each surface first (mabdi).
    #[arg(long)]
    pub no_smooth: bool,
}

impl MapArgs {
    /// Rejects flags that do not go together, before any frame is read.
    pub fn check(&self) -> Result<()> {
        self.tsdf.check()?;
        if self.color && self.map != RealMap::Tsdf {
            bail!("--color applies to --map tsdf only");
        }
        if self.tsdf.min_weight != 1 && self.map != RealMap::Tsdf {
            bail!("--min-weight applies to --map tsdf only");
        }
        if self.no_smooth && self.map != RealMap::Mabdi {
            bail!("--no-smooth applies to --map mabdi only");
        }
        self.bounded.check(self.map == RealMap::Tsdf)
    }

    /// The map these flags describe, for frames from `intrinsics`.
    pub fn config(&self, intrinsics: Intrinsics) -> MapConfig {
        match self.map {
            RealMap::Tsdf => {
                let mut config = self.tsdf.config();
                config.color = self.color;
                MapConfig::Tsdf(TsdfSettings {
                    config,
                    range: (self.tsdf.depth_min, self.tsdf.depth_max),
                    remesh_every: self.remesh_every,
                    active_radius: self.bounded.active_radius,
                })
            }
            // The thesis's thresholds are calibrated for a Kinect's 0.8–4 m
            // z-buffer, whatever depth range the frames are read with.
            RealMap::Mabdi => {
                let mut mabdi = MabdiConfig::thesis(intrinsics, 0.8, 4.0);
                if self.no_smooth {
                    mabdi.smoothing = None;
                }
                MapConfig::Mabdi(mabdi)
            }
            RealMap::Planes => MapConfig::Planes(PlanesSettings {
                config: self.planes.config(),
                remesh_every: self.remesh_every,
            }),
        }
    }
}
