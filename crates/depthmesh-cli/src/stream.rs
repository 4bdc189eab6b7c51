//! `depthmesh stream`: the sensor client. Replays a recorded dataset (or a
//! scene through the simulated sensor) to a `depthmesh serve`, showing live
//! figures, and writes the session's mesh, status images and its own
//! figures into `--out`.

use crate::dataset_args::DatasetArgs;
use crate::out_dir::OutDir;
use crate::progress;
use crate::simulate::load_scene;
use anyhow::{bail, Context, Result};
use clap::Args;
use depthmesh::atomic::write_atomic;
use depthmesh::codec::{Codec, RawDepth};
use depthmesh::dataset::{Dataset, DatasetOptions};
use depthmesh::sim::{NoiseModel, PathSpec, Scene, SimulatedSensor};
use depthmesh::{Intrinsics, Pose};
use depthmesh_server::{FrameSource, SourceFrame, StreamOptions};
use std::io::Write;
use std::path::PathBuf;

/// Units per metre of simulated depth on the wire: millimetres, as a
/// Kinect reports.
const SIMULATED_UNITS_PER_METRE: f32 = 1000.0;

/// Flags of `depthmesh stream`.
#[derive(Args, Debug, Clone)]
pub struct StreamArgs {
    /// A 7-Scenes frames folder or a TUM RGB-D folder (or give --scene).
    pub dataset: Option<PathBuf>,
    /// Stream a scene file through the simulated Kinect instead of a dataset.
    #[arg(long, conflicts_with = "dataset")]
    pub scene: Option<PathBuf>,
    /// The server, http://HOST:PORT.
    #[arg(long, default_value = "http://127.0.0.1:7878")]
    pub server: String,
    /// The server's token.
    #[arg(long, env = "DEPTHMESH_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// Publish to a site's stream on this NATS server (nats://HOST:PORT,
    /// JetStream enabled) instead of streaming to a `serve`: the site's
    /// `cluster worker`s map it.
    #[arg(long, requires_all = ["site", "sensor"])]
    pub nats: Option<String>,
    /// The site to publish to (--nats).
    #[arg(long, requires = "nats")]
    pub site: Option<String>,
    /// This sensor's name on the site (--nats).
    #[arg(long, requires = "nats")]
    pub sensor: Option<String>,
    /// The session's name on the server (letters, digits, '-', '_'; default: generated).
    #[arg(long)]
    pub session: Option<String>,
    /// Frames per second to send at, or `max`: as fast as the server maps.
    #[arg(long, default_value = "30")]
    pub rate: String,
    /// A live sensor: send at the rate whatever the server's pace; the
    /// server maps the newest frame and drops what it cannot keep up with.
    #[arg(long)]
    pub realtime: bool,
    /// Leave the poses to ICP (only the first frame's pose is sent): the
    /// server's, or with --nats a `cluster tracker`'s.
    #[arg(long)]
    pub track: bool,
    /// Continue the --session of this name from the server's store of it
    /// (`serve --store`): only the frames after the last one it mapped are
    /// sent.
    #[arg(long, requires = "session")]
    pub resume: bool,
    /// Depth codec: default, levels, rvl, png or raw.
    #[arg(long, default_value = "default")]
    pub codec: Codec,
    /// Ask for a status image every N mapped frames (0: never).
    #[arg(long, default_value_t = 0)]
    pub status_every: u32,
    /// Write the status images received to OUT/status/.
    #[arg(long)]
    pub save_status: bool,
    #[command(flatten)]
    pub frames: DatasetArgs,
    /// Number of sensor poses along the path (--scene).
    #[arg(long, default_value_t = 30)]
    pub iterations: u32,
    /// Depth noise of the simulated sensor (--scene).
    #[arg(long, default_value = "none")]
    pub noise: NoiseModel,
    /// Sensor path (--scene): helix, line or tum:FILE.
    #[arg(long, default_value = "helix")]
    pub path: PathSpec,
    /// Mesh file for `${bunny}` in scene files (--scene).
    #[arg(long)]
    pub bunny: Option<PathBuf>,
    /// Give up when the server says nothing for this many seconds.
    #[arg(long, default_value_t = 60)]
    pub timeout: u64,
    /// Output folder (mesh.ply, summary.json, status/): new, empty, or an
    /// earlier run's with --force (not with --nats, which prints its summary).
    #[arg(long, required_unless_present = "nats", conflicts_with = "nats")]
    pub out: Option<PathBuf>,
    /// Replace the earlier run in --out.
    #[arg(long)]
    pub force: bool,
}

