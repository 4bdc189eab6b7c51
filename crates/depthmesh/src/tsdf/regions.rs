//! Space cut into regions, and regions dealt into shards: how a cluster
//! splits one TSDF map between workers.
//!
//! A region is a cube of whole blocks, so a block belongs to exactly one
//! region and fusing a frame into a region needs nothing from any other
//! (see [`super::TsdfVolume::integrate_where`]). Regions are dealt into a
//! fixed number of shards by a hash of their coordinates; a shard is what a
//! worker owns, checkpoints and hands over. Hashing spreads every view over
//! all shards, so each worker fuses a share of every frame instead of one
//! worker fusing the room the sensors are in while the others wait; the
//! price is more shard borders, which only the assembled map crosses.

use crate::error::{Error, Result};
use glam::IVec3;
use serde::{Deserialize, Serialize};

/// The cut of a map into regions and shards. Its numbers are part of a
/// site's identity: every worker must deal blocks the same way.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Regions {
    /// Blocks along each side of a region.
    pub region_blocks: i32,
    /// Shards the regions are dealt into.
    pub shards: u32,
}

impl Regions {
    /// Regions of 8³ blocks (64 voxels a side: 64 cm at 1 cm voxels, about
    /// the truncation band of a wall seen across a room) in 16 shards: room
    /// for up to 16 workers, and a view of a room touches most shards.
    pub fn new() -> Self {
        Regions {
            region_blocks: 8,
            shards: 16,
        }
    }

    /// Checks the numbers (1–64 blocks a side, 1–4096 shards).
    pub fn validate(&self) -> Result<()> {
        if !(1..=64).contains(&self.region_blocks) {
            return Err(Error::parameter(
                "region_blocks",
                format!("{} must be 1 to 64", self.region_blocks),
            ));
        }
        if !(1..=4096).contains(&self.shards) {
            return Err(Error::parameter(
                "shards",
                format!("{} must be 1 to 4096", self.shards),
            ));
        }
        Ok(())
    }

    /// The region holding block `block`.
    #[inline]
    pub fn region_of(&self, block: IVec3) -> IVec3 {
        IVec3::new(
            block.x.div_euclid(self.region_blocks),
            block.y.div_euclid(self.region_blocks),
            block.z.div_euclid(self.region_blocks),
        )
    }

    /// The shard region `region` is dealt to: a fixed mix of its
    /// coordinates (the same on every machine and in every version, since
    /// checkpoints are kept by shard).
    #[inline]
    pub fn shard_of_region(&self, region: IVec3) -> u32 {
        let mut h: u64 = 0x9e37_79b9_7f4a_7c15;
        for c in [region.x, region.y, region.z] {
            h = (h ^ u64::from(c as u32)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            h ^= h >> 31;
        }
        (h % u64::from(self.shards)) as u32
    }

    /// The shard block `block` belongs to.
    #[inline]
    pub fn shard_of(&self, block: IVec3) -> u32 {
        self.shard_of_region(self.region_of(block))
    }
}

impl Default for Regions {
    fn default() -> Self {
        Regions::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{Intrinsics, Pose};
    use crate::image::DepthImage;
    use crate::tsdf::{TsdfConfig, TsdfVolume};
    use glam::{Mat3, Vec3};

    #[test]
    fn a_block_belongs_to_the_region_that_contains_it_on_both_sides_of_zero() {
        let r = Regions::new();
        assert_eq!(r.region_of(IVec3::new(0, 7, -1)), IVec3::new(0, 0, -1));
        assert_eq!(r.region_of(IVec3::new(-8, 8, -9)), IVec3::new(-1, 1, -2));
    }

    #[test]
    fn regions_are_spread_over_every_shard() {
        let r = Regions::new();
        let mut counts = vec![0u32; r.shards as usize];
        for x in -4..4 {
            for y in -2..2 {
                for z in -4..4 {
                    counts[r.shard_of_region(IVec3::new(x, y, z)) as usize] += 1;
                }
            }
        }
        // 256 regions in 16 shards: 16 each on average.
        assert!(counts.iter().all(|&c| (6..=28).contains(&c)), "{counts:?}");
    }

    #[test]
    fn shards_fused_apart_hold_exactly_the_blocks_of_one_volume() {
        let k = Intrinsics::from_vertical_fov(64, 48, 50.0);
        let mut depth = DepthImage::default();
        depth.reset(64, 48);
        for (i, d) in depth.data.iter_mut().enumerate() {
            *d = 1.0 + 0.3 * ((i % 64) as f32 / 64.0) + 0.1 * ((i / 64) as f32 / 48.0);
        }
        let poses = [
            Pose::IDENTITY,
            Pose::new(Mat3::from_rotation_y(0.2), Vec3::new(0.1, 0.0, 0.05)),
        ];
        let config = TsdfConfig::new(0.02);
        let regions = Regions {
            region_blocks: 1,
            shards: 3,
        };
        let mut whole = TsdfVolume::new(config).unwrap();
        let mut parts: Vec<TsdfVolume> = (0..3).map(|_| TsdfVolume::new(config).unwrap()).collect();
        for pose in &poses {
            whole.integrate(&depth, None, &k, pose).unwrap();
            for (s, part) in parts.iter_mut().enumerate() {
                part.integrate_where(&depth, None, &k, pose, |b| regions.shard_of(b) == s as u32)
                    .unwrap();
            }
        }
        let held: usize = parts.iter().map(|p| p.blocks().len()).sum();
        assert_eq!(held, whole.blocks().len());
        assert!(parts.iter().all(|p| !p.blocks().is_empty()));
        for part in &parts {
            for b in part.blocks() {
                let w = whole.block(b.key).expect("block of the whole volume");
                assert_eq!(w.tsdf, b.tsdf);
                assert_eq!(w.weight, b.weight);
            }
        }
    }
}
