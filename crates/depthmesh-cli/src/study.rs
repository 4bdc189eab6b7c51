//! `depthmesh study`: the voxel-planes paper's comparison with marching
//! cubes (its Figs. 6–7) on our data: runtime against the number of points,
//! and cross-validation error against representation size, for voxel planes
//! and TSDF + marching cubes at the same voxel sizes.

use crate::bench::TABLE_SCENE;
use crate::draw::canvas::{Canvas, Rgb, WHITE};
use crate::draw::plot::{LinePlot, Series};
use crate::progress;
use anyhow::{bail, Context, Result};
use clap::Args;
use depthmesh::atomic::write_atomic;
use depthmesh::dataset::{Dataset, DatasetOptions, FrameRange};
use depthmesh::eval::distance::MeshDistance;
use depthmesh::map::Mapper;
use depthmesh::planes::{PlaneGridConfig, PlanesConfig, PlanesMapper, DEFAULT_EPSILON};
use depthmesh::sim::{NoiseModel, PathSpec, Scene, SceneOptions, SimulatedSensor};
use depthmesh::tsdf::mapper::TsdfMapper;
use depthmesh::tsdf::TsdfConfig;
use depthmesh::{Frame, Intrinsics};
use glam::Vec3;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::PathBuf;
use std::time::Instant;

/// Share of the valid pixels held out for testing (the paper's 1:9 split).
const HOLD_OUT: f64 = 0.1;
/// At most this many held-out points are measured: plenty for a mean.
const MAX_TEST_POINTS: usize = 100_000;
/// Held-out points farther than this from a mesh count at this distance
/// (metres), so a hole costs as much as a gross error but no more.
const DISTANCE_CAP: f32 = 0.5;
/// ε as a fraction of the voxel: the window's in-plane variances are at
/// most about (2·voxel)²/12, so a fixed ε = 2 cm would call nothing planar
/// in small voxels; 0.4 reproduces the paper's 2 cm at its 5 cm voxels.
const EPSILON_PER_VOXEL: f64 = 0.4;

/// Flags of `depthmesh study`.
#[derive(Args, Debug)]
pub struct StudyArgs {
    /// A 7-Scenes frames folder or TUM RGB-D folder with poses; without it
    /// only the simulated table scene is studied.
    #[arg(long)]
    pub dataset: Option<PathBuf>,
    /// Frame numbers of the dataset to use, half-open: A..B, A.. or ..B.
    #[arg(long)]
    pub frames: Option<FrameRange>,
    /// Use every K-th frame of the dataset.
    #[arg(long, default_value_t = 10)]
    pub stride: usize,
    /// Simulated frames of the table scene (Kinect noise, the helix path),
    /// as `simulate --iterations`.
    #[arg(long = "iterations", alias = "sim-iterations", default_value_t = 30)]
    pub sim_iterations: u32,
    /// Voxel sizes in metres, used by both methods.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0.02,0.03,0.05,0.075,0.1"
    )]
    pub voxels: Vec<f32>,
    /// Seed of the held-out pixel choice and of the simulated noise.
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    pub seed: u64,
    /// Output folder: runtime_vs_points.png, error_vs_size.png, study.csv, study.md.
    #[arg(long)]
    pub out: PathBuf,
}

/// Frames to fuse (with the held-out pixels removed) and the held-out points.
struct Source {
    name: String,
    intrinsics: Intrinsics,
    frames: Vec<Frame>,
    /// Valid pixels fused up to and including each frame.
    points_after: Vec<usize>,
    test: Vec<Vec3>,
}

/// The two methods compared.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Method {
    Planes,
    Tsdf,
}

impl Method {
    fn name(self) -> &'static str {
        match self {
            Method::Planes => "voxel planes",
            Method::Tsdf => "TSDF + marching cubes",
        }
    }
}

/// One method at one voxel size on one source.
struct Outcome {
    source: String,
    method: Method,
    voxel: f32,
    /// (points fused, cumulative seconds of integration and meshing).
    runtime: Vec<(usize, f64)>,
    representation_bytes: usize,
    /// The bytes the map really holds (`Mapper::stats`): for planes the
    /// dense voxel grids of every allocated cell, not only occupied voxels.
    map_bytes: usize,
    triangles: usize,
    mean_error: f64,
    median_error: f64,
    within_1cm: f64,
}

