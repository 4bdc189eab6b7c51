//! CPU z-buffer rasterizer: metric depth and triangle ids of a mesh seen from a pose.
//!
//! This is what the simulated sensor uses to image a scene and what MABDI uses
//! to predict the expected depth image E from the global mesh. Design points:
//!
//! * **Exact coverage.** Vertices are snapped to 1/256 pixel and edge functions are
//!   evaluated in integers with a top-left style tie rule, so two triangles that share
//!   an edge cover every pixel centre on it exactly once. Meshes made from depth
//!   images put their vertices *on* pixel centres when seen from the pose they were
//!   made from; a floating-point rasterizer would leave cracks there, and MABDI
//!   would see them as novel surface.
//! * **Exact depth.** Depth comes from the triangle's plane, `1/z = A·u + B·v + C`,
//!   which is exact for planar triangles under perspective, so analytic shapes
//!   render to float precision.
//! * **Near-plane clipping** in camera space; polygons that reach far outside the
//!   image are clipped to a guard band in screen space (those cuts lie off-image).
//! * **Parallel over image bands.** A binning pass (parallel over triangle chunks)
//!   files each triangle under the horizontal bands it overlaps; bands are then
//!   rasterized independently. Scratch buffers live in [`Rasterizer`] and are
//!   reused from frame to frame.

use crate::camera::{Intrinsics, Pose};
use crate::image::DepthImage;
use glam::Vec3;
use rayon::prelude::*;

/// Triangle id of pixels that no triangle covers.
pub const NO_TRIANGLE: u32 = u32::MAX;

/// Rows per band of the parallel raster pass.
const BAND_ROWS: usize = 16;
/// Triangles per chunk of the parallel binning pass.
const CHUNK_TRIANGLES: usize = 1 << 14;
/// Sub-pixel precision of snapped vertices (bits).
const SUBPIXEL_BITS: u32 = 8;
const SUBPIXEL: f32 = (1 << SUBPIXEL_BITS) as f32;
/// How far outside the image (pixels) a polygon may reach before it is clipped
/// in screen space; keeps fixed-point products well inside `i64`.
const GUARD_BAND: f32 = 2048.0;

/// The result of a render: depth along the optical axis and the id of the
/// triangle seen at each pixel.
#[derive(Clone, Debug, Default)]
pub struct RenderTarget {
    /// Metric depth; 0 where nothing is seen.
    pub depth: DepthImage,
    /// Index of the visible triangle, or [`NO_TRIANGLE`].
    pub triangle: Vec<u32>,
    /// Working z-buffer of inverse depths (larger is nearer).
    inverse_depth: Vec<f32>,
}

impl RenderTarget {
    fn reset(&mut self, width: u32, height: u32) {
        let n = width as usize * height as usize;
        self.depth.reset(width, height);
        self.triangle.clear();
        self.triangle.resize(n, NO_TRIANGLE);
        self.inverse_depth.clear();
        self.inverse_depth.resize(n, 0.0);
    }
}

/// A reusable rasterizer; keep one per view so its buffers are reused.
#[derive(Debug, Default)]
pub struct Rasterizer {
    /// Camera-space vertex positions of the current render.
    camera_points: Vec<Vec3>,
    /// Triangle ids per (chunk, band), flattened chunk-major.
    bins: Vec<Vec<u32>>,
}

/// View parameters shared by the passes of one render.
#[derive(Clone, Copy)]
struct View {
    width: usize,
    height: usize,
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
    near: f32,
}

impl View {
    #[inline]
    fn project(&self, p: Vec3) -> (f32, f32) {
        let inv = 1.0 / p.z;
        (self.fx * p.x * inv + self.cx, self.fy * p.y * inv + self.cy)
    }
}

/// A convex polygon of at most 3 + 4 (near plane, then four guard-band cuts) vertices.
#[derive(Clone, Copy)]
struct Polygon {
    n: usize,
    p: [[f32; 2]; 8],
}

impl Rasterizer {
    /// A rasterizer with empty buffers.
    pub fn new() -> Self {
        Self::default()
    }

    /// Camera-space positions of the vertices of the last render, so that
    /// per-triangle passes after a render need not transform them again.
    pub fn camera_points(&self) -> &[Vec3] {
        &self.camera_points
    }

