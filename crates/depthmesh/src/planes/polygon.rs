//! The surface patch of a planar window: its plane cut by an axis-aligned
//! cube (the paper's eq. 4 on the cube's 12 edges), a convex polygon of 3–6
//! vertices ordered around the normal and triangulated as a fan.

use crate::tsdf::cases::{CORNERS, EDGES};
use glam::DVec3;

/// Intersections closer than this fraction of the cube's edge are one vertex:
/// a plane through a cube corner crosses three edges there.
const MERGE_TOLERANCE: f64 = 1e-9;

/// A convex polygon of at most six vertices (a plane meets at most six of a
/// cube's faces), counter-clockwise seen from the side its normal points to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Polygon {
    len: u8,
    vertices: [DVec3; 6],
}

impl Polygon {
    /// The vertices in order around the normal.
    pub fn vertices(&self) -> &[DVec3] {
        &self.vertices[..usize::from(self.len)]
    }

    /// The fan triangulation from the first vertex, as index triples into
    /// [`Polygon::vertices`]; convexity makes every fan triangle valid.
    pub fn fan(&self) -> impl Iterator<Item = [u32; 3]> {
        (1..u32::from(self.len).saturating_sub(1)).map(|i| [0, i, i + 1])
    }
}

/// The plane through `point` with unit `normal`, cut by the axis-aligned cube
/// `[min, min + size]³`: `None` when the plane misses the cube or only
/// touches it in a point or along an edge (fewer than three vertices).
pub fn plane_cube_polygon(point: DVec3, normal: DVec3, min: DVec3, size: f64) -> Option<Polygon> {
    // The cube's corners and edges numbered as in marching cubes.
    let corner = |i: u8| {
        let [x, y, z] = CORNERS[usize::from(i)].map(f64::from);
        min + DVec3::new(x, y, z) * size
    };
    // Signed distances of the corners; a corner exactly on the plane counts
    // as above, so each crossing is found once per edge.
    let d: [f64; 8] = std::array::from_fn(|i| normal.dot(corner(i as u8) - point));
    let mut found = [DVec3::ZERO; 12];
    let mut n = 0;
    for (a, b) in EDGES {
        let (da, db) = (d[usize::from(a)], d[usize::from(b)]);
        if (da < 0.0) == (db < 0.0) {
            continue;
        }
        // Eq. (4): the fraction of the way from P1 to P2 where n̂·(U − P0) = 0.
        let t = da / (da - db);
        let p = corner(a) + (corner(b) - corner(a)) * t;
        if found[..n]
            .iter()
            .all(|q| (*q - p).abs().max_element() > MERGE_TOLERANCE * size)
        {
            found[n] = p;
            n += 1;
        }
    }
    if !(3..=6).contains(&n) {
        return None;
    }
    // Order by angle in the plane, around the centroid (inside a convex polygon).
    let centre = found[..n].iter().sum::<DVec3>() / n as f64;
    let u = normal.any_orthonormal_vector();
    let v = normal.cross(u);
    let angle = |p: &DVec3| {
        let r = *p - centre;
        r.dot(v).atan2(r.dot(u))
    };
    found[..n].sort_by(|p, q| angle(p).total_cmp(&angle(q)));
    let mut vertices = [DVec3::ZERO; 6];
    vertices[..n].copy_from_slice(&found[..n]);
    Some(Polygon {
        len: n as u8,
        vertices,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::SmallRng;
    use rand::{Rng, SeedableRng};

    /// Vertices lie on the plane and on the cube's surface, are distinct, and
    /// turn counter-clockwise around the normal with every interior angle < 180°.
    fn check(poly: &Polygon, point: DVec3, normal: DVec3, min: DVec3, size: f64) {
        let v = poly.vertices();
        assert!((3..=6).contains(&v.len()), "{} vertices", v.len());
        for p in v {
            assert!(normal.dot(*p - point).abs() < 1e-12, "off the plane");
            let local = (*p - min) / size;
            assert!(local.min_element() > -1e-12 && local.max_element() < 1.0 + 1e-12);
            let on_face = local
                .to_array()
                .iter()
                .any(|c| c.abs() < 1e-12 || (c - 1.0).abs() < 1e-12);
            assert!(on_face, "{p} is inside the cube");
        }
        for i in 0..v.len() {
            let (a, b, c) = (v[i], v[(i + 1) % v.len()], v[(i + 2) % v.len()]);
            assert!((b - a).length() > 1e-12);
            assert!((b - a).cross(c - b).dot(normal) > 0.0, "not convex CCW");
        }
        assert_eq!(poly.fan().count(), v.len() - 2);
    }

    #[test]
    fn random_planes_through_a_cube_give_convex_polygons() {
        let mut rng = SmallRng::seed_from_u64(41);
        let (min, size) = (DVec3::new(0.3, -1.2, 4.0), 0.05);
        let mut counts = [0usize; 7];
        for _ in 0..20_000 {
            let normal = DVec3::new(
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
            )
            .normalize();
            let point = min + DVec3::splat(size * 0.5) + normal * rng.gen_range(-0.04..0.04);
            if let Some(poly) = plane_cube_polygon(point, normal, min, size) {
                check(&poly, point, normal, min, size);
                counts[poly.vertices().len()] += 1;
            }
        }
        // Triangles, quads, pentagons and hexagons all occur.
        assert!(counts[3..].iter().all(|&c| c > 100), "{counts:?}");
    }

    #[test]
    fn special_cases() {
        let (min, size) = (DVec3::ZERO, 1.0);
        // Axis-aligned through the middle: a square.
        let sq = plane_cube_polygon(DVec3::splat(0.5), DVec3::Z, min, size).unwrap();
        check(&sq, DVec3::splat(0.5), DVec3::Z, min, size);
        assert_eq!(sq.vertices().len(), 4);
        // Perpendicular to the diagonal through the centre: the hexagon.
        let n = DVec3::ONE.normalize();
        let hex = plane_cube_polygon(DVec3::splat(0.5), n, min, size).unwrap();
        check(&hex, DVec3::splat(0.5), n, min, size);
        assert_eq!(hex.vertices().len(), 6);
        // Through three corners: a triangle, no duplicated corners.
        let tri = plane_cube_polygon(DVec3::X, n, min, size).unwrap();
        check(&tri, DVec3::X, n, min, size);
        assert_eq!(tri.vertices().len(), 3);
        // On a shared face: exactly one of the two cubes has it (corners on
        // the plane count as above it), so neighbours never both draw it.
        assert!(plane_cube_polygon(DVec3::ZERO, DVec3::Z, min, size).is_none());
        let below = plane_cube_polygon(DVec3::ZERO, DVec3::Z, -DVec3::Z, size).unwrap();
        assert_eq!(below.vertices().len(), 4);
        // Touching a single corner, and missing the cube.
        assert!(plane_cube_polygon(DVec3::ZERO, n, min, size).is_none());
        assert!(plane_cube_polygon(DVec3::splat(3.0), n, min, size).is_none());
    }
}
