//! Spatial chunks: a mesh cut into pieces a game engine accepts.
//!
//! Unreal Engine 3 took at most 65,535 vertices per static mesh (16-bit
//! indices), so the thesis exported its map as many meshes, each in global
//! coordinates. Chunks here come from a k-d split of the triangles'
//! centroids: every triangle lands in exactly one chunk, and a vertex used by
//! triangles of several chunks is copied into each of them and flagged as a
//! seam vertex, so chunks simplified separately with their seams locked
//! still meet without cracks.

use crate::error::{Error, Result};
use crate::mesh::Mesh;
use glam::Vec3;

/// One piece of a split mesh, in the input's coordinates.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Chunk {
    /// The chunk's triangles and the vertices they use.
    pub mesh: Mesh,
    /// Per chunk vertex: whether triangles of another chunk use it too.
    pub seam: Vec<bool>,
}

/// The default vertex limit: the largest count 16-bit indices can address
/// (65,535 itself is the primitive-restart value glTF forbids as an index).
pub const DEFAULT_MAX_VERTICES: usize = 65_535;

/// Splits `mesh` into chunks of at most `max_vertices` vertices each.
pub fn split_by_vertices(mesh: &Mesh, max_vertices: usize) -> Result<Vec<Chunk>> {
    if max_vertices < 3 {
        return Err(Error::parameter(
            "chunk_vertices",
            format!("a chunk needs room for a triangle (3 vertices), got {max_vertices}"),
        ));
    }
    mesh.check().map_err(|m| Error::parameter("mesh", m))?;
    let mut seen = Stamps::new(mesh.vertex_count());
    Ok(build(mesh, |tris| seen.count(mesh, tris) <= max_vertices))
}

/// Splits `mesh` into chunks of at most `max_triangles` triangles each: equal
/// shares of work for parallel processing.
pub(crate) fn split_by_triangles(mesh: &Mesh, max_triangles: usize) -> Vec<Chunk> {
    build(mesh, |tris| tris.len() <= max_triangles.max(1))
}

/// Gathers chunk meshes back into one, merging the copies of seam vertices.
pub fn merge<'a>(meshes: impl IntoIterator<Item = &'a Mesh>) -> Mesh {
    let mut all = Mesh::default();
    for m in meshes {
        all.append(m);
    }
    crate::mesh::weld::weld(&all)
}

/// Splits the triangles at the median centroid along the widest axis until
/// `fits` accepts every part, then makes one chunk per part.
fn build(mesh: &Mesh, mut fits: impl FnMut(&[u32]) -> bool) -> Vec<Chunk> {
    let centroids: Vec<Vec3> = (0..mesh.triangle_count())
        .map(|t| {
            let [a, b, c] = mesh.corners(t);
            (a + b + c) / 3.0
        })
        .collect();
    let mut order: Vec<u32> = (0..mesh.triangle_count() as u32).collect();
    let mut parts = Vec::new();
    // Depth first, left before right, so neighbouring chunks get neighbouring numbers.
    let mut stack = Vec::with_capacity(64);
    stack.push(0..order.len());
    while let Some(range) = stack.pop() {
        if range.is_empty() {
            continue;
        }
        let tris = &mut order[range.clone()];
        if fits(tris) {
            parts.push(range);
            continue;
        }
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for &t in tris.iter() {
            lo = lo.min(centroids[t as usize]);
            hi = hi.max(centroids[t as usize]);
        }
        let extent = hi - lo;
        let axis = (0..3)
            .max_by(|&a, &b| extent[a].total_cmp(&extent[b]))
            .unwrap_or(0);
        let mid = tris.len() / 2;
        tris.select_nth_unstable_by(mid, |&a, &b| {
            centroids[a as usize][axis].total_cmp(&centroids[b as usize][axis])
        });
        stack.push(range.start + mid..range.end);
        stack.push(range.start..range.start + mid);
    }
    let mut owner = vec![u32::MAX; mesh.vertex_count()];
    let mut shared = vec![false; mesh.vertex_count()];
    for (c, range) in parts.iter().enumerate() {
        for &t in &order[range.clone()] {
            for &v in &mesh.triangles[t as usize] {
                let o = &mut owner[v as usize];
                if *o == u32::MAX {
                    *o = c as u32;
                } else if *o != c as u32 {
                    shared[v as usize] = true;
                }
            }
        }
    }
    let mut local = vec![u32::MAX; mesh.vertex_count()];
    parts
        .iter()
        .map(|range| {
            let mut chunk = Chunk::default();
            let mut used = Vec::new();
            for &t in &order[range.clone()] {
                let tri = mesh.triangles[t as usize].map(|v| {
                    let l = &mut local[v as usize];
                    if *l == u32::MAX {
                        *l = used.len() as u32;
                        used.push(v);
                    }
                    *l
                });
                chunk.mesh.triangles.push(tri);
            }
            for &v in &used {
                let v = v as usize;
                chunk.mesh.positions.push(mesh.positions[v]);
                if !mesh.normals.is_empty() {
                    chunk.mesh.normals.push(mesh.normals[v]);
                }
                if !mesh.colors.is_empty() {
                    chunk.mesh.colors.push(mesh.colors[v]);
                }
                chunk.seam.push(shared[v]);
                local[v] = u32::MAX;
            }
            chunk
        })
        .collect()
}

