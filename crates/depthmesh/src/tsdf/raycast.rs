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

/// Blocks a [`Sampler`] remembers (a power of two): a ray's samples near a
/// block corner reach into up to eight blocks, and neighbouring rays
/// revisit them.
const CACHED_BLOCKS: usize = 16;

/// Trilinear samples of the volume, remembering the blocks last looked up
/// (a hash lookup costs more than the rest of a sample).
struct Sampler<'a> {
    volume: &'a TsdfVolume,
    /// Blocks looked up (`None`: not allocated), direct-mapped by key.
    cache: [(IVec3, Option<&'a Block>); CACHED_BLOCKS],
    /// Voxels per metre.
    scale: f32,
}

/// log2 of [`BLOCK`]: block keys and offsets of voxels by shifts and masks.
const BLOCK_SHIFT: i32 = BLOCK.trailing_zeros() as i32;
const _: () = assert!(1 << BLOCK_SHIFT == BLOCK);

impl<'a> Sampler<'a> {
    fn new(volume: &'a TsdfVolume) -> Self {
        Sampler {
            volume,
            // A key no voxel maps to (block keys are voxel indices / 8).
            cache: [(IVec3::MAX, None); CACHED_BLOCKS],
            scale: 1.0 / volume.config().voxel,
        }
    }

    /// The block holding voxel `v` and the voxel's index in it.
    #[inline(always)]
    fn locate(&mut self, v: IVec3) -> Option<(&'a Block, usize)> {
        let key = v >> BLOCK_SHIFT;
        // Neighbouring blocks land in different slots.
        let slot =
            (key.x ^ key.y.wrapping_mul(3) ^ key.z.wrapping_mul(5)) as usize & (CACHED_BLOCKS - 1);
        let entry = &mut self.cache[slot];
        if entry.0 != key {
            *entry = (
                key,
                self.volume
                    .index()
                    .get(&key)
                    .map(|&i| &self.volume.blocks()[i as usize]),
            );
        }
        let l = v & (BLOCK as i32 - 1);
        Some((
            entry.1?,
            voxel_index(l.x as usize, l.y as usize, l.z as usize),
        ))
    }

    fn voxel(&mut self, v: IVec3) -> Option<f32> {
        let (block, i) = self.locate(v)?;
        (block.weight[i] > 0).then(|| f32::from(block.tsdf[i]) / TSDF_SCALE)
    }

    /// The distance at the voxel nearest to world point `p`: `Err(true)`
    /// when its block does not exist, `Err(false)` when it was never observed.
    #[inline(always)]
    fn nearest(&mut self, p: Vec3) -> Result<f32, bool> {
        let (block, i) = self.locate(floor(p * self.scale + 0.5)).ok_or(true)?;
        if block.weight[i] == 0 {
            return Err(false);
        }
        Ok(f32::from(block.tsdf[i]) / TSDF_SCALE)
    }

    /// The distance (in truncation units) at world point `p`, if all eight
    /// surrounding voxels were observed.
    #[inline(always)]
    fn sample(&mut self, p: Vec3) -> Option<f32> {
        let g = p * self.scale;
        let base = floor(g);
        let f = g - base.as_vec3();
        let local = base & (BLOCK as i32 - 1);
        if local.max_element() < BLOCK as i32 - 1 {
            // All eight corners in one block (most samples): index directly.
            let (block, i) = self.locate(base)?;
            let mut value = 0.0;
            for c in 0..8 {
                let j = i + voxel_index(c & 1, (c >> 1) & 1, (c >> 2) & 1);
                if block.weight[j] == 0 {
                    return None;
                }
                value += corner_weight(f, c) * f32::from(block.tsdf[j]);
            }
            return Some(value / TSDF_SCALE);
        }
        let mut value = 0.0;
        for c in 0..8 {
            let o = IVec3::new(c as i32 & 1, (c as i32 >> 1) & 1, (c as i32 >> 2) & 1);
            value += corner_weight(f, c) * self.voxel(base + o)?;
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

/// The trilinear weight of cube corner `c` (bits x, y, z) at fraction `f`.
#[inline]
fn corner_weight(f: Vec3, c: usize) -> f32 {
    let pick = |bit: usize, t: f32| if c >> bit & 1 == 1 { t } else { 1.0 - t };
    pick(0, f.x) * pick(1, f.y) * pick(2, f.z)
}

/// Rays with a hint start this many truncation distances in front of the
/// depth it measured. Starting closer saves steps but misses more of the
/// foreground at silhouettes, where the hint saw the background: at 1.0 the
/// half-resolution 7-Scenes view renders 15–20 % faster, but tracking the
/// simulated room's line path (2 cm voxels, 20 frames) ends 1.02 cm from
/// the truth instead of 0.86 cm.
const HINT_BACK: f32 = 1.5;

/// Pixels per side of the tiles of the depth-range image.
const TILE: usize = 8;

/// `⌊v⌋` per component; the `floorf` of a target without SSE4.1 is a
/// library call, too slow for every step of every ray.
#[inline]
fn floor(v: Vec3) -> IVec3 {
    let f = |x: f32| {
        let i = x as i32;
        i - i32::from(i as f32 > x)
    };
    IVec3::new(f(v.x), f(v.y), f(v.z))
}

/// The ray parameter where `origin + dir·t` leaves the block `key` (block
/// coordinates as floats).
fn block_exit(origin: Vec3, dir: Vec3, key: Vec3, size: f32) -> f32 {
    let low = key * size;
    let mut exit = f32::INFINITY;
    for a in 0..3 {
        if dir[a] != 0.0 {
            let bound = if dir[a] > 0.0 { low[a] + size } else { low[a] };
            exit = exit.min((bound - origin[a]) / dir[a]);
        }
    }
    exit
}

impl TsdfVolume {
    /// Per tile of `TILE`×`TILE` pixels, the depth range covered by the
    /// allocated blocks seen from `pose`, clipped to `near..far` (an empty
    /// range where none is): rays start where the map starts and skip the
    /// free space in front of it (InfiniTAM's expected-depth image).
    fn depth_ranges(
        &self,
        k: &Intrinsics,
        pose: &Pose,
        near: f32,
        far: f32,
    ) -> (usize, Vec<(f32, f32)>) {
        let tiles_x = (k.width as usize).div_ceil(TILE);
        let tiles_y = (k.height as usize).div_ceil(TILE);
        let empty = (f32::INFINITY, f32::NEG_INFINITY);
        let to_camera = pose.inverse();
        let size = self.config().voxel * BLOCK as f32;
        let ranges = self
            .blocks()
            .par_iter()
            .fold(
                || vec![empty; tiles_x * tiles_y],
                |mut tiles, block| {
                    // The block's cube, one voxel wider for trilinear samples.
                    let low = block.key.as_vec3() * size - self.config().voxel;
                    let side = size + 2.0 * self.config().voxel;
                    let (mut z0, mut z1) = (f32::INFINITY, f32::NEG_INFINITY);
                    let (mut u0, mut u1, mut v0, mut v1) = (
                        f32::INFINITY,
                        f32::NEG_INFINITY,
                        f32::INFINITY,
                        f32::NEG_INFINITY,
                    );
                    for c in 0..8 {
                        let corner = low
                            + Vec3::new(
                                (c & 1) as f32,
                                ((c >> 1) & 1) as f32,
                                ((c >> 2) & 1) as f32,
                            ) * side;
                        let p = to_camera.transform_point(corner);
                        z0 = z0.min(p.z);
                        z1 = z1.max(p.z);
                        if p.z > 1e-3 {
                            u0 = u0.min(k.fx * p.x / p.z + k.cx);
                            u1 = u1.max(k.fx * p.x / p.z + k.cx);
                            v0 = v0.min(k.fy * p.y / p.z + k.cy);
                            v1 = v1.max(k.fy * p.y / p.z + k.cy);
                        }
                    }
                    if z1 <= near || z0 >= far {
                        return tiles;
                    }
                    if z0 <= 1e-3 {
                        // Straddles the camera plane: may cover any pixel.
                        (u0, u1, v0, v1) = (0.0, k.width as f32, 0.0, k.height as f32);
                    }
                    let (z0, z1) = (z0.max(near), z1.min(far));
                    let tx = |u: f32| (u.max(0.0) as usize / TILE).min(tiles_x - 1);
                    let ty = |v: f32| (v.max(0.0) as usize / TILE).min(tiles_y - 1);
                    if u1 < 0.0 || v1 < 0.0 || u0 >= k.width as f32 || v0 >= k.height as f32 {
                        return tiles;
                    }
                    for y in ty(v0)..=ty(v1) {
                        for t in &mut tiles[y * tiles_x + tx(u0)..=y * tiles_x + tx(u1)] {
                            *t = (t.0.min(z0), t.1.max(z1));
                        }
                    }
                    tiles
                },
            )
            .reduce(
                || vec![empty; tiles_x * tiles_y],
                |mut a, b| {
                    for (x, y) in a.iter_mut().zip(b) {
                        *x = (x.0.min(y.0), x.1.max(y.1));
                    }
                    a
                },
            );
        (tiles_x, ranges)
    }

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
        let rays = Rays::new(self, intrinsics, pose, near, far);
        out.depth
            .data
            .par_chunks_mut(w)
            .zip(out.points.par_chunks_mut(w))
            .zip(out.normals.par_chunks_mut(w))
            .enumerate()
            .for_each(|(r, ((depth, points), normals))| {
                let mut sampler = Sampler::new(self);
                for col in 0..w {
                    if let Some((hit, point)) = rays.cast(&mut sampler, col, r) {
                        depth[col] = hit;
                        points[col] = point;
                        normals[col] = sampler.gradient(point).normalize_or_zero();
                    }
                }
            });
    }

    /// The depth part of [`TsdfVolume::raycast`] alone (no surface points
    /// or normals, which cost more than the depth).
    ///
    /// `hint` is a depth image taken from the same pose (any resolution, its
    /// camera model given): rays start just in front of the depth it
    /// measured instead of where the map's blocks begin, which saves most of
    /// the stepping when ray casting the view a frame was just fused from.
    pub fn raycast_depth(
        &self,
        intrinsics: &Intrinsics,
        pose: &Pose,
        (near, far): (f32, f32),
        hint: Option<(&DepthImage, &Intrinsics)>,
        out: &mut DepthImage,
    ) {
        out.reset(intrinsics.width, intrinsics.height);
        let mut rays = Rays::new(self, intrinsics, pose, near, far);
        rays.hint = hint;
        out.data
            .par_chunks_mut(intrinsics.width as usize)
            .enumerate()
            .for_each(|(r, depth)| {
                let mut sampler = Sampler::new(self);
                for (col, d) in depth.iter_mut().enumerate() {
                    if let Some((hit, _)) = rays.cast(&mut sampler, col, r) {
                        *d = hit;
                    }
                }
            });
    }
}

/// Steps back a crossing may take (see [`crossing`]): the last sample in
/// front is at most one voxel diagonal past the surface, which along a
/// ray grazing it at 15° is under four voxel steps.
const MAX_STEPS_BACK: usize = 4;

/// The depth where the trilinear field crosses zero between the last
/// sample whose nearest voxel was in front of the surface, `(t0, f0)`
/// (`f0` that voxel's distance), and the sample behind it, `(t, g)`.
///
/// The field at `t0` itself may already be behind the surface: its nearest
/// voxel lies up to half a voxel away, on the other side of a surface
/// between them. Interpolating from `f0` then puts the hit past the
/// surface, by up to a voxel where a surface passes through a layer of
/// voxel centres (a floor at a round height): in a fused floor that made
/// depth steps of several millimetres and model normals off by degrees,
/// which ICP read as constraints along the floor. So the marcher steps
/// back from `t0` until the field is in front.
fn crossing(
    sampler: &mut Sampler<'_>,
    origin: Vec3,
    dir: Vec3,
    step: f32,
    (t0, f0): (f32, f32),
    (t, g): (f32, f32),
) -> f32 {
    let (mut front, mut behind) = ((t0, sampler.sample(origin + dir * t0)), (t, g));
    for _ in 0..MAX_STEPS_BACK {
        match front.1 {
            Some(v) if v <= 0.0 => {
                behind = (front.0, v);
                let back = front.0 - step;
                front = (back, sampler.sample(origin + dir * back));
            }
            _ => break,
        }
    }
    match front {
        (ta, Some(ga)) if ga > 0.0 => ta + (behind.0 - ta) * ga / (ga - behind.1),
        // No field in front to interpolate from: the nearest voxel's.
        _ => t0 + (t - t0) * f0 / (f0 - g),
    }
}

/// The rays of one cast: camera, pose and where along each ray the map is.
struct Rays<'a> {
    /// Depth seen from the same pose, where rays may start.
    hint: Option<(&'a DepthImage, &'a Intrinsics)>,
    intrinsics: &'a Intrinsics,
    pose: &'a Pose,
    voxel: f32,
    truncation: f32,
    tiles_x: usize,
    ranges: Vec<(f32, f32)>,
}

impl<'a> Rays<'a> {
    fn new(
        volume: &TsdfVolume,
        intrinsics: &'a Intrinsics,
        pose: &'a Pose,
        near: f32,
        far: f32,
    ) -> Self {
        let (tiles_x, ranges) = volume.depth_ranges(intrinsics, pose, near, far);
        Rays {
            hint: None,
            intrinsics,
            pose,
            voxel: volume.config().voxel,
            truncation: volume.config().truncation,
            tiles_x,
            ranges,
        }
    }

    /// The first surface seen from the front through pixel `(col, row)`:
    /// its depth and world point.
    fn cast(&self, sampler: &mut Sampler<'_>, col: usize, row: usize) -> Option<(f32, Vec3)> {
        // Along a ray with unit z, the parameter is the depth.
        let ray = self.intrinsics.back_project(col as f32, row as f32, 1.0);
        let dir = self.pose.transform_vector(ray);
        let (start, far) = self.ranges[(row / TILE) * self.tiles_x + col / TILE];
        if let Some(d) = self.hint_depth(ray) {
            // If the ray starts behind the surface, start over.
            let from = (d - HINT_BACK * self.truncation).max(start);
            if from < far {
                if let Ok(hit) = self.march(sampler, dir, from, far) {
                    return hit;
                }
            }
        }
        self.march(sampler, dir, start, far).ok().flatten()
    }

    /// The hint's depth along the camera-space ray `ray` (unit z).
    fn hint_depth(&self, ray: Vec3) -> Option<f32> {
        let (depth, k) = self.hint?;
        let u = k.fx * ray.x + k.cx + 0.5;
        let v = k.fy * ray.y + k.cy + 0.5;
        if !(u >= 0.0 && v >= 0.0 && u < k.width as f32 && v < k.height as f32) {
            return None;
        }
        let d = depth.data[v as usize * k.width as usize + u as usize];
        (d > 0.0).then_some(d)
    }

    /// Marches along `dir` from depth `t` to `far`: the first zero crossing
    /// seen from the front, `Ok(None)` for none, `Err(())` when the ray
    /// starts behind a surface.
    fn march(
        &self,
        sampler: &mut Sampler<'_>,
        dir: Vec3,
        mut t: f32,
        far: f32,
    ) -> Result<Option<(f32, Vec3)>, ()> {
        let origin = self.pose.translation;
        let block_size = self.voxel * BLOCK as f32;
        let len = dir.length();
        let voxel_step = self.voxel / len;
        let free_step = 0.8 * self.truncation / len;
        // The last sample in front of the surface.
        let mut previous: Option<(f32, f32)> = None;
        let mut first = true;
        while t < far {
            let p = origin + dir * t;
            match sampler.nearest(p) {
                Err(true) => {
                    // No block holds the nearest voxel: skip to where the
                    // ray leaves the points whose nearest voxel is in that
                    // block — the block's extent shifted down half a voxel,
                    // not the block the point itself lies in, which may be
                    // a block with surface (the point in its top half voxel).
                    previous = None;
                    let key = floor(p * sampler.scale + 0.5).div_euclid(IVec3::splat(BLOCK as i32));
                    let shifted = origin + Vec3::splat(0.5 * self.voxel);
                    t = block_exit(shifted, dir, key.as_vec3(), block_size).max(t)
                        + voxel_step * 0.5;
                }
                Err(false) => {
                    previous = None;
                    t += voxel_step;
                }
                Ok(f) if f < 0.0 => {
                    // The nearest voxel is behind the surface; the trilinear
                    // field decides (near a silhouette the ray may still pass
                    // in front of it).
                    match (previous, sampler.sample(p)) {
                        (_, None) => previous = None,
                        (_, Some(g)) if g >= 0.0 => previous = Some((t, g)),
                        (Some((t0, f0)), Some(g)) => {
                            let hit = crossing(sampler, origin, dir, voxel_step, (t0, f0), (t, g));
                            return Ok(Some((hit, origin + dir * hit)));
                        }
                        (None, Some(_)) if first => return Err(()),
                        // Entered from the unknown.
                        (None, Some(_)) => return Ok(None),
                    }
                    t += voxel_step;
                }
                Ok(f) => {
                    previous = Some((t, f));
                    // Far from the surface the distance allows big steps.
                    t += (f * free_step).max(voxel_step);
                }
            }
            first = false;
        }
        Ok(None)
    }
}
