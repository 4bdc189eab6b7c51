//! Space the frames have seen empty, for verifying a pose, followed or
//! found without a prediction: a frame whose points land deep inside it
//! sees something where earlier frames saw through to a surface behind. A
//! place that merely looks alike from where the frame was taken (a room's
//! quarter turn, a second table, chairs further round) puts part of the
//! frame there; the camera's own pose does not, on a static scene.
//!
//! Each frame the tracker keeps adds its rays, from its pose, to coarse
//! cells (`CELL`): a cell counts the rays that crossed it and whether a
//! ray ended (saw a surface) in it. A cell counts as empty only when
//! `MIN_CROSSINGS` rays crossed it and no ray ended in it or in the 26
//! around it: rays from poses that drift against each other by
//! centimetres cross cells where others saw a surface, and counting
//! crossings alone put up to 8 % of the kitchen's right frames in "empty"
//! space, against at most 0.02 % with the surfaces counted (cells of 8 cm
//! then)
//! (`docs/tracking-experiments.md`, "Telling a look-alike place from the
//! camera's own").
//!
//! Cost and size: one ray per `RAY_STRIDE`² pixels, walked through every
//! cell it passes (the kitchen's 300 frames track as fast as with 8 cm
//! cells, within run-to-run noise). Cells, a byte each, are held by
//! regions of `REGION`³ (1.28 m, 32 KB), copied on write, so the
//! tracker's state is saved without copying them and a store writes only
//! the regions changed since its last checkpoint: the simulated 60 m
//! corridor walk (`bench/corridor_walk.py 60`, straight, `simulate --track
//! --store`) ends with 433 regions (13.9 MB; its peak memory 1.52 GB
//! against 1.51 with 8 cm cells, its store 281.0 MB against 278.9), and
//! each checkpoint writes the few dozen its last second of frames
//! changed. The regions are not bounded like the map's active region: a
//! walk of hundreds of metres holds them all.

use super::pyramid::Level;
use crate::camera::Pose;
use crate::tsdf::KeyMap;
use glam::{IVec3, Vec3};
use rayon::prelude::*;
use std::sync::Arc;

/// Cell size (metres): a few times the depth noise of a Kinect-class
/// sensor at room range, so that noise does not reach across a cell, and
/// small enough that what stands on a surface rises out of the cells kept
/// clear around it (a ray stops [`STOP_CELLS`] short of its surface, and
/// a cell next to a surface is not empty). With 8 cm cells those were the
/// 16–24 cm above a floor, and a floor with a 25 cm box, followed to a
/// place where the box stands on bare floor, put 0.73 % of the frame in
/// space seen empty; with 4 cm, the camera's own poses put at most 0.34 %
/// of the kitchen's frames there (0.26 % with 8 cm) and that place is
/// refused (`docs/tracking-experiments.md`, "Finer cells").
const CELL: f32 = 0.04;

/// Rays that must have crossed a cell for it to count as empty: more
/// than one frame's worth of noise.
const MIN_CROSSINGS: u8 = 3;

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

/// A cell, in a byte: the rays that crossed it, counted up to
/// [`MIN_CROSSINGS`] (all that [`Cell::open`] asks), and whether a
/// ray ended in it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Cell(u8);

/// The bits of [`Cell`] that count crossings.
const CROSSINGS: u8 = 0b011;

/// The bit of [`Cell`] set when a ray ended in it.
const SURFACE: u8 = 0b100;

const _: () = assert!(MIN_CROSSINGS <= CROSSINGS);

impl Cell {
    fn crossed(self) -> u8 {
        self.0 & CROSSINGS
    }

    fn surface(self) -> bool {
        self.0 & SURFACE != 0
    }

    fn cross(&mut self) {
        self.0 += u8::from(self.crossed() < MIN_CROSSINGS);
    }

    /// Crossed often enough to count as empty, and no ray ended in it.
    fn open(self) -> bool {
        self.crossed() >= MIN_CROSSINGS && !self.surface()
    }

    fn end_ray(&mut self) {
        self.0 |= SURFACE;
    }
}

/// Cells along each side of a region (1.28 m), a power of two.
const REGION: i32 = 1 << REGION_BITS;

/// The bits of a cell's coordinates that place it in its region.
const REGION_BITS: i32 = 5;

/// Cells along each side of a region as stores saved them when cells were
/// twice as large (8 cm; the same 1.28 m regions): each such cell is read
/// as the eight it holds now.
const COARSE_REGION: i32 = 16;

/// Cells in a region.
const REGION_CELLS: usize = (REGION * REGION * REGION) as usize;

