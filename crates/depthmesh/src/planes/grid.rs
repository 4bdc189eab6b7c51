//! The semi-sparse blockwise map of the paper (Sec. C, Fig. 4): a coarse
//! map of cells (1 m), each occupied cell holding a dense fine grid of voxel
//! statistics (0.05 m).
//!
//! One level of indirection makes a voxel lookup a hash probe plus an index,
//! and a 2×2×2 neighbourhood touches at most eight cells; memory grows with
//! the occupied cells only, which suits the clustered points of real scans.
//! The paper's coarse level is a dense grid of pointers; here it is a hash
//! map so the map has no fixed extent.

use super::stats::VoxelStats;
use crate::error::{Error, Result};
use crate::tsdf::KeyHasher;
use glam::{IVec3, Vec3};
use rayon::prelude::*;
use std::collections::HashMap;
use std::hash::BuildHasherDefault;

/// Largest fine grid edge in voxels: 256³ voxels of statistics is already
/// 20 MB per cell.
const MAX_CELL_VOXELS: usize = 256;

/// A cell as saved: its key and its voxels, x fastest.
pub type SavedCell = (IVec3, Box<[VoxelStats]>);

/// Sizes of the two levels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlaneGridConfig {
    /// Fine voxel edge in metres.
    pub voxel: f32,
    /// Coarse cell edge in metres, a whole multiple of `voxel`.
    pub cell: f32,
}

impl Default for PlaneGridConfig {
    /// The paper's 0.05 m voxels in 1 m cells.
    fn default() -> Self {
        PlaneGridConfig {
            voxel: 0.05,
            cell: 1.0,
        }
    }
}

impl PlaneGridConfig {
    /// Voxels along a cell's edge, or the reason the sizes are rejected.
    pub fn cell_voxels(&self) -> Result<usize> {
        if !(self.voxel.is_finite() && self.voxel > 0.0) {
            return Err(Error::parameter(
                "grid.voxel",
                format!("must be a positive size in metres, got {}", self.voxel),
            ));
        }
        if !(self.cell.is_finite() && self.cell > 0.0) {
            return Err(Error::parameter(
                "grid.cell",
                format!("must be a positive size in metres, got {}", self.cell),
            ));
        }
        // In f64 and with a tolerance: 1.0 / 0.05f32 is 19.9999997, not 20.
        let ratio = f64::from(self.cell) / f64::from(self.voxel);
        let n = ratio.round();
        if n < 1.0 || (ratio - n).abs() > 1e-5 * n {
            return Err(Error::parameter(
                "grid.cell",
                format!(
                    "must be a whole multiple of the voxel size {} m, got {} m",
                    self.voxel, self.cell
                ),
            ));
        }
        if n > MAX_CELL_VOXELS as f64 {
            return Err(Error::parameter(
                "grid.cell",
                format!(
                    "{} m holds {n} voxels of {} m per edge, at most {MAX_CELL_VOXELS} are allowed",
                    self.cell, self.voxel
                ),
            ));
        }
        Ok(n as usize)
    }
}

/// Cell key → index into the cell list.
type CellIndex = HashMap<IVec3, u32, BuildHasherDefault<KeyHasher>>;

/// An item (point or statistics) on its way into the grid: where it goes.
#[derive(Clone, Copy)]
struct Binned {
    /// Index of its cell in the cell list, [`NEW_CELL`] before allocation,
    /// or [`SKIP`].
    slot: u32,
    /// Index of its voxel inside the cell.
    local: u32,
    /// Index of the item in the input.
    item: u32,
}

/// One cell's share of an insertion: its key, its voxels and its
/// (voxel index, item index) entries.
type CellJob<'a> = (IVec3, &'a mut [VoxelStats], &'a mut [(u32, u32)]);

/// Slot of an item whose cell is not allocated yet.
const NEW_CELL: u32 = u32::MAX;
/// Slot of an item that has no voxel (non-finite or out of range).
const SKIP: u32 = u32::MAX - 1;

/// What one [`PlaneGrid::insert_points`] call did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Inserted {
    /// Items (points or statistics) added; the others were non-finite or out of range.
    pub items: usize,
    /// Points added.
    pub points: usize,
    /// Voxels that held no point before.
    pub new_voxels: usize,
    /// Every voxel whose statistics changed, each once.
    pub changed: Vec<IVec3>,
}

