//! `depthmesh cluster`: fusion workers that share a site's map over NATS
//! JetStream, and what a person asks of a site (its map, its status, a
//! single-process replay of its stream).

use crate::map_args::TsdfArgs;
use crate::progress;
use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use depthmesh::mesh::io::write_mesh;
use depthmesh::track::TrackerConfig;
use depthmesh::tsdf::regions::Regions;
use depthmesh_cluster::tracker::TrackerOptions;
use depthmesh_cluster::worker::WorkerOptions;
use depthmesh_cluster::{Site, SiteConfig};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// `depthmesh cluster …`.
#[derive(Subcommand, Debug)]
pub enum ClusterCommand {
    /// Fuse a share of a site's map: claim shards, fuse the stream's frames
    /// into them, checkpoint them, take over those of dead workers.
    Worker(WorkerArgs),
    /// Assemble the site's map from the shards' checkpoints.
    Fetch(FetchArgs),
    /// Workers, shards, lag per sensor and frames per second (JSON).
    Status(SiteArgs),
    /// Fuse the site's whole stream in this process, in the stream's order.
    Replay(ReplayArgs),
    /// Track a sensor that publishes frames without poses, and publish
    /// them with the poses found for the workers.
    Tracker(TrackerArgs),
}

/// Which site, on which bus.
#[derive(Args, Debug, Clone)]
pub struct SiteArgs {
    /// The NATS server, nats://HOST:PORT (JetStream enabled).
    #[arg(long, default_value = "nats://127.0.0.1:4222")]
    pub nats: String,
    /// The site's name (letters, digits, '-', '_').
    #[arg(long)]
    pub site: String,
    /// Seconds a shard's lease lives unrenewed, for the whole site (a new
    /// site's is 10): how long a dead worker's shards wait for a new owner.
    #[arg(long)]
    pub lease_seconds: Option<f64>,
}

impl SiteArgs {
    /// The site if it exists (for commands that only read it).
    async fn open(&self) -> Result<Site> {
        if self.lease_seconds.is_some() {
            bail!("--lease-seconds is set by a worker, not by a command that reads the site");
        }
        Site::open(&self.nats, &self.site)
            .await
            .with_context(|| format!("site {} on {}", self.site, self.nats))
    }

    /// The site, made if it does not exist yet.
    async fn connect(&self) -> Result<Site> {
        let lease = match self.lease_seconds {
            Some(s) if s.is_finite() && s > 0.0 => Some(Duration::from_secs_f64(s)),
            Some(s) => bail!("--lease-seconds must be a positive number, got {s}"),
            None => None,
        };
        Site::connect(&self.nats, &self.site, lease)
            .await
            .with_context(|| format!("site {} on {}", self.site, self.nats))
    }
}

/// The map's settings, which every worker of a site must share.
#[derive(Args, Debug, Clone)]
pub struct SiteMapArgs {
    #[command(flatten)]
    pub tsdf: TsdfArgs,
    /// Blocks (8 voxels) along each side of a region.
    #[arg(long, default_value_t = Regions::new().region_blocks)]
    pub region_blocks: i32,
    /// Shards the regions are dealt into (the most workers that can share the site).
    #[arg(long, default_value_t = Regions::new().shards)]
    pub shards: u32,
}

impl SiteMapArgs {
    fn config(&self) -> Result<SiteConfig> {
        self.tsdf.check()?;
        let tsdf = self.tsdf.config();
        Ok(SiteConfig {
            voxel: tsdf.voxel,
            truncation: tsdf.truncation,
            max_weight: tsdf.max_weight,
            min_weight: tsdf.min_weight,
            depth_min: self.tsdf.depth_min,
            depth_max: self.tsdf.depth_max,
            regions: Regions {
                region_blocks: self.region_blocks,
                shards: self.shards,
            },
        })
    }
}

/// Flags of `cluster worker`.
#[derive(Args, Debug, Clone)]
pub struct WorkerArgs {
    #[command(flatten)]
    pub site: SiteArgs,
    #[command(flatten)]
    pub map: SiteMapArgs,
    /// This worker's name on the site, which no other process there may use
    /// at the same time (default: host, process and time).
    #[arg(long)]
    pub name: Option<String>,
    /// Checkpoint a shard after this many frames fused into it (and
    /// whenever the worker has caught up with the stream).
    #[arg(long, default_value_t = 30)]
    pub checkpoint_every: u64,
}

/// Flags of `cluster tracker`.
#[derive(Args, Debug, Clone)]
pub struct TrackerArgs {
    #[command(flatten)]
    pub site: SiteArgs,
    /// Track only this sensor (default: any sensor that needs a tracker).
    #[arg(long)]
    pub sensor: Option<String>,
    /// This tracker's name on the site, which no other process there may use
    /// at the same time (default: host, process and time).
    #[arg(long)]
    pub name: Option<String>,
}

