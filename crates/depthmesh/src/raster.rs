//! CPU z-buffer rasterizer: metric depth (and, unless only depth is asked
//! for, triangle ids) of a mesh seen from a pose.
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
//! * **Parallel over triangle chunks, then image bands.** A binning pass
//!   (parallel over triangle chunks) draws each small triangle at once into a
//!   per-thread layer of depth keys, and files the others (tall, near-clipped or
//!   far-reaching) under the horizontal bands they overlap; bands are then
//!   rasterized independently and the layers merged by `max`. Keys order by
//!   depth, then id (depth alone when no ids are asked for), so the result
//!   does not depend on the drawing order.
//!   Scratch buffers live in [`Rasterizer`] and are reused from frame to frame.
//! * **AVX2 where the CPU has it** (detected at run time; the crate is built
//!   for any x86-64): vertices are projected and small triangles drawn
//!   eight at a time, larger ones eight pixels of a row at a time, with the
//!   portable code's arithmetic operation for operation, so the image is
//!   the same to the bit (a test checks).

use crate::camera::{Intrinsics, Pose};
use crate::image::DepthImage;
use crate::mesh::Aabb;
use crate::worker_slots::lock_own;
use glam::Vec3;
use rayon::prelude::*;
use std::sync::{Mutex, PoisonError};

#[cfg(target_arch = "x86_64")]
mod avx2;

/// Triangle id of pixels that no triangle covers.
pub const NO_TRIANGLE: u32 = u32::MAX;

/// Rows per band of the parallel raster pass; triangles spanning at most
/// this many rows are drawn during binning instead.
const BAND_ROWS: usize = 16;
/// Triangles per chunk of the parallel binning pass.
const CHUNK_TRIANGLES: usize = 1 << 13;
/// Vertices per block of the vertex pass.
const VERTEX_BLOCK: usize = 1 << 12;
/// Sub-pixel precision of snapped vertices (bits).
const SUBPIXEL_BITS: u32 = 8;
const SUBPIXEL: f32 = (1 << SUBPIXEL_BITS) as f32;
/// How far outside the image (pixels) a polygon may reach before it is clipped
/// in screen space; keeps fixed-point products well inside `i64`.
const GUARD_BAND: f32 = 2048.0;

/// The result of a render: depth along the optical axis and, unless the
/// target is [`RenderTarget::depth_only`], the id of the triangle seen at
/// each pixel.
#[derive(Clone, Debug, Default)]
pub struct RenderTarget {
    /// Metric depth; 0 where nothing is seen.
    pub depth: DepthImage,
    /// Index of the visible triangle, or [`NO_TRIANGLE`]; empty for a
    /// [`RenderTarget::depth_only`] target.
    pub triangle: Vec<u32>,
    /// Whether only depth is wanted.
    depth_only: bool,
}

impl RenderTarget {
    /// A target for depth alone: the render keeps 4 bytes a pixel for the
    /// depth test instead of 8 with the triangle id, half the memory
    /// traffic of its hottest loop (the same depths, bit for bit).
    pub fn depth_only() -> Self {
        Self {
            depth_only: true,
            ..Self::default()
        }
    }

    /// Sizes the buffers for an image; their contents are left to the
    /// render, which writes every pixel.
    fn resize(&mut self, width: u32, height: u32) {
        let n = width as usize * height as usize;
        self.depth.width = width;
        self.depth.height = height;
        self.depth.data.resize(n, 0.0);
        self.triangle
            .resize(if self.depth_only { 0 } else { n }, NO_TRIANGLE);
    }
}

/// Depth of a mesh seen from a pose (a fresh rasterizer: for occasional use).
pub fn render_mesh_depth(mesh: &crate::Mesh, intrinsics: &Intrinsics, pose: &Pose) -> DepthImage {
    let mut target = RenderTarget::depth_only();
    Rasterizer::new().render(
        &mesh.positions,
        &mesh.triangles,
        intrinsics,
        pose,
        0.01,
        &mut target,
    );
    target.depth
}

/// A reusable rasterizer; keep one per view so its buffers are reused.
#[derive(Debug, Default)]
pub struct Rasterizer {
    /// Per vertex: pixel coordinates and inverse depth, or a non-positive
    /// inverse depth when the vertex is nearer than the near plane.
    screen_points: Vec<[f32; 3]>,
    /// Per vertex: its pixel coordinates snapped to fixed point, or
    /// [`OFF_GRID`] when it is behind the near plane or beyond the guard
    /// band; snapping once per vertex rather than per triangle corner.
    snapped: Vec<[i32; 2]>,
    /// The depth keys of renders with triangle ids.
    wide: Layers<u64>,
    /// The depth keys of depth-only renders.
    narrow: Layers<u32>,
    /// Ids of the triangles left to the band pass, per (chunk, band),
    /// flattened chunk-major.
    bins: Vec<Vec<u32>>,
    /// Per chunk of triangles: whether it may be in view.
    chunk_visible: Vec<bool>,
    /// Per block of vertices: whether a chunk in view uses it.
    vertex_block_needed: Vec<bool>,
    /// The code that projects the vertices and draws the triangles.
    kernel: Kernel,
}

/// Which code projects the vertices and draws the triangles; both give
/// the same bits.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
enum Kernel {
    /// AVX2 ([`avx2`]) where the CPU has it, else the portable code.
    #[default]
    Fastest,
    /// The portable code on any CPU: the reference for the vector path.
    #[cfg_attr(not(test), allow(dead_code))]
    Portable,
}

impl Kernel {
    /// Whether the vector path runs, for a render of `vertices` vertices.
    fn vector(self, vertices: usize) -> bool {
        #[cfg(target_arch = "x86_64")]
        return self == Kernel::Fastest && avx2::usable(vertices);
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = (self, vertices); // no vector path on other CPUs
            false
        }
    }
}

/// Per-pixel depth keys (see [`Key`]), one layer per worker thread: small
/// triangles are drawn into the layer of the thread that bins them, and the
/// layers are merged by `max` at the end (a key a pixel a thread: cheaper
/// than re-reading every small triangle per band).
#[derive(Debug, Default)]
struct Layers<K> {
    /// The layers, each behind a lock that only its thread takes.
    layers: Vec<Mutex<Vec<K>>>,
    /// Whether every layer holds only zero keys, as the merge leaves them.
    clear: bool,
}

