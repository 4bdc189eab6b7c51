//! Primitive solids tessellated into meshes, centred at the origin, for scene objects.
//!
//! Every shape has outward counter-clockwise triangles and per-vertex normals.
//! Flat faces get their own vertices so their normals stay flat; curved
//! surfaces share vertices so their normals are smooth.

use crate::mesh::Mesh;
use glam::{Vec2, Vec3};
use std::f32::consts::{PI, TAU};

/// Segments around a cylinder when a scene does not say: fine enough that a
/// 3 cm cup looks round at Kinect resolution.
pub const DEFAULT_CYLINDER_SEGMENTS: u32 = 64;

/// Longitude segments of a sphere when a scene does not say (latitude gets half).
pub const DEFAULT_SPHERE_SEGMENTS: u32 = 32;

/// Fewest segments that still enclose a volume: a triangular prism.
pub const MIN_CYLINDER_SEGMENTS: u32 = 3;

/// Fewest longitude segments that leave at least one ring between the poles.
pub const MIN_SPHERE_SEGMENTS: u32 = 4;

/// An axis-aligned box with full extents `size`: 24 vertices (flat normals), 12 triangles.
pub fn cuboid(size: Vec3) -> Mesh {
    let half = 0.5 * size;
    let mut mesh = Mesh::default();
    for axis in 0..3 {
        for sign in [1.0f32, -1.0] {
            let mut n = Vec3::ZERO;
            n[axis] = sign;
            // u × v = n keeps the quad counter-clockwise seen from outside.
            let mut u = Vec3::ZERO;
            u[(axis + 1) % 3] = 1.0;
            let mut v = Vec3::ZERO;
            v[(axis + 2) % 3] = sign;
            let (c, u, v) = (n * half, u * half, v * half);
            push_quad(&mut mesh, [c - u - v, c + u - v, c + u + v, c - u + v], n);
        }
    }
    mesh
}

/// A finite square in the xz plane with normal +y: `size = (x extent, z extent)`.
pub fn plane(size: Vec2) -> Mesh {
    let (x, z) = (0.5 * size.x, 0.5 * size.y);
    let mut mesh = Mesh::default();
    push_quad(
        &mut mesh,
        [
            Vec3::new(-x, 0.0, -z),
            Vec3::new(-x, 0.0, z),
            Vec3::new(x, 0.0, z),
            Vec3::new(x, 0.0, -z),
        ],
        Vec3::Y,
    );
    mesh
}

/// A capped cylinder with its axis along y: `4 · segments` triangles.
/// `segments` below [`MIN_CYLINDER_SEGMENTS`] is raised to it.
pub fn cylinder(radius: f32, height: f32, segments: u32) -> Mesh {
    let s = segments.max(MIN_CYLINDER_SEGMENTS);
    let h = 0.5 * height;
    let around = |i: u32| {
        let a = TAU * i as f32 / s as f32;
        Vec3::new(a.cos(), 0.0, a.sin())
    };
    let mut mesh = Mesh::default();
    for i in 0..s {
        let d = around(i);
        mesh.positions.push(radius * d - h * Vec3::Y);
        mesh.positions.push(radius * d + h * Vec3::Y);
        mesh.normals.extend([d, d]);
    }
    for i in 0..s {
        let j = (i + 1) % s;
        let (b0, t0, b1, t1) = (2 * i, 2 * i + 1, 2 * j, 2 * j + 1);
        mesh.triangles.extend([[b0, t1, b1], [b0, t0, t1]]);
    }
    for (y, normal) in [(h, Vec3::Y), (-h, Vec3::NEG_Y)] {
        let centre = mesh.positions.len() as u32;
        mesh.positions.push(y * Vec3::Y);
        mesh.normals.push(normal);
        for i in 0..s {
            mesh.positions.push(radius * around(i) + y * Vec3::Y);
            mesh.normals.push(normal);
        }
        for i in 0..s {
            let (a, b) = (centre + 1 + i, centre + 1 + (i + 1) % s);
            // The ring runs x → z, which is clockwise seen from +y.
            mesh.triangles.push(if y > 0.0 {
                [centre, b, a]
            } else {
                [centre, a, b]
            });
        }
    }
    mesh
}

/// A UV sphere: `segments` meridians, `segments / 2` bands of latitude, one
/// vertex per pole (no degenerate triangles), `2 · segments · (segments/2 − 1)` triangles.
/// `segments` below [`MIN_SPHERE_SEGMENTS`] is raised to it.
pub fn sphere(radius: f32, segments: u32) -> Mesh {
    let s = segments.max(MIN_SPHERE_SEGMENTS);
    let bands = s / 2;
    let mut mesh = Mesh::default();
    let mut push = |d: Vec3| {
        mesh.positions.push(radius * d);
        mesh.normals.push(d);
    };
    push(Vec3::Y);
    for j in 1..bands {
        let polar = PI * j as f32 / bands as f32;
        for i in 0..s {
            let a = TAU * i as f32 / s as f32;
            push(Vec3::new(
                polar.sin() * a.cos(),
                polar.cos(),
                polar.sin() * a.sin(),
            ));
        }
    }
    push(Vec3::NEG_Y);
    let south = mesh.positions.len() as u32 - 1;
    // Vertex `i` of ring `j` (rings 1..bands; 0 and `bands` are the poles).
    let ring = |j: u32, i: u32| 1 + (j - 1) * s + i % s;
    for i in 0..s {
        mesh.triangles.push([0, ring(1, i + 1), ring(1, i)]);
        for j in 1..bands - 1 {
            let (a, b, c, d) = (
                ring(j, i),
                ring(j, i + 1),
                ring(j + 1, i + 1),
                ring(j + 1, i),
            );
            mesh.triangles.extend([[a, b, c], [a, c, d]]);
        }
        mesh.triangles
            .push([ring(bands - 1, i), ring(bands - 1, i + 1), south]);
    }
    mesh
}

