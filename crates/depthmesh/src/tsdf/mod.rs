//! Truncated signed distance fusion (Curless–Levoy, as in KinectFusion and
//! KinfuLS) in a sparse map of 8×8×8 voxel blocks with no fixed extent.
//!
//! Each voxel keeps its truncated distance as an `i16` (−1..1 scaled) and its
//! weight as a `u16`: 4 bytes. Blocks are allocated along each pixel's
//! truncation band and integrated in parallel, block by block; a block's
//! mesh is rebuilt only when what it is meshed from changed (see [`changes`]
//! and [`mesh`]).

pub mod archive;
pub mod cases;
pub mod changes;
pub mod evict;
pub mod mapper;
pub mod mesh;
pub mod raycast;
pub mod regions;

use crate::camera::{Intrinsics, Pose};
use crate::error::{Error, Result};
use crate::image::{ColorImage, DepthImage};
use changes::Changes;
use glam::{IVec3, Vec3};
use rayon::prelude::*;
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

/// Voxels along each side of a block.
pub const BLOCK: usize = 8;
/// Voxels in a block.
pub const BLOCK_VOXELS: usize = BLOCK * BLOCK * BLOCK;
/// Scale of the stored distance: ±1 (the truncation) maps to ±32767.
const TSDF_SCALE: f32 = 32767.0;

/// Axial depth noise (σ, metres) of a structured-light depth camera at `z`
/// metres (Nguyen, Izadi and Lovell 2012, the Kinect): the spread a map's
/// truncation bands take over many frames.
fn depth_noise(z: f64) -> f64 {
    0.0012 + 0.0019 * (z - 0.4).powi(2)
}

/// Parameters of the fusion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TsdfConfig {
    /// Voxel edge in metres.
    pub voxel: f32,
    /// Truncation distance in metres.
    pub truncation: f32,
    /// Weights stop growing here, so the map keeps adapting to change.
    pub max_weight: u16,
    /// Keep an RGB colour per voxel (3 more bytes) from the frames' colour images.
    pub color: bool,
    /// Marching cubes meshes only voxels fused at least this often (Open3D's
    /// `weight_threshold`): above 1 it drops surface seen once, such as
    /// flying pixels, at the cost of surface at the edge of the views.
    pub min_weight: u16,
}

impl TsdfConfig {
    /// 1 cm voxels and a truncation of 4 voxels, as the reference tools use.
    pub fn new(voxel: f32) -> Self {
        TsdfConfig {
            voxel,
            truncation: 4.0 * voxel,
            max_weight: 1024,
            color: false,
            min_weight: 1,
        }
    }

    /// Bytes a voxel takes: a distance and a weight, and a colour if kept.
    pub fn bytes_per_voxel(&self) -> usize {
        if self.color {
            7
        } else {
            4
        }
    }

    /// About how many bytes of voxels mapping `frames` frames of camera `k`
    /// of surfaces `depth` metres away allocates (the far limit gives an
    /// upper bound): the least of two bounds. Each frame allocates at most
    /// the blocks its truncation band crosses (along the steepest ray), a
    /// block column per block-wide patch of the view at `depth` (at most one
    /// per pixel); and frames of one view fuse into
    /// the same columns, but a depth camera's noise spreads their bands over
    /// ±3σ. A moving camera sees more than one view, so this is a floor for
    /// refusing settings no machine can hold, not a promise.
    pub fn estimate_bytes(&self, k: &Intrinsics, depth: f32, frames: usize) -> f64 {
        let side = f64::from(self.voxel) * BLOCK as f64;
        let z = f64::from(depth);
        let across = |pixels: u32, f: f32| f64::from(pixels) * z / (f64::from(f) * side) + 1.0;
        let columns = (across(k.width, k.fx) * across(k.height, k.fy))
            .min(f64::from(k.width) * f64::from(k.height));
        // A band of depth `band` along the steepest (corner) ray crosses
        // block faces across the view as well as along it.
        let slope = |size: u32, c: f32, f: f32| f64::from(c.max(size as f32 - c) / f);
        let (sx, sy) = (slope(k.width, k.cx, k.fx), slope(k.height, k.cy, k.fy));
        let blocks_along = |band: f64| {
            let crossings = |length: f64| (length / side).ceil();
            crossings(band) + crossings(band * sx) + crossings(band * sy) + 1.0
        };
        let per_frame = blocks_along(2.0 * f64::from(self.truncation));
        let fused = blocks_along((6.0 * depth_noise(z)).max(2.0 * f64::from(self.truncation)));
        let blocks = columns * (per_frame * frames as f64).min(fused);
        blocks * (BLOCK_VOXELS * self.bytes_per_voxel()) as f64
    }