    /// Renders the triangles seen from `pose` into `target` (resized to the
    /// intrinsics). Both faces of every triangle are drawn; geometry nearer than
    /// `near` metres is clipped away. Triangles whose indices are out of range
    /// must not be passed (see [`crate::Mesh::check`]).
    pub fn render(
        &mut self,
        positions: &[Vec3],
        triangles: &[[u32; 3]],
        intrinsics: &Intrinsics,
        pose: &Pose,
        near: f32,
        target: &mut RenderTarget,
    ) {
        let view = View {
            width: intrinsics.width as usize,
            height: intrinsics.height as usize,
            fx: intrinsics.fx,
            fy: intrinsics.fy,
            cx: intrinsics.cx,
            cy: intrinsics.cy,
            near: near.max(1e-6),
        };
        target.reset(intrinsics.width, intrinsics.height);
        if view.width == 0 || view.height == 0 {
            return;
        }
        let world_to_camera = pose.inverse();
        self.camera_points.resize(positions.len(), Vec3::ZERO);
        self.camera_points
            .par_chunks_mut(1 << 14)
            .zip(positions.par_chunks(1 << 14))
            .for_each(|(out, inp)| {
                for (o, &p) in out.iter_mut().zip(inp) {
                    *o = world_to_camera.transform_point(p);
                }
            });

        let bands = view.height.div_ceil(BAND_ROWS);
        let chunks = triangles.len().div_ceil(CHUNK_TRIANGLES);
        if self.bins.len() < chunks * bands {
            self.bins.resize_with(chunks * bands, Vec::new);
        }
        let camera_points = &self.camera_points;
        self.bins[..chunks * bands]
            .par_chunks_mut(bands)
            .zip(triangles.par_chunks(CHUNK_TRIANGLES))
            .enumerate()
            .for_each(|(chunk, (bins, tris))| {
                bins.iter_mut().for_each(Vec::clear);
                let first = (chunk * CHUNK_TRIANGLES) as u32;
                for (i, t) in tris.iter().enumerate() {
                    let corners = t.map(|v| camera_points[v as usize]);
                    if let Some((r0, r1)) = row_span(&view, &corners) {
                        for bin in &mut bins[r0 / BAND_ROWS..=r1 / BAND_ROWS] {
                            bin.push(first + i as u32);
                        }
                    }
                }
            });

        let bins = &self.bins[..chunks * bands];
        let rows = BAND_ROWS * view.width;
        target
            .inverse_depth
            .par_chunks_mut(rows)
            .zip(target.triangle.par_chunks_mut(rows))
            .enumerate()
            .for_each(|(band, (zbuf, ids))| {
                let row0 = band * BAND_ROWS;
                let row1 = (row0 + BAND_ROWS).min(view.height) - 1;
                for chunk in 0..chunks {
                    for &t in &bins[chunk * bands + band] {
                        let corners = triangles[t as usize].map(|v| camera_points[v as usize]);
                        draw_triangle(&view, &corners, t, row0, row1, zbuf, ids);
                    }
                }
            });

        target
            .depth
            .data
            .par_iter_mut()
            .zip(target.inverse_depth.par_iter())
            .for_each(|(d, &w)| *d = if w > 0.0 { 1.0 / w } else { 0.0 });
    }
}

/// The image rows (inclusive) a triangle may cover, or `None` when it cannot
/// cover any pixel centre. A conservative float test: exact coverage is decided later.
#[inline]
fn row_span(view: &View, c: &[Vec3; 3]) -> Option<(usize, usize)> {
    let (w, h) = (view.width as f32, view.height as f32);
    let (vmin, vmax, umin, umax);
    if c[0].z >= view.near && c[1].z >= view.near && c[2].z >= view.near {
        let a = view.project(c[0]);
        let b = view.project(c[1]);
        let d = view.project(c[2]);
        umin = a.0.min(b.0).min(d.0);
        umax = a.0.max(b.0).max(d.0);
        vmin = a.1.min(b.1).min(d.1);
        vmax = a.1.max(b.1).max(d.1);
    } else {
        let poly = clip_near(view, c)?;
        let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
        for p in &poly.p[..poly.n] {
            lo = [lo[0].min(p[0]), lo[1].min(p[1])];
            hi = [hi[0].max(p[0]), hi[1].max(p[1])];
        }
        (umin, vmin, umax, vmax) = (lo[0], lo[1], hi[0], hi[1]);
    }
    // A small margin keeps this test conservative against the snapping below.
    let (u0, u1) = (
        (umin - 0.01).ceil().max(0.0),
        (umax + 0.01).floor().min(w - 1.0),
    );
    let (v0, v1) = (
        (vmin - 0.01).ceil().max(0.0),
        (vmax + 0.01).floor().min(h - 1.0),
    );
    (u0 <= u1 && v0 <= v1).then_some((v0 as usize, v1 as usize))
}

