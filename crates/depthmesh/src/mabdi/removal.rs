//! Object removal, beyond the thesis: free-space evidence against mesh triangles.
//!
//! The thesis classifies with `|D − E|` and so can only add (§3.2.1 notes that
//! the sign of `D − E` would reveal removals). depthmesh uses that sign, per
//! triangle rather than per pixel so that every layer of a removed object is
//! found, not only the front one that E shows:
//!
//! * A triangle is **contradicted** in a frame when its centroid projects to a
//!   pixel whose measured depth — the minimum over its 3×3 neighbourhood, all
//!   nine valid — lies more than `threshold(z)` *beyond* the centroid: the
//!   sensor saw through where the triangle should be. The neighbourhood
//!   minimum keeps silhouettes and thin parts from being contradicted by the
//!   background next to them.
//! * A triangle is **confirmed** when the measured depth at its pixel is
//!   within `threshold(z)` of it; this resets its count. Occluded triangles
//!   (measurement in front of them) are left alone.
//! * A triangle contradicted in `frames_to_remove` frames without being
//!   confirmed in between is removed.
//!
//! The default threshold is 0.005 in normalised depth (≈ 0.005·z² m, half the
//! novelty threshold); with the thesis's noise (σ ≈ 0.002·z² m) a false
//! contradiction needs a 2.5σ error at all nine pixels in two frames, so noise
//! does not erode unchanged surfaces. What noise does remove is noise:
//! triangles made from a noisy spike that later frames see through.
//!
//! Pixels with no return give no free-space evidence here; where a surface
//! is seen through in part, its missing returns count too
//! ([`absence`](mod@super::absence)), so an object removed in front of open
//! space leaves M as well.

use crate::image::DepthImage;
use crate::mabdi::absence::{centroid_pixel, Absence, AbsenceMap, MissingReturns};
use crate::mabdi::classify::Threshold;
use rayon::prelude::*;

/// Free-space evidence counters, one per triangle of the global mesh.
#[derive(Debug, Default)]
pub struct Carver {
    /// Contradictions without a confirmation in between, per triangle.
    pub votes: Vec<u8>,
    /// Per pixel: the depth and its 3×3 neighbourhood minimum (0 = not all
    /// nine valid, [`NONE_OF_NINE`] = none valid), side by side so a lookup
    /// touches one cache line.
    depths: Vec<[f32; 2]>,
    /// Scratch: per band of rows, one row of the minimum and maximum of
    /// each pixel and its neighbours above and below.
    column_extremes: Vec<[f32; 2]>,
    /// The regions of missing returns (see [`absence`](mod@super::absence)).
    absence: AbsenceMap,
}

/// The neighbourhood "minimum" of a pixel none of whose nine pixels has a
/// measurement.
pub(crate) const NONE_OF_NINE: f32 = -1.0;

/// Rows of the image per parallel task of [`Carver::prepare`].
const BAND_ROWS: usize = 16;

/// The evidence one depth image gives about triangles, ready to be asked
/// triangle by triangle (from the render of E, which projects them anyway).
#[derive(Clone, Copy, Debug)]
pub struct Evidence<'a> {
    width: usize,
    height: usize,
    depths: &'a [[f32; 2]],
    threshold: Threshold,
    frames_to_remove: u8,
}