    /// Rejects sizes that make no sense.
    pub fn validate(&self) -> Result<()> {
        if !(self.voxel.is_finite() && self.voxel > 0.0) {
            return Err(Error::parameter(
                "voxel",
                format!("must be a positive size in metres, got {}", self.voxel),
            ));
        }
        if !(self.truncation.is_finite() && self.truncation >= self.voxel) {
            return Err(Error::parameter(
                "truncation",
                format!(
                    "must be at least one voxel ({} m), got {}",
                    self.voxel, self.truncation
                ),
            ));
        }
        if self.max_weight == 0 {
            return Err(Error::parameter("max weight", "must be at least 1"));
        }
        if !(1..=self.max_weight).contains(&self.min_weight) {
            return Err(Error::parameter(
                "min_weight",
                format!(
                    "must be between 1 and the largest weight {}, got {}",
                    self.max_weight, self.min_weight
                ),
            ));
        }
        Ok(())
    }
}

/// Offsets of a block and its seven neighbours above (+x, +y, +z combined).
pub const ABOVE: [IVec3; 8] = [
    IVec3::new(0, 0, 0),
    IVec3::new(1, 0, 0),
    IVec3::new(0, 1, 0),
    IVec3::new(1, 1, 0),
    IVec3::new(0, 0, 1),
    IVec3::new(1, 0, 1),
    IVec3::new(0, 1, 1),
    IVec3::new(1, 1, 1),
];

/// The voxels of one block.
#[derive(Clone, Debug)]
pub struct Block {
    /// Block coordinates (world position / (voxel · 8), floored).
    pub key: IVec3,
    /// Truncated signed distance per voxel, x fastest, scaled by 32767.
    pub tsdf: Box<[i16; BLOCK_VOXELS]>,
    /// Fusion weight per voxel; 0 = never observed.
    pub weight: Box<[u16; BLOCK_VOXELS]>,
    /// Averaged colour per voxel, when the volume keeps colour.
    pub color: Option<Box<[[u8; 3]; BLOCK_VOXELS]>>,
}

/// Whether a depth value is a measurement: positive and finite. NaN or an
/// infinity handed in by a caller counts as none, like 0.
#[inline]
fn measured(d: f32) -> bool {
    d > 0.0 && d < f32::INFINITY
}

/// Index of voxel `(x, y, z)` inside a block.
#[inline]
pub fn voxel_index(x: usize, y: usize, z: usize) -> usize {
    x + BLOCK * (y + BLOCK * z)
}

/// A fast hash for block keys (integer triples from a small range).
#[derive(Default)]
pub struct KeyHasher(u64);

impl Hasher for KeyHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }

    fn write_i32(&mut self, v: i32) {
        self.write_u64(v as u32 as u64);
    }

    fn write_u64(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(5) ^ v).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
}

/// A map keyed by block coordinates with the fast key hash.
pub type KeyMap<V> = HashMap<IVec3, V, BuildHasherDefault<KeyHasher>>;

/// Block key → index into the block list.
pub type BlockIndex = KeyMap<u32>;

/// The sparse TSDF volume.
#[derive(Debug)]
pub struct TsdfVolume {
    config: TsdfConfig,
    blocks: Vec<Block>,
    index: BlockIndex,
    /// Per block: the frames that last changed it, by who reads the change.
    changes: Vec<Changes>,
    frames: u32,
    /// Only blocks wholly within this distance of the camera are fused.
    reach: Option<f32>,
    /// Scratch: block keys touched by the current frame.
    keys: Vec<IVec3>,
}

impl TsdfVolume {
    /// An empty volume.
    pub fn new(config: TsdfConfig) -> Result<Self> {
        config.validate()?;
        Ok(TsdfVolume {
            config,
            blocks: Vec::new(),
            index: BlockIndex::default(),
            changes: Vec::new(),
            frames: 0,
            reach: None,
            keys: Vec::new(),
        })
    }

