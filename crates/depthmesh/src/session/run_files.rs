//! The output contract of a mapping run (DESIGN.md): `mesh.ply`,
//! `trajectory.txt`, `stats.csv` and `summary.json` in one folder, each
//! written whole or not at all; with bounded memory also the chunk files of
//! the blocks the camera left behind, written as they are evicted (or, when
//! they go to a map store, from the store and memory at the end).

use super::{Backend, Session};
use crate::atomic::write_atomic;
use crate::error::{Error, Result};
use crate::eval::fraction_within;
use crate::mesh::chunk::DEFAULT_MAX_VERTICES;
use crate::mesh::chunk_files::ChunkFiles;
use crate::mesh::ply::{write_ply, PlyFormat, PlyLayout};
use crate::mesh::Mesh;
use crate::track::degeneracy::axes_label;
use crate::trajectory::format_tum;
use serde_json::{json, Map, Value};
use std::io::Write;
use std::path::{Path, PathBuf};

/// The files of one run, in one folder.
#[derive(Debug)]
pub struct RunFiles {
    dir: PathBuf,
    /// `chunks/chunk-NNNNNN.ply`, for a session with bounded memory.
    chunks: Option<ChunkFiles>,
    /// Whether the chunks hold the whole map (an archived bounded map, once
    /// meshed at the end; see [`RunFiles::settle`]).
    settled: bool,
}

impl RunFiles {
    /// Prepares `dir` (created if missing) for `session`'s files; a
    /// bounded TSDF session's chunk files go to `dir/chunks` (chunk files of
    /// an earlier run there are removed).
    pub fn create(dir: &Path, session: &Session) -> Result<Self> {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        let bounded = session
            .backend()
            .tsdf()
            .is_some_and(|t| t.active_radius().is_some());
        let chunks = bounded
            .then(|| ChunkFiles::create(&dir.join("chunks"), DEFAULT_MAX_VERTICES))
            .transpose()?;
        Ok(RunFiles {
            dir: dir.to_path_buf(),
            chunks,
            settled: false,
        })
    }

    /// A path inside the run's folder.
    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// Writes what the session's last frame evicted (bounded memory) to the
    /// chunk files; call after every frame.
    pub fn after_frame(&mut self, session: &mut Session) -> Result<()> {
        if let (Some(files), Backend::Tsdf(t)) = (&mut self.chunks, session.backend_mut()) {
            files.push(&t.take_evicted())?;
        }
        Ok(())
    }

    /// A bounded map whose blocks went to an archive is meshed into the
    /// chunk files once, from the archive and memory, a slab at a time; the
    /// mesh still held is then already in the chunks. Returns that mesh:
    /// the session's, or an empty one after settling.
    fn settle<'a>(&mut self, session: &'a mut Session, empty: &'a Mesh) -> Result<&'a Mesh> {
        let archived = session.backend().tsdf().is_some_and(|t| t.archived());
        if !archived {
            return Ok(session.mesh());
        }
        if let (Some(files), Some(t), false) = (
            &mut self.chunks,
            session.backend_mut().tsdf_mut(),
            self.settled,
        ) {
            t.mesh_all(|m| files.push(&m))?;
            self.settled = true;
        }
        Ok(empty)
    }

    /// Fraction of the whole map's surface — chunks written and the mesh
    /// still held — within `tolerance` of `truth`, weighted by area
    /// (`None` for an empty map). About a million samples per part keeps it
    /// to about a second a part.
    pub fn fraction_within(
        &mut self,
        session: &mut Session,
        truth: &Mesh,
        tolerance: f32,
    ) -> Result<Option<f64>> {
        let (mut near, mut area) = (0.0, 0.0);
        let mut judge = |m: &Mesh| {
            let a = m.area();
            let spacing = ((a / 1.0e6).sqrt() as f32).max(0.002);
            if let Some(f) = fraction_within(m, truth, tolerance, spacing) {
                near += f * a;
                area += a;
            }
            Ok(())
        };
        let empty = Mesh::default();
        let rest = self.settle(session, &empty)?;
        match &self.chunks {
            Some(files) => files.for_each(rest, judge)?,
            None => judge(rest)?,
        }
        Ok((area > 0.0).then(|| near / area))
    }