/// The voxel holding `p` for voxels of `1 / scale` metres, see
/// [`PlaneGrid::voxel_of`].
#[inline]
fn voxel_at(scale: f64, p: Vec3) -> Option<IVec3> {
    // Headroom below i32::MAX so `cell * n + n` and `corner ± 1` cannot overflow.
    let limit = f64::from(i32::MAX / 4);
    let mut v = [0i32; 3];
    for (out, c) in v.iter_mut().zip([p.x, p.y, p.z]) {
        // f64 so a point a rounding error inside a voxel border is binned
        // the same way in every call.
        let x = f64::from(c) * scale;
        // `!(x.abs() < limit)` in effect: NaN fails too.
        if x.abs() >= limit || x.is_nan() {
            return None;
        }
        // Floor by truncation: `f64::floor` is a libm call without SSE4.1,
        // and binning is the hottest loop of insertion.
        let t = x as i32;
        *out = t - i32::from(f64::from(t) > x);
    }
    Some(IVec3::from_array(v))
}

/// Voxel statistics in a semi-sparse blockwise grid.
///
/// Voxel `k` (global integer coordinates) covers `[k, k + 1) · voxel`; cell
/// `c` holds voxels `c · n .. c · n + n` on each axis, `n` =
/// [`PlaneGrid::cell_voxels`]. Cells are stored in the order they were first
/// touched, so iteration is deterministic for a given input sequence.
#[derive(Debug)]
pub struct PlaneGrid {
    config: PlaneGridConfig,
    /// Voxels along a cell's edge.
    n: i32,
    index: CellIndex,
    /// Key of each cell, parallel to `cells`.
    keys: Vec<IVec3>,
    /// Each cell's n³ voxels, x fastest.
    cells: Vec<Box<[VoxelStats]>>,
    /// Per cell, the insertion that last changed it (0: not since restored).
    stamps: Vec<u32>,
    /// Insertions so far.
    inserts: u32,
    /// Voxels holding at least one point.
    occupied: usize,
}

impl PlaneGrid {
    /// An empty grid; fails when the sizes are rejected, see
    /// [`PlaneGridConfig::cell_voxels`].
    pub fn new(config: PlaneGridConfig) -> Result<Self> {
        let n = config.cell_voxels()?;
        Ok(PlaneGrid {
            config,
            n: n as i32,
            index: CellIndex::default(),
            keys: Vec::new(),
            cells: Vec::new(),
            stamps: Vec::new(),
            inserts: 0,
            occupied: 0,
        })
    }

    /// Insertions so far ([`PlaneGrid::insert_points`], [`PlaneGrid::insert_stats`]).
    pub fn inserts(&self) -> u32 {
        self.inserts
    }

    /// The cells allocated or changed by insertions after the `since`-th, in
    /// allocation order: slot, key and voxels (x fastest).
    pub fn cells_changed_after(&self, since: u32) -> Vec<(usize, IVec3, &[VoxelStats])> {
        (0..self.cells.len())
            .filter(|&s| self.stamps[s] > since)
            .map(|s| (s, self.keys[s], &*self.cells[s]))
            .collect()
    }

    /// Puts back cells saved after `inserts` insertions, in their
    /// allocation order, into an empty grid: it continues as the one saved.
    pub fn restore(&mut self, cells: Vec<SavedCell>, inserts: u32) -> Result<()> {
        let voxels = (self.n as usize).pow(3);
        if !self.cells.is_empty() {
            return Err(Error::parameter("plane grid", "restored into a used grid"));
        }
        for (key, cell) in cells {
            if cell.len() != voxels || self.index.contains_key(&key) {
                return Err(Error::parameter(
                    "plane grid",
                    format!("saved cell ({}, {}, {}) does not fit", key.x, key.y, key.z),
                ));
            }
            self.occupied += cell.iter().filter(|s| s.count > 0).count();
            self.index.insert(key, self.cells.len() as u32);
            self.keys.push(key);
            self.cells.push(cell);
            self.stamps.push(0);
        }
        self.inserts = inserts;
        Ok(())
    }

