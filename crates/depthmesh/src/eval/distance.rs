//! Exact point-to-mesh distances up to a search radius, through a uniform grid
//! of triangle buckets. Evaluation asks "within 5 mm?" of millions of points,
//! so queries are bounded by a radius rather than searching the whole mesh.

use crate::mesh::{Aabb, Mesh};
use glam::{IVec3, Vec3};
use std::collections::HashMap;

/// Closest-point queries against a fixed mesh.
#[derive(Debug)]
pub struct MeshDistance {
    cell: f32,
    radius: f32,
    corners: Vec<[Vec3; 3]>,
    cells: HashMap<IVec3, Vec<u32>>,
}

impl MeshDistance {
    /// Indexes `mesh` for queries up to `radius` metres (cells of that size).
    pub fn new(mesh: &Mesh, radius: f32) -> Self {
        let cell = radius.max(1e-4);
        let corners: Vec<[Vec3; 3]> = (0..mesh.triangle_count())
            .map(|t| mesh.corners(t))
            .collect();
        let mut cells: HashMap<IVec3, Vec<u32>> = HashMap::new();
        for (t, c) in corners.iter().enumerate() {
            let mut b = Aabb::EMPTY;
            c.iter().for_each(|&p| b.include(p));
            let lo = (b.min / cell).floor().as_ivec3();
            let hi = (b.max / cell).floor().as_ivec3();
            for z in lo.z..=hi.z {
                for y in lo.y..=hi.y {
                    for x in lo.x..=hi.x {
                        cells.entry(IVec3::new(x, y, z)).or_default().push(t as u32);
                    }
                }
            }
        }
        MeshDistance {
            cell,
            radius,
            corners,
            cells,
        }
    }

    /// Distance from `p` to the mesh, or `None` when it is farther than the radius.
    pub fn distance(&self, p: Vec3) -> Option<f32> {
        let c = (p / self.cell).floor().as_ivec3();
        let mut best = self.radius * self.radius;
        let mut found = false;
        for z in -1..=1 {
            for y in -1..=1 {
                for x in -1..=1 {
                    let Some(list) = self.cells.get(&(c + IVec3::new(x, y, z))) else {
                        continue;
                    };
                    for &t in list {
                        let [a, b, cc] = self.corners[t as usize];
                        let d = (closest_point_on_triangle(p, a, b, cc) - p).length_squared();
                        if d <= best {
                            best = d;
                            found = true;
                        }
                    }
                }
            }
        }
        found.then(|| best.sqrt())
    }
}

/// The point of triangle `abc` closest to `p` (Ericson, Real-Time Collision Detection §5.1.5).
pub fn closest_point_on_triangle(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> Vec3 {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distances_to_a_triangle() {
        let (a, b, c) = (Vec3::ZERO, Vec3::X, Vec3::Y);
        let inside = closest_point_on_triangle(Vec3::new(0.2, 0.2, 1.0), a, b, c);
        assert!((inside - Vec3::new(0.2, 0.2, 0.0)).length() < 1e-6);
        assert_eq!(
            closest_point_on_triangle(Vec3::new(-1.0, -1.0, 0.0), a, b, c),
            a
        );
        assert_eq!(
            closest_point_on_triangle(Vec3::new(2.0, -0.5, 0.0), a, b, c),
            b
        );
        let e = closest_point_on_triangle(Vec3::new(1.0, 1.0, 0.0), a, b, c);
        assert!((e - Vec3::new(0.5, 0.5, 0.0)).length() < 1e-6);
        let mesh = Mesh {
            positions: vec![a, b, c],
            triangles: vec![[0, 1, 2]],
            ..Mesh::default()
        };
        let index = MeshDistance::new(&mesh, 0.1);
        assert!((index.distance(Vec3::new(0.2, 0.2, 0.05)).unwrap() - 0.05).abs() < 1e-6);
        assert!(index.distance(Vec3::new(0.2, 0.2, 0.5)).is_none());
    }
}
