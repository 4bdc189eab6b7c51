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
//! With the thesis threshold (0.01·z² m) and its noise (σ ≈ 0.002·z² m), a
//! contradiction needs a ~5σ error at all nine pixels, so noise does not erode
//! unchanged surfaces.

use crate::camera::Intrinsics;
use crate::image::DepthImage;
use crate::mabdi::classify::Threshold;
use glam::Vec3;
use rayon::prelude::*;

/// Free-space evidence counters, one per triangle of the global mesh.
#[derive(Debug, Default)]
pub struct Carver {
    /// Contradictions without a confirmation in between, per triangle.
    pub votes: Vec<u8>,
    /// Neighbourhood minimum of the current depth image (0 = not usable).
    min_depth: Vec<f32>,
}

impl Carver {
    /// Updates the counters of all triangles from one depth image and returns
    /// whether any triangle reached `frames_to_remove`. `camera_points` are the
    /// mesh vertices in the camera frame of `depth`.
    pub fn observe(
        &mut self,
        camera_points: &[Vec3],
        triangles: &[[u32; 3]],
        depth: &DepthImage,
        intrinsics: &Intrinsics,
        threshold: Threshold,
        frames_to_remove: u8,
    ) -> bool {
        self.votes.resize(triangles.len(), 0);
        let (w, h) = (depth.width as usize, depth.height as usize);
        self.min_depth.clear();
        self.min_depth.resize(w * h, 0.0);
        if w < 3 || h < 3 {
            return false;
        }
        self.min_depth
            .par_chunks_mut(w)
            .enumerate()
            .skip(1)
            .take(h - 2)
            .for_each(|(r, row)| {
                for (c, out) in row.iter_mut().enumerate().take(w - 1).skip(1) {
                    let (mut m, mut valid) = (f32::INFINITY, true);
                    for rr in r - 1..=r + 1 {
                        for d in &depth.data[rr * w + c - 1..=rr * w + c + 1] {
                            valid &= *d > 0.0;
                            m = m.min(*d);
                        }
                    }
                    *out = if valid { m } else { 0.0 };
                }
            });
        let min_depth = &self.min_depth;
        self.votes
            .par_iter_mut()
            .zip(triangles.par_iter())
            .map(|(vote, t)| {
                let c = (camera_points[t[0] as usize]
                    + camera_points[t[1] as usize]
                    + camera_points[t[2] as usize])
                    / 3.0;
                if c.z <= 0.0 {
                    return false;
                }
                let u = (intrinsics.fx * c.x / c.z + intrinsics.cx).round();
                let v = (intrinsics.fy * c.y / c.z + intrinsics.cy).round();
                if !(u >= 0.0 && v >= 0.0 && (u as usize) < w && (v as usize) < h) {
                    return false;
                }
                let at = v as usize * w + u as usize;
                let (d, beyond) = (depth.data[at], min_depth[at]);
                let tol = threshold.at(c.z);
                if beyond > 0.0 && c.z < beyond - tol {
                    *vote = vote.saturating_add(1);
                } else if d > 0.0 && (d - c.z).abs() <= tol {
                    *vote = 0;
                }
                *vote >= frames_to_remove
            })
            .reduce(|| false, |a, b| a || b)
    }
}
