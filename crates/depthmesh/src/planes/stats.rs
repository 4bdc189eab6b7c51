//! Sufficient statistics of the points in a voxel: count, centroid and
//! scatter, updated one point at a time (Welford) or combined pairwise
//! (Chan, Golub and LeVeque), which is the paper's eqs. (2)–(3).
//!
//! The scatter (sum of outer products of deviations from the mean) is kept
//! instead of the covariance, and everything is `f64`, so that neither the
//! update nor the merge subtracts two large, nearly equal numbers: a map
//! kilometres from its origin keeps centimetre-scale covariances exact.

use super::eigen::{symmetric_eigen, SymmetricEigen};
use glam::{DMat3, DVec3};

/// A symmetric 3×3 matrix stored as its six distinct entries.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Sym3 {
    /// Entry (0, 0).
    pub xx: f64,
    /// Entries (0, 1) and (1, 0).
    pub xy: f64,
    /// Entries (0, 2) and (2, 0).
    pub xz: f64,
    /// Entry (1, 1).
    pub yy: f64,
    /// Entries (1, 2) and (2, 1).
    pub yz: f64,
    /// Entry (2, 2).
    pub zz: f64,
}

impl Sym3 {
    /// `w · d dᵀ`.
    #[inline]
    pub fn outer(d: DVec3, w: f64) -> Self {
        Sym3 {
            xx: w * d.x * d.x,
            xy: w * d.x * d.y,
            xz: w * d.x * d.z,
            yy: w * d.y * d.y,
            yz: w * d.y * d.z,
            zz: w * d.z * d.z,
        }
    }

    /// Every entry times `s`.
    #[inline]
    pub fn scale(self, s: f64) -> Self {
        Sym3 {
            xx: self.xx * s,
            xy: self.xy * s,
            xz: self.xz * s,
            yy: self.yy * s,
            yz: self.yz * s,
            zz: self.zz * s,
        }
    }

    /// The full matrix.
    pub fn to_mat3(self) -> DMat3 {
        DMat3::from_cols(
            DVec3::new(self.xx, self.xy, self.xz),
            DVec3::new(self.xy, self.yy, self.yz),
            DVec3::new(self.xz, self.yz, self.zz),
        )
    }
}

impl std::ops::Add for Sym3 {
    type Output = Sym3;

    /// Entry-wise sum.
    #[inline]
    fn add(self, o: Sym3) -> Sym3 {
        Sym3 {
            xx: self.xx + o.xx,
            xy: self.xy + o.xy,
            xz: self.xz + o.xz,
            yy: self.yy + o.yy,
            yz: self.yz + o.yz,
            zz: self.zz + o.zz,
        }
    }
}

/// Count, mean and scatter of a set of points.
///
/// `count == 0` is the empty set (mean and scatter zero); a voxel that never
/// received a point is stored this way rather than as an `Option`, which
/// keeps the fine grids plain arrays.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct VoxelStats {
    /// Number of points.
    pub count: u32,
    /// Centroid of the points.
    pub mean: DVec3,
    /// Σ (p − mean)(p − mean)ᵀ over the points.
    pub scatter: Sym3,
}

impl VoxelStats {
    /// The empty set.
    pub const EMPTY: VoxelStats = VoxelStats {
        count: 0,
        mean: DVec3::ZERO,
        scatter: Sym3 {
            xx: 0.0,
            xy: 0.0,
            xz: 0.0,
            yy: 0.0,
            yz: 0.0,
            zz: 0.0,
        },
    };

    /// Two-pass statistics of `points`: the reference the incremental forms
    /// are tested against.
    pub fn from_points(points: &[DVec3]) -> Self {
        if points.is_empty() {
            return VoxelStats::EMPTY;
        }
        let n = points.len() as f64;
        let mean = points.iter().copied().sum::<DVec3>() / n;
        let scatter = points
            .iter()
            .fold(Sym3::default(), |s, &p| s + Sym3::outer(p - mean, 1.0));
        VoxelStats {
            count: points.len() as u32,
            mean,
            scatter,
        }
    }

    /// True when no point has been added.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Adds one point (Welford's update).
    #[inline]
    pub fn add_point(&mut self, p: DVec3) {
        self.count += 1;
        let n = f64::from(self.count);
        let delta = p - self.mean;
        self.mean += delta / n;
        // delta · (p − new mean)ᵀ = delta deltaᵀ (n − 1)/n, which is symmetric,
        // so the six-entry form loses nothing.
        self.scatter = self.scatter + Sym3::outer(delta, (n - 1.0) / n);
    }

    /// Adds the points of `other` (Chan et al.'s pairwise combination).
    ///
    /// This is eqs. (2)–(3) of the paper with weights pᵢ = nᵢ / n, rewritten
    /// in terms of the difference of the two means so that no large
    /// `X̄ X̄ᵀ` terms cancel.
    pub fn merge(&mut self, other: &VoxelStats) {
        if other.count == 0 {
            return;
        }
        if self.count == 0 {
            *self = *other;
            return;
        }
        let na = f64::from(self.count);
        let nb = f64::from(other.count);
        let n = na + nb;
        let delta = other.mean - self.mean;
        self.mean += delta * (nb / n);
        self.scatter = self.scatter + other.scatter + Sym3::outer(delta, na * nb / n);
        self.count += other.count;
    }

    /// `self` and `other` combined, see [`VoxelStats::merge`].
    pub fn merged(mut self, other: &VoxelStats) -> Self {
        self.merge(other);
        self
    }