/// Counts distinct vertices of a set of triangles without clearing a table
/// per call: a vertex counts when its stamp differs from the current round.
struct Stamps {
    stamp: Vec<u32>,
    round: u32,
}

impl Stamps {
    fn new(vertices: usize) -> Self {
        Stamps {
            stamp: vec![0; vertices],
            round: 0,
        }
    }

    fn count(&mut self, mesh: &Mesh, tris: &[u32]) -> usize {
        self.round += 1;
        let mut n = 0;
        for &t in tris {
            for &v in &mesh.triangles[t as usize] {
                let s = &mut self.stamp[v as usize];
                if *s != self.round {
                    *s = self.round;
                    n += 1;
                }
            }
        }
        n
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::mesh::simplify::{simplify_locked, SimplifyParams};
    use std::collections::{BTreeMap, BTreeSet};

    /// A closed latitude–longitude sphere of radius 1 with single pole vertices.
    pub(crate) fn sphere(rings: u32, segments: u32) -> Mesh {
        let mut m = Mesh::default();
        m.positions.push(Vec3::Y);
        for r in 1..rings {
            let theta = std::f32::consts::PI * r as f32 / rings as f32;
            for s in 0..segments {
                let phi = std::f32::consts::TAU * s as f32 / segments as f32;
                m.positions.push(Vec3::new(
                    theta.sin() * phi.cos(),
                    theta.cos(),
                    theta.sin() * phi.sin(),
                ));
            }
        }
        m.positions.push(-Vec3::Y);
        let ring = |r: u32, s: u32| 1 + (r - 1) * segments + s % segments;
        let south = m.positions.len() as u32 - 1;
        for s in 0..segments {
            m.triangles.push([0, ring(1, s + 1), ring(1, s)]);
            m.triangles
                .push([south, ring(rings - 1, s), ring(rings - 1, s + 1)]);
            for r in 1..rings - 1 {
                let (a, b) = (ring(r, s), ring(r, s + 1));
                let (c, d) = (ring(r + 1, s), ring(r + 1, s + 1));
                m.triangles.push([a, b, d]);
                m.triangles.push([a, d, c]);
            }
        }
        m.compute_vertex_normals();
        m
    }

    /// Edges used by exactly one triangle, as position pairs.
    fn border_edges(mesh: &Mesh) -> usize {
        let mut count: BTreeMap<(u32, u32), u32> = BTreeMap::new();
        for t in &mesh.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *count.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
        count.values().filter(|&&c| c == 1).count()
    }

    fn key(p: Vec3) -> [u32; 3] {
        p.to_array().map(f32::to_bits)
    }

    #[test]
    fn chunks_respect_the_limit_and_cover_every_triangle_once() {
        let mesh = sphere(120, 200);
        for limit in [3, 500, 4_000, DEFAULT_MAX_VERTICES] {
            let chunks = split_by_vertices(&mesh, limit).unwrap();
            assert!(chunks.iter().all(|c| c.mesh.vertex_count() <= limit));
            assert!(chunks.iter().all(|c| c.seam.len() == c.mesh.vertex_count()));
            let mut seen: Vec<[[u32; 3]; 3]> = chunks
                .iter()
                .flat_map(|c| (0..c.mesh.triangle_count()).map(|t| c.mesh.corners(t).map(key)))
                .collect();
            let mut all: Vec<[[u32; 3]; 3]> = (0..mesh.triangle_count())
                .map(|t| mesh.corners(t).map(key))
                .collect();
            seen.sort();
            all.sort();
            assert_eq!(seen, all, "limit {limit}");
        }
        assert_eq!(
            split_by_vertices(&mesh, DEFAULT_MAX_VERTICES)
                .unwrap()
                .len(),
            1
        );
    }

    #[test]
    fn too_small_a_limit_names_the_flag() {
        let e = split_by_vertices(&sphere(4, 4), 0).unwrap_err().to_string();
        assert!(e.contains("chunk_vertices"), "{e}");
    }

    #[test]
    fn simplified_chunks_meet_without_cracks() {
        let mesh = sphere(100, 160);
        assert_eq!(border_edges(&mesh), 0);
        let chunks = split_by_vertices(&mesh, 2_000).unwrap();
        assert!(chunks.len() >= 8);
        let params = SimplifyParams {
            lock_border: false,
            ..SimplifyParams::ratio(0.1)
        };
        let simplified: Vec<Mesh> = chunks
            .iter()
            .map(|c| simplify_locked(&c.mesh, &c.seam, &params).unwrap().mesh)
            .collect();
        let before: usize = chunks.iter().map(|c| c.mesh.triangle_count()).sum();
        let after: usize = simplified.iter().map(Mesh::triangle_count).sum();
        assert!(after < before / 3, "{before} -> {after}");
        // Every seam vertex is still there, exactly where it was.
        for (c, s) in chunks.iter().zip(&simplified) {
            let kept: BTreeSet<[u32; 3]> = s.positions.iter().map(|&p| key(p)).collect();
            for (p, _) in c
                .mesh
                .positions
                .iter()
                .zip(&c.seam)
                .filter(|(_, &seam)| seam)
            {
                assert!(kept.contains(&key(*p)));
            }
        }
        // Joined by position, the simplified chunks are closed again.
        let joined = merge(&simplified);
        assert_eq!(border_edges(&joined), 0);
    }
}
