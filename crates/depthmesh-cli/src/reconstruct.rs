//! `depthmesh reconstruct`: a recorded depth sequence into a map, with the
//! data's poses or tracked ones.

use crate::bounded::ActiveRadiusArgs;
use crate::draw::canvas::Canvas;
use crate::draw::colormap::normal_shade;
use crate::export::RunExportArgs;
use crate::output::{FrameStats, RunOutput};
use crate::planes::{self, PlanesArgs};
use crate::progress;
use crate::tracking::PoseSource;
use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use depthmesh::atomic::write_atomic;
use depthmesh::dataset::{Dataset, DatasetOptions, FrameRange, IntrinsicsSpec};
use depthmesh::mabdi::{MabdiConfig, MabdiMapper};
use depthmesh::map::Mapper;
use depthmesh::planes::PlanesMapper;
use depthmesh::tsdf::mapper::TsdfMapper;
use depthmesh::tsdf::raycast::RaycastImage;
use depthmesh::tsdf::{TsdfConfig, BLOCK_VOXELS};
use depthmesh::{Intrinsics, Pose};
use glam::Vec3;
use serde_json::{json, Map};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The back-ends `reconstruct` can drive.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum ReconstructMap {
    /// TSDF fusion with marching cubes.
    Tsdf,
    /// MABDI mesh addition.
    Mabdi,
    /// Voxel planes: per-voxel statistics, a plane patch per planar 2×2×2 window.
    Planes,
}

/// Flags of `depthmesh reconstruct`.
#[derive(Args, Debug, Clone)]
pub struct ReconstructArgs {
    /// A 7-Scenes frames folder or a TUM RGB-D folder (detected).
    pub dataset: PathBuf,
    /// Map back-end.
    #[arg(long, value_enum, default_value_t = ReconstructMap::Tsdf)]
    pub map: ReconstructMap,
    /// Voxel size in metres (tsdf).
    #[arg(long, default_value_t = 0.01)]
    pub voxel: f32,
    /// Truncation distance in metres (tsdf; default 4 voxels).
    #[arg(long)]
    pub trunc: Option<f32>,
    /// Keep colour from the dataset's colour images (tsdf; 3 more bytes per voxel).
    #[arg(long)]
    pub color: bool,
    /// Frame numbers to use, half-open: A..B, A.. or ..B.
    #[arg(long)]
    pub frames: Option<FrameRange>,
    /// Use every K-th frame.
    #[arg(long, default_value_t = 1)]
    pub stride: usize,
    /// Nearer depths are dropped (metres).
    #[arg(long, default_value_t = 0.1)]
    pub depth_min: f32,
    /// Farther depths are dropped (metres).
    #[arg(long, default_value_t = 4.0)]
    pub depth_max: f32,
    /// Intrinsics fx,fy,cx,cy[,width,height] or a file (3×3 K, or "w h fx fy cx cy").
    #[arg(long)]
    pub intrinsics: Option<String>,
    #[command(flatten)]
    pub planes: PlanesArgs,
    /// Re-mesh the changed blocks (tsdf) or windows (planes) every N frames (0: once, at the end).
    #[arg(long, default_value_t = 0)]
    pub remesh_every: u32,
    /// Write a shaded ray-cast "status image" of the map every N frames (tsdf).
    #[arg(long, default_value_t = 0)]
    pub status_every: usize,
    /// Estimate poses by ICP against the map (only the first frame's pose is
    /// taken from the data, or the origin when it has none).
    #[arg(long)]
    pub track: bool,
    /// Go on past unreadable frames, reporting them.
    #[arg(long)]
    pub skip_bad_frames: bool,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub export: RunExportArgs,
    #[command(flatten)]
    pub bounded: ActiveRadiusArgs,
}