impl<K: Key> Layers<K> {
    /// Makes the first `count` layers hold `pixels` zero keys. The merge
    /// leaves layers cleared, so this normally only checks sizes.
    fn prepare(&mut self, count: usize, pixels: usize) {
        if self.layers.len() < count {
            self.layers.resize_with(count, Default::default);
        }
        let clear = std::mem::take(&mut self.clear);
        for layer in &mut self.layers {
            let layer = layer.get_mut().unwrap_or_else(PoisonError::into_inner);
            if !clear || layer.len() != pixels {
                layer.clear();
                layer.resize(pixels, K::EMPTY);
            }
        }
    }
}

/// A pixel's depth-test key: the inverse depth's bits above, for renders
/// with ids, the complement of the triangle id. Positive floats order like
/// their bits, so the largest key is the nearest triangle and, among
/// equally near ones, the lowest id: the winner of drawing in id order with
/// a strict test, but independent of the drawing order, which lets threads
/// draw into layers merged by `max`. Non-positive (or NaN) inverse depths
/// get the key of an empty pixel's depth.
trait Key: Copy + Ord + Send + Sync + std::fmt::Debug {
    /// The key of no surface.
    const EMPTY: Self;
    /// Whether the key holds the triangle id.
    const IDS: bool;
    /// The key of inverse depth `w` on triangle `id`.
    fn new(w: f32, id: u32) -> Self;
    /// The inverse depth and triangle id of a key ([`NO_TRIANGLE`] when the
    /// key holds none).
    fn decode(self) -> (f32, u32);
    /// This kind's layers of a rasterizer's two.
    fn layers<'a>(wide: &'a mut Layers<u64>, narrow: &'a mut Layers<u32>) -> &'a mut Layers<Self>;
}

/// The bits of a positive inverse depth, else 0.
#[inline]
fn depth_bits(w: f32) -> u32 {
    if w > 0.0 {
        w.to_bits()
    } else {
        0
    }
}

impl Key for u64 {
    const EMPTY: Self = 0;
    const IDS: bool = true;
    #[inline]
    fn new(w: f32, id: u32) -> Self {
        (u64::from(depth_bits(w)) << 32) | u64::from(!id)
    }
    #[inline]
    fn decode(self) -> (f32, u32) {
        (f32::from_bits((self >> 32) as u32), !(self as u32))
    }
    fn layers<'a>(wide: &'a mut Layers<u64>, _: &'a mut Layers<u32>) -> &'a mut Layers<Self> {
        wide
    }
}

impl Key for u32 {
    const EMPTY: Self = 0;
    const IDS: bool = false;
    #[inline]
    fn new(w: f32, _: u32) -> Self {
        depth_bits(w)
    }
    #[inline]
    fn decode(self) -> (f32, u32) {
        (f32::from_bits(self), NO_TRIANGLE)
    }
    fn layers<'a>(_: &'a mut Layers<u64>, narrow: &'a mut Layers<u32>) -> &'a mut Layers<Self> {
        narrow
    }
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
    /// Whether AVX2 projects the vertices and draws the triangles (see [`Kernel`]).
    vector: bool,
}

impl View {
    /// Whether any part of a world-space box may be in the view frustum
    /// (`world_to_camera` maps world to camera coordinates); conservative.
    fn may_see(&self, world_to_camera: &Pose, b: &Aabb) -> bool {
        if b.is_empty() {
            return false;
        }
        let c = world_to_camera.transform_point(b.center());
        let h = 0.5 * b.extent();
        let r = world_to_camera.rotation;
        // Half extents of the box along the camera axes.
        let e = Vec3::new(
            r.row(0).abs().dot(h),
            r.row(1).abs().dot(h),
            r.row(2).abs().dot(h),
        );
        if c.z + e.z < self.near {
            return false;
        }
        // Side planes through the optical centre at the image borders (half
        // a pixel out): inside where n·p ≥ 0.
        let left = (-0.5 - self.cx) / self.fx;
        let right = (self.width as f32 - 0.5 - self.cx) / self.fx;
        let top = (-0.5 - self.cy) / self.fy;
        let bottom = (self.height as f32 - 0.5 - self.cy) / self.fy;
        let planes = [
            Vec3::new(1.0, 0.0, -left),
            Vec3::new(-1.0, 0.0, right),
            Vec3::new(0.0, 1.0, -top),
            Vec3::new(0.0, -1.0, bottom),
        ];
        planes.iter().all(|n| n.dot(c) + n.abs().dot(e) >= 0.0)
    }

    #[inline]
    fn project(&self, p: Vec3) -> (f32, f32) {
        let inv = 1.0 / p.z;
        (self.fx * p.x * inv + self.cx, self.fy * p.y * inv + self.cy)
    }
}

/// The vertices of one render, in the forms the passes need.
#[derive(Clone, Copy)]
struct Vertices<'a> {
    view: View,
    world_to_camera: Pose,
    positions: &'a [Vec3],
    screen: &'a [[f32; 3]],
    snapped: &'a [[i32; 2]],
}