    /// The parameters.
    pub fn config(&self) -> &TsdfConfig {
        &self.config
    }

    /// All allocated blocks.
    pub fn blocks(&self) -> &[Block] {
        &self.blocks
    }

    /// The key → block index map.
    pub fn index(&self) -> &BlockIndex {
        &self.index
    }

    /// Frames integrated so far.
    pub fn frames(&self) -> u32 {
        self.frames
    }

    /// Per block, the frames that last changed it (1-based; 0 = never).
    pub fn changes(&self) -> &[Changes] {
        &self.changes
    }

    /// Fuse only into blocks that reach within `radius` metres of the
    /// camera (KinfuLS's volume around the camera; see [`evict`]). Not
    /// validated here: [`evict::ActiveRegion::new`] checks the radius.
    pub fn set_reach(&mut self, radius: f32) {
        self.reach = Some(radius);
    }

    /// Distance from `point` to the nearest point of block `key`.
    #[inline]
    pub fn block_distance(&self, key: IVec3, point: Vec3) -> f32 {
        let side = self.config.voxel * BLOCK as f32;
        let lo = key.as_vec3() * side;
        point.clamp(lo, lo + side).distance(point)
    }

    /// Bytes held by the voxels (see [`TsdfConfig::bytes_per_voxel`]).
    pub fn voxel_bytes(&self) -> usize {
        self.blocks.len() * BLOCK_VOXELS * self.config.bytes_per_voxel()
    }

    /// World position of voxel `(x, y, z)` of the block with `key`.
    #[inline]
    pub fn voxel_position(&self, key: IVec3, x: usize, y: usize, z: usize) -> Vec3 {
        let v = self.config.voxel;
        (key * BLOCK as i32).as_vec3() * v + Vec3::new(x as f32, y as f32, z as f32) * v
    }

    /// Fuses one depth image (metres; 0, NaN or an infinity = none) taken
    /// from `pose`, and its colour image (same camera) when the volume keeps
    /// colour.
    pub fn integrate(
        &mut self,
        depth: &DepthImage,
        color: Option<&ColorImage>,
        intrinsics: &Intrinsics,
        pose: &Pose,
    ) -> Result<()> {
        self.integrate_where(depth, color, intrinsics, pose, |_| true)
    }

    /// [`TsdfVolume::integrate`] into only the blocks whose key `keep`
    /// accepts: a block's fusion depends on nothing but the frame and the
    /// block, so volumes that split the blocks between them (the shards of
    /// a cluster) hold exactly what one volume fusing everything holds.
    pub fn integrate_where(
        &mut self,
        depth: &DepthImage,
        color: Option<&ColorImage>,
        intrinsics: &Intrinsics,
        pose: &Pose,
        keep: impl Fn(IVec3) -> bool + Sync,
    ) -> Result<()> {
        let color = match (self.config.color, color) {
            (true, Some(c)) if c.width != depth.width || c.height != depth.height => {
                return Err(Error::parameter(
                    "colour image",
                    format!(
                        "{}×{} but the depth image is {}×{}",
                        c.width, c.height, depth.width, depth.height
                    ),
                ));
            }
            (true, c) => c,
            (false, _) => None,
        };
        if depth.width != intrinsics.width || depth.height != intrinsics.height {
            return Err(Error::parameter(
                "depth image",
                format!(
                    "{}×{} but the camera is {}×{}",
                    depth.width, depth.height, intrinsics.width, intrinsics.height
                ),
            ));
        }
        self.frames += 1;
        self.allocate(depth, intrinsics, pose, keep);
        let frame = self.frames;
        let touched: Vec<bool> = {
            let mut t = vec![false; self.blocks.len()];
            for k in &self.keys {
                t[self.index[k] as usize] = true;
            }
            t
        };
        let config = self.config;
        // 1 / (w + 1) for every weight a voxel can have: a division less per voxel.
        let reciprocal: Vec<f32> = (0..=config.max_weight as usize)
            .map(|w| 1.0 / (w as f32 + 1.0))
            .collect();
        let world_to_camera = pose.inverse();
        let k = *intrinsics;
        self.blocks
            .par_iter_mut()
            .zip(self.changes.par_iter_mut())
            .zip(touched.par_iter())
            .filter(|(_, t)| **t)
            .for_each(|((block, changes), _)| {
                let (readers, weights) = integrate_block(
                    block,
                    &config,
                    &k,
                    &world_to_camera,
                    depth,
                    color,
                    &reciprocal,
                );
                changes.record(frame, readers, weights);
            });
        Ok(())
    }

