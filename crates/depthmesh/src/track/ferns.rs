//! Keyframes for relocalisation, encoded by random ferns on small depth
//! thumbnails (Glocker, Shotton, Criminisi and Izadi 2015, as InfiniTAM
//! uses them): a frame becomes a short code, one small integer per fern;
//! frames whose codes differ in few ferns saw the scene from nearby, so the
//! poses of the keyframes most like a lost frame are where to look for it.
//!
//! Memory is bounded: at most [`FernConfig::max_keyframes`] keyframes of
//! [`FernConfig::ferns`] bytes and a pose each (1000 × 500 B ≈ 0.5 MB with
//! the defaults). A frame is learnt only when no keyframe is like it (its
//! smallest dissimilarity exceeds [`FernConfig::novelty`]), so a camera that
//! stays in one place adds nothing; once the store is full, no more are
//! learnt and the places first mapped stay findable.

use crate::camera::Pose;
use crate::error::{Error, Result};
use crate::image::DepthImage;

/// Thumbnail size (Glocker et al. use 40 × 30: coarse enough that a few
/// centimetres of motion change few ferns).
const THUMB_WIDTH: usize = 40;
const THUMB_HEIGHT: usize = 30;

/// Depth thresholds of the fern tests are drawn from this range (metres),
/// where depth cameras for rooms measure.
const THRESHOLD_RANGE: (f32, f32) = (0.4, 4.0);

/// Binary tests per fern: a code is 4 bits (Glocker et al.'s choice).
const TESTS_PER_FERN: usize = 4;

/// Seed of the tests: the same ferns in every run, so runs are repeatable.
const SEED: u64 = 0x0d3e_97f4_5eed_0001;

/// Settings of the keyframe store.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FernConfig {
    /// Ferns per code (Glocker et al.: 500).
    pub ferns: usize,
    /// Keyframes kept at most.
    pub max_keyframes: usize,
    /// A well-tracked frame becomes a keyframe when it differs from every
    /// keyframe in more than this fraction of ferns.
    pub novelty: f64,
    /// Keyframes a lost frame is tried from, most alike first.
    pub candidates: usize,
}

impl Default for FernConfig {
    fn default() -> Self {
        FernConfig {
            ferns: 500,
            max_keyframes: 1000,
            novelty: 0.1,
            candidates: 6,
        }
    }
}

impl FernConfig {
    /// Rejects settings that cannot encode or find anything.
    pub fn validate(&self) -> Result<()> {
        let counts = [
            ("relocalisation ferns", self.ferns, 1, 4096),
            (
                "relocalisation max_keyframes",
                self.max_keyframes,
                1,
                100_000,
            ),
            ("relocalisation candidates", self.candidates, 1, 64),
        ];
        for (name, v, lo, hi) in counts {
            if !(lo..=hi).contains(&v) {
                return Err(Error::parameter(
                    name,
                    format!("must be {lo}..={hi}, got {v}"),
                ));
            }
        }
        if !(self.novelty > 0.0 && self.novelty < 1.0) {
            return Err(Error::parameter(
                "relocalisation novelty",
                format!("must be a fraction in (0, 1), got {}", self.novelty),
            ));
        }
        Ok(())
    }
}

/// One binary test: is the thumbnail at `cell` at least `threshold` deep?
#[derive(Clone, Copy, Debug)]
struct Test {
    cell: usize,
    threshold: f32,
}

/// The ferns and the keyframes encoded with them.
#[derive(Clone, Debug)]
pub struct Keyframes {
    config: FernConfig,
    tests: Vec<Test>,
    /// One code per keyframe, `config.ferns` bytes each, back to back.
    codes: Vec<u8>,
    poses: Vec<Pose>,
    /// Scratch buffers, reused across frames.
    thumb: Vec<f32>,
    blurred: Vec<f32>,
    code: Vec<u8>,
    distances: Vec<(usize, usize)>,
}

