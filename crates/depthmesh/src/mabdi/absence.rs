//! Evidence from missing returns: removal in front of open space.
//!
//! Free-space evidence ([`removal`](mod@super::removal)) needs a measurement
//! beyond a triangle. An object taken away in front of open space (nothing
//! within the sensor's range behind it) leaves pixels with no return at all,
//! which alone cannot tell "gone" from "still there but black or shiny":
//! both return nothing. The tie is broken by the rest of the same surface:
//!
//! * Pixels where E shows surface of M within `range` (where a present,
//!   ordinary surface always returns) but D does not confirm it — no return,
//!   or a return beyond it — form regions, 4-connected where E is continuous
//!   (neighbouring E closer than the boundary threshold, as for one surface).
//! * A region is **vanishing** when at least `seeds` of its pixels are seen
//!   through *solidly*: the pixel and its four neighbours each have all nine
//!   pixels around them measured more than `τ_r(z)` beyond E. Part of that
//!   surface is certainly gone; its pixels with no return are taken as gone too.
//! * A triangle whose projected centroid falls on a pixel of a vanishing
//!   region, or within `fringe` pixels of one, with no return at any of the
//!   nine pixels around it, and whose depth is within `range`, gets one
//!   removal vote, as a contradiction does. The fringe takes the slivers an
//!   object's outline leaves in E (a face seen edge-on, mixed depths at its
//!   silhouette), which fall apart from its surface into regions of their
//!   own: with none, 164 triangles of the open-space post (1.6 %) stayed in
//!   M, with 2 pixels 97 (0.9 %).
//!
//! A black object that is present is never seen through (it hides what is
//! behind it), so its region has no seeds and it is kept; neither is surface
//! of M that a black object merely hides. Misplaced silhouettes of noisy M,
//! a pixel or two wide, are not solid enough to seed a region. The cost is
//! one pass over the pixels to find seeds and, only when some exist, a flood
//! fill of their regions and a second pass over the triangles in view.

use crate::image::DepthImage;
use crate::mabdi::classify::Threshold;
use crate::mabdi::removal::NONE_OF_NINE;
use rayon::prelude::*;

/// Parameters of the evidence from missing returns.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MissingReturns {
    /// Depths in metres within which a present surface returns depth
    /// (well inside the sensor's range, so range limits are no evidence).
    pub range: [f32; 2],
    /// Solidly seen-through pixels a region needs before its missing returns count.
    pub seeds: u32,
    /// Pixels with no return around them within this many pixels of a
    /// vanishing region count with it: an object's outline in E (mixed
    /// depths at its silhouette, a face seen edge-on) falls apart from the
    /// rest of its surface into slivers of its own, with no seeds.
    pub fringe: u32,
}

/// Pixel flags of the region search.
const MEMBER: u8 = 1;
/// Seen through: all nine pixels around it measured beyond E.
const THROUGH: u8 = 2;
/// No return at any of the nine pixels around it.
const EMPTY: u8 = 4;

/// Per-pixel scratch of the region search, reused from frame to frame.
#[derive(Debug, Default)]
pub struct AbsenceMap {
    flags: Vec<u8>,
    /// Region of each pixel (0 = none), then whether it is a vanishing one's.
    labels: Vec<u32>,
    /// Seeds per region, indexed by label.
    seeds: Vec<u32>,
    stack: Vec<u32>,
    /// The solid seeds, in image order.
    solid: Vec<usize>,
    /// Per pixel: a vanishing region's pixel with no return around it.
    vanished: Vec<bool>,
}

/// Which pixels lost their surface, ready to be asked triangle by triangle.
#[derive(Clone, Copy, Debug)]
pub struct Absence<'a> {
    width: usize,
    height: usize,
    vanished: &'a [bool],
    range: [f32; 2],
    frames_to_remove: u8,
}

