//! The interface every map back-end implements.

use crate::camera::{Intrinsics, Pose};
use crate::error::Result;
use crate::image::{DepthImage, Frame};
use crate::mesh::Mesh;

/// What one call to [`Mapper::integrate`] did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct IntegrateReport {
    /// Elements (triangles, voxels, patches) added to the map.
    pub new_elements: usize,
    /// Elements removed from the map.
    pub removed_elements: usize,
    /// Back-end specific figures, written as extra `stats.csv` columns.
    pub extra: Vec<(&'static str, f64)>,
}

impl IntegrateReport {
    /// The back-end specific figure called `name`, if reported.
    pub fn get(&self, name: &str) -> Option<f64> {
        self.extra.iter().find(|(k, _)| *k == name).map(|(_, v)| *v)
    }
}

/// Size of a map.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MapStats {
    /// Elements of the map (triangles for mesh maps).
    pub elements: usize,
    /// Vertices of the map's mesh; `None` while the kept mesh is older than
    /// the map (a back-end that re-meshes on demand has not been asked yet),
    /// rather than a stale count.
    pub vertices: Option<usize>,
    /// Bytes of memory the map representation holds.
    pub bytes: usize,
}

/// A map back-end: fuses posed depth frames and keeps a mesh of the result.
pub trait Mapper {
    /// Short name used in files and summaries (`mabdi`, `naive`, ...).
    fn name(&self) -> &'static str;
    /// Fuses one frame taken from `pose` (camera-to-world).
    fn integrate(&mut self, frame: &Frame, pose: &Pose) -> Result<IntegrateReport>;
    /// The depth the map predicts a camera with `intrinsics` would see from `pose`.
    fn render_depth(&self, intrinsics: &Intrinsics, pose: &Pose) -> DepthImage;
    /// The current mesh of the map.
    fn mesh(&mut self) -> &Mesh;
    /// The current size of the map.
    fn stats(&self) -> MapStats;
}
