//! Where each frame's pose comes from: the frame itself, or ICP against the
//! map (only the first frame's pose is taken from the data, or the origin).

use crate::camera::{Intrinsics, Pose};
use crate::error::{Error, Result};
use crate::image::Frame;
use crate::map::Mapper;
use crate::track::clock::FrameClock;
use crate::track::{LostReason, Tracked, Tracker, TrackerConfig, TrackerState};
use std::time::Instant;

/// The tracking columns of a frame's record.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackRecord {
    /// Milliseconds spent tracking (part of the record's `ms`).
    pub ms: f64,
    /// Fraction of the frame's points matched with the map.
    pub inlier_fraction: f64,
    /// RMS point-to-plane error of the matches in millimetres.
    pub residual_mm: f64,
    /// How well the view pins down all six degrees of freedom (0: not at all).
    pub conditioning: f64,
    /// ICP iterations run, all levels.
    pub iterations: usize,
    /// Directions of motion the view barely constrains, taken from the
    /// motion model instead of the data (0 to 6).
    pub weak_directions: u8,
    /// Which: a bit per axis, as [`crate::track::degeneracy::axes_label`] names them.
    pub weak_axes: u8,
    /// The frame was found again after a loss.
    pub relocalised: bool,
    /// Following lost the frame and the search for the lost camera found
    /// it in the same frame (it is fused, not lost).
    pub recovered: bool,
    /// Why the frame was lost (and not fused), if it was.
    pub lost: Option<LostReason>,
    /// Lost for space seen empty, but followed on from its pose: something
    /// in view where earlier frames saw through (see [`Tracked::held`]).
    pub held: bool,
}

/// A change of tracking state, worth telling the person watching.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TrackEvent {
    /// The first frame of a run of lost frames.
    Lost(LostReason),
    /// The first frame of a run of lost frames, held: followed on from its
    /// pose but not fused, for this reason (see [`Tracked::held`]).
    Held(LostReason),
    /// The first good frame after `after` lost ones.
    Recovered {
        /// Frames lost before this one.
        after: usize,
    },
    /// A frame following lost, for this reason, and the search for the
    /// lost camera found in the same frame: it is fused, not lost.
    FoundAgain(LostReason),
}

/// The pose decided for one frame.
#[derive(Clone, Copy, Debug)]
pub(super) struct Decided {
    /// The pose to fuse the frame with; `None` when tracking lost it.
    pub pose: Option<Pose>,
    /// The best estimate of where the camera was: the fused pose, or the
    /// last good one for a lost frame (what trajectory errors count).
    pub estimate: Pose,
    pub track: Option<TrackRecord>,
    pub event: Option<TrackEvent>,
}

/// What a tracked session's pose source carries from frame to frame.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseState {
    /// The tracker's state, once the first frame started it.
    pub tracker: Option<TrackerState>,
    /// Times tracking was lost.
    pub lost: usize,
    /// Frames lost.
    pub lost_frames: usize,
    /// Frames lost in the current run of losses.
    pub streak: usize,
    /// Seconds spent tracking.
    pub track_seconds: f64,
    /// Frames tracked.
    pub tracked: usize,
    /// The frames' timestamps so far.
    pub clock: FrameClock,
    /// Frames the timestamps say the sensor dropped.
    pub dropped_frames: usize,
}

/// Given poses, or a tracker and its count of losses.
#[derive(Debug)]
pub(super) struct PoseSource {
    intrinsics: Intrinsics,
    /// `Some` when poses are tracked; the tracker starts at the first frame.
    tracking: Option<(TrackerConfig, Option<Tracker>)>,
    /// Times tracking was lost (a run of lost frames counts once).
    pub lost: usize,
    /// Frames not fused because tracking lost them.
    pub lost_frames: usize,
    /// Frames lost in the current run of losses.
    streak: usize,
    pub track_seconds: f64,
    pub tracked: usize,
    /// Frame intervals between frames, from their timestamps.
    clock: FrameClock,
    /// Frames the timestamps say the sensor dropped (a frame several
    /// intervals after the last: all but one of them), at the stream's
    /// own rate ([`FrameClock::gap`]).
    pub dropped_frames: usize,
}

impl PoseSource {
    /// Poses for frames from `intrinsics`; tracked with `tracking`'s settings when given.
    pub fn new(tracking: Option<TrackerConfig>, intrinsics: Intrinsics) -> Result<Self> {
        if let Some(config) = &tracking {
            config.validate()?;
        }
        Ok(PoseSource {
            intrinsics,
            tracking: tracking.map(|c| (c, None)),
            lost: 0,
            lost_frames: 0,
            streak: 0,
            track_seconds: 0.0,
            tracked: 0,
            clock: FrameClock::default(),
            dropped_frames: 0,
        })
    }