/// Clips a camera-space triangle to `z >= near` and projects it. The cut point
/// of an edge is computed from its endpoints in a fixed order, so the two
/// triangles sharing the edge get the very same point.
fn clip_near(view: &View, c: &[Vec3; 3]) -> Option<Polygon> {
    let mut poly = Polygon {
        n: 0,
        p: [[0.0; 2]; 8],
    };
    for i in 0..3 {
        let (p, q) = (c[i], c[(i + 1) % 3]);
        let (p_in, q_in) = (p.z >= view.near, q.z >= view.near);
        if p_in {
            let s = view.project(p);
            poly.p[poly.n] = [s.0, s.1];
            poly.n += 1;
        }
        if p_in != q_in {
            let (a, b) = if (p.z, p.x, p.y) < (q.z, q.x, q.y) {
                (p, q)
            } else {
                (q, p)
            };
            let t = (view.near - a.z) / (b.z - a.z);
            let mut x = a + (b - a) * t;
            x.z = view.near;
            let s = view.project(x);
            poly.p[poly.n] = [s.0, s.1];
            poly.n += 1;
        }
    }
    (poly.n >= 3).then_some(poly)
}

/// Clips a screen-space polygon to the guard band around the image.
fn clip_guard(view: &View, poly: &Polygon) -> Polygon {
    let bounds = [
        (0, -GUARD_BAND, true),
        (0, view.width as f32 + GUARD_BAND, false),
        (1, -GUARD_BAND, true),
        (1, view.height as f32 + GUARD_BAND, false),
    ];
    let mut cur = *poly;
    for (axis, limit, is_min) in bounds {
        let inside = |p: &[f32; 2]| {
            if is_min {
                p[axis] >= limit
            } else {
                p[axis] <= limit
            }
        };
        let mut out = Polygon {
            n: 0,
            p: [[0.0; 2]; 8],
        };
        for i in 0..cur.n {
            let (p, q) = (cur.p[i], cur.p[(i + 1) % cur.n]);
            if inside(&p) {
                out.p[out.n] = p;
                out.n += 1;
            }
            if inside(&p) != inside(&q) && out.n < 8 {
                let t = (limit - p[axis]) / (q[axis] - p[axis]);
                let mut x = [p[0] + (q[0] - p[0]) * t, p[1] + (q[1] - p[1]) * t];
                x[axis] = limit;
                out.p[out.n] = x;
                out.n += 1;
            }
        }
        cur = out;
        if cur.n < 3 {
            break;
        }
    }
    cur
}

/// Rasterizes one triangle into the rows `row0..=row1` of the band buffers.
#[inline]
fn draw_triangle(
    view: &View,
    c: &[Vec3; 3],
    id: u32,
    row0: usize,
    row1: usize,
    zbuf: &mut [f32],
    ids: &mut [u32],
) {
    // Plane of the triangle in camera space, n·X = d, gives 1/z = (n·ray(u, v)) / d.
    let n = (c[1] - c[0]).cross(c[2] - c[0]);
    let d = n.dot(c[0]);
    if d.abs() <= f32::MIN_POSITIVE * 1e6 || !d.is_finite() {
        return; // seen edge-on (or degenerate): covers no area
    }
    let a = n.x / (view.fx * d);
    let b = n.y / (view.fy * d);
    let k = (n.z - n.x * view.cx / view.fx - n.y * view.cy / view.fy) / d;

    let mut poly = if c.iter().all(|p| p.z >= view.near) {
        let mut poly = Polygon {
            n: 3,
            p: [[0.0; 2]; 8],
        };
        for (dst, &p) in poly.p.iter_mut().zip(c) {
            let s = view.project(p);
            *dst = [s.0, s.1];
        }
        poly
    } else {
        match clip_near(view, c) {
            Some(p) => p,
            None => return,
        }
    };
    let reach = poly.p[..poly.n]
        .iter()
        .any(|p| p[0].abs() > GUARD_BAND * 2.0 || p[1].abs() > GUARD_BAND * 2.0);
    if reach {
        poly = clip_guard(view, &poly);
        if poly.n < 3 {
            return;
        }
    }
    fill_polygon(view, &poly, [a, b, k], id, row0, row1, zbuf, ids);
}

