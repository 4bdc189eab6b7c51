//! Reading and writing mesh files, chosen by extension.

use crate::error::{Error, Result};
use crate::mesh::glb::{read_glb, write_glb, GlbNode};
use crate::mesh::obj::{read_obj, write_obj};
use crate::mesh::ply::{read_ply, write_ply, PlyFormat};
use crate::mesh::Mesh;
use std::path::Path;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Ply,
    Obj,
    Glb,
}

fn kind(path: &Path) -> Result<Kind> {
    let extension = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase());
    match extension.as_deref() {
        Some("ply") => Ok(Kind::Ply),
        Some("obj") => Ok(Kind::Obj),
        Some("glb") => Ok(Kind::Glb),
        other => Err(Error::format(
            path,
            format!(
                "unsupported mesh file extension {} (supported: .ply, .obj, .glb)",
                other.map_or("(none)".to_string(), |e| format!("'.{e}'"))
            ),
        )),
    }
}

/// Reads a PLY (ASCII or binary), OBJ or GLB mesh, chosen by the file's
/// extension (case-insensitive). The result is checked, so every index is in
/// range and every attribute covers every vertex. A GLB file's nodes are
/// joined, leaving out collision meshes.
pub fn read_mesh(path: &Path) -> Result<Mesh> {
    let mesh = match kind(path)? {
        Kind::Ply => read_ply(path)?,
        Kind::Obj => read_obj(path)?,
        Kind::Glb => {
            let mut mesh = Mesh::default();
            for node in read_glb(path)?.iter().filter(|n| !n.collision) {
                mesh.append(&node.mesh);
            }
            mesh
        }
    };
    mesh.check().map_err(|m| Error::format(path, m))?;
    Ok(mesh)
}

/// Writes a mesh as binary little-endian PLY, OBJ or GLB (one node), chosen by the extension,
/// through a temporary file renamed into place so a failure never leaves a partial file.
/// An inconsistent mesh (see [`Mesh::check`]) is rejected before anything is written.
pub fn write_mesh(path: &Path, mesh: &Mesh) -> Result<()> {
    match kind(path)? {
        Kind::Ply => write_ply(path, mesh, PlyFormat::BinaryLittleEndian),
        Kind::Obj => write_obj(path, mesh),
        Kind::Glb => write_glb(
            path,
            &[GlbNode {
                name: "mesh",
                mesh,
                collision: false,
            }],
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atomic::scratch::ScratchDir;
    use glam::Vec3;

    fn sample() -> Mesh {
        Mesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::ONE],
            normals: vec![Vec3::Z; 4],
            colors: vec![[1, 2, 3], [4, 5, 6], [7, 8, 9], [250, 251, 252]],
            triangles: vec![[0, 1, 2], [1, 3, 2]],
        }
    }

    #[test]
    fn round_trips_by_extension_case_insensitively() {
        let dir = ScratchDir::new("io-ext");
        for name in ["a.ply", "b.PLY", "c.obj", "d.Obj", "e.glb"] {
            let path = dir.path().join(name);
            write_mesh(&path, &sample()).unwrap();
            assert_eq!(read_mesh(&path).unwrap(), sample(), "{name}");
        }
        let ply = std::fs::read(dir.path().join("a.ply")).unwrap();
        assert!(ply.starts_with(b"ply\nformat binary_little_endian 1.0\n"));
        assert!(std::fs::read(dir.path().join("c.obj"))
            .unwrap()
            .starts_with(b"#"));
    }

    #[test]
    fn unknown_extension_lists_supported_ones() {
        let dir = ScratchDir::new("io-unknown");
        for name in ["mesh.stl", "mesh"] {
            let path = dir.path().join(name);
            let e = write_mesh(&path, &sample()).unwrap_err().to_string();
            assert!(e.contains(name) && e.contains(".ply, .obj"), "{e}");
            let e = read_mesh(&path).unwrap_err().to_string();
            assert!(e.contains(name) && e.contains(".ply, .obj"), "{e}");
        }
        assert!(dir.entries().is_empty());
    }

    #[test]
    fn missing_file_is_io_error_naming_path() {
        let dir = ScratchDir::new("io-missing");
        let path = dir.path().join("absent.ply");
        let e = read_mesh(&path).unwrap_err();
        assert!(matches!(e, Error::Io { .. }));
        assert!(e.to_string().contains("absent.ply"), "{e}");
    }

    #[test]
    fn invalid_mesh_is_rejected_before_writing() {
        let dir = ScratchDir::new("io-invalid");
        let mut mesh = sample();
        mesh.normals.pop();
        for name in ["m.ply", "m.obj", "m.glb"] {
            let e = write_mesh(&dir.path().join(name), &mesh).unwrap_err();
            assert!(matches!(e, Error::Parameter { .. }), "{e}");
        }
        assert!(dir.entries().is_empty());
    }
}
