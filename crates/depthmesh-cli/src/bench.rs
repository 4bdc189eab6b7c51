//! `depthmesh bench`: speed figures measured on generated data, printed as
//! JSON so scripts can set them beside a reference implementation's.

use crate::planes::PlanesArgs;
use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use depthmesh::atomic::write_atomic;
use depthmesh::codec::{Codec, Decoder, Encoder, RawDepth};
use depthmesh::dataset::{Dataset, DatasetOptions, FrameRange};
use depthmesh::eval::distance::MeshDistance;
use depthmesh::eval::{area_on, fraction_within, triangles_on};
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
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The table scene (built in, like the demo's).
pub const TABLE_SCENE: &str = include_str!("../../../scenes/table.toml");

/// Benchmarks.
#[derive(Subcommand, Debug)]
pub enum BenchCommand {
    /// Time full MABDI iterations (render D, render E, classify, mesh, append)
    /// against a global mesh of at least `--min-triangles`.
    Mabdi(MabdiBenchArgs),
    /// Object removal on a simulated scene in a dynamic run: the triangles
    /// of M on each object with removal and without (`--keep-removed`), and
    /// for removed objects how many are left 15 iterations after they went.
    MabdiRemoval(MabdiRemovalArgs),
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
    /// Timed passes over all frames per codec; the median frame time is reported.
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

/// Flags of `depthmesh bench mabdi-removal`.
#[derive(Args, Debug)]
pub struct MabdiRemovalArgs {
    /// Scene file (TOML); its `dynamic` lifetimes apply.
    #[arg(long)]
    pub scene: PathBuf,
    /// Mesh for a scene's `${bunny}` path.
    #[arg(long)]
    pub bunny: Option<PathBuf>,
    /// Iterations of the helix.
    #[arg(long, default_value_t = 50)]
    pub iterations: u32,
    /// Sensor noise: none, zbuffer:SIGMA or kinect.
    #[arg(long, default_value = "zbuffer:0.002")]
    pub noise: NoiseModel,
    /// Iterations after an object's removal at which what is left of it is counted.
    #[arg(long, default_value_t = 15)]
    pub after: u32,
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
        BenchCommand::MabdiRemoval(args) => mabdi_removal(args),
        BenchCommand::Planes(args) => planes(args),
        BenchCommand::Codec(args) => codec(args),
    }
}

/// The frames `frames` of the dataset at `path` for a benchmark of
/// `repeats` passes: a range reaching past the data is refused rather than
/// silently cut short.
fn bench_dataset(path: &Path, frames: FrameRange, repeats: u32) -> Result<Dataset> {
    if repeats == 0 {
        bail!("--repeats must be at least 1");
    }
    let options = DatasetOptions {
        frames: Some(frames),
        ..DatasetOptions::default()
    };
    let dataset = Dataset::open(path, &options)?;
    if dataset.is_empty() {
        bail!("--frames: no frames of {} selected", path.display());
    }
    if let Some(end) = frames.end {
        if dataset.len() < end.saturating_sub(frames.start) {
            bail!(
                "--frames {}..{end}: {} has only {} of those frames",
                frames.start,
                path.display(),
                dataset.len()
            );
        }
    }
    Ok(dataset)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn planes(args: &PlanesBenchArgs) -> Result<()> {
    let dataset = bench_dataset(&args.dataset, args.frames, args.repeats)?;
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
    let dataset = bench_dataset(&args.dataset, args.frames, args.repeats)?;
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
        let encode_ms = median_frame_ms(args.repeats, frames.len(), |i| {
            encoder.encode(&frames[i], &mut streams[i]);
        });
        let mut decoder = Decoder::new(codec, max_pixels);
        let mut decoded = vec![RawDepth::default(); frames.len()];
        let mut failure = None;
        let decode_ms = median_frame_ms(args.repeats, frames.len(), |i| {
            if let Err(e) = decoder.decode_into(&streams[i], &mut decoded[i]) {
                failure.get_or_insert(e);
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
            "timing": "median CPU ms per frame, one thread",
            "default": Codec::default().name(),
            "codecs": results,
        })
    );
    Ok(())
}

fn mabdi_removal(args: &MabdiRemovalArgs) -> Result<()> {
    if args.iterations == 0 || args.after == 0 {
        bail!("--iterations and --after must be at least 1");
    }
    let mut options = SceneOptions {
        dynamic: true,
        ..Default::default()
    };
    if let Some(bunny) = &args.bunny {
        options.variables.insert("bunny".into(), bunny.clone());
    }
    let scene = Scene::load(&args.scene, &options)?;
    // The same scene with nothing taken away or added: a run of it with
    // removal is what present objects are compared with besides a
    // `--keep-removed` run, which adds surface again behind a stale object.
    let unchanged = Scene::load(
        &args.scene,
        &SceneOptions {
            dynamic: false,
            ..options.clone()
        },
    )?;
    let poses = PathSpec::Helix.build(&scene, args.iterations)?;
    let mut sensor = SimulatedSensor::kinect(args.noise, 0);
    let mut unchanged_sensor = SimulatedSensor::kinect(args.noise, 0);
    let config = MabdiConfig::thesis(sensor.intrinsics, sensor.near, sensor.far);
    let mut removing = MabdiMapper::new(config)?;
    let mut keeping = MabdiMapper::new(MabdiConfig {
        removal: None,
        ..config
    })?;
    let mut steady = MabdiMapper::new(config)?;
    // A triangle is on an object within 1 cm of it and not within 5 cm of another.
    let index: Vec<(MeshDistance, MeshDistance)> = (0..scene.objects.len())
        .map(|i| {
            let mut rest = depthmesh::Mesh::default();
            for (_, o) in scene.objects.iter().enumerate().filter(|(j, _)| *j != i) {
                rest.append(&o.mesh);
            }
            (
                MeshDistance::new(&scene.objects[i].mesh, 0.01),
                MeshDistance::new(&rest, 0.05),
            )
        })
        .collect();
    let on = |m: &mut MabdiMapper, i: usize| triangles_on(m.mesh(), &index[i].0, &index[i].1);
    // Per removed object: the most triangles on it before it went, and what is left `after` iterations on.
    let mut peak = vec![0; scene.objects.len()];
    let mut left = vec![None; scene.objects.len()];
    for (i, pose) in poses.iter().enumerate() {
        let iteration = i as u32 + 1;
        let frame = sensor.capture(&scene, iteration, pose);
        removing.integrate(&frame, pose)?;
        keeping.integrate(&frame, pose)?;
        steady.integrate(&unchanged_sensor.capture(&unchanged, iteration, pose), pose)?;
        for (o, object) in scene.objects.iter().enumerate() {
            match object.remove_at {
                Some(r) if iteration < r => peak[o] = peak[o].max(on(&mut removing, o)),
                Some(r) if iteration + 1 == r + args.after => left[o] = Some(on(&mut removing, o)),
                _ => {}
            }
        }
    }
    let objects: Vec<_> = scene
        .objects
        .iter()
        .enumerate()
        .map(|(o, object)| {
            let (with, without) = (on(&mut removing, o), on(&mut keeping, o));
            let present = object.remove_at.is_none() && object.appear_at.is_none();
            let unchanged = present.then(|| on(&mut steady, o));
            // Surface of the object with M within 1 cm: unlike triangles, not
            // raised by surface added again behind a stale object; the area
            // of M's triangles on it over that surface says how many layers
            // of it M holds.
            let mapped = |m: &mut MabdiMapper| {
                let share = fraction_within(&object.mesh, m.mesh(), 0.01, 0.01);
                let covered = share.unwrap_or(0.0) * object.mesh.area();
                let area = area_on(m.mesh(), &index[o].0, &index[o].1);
                (share, (covered > 0.0).then(|| area / covered))
            };
            let (surface, layers) = mapped(&mut removing);
            let (surface_kept, layers_kept) = mapped(&mut keeping);
            json!({
                "name": object.name,
                "returns": object.returns,
                "appear_at": object.appear_at,
                "remove_at": object.remove_at,
                "triangles": with,
                "triangles_keep_removed": without,
                "kept_vs_keep_removed": with as f64 / without.max(1) as f64,
                "triangles_unchanged_scene": unchanged,
                "kept_vs_unchanged_scene": unchanged.map(|u| with as f64 / u.max(1) as f64),
                "surface_mapped": surface,
                "surface_mapped_keep_removed": surface_kept,
                "surface_layers": layers,
                "surface_layers_keep_removed": layers_kept,
                "peak_before_removal": object.remove_at.map(|_| peak[o]),
                "left_after": left[o],
                "gone_after": left[o].map(|l| 1.0 - l as f64 / peak[o].max(1) as f64),
            })
        })
        .collect();
    println!(
        "{}",
        json!({
            "bench": "mabdi_removal",
            "scene": scene.name,
            "iterations": args.iterations,
            "after": args.after,
            "noise": args.noise.to_string(),
            "triangles": removing.stats().elements,
            "triangles_keep_removed": keeping.stats().elements,
            "objects": objects,
        })
    );
    Ok(())
}

/// The median CPU time of `frame(i)` over every frame and `repeats` passes,
/// in milliseconds. CPU time of the calling thread (every codec runs on it
/// alone), so time lost to other processes on a shared machine counts for
/// no codec, short or long.
fn median_frame_ms(repeats: u32, frames: usize, mut frame: impl FnMut(usize)) -> f64 {
    let mut seconds = Vec::with_capacity(repeats as usize * frames);
    for _ in 0..repeats {
        for i in 0..frames {
            let start = thread_cpu_seconds();
            frame(i);
            seconds.push(thread_cpu_seconds() - start);
        }
    }
    median(seconds) * 1e3
}

/// CPU seconds the calling thread has used.
fn thread_cpu_seconds() -> f64 {
    let mut time = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime only writes the one timespec it is given, which
    // lives through the call; this clock exists on every Unix the tool runs on.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut time) };
    time.tv_sec as f64 + time.tv_nsec as f64 * 1e-9
}