impl Keyframes {
    /// An empty store with `config`'s ferns.
    pub fn new(config: FernConfig) -> Result<Self> {
        config.validate()?;
        let mut state = SEED;
        let tests = (0..config.ferns * TESTS_PER_FERN)
            .map(|_| {
                let cell = (next(&mut state) % (THUMB_WIDTH * THUMB_HEIGHT) as u64) as usize;
                let unit = (next(&mut state) >> 40) as f32 / (1u64 << 24) as f32;
                let (lo, hi) = THRESHOLD_RANGE;
                Test {
                    cell,
                    threshold: lo + unit * (hi - lo),
                }
            })
            .collect();
        Ok(Keyframes {
            config,
            tests,
            codes: Vec::new(),
            poses: Vec::new(),
            thumb: Vec::new(),
            blurred: Vec::new(),
            code: Vec::new(),
            distances: Vec::new(),
        })
    }

    /// The keyframes learnt, to save: their codes back to back, and poses.
    pub fn saved(&self) -> (&[u8], &[Pose]) {
        (&self.codes, &self.poses)
    }

    /// Puts back keyframes from [`Keyframes::saved`]; codes of the wrong
    /// length for this configuration are an error.
    pub fn restore(&mut self, codes: Vec<u8>, poses: Vec<Pose>) -> Result<()> {
        if codes.len() != poses.len() * self.config.ferns {
            return Err(crate::error::Error::parameter(
                "keyframes",
                format!(
                    "{} code bytes for {} keyframes of {} ferns",
                    codes.len(),
                    poses.len(),
                    self.config.ferns
                ),
            ));
        }
        self.codes = codes;
        self.poses = poses;
        Ok(())
    }

    /// Keyframes learnt so far.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// Whether no keyframe was learnt yet.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Learns `depth`, seen from `pose`, as a keyframe unless one like it is
    /// known or the store is full; whether it was learnt.
    pub fn learn(&mut self, depth: &DepthImage, pose: &Pose) -> bool {
        if self.len() >= self.config.max_keyframes {
            return false;
        }
        self.encode(depth);
        let ferns = self.config.ferns;
        let novel = self
            .codes
            .chunks_exact(ferns)
            .all(|c| differing(c, &self.code) as f64 > self.config.novelty * ferns as f64);
        if novel {
            self.codes.extend_from_slice(&self.code);
            self.poses.push(*pose);
        }
        novel
    }

    /// The poses of the keyframes most like `depth`, most alike first, at
    /// most [`FernConfig::candidates`] of them, with their dissimilarity
    /// (fraction of ferns that differ).
    pub fn nearest(&mut self, depth: &DepthImage) -> Vec<(Pose, f64)> {
        self.encode(depth);
        let ferns = self.config.ferns;
        self.distances.clear();
        self.distances.extend(
            self.codes
                .chunks_exact(ferns)
                .map(|c| differing(c, &self.code))
                .enumerate(),
        );
        self.distances.sort_by_key(|&(i, d)| (d, i));
        self.distances
            .iter()
            .take(self.config.candidates)
            .map(|&(i, d)| (self.poses[i], d as f64 / ferns as f64))
            .collect()
    }

    /// Encodes `depth` into `self.code`.
    fn encode(&mut self, depth: &DepthImage) {
        thumbnail(depth, &mut self.thumb);
        blur(&self.thumb, &mut self.blurred);
        self.code.clear();
        for fern in self.tests.chunks_exact(TESTS_PER_FERN) {
            let code = fern.iter().enumerate().fold(0u8, |code, (bit, t)| {
                code | (u8::from(self.blurred[t.cell] >= t.threshold) << bit)
            });
            self.code.push(code);
        }
    }
}

/// Ferns whose codes differ.
fn differing(a: &[u8], b: &[u8]) -> usize {
    a.iter().zip(b).filter(|(a, b)| a != b).count()
}