/// A region's cells, x fastest, and when they last changed.
#[derive(Clone, Debug)]
struct Region {
    /// Shared with the saved copies of the space until written to.
    cells: Arc<[Cell; REGION_CELLS]>,
    /// The frames added when a ray last changed a cell of it.
    changed: usize,
}

/// Regions are the same when their cells are: when they changed is the
/// saving's business, not the space's.
impl PartialEq for Region {
    fn eq(&self, other: &Self) -> bool {
        self.cells == other.cells
    }
}

/// Space seen empty by a set of frames (see the module docs).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FreeSpace {
    /// Keyed with the block keys' fast hash: cells are looked up tens of
    /// thousands of times a frame.
    regions: KeyMap<Region>,
    /// Frames added: where the next one's rays start in the stride, so
    /// that successive frames cast different pixels.
    added: usize,
}

/// The region holding `cell`, and the cell's index in it.
fn split(cell: IVec3) -> (IVec3, usize) {
    // An arithmetic shift floors, as a region's key must for cells below 0.
    let region = cell >> REGION_BITS;
    let i = cell & (REGION - 1);
    (region, (i.x + REGION * (i.y + REGION * i.z)) as usize)
}

/// The cells a ray from `start` along the unit vector `direction` crosses
/// within `length` metres, in order: each cell it passes through once,
/// stepping from cell face to cell face (Amanatides and Woo's traversal),
/// so a ray that clips a cell's corner counts it, and no position along
/// the ray is rounded to a cell.
struct Walk {
    /// The cell the ray is in; `None` once past `length`.
    cell: Option<IVec3>,
    /// The step between cells along each axis (-1, 0 or 1).
    step: IVec3,
    /// The distance along the ray to the next face across each axis.
    next: Vec3,
    /// The distance along the ray between faces across each axis.
    delta: Vec3,
    length: f32,
}

impl Walk {
    fn new(start: Vec3, direction: Vec3, length: f32) -> Walk {
        let cell = cell_of(start);
        // An axis the ray runs along never has its face next; its distance
        // between faces is finite so that, stepped zero times, it stays 0.
        let (mut step, mut next, mut delta) = (IVec3::ZERO, Vec3::INFINITY, Vec3::ZERO);
        for axis in 0..3 {
            let d = direction[axis];
            if d > 0.0 {
                step[axis] = 1;
                next[axis] = ((cell[axis] + 1) as f32 * CELL - start[axis]) / d;
                delta[axis] = (CELL / d).min(f32::MAX);
            } else if d < 0.0 {
                step[axis] = -1;
                next[axis] = (cell[axis] as f32 * CELL - start[axis]) / d;
                delta[axis] = (-CELL / d).min(f32::MAX);
            }
        }
        Walk {
            cell: Some(cell),
            step,
            next,
            delta,
            length,
        }
    }
}

impl Iterator for Walk {
    type Item = IVec3;

    fn next(&mut self) -> Option<IVec3> {
        let cell = self.cell?;
        // The nearest face (the first axis of a tie), chosen by selects,
        // not branches: which axis comes next follows no pattern a branch
        // predictor could learn, and a walk by index kept the distances in
        // memory.
        let n = self.next;
        let x = n.x < n.y && n.x < n.z;
        let y = !x && n.y < n.z;
        let crossed = IVec3::new(i32::from(x), i32::from(y), i32::from(!x && !y));
        self.next = n + self.delta * crossed.as_vec3();
        self.cell = (n.min_element() <= self.length).then_some(cell + self.step * crossed);
        Some(cell)
    }
}

fn cell_of(p: Vec3) -> IVec3 {
    (p / CELL).floor().as_ivec3()
}

impl FreeSpace {
    /// Adds the rays of the frame whose camera-space points and normals are
    /// `view`, taken from `pose` (camera-to-world).
    pub fn add_view(&mut self, view: &Level, pose: &Pose) {
        let (w, h) = view.size();
        // Successive frames cast pixels offset by steps coprime to the
        // stride, and every `RAY_STRIDE` frames the rows shift by another
        // such step, so that `RAY_STRIDE`² frames cast every offset once:
        // without that shift the offsets repeated every `RAY_STRIDE`
        // frames, and a camera holding still saw one cell in two of 4 cm
        // at 2 m crossed by too few rays.
        let (u0, v0) = (
            (self.added * 5) % RAY_STRIDE,
            (self.added * 11 + self.added / RAY_STRIDE * 7) % RAY_STRIDE,
        );
        self.added += 1;
        let (origin, rotation) = (pose.translation, pose.rotation);
        for v in (v0..h).step_by(RAY_STRIDE) {
            for u in (u0..w).step_by(RAY_STRIDE) {
                let i = v * w + u;
                let (p, n) = (view.points[i], view.normals[i]);
                if p.z <= 0.0 || n == Vec3::ZERO {
                    continue;
                }
                self.cell_mut(cell_of(pose.transform_point(p))).end_ray();
                let length = p.length();
                let direction = p / length;
                // Grazing rays stop farther back: a floor seen at a low
                // angle is near the ray long before the ray reaches it.
                let facing = direction.dot(n).abs().max(0.05);
                let stop = length - STOP_CELLS * CELL / facing;
                if stop > RAY_START {
                    let world = rotation * direction;
                    self.cross(Walk::new(
                        origin + world * RAY_START,
                        world,
                        stop - RAY_START,
                    ));
                }
            }
        }
    }