    /// Allocates the blocks within the truncation band of every measured
    /// pixel, and leaves their keys in `self.keys`.
    fn allocate(
        &mut self,
        depth: &DepthImage,
        k: &Intrinsics,
        pose: &Pose,
        keep: impl Fn(IVec3) -> bool + Sync,
    ) {
        let c = self.config;
        let block_size = c.voxel * BLOCK as f32;
        // Blocks are 8 voxels wide, so sampling every few pixels and every
        // half block along the band cannot miss one: the gap between sampled
        // rays, at most `(max depth + truncation) · step / f`, stays below half a block.
        let farthest = depth
            .data
            .iter()
            .fold(0.0f32, |m, &d| if measured(d) { m.max(d) } else { m })
            + c.truncation;
        let step =
            ((0.5 * block_size * k.fx.min(k.fy) / farthest.max(1e-3)).floor() as usize).clamp(1, 8);
        let w = depth.width as usize;
        let rows: Vec<Vec<IVec3>> = (0..depth.height as usize)
            .into_par_iter()
            .step_by(step)
            .map(|r| {
                let mut keys = Vec::new();
                for col in (0..w).step_by(step) {
                    let d = depth.data[r * w + col];
                    if !measured(d) {
                        continue;
                    }
                    let ray = pose.transform_vector(k.back_project(col as f32, r as f32, 1.0));
                    let (near, far) = ((d - c.truncation).max(0.0), d + c.truncation);
                    let samples = (((far - near) * ray.length()) / (0.5 * block_size))
                        .ceil()
                        .max(1.0) as usize;
                    for s in 0..=samples {
                        let z = near + (far - near) * s as f32 / samples as f32;
                        let p = pose.translation + ray * z;
                        let key = (p / block_size).floor().as_ivec3();
                        // Samples along a ray mostly stay in one block.
                        // Blocks not kept are dropped here, before the sort.
                        if keys.last() != Some(&key) && keep(key) {
                            keys.push(key);
                        }
                    }
                }
                // Neighbouring rays hit the same blocks: thin the row out
                // here, in parallel, so the merge below sorts far fewer keys.
                keys.sort_unstable_by_key(|k| (k.x, k.y, k.z));
                keys.dedup();
                keys
            })
            .collect();
        self.keys.clear();
        for r in rows {
            self.keys.extend(r);
        }
        self.keys.par_sort_unstable_by_key(|k| (k.x, k.y, k.z));
        self.keys.dedup();
        if let Some(radius) = self.reach {
            let camera = pose.translation;
            let keys = std::mem::take(&mut self.keys);
            self.keys = keys
                .into_iter()
                .filter(|&k| self.block_distance(k, camera) <= radius)
                .collect();
        }
        for &key in &self.keys {
            if !self.index.contains_key(&key) {
                self.index.insert(key, self.blocks.len() as u32);
                self.blocks.push(Block {
                    key,
                    tsdf: Box::new([0; BLOCK_VOXELS]),
                    weight: Box::new([0; BLOCK_VOXELS]),
                    color: c.color.then(|| Box::new([[0; 3]; BLOCK_VOXELS])),
                });
                self.changes.push(Changes {
                    fused: self.frames,
                    ..Changes::default()
                });
            }
        }
    }

    /// Puts back blocks saved after `frames` fused frames (a map store's
    /// checkpoint): the volume continues as the one that was saved. Every
    /// block counts as changed at `frames`, so the first mesh made from it
    /// meshes them all. A block whose key is already held replaces it.
    pub fn restore(&mut self, blocks: Vec<Block>, frames: u32) -> Result<()> {
        self.frames = self.frames.max(frames);
        self.put_back(blocks, frames)
    }

    /// Puts back blocks kept elsewhere while the volume went on (bounded
    /// memory with a map store): they count as changed by the next frame, so
    /// the mesh made after it includes them and the blocks below them, but
    /// not as fused (where they came from holds them as they are).
    pub fn load(&mut self, blocks: Vec<Block>) -> Result<()> {
        self.put_back(blocks, self.frames + 1)
    }