/// Runs `study`.
pub fn run(args: &StudyArgs, quiet: bool) -> Result<()> {
    if args.voxels.is_empty() || args.voxels.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
        bail!("--voxels must list positive sizes in metres");
    }
    if args.stride == 0 || args.sim_iterations == 0 {
        bail!("--stride and --iterations must be at least 1");
    }
    let mut sources = Vec::new();
    if let Some(path) = &args.dataset {
        sources.push(dataset_source(path, args)?);
    } else {
        eprintln!("no --dataset: studying the simulated scene only");
    }
    sources.push(simulated_source(args)?);
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;

    let runs = sources.len() * args.voxels.len() * 2;
    let bar = progress::bar(runs as u64, "study", quiet);
    let mut outcomes = Vec::new();
    for source in &sources {
        for &voxel in &args.voxels {
            for method in [Method::Planes, Method::Tsdf] {
                outcomes.push(measure(source, method, voxel)?);
                bar.inc(1);
            }
        }
    }
    bar.finish_and_clear();

    let names: Vec<&str> = sources.iter().map(|s| s.name.as_str()).collect();
    write_png(
        &args.out,
        "runtime_vs_points.png",
        &names,
        &outcomes,
        runtime_plot,
    )?;
    write_png(
        &args.out,
        "error_vs_size.png",
        &names,
        &outcomes,
        error_plot,
    )?;
    let csv = table_csv(&outcomes);
    write_atomic(&args.out.join("study.csv"), |w| w.write_all(csv.as_bytes()))?;
    let md = table_markdown(&sources, &outcomes);
    write_atomic(&args.out.join("study.md"), |w| w.write_all(md.as_bytes()))?;
    print!("{md}");
    Ok(())
}

/// Frames of a recorded sequence.
fn dataset_source(path: &std::path::Path, args: &StudyArgs) -> Result<Source> {
    let options = DatasetOptions {
        frames: args.frames,
        stride: args.stride,
        ..DatasetOptions::default()
    };
    let dataset = Dataset::open(path, &options)?;
    let mut frames = Vec::with_capacity(dataset.len());
    for frame in dataset.frames() {
        let frame = frame?;
        if frame.pose.is_none() {
            bail!("frame {} of {} has no pose", frame.index, path.display());
        }
        frames.push(frame);
    }
    let name = path
        .file_name()
        .map_or("dataset".into(), |n| n.to_string_lossy().into_owned());
    Ok(hold_out(name, dataset.intrinsics(), frames, args.seed))
}

/// The table scene seen by the simulated Kinect along the helix, with noise.
fn simulated_source(args: &StudyArgs) -> Result<Source> {
    let scene = Scene::parse(
        TABLE_SCENE,
        "scenes/table.toml".as_ref(),
        &SceneOptions::default(),
    )?;
    let poses = PathSpec::Helix.build(&scene, args.sim_iterations)?;
    let mut sensor = SimulatedSensor::kinect(NoiseModel::Kinect, args.seed);
    let frames = poses
        .iter()
        .enumerate()
        .map(|(i, pose)| {
            let mut frame = sensor.capture(&scene, i as u32 + 1, pose);
            frame.pose = Some(*pose);
            frame
        })
        .collect();
    Ok(hold_out(
        "simulated table (Kinect noise)".into(),
        sensor.intrinsics,
        frames,
        args.seed,
    ))
}