    /// The sizes.
    pub fn config(&self) -> PlaneGridConfig {
        self.config
    }

    /// Voxels along a cell's edge.
    pub fn cell_voxels(&self) -> usize {
        self.n as usize
    }

    /// Number of allocated cells.
    pub fn cell_count(&self) -> usize {
        self.cells.len()
    }

    /// The voxel holding `p`, or `None` for a non-finite point or one so far
    /// away its voxel coordinates would overflow.
    pub fn voxel_of(&self, p: Vec3) -> Option<IVec3> {
        voxel_at(1.0 / f64::from(self.config.voxel), p)
    }

    /// Position of the grid vertex `corner` (the lowest corner of voxel `corner`).
    pub fn corner_position(&self, corner: IVec3) -> Vec3 {
        corner.as_vec3() * self.config.voxel
    }

    /// The cell holding voxel `v` and the voxel's index inside it.
    #[inline]
    fn split(&self, v: IVec3) -> (IVec3, usize) {
        let n = self.n;
        let cell = IVec3::new(v.x.div_euclid(n), v.y.div_euclid(n), v.z.div_euclid(n));
        let l = v - cell * n;
        let local = l.x + n * (l.y + n * l.z);
        (cell, local as usize)
    }

    /// Adds `points` to the statistics of their voxels, allocating the cells
    /// they first touch; reports how many were added (non-finite and
    /// out-of-range points are skipped) and which voxels changed.
    pub fn insert_points(&mut self, points: &[Vec3]) -> Inserted {
        let scale = 1.0 / f64::from(self.config.voxel);
        let mut inserted = self.fill(
            points,
            |p| voxel_at(scale, *p),
            |s, p| s.add_point(p.as_dvec3()),
        );
        inserted.points = inserted.items;
        inserted
    }

    /// Merges ready-made statistics into voxels (eqs. 2–3), e.g. those of
    /// runs of pixels gathered by [`super::runs::depth_runs`]; out-of-range
    /// voxels are skipped.
    pub fn insert_stats(&mut self, items: &[(IVec3, VoxelStats)]) -> Inserted {
        let limit = i32::MAX / 4;
        let mut inserted = self.fill(
            items,
            |(v, _)| (v.abs().max_element() < limit).then_some(*v),
            |s, (_, other)| s.merge(other),
        );
        inserted.points = items
            .iter()
            .filter(|(v, _)| v.abs().max_element() < limit)
            .map(|(_, s)| s.count as usize)
            .sum();
        inserted
    }

