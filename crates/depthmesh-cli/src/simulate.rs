//! `depthmesh simulate`: a simulated sensor follows a path through a scene
//! file and a map back-end builds the mesh.

use crate::bounded::ActiveRadiusArgs;
use crate::export::RunExportArgs;
use crate::memory::MemoryArgs;
use crate::out_dir::OutDir;
use crate::planes::PlanesArgs;
use crate::progress;
use crate::run::{conclude, report_event};
use crate::store::StoreArgs;
use crate::views::{self, Dashboard, MapperView};
use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use depthmesh::atomic::write_atomic;
use depthmesh::dataset::FramesWriter;
use depthmesh::eval::trajectory::trajectory_error;
use depthmesh::mabdi::classify::Threshold;
use depthmesh::mabdi::MabdiConfig;
use depthmesh::mesh::ply::{write_ply, PlyFormat};
use depthmesh::session::run_files::RunFiles;
use depthmesh::session::{
    Backend, MapConfig, PlanesSettings, Session, SessionConfig, TsdfSettings,
};
use depthmesh::sim::{NoiseModel, PathSpec, Scene, SceneModel, SceneOptions, SimulatedSensor};
use depthmesh::track::TrackerConfig;
use depthmesh::trajectory::format_tum;
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

/// What `simulate --track` aligns frames against.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum TrackModel {
    /// The map fused so far, as every other command tracks.
    Map,
    /// The scene itself, rendered without noise (a perfect map); the map is
    /// still fused, from the poses found. The tracker's own error, without
    /// what the map's rendition of the scene adds.
    Scene,
    /// The map fused from the true poses of the frames tracking keeps
    /// (each pose is still tracked against it): the error the map's
    /// rendition of the scene adds, without the drift that fusing at
    /// estimated poses feeds back.
    TrueMap,
}

impl TrackModel {
    /// The flag's value, as the summary records it.
    fn name(self) -> &'static str {
        match self {
            TrackModel::Map => "map",
            TrackModel::Scene => "scene",
            TrackModel::TrueMap => "true-map",
        }
    }
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
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    pub seed: u64,
    /// Mesh file for `${bunny}` in scene files (e.g. the Stanford bunny PLY).
    #[arg(long)]
    pub bunny: Option<PathBuf>,
    /// Sensor path: helix (the thesis's), line, or tum:FILE.
    #[arg(long, default_value = "helix")]
    pub path: PathSpec,
    /// Novelty threshold in metres (default: the thesis's 0.01 in normalised depth, ≈ 0.01·z² m).
    #[arg(long, allow_negative_numbers = true)]
    pub threshold: Option<f32>,
    /// Keep triangles the sensor sees through (the thesis's behaviour) instead of removing them.
    #[arg(long)]
    pub keep_removed: bool,
    /// Mesh novel pixels in half pixels as the thesis does and keep M as
    /// that mesher made it: no adaptive meshing, no simplification of
    /// settled surface (mabdi).
    #[arg(long)]
    pub no_settle: bool,
    /// Mesh novel surface from the measured depth as it came, not smoothed
    /// on each surface first (mabdi).
    #[arg(long)]
    pub no_smooth: bool,
    /// Voxel size in metres (tsdf; truncation 4 voxels).
    #[arg(long, default_value_t = 0.01, allow_negative_numbers = true)]
    pub voxel: f32,
    /// Estimate poses by ICP against the map (only the first pose of the
    /// path is given); `trajectory.txt` then holds the estimates,
    /// `groundtruth.txt` the true poses, and the summary their error.
    #[arg(long)]
    pub track: bool,
    /// What --track aligns frames against.
    #[arg(long, value_enum, default_value_t = TrackModel::Map)]
    pub track_against: TrackModel,
    #[command(flatten)]
    pub planes: PlanesArgs,
    /// Also write the frames the sensor took (depth in millimetres, the
    /// true poses, the intrinsics) to `frames/` in --out, as a 7-Scenes
    /// frames folder: `reconstruct`, or another tool, maps the same depth.
    #[arg(long)]
    pub save_frames: bool,
    /// Write a dashboard image per iteration and the element plot (mabdi, naive).
    #[arg(long)]
    pub dashboard: bool,
    /// Write `view.png`: the final mesh, lit and in its colours, from the
    /// dashboard's third-person camera.
    #[arg(long)]
    pub view: bool,
    /// Output folder: new, empty, or an earlier run's with --force.
    #[arg(long)]
    pub out: PathBuf,
    /// Replace an earlier run in --out (without it, a folder holding one is refused).
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub export: RunExportArgs,
    #[command(flatten)]
    pub bounded: ActiveRadiusArgs,
    #[command(flatten)]
    pub memory: MemoryArgs,
    #[command(flatten)]
    pub store: StoreArgs,
}

