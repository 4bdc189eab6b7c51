//! Novel surface is meshed from an edge-preserving smoothing of D, not
//! from D itself (beyond the thesis, which meshes the raw pixels).
//!
//! Sensor noise is as large as the geometric error that settled surface may
//! be simplified to (σ of the thesis's noise is 0.2·τ(z)), so noisy grid
//! triangles barely simplify and M stays several times larger than the
//! surface needs. Averaging each pixel with its neighbours on the same
//! surface before meshing removes most of that noise at no cost in
//! geometry: the filter works on inverse depth, which is affine in the
//! pixel coordinates for any plane, so a symmetric window reproduces a
//! plane exactly, and a neighbour further than the novelty threshold τ(z)
//! from the pixel (which the classification calls a boundary) never counts.
//! Only meshing sees the smoothed image: E, the classification and the
//! removal evidence judge the measurement as it came.

use crate::error::Result;
use crate::image::DepthImage;
use crate::mabdi::classify::{PixelClass, Threshold};
use crate::track::filter::{Bilateral, BilateralParams};
use rayon::prelude::*;
use std::ops::Range;

/// How novel surface is smoothed before it is meshed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Smoothing {
    /// Half width of the square window in pixels (the spatial weight's σ
    /// is the same number of pixels).
    pub radius: u32,
}

impl Smoothing {
    /// The filter's parameters for the novelty threshold `novelty` (which
    /// [`Bilateral::new`] checks).
    pub fn filter(&self, novelty: Threshold) -> BilateralParams {
        BilateralParams {
            radius: self.radius,
            sigma_space: self.radius as f32,
            sigma_depth: SIGMA_OF_THRESHOLD * domain_threshold(novelty),
            cutoff: CUTOFF,
            symmetric: Some(MAX_SHIFT * domain_threshold(novelty)),
        }
    }
}

/// Neighbours are weighted with a depth σ of half the novelty threshold and
/// cut off at 2σ, τ(z) itself. σ must be well above the noise to average
/// it (at τ/3, 1.7σ of the thesis's noise, a pixel's own noise kept most
/// of its weight and a 5×5 window took off only a third of the error).
const SIGMA_OF_THRESHOLD: f32 = 0.5;
/// The cut-off, in σ of the depth weight.
const CUTOFF: f32 = 2.0;
/// No pixel moves further than this fraction of the novelty threshold, the
/// depth beyond a triangle that removal needs to see: a pair of neighbours
/// whose mean is further than this from the pixel is left out. On a plane
/// the pairs through a pixel are straight and a crease (a floor meeting a
/// wall) bends them; noise of the thesis's σ = 0.2·τ(z) bends them by
/// 0.25·τ(z) RMS. Measured on the noisy bunnies and the noise-free table:
/// with no limit, the table lost a triangle to removal (its surface rounded
/// off at a table leg's foot); at 0.25·τ(z) the bunnies' M was 1.8× as
/// large and 88 % of it within 5 mm (a pixel whose own noise is large loses
/// all its pairs); at 0.5·τ(z) M was 211,000 triangles, 96 % within 5 mm,
/// and the noise-free table keeps 99.92 % of its M within 5 mm.
const MAX_SHIFT: f32 = 0.5;

/// Smooths depth images for meshing; keeps its filter and buffers across frames.
#[derive(Debug, Default)]
pub struct Smoother {
    /// The filter for the settings it was made for.
    filter: Option<(Smoothing, Threshold, Bilateral)>,
    /// Per row, its runs of pixels to smooth (gaps of a few pixels bridged).
    runs: Vec<Vec<Range<usize>>>,
    /// The image in the filter's domain (inverse depth for normalised
    /// thresholds), where the spans' windows reach.
    domain: DepthImage,
    /// The filter's output, back in metres.
    out: DepthImage,
}