    /// Folds `items` into the voxels `voxel` assigns them (`None`: skip)
    /// with `add`, allocating the cells they first touch.
    ///
    /// Items are binned in parallel, grouped by cell with a stable counting
    /// sort (a frame touches few cells, and consecutive pixels mostly share
    /// one), then every touched cell is filled by one task. Each voxel sees
    /// its items in input order, so the result does not depend on the
    /// thread count.
    fn fill<T: Sync>(
        &mut self,
        items: &[T],
        voxel: impl Fn(&T) -> Option<IVec3> + Sync,
        add: impl Fn(&mut VoxelStats, &T) + Sync,
    ) -> Inserted {
        self.inserts += 1;
        // Bin in parallel (an indexed map, so the output is allocated once);
        // cells already in the index get their slot here (consecutive items
        // mostly share a cell, so the last one is remembered), new ones are
        // marked and allocated below.
        let mut binned: Vec<Binned> = items
            .par_iter()
            .enumerate()
            .map_init(
                || None,
                |last: &mut Option<(IVec3, u32)>, (item, t)| {
                    let Some(v) = voxel(t) else {
                        return Binned {
                            slot: SKIP,
                            local: 0,
                            item: item as u32,
                        };
                    };
                    let (cell, local) = self.split(v);
                    let slot = match *last {
                        Some((c, slot)) if c == cell => slot,
                        _ => {
                            let slot = self.index.get(&cell).copied().unwrap_or(NEW_CELL);
                            *last = Some((cell, slot));
                            slot
                        }
                    };
                    Binned {
                        slot,
                        local: local as u32,
                        item: item as u32,
                    }
                },
            )
            .collect();
        binned.retain(|b| b.slot != SKIP);
        // New cells are allocated serially, because the index is shared.
        for b in binned.iter_mut().filter(|b| b.slot == NEW_CELL) {
            let v = voxel(&items[b.item as usize]).expect("binned items have a voxel");
            b.slot = self.slot(self.split(v).0);
        }

        // Stable counting sort by slot: `starts[s]..starts[s + 1]` is cell s.
        let mut starts = vec![0usize; self.cells.len() + 1];
        for b in &binned {
            starts[b.slot as usize + 1] += 1;
        }
        for i in 1..starts.len() {
            starts[i] += starts[i - 1];
        }
        let mut next = starts.clone();
        let mut sorted = vec![(0u32, 0u32); binned.len()];
        for b in &binned {
            let i = &mut next[b.slot as usize];
            sorted[*i] = (b.local, b.item);
            *i += 1;
        }

        // Each touched cell is one job with a distinct `&mut` to its voxels
        // and to its entries.
        let n = self.n;
        let mut rest = &mut sorted[..];
        let mut jobs: Vec<CellJob> = Vec::new();
        let cells = self.cells.iter_mut().zip(&self.keys).zip(&mut self.stamps);
        for (s, ((cell, &key), stamp)) in cells.enumerate() {
            let (mine, tail) = rest.split_at_mut(starts[s + 1] - starts[s]);
            rest = tail;
            if !mine.is_empty() {
                *stamp = self.inserts;
                jobs.push((key, &mut **cell, mine));
            }
        }
        let per_cell: Vec<(usize, Vec<IVec3>)> = jobs
            .into_par_iter()
            .map(|(key, cell, entries)| {
                // In voxel order, so the cell's memory is walked once; the
                // sort is stable, so each voxel still gets its items in
                // input order.
                entries.sort_by_key(|&(local, _)| local);
                let mut touched = vec![0u64; cell.len().div_ceil(64)];
                let mut new = 0;
                for &mut (local, item) in entries {
                    let stats = &mut cell[local as usize];
                    new += usize::from(stats.count == 0);
                    add(stats, &items[item as usize]);
                    touched[local as usize / 64] |= 1 << (local % 64);
                }
                let changed = touched
                    .iter()
                    .enumerate()
                    .flat_map(|(w, &bits)| {
                        (0..64).filter(move |b| bits >> b & 1 == 1).map(move |b| {
                            let l = (w * 64 + b) as i32;
                            key * n + IVec3::new(l % n, (l / n) % n, l / (n * n))
                        })
                    })
                    .collect();
                (new, changed)
            })
            .collect();
        let new_voxels = per_cell.iter().map(|(new, _)| new).sum();
        self.occupied += new_voxels;
        Inserted {
            items: binned.len(),
            points: 0,
            new_voxels,
            changed: per_cell.into_iter().flat_map(|(_, c)| c).collect(),
        }
    }

    /// The slot of `cell` in the cell list, allocating it when new.
    fn slot(&mut self, cell: IVec3) -> u32 {
        let next = self.cells.len() as u32;
        let slot = *self.index.entry(cell).or_insert(next);
        if slot == next {
            self.keys.push(cell);
            let voxels = (self.n as usize).pow(3);
            self.cells
                .push(vec![VoxelStats::EMPTY; voxels].into_boxed_slice());
            self.stamps.push(self.inserts);
        }
        slot
    }

    /// Number of voxels holding at least one point.
    pub fn occupied_count(&self) -> usize {
        self.occupied
    }

    /// Statistics of voxel `v`, `None` when it holds no point.
    pub fn voxel(&self, v: IVec3) -> Option<&VoxelStats> {
        let (cell, local) = self.split(v);
        let slot = *self.index.get(&cell)?;
        let s = &self.cells[slot as usize][local];
        (s.count > 0).then_some(s)
    }

