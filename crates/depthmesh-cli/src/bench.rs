//! `depthmesh bench`: speed figures measured on generated data, printed as
//! JSON so scripts can set them beside a reference implementation's.

use crate::planes::PlanesArgs;
use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use depthmesh::atomic::write_atomic;
use depthmesh::codec::{Codec, Decoder, Encoder, RawDepth};
use depthmesh::dataset::{Dataset, DatasetOptions, FrameRange};
use depthmesh::mabdi::{MabdiConfig, MabdiMapper, NaiveMapper};
use depthmesh::map::Mapper;
use depthmesh::mesh::ply::{write_ply, PlyFormat};
use depthmesh::planes::mapper::frame_points;
use depthmesh::planes::runs::depth_runs;
use depthmesh::planes::PlaneGrid;
use depthmesh::sim::{NoiseModel, PathSpec, Scene, SceneOptions, SimulatedSensor};
use depthmesh::trajectory::format_tum;
use serde_json::json;
use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

/// The table scene (built in, like the demo's).
pub const TABLE_SCENE: &str = include_str!("../../../scenes/table.toml");

/// Benchmarks.
#[derive(Subcommand, Debug)]
pub enum BenchCommand {
    /// Time full MABDI iterations (render D, render E, classify, mesh, append)
    /// against a global mesh of at least `--min-triangles`.
    Mabdi(MabdiBenchArgs),
    /// Points per second folded into the voxel-planes statistics on
    /// recorded depth frames: from the depth images as the mapper does it,
    /// and from ready world points (`insert_points`).
    Planes(PlanesBenchArgs),
    /// Bytes per frame, compression ratio and encode/decode times of every
    /// depth codec on a recorded dataset's depth frames, decoded and checked lossless.
    Codec(CodecBenchArgs),
}

/// Flags of `depthmesh bench codec`.
#[derive(Args, Debug)]
pub struct CodecBenchArgs {
    /// A 7-Scenes frames folder or TUM RGB-D folder.
    pub dataset: PathBuf,
    /// Frame numbers to use, `A..B` (half-open).
    #[arg(long, default_value = "0..60")]
    pub frames: FrameRange,
    /// Timed passes over all frames per codec; the median is reported.
    #[arg(long, default_value_t = 3)]
    pub repeats: u32,
}

/// Flags of `depthmesh bench planes`.
#[derive(Args, Debug)]
pub struct PlanesBenchArgs {
    /// A 7-Scenes frames folder or TUM RGB-D folder with poses.
    pub dataset: PathBuf,
    /// Frame numbers to use, `A..B` (half-open), as everywhere; their points
    /// are inserted in one timed pass. A range beyond the dataset is refused.
    #[arg(long, default_value = "0..100")]
    pub frames: FrameRange,
    /// Timed passes, each into a fresh map; the median is reported.
    #[arg(long, default_value_t = 5)]
    pub repeats: u32,
    #[command(flatten)]
    pub planes: PlanesArgs,
}

/// Flags of `depthmesh bench mabdi`.
#[derive(Args, Debug)]
pub struct MabdiBenchArgs {
    /// Smallest global mesh M to time against.
    #[arg(long, default_value_t = 1_000_000)]
    pub min_triangles: usize,
    /// Timed iterations.
    #[arg(long, default_value_t = 20)]
    pub iterations: u32,
    /// Where to write M (`mesh.ply`) and the timed poses (`poses.txt`) for a
    /// reference renderer.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Time iterations without object removal (no evidence gathered while E
    /// is rendered), as `simulate --keep-removed` runs; recorded in the JSON
    /// as `removal`.
    #[arg(long)]
    pub keep_removed: bool,
}