    fn put_back(&mut self, blocks: Vec<Block>, changed_at: u32) -> Result<()> {
        let colour = self.config.color;
        for block in blocks {
            if block.color.is_some() != colour {
                return Err(Error::parameter(
                    "color",
                    "a saved block's colour does not match the volume's setting",
                ));
            }
            let changed = Changes {
                values: [changed_at; 8],
                weights: changed_at,
                fused: 0,
            };
            match self.index.get(&block.key) {
                Some(&i) => {
                    self.blocks[i as usize] = block;
                    self.changes[i as usize] = changed;
                }
                None => {
                    self.index.insert(block.key, self.blocks.len() as u32);
                    self.blocks.push(block);
                    self.changes.push(changed);
                }
            }
        }
        Ok(())
    }

    /// The keys of blocks fusion allocated or changed (any voxel, weights
    /// included) after frame `since`; blocks put back by [`TsdfVolume::restore`]
    /// or [`TsdfVolume::load`] count only once fused again.
    pub fn changed_after(&self, since: u32) -> Vec<IVec3> {
        self.blocks
            .iter()
            .zip(&self.changes)
            .filter(|(_, c)| c.fused > since)
            .map(|(b, _)| b.key)
            .collect()
    }

    /// The block with key `key`, if held.
    pub fn block(&self, key: IVec3) -> Option<&Block> {
        self.index.get(&key).map(|&i| &self.blocks[i as usize])
    }

    /// Frees the blocks with the given keys (keys not in the map are ignored).
    /// Block indices change: the last block moves into each freed slot.
    pub fn remove_blocks(&mut self, keys: &[IVec3]) {
        self.take_blocks(keys);
    }

    /// Takes the blocks with the given keys out of the volume, each with the
    /// frame fusion last changed it ([`Changes::fused`]); as
    /// [`TsdfVolume::remove_blocks`].
    pub fn take_blocks(&mut self, keys: &[IVec3]) -> Vec<(Block, u32)> {
        let mut taken = Vec::with_capacity(keys.len());
        for key in keys {
            let Some(i) = self.index.remove(key) else {
                continue;
            };
            let i = i as usize;
            let block = self.blocks.swap_remove(i);
            taken.push((block, self.changes.swap_remove(i).fused));
            if let Some(moved) = self.blocks.get(i) {
                self.index.insert(moved.key, i as u32);
            }
        }
        taken
    }

    /// The truncated distance (in units of the truncation, −1..1) and weight
    /// of the voxel at integer voxel coordinates `v`, if its block exists.
    #[inline]
    pub fn voxel(&self, v: IVec3) -> Option<(f32, u16)> {
        let key = v.div_euclid(IVec3::splat(BLOCK as i32));
        let local = v.rem_euclid(IVec3::splat(BLOCK as i32));
        let b = &self.blocks[*self.index.get(&key)? as usize];
        let i = voxel_index(local.x as usize, local.y as usize, local.z as usize);
        Some((f32::from(b.tsdf[i]) / TSDF_SCALE, b.weight[i]))
    }
}