    /// Statistics of the 2×2×2 voxels sharing the grid vertex `corner`
    /// (voxels `corner − 1 ..= corner` on each axis), combined by eqs. (2)–(3):
    /// the sliding window of the paper. Empty when none holds a point.
    pub fn neighbourhood(&self, corner: IVec3) -> VoxelStats {
        let mut acc = VoxelStats::EMPTY;
        // Fixed order, so a vertex's result is reproducible bit for bit.
        let (cell, first) = self.split(corner - IVec3::ONE);
        if self.split(corner).0 == cell {
            // All eight in one cell (most windows): one lookup, then offsets.
            let Some(&slot) = self.index.get(&cell) else {
                return acc;
            };
            let (voxels, n) = (&self.cells[slot as usize], self.n as usize);
            for dz in 0..2 {
                for dy in 0..2 {
                    for dx in 0..2 {
                        let s = &voxels[first + dx + n * (dy + n * dz)];
                        if s.count > 0 {
                            acc.merge(s);
                        }
                    }
                }
            }
            return acc;
        }
        for dz in -1..=0 {
            for dy in -1..=0 {
                for dx in -1..=0 {
                    if let Some(s) = self.voxel(corner + IVec3::new(dx, dy, dz)) {
                        acc.merge(s);
                    }
                }
            }
        }
        acc
    }

