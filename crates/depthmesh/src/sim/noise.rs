//! Depth noise of the simulated sensor.
//!
//! Noise is reproducible: the same seed and iteration give the same image
//! whatever the number of threads, because each row draws from its own
//! generator seeded from (seed, iteration, row).

use crate::error::{Error, Result};
use crate::image::DepthImage;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use rayon::prelude::*;
use std::fmt;
use std::str::FromStr;

/// Standard deviation of Khoshelham's Kinect model per square metre of depth.
const KINECT_SIGMA_PER_M2: f32 = 1.425e-3;

/// A depth noise model, as chosen with `--noise`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum NoiseModel {
    /// Exact depth.
    None,
    /// Eq. 4.2 of the MABDI thesis: Gaussian noise of standard deviation
    /// `sigma` added to the normalised OpenGL z-buffer depth (0 at the near
    /// clipping plane, 1 at the far one), so about `sigma·Z²·(f−n)/(f·n)` metres.
    ZBuffer {
        /// Standard deviation in normalised depth units (the thesis used 0.002).
        sigma: f32,
    },
    /// Khoshelham's Kinect model: Gaussian noise of `1.425e-3·Z²` metres.
    Kinect,
}

impl FromStr for NoiseModel {
    type Err = Error;

    /// Parses `none`, `zbuffer:SIGMA` (e.g. `zbuffer:0.002`) or `kinect`.
    fn from_str(s: &str) -> Result<Self> {
        let bad = |message: String| Error::parameter("noise", message);
        match s {
            "none" => Ok(NoiseModel::None),
            "kinect" => Ok(NoiseModel::Kinect),
            _ => {
                let sigma = s.strip_prefix("zbuffer:").ok_or_else(|| {
                    bad(format!(
                        "unknown noise model \"{s}\": use none, zbuffer:SIGMA (e.g. zbuffer:0.002) or kinect"
                    ))
                })?;
                match sigma.parse::<f32>() {
                    Ok(sigma) if sigma.is_finite() && sigma >= 0.0 => {
                        Ok(NoiseModel::ZBuffer { sigma })
                    }
                    _ => Err(bad(format!(
                        "zbuffer sigma \"{sigma}\" must be a finite number ≥ 0 (normalised depth units, e.g. 0.002)"
                    ))),
                }
            }
        }
    }
}

impl fmt::Display for NoiseModel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NoiseModel::None => f.write_str("none"),
            NoiseModel::ZBuffer { sigma } => write!(f, "zbuffer:{sigma}"),
            NoiseModel::Kinect => f.write_str("kinect"),
        }
    }
}

impl NoiseModel {
    /// Perturbs every measured pixel of `depth` (0 stays 0), for a sensor
    /// clipping at `near < far` metres. A z-buffer value pushed outside (0, 1)
    /// becomes 0: the renderer would have clipped it. The noise depends only
    /// on `seed`, `iteration` and the pixel's row.
    pub fn apply(&self, depth: &mut DepthImage, near: f32, far: f32, seed: u64, iteration: u32) {
        debug_assert!(0.0 < near && near < far, "clipping range {near}..{far}");
        match *self {
            NoiseModel::None => {}
            NoiseModel::ZBuffer { sigma } => {
                // In f64: for a short range the normalised depth loses digits.
                let (n, f, sigma) = (near as f64, far as f64, sigma as f64);
                perturb_rows(depth, seed, iteration, |z, noise| {
                    let z = z as f64;
                    let normalised = f * (z - n) / ((f - n) * z) + sigma * noise as f64;
                    if normalised > 0.0 && normalised < 1.0 {
                        (f * n / (f - normalised * (f - n))) as f32
                    } else {
                        0.0
                    }
                })
            }
            NoiseModel::Kinect => perturb_rows(depth, seed, iteration, |z, noise| {
                (z + KINECT_SIGMA_PER_M2 * z * z * noise).max(0.0)
            }),
        }
    }
}

/// Replaces each measured depth `z` with `perturb(z, standard normal sample)`,
/// row-parallel with one generator per row.
fn perturb_rows(
    depth: &mut DepthImage,
    seed: u64,
    iteration: u32,
    perturb: impl Fn(f32, f32) -> f32 + Sync,
) {
    let width = (depth.width as usize).max(1);
    depth
        .data
        .par_chunks_mut(width)
        .enumerate()
        .for_each(|(row, pixels)| {
            let mut rng = SmallRng::seed_from_u64(row_seed(seed, iteration, row as u32));
            for z in pixels.iter_mut().filter(|z| **z > 0.0) {
                *z = perturb(*z, rng.sample(StandardNormal));
            }
        });
}

