//! Depth pyramids with camera-space vertex and normal maps per level, for
//! coarse-to-fine ICP (KinectFusion's measurement step).

use crate::camera::Intrinsics;
use crate::image::DepthImage;
use glam::Vec3;
use rayon::prelude::*;

/// Neighbouring depths further apart than this fraction of the depth are a
/// depth edge: they are neither averaged together nor used for a normal.
const EDGE_FRACTION: f32 = 0.04;

/// One level of a pyramid.
#[derive(Clone, Debug, Default)]
pub struct Level {
    /// The camera model at this level's resolution.
    pub intrinsics: Option<Intrinsics>,
    /// Depth in metres (0 = none).
    pub depth: DepthImage,
    /// Camera-space points (zero where no depth).
    pub points: Vec<Vec3>,
    /// Camera-space unit normals facing the camera (zero where unknown).
    pub normals: Vec<Vec3>,
}

impl Level {
    /// Width and height in pixels.
    pub fn size(&self) -> (usize, usize) {
        (self.depth.width as usize, self.depth.height as usize)
    }

    /// Fills points and normals from `depth` and `intrinsics`.
    fn compute_maps(&mut self, k: Intrinsics, step: usize) {
        self.intrinsics = Some(k);
        let (w, h) = self.size();
        self.points.resize(w * h, Vec3::ZERO);
        self.normals.resize(w * h, Vec3::ZERO);
        let depth = &self.depth.data;
        // `Intrinsics::back_project` with the divisions hoisted; a missing
        // depth (0, or anything not positive) gives the zero point.
        let (inv_fx, inv_fy) = (1.0 / k.fx, 1.0 / k.fy);
        self.points
            .par_chunks_mut(w)
            .zip(depth.par_chunks(w))
            .enumerate()
            .for_each(|(y, (row, depth))| {
                let ray_y = (y as f32 - k.cy) * inv_fy;
                for (x, (p, &z)) in row.iter_mut().zip(depth).enumerate() {
                    let z = z.max(0.0);
                    *p = Vec3::new((x as f32 - k.cx) * inv_fx * z, ray_y * z, z);
                }
            });
        let points = &self.points;
        self.normals
            .par_chunks_mut(w)
            .enumerate()
            .for_each(|(y, row)| normal_row(points, depth, w, h, y, step, row));
    }
}

/// The normals of row `y` from central differences over `s` pixels, where
/// the four neighbours have depth on the same surface as the pixel (zero
/// elsewhere, and along the image border).
fn normal_row(
    points: &[Vec3],
    depth: &[f32],
    w: usize,
    h: usize,
    y: usize,
    s: usize,
    row: &mut [Vec3],
) {
    row.fill(Vec3::ZERO);
    if y < s || y + s >= h || w < 2 * s + 1 {
        return;
    }
    // The three rows as slices: no index checks per pixel.
    let (d_up, d_mid, d_down) = rows_around(depth, w, y, s);
    let (p_up, p_mid, p_down) = rows_around(points, w, y, s);
    for x in s..w - s {
        let z = d_mid[x];
        let limit = EDGE_FRACTION * z * s as f32;
        let same = |d: f32| d > 0.0 && (d - z).abs() <= limit;
        if z > 0.0 && same(d_mid[x - s]) && same(d_mid[x + s]) && same(d_up[x]) && same(d_down[x]) {
            let dx = p_mid[x + s] - p_mid[x - s];
            let dy = p_down[x] - p_up[x];
            // Camera x right, y down, z forward: dy × dx points towards the camera.
            row[x] = dy.cross(dx).normalize_or_zero();
        }
    }
}

/// Rows `y − s`, `y` and `y + s` of an image `w` pixels wide.
fn rows_around<T>(data: &[T], w: usize, y: usize, s: usize) -> (&[T], &[T], &[T]) {
    (
        &data[(y - s) * w..(y - s + 1) * w],
        &data[y * w..(y + 1) * w],
        &data[(y + s) * w..(y + s + 1) * w],
    )
}

/// Halves a depth image: each output pixel averages the valid depths of its
/// 2×2 block that lie on the block's nearest surface.
fn downsample(input: &DepthImage, out: &mut DepthImage) {
    let (w, h) = (input.width as usize / 2, input.height as usize / 2);
    out.reset(w as u32, h as u32);
    let iw = input.width as usize;
    out.data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let i = 2 * y * iw + 2 * x;
            let block = [
                input.data[i],
                input.data[i + 1],
                input.data[i + iw],
                input.data[i + iw + 1],
            ];
            let near = block
                .iter()
                .copied()
                .filter(|&d| d > 0.0)
                .fold(f32::INFINITY, f32::min);
            if near.is_finite() {
                let limit = EDGE_FRACTION * near;
                let (sum, n) = block
                    .iter()
                    .filter(|&&d| d > 0.0 && d - near <= limit)
                    .fold((0.0, 0.0), |(s, n), &d| (s + d, n + 1.0));
                *o = sum / n;
            }
        }
    });
}