impl Carver {
    /// Prepares the evidence of `depth` for a mesh of `triangles` triangles;
    /// returns the per-triangle counters and the evidence to update them with.
    pub fn prepare<'a>(
        &'a mut self,
        depth: &'a DepthImage,
        triangles: usize,
        threshold: Threshold,
        frames_to_remove: u8,
    ) -> (&'a mut [u8], Evidence<'a>) {
        self.votes.resize(triangles, 0);
        let (w, h) = (depth.width as usize, depth.height as usize);
        // Every pixel is written below: no clearing.
        self.depths.resize(w * h, [0.0; 2]);
        if w >= 3 && h >= 3 {
            // The 3×3 minimum and maximum are separable: down the three
            // rows of each column, then along the row. An invalid depth
            // counts as 0, so a minimum is positive exactly when all nine
            // are valid, and a maximum is 0 exactly when none is. One pass
            // per band of rows, each with a row of column extremes of its
            // own: no pass over the whole image in between, nothing cleared.
            let valid = |d: f32| if d > 0.0 { d } else { 0.0 };
            let data = &depth.data;
            self.column_extremes
                .resize(h.div_ceil(BAND_ROWS) * w, [0.0; 2]);
            self.depths
                .par_chunks_mut(BAND_ROWS * w)
                .zip(self.column_extremes.par_chunks_mut(w))
                .enumerate()
                .for_each(|(band, (rows, extremes))| {
                    for (i, out) in rows.chunks_mut(w).enumerate() {
                        let r = band * BAND_ROWS + i;
                        for (o, &d) in out.iter_mut().zip(&data[r * w..(r + 1) * w]) {
                            *o = [d, 0.0];
                        }
                        if r == 0 || r == h - 1 {
                            continue;
                        }
                        let [above, here, below] = [r - 1, r, r + 1].map(|r| &data[r * w..][..w]);
                        for (e, ((&a, &b), &c)) in
                            extremes.iter_mut().zip(above.iter().zip(here).zip(below))
                        {
                            let [a, b, c] = [a, b, c].map(valid);
                            *e = [a.min(b).min(c), a.max(b).max(c)];
                        }
                        for (o, e) in out[1..w - 1].iter_mut().zip(extremes.windows(3)) {
                            let min = e[0][0].min(e[1][0]).min(e[2][0]);
                            let max = e[0][1].max(e[1][1]).max(e[2][1]);
                            o[1] = if max > 0.0 { min } else { NONE_OF_NINE };
                        }
                    }
                });
        } else {
            self.depths.fill([0.0; 2]);
        }
        let evidence = Evidence {
            width: w,
            height: h,
            depths: &self.depths,
            threshold,
            frames_to_remove,
        };
        (&mut self.votes, evidence)
    }

    /// After E is rendered: the per-triangle counters and, when some surface
    /// of E is vanishing in front of open space, the evidence of its missing
    /// returns (see [`absence`](mod@super::absence)). Call after [`Carver::prepare`]
    /// for the same frame.
    pub fn absence(
        &mut self,
        expected: &DepthImage,
        threshold: Threshold,
        continuity: Threshold,
        params: &MissingReturns,
        frames_to_remove: u8,
    ) -> (&mut [u8], Option<Absence<'_>>) {
        let absence = self.absence.find(
            &self.depths,
            expected,
            threshold,
            continuity,
            params,
            frames_to_remove,
        );
        (&mut self.votes, absence)
    }
}