/// Flags of `cluster fetch`.
#[derive(Args, Debug, Clone)]
pub struct FetchArgs {
    #[command(flatten)]
    pub site: SiteArgs,
    /// The mesh file to write (.ply, .glb or .obj).
    #[arg(short = 'o', long = "output")]
    pub output: PathBuf,
    /// First wait until every frame on the stream is fused and checkpointed.
    #[arg(long)]
    pub wait: bool,
    /// Give up waiting after this many seconds.
    #[arg(long, default_value_t = 600.0)]
    pub timeout: f64,
}

/// Flags of `cluster replay`.
#[derive(Args, Debug, Clone)]
pub struct ReplayArgs {
    #[command(flatten)]
    pub site: SiteArgs,
    #[command(flatten)]
    pub map: SiteMapArgs,
    /// The mesh file to write (.ply, .glb or .obj).
    #[arg(short = 'o', long = "output")]
    pub output: PathBuf,
}

/// Runs `depthmesh cluster …`.
pub fn run(command: &ClusterCommand, quiet: bool) -> Result<()> {
    let runtime = tokio::runtime::Runtime::new().context("cannot start the cluster's runtime")?;
    runtime.block_on(async {
        match command {
            ClusterCommand::Worker(args) => worker(args).await,
            ClusterCommand::Fetch(args) => fetch(args).await,
            ClusterCommand::Status(args) => {
                let site = args.open().await?;
                let status = depthmesh_cluster::status::status(&site).await?;
                println!("{}", serde_json::to_string_pretty(&status)?);
                Ok(())
            }
            ClusterCommand::Replay(args) => replay(args, quiet).await,
            ClusterCommand::Tracker(args) => tracker(args).await,
        }
    })
}

async fn worker(args: &WorkerArgs) -> Result<()> {
    if args.checkpoint_every == 0 {
        bail!("--checkpoint-every must be at least 1");
    }
    let site = args.site.connect().await?;
    site.settle_config(&args.map.config()?).await?;
    let options = WorkerOptions {
        id: name(&args.name)?,
        checkpoint_every: args.checkpoint_every,
    };
    depthmesh_cluster::worker::run(&site, &options, &stop_on_signal()).await?;
    Ok(())
}

async fn tracker(args: &TrackerArgs) -> Result<()> {
    let site = args.site.connect().await?;
    let options = TrackerOptions {
        id: name(&args.name)?,
        sensor: args.sensor.clone(),
        tracking: TrackerConfig::default(),
    };
    depthmesh_cluster::tracker::run(&site, &options, &stop_on_signal()).await?;
    Ok(())
}

/// The `--name` given, checked, or a generated one.
fn name(given: &Option<String>) -> Result<String> {
    let id = given.clone().unwrap_or_else(default_name);
    if !depthmesh_server::protocol::valid_session_name(&id) {
        bail!("--name {id:?}: 1 to 64 letters, digits, '-' or '_'");
    }
    Ok(id)
}

/// A flag set by Ctrl-C or SIGTERM: a worker then checkpoints and hands its
/// shards over instead of leaving them to expire.
fn stop_on_signal() -> Arc<AtomicBool> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    tokio::spawn(async move {
        let term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate());
        match term {
            Ok(mut term) => {
                tokio::select! {
                    _ = tokio::signal::ctrl_c() => {}
                    _ = term.recv() => {}
                }
            }
            Err(_) => {
                let _ = tokio::signal::ctrl_c().await;
            }
        }
        flag.store(true, Ordering::Relaxed);
    });
    stop
}

/// A worker name unique enough on one site: host, process id and start time.
fn default_name() -> String {
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_string())
        .unwrap_or_default();
    let host: String = host
        .chars()
        .filter(|c| c.is_ascii_alphanumeric() || *c == '-')
        .take(32)
        .collect();
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    format!(
        "{}-{}-{nanos:x}",
        if host.is_empty() { "worker" } else { &host },
        std::process::id()
    )
}

async fn fetch(args: &FetchArgs) -> Result<()> {
    if !(args.timeout.is_finite() && args.timeout > 0.0) {
        bail!("--timeout must be a positive number of seconds");
    }
    let site = args.site.open().await?;
    let wait = args.wait.then(|| Duration::from_secs_f64(args.timeout));
    let (mesh, report) = depthmesh_cluster::fetch::fetch(&site, wait).await?;
    write_mesh(&args.output, &mesh)?;
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(())
}

async fn replay(args: &ReplayArgs, quiet: bool) -> Result<()> {
    let site = args.site.open().await?;
    site.settle_config(&args.map.config()?).await?;
    let bar = progress::bar(0, "replay", quiet);
    let (mesh, report) = depthmesh_cluster::fetch::replay(&site, |seq, last| {
        bar.set_length(last);
        bar.set_position(seq);
    })
    .await?;
    bar.finish_and_clear();
    write_mesh(&args.output, &mesh)?;
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(())
}
