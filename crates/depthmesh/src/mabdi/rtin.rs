//! Adaptive meshing of a square tile of a depth image as a right-triangulated
//! irregular network (RTIN: Evans, Kirkpatrick and Townsend, Algorithmica
//! 2001; the error pass as in Mapbox's Martini).
//!
//! The tile's triangles form a binary hierarchy: the square split along a
//! diagonal, then every right triangle split at the midpoint of its
//! hypotenuse, down to half pixels (the depth-image mesher's triangles).
//! Each grid point is the hypotenuse midpoint of at most two triangles of
//! one level, and a triangle is split when the error stored at its
//! midpoint is too large. The error at a midpoint is the larger of both
//! triangles' own errors and of their descendants' errors, so both sides of
//! a hypotenuse split alike (no cracks inside a tile) and a triangle whose
//! descendants must split splits too. The mesh follows pixels that are not
//! kept exactly: a triangle covering one has an infinite error, so only
//! half-pixel triangles of kept pixels are made near them.
//!
//! The error of a triangle is how far, along its ray, the depth at the
//! midpoint of its hypotenuse lies from the triangle's surface there
//! (perspective-correct: inverse depth is affine across a projected plane),
//! in units of a bound that grows with depth as the novelty threshold does.
//! As in Martini, a triangle's error counts the midpoints of its own
//! hypotenuse and of its descendants', each against its own triangle: every
//! grid point of a triangle is one of those midpoints, but not measured
//! against the triangle itself, so the bound holds within about a factor
//! of two.

use std::sync::OnceLock;

/// Side of a tile in pixels (a power of two: the hierarchy halves it).
pub const SIDE: usize = 64;
/// Grid points along a side of a tile.
const GRID: usize = SIDE + 1;
/// Triangles are numbered as in a binary heap: the two halves of the square
/// are 2 and 3 and the children of `t` are `2t` and `2t + 1`. Those from
/// here on are half pixels, the leaves (their hypotenuse midpoint is not a
/// grid point).
const FIRST_LEAF: usize = 2 * SIDE * SIDE;
/// One past the last leaf.
const END: usize = 2 * FIRST_LEAF;

/// Tiles with fewer kept pixels than this (an eighth) are meshed in half
/// pixels without the hierarchy.
const SPARSE: usize = GRID * GRID / 8;

/// A grid point of a tile: column, row.
pub type Point = [u8; 2];

/// A triangle of a tile, counter-clockwise as the depth-image mesher's
/// (negative signed area in pixel coordinates, rows down).
pub type Triangle = [Point; 3];

/// Corners `[a, b, c]` of every triangle of the hierarchy by number:
/// `a`–`b` is the hypotenuse, `c` the right angle.
fn hierarchy() -> &'static [[Point; 3]] {
    static TRIANGLES: OnceLock<Vec<[Point; 3]>> = OnceLock::new();
    TRIANGLES.get_or_init(|| {
        let s = SIDE as u8;
        let mut t = vec![[[0; 2]; 3]; END];
        t[2] = [[0, 0], [s, s], [s, 0]];
        t[3] = [[s, s], [0, 0], [0, s]];
        for id in 2..FIRST_LEAF {
            let [a, b, c] = t[id];
            let m = midpoint(a, b);
            t[2 * id] = [c, a, m];
            t[2 * id + 1] = [b, c, m];
        }
        t
    })
}

#[inline]
fn midpoint(a: Point, b: Point) -> Point {
    [(a[0] + b[0]) / 2, (a[1] + b[1]) / 2]
}

#[inline]
fn at(p: Point) -> usize {
    p[1] as usize * GRID + p[0] as usize
}

/// Work space for one tile at a time, reused from tile to tile.
#[derive(Debug, Default)]
pub struct Tile {
    /// Per grid point: inverse depth, or 0 where the pixel is not kept or
    /// lies outside the image.
    inverse: Vec<f32>,
    /// Per grid point: the error of the triangles whose hypotenuse
    /// midpoint it is, in units of the bound.
    error: Vec<f32>,
    /// Per grid point: depth (infinite where not kept).
    depth: Vec<f32>,
    /// Per grid point: the inverse of the bound at its depth.
    scale: Vec<f32>,
    /// Per triangle above the leaves: whether it holds a kept pixel.
    any: Vec<bool>,
    stack: Vec<u32>,
}

