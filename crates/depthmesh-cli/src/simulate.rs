//! `depthmesh simulate`: a simulated sensor follows a path through a scene
//! file and a map back-end builds the mesh.

use crate::bounded::ActiveRadiusArgs;
use crate::export::RunExportArgs;
use crate::output::{FrameStats, RunOutput};
use crate::planes::{self, PlanesArgs};
use crate::progress;
use crate::tracking::PoseSource;
use crate::views::{self, Dashboard, MapperView};
use anyhow::{bail, Result};
use clap::{Args, ValueEnum};
use depthmesh::atomic::write_atomic;
use depthmesh::eval::fraction_within;
use depthmesh::eval::trajectory::trajectory_error;
use depthmesh::mabdi::classify::Threshold;
use depthmesh::mabdi::{MabdiConfig, MabdiMapper, NaiveMapper};
use depthmesh::map::Mapper;
use depthmesh::mesh::ply::{write_ply, PlyFormat};
use depthmesh::planes::PlanesMapper;
use depthmesh::sim::{NoiseModel, PathSpec, Scene, SceneOptions, SimulatedSensor};
use depthmesh::trajectory::format_tum;
use depthmesh::tsdf::mapper::TsdfMapper;
use depthmesh::tsdf::TsdfConfig;
use depthmesh::Pose;
use serde_json::{json, Map, Value};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// More iterations than this is a typo, not a run (each keeps its pose and stats).
const MAX_ITERATIONS: u32 = 100_000;

/// The map back-ends `simulate` can drive.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum MapKind {
    /// MABDI mesh addition: only surface the map does not predict is added.
    Mabdi,
    /// The thesis's traditional method: every frame's whole surface is added.
    Naive,
    /// TSDF fusion with marching cubes.
    Tsdf,
    /// Voxel planes: per-voxel statistics, a plane patch per planar 2×2×2 window.
    Planes,
}

/// Flags of `depthmesh simulate`.
#[derive(Args, Debug, Clone)]
pub struct SimulateArgs {
    /// Scene file (TOML; see scenes/example.toml).
    #[arg(long)]
    pub scene: PathBuf,
    /// Map back-end.
    #[arg(long, value_enum, default_value_t = MapKind::Mabdi)]
    pub map: MapKind,
    /// Number of sensor poses along the path.
    #[arg(long, default_value_t = 30)]
    pub iterations: u32,
    /// Depth noise: none, zbuffer:SIGMA (thesis eq. 4.2, e.g. zbuffer:0.002) or kinect.
    #[arg(long, default_value = "none")]
    pub noise: NoiseModel,
    /// Let objects appear and disappear as the scene's `dynamic` entries say.
    #[arg(long)]
    pub dynamic: bool,
    /// Seed of the noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Mesh file for `${bunny}` in scene files (e.g. the Stanford bunny PLY).
    #[arg(long)]
    pub bunny: Option<PathBuf>,
    /// Sensor path: helix (the thesis's), line, or tum:FILE.
    #[arg(long, default_value = "helix")]
    pub path: PathSpec,
    /// Novelty threshold in metres (default: the thesis's 0.01 in normalised depth, ≈ 0.01·z² m).
    #[arg(long)]
    pub threshold: Option<f32>,
    /// Keep triangles the sensor sees through (the thesis's behaviour) instead of removing them.
    #[arg(long)]
    pub keep_removed: bool,
    /// Voxel size in metres (tsdf; truncation 4 voxels).
    #[arg(long, default_value_t = 0.01)]
    pub voxel: f32,
    /// Estimate poses by ICP against the map (only the first pose of the
    /// path is given); `trajectory.txt` then holds the estimates,
    /// `groundtruth.txt` the true poses, and the summary their error.
    #[arg(long)]
    pub track: bool,
    #[command(flatten)]
    pub planes: PlanesArgs,
    /// Write a dashboard image per iteration and the element plot (mabdi, naive).
    #[arg(long)]
    pub dashboard: bool,
    /// Write `view.png`: the final mesh, lit and in its colours, from the
    /// dashboard's third-person camera.
    #[arg(long)]
    pub view: bool,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub export: RunExportArgs,
    #[command(flatten)]
    pub bounded: ActiveRadiusArgs,
}

/// The back-ends `simulate` drives, kept concrete so the dashboard can show
/// their internals (E, the pixel classes).
enum SimMap {
    Mabdi(Box<MabdiMapper>),
    Naive(Box<NaiveMapper>),
    Tsdf(Box<TsdfMapper>),
    Planes(Box<PlanesMapper>),
}

impl SimMap {
    fn mapper(&mut self) -> &mut dyn Mapper {
        match self {
            SimMap::Mabdi(m) => m.as_mut(),
            SimMap::Naive(m) => m.as_mut(),
            SimMap::Tsdf(m) => m.as_mut(),
            SimMap::Planes(m) => m.as_mut(),
        }
    }

