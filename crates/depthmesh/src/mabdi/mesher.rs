//! The depth-image mesher of MABDI (thesis §3.2.2, Fig. 3.2): every 2×2 block
//! of pixels is split into two triangles along the diagonal from its top-right
//! to its bottom-left pixel, and a triangle is kept only if all three of its
//! pixels are kept (eq. 3.5 drops every element touching D_throwaway).
//! [`DepthMesher::mesh_adaptive`] makes the same surface with few triangles
//! where a few describe it ([`rtin`]).

use crate::camera::{Intrinsics, Pose};
use crate::image::DepthImage;
use crate::mabdi::classify::PixelClass;
use crate::mabdi::rtin::{self, Triangle};
use crate::worker_slots::lock_own;
use glam::Vec3;
use rayon::prelude::*;
use std::sync::Mutex;

const NO_VERTEX: u32 = u32::MAX;

/// Triangles of a full `width × height` image with every pixel kept (eq. 3.6):
/// `2·(width − 1)·(height − 1)`, 612,162 at 640×480.
pub fn full_frame_triangles(width: u32, height: u32) -> usize {
    2 * (width.saturating_sub(1) as usize) * (height.saturating_sub(1) as usize)
}

/// Side of the square pixel tiles the mesher walks in turn.
const TILE: usize = rtin::SIDE;

/// Meshes depth images; holds a per-pixel vertex table reused across frames.
#[derive(Debug, Default)]
pub struct DepthMesher {
    vertex_of_pixel: Vec<u32>,
    /// Per row of pixels, whether any of its pixels is kept.
    row_kept: Vec<bool>,
    /// Per tile, the triangles the adaptive mesher made of it.
    tiles: Vec<Vec<Triangle>>,
    /// Work space of the adaptive mesher, one per worker thread.
    scratch: Vec<Mutex<rtin::Tile>>,
    /// Triangles waiting to be split where another tile's vertices lie on
    /// their edges.
    pending: Vec<[[usize; 2]; 3]>,
    /// The pixels the adaptive mesher gave vertices in this call.
    vertex_pixels: Vec<u32>,
    /// Whether `vertex_of_pixel` holds no vertex.
    table_clear: bool,
}

/// The two triangles of the block whose top-left pixel is `i`, as pixel
/// indices, counter-clockwise seen from the camera (so normals face it).
#[inline]
fn block_triangles(i: usize, w: usize) -> [[usize; 3]; 2] {
    [[i, i + w, i + 1], [i + 1, i + w, i + w + 1]]
}

impl DepthMesher {
    /// A mesher with empty buffers.
    pub fn new() -> Self {
        Self::default()
    }

    /// Number of triangles [`DepthMesher::mesh`] would make, without making
    /// them: rows of blocks in parallel, each walked without branches.
    pub fn count(
        classes: &[PixelClass],
        width: u32,
        keep: impl Fn(PixelClass) -> bool + Sync,
    ) -> usize {
        let w = width as usize;
        if w < 2 {
            return 0;
        }
        let h = classes.len() / w;
        (0..h.saturating_sub(1))
            .into_par_iter()
            .map(|r| {
                let (top, bottom) = (
                    &classes[r * w..(r + 1) * w],
                    &classes[(r + 1) * w..(r + 2) * w],
                );
                let (mut top_left, mut bottom_left) = (keep(top[0]), keep(bottom[0]));
                let mut n = 0;
                for (&t, &b) in top[1..].iter().zip(&bottom[1..]) {
                    let (top_right, bottom_right) = (keep(t), keep(b));
                    // The block's two triangles, as in `block_triangles`.
                    n += usize::from(top_left & bottom_left & top_right)
                        + usize::from(top_right & bottom_left & bottom_right);
                    (top_left, bottom_left) = (top_right, bottom_right);
                }
                n
            })
            .sum()
    }