    /// Counts a ray's crossing of `cells`, looking each region up once for
    /// the cells in a row that lie in it (a ray crosses tens of cells a
    /// region, and a lookup a cell cost the kitchen's tracking a quarter
    /// of its speed with rays every 8 pixels).
    fn cross(&mut self, cells: impl Iterator<Item = IVec3>) {
        let mut run: Option<(IVec3, &mut [Cell; REGION_CELLS])> = None;
        for cell in cells {
            let (key, i) = split(cell);
            if run.as_ref().is_none_or(|(k, _)| *k != key) {
                run = Some((key, self.region_mut(key)));
            }
            if let Some((_, region)) = run.as_mut() {
                region[i].cross();
            }
        }
    }

    /// Whether no view saw a surface in `cell` or in the 26 around it
    /// (asked only of an open cell, which a right pose's points rarely
    /// fall in).
    fn clear_around(&self, cell: IVec3) -> bool {
        (-1..=1).all(|dz| {
            (-1..=1).all(|dy| {
                (-1..=1).all(|dx| {
                    !self
                        .cell(cell + IVec3::new(dx, dy, dz))
                        .is_some_and(|c| c.surface())
                })
            })
        })
    }

    /// `cell`, if a ray reached its region.
    fn cell(&self, cell: IVec3) -> Option<&Cell> {
        let (region, i) = split(cell);
        self.regions.get(&region).map(|r| &r.cells[i])
    }

    /// `cell`, to change by the frame being added, its region made (or
    /// copied, if a saved copy of the space shares it) and marked changed.
    fn cell_mut(&mut self, cell: IVec3) -> &mut Cell {
        let (region, i) = split(cell);
        &mut self.region_mut(region)[i]
    }

    /// The cells of region `key`, to change by the frame being added, made
    /// (or copied, if a saved copy of the space shares them) and marked
    /// changed.
    fn region_mut(&mut self, key: IVec3) -> &mut [Cell; REGION_CELLS] {
        let r = self.regions.entry(key).or_insert_with(|| Region {
            cells: Arc::new([Cell::default(); REGION_CELLS]),
            changed: 0,
        });
        r.changed = self.added;
        Arc::make_mut(&mut r.cells)
    }

    /// Frames added so far.
    pub fn frames(&self) -> usize {
        self.added
    }

    /// Regions a ray reached.
    pub fn regions(&self) -> usize {
        self.regions.len()
    }

    /// The keys of the regions a frame changed after the first `frames`
    /// frames were added: what a store must write to hold the space again.
    pub fn changed_after(&self, frames: usize) -> Vec<IVec3> {
        self.regions
            .iter()
            .filter(|(_, r)| r.changed > frames)
            .map(|(k, _)| *k)
            .collect()
    }

    /// The cells of region `key` as bytes, to save: a byte a cell, x
    /// fastest, the rays that crossed it (up to three) in its two low bits
    /// and whether one ended in it in the third; `None` if no ray reached
    /// the region.
    pub fn encode_region(&self, key: IVec3) -> Option<Vec<u8>> {
        let region = self.regions.get(&key)?;
        Some(region.cells.iter().map(|c| c.0).collect())
    }

