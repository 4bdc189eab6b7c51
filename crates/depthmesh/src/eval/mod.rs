//! Accuracy of maps and trajectories: distances between meshes and to
//! ground truth, trajectory errors.

pub mod distance;
pub mod trajectory;

use crate::mesh::Mesh;
use distance::MeshDistance;
use glam::Vec3;
use rayon::prelude::*;

/// Points spread over a mesh's surface, about `spacing` metres apart, in a
/// deterministic pattern (each triangle gets a count proportional to its area,
/// placed on a low-discrepancy sequence).
/// A non-positive or non-finite `spacing` gives no points.
pub fn sample_surface(mesh: &Mesh, spacing: f32) -> Vec<Vec3> {
    let mut points = Vec::new();
    if !(spacing > 0.0 && spacing.is_finite()) {
        return points;
    }
    let per_area = 1.0 / (spacing * spacing);
    let mut carry = 0.0f32;
    // The sequence is stepped, not recomputed from the count, so it keeps
    // its precision over millions of samples.
    let (mut su, mut sv) = (0.5f64, 0.5f64);
    for t in 0..mesh.triangle_count() {
        let [a, b, c] = mesh.corners(t);
        carry += 0.5 * (b - a).cross(c - a).length() * per_area;
        while carry >= 1.0 {
            carry -= 1.0;
            // R2 sequence folded into the triangle.
            su = (su + 0.754_877_666_246_692_7).fract();
            sv = (sv + 0.569_840_290_998_053_3).fract();
            let (mut u, mut v) = (su as f32, sv as f32);
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            points.push(a + (b - a) * u + (c - a) * v);
        }
    }
    points
}

/// Fraction of `mesh`'s surface (sampled every `spacing` m) that lies within
/// `tolerance` metres of `reference`; `None` when there is no surface to sample.
pub fn fraction_within(mesh: &Mesh, reference: &Mesh, tolerance: f32, spacing: f32) -> Option<f64> {
    let index = MeshDistance::new(reference, tolerance);
    let points = sample_surface(mesh, spacing);
    if points.is_empty() {
        return None;
    }
    let near = points
        .par_iter()
        .filter(|&&p| index.distance(p).is_some())
        .count();
    Some(near as f64 / points.len() as f64)
}

/// Triangles of `mesh` whose centroid lies within reach of `object` (its
/// index's radius) and out of reach of `others`: the triangles on one object
/// of a scene, leaving out those near a contact, whose owner is unclear.
pub fn triangles_on(mesh: &Mesh, object: &MeshDistance, others: &MeshDistance) -> usize {
    (0..mesh.triangle_count())
        .into_par_iter()
        .filter(|&t| on_object(mesh, t, object, others))
        .count()
}

/// The summed area (square metres) of the triangles of `mesh` that
/// [`triangles_on`] counts on an object. Over the object's area the mesh
/// covers ([`fraction_within`]) it says how many layers of surface the
/// mesh holds there (reading a little low where triangles near other
/// objects are left out).
pub fn area_on(mesh: &Mesh, object: &MeshDistance, others: &MeshDistance) -> f64 {
    (0..mesh.triangle_count())
        .into_par_iter()
        .filter(|&t| on_object(mesh, t, object, others))
        .map(|t| f64::from(mesh.triangle_area(t)))
        .sum::<f64>()
        + 0.0 // an empty sum is −0.0
}

/// Whether triangle `t`'s centroid is within reach of `object` and out of reach of `others`.
fn on_object(mesh: &Mesh, t: usize, object: &MeshDistance, others: &MeshDistance) -> bool {
    let [a, b, c] = mesh.corners(t);
    let p = (a + b + c) / 3.0;
    object.distance(p).is_some() && others.distance(p).is_none()
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
        assert_eq!(fraction_within(&lifted, &mesh, 0.005, 0.02), Some(1.0));
        assert_eq!(fraction_within(&lifted, &mesh, 0.003, 0.02), Some(0.0));
        assert_eq!(fraction_within(&Mesh::default(), &mesh, 0.003, 0.02), None);
        assert!(sample_surface(&mesh, 0.0).is_empty());
    }
}