    /// Writes `mesh.ply` (the chunks joined with the mesh still held),
    /// `trajectory.txt`, `stats.csv` and, last, `summary.json`: an old
    /// summary is removed first, so a summary always describes the files
    /// beside it. `summary` holds the front end's keys; the session's and the
    /// common ones (`frames`, `seconds`, `fps`, `map`, `triangles`,
    /// `vertices`, `map_bytes`, and `chunks` when bounded) are added here,
    /// and the whole summary is returned.
    pub fn finish(
        &mut self,
        session: &mut Session,
        mut summary: Map<String, Value>,
    ) -> Result<Map<String, Value>> {
        let summary_path = self.path("summary.json");
        if summary_path.exists() {
            std::fs::remove_file(&summary_path).map_err(|e| Error::io(&summary_path, e))?;
        }
        summary.extend(session.summarise());
        let map_bytes = session.backend().mapper().stats().bytes;
        let name = session.backend().mapper().name();
        let mesh_path = self.path("mesh.ply");
        let empty = Mesh::default();
        let rest = self.settle(session, &empty)?;
        let layout = match &mut self.chunks {
            Some(files) => {
                files.flush()?;
                summary.insert("chunks".into(), json!(files.files().len()));
                files.write_joined(&mesh_path, rest)?;
                let mut layout = files.written();
                layout.vertices += rest.vertex_count();
                layout.triangles += rest.triangle_count();
                layout
            }
            None => {
                write_ply(&mesh_path, rest, PlyFormat::BinaryLittleEndian)?;
                PlyLayout::of(rest)
            }
        };
        let tum = format_tum(&session.trajectory());
        let path = self.path("trajectory.txt");
        write_atomic(&path, |w| w.write_all(tum.as_bytes()))?;
        write_stats(&self.path("stats.csv"), session)?;
        let seconds = session.seconds();
        let frames = session.records().len();
        summary.insert("frames".into(), frames.into());
        summary.insert("seconds".into(), seconds.into());
        let fps = if seconds > 0.0 {
            frames as f64 / seconds
        } else {
            0.0
        };
        summary.insert("fps".into(), fps.into());
        summary.insert("map".into(), name.into());
        summary.insert("triangles".into(), layout.triangles.into());
        summary.insert("vertices".into(), layout.vertices.into());
        summary.insert("map_bytes".into(), map_bytes.into());
        let text = serde_json::to_string_pretty(&summary)
            .map_err(|e| Error::format(&summary_path, e.to_string()))?;
        write_atomic(&summary_path, |w| writeln!(w, "{text}"))?;
        Ok(summary)
    }
}

/// `stats.csv`: a row per frame. Every back-end figure any row reported
/// comes as a column, in first-seen order; a row without one (a frame lost
/// by tracking) leaves its field empty, as does `total_vertices` while the
/// kept mesh is older than the map.
fn write_stats(path: &Path, session: &Session) -> Result<()> {
    let records = session.records();
    let mut extra: Vec<&str> = Vec::new();
    for r in records {
        for (k, _) in &r.report.extra {
            if !extra.contains(k) {
                extra.push(k);
            }
        }
    }
    let tracked = records.iter().any(|r| r.track.is_some());
    write_atomic(path, |w| {
        write!(
            w,
            "frame,ms,new_elements,removed_elements,total_elements,total_vertices"
        )?;
        for k in &extra {
            write!(w, ",{k}")?;
        }
        if tracked {
            write!(
                w,
                ",track_ms,inlier_fraction,residual_mm,conditioning,lost,icp_iterations,\
                 weak_directions,weak_axes,relocalised,recovered,held"
            )?;
        }
        writeln!(w)?;
        for r in records {
            write!(
                w,
                "{},{:.3},{},{},{},",
                r.frame, r.ms, r.report.new_elements, r.report.removed_elements, r.total_elements,
            )?;
            if let Some(v) = r.total_vertices {
                write!(w, "{v}")?;
            }
            for &k in &extra {
                match r.report.get(k) {
                    Some(v) if v.fract() == 0.0 => write!(w, ",{v}")?,
                    Some(v) => write!(w, ",{v:.3}")?,
                    None => write!(w, ",")?,
                }
            }
            match (tracked, r.track) {
                (true, Some(t)) => write!(
                    w,
                    ",{:.3},{:.4},{:.3},{:.5},{},{},{},{},{},{},{}",
                    t.ms,
                    t.inlier_fraction,
                    t.residual_mm,
                    t.conditioning,
                    u8::from(t.lost.is_some()),
                    t.iterations,
                    t.weak_directions,
                    axes_label(t.weak_axes),
                    u8::from(t.relocalised),
                    u8::from(t.recovered),
                    u8::from(t.held)
                )?,
                (true, None) => write!(w, ",,,,,0,,,,0,0,0")?,
                (false, _) => {}
            }
            writeln!(w)?;
        }
        Ok(())
    })
}
