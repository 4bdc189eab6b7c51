//! `depthmesh simplify`: quadric edge collapse of a mesh file.

use anyhow::Result;
use clap::Args;
use depthmesh::mesh::io::write_mesh;
use depthmesh::mesh::simplify::{simplify, SimplifyParams, Target};
use std::path::PathBuf;
use std::time::Instant;

/// Flags of `depthmesh simplify`.
#[derive(Args, Debug, Clone)]
pub struct SimplifyArgs {
    /// Input mesh (PLY, OBJ or GLB), or a map store (`reconstruct --store`).
    pub input: PathBuf,
    /// Output mesh; the format follows the extension (.ply, .obj, .glb).
    #[arg(short, long)]
    pub out: PathBuf,
    /// Keep this fraction of the triangles, in (0, 1] (`--simplify` in
    /// `export` and the mapping commands' export).
    #[arg(long, alias = "simplify", conflicts_with = "target_triangles")]
    pub ratio: Option<f32>,
    /// Keep this many triangles.
    #[arg(long)]
    pub target_triangles: Option<usize>,
    /// Largest deviation from the input surface, in metres; alone, simplifies
    /// as far as it allows.
    #[arg(long)]
    pub max_error: Option<f32>,
    /// Let vertices on open borders (hole outlines) move.
    #[arg(long)]
    pub no_lock_border: bool,
}

impl SimplifyArgs {
    /// The library parameters the flags stand for.
    pub fn params(&self) -> SimplifyParams {
        SimplifyParams {
            target: self
                .ratio
                .map(Target::Ratio)
                .or(self.target_triangles.map(Target::Triangles)),
            max_error: self.max_error,
            lock_border: !self.no_lock_border,
        }
    }
}

/// Runs `simplify`: reads, simplifies, writes, and reports on stderr.
pub fn run(args: &SimplifyArgs, quiet: bool) -> Result<()> {
    let params = args.params();
    params.validate()?;
    let mesh = crate::export::read_input(&args.input)?;
    let start = Instant::now();
    let result = simplify(&mesh, &params)?;
    let seconds = start.elapsed().as_secs_f64();
    write_mesh(&args.out, &result.mesh)?;
    if !quiet {
        eprintln!(
            "simplified {} triangles to {} in {seconds:.3} s (estimated error {:.2} mm) -> {}",
            mesh.triangle_count(),
            result.mesh.triangle_count(),
            result.error * 1e3,
            args.out.display()
        );
    }
    Ok(())
}