impl Smoother {
    /// `depth` smoothed as [`Smoothing`] says, with the range weight set by
    /// the novelty threshold `novelty`, at the novel pixels (as `classes`
    /// says) that a triangle of novel pixels can use: the rest of the
    /// image, novel pixels scattered alone included, is left as it was and
    /// must not be read. Pixels without depth stay without.
    pub fn apply(
        &mut self,
        depth: &DepthImage,
        classes: &[PixelClass],
        smoothing: Smoothing,
        novelty: Threshold,
    ) -> Result<&DepthImage> {
        let filter = match &self.filter {
            Some((s, t, f)) if *s == smoothing && *t == novelty => f,
            _ => {
                &self
                    .filter
                    .insert((
                        smoothing,
                        novelty,
                        Bilateral::new(smoothing.filter(novelty))?,
                    ))
                    .2
            }
        };
        let w = depth.width as usize;
        let h = classes.len() / w.max(1);
        self.runs.resize_with(h, Vec::new);
        self.runs.par_iter_mut().enumerate().for_each(|(y, runs)| {
            let row = |y: usize| &classes[y * w..(y + 1) * w];
            let above = y.checked_sub(1).map(row);
            let below = (y + 1 < h).then(|| row(y + 1));
            meshed_runs([above, Some(row(y)), below], runs)
        });
        let runs = &self.runs;
        let spans = |y: usize| runs[y].iter().cloned();
        match novelty {
            // A normalised threshold is a constant step of inverse depth.
            Threshold::Normalised { .. } => {
                if self.domain.width != depth.width || self.domain.height != depth.height {
                    self.domain.reset(depth.width, depth.height);
                }
                let r = smoothing.radius as usize;
                self.domain
                    .data
                    .par_chunks_mut(w)
                    .zip(depth.data.par_chunks(w))
                    .enumerate()
                    .for_each(|(y, (inverse, metres))| {
                        // Every column the windows of nearby rows' runs reach.
                        let (a, b) = runs[y.saturating_sub(r)..(y + r + 1).min(h)]
                            .iter()
                            .filter_map(|row| Some(row.first()?.start..row.last()?.end))
                            .fold((w, 0), |(a, b), s| (a.min(s.start), b.max(s.end)));
                        let (a, b) = (a.saturating_sub(r), (b + r).min(w));
                        for x in a..b {
                            let z = metres[x];
                            inverse[x] = if z > 0.0 { 1.0 / z } else { 0.0 };
                        }
                    });
                filter.apply_spans(&self.domain, &mut self.out, spans);
                self.out
                    .data
                    .par_chunks_mut(w)
                    .zip(runs.par_iter())
                    .for_each(|(row, runs)| {
                        for run in runs {
                            for u in &mut row[run.clone()] {
                                if *u > 0.0 {
                                    *u = 1.0 / *u;
                                }
                            }
                        }
                    });
            }
            Threshold::Metres(_) => filter.apply_spans(depth, &mut self.out, spans),
        }
        Ok(&self.out)
    }
}

/// Runs of novel pixels closer than this are filtered as one: the filter
/// runs fastest along long rows.
const BRIDGED_GAP: usize = 8;

/// The runs of the pixels of one row (`rows[1]`, between the rows above
/// and below it, if any) that a triangle of novel pixels may use, into
/// `runs`: novel pixels in a 2×2 block with at least three novel pixels,
/// which every triangle of the mesher (a half pixel, or a larger one
/// covering only novel pixels) lies in. Novel pixels scattered by noise
/// are meshed by no triangle, so they are not smoothed.
fn meshed_runs(rows: [Option<&[PixelClass]>; 3], runs: &mut Vec<Range<usize>>) {
    runs.clear();
    let Some(row) = rows[1] else { return };
    let novel = |r: &[PixelClass], x: usize| usize::from(r[x] == PixelClass::Novel);
    // Whether the block of `upper` and `lower` from column `x` has three.
    let block = |upper: &[PixelClass], lower: &[PixelClass], x: usize| {
        x + 1 < row.len()
            && novel(upper, x) + novel(upper, x + 1) + novel(lower, x) + novel(lower, x + 1) >= 3
    };
    // Eight classes at a time: most of a frame is not novel.
    for (i, eight) in row.chunks(8).enumerate() {
        if !eight.contains(&PixelClass::Novel) {
            continue;
        }
        for (j, c) in eight.iter().enumerate() {
            let x = 8 * i + j;
            if *c != PixelClass::Novel {
                continue;
            }
            let meshed = [(rows[0], Some(row)), (Some(row), rows[2])]
                .into_iter()
                .filter_map(|(upper, lower)| Some((upper?, lower?)))
                .any(|(upper, lower)| {
                    (x > 0 && block(upper, lower, x - 1)) || block(upper, lower, x)
                });
            if !meshed {
                continue;
            }
            match runs.last_mut() {
                Some(run) if x - run.end <= BRIDGED_GAP => run.end = x + 1,
                _ => runs.push(x..x + 1),
            }
        }
    }
}

