//! Space the frames have seen empty, for verifying a pose found without a
//! prediction: a frame whose points land deep inside it sees something
//! where earlier frames saw through to a surface behind. A place that
//! merely looks alike from where the frame was taken (a room's quarter
//! turn, a second table) puts part of the frame there; the camera's own
//! pose does not, on a static scene.
//!
//! Each frame the tracker keeps adds its rays, from its pose, to coarse
//! cells (`CELL`): a cell counts the rays that crossed it and whether a
//! ray ended (saw a surface) in it. A cell counts as empty only when
//! `MIN_CROSSINGS` rays crossed it and no ray ended in it or in the 26
//! around it: rays from poses that drift against each other by
//! centimetres cross cells where others saw a surface, and counting
//! crossings alone put up to 8 % of the kitchen's right frames in "empty"
//! space, against at most 0.02 % with the surfaces counted
//! (`docs/tracking-experiments.md`, "Telling a look-alike place from the
//! camera's own").
//!
//! Cost and size: one ray per `RAY_STRIDE`² pixels, stepped a cell at a
//! time (the kitchen's 300 frames track as fast as without it, within
//! run-to-run noise), and a few bytes per cell the rays reached. The cells are not
//! bounded like the map's active region, and a store saves them whole at
//! each checkpoint: the kitchen's 300 tracked frames end with 18,301 cells
//! (0.12 MB compressed), the simulated 60 m corridor walk of
//! `bench/tsdf_bounded.sh`, tracked, with 467,028 (2.8 MB, compressed in
//! 11 ms on the commit's thread); a walk of hundreds of metres would want
//! them kept and saved by region, as the map's blocks are.

use super::pyramid::Level;
use crate::camera::Pose;
use crate::tsdf::KeyMap;
use glam::{IVec3, Vec3};

/// Cell size (metres): a few times the depth noise of a Kinect-class
/// sensor at room range, so that noise does not reach across a cell.
const CELL: f32 = 0.08;

/// Rays that must have crossed a cell for it to count as empty: more
/// than one frame's worth of noise.
const MIN_CROSSINGS: u16 = 3;

/// Only every this many pixels of a frame, in each direction, is cast
/// (frames overlap, and the next frame's rays fall between these).
const RAY_STRIDE: usize = 16;

/// Rays start this far from the camera (metres): nearer, the sensor
/// measures nothing.
const RAY_START: f32 = 0.3;

/// A ray stops this many cells before its surface along the surface's
/// normal, so that a ray grazing a surface leaves the cells next to it
/// alone.
const STOP_CELLS: f32 = 2.0;

/// One frame point in this many (per direction) is looked up.
const CHECK_STRIDE: usize = 2;

#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Cell {
    /// Rays that crossed the cell.
    crossed: u16,
    /// A ray ended in the cell.
    surface: bool,
}

/// Space seen empty by a set of frames (see the module docs).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FreeSpace {
    /// Keyed with the block keys' fast hash: cells are looked up tens of
    /// thousands of times a frame.
    cells: KeyMap<Cell>,
    /// Frames added: where the next one's rays start in the stride, so
    /// that successive frames cast different pixels.
    added: usize,
}

/// Bytes of one cell in [`FreeSpace::encode`]: its key (three `i32`),
/// the rays that crossed it (`u16`) and whether one ended in it (`u8`).
const CELL_BYTES: usize = 15;

fn cell_of(p: Vec3) -> IVec3 {
    (p / CELL).floor().as_ivec3()
}

