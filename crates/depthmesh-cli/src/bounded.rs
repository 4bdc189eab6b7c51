//! `--active-radius` on the mapping commands: the TSDF map in bounded memory.
//! Blocks the camera left behind are written to `OUT/chunks/chunk-NNNNNN.ply`
//! (at most 65,535 vertices each, global coordinates) and freed; at the end
//! `mesh.ply` is the chunks joined with the blocks still in memory (see
//! `depthmesh::session::run_files`). With `--store`, freed blocks go to the
//! store instead and come back when the camera returns; the chunks and
//! `mesh.ply` are then made from the store and memory at the end.

use crate::export::RunExportArgs;
use anyhow::{bail, Result};
use clap::Args;
use depthmesh::session::Session;
use depthmesh::tsdf::evict::ActiveRegion;

/// The flag, shared by the mapping commands.
#[derive(Args, Debug, Clone, Default)]
pub struct ActiveRadiusArgs {
    /// Bounded memory (tsdf): keep and fuse only blocks within R metres of the
    /// camera; farther blocks are written to chunks/ and freed, and mesh.ply is
    /// their union with the rest. Choose R beyond the sensor's reach to keep
    /// every measurement.
    #[arg(long, value_name = "R")]
    pub active_radius: Option<f32>,
}

impl ActiveRadiusArgs {
    /// Rejects a radius that is not positive, and the flag with other maps.
    pub fn check(&self, tsdf: bool) -> Result<()> {
        let Some(radius) = self.active_radius else {
            return Ok(());
        };
        if let Err(e) = ActiveRegion::new(radius) {
            bail!("invalid --active-radius: {e}");
        }
        if !tsdf {
            bail!("--active-radius applies to --map tsdf only");
        }
        Ok(())
    }

    /// Rejects `--export` with the flag: it needs the whole mesh in memory
    /// (export `mesh.ply` afterwards instead).
    pub fn check_export(&self, export: &RunExportArgs) -> Result<()> {
        if self.active_radius.is_some() && export.export.is_some() {
            bail!(
                "--export needs the whole mesh in memory, which --active-radius avoids: \
                 run `depthmesh export OUT/mesh.ply` afterwards"
            );
        }
        Ok(())
    }

    /// Says so when the radius drops measurements the sensor makes.
    pub fn note_reach(&self, session: &Session) {
        let (Some(radius), Some(t)) = (self.active_radius, session.backend().tsdf()) else {
            return;
        };
        if radius < t.reach() {
            eprintln!(
                "note: --active-radius {radius} m is less than the sensor's reach ({:.2} m): \
                 farther measurements are not fused",
                t.reach()
            );
        }
    }
}
