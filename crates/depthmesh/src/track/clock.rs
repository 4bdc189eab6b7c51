//! The frames' clock: how many frame intervals passed between one frame
//! and the next, read from their timestamps, so that the motion model
//! predicts across frames the sensor dropped (a USB hiccup, a busy
//! machine, a recording with gaps) instead of taking the camera to have
//! moved one frame's worth while it moved several.
//!
//! The interval is learnt from the frames themselves (a Kinect's 30 Hz, a
//! recording's frame numbers), so timestamps in any unit serve, and learnt
//! again when the frames keep coming at a longer one (a sensor switched
//! to half its rate, a link that loses five frames in six).
//!
//! Predicting and counting read the gaps differently. The motion model
//! steps by the interval the frames now come at; the count of frames
//! dropped stays with the stream's own rate, the interval learnt before
//! the longer one: a link that loses five frames in six for seconds drops
//! five a frame, not five a frame for a second and then none. A sensor
//! that truly switched to a lower rate reads the same way (nothing in the
//! timestamps tells the two apart), until frames come at the rate
//! before again. Frames received and passed over untracked (a live server
//! mapping the newest) are neither: [`FrameClock::pass`] learns from their
//! timestamps and adds their steps to the next tracked frame's.

/// A gap counts as this many intervals or more only when it is at least
/// this much longer than one: timestamps jitter by a few milliseconds, and
/// a dropped frame doubles the interval.
const LONGER: f64 = 1.5;

/// How much of each regular interval goes into the learnt one: the
/// learnt interval follows a clock that drifts, not one frame's jitter.
const FOLLOW: f64 = 0.1;

/// Frames in a row read as gaps after which their interval is taken as
/// the frames' own: a sensor switched to half its rate, or a machine that
/// keeps only every other frame, drops nothing more.
const RELEARN: usize = 30;

/// The timestamps seen so far (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameClock {
    /// The last frame's timestamp.
    pub last: Option<f64>,
    /// The interval between consecutive frames, once two were seen.
    pub interval: Option<f64>,
    /// Frames in a row read as more than one interval after the last.
    pub gaps_in_a_row: usize,
    /// The stream's own interval, once `interval` was learnt again at a
    /// longer one: what dropped frames are counted against.
    pub own_interval: Option<f64>,
    /// Frame intervals spanned by frames received but not tracked since
    /// the last tracked one ([`FrameClock::pass`]).
    pub passed: usize,
}

/// What the timestamps say of the gap before a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Gap {
    /// Frame intervals since the last frame, at least 1: what the motion
    /// model predicts across.
    pub steps: usize,
    /// Frames missing in the gap at the stream's own rate.
    pub dropped: usize,
}

impl FrameClock {
    /// The gap from the last tracked frame to one taken at `timestamp`:
    /// 1 step and nothing dropped for the first frame, for timestamps
    /// that do not increase (nothing to read from them), and while the
    /// interval is being learnt; 2 steps and 1 dropped when one frame was
    /// dropped, and so on. Frames passed over since ([`FrameClock::pass`])
    /// add their steps, not to the frames dropped.
    pub fn gap(&mut self, timestamp: f64) -> Gap {
        let gap = self.read(timestamp);
        Gap {
            steps: gap.steps + std::mem::take(&mut self.passed),
            dropped: gap.dropped,
        }
    }

    /// A frame received at `timestamp` but not tracked (a live server
    /// keeping up with its sensor maps the newest frame and passes over
    /// the ones before): the clock learns from its timestamp as from any
    /// frame's, and the next tracked frame is predicted across it too.
    /// The frames dropped before it, which were never received.
    pub fn pass(&mut self, timestamp: f64) -> usize {
        let gap = self.read(timestamp);
        self.passed += gap.steps;
        gap.dropped
    }