/// The novelty threshold in the filter's domain: inverse metres for a
/// normalised threshold (`value·(1/near − 1/far)`), metres for a fixed one.
fn domain_threshold(novelty: Threshold) -> f32 {
    match novelty {
        Threshold::Normalised { value, near, far } => value * (1.0 / near - 1.0 / far),
        Threshold::Metres(m) => m,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Intrinsics;

    /// Depth of the plane `n·p = d` (camera frame) seen through `k`.
    fn plane_image(k: &Intrinsics, n: [f32; 3], d: f32) -> DepthImage {
        let mut img = DepthImage::new(k.width, k.height);
        for y in 0..k.height {
            for x in 0..k.width {
                let ray = k.back_project(x as f32, y as f32, 1.0);
                img.data[(y * k.width + x) as usize] =
                    d / (n[0] * ray.x + n[1] * ray.y + n[2] * ray.z);
            }
        }
        img
    }

    /// Every pixel novel.
    fn novel(depth: &DepthImage) -> Vec<PixelClass> {
        vec![PixelClass::Novel; depth.data.len()]
    }

    #[test]
    fn planes_are_kept_and_never_mixed_across_a_step() {
        let k = Intrinsics::from_vertical_fov(160, 120, 60.0);
        let novelty = Threshold::thesis(0.8, 4.0);
        let mut depth = plane_image(&k, [0.0, 0.6, 0.8], 1.6);
        // A box face 30 cm or more in front of the slanted plane.
        let face = plane_image(&k, [0.3, 0.0, 0.95], 1.0);
        let on_face = |x: usize| (70..100).contains(&x);
        for y in 0..120 {
            for x in (0..160).filter(|&x| on_face(x)) {
                depth.data[y * 160 + x] = face.data[y * 160 + x];
            }
        }
        depth.data[5 * 160 + 5] = 0.0;
        let mut smoother = Smoother::default();
        let out = smoother
            .apply(&depth, &novel(&depth), Smoothing { radius: 2 }, novelty)
            .unwrap();
        // The windows cut by the image border, the step or the missing
        // pixel are kept symmetric, so every pixel is reproduced.
        for (i, (&a, &b)) in depth.data.iter().zip(&out.data).enumerate() {
            let (x, y) = (i % 160, i / 160);
            assert!(
                (a - b).abs() <= 1e-5 * a,
                "pixel ({x}, {y}): {a} smoothed to {b}"
            );
        }
    }

    /// RMS error of `img` against `truth`.
    fn rms(img: &DepthImage, truth: &DepthImage) -> f32 {
        let sum: f32 = img
            .data
            .iter()
            .zip(&truth.data)
            .map(|(a, b)| (a - b) * (a - b))
            .sum();
        (sum / img.data.len() as f32).sqrt()
    }

    /// `truth` with uniform noise of σ = 0.2·τ(z), the thesis's.
    fn noisy(truth: &DepthImage, novelty: Threshold) -> DepthImage {
        use rand::{rngs::SmallRng, Rng, SeedableRng};
        let mut rng = SmallRng::seed_from_u64(7);
        let mut noisy = truth.clone();
        for z in &mut noisy.data {
            *z += 0.2 * novelty.at(*z) * (rng.gen::<f32>() - 0.5) * 12f32.sqrt();
        }
        noisy
    }

    #[test]
    fn noise_on_a_plane_is_reduced() {
        let k = Intrinsics::from_vertical_fov(160, 120, 60.0);
        let novelty = Threshold::thesis(0.8, 4.0);
        let truth = plane_image(&k, [0.2, 0.0, 1.0], 2.0);
        let noisy = noisy(&truth, novelty);
        let before = rms(&noisy, &truth);
        let after = rms(
            Smoother::default()
                .apply(&noisy, &novel(&noisy), Smoothing { radius: 2 }, novelty)
                .unwrap(),
            &truth,
        );
        assert!(after < before / 3.0, "RMS error {before} -> {after}");
    }

    #[test]
    fn a_threshold_in_metres_smooths_depth_in_metres_at_the_novel_pixels() {
        let k = Intrinsics::from_vertical_fov(160, 120, 60.0);
        let novelty = Threshold::Metres(0.05);
        let truth = plane_image(&k, [0.0, 0.0, 1.0], 1.5);
        let noisy = noisy(&truth, novelty);
        let mut classes = novel(&noisy);
        classes[..160 * 60].fill(PixelClass::Known);
        let mut smoother = Smoother::default();
        let out = smoother
            .apply(&noisy, &classes, Smoothing { radius: 2 }, novelty)
            .unwrap();
        let lower = |img: &DepthImage| DepthImage {
            width: 160,
            height: 60,
            data: img.data[160 * 60..].to_vec(),
        };
        let (before, after) = (
            rms(&lower(&noisy), &lower(&truth)),
            rms(&lower(out), &lower(&truth)),
        );
        assert!(after < before / 3.0, "RMS error {before} -> {after}");
    }
}
