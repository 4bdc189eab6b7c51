//! Exact point-to-mesh distances up to a search radius, through a bounding
//! volume hierarchy over the triangles. A BVH handles meshes of huge
//! triangles (a 10 m floor slab) and of millions of tiny ones alike, which a
//! uniform grid does not; the radius bounds the work of a query when
//! evaluation only asks "within 5 mm?".

use crate::mesh::{Aabb, Mesh};
use glam::Vec3;

/// Triangles per leaf.
const LEAF_SIZE: usize = 4;

#[derive(Clone, Copy, Debug)]
struct Node {
    bounds: Aabb,
    /// Leaf: first triangle in `order`; inner: index of the left child (the right one follows it).
    start: u32,
    /// Leaf: number of triangles; inner: 0.
    count: u32,
}

/// Closest-point queries against a fixed mesh.
#[derive(Debug)]
pub struct MeshDistance {
    radius: f32,
    corners: Vec<[Vec3; 3]>,
    nodes: Vec<Node>,
}

fn squared_distance_to_box(b: &Aabb, p: Vec3) -> f32 {
    let d = (b.min - p).max(p - b.max).max(Vec3::ZERO);
    d.length_squared()
}

impl MeshDistance {
    /// Indexes `mesh` for queries up to `radius` metres.
    pub fn new(mesh: &Mesh, radius: f32) -> Self {
        let mut corners: Vec<[Vec3; 3]> = (0..mesh.triangle_count())
            .map(|t| mesh.corners(t))
            .collect();
        let mut nodes = Vec::with_capacity(2 * corners.len() / LEAF_SIZE + 1);
        if !corners.is_empty() {
            nodes.push(Node {
                bounds: Aabb::EMPTY,
                start: 0,
                count: corners.len() as u32,
            });
            build(&mut nodes, 0, &mut corners);
        }
        MeshDistance {
            radius,
            corners,
            nodes,
        }
    }

    /// Distance from `p` to the mesh, or `None` when it is farther than the radius.
    pub fn distance(&self, p: Vec3) -> Option<f32> {
        let mut best = self.radius * self.radius;
        let mut found = false;
        let mut stack = [0u32; 64];
        let mut top = usize::from(!self.nodes.is_empty());
        while top > 0 {
            top -= 1;
            let node = &self.nodes[stack[top] as usize];
            if squared_distance_to_box(&node.bounds, p) > best {
                continue;
            }
            if node.count > 0 {
                for [a, b, c] in
                    &self.corners[node.start as usize..(node.start + node.count) as usize]
                {
                    let d = (closest_point_on_triangle(p, *a, *b, *c) - p).length_squared();
                    if d <= best {
                        best = d;
                        found = true;
                    }
                }
            } else {
                stack[top] = node.start;
                stack[top + 1] = node.start + 1;
                top += 2;
            }
        }
        found.then(|| best.sqrt())
    }
}

/// Splits node `index` (holding `tris`, whose bounds it gets) at the median of
/// its longest axis until leaves are small. Depth stays near log2(n), far
/// below the query stack's 64.
fn build(nodes: &mut Vec<Node>, index: usize, tris: &mut [[Vec3; 3]]) {
    let mut bounds = Aabb::EMPTY;
    let mut centres = Aabb::EMPTY;
    for t in tris.iter() {
        t.iter().for_each(|&p| bounds.include(p));
        centres.include((t[0] + t[1] + t[2]) / 3.0);
    }
    nodes[index].bounds = bounds;
    if tris.len() <= LEAF_SIZE {
        return;
    }
    let e = centres.extent();
    let axis = if e.x >= e.y && e.x >= e.z {
        0
    } else if e.y >= e.z {
        1
    } else {
        2
    };
    let mid = tris.len() / 2;
    tris.select_nth_unstable_by(mid, |a, b| {
        let ca = a[0][axis] + a[1][axis] + a[2][axis];
        let cb = b[0][axis] + b[1][axis] + b[2][axis];
        ca.total_cmp(&cb)
    });
    let start = nodes[index].start;
    let left = nodes.len();
    nodes.push(Node {
        bounds: Aabb::EMPTY,
        start,
        count: mid as u32,
    });
    nodes.push(Node {
        bounds: Aabb::EMPTY,
        start: start + mid as u32,
        count: (tris.len() - mid) as u32,
    });
    nodes[index].start = left as u32;
    nodes[index].count = 0;
    let (lo, hi) = tris.split_at_mut(mid);
    build(nodes, left, lo);
    build(nodes, left + 1, hi);
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