/// The intrinsics of a half-resolution image (pixel centres at half-integers).
pub fn half(k: &Intrinsics) -> Intrinsics {
    Intrinsics {
        width: k.width / 2,
        height: k.height / 2,
        fx: k.fx / 2.0,
        fy: k.fy / 2.0,
        cx: (k.cx + 0.5) / 2.0 - 0.5,
        cy: (k.cy + 0.5) / 2.0 - 0.5,
    }
}

/// A depth pyramid; level 0 is the full resolution. Buffers are kept and
/// reused by [`Pyramid::build`].
#[derive(Clone, Debug, Default)]
pub struct Pyramid {
    /// Finest first.
    pub levels: Vec<Level>,
}

impl Pyramid {
    /// Rebuilds the pyramid with `count` levels from `depth` taken with `k`.
    pub fn build(&mut self, depth: &DepthImage, k: &Intrinsics, count: usize) {
        self.build_spaced(depth, k, count, 1);
    }

    /// [`Pyramid::build`] with level 0's normals from neighbours `step`
    /// pixels apart (level `l`'s from `step / 2^l`, at least 1): the same
    /// baseline on the surface at every level, so a view at a finer
    /// resolution keeps its edges without normals that follow pixel-scale
    /// noise.
    pub fn build_spaced(&mut self, depth: &DepthImage, k: &Intrinsics, count: usize, step: usize) {
        self.levels.resize_with(count, Level::default);
        let mut k = *k;
        for l in 0..count {
            let (done, rest) = self.levels.split_at_mut(l);
            let level = &mut rest[0];
            match done.last() {
                None => {
                    level.depth.reset(depth.width, depth.height);
                    level.depth.data.copy_from_slice(&depth.data);
                }
                Some(finer) => {
                    downsample(&finer.depth, &mut level.depth);
                    k = half(&k);
                }
            }
            level.compute_maps(k, (step >> l).max(1));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tilted_plane(k: &Intrinsics) -> DepthImage {
        // The plane z = 2 + 0.5·x (camera space), seen through each pixel.
        let mut depth = DepthImage::new(k.width, k.height);
        for v in 0..k.height {
            for u in 0..k.width {
                let ray = k.back_project(u as f32, v as f32, 1.0);
                depth.data[(v * k.width + u) as usize] = 2.0 / (1.0 - 0.5 * ray.x);
            }
        }
        depth
    }

    #[test]
    fn levels_keep_the_surface_and_its_normal() {
        let k = Intrinsics::from_vertical_fov(160, 120, 60.0);
        let mut pyramid = Pyramid::default();
        pyramid.build(&tilted_plane(&k), &k, 3);
        let want = Vec3::new(0.5, 0.0, -1.0).normalize();
        assert_eq!(pyramid.levels[2].size(), (40, 30));
        for level in &pyramid.levels {
            let (w, h) = level.size();
            let mut checked = 0;
            for i in 0..w * h {
                let p = level.points[i];
                // Every point on the plane...
                assert!((p.z - (2.0 + 0.5 * p.x)).abs() < 2e-3 * p.z, "{p}");
                // ...and interior normals match it.
                if level.normals[i] != Vec3::ZERO {
                    assert!(level.normals[i].dot(want) > 0.9999);
                    checked += 1;
                }
            }
            assert_eq!(checked, (w - 2) * (h - 2));
        }
    }

    #[test]
    fn spaced_normals_keep_the_surface_and_leave_a_wider_border() {
        let k = Intrinsics::from_vertical_fov(160, 120, 60.0);
        let mut pyramid = Pyramid::default();
        pyramid.build_spaced(&tilted_plane(&k), &k, 3, 2);
        let want = Vec3::new(0.5, 0.0, -1.0).normalize();
        // Two pixels apart at the finest level, one at the coarser ones.
        for (level, border) in pyramid.levels.iter().zip([2, 1, 1]) {
            let (w, h) = level.size();
            let normals = level.normals.iter().filter(|n| **n != Vec3::ZERO);
            assert!(normals.clone().all(|n| n.dot(want) > 0.9999));
            assert_eq!(normals.count(), (w - 2 * border) * (h - 2 * border));
        }
    }

    #[test]
    fn downsampling_keeps_the_nearer_side_of_an_edge() {
        let mut depth = DepthImage::new(4, 2);
        depth.data = vec![1.0, 3.0, 0.0, 2.0, 1.02, 3.0, 0.0, 0.0];
        let mut out = DepthImage::default();
        downsample(&depth, &mut out);
        assert_eq!(out.data, vec![1.01, 2.0]);
    }
}