    /// What the dashboard shows of the last frame, which added `new_triangles`
    /// (dashboards show mesh addition, so only its back-ends have one).
    fn view(&self, new_triangles: usize) -> Option<MapperView<'_>> {
        Some(match self {
            SimMap::Mabdi(m) => MapperView {
                mesh: m.mesh_ref(),
                new_triangles,
                expected: Some(m.expected()),
                classes: m.classes(),
            },
            SimMap::Naive(m) => MapperView {
                mesh: m.mesh_ref(),
                new_triangles,
                expected: None,
                classes: m.classes(),
            },
            SimMap::Tsdf(_) | SimMap::Planes(_) => return None,
        })
    }
}

/// What a finished run reports to the caller (the demo's table).
#[derive(Debug, Clone)]
pub struct RunSummary {
    /// The summary.json content.
    pub summary: Map<String, Value>,
}

/// Loads the scene named by the flags (or an embedded one via `text`).
pub fn load_scene(path: &Path, text: Option<&str>, args: &SimulateArgs) -> Result<Scene> {
    let mut options = SceneOptions {
        dynamic: args.dynamic,
        ..SceneOptions::default()
    };
    if let Some(bunny) = &args.bunny {
        options.variables.insert("bunny".into(), bunny.clone());
    }
    Ok(match text {
        Some(text) => Scene::parse(text, path, &options)?,
        None => Scene::load(path, &options)?,
    })
}

/// Runs `simulate` with the scene file of the flags.
pub fn run(args: &SimulateArgs, quiet: bool) -> Result<RunSummary> {
    let scene = load_scene(&args.scene, None, args)?;
    run_scene(args, &scene, quiet)
}

