//! The voxel-planes flags and summary keys shared by `simulate` and
//! `reconstruct`.

use anyhow::Result;
use clap::Args;
use depthmesh::map::Mapper;
use depthmesh::planes::{PlaneGridConfig, PlanesConfig, PlanesMapper};
use depthmesh::Intrinsics;
use serde_json::{json, Map, Value};

/// Flags of the voxel-planes back-end (`--map planes`).
#[derive(Args, Debug, Clone)]
pub struct PlanesArgs {
    /// Voxel size in metres (planes; separate from --voxel, whose 1 cm suits the TSDF).
    #[arg(long, default_value_t = PlanesConfig::default().grid.voxel)]
    pub plane_voxel: f32,
    /// Coarse cell size in metres, a whole multiple of --plane-voxel (planes).
    #[arg(long, default_value_t = PlanesConfig::default().grid.cell)]
    pub plane_cell: f32,
    /// Anticipated point noise ε in metres; a window is planar when two
    /// eigenvalues exceed ε² and one does not (planes).
    #[arg(long, default_value_t = PlanesConfig::default().epsilon)]
    pub epsilon: f64,
}

impl Default for PlanesArgs {
    /// The flags' defaults: the paper's 0.05 m voxels, 1 m cells, ε = 0.02 m.
    fn default() -> Self {
        let config = PlanesConfig::default();
        PlanesArgs {
            plane_voxel: config.grid.voxel,
            plane_cell: config.grid.cell,
            epsilon: config.epsilon,
        }
    }
}

impl PlanesArgs {
    /// The configuration the flags describe.
    pub fn config(&self) -> PlanesConfig {
        PlanesConfig {
            grid: PlaneGridConfig {
                voxel: self.plane_voxel,
                cell: self.plane_cell,
            },
            epsilon: self.epsilon,
        }
    }

    /// A mapper for frames from `intrinsics`; bad flags are errors naming them.
    pub fn mapper(&self, intrinsics: Intrinsics) -> Result<PlanesMapper> {
        Ok(PlanesMapper::new(self.config(), intrinsics)?)
    }
}

/// Adds the voxel-planes keys to a run's summary: `voxels` (occupied),
/// `planar_voxels` (planar windows), `representation_bytes` (10 floats per
/// voxel, as the paper counts) and the parameters. Meshes first, so the
/// planar count is current.
pub fn summarise(mapper: &mut PlanesMapper, summary: &mut Map<String, Value>) {
    mapper.mesh();
    let config = mapper.grid().config();
    summary.insert("plane_voxel".into(), json!(config.voxel));
    summary.insert("plane_cell".into(), json!(config.cell));
    summary.insert("epsilon".into(), json!(mapper.epsilon()));
    summary.insert("voxels".into(), json!(mapper.grid().occupied_count()));
    summary.insert("planar_voxels".into(), json!(mapper.planar_count()));
    summary.insert(
        "representation_bytes".into(),
        json!(mapper.representation_bytes()),
    );
}
