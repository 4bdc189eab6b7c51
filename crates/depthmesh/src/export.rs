//! Game-engine assets from a map mesh, without the thesis's manual MeshLab
//! and Blender steps: level the floor, cut into chunks an engine accepts,
//! simplify each chunk, add coarse collision meshes, convert units and axes,
//! and write GLB (one node per chunk), OBJ or PLY.

use crate::atomic::write_atomic;
use crate::error::{Error, Result};
use crate::mesh::align::{find_floor, Floor};
use crate::mesh::chunk::{split_by_vertices, DEFAULT_MAX_VERTICES};
use crate::mesh::glb::{glb_bytes, GlbNode};
use crate::mesh::io::write_mesh;
use crate::mesh::simplify::{simplify_locked, SimplifyParams};
use crate::mesh::weld::weld;
use crate::mesh::Mesh;
use glam::Vec3;
use rayon::prelude::*;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::str::FromStr;

/// Output file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Binary glTF 2.0: one file, one node per chunk.
    Glb,
    /// Wavefront OBJ: one file per chunk.
    Obj,
    /// Binary PLY: one file per chunk.
    Ply,
}

impl FromStr for Format {
    type Err = Error;

    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().as_str() {
            "glb" => Ok(Format::Glb),
            "obj" => Ok(Format::Obj),
            "ply" => Ok(Format::Ply),
            _ => Err(Error::parameter(
                "format",
                format!("unknown format '{s}' (expected glb, obj or ply)"),
            )),
        }
    }
}

impl Format {
    /// The format named by `path`'s extension.
    pub fn of_path(path: &Path) -> Result<Self> {
        let ext = path.extension().map(|e| e.to_string_lossy().into_owned());
        ext.as_deref().unwrap_or("").parse().map_err(|_| {
            Error::parameter(
                "format",
                format!(
                    "cannot tell the format of {} from its extension; give --format glb|obj|ply",
                    path.display()
                ),
            )
        })
    }

    /// The usual file extension.
    pub fn extension(self) -> &'static str {
        match self {
            Format::Glb => "glb",
            Format::Obj => "obj",
            Format::Ply => "ply",
        }
    }
}

/// Which axis points up in the written files. Meshes here are y-up (the
/// DESIGN convention, and glTF's); Unreal, Blender and many CAD tools are z-up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UpAxis {
    /// +y up (glTF, Unity, three.js).
    Y,
    /// +z up, right-handed: y-up turned by +90° about x.
    Z,
}

/// What [`export`] does.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExportOptions {
    /// File format.
    pub format: Format,
    /// Simplify each chunk (seams locked), or keep every triangle.
    pub simplify: Option<SimplifyParams>,
    /// Most vertices per chunk.
    pub chunk_vertices: usize,
    /// Engine units per metre (50 for Unreal Units of 2 cm).
    pub scale: f32,
    /// Up axis of the written files.
    pub up: UpAxis,
    /// Find the floor and make it level at height 0 (see [`crate::mesh::align`]).
    pub align_floor: bool,
    /// Add a coarse collision mesh per chunk.
    pub collision: bool,
}

impl Default for ExportOptions {
    fn default() -> Self {
        ExportOptions {
            format: Format::Glb,
            simplify: None,
            chunk_vertices: DEFAULT_MAX_VERTICES,
            scale: 1.0,
            up: UpAxis::Y,
            align_floor: false,
            collision: false,
        }
    }
}

/// How far a collision mesh may deviate from the surface, in metres: coarse
/// enough to be cheap for physics, close enough that nothing visibly floats
/// or sinks.
pub const COLLISION_ERROR: f32 = 0.03;

/// One chunk ready to write, in output units and axes.
#[derive(Clone, Debug, PartialEq)]
pub struct Asset {
    /// Node or file name stem, e.g. `chunk_003`.
    pub name: String,
    /// What is drawn: positions, normals and (if the input had them) colours.
    pub mesh: Mesh,
    /// Collision geometry (positions only), if asked for.
    pub collision: Option<Mesh>,
}

/// What [`export`] made.
#[derive(Clone, Debug)]
pub struct ExportReport {
    /// The chunks as written.
    pub assets: Vec<Asset>,
    /// The floor found, in the input's coordinates, with `--align-floor`.
    pub floor: Option<Floor>,
    /// Files written.
    pub files: Vec<PathBuf>,
}

