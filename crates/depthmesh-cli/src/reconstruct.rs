//! `depthmesh reconstruct`: a recorded depth sequence into a map, with the
//! data's poses or tracked ones.

use crate::dataset_args::DatasetArgs;
use crate::export::RunExportArgs;
use crate::map_args::MapArgs;
use crate::memory::{median_depth, MemoryArgs};
use crate::out_dir::OutDir;
use crate::progress;
use crate::run::{conclude, report_event};
use crate::status::StatusWriter;
use crate::store::{dataset_identity, StoreArgs};
use anyhow::{bail, Context, Result};
use clap::Args;
use depthmesh::dataset::{Dataset, DatasetOptions};
use depthmesh::session::run_files::RunFiles;
use depthmesh::session::SessionConfig;
use depthmesh::track::TrackerConfig;
use serde_json::{json, Map};
use std::path::PathBuf;

/// Flags of `depthmesh reconstruct`.
#[derive(Args, Debug, Clone)]
pub struct ReconstructArgs {
    /// A 7-Scenes frames folder or a TUM RGB-D folder (detected).
    pub dataset: PathBuf,
    #[command(flatten)]
    pub map: MapArgs,
    #[command(flatten)]
    pub frames: DatasetArgs,
    /// Write a shaded "status image" of the map seen from the camera every N frames.
    #[arg(long, default_value_t = 0)]
    pub status_every: usize,
    /// Estimate poses by ICP against the map (only the first frame's pose is
    /// taken from the data, or the origin when it has none).
    #[arg(long)]
    pub track: bool,
    /// Go on past unreadable frames, reporting them.
    #[arg(long)]
    pub skip_bad_frames: bool,
    /// Output folder: new, empty, or an earlier run's with --force.
    #[arg(long)]
    pub out: PathBuf,
    /// Replace an earlier run in --out (without it, a folder holding one is refused).
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub export: RunExportArgs,
    #[command(flatten)]
    pub memory: MemoryArgs,
    #[command(flatten)]
    pub store: StoreArgs,
}

/// Runs `reconstruct`.
pub fn run(args: &ReconstructArgs, quiet: bool) -> Result<()> {
    args.export.check()?;
    args.map.check()?;
    args.map.bounded.check_export(&args.export)?;
    let options = args.frames.options(DatasetOptions {
        depth_min: args.map.tsdf.depth_min,
        depth_max: args.map.tsdf.depth_max,
        color: args.map.color,
        skip_bad_frames: args.skip_bad_frames,
        ..DatasetOptions::default()
    })?;
    let dataset = Dataset::open(&args.dataset, &options)?;
    if dataset.is_empty() {
        bail!("{}: no frames selected", args.dataset.display());
    }
    let first = dataset.frame(0)?;
    if args.map.color && first.color.is_none() {
        bail!(
            "--color: {} has no colour image for its first frame (7-Scenes: \
             frame-NNNNNN.color.jpg or .png; TUM: rgb.txt); without one the mesh would be black",
            args.dataset.display()
        );
    }
    let k = dataset.intrinsics();
    let map = args.map.config(k);
    let depth = median_depth(&first.depth);
    args.memory.check_map(&map, &k, dataset.len(), depth)?;
    let config = SessionConfig {
        intrinsics: k,
        map,
        tracking: args.track.then(TrackerConfig::default),
    };
    let (mut session, mut store, position) = args.store.open(
        config,
        || dataset_identity(&args.dataset, &dataset),
        dataset.len(),
    )?;
    args.map.bounded.note_reach(&session);
    let out = OutDir::prepare(&args.out, args.force || args.store.resume)?;
    let mut files = RunFiles::create(&args.out, &session)?;
    let mut status = StatusWriter::new(args.status_every, files.path("status"));
    let bar = progress::bar(dataset.len() as u64, "reconstruct", quiet);
    bar.inc(position as u64);
    let mut frames = dataset.frames_from(position);
    let mut colourless = 0;
    let mut stopped = None;
    while let Some(frame) = frames.next() {
        let frame = frame?;
        colourless += usize::from(args.map.color && frame.color.is_none());
        let outcome = session
            .push(&frame)
            .with_context(|| format!("frame {}", frame.index))?;
        report_event(&bar, frame.index, outcome.event);
        let pose = outcome.record.pose;
        files.after_frame(&mut session)?;
        status.after_frame(&session, &k, pose, frame.index)?;
        store.after_frame(&session, frames.position())?;
        bar.inc(1);
        if let Some(why) = args.memory.exceeded(&session) {
            bar.suspend(|| eprintln!("frame {}: {why}: stopping", frame.index));
            stopped = Some((frame.index, why));
            break;
        }
    }
    bar.finish_and_clear();
    if colourless > 0 {
        eprintln!("warning: --color: {colourless} frame(s) had no colour image and left no colour");
    }
    for s in frames.skipped() {
        eprintln!("skipped frame {}: {}", s.index, s.error);
    }
    if session.records().is_empty() {
        bail!("{}: no frame could be read", args.dataset.display());
    }
    let mut summary = Map::new();
    summary.insert("dataset".into(), args.dataset.display().to_string().into());
    summary.insert("skipped_frames".into(), json!(frames.skipped().len()));
    if let Some((index, _)) = &stopped {
        summary.insert("stopped_at_frame".into(), json!(index));
    }
    summary.insert(
        "integrate_fps".into(),
        json!(session.records().len() as f64 / session.seconds()),
    );
    store.summarise(&session, &mut summary)?;
    let summary = files.finish(&mut session, summary)?;
    args.export.write(session.mesh(), &args.out)?;
    // A run that lost tracking keeps its files: they show what happened.
    out.keep();
    conclude(&session, &summary, &args.out, quiet, "frame", stopped)
}
