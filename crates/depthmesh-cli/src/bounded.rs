//! `--active-radius` on the mapping commands: the TSDF map in bounded memory.
//! Blocks the camera left behind are written to `OUT/chunks/chunk-NNNNNN.ply`
//! (at most 65,535 vertices each, global coordinates) and freed; at the end
//! `mesh.ply` is the chunks joined with the blocks still in memory.

use crate::export::RunExportArgs;
use crate::output::RunOutput;
use anyhow::{bail, Result};
use clap::Args;
use depthmesh::eval::fraction_within;
use depthmesh::mesh::chunk::DEFAULT_MAX_VERTICES;
use depthmesh::mesh::chunk_files::ChunkFiles;
use depthmesh::tsdf::evict::ActiveRegion;
use depthmesh::tsdf::mapper::TsdfMapper;
use depthmesh::Mesh;
use serde_json::{json, Map, Value};

/// The flag, shared by `reconstruct` and `simulate`.
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
    /// Rejects a radius that is not positive, the flag with other maps, and
    /// with `--export`, which needs the whole mesh in memory (export
    /// `mesh.ply` afterwards instead).
    pub fn check(&self, tsdf: bool, export: &RunExportArgs) -> Result<()> {
        let Some(radius) = self.active_radius else {
            return Ok(());
        };
        ActiveRegion::new(radius)?;
        if !tsdf {
            bail!("--active-radius applies to --map tsdf only");
        }
        if export.export.is_some() {
            bail!(
                "--export needs the whole mesh in memory, which --active-radius avoids: \
                 run `depthmesh export OUT/mesh.ply` afterwards"
            );
        }
        Ok(())
    }

    /// Bounds `mapper`'s memory and starts the chunk files, if the flag is given.
    pub fn start(&self, mapper: &mut TsdfMapper, out: &RunOutput) -> Result<Option<Chunks>> {
        let Some(radius) = self.active_radius else {
            return Ok(None);
        };
        mapper.set_active_radius(radius)?;
        if radius < mapper.reach() {
            eprintln!(
                "note: --active-radius {radius} m is less than the sensor's reach ({:.2} m): \
                 farther measurements are not fused",
                mapper.reach()
            );
        }
        Ok(Some(Chunks {
            radius,
            files: ChunkFiles::create(&out.path("chunks"), DEFAULT_MAX_VERTICES)?,
        }))
    }
}

/// The chunk files of a bounded run.
pub struct Chunks {
    radius: f32,
    files: ChunkFiles,
}

impl Chunks {
    /// Takes what the mapper wrote out during the last frame.
    pub fn after_frame(&mut self, mapper: &mut TsdfMapper) -> Result<()> {
        Ok(self.files.push(&mapper.take_evicted())?)
    }

    /// Writes the last chunk and adds `active_radius`, `chunks`,
    /// `evicted_blocks` and `peak_blocks` to the summary.
    pub fn summarise(
        &mut self,
        mapper: &TsdfMapper,
        summary: &mut Map<String, Value>,
    ) -> Result<()> {
        self.files.flush()?;
        summary.insert("active_radius".into(), json!(self.radius));
        summary.insert("sensor_reach".into(), json!(mapper.reach()));
        summary.insert("chunks".into(), json!(self.files.files().len()));
        summary.insert("evicted_blocks".into(), json!(mapper.evicted_blocks()));
        summary.insert("peak_blocks".into(), json!(mapper.peak_blocks()));
        Ok(())
    }

    /// Fraction of the whole map's surface (chunks and `rest`) within
    /// `tolerance` of `truth`, chunk by chunk, weighted by area.
    pub fn fraction_within(
        &self,
        rest: &Mesh,
        truth: &Mesh,
        tolerance: f32,
    ) -> Result<Option<f64>> {
        let (mut near, mut area) = (0.0, 0.0);
        self.files.for_each(rest, |m| {
            let a = m.area();
            // The spacing rule of the unbounded run, per chunk.
            let spacing = ((a / 1.0e6).sqrt() as f32).max(0.002);
            if let Some(f) = fraction_within(m, truth, tolerance, spacing) {
                near += f * a;
                area += a;
            }
            Ok(())
        })?;
        Ok((area > 0.0).then(|| near / area))
    }

    /// Writes the run's files with `mesh.ply` the chunks joined with `rest`.
    pub fn finish(
        &self,
        out: &RunOutput,
        map: &str,
        rest: &Mesh,
        map_bytes: usize,
        summary: Map<String, Value>,
    ) -> Result<Map<String, Value>> {
        out.finish_chunked(map, &self.files, rest, map_bytes, summary)
    }
}