impl Tile {
    /// Meshes the tile whose top-left grid point is pixel (`x0`, `y0`) of
    /// a `width × height` image into `out` (cleared first).
    /// `inverse_row(p, row)` fills `row` with the inverse depths of the
    /// pixels from `p` on (0 where a pixel is not to be meshed) and says
    /// how many are kept; `(a, b)` is the bound in metres at depth `z`,
    /// `a + b·z²`. Returns whether the tile holds any kept pixel.
    #[allow(clippy::too_many_arguments)]
    pub fn mesh(
        &mut self,
        x0: usize,
        y0: usize,
        width: usize,
        height: usize,
        inverse_row: impl Fn(usize, &mut [f32]) -> usize,
        bound: (f32, f32),
        out: &mut Vec<Triangle>,
    ) -> bool {
        out.clear();
        self.inverse.clear();
        self.inverse.resize(GRID * GRID, 0.0);
        let columns = GRID.min(width.saturating_sub(x0));
        let mut kept = 0;
        for (y, row) in self
            .inverse
            .chunks_exact_mut(GRID)
            .take(height.saturating_sub(y0))
            .enumerate()
        {
            kept += inverse_row((y0 + y) * width + x0, &mut row[..columns]);
        }
        if kept == 0 {
            return false;
        }
        if kept < SPARSE {
            self.half_pixels(out);
        } else {
            self.errors(bound);
            self.extract(out);
        }
        true
    }

    /// Every half pixel with three kept corners, for a tile with few kept
    /// pixels: scattered pixels gain nothing from the hierarchy, whose
    /// error pass visits every triangle of it.
    fn half_pixels(&self, out: &mut Vec<Triangle>) {
        for y in 0..SIDE {
            let (top, bottom) = (
                &self.inverse[y * GRID..][..GRID],
                &self.inverse[(y + 1) * GRID..][..GRID],
            );
            if !top.iter().chain(bottom).any(|&w| w > 0.0) {
                continue;
            }
            for x in 0..SIDE {
                let p = |dx: usize, dy: usize| [(x + dx) as u8, (y + dy) as u8];
                let [tl, tr, bl, br] =
                    [top[x], top[x + 1], bottom[x], bottom[x + 1]].map(|w| w > 0.0);
                // Split as the depth-image mesher splits a block.
                if tl && bl && tr {
                    out.push([p(0, 0), p(0, 1), p(1, 0)]);
                }
                if tr && bl && br {
                    out.push([p(1, 0), p(0, 1), p(1, 1)]);
                }
            }
        }
    }

    /// The error pass, from the smallest triangles up: first those whose
    /// children are half pixels, then the rest, without branches.
    fn errors(&mut self, (b0, b1): (f32, f32)) {
        let nodes = nodes();
        let w = &self.inverse;
        // Per grid point: depth, and the inverse of the bound there.
        self.depth.clear();
        self.depth.extend(w.iter().map(|&w| 1.0 / w));
        self.scale.clear();
        self.scale.extend(
            self.depth
                .iter()
                .map(|&z| 1.0 / (b0 + b1 * z * z).max(f32::MIN_POSITIVE)),
        );
        let (depth, scale, error) = (&self.depth, &self.scale, &mut self.error);
        error.clear();
        error.resize(GRID * GRID, 0.0);
        self.any.clear();
        self.any.resize(FIRST_LEAF, false);
        // The error at m of the hypotenuse a–b, if a, b and m are kept.
        let own = |n: &Node, wa: f32, wb: f32| (depth[n.m] - 2.0 / (wa + wb)).abs() * scale[n.m];
        for id in (FIRST_LEAF / 2..FIRST_LEAF).rev() {
            let n = &nodes[id];
            let [wa, wb, wc, wm] = [n.a, n.b, n.c, n.m].map(|p| w[p]);
            let all = (wa > 0.0) & (wb > 0.0) & (wc > 0.0) & (wm > 0.0);
            let e = if all { own(n, wa, wb) } else { f32::INFINITY };
            error[n.m] = error[n.m].max(e);
            self.any[id] = (wa > 0.0) | (wb > 0.0) | (wc > 0.0) | (wm > 0.0);
        }
        for id in (2..FIRST_LEAF / 2).rev() {
            let n = &nodes[id];
            let [wa, wb, wm] = [n.a, n.b, n.m].map(|p| w[p]);
            let kept = (wa > 0.0) & (wb > 0.0) & (wm > 0.0);
            let e = if kept { own(n, wa, wb) } else { f32::INFINITY };
            error[n.m] = error[n.m].max(e.max(error[n.left]).max(error[n.right]));
            self.any[id] = self.any[2 * id] | self.any[2 * id + 1];
        }
    }