impl FreeSpace {
    /// Adds the rays of the frame whose camera-space points and normals are
    /// `view`, taken from `pose` (camera-to-world).
    pub fn add_view(&mut self, view: &Level, pose: &Pose) {
        let (w, h) = view.size();
        // Successive frames cast pixels offset by steps coprime to the
        // stride, covering it in turn.
        let (u0, v0) = (
            (self.added * 5) % RAY_STRIDE,
            (self.added * 11) % RAY_STRIDE,
        );
        self.added += 1;
        for v in (v0..h).step_by(RAY_STRIDE) {
            for u in (u0..w).step_by(RAY_STRIDE) {
                let i = v * w + u;
                let (p, n) = (view.points[i], view.normals[i]);
                if p.z <= 0.0 || n == Vec3::ZERO {
                    continue;
                }
                self.cells
                    .entry(cell_of(pose.transform_point(p)))
                    .or_default()
                    .surface = true;
                let length = p.length();
                let direction = p / length;
                // Grazing rays stop farther back: a floor seen at a low
                // angle is near the ray long before the ray reaches it.
                let facing = direction.dot(n).abs().max(0.05);
                let stop = length - STOP_CELLS * CELL / facing;
                let mut last = None;
                let mut t = RAY_START;
                while t < stop {
                    let cell = cell_of(pose.transform_point(direction * t));
                    if last != Some(cell) {
                        let c = self.cells.entry(cell).or_default();
                        c.crossed = c.crossed.saturating_add(1);
                        last = Some(cell);
                    }
                    t += CELL;
                }
            }
        }
    }

    /// Whether `cell` was crossed often enough, and no view saw a surface
    /// in it or in the 26 around it (checked only for a crossed cell, which
    /// a right pose's points rarely fall in).
    fn empty(&self, cell: IVec3) -> bool {
        if !self
            .cells
            .get(&cell)
            .is_some_and(|c| c.crossed >= MIN_CROSSINGS && !c.surface)
        {
            return false;
        }
        (-1..=1).all(|dz| {
            (-1..=1).all(|dy| {
                (-1..=1).all(|dx| {
                    !self
                        .cells
                        .get(&(cell + IVec3::new(dx, dy, dz)))
                        .is_some_and(|c| c.surface)
                })
            })
        })
    }

    /// The cells as bytes, to save with the tracker's state: the frames
    /// added (`u64`), then each cell ([`CELL_BYTES`]) in key order, so the
    /// same space gives the same bytes; little-endian.
    pub fn encode(&self) -> Vec<u8> {
        let mut cells: Vec<(&IVec3, &Cell)> = self.cells.iter().collect();
        cells.sort_unstable_by_key(|(k, _)| k.to_array());
        let mut out = Vec::with_capacity(8 + cells.len() * CELL_BYTES);
        out.extend((self.added as u64).to_le_bytes());
        for (key, cell) in cells {
            for x in key.to_array() {
                out.extend(x.to_le_bytes());
            }
            out.extend(cell.crossed.to_le_bytes());
            out.push(u8::from(cell.surface));
        }
        out
    }

    /// The space [`FreeSpace::encode`] wrote; why not, when `bytes` are
    /// not such.
    pub fn decode(bytes: &[u8]) -> Result<FreeSpace, String> {
        let (added, rest) = bytes
            .split_first_chunk::<8>()
            .ok_or("free space: no frame count")?;
        if rest.len() % CELL_BYTES != 0 {
            return Err(format!(
                "free space: {} bytes of cells, not whole cells",
                rest.len()
            ));
        }
        let added = usize::try_from(u64::from_le_bytes(*added))
            .map_err(|_| "free space: frame count out of range")?;
        let i = |b: &[u8]| i32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        let mut cells = KeyMap::default();
        cells.reserve(rest.len() / CELL_BYTES);
        for c in rest.chunks_exact(CELL_BYTES) {
            let surface = match c[14] {
                0 => false,
                1 => true,
                b => return Err(format!("free space: surface flag {b}")),
            };
            let key = IVec3::new(i(&c[..4]), i(&c[4..8]), i(&c[8..12]));
            let crossed = u16::from_le_bytes([c[12], c[13]]);
            if cells.insert(key, Cell { crossed, surface }).is_some() {
                return Err(format!("free space: cell {key} twice"));
            }
        }
        Ok(FreeSpace { cells, added })
    }