    /// Appends to `positions`/`triangles` the world-space surface of the
    /// pixels of `depth` whose class passes `keep`, and returns how many
    /// triangles were added. Vertices are the kept pixels back-projected
    /// through `intrinsics` and `pose`, shared between the triangles that use them.
    #[allow(clippy::too_many_arguments)]
    pub fn mesh(
        &mut self,
        depth: &DepthImage,
        classes: &[PixelClass],
        keep: impl Fn(PixelClass) -> bool + Sync,
        intrinsics: &Intrinsics,
        pose: &Pose,
        positions: &mut Vec<Vec3>,
        triangles: &mut Vec<[u32; 3]>,
    ) -> usize {
        let w = depth.width as usize;
        let h = depth.height as usize;
        if w < 2 || h < 2 {
            return 0;
        }
        self.vertex_of_pixel.clear();
        self.vertex_of_pixel.resize(w * h, NO_VERTEX);
        self.table_clear = false;
        // Rows of blocks with an empty row of pixels make no triangle: most
        // of a frame is not novel once the map has seen it.
        classes
            .par_chunks(w)
            .map(|row| row.iter().any(|&c| keep(c)))
            .collect_into_vec(&mut self.row_kept);
        let pixel = Unprojection {
            depth,
            intrinsics,
            pose,
        };
        let before = triangles.len();
        // Tile by tile rather than row by row: each run of triangles (and
        // their vertices) then covers a compact patch of surface, which lets
        // renders of the global mesh cull whole runs outside the view.
        let (rows, columns) = (h - 1, w - 1);
        for tile_row in (0..rows).step_by(TILE) {
            for tile_column in (0..columns).step_by(TILE) {
                for r in tile_row..(tile_row + TILE).min(rows) {
                    if !(self.row_kept[r] && self.row_kept[r + 1]) {
                        continue;
                    }
                    for c in tile_column..(tile_column + TILE).min(columns) {
                        for t in block_triangles(r * w + c, w) {
                            if !t.iter().all(|&p| keep(classes[p])) {
                                continue;
                            }
                            let tri =
                                t.map(|p| pixel.vertex(&mut self.vertex_of_pixel, p, positions).0);
                            triangles.push(tri);
                        }
                    }
                }
            }
        }
        triangles.len() - before
    }

