//! Reading and writing mesh files, chosen by extension.

use crate::error::Result;
use crate::mesh::Mesh;
use std::path::Path;

/// Reads a PLY (ASCII or binary) or OBJ mesh, chosen by the file's extension.
pub fn read_mesh(path: &Path) -> Result<Mesh> {
    let _ = path;
    todo!("mesh reading")
}

/// Writes a mesh as binary little-endian PLY or OBJ, chosen by the extension,
/// through a temporary file renamed into place so a failure never leaves a partial file.
pub fn write_mesh(path: &Path, mesh: &Mesh) -> Result<()> {
    let _ = (path, mesh);
    todo!("mesh writing")
}