impl Vertices<'_> {
    /// The snapped corners of a triangle, unless one of them is off the grid.
    #[inline]
    fn on_grid(&self, t: &[u32; 3]) -> Option<[[i64; 2]; 3]> {
        let q = t.map(|v| self.snapped[v as usize]);
        q.iter()
            .all(|p| *p != OFF_GRID)
            .then(|| q.map(|p| p.map(i64::from)))
    }

    /// The camera-space corners of a triangle.
    fn camera(&self, t: &[u32; 3]) -> [Vec3; 3] {
        t.map(|v| {
            self.world_to_camera
                .transform_point(self.positions[v as usize])
        })
    }

    /// The binning pass for a chunk of triangles (ids from `first`): draws
    /// the small ones into `keys` (the whole image), eight at a time with
    /// AVX2, and files the others under the bands they overlap.
    fn draw_or_bin_chunk<K: Key>(
        &self,
        tris: &[[u32; 3]],
        first: u32,
        bins: &mut [Vec<u32>],
        keys: &mut [K],
    ) {
        let mut done = 0;
        #[cfg(target_arch = "x86_64")]
        if self.view.vector {
            let groups = tris.chunks_exact(8);
            done = tris.len() - groups.remainder().len();
            for (g, group) in groups.enumerate() {
                let at = 8 * g;
                let group = group.try_into().expect("eight triangles");
                // SAFETY: `vector` is only set when `avx2::usable` says so
                // for these vertices.
                let mut left = unsafe { avx2::draw_small(self, group, first + at as u32, keys) };
                while left != 0 {
                    let lane = left.trailing_zeros() as usize;
                    left &= left - 1;
                    self.draw_or_bin(&tris[at + lane], first + (at + lane) as u32, bins, keys);
                }
            }
        }
        for (i, t) in tris.iter().enumerate().skip(done) {
            self.draw_or_bin(t, first + i as u32, bins, keys);
        }
    }

    /// The binning pass for one triangle: drawn into `keys` (the whole
    /// image) if small, else filed under the bands it overlaps.
    #[inline]
    fn draw_or_bin<K: Key>(&self, t: &[u32; 3], id: u32, bins: &mut [Vec<u32>], keys: &mut [K]) {
        if is_hole(t) {
            return;
        }
        let screen = t.map(|v| self.screen[v as usize]);
        if let Some(q) = self.on_grid(t) {
            if row_count(&q) <= BAND_ROWS as i64 {
                let plane = || screen_plane(&screen);
                fill_triangle(&self.view, q, plane, id, 0, self.view.height - 1, keys);
                return;
            }
        }
        let span = if in_front(&screen) {
            pixel_span(&self.view, &screen)
        } else {
            clipped_row_span(&self.view, &self.camera(t))
        };
        if let Some((r0, r1)) = span {
            for bin in &mut bins[r0 / BAND_ROWS..=r1 / BAND_ROWS] {
                bin.push(id);
            }
        }
    }

    /// Draws a triangle into rows `row0..=row1` (`keys` holds those rows).
    fn draw<K: Key>(&self, t: &[u32; 3], id: u32, row0: usize, row1: usize, keys: &mut [K]) {
        let screen = t.map(|v| self.screen[v as usize]);
        if let Some(q) = self.on_grid(t) {
            // The plane is fitted lazily: most small triangles cover no pixel centre.
            fill_triangle(
                &self.view,
                q,
                || screen_plane(&screen),
                id,
                row0,
                row1,
                keys,
            );
        } else if in_front(&screen) {
            draw_guarded(&self.view, &screen, id, row0, row1, keys);
        } else {
            draw_clipped(&self.view, &self.camera(t), id, row0, row1, keys);
        }
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

    /// Per vertex of the last render: pixel coordinates `u, v` and inverse
    /// depth `1/z` (non-positive for vertices nearer than the near plane), so
    /// that per-triangle passes after a render need not project them again.
    pub fn screen_points(&self) -> &[[f32; 3]] {
        &self.screen_points
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
        let geometry = Geometry {
            positions,
            triangles,
            chunks: None,
        };
        self.render_visiting(geometry, intrinsics, pose, near, target, None, |_, _| false);
    }

    /// [`Rasterizer::render`], skipping the chunks of triangles whose boxes
    /// (when `geometry` has them) lie outside the view, and calling `visit`
    /// on every triangle of the chunks in view with its projected corners
    /// (see [`Rasterizer::screen_points`]) and its byte of `state`, while
    /// those corners are at hand. Returns whether any visit returned true.
    #[allow(clippy::too_many_arguments)]
    pub fn render_visiting<F>(
        &mut self,
        geometry: Geometry,
        intrinsics: &Intrinsics,
        pose: &Pose,
        near: f32,
        target: &mut RenderTarget,
        state: Option<&mut [u8]>,
        visit: F,
    ) -> bool
    where
        F: Fn(&mut u8, &[[f32; 3]; 3]) -> bool + Sync,
    {
        let view = View {
            width: intrinsics.width as usize,
            height: intrinsics.height as usize,
            fx: intrinsics.fx,
            fy: intrinsics.fy,
            cx: intrinsics.cx,
            cy: intrinsics.cy,
            near: near.max(1e-6),
            vector: self.kernel.vector(geometry.positions.len()),
        };
        target.resize(intrinsics.width, intrinsics.height);
        if view.width == 0 || view.height == 0 {
            return false;
        }
        let world_to_camera = pose.inverse();
        if target.depth_only {
            self.render_keys::<u32, F>(geometry, view, world_to_camera, target, state, visit)
        } else {
            self.render_keys::<u64, F>(geometry, view, world_to_camera, target, state, visit)
        }
    }

    /// The passes of [`Rasterizer::render_visiting`] into a target sized
    /// for `view`, with depth keys `K`.
    fn render_keys<K: Key, F>(
        &mut self,
        geometry: Geometry,
        view: View,
        world_to_camera: Pose,
        target: &mut RenderTarget,
        state: Option<&mut [u8]>,
        visit: F,
    ) -> bool
    where
        F: Fn(&mut u8, &[[f32; 3]; 3]) -> bool + Sync,
    {
        let Geometry {
            positions,
            triangles,
            chunks: bounds,
        } = geometry;
        let chunks = triangles.len().div_ceil(CHUNK_TRIANGLES);

        // Which chunks can be seen, and so which blocks of vertices are needed.
        self.chunk_visible.clear();
        self.vertex_block_needed.clear();
        let vertex_blocks = positions.len().div_ceil(VERTEX_BLOCK);
        match bounds.filter(|b| b.boxes.len() == chunks && b.counted == triangles.len()) {
            Some(b) => {
                self.vertex_block_needed.resize(vertex_blocks, false);
                for (bx, range) in b.boxes.iter().zip(&b.vertex_ranges) {
                    // A chunk of holes only uses no vertex (range empty).
                    let visible = range.0 <= range.1 && view.may_see(&world_to_camera, bx);
                    self.chunk_visible.push(visible);
                    if visible {
                        let (lo, hi) = (
                            range.0 as usize / VERTEX_BLOCK,
                            range.1 as usize / VERTEX_BLOCK,
                        );
                        self.vertex_block_needed[lo..=hi.min(vertex_blocks - 1)].fill(true);
                    }
                }
            }
            None => {
                self.chunk_visible.resize(chunks, true);
                self.vertex_block_needed.resize(vertex_blocks, true);
            }
        }

        // Camera-space points are not kept: only the few triangles that
        // cross the near plane need them, and they recompute them.
        self.screen_points.resize(positions.len(), [0.0; 3]);
        self.snapped.resize(positions.len(), OFF_GRID);
        self.screen_points
            .par_chunks_mut(VERTEX_BLOCK)
            .zip(self.snapped.par_chunks_mut(VERTEX_BLOCK))
            .zip(positions.par_chunks(VERTEX_BLOCK))
            .zip(self.vertex_block_needed.par_iter())
            .filter(|(_, needed)| **needed)
            .for_each(|(((screen, snapped), inp), _)| {
                let mut done = 0;
                #[cfg(target_arch = "x86_64")]
                if view.vector {
                    // SAFETY: `vector` is only set when the CPU has AVX2.
                    done = unsafe { avx2::project(&view, &world_to_camera, inp, screen, snapped) };
                }
                for ((s, q), &p) in screen.iter_mut().zip(snapped).zip(inp).skip(done) {
                    (*s, *q) = project_vertex(&view, &world_to_camera, p);
                }
            });

        let visible_chunks = self.chunk_visible.iter().filter(|&&v| v).count();
        let layer_count = rayon::current_num_threads().min(visible_chunks).max(1);
        let key_layers = K::layers(&mut self.wide, &mut self.narrow);
        key_layers.prepare(layer_count, view.width * view.height);
        let bands = view.height.div_ceil(BAND_ROWS);
        if self.bins.len() < chunks * bands {
            self.bins.resize_with(chunks * bands, Vec::new);
        }
        let mut states: Vec<Option<&mut [u8]>> = match state {
            Some(s) => s.chunks_mut(CHUNK_TRIANGLES).map(Some).collect(),
            None => (0..chunks).map(|_| None).collect(),
        };
        states.resize_with(chunks, || None);
        let vertices = Vertices {
            view,
            world_to_camera,
            positions,
            screen: &self.screen_points,
            snapped: &self.snapped,
        };
        let chunk_visible = &self.chunk_visible;
        let layers = &key_layers.layers[..layer_count];
        // Binning pass: small triangles (nearly all of a mesh made from depth
        // images) are drawn at once, while their corners are at hand; the
        // others are filed under the bands they overlap.
        let any = self.bins[..chunks * bands]
            .par_chunks_mut(bands)
            .zip(triangles.par_chunks(CHUNK_TRIANGLES))
            .zip(states.par_iter_mut())
            .enumerate()
            .map(|(chunk, ((bins, tris), state))| {
                bins.iter_mut().for_each(Vec::clear);
                if !chunk_visible[chunk] {
                    return false;
                }
                // Each worker thread has a layer of its own (once per chunk).
                let mut keys = lock_own(layers);
                let first = (chunk * CHUNK_TRIANGLES) as u32;
                vertices.draw_or_bin_chunk(tris, first, bins, &mut keys);
                state
                    .as_deref_mut()
                    .is_some_and(|state| visit_chunk(vertices.screen, tris, state, &visit))
            })
            .reduce(|| false, |a, b| a || b);

        // Band pass: the binned triangles, into the first layer, band by band.
        let bins = &self.bins[..chunks * bands];
        let (base, others) = key_layers.layers[..layer_count]
            .split_first_mut()
            .expect("at least one layer");
        let base = base.get_mut().unwrap_or_else(PoisonError::into_inner);
        let rows = BAND_ROWS * view.width;
        base.par_chunks_mut(rows)
            .enumerate()
            .for_each(|(band, keys)| {
                let row0 = band * BAND_ROWS;
                let row1 = (row0 + BAND_ROWS).min(view.height) - 1;
                for chunk in 0..chunks {
                    for &t in &bins[chunk * bands + band] {
                        vertices.draw(&triangles[t as usize], t, row0, row1, keys);
                    }
                }
            });

        // Merge the layers into the first, clearing them for the next render,
        // then decode the keys.
        for layer in others {
            let layer = layer.get_mut().unwrap_or_else(PoisonError::into_inner);
            base.par_chunks_mut(rows)
                .zip(layer.par_chunks_mut(rows))
                .for_each(|(into, from)| {
                    for (a, b) in into.iter_mut().zip(from) {
                        *a = (*a).max(*b);
                        *b = K::EMPTY;
                    }
                });
        }
        let decode = |k: &mut K| {
            let (w, id) = std::mem::replace(k, K::EMPTY).decode();
            if w > 0.0 {
                (1.0 / w, id)
            } else {
                (0.0, NO_TRIANGLE)
            }
        };
        let depths = target
            .depth
            .data
            .par_chunks_mut(rows)
            .zip(base.par_chunks_mut(rows));
        if !K::IDS {
            depths.for_each(|(depth, keys)| {
                for (d, k) in depth.iter_mut().zip(keys) {
                    *d = decode(k).0;
                }
            });
        } else {
            depths
                .zip(target.triangle.par_chunks_mut(rows))
                .for_each(|((depth, keys), ids)| {
                    for ((d, t), k) in depth.iter_mut().zip(ids).zip(keys) {
                        (*d, *t) = decode(k);
                    }
                });
        }
        key_layers.clear = true;
        any
    }

    /// After a render of `triangles`, calls `visit` on every triangle of the
    /// chunks that render had in view, with its projected corners (see
    /// [`Rasterizer::screen_points`]) and its byte of `state`: a second
    /// per-triangle pass for evidence that needs the finished image.
    /// Returns whether any visit returned true; visits nothing if
    /// `triangles` is not what was rendered last.
    pub fn visit_in_view<F>(&self, triangles: &[[u32; 3]], state: &mut [u8], visit: F) -> bool
    where
        F: Fn(&mut u8, &[[f32; 3]; 3]) -> bool + Sync,
    {
        let chunks = triangles.len().div_ceil(CHUNK_TRIANGLES);
        if self.chunk_visible.len() != chunks || state.len() != triangles.len() {
            return false;
        }
        let screen = &self.screen_points;
        state
            .par_chunks_mut(CHUNK_TRIANGLES)
            .zip(triangles.par_chunks(CHUNK_TRIANGLES))
            .zip(self.chunk_visible.par_iter())
            .filter(|(_, &visible)| visible)
            .map(|((state, tris), _)| visit_chunk(screen, tris, state, &visit))
            .reduce(|| false, |a, b| a || b)
    }
}