/// Runs `stream`.
pub fn run(args: &StreamArgs, quiet: bool) -> Result<()> {
    let rate = match args.rate.as_str() {
        "max" => None,
        r => match r.parse::<f64>() {
            Ok(v) if v.is_finite() && v > 0.0 => Some(v),
            _ => bail!("--rate must be frames per second or `max`, got {r}"),
        },
    };
    if args.realtime && rate.is_none() {
        bail!("--realtime sends at the sensor's rate: give --rate FPS");
    }
    let source = open_source(args)?;
    if let Some(nats) = &args.nats {
        return publish(args, nats, source, rate, quiet);
    }
    let (Some(out_path), Some(token)) = (&args.out, &args.token) else {
        bail!("streaming to a server needs --out and --token (or DEPTHMESH_TOKEN)");
    };
    let out = OutDir::prepare(out_path, args.force)?;
    let options = StreamOptions {
        url: args.server.clone(),
        token: token.clone(),
        session: args.session.clone(),
        codec: args.codec,
        rate,
        realtime: args.realtime,
        track: args.track,
        status_every: args.status_every,
        reply_timeout: std::time::Duration::from_secs(args.timeout.max(1)),
        resume: args.resume,
    };
    let bar = progress::bar(source.len() as u64, "stream", quiet);
    let runtime = tokio::runtime::Runtime::new().context("cannot start the client's runtime")?;
    let result = runtime
        .block_on(depthmesh_server::stream(
            source,
            &options,
            args.save_status,
            |p| {
                bar.set_position(p.mapped + p.dropped);
                let s = p.seconds.max(1e-3);
                bar.set_message(format!(
                    "{:.1} fps, up {:.0} kB/s, down {:.0} kB/s, tracking {}",
                    p.mapped as f64 / s,
                    p.upload_bytes as f64 / s / 1e3,
                    p.download_bytes as f64 / s / 1e3,
                    if p.tracking_lost { "LOST" } else { "ok" }
                ));
            },
        ))
        .map_err(anyhow::Error::msg)?;
    bar.finish_and_clear();
    write_atomic(&out_path.join("mesh.ply"), |w| {
        w.write_all(&result.mesh_ply)
    })?;
    if args.save_status {
        let dir = out_path.join("status");
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("cannot create {}", dir.display()))?;
        for (frame, jpeg) in &result.status {
            write_atomic(&dir.join(format!("frame-{frame:06}.jpg")), |w| {
                w.write_all(jpeg)
            })?;
        }
    }
    let text = serde_json::to_string_pretty(&result.summary)?;
    write_atomic(&out_path.join("summary.json"), |w| writeln!(w, "{text}"))?;
    out.keep();
    if !quiet {
        let s = &result.summary;
        eprintln!(
            "{} frames sent, {} mapped, {} dropped, {} lost, {} {}; {} triangles; latency p50 {} ms; wrote {}",
            s["frames_sent"], s["frames_mapped"], s["frames_dropped"], s["frames_lost"],
            s["frames_weak"], crate::run::WEAK_FRAMES, s["triangles"], s["latency_ms_p50"],
            out_path.display()
        );
    }
    Ok(())
}

