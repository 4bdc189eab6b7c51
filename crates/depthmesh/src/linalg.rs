//! Small dense symmetric systems: the 6×6 normal equations of ICP and the
//! 4×4 matrix of Horn's rigid fit (trajectory alignment, relocalisation).
//!
//! Both are fixed-size and tiny, so plain arrays on the stack beat a general
//! matrix library, and the code stays short enough to read as the textbook.

use glam::{DMat3, DQuat, DVec3};

/// Sweeps after which Jacobi stops; it converges quadratically, small
/// matrices in f64 need well under ten.
const MAX_SWEEPS: usize = 50;

/// Solves `a·x = b` for a symmetric positive definite `a` by Cholesky
/// decomposition (row-major; only the lower triangle is read).
///
/// `None` when `a` is not numerically positive definite (a pivot at or below
/// `1e-12` of the largest diagonal entry, or not finite): the caller's system
/// is degenerate and has no unique solution.
#[allow(clippy::needless_range_loop)] // Index loops read as the textbook formulas.
pub fn cholesky_solve<const N: usize>(a: &[[f64; N]; N], b: &[f64; N]) -> Option<[f64; N]> {
    let scale = (0..N).map(|i| a[i][i].abs()).fold(0.0, f64::max);
    if !(scale.is_finite() && scale > 0.0) {
        return None;
    }
    let mut l = [[0.0; N]; N];
    for i in 0..N {
        for j in 0..=i {
            let mut s = a[i][j];
            for k in 0..j {
                s -= l[i][k] * l[j][k];
            }
            if i == j {
                // Also rejects NaN pivots.
                if s.is_nan() || s <= 1e-12 * scale {
                    return None;
                }
                l[i][i] = s.sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    // L·y = b, then Lᵀ·x = y.
    let mut y = [0.0; N];
    for i in 0..N {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i][k] * y[k];
        }
        y[i] = s / l[i][i];
    }
    let mut x = [0.0; N];
    for i in (0..N).rev() {
        let mut s = y[i];
        for k in i + 1..N {
            s -= l[k][i] * x[k];
        }
        x[i] = s / l[i][i];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Eigenvalues (ascending) and unit eigenvectors (`vectors[i]` for
/// `values[i]`) of a symmetric matrix, by cyclic Jacobi rotations.
///
/// Jacobi is accurate to working precision for every input, including the
/// repeated and near-zero eigenvalues of degenerate systems, which is what
/// the callers test for. Non-finite input gives non-finite output, never a
/// hang.
#[allow(clippy::needless_range_loop)] // Index loops read as the textbook formulas.
pub fn symmetric_eigen<const N: usize>(m: &[[f64; N]; N]) -> ([f64; N], [[f64; N]; N]) {
    let mut a = *m;
    let mut v = [[0.0; N]; N];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    let norm2: f64 = a.iter().flatten().map(|x| x * x).sum();
    for _ in 0..MAX_SWEEPS {
        let mut off2 = 0.0;
        for p in 0..N {
            for q in p + 1..N {
                off2 += 2.0 * a[p][q] * a[p][q];
            }
        }
        // Relative to the whole matrix: what is left is below rounding.
        if off2 <= (f64::EPSILON * f64::EPSILON) * norm2 * 1e-4 || !off2.is_finite() {
            break;
        }
        for p in 0..N {
            for q in p + 1..N {
                rotate(&mut a, &mut v, p, q);
            }
        }
    }
    let mut order: [usize; N] = std::array::from_fn(|i| i);
    order.sort_by(|&i, &j| a[i][i].total_cmp(&a[j][j]));
    (order.map(|i| a[i][i]), order.map(|i| v[i]))
}

/// One Jacobi rotation zeroing `a[p][q]` (Numerical Recipes' form, which
/// chooses the smaller rotation angle for stability). `v` holds the
/// eigenvectors as rows.
#[allow(clippy::needless_range_loop)] // The p/q updates read as the textbook formulas.
fn rotate<const N: usize>(a: &mut [[f64; N]; N], v: &mut [[f64; N]; N], p: usize, q: usize) {
    let apq = a[p][q];
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
    // a ← a·P (columns p, q), then a ← Pᵀ·a (rows p, q).
    for k in 0..N {
        let (akp, akq) = (a[k][p], a[k][q]);
        a[k][p] = c * akp - s * akq;
        a[k][q] = s * akp + c * akq;
    }
    for k in 0..N {
        let (apk, aqk) = (a[p][k], a[q][k]);
        a[p][k] = c * apk - s * aqk;
        a[q][k] = s * apk + c * aqk;
    }
    // Exactly zero, rather than the rounding residue, so later sweeps see it.
    a[p][q] = 0.0;
    a[q][p] = 0.0;
    for k in 0..N {
        let (vpk, vqk) = (v[p][k], v[q][k]);
        v[p][k] = c * vpk - s * vqk;
        v[q][k] = s * vpk + c * vqk;
    }
}

/// The rigid motion `(R, t)` minimising Σ‖R·e + t − r‖² over the pairs
/// `(e, r)` (Horn 1987: the rotation is the dominant eigenvector of a
/// symmetric 4×4 matrix built from the cross-covariance). The pairs are
/// read twice, so an iterator over borrowed points costs no allocation.
/// Without pairs the rotation is the identity and the translation not finite.
pub fn horn(pairs: impl Iterator<Item = (DVec3, DVec3)> + Clone) -> (DMat3, DVec3) {
    let (mut n, mut sum_e, mut sum_r) = (0.0, DVec3::ZERO, DVec3::ZERO);
    for (e, r) in pairs.clone() {
        n += 1.0;
        sum_e += e;
        sum_r += r;
    }
    let (mean_e, mean_r) = (sum_e / n, sum_r / n);
    // s[i][j] = Σ e_i · r_j of the centred points.
    let mut s = [[0.0; 3]; 3];
    for (e, r) in pairs {
        let (e, r) = ((e - mean_e).to_array(), (r - mean_r).to_array());
        for (i, row) in s.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v += e[i] * r[j];
            }
        }
    }
    let [[xx, xy, xz], [yx, yy, yz], [zx, zy, zz]] = s;
    let m = [
        [xx + yy + zz, yz - zy, zx - xz, xy - yx],
        [yz - zy, xx - yy - zz, xy + yx, zx + xz],
        [zx - xz, xy + yx, -xx + yy - zz, yz + zy],
        [xy - yx, zx + xz, yz + zy, -xx - yy + zz],
    ];
    let (_, vectors) = symmetric_eigen(&m);
    let [w, x, y, z] = vectors[3];
    let q = DQuat::from_xyzw(x, y, z, w);
    let rotation = if q.length() > 0.5 {
        DMat3::from_quat(q.normalize())
    } else {
        DMat3::IDENTITY
    };
    (rotation, mean_r - rotation * mean_e)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::SmallRng;
    use rand::{Rng, SeedableRng};

    fn random_spd(rng: &mut SmallRng) -> [[f64; 6]; 6] {
        let g: [[f64; 6]; 6] =
            std::array::from_fn(|_| std::array::from_fn(|_| rng.gen_range(-1.0..1.0)));
        std::array::from_fn(|i| {
            std::array::from_fn(|j| {
                (0..6).map(|k| g[i][k] * g[j][k]).sum::<f64>() + if i == j { 0.1 } else { 0.0 }
            })
        })
    }

    #[test]
    fn cholesky_solves_spd_systems() {
        let mut rng = SmallRng::seed_from_u64(7);
        for _ in 0..100 {
            let a = random_spd(&mut rng);
            let x: [f64; 6] = std::array::from_fn(|_| rng.gen_range(-2.0..2.0));
            let b: [f64; 6] = std::array::from_fn(|i| (0..6).map(|j| a[i][j] * x[j]).sum());
            let got = cholesky_solve(&a, &b).unwrap();
            for i in 0..6 {
                assert!((got[i] - x[i]).abs() < 1e-8, "{got:?} vs {x:?}");
            }
        }
    }

    #[test]
    fn cholesky_rejects_singular_and_non_finite_systems() {
        // Rank 3: only the first three unknowns are constrained.
        let mut a = [[0.0; 6]; 6];
        for (i, row) in a.iter_mut().enumerate().take(3) {
            row[i] = 1.0;
        }
        assert_eq!(cholesky_solve(&a, &[1.0; 6]), None);
        assert_eq!(cholesky_solve(&[[0.0; 6]; 6], &[0.0; 6]), None);
        let mut nan = [[0.0; 6]; 6];
        for (i, row) in nan.iter_mut().enumerate() {
            row[i] = 1.0;
        }
        nan[2][2] = f64::NAN;
        assert_eq!(cholesky_solve(&nan, &[1.0; 6]), None);
    }

    #[test]
    fn eigen_decomposes_symmetric_matrices() {
        let mut rng = SmallRng::seed_from_u64(3);
        for _ in 0..100 {
            let a = random_spd(&mut rng);
            let (values, vectors) = symmetric_eigen(&a);
            for w in values.windows(2) {
                assert!(w[0] <= w[1]);
            }
            for (l, v) in values.iter().zip(&vectors) {
                for i in 0..6 {
                    let av: f64 = (0..6).map(|j| a[i][j] * v[j]).sum();
                    assert!((av - l * v[i]).abs() < 1e-9);
                }
                let norm: f64 = v.iter().map(|x| x * x).sum();
                assert!((norm - 1.0).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn eigen_finds_the_null_space_of_a_degenerate_matrix() {
        let mut a = [[0.0; 6]; 6];
        for (i, row) in a.iter_mut().enumerate().take(3) {
            row[i] = 2.0;
        }
        let (values, _) = symmetric_eigen(&a);
        assert_eq!(values, [0.0, 0.0, 0.0, 2.0, 2.0, 2.0]);
        let (values, _) = symmetric_eigen(&[[f64::NAN; 4]; 4]);
        assert!(values.iter().all(|v| v.is_nan()));
    }
}
