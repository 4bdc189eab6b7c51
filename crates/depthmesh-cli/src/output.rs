//! The output contract of a mapping run (DESIGN.md): `mesh.ply`,
//! `trajectory.txt`, `stats.csv` and `summary.json` in the `--out` folder,
//! each written whole or not at all.

use anyhow::{Context, Result};
use depthmesh::atomic::write_atomic;
use depthmesh::map::IntegrateReport;
use depthmesh::mesh::chunk_files::ChunkFiles;
use depthmesh::mesh::ply::{write_ply, PlyFormat, PlyLayout};
use depthmesh::trajectory::format_tum;
use depthmesh::{Mesh, Pose};
use serde_json::{Map, Value};
use std::io::Write;
use std::path::{Path, PathBuf};

/// One row of `stats.csv`.
#[derive(Clone, Debug)]
pub struct FrameStats {
    /// Frame number (iteration for the simulator).
    pub frame: usize,
    /// Milliseconds the iteration took: the sensor's frame and the mapping,
    /// without drawing or file writing.
    pub ms: f64,
    /// What the mapper reported.
    pub report: IntegrateReport,
    /// Map size after the frame.
    pub total_elements: usize,
    /// Mesh vertices after the frame.
    pub total_vertices: usize,
    /// How the frame was tracked, when poses are tracked.
    pub track: Option<TrackStats>,
}

/// The tracking columns of a `stats.csv` row.
#[derive(Clone, Copy, Debug)]
pub struct TrackStats {
    /// Milliseconds spent tracking (part of the row's `ms`).
    pub ms: f64,
    /// Fraction of the frame's points matched with the map.
    pub inlier_fraction: f64,
    /// RMS point-to-plane error of the matches in millimetres.
    pub residual_mm: f64,
    /// How well the view pins down all six degrees of freedom (0: not at all).
    pub conditioning: f64,
    /// Whether the frame was lost (and not fused).
    pub lost: bool,
}

/// Collects what a run produces and writes the contract files.
#[derive(Debug)]
pub struct RunOutput {
    dir: PathBuf,
    /// Per-frame rows, in order.
    pub frames: Vec<FrameStats>,
    /// Timestamped poses used for the frames.
    pub trajectory: Vec<(f64, Pose)>,
}

impl RunOutput {
    /// Prepares `dir` (created if missing).
    pub fn create(dir: &Path) -> Result<Self> {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create output folder {}", dir.display()))?;
        Ok(RunOutput {
            dir: dir.to_path_buf(),
            frames: Vec::new(),
            trajectory: Vec::new(),
        })
    }

    /// A path inside the output folder.
    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// Total iteration time in seconds.
    pub fn seconds(&self) -> f64 {
        self.frames.iter().map(|f| f.ms).sum::<f64>() / 1000.0
    }

    /// Writes `mesh.ply`, `trajectory.txt`, `stats.csv` and, last,
    /// `summary.json`: an old summary is removed first, so a summary always
    /// describes the files beside it, even when a later write fails.
    /// `summary` holds the back-end specific keys; the common ones are added
    /// here, and the whole summary is returned.
    pub fn finish(
        &self,
        map: &str,
        mesh: &Mesh,
        map_bytes: usize,
        summary: Map<String, Value>,
    ) -> Result<Map<String, Value>> {
        self.finish_with(map, PlyLayout::of(mesh), map_bytes, summary, |path| {
            Ok(write_ply(path, mesh, PlyFormat::BinaryLittleEndian)?)
        })
    }

    /// As [`RunOutput::finish`], for a map written out in chunks: `mesh.ply`
    /// is the chunks joined with `rest`, streamed from the chunk files.
    pub fn finish_chunked(
        &self,
        map: &str,
        chunks: &ChunkFiles,
        rest: &Mesh,
        map_bytes: usize,
        summary: Map<String, Value>,
    ) -> Result<Map<String, Value>> {
        let mut layout = chunks.written();
        layout.vertices += rest.vertex_count();
        layout.triangles += rest.triangle_count();
        self.finish_with(map, layout, map_bytes, summary, |path| {
            Ok(chunks.write_joined(path, rest)?)
        })
    }

    fn finish_with(
        &self,
        map: &str,
        mesh: PlyLayout,
        map_bytes: usize,
        mut summary: Map<String, Value>,
        write_mesh: impl FnOnce(&Path) -> Result<()>,
    ) -> Result<Map<String, Value>> {
        let summary_path = self.path("summary.json");
        if summary_path.exists() {
            std::fs::remove_file(&summary_path)
                .with_context(|| format!("cannot replace {}", summary_path.display()))?;
        }
        write_mesh(&self.path("mesh.ply"))?;
        let tum = format_tum(&self.trajectory);
        write_atomic(&self.path("trajectory.txt"), |w| {
            w.write_all(tum.as_bytes())
        })?;
        self.write_stats()?;
        let seconds = self.seconds();
        let frames = self.frames.len();
        summary.insert("frames".into(), frames.into());
        summary.insert("seconds".into(), seconds.into());
        summary.insert(
            "fps".into(),
            if seconds > 0.0 {
                frames as f64 / seconds
            } else {
                0.0
            }
            .into(),
        );
        summary.insert("map".into(), map.into());
        summary.insert("triangles".into(), mesh.triangles.into());
        summary.insert("vertices".into(), mesh.vertices.into());
        summary.insert("map_bytes".into(), map_bytes.into());
        let text = serde_json::to_string_pretty(&summary)?;
        write_atomic(&summary_path, |w| writeln!(w, "{text}"))?;
        Ok(summary)
    }

    fn write_stats(&self) -> Result<()> {
        // Every back-end figure any row reported, in first-seen order; a row
        // without one (a frame lost by tracking) leaves its field empty.
        let mut extra: Vec<&str> = Vec::new();
        for f in &self.frames {
            for (k, _) in &f.report.extra {
                if !extra.contains(k) {
                    extra.push(k);
                }
            }
        }
        let tracked = self.frames.iter().any(|f| f.track.is_some());
        write_atomic(&self.path("stats.csv"), |w| {
            write!(
                w,
                "frame,ms,new_elements,removed_elements,total_elements,total_vertices"
            )?;
            for k in &extra {
                write!(w, ",{k}")?;
            }
            if tracked {
                write!(w, ",track_ms,inlier_fraction,residual_mm,conditioning,lost")?;
            }
            writeln!(w)?;
            for f in &self.frames {
                write!(
                    w,
                    "{},{:.3},{},{},{},{}",
                    f.frame,
                    f.ms,
                    f.report.new_elements,
                    f.report.removed_elements,
                    f.total_elements,
                    f.total_vertices
                )?;
                for &k in &extra {
                    match f.report.get(k) {
                        Some(v) if v.fract() == 0.0 => write!(w, ",{v}")?,
                        Some(v) => write!(w, ",{v:.3}")?,
                        None => write!(w, ",")?,
                    }
                }
                match (tracked, f.track) {
                    (true, Some(t)) => write!(
                        w,
                        ",{:.3},{:.4},{:.3},{:.5},{}",
                        t.ms,
                        t.inlier_fraction,
                        t.residual_mm,
                        t.conditioning,
                        u8::from(t.lost)
                    )?,
                    (true, None) => write!(w, ",,,,,0")?,
                    (false, _) => {}
                }
                writeln!(w)?;
            }
            Ok(())
        })?;
        Ok(())
    }
}
