//! What the mapping commands share around a [`Session`]: telling the person
//! watching when tracking is lost or recovered, and the closing lines.

use anyhow::{bail, Result};
use depthmesh::session::{Session, TrackEvent};
use indicatif::ProgressBar;
use serde_json::{Map, Value};
use std::path::Path;

/// Prints a change of tracking state of frame `frame` (the simulator's
/// iteration) above `bar`.
pub fn report_event(bar: &ProgressBar, frame: usize, event: Option<TrackEvent>) {
    let line = match event {
        None => return,
        Some(TrackEvent::Lost(reason)) => {
            format!("frame {frame}: tracking lost, not fused: {reason}")
        }
        Some(TrackEvent::Held(reason)) => format!(
            "frame {frame}: held, not fused, followed on: {reason} \
             (something in view that was not there before, or a place that looks alike)"
        ),
        Some(TrackEvent::Recovered { after }) => format!(
            "frame {frame}: tracking recovered after {after} lost frame{}",
            if after == 1 { "" } else { "s" }
        ),
        Some(TrackEvent::FoundAgain(reason)) => {
            format!("frame {frame}: tracking lost the camera ({reason}) and found it again in the same frame")
        }
    };
    bar.suspend(|| eprintln!("{line}"));
}

/// How the closing lines of `run` and `stream` name frames fused with a
/// direction tracking left to the motion model (after their count).
pub const WEAK_FRAMES: &str = "fused with a direction left to the motion model";

/// The closing lines of a mapping run: frames, speed, map size, lost
/// frames and where the files are; silent when `quiet`.
pub fn print_summary(summary: &Map<String, Value>, out: &Path, quiet: bool) {
    if quiet {
        return;
    }
    let get = |k: &str| summary.get(k).and_then(Value::as_f64).unwrap_or(0.0);
    let mut line = format!(
        "{} frames ({} fused) at {:.1} frames/s: {} triangles, {} vertices",
        get("frames"),
        get("frames_fused"),
        get("fps"),
        get("triangles"),
        get("vertices"),
    );
    if summary.get("tracking") == Some(&Value::Bool(true)) {
        // Held frames are rare, and named only when there were some.
        let held = match get("held_frames") {
            0.0 => String::new(),
            n => format!(", {n} of them held (followed on past something new in view)"),
        };
        // So are frames the sensor dropped, which no record stands for.
        let dropped = match get("dropped_frames") {
            0.0 => String::new(),
            n => format!(", {n} dropped by the sensor (its timestamps skip them)"),
        };
        line += &format!(
            "; tracking lost {} time(s), {} frame(s) not fused ({:.0} % fused){held}, \
             {} found again in the frame following lost them, {} {WEAK_FRAMES}{dropped}",
            get("lost"),
            get("lost_frames"),
            100.0 * get("fused_fraction"),
            get("recovered_frames"),
            get("weak_frames"),
        );
    }
    if let Some(ate) = summary.get("ate_rmse_cm").and_then(Value::as_f64) {
        line += &format!("; ATE {ate:.2} cm over all frames");
    }
    eprintln!("{line}\nwrote {}", out.display());
}

/// Whether a tracked run fused nothing past its first frame: such a run
/// must not end as a success.
fn failed_to_track(session: &Session) -> bool {
    session.config().tracking.is_some()
        && session.records().len() > 1
        && session.frames_fused() <= 1
}

/// The end of a mapping run whose files are written: the closing lines,
/// then a failure if it stopped early (`stopped`: the last frame, called
/// `what` — "frame" or "iteration" — and why) or if tracking fused nothing
/// past the first frame. Such runs keep their files: they show what happened.
pub fn conclude(
    session: &Session,
    summary: &Map<String, Value>,
    out: &Path,
    quiet: bool,
    what: &str,
    stopped: Option<(impl std::fmt::Display, String)>,
) -> Result<()> {
    print_summary(summary, out, quiet);
    if let Some((index, why)) = stopped {
        bail!("stopped after {what} {index}: {why}; the files hold the {what}s up to it");
    }
    if failed_to_track(session) {
        bail!("tracking lost the camera: nothing past the first frame was fused");
    }
    Ok(())
}
