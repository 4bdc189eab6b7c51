//! What changed in a block, precisely enough to re-mesh only what it affects.
//!
//! A block's mesh piece reads its own voxels and the two lowest voxel layers
//! of its seven neighbours above (see [`super::mesh`]). Fusion often leaves
//! that input as it was — voxels in free space stay truncated at +1 and only
//! gain weight — and a change inside a block's upper layers concerns no
//! block below it. So fusion records, per block, the last frame that changed
//! a voxel *as the mesh sees it* (stored distance, colour, or becoming
//! observed), separately for the part each of the eight readers (the block
//! itself and the seven blocks below) reads, and the last frame that changed
//! any weight (for meshes that need more than one observation).

use super::{voxel_index, BLOCK, BLOCK_VOXELS};
use std::sync::OnceLock;

/// Last frames (1-based; 0 = never) a block changed, by who reads the change.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Changes {
    /// Indexed by the offset `o` of the reader at `key − o` (bit 0: x, bit 1:
    /// y, bit 2: z); `[0]` is the block itself, so any change at all.
    pub values: [u32; 8],
    /// Any weight, including weights that only grew.
    pub weights: u32,
    /// Fusion allocated the block or changed any voxel of it (0: not
    /// since it was put back from elsewhere, a map store, which holds it
    /// as it is): what a store must write again.
    pub fused: u32,
}

impl Changes {
    /// The last frame that changed what the block at `key − offset` meshes
    /// from, for a mesh that counts voxels of weight ≥ `min_weight` as observed.
    #[inline]
    pub fn affecting(&self, offset: usize, min_weight: u16) -> u32 {
        if min_weight <= 1 {
            self.values[offset]
        } else {
            // Crossing a higher weight threshold is not tracked: any weight
            // change may matter, to every reader.
            self.values[offset].max(self.weights)
        }
    }

    /// Records a frame's changes: `readers` is a bit mask of offsets (as
    /// from [`readers`]), `weights` whether any weight changed.
    #[inline]
    pub fn record(&mut self, frame: u32, readers: u8, weights: bool) {
        for (o, at) in self.values.iter_mut().enumerate() {
            if readers & (1 << o) != 0 {
                *at = frame;
            }
        }
        if weights {
            self.weights = frame;
        }
        if weights || readers != 0 {
            self.fused = frame;
        }
    }
}

/// Per voxel of a block, the bit mask of offsets `o` whose block at
/// `key − o` reads the voxel (bit 0 always: the block itself).
pub fn readers() -> &'static [u8; BLOCK_VOXELS] {
    static TABLE: OnceLock<[u8; BLOCK_VOXELS]> = OnceLock::new();
    TABLE.get_or_init(|| {
        let mut table = [0u8; BLOCK_VOXELS];
        for z in 0..BLOCK {
            for y in 0..BLOCK {
                for x in 0..BLOCK {
                    let low = [x < 2, y < 2, z < 2];
                    table[voxel_index(x, y, z)] = (0..8u8)
                        .filter(|o| (0..3).all(|a| o & (1 << a) == 0 || low[a]))
                        .fold(0, |mask, o| mask | 1 << o);
                }
            }
        }
        table
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corner_voxel_is_read_by_all_eight_and_an_upper_voxel_by_its_own_block_only() {
        assert_eq!(readers()[voxel_index(0, 1, 0)], 0xff);
        assert_eq!(readers()[voxel_index(5, 5, 5)], 1);
        // Low in x only: read by the block itself and the one at −x.
        assert_eq!(readers()[voxel_index(1, 4, 7)], 0b11);
    }

    #[test]
    fn weight_changes_matter_only_above_one_observation() {
        let mut c = Changes::default();
        c.record(3, 1, true);
        assert_eq!((c.affecting(0, 1), c.affecting(1, 1)), (3, 0));
        assert_eq!(c.affecting(1, 2), 3);
    }
}