/// What a finished run reports to the caller (the demo's table).
#[derive(Debug, Clone)]
pub struct RunSummary {
    /// The summary.json content.
    pub summary: Map<String, Value>,
}

/// Loads a scene file (or an embedded one via `text`), with objects
/// appearing and disappearing when `dynamic`, and `bunny` for `${bunny}`.
pub fn load_scene(
    path: &Path,
    text: Option<&str>,
    dynamic: bool,
    bunny: Option<&Path>,
) -> Result<Scene> {
    let mut options = SceneOptions {
        dynamic,
        ..SceneOptions::default()
    };
    if let Some(bunny) = bunny {
        options
            .variables
            .insert("bunny".into(), bunny.to_path_buf());
    }
    Ok(match text {
        Some(text) => Scene::parse(text, path, &options)?,
        None => Scene::load(path, &options)?,
    })
}

/// Runs `simulate` with the scene file of the flags.
pub fn run(args: &SimulateArgs, quiet: bool) -> Result<RunSummary> {
    let scene = load_scene(&args.scene, None, args.dynamic, args.bunny.as_deref())?;
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
    args.bounded.check(args.map == MapKind::Tsdf)?;
    args.bounded.check_export(&args.export)?;
    if args.track_against != TrackModel::Map && !args.track {
        bail!(
            "--track-against {} chooses what --track aligns frames against: add --track",
            args.track_against.name()
        );
    }
    if args.dashboard && matches!(args.map, MapKind::Tsdf | MapKind::Planes) {
        bail!("--dashboard shows mesh addition: use it with --map mabdi or --map naive");
    }
    let timed = args.path.build_timed(scene, args.iterations)?;
    let poses: Vec<Pose> = timed.iter().map(|(_, pose)| *pose).collect();
    let mut sensor = SimulatedSensor::kinect(args.noise, args.seed);
    let map = map_config(args, &sensor);
    // No frame yet to measure: the far limit bounds the estimate.
    args.memory
        .check_map(&map, &sensor.intrinsics, poses.len(), None)?;
    let config = SessionConfig {
        intrinsics: sensor.intrinsics,
        map,
        tracking: args.track.then(TrackerConfig::default),
    };
    // The simulator's noise depends only on the seed and the iteration, so
    // a continued run sees the frames an uninterrupted one sees.
    let source = || {
        Ok(json!({
            "scene": args.scene.display().to_string(),
            "iterations": args.iterations,
            "path": args.path.to_string(),
            "noise": args.noise.to_string(),
            "seed": args.seed,
            "dynamic": args.dynamic,
        }))
    };
    let (mut session, mut store, position) = args.store.open(config, source, poses.len())?;
    match args.track_against {
        TrackModel::Map => {}
        TrackModel::Scene => {
            session.track_against_scene(SceneModel::new(scene.clone(), sensor.near, sensor.far)?)
        }
        TrackModel::TrueMap => session.fuse_given_poses(),
    }
    args.bounded.note_reach(&session);
    let out = OutDir::prepare(&args.out, args.force || args.store.resume)?;
    let mut files = RunFiles::create(&args.out, &session)?;
    let mut dashboard = args
        .dashboard
        .then(|| {
            Dashboard::new(
                session.backend().mapper().name(),
                scene,
                &poses,
                sensor.intrinsics,
                &files.path("dashboard"),
            )
        })
        .transpose()?;

    let mut saved = args
        .save_frames
        .then(|| FramesWriter::create(&files.path("frames"), &sensor.intrinsics))
        .transpose()?;
    if let Some(saved) = saved.as_mut() {
        // A continued run saves the frames before it too: the noise depends
        // only on the seed and the iteration, so they are the same frames.
        for (i, truth) in poses.iter().enumerate().take(position) {
            let frame = sensor.capture(scene, i as u32 + 1, truth);
            saved.write(i + 1, &frame.depth, truth)?;
        }
    }
    let bar = progress::bar(poses.len() as u64, scene.name.as_str(), quiet);
    let mut sensor_seconds = 0.0;
    let mut stopped = None;
    bar.inc(position as u64);
    for (i, truth) in poses.iter().enumerate().skip(position) {
        let iteration = i as u32 + 1;
        let start = Instant::now();
        let mut frame = sensor.capture(scene, iteration, truth);
        frame.timestamp = timed[i].0;
        sensor_seconds += start.elapsed().as_secs_f64();
        if let Some(saved) = saved.as_mut() {
            saved.write(i + 1, &frame.depth, truth)?;
        }
        let outcome = session
            .push(&frame)
            .with_context(|| format!("iteration {iteration}"))?;
        report_event(&bar, iteration as usize, outcome.event);
        let new_triangles = outcome.record.report.new_elements;
        files.after_frame(&mut session)?;
        store.after_frame(&session, i + 1)?;
        if let (Some(d), Some(view)) = (dashboard.as_mut(), mapper_view(&session, new_triangles)) {
            d.draw(iteration, scene, &frame.depth, &view, session.records())?;
        }
        let elements = session.records().last().map_or(0, |r| r.total_elements);
        bar.set_message(format!("{elements} elements"));
        bar.inc(1);
        if let Some(why) = args.memory.exceeded(&session) {
            bar.suspend(|| eprintln!("iteration {iteration}: {why}: stopping"));
            stopped = Some((iteration, why));
            break;
        }
    }
    bar.finish_and_clear();

    let last = args.iterations;
    let truth = scene.world_mesh(last).0;
    write_ply(
        &files.path("scene.ply"),
        &truth,
        PlyFormat::BinaryLittleEndian,
    )?;
    if let Some(d) = dashboard.as_ref() {
        d.element_plot(session.records(), &files.path("elements.png"))?;
    }
    let mut summary = Map::new();
    summary.insert("scene".into(), scene.name.clone().into());
    summary.insert("iterations".into(), args.iterations.into());
    summary.insert("noise".into(), args.noise.to_string().into());
    summary.insert("seed".into(), args.seed.into());
    summary.insert("dynamic".into(), args.dynamic.into());
    summary.insert("path".into(), args.path.to_string().into());
    if let Some((iteration, _)) = &stopped {
        summary.insert("stopped_at_iteration".into(), json!(iteration));
    }
    if args.track {
        summary.insert("tracked_against".into(), args.track_against.name().into());
        // The true poses beside the estimated ones, and how far apart they
        // are over every frame (a lost frame counts at its last good pose).
        let truth = &timed;
        let tum = format_tum(truth);
        write_atomic(&files.path("groundtruth.txt"), |w| {
            w.write_all(tum.as_bytes())
        })?;
        let e = trajectory_error(&session.estimates(), truth, 0.0)?;
        summary.insert("ate_rmse_cm".into(), json!(e.ate_rmse * 100.0));
        summary.insert(
            "ate_rmse_aligned_cm".into(),
            json!(e.ate_rmse_aligned * 100.0),
        );
    }
    summary.insert("sensor_seconds".into(), json!(sensor_seconds));
    store.summarise(&session, &mut summary)?;
    // null for an empty map: there is no surface to judge.
    for (key, tolerance) in [
        ("surface_within_5mm", 0.005),
        ("surface_within_1cm", 0.01),
        ("surface_within_2cm", 0.02),
    ] {
        let within = files.fraction_within(&mut session, &truth, tolerance)?;
        summary.insert(key.into(), json!(within));
    }
    if args.view {
        views::write_view(scene, &poses, session.mesh(), &files.path("view.png"))?;
    }
    let summary = files.finish(&mut session, summary)?;
    args.export.write(session.mesh(), &args.out)?;
    // A run that lost tracking keeps its files: they show what happened.
    out.keep();
    conclude(&session, &summary, &args.out, quiet, "iteration", stopped)?;
    Ok(RunSummary { summary })
}