    /// The space of `frames` frames whose regions `regions` holds, as
    /// [`FreeSpace::encode_region`] wrote them; why not, when they are not
    /// such.
    pub fn decode<'a>(
        frames: usize,
        regions: impl IntoIterator<Item = (IVec3, &'a [u8])>,
    ) -> Result<FreeSpace, String> {
        let mut space = FreeSpace {
            regions: KeyMap::default(),
            added: frames,
        };
        for (key, bytes) in regions {
            let scale = match bytes.len() {
                REGION_CELLS => 1,
                n if n == (COARSE_REGION * COARSE_REGION * COARSE_REGION) as usize => 2,
                n => return Err(format!("free space region {key}: {n} bytes")),
            };
            let side = REGION / scale;
            let mut cells = [Cell::default(); REGION_CELLS];
            for (i, cell) in cells.iter_mut().enumerate() {
                let i = i as i32;
                let (x, y, z) = (i % REGION, (i / REGION) % REGION, i / (REGION * REGION));
                let b = bytes[((x / scale) + side * ((y / scale) + side * (z / scale))) as usize];
                *cell = Cell(b);
                if b & !(CROSSINGS | SURFACE) != 0 || cell.crossed() > MIN_CROSSINGS {
                    return Err(format!("free space region {key}: cell byte {b}"));
                }
            }
            let region = Region {
                cells: Arc::new(cells),
                changed: frames,
            };
            if space.regions.insert(key, region).is_some() {
                return Err(format!("free space region {key} twice"));
            }
        }
        Ok(space)
    }

    /// Of the frame's measured points (camera space), seen from `pose`, the
    /// share that lands in cells seen empty.
    pub fn share_inside(&self, points: &[Vec3], width: usize, pose: &Pose) -> f64 {
        if self.regions.is_empty() || width == 0 {
            return 0.0;
        }
        // Rows are counted in parallel: this runs on every followed frame,
        // between its alignment and its fusion.
        let (measured, inside) = points
            .par_chunks(width * CHECK_STRIDE)
            .map(|rows| {
                let (mut measured, mut inside) = (0usize, 0usize);
                self.check_row(&rows[..width.min(rows.len())], pose, |_, open| {
                    measured += 1;
                    inside += usize::from(open);
                });
                (measured, inside)
            })
            .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
        inside as f64 / measured.max(1) as f64
    }

    /// Calls `inside` with each of the points [`FreeSpace::share_inside`]
    /// checks that lies in space seen empty, in world coordinates.
    pub fn points_inside(
        &self,
        points: &[Vec3],
        width: usize,
        pose: &Pose,
        mut inside: impl FnMut(Vec3),
    ) {
        if self.regions.is_empty() || width == 0 {
            return;
        }
        for rows in points.chunks(width * CHECK_STRIDE) {
            self.check_row(&rows[..width.min(rows.len())], pose, |world, open| {
                if open {
                    inside(world);
                }
            });
        }
    }

    /// Calls `checked` with every [`CHECK_STRIDE`]th measured point of
    /// `row` (in world coordinates, by `pose`) and whether it lies in space
    /// seen empty.
    fn check_row(&self, row: &[Vec3], pose: &Pose, mut checked: impl FnMut(Vec3, bool)) {
        // Neighbouring points mostly lie in the same region: it is looked
        // up again only when the region changes.
        let mut region: Option<(IVec3, Option<&[Cell; REGION_CELLS]>)> = None;
        for &p in row.iter().step_by(CHECK_STRIDE) {
            if p.z <= 0.0 {
                continue;
            }
            let world = pose.transform_point(p);
            let cell = cell_of(world);
            let (key, i) = split(cell);
            let cells = match region {
                Some((k, cells)) if k == key => cells,
                _ => {
                    region
                        .insert((key, self.regions.get(&key).map(|r| &*r.cells)))
                        .1
                }
            };
            let open = cells.is_some_and(|cells| cells[i].open());
            checked(world, open && self.clear_around(cell));
        }
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
        // The points counted inside are the ones visited, where the pose
        // puts them: the nearer wall's, 2 m ahead of the camera.
        let mut inside = Vec::new();
        let points = &nearer.levels[0].points;
        free.points_inside(points, 320, &Pose::IDENTITY, |p| inside.push(p));
        let checked = points
            .chunks(320 * CHECK_STRIDE)
            .map(|rows| rows[..320].iter().step_by(CHECK_STRIDE).count())
            .sum::<usize>();
        let counted = share(&free, &nearer, &Pose::IDENTITY) * checked as f64;
        assert_eq!(inside.len(), counted.round() as usize);
        assert!(
            inside.iter().all(|p| (p.z - 2.0).abs() < 1e-3),
            "{:?}",
            inside.first()
        );
    }

