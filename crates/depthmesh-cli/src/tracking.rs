//! Where each frame's pose comes from: the data, or, with `--track`, ICP
//! against the map (only the first frame's pose is taken from the data).

use crate::output::TrackStats;
use anyhow::{bail, Context, Result};
use depthmesh::map::{IntegrateReport, Mapper};
use depthmesh::track::{Tracker, TrackerConfig};
use depthmesh::{DepthImage, Frame, Intrinsics, Pose};
use indicatif::ProgressBar;
use serde_json::{json, Map, Value};
use std::time::Instant;

/// What became of one frame.
#[derive(Debug)]
pub struct Fused {
    /// The pose it was fused with; `None` when tracking lost it.
    pub pose: Option<Pose>,
    /// What the map reported (nothing for a lost frame).
    pub report: IntegrateReport,
    /// Tracking figures, when tracking.
    pub track: Option<TrackStats>,
}

/// The pose decided for one frame.
#[derive(Debug)]
struct FramePose {
    /// The pose to fuse the frame with; `None` when tracking lost it.
    pub pose: Option<Pose>,
    /// Tracking figures, when tracking.
    pub track: Option<TrackStats>,
    /// A line for the console (tracking lost or recovered).
    pub message: Option<String>,
}

/// Given poses, or a tracker and its count of losses.
#[derive(Debug)]
pub struct PoseSource {
    intrinsics: Intrinsics,
    track: bool,
    tracker: Option<Tracker>,
    /// Times tracking was lost (a run of lost frames counts once).
    lost: usize,
    lost_frames: usize,
    /// Frames lost in the current run of losses.
    streak: usize,
    track_seconds: f64,
    tracked: usize,
}

impl PoseSource {
    /// Poses for frames from `intrinsics`; tracked when `track` is set.
    pub fn new(track: bool, intrinsics: Intrinsics) -> Self {
        PoseSource {
            intrinsics,
            track,
            tracker: None,
            lost: 0,
            lost_frames: 0,
            streak: 0,
            track_seconds: 0.0,
            tracked: 0,
        }
    }

    /// Decides `frame`'s pose (`given` is the data's) and fuses the frame
    /// into `map` unless tracking lost it; losses and recoveries are printed
    /// above `bar`. Errors name the frame as `what` N.
    pub fn fuse(
        &mut self,
        frame: &Frame,
        given: Option<Pose>,
        map: &mut dyn Mapper,
        bar: &ProgressBar,
        what: &str,
    ) -> Result<Fused> {
        let decided = self.pose(frame.index, given, &frame.depth, map)?;
        if let Some(message) = &decided.message {
            bar.suspend(|| eprintln!("{message}"));
        }
        let report = match decided.pose {
            Some(pose) => map
                .integrate(frame, &pose)
                .with_context(|| format!("{what} {}", frame.index))?,
            None => IntegrateReport::default(),
        };
        Ok(Fused {
            pose: decided.pose,
            report,
            track: decided.track,
        })
    }

    /// The pose of frame `frame` with depth `depth`; `given` is the data's
    /// pose, `map` the map built so far.
    fn pose(
        &mut self,
        frame: usize,
        given: Option<Pose>,
        depth: &DepthImage,
        map: &dyn Mapper,
    ) -> Result<FramePose> {
        if !self.track {
            let Some(pose) = given else {
                bail!("frame {frame} has no pose: add --track to estimate poses by ICP");
            };
            return Ok(FramePose {
                pose: Some(pose),
                track: None,
                message: None,
            });
        }
        let Some(tracker) = self.tracker.as_mut() else {
            // The first frame defines the map's frame: its given pose, or the origin.
            let start = given.unwrap_or(Pose::IDENTITY);
            self.tracker = Some(Tracker::new(
                TrackerConfig::default(),
                self.intrinsics,
                start,
            )?);
            return Ok(FramePose {
                pose: Some(start),
                track: None,
                message: None,
            });
        };
        let start = Instant::now();
        let t = tracker.track(depth, map);
        let ms = start.elapsed().as_secs_f64() * 1e3;
        self.track_seconds += ms / 1e3;
        self.tracked += 1;
        let message = match (t.lost, self.streak) {
            (Some(reason), 0) => {
                self.lost += 1;
                Some(format!("frame {frame}: tracking lost, not fused: {reason}"))
            }
            (None, n) if n > 0 => Some(format!(
                "frame {frame}: tracking recovered after {n} lost frame{}",
                if n == 1 { "" } else { "s" }
            )),
            _ => None,
        };
        if t.lost.is_some() {
            self.lost_frames += 1;
            self.streak += 1;
        } else {
            self.streak = 0;
        }
        Ok(FramePose {
            pose: t.lost.is_none().then_some(t.pose),
            track: Some(TrackStats {
                ms,
                inlier_fraction: t.inlier_fraction,
                residual_mm: t.rms * 1e3,
                conditioning: t.conditioning,
                lost: t.lost.is_some(),
            }),
            message,
        })
    }

    /// Adds `tracking`, `lost`, `lost_frames` and `track_ms` (mean per
    /// tracked frame) to a run's summary.
    pub fn summarize(&self, summary: &mut Map<String, Value>) {
        summary.insert("tracking".into(), json!(self.track));
        if self.track {
            summary.insert("lost".into(), json!(self.lost));
            summary.insert("lost_frames".into(), json!(self.lost_frames));
            summary.insert(
                "track_ms".into(),
                json!(self.track_seconds * 1e3 / self.tracked.max(1) as f64),
            );
        }
    }
}
