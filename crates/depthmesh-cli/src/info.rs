//! `depthmesh info STORE`: what a map store holds (frames, blocks, bytes,
//! last checkpoint, settings), as JSON.

use anyhow::Result;
use clap::Args;
use std::path::PathBuf;

/// Flags of `depthmesh info`.
#[derive(Args, Debug, Clone)]
pub struct InfoArgs {
    /// A map store written by `reconstruct --store`.
    pub store: PathBuf,
}

/// Runs `depthmesh info`.
pub fn run(args: &InfoArgs) -> Result<()> {
    let info = depthmesh::store::info(&args.store)?;
    println!("{}", serde_json::to_string_pretty(&info)?);
    Ok(())
}