    /// The triangles to make, each split while its error is above 1.
    fn extract(&mut self, out: &mut Vec<Triangle>) {
        let triangles = hierarchy();
        self.stack.clear();
        self.stack.extend([3, 2]);
        while let Some(id) = self.stack.pop() {
            let id = id as usize;
            let [a, b, c] = triangles[id];
            if id >= FIRST_LEAF {
                if [a, b, c].iter().all(|&p| self.inverse[at(p)] > 0.0) {
                    out.push(oriented([a, b, c]));
                }
            } else if self.any[id] {
                if self.error[at(midpoint(a, b))] <= 1.0 {
                    out.push(oriented([a, b, c]));
                } else {
                    self.stack.extend([2 * id as u32 + 1, 2 * id as u32]);
                }
            }
        }
    }
}

/// A triangle above the leaves, as grid-point indices: corners `a`, `b`
/// (the hypotenuse) and `c`, the hypotenuse midpoint `m`, and the
/// hypotenuse midpoints of its children.
#[derive(Clone, Copy, Debug, Default)]
struct Node {
    a: usize,
    b: usize,
    c: usize,
    m: usize,
    left: usize,
    right: usize,
}

/// [`hierarchy`] above the leaves as [`Node`]s, by number.
fn nodes() -> &'static [Node] {
    static NODES: OnceLock<Vec<Node>> = OnceLock::new();
    NODES.get_or_init(|| {
        hierarchy()[..FIRST_LEAF]
            .iter()
            .map(|&[a, b, c]| Node {
                a: at(a),
                b: at(b),
                c: at(c),
                m: at(midpoint(a, b)),
                left: at(midpoint(c, a)),
                right: at(midpoint(b, c)),
            })
            .collect()
    })
}