/// Fills a convex polygon with the inverse-depth plane `w = a·u + b·v + k`.
#[allow(clippy::too_many_arguments)]
#[inline]
fn fill_polygon(
    view: &View,
    poly: &Polygon,
    plane: [f32; 3],
    id: u32,
    row0: usize,
    row1: usize,
    zbuf: &mut [f32],
    ids: &mut [u32],
) {
    let n = poly.n;
    let mut q = [[0i64; 2]; 8];
    let (mut x0, mut y0, mut x1, mut y1) = (i64::MAX, i64::MAX, i64::MIN, i64::MIN);
    for (s, p) in q.iter_mut().zip(&poly.p[..n]) {
        *s = [
            (p[0] * SUBPIXEL).round() as i64,
            (p[1] * SUBPIXEL).round() as i64,
        ];
        x0 = x0.min(s[0]);
        x1 = x1.max(s[0]);
        y0 = y0.min(s[1]);
        y1 = y1.max(s[1]);
    }
    let one = 1i64 << SUBPIXEL_BITS;
    // Pixel centres are at integer coordinates: the covered range is
    // ceil(min)..=floor(max) in pixels.
    let px0 = ((x0 + one - 1) >> SUBPIXEL_BITS).max(0);
    let px1 = (x1 >> SUBPIXEL_BITS).min(view.width as i64 - 1);
    let py0 = ((y0 + one - 1) >> SUBPIXEL_BITS).max(row0 as i64);
    let py1 = (y1 >> SUBPIXEL_BITS).min(row1 as i64);
    if px0 > px1 || py0 > py1 {
        return;
    }
    // Twice the signed area decides the orientation; both faces are drawn, so
    // a clockwise polygon is walked backwards.
    let mut area = 0i64;
    for i in 0..n {
        let (p, r) = (q[i], q[(i + 1) % n]);
        area += p[0] * r[1] - p[1] * r[0];
    }
    if area == 0 {
        return;
    }
    // Edge i: E(p) = (r - s) × (p - s), ≥ 0 inside for a positive polygon.
    let mut e_row = [0i64; 8];
    let mut step_x = [0i64; 8];
    let mut step_y = [0i64; 8];
    let start = [px0 << SUBPIXEL_BITS, py0 << SUBPIXEL_BITS];
    for i in 0..n {
        let (mut s, mut r) = (q[i], q[(i + 1) % n]);
        if area < 0 {
            std::mem::swap(&mut s, &mut r);
        }
        let (dx, dy) = (r[0] - s[0], r[1] - s[1]);
        // Tie rule: a pixel centre exactly on an edge belongs to one side only.
        // The rule flips when the edge is walked the other way, which is how
        // the neighbouring triangle walks a shared edge.
        let bias = if dy < 0 || (dy == 0 && dx > 0) { 0 } else { -1 };
        e_row[i] = dx * (start[1] - s[1]) - dy * (start[0] - s[0]) + bias;
        step_x[i] = -dy * one;
        step_y[i] = dx * one;
    }
    let [a, b, k] = plane;
    for py in py0..=py1 {
        let mut e = e_row;
        let row = (py as usize - row0) * view.width;
        let wy = b * py as f32 + k;
        for px in px0..=px1 {
            if e[..n].iter().all(|&v| v >= 0) {
                let w = a * px as f32 + wy;
                let at = row + px as usize;
                if w > zbuf[at] {
                    zbuf[at] = w;
                    ids[at] = id;
                }
            }
            for i in 0..n {
                e[i] += step_x[i];
            }
        }
        for i in 0..n {
            e_row[i] += step_y[i];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn render(
        positions: &[Vec3],
        triangles: &[[u32; 3]],
        k: &Intrinsics,
        pose: &Pose,
    ) -> RenderTarget {
        let mut target = RenderTarget::default();
        Rasterizer::new().render(positions, triangles, k, pose, 0.05, &mut target);
        target
    }

    /// Depth along the optical axis where the ray through pixel (u, v) meets
    /// the world plane `n·X = d`, if in front of the camera.
    fn plane_depth(k: &Intrinsics, pose: &Pose, n: Vec3, d: f32, u: f32, v: f32) -> Option<f32> {
        let ray = pose.transform_vector(k.back_project(u, v, 1.0));
        let denom = n.dot(ray);
        let t = (d - n.dot(pose.translation)) / denom;
        (denom.abs() > 1e-9 && t > 0.0).then_some(t)
    }

    fn quad(corners: [Vec3; 4]) -> (Vec<Vec3>, Vec<[u32; 3]>) {
        (corners.to_vec(), vec![[0, 1, 2], [0, 2, 3]])
    }

    #[test]
    fn tilted_plane_depth_is_exact() {
        let k = Intrinsics::kinect();
        let pose = Pose::look_at(Vec3::new(0.3, 1.2, -2.5), Vec3::new(0.0, 0.2, 0.0), Vec3::Y);
        let (p, t) = quad([
            Vec3::new(-5.0, 0.0, -5.0),
            Vec3::new(5.0, 0.0, -5.0),
            Vec3::new(5.0, 0.0, 5.0),
            Vec3::new(-5.0, 0.0, 5.0),
        ]);
        let r = render(&p, &t, &k, &pose);
        let mut checked = 0;
        for v in 0..k.height {
            for u in 0..k.width {
                let got = r.depth.get(u, v);
                let want = plane_depth(&k, &pose, Vec3::Y, 0.0, u as f32, v as f32);
                let world =
                    want.map(|z| pose.transform_point(k.back_project(u as f32, v as f32, z)));
                match world {
                    Some(w) if w.x.abs() < 4.99 && w.z.abs() < 4.99 => {
                        assert!(
                            (got - want.unwrap()).abs() < 1e-4,
                            "pixel ({u},{v}): {got} vs {want:?}"
                        );
                        checked += 1;
                    }
                    Some(w) if w.x.abs() > 5.01 || w.z.abs() > 5.01 => assert_eq!(got, 0.0),
                    None => assert_eq!(
                        got, 0.0,
                        "pixel ({u},{v}) sees the plane from above the horizon"
                    ),
                    _ => {}
                }
            }
        }
        assert!(checked > 100_000);
    }

    #[test]
    fn box_matches_ray_casting() {
        let k = Intrinsics::from_vertical_fov(160, 120, 60.0);
        let pose = Pose::look_at(Vec3::new(1.7, 1.1, -2.2), Vec3::ZERO, Vec3::Y);
        let h = Vec3::new(0.5, 0.3, 0.4);
        let mut positions = Vec::new();
        for i in 0..8 {
            positions.push(Vec3::new(
                if i & 1 == 0 { -h.x } else { h.x },
                if i & 2 == 0 { -h.y } else { h.y },
                if i & 4 == 0 { -h.z } else { h.z },
            ));
        }
        let triangles = vec![
            [0, 2, 3],
            [0, 3, 1],
            [4, 5, 7],
            [4, 7, 6],
            [0, 1, 5],
            [0, 5, 4],
            [2, 6, 7],
            [2, 7, 3],
            [0, 4, 6],
            [0, 6, 2],
            [1, 3, 7],
            [1, 7, 5],
        ];
        let r = render(&positions, &triangles, &k, &pose);
        let (mut hits, mut disagree) = (0, 0);
        for v in 0..k.height {
            for u in 0..k.width {
                let o = pose.translation;
                let dir = pose.transform_vector(k.back_project(u as f32, v as f32, 1.0));
                // Slab test gives the ray parameter, which is depth for a z = 1 ray.
                let t1 = (-h - o) / dir;
                let t2 = (h - o) / dir;
                let tn = t1.min(t2).max_element();
                let tf = t1.max(t2).min_element();
                let got = r.depth.get(u, v);
                if tn < tf && tn > 0.0 {
                    if got > 0.0 {
                        assert!((got - tn).abs() < 1e-4, "({u},{v}) {got} vs {tn}");
                        hits += 1;
                    } else {
                        disagree += 1;
                    }
                } else if got > 0.0 {
                    disagree += 1;
                }
            }
        }
        assert!(hits > 1000, "{hits}");
        assert!(disagree <= 2, "{disagree} pixels disagree on coverage");
    }

    #[test]
    fn near_plane_clipping_keeps_the_visible_part() {
        // A camera standing on a huge floor looking slightly down: the floor
        // reaches behind the camera, through the near plane.
        let k = Intrinsics::from_vertical_fov(200, 150, 60.0);
        let pose = Pose::look_at(Vec3::new(0.0, 0.5, 0.0), Vec3::new(0.0, 0.3, 3.0), Vec3::Y);
        let (p, t) = quad([
            Vec3::new(-100.0, 0.0, -100.0),
            Vec3::new(100.0, 0.0, -100.0),
            Vec3::new(100.0, 0.0, 100.0),
            Vec3::new(-100.0, 0.0, 100.0),
        ]);
        let r = render(&p, &t, &k, &pose);
        for v in 0..k.height {
            for u in 0..k.width {
                let got = r.depth.get(u, v);
                match plane_depth(&k, &pose, Vec3::Y, 0.0, u as f32, v as f32) {
                    Some(z) if z < 50.0 => {
                        assert!((got - z).abs() < 1e-4 * z * z, "({u},{v}) {got} vs {z}")
                    }
                    Some(_) => {}
                    None => assert_eq!(got, 0.0),
                }
            }
        }
        // A triangle entirely behind the camera draws nothing, and one cut by
        // the near plane draws only its part in front.
        let behind = [
            Vec3::new(-1.0, 0.4, -1.0),
            Vec3::new(1.0, 0.4, -1.0),
            Vec3::new(0.0, 0.6, -1.0),
        ];
        let r = render(&behind, &[[0, 1, 2]], &k, &pose);
        assert!(r.triangle.iter().all(|&t| t == NO_TRIANGLE));
        let pose = Pose::IDENTITY;
        let cut = [
            Vec3::new(-0.5, -0.5, -1.0),
            Vec3::new(0.5, -0.5, -1.0),
            Vec3::new(0.0, 0.2, 1.5),
        ];
        let mut target = RenderTarget::default();
        Rasterizer::new().render(&cut, &[[0, 1, 2]], &k, &pose, 0.5, &mut target);
        let seen: Vec<f32> = target
            .depth
            .data
            .iter()
            .copied()
            .filter(|&d| d > 0.0)
            .collect();
        assert!(!seen.is_empty());
        assert!(seen.iter().all(|&d| (0.5 - 1e-4..=1.5 + 1e-4).contains(&d)));
    }

    #[test]
    fn shared_edges_leave_no_cracks_and_nearest_wins() {
        // A fan of thin triangles around a vertex on a pixel centre, with
        // vertices on pixel centres too: every pixel inside must be covered.
        let k = Intrinsics::from_vertical_fov(64, 64, 60.0);
        let pose = Pose::IDENTITY;
        let z = 2.0;
        let centre = k.back_project(31.0, 31.0, z);
        let mut positions = vec![centre];
        let ring = 40;
        for i in 0..ring {
            let a = i as f32 / ring as f32 * std::f32::consts::TAU;
            let (u, v) = (31.0 + 25.0 * a.cos(), 31.0 + 25.0 * a.sin());
            positions.push(k.back_project(u.round(), v.round(), z));
        }
        let triangles: Vec<[u32; 3]> = (0..ring).map(|i| [0, 1 + i, 1 + (i + 1) % ring]).collect();
        let r = render(&positions, &triangles, &k, &pose);
        for v in 12..50 {
            for u in 12..50 {
                let (du, dv) = (u as f32 - 31.0, v as f32 - 31.0);
                if du * du + dv * dv < 22.0 * 22.0 {
                    assert!((r.depth.get(u, v) - z).abs() < 1e-4, "crack at ({u},{v})");
                }
            }
        }
        // A nearer triangle over the fan wins the depth test.
        let mut positions2 = positions.clone();
        let base = positions2.len() as u32;
        positions2.extend([
            k.back_project(20.0, 20.0, 1.0),
            k.back_project(40.0, 20.0, 1.0),
            k.back_project(30.0, 40.0, 1.0),
        ]);
        let mut triangles2 = triangles.clone();
        triangles2.push([base, base + 2, base + 1]);
        let r = render(&positions2, &triangles2, &k, &pose);
        let at = 30 * 64 + 30;
        assert_eq!(r.triangle[at], ring);
        assert!((r.depth.data[at] - 1.0).abs() < 1e-5);
    }
}
