//! The depth-image mesher of MABDI (thesis §3.2.2, Fig. 3.2): every 2×2 block
//! of pixels is split into two triangles along the diagonal from its top-right
//! to its bottom-left pixel, and a triangle is kept only if all three of its
//! pixels are kept (eq. 3.5 drops every element touching D_throwaway).

use crate::camera::{Intrinsics, Pose};
use crate::image::DepthImage;
use crate::mabdi::classify::PixelClass;
use glam::Vec3;
use rayon::prelude::*;

const NO_VERTEX: u32 = u32::MAX;

/// Triangles of a full `width × height` image with every pixel kept (eq. 3.6):
/// `2·(width − 1)·(height − 1)`, 612,162 at 640×480.
pub fn full_frame_triangles(width: u32, height: u32) -> usize {
    2 * (width.saturating_sub(1) as usize) * (height.saturating_sub(1) as usize)
}

/// Side of the square pixel tiles the mesher walks in turn.
const TILE: usize = 64;

/// Meshes depth images; holds a per-pixel vertex table reused across frames.
#[derive(Debug, Default)]
pub struct DepthMesher {
    vertex_of_pixel: Vec<u32>,
    /// Per row of pixels, whether any of its pixels is kept.
    row_kept: Vec<bool>,
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
        // Rows of blocks with an empty row of pixels make no triangle: most
        // of a frame is not novel once the map has seen it.
        classes
            .par_chunks(w)
            .map(|row| row.iter().any(|&c| keep(c)))
            .collect_into_vec(&mut self.row_kept);
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
                                t.map(|p| {
                                    let v = &mut self.vertex_of_pixel[p];
                                    if *v == NO_VERTEX {
                                        *v = positions.len() as u32;
                                        let (u, row) = ((p % w) as f32, (p / w) as f32);
                                        positions.push(pose.transform_point(
                                            intrinsics.back_project(u, row, depth.data[p]),
                                        ));
                                    }
                                    *v
                                });
                            triangles.push(tri);
                        }
                    }
                }
            }
        }
        triangles.len() - before
    }
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