/// Publishes the frames to a site's stream (`--nats`) and prints what was stored.
fn publish(
    args: &StreamArgs,
    nats: &str,
    mut source: Box<dyn FrameSource>,
    rate: Option<f64>,
    quiet: bool,
) -> Result<()> {
    if args.realtime || args.resume || args.status_every > 0 || args.save_status {
        bail!("--nats publishes every frame: --realtime, --resume, --status-every and --save-status are for a server");
    }
    let (Some(site), Some(sensor)) = (&args.site, &args.sensor) else {
        bail!("--nats needs --site and --sensor");
    };
    let options = depthmesh_cluster::publish::PublishOptions {
        sensor: sensor.clone(),
        codec: args.codec,
        rate,
        track: args.track,
    };
    let bar = progress::bar(source.len() as u64, "publish", quiet);
    let runtime = tokio::runtime::Runtime::new().context("cannot start the client's runtime")?;
    let published = runtime
        .block_on(async {
            let site = depthmesh_cluster::Site::connect(nats, site, None).await?;
            depthmesh_cluster::publish::publish(&site, source.as_mut(), &options, |p| {
                bar.set_position(p.frames + p.duplicates);
            })
            .await
        })
        .with_context(|| format!("site {site} on {nats}"))?;
    bar.finish_and_clear();
    println!("{}", serde_json::to_string_pretty(&published)?);
    Ok(())
}

/// The frames the flags name: a dataset, or a scene through the simulator.
fn open_source(args: &StreamArgs) -> Result<Box<dyn FrameSource>> {
    match (&args.dataset, &args.scene) {
        (Some(path), None) => {
            let options = args.frames.options(DatasetOptions::default())?;
            let dataset = Dataset::open(path, &options)?;
            if dataset.is_empty() {
                bail!("{}: no frames selected", path.display());
            }
            Ok(Box::new(DatasetSource { dataset, next: 0 }))
        }
        (None, Some(scene)) => {
            let scene = load_scene(scene, None, false, args.bunny.as_deref())?;
            let poses = args.path.build_timed(&scene, args.iterations)?;
            Ok(Box::new(SceneSource {
                sensor: SimulatedSensor::kinect(args.noise, 0),
                scene,
                poses,
                next: 0,
            }))
        }
        _ => bail!("give a DATASET folder or --scene FILE"),
    }
}

/// A recorded dataset's frames, depth as stored.
struct DatasetSource {
    dataset: Dataset,
    next: usize,
}

impl FrameSource for DatasetSource {
    fn intrinsics(&self) -> Intrinsics {
        self.dataset.intrinsics()
    }

    fn len(&self) -> usize {
        self.dataset.len()
    }

    fn next_frame(&mut self, raw: &mut RawDepth) -> Option<Result<SourceFrame, String>> {
        let i = self.next;
        if i >= self.dataset.len() {
            return None;
        }
        self.next += 1;
        let frame = self.dataset.frame_info(i).and_then(|info| {
            self.dataset.raw_depth(i, raw)?;
            Ok(SourceFrame {
                index: info.index as u64,
                timestamp: info.timestamp,
                pose: info.pose,
            })
        });
        Some(frame.map_err(|e| e.to_string()))
    }
}

/// The simulated Kinect following a path through a scene.
struct SceneSource {
    sensor: SimulatedSensor,
    scene: Scene,
    /// Each frame's time and pose.
    poses: Vec<(f64, Pose)>,
    next: usize,
}

impl FrameSource for SceneSource {
    fn intrinsics(&self) -> Intrinsics {
        self.sensor.intrinsics
    }

    fn len(&self) -> usize {
        self.poses.len()
    }

    fn next_frame(&mut self, raw: &mut RawDepth) -> Option<Result<SourceFrame, String>> {
        let (timestamp, pose) = *self.poses.get(self.next)?;
        self.next += 1;
        let iteration = self.next as u32;
        let frame = self.sensor.capture(&self.scene, iteration, &pose);
        let done = raw.set_from_metres(&frame.depth, SIMULATED_UNITS_PER_METRE);
        Some(done.map_err(|e| e.to_string()).map(|()| SourceFrame {
            index: u64::from(iteration),
            timestamp,
            pose: Some(pose),
        }))
    }
}
