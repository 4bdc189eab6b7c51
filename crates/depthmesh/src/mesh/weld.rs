//! Welding: one vertex per position.
//!
//! Marching cubes, per-chunk exports and some PLY writers repeat a vertex for
//! each triangle or block that uses it. A simplifier sees such a seam as a hole
//! border and refuses to collapse across it, so meshes are welded first.

use crate::mesh::Mesh;
use glam::Vec3;

/// Merges vertices with bit-identical positions, drops vertices no triangle
/// uses and triangles that welding made degenerate (two equal corners).
///
/// Merged vertices get the mean of their normals (renormalised) and the
/// colour of the first of them; vertices are numbered in the order the
/// triangles first use them.
pub fn weld(mesh: &Mesh) -> Mesh {
    let indices: Vec<u32> = mesh.triangles.iter().flatten().copied().collect();
    let positions: Vec<[f32; 3]> = mesh
        .positions
        .iter()
        // -0.0 and 0.0 are the same position but not the same bits.
        .map(|p| (*p + Vec3::ZERO).to_array())
        .collect();
    let (count, remap) = meshopt::remap::generate_vertex_remap(&positions, Some(&indices));
    let mut out = Mesh {
        positions: vec![Vec3::ZERO; count],
        normals: vec![Vec3::ZERO; if mesh.normals.is_empty() { 0 } else { count }],
        colors: vec![[0; 3]; if mesh.colors.is_empty() { 0 } else { count }],
        triangles: Vec::with_capacity(mesh.triangles.len()),
    };
    let mut seen = vec![false; count];
    for (old, &new) in remap.iter().enumerate() {
        // Unreferenced vertices map to u32::MAX.
        let Some(new) = (new != u32::MAX).then_some(new as usize) else {
            continue;
        };
        out.positions[new] = mesh.positions[old];
        if !mesh.normals.is_empty() {
            out.normals[new] += mesh.normals[old];
        }
        if !mesh.colors.is_empty() && !seen[new] {
            out.colors[new] = mesh.colors[old];
        }
        seen[new] = true;
    }
    for n in &mut out.normals {
        *n = n.normalize_or_zero();
    }
    out.triangles.extend(
        mesh.triangles
            .iter()
            .map(|t| t.map(|i| remap[i as usize]))
            .filter(|[a, b, c]| a != b && b != c && a != c),
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn merges_duplicates_and_drops_degenerate_and_unused() {
        let mesh = Mesh {
            positions: vec![
                Vec3::ZERO,
                Vec3::X,
                Vec3::Y,
                Vec3::X, // duplicate of 1
                Vec3::ONE,
                Vec3::new(-0.0, 1.0, 0.0), // duplicate of 2 despite the sign
                Vec3::splat(9.0),          // unused
            ],
            normals: vec![
                Vec3::Z,
                Vec3::Z,
                Vec3::Z,
                Vec3::X,
                Vec3::Z,
                Vec3::Z,
                Vec3::Z,
            ],
            colors: vec![[0; 3], [1; 3], [2; 3], [3; 3], [4; 3], [5; 3], [6; 3]],
            triangles: vec![[0, 1, 2], [3, 4, 5], [1, 3, 2]],
        };
        let welded = weld(&mesh);
        assert_eq!(
            welded.positions,
            vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::ONE]
        );
        assert_eq!(welded.triangles, vec![[0, 1, 2], [1, 3, 2]]);
        assert_eq!(welded.colors, vec![[0; 3], [1; 3], [2; 3], [4; 3]]);
        assert!((welded.normals[1] - (Vec3::X + Vec3::Z).normalize()).length() < 1e-6);
        welded.check().unwrap();
    }
}
