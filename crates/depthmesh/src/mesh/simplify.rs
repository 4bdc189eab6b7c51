//! Quadric edge-collapse simplification through meshoptimizer.
//!
//! meshoptimizer's simplifier is the fastest quadric simplifier we know of and
//! matches MeshLab's error; `bench/export_check.sh` measures both. We use the
//! variant that moves the kept vertices to their optimal positions, as
//! MeshLab's "optimal placement" does. Only positions steer it: weighing
//! normals and colours in doubled its time on a TSDF mesh for no gain in
//! distance. Kept vertices keep their colours, and normals are recomputed
//! from the simplified surface (except at locked vertices).

use crate::error::{Error, Result};
use crate::mesh::chunk::{merge, split_by_triangles};
use crate::mesh::weld::weld;
use crate::mesh::Mesh;
use glam::Vec3;
use meshopt::simplify::{simplify_with_update, SimplifyOptions, SimplifyVertex};
use rayon::prelude::*;

/// How many triangles to keep.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Target {
    /// A fraction of the input's triangles, in (0, 1].
    Ratio(f32),
    /// A number of triangles.
    Triangles(usize),
}

/// How far to simplify. The simplifier stops at whichever of the target and
/// the error bound it reaches first.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimplifyParams {
    /// Triangles to keep; `None` simplifies as far as `max_error` allows.
    pub target: Option<Target>,
    /// Largest distance in metres a vertex may move from the surface it
    /// stands for; `None` lets the target alone decide.
    pub max_error: Option<f32>,
    /// Keep vertices on the mesh's open borders where they are, as MeshLab's
    /// "preserve boundary" does: scans are full of holes whose outlines would
    /// otherwise shrink.
    pub lock_border: bool,
}

impl SimplifyParams {
    /// Simplify to `ratio` of the triangles with borders locked.
    pub fn ratio(ratio: f32) -> Self {
        SimplifyParams {
            target: Some(Target::Ratio(ratio)),
            max_error: None,
            lock_border: true,
        }
    }

    /// Checks that the parameters make sense; errors name the flag.
    pub fn validate(&self) -> Result<()> {
        match self.target {
            Some(Target::Ratio(r)) if !(r > 0.0 && r <= 1.0) => {
                return Err(Error::parameter(
                    "ratio",
                    format!("must be in (0, 1], got {r}"),
                ))
            }
            Some(Target::Triangles(0)) => {
                return Err(Error::parameter("target_triangles", "must be at least 1"))
            }
            None if self.max_error.is_none() => {
                return Err(Error::parameter(
                    "simplification",
                    "give a ratio, a target triangle count or a maximum error",
                ))
            }
            _ => {}
        }
        match self.max_error {
            Some(e) if !(e.is_finite() && e > 0.0) => Err(Error::parameter(
                "max_error",
                format!("must be a positive number of metres, got {e}"),
            )),
            _ => Ok(()),
        }
    }

    fn target_triangles(&self, input: usize) -> usize {
        match self.target {
            Some(Target::Ratio(r)) => (input as f64 * r as f64).round() as usize,
            Some(Target::Triangles(n)) => n,
            None => 0,
        }
    }
}

/// A simplified mesh and how far it strays from its input.
#[derive(Clone, Debug)]
pub struct Simplified {
    /// The result, with only the vertices it uses.
    pub mesh: Mesh,
    /// meshoptimizer's estimate of the largest deviation, in metres.
    pub error: f32,
}

/// Below this many triangles one thread is quick enough and splitting would
/// only add work.
const PARALLEL_MIN_TRIANGLES: usize = 50_000;

/// Chunks a large mesh is split into: a constant, not the thread count, so
/// the result is the same whatever the pool size. More chunks lock more
/// seam vertices in the first pass: on a 250k-triangle TSDF mesh of the
/// kitchen at 10 %, 4 chunks left a 3 % and 8 chunks a 5 % larger mean
/// distance to the input than 2 (0.86 mm).
const CHUNKS: usize = 2;

/// Welds `mesh` (see [`weld`]) and simplifies it.
///
/// A large mesh with a triangle target is simplified in parallel: it is
/// split into two chunks, the chunks are simplified to 1.5 times the
/// target ratio with their seams locked, and a last pass over the joined
/// result, 15 % of the input's size at a 10 % target, reaches the target
/// and dissolves the seams. With an error bound it runs as one pass, since two
/// passes could add their errors. The output does not depend on the number
/// of threads.
pub fn simplify(mesh: &Mesh, params: &SimplifyParams) -> Result<Simplified> {
    params.validate()?;
    let mesh = weld(mesh);
    let target = params.target_triangles(mesh.triangle_count());
    if mesh.triangle_count() < PARALLEL_MIN_TRIANGLES
        || params.max_error.is_some()
        || target >= mesh.triangle_count()
    {
        return simplify_locked(&mesh, &[], params);
    }
    let chunks = split_by_triangles(&mesh, mesh.triangle_count().div_ceil(CHUNKS));
    // The first pass stops at 1.5 times the target: the last pass, over the
    // whole surface, then picks the cheapest collapses everywhere, which
    // measured a lower mean error on a TSDF mesh (0.62 against 0.69 mm).
    let first = SimplifyParams {
        target: Some(Target::Ratio(
            (target.max(1) as f32 / mesh.triangle_count() as f32 * 1.5).min(1.0),
        )),
        ..*params
    };
    let parts = chunks
        .par_iter()
        .map(|c| simplify_locked(&c.mesh, &c.seam, &first))
        .collect::<Result<Vec<_>>>()?;
    let joined = merge(parts.iter().map(|p| &p.mesh));
    let last = SimplifyParams {
        target: Some(Target::Triangles(target.max(1))),
        ..*params
    };
    let mut result = simplify_locked(&joined, &[], &last)?;
    // The passes' deviations can add up.
    result.error += parts.iter().map(|p| p.error).fold(0.0, f32::max);
    Ok(result)
}

