//! Edge-preserving smoothing of depth before tracking (KinectFusion's
//! bilateral filter): neighbours count by pixel distance and by depth
//! difference, so noise on a surface is averaged while depth edges stay sharp.

use crate::error::{Error, Result};
use crate::image::DepthImage;
use rayon::prelude::*;

/// Parameters of the bilateral filter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BilateralParams {
    /// Half width of the square window in pixels.
    pub radius: u32,
    /// Standard deviation of the spatial weight in pixels.
    pub sigma_space: f32,
    /// Standard deviation of the depth weight in metres.
    pub sigma_depth: f32,
    /// Depth differences beyond this many standard deviations get no weight.
    pub cutoff: f32,
    /// `Some(max_shift)`: weigh each neighbour and its mirror image
    /// through the pixel alike (the smaller of their weights), so that a
    /// window cut by a depth edge, a missing pixel or the image border
    /// stays symmetric (a one-sided window averages a slanted surface
    /// towards its inside, a symmetric one keeps anything affine in the
    /// pixel coordinates exactly: inverse depth of a plane, for one), and
    /// leave out a pair whose mean is more than `max_shift` from the pixel
    /// (it bends over a crease), so that no pixel moves further than that.
    pub symmetric: Option<f32>,
}

impl Default for BilateralParams {
    /// A 3×3 window (KinectFusion's GPU filter is 7×7; on 7-Scenes
    /// tracking is as accurate with 3×3 at a fifth of the cost) and
    /// KinectFusion's 3 cm depth σ.
    fn default() -> Self {
        BilateralParams {
            radius: 1,
            sigma_space: 1.0,
            sigma_depth: 0.03,
            cutoff: 3.0,
            symmetric: None,
        }
    }
}

impl BilateralParams {
    /// Rejects windows and deviations that make no filter.
    pub fn validate(&self) -> Result<()> {
        if self.radius == 0 || self.radius > 16 {
            return Err(Error::parameter(
                "bilateral radius",
                format!("must be 1..=16 pixels, got {}", self.radius),
            ));
        }
        for (name, v) in [
            ("sigma_space", self.sigma_space),
            ("sigma_depth", self.sigma_depth),
            ("cutoff", self.cutoff),
            ("max_shift", self.symmetric.unwrap_or(1.0)),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::parameter(
                    format!("bilateral {name}"),
                    format!("must be positive, got {v}"),
                ));
            }
        }
        Ok(())
    }
}

/// A bilateral filter with its spatial weights, reusable across frames.
#[derive(Clone, Debug)]
pub struct Bilateral {
    radius: usize,
    /// Spatial weight per window offset, row by row.
    spatial: Vec<f32>,
    /// `log2(e) / (2σ²)`: the range weight is `2^(-d²·this)`.
    range_exponent: f32,
    /// Squared depth difference of [`BilateralParams::cutoff`] standard deviations.
    max_difference2: f32,
    /// [`BilateralParams::symmetric`]'s largest shift, if symmetric.
    symmetric: Option<f32>,
}

impl Bilateral {
    /// Tabulates the spatial weights of `params`.
    pub fn new(params: BilateralParams) -> Result<Self> {
        params.validate()?;
        let r = params.radius as i32;
        let spatial = (-r..=r)
            .flat_map(|dy| (-r..=r).map(move |dx| (dx * dx + dy * dy) as f32))
            .map(|d2| (-d2 / (2.0 * params.sigma_space * params.sigma_space)).exp())
            .collect();
        let s2 = params.sigma_depth * params.sigma_depth;
        Ok(Bilateral {
            radius: params.radius as usize,
            spatial,
            range_exponent: std::f32::consts::LOG2_E / (2.0 * s2),
            max_difference2: params.cutoff * params.cutoff * s2,
            symmetric: params.symmetric,
        })
    }

    /// The weight of a neighbour at depth `depth` for a pixel at `centre`,
    /// without its spatial factor; missing neighbours (depth 0) count for
    /// nothing. Branch-free, so that loops over a row vectorise.
    #[inline(always)]
    fn range_weight(&self, centre: f32, depth: f32) -> f32 {
        let d2 = (depth - centre) * (depth - centre);
        let w = exp2_negative(d2 * self.range_exponent);
        if d2 <= self.max_difference2 && depth > 0.0 {
            w
        } else {
            0.0
        }
    }