/// A vertex's pixel coordinates and inverse depth, and those coordinates
/// snapped (see [`Rasterizer::snapped`]); `[0, 0, −1]` and [`OFF_GRID`]
/// when it is nearer than the near plane.
#[inline]
fn project_vertex(view: &View, world_to_camera: &Pose, p: Vec3) -> ([f32; 3], [i32; 2]) {
    let c = world_to_camera.transform_point(p);
    if c.z >= view.near {
        let (u, v) = view.project(c);
        let q = if within_guard_band(u, v) {
            // Within ±2^21 (see `snap`), so no bits are lost.
            snap(&[u, v]).map(|x| x as i32)
        } else {
            OFF_GRID
        };
        ([u, v, 1.0 / c.z], q)
    } else {
        ([0.0, 0.0, -1.0], OFF_GRID)
    }
}

/// Calls `visit` on every triangle of a chunk that is not a hole, with its
/// byte of `state` and its projected corners; returns whether any visit
/// returned true.
fn visit_chunk<F>(screen: &[[f32; 3]], tris: &[[u32; 3]], state: &mut [u8], visit: &F) -> bool
where
    F: Fn(&mut u8, &[[f32; 3]; 3]) -> bool,
{
    let mut any = false;
    for (s, t) in state.iter_mut().zip(tris).filter(|(_, t)| !is_hole(t)) {
        any |= visit(s, &t.map(|v| screen[v as usize]));
    }
    any
}

