//! The marching-cubes case table, built once from first principles instead
//! of being typed in: for each of the 256 inside/outside patterns of a cube's
//! corners, the surface crosses the edges whose ends differ; on each face the
//! crossing points are joined so that every inside corner is cut off on its
//! own (this also settles the ambiguous faces, consistently for the two cubes
//! that share a face, so the surface has no cracks); the segments chain into
//! closed loops, which are oriented to face the outside and split into fans.

use std::sync::OnceLock;

/// Corner `i` of the unit cube sits at `(i & 1, (i >> 1) & 1, (i >> 2) & 1)`.
pub const CORNERS: [[u8; 3]; 8] = [
    [0, 0, 0],
    [1, 0, 0],
    [0, 1, 0],
    [1, 1, 0],
    [0, 0, 1],
    [1, 0, 1],
    [0, 1, 1],
    [1, 1, 1],
];

/// The 12 edges as (corner, corner), the first corner the lower one, so an
/// edge starts at its first corner and runs along one axis.
pub const EDGES: [(u8, u8); 12] = [
    (0, 1),
    (2, 3),
    (4, 5),
    (6, 7),
    (0, 2),
    (1, 3),
    (4, 6),
    (5, 7),
    (0, 4),
    (1, 5),
    (2, 6),
    (3, 7),
];

/// Faces as corner loops (any winding; only adjacency matters).
const FACES: [[u8; 4]; 6] = [
    [0, 2, 6, 4],
    [1, 3, 7, 5],
    [0, 1, 5, 4],
    [2, 3, 7, 6],
    [0, 1, 3, 2],
    [4, 5, 7, 6],
];

fn edge_between(a: u8, b: u8) -> usize {
    let (a, b) = (a.min(b), a.max(b));
    EDGES
        .iter()
        .position(|&e| e == (a, b))
        .expect("adjacent corners")
}

/// Triangles (as edge triples) of every case; bit `i` of the case is set when
/// corner `i` is inside (negative distance). Triangles wind counter-clockwise
/// seen from outside.
pub fn table() -> &'static [Vec<[u8; 3]>; 256] {
    static TABLE: OnceLock<[Vec<[u8; 3]>; 256]> = OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(|case| triangulate(case as u8)))
}

fn midpoint(e: usize) -> [f32; 3] {
    let (a, b) = EDGES[e];
    std::array::from_fn(|k| 0.5 * f32::from(CORNERS[a as usize][k] + CORNERS[b as usize][k]))
}

fn triangulate(case: u8) -> Vec<[u8; 3]> {
    let inside = |c: u8| case & (1 << c) != 0;
    // Segments between crossed edges, face by face.
    let mut segments: Vec<(usize, usize)> = Vec::new();
    for face in FACES {
        for k in 0..4 {
            let corner = face[k];
            if !inside(corner) {
                continue;
            }
            let prev = face[(k + 3) % 4];
            let next = face[(k + 1) % 4];
            match (inside(prev), inside(next)) {
                // An isolated inside corner: cut it off.
                (false, false) => {
                    segments.push((edge_between(prev, corner), edge_between(corner, next)))
                }
                // A run of inside corners: cut where the run starts and ends.
                (false, true) => {
                    let mut end = (k + 1) % 4;
                    while inside(face[(end + 1) % 4]) {
                        end = (end + 1) % 4;
                    }
                    if end != (k + 3) % 4 {
                        let last = face[end];
                        let after = face[(end + 1) % 4];
                        segments.push((edge_between(prev, corner), edge_between(last, after)));
                    }
                }
                _ => {}
            }
        }
    }
    // Chain segments into loops.
    let mut triangles = Vec::new();
    while let Some((start, mut at)) = segments.pop() {
        let mut lp = vec![start];
        while at != start {
            lp.push(at);
            let i = segments
                .iter()
                .position(|&(a, b)| a == at || b == at)
                .expect("every crossing point is on two faces");
            let (a, b) = segments.swap_remove(i);
            at = if a == at { b } else { a };
        }
        // Orient the loop: its normal should point from inside to outside.
        let mut outward = [0.0f32; 3];
        for &e in &lp {
            let (a, b) = EDGES[e];
            let (i, o) = if inside(a) { (a, b) } else { (b, a) };
            for k in 0..3 {
                outward[k] += f32::from(CORNERS[o as usize][k]) - f32::from(CORNERS[i as usize][k]);
            }
        }
        let mut normal = [0.0f32; 3];
        for j in 0..lp.len() {
            let (p, q) = (midpoint(lp[j]), midpoint(lp[(j + 1) % lp.len()]));
            normal[0] += (p[1] - q[1]) * (p[2] + q[2]);
            normal[1] += (p[2] - q[2]) * (p[0] + q[0]);
            normal[2] += (p[0] - q[0]) * (p[1] + q[1]);
        }
        if (0..3).map(|k| normal[k] * outward[k]).sum::<f32>() < 0.0 {
            lp.reverse();
        }
        for j in 1..lp.len() - 1 {
            triangles.push([lp[0] as u8, lp[j] as u8, lp[j + 1] as u8]);
        }
    }
    triangles
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn classic_case_counts() {
        let t = table();
        assert!(t[0].is_empty() && t[255].is_empty());
        assert_eq!(t[1].len(), 1); // one corner: one triangle
        assert_eq!(t[3].len(), 2); // an edge's two corners: a quad
        assert_eq!(t[0b0000_1111].len(), 2); // a face: a quad
                                             // Every case: each crossed edge is used, the loops are closed
                                             // (every triangle edge between crossing points pairs up in the case).
        for (case, tris) in t.iter().enumerate() {
            let crossed: Vec<usize> = (0..12)
                .filter(|&e| {
                    let (a, b) = EDGES[e];
                    ((case >> a) & 1) != ((case >> b) & 1)
                })
                .collect();
            let mut used: Vec<usize> = tris.iter().flatten().map(|&e| e as usize).collect();
            used.sort_unstable();
            used.dedup();
            assert_eq!(used, crossed, "case {case}");
        }
    }
}
