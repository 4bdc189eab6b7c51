//! Ray casting of the TSDF: what the map predicts a camera sees, as depth,
//! surface points and normals per pixel (the model view of KinectFusion, the
//! status image, and `Mapper::render_depth`).

use super::{voxel_index, Block, TsdfVolume, BLOCK, TSDF_SCALE};
use crate::camera::{Intrinsics, Pose};
use crate::image::DepthImage;
use glam::{IVec3, Vec3};
use rayon::prelude::*;

/// Per-pixel results of a ray cast; buffers are reused between casts.
#[derive(Clone, Debug, Default)]
pub struct RaycastImage {
    /// Depth along the optical axis in metres (0 = no surface).
    pub depth: DepthImage,
    /// World-space surface points (meaningful where depth > 0).
    pub points: Vec<Vec3>,
    /// World-space unit normals facing the camera side (zero where no surface).
    pub normals: Vec<Vec3>,
}

/// Trilinear samples of the volume, remembering the last block looked up
/// (consecutive samples along a ray mostly stay in one block).
struct Sampler<'a> {
    volume: &'a TsdfVolume,
    last: Option<(IVec3, &'a Block)>,
}

impl<'a> Sampler<'a> {
    fn voxel(&mut self, v: IVec3) -> Option<f32> {
        let b = BLOCK as i32;
        let key = v.div_euclid(IVec3::splat(b));
        let block = match self.last {
            Some((k, block)) if k == key => block,
            _ => {
                let block = &self.volume.blocks()[*self.volume.index().get(&key)? as usize];
                self.last = Some((key, block));
                block
            }
        };
        let l = v - key * b;
        let i = voxel_index(l.x as usize, l.y as usize, l.z as usize);
        (block.weight[i] > 0).then(|| f32::from(block.tsdf[i]) / TSDF_SCALE)
    }

    /// The distance (in truncation units) at world point `p`, if all eight
    /// surrounding voxels were observed.
    fn sample(&mut self, p: Vec3) -> Option<f32> {
        let g = p / self.volume.config().voxel;
        let base = g.floor();
        let f = g - base;
        let base = base.as_ivec3();
        let mut value = 0.0;
        for c in 0..8 {
            let o = IVec3::new(c & 1, (c >> 1) & 1, (c >> 2) & 1);
            let w = (if o.x == 1 { f.x } else { 1.0 - f.x })
                * (if o.y == 1 { f.y } else { 1.0 - f.y })
                * (if o.z == 1 { f.z } else { 1.0 - f.z });
            value += w * self.voxel(base + o)?;
        }
        Some(value)
    }

    fn gradient(&mut self, p: Vec3) -> Vec3 {
        let h = self.volume.config().voxel;
        let mut g = Vec3::ZERO;
        for axis in 0..3 {
            let e = Vec3::AXES[axis] * h;
            if let (Some(a), Some(b)) = (self.sample(p + e), self.sample(p - e)) {
                g[axis] = a - b;
            }
        }
        g
    }
}

impl TsdfVolume {
    /// Casts a ray through every pixel from `pose`, between `near` and `far`
    /// metres of depth, into `out`.
    pub fn raycast(
        &self,
        intrinsics: &Intrinsics,
        pose: &Pose,
        near: f32,
        far: f32,
        out: &mut RaycastImage,
    ) {
        let (w, h) = (intrinsics.width as usize, intrinsics.height as usize);
        out.depth.reset(intrinsics.width, intrinsics.height);
        out.points.clear();
        out.points.resize(w * h, Vec3::ZERO);
        out.normals.clear();
        out.normals.resize(w * h, Vec3::ZERO);
        let c = *self.config();
        let block_size = c.voxel * BLOCK as f32;
        out.depth
            .data
            .par_chunks_mut(w)
            .zip(out.points.par_chunks_mut(w))
            .zip(out.normals.par_chunks_mut(w))
            .enumerate()
            .for_each(|(r, ((depth, points), normals))| {
                let mut sampler = Sampler {
                    volume: self,
                    last: None,
                };
                for col in 0..w {
                    // Along a ray with unit z, the parameter is the depth.
                    let dir =
                        pose.transform_vector(intrinsics.back_project(col as f32, r as f32, 1.0));
                    let len = dir.length();
                    let mut t = near;
                    let mut previous: Option<(f32, f32)> = None;
                    while t < far {
                        let p = pose.translation + dir * t;
                        match sampler.sample(p) {
                            None => {
                                previous = None;
                                t += 0.5 * block_size / len;
                            }
                            Some(f) if f < 0.0 => {
                                if let Some((t0, f0)) = previous {
                                    // Seen from the front: the zero crossing.
                                    let hit = t0 + (t - t0) * f0 / (f0 - f);
                                    let point = pose.translation + dir * hit;
                                    depth[col] = hit;
                                    points[col] = point;
                                    normals[col] = sampler.gradient(point).normalize_or_zero();
                                }
                                break;
                            }
                            Some(f) => {
                                previous = Some((t, f));
                                // Far from the surface the distance allows big steps.
                                t += (0.8 * f * c.truncation).max(c.voxel) / len;
                            }
                        }
                    }
                }
            });
    }
}
