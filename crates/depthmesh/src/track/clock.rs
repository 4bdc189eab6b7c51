//! The frames' clock: how many frame intervals passed between one frame
//! and the next, read from their timestamps, so that the motion model
//! predicts across frames the sensor dropped (a USB hiccup, a busy
//! machine, a recording with gaps) instead of taking the camera to have
//! moved one frame's worth while it moved several.
//!
//! The interval is learnt from the frames themselves (a Kinect's 30 Hz, a
//! recording's frame numbers), so timestamps in any unit serve, and learnt
//! again when the frames keep coming at a longer one (a sensor switched
//! to half its rate).

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
}

impl FrameClock {
    /// The frame intervals from the last frame to one taken at
    /// `timestamp`, at least 1: 1 for the first frame, for timestamps that
    /// do not increase (nothing to read from them), and while the interval
    /// is being learnt; 2 when one frame was dropped, and so on.
    pub fn steps(&mut self, timestamp: f64) -> usize {
        let Some(last) = self.last.replace(timestamp) else {
            return 1;
        };
        let dt = timestamp - last;
        if !(dt > 0.0 && dt.is_finite()) {
            return 1;
        }
        match self.interval {
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
            _ => {
                self.interval = Some(dt);
                self.gaps_in_a_row = 0;
                1
            }
        }
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
        let steps: Vec<usize> = times.iter().map(|&t| clock.steps(t)).collect();
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
            .map(|&t| clock.steps(t))
            .collect();
        assert_eq!(steps, [1, 1, 1, 1, 2]);
        assert_eq!(clock.interval, Some(1.0));
    }

    #[test]
    fn a_rate_halved_for_good_is_learnt_again() {
        let mut clock = FrameClock::default();
        let steps: Vec<usize> = (0..50)
            .map(|i| clock.steps(if i < 10 { i } else { 2 * i - 10 } as f64))
            .collect();
        // Ten frames a unit apart, then every other one for good: read as
        // one dropped frame each until 30 in a row have said so.
        assert!(steps[..11].iter().all(|&s| s == 1), "{steps:?}");
        assert!(steps[11..41].iter().all(|&s| s == 2), "{steps:?}");
        assert!(steps[41..].iter().all(|&s| s == 1), "{steps:?}");
        assert_eq!(clock.interval, Some(2.0));
    }

    #[test]
    fn timestamps_that_do_not_increase_say_one_frame() {
        let mut clock = FrameClock::default();
        for t in [5.0, 5.0, 4.0, f64::NAN, 6.0] {
            assert_eq!(clock.steps(t), 1, "{t}");
        }
    }
}
