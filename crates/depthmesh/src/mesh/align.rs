//! Floor alignment: find the floor of a scan and make it level.
//!
//! A tracked scan's world frame is wherever the camera started, so its floor
//! is tilted; the thesis rotated every mesh into the game world by hand. The
//! floor is found as the plane with the most supporting vertices among those
//! with (almost) the whole mesh on one side: a table or a counter has
//! surface below it, a floor does not. Walls can pass that test too, so the
//! largest such plane wins, which in a room scan is the floor. Support is
//! measured in surface area (points sampled over the triangles), candidates
//! come from single samples and their normals (RANSAC), and the winner is
//! refitted by least squares to its inliers.

use crate::error::{Error, Result};
use crate::mesh::Mesh;
use glam::{Affine3A, Quat, Vec3};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

/// A plane `normal · p = offset`, with `normal` pointing to the side the mesh is on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Floor {
    /// Unit normal, pointing up (into the room).
    pub normal: Vec3,
    /// Signed distance of the plane from the origin along `normal`, metres.
    pub offset: f32,
    /// Share of the surface (by area; of the vertices for a point cloud) on the plane.
    pub support: f32,
}

impl Floor {
    /// The rigid transform that turns `normal` into `up` (unit) by the
    /// smallest rotation and moves the floor to height 0 along `up`;
    /// horizontal positions stay as they were, up to the rotation.
    pub fn leveling(&self, up: Vec3) -> Affine3A {
        let rotation = Quat::from_rotation_arc(self.normal, up);
        Affine3A::from_translation(-self.offset * up) * Affine3A::from_quat(rotation)
    }
}

/// Vertices farther than this from a plane do not support it; a little
/// more than the depth noise of a Kinect at 2–3 m.
const INLIER_DISTANCE: f32 = 0.02;
/// Supporting vertices must also have a normal within this angle (cosine,
/// about 25°) of the plane's, so a wall's foot does not count for the floor.
const INLIER_NORMAL_COS: f32 = 0.9;
/// A floor has at most this share of the mesh more than `BELOW_DISTANCE` under it.
const MAX_BELOW: f32 = 0.05;
/// Noise and small dips under a floor that do not count as surface below it.
const BELOW_DISTANCE: f32 = 0.05;
const SAMPLES: usize = 20_000;
const HYPOTHESES: usize = 500;

/// Finds the floor of `mesh` (see the module notes). Deterministic.
pub fn find_floor(mesh: &Mesh) -> Result<Floor> {
    let points = surface_samples(mesh);
    if points.len() < 3 {
        return Err(Error::parameter(
            "align_floor",
            "the mesh has too few vertices to find a floor",
        ));
    }
    let mut rng = SmallRng::seed_from_u64(0);
    let mut best: Option<(usize, Floor)> = None;
    let mut fallback: Option<(usize, Floor)> = None;
    for _ in 0..HYPOTHESES {
        let (p, n) = points[rng.gen_range(0..points.len())];
        let (support, floor) = evaluate(&points, n, n.dot(p));
        let keep = |slot: &Option<(usize, Floor)>| slot.as_ref().is_none_or(|(s, _)| support > *s);
        if keep(&fallback) {
            fallback = Some((support, floor));
        }
        if is_floor(&points, &floor) && keep(&best) {
            best = Some((support, floor));
        }
    }
    // Without any plane that has the mesh on one side (no floor scanned),
    // the largest plane is the best guess at something level.
    let (_, mut floor) = best.or(fallback).expect("at least one hypothesis");
    for _ in 0..3 {
        floor = refit(&points, &floor).unwrap_or(floor);
    }
    Ok(floor)
}