impl AbsenceMap {
    /// Finds the vanishing regions of E (`expected`) given the measured
    /// `depths` (depth and 3×3 minimum, as the carver keeps them); returns
    /// the absence evidence when any pixel vanished.
    pub fn find<'a>(
        &'a mut self,
        depths: &[[f32; 2]],
        expected: &DepthImage,
        threshold: Threshold,
        continuity: Threshold,
        params: &MissingReturns,
        frames_to_remove: u8,
    ) -> Option<Absence<'a>> {
        let (w, h) = (expected.width as usize, expected.height as usize);
        if w < 3 || h < 3 || depths.len() != w * h {
            return None;
        }
        let [lo, hi] = params.range;
        self.flags.resize(w * h, 0);
        let through = self
            .flags
            .par_chunks_mut(w)
            .zip(expected.data.par_chunks(w))
            .zip(depths.par_chunks(w))
            .map(|((flags, e), d)| {
                let mut through = 0;
                for ((f, &e), &[d, beyond]) in flags.iter_mut().zip(e).zip(d) {
                    *f = 0;
                    if !(e >= lo && e <= hi) {
                        continue;
                    }
                    let tol = threshold.at(e);
                    if d <= 0.0 || d.is_nan() || d > e + tol {
                        *f |= MEMBER;
                    }
                    if beyond > 0.0 && e < beyond - tol {
                        *f |= THROUGH;
                        through += 1;
                    }
                    if beyond == NONE_OF_NINE {
                        *f |= EMPTY;
                    }
                }
                through
            })
            .sum::<u32>();
        if through < params.seeds {
            return None;
        }
        // Noise makes pixels seen through here and there in most frames;
        // solid seeds are rarer, and without enough of them no region can
        // be vanishing (counted apart, as regions are only labelled from them).
        let flags = &self.flags;
        self.solid.clear();
        self.solid.par_extend(
            (1..h - 1)
                .into_par_iter()
                .flat_map_iter(|r| (r * w + 1..(r + 1) * w - 1).filter(|&p| solid(flags, w, p))),
        );
        if self.solid.len() < params.seeds as usize {
            return None;
        }
        self.label_regions(&expected.data, w, h, continuity);
        let (labels, seeds, flags) = (&self.labels, &self.seeds, &self.flags);
        self.vanished.resize(w * h, false);
        let in_vanishing = |q: usize| labels[q] != 0 && seeds[labels[q] as usize] >= params.seeds;
        let r = params.fringe as usize;
        let near_vanishing = |p: usize| {
            let (y, x) = (p / w, p % w);
            (y.saturating_sub(r)..(y + r + 1).min(h))
                .any(|y| (x.saturating_sub(r)..(x + r + 1).min(w)).any(|x| in_vanishing(y * w + x)))
        };
        let any = self
            .vanished
            .par_iter_mut()
            .enumerate()
            .map(|(p, v)| {
                *v = flags[p] & EMPTY != 0 && (in_vanishing(p) || near_vanishing(p));
                *v as u32
            })
            .sum::<u32>();
        (any > 0).then_some(Absence {
            width: w,
            height: h,
            vanished: &self.vanished,
            range: params.range,
            frames_to_remove,
        })
    }

    /// Labels the regions that hold a solid seed (flood fill over members
    /// where E is continuous, from the seeds found, in image order) and
    /// counts each one's solid seeds.
    fn label_regions(&mut self, e: &[f32], w: usize, h: usize, continuity: Threshold) {
        self.labels.clear();
        self.labels.resize(w * h, 0);
        self.seeds.clear();
        self.seeds.push(0); // label 0: no region
        let flags = &self.flags;
        let solid = |p: usize| {
            let (r, c) = (p / w, p % w);
            r > 0 && c > 0 && r + 1 < h && c + 1 < w && solid(flags, w, p)
        };
        // A solid seed is a member: measured beyond E.
        for &start in &self.solid {
            if self.labels[start] != 0 {
                continue;
            }
            let label = self.seeds.len() as u32;
            let mut count = 0;
            self.labels[start] = label;
            self.stack.push(start as u32);
            while let Some(p) = self.stack.pop() {
                let p = p as usize;
                count += solid(p) as u32;
                let (r, c) = (p / w, p % w);
                let tol = continuity.at(e[p]);
                let neighbours = [
                    (c > 0).then(|| p - 1),
                    (c + 1 < w).then(|| p + 1),
                    (r > 0).then(|| p - w),
                    (r + 1 < h).then(|| p + w),
                ];
                for q in neighbours.into_iter().flatten() {
                    if flags[q] & MEMBER != 0 && self.labels[q] == 0 && (e[q] - e[p]).abs() <= tol {
                        self.labels[q] = label;
                        self.stack.push(q as u32);
                    }
                }
            }
            self.seeds.push(count);
        }
    }
}

/// Whether pixel `p` (not on the image border) and its four neighbours
/// are all seen through: a solid seed.
#[inline]
fn solid(flags: &[u8], w: usize, p: usize) -> bool {
    flags[p] & THROUGH != 0
        && [p - 1, p + 1, p - w, p + w]
            .iter()
            .all(|&q| flags[q] & THROUGH != 0)
}

impl Absence<'_> {
    /// Gives one triangle (projected corners: pixel `u, v` and inverse
    /// depth) its vote if it lies on a vanished pixel within range; says
    /// whether it is to be removed.
    #[inline]
    pub fn judge(&self, vote: &mut u8, s: &[[f32; 3]; 3]) -> bool {
        if let Some((pixel, z)) = centroid_pixel(s, self.width, self.height) {
            if self.vanished[pixel] && z >= self.range[0] && z <= self.range[1] {
                *vote = vote.saturating_add(1);
            }
        }
        *vote >= self.frames_to_remove
    }
}