    /// Appends the surface [`DepthMesher::mesh`] would, outline for
    /// outline, with fewer triangles: each 64×64 tile of pixels is meshed
    /// as a right-triangulated irregular network ([`rtin`]) whose triangles
    /// keep the depth of the kept pixels within about `bound` metres at
    /// depth z, `a + b·z²` for `bound = (a, b)`, and large triangles on a
    /// tile's border are split where the next tile has vertices on them,
    /// so the surface has no cracks between tiles.
    #[allow(clippy::too_many_arguments)]
    pub fn mesh_adaptive(
        &mut self,
        depth: &DepthImage,
        classes: &[PixelClass],
        keep: impl Fn(PixelClass) -> bool + Sync,
        bound: (f32, f32),
        intrinsics: &Intrinsics,
        pose: &Pose,
        positions: &mut Vec<Vec3>,
        triangles: &mut Vec<[u32; 3]>,
    ) -> usize {
        let (w, h) = (depth.width as usize, depth.height as usize);
        if w < 2 || h < 2 {
            return 0;
        }
        let columns = (w - 1).div_ceil(TILE);
        let tiles = columns * (h - 1).div_ceil(TILE);
        // The top-left pixel of tile `i`, row-major.
        let origin = |i: usize| [i % columns * TILE, i / columns * TILE];
        self.tiles.resize_with(tiles, Vec::new);
        let threads = rayon::current_num_threads().max(1);
        self.scratch.resize_with(threads, Default::default);
        // Without branches, so that the rows vectorise. Kept pixels are
        // counted by class: a caller may leave the depth of kept pixels
        // that no triangle can use undefined (see `Smoother::apply`).
        let inverse_row = |p: usize, row: &mut [f32]| {
            let (d, c) = (&depth.data[p..p + row.len()], &classes[p..p + row.len()]);
            let mut kept = 0;
            for ((w, &d), &c) in row.iter_mut().zip(d).zip(c) {
                let k = keep(c);
                *w = if k & (d > 0.0) & (d < f32::INFINITY) {
                    1.0 / d
                } else {
                    0.0
                };
                kept += usize::from(k);
            }
            kept
        };
        let scratch = &self.scratch;
        self.tiles[..tiles]
            .par_iter_mut()
            .enumerate()
            .for_each(|(i, out)| {
                let mut tile = lock_own(scratch);
                let [x0, y0] = origin(i);
                tile.mesh(x0, y0, w, h, inverse_row, bound, out);
            });
        // Vertices first, tile by tile (each tile's run of triangles and
        // vertices covers a compact patch), so that the splitting below
        // sees every tile's.
        if !self.table_clear || self.vertex_of_pixel.len() != w * h {
            self.vertex_of_pixel.clear();
            self.vertex_of_pixel.resize(w * h, NO_VERTEX);
        }
        let pixel = Unprojection {
            depth,
            intrinsics,
            pose,
        };
        for (i, tile) in self.tiles[..tiles].iter().enumerate() {
            let [x0, y0] = origin(i);
            for p in tile.iter().flatten() {
                let at = (y0 + p[1] as usize) * w + x0 + p[0] as usize;
                if pixel.vertex(&mut self.vertex_of_pixel, at, positions).1 {
                    self.vertex_pixels.push(at as u32);
                }
            }
        }
        let before = triangles.len();
        for (i, tile) in self.tiles[..tiles].iter().enumerate() {
            let [x0, y0] = origin(i);
            for t in tile {
                let t = t.map(|p| [x0 + p[0] as usize, y0 + p[1] as usize]);
                if !has_long_border_edge(&t, [x0, y0]) {
                    triangles.push(t.map(|[x, y]| self.vertex_of_pixel[y * w + x]));
                    continue;
                }
                self.pending.push(t);
                while let Some(t) = self.pending.pop() {
                    match split_at_neighbours(&t, [x0, y0], w, &self.vertex_of_pixel) {
                        Some(at) => fan(&t, at, w, &self.vertex_of_pixel, &mut self.pending),
                        None => triangles.push(t.map(|[x, y]| self.vertex_of_pixel[y * w + x])),
                    }
                }
            }
        }
        // Few pixels have vertices: resetting those is cheaper than the table.
        for p in self.vertex_pixels.drain(..) {
            self.vertex_of_pixel[p as usize] = NO_VERTEX;
        }
        self.table_clear = true;
        triangles.len() - before
    }
}

/// Pixels of a depth image back-projected into world space.
struct Unprojection<'a> {
    depth: &'a DepthImage,
    intrinsics: &'a Intrinsics,
    pose: &'a Pose,
}

impl Unprojection<'_> {
    /// The vertex of pixel `p` in `table` (per pixel, [`NO_VERTEX`] until
    /// made), made the first time it is asked: back-projected at its depth
    /// onto the end of `positions`. Says whether it was made now.
    #[inline]
    fn vertex(&self, table: &mut [u32], p: usize, positions: &mut Vec<Vec3>) -> (u32, bool) {
        let v = &mut table[p];
        if *v != NO_VERTEX {
            return (*v, false);
        }
        *v = positions.len() as u32;
        let w = self.depth.width as usize;
        let (u, row) = ((p % w) as f32, (p / w) as f32);
        positions.push(self.pose.transform_point(self.intrinsics.back_project(
            u,
            row,
            self.depth.data[p],
        )));
        (*v, true)
    }
}

/// Whether an edge of `t` longer than a pixel lies on the border of the
/// tile at `origin`: only such an edge can have another tile's vertices
/// inside it.
#[inline]
fn has_long_border_edge(t: &[[usize; 2]; 3], origin: [usize; 2]) -> bool {
    (0..3).any(|i| on_border(t[i], t[(i + 1) % 3], origin))
}

/// Whether the edge `a`–`b`, longer than a pixel, lies on the border of the
/// tile at `origin`.
#[inline]
fn on_border(a: [usize; 2], b: [usize; 2], origin: [usize; 2]) -> bool {
    (0..2).any(|axis| {
        let other = 1 - axis;
        a[axis] == b[axis]
            && a[other].abs_diff(b[other]) > 1
            && (a[axis] == origin[axis] || a[axis] == origin[axis] + TILE)
    })
}

