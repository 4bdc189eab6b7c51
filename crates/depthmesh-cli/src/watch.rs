//! `depthmesh watch`: a viewer without a browser. Follows a session's view
//! on a `depthmesh serve` as the page does and prints, as JSON, what it
//! received: bytes, part messages, the parts and triangles held, the last
//! figures and the session's summary. For scripts and benchmarks.

use anyhow::{bail, Context, Result};
use clap::Args;
use serde_json::json;
use std::time::Duration;

/// Flags of `depthmesh watch`.
#[derive(Args, Debug, Clone)]
pub struct WatchArgs {
    /// The session's name.
    pub session: String,
    /// The server, http://HOST:PORT.
    #[arg(long, default_value = "http://127.0.0.1:7878")]
    pub server: String,
    /// The server's token.
    #[arg(long, env = "DEPTHMESH_TOKEN", hide_env_values = true)]
    pub token: String,
    /// Stop when nothing arrives for this many seconds (the session may
    /// not have ended).
    #[arg(long, default_value_t = 60.0)]
    pub timeout: f64,
}

/// Runs `depthmesh watch`.
pub fn run(args: &WatchArgs) -> Result<()> {
    if !(args.timeout > 0.0 && args.timeout.is_finite()) {
        bail!(
            "--timeout must be a positive number of seconds, got {}",
            args.timeout
        );
    }
    let runtime = tokio::runtime::Runtime::new().context("cannot start the viewer's runtime")?;
    let watched = runtime
        .block_on(depthmesh_server::watcher::watch(
            &args.server,
            &args.token,
            &args.session,
            Duration::from_secs_f64(args.timeout),
        ))
        .map_err(anyhow::Error::msg)?;
    println!(
        "{}",
        json!({
            "session": args.session,
            "ended": watched.ended.is_some(),
            "bytes": watched.bytes,
            "messages": watched.messages,
            "part_messages": watched.part_messages,
            "parts": watched.parts,
            "triangles": watched.triangles,
            "figures": watched.figures,
            "summary": watched.ended,
        })
    );
    if watched.ended.is_none() {
        bail!(
            "session {}: no end within {} s of silence",
            args.session,
            args.timeout
        );
    }
    Ok(())
}