/// Removes a seeded random 10 % of each frame's valid pixels and keeps
/// their world points as the test set.
fn hold_out(name: String, k: Intrinsics, mut frames: Vec<Frame>, seed: u64) -> Source {
    let mut test = Vec::new();
    let mut points_after = Vec::with_capacity(frames.len());
    let mut fused = 0;
    for (i, frame) in frames.iter_mut().enumerate() {
        let pose = frame.pose.expect("study frames have poses");
        let mut rng =
            SmallRng::seed_from_u64(seed ^ (i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15));
        let width = frame.depth.width as usize;
        for (p, z) in frame.depth.data.iter_mut().enumerate() {
            if *z <= 0.0 {
                continue;
            }
            if rng.gen_bool(HOLD_OUT) {
                let (u, v) = ((p % width) as f32, (p / width) as f32);
                test.push(pose.transform_point(k.back_project(u, v, *z)));
                *z = 0.0;
            } else {
                fused += 1;
            }
        }
        points_after.push(fused);
    }
    let step = test.len().div_ceil(MAX_TEST_POINTS).max(1);
    let test = test.into_iter().step_by(step).collect();
    Source {
        name,
        intrinsics: k,
        frames,
        points_after,
        test,
    }
}

/// The map of one method: the concrete types, for their representation sizes.
enum StudyMap {
    Planes(Box<PlanesMapper>),
    Tsdf(Box<TsdfMapper>),
}

impl StudyMap {
    fn new(method: Method, voxel: f32, k: Intrinsics) -> Result<Self> {
        Ok(match method {
            Method::Planes => {
                // The paper's 20 voxels per cell edge (1 m of 5 cm voxels) at
                // every size: 1 m cells of 2 cm voxels would be 10 MB each.
                let cell = voxel * 20.0;
                let config = PlanesConfig {
                    grid: PlaneGridConfig { voxel, cell },
                    epsilon: epsilon_for(voxel),
                };
                StudyMap::Planes(Box::new(PlanesMapper::new(config, k)?))
            }
            Method::Tsdf => StudyMap::Tsdf(Box::new(TsdfMapper::new(
                TsdfConfig::new(voxel),
                k,
                0.1,
                4.0,
            )?)),
        })
    }

    fn mapper(&mut self) -> &mut dyn Mapper {
        match self {
            StudyMap::Planes(m) => m.as_mut(),
            StudyMap::Tsdf(m) => m.as_mut(),
        }
    }

    /// Planes: 10 floats per occupied voxel (the paper's count); TSDF: the
    /// voxels it allocates, at the bytes it stores per voxel.
    fn representation_bytes(&self) -> usize {
        match self {
            StudyMap::Planes(m) => m.representation_bytes(),
            StudyMap::Tsdf(m) => m.volume().voxel_bytes(),
        }
    }
}

/// The planarity noise used at `voxel`: the paper's 2 cm, or less where
/// the window is too small for it (see [`EPSILON_PER_VOXEL`]).
fn epsilon_for(voxel: f32) -> f64 {
    DEFAULT_EPSILON.min(EPSILON_PER_VOXEL * f64::from(voxel))
}

/// Fuses the source's frames, meshing (incrementally) at four checkpoints,
/// and measures the final mesh against the held-out points.
fn measure(source: &Source, method: Method, voxel: f32) -> Result<Outcome> {
    let mut map = StudyMap::new(method, voxel, source.intrinsics)?;
    let n = source.frames.len();
    let mut checkpoints: Vec<usize> = [n / 8, n / 4, n / 2, n].iter().map(|&c| c.max(1)).collect();
    checkpoints.dedup();
    let (mut seconds, mut runtime) = (0.0, Vec::new());
    for (i, frame) in source.frames.iter().enumerate() {
        let pose = frame.pose.expect("study frames have poses");
        let start = Instant::now();
        map.mapper().integrate(frame, &pose)?;
        if checkpoints.contains(&(i + 1)) {
            map.mapper().mesh();
        }
        seconds += start.elapsed().as_secs_f64();
        if checkpoints.contains(&(i + 1)) {
            runtime.push((source.points_after[i], seconds));
        }
    }
    let mesh = map.mapper().mesh().clone();
    let index = MeshDistance::new(&mesh, DISTANCE_CAP);
    let mut distances: Vec<f32> = source
        .test
        .par_iter()
        .map(|&p| index.distance(p).unwrap_or(DISTANCE_CAP))
        .collect();
    distances.sort_by(f32::total_cmp);
    let count = distances.len().max(1) as f64;
    Ok(Outcome {
        source: source.name.clone(),
        method,
        voxel,
        runtime,
        representation_bytes: map.representation_bytes(),
        map_bytes: map.mapper().stats().bytes,
        triangles: mesh.triangle_count(),
        mean_error: distances.iter().map(|&d| f64::from(d)).sum::<f64>() / count,
        median_error: distances
            .get(distances.len() / 2)
            .map_or(0.0, |&d| f64::from(d)),
        within_1cm: distances.iter().filter(|&&d| d <= 0.01).count() as f64 / count,
    })
}