/// The triangle with its corners in the depth-image mesher's winding.
fn oriented([a, b, c]: Triangle) -> Triangle {
    let d = |p: Point, q: Point| [q[0] as i32 - p[0] as i32, q[1] as i32 - p[1] as i32];
    let (u, v) = (d(a, b), d(a, c));
    if u[0] * v[1] - u[1] * v[0] < 0 {
        [a, b, c]
    } else {
        [a, c, b]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Meshes one tile of an image `depth(x, y)`, with every pixel kept
    /// where it is positive; bound 1 mm.
    fn tile(depth: impl Fn(usize, usize) -> f32) -> Vec<Triangle> {
        let mut out = Vec::new();
        let inverse_row = |p: usize, row: &mut [f32]| {
            for (x, w) in row.iter_mut().enumerate() {
                let d = depth(x, p / GRID);
                *w = if d > 0.0 { 1.0 / d } else { 0.0 };
            }
            row.iter().filter(|&&w| w > 0.0).count()
        };
        Tile::default().mesh(0, 0, GRID, GRID, inverse_row, (0.001, 0.0), &mut out);
        out
    }

    /// Twice the area of a triangle, in pixels.
    fn area2(t: &Triangle) -> i32 {
        let d = |p: Point, q: Point| [q[0] as i32 - p[0] as i32, q[1] as i32 - p[1] as i32];
        let (u, v) = (d(t[0], t[1]), d(t[0], t[2]));
        u[0] * v[1] - u[1] * v[0]
    }

    #[test]
    fn a_plane_is_two_triangles_and_a_tile_without_kept_pixels_none() {
        // A slanted plane: inverse depth affine in the pixel coordinates.
        let plane = tile(|x, y| 1.0 / (0.5 + 0.002 * x as f32 + 0.001 * y as f32));
        assert_eq!(plane.len(), 2);
        assert!(
            plane.iter().all(|t| area2(t) < 0),
            "winding as the mesher's"
        );
        assert_eq!(plane.iter().map(|t| -area2(t)).sum::<i32>(), 2 * 64 * 64);
        assert!(tile(|_, _| 0.0).is_empty());
    }

    #[test]
    fn triangles_cover_kept_pixels_only_and_split_where_the_surface_bends() {
        // A bump in a plane at 2 m, and a hole of pixels not kept.
        let depth = |x: usize, y: usize| {
            let (dx, dy) = (x as f32 - 40.0, y as f32 - 20.0);
            let hole = (10..14).contains(&x) && (30..37).contains(&y);
            if hole {
                0.0
            } else {
                2.0 - 0.05 * (-(dx * dx + dy * dy) / 30.0).exp()
            }
        };
        let mesh = tile(depth);
        // Exactly the half pixels with three kept corners are covered.
        let kept = |p: &Point| depth(p[0] as usize, p[1] as usize) > 0.0;
        let half_pixels = hierarchy()[FIRST_LEAF..]
            .iter()
            .filter(|t| t.iter().all(kept))
            .count();
        assert!(half_pixels < 2 * 64 * 64 - 50);
        let covered: i32 = mesh.iter().map(|t| -area2(t)).sum();
        assert_eq!(covered as usize, half_pixels);
        for t in &mesh {
            assert!(t.iter().all(|p| depth(p[0] as usize, p[1] as usize) > 0.0));
            // No triangle holds a pixel of the hole, inside or on an edge.
            for y in 0..GRID {
                for x in 0..GRID {
                    if depth(x, y) == 0.0 {
                        assert!(!covers(t, [x as i32, y as i32]), "{t:?} covers ({x}, {y})");
                    }
                }
            }
        }
        // Far fewer triangles than the 8,192 half pixels, more near the bump.
        assert!(mesh.len() < 1500, "{} triangles", mesh.len());
        let near_bump = |t: &Triangle| {
            t.iter()
                .all(|p| (p[0] as i32 - 40).abs() < 10 && (p[1] as i32 - 20).abs() < 10)
        };
        assert!(mesh.iter().filter(|t| near_bump(t)).count() > 20);
    }

    /// Whether a grid point lies inside or on a triangle.
    fn covers(t: &Triangle, p: [i32; 2]) -> bool {
        let c = t.map(|q| [q[0] as i32, q[1] as i32]);
        let side = |a: [i32; 2], b: [i32; 2]| {
            (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])
        };
        let s = [side(c[0], c[1]), side(c[1], c[2]), side(c[2], c[0])];
        s.iter().all(|&v| v <= 0) || s.iter().all(|&v| v >= 0)
    }

    #[test]
    fn every_grid_point_of_a_curved_surface_lies_within_twice_the_bound() {
        let depth =
            |x: usize, y: usize| 1.0 + 0.3 * ((x as f32 / 9.0).sin() * (y as f32 / 13.0).cos());
        let mesh = tile(depth);
        for t in &mesh {
            let c = t.map(|q| [q[0] as f32, q[1] as f32]);
            let w = t.map(|q| 1.0 / depth(q[0] as usize, q[1] as usize));
            for y in 0..GRID {
                for x in 0..GRID {
                    if !covers(t, [x as i32, y as i32]) {
                        continue;
                    }
                    // Barycentric interpolation of inverse depth.
                    let (px, py) = (x as f32, y as f32);
                    let det = (c[1][1] - c[2][1]) * (c[0][0] - c[2][0])
                        + (c[2][0] - c[1][0]) * (c[0][1] - c[2][1]);
                    let l0 = ((c[1][1] - c[2][1]) * (px - c[2][0])
                        + (c[2][0] - c[1][0]) * (py - c[2][1]))
                        / det;
                    let l1 = ((c[2][1] - c[0][1]) * (px - c[2][0])
                        + (c[0][0] - c[2][0]) * (py - c[2][1]))
                        / det;
                    let inv = l0 * w[0] + l1 * w[1] + (1.0 - l0 - l1) * w[2];
                    let err = (1.0 / inv - depth(x, y)).abs();
                    assert!(err <= 0.002 + 1e-5, "({x}, {y}) off by {err} m in {t:?}");
                }
            }
        }
    }
}