    /// Population covariance (scatter / n), the form of eq. (3): its
    /// eigenvalues are the variances the planarity test compares with ε².
    /// Zero for the empty set.
    pub fn covariance(&self) -> DMat3 {
        if self.count == 0 {
            return DMat3::ZERO;
        }
        self.scatter.scale(1.0 / f64::from(self.count)).to_mat3()
    }

    /// Eigen-decomposition of [`VoxelStats::covariance`], eigenvalues ascending:
    /// `vectors[0]` is the normal of the best-fitting plane.
    pub fn eigen(&self) -> SymmetricEigen {
        symmetric_eigen(self.covariance())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::SmallRng;
    use rand::seq::SliceRandom;
    use rand::{Rng, SeedableRng};

    /// Points scattered by centimetres around a point far from the origin,
    /// where a naive Σppᵀ − n p̄p̄ᵀ form would lose most digits.
    fn random_points(n: usize, seed: u64) -> Vec<DVec3> {
        let mut rng = SmallRng::seed_from_u64(seed);
        let centre = DVec3::new(1234.5, -987.25, 42.0);
        (0..n)
            .map(|_| {
                centre
                    + DVec3::new(
                        rng.gen_range(-0.05..0.05),
                        rng.gen_range(-0.02..0.02),
                        rng.gen_range(-0.001..0.001),
                    )
            })
            .collect()
    }

    fn assert_close(a: &VoxelStats, b: &VoxelStats) {
        assert_eq!(a.count, b.count);
        let mean_scale = a.mean.abs().max_element().max(1e-300);
        assert!(
            (a.mean - b.mean).abs().max_element() <= 1e-9 * mean_scale,
            "means {} vs {}",
            a.mean,
            b.mean
        );
        let (ma, mb) = (a.scatter.to_mat3(), b.scatter.to_mat3());
        let scale = (0..3)
            .map(|i| ma.col(i).abs().max_element())
            .fold(1e-300, f64::max);
        for i in 0..3 {
            let d = (ma.col(i) - mb.col(i)).abs().max_element();
            assert!(d <= 1e-9 * scale, "scatter differs by {d} (scale {scale})");
        }
    }

    #[test]
    fn incremental_equals_batch() {
        let points = random_points(1000, 1);
        let batch = VoxelStats::from_points(&points);
        let mut inc = VoxelStats::default();
        for &p in &points {
            inc.add_point(p);
        }
        assert_close(&inc, &batch);
    }

    #[test]
    fn shuffled_order_equals_batch() {
        let mut points = random_points(777, 2);
        let batch = VoxelStats::from_points(&points);
        let mut rng = SmallRng::seed_from_u64(3);
        points.shuffle(&mut rng);
        let mut inc = VoxelStats::default();
        for &p in &points {
            inc.add_point(p);
        }
        assert_close(&inc, &batch);
    }

    #[test]
    fn merge_of_halves_equals_batch() {
        let points = random_points(1001, 4);
        let batch = VoxelStats::from_points(&points);
        let (a, b) = points.split_at(400);
        let mut sa = VoxelStats::default();
        a.iter().for_each(|&p| sa.add_point(p));
        let mut sb = VoxelStats::default();
        b.iter().for_each(|&p| sb.add_point(p));
        assert_close(&sa.merged(&sb), &batch);
        assert_close(&sb.merged(&sa), &batch);
    }

    #[test]
    fn any_merge_tree_equals_batch() {
        let points = random_points(500, 5);
        let batch = VoxelStats::from_points(&points);
        let mut rng = SmallRng::seed_from_u64(6);
        // Random leaves of 1..20 points, then merged in a random order.
        let mut parts = Vec::new();
        let mut rest = &points[..];
        while !rest.is_empty() {
            let k = rng.gen_range(1..=20).min(rest.len());
            parts.push(VoxelStats::from_points(&rest[..k]));
            rest = &rest[k..];
        }
        while parts.len() > 1 {
            let i = rng.gen_range(0..parts.len());
            let a = parts.swap_remove(i);
            let j = rng.gen_range(0..parts.len());
            parts[j].merge(&a);
        }
        assert_close(&parts[0], &batch);
    }

    #[test]
    fn empty_merges_are_identities() {
        let s = VoxelStats::from_points(&random_points(10, 7));
        assert_eq!(s.merged(&VoxelStats::EMPTY), s);
        assert_eq!(VoxelStats::EMPTY.merged(&s), s);
        assert_eq!(VoxelStats::EMPTY.covariance(), DMat3::ZERO);
        assert!(VoxelStats::EMPTY.is_empty());
    }

    #[test]
    fn covariance_is_eq_3() {
        // Eq. (3) evaluated literally (fine near the origin) against ours.
        let mut rng = SmallRng::seed_from_u64(8);
        let pts: Vec<DVec3> = (0..300)
            .map(|_| DVec3::new(rng.gen(), rng.gen(), rng.gen()))
            .collect();
        let parts: Vec<VoxelStats> = pts.chunks(37).map(VoxelStats::from_points).collect();
        let n = pts.len() as f64;
        let mean: DVec3 = parts
            .iter()
            .map(|s| s.mean * (f64::from(s.count) / n))
            .sum();
        let mut cov = DMat3::ZERO;
        for s in &parts {
            let p = f64::from(s.count) / n;
            let term = s.covariance() + outer(s.mean, s.mean) - outer(mean, mean);
            cov += term * p;
        }
        let ours = parts
            .iter()
            .fold(VoxelStats::EMPTY, |acc, s| acc.merged(s))
            .covariance();
        assert!(ours.abs_diff_eq(cov, 1e-12));
    }

    fn outer(a: DVec3, b: DVec3) -> DMat3 {
        DMat3::from_cols(a * b.x, a * b.y, a * b.z)
    }
}