/// Whether a triangle is a hole: all three corners one vertex. A mesh that
/// drops triangles often (MABDI's removal) leaves holes in their slots and
/// closes them up now and then, rather than moving every later triangle at
/// each removal; a hole covers nothing, is not visited and bounds nothing.
#[inline]
pub fn is_hole(t: &[u32; 3]) -> bool {
    t[0] == t[1] && t[1] == t[2]
}

/// What to render: vertex positions, triangles and optionally the boxes of
/// the triangle chunks for culling.
#[derive(Clone, Copy, Debug)]
pub struct Geometry<'a> {
    /// Vertex positions in world coordinates.
    pub positions: &'a [Vec3],
    /// Triangles as vertex index triples.
    pub triangles: &'a [[u32; 3]],
    /// Boxes of the triangle chunks; ignored unless up to date with `triangles`.
    pub chunks: Option<&'a ChunkBounds>,
}

/// Bounding boxes of consecutive runs of triangles, kept up to date by the
/// owner of a growing mesh so that a render skips the runs outside the view
/// (a global mesh grows by surfaces seen from one pose at a time, so its runs
/// are compact in space).
#[derive(Clone, Debug, Default)]
pub struct ChunkBounds {
    boxes: Vec<Aabb>,
    /// Smallest and largest vertex index used by each chunk.
    vertex_ranges: Vec<(u32, u32)>,
    /// Triangles accounted for.
    counted: usize,
}

impl ChunkBounds {
    /// Accounts for triangles appended since the last call (only those, and
    /// the rest of the last chunk, are read; chunks in parallel).
    pub fn extend(&mut self, positions: &[Vec3], triangles: &[[u32; 3]]) {
        if self.counted > triangles.len() {
            self.clear();
        }
        let from = self.counted / CHUNK_TRIANGLES;
        self.boxes.truncate(from);
        self.vertex_ranges.truncate(from);
        let fresh: Vec<(Aabb, (u32, u32))> = triangles[from * CHUNK_TRIANGLES..]
            .par_chunks(CHUNK_TRIANGLES)
            .map(|tris| {
                let mut b = Aabb::EMPTY;
                let mut range = (u32::MAX, 0);
                for &v in tris.iter().filter(|t| !is_hole(t)).flatten() {
                    b.include(positions[v as usize]);
                    range = (range.0.min(v), range.1.max(v));
                }
                (b, range)
            })
            .collect();
        for (b, range) in fresh {
            self.boxes.push(b);
            self.vertex_ranges.push(range);
        }
        self.counted = triangles.len();
    }

    /// Forgets the boxes of the chunks from the one holding triangle `first`
    /// on, for when the triangles from `first` on were replaced.
    pub fn truncate(&mut self, first: usize) {
        let chunk = (first / CHUNK_TRIANGLES).min(self.boxes.len());
        self.boxes.truncate(chunk);
        self.vertex_ranges.truncate(chunk);
        self.counted = self.counted.min(chunk * CHUNK_TRIANGLES);
    }

    /// Forgets all boxes, for when triangles were removed or reordered.
    pub fn clear(&mut self) {
        self.boxes.clear();
        self.vertex_ranges.clear();
        self.counted = 0;
    }
}

/// `floor(x)` within 1/512 for pixel coordinates, fast: the offset makes the
/// value positive so truncation is flooring, with no libm call and no
/// int-to-float round trip (hot loops run on baseline x86-64). Callers keep
/// a margin larger than the error.
#[inline]
fn floor_i(x: f32) -> i64 {
    const OFFSET: f32 = 32768.0;
    ((x.clamp(-30000.0, 30000.0) + OFFSET) as i32 - OFFSET as i32) as i64
}

/// `ceil(x)`, to the same precision as [`floor_i`].
#[inline]
fn ceil_i(x: f32) -> i64 {
    -floor_i(-x)
}

/// Rows (inclusive) of the pixel centres inside the screen-space box
/// `lo..hi`, or `None` when it holds none. A conservative float test with a
/// small margin against the snapping: exact coverage is decided later.
#[inline]
fn span_of(view: &View, lo: [f32; 2], hi: [f32; 2]) -> Option<(usize, usize)> {
    let u0 = ceil_i(lo[0] - 0.01).max(0);
    let u1 = floor_i(hi[0] + 0.01).min(view.width as i64 - 1);
    let v0 = ceil_i(lo[1] - 0.01).max(0);
    let v1 = floor_i(hi[1] + 0.01).min(view.height as i64 - 1);
    (u0 <= u1 && v0 <= v1).then_some((v0 as usize, v1 as usize))
}