/// Runs a benchmark.
pub fn run(command: &BenchCommand) -> Result<()> {
    match command {
        BenchCommand::Mabdi(args) => mabdi(args),
        BenchCommand::Planes(args) => planes(args),
        BenchCommand::Codec(args) => codec(args),
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn planes(args: &PlanesBenchArgs) -> Result<()> {
    if args.repeats == 0 {
        bail!("--repeats must be at least 1");
    }
    let options = DatasetOptions {
        frames: Some(args.frames),
        ..DatasetOptions::default()
    };
    let dataset = Dataset::open(&args.dataset, &options)?;
    if dataset.is_empty() {
        bail!("--frames: no frames of {} selected", args.dataset.display());
    }
    if let Some(end) = args.frames.end {
        if dataset.len() < end.saturating_sub(args.frames.start) {
            bail!(
                "--frames {}..{end}: {} has only {} of those frames",
                args.frames.start,
                args.dataset.display(),
                dataset.len()
            );
        }
    }
    let k = dataset.intrinsics();
    // Frames are read (PNG decoding) before timing.
    let mut frames = Vec::with_capacity(dataset.len());
    for frame in dataset.frames() {
        let frame = frame?;
        let pose = frame
            .pose
            .with_context(|| format!("frame {} has no pose", frame.index))?;
        frames.push((frame.depth, pose));
    }
    let config = args.planes.config().grid;
    // The mapper's path: pixels → world points → runs → statistics.
    let mut runs = Vec::new();
    let (mut depth_seconds, mut points, mut voxels) = (Vec::new(), 0, 0);
    for _ in 0..args.repeats {
        let mut grid = PlaneGrid::new(config)?;
        let start = Instant::now();
        points = 0;
        for (depth, pose) in &frames {
            depth_runs(&grid, depth, &k, pose, &mut runs);
            points += grid.insert_stats(&runs).points;
        }
        depth_seconds.push(start.elapsed().as_secs_f64());
        voxels = grid.occupied_count();
    }
    // A point cloud's path: world points (made before timing) → statistics.
    let clouds: Vec<Vec<_>> = frames
        .iter()
        .map(|(depth, pose)| {
            let mut cloud = Vec::new();
            frame_points(depth, &k, pose, &mut cloud);
            cloud
        })
        .collect();
    let mut cloud_seconds = Vec::new();
    for _ in 0..args.repeats {
        let mut grid = PlaneGrid::new(config)?;
        let start = Instant::now();
        for cloud in &clouds {
            grid.insert_points(cloud);
        }
        cloud_seconds.push(start.elapsed().as_secs_f64());
    }
    let (depth_s, cloud_s) = (median(depth_seconds), median(cloud_seconds));
    println!(
        "{}",
        json!({
            "bench": "planes_insert",
            "frames": frames.len(),
            "points": points,
            "voxels": voxels,
            "voxel": args.planes.plane_voxel,
            "threads": rayon::current_num_threads(),
            "depth_median_seconds": depth_s,
            "points_per_second": points as f64 / depth_s,
            "cloud_median_seconds": cloud_s,
            "cloud_points_per_second": points as f64 / cloud_s,
        })
    );
    Ok(())
}

fn mabdi(args: &MabdiBenchArgs) -> Result<()> {
    if args.iterations == 0 {
        bail!("--iterations must be at least 1");
    }
    let scene = Scene::parse(
        TABLE_SCENE,
        "scenes/table.toml".as_ref(),
        &SceneOptions::default(),
    )?;
    // M: the thesis's traditional method over the start of one helix, which
    // piles up overlapping full-frame surfaces until M is big enough.
    let build_poses = PathSpec::Helix.build(&scene, 30)?;
    let mut sensor = SimulatedSensor::kinect(NoiseModel::None, 0);
    let mut config = MabdiConfig::thesis(sensor.intrinsics, sensor.near, sensor.far);
    if args.keep_removed {
        config.removal = None;
    }
    let mut naive = NaiveMapper::new(config)?;
    for (i, pose) in build_poses.iter().enumerate() {
        if naive.stats().elements >= args.min_triangles {
            break;
        }
        naive.integrate(&sensor.capture(&scene, i as u32 + 1, pose), pose)?;
    }
    let m = naive.mesh().clone();
    if m.triangle_count() < args.min_triangles {
        bail!(
            "could not build a global mesh of {} triangles",
            args.min_triangles
        );
    }
    // Timed: a second helix at other angles, so E is never the view M was made from.
    let poses = PathSpec::Helix.build(&scene, args.iterations + 1)?;
    let poses = &poses[1..];
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("--out {}: cannot create the folder", dir.display()))?;
        write_ply(&dir.join("mesh.ply"), &m, PlyFormat::BinaryLittleEndian)?;
        let stamped: Vec<_> = poses
            .iter()
            .enumerate()
            .map(|(i, p)| (i as f64, *p))
            .collect();
        let tum = format_tum(&stamped);
        write_atomic(&dir.join("poses.txt"), |w| w.write_all(tum.as_bytes()))?;
    }
    let triangles = m.triangle_count();
    let mut mapper = MabdiMapper::with_mesh(config, m)?;
    let (mut total, mut sense, mut stages) = (Vec::new(), Vec::new(), vec![Vec::new(); 4]);
    for (i, pose) in poses.iter().enumerate() {
        let start = Instant::now();
        let frame = sensor.capture(&scene, i as u32 + 1, pose);
        let d = start.elapsed().as_secs_f64() * 1e3;
        let report = mapper.integrate(&frame, pose)?;
        total.push(start.elapsed().as_secs_f64() * 1e3);
        sense.push(d);
        for (k, name) in ["render_ms", "classify_ms", "removal_ms", "mesh_ms"]
            .iter()
            .enumerate()
        {
            stages[k].push(report.get(name).unwrap_or(0.0));
        }
    }
    let [render_e, classify, removal, mesh]: [f64; 4] = stages
        .into_iter()
        .map(median)
        .collect::<Vec<_>>()
        .try_into()
        .expect("four stages");
    let iteration = median(total);
    println!(
        "{}",
        json!({
            "bench": "mabdi_iteration",
            "width": sensor.intrinsics.width,
            "height": sensor.intrinsics.height,
            "fx": sensor.intrinsics.fx,
            "cx": sensor.intrinsics.cx,
            "cy": sensor.intrinsics.cy,
            "triangles": triangles,
            "iterations": args.iterations,
            "removal": !args.keep_removed,
            "threads": rayon::current_num_threads(),
            "median_ms": iteration,
            "hz": 1000.0 / iteration,
            "render_d_ms": median(sense),
            "render_e_ms": render_e,
            "classify_ms": classify,
            "removal_ms": removal,
            "mesh_append_ms": mesh,
        })
    );
    Ok(())
}