/// Simplifies an already welded `mesh`, never moving or removing the vertices
/// flagged in `locked` (one flag per vertex, or empty for none).
///
/// Chunks of one mesh simplified separately still meet exactly when the
/// vertices they share are locked: the seams keep every vertex and edge.
pub fn simplify_locked(
    mesh: &Mesh,
    locked: &[bool],
    params: &SimplifyParams,
) -> Result<Simplified> {
    params.validate()?;
    mesh.check().map_err(|m| Error::parameter("mesh", m))?;
    if !locked.is_empty() && locked.len() != mesh.vertex_count() {
        return Err(Error::parameter(
            "locked",
            format!(
                "{} flags for {} vertices",
                locked.len(),
                mesh.vertex_count()
            ),
        ));
    }
    let mut positions: Vec<[f32; 3]> = mesh.positions.iter().map(|p| p.to_array()).collect();
    let lock: Vec<SimplifyVertex> = locked
        .iter()
        .map(|&l| {
            if l {
                SimplifyVertex::Lock
            } else {
                SimplifyVertex::None
            }
        })
        .collect();
    let mut options = SimplifyOptions::ErrorAbsolute;
    if params.lock_border {
        options |= SimplifyOptions::LockBorder;
    }
    let mut indices: Vec<u32> = mesh.triangles.iter().flatten().copied().collect();
    let mut error = 0.0f32;
    let count = simplify_with_update(
        &mut indices,
        &mut positions,
        &mut [],
        &[],
        0,
        (!lock.is_empty()).then_some(lock.as_slice()),
        // meshoptimizer aborts the process on a target above the input.
        3 * params
            .target_triangles(mesh.triangle_count())
            .min(mesh.triangle_count()),
        params.max_error.unwrap_or(f32::MAX),
        options,
        Some(&mut error),
    );
    indices.truncate(count);
    let mut out = Mesh {
        positions: positions.into_iter().map(Vec3::from_array).collect(),
        normals: Vec::new(),
        colors: mesh.colors.clone(),
        triangles: indices
            .chunks_exact(3)
            .map(|t| [t[0], t[1], t[2]])
            .collect(),
    };
    if !mesh.normals.is_empty() {
        out.compute_vertex_normals();
        // A locked vertex's surface goes on beyond this mesh (the next
        // chunk), so only its own normal shades both sides alike.
        for (i, _) in locked.iter().enumerate().filter(|(_, &l)| l) {
            out.normals[i] = mesh.normals[i];
        }
    }
    out.remove_unreferenced_vertices();
    Ok(Simplified { mesh: out, error })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::chunk::tests::sphere;

    fn radius_error(mesh: &Mesh) -> f32 {
        mesh.positions
            .iter()
            .map(|p| (p.length() - 1.0).abs())
            .fold(0.0, f32::max)
    }

    #[test]
    fn reaches_the_ratio_and_keeps_attributes() {
        let mut mesh = sphere(200, 300);
        mesh.colors = (0..mesh.vertex_count()).map(|i| [i as u8, 7, 9]).collect();
        let out = simplify(&mesh, &SimplifyParams::ratio(0.1)).unwrap();
        let target = mesh.triangle_count() / 10;
        assert!(out.mesh.triangle_count() <= target + 2);
        assert!(out.mesh.triangle_count() >= target * 9 / 10);
        out.mesh.check().unwrap();
        assert_eq!(out.mesh.normals.len(), out.mesh.vertex_count());
        assert_eq!(out.mesh.colors.len(), out.mesh.vertex_count());
        assert!(out.mesh.colors.iter().all(|c| c[1] == 7 && c[2] == 9));
        assert!(radius_error(&out.mesh) < 0.01);
    }

    #[test]
    fn the_error_bound_holds() {
        let mesh = sphere(60, 90);
        let params = SimplifyParams {
            target: None,
            max_error: Some(0.002),
            lock_border: true,
        };
        let out = simplify(&mesh, &params).unwrap();
        assert!(out.mesh.triangle_count() < mesh.triangle_count());
        assert!(out.error <= 0.002, "{}", out.error);
    }

    #[test]
    fn bad_parameters_name_their_flag() {
        let mesh = sphere(4, 4);
        let cases = [
            (SimplifyParams::ratio(0.0), "ratio"),
            (SimplifyParams::ratio(1.5), "ratio"),
            (SimplifyParams::ratio(f32::NAN), "ratio"),
            (
                SimplifyParams {
                    target: Some(Target::Triangles(0)),
                    ..SimplifyParams::ratio(1.0)
                },
                "target_triangles",
            ),
            (
                SimplifyParams {
                    max_error: Some(-1.0),
                    ..SimplifyParams::ratio(0.5)
                },
                "max_error",
            ),
            (
                SimplifyParams {
                    target: None,
                    max_error: None,
                    lock_border: true,
                },
                "ratio",
            ),
        ];
        for (params, flag) in cases {
            let e = simplify(&mesh, &params).unwrap_err().to_string();
            assert!(e.contains(flag), "{e}");
        }
    }

    #[test]
    fn a_target_above_the_input_keeps_the_mesh() {
        let mesh = sphere(10, 12);
        let params = SimplifyParams {
            target: Some(Target::Triangles(1_000_000)),
            ..SimplifyParams::ratio(1.0)
        };
        let out = simplify(&mesh, &params).unwrap();
        assert_eq!(out.mesh.triangle_count(), mesh.triangle_count());
    }
}