/// The first edge of `t` (corners as pixel column and row; `i` for the
/// edge from corner `i` to the next) that lies on the border of the tile
/// at `origin` and has a vertex of another tile inside it.
fn split_at_neighbours(
    t: &[[usize; 2]; 3],
    origin: [usize; 2],
    width: usize,
    vertex_of_pixel: &[u32],
) -> Option<usize> {
    (0..3).find(|&i| {
        let (a, b) = (t[i], t[(i + 1) % 3]);
        on_border(a, b, origin)
            && inside(a, b).any(|[x, y]| vertex_of_pixel[y * width + x] != NO_VERTEX)
    })
}

/// The pixels strictly between `a` and `b`, which share a row or column.
fn inside(a: [usize; 2], b: [usize; 2]) -> impl Iterator<Item = [usize; 2]> {
    let axis = usize::from(a[0] == b[0]);
    let (lo, hi) = (a[axis].min(b[axis]), a[axis].max(b[axis]));
    let forward = a[axis] < b[axis];
    (1..hi - lo).map(move |k| {
        let mut p = a;
        p[axis] = if forward { a[axis] + k } else { a[axis] - k };
        p
    })
}

/// Pushes onto `out` the fan `t` splits into from the corner opposite
/// edge `edge` through the vertices inside that edge, in `t`'s winding.
fn fan(
    t: &[[usize; 2]; 3],
    edge: usize,
    width: usize,
    vertex_of_pixel: &[u32],
    out: &mut Vec<[[usize; 2]; 3]>,
) {
    let (a, b, apex) = (t[edge], t[(edge + 1) % 3], t[(edge + 2) % 3]);
    let mut from = a;
    for p in inside(a, b).filter(|&[x, y]| vertex_of_pixel[y * width + x] != NO_VERTEX) {
        out.push([from, p, apex]);
        from = p;
    }
    out.push([from, b, apex]);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Meshes the novel pixels of `depth` seen from the origin.
    fn mesh_novel(
        depth: &DepthImage,
        classes: &[PixelClass],
        k: &Intrinsics,
    ) -> (usize, Vec<Vec3>, Vec<[u32; 3]>) {
        let (mut p, mut t) = (Vec::new(), Vec::new());
        let n = DepthMesher::new().mesh(
            depth,
            classes,
            |c| c == PixelClass::Novel,
            k,
            &Pose::IDENTITY,
            &mut p,
            &mut t,
        );
        (n, p, t)
    }

    #[test]
    fn full_valid_image_gives_eq_3_6() {
        let k = Intrinsics::kinect();
        let depth = DepthImage {
            width: 640,
            height: 480,
            data: vec![2.0; 640 * 480],
        };
        let classes = vec![PixelClass::Novel; 640 * 480];
        let (n, p, t) = mesh_novel(&depth, &classes, &k);
        assert_eq!(n, 612_162);
        assert_eq!(full_frame_triangles(640, 480), 612_162);
        assert_eq!(
            DepthMesher::count(&classes, 640, |c| c == PixelClass::Novel),
            612_162
        );
        assert_eq!(p.len(), 640 * 480);
        // Triangles face the camera (normal towards −z in camera space).
        let [a, b, c] = t[0].map(|i| p[i as usize]);
        assert!((b - a).cross(c - a).z < 0.0);
    }

    #[test]
    fn the_adaptive_mesh_has_no_vertex_inside_an_edge_across_tiles() {
        // Four by three tiles of a wavy surface (tiles split differently)
        // with a hole that is not novel across a tile corner.
        let k = Intrinsics::from_vertical_fov(200, 150, 60.0);
        let (w, h) = (200usize, 150usize);
        let mut depth = DepthImage::new(200, 150);
        let mut classes = vec![PixelClass::Novel; w * h];
        for y in 0..h {
            for x in 0..w {
                let (u, v) = (x as f32, y as f32);
                depth.data[y * w + x] = 2.0 + 0.2 * (u / 17.0).sin() * (v / 23.0).cos();
                if (50..80).contains(&x) && (55..70).contains(&y) {
                    classes[y * w + x] = PixelClass::Known;
                }
            }
        }
        let (mut positions, mut triangles) = (Vec::new(), Vec::new());
        let novel = |c| c == PixelClass::Novel;
        let mut mesher = DepthMesher::new();
        let mesh = |mesher: &mut DepthMesher, p: &mut Vec<Vec3>, t: &mut Vec<[u32; 3]>| {
            mesher.mesh_adaptive(
                &depth,
                &classes,
                novel,
                (0.002, 0.0),
                &k,
                &Pose::IDENTITY,
                p,
                t,
            )
        };
        let n = mesh(&mut mesher, &mut positions, &mut triangles);
        assert_eq!(n, triangles.len());
        let pixel_mesh = DepthMesher::count(&classes, 200, novel);
        assert!(n * 4 < pixel_mesh, "{n} triangles against {pixel_mesh}");
        // Back to pixels: vertices are kept pixels at their own depth.
        let pixel = |p: Vec3| {
            let (u, v) = (k.fx * p.x / p.z + k.cx, k.fy * p.y / p.z + k.cy);
            let (x, y) = (u.round() as usize, v.round() as usize);
            assert!((u - x as f32).abs() < 1e-3 && (v - y as f32).abs() < 1e-3);
            assert!(novel(classes[y * w + x]));
            assert!((p.z - depth.data[y * w + x]).abs() < 1e-5);
            [x as i64, y as i64]
        };
        let corners: Vec<[i64; 2]> = positions.iter().map(|&p| pixel(p)).collect();
        let used: std::collections::HashSet<[i64; 2]> = corners.iter().copied().collect();
        let mut area2 = 0;
        for t in &triangles {
            let [a, b, c] = t.map(|v| corners[v as usize]);
            let cross = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
            assert!(cross < 0, "winding as the pixel mesher's");
            area2 -= cross;
            for (p, q) in [(a, b), (b, c), (c, a)] {
                // The pixels on an edge are steps of (dx, dy) / gcd.
                let (dx, dy) = (q[0] - p[0], q[1] - p[1]);
                let gcd = |mut a: i64, mut b: i64| {
                    while b != 0 {
                        (a, b) = (b, a % b);
                    }
                    a.abs()
                };
                let steps = gcd(dx, dy);
                for s in 1..steps {
                    let inside = [p[0] + dx / steps * s, p[1] + dy / steps * s];
                    assert!(
                        !used.contains(&inside),
                        "vertex {inside:?} inside edge {p:?}-{q:?}"
                    );
                }
            }
        }
        // The same surface as the pixel mesher's, up to the diagonals of
        // half pixels along the hole and the image border.
        let pixel_area = pixel_mesh as i64;
        assert!(
            (area2 - pixel_area).abs() * 100 < pixel_area,
            "{area2} against {pixel_area}"
        );
        // A second frame starts from a clean vertex table.
        let again = mesh(&mut mesher, &mut Vec::new(), &mut Vec::new());
        assert_eq!(again, n);
    }

    #[test]
    fn drops_every_triangle_touching_a_thrown_away_pixel() {
        let k = Intrinsics::from_vertical_fov(4, 3, 60.0);
        let depth = DepthImage {
            width: 4,
            height: 3,
            data: vec![1.0; 12],
        };
        let mut classes = vec![PixelClass::Novel; 12];
        classes[5] = PixelClass::Known; // pixel (1, 1): used by 6 of the 12 triangles
        let (n, p, t) = mesh_novel(&depth, &classes, &k);
        assert_eq!(n, 12 - 6);
        assert!(t.iter().all(|tri| tri
            .iter()
            .all(|&v| (p[v as usize] - k.back_project(1.0, 1.0, 1.0)).length() > 1e-6)));
        assert_eq!(
            DepthMesher::count(&classes, 4, |c| c == PixelClass::Novel),
            n
        );
    }
}