fn codec(args: &CodecBenchArgs) -> Result<()> {
    if args.repeats == 0 {
        bail!("--repeats must be at least 1");
    }
    let options = DatasetOptions {
        frames: Some(args.frames),
        ..DatasetOptions::default()
    };
    let dataset = Dataset::open(&args.dataset, &options)?;
    // Frames are read (PNG decoding) before timing.
    let mut frames = Vec::with_capacity(dataset.len());
    for i in 0..dataset.len() {
        let mut raw = RawDepth::default();
        dataset.raw_depth(i, &mut raw)?;
        frames.push(raw);
    }
    let raw_bytes = frames[0].data().len() * 2;
    let max_pixels = frames
        .iter()
        .map(|f| f.data().len() as u64)
        .max()
        .unwrap_or(0);
    let mut results = Vec::new();
    for codec in Codec::ALL {
        let mut encoder = Encoder::new(codec);
        let mut streams: Vec<Vec<u8>> = vec![Vec::new(); frames.len()];
        let encode_ms = timed_passes(args.repeats, frames.len(), || {
            for (frame, stream) in frames.iter().zip(&mut streams) {
                encoder.encode(frame, stream);
            }
        });
        let mut decoder = Decoder::new(codec, max_pixels);
        let mut decoded = vec![RawDepth::default(); frames.len()];
        let mut failure = None;
        let decode_ms = timed_passes(args.repeats, frames.len(), || {
            for (stream, out) in streams.iter().zip(&mut decoded) {
                if let Err(e) = decoder.decode_into(stream, out) {
                    failure.get_or_insert(e);
                }
            }
        });
        if let Some(e) = failure {
            bail!("{codec} could not decode its own stream: {e}");
        }
        if let Some(i) = (0..frames.len()).find(|&i| decoded[i] != frames[i]) {
            bail!(
                "{codec} is not lossless on the {}-th frame of {}",
                i + 1,
                args.frames
            );
        }
        let bytes = streams.iter().map(Vec::len).sum::<usize>() as f64 / frames.len() as f64;
        results.push(json!({
            "name": codec.name(),
            "bytes_per_frame": bytes,
            "ratio": raw_bytes as f64 / bytes,
            "encode_ms": encode_ms,
            "decode_ms": decode_ms,
        }));
    }
    println!(
        "{}",
        json!({
            "bench": "codec",
            "frames": frames.len(),
            "width": frames[0].width(),
            "height": frames[0].height(),
            "threads": rayon::current_num_threads(),
            "default": Codec::default().name(),
            "codecs": results,
        })
    );
    Ok(())
}

/// The median over `repeats` passes of `pass`, in milliseconds per frame.
fn timed_passes(repeats: u32, frames: usize, mut pass: impl FnMut()) -> f64 {
    let seconds = (0..repeats)
        .map(|_| {
            let start = Instant::now();
            pass();
            start.elapsed().as_secs_f64()
        })
        .collect();
    median(seconds) * 1e3 / frames as f64
}