    #[test]
    fn the_space_comes_back_from_its_changed_regions_and_bad_bytes_are_refused() {
        let view = wall(3.0);
        let step = |i: usize| Pose::new(glam::Mat3::IDENTITY, Vec3::new(0.5 * i as f32, 0.0, 0.0));
        let mut free = FreeSpace::default();
        // Saved after three frames, then after two more: the regions the
        // first save wrote, and over them those changed since.
        let mut saved = KeyMap::default();
        let save = |saved: &mut KeyMap<Vec<u8>>, free: &FreeSpace, after: usize| {
            for key in free.changed_after(after) {
                saved.insert(key, free.encode_region(key).unwrap());
            }
        };
        for i in 0..3 {
            free.add_view(&view.levels[0], &step(i));
        }
        save(&mut saved, &free, 0);
        let first = saved.len();
        for i in 3..5 {
            free.add_view(&view.levels[0], &step(i));
        }
        let changed = free.changed_after(3).len();
        assert!(changed > 0 && changed < free.regions.len(), "{changed}");
        save(&mut saved, &free, 3);
        assert!(saved.len() > first);
        let back = FreeSpace::decode(5, saved.iter().map(|(k, b)| (*k, b.as_slice()))).unwrap();
        assert_eq!(back, free);
        assert_eq!(back.frames(), 5);
        assert!(back.changed_after(5).is_empty());
        // The next frame's rays start where the saved ones' left off, and
        // a copy taken before shares nothing it changes.
        let copy = back.clone();
        let (mut a, mut b) = (free, back);
        a.add_view(&view.levels[0], &Pose::IDENTITY);
        b.add_view(&view.levels[0], &Pose::IDENTITY);
        assert_eq!(a, b);
        assert_ne!(b, copy);
        let key = *saved.keys().next().unwrap();
        let bytes = &saved[&key];
        assert!(FreeSpace::decode(5, [(key, &bytes[1..])]).is_err());
        let mut flag = bytes.clone();
        flag[0] = 0b1000;
        let e = FreeSpace::decode(5, [(key, flag.as_slice())]).unwrap_err();
        assert!(e.contains("cell byte 8"), "{e}");
    }

    #[test]
    fn a_ray_walks_every_cell_it_passes_through_once_face_to_face() {
        let rays = [
            (Vec3::new(0.01, 0.02, 0.03), Vec3::new(1.0, 0.0, 0.0)),
            (Vec3::new(-0.3, 0.5, -0.07), Vec3::new(0.3, -0.5, 0.8)),
            (Vec3::new(1.99, -2.01, 0.0), Vec3::new(-0.7, -0.1, -0.2)),
        ];
        for (start, direction) in rays {
            let direction = direction.normalize();
            let length = 1.3;
            let cells: Vec<IVec3> = Walk::new(start, direction, length).collect();
            for pair in cells.windows(2) {
                let d = (pair[1] - pair[0]).abs();
                assert_eq!(d.x + d.y + d.z, 1, "{pair:?}");
            }
            // Sampled every tenth of a millimetre, the ray meets no other
            // cell (up to its last millimetre, where the walk may stop
            // short of a face the sample crossed).
            for k in 0..=(length * 1e4) as i32 {
                let t = k as f32 * 1e-4;
                let near = cell_of(start + direction * t);
                assert!(
                    cells.contains(&near) || t > length - 1e-3,
                    "{near} at {t} m"
                );
            }
            let mut unique = cells.clone();
            unique.sort_by_key(|c| c.to_array());
            unique.dedup();
            assert_eq!(unique.len(), cells.len());
            assert_eq!(cells[0], cell_of(start));
        }
    }

    #[test]
    fn a_region_saved_with_cells_twice_as_large_is_read_as_eight_cells_each() {
        let side = COARSE_REGION as usize;
        let mut coarse = vec![0u8; side * side * side];
        // Coarse cell (1, 2, 3): crossed three times; (0, 0, 0): a surface.
        coarse[1 + side * (2 + side * 3)] = MIN_CROSSINGS;
        coarse[0] = SURFACE;
        let key = IVec3::new(-1, 0, 2);
        let space = FreeSpace::decode(7, [(key, coarse.as_slice())]).unwrap();
        let region = key * REGION;
        let crossed = |x, y, z| space.cell(region + IVec3::new(x, y, z)).unwrap().crossed();
        let surface = |x, y, z| space.cell(region + IVec3::new(x, y, z)).unwrap().surface();
        for (dx, dy, dz) in (0..8).map(|i| (i & 1, (i >> 1) & 1, i >> 2)) {
            assert_eq!(crossed(2 + dx, 4 + dy, 6 + dz), MIN_CROSSINGS);
            assert!(surface(dx, dy, dz));
        }
        assert_eq!(crossed(4, 4, 6), 0);
        assert!(!surface(2, 0, 0));
        // Saved again, it is written with the cells it has now.
        assert_eq!(space.encode_region(key).unwrap().len(), REGION_CELLS);
    }
}