impl Evidence<'_> {
    /// Updates the counter of one triangle from its projected corners
    /// (pixel `u, v` and inverse depth) and says whether it is to be removed.
    #[inline]
    pub fn judge(&self, vote: &mut u8, s: &[[f32; 3]; 3]) -> bool {
        let Some((pixel, z)) = centroid_pixel(s, self.width, self.height) else {
            return *vote >= self.frames_to_remove;
        };
        let [d, beyond] = self.depths[pixel];
        // Decided without branches (`&`, not `&&`): the outcome follows
        // the image, and a branch on it would wait for every lookup above,
        // where without one the lookups of neighbouring triangles overlap.
        // No evidence without a measurement (NaN is not `<= 0` and counts).
        let measured = (d > 0.0) | d.is_nan();
        let tol = self.threshold.at(z);
        let contradicted = measured & (beyond > 0.0) & (z < beyond - tol);
        let confirmed = measured & !contradicted & ((d - z).abs() <= tol);
        let v = *vote;
        *vote = if contradicted {
            v.saturating_add(1)
        } else if confirmed {
            0
        } else {
            v
        };
        *vote >= self.frames_to_remove
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 5×5 image at 2 m everywhere, with the carver's evidence for it.
    fn judge_at(depth_m: f32, triangle_z: f32, votes: &mut u8) -> bool {
        let depth = DepthImage {
            width: 5,
            height: 5,
            data: vec![depth_m; 25],
        };
        let mut carver = Carver::default();
        let (_, evidence) = carver.prepare(&depth, 1, Threshold::Metres(0.05), 2);
        // A small triangle around pixel (2, 2) at depth `triangle_z`.
        let w = 1.0 / triangle_z;
        evidence.judge(votes, &[[1.8, 1.8, w], [2.2, 1.9, w], [2.0, 2.3, w]])
    }

    #[test]
    fn contradicted_twice_is_removed_confirmed_resets_occluded_is_kept() {
        let mut v = 0;
        assert!(
            !judge_at(2.0, 1.5, &mut v),
            "one contradiction is not enough"
        );
        assert_eq!(v, 1);
        assert!(judge_at(2.0, 1.5, &mut v), "two contradictions remove");
        let mut v = 1;
        judge_at(2.0, 1.98, &mut v);
        assert_eq!(v, 0, "a measurement on the triangle confirms it");
        let mut v = 1;
        judge_at(1.0, 1.5, &mut v);
        assert_eq!(
            v, 1,
            "a triangle behind the measured surface is occluded, not judged"
        );
        let mut v = 1;
        judge_at(0.0, 1.5, &mut v);
        assert_eq!(v, 1, "no measurement, no evidence");
    }

    #[test]
    fn silhouettes_and_borders_give_no_evidence() {
        // Background at 3 m with a foreground pixel at 1 m next to the triangle's pixel.
        let mut data = vec![3.0; 25];
        data[2 * 5 + 3] = 1.0;
        let depth = DepthImage {
            width: 5,
            height: 5,
            data,
        };
        let mut carver = Carver::default();
        let (_, evidence) = carver.prepare(&depth, 1, Threshold::Metres(0.05), 1);
        let w = 1.0 / 1.0;
        let mut v = 0;
        // The triangle at 1 m projects next to the foreground: the 3×3 minimum protects it.
        assert!(!evidence.judge(&mut v, &[[1.8, 1.8, w], [2.2, 1.9, w], [2.0, 2.3, w]]));
        // At the image border there is no full neighbourhood: no evidence either.
        assert!(!evidence.judge(&mut v, &[[0.0, 0.0, 0.5], [0.2, 0.0, 0.5], [0.0, 0.2, 0.5]]));
        // Behind the camera: no evidence.
        assert!(!evidence.judge(
            &mut v,
            &[[2.0, 2.0, -1.0], [2.2, 2.0, -1.0], [2.0, 2.2, -1.0]]
        ));
        assert_eq!(v, 0);
    }

    #[test]
    fn neighbourhood_minimum_needs_all_nine_valid() {
        let (w, h) = (7usize, 5usize);
        let mut depth = DepthImage::new(w as u32, h as u32);
        for (i, d) in depth.data.iter_mut().enumerate() {
            *d = 1.0 + ((i * 37) % 11) as f32 * 0.1;
        }
        depth.data[3 * w + 5] = 0.0;
        depth.data[w + 1] = f32::NAN;
        let mut carver = Carver::default();
        let (_, evidence) = carver.prepare(&depth, 0, Threshold::Metres(0.01), 2);
        for r in 0..h {
            for c in 0..w {
                let [d, beyond] = evidence.depths[r * w + c];
                assert_eq!(d.to_bits(), depth.data[r * w + c].to_bits());
                let border = r == 0 || c == 0 || r == h - 1 || c == w - 1;
                let nine: Vec<f32> = if border {
                    Vec::new()
                } else {
                    (r - 1..=r + 1)
                        .flat_map(|rr| depth.data[rr * w + c - 1..=rr * w + c + 1].to_vec())
                        .collect()
                };
                let want = if border || !nine.iter().all(|&d| d > 0.0) {
                    0.0
                } else {
                    nine.iter().copied().fold(f32::INFINITY, f32::min)
                };
                assert_eq!(beyond, want, "({c},{r})");
            }
        }
    }
}