    /// Whether poses are tracked.
    pub fn tracking(&self) -> bool {
        self.tracking.is_some()
    }

    /// What tracking carries from frame to frame (`None` when poses are
    /// given), to save.
    pub fn state(&self) -> Option<PoseState> {
        let (_, tracker) = self.tracking.as_ref()?;
        Some(PoseState {
            tracker: tracker.as_ref().map(Tracker::state),
            lost: self.lost,
            lost_frames: self.lost_frames,
            streak: self.streak,
            track_seconds: self.track_seconds,
            tracked: self.tracked,
            clock: self.clock,
            dropped_frames: self.dropped_frames,
        })
    }

    /// Goes on from a saved [`PoseSource::state`].
    pub fn restore(&mut self, state: PoseState) -> Result<()> {
        let Some((config, tracker)) = self.tracking.as_mut() else {
            return Err(Error::parameter(
                "tracking",
                "the saved session tracked its poses",
            ));
        };
        *tracker = state
            .tracker
            .map(|t| Tracker::restore(config.clone(), self.intrinsics, t))
            .transpose()?;
        self.lost = state.lost;
        self.lost_frames = state.lost_frames;
        self.streak = state.streak;
        self.track_seconds = state.track_seconds;
        self.tracked = state.tracked;
        self.clock = state.clock;
        self.dropped_frames = state.dropped_frames;
        Ok(())
    }

    /// A frame received at `timestamp` and not decided (see
    /// [`crate::session::Session::pass`]).
    pub fn pass(&mut self, timestamp: f64) {
        if self.tracking() {
            self.dropped_frames += self.clock.pass(timestamp);
        }
    }

    /// The pose of `frame` against `map`, the map built so far.
    pub fn decide(&mut self, frame: &Frame, map: &dyn Mapper) -> Result<Decided> {
        let Some((config, tracker)) = self.tracking.as_mut() else {
            let pose = frame.pose.ok_or_else(|| {
                Error::parameter(
                    format!("frame {}", frame.index),
                    "has no pose: track poses to estimate them",
                )
            })?;
            return Ok(given(pose));
        };
        // Only the tracker predicts across dropped frames, and only a
        // tracked run reports them; the first frame starts the clock.
        let gap = self.clock.gap(frame.timestamp);
        self.dropped_frames += gap.dropped;
        let Some(tracker) = tracker.as_mut() else {
            // The first frame defines the map's frame: its given pose, or the origin.
            let start = frame.pose.unwrap_or(Pose::IDENTITY);
            *tracker = Some(Tracker::new(config.clone(), self.intrinsics, start)?);
            return Ok(given(start));
        };
        let start = Instant::now();
        let t = tracker.track_after(&frame.depth, gap.steps, map);
        let ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(self.judge(t, ms))
    }

    /// Counts a tracked frame and turns its outcome into a decision.
    fn judge(&mut self, t: Tracked, ms: f64) -> Decided {
        self.track_seconds += ms / 1e3;
        self.tracked += 1;
        let event = match (t.lost, self.streak) {
            (Some(reason), 0) if t.held => Some(TrackEvent::Held(reason)),
            (Some(reason), 0) => Some(TrackEvent::Lost(reason)),
            (None, n) if n > 0 => Some(TrackEvent::Recovered { after: n }),
            (None, _) => t.recovered_from.map(TrackEvent::FoundAgain),
            _ => None,
        };
        if t.lost.is_some() {
            self.lost += usize::from(self.streak == 0);
            self.lost_frames += 1;
            self.streak += 1;
        } else {
            self.streak = 0;
        }
        Decided {
            pose: t.lost.is_none().then_some(t.pose),
            estimate: t.pose,
            track: Some(TrackRecord {
                ms,
                inlier_fraction: t.inlier_fraction,
                residual_mm: t.rms * 1e3,
                conditioning: t.conditioning,
                iterations: t.iterations,
                weak_directions: t.weak_directions,
                weak_axes: t.weak_axes,
                relocalised: t.relocalised,
                recovered: t.recovered_from.is_some(),
                lost: t.lost,
                held: t.held,
            }),
            event,
        }
    }
}

/// A pose taken as given, untracked.
fn given(pose: Pose) -> Decided {
    Decided {
        pose: Some(pose),
        estimate: pose,
        track: None,
        event: None,
    }
}