/// Fuses a depth image into one block. Returns the readers (see
/// [`changes::readers`]) of the voxels whose distance, colour or observed
/// state changed, and whether any weight changed.
fn integrate_block(
    block: &mut Block,
    c: &TsdfConfig,
    k: &Intrinsics,
    world_to_camera: &Pose,
    depth: &DepthImage,
    color: Option<&ColorImage>,
    reciprocal: &[f32],
) -> (u8, bool) {
    let v = c.voxel;
    let origin = (block.key * BLOCK as i32).as_vec3() * v;
    let base = world_to_camera.transform_point(origin);
    let r = world_to_camera.rotation;
    let (dx, dy, dz) = (r.x_axis * v, r.y_axis * v, r.z_axis * v);
    let (w, h) = (depth.width as i32, depth.height as i32);
    let inv_trunc = 1.0 / c.truncation;
    let readers_of = changes::readers();
    let (mut readers, mut weights) = (0u8, false);
    // A row of voxels at a time: first project all eight (branch-free, so it
    // vectorises), then update those that land on a measurement.
    let mut pixel = [0usize; BLOCK];
    let mut inside = [false; BLOCK];
    let mut depth_z = [0.0f32; BLOCK];
    for z in 0..BLOCK {
        for y in 0..BLOCK {
            let row = base + dy * y as f32 + dz * z as f32;
            for x in 0..BLOCK {
                let p = row + dx * x as f32;
                // Nearest pixel, as the reference implementations do; the
                // range test comes first so truncation is flooring.
                let inv = 1.0 / p.z;
                let fu = k.fx * p.x * inv + k.cx + 0.5;
                let fv = k.fy * p.y * inv + k.cy + 0.5;
                inside[x] = p.z > 0.0 && fu >= 0.0 && fv >= 0.0 && fu < w as f32 && fv < h as f32;
                // Pixel 0 stands in outside the image; `inside` rules it out.
                let index = ((fv as i32) * w + fu as i32) as usize;
                pixel[x] = if inside[x] { index } else { 0 };
                depth_z[x] = p.z;
            }
            for x in 0..BLOCK {
                let px = pixel[x];
                let d = depth.data[px];
                let sdf = d - depth_z[x];
                // One branch for the three reasons to leave a voxel alone:
                // which of them applies is hard to predict.
                if !(inside[x] & measured(d) & (sdf >= -c.truncation)) {
                    continue;
                }
                let t = (sdf * inv_trunc).min(1.0);
                let i = voxel_index(x, y, z);
                let wt = block.weight[i];
                // Running average in stored units: old + (new − old) / (w + 1),
                // rounded half away from zero without a libm call.
                let old = block.tsdf[i];
                let o = f32::from(old);
                let fused = o + (t * TSDF_SCALE - o) * reciprocal[usize::from(wt)];
                let new = (fused + 0.5f32.copysign(fused)) as i16;
                block.tsdf[i] = new;
                block.weight[i] = (wt + 1).min(c.max_weight);
                let mut seen = new != old || wt == 0;
                // Colour is averaged with the distance's own weight, so it
                // must be fused whenever the distance is (as Open3D does):
                // fused only near the surface, a voxel first seen as free
                // space would average its first colour with black.
                if let (Some(colors), Some(image)) = (block.color.as_deref_mut(), color) {
                    let (old, new) = (colors[i], image.data[px]);
                    colors[i] = std::array::from_fn(|ch| {
                        let o = f32::from(old[ch]);
                        (o + (f32::from(new[ch]) - o) * reciprocal[usize::from(wt)] + 0.5) as u8
                    });
                    seen |= colors[i] != old;
                }
                readers |= readers_of[i] & 0u8.wrapping_sub(u8::from(seen));
                weights = true;
            }
        }
    }
    (readers, weights)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bytes one frame of a wall facing the camera at `z` metres allocates.
    fn wall_bytes(config: TsdfConfig, k: &Intrinsics, z: f32) -> usize {
        let mut volume = TsdfVolume::new(config).unwrap();
        let mut depth = DepthImage::new(k.width, k.height);
        depth.data.fill(z);
        volume.integrate(&depth, None, k, &Pose::IDENTITY).unwrap();
        volume.voxel_bytes()
    }

    #[test]
    fn the_estimate_bounds_a_frame_and_grows_as_voxels_shrink() {
        let k = Intrinsics::from_vertical_fov(160, 120, 60.0);
        for voxel in [0.002, 0.01, 0.05] {
            let config = TsdfConfig::new(voxel);
            // A wall at the far limit is the frame that allocates most.
            let actual = wall_bytes(config, &k, 4.0) as f64;
            let estimate = config.estimate_bytes(&k, 4.0, 1);
            // An upper bound for one frame, and within 4× of it: the
            // bound counts every block the steepest ray's band crosses.
            assert!(actual <= estimate, "{voxel}: {actual} > {estimate}");
            assert!(estimate <= 4.0 * actual, "{voxel}: {estimate} ≫ {actual}");
        }
        let a = TsdfConfig::new(0.01).estimate_bytes(&k, 4.0, 100);
        let b = TsdfConfig::new(0.001).estimate_bytes(&k, 4.0, 100);
        // Ten times finer voxels: up to 100× the block columns (fewer once
        // each pixel has its own) and more blocks along each ray.
        assert!(b > 10.0 * a, "{b} vs {a}");
    }
}