/// Colour of a series: blues for planes, reds for the TSDF, darker for
/// larger voxels.
fn colour(method: Method, rank: usize, of: usize) -> Rgb {
    let t = if of > 1 {
        rank as f32 / (of - 1) as f32
    } else {
        0.0
    };
    let shade = |light: f32, dark: f32| (light + (dark - light) * t) as u8;
    match method {
        Method::Planes => [shade(110.0, 10.0), shade(170.0, 40.0), shade(255.0, 140.0)],
        Method::Tsdf => [shade(255.0, 130.0), shade(150.0, 20.0), shade(110.0, 10.0)],
    }
}

/// Runtime against points fused, one line per method and voxel size.
fn runtime_plot(source: &str, outcomes: &[&Outcome]) -> LinePlot {
    let mut voxels: Vec<f32> = outcomes.iter().map(|o| o.voxel).collect();
    voxels.sort_by(f32::total_cmp);
    voxels.dedup();
    let series = outcomes
        .iter()
        .map(|o| Series {
            name: format!("{} {} cm", o.method.name(), centimetres(o.voxel)),
            colour: colour(
                o.method,
                voxels.iter().position(|&v| v == o.voxel).unwrap_or(0),
                voxels.len(),
            ),
            points: o
                .runtime
                .iter()
                .map(|&(p, s)| (p as f64 / 1e6, s))
                .collect(),
            markers: true,
        })
        .collect();
    LinePlot {
        title: format!("Runtime (integrate + mesh): {source}"),
        x_label: "points fused (millions)".into(),
        y_label: "CPU wall time (s), 2 threads".into(),
        series,
    }
}

/// Mean held-out distance against representation size, one line per method.
fn error_plot(source: &str, outcomes: &[&Outcome]) -> LinePlot {
    let series = [Method::Planes, Method::Tsdf]
        .into_iter()
        .map(|method| Series {
            name: format!("{} (one dot per voxel size)", method.name()),
            colour: colour(method, 1, 2),
            points: outcomes
                .iter()
                .filter(|o| o.method == method)
                .map(|o| {
                    (
                        (o.representation_bytes.max(1) as f64 / 1e3).log10(),
                        o.mean_error * 100.0,
                    )
                })
                .collect(),
            markers: true,
        })
        .collect();
    LinePlot {
        title: format!("Cross-validation error: {source}"),
        x_label: "representation size, log10 kB".into(),
        y_label: "mean distance of held-out points (cm)".into(),
        series,
    }
}

/// One panel per source, side by side.
fn write_png(
    dir: &std::path::Path,
    file: &str,
    sources: &[&str],
    outcomes: &[Outcome],
    plot: fn(&str, &[&Outcome]) -> LinePlot,
) -> Result<()> {
    let (w, h) = (900, 680);
    let mut canvas = Canvas::new(w * sources.len() as u32, h, WHITE);
    for (i, source) in sources.iter().enumerate() {
        let mine: Vec<&Outcome> = outcomes.iter().filter(|o| o.source == *source).collect();
        canvas.blit(&plot(source, &mine).render(w, h), (i as u32 * w) as i32, 0);
    }
    let png = canvas.encode_png();
    write_atomic(&dir.join(file), |w| w.write_all(&png))?;
    Ok(())
}

/// A voxel size in centimetres as people write it (7.5, not 7.5000005).
fn centimetres(voxel: f32) -> f64 {
    (f64::from(voxel) * 1000.0).round() / 10.0
}

