//! Accuracy of maps: distances between meshes and to ground truth.

pub mod distance;

use crate::mesh::Mesh;
use distance::MeshDistance;
use glam::Vec3;
use rayon::prelude::*;

/// Points spread over a mesh's surface, about `spacing` metres apart, in a
/// deterministic pattern (each triangle gets a count proportional to its area,
/// placed on a low-discrepancy sequence).
pub fn sample_surface(mesh: &Mesh, spacing: f32) -> Vec<Vec3> {
    let per_area = 1.0 / (spacing * spacing);
    let mut points = Vec::new();
    let mut carry = 0.0f32;
    let mut k = 0u32;
    for t in 0..mesh.triangle_count() {
        let [a, b, c] = mesh.corners(t);
        carry += 0.5 * (b - a).cross(c - a).length() * per_area;
        while carry >= 1.0 {
            carry -= 1.0;
            k += 1;
            // R2 sequence folded into the triangle.
            let (mut u, mut v) = (
                (0.5 + 0.754_877_7 * k as f32).fract(),
                (0.5 + 0.569_840_3 * k as f32).fract(),
            );
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            points.push(a + (b - a) * u + (c - a) * v);
        }
    }
    points
}

/// Fraction of `mesh`'s surface (sampled every `spacing` m) that lies within
/// `tolerance` metres of `reference`.
pub fn fraction_within(mesh: &Mesh, reference: &Mesh, tolerance: f32, spacing: f32) -> f64 {
    let index = MeshDistance::new(reference, tolerance);
    let points = sample_surface(mesh, spacing);
    if points.is_empty() {
        return 0.0;
    }
    let near = points
        .par_iter()
        .filter(|&&p| index.distance(p).is_some())
        .count();
    near as f64 / points.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sampling_covers_the_area_evenly() {
        let mesh = Mesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            ..Mesh::default()
        };
        let pts = sample_surface(&mesh, 0.01);
        assert!((pts.len() as i64 - 10_000).abs() <= 2);
        let left = pts.iter().filter(|p| p.x < 0.5).count() as f64 / pts.len() as f64;
        assert!((left - 0.5).abs() < 0.02);
        let mut lifted = mesh.clone();
        lifted.transform(|p| p + Vec3::new(0.0, 0.0, 0.004), |n| n);
        assert_eq!(fraction_within(&lifted, &mesh, 0.005, 0.02), 1.0);
        assert_eq!(fraction_within(&lifted, &mesh, 0.003, 0.02), 0.0);
    }
}