/// The pixel and depth of a triangle's projected centroid, if it is in front
/// of the camera and inside the image. Triangles are small, so the mean of
/// the projected corners stands for the projected centroid.
#[inline]
pub(crate) fn centroid_pixel(s: &[[f32; 3]; 3], w: usize, h: usize) -> Option<(usize, f32)> {
    if s[0][2] <= 0.0 || s[1][2] <= 0.0 || s[2][2] <= 0.0 {
        return None; // reaches behind the camera
    }
    let u = (s[0][0] + s[1][0] + s[2][0]) * (1.0 / 3.0) + 0.5;
    let v = (s[0][1] + s[1][1] + s[2][1]) * (1.0 / 3.0) + 0.5;
    if !(u >= 0.0 && v >= 0.0 && u < w as f32 && v < h as f32) {
        return None;
    }
    // In range, so converting through `i32` floors like `as usize` would,
    // for a fraction of the instructions of a saturating float-to-usize.
    let pixel = v as i32 as usize * w + u as i32 as usize;
    Some((pixel, 3.0 / (s[0][2] + s[1][2] + s[2][2])))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mabdi::removal::Carver;

    const W: usize = 40;
    const H: usize = 30;

    /// E: a surface at 2 m over columns 5..35. D: columns `through` of it
    /// show a wall at 3 m behind, the other columns of it return nothing,
    /// and outside it D sees the wall.
    fn vanished(through: std::ops::Range<usize>) -> Vec<bool> {
        vanished_with_sliver(through, 0..0)
    }

    /// As [`vanished`], with a sliver of surface at 1.7 m in E over the
    /// columns `sliver` (not continuous with the surface), returning nothing.
    fn vanished_with_sliver(
        through: std::ops::Range<usize>,
        sliver: std::ops::Range<usize>,
    ) -> Vec<bool> {
        let mut expected = DepthImage::new(W as u32, H as u32);
        let mut depth = DepthImage::new(W as u32, H as u32);
        for r in 0..H {
            for c in 0..W {
                let on = (5..35).contains(&c);
                expected.data[r * W + c] = if sliver.contains(&c) {
                    1.7
                } else if on {
                    2.0
                } else {
                    3.0
                };
                depth.data[r * W + c] = if sliver.contains(&c) || on && !through.contains(&c) {
                    0.0
                } else {
                    3.0
                };
            }
        }
        let t = Threshold::Metres(0.05);
        let mut carver = Carver::default();
        carver.prepare(&depth, 0, t, 2);
        let params = MissingReturns {
            range: [0.9, 3.5],
            seeds: 16,
            fringe: 2,
        };
        let (_, absence) = carver.absence(&expected, t, t, &params, 2);
        match absence {
            Some(a) => a.vanished.to_vec(),
            None => vec![false; W * H],
        }
    }

    #[test]
    fn missing_returns_count_only_where_the_surface_is_seen_through() {
        // Seen through over six columns: the rest of the surface is vanishing,
        // except within a pixel of a return.
        let v = vanished(5..11);
        assert!(
            v[15 * W + 20],
            "a pixel with no return on vanishing surface"
        );
        assert!(!v[15 * W + 11], "next to a return");
        assert!(!v[15 * W + 8], "seen through, not missing");
        assert!(!v[15 * W + 38], "no surface of M there");
        // Never seen through (a black object that is there): nothing vanishes.
        assert!(vanished(0..0).iter().all(|&v| !v));
        // Seen through in a strip two pixels wide (a misplaced silhouette):
        // not solid enough to count.
        assert!(vanished(5..7).iter().all(|&v| !v));
    }

    #[test]
    fn a_sliver_of_the_outline_vanishes_with_its_surface_and_only_then() {
        // A sliver next to the vanishing surface, apart from it in E.
        let v = vanished_with_sliver(5..11, 35..38);
        assert!(v[15 * W + 35], "a pixel beside the vanishing region");
        // The same sliver four pixels away is a surface of its own.
        let v = vanished_with_sliver(5..11, 37..40);
        assert!(!v[15 * W + 38], "four pixels from the vanishing region");
        // Beside a surface that is never seen through, nothing vanishes.
        assert!(vanished_with_sliver(0..0, 35..38).iter().all(|&v| !v));
    }

    #[test]
    fn a_triangle_on_a_vanished_pixel_within_range_gets_a_vote() {
        let vanished = vec![true; 9];
        let absence = Absence {
            width: 3,
            height: 3,
            vanished: &vanished,
            range: [1.0, 3.0],
            frames_to_remove: 2,
        };
        let at = |z: f32| {
            [
                [0.9, 0.9, 1.0 / z],
                [1.2, 1.0, 1.0 / z],
                [1.0, 1.2, 1.0 / z],
            ]
        };
        let mut vote = 0;
        assert!(!absence.judge(&mut vote, &at(2.0)));
        assert!(absence.judge(&mut vote, &at(2.0)), "two votes remove");
        let mut vote = 0;
        absence.judge(&mut vote, &at(3.8));
        assert_eq!(vote, 0, "beyond the range a surface may not return");
    }
}