/// SplitMix64: a small, well-mixed generator for the fern tests.
fn next(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// `depth` averaged over a [`THUMB_WIDTH`] × [`THUMB_HEIGHT`] grid of
/// cells, missing depth left out; a cell with fewer than half its pixels
/// measured is 0 (unknown).
fn thumbnail(depth: &DepthImage, out: &mut Vec<f32>) {
    out.clear();
    out.resize(THUMB_WIDTH * THUMB_HEIGHT, 0.0);
    let (w, h) = (depth.width as usize, depth.height as usize);
    for (cy, row) in out.chunks_exact_mut(THUMB_WIDTH).enumerate() {
        let (y0, y1) = (cy * h / THUMB_HEIGHT, (cy + 1) * h / THUMB_HEIGHT);
        for (cx, cell) in row.iter_mut().enumerate() {
            let (x0, x1) = (cx * w / THUMB_WIDTH, (cx + 1) * w / THUMB_WIDTH);
            let (mut sum, mut count) = (0.0f32, 0usize);
            for y in y0..y1 {
                for &z in &depth.data[y * w + x0..y * w + x1] {
                    if z > 0.0 {
                        sum += z;
                        count += 1;
                    }
                }
            }
            let area = (y1 - y0) * (x1 - x0);
            if count > 0 && 2 * count >= area {
                *cell = sum / count as f32;
            }
        }
    }
}

/// A 3 × 3 mean of the known cells of a thumbnail (unknown cells stay
/// unknown): a camera moved by a fraction of a cell changes few tests.
fn blur(thumb: &[f32], out: &mut Vec<f32>) {
    out.clear();
    out.resize(thumb.len(), 0.0);
    for y in 0..THUMB_HEIGHT {
        for x in 0..THUMB_WIDTH {
            if thumb[y * THUMB_WIDTH + x] <= 0.0 {
                continue;
            }
            let (mut sum, mut count) = (0.0, 0);
            for ny in y.saturating_sub(1)..(y + 2).min(THUMB_HEIGHT) {
                for nx in x.saturating_sub(1)..(x + 2).min(THUMB_WIDTH) {
                    let z = thumb[ny * THUMB_WIDTH + nx];
                    if z > 0.0 {
                        sum += z;
                        count += 1;
                    }
                }
            }
            out[y * THUMB_WIDTH + x] = sum / count as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(width: u32, height: u32, offset: f32) -> DepthImage {
        let mut d = DepthImage::new(width, height);
        for y in 0..height {
            for x in 0..width {
                d.data[(y * width + x) as usize] = 1.0 + offset + 2.0 * x as f32 / width as f32;
            }
        }
        d
    }

    #[test]
    fn alike_frames_are_not_learnt_twice_and_are_found_first() {
        let mut k = Keyframes::new(FernConfig::default()).unwrap();
        let a = Pose::IDENTITY;
        let b = Pose::from_quat(glam::Quat::IDENTITY, glam::Vec3::X);
        assert!(k.learn(&ramp(160, 120, 0.0), &a));
        // 1 mm further: the same code.
        assert!(!k.learn(&ramp(160, 120, 0.001), &a));
        // Reversed: most tests change.
        let mut far = ramp(160, 120, 0.0);
        far.data.reverse();
        assert!(k.learn(&far, &b));
        assert_eq!(k.len(), 2);
        let found = k.nearest(&ramp(160, 120, 0.01));
        assert_eq!(found[0].0, a);
        // A 1 cm shift flips only the tests within 1 cm of their threshold:
        // a few percent of them.
        assert!(found[0].1 < 0.05, "{}", found[0].1);
        assert!(found[1].1 > 0.3, "{}", found[1].1);
    }

    #[test]
    fn the_store_is_bounded() {
        let config = FernConfig {
            max_keyframes: 2,
            novelty: 0.01,
            ..FernConfig::default()
        };
        let mut k = Keyframes::new(config).unwrap();
        let learnt = (0..5)
            .filter(|&i| k.learn(&ramp(80, 60, 0.5 * i as f32), &Pose::IDENTITY))
            .count();
        assert_eq!(learnt, 2);
        assert_eq!(k.len(), 2);
    }

    #[test]
    fn rejects_bad_settings() {
        for config in [
            FernConfig {
                ferns: 0,
                ..FernConfig::default()
            },
            FernConfig {
                novelty: 1.5,
                ..FernConfig::default()
            },
            FernConfig {
                candidates: 0,
                ..FernConfig::default()
            },
        ] {
            let e = Keyframes::new(config).unwrap_err().to_string();
            assert!(e.contains("relocalisation"), "{e}");
        }
    }
}