/// Runs `simulate` on an already loaded scene.
pub fn run_scene(args: &SimulateArgs, scene: &Scene, quiet: bool) -> Result<RunSummary> {
    if !(1..=MAX_ITERATIONS).contains(&args.iterations) {
        bail!(
            "--iterations must be between 1 and {MAX_ITERATIONS}, got {}",
            args.iterations
        );
    }
    if let Some(t) = args.threshold {
        if !(t.is_finite() && t > 0.0) {
            bail!("--threshold must be a positive number of metres, got {t}");
        }
    }
    args.export.check()?;
    args.bounded
        .check(args.map == MapKind::Tsdf, &args.export)?;
    let poses = args.path.build(scene, args.iterations)?;
    let mut sensor = SimulatedSensor::kinect(args.noise, args.seed);
    let mut config = MabdiConfig::thesis(sensor.intrinsics, sensor.near, sensor.far);
    if let Some(t) = args.threshold {
        config.novelty = Threshold::Metres(t);
    }
    if args.keep_removed {
        config.removal = None;
    }
    if args.dashboard && matches!(args.map, MapKind::Tsdf | MapKind::Planes) {
        bail!("--dashboard shows mesh addition: use it with --map mabdi or --map naive");
    }
    let mut map = match args.map {
        MapKind::Mabdi => SimMap::Mabdi(Box::new(MabdiMapper::new(config)?)),
        MapKind::Naive => SimMap::Naive(Box::new(NaiveMapper::new(config)?)),
        MapKind::Tsdf => SimMap::Tsdf(Box::new(TsdfMapper::new(
            TsdfConfig::new(args.voxel),
            sensor.intrinsics,
            sensor.near,
            sensor.far,
        )?)),
        MapKind::Planes => SimMap::Planes(Box::new(args.planes.mapper(sensor.intrinsics)?)),
    };
    let mut out = RunOutput::create(&args.out)?;
    let mut chunks = match &mut map {
        SimMap::Tsdf(t) => args.bounded.start(t, &out)?,
        _ => None,
    };
    let mut dashboard = args
        .dashboard
        .then(|| {
            Dashboard::new(
                map.mapper().name(),
                scene,
                &poses,
                sensor.intrinsics,
                &out.path("dashboard"),
            )
        })
        .transpose()?;

    let bar = progress::bar(poses.len() as u64, scene.name.as_str(), quiet);
    let mut sensor_ms = Vec::with_capacity(poses.len());
    let mut tracking = PoseSource::new(args.track, sensor.intrinsics);
    for (i, truth) in poses.iter().enumerate() {
        let iteration = i as u32 + 1;
        let start = Instant::now();
        let frame = sensor.capture(scene, iteration, truth);
        let captured = start.elapsed().as_secs_f64() * 1e3;
        let fused = tracking.fuse(&frame, Some(*truth), map.mapper(), &bar, "iteration")?;
        if let Some(pose) = fused.pose {
            out.trajectory.push((frame.timestamp, pose));
        }
        let report = fused.report;
        let ms = start.elapsed().as_secs_f64() * 1e3;
        if let (SimMap::Tsdf(t), Some(c)) = (&mut map, &mut chunks) {
            c.after_frame(t)?;
        }
        let stats = map.mapper().stats();
        let new_triangles = report.new_elements;
        sensor_ms.push(captured);
        out.frames.push(FrameStats {
            frame: iteration as usize,
            ms,
            report,
            total_elements: stats.elements,
            total_vertices: stats.vertices,
            track: fused.track,
        });
        if let (Some(d), Some(view)) = (dashboard.as_mut(), map.view(new_triangles)) {
            d.draw(iteration, scene, &frame.depth, &view, &out.frames)?;
        }
        bar.set_message(format!("{} elements", stats.elements));
        bar.inc(1);
    }
    bar.finish_and_clear();

    let last = args.iterations;
    let truth = scene.world_mesh(last).0;
    write_ply(
        &out.path("scene.ply"),
        &truth,
        PlyFormat::BinaryLittleEndian,
    )?;
    if let Some(d) = dashboard.as_ref() {
        d.element_plot(&out.frames, &out.path("elements.png"))?;
    }
    let mut summary = Map::new();
    if let (SimMap::Tsdf(t), Some(c)) = (&map, &mut chunks) {
        c.summarise(t, &mut summary)?;
    }
    if let SimMap::Planes(p) = &mut map {
        planes::summarise(p, &mut summary);
    }
    let mapper = map.mapper();
    let stats = mapper.stats();
    let name = mapper.name();
    let mesh = mapper.mesh();
    // ~1M samples at most keeps the check to about a second on any map.
    let spacing = ((mesh.area() / 1.0e6).sqrt() as f32).max(0.002);
    let (within, within_1cm, within_2cm) = match &chunks {
        Some(c) => (
            c.fraction_within(mesh, &truth, 0.005)?,
            c.fraction_within(mesh, &truth, 0.01)?,
            c.fraction_within(mesh, &truth, 0.02)?,
        ),
        None => (
            fraction_within(mesh, &truth, 0.005, spacing),
            fraction_within(mesh, &truth, 0.01, spacing),
            fraction_within(mesh, &truth, 0.02, spacing),
        ),
    };
    let column = |name: &str| -> f64 { out.frames.iter().filter_map(|f| f.report.get(name)).sum() };
    let naive = column("naive_elements");
    summary.insert("scene".into(), scene.name.clone().into());
    summary.insert("iterations".into(), args.iterations.into());
    summary.insert("noise".into(), args.noise.to_string().into());
    summary.insert("seed".into(), args.seed.into());
    summary.insert("dynamic".into(), args.dynamic.into());
    summary.insert("path".into(), args.path.to_string().into());
    tracking.summarize(&mut summary);
    if args.track {
        // The true poses beside the estimated ones, and how far apart they are.
        let truth: Vec<(f64, Pose)> = (1..).map(f64::from).zip(poses.iter().copied()).collect();
        let tum = format_tum(&truth);
        write_atomic(&out.path("groundtruth.txt"), |w| {
            w.write_all(tum.as_bytes())
        })?;
        let e = trajectory_error(&out.trajectory, &truth, 0.0)?;
        summary.insert("ate_rmse_cm".into(), json!(e.ate_rmse * 100.0));
        summary.insert(
            "ate_rmse_aligned_cm".into(),
            json!(e.ate_rmse_aligned * 100.0),
        );
    }
    summary.insert("naive_elements".into(), json!(naive as u64));
    summary.insert(
        "elements_vs_naive".into(),
        json!(if naive > 0.0 {
            stats.elements as f64 / naive
        } else {
            0.0
        }),
    );
    summary.insert(
        "removed_elements".into(),
        json!(out
            .frames
            .iter()
            .map(|f| f.report.removed_elements)
            .sum::<usize>()),
    );
    summary.insert("novel_pixels".into(), json!(column("novel_pixels") as u64));
    summary.insert(
        "sensor_seconds".into(),
        json!(sensor_ms.iter().sum::<f64>() / 1e3),
    );
    // null for an empty map: there is no surface to judge.
    summary.insert("surface_within_5mm".into(), json!(within));
    summary.insert("surface_within_1cm".into(), json!(within_1cm));
    summary.insert("surface_within_2cm".into(), json!(within_2cm));
    if args.view {
        views::write_view(scene, &poses, mesh, &out.path("view.png"))?;
    }
    let summary = match &chunks {
        Some(c) => c.finish(&out, name, mesh, stats.bytes, summary)?,
        None => out.finish(name, mesh, stats.bytes, summary)?,
    };
    args.export.write(mesh, &args.out)?;
    Ok(RunSummary { summary })
}
