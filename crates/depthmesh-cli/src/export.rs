//! `depthmesh export`: a mesh file to game-engine assets (see `depthmesh::export`).

use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use depthmesh::export::{export, ExportOptions, ExportReport, Format, UpAxis};
use depthmesh::mesh::chunk::DEFAULT_MAX_VERTICES;
use depthmesh::mesh::io::read_mesh;
use depthmesh::mesh::simplify::SimplifyParams;
use depthmesh::Mesh;
use std::path::{Path, PathBuf};

/// File format of the assets.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum FormatArg {
    /// Binary glTF 2.0, one node per chunk.
    Glb,
    /// Wavefront OBJ, one file per chunk.
    Obj,
    /// Binary PLY, one file per chunk.
    Ply,
}

impl From<FormatArg> for Format {
    fn from(f: FormatArg) -> Self {
        match f {
            FormatArg::Glb => Format::Glb,
            FormatArg::Obj => Format::Obj,
            FormatArg::Ply => Format::Ply,
        }
    }
}

/// Up axis of the written files.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Up {
    /// +y (glTF, Unity).
    Y,
    /// +z (Unreal, Blender).
    Z,
}

/// Export flags shared by `export` and the mapping commands.
#[derive(Args, Debug, Clone)]
pub struct AssetArgs {
    /// Keep this fraction of each chunk's triangles, in (0, 1] (seams and
    /// borders locked); `simplify --ratio` in the simplify command.
    #[arg(long, alias = "ratio", allow_negative_numbers = true)]
    pub simplify: Option<f32>,
    /// Most vertices per chunk (65,535: 16-bit indices, Unreal Engine 3's limit).
    #[arg(long, default_value_t = DEFAULT_MAX_VERTICES)]
    pub chunk_vertices: usize,
    /// Engine units per metre (e.g. 50 for Unreal Units of 2 cm, 100 for centimetres).
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    pub scale: f32,
    /// Up axis of the written files.
    #[arg(long, value_enum, default_value_t = Up::Y)]
    pub up: Up,
    /// Find the floor, make it level and put it at height 0.
    #[arg(long)]
    pub align_floor: bool,
    /// Add a coarse collision mesh per chunk (separate nodes or files).
    #[arg(long)]
    pub collision: bool,
}

impl Default for AssetArgs {
    fn default() -> Self {
        AssetArgs {
            simplify: None,
            chunk_vertices: DEFAULT_MAX_VERTICES,
            scale: 1.0,
            up: Up::Y,
            align_floor: false,
            collision: false,
        }
    }
}

impl AssetArgs {
    /// Library options for writing `format`.
    pub fn options(&self, format: Format) -> Result<ExportOptions> {
        if let Some(r) = self.simplify {
            if !(r > 0.0 && r <= 1.0) {
                bail!("invalid --simplify: must be a fraction of the triangles in (0, 1], got {r}");
            }
        }
        Ok(ExportOptions {
            format,
            simplify: self.simplify.map(SimplifyParams::ratio),
            chunk_vertices: self.chunk_vertices,
            scale: self.scale,
            up: match self.up {
                Up::Y => UpAxis::Y,
                Up::Z => UpAxis::Z,
            },
            align_floor: self.align_floor,
            collision: self.collision,
        })
    }
}

/// Export flags of the mapping commands: assets of the final mesh in `--out`.
#[derive(Args, Debug, Clone, Default)]
pub struct RunExportArgs {
    /// Also write the final mesh as assets, `mesh.glb` (or .obj, .ply) in --out.
    #[arg(long, value_enum)]
    pub export: Option<FormatArg>,
    #[command(flatten)]
    pub assets: AssetArgs,
}

impl RunExportArgs {
    /// Checks the flags, so that a run fails before it starts rather than
    /// after its mapping.
    pub fn check(&self) -> Result<()> {
        match self.export {
            Some(f) => self.assets.options(f.into()).map(|_| ()),
            None => Ok(()),
        }
    }

    /// Writes `mesh.EXT` into `dir` if `--export` was given.
    pub fn write(&self, mesh: &Mesh, dir: &Path) -> Result<Option<ExportReport>> {
        let Some(format) = self.export else {
            return Ok(None);
        };
        let format = Format::from(format);
        let options = self.assets.options(format)?;
        let path = dir.join(format!("mesh.{}", format.extension()));
        write(mesh, &path, &options).map(Some)
    }
}

/// Flags of `depthmesh export`.
#[derive(Args, Debug, Clone)]
pub struct ExportArgs {
    /// Input mesh (PLY, OBJ or GLB), or a map store (`reconstruct --store`).
    pub input: PathBuf,
    /// Output file (for OBJ and PLY with several chunks, the stem of one file per chunk).
    #[arg(short, long)]
    pub out: PathBuf,
    /// File format (default: from the output's extension).
    #[arg(long, value_enum)]
    pub format: Option<FormatArg>,
    #[command(flatten)]
    pub assets: AssetArgs,
}

/// The mesh in `path`: a mesh file, or the map of a store (`--store`) at
/// its last checkpoint.
pub fn read_input(path: &std::path::Path) -> Result<depthmesh::mesh::Mesh> {
    if depthmesh::store::is_store(path) {
        return Ok(depthmesh::store::mesh(path)?);
    }
    read_mesh(path).with_context(|| format!("cannot read the input mesh {}", path.display()))
}

/// Runs `export`.
pub fn run(args: &ExportArgs, quiet: bool) -> Result<()> {
    let format = match args.format {
        Some(f) => {
            let format = Format::from(f);
            // A file whose extension says another format misleads whoever
            // opens it.
            if let Some(ext) = args.out.extension() {
                if !ext.eq_ignore_ascii_case(format.extension()) {
                    bail!(
                        "--format {} but -o {} has the extension .{}: make them agree",
                        format.extension(),
                        args.out.display(),
                        ext.to_string_lossy()
                    );
                }
            }
            format
        }
        None => Format::of_path(&args.out)?,
    };
    let options = args.assets.options(format)?;
    let mesh = read_input(&args.input)?;
    let report = write(&mesh, &args.out, &options)?;
    if !quiet {
        eprintln!("{}", describe(&report));
    }
    Ok(())
}

/// Exports `mesh` to `path`, with the path in any error.
pub fn write(mesh: &Mesh, path: &Path, options: &ExportOptions) -> Result<ExportReport> {
    export(mesh, path, options).with_context(|| format!("cannot export {}", path.display()))
}

/// One line saying what was written.
pub fn describe(report: &ExportReport) -> String {
    let triangles: usize = report.assets.iter().map(|a| a.mesh.triangle_count()).sum();
    let largest = report
        .assets
        .iter()
        .map(|a| a.mesh.vertex_count())
        .max()
        .unwrap_or(0);
    let mut line = format!(
        "exported {} chunk(s), {triangles} triangles, at most {largest} vertices per chunk",
        report.assets.len()
    );
    if let Some(f) = &report.floor {
        line += &format!(
            "; floor normal {:.3} {:.3} {:.3} levelled ({:.0} % of the surface on it)",
            f.normal.x,
            f.normal.y,
            f.normal.z,
            100.0 * f.support
        );
    }
    let files: Vec<String> = report
        .files
        .iter()
        .map(|f| f.display().to_string())
        .collect();
    line + " -> " + &files.join(", ")
}