/// Appends a flat quad given counter-clockwise (seen from outside) with normal `n`.
fn push_quad(mesh: &mut Mesh, corners: [Vec3; 4], n: Vec3) {
    let base = mesh.positions.len() as u32;
    mesh.positions.extend(corners);
    mesh.normals.extend([n; 4]);
    mesh.triangles
        .extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use std::collections::HashMap;

    /// Panics unless every edge (by position, since flat faces duplicate
    /// vertices) is used exactly twice, once in each direction: the surface
    /// is closed and consistently oriented.
    pub(crate) fn assert_closed(mesh: &Mesh) {
        let key = |p: Vec3| (p * 1e5).round().as_ivec3().to_array();
        let mut directed: HashMap<_, u32> = HashMap::new();
        for t in 0..mesh.triangle_count() {
            let c = mesh.corners(t).map(key);
            for k in 0..3 {
                *directed.entry((c[k], c[(k + 1) % 3])).or_default() += 1;
            }
        }
        for (&(a, b), &n) in &directed {
            assert_eq!(n, 1, "edge {a:?}-{b:?} used twice in one direction");
            assert_eq!(directed.get(&(b, a)), Some(&1), "edge {a:?}-{b:?} is open");
        }
    }

    /// Panics unless every face normal points away from the origin and agrees
    /// with its vertex normals' side (shapes are centred and convex).
    fn assert_outward(mesh: &Mesh) {
        assert_eq!(mesh.normals.len(), mesh.positions.len());
        for t in 0..mesh.triangle_count() {
            let [a, b, c] = mesh.corners(t);
            let n = (b - a).cross(c - a);
            let centre = (a + b + c) / 3.0;
            assert!(n.dot(centre) > 0.0, "triangle {t} faces inwards");
            for &i in &mesh.triangles[t] {
                let vn = mesh.normals[i as usize];
                assert!((vn.length() - 1.0).abs() < 1e-5);
                assert!(
                    vn.dot(n) > 0.0,
                    "vertex normal of triangle {t} faces inwards"
                );
            }
        }
    }

    #[test]
    fn cuboid_is_closed_outward_with_exact_area() {
        let m = cuboid(Vec3::new(1.0, 0.1, 0.75));
        assert_eq!((m.vertex_count(), m.triangle_count()), (24, 12));
        assert_closed(&m);
        assert_outward(&m);
        assert!((m.area() - 2.0 * (0.1 + 0.75 + 0.075)).abs() < 1e-5);
        let b = m.bounds();
        assert!((b.min + Vec3::new(0.5, 0.05, 0.375)).length() < 1e-6);
        assert!((b.max - Vec3::new(0.5, 0.05, 0.375)).length() < 1e-6);
    }

    #[test]
    fn cylinder_is_closed_outward_with_near_analytic_area() {
        let (r, h) = (0.03, 0.12);
        let m = cylinder(r, h, DEFAULT_CYLINDER_SEGMENTS);
        assert_eq!(m.triangle_count(), 4 * 64);
        assert_closed(&m);
        assert_outward(&m);
        let exact = (TAU * r * h + 2.0 * PI * r * r) as f64;
        assert!((m.area() - exact).abs() / exact < 0.005);
        let b = m.bounds();
        assert!((b.max.y - 0.06).abs() < 1e-6 && (b.min.y + 0.06).abs() < 1e-6);
    }

    #[test]
    fn sphere_is_closed_outward_with_near_analytic_area() {
        let m = sphere(2.0, DEFAULT_SPHERE_SEGMENTS);
        assert_eq!(m.triangle_count(), 2 * 32 * 15);
        assert_closed(&m);
        assert_outward(&m);
        let exact = 4.0 * std::f64::consts::PI * 4.0;
        assert!((m.area() - exact).abs() / exact < 0.02);
        for p in &m.positions {
            assert!((p.length() - 2.0).abs() < 1e-5);
        }
    }

    #[test]
    fn plane_faces_up() {
        let m = plane(Vec2::new(2.0, 3.0));
        assert_eq!(m.triangle_count(), 2);
        assert!((m.area() - 6.0).abs() < 1e-6);
        for t in 0..2 {
            let [a, b, c] = m.corners(t);
            assert!((b - a).cross(c - a).normalize().abs_diff_eq(Vec3::Y, 1e-6));
        }
        assert!(m.normals.iter().all(|&n| n == Vec3::Y));
    }

    #[test]
    fn too_few_segments_are_raised() {
        assert_eq!(cylinder(1.0, 1.0, 0).triangle_count(), 12);
        let m = sphere(1.0, 1);
        assert_eq!(m.triangle_count(), 8);
        assert_closed(&m);
    }
}
