//! Eigen-decomposition of symmetric 3×3 matrices by cyclic Jacobi rotations.
//!
//! Jacobi is slower than the closed-form cubic but accurate to working
//! precision for every input, including the repeated and near-zero
//! eigenvalues a planar or linear neighbourhood produces, where the
//! closed form loses the smallest eigenvector: the one we need as the normal.

use glam::{DMat3, DVec3};

/// Sweeps after which the rotation stops; Jacobi converges quadratically, a
/// 3×3 matrix in f64 needs 4–6.
const MAX_SWEEPS: usize = 32;

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
    let mut a = m.to_cols_array_2d();
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let norm2: f64 = a.iter().flatten().map(|x| x * x).sum();
    for _ in 0..MAX_SWEEPS {
        let off2 = 2.0 * (a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2]);
        // Relative to the whole matrix: what is left is below rounding.
        if off2 <= (f64::EPSILON * f64::EPSILON) * norm2 * 1e-4 || !off2.is_finite() {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            rotate(&mut a, &mut v, p, q);
        }
    }
    // `a` and `v` are column-major arrays: `v[i]` is the i-th eigenvector.
    let mut order = [0, 1, 2];
    order.sort_by(|&i, &j| a[i][i].total_cmp(&a[j][j]));
    let values = order.map(|i| a[i][i]);
    let mut vectors = order.map(|i| DVec3::from_array(v[i]).normalize_or_zero());
    // A right-handed frame, so callers can rely on v0 = v1 × v2.
    if vectors[0].dot(vectors[1].cross(vectors[2])) < 0.0 {
        vectors[0] = -vectors[0];
    }
    SymmetricEigen { values, vectors }
}

/// One Jacobi rotation zeroing `a[p][q]` (Numerical Recipes' form, which
/// chooses the smaller rotation angle for stability).
// Index loops: the p/q row and column updates read as the textbook formulas.
#[allow(clippy::needless_range_loop)]
fn rotate(a: &mut [[f64; 3]; 3], v: &mut [[f64; 3]; 3], p: usize, q: usize) {
    let apq = a[q][p];
    if apq == 0.0 {
        return;
    }
    let theta = (a[q][q] - a[p][p]) / (2.0 * apq);
    let t = if theta.abs() > 1e150 {
        // θ² would overflow; t ≈ 1/(2θ) there.
        0.5 / theta
    } else {
        theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt())
    };
    let c = 1.0 / (t * t + 1.0).sqrt();
    let s = t * c;
    // a ← a·P (columns p, q), then a ← Pᵀ·a (rows p, q); arrays are
    // column-major, so `a[col][row]`.
    for k in 0..3 {
        let (akp, akq) = (a[p][k], a[q][k]);
        a[p][k] = c * akp - s * akq;
        a[q][k] = s * akp + c * akq;
    }
    for k in 0..3 {
        let (apk, aqk) = (a[k][p], a[k][q]);
        a[k][p] = c * apk - s * aqk;
        a[k][q] = s * apk + c * aqk;
    }
    // Exactly zero, rather than the rounding residue, so later sweeps see it.
    a[q][p] = 0.0;
    a[p][q] = 0.0;
    for k in 0..3 {
        let (vkp, vkq) = (v[p][k], v[q][k]);
        v[p][k] = c * vkp - s * vkq;
        v[q][k] = s * vkp + c * vkq;
    }
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
