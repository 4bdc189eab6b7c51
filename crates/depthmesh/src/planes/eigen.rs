//! Eigen-decomposition of symmetric 3×3 matrices by cyclic Jacobi rotations.
//!
//! Jacobi is slower than the closed-form cubic but accurate to working
//! precision for every input, including the repeated and near-zero
//! eigenvalues a planar or linear neighbourhood produces, where the
//! closed form loses the smallest eigenvector: the one we need as the normal.

use glam::{DMat3, DVec3};

/// Eigenvalues and eigenvectors of a symmetric matrix.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SymmetricEigen {
    /// Eigenvalues, ascending.
    pub values: [f64; 3],
    /// Unit eigenvectors, `vectors[i]` belongs to `values[i]`; mutually
    /// orthogonal and right-handed.
    pub vectors: [DVec3; 3],
}

/// Eigen-decomposition of `m`, which must be symmetric (only the upper
/// triangle's values are trusted to match the lower one).
pub fn symmetric_eigen(m: DMat3) -> SymmetricEigen {
    let (values, vectors) = crate::linalg::symmetric_eigen(&m.transpose().to_cols_array_2d());
    let mut vectors = vectors.map(|v| DVec3::from_array(v).normalize_or_zero());
    // A right-handed frame, so callers can rely on v0 = v1 × v2.
    if vectors[0].dot(vectors[1].cross(vectors[2])) < 0.0 {
        vectors[0] = -vectors[0];
    }
    SymmetricEigen { values, vectors }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::SmallRng;
    use rand::{Rng, SeedableRng};

    /// A·v = λ·v, orthonormal, ascending; tolerance relative to ‖A‖.
    fn check(m: DMat3, e: &SymmetricEigen) {
        let scale = (0..3)
            .map(|i| m.col(i).abs().max_element())
            .fold(1.0_f64, f64::max);
        assert!(e.values[0] <= e.values[1] && e.values[1] <= e.values[2]);
        for i in 0..3 {
            let r = m * e.vectors[i] - e.vectors[i] * e.values[i];
            assert!(
                r.abs().max_element() <= 1e-9 * scale,
                "residual {r} for λ{i} = {}",
                e.values[i]
            );
            for j in 0..3 {
                let d = e.vectors[i].dot(e.vectors[j]);
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((d - want).abs() <= 1e-12, "v{i}·v{j} = {d}");
            }
        }
        let det = e.vectors[0].dot(e.vectors[1].cross(e.vectors[2]));
        assert!((det - 1.0).abs() < 1e-12);
    }

    fn random_rotation(rng: &mut SmallRng) -> DMat3 {
        let axis = DVec3::new(rng.gen(), rng.gen(), rng.gen()) - 0.5;
        DMat3::from_axis_angle(axis.normalize(), rng.gen_range(0.0..6.0))
    }

    #[test]
    fn diagonal() {
        let m = DMat3::from_diagonal(DVec3::new(3.0, -1.0, 2.0));
        let e = symmetric_eigen(m);
        check(m, &e);
        assert_eq!(e.values, [-1.0, 2.0, 3.0]);
        assert!((e.vectors[0].dot(DVec3::Y)).abs() > 1.0 - 1e-15);
    }

    #[test]
    fn rotated() {
        let mut rng = SmallRng::seed_from_u64(11);
        for _ in 0..200 {
            let r = random_rotation(&mut rng);
            let d = DVec3::new(rng.gen(), rng.gen::<f64>() * 10.0, rng.gen::<f64>() * 1e-3);
            let m = r * DMat3::from_diagonal(d) * r.transpose();
            let e = symmetric_eigen(m);
            check(m, &e);
            let mut want = d.to_array();
            want.sort_by(f64::total_cmp);
            for (got, want) in e.values.iter().zip(want) {
                assert!((got - want).abs() < 1e-12 * 10.0);
            }
        }
    }

    #[test]
    fn repeated_eigenvalues() {
        let mut rng = SmallRng::seed_from_u64(12);
        for d in [
            DVec3::new(2.0, 2.0, 5.0),
            DVec3::new(1.0, 4.0, 4.0),
            DVec3::splat(7.0),
        ] {
            let r = random_rotation(&mut rng);
            let m = r * DMat3::from_diagonal(d) * r.transpose();
            check(m, &symmetric_eigen(m));
        }
    }

    #[test]
    fn rank_deficient() {
        let mut rng = SmallRng::seed_from_u64(13);
        // Rank 2 (a plane's scatter), rank 1 (a line's), rank 0.
        for d in [
            DVec3::new(0.0, 1.0, 3.0),
            DVec3::new(0.0, 0.0, 2.0),
            DVec3::ZERO,
        ] {
            let r = random_rotation(&mut rng);
            let m = r * DMat3::from_diagonal(d) * r.transpose();
            let e = symmetric_eigen(m);
            check(m, &e);
            assert!(e.values[0].abs() < 1e-14);
        }
        // The plane's normal is the null vector.
        let r = random_rotation(&mut rng);
        let m = r * DMat3::from_diagonal(DVec3::new(0.0, 1.0, 3.0)) * r.transpose();
        let e = symmetric_eigen(m);
        assert!(e.vectors[0].dot(r.col(0)).abs() > 1.0 - 1e-12);
    }

    #[test]
    fn random_symmetric() {
        let mut rng = SmallRng::seed_from_u64(14);
        for _ in 0..500 {
            let b = DMat3::from_cols_array(&std::array::from_fn(|_| rng.gen_range(-1.0..1.0)));
            let m = b + b.transpose();
            check(m, &symmetric_eigen(m));
        }
    }
}
