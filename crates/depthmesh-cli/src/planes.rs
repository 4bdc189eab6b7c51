//! The voxel-planes flags shared by the mapping commands.

use clap::Args;
use depthmesh::planes::{PlaneGridConfig, PlanesConfig};

/// Flags of the voxel-planes back-end (`--map planes`).
#[derive(Args, Debug, Clone)]
pub struct PlanesArgs {
    /// Voxel size of the voxel-planes map, metres (planes).
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
}