    /// The weight of each of a mirror pair `a`, `b` through a pixel at
    /// `centre` with spatial weight `ws`: the smaller of their range
    /// weights, or none where their mean is more than `max_shift` from
    /// `centre`. Branch-free, as [`Bilateral::range_weight`].
    #[inline(always)]
    fn pair_weight(&self, ws: f32, centre: f32, a: f32, b: f32, max_shift: f32) -> f32 {
        let g = ws
            * self
                .range_weight(centre, a)
                .min(self.range_weight(centre, b));
        if (a + b - 2.0 * centre).abs() <= 2.0 * max_shift {
            g
        } else {
            0.0
        }
    }

    /// Filters `input` into `out` (resized as needed). Pixels without depth
    /// stay without depth and never contribute.
    pub fn apply(&self, input: &DepthImage, out: &mut DepthImage) {
        let w = input.width as usize;
        self.apply_spans(input, out, |_| std::iter::once(0..w));
    }

    /// Filters, of each row `y` of `input`, only the runs of columns
    /// `spans(y)` (clipped to the image) into `out` (resized, and zeroed,
    /// when its size differs); every other pixel of `out` keeps its value.
    /// For a caller that needs a few pixels of a frame.
    pub fn apply_spans<S>(
        &self,
        input: &DepthImage,
        out: &mut DepthImage,
        spans: impl Fn(usize) -> S + Sync,
    ) where
        S: IntoIterator<Item = std::ops::Range<usize>>,
    {
        let (w, h) = (input.width as usize, input.height as usize);
        if (out.width, out.height) != (input.width, input.height) {
            out.reset(input.width, input.height);
        }
        let r = self.radius;
        let side = 2 * r + 1;
        let data = &input.data;
        out.data.par_chunks_mut(w).enumerate().for_each_init(
            || (vec![0.0f32; w], vec![0.0f32; w]),
            |(sum, weight), (y, row)| {
                for span in spans(y) {
                    let (a, b) = (span.start.min(w), span.end.min(w));
                    if a >= b {
                        continue;
                    }
                    if y < r || y + r >= h || w <= 2 * r {
                        for (x, o) in row.iter_mut().enumerate().take(b).skip(a) {
                            *o = self.at_border(data, w, h, x, y);
                        }
                        continue;
                    }
                    // The interior of the span, one window offset at a time:
                    // each pass runs along contiguous rows and vectorises.
                    let (ia, ib) = (a.max(r), b.min(w - r));
                    if ia < ib {
                        let n = ib - ia;
                        let centre = &data[y * w + ia..y * w + ib];
                        let (sum, weight) = (&mut sum[..n], &mut weight[..n]);
                        sum.fill(0.0);
                        weight.fill(0.0);
                        let neighbours = |k: usize| {
                            let start = (y + k / side - r) * w + ia + k % side - r;
                            &data[start..start + n]
                        };
                        if let Some(max_shift) = self.symmetric {
                            // Offsets in pairs through the centre, then the centre.
                            let half = self.spatial.len() / 2;
                            for (k, &ws) in self.spatial[..half].iter().enumerate() {
                                let (near, far) = (neighbours(k), neighbours(2 * half - k));
                                for ((((s, wt), &c), &a), &b) in sum
                                    .iter_mut()
                                    .zip(weight.iter_mut())
                                    .zip(centre)
                                    .zip(near)
                                    .zip(far)
                                {
                                    let g = self.pair_weight(ws, c, a, b, max_shift);
                                    *s += g * (a + b);
                                    *wt += 2.0 * g;
                                }
                            }
                            for ((s, wt), &c) in sum.iter_mut().zip(weight.iter_mut()).zip(centre) {
                                *s += c;
                                *wt += 1.0;
                            }
                        } else {
                            for (k, &ws) in self.spatial.iter().enumerate() {
                                for (((s, wt), &c), &d) in sum
                                    .iter_mut()
                                    .zip(weight.iter_mut())
                                    .zip(centre)
                                    .zip(neighbours(k))
                                {
                                    let g = ws * self.range_weight(c, d);
                                    *s += g * d;
                                    *wt += g;
                                }
                            }
                        }
                        for (((o, &c), &s), &wt) in
                            row[ia..ib].iter_mut().zip(centre).zip(&*sum).zip(&*weight)
                        {
                            *o = if c > 0.0 { s / wt } else { 0.0 };
                        }
                    }
                    for x in (a..b).filter(|&x| x < r || x >= w - r) {
                        row[x] = self.at_border(data, w, h, x, y);
                    }
                }
            },
        );
    }