/// Runs `reconstruct`.
pub fn run(args: &ReconstructArgs, quiet: bool) -> Result<()> {
    args.export.check()?;
    args.bounded
        .check(args.map == ReconstructMap::Tsdf, &args.export)?;
    if args.stride == 0 {
        bail!("--stride must be at least 1");
    }
    if !(args.depth_min >= 0.0 && args.depth_max > args.depth_min && args.depth_max.is_finite()) {
        bail!(
            "need 0 ≤ --depth-min < --depth-max, got {} and {}",
            args.depth_min,
            args.depth_max
        );
    }
    let options = DatasetOptions {
        frames: args.frames,
        stride: args.stride,
        depth_min: args.depth_min,
        depth_max: args.depth_max,
        intrinsics: args
            .intrinsics
            .as_deref()
            .map(IntrinsicsSpec::from_arg)
            .transpose()?,
        color: args.color,
        skip_bad_frames: args.skip_bad_frames,
    };
    let dataset = Dataset::open(&args.dataset, &options)?;
    if dataset.is_empty() {
        bail!("{}: no frames selected", args.dataset.display());
    }
    let k = dataset.intrinsics();
    let mut map = match args.map {
        ReconstructMap::Tsdf => {
            let mut config = TsdfConfig::new(args.voxel);
            if let Some(t) = args.trunc {
                config.truncation = t;
            }
            config.color = args.color;
            let mut mapper = TsdfMapper::new(config, k, args.depth_min, args.depth_max)?;
            mapper.remesh_every = args.remesh_every;
            RealMap::Tsdf(Box::new(mapper))
        }
        // The thesis's thresholds are calibrated for a Kinect's 0.8–4 m
        // z-buffer, whatever depth range the dataset is read with.
        ReconstructMap::Mabdi => RealMap::Mabdi(Box::new(MabdiMapper::new(MabdiConfig::thesis(
            k, 0.8, 4.0,
        ))?)),
        ReconstructMap::Planes => {
            let mut mapper = args.planes.mapper(k)?;
            mapper.remesh_every = args.remesh_every;
            RealMap::Planes(Box::new(mapper))
        }
    };
    let mut raycast = RaycastImage::default();
    let mut out = RunOutput::create(&args.out)?;
    let mut chunks = match &mut map {
        RealMap::Tsdf(t) => args.bounded.start(t, &out)?,
        RealMap::Mabdi(_) | RealMap::Planes(_) => None,
    };
    let bar = progress::bar(dataset.len() as u64, "reconstruct", quiet);
    let mut poses = PoseSource::new(args.track, k);
    let mut frames = dataset.frames();
    for frame in frames.by_ref() {
        let frame = frame?;
        let start = Instant::now();
        let fused = poses.fuse(&frame, frame.pose, map.mapper(), &bar, "frame")?;
        if let Some(pose) = fused.pose {
            out.trajectory.push((frame.timestamp, pose));
        }
        let report = fused.report;
        let ms = start.elapsed().as_secs_f64() * 1e3;
        let stats = map.mapper().stats();
        out.frames.push(FrameStats {
            frame: frame.index,
            ms,
            report,
            total_elements: stats.elements,
            total_vertices: stats.vertices,
            track: fused.track,
        });
        if let RealMap::Tsdf(t) = &mut map {
            if let Some(c) = &mut chunks {
                c.after_frame(t)?;
            }
        }
        if let (RealMap::Tsdf(t), Some(pose)) = (&map, fused.pose) {
            if args.status_every > 0 && out.frames.len() % args.status_every == 0 {
                write_status_image(t, &k, &pose, &mut raycast, &out.path("status"), frame.index)?;
            }
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    for s in frames.skipped() {
        eprintln!("skipped frame {}: {}", s.index, s.error);
    }
    if out.frames.is_empty() {
        bail!("{}: no frame could be read", args.dataset.display());
    }

    let mut summary = Map::new();
    summary.insert("dataset".into(), args.dataset.display().to_string().into());
    summary.insert("skipped_frames".into(), json!(frames.skipped().len()));
    poses.summarize(&mut summary);
    summary.insert(
        "integrate_fps".into(),
        json!(out.frames.len() as f64 / out.seconds()),
    );
    let start = Instant::now();
    let (name, bytes, mesh) = match &mut map {
        RealMap::Tsdf(t) => {
            // Timed from scratch, comparable with other tools' extraction;
            // the incrementally kept mesh is the same by construction.
            let mesh = t.extract_mesh();
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
            if let Some(c) = &mut chunks {
                c.summarise(t, &mut summary)?;
            }
            (t.name(), v.voxel_bytes(), mesh)
        }
        RealMap::Mabdi(m) => {
            let bytes = m.stats().bytes;
            (m.name(), bytes, m.mesh().clone())
        }
        RealMap::Planes(p) => {
            // The windows changed since the last re-mesh, then assembly.
            planes::summarise(p, &mut summary);
            summary.insert("mesh_seconds".into(), json!(start.elapsed().as_secs_f64()));
            let bytes = p.stats().bytes;
            (p.name(), bytes, p.mesh().clone())
        }
    };
    match &chunks {
        Some(c) => c.finish(&out, name, &mesh, bytes, summary)?,
        None => out.finish(name, &mesh, bytes, summary)?,
    };
    args.export.write(&mesh, &args.out)?;
    Ok(())
}

/// The map seen from the camera, shaded by its normals (KinectFusion's
/// status view), as `status/frame-NNNNNN.png`.
fn write_status_image(
    map: &TsdfMapper,
    k: &Intrinsics,
    pose: &Pose,
    raycast: &mut RaycastImage,
    dir: &Path,
    frame: usize,
) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    map.raycast(k, pose, raycast);
    let light = pose.transform_vector(Vec3::new(0.3, -0.5, -1.0));
    let mut canvas = Canvas::new(k.width, k.height, [0; 3]);
    for ((px, &d), &n) in canvas
        .pixels
        .iter_mut()
        .zip(&raycast.depth.data)
        .zip(&raycast.normals)
    {
        if d > 0.0 {
            *px = [(230.0 * normal_shade(n, light)) as u8; 3];
        }
    }
    let png = canvas.encode_png();
    write_atomic(&dir.join(format!("frame-{frame:06}.png")), |w| {
        w.write_all(&png)
    })?;
    Ok(())
}

/// The back-ends, kept concrete for what only one of them reports.
enum RealMap {
    Tsdf(Box<TsdfMapper>),
    Mabdi(Box<MabdiMapper>),
    Planes(Box<PlanesMapper>),
}

impl RealMap {
    fn mapper(&mut self) -> &mut dyn Mapper {
        match self {
            RealMap::Tsdf(m) => m.as_mut(),
            RealMap::Mabdi(m) => m.as_mut(),
            RealMap::Planes(m) => m.as_mut(),
        }
    }
}