    /// The gap from the last frame received to one taken at `timestamp`.
    fn read(&mut self, timestamp: f64) -> Gap {
        const NONE: Gap = Gap {
            steps: 1,
            dropped: 0,
        };
        let Some(last) = self.last.replace(timestamp) else {
            return NONE;
        };
        let dt = timestamp - last;
        if !(dt > 0.0 && dt.is_finite()) {
            return NONE;
        }
        let steps = match self.interval {
            // A shorter interval than the one learnt: the first was a gap.
            Some(interval) if dt * LONGER > interval && self.gaps_in_a_row < RELEARN => {
                let steps = (dt / interval).round().max(1.0);
                if steps == 1.0 {
                    self.interval = Some(interval + FOLLOW * (dt - interval));
                    self.gaps_in_a_row = 0;
                } else {
                    self.gaps_in_a_row += 1;
                }
                steps as usize
            }
            previous => {
                let relearnt = previous.is_some_and(|interval| dt * LONGER > interval);
                if relearnt {
                    self.own_interval = self.own_interval.or(previous);
                }
                // Frames at the stream's own rate again, or at a shorter
                // one: that is its rate.
                if self.own_interval.is_some_and(|own| dt < LONGER * own) {
                    self.own_interval = None;
                }
                self.interval = Some(dt);
                self.gaps_in_a_row = 0;
                1
            }
        };
        let dropped = match self.own_interval {
            Some(own) => (dt / own).round().max(1.0) as usize - 1,
            None => steps - 1,
        };
        Gap { steps, dropped }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dropped_frames_count_as_the_intervals_they_span() {
        let mut clock = FrameClock::default();
        // 30 Hz with a few milliseconds of jitter; frames 5-8 dropped.
        let times = [0.0, 0.033, 0.068, 0.1, 0.134, 0.3, 0.333, 0.368];
        let steps: Vec<usize> = times.iter().map(|&t| clock.gap(t).steps).collect();
        assert_eq!(steps, [1, 1, 1, 1, 1, 5, 1, 1]);
        let interval = clock.interval.unwrap();
        assert!((interval - 1.0 / 30.0).abs() < 2e-3, "{interval}");
    }

    #[test]
    fn a_gap_first_is_unlearnt_by_the_regular_frames_after_it() {
        let mut clock = FrameClock::default();
        // Frame numbers as timestamps: 0, then 10 (a gap), then 11, 12, 14.
        let steps: Vec<usize> = [0.0, 10.0, 11.0, 12.0, 14.0]
            .iter()
            .map(|&t| clock.gap(t).steps)
            .collect();
        assert_eq!(steps, [1, 1, 1, 1, 2]);
        assert_eq!(clock.interval, Some(1.0));
    }

    #[test]
    fn a_rate_halved_is_learnt_again_and_its_missing_frames_still_count() {
        let mut clock = FrameClock::default();
        // Ten frames a unit apart, every other one for 40 frames, then a
        // unit apart again.
        let times = (0..10)
            .chain((0..40).map(|i| 10 + 2 * i))
            .chain((0..5).map(|i| 89 + i));
        let gaps: Vec<Gap> = times.map(|t| clock.gap(t as f64)).collect();
        let steps: Vec<usize> = gaps.iter().map(|g| g.steps).collect();
        let dropped: Vec<usize> = gaps.iter().map(|g| g.dropped).collect();
        // Predicted across one dropped frame each until 30 in a row have
        // said the interval is 2; counted as one dropped each throughout.
        assert!(steps[..11].iter().all(|&s| s == 1), "{steps:?}");
        assert!(steps[11..41].iter().all(|&s| s == 2), "{steps:?}");
        assert!(steps[41..].iter().all(|&s| s == 1), "{steps:?}");
        assert!(dropped[..11].iter().all(|&d| d == 0), "{dropped:?}");
        assert!(dropped[11..50].iter().all(|&d| d == 1), "{dropped:?}");
        assert!(dropped[50..].iter().all(|&d| d == 0), "{dropped:?}");
        assert_eq!(clock.interval, Some(1.0));
        assert_eq!(clock.own_interval, None);
    }

    // A server that cannot keep up keeps one frame in three to six: once
    // the interval is learnt again at one of those gaps, the shorter and
    // longer ones after it are still counted against the stream's rate.
    #[test]
    fn frames_dropped_irregularly_for_long_are_counted_at_the_streams_rate() {
        let mut clock = FrameClock::default();
        let mut t = 0.0;
        let mut missing = 0;
        let mut counted = 0;
        for i in 0..200 {
            let every = if i < 5 { 1 } else { 3 + i % 4 };
            t += every as f64 / 30.0;
            missing += every - 1;
            counted += clock.gap(t).dropped;
        }
        assert_eq!(counted, missing);
        assert!(clock.own_interval.is_some());
    }

    // A server maps one frame of its sensor's in three and passes over
    // the others: the clock still learns the sensor's interval from them,
    // each tracked frame is three intervals on, and none was dropped
    // before the server received it; a frame the sensor did drop counts.
    #[test]
    fn frames_passed_over_count_as_steps_not_as_dropped() {
        let mut clock = FrameClock::default();
        let mut gaps = Vec::new();
        for i in 0..60u32 {
            // The sensor drops frame 40.
            if i == 40 {
                continue;
            }
            let t = f64::from(i) / 30.0;
            if i % 3 == 0 {
                gaps.push(clock.gap(t));
            } else {
                assert_eq!(clock.pass(t), usize::from(i == 41), "frame {i}");
            }
        }
        let expected = |steps, dropped| Gap { steps, dropped };
        assert_eq!(gaps[0], expected(1, 0));
        assert!(gaps[1..].iter().all(|&g| g == expected(3, 0)), "{gaps:?}");
        let interval = clock.interval.unwrap();
        assert!((interval - 1.0 / 30.0).abs() < 1e-9, "{interval}");
        // Frame 41, passed over, came two intervals after frame 39; the
        // next tracked frame, 42, is three on from 39.
        assert_eq!(gaps[13..15], [expected(3, 0), expected(3, 0)]);
        let mut clock = FrameClock::default();
        for i in [0, 1, 2] {
            clock.gap(f64::from(i) / 30.0);
        }
        assert_eq!(clock.pass(4.0 / 30.0), 1);
        assert_eq!(clock.gap(5.0 / 30.0), expected(3, 0));
    }

    #[test]
    fn timestamps_that_do_not_increase_say_one_frame() {
        let mut clock = FrameClock::default();
        for t in [5.0, 5.0, 4.0, f64::NAN, 6.0] {
            assert_eq!(
                clock.gap(t),
                Gap {
                    steps: 1,
                    dropped: 0
                },
                "{t}"
            );
        }
    }
}