/// Points with their normals spread over the surface by area: support is
/// then a share of the surface, not of the vertices. A scanned floor and a
/// modelled one (a few large triangles under a finely tessellated object)
/// weigh as much as they cover; counting vertices let a small dense object
/// outvote a floor of four corners and tilt the result. A mesh without
/// triangles (a point cloud) is sampled by its vertices and their normals.
fn surface_samples(mesh: &Mesh) -> Vec<(Vec3, Vec3)> {
    let mut rng = SmallRng::seed_from_u64(1);
    let mut cumulative = Vec::with_capacity(mesh.triangle_count());
    let mut total = 0.0f64;
    for t in 0..mesh.triangle_count() {
        total += f64::from(mesh.triangle_area(t));
        cumulative.push(total);
    }
    if total <= 0.0 {
        let mut normals = mesh.normals.clone();
        if normals.len() != mesh.vertex_count() {
            let mut m = mesh.clone();
            m.compute_vertex_normals();
            normals = m.normals;
        }
        let step = mesh.vertex_count().div_ceil(SAMPLES).max(1);
        return (0..mesh.vertex_count())
            .step_by(step)
            .filter_map(|i| normals[i].try_normalize().map(|n| (mesh.positions[i], n)))
            .collect();
    }
    // Stratified over the cumulative area: every part of the surface gets
    // its share of samples whatever the random draws.
    (0..SAMPLES)
        .filter_map(|i| {
            let target = (i as f64 + rng.gen::<f64>()) / SAMPLES as f64 * total;
            let t = cumulative
                .partition_point(|&c| c < target)
                .min(cumulative.len() - 1);
            let [a, b, c] = mesh.corners(t);
            let normal = (b - a).cross(c - a).try_normalize()?;
            let (mut u, mut v) = (rng.gen::<f32>(), rng.gen::<f32>());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            Some((a + u * (b - a) + v * (c - a), normal))
        })
        .collect()
}

/// Counts the support of plane (`n`, `d`) and orients it towards the
/// majority of the points.
fn evaluate(points: &[(Vec3, Vec3)], n: Vec3, d: f32) -> (usize, Floor) {
    let mut support = 0;
    let mut above = 0usize;
    for &(p, pn) in points {
        let h = n.dot(p) - d;
        if h.abs() < INLIER_DISTANCE && n.dot(pn).abs() > INLIER_NORMAL_COS {
            support += 1;
        } else if h > 0.0 {
            above += 1;
        }
    }
    let others = points.len() - support;
    let sign = if 2 * above >= others { 1.0 } else { -1.0 };
    let floor = Floor {
        normal: sign * n,
        offset: sign * d,
        support: support as f32 / points.len() as f32,
    };
    (support, floor)
}

fn is_floor(points: &[(Vec3, Vec3)], floor: &Floor) -> bool {
    let below = points
        .iter()
        .filter(|(p, _)| floor.normal.dot(*p) - floor.offset < -BELOW_DISTANCE)
        .count();
    (below as f32) <= MAX_BELOW * points.len() as f32
}

/// Least-squares plane through the inliers of `floor`, keeping its orientation.
fn refit(points: &[(Vec3, Vec3)], floor: &Floor) -> Option<Floor> {
    let inliers: Vec<Vec3> = points
        .iter()
        .filter(|(p, pn)| {
            (floor.normal.dot(*p) - floor.offset).abs() < INLIER_DISTANCE
                && floor.normal.dot(*pn).abs() > INLIER_NORMAL_COS
        })
        .map(|(p, _)| *p)
        .collect();
    if inliers.len() < 3 {
        return None;
    }
    let mean = inliers.iter().copied().sum::<Vec3>() / inliers.len() as f32;
    let mut cov = [[0.0f64; 3]; 3];
    for p in &inliers {
        let d = (*p - mean).as_dvec3().to_array();
        for (i, row) in cov.iter_mut().enumerate() {
            for (j, c) in row.iter_mut().enumerate() {
                *c += d[i] * d[j];
            }
        }
    }
    let n = smallest_eigenvector(cov).as_vec3();
    let n = if n.dot(floor.normal) < 0.0 { -n } else { n };
    Some(Floor {
        normal: n,
        offset: n.dot(mean),
        support: floor.support,
    })
}