/// Mixes (seed, iteration, row) into one generator seed. A fixed
/// hash (SplitMix64's finaliser) rather than std's hasher, whose output may
/// change between Rust releases and would change every simulated run.
fn row_seed(seed: u64, iteration: u32, row: u32) -> u64 {
    let mix = |mut x: u64| {
        x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        x ^ (x >> 31)
    };
    mix(mix(seed) ^ ((iteration as u64) << 32 | row as u64))
}

#[cfg(test)]
mod tests {
    use super::*;

    const NEAR: f32 = 0.8;
    const FAR: f32 = 4.0;

    fn constant(z: f32) -> DepthImage {
        let mut d = DepthImage::new(640, 480);
        d.data.fill(z);
        // A hole that must stay a hole.
        d.data[1000] = 0.0;
        d
    }

    /// Mean and standard deviation of `values`, in f64.
    fn stats(values: impl Iterator<Item = f64>) -> (f64, f64) {
        let (mut n, mut sum, mut sq) = (0.0, 0.0, 0.0);
        for v in values {
            n += 1.0;
            sum += v;
            sq += v * v;
        }
        let mean = sum / n;
        (mean, (sq / n - mean * mean).sqrt())
    }

    fn normalised(z: f32) -> f64 {
        let (z, n, f) = (z as f64, NEAR as f64, FAR as f64);
        f * (z - n) / ((f - n) * z)
    }

    #[test]
    fn zbuffer_noise_has_the_asked_sigma_in_normalised_depth() {
        let mut d = constant(2.0);
        let model = NoiseModel::ZBuffer { sigma: 0.002 };
        model.apply(&mut d, NEAR, FAR, 7, 1);
        assert_eq!(d.data[1000], 0.0);
        let base = normalised(2.0);
        let (mean, std) = stats(
            d.data
                .iter()
                .filter(|&&z| z > 0.0)
                .map(|&z| normalised(z) - base),
        );
        assert!(mean.abs() < 0.02 * 0.002, "mean {mean}");
        assert!((std / 0.002 - 1.0).abs() < 0.03, "std {std}");
    }

    #[test]
    fn zbuffer_noise_drops_depths_pushed_past_the_clipping_planes() {
        let mut d = constant(FAR * 0.9999);
        NoiseModel::ZBuffer { sigma: 0.002 }.apply(&mut d, NEAR, FAR, 1, 1);
        let dropped = d.data.iter().filter(|&&z| z == 0.0).count();
        // About half of the pixels land beyond the far plane.
        assert!(
            (dropped as f64 / d.data.len() as f64 - 0.5).abs() < 0.05,
            "{dropped}"
        );
        assert!(d.data.iter().all(|&z| z == 0.0 || (NEAR..FAR).contains(&z)));
    }

    #[test]
    fn kinect_noise_matches_khoshelham() {
        let z = 3.0;
        let mut d = constant(z);
        NoiseModel::Kinect.apply(&mut d, NEAR, FAR, 42, 3);
        assert_eq!(d.data[1000], 0.0);
        let sigma = 1.425e-3 * 9.0;
        let (mean, std) = stats(
            d.data
                .iter()
                .filter(|&&v| v > 0.0)
                .map(|&v| v as f64 - z as f64),
        );
        assert!(mean.abs() < 0.02 * sigma, "mean {mean}");
        assert!((std / sigma - 1.0).abs() < 0.03, "std {std}");
    }

    #[test]
    fn noise_is_reproducible_and_seeded() {
        let run = |seed, iteration| {
            let mut d = constant(1.5);
            NoiseModel::Kinect.apply(&mut d, NEAR, FAR, seed, iteration);
            d
        };
        let a = run(1, 1);
        let single = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| run(1, 1));
        assert_eq!(a, single);
        assert_ne!(a, run(2, 1));
        assert_ne!(a, run(1, 2));
        // Rows must not repeat each other's noise.
        assert_ne!(a.data[640..1280], a.data[1280..1920]);
    }

    #[test]
    fn none_leaves_the_image_alone() {
        let mut d = constant(2.0);
        NoiseModel::None.apply(&mut d, NEAR, FAR, 1, 1);
        assert_eq!(d, constant(2.0));
    }

    #[test]
    fn parses_and_prints_models() {
        for s in ["none", "kinect", "zbuffer:0.002", "zbuffer:0"] {
            assert_eq!(s.parse::<NoiseModel>().unwrap().to_string(), s);
        }
        assert_eq!(
            "zbuffer:0.002".parse::<NoiseModel>().unwrap(),
            NoiseModel::ZBuffer { sigma: 0.002 }
        );
        for bad in [
            "gauss",
            "zbuffer",
            "zbuffer:",
            "zbuffer:-0.1",
            "zbuffer:x",
            "zbuffer:inf",
        ] {
            let e = bad.parse::<NoiseModel>().unwrap_err().to_string();
            assert!(e.contains("noise"), "{e}");
        }
        let e = "gauss".parse::<NoiseModel>().unwrap_err().to_string();
        assert!(e.contains("unknown noise model"), "{e}");
    }
}