    /// The filtered depth of pixel `(x, y)` whose window is cut by the
    /// image border.
    fn at_border(&self, data: &[f32], w: usize, h: usize, x: usize, y: usize) -> f32 {
        let r = self.radius;
        let side = 2 * r + 1;
        let centre = data[y * w + x];
        if centre <= 0.0 {
            return 0.0;
        }
        let (mut sum, mut weight) = (0.0f32, 0.0f32);
        for yy in y.saturating_sub(r)..=(y + r).min(h - 1) {
            for xx in x.saturating_sub(r)..=(x + r).min(w - 1) {
                let d = data[yy * w + xx];
                let ws = self.spatial[(yy + r - y) * side + (xx + r - x)];
                let g = match self.symmetric {
                    Some(max_shift) => {
                        // The mirror image through the pixel, if in the image.
                        let (my, mx) = ((2 * y).wrapping_sub(yy), (2 * x).wrapping_sub(xx));
                        if my >= h || mx >= w {
                            continue;
                        }
                        self.pair_weight(ws, centre, d, data[my * w + mx], max_shift)
                    }
                    None => ws * self.range_weight(centre, d),
                };
                sum += g * d;
                weight += g;
            }
        }
        sum / weight
    }
}

/// `2^-x` for `x ≥ 0` to a relative error below 1e-4, branch-free (so it
/// vectorises; `f32::exp2` is a library call): the integer part of the
/// exponent goes into the float's exponent bits, a polynomial covers the
/// fraction. `x` is clamped at 126 (2^-126 ≈ 1e-38).
#[inline(always)]
fn exp2_negative(x: f32) -> f32 {
    let x = x.min(126.0);
    // ROUND − x rounds −x to an integer n, left in the low mantissa bits.
    const ROUND: f32 = 12_582_912.0; // 1.5 · 2²³
    let shifted = ROUND - x;
    let n = shifted.to_bits().wrapping_sub(ROUND.to_bits()) as i32;
    // 2^-x = 2^n · 2^f with f = −x − n ∈ [−0.5, 0.5]; 2^f by its Taylor
    // polynomial of degree 4.
    let f = -x - (shifted - ROUND);
    let p = 1.0
        + f * (std::f32::consts::LN_2 + f * (0.240_226_5 + f * (0.055_504_1 + f * 0.009_618_1)));
    f32::from_bits((p.to_bits() as i32).wrapping_add(n << 23) as u32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smooths_noise_and_keeps_edges() {
        let (w, h) = (40u32, 20u32);
        let mut depth = DepthImage::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let base = if x < 20 { 1.0 } else { 2.0 };
                // ±5 mm checkerboard noise.
                let noise = if (x + y) % 2 == 0 { 0.005 } else { -0.005 };
                depth.data[(y * w + x) as usize] = base + noise;
            }
        }
        depth.data[0] = 0.0;
        let filter = Bilateral::new(BilateralParams::default()).unwrap();
        let mut out = DepthImage::default();
        filter.apply(&depth, &mut out);
        assert_eq!(out.data[0], 0.0);
        // Any span of a row is filtered as the whole row is.
        let mut part = DepthImage::default();
        let spans = |y: usize| [y % 7..y % 7 + 5, y % 7 + 9..y % 7 + 30];
        filter.apply_spans(&depth, &mut part, spans);
        for (i, (&p, &o)) in part.data.iter().zip(&out.data).enumerate() {
            let (x, y) = (i % w as usize, i / w as usize);
            let want = if spans(y).iter().any(|s| s.contains(&x)) {
                o
            } else {
                0.0
            };
            assert_eq!(p.to_bits(), want.to_bits(), "({x},{y})");
        }
        for y in 2..h - 2 {
            for x in 2..w - 2 {
                let want = if x < 20 { 1.0 } else { 2.0 };
                let got = out.data[(y * w + x) as usize];
                assert!((got - want).abs() < 0.0015, "({x},{y}): {got}");
            }
        }
    }

    #[test]
    fn the_fast_power_of_two_is_accurate() {
        for i in 0..=2000 {
            let x = i as f32 * 0.01;
            let (got, want) = (exp2_negative(x), (-x).exp2());
            assert!((got - want).abs() <= 1e-4 * want, "2^-{x}: {got} vs {want}");
        }
        let tiny = exp2_negative(1000.0);
        assert!((0.0..1e-37).contains(&tiny), "{tiny}");
    }

    #[test]
    fn rejects_bad_parameters() {
        let bad = BilateralParams {
            sigma_depth: 0.0,
            ..BilateralParams::default()
        };
        assert!(Bilateral::new(bad)
            .unwrap_err()
            .to_string()
            .contains("sigma_depth"));
    }
}
