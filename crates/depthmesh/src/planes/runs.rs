//! A depth frame's points gathered into per-voxel statistics without
//! storing them: consecutive pixels of a row mostly land in the same voxel
//! (a 5 cm voxel spans a dozen pixels at 2 m), so each such run is summed
//! on the fly and merged into the grid once (eqs. 2–3), instead of every
//! point being binned, sorted and added on its own.

use super::grid::PlaneGrid;
use super::stats::{Sym3, VoxelStats};
use crate::camera::{Intrinsics, Pose};
use crate::image::DepthImage;
use glam::{DVec3, IVec3, Vec3};
use rayon::prelude::*;

/// Rows per parallel task; fixed, so the runs (and the statistics they
/// make) do not depend on the thread count.
const BAND_ROWS: usize = 8;

/// World points of one image row: the ray of pixel `u` is `start + u · step`
/// (per unit depth), two multiply-adds per pixel instead of a
/// back-projection and a rotation.
pub struct RowRays {
    origin: Vec3,
    start: Vec3,
    step: Vec3,
}

impl RowRays {
    /// The rays of row `v` of a camera with `intrinsics` at `pose`.
    pub fn new(intrinsics: &Intrinsics, pose: &Pose, v: f32) -> Self {
        let start = pose.transform_vector(intrinsics.back_project(0.0, v, 1.0));
        let step = pose.transform_vector(intrinsics.back_project(1.0, v, 1.0)) - start;
        RowRays {
            origin: pose.translation,
            start,
            step,
        }
    }

    /// The world point of pixel `u` of the row at depth `z`.
    #[inline]
    pub fn point(&self, u: usize, z: f32) -> Vec3 {
        self.origin + (self.start + self.step * u as f32) * z
    }
}

/// The points of one run, summed relative to its first point so that no
/// large coordinates are squared.
struct Run {
    voxel: IVec3,
    origin: DVec3,
    count: u32,
    sum: DVec3,
    products: Sym3,
}

impl Run {
    fn new(voxel: IVec3, origin: DVec3) -> Self {
        Run {
            voxel,
            origin,
            count: 0,
            sum: DVec3::ZERO,
            products: Sym3::default(),
        }
    }

    #[inline]
    fn add(&mut self, p: DVec3) {
        let d = p - self.origin;
        self.count += 1;
        self.sum += d;
        self.products = self.products + Sym3::outer(d, 1.0);
    }

    /// Count, mean and scatter: Σddᵀ − (Σd)(Σd)ᵀ/n, whose terms are small
    /// (offsets within one voxel), so the difference keeps its digits.
    fn stats(&self) -> (IVec3, VoxelStats) {
        let n = f64::from(self.count);
        let stats = VoxelStats {
            count: self.count,
            mean: self.origin + self.sum / n,
            scatter: self.products + Sym3::outer(self.sum, -1.0 / n),
        };
        (self.voxel, stats)
    }
}

/// The statistics of the world points of `depth`'s valid pixels (the same
/// points as [`super::mapper::frame_points`]), one entry per run of
/// consecutive pixels of a row in one voxel of `grid`, into `out` (cleared
/// first). Feed them to [`PlaneGrid::insert_stats`].
pub fn depth_runs(
    grid: &PlaneGrid,
    depth: &DepthImage,
    intrinsics: &Intrinsics,
    pose: &Pose,
    out: &mut Vec<(IVec3, VoxelStats)>,
) {
    out.clear();
    let width = depth.width.max(1) as usize;
    let bands: Vec<Vec<(IVec3, VoxelStats)>> = depth
        .data
        .par_chunks(width * BAND_ROWS)
        .enumerate()
        .map(|(band, rows)| {
            let mut runs = Vec::new();
            for (r, row) in rows.chunks(width).enumerate() {
                let v = (band * BAND_ROWS + r) as f32;
                let ray = RowRays::new(intrinsics, pose, v);
                let mut run: Option<Run> = None;
                for (u, &z) in row.iter().enumerate() {
                    if !(z > 0.0 && z.is_finite()) {
                        continue;
                    }
                    let p = ray.point(u, z);
                    let Some(voxel) = grid.voxel_of(p) else {
                        continue;
                    };
                    let current = match &mut run {
                        Some(r) if r.voxel == voxel => r,
                        _ => {
                            if let Some(done) = run.take() {
                                runs.push(done.stats());
                            }
                            run.insert(Run::new(voxel, p.as_dvec3()))
                        }
                    };
                    current.add(p.as_dvec3());
                }
                if let Some(done) = run {
                    runs.push(done.stats());
                }
            }
            runs
        })
        .collect();
    out.extend(bands.into_iter().flatten());
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::planes::grid::PlaneGridConfig;
    use crate::planes::mapper::frame_points;

    /// A tilted, bumpy depth image seen from an off-origin pose.
    fn frame() -> (DepthImage, Intrinsics, Pose) {
        let k = Intrinsics::from_vertical_fov(160, 120, 60.0);
        let mut depth = DepthImage::new(k.width, k.height);
        for (i, d) in depth.data.iter_mut().enumerate() {
            let (u, v) = ((i % 160) as f32, (i / 160) as f32);
            *d = if ((u + v) as u32).is_multiple_of(17) {
                0.0
            } else {
                1.5 + 0.004 * u + 0.002 * v + 0.01 * (u * 0.3).sin()
            };
        }
        let pose = Pose::look_at(
            Vec3::new(101.0, -40.0, 7.0),
            Vec3::new(103.0, -40.5, 8.0),
            Vec3::Y,
        );
        (depth, k, pose)
    }

    #[test]
    fn runs_give_the_statistics_of_the_points() {
        let (depth, k, pose) = frame();
        let config = PlaneGridConfig::default();
        let mut by_points = PlaneGrid::new(config).unwrap();
        let mut points = Vec::new();
        frame_points(&depth, &k, &pose, &mut points);
        let a = by_points.insert_points(&points);
        let mut by_runs = PlaneGrid::new(config).unwrap();
        let mut runs = Vec::new();
        depth_runs(&by_runs, &depth, &k, &pose, &mut runs);
        assert!(runs.len() < points.len() / 2, "runs merge pixels");
        let b = by_runs.insert_stats(&runs);
        assert_eq!(a.points, b.points);
        assert_eq!(a.changed, b.changed);
        assert_eq!(by_points.occupied_count(), by_runs.occupied_count());
        for (v, s) in by_points.occupied_voxels() {
            let t = by_runs.voxel(v).unwrap();
            assert_eq!(s.count, t.count);
            assert!((s.mean - t.mean).abs().max_element() < 1e-9);
            let (ms, mt) = (s.scatter.to_mat3(), t.scatter.to_mat3());
            for i in 0..3 {
                assert!((ms.col(i) - mt.col(i)).abs().max_element() < 1e-9);
            }
        }
    }

    #[test]
    fn runs_do_not_depend_on_the_thread_count() {
        let (depth, k, pose) = frame();
        let grid = PlaneGrid::new(PlaneGridConfig::default()).unwrap();
        let gather = |threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let mut runs = Vec::new();
            pool.install(|| depth_runs(&grid, &depth, &k, &pose, &mut runs));
            runs
        };
        assert_eq!(gather(1), gather(3));
    }
}
