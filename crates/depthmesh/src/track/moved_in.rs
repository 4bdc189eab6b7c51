//! What moved into view: where a held frame (followed, not fused: it put
//! points in space earlier frames saw empty, [`crate::track::free_space`])
//! saw those points, kept for the frame after it.
//!
//! Something that walks through the view (a person crossing between the
//! camera and the furniture) hides the map's surface behind it, and a
//! followed frame is held to the share of that surface it sees where the
//! map does. Counted, a person covering a quarter of the view read as a
//! contradiction and lost a camera that was held right on. Counting no
//! point in front of the surface was tried, and a wrong pose after a
//! jump, which also puts points in front of the surface, was then held
//! instead of searched for. What tells the two apart is time: a person
//! comes into view over frames, and the frames while they are there are
//! held; a wrong pose comes at once. So only where the held frame before
//! saw something in the empty space, and around it as far as it may have
//! moved in a frame, are points in front of the surface left out.

use crate::tsdf::KeyMap;
use glam::{IVec3, Vec3};

/// Side of the cells the points are kept in (metres). A point is covered
/// by its own cell and the 26 around it, so what moves up to a cell in a
/// frame (3 m/s at 30 Hz) is still covered in the next.
const CELL: f32 = 0.1;

/// The cells around what the last held frame saw moved in (see the module
/// docs); empty after a frame fused or lost.
#[derive(Clone, Debug, Default)]
pub struct MovedIn {
    cells: KeyMap<()>,
}

impl MovedIn {
    /// Forgets everything: the frame was fused or lost.
    pub fn clear(&mut self) {
        self.cells.clear();
    }

    /// Whether nothing is marked.
    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    /// Marks the cells around `point` (world coordinates).
    pub fn mark(&mut self, point: Vec3) {
        let centre = cell_of(point);
        if self.cells.contains_key(&centre) {
            // Its neighbours were marked with it.
            return;
        }
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    self.cells.insert(centre + IVec3::new(dx, dy, dz), ());
                }
            }
        }
    }

    /// Whether `point` (world coordinates) lies where something was seen
    /// moving in.
    pub fn covers(&self, point: Vec3) -> bool {
        self.cells.contains_key(&cell_of(point))
    }
}

/// The cell holding `p`.
fn cell_of(p: Vec3) -> IVec3 {
    (p / CELL).floor().as_ivec3()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mark_covers_what_moved_up_to_a_cell_and_no_further() {
        let mut moved = MovedIn::default();
        assert!(moved.is_empty());
        let at = Vec3::new(1.04, 0.85, -1.1);
        moved.mark(at);
        for step in [
            Vec3::ZERO,
            Vec3::X * 0.09,
            Vec3::NEG_Z * 0.08,
            Vec3::splat(0.05),
        ] {
            assert!(moved.covers(at + step), "{step}");
        }
        for step in [Vec3::X * 0.25, Vec3::NEG_Y * 0.3] {
            assert!(!moved.covers(at + step), "{step}");
        }
        moved.clear();
        assert!(moved.is_empty() && !moved.covers(at));
    }
}