    /// Of the frame's measured points (camera space), seen from `pose`, the
    /// share that lands in cells seen empty.
    pub fn share_inside(&self, points: &[Vec3], width: usize, pose: &Pose) -> f64 {
        if self.cells.is_empty() || width == 0 {
            return 0.0;
        }
        let (mut measured, mut inside) = (0usize, 0usize);
        for row in points.chunks(width).step_by(CHECK_STRIDE) {
            for &p in row.iter().step_by(CHECK_STRIDE) {
                if p.z <= 0.0 {
                    continue;
                }
                measured += 1;
                inside += usize::from(self.empty(cell_of(pose.transform_point(p))));
            }
        }
        inside as f64 / measured.max(1) as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Intrinsics;
    use crate::image::DepthImage;
    use crate::track::pyramid::Pyramid;

    /// A 320×240 view of a wall `distance` metres ahead.
    fn wall(distance: f32) -> Pyramid {
        let k = Intrinsics::from_vertical_fov(320, 240, 60.0);
        let mut depth = DepthImage::new(320, 240);
        depth.data.fill(distance);
        let mut view = Pyramid::default();
        view.build(&depth, &k, 1);
        view
    }

    #[test]
    fn points_where_frames_saw_through_count_and_points_on_a_surface_do_not() {
        let view = wall(3.0);
        let share = |free: &FreeSpace, view: &Pyramid, pose: &Pose| {
            free.share_inside(&view.levels[0].points, 320, pose)
        };
        let mut free = FreeSpace::default();
        // Nothing seen yet: nothing is known empty.
        assert_eq!(share(&free, &view, &Pose::IDENTITY), 0.0);
        // A camera holding still for 48 frames, seeing the wall.
        for _ in 0..48 {
            free.add_view(&view.levels[0], &Pose::IDENTITY);
        }
        // The wall itself, from where it was seen, lies on its surface.
        assert_eq!(share(&free, &view, &Pose::IDENTITY), 0.0);
        // A wall one metre nearer stands in space the frames saw through
        // (all but the frustum's edge, which fewer rays crossed).
        let nearer = wall(2.0);
        let s = share(&free, &nearer, &Pose::IDENTITY);
        assert!(s > 0.8, "{s}");
        // ...and so does the same wall seen from a camera stepped a metre
        // back: the pose, not the frame, puts it there (the part of the
        // frame outside what the frames saw is not counted).
        let back = Pose::new(glam::Mat3::IDENTITY, Vec3::new(0.0, 0.0, -1.0));
        let s = share(&free, &view, &back);
        assert!(s > 0.3, "{s}");
        // A wall beyond the one seen is behind a surface, not in empty space.
        assert_eq!(share(&free, &wall(3.5), &Pose::IDENTITY), 0.0);
    }

    #[test]
    fn the_space_comes_back_from_its_bytes_and_bad_bytes_are_refused() {
        let view = wall(3.0);
        let mut free = FreeSpace::default();
        for i in 0..5 {
            let pose = Pose::new(glam::Mat3::IDENTITY, Vec3::new(0.1 * i as f32, 0.0, 0.0));
            free.add_view(&view.levels[0], &pose);
        }
        let bytes = free.encode();
        let back = FreeSpace::decode(&bytes).unwrap();
        assert_eq!(back, free);
        // The same space gives the same bytes, whatever the map's order.
        assert_eq!(back.encode(), bytes);
        // The next frame's rays start where the saved ones' left off.
        let (mut a, mut b) = (free, back);
        a.add_view(&view.levels[0], &Pose::IDENTITY);
        b.add_view(&view.levels[0], &Pose::IDENTITY);
        assert_eq!(a, b);
        for bad in [&bytes[..7], &bytes[..bytes.len() - 1]] {
            assert!(FreeSpace::decode(bad).is_err());
        }
        let mut flag = bytes.clone();
        flag[8 + CELL_BYTES - 1] = 2;
        assert!(FreeSpace::decode(&flag)
            .unwrap_err()
            .contains("surface flag"));
    }
}