/// Eigenvector of the smallest eigenvalue of a symmetric 3×3 matrix, by
/// cyclic Jacobi rotations (exact to rounding for 3×3 in a few sweeps).
fn smallest_eigenvector(mut a: [[f64; 3]; 3]) -> glam::DVec3 {
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _ in 0..32 {
        let off = a[0][1].abs() + a[0][2].abs() + a[1][2].abs();
        if off < 1e-15 * (a[0][0].abs() + a[1][1].abs() + a[2][2].abs()).max(1e-300) {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q] == 0.0 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            for row in a.iter_mut() {
                let (akp, akq) = (row[p], row[q]);
                row[p] = c * akp - s * akq;
                row[q] = s * akp + c * akq;
            }
            let (rp, rq) = (a[p], a[q]);
            a[p] = std::array::from_fn(|k| c * rp[k] - s * rq[k]);
            a[q] = std::array::from_fn(|k| s * rp[k] + c * rq[k]);
            for row in &mut v {
                let (vp, vq) = (row[p], row[q]);
                row[p] = c * vp - s * vq;
                row[q] = s * vp + c * vq;
            }
        }
    }
    let k = (0..3)
        .min_by(|&i, &j| a[i][i].total_cmp(&a[j][j]))
        .unwrap_or(0);
    glam::DVec3::new(v[0][k], v[1][k], v[2][k]).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A grid of `n`×`n` quads spanning `a` + s·`u` + t·`v`, s, t in 0..1.
    fn grid(a: Vec3, u: Vec3, v: Vec3, n: u32) -> Mesh {
        let mut m = Mesh::default();
        for j in 0..=n {
            for i in 0..=n {
                m.positions
                    .push(a + u * (i as f32 / n as f32) + v * (j as f32 / n as f32));
            }
        }
        for j in 0..n {
            for i in 0..n {
                let k = j * (n + 1) + i;
                m.triangles.push([k, k + 1, k + n + 2]);
                m.triangles.push([k, k + n + 2, k + n + 1]);
            }
        }
        m
    }

    #[test]
    fn eigenvector_of_a_known_matrix() {
        let e = smallest_eigenvector([[2.0, 1.0, 0.0], [1.0, 2.0, 0.0], [0.0, 0.0, 5.0]]);
        let expected = glam::DVec3::new(1.0, -1.0, 0.0).normalize();
        assert!(e.dot(expected).abs() > 1.0 - 1e-12, "{e}");
    }

    #[test]
    fn levels_a_tilted_room_with_a_table() {
        // A room in y-up, 10 vertices per metre: a 4×4 m floor, a 4×2.5 m
        // wall and a 1×1 m table top at 0.75 m; then tilted by 20° and shifted.
        let mut room = grid(Vec3::new(-2.0, 0.0, -2.0), 4.0 * Vec3::X, 4.0 * Vec3::Z, 40);
        room.append(&grid(
            Vec3::new(-2.0, 0.0, -2.0),
            4.0 * Vec3::X,
            2.5 * Vec3::Y,
            25,
        ));
        room.append(&grid(Vec3::new(-0.5, 0.75, -0.5), Vec3::X, Vec3::Z, 10));
        let tilt = Affine3A::from_translation(Vec3::new(0.3, -1.2, 2.0))
            * Affine3A::from_axis_angle(Vec3::new(1.0, 0.0, 1.0).normalize(), 0.35);
        room.transform(|p| tilt.transform_point3(p), |n| tilt.transform_vector3(n));
        let floor = find_floor(&room).unwrap();
        let true_up = tilt.transform_vector3(Vec3::Y);
        assert!(floor.normal.angle_between(true_up) < 1e-3, "{floor:?}");
        let level = floor.leveling(Vec3::Z);
        room.transform(
            |p| level.transform_point3(p),
            |n| level.transform_vector3(n),
        );
        let lowest = room
            .positions
            .iter()
            .map(|p| p.z)
            .fold(f32::INFINITY, f32::min);
        assert!(lowest.abs() < 1e-3, "floor at height {lowest}");
        let table = level.transform_point3(tilt.transform_point3(Vec3::new(0.0, 0.75, 0.0)));
        assert!((table.z - 0.75).abs() < 1e-3, "table at {table}");
    }

    #[test]
    fn too_small_a_mesh_is_an_error_naming_the_flag() {
        let e = find_floor(&Mesh::default()).unwrap_err().to_string();
        assert!(e.contains("align_floor"), "{e}");
    }
}
