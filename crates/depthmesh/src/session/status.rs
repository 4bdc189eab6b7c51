//! The status image (KinectFusion's, and Mouser's Fig. 24): the map as the
//! sensor would see it from a pose, shaded by its surface normals, so the
//! person scanning sees what is mapped and what is still missing. Any
//! back-end: the TSDF is ray cast (normals from the distance gradient);
//! mesh back-ends are rendered to depth and shaded by the normals of the
//! rendered surface.

use super::Backend;
use crate::camera::{Intrinsics, Pose};
use crate::tsdf::raycast::RaycastImage;
use glam::Vec3;
use rayon::prelude::*;

/// Light that does not come from exactly behind the camera, so surfaces
/// facing the sensor are not all equally bright.
const LIGHT: Vec3 = Vec3::new(0.3, -0.5, -1.0);
/// Brightness of a surface facing away from the light.
const AMBIENT: f32 = 0.25;

/// An 8-bit grey status image, reused from frame to frame.
#[derive(Clone, Debug, Default)]
pub struct StatusImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Row-major grey levels; 0 where the map has no surface.
    pub pixels: Vec<u8>,
    raycast: RaycastImage,
}

impl StatusImage {
    /// Draws `backend`'s map seen by a camera `intrinsics` at `pose`.
    pub fn draw(&mut self, backend: &Backend, intrinsics: &Intrinsics, pose: &Pose) {
        let light = pose.transform_vector(LIGHT).normalize();
        self.width = intrinsics.width;
        self.height = intrinsics.height;
        self.pixels.clear();
        self.pixels.resize(intrinsics.pixel_count(), 0);
        match backend {
            Backend::Tsdf(t) => {
                t.raycast(intrinsics, pose, &mut self.raycast);
                let r = &self.raycast;
                self.pixels
                    .par_iter_mut()
                    .zip(&r.depth.data)
                    .zip(&r.normals)
                    .for_each(|((px, &d), &n)| {
                        if d > 0.0 {
                            *px = shade(n, light);
                        }
                    });
            }
            _ => {
                let depth = backend.mapper().render_depth(intrinsics, pose);
                let w = intrinsics.width as usize;
                let at = |u: usize, v: usize| {
                    let d = depth.data[v * w + u];
                    (d > 0.0).then(|| intrinsics.back_project(u as f32, v as f32, d))
                };
                self.pixels
                    .par_chunks_mut(w)
                    .enumerate()
                    .for_each(|(v, row)| {
                        for (u, px) in row.iter_mut().enumerate() {
                            let Some(p) = at(u, v) else { continue };
                            // Forward differences, backward at the last row and column.
                            let du = if u + 1 < w {
                                at(u + 1, v)
                            } else {
                                u.checked_sub(1).and_then(|u| at(u, v))
                            };
                            let dv = if v + 1 < depth.height as usize {
                                at(u, v + 1)
                            } else {
                                v.checked_sub(1).and_then(|v| at(u, v))
                            };
                            // Depth edges have no neighbour: lit as facing the camera.
                            let n = match (du, dv) {
                                (Some(a), Some(b)) => (a - p).cross(b - p),
                                _ => Vec3::Z,
                            };
                            *px = shade(pose.transform_vector(n), light);
                        }
                    });
            }
        }
    }
}

/// Two-sided Lambert shading of a surface with normal `n` (any length),
/// never 0 so a surface is told apart from no surface.
fn shade(n: Vec3, light: Vec3) -> u8 {
    let lambert = n.normalize_or_zero().dot(light).abs();
    (1.0 + 229.0 * (AMBIENT + (1.0 - AMBIENT) * lambert)) as u8
}