/// [`span_of`] a triangle whose vertices are all in front of the near plane.
#[inline]
fn pixel_span(view: &View, s: &[[f32; 3]; 3]) -> Option<(usize, usize)> {
    let lo = [
        s[0][0].min(s[1][0]).min(s[2][0]),
        s[0][1].min(s[1][1]).min(s[2][1]),
    ];
    let hi = [
        s[0][0].max(s[1][0]).max(s[2][0]),
        s[0][1].max(s[1][1]).max(s[2][1]),
    ];
    span_of(view, lo, hi)
}

/// [`span_of`] a triangle that crosses the near plane, after clipping it.
fn clipped_row_span(view: &View, c: &[Vec3; 3]) -> Option<(usize, usize)> {
    let poly = clip_near(view, c)?;
    let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
    for p in &poly.p[..poly.n] {
        lo = [lo[0].min(p[0]), lo[1].min(p[1])];
        hi = [hi[0].max(p[0]), hi[1].max(p[1])];
    }
    span_of(view, lo, hi)
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

/// Whether all corners of a projected triangle are in front of the near plane.
#[inline]
fn in_front(s: &[[f32; 3]; 3]) -> bool {
    s[0][2] > 0.0 && s[1][2] > 0.0 && s[2][2] > 0.0
}

/// Whether a projected point is near enough to the image that triangles
/// with all corners like it are snapped and drawn without clipping to the
/// guard band.
#[inline]
fn within_guard_band(u: f32, v: f32) -> bool {
    u.abs() <= GUARD_BAND * 2.0 && v.abs() <= GUARD_BAND * 2.0
}

/// The inverse-depth plane `w = a·u + b·v + k` of a projected triangle
/// (inverse depth is affine in pixel coordinates).
#[inline]
fn screen_plane(s: &[[f32; 3]; 3]) -> [f32; 3] {
    let (du1, dv1, dw1) = (s[1][0] - s[0][0], s[1][1] - s[0][1], s[1][2] - s[0][2]);
    let (du2, dv2, dw2) = (s[2][0] - s[0][0], s[2][1] - s[0][1], s[2][2] - s[0][2]);
    let area = du1 * dv2 - du2 * dv1;
    let (a, b) = if area != 0.0 {
        (
            (dw1 * dv2 - dw2 * dv1) / area,
            (du1 * dw2 - du2 * dw1) / area,
        )
    } else {
        (0.0, 0.0)
    };
    [a, b, s[0][2] - a * s[0][0] - b * s[0][1]]
}

/// Rasterizes a triangle whose vertices are all in front of the near plane
/// but not all within the guard band, clipping it to the band.
fn draw_guarded<K: Key>(
    view: &View,
    s: &[[f32; 3]; 3],
    id: u32,
    row0: usize,
    row1: usize,
    keys: &mut [K],
) {
    let mut poly = Polygon {
        n: 3,
        p: [[0.0; 2]; 8],
    };
    for (dst, p) in poly.p.iter_mut().zip(s) {
        *dst = [p[0], p[1]];
    }
    poly = clip_guard(view, &poly);
    if poly.n >= 3 {
        fill_polygon(view, &poly, screen_plane(s), id, row0, row1, keys);
    }
}

/// Rasterizes a triangle that crosses the near plane (camera-space corners).
fn draw_clipped<K: Key>(
    view: &View,
    c: &[Vec3; 3],
    id: u32,
    row0: usize,
    row1: usize,
    keys: &mut [K],
) {
    // The clipped corners' depths are all `near`, so the plane comes from the
    // camera-space triangle: n·X = d gives 1/z = (n·ray(u, v)) / d.
    let n = (c[1] - c[0]).cross(c[2] - c[0]);
    let d = n.dot(c[0]);
    if d == 0.0 || !d.is_finite() {
        return; // seen edge-on (or degenerate): covers no area
    }
    let a = n.x / (view.fx * d);
    let b = n.y / (view.fy * d);
    let k = (n.z - n.x * view.cx / view.fx - n.y * view.cy / view.fy) / d;
    let Some(mut poly) = clip_near(view, c) else {
        return;
    };
    if poly.p[..poly.n]
        .iter()
        .any(|p| p[0].abs() > GUARD_BAND * 2.0 || p[1].abs() > GUARD_BAND * 2.0)
    {
        poly = clip_guard(view, &poly);
        if poly.n < 3 {
            return;
        }
    }
    fill_polygon(view, &poly, [a, b, k], id, row0, row1, keys);
}

/// Fills a convex polygon with the inverse-depth plane `w = a·u + b·v + k`,
/// as a fan of triangles. Snapping happens once per vertex, so the fan's
/// inner edges are shared exactly and the tie rule covers them once.
#[allow(clippy::too_many_arguments)]
#[inline]
fn fill_polygon<K: Key>(
    view: &View,
    poly: &Polygon,
    plane: [f32; 3],
    id: u32,
    row0: usize,
    row1: usize,
    keys: &mut [K],
) {
    let first = snap(&poly.p[0]);
    let mut prev = snap(&poly.p[1]);
    for p in &poly.p[2..poly.n] {
        let next = snap(p);
        fill_triangle(view, [first, prev, next], || plane, id, row0, row1, keys);
        prev = next;
    }
}

/// How many rows of pixel centres the box of a snapped triangle spans (not
/// clipped to the image; zero or less when it spans none).
#[inline]
fn row_count(q: &[[i64; 2]; 3]) -> i64 {
    let y0 = q[0][1].min(q[1][1]).min(q[2][1]);
    let y1 = q[0][1].max(q[1][1]).max(q[2][1]);
    let one = 1i64 << SUBPIXEL_BITS;
    (y1 >> SUBPIXEL_BITS) - ((y0 + one - 1) >> SUBPIXEL_BITS) + 1
}

/// [`Rasterizer::snapped`] of a vertex that is not on the fixed-point grid.
const OFF_GRID: [i32; 2] = [i32::MIN; 2];

/// A vertex snapped to fixed point (about 1/256 pixel). Any deterministic
/// rounding keeps coverage exact, since shared vertices snap alike; this one
/// is fast and holds over the guard band (|x| ≤ 2^21 / 256 pixels).
#[inline]
fn snap(p: &[f32; 2]) -> [i64; 2] {
    const OFFSET: f32 = (1 << 21) as f32;
    let one = |x: f32| ((x * SUBPIXEL).clamp(-OFFSET, OFFSET) + OFFSET) as i64 - OFFSET as i64;
    [one(p[0]), one(p[1])]
}

/// Fills a triangle with vertices in fixed point (1/256 pixel); `plane`
/// gives the inverse-depth plane when a pixel turns out to be covered.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn fill_triangle<K: Key>(
    view: &View,
    q: [[i64; 2]; 3],
    plane: impl Fn() -> [f32; 3],
    id: u32,
    row0: usize,
    row1: usize,
    keys: &mut [K],
) {
    let x0 = q[0][0].min(q[1][0]).min(q[2][0]);
    let x1 = q[0][0].max(q[1][0]).max(q[2][0]);
    let y0 = q[0][1].min(q[1][1]).min(q[2][1]);
    let y1 = q[0][1].max(q[1][1]).max(q[2][1]);
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
    // a clockwise triangle is walked backwards. Walking an edge backwards
    // negates its edge function exactly, so that is done by a sign rather
    // than a branch (orientations come as good as at random).
    let area =
        (q[1][0] - q[0][0]) * (q[2][1] - q[0][1]) - (q[2][0] - q[0][0]) * (q[1][1] - q[0][1]);
    if area == 0 {
        return;
    }
    let sign = area.signum();
    // Edge i: E(p) = (r − s) × (p − s), ≥ 0 inside.
    let mut e_row = [0i64; 3];
    let mut step_x = [0i64; 3];
    let mut step_y = [0i64; 3];
    let start = [px0 << SUBPIXEL_BITS, py0 << SUBPIXEL_BITS];
    for i in 0..3 {
        let (s, r) = (q[i], q[(i + 1) % 3]);
        let (dx, dy) = (sign * (r[0] - s[0]), sign * (r[1] - s[1]));
        // Tie rule: a pixel centre exactly on an edge belongs to one side only.
        // The rule flips when the edge is walked the other way, which is how
        // the neighbouring triangle walks a shared edge.
        let bias = if dy < 0 || (dy == 0 && dx > 0) { 0 } else { -1 };
        e_row[i] = dx * (start[1] - s[1]) - dy * (start[0] - s[0]) + bias;
        step_x[i] = -dy * one;
        step_y[i] = dx * one;
    }
    if px0 == px1 && py0 == py1 {
        // The common case of a triangle around one pixel centre: one test.
        if (e_row[0] | e_row[1] | e_row[2]) >= 0 {
            let [a, b, k] = plane();
            // Summed in the order of the loop below, so a pixel's depth does
            // not depend on which path drew it (clipping to a band can turn
            // a larger triangle into a one-pixel one).
            let w = a * px0 as f32 + (b * py0 as f32 + k);
            let at = (py0 as usize - row0) * view.width + px0 as usize;
            keys[at] = keys[at].max(K::new(w, id));
        }
        return;
    }
    let [a, b, k] = plane();
    #[cfg(target_arch = "x86_64")]
    if view.vector && avx2::fits_rows(x1 - x0, y1 - y0) {
        let edges = avx2::Edges {
            e: e_row.map(|e| e as i32),
            step_x: step_x.map(|e| e as i32),
            step_y: step_y.map(|e| e as i32),
        };
        let rows = (py0 as usize - row0)..=(py1 as usize - row0);
        let cols = px0 as usize..=px1 as usize;
        let target = avx2::Target {
            keys,
            width: view.width,
            row0,
        };
        // SAFETY: `vector` is only set when the CPU has AVX2.
        unsafe { avx2::fill_rows(&edges, [a, b, k], id, rows, cols, target) };
        return;
    }
    for py in py0..=py1 {
        let mut e = e_row;
        let row = (py as usize - row0) * view.width;
        let wy = b * py as f32 + k;
        for px in px0..=px1 {
            if (e[0] | e[1] | e[2]) >= 0 {
                let w = a * px as f32 + wy;
                let at = row + px as usize;
                keys[at] = keys[at].max(K::new(w, id));
            }
            e[0] += step_x[0];
            e[1] += step_x[1];
            e[2] += step_x[2];
        }
        e_row[0] += step_y[0];
        e_row[1] += step_y[1];
        e_row[2] += step_y[2];
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

    /// A grid mesh of a tilted plane made like MABDI's: vertices on the pixel
    /// centres of a `w × h` image seen from `pose`, two triangles per quad.
    fn depth_image_grid(
        k: &Intrinsics,
        pose: &Pose,
        n: Vec3,
        d: f32,
    ) -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let (w, h) = (k.width, k.height);
        let mut positions = Vec::new();
        for v in 0..h {
            for u in 0..w {
                let z = plane_depth(k, pose, n, d, u as f32, v as f32).expect("plane in view");
                positions.push(pose.transform_point(k.back_project(u as f32, v as f32, z)));
            }
        }
        let mut triangles = Vec::new();
        for v in 0..h - 1 {
            for u in 0..w - 1 {
                let i = v * w + u;
                triangles.push([i, i + 1, i + w]);
                triangles.push([i + 1, i + w + 1, i + w]);
            }
        }
        (positions, triangles)
    }

    #[test]
    fn pixel_sized_triangles_leave_no_cracks_and_ties_go_to_the_lowest_id() {
        // Pixel-sized triangles in several chunks (drawn while binning, into
        // per-thread layers), seen from the pose they were made from and
        // from a nearby one.
        let k = Intrinsics::from_vertical_fov(160, 120, 60.0);
        let made_from = Pose::look_at(Vec3::new(0.2, 0.4, -2.0), Vec3::ZERO, Vec3::Y);
        let n = Vec3::new(0.1, 0.3, -1.0).normalize();
        let (mut positions, mut triangles) = depth_image_grid(&k, &made_from, n, 0.1);
        assert!(triangles.len() > 4 * CHUNK_TRIANGLES);
        // A second copy of the surface after the first: equally near
        // everywhere, so the first copy's (lower) ids must win every pixel.
        let copy = triangles.len() as u32;
        let offset = positions.len() as u32;
        positions.extend_from_slice(&positions.clone());
        triangles.extend(triangles.clone().iter().map(|t| t.map(|v| v + offset)));
        let moved = Pose::look_at(
            Vec3::new(0.25, 0.35, -1.9),
            Vec3::new(0.0, 0.02, 0.0),
            Vec3::Y,
        );
        for pose in [made_from, moved] {
            let r = render(&positions, &triangles, &k, &pose);
            let mut checked = 0;
            for v in 0..k.height {
                for u in 0..k.width {
                    let z = plane_depth(&k, &pose, n, 0.1, u as f32, v as f32).unwrap();
                    let world = pose.transform_point(k.back_project(u as f32, v as f32, z));
                    // Only pixels well inside the grid's image.
                    let Some(p) = k.project(made_from.inverse().transform_point(world)) else {
                        continue;
                    };
                    if !(1.0..k.width as f32 - 2.0).contains(&p.x)
                        || !(1.0..k.height as f32 - 2.0).contains(&p.y)
                    {
                        continue;
                    }
                    let at = (v * k.width + u) as usize;
                    assert!(r.triangle[at] < copy, "crack or copy at ({u},{v})");
                    assert!((r.depth.data[at] - z).abs() < 1e-4, "({u},{v})");
                    checked += 1;
                }
            }
            assert!(checked > 10_000, "{checked}");
        }
    }

    #[test]
    fn the_vector_path_draws_bit_for_bit_what_the_portable_one_does() {
        use rand::rngs::SmallRng;
        use rand::{Rng, SeedableRng};
        let k = Intrinsics {
            width: 160,
            height: 120,
            fx: 128.0,
            fy: 128.0,
            cx: 80.0,
            cy: 60.0,
        };
        let mut rng = SmallRng::seed_from_u64(7);
        // Pixel-sized grid triangles and a soup of every size the passes
        // meet: slivers, a few pixels wide, large, off the image, through
        // the near plane, behind the camera, degenerate, and holes.
        let made_from = Pose::look_at(Vec3::new(0.2, 0.4, -2.0), Vec3::ZERO, Vec3::Y);
        let n = Vec3::new(0.1, 0.3, -1.0).normalize();
        let (mut soup, mut soup_triangles) = depth_image_grid(&k, &made_from, n, 0.1);
        for _ in 0..30_000 {
            let centre = Vec3::new(
                rng.gen_range(-3.0..3.0),
                rng.gen_range(-2.5..2.5),
                rng.gen_range(-1.0..6.0),
            );
            let size = 10f32.powf(rng.gen_range(-3.0..0.7));
            let base = soup.len() as u32;
            for _ in 0..3 {
                let d = Vec3::new(
                    rng.gen_range(-1.0..1.0),
                    rng.gen_range(-1.0..1.0),
                    rng.gen_range(-1.0..1.0),
                );
                soup.push(centre + size * d);
            }
            soup_triangles.push(match rng.gen_range(0..40) {
                0 => [base; 3],
                1 => [base, base + 1, base + 1],
                _ => [base, base + 1, base + 2],
            });
        }
        // Small triangles with corners exactly on pixel centres from the
        // identity pose (with these intrinsics): their edges meet pixel
        // centres exactly, so the tie rule decides.
        let (mut ties, mut tie_triangles) = (Vec::new(), Vec::new());
        for _ in 0..20_000 {
            let z = [1.0, 2.0, 4.0][rng.gen_range(0..3)];
            let (u, v) = (rng.gen_range(-2..162), rng.gen_range(-2..122));
            let base = ties.len() as u32;
            for _ in 0..3 {
                let (du, dv) = (rng.gen_range(-3..=3), rng.gen_range(-3..=3));
                let pixel = [u + du - 80, v + dv - 60].map(|p| p as f32 * z / 128.0);
                ties.push(Vec3::new(pixel[0], pixel[1], z));
            }
            tie_triangles.push([base, base + 1, base + 2]);
        }
        let moved = Pose::look_at(
            Vec3::new(0.25, 0.35, -1.9),
            Vec3::new(0.0, 0.02, 0.0),
            Vec3::Y,
        );
        let views = [
            (&soup, &soup_triangles, made_from),
            (&soup, &soup_triangles, moved),
            (&ties, &tie_triangles, Pose::IDENTITY),
        ];
        for (positions, triangles, pose) in views {
            let mut fastest = Rasterizer::new();
            let mut portable = Rasterizer {
                kernel: Kernel::Portable,
                ..Rasterizer::new()
            };
            let (mut a, mut b) = (RenderTarget::default(), RenderTarget::default());
            fastest.render(positions, triangles, &k, &pose, 0.05, &mut a);
            portable.render(positions, triangles, &k, &pose, 0.05, &mut b);
            let bits =
                |r: &RenderTarget| r.depth.data.iter().map(|d| d.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&a), bits(&b));
            assert_eq!(a.triangle, b.triangle);
            // Depth alone, with either kernel: the same depths, no ids.
            for rasterizer in [&mut fastest, &mut portable] {
                let mut depth_only = RenderTarget::depth_only();
                rasterizer.render(positions, triangles, &k, &pose, 0.05, &mut depth_only);
                assert_eq!(bits(&depth_only), bits(&a));
                assert!(depth_only.triangle.is_empty());
                // and the layers of either kind are left clean for the other.
                let mut again = RenderTarget::default();
                rasterizer.render(positions, triangles, &k, &pose, 0.05, &mut again);
                assert_eq!((bits(&again), &again.triangle), (bits(&a), &a.triangle));
            }
            let points = |r: &Rasterizer| {
                let s = r.screen_points().iter().flatten().map(|x| x.to_bits());
                (s.collect::<Vec<_>>(), r.snapped.clone())
            };
            assert_eq!(points(&fastest), points(&portable));
        }
    }
}