/// The back-end the flags choose, for the simulated sensor.
fn map_config(args: &SimulateArgs, sensor: &SimulatedSensor) -> MapConfig {
    let mut mabdi = MabdiConfig::thesis(sensor.intrinsics, sensor.near, sensor.far);
    if let Some(t) = args.threshold {
        mabdi.novelty = Threshold::Metres(t);
    }
    if args.keep_removed {
        mabdi.removal = None;
    }
    if args.no_settle {
        mabdi.settling = None;
    }
    if args.no_smooth {
        mabdi.smoothing = None;
    }
    match args.map {
        MapKind::Mabdi => MapConfig::Mabdi(mabdi),
        MapKind::Naive => MapConfig::Naive(mabdi),
        MapKind::Tsdf => MapConfig::Tsdf(TsdfSettings {
            config: TsdfConfig::new(args.voxel),
            range: (sensor.near, sensor.far),
            remesh_every: 0,
            active_radius: args.bounded.active_radius,
        }),
        MapKind::Planes => MapConfig::Planes(PlanesSettings {
            config: args.planes.config(),
            remesh_every: 0,
        }),
    }
}

/// What the dashboard shows of the last frame, which added `new_triangles`
/// (dashboards show mesh addition, so only its back-ends have one).
fn mapper_view(session: &Session, new_triangles: usize) -> Option<MapperView<'_>> {
    Some(match session.backend() {
        Backend::Mabdi(m) => MapperView {
            mesh: m.mesh_ref(),
            new_triangles,
            expected: Some(m.expected()),
            classes: m.classes(),
        },
        Backend::Naive(m) => MapperView {
            mesh: m.mesh_ref(),
            new_triangles,
            expected: None,
            classes: m.classes(),
        },
        Backend::Tsdf(_) | Backend::Planes(_) => return None,
    })
}
