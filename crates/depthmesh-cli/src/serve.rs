//! `depthmesh serve`: the mapping service. Sensor clients (`depthmesh
//! stream`) connect over a WebSocket and map a session each, with the map
//! flags of `reconstruct`; each session writes the run's files into
//! `--out/<session>/` when it ends.

use crate::map_args::MapArgs;
use anyhow::{bail, Context, Result};
use clap::Args;
use depthmesh::track::TrackerConfig;
use depthmesh_server::{Limits, ServeOptions, Server};
use rand::rngs::OsRng;
use rand::RngCore;
use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

/// Flags of `depthmesh serve`.
#[derive(Args, Debug, Clone)]
pub struct ServeArgs {
    /// Address to listen on; port 0 picks a free one.
    #[arg(long, default_value = "127.0.0.1:7878")]
    pub bind: SocketAddr,
    /// The token every client must present (default: a random one, printed;
    /// required to listen beyond this machine).
    #[arg(long, env = "DEPTHMESH_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// Sessions write their files into OUT/<session>/.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub map: MapArgs,
    /// Largest message a client may send, bytes.
    #[arg(long, default_value_t = Limits::default().max_message_bytes)]
    pub max_message_bytes: usize,
    /// Largest depth image a client may send, pixels.
    #[arg(long, default_value_t = Limits::default().max_frame_pixels)]
    pub max_frame_pixels: u64,
    /// Sessions mapping at once.
    #[arg(long, default_value_t = Limits::default().max_sessions)]
    pub max_sessions: usize,
    /// Seconds a client may stay silent before its session ends.
    #[arg(long, default_value_t = Limits::default().idle_timeout.as_secs())]
    pub idle_timeout: u64,
    /// Frames a client may have in flight.
    #[arg(long, default_value_t = Limits::default().window)]
    pub window: u32,
    /// Each session keeps its map in OUT/<session>/map.store, checkpointed
    /// as it goes; after a crash, `stream --session NAME --resume` continues
    /// it (tsdf, planes and mabdi maps).
    #[arg(long)]
    pub store: bool,
    /// With --store: commit a checkpoint every this many frames.
    #[arg(long, default_value_t = 30)]
    pub checkpoint_every: u32,
    /// Show a cluster site in the browser view too, as `site-NAME`: the
    /// NATS server (nats://HOST:PORT) of --site.
    #[arg(long, requires = "site")]
    pub nats: Option<String>,
    /// The site to show (--nats).
    #[arg(long, requires = "nats")]
    pub site: Option<String>,
}

/// Runs `serve` until interrupted (Ctrl-C or SIGTERM): live sessions then
/// end and write their files.
pub fn run(args: &ServeArgs) -> Result<()> {
    args.map.check()?;
    let limits = Limits {
        max_message_bytes: args.max_message_bytes,
        max_frame_pixels: args.max_frame_pixels,
        max_sessions: args.max_sessions,
        idle_timeout: Duration::from_secs(args.idle_timeout),
        window: args.window,
    };
    for (flag, value) in [
        ("--max-message-bytes", args.max_message_bytes as u64),
        ("--max-frame-pixels", args.max_frame_pixels),
        ("--max-sessions", args.max_sessions as u64),
        ("--idle-timeout", args.idle_timeout),
        ("--window", u64::from(args.window)),
        ("--checkpoint-every", u64::from(args.checkpoint_every)),
    ] {
        if value == 0 {
            bail!("{flag} must be at least 1");
        }
    }
    let (token, generated) = match &args.token {
        Some(t) if t.trim().is_empty() => bail!("--token must not be empty"),
        Some(t) => (t.clone(), false),
        None if !args.bind.ip().is_loopback() => bail!(
            "--bind {} listens beyond this machine: give --token (or DEPTHMESH_TOKEN)",
            args.bind
        ),
        None => (random_token(), true),
    };
    let map = args.map.clone();
    let options = ServeOptions {
        bind: args.bind,
        token: token.clone(),
        out: args.out.clone(),
        limits,
        depth_range: (args.map.tsdf.depth_min, args.map.tsdf.depth_max),
        tracker: TrackerConfig::default(),
        map: Box::new(move |k| map.config(k)),
        checkpoint_every: args.store.then_some(args.checkpoint_every),
    };
    let runtime = tokio::runtime::Runtime::new().context("cannot start the server's runtime")?;
    runtime.block_on(async {
        let server = Server::start(options)
            .await
            .with_context(|| format!("cannot listen on {}", args.bind))?;
        let mut stdout = std::io::stdout();
        writeln!(stdout, "listening on http://{}", server.addr)?;
        if generated {
            writeln!(stdout, "token: {token}")?;
        }
        stdout.flush()?;
        match (&args.nats, &args.site) {
            (Some(url), Some(site)) => {
                tokio::select! {
                    _ = interrupted() => {}
                    _ = show_site(url, site, &server) => {}
                }
            }
            _ => interrupted().await,
        }
        eprintln!("stopping: live sessions write their files");
        server.stop().await.context("server")?;
        Ok(())
    })
}

/// Shows `site` on `server` for as long as the server runs; a failure on
/// the bus is said and the site followed again a little later.
async fn show_site(url: &str, site: &str, server: &Server) {
    let stop = std::sync::atomic::AtomicBool::new(false);
    loop {
        let followed = async {
            let s = depthmesh_cluster::Site::connect(url, site, None).await?;
            depthmesh_cluster::view::follow(&s, server, &stop).await
        };
        if let Err(e) = followed.await {
            eprintln!("site {site} on {url}: {e}; trying again in 5 s");
        }
        tokio::time::sleep(Duration::from_secs(5)).await;
    }
}

/// Waits for Ctrl-C or SIGTERM.
async fn interrupted() {
    let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
        .expect("signal handler");
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {}
        _ = term.recv() => {}
    }
}

/// 128 random bits, hex.
fn random_token() -> String {
    let mut bytes = [0u8; 16];
    OsRng.fill_bytes(&mut bytes);
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}