/// Seconds of the whole run (the last checkpoint) and points fused.
fn total(o: &Outcome) -> (usize, f64) {
    o.runtime.last().copied().unwrap_or((0, 0.0))
}

fn table_csv(outcomes: &[Outcome]) -> String {
    let mut s = String::from(
        "source,method,voxel_m,epsilon_m,points,seconds,points_per_second,representation_bytes,map_bytes,triangles,mean_error_m,median_error_m,within_1cm\n",
    );
    for o in outcomes {
        let (points, seconds) = total(o);
        let epsilon = match o.method {
            Method::Planes => format!("{}", epsilon_for(o.voxel)),
            Method::Tsdf => String::new(),
        };
        let _ = writeln!(
            s,
            "{},{},{},{},{},{:.4},{:.0},{},{},{},{:.5},{:.5},{:.4}",
            o.source,
            o.method.name(),
            o.voxel,
            epsilon,
            points,
            seconds,
            points as f64 / seconds.max(1e-12),
            o.representation_bytes,
            o.map_bytes,
            o.triangles,
            o.mean_error,
            o.median_error,
            o.within_1cm
        );
    }
    s
}

/// The TSDF's mean error at representation size `bytes`, interpolated
/// linearly in log size between its two nearest sizes; `None` outside the
/// sizes it was measured at.
fn tsdf_error_at(tsdf: &[&Outcome], bytes: usize) -> Option<f64> {
    let x = (bytes as f64).log10();
    let mut pts: Vec<(f64, f64)> = tsdf
        .iter()
        .map(|o| ((o.representation_bytes.max(1) as f64).log10(), o.mean_error))
        .collect();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    pts.windows(2).find_map(|w| {
        let ((x0, y0), (x1, y1)) = (w[0], w[1]);
        (x0 <= x && x <= x1 && x1 > x0).then(|| y0 + (y1 - y0) * (x - x0) / (x1 - x0))
    })
}

fn table_markdown(sources: &[Source], outcomes: &[Outcome]) -> String {
    let mut s = String::new();
    for source in sources {
        let mine: Vec<&Outcome> = outcomes
            .iter()
            .filter(|o| o.source == source.name)
            .collect();
        let tsdf: Vec<&Outcome> = mine
            .iter()
            .copied()
            .filter(|o| o.method == Method::Tsdf)
            .collect();
        let _ = writeln!(
            s,
            "### {} — {} frames, {} points fused, {} held-out points measured\n",
            source.name,
            source.frames.len(),
            source.points_after.last().copied().unwrap_or(0),
            source.test.len()
        );
        let _ = writeln!(
            s,
            "| voxel | method | seconds | M points/s | TSDF s / planes s | representation | map memory | triangles | mean error | median error | within 1 cm | TSDF mean error at the same size |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|---|");
        for o in &mine {
            let (points, seconds) = total(o);
            let twin = mine
                .iter()
                .find(|t| t.voxel == o.voxel && t.method != o.method);
            let ratio = match (o.method, twin) {
                (Method::Planes, Some(t)) => format!("{:.2}", total(t).1 / seconds.max(1e-12)),
                _ => String::new(),
            };
            let same_size = match o.method {
                Method::Planes => tsdf_error_at(&tsdf, o.representation_bytes)
                    .map_or("outside TSDF sizes".into(), |e| {
                        format!("{:.2} cm", e * 100.0)
                    }),
                Method::Tsdf => String::new(),
            };
            let _ = writeln!(
                s,
                "| {} cm | {} | {:.3} | {:.1} | {} | {:.2} MB | {:.2} MB | {} | {:.2} cm | {:.2} cm | {:.1} % | {} |",
                centimetres(o.voxel),
                o.method.name(),
                seconds,
                points as f64 / seconds.max(1e-12) / 1e6,
                ratio,
                o.representation_bytes as f64 / 1e6,
                o.map_bytes as f64 / 1e6,
                o.triangles,
                o.mean_error * 100.0,
                o.median_error * 100.0,
                o.within_1cm * 100.0,
                same_size
            );
        }
        let _ = writeln!(s);
    }
    s
}