    /// Every voxel holding at least one point, cell by cell in allocation
    /// order, x fastest inside a cell.
    pub fn occupied_voxels(&self) -> impl Iterator<Item = (IVec3, &VoxelStats)> + '_ {
        let n = self.n;
        self.keys
            .iter()
            .zip(&self.cells)
            .flat_map(move |(&key, cell)| {
                cell.iter().enumerate().filter_map(move |(i, s)| {
                    if s.count == 0 {
                        return None;
                    }
                    let i = i as i32;
                    let l = IVec3::new(i % n, (i / n) % n, i / (n * n));
                    Some((key * n + l, s))
                })
            })
    }

    /// Bytes held: the fine grids, the cell list and the coarse index
    /// (its capacity, with one control byte per bucket as hashbrown uses).
    pub fn memory_bytes(&self) -> usize {
        let voxels = (self.n as usize).pow(3);
        self.cells.len() * voxels * std::mem::size_of::<VoxelStats>()
            + self.cells.capacity() * std::mem::size_of::<Box<[VoxelStats]>>()
            + self.keys.capacity() * std::mem::size_of::<IVec3>()
            + self.index.capacity() * (std::mem::size_of::<(IVec3, u32)>() + 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use rand::rngs::SmallRng;
    use rand::seq::SliceRandom;
    use rand::{Rng, SeedableRng};

    fn grid() -> PlaneGrid {
        PlaneGrid::new(PlaneGridConfig::default()).unwrap()
    }

    fn assert_close(a: &VoxelStats, b: &VoxelStats) {
        assert_eq!(a.count, b.count);
        assert!(
            (a.mean - b.mean).abs().max_element() <= 1e-9 * a.mean.abs().max_element().max(1.0)
        );
        let (ma, mb) = (a.scatter.to_mat3(), b.scatter.to_mat3());
        let scale = (0..3)
            .map(|i| ma.col(i).abs().max_element())
            .fold(1e-300, f64::max);
        for i in 0..3 {
            assert!((ma.col(i) - mb.col(i)).abs().max_element() <= 1e-9 * scale);
        }
    }

    #[test]
    fn sizes_are_validated() {
        let ok = |voxel, cell| PlaneGridConfig { voxel, cell }.cell_voxels();
        assert_eq!(ok(0.05, 1.0).unwrap(), 20);
        assert_eq!(ok(0.1, 0.8).unwrap(), 8);
        assert_eq!(ok(0.25, 0.25).unwrap(), 1);
        assert!(ok(0.05, 1.01).is_err());
        assert!(ok(0.3, 1.0).is_err());
        assert!(ok(1.0, 0.5).is_err());
        assert!(ok(0.0, 1.0).is_err());
        assert!(ok(-0.05, 1.0).is_err());
        assert!(ok(f32::NAN, 1.0).is_err());
        assert!(ok(0.05, f32::INFINITY).is_err());
        assert!(ok(0.001, 1.0).is_err());
        assert!(PlaneGrid::new(PlaneGridConfig {
            voxel: 0.05,
            cell: 0.12
        })
        .is_err());
    }

    #[test]
    fn voxels_and_cells_are_addressed_consistently() {
        let mut g = grid();
        let p = Vec3::new(-0.01, 0.99, 1.01);
        let inserted = g.insert_points(&[p, Vec3::NAN, Vec3::splat(1e12)]);
        assert_eq!(inserted.points, 1);
        let v = g.voxel_of(p).unwrap();
        assert_eq!(v, IVec3::new(-1, 19, 20));
        assert_eq!(g.voxel(v).unwrap().count, 1);
        assert!(g.voxel(v + IVec3::X).is_none());
        assert_eq!(g.cell_count(), 1);
        let occ: Vec<_> = g.occupied_voxels().collect();
        assert_eq!(occ.len(), 1);
        assert_eq!(occ[0].0, v);
        assert_eq!(inserted.changed, vec![v]);
        assert_eq!((inserted.new_voxels, g.occupied_count()), (1, 1));
        assert!(g
            .corner_position(IVec3::new(2, -4, 20))
            .abs_diff_eq(Vec3::new(0.1, -0.2, 1.0), 1e-6));
        // One 20³ grid of statistics plus bookkeeping.
        assert!(g.memory_bytes() >= 8000 * std::mem::size_of::<VoxelStats>());
    }

    #[test]
    fn insertion_order_and_batching_do_not_matter() {
        let mut rng = SmallRng::seed_from_u64(21);
        let mut pts: Vec<Vec3> = (0..20_000)
            .map(|_| {
                Vec3::new(
                    rng.gen_range(-1.5..1.5),
                    rng.gen_range(-1.5..1.5),
                    rng.gen_range(-0.2..0.2),
                )
            })
            .collect();
        let mut a = grid();
        a.insert_points(&pts);
        pts.shuffle(&mut rng);
        let mut b = grid();
        for chunk in pts.chunks(777) {
            b.insert_points(chunk);
        }
        assert_eq!(a.occupied_voxels().count(), b.occupied_voxels().count());
        for (v, s) in a.occupied_voxels() {
            assert_close(s, b.voxel(v).unwrap());
        }
        assert_eq!(a.occupied_count(), a.occupied_voxels().count());
        assert_eq!(b.occupied_count(), a.occupied_count());
        let total: u32 = a.occupied_voxels().map(|(_, s)| s.count).sum();
        assert_eq!(total, 20_000);
    }

    #[test]
    fn thread_count_does_not_change_a_bit() {
        let mut rng = SmallRng::seed_from_u64(23);
        let pts: Vec<Vec3> = (0..50_000)
            .map(|_| {
                Vec3::new(
                    rng.gen_range(-3.0..3.0),
                    rng.gen_range(-3.0..3.0),
                    rng.gen_range(-0.3..0.3),
                )
            })
            .collect();
        let build = |threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let mut g = grid();
                g.insert_points(&pts);
                g
            })
        };
        let (one, many) = (build(1), build(4));
        let a: Vec<_> = one.occupied_voxels().map(|(v, s)| (v, *s)).collect();
        let b: Vec<_> = many.occupied_voxels().map(|(v, s)| (v, *s)).collect();
        assert_eq!(a, b);
        assert_eq!(one.memory_bytes(), many.memory_bytes());
    }

    #[test]
    fn neighbourhood_across_a_cell_border_equals_batch() {
        let mut g = grid();
        // Vertex (20, 20, 20) is the corner shared by eight 1 m cells.
        let corner = IVec3::splat(20);
        let c = g.corner_position(corner);
        let mut rng = SmallRng::seed_from_u64(22);
        let pts: Vec<Vec3> = (0..5000)
            .map(|_| {
                c + Vec3::new(
                    rng.gen_range(-0.1..0.1),
                    rng.gen_range(-0.1..0.1),
                    rng.gen_range(-0.1..0.1),
                )
            })
            .collect();
        g.insert_points(&pts);
        assert_eq!(g.cell_count(), 8);
        let inside: Vec<DVec3> = pts
            .iter()
            .filter(|&&p| {
                let v = g.voxel_of(p).unwrap();
                (v - corner + IVec3::ONE).cmpge(IVec3::ZERO).all()
                    && (v - corner).cmple(IVec3::ZERO).all()
            })
            .map(|p| p.as_dvec3())
            .collect();
        assert!(inside.len() > 400);
        assert_close(&g.neighbourhood(corner), &VoxelStats::from_points(&inside));
        assert!(g.neighbourhood(IVec3::splat(100)).is_empty());
    }
}