/// Builds the assets of `mesh` (see the module notes) without writing them.
pub fn build_assets(mesh: &Mesh, options: &ExportOptions) -> Result<(Vec<Asset>, Option<Floor>)> {
    if !(options.scale.is_finite() && options.scale > 0.0) {
        return Err(Error::parameter(
            "scale",
            format!("must be a positive number, got {}", options.scale),
        ));
    }
    if let Some(p) = &options.simplify {
        p.validate()?;
    }
    let mut mesh = weld(mesh);
    if mesh.is_empty() {
        return Err(Error::parameter("mesh", "has no triangles to export"));
    }
    if mesh.normals.is_empty() {
        // Normals of the whole mesh, so chunks shade alike across seams.
        mesh.compute_vertex_normals();
    }
    let floor = options.align_floor.then(|| find_floor(&mesh)).transpose()?;
    if let Some(f) = &floor {
        let level = f.leveling(Vec3::Y);
        mesh.transform(
            |p| level.transform_point3(p),
            |n| level.transform_vector3(n),
        );
    }
    let chunks = split_by_vertices(&mesh, options.chunk_vertices)?;
    let collision_params = SimplifyParams {
        target: None,
        max_error: Some(COLLISION_ERROR),
        // Physics needs no hole outlines, only the seams kept.
        lock_border: false,
    };
    let scale = options.scale;
    let to_output = |p: Vec3| match options.up {
        UpAxis::Y => p,
        UpAxis::Z => Vec3::new(p.x, -p.z, p.y),
    };
    let mut assets = chunks
        .par_iter()
        .enumerate()
        .map(|(i, chunk)| {
            let mut render = match &options.simplify {
                Some(p) => simplify_locked(&chunk.mesh, &chunk.seam, p)?.mesh,
                None => chunk.mesh.clone(),
            };
            render.transform(|p| scale * to_output(p), to_output);
            let collision = options
                .collision
                .then(|| -> Result<Mesh> {
                    let mut c = simplify_locked(&chunk.mesh, &chunk.seam, &collision_params)?.mesh;
                    c.normals.clear();
                    c.colors.clear();
                    c.transform(|p| scale * to_output(p), to_output);
                    Ok(c)
                })
                .transpose()?;
            Ok(Asset {
                name: format!("chunk_{i:03}"),
                mesh: render,
                collision,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    assets.retain(|a| !a.mesh.is_empty());
    Ok((assets, floor))
}

/// Writes assets to `path`: one GLB file, or for OBJ and PLY the file itself
/// when there is a single chunk and no collision mesh, else one file per
/// chunk and collision mesh named `STEM_chunk_NNN[_collision].EXT` beside it.
pub fn write_assets(path: &Path, format: Format, assets: &[Asset]) -> Result<Vec<PathBuf>> {
    if format == Format::Glb {
        let bytes = glb_of_assets(assets)?;
        write_atomic(path, |w| w.write_all(&bytes))?;
        return Ok(vec![path.to_path_buf()]);
    }
    let single = assets.len() == 1 && assets[0].collision.is_none();
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut files = Vec::new();
    let mut write = |name: String, mesh: &Mesh| -> Result<()> {
        let file = if single {
            path.to_path_buf()
        } else {
            path.with_file_name(format!("{stem}_{name}.{}", format.extension()))
        };
        write_mesh(&file, mesh)?;
        files.push(file);
        Ok(())
    };
    for a in assets {
        write(a.name.clone(), &a.mesh)?;
        if let Some(c) = &a.collision {
            write(format!("{}_collision", a.name), c)?;
        }
    }
    Ok(files)
}

/// The bytes of one GLB file holding `assets`: a node per chunk, and the
/// collision meshes as nodes flagged `extras.collision`.
pub fn glb_of_assets(assets: &[Asset]) -> Result<Vec<u8>> {
    let collision_names: Vec<String> = assets
        .iter()
        .map(|a| a.name.replace("chunk", "collision"))
        .collect();
    let mut nodes: Vec<GlbNode> = assets
        .iter()
        .map(|a| GlbNode {
            name: &a.name,
            mesh: &a.mesh,
            collision: false,
        })
        .collect();
    nodes.extend(assets.iter().zip(&collision_names).filter_map(|(a, name)| {
        a.collision.as_ref().map(|mesh| GlbNode {
            name,
            mesh,
            collision: true,
        })
    }));
    glb_bytes(&nodes)
}

/// Builds the assets of `mesh` and writes them to `path`.
pub fn export(mesh: &Mesh, path: &Path, options: &ExportOptions) -> Result<ExportReport> {
    let (assets, floor) = build_assets(mesh, options)?;
    let files = write_assets(path, options.format, &assets)?;
    Ok(ExportReport {
        assets,
        floor,
        files,
    })
}
