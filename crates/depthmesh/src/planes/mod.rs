//! Voxel planes (Ryde, Dhiman and Platt, "Voxel Planes: Rapid Visualization
//! and Meshification of Point Cloud Ensembles").
//!
//! Points are binned into fine voxels (0.05 m) held in a semi-sparse map of
//! coarse cells (1 m), see [`grid`]. Each voxel keeps only sufficient
//! statistics of its points — count, centroid and scatter, see [`stats`] —
//! so new points are folded in as they arrive and never stored. Planes are
//! fitted not per voxel but per 2×2×2 window around each voxel-grid vertex
//! (the paper's sliding window): the eight voxels' statistics are combined
//! by eqs. (2)–(3) ([`stats::VoxelStats::merge`]) and the combined
//! covariance decomposed ([`eigen`]). A window is planar when two
//! eigenvalues are large and one small, [`is_planar`]; its smallest
//! eigenvector is the plane normal.
//!
//! A planar window is meshed ([`mapper`]) by cutting its plane with the
//! voxel-sized cube centred on its vertex ([`polygon`], eq. 4): those cubes
//! tile space, so the patches of neighbouring windows tessellate. Patches are
//! coloured by their unoriented normal ([`crate::palette::normal_color`],
//! eqs. 5–7), and only windows touching a changed voxel are re-meshed.

pub mod eigen;
pub mod grid;
pub mod mapper;
pub mod polygon;
pub mod runs;
pub mod stats;

pub use eigen::{symmetric_eigen, SymmetricEigen};
pub use grid::{Inserted, PlaneGrid, PlaneGridConfig};
pub use mapper::{PlanesConfig, PlanesMapper};
pub use stats::{Sym3, VoxelStats};

/// The paper's anticipated point noise ε in metres (sensor noise plus
/// registration error).
pub const DEFAULT_EPSILON: f64 = 0.02;

/// The paper's planarity test on a window's covariance eigenvalues (in any
/// order): with λ0 ≥ λ1 ≥ λ2 and λt = ε², planar when λ0 > λt, λ1 > λt and
/// λ2 < λt.
///
/// The eigenvalues are variances along the principal axes, so ε is a
/// standard deviation: a plane has two axes spread wider than the noise
/// and one within it. A line fails on λ1, a blob on λ2.
pub fn is_planar(eigenvalues: [f64; 3], epsilon: f64) -> bool {
    let mut l = eigenvalues;
    l.sort_by(|a, b| b.total_cmp(a));
    let t = epsilon * epsilon;
    l[0] > t && l[1] > t && l[2] < t
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DVec3, IVec3, Vec3};
    use rand::rngs::SmallRng;
    use rand::{Rng, SeedableRng};

    fn grid() -> PlaneGrid {
        PlaneGrid::new(PlaneGridConfig::default()).unwrap()
    }

    #[test]
    fn threshold_is_epsilon_squared() {
        let e = 0.02;
        assert!(is_planar([1e-3, 1e-3, 1e-5], e));
        assert!(is_planar([1e-5, 1e-3, 5e-4], e));
        assert!(!is_planar([1e-3, 1e-5, 1e-5], e));
        assert!(!is_planar([1e-3, 1e-3, 5e-4], e));
        assert!(!is_planar([0.0; 3], e));
    }

    #[test]
    fn plane_gives_its_normal_and_is_planar() {
        let mut rng = SmallRng::seed_from_u64(31);
        let normal = DVec3::new(1.0, 2.0, 3.0).normalize();
        let u = normal.any_orthonormal_vector();
        let w = normal.cross(u);
        let mut g = grid();
        // Vertex on a cell border, so the window spans cells too.
        let corner = IVec3::new(20, 3, -7);
        let c = g.corner_position(corner).as_dvec3();
        let pts: Vec<Vec3> = (0..20_000)
            .map(|_| {
                let p = c + u * rng.gen_range(-0.15..0.15) + w * rng.gen_range(-0.15..0.15);
                p.as_vec3()
            })
            .collect();
        g.insert_points(&pts);
        let s = g.neighbourhood(corner);
        assert!(s.count > 1000);
        let e = s.eigen();
        // f32 points: the plane is exact to ~1e-8 m, far below 1e-6.
        assert!(
            e.vectors[0].dot(normal).abs() > 1.0 - 1e-6,
            "{}",
            e.vectors[0]
        );
        assert!(1.0 - e.vectors[0].dot(normal).abs() < 1e-6);
        assert!(is_planar(e.values, DEFAULT_EPSILON), "{:?}", e.values);
    }

    #[test]
    fn line_is_not_planar() {
        let mut rng = SmallRng::seed_from_u64(32);
        let dir = Vec3::new(0.3, -1.0, 0.2).normalize();
        let mut g = grid();
        let corner = IVec3::new(5, 5, 5);
        let c = g.corner_position(corner);
        let pts: Vec<Vec3> = (0..5000)
            .map(|_| c + dir * rng.gen_range(-0.3..0.3))
            .collect();
        g.insert_points(&pts);
        let e = g.neighbourhood(corner).eigen();
        assert!(e.values[2] > DEFAULT_EPSILON * DEFAULT_EPSILON);
        assert!(!is_planar(e.values, DEFAULT_EPSILON), "{:?}", e.values);
    }

    #[test]
    fn blob_is_not_planar() {
        let mut rng = SmallRng::seed_from_u64(33);
        let mut g = grid();
        let corner = IVec3::new(-3, 0, 40);
        let c = g.corner_position(corner);
        let pts: Vec<Vec3> = (0..20_000)
            .map(|_| {
                c + Vec3::new(
                    rng.gen_range(-0.2..0.2),
                    rng.gen_range(-0.2..0.2),
                    rng.gen_range(-0.2..0.2),
                )
            })
            .collect();
        g.insert_points(&pts);
        let e = g.neighbourhood(corner).eigen();
        assert!(!is_planar(e.values, DEFAULT_EPSILON), "{:?}", e.values);
    }
}
