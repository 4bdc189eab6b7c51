//! The voxel-planes back-end behind the common [`Mapper`] interface: frames
//! become world points folded into the voxel statistics, and the 2×2×2
//! windows whose statistics changed are re-meshed into plane patches.

use super::grid::{Inserted, PlaneGrid, PlaneGridConfig};
use super::polygon::plane_cube_polygon;
use super::runs::{depth_runs, RowRays};
use super::stats::VoxelStats;
use super::{is_planar, DEFAULT_EPSILON};
use crate::camera::{Intrinsics, Pose};
use crate::error::{Error, Result};
use crate::image::{DepthImage, Frame};
use crate::map::{IntegrateReport, MapStats, Mapper};
use crate::mesh::Mesh;
use crate::palette::normal_color;
use crate::raster::render_mesh_depth;
use crate::tsdf::KeyHasher;
use glam::{DVec3, IVec3, Vec3};
use rayon::prelude::*;
use std::collections::HashMap;
use std::hash::BuildHasherDefault;
use std::time::Instant;

/// Fewer points than this in a window make no plane: three points always
/// fit one exactly, so a few stray measurements would otherwise sprout
/// patches in empty space.
pub const MIN_WINDOW_POINTS: u32 = 10;

/// Floats the paper counts per voxel: count, centroid (3) and covariance (6).
pub const FLOATS_PER_VOXEL: usize = 10;

/// Parameters of a voxel-planes map.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlanesConfig {
    /// Voxel and cell sizes.
    pub grid: PlaneGridConfig,
    /// Anticipated point noise ε in metres; the planarity threshold is ε².
    pub epsilon: f64,
}

impl Default for PlanesConfig {
    /// The paper's 0.05 m voxels in 1 m cells, ε = 0.02 m.
    fn default() -> Self {
        PlanesConfig {
            grid: PlaneGridConfig::default(),
            epsilon: DEFAULT_EPSILON,
        }
    }
}

impl PlanesConfig {
    /// Checks the sizes and ε.
    pub fn validate(&self) -> Result<()> {
        self.grid.cell_voxels()?;
        if !(self.epsilon.is_finite() && self.epsilon > 0.0) {
            return Err(Error::parameter(
                "epsilon",
                format!(
                    "must be a positive distance in metres, got {}",
                    self.epsilon
                ),
            ));
        }
        Ok(())
    }
}

/// The surface patch of one planar window, in world coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Patch {
    /// Polygon vertices in order around `normal`; only the first `len` count.
    vertices: [Vec3; 6],
    /// Number of vertices: 0 when the plane misses the window's central cube.
    len: u8,
    /// Unit plane normal (its sign is arbitrary: points carry no orientation).
    pub normal: Vec3,
}

impl Patch {
    /// The polygon's vertices, empty when the plane misses the cube.
    pub fn vertices(&self) -> &[Vec3] {
        &self.vertices[..usize::from(self.len)]
    }
}

/// Grid vertex → the patch of its window, for planar windows only.
type PatchCache = HashMap<IVec3, Patch, BuildHasherDefault<KeyHasher>>;

/// The patch of the window around grid vertex `corner`, `None` when the
/// window is not planar.
///
/// The window's plane (centroid, smallest eigenvector) is cut by the
/// voxel-sized cube centred on `corner`; those cubes tile space with a
/// half-voxel offset, so the patches of neighbouring windows abut.
pub fn window_patch(grid: &PlaneGrid, corner: IVec3, epsilon: f64) -> Option<Patch> {
    let stats = grid.neighbourhood(corner);
    if stats.count < MIN_WINDOW_POINTS {
        return None;
    }
    let eigen = stats.eigen();
    if !is_planar(eigen.values, epsilon) {
        return None;
    }
    let normal = eigen.vectors[0];
    let size = f64::from(grid.config().voxel);
    let min = corner.as_dvec3() * size - DVec3::splat(0.5 * size);
    let mut patch = Patch {
        vertices: [Vec3::ZERO; 6],
        len: 0,
        normal: normal.as_vec3(),
    };
    if let Some(polygon) = plane_cube_polygon(stats.mean, normal, min, size) {
        for (out, v) in patch.vertices.iter_mut().zip(polygon.vertices()) {
            *out = v.as_vec3();
        }
        patch.len = polygon.vertices().len() as u8;
    }
    Some(patch)
}

/// The world points of a frame's valid depth pixels, row by row, into `out`
/// (cleared first; its allocation is reused).
pub fn frame_points(depth: &DepthImage, intrinsics: &Intrinsics, pose: &Pose, out: &mut Vec<Vec3>) {
    out.clear();
    let width = depth.width.max(1) as usize;
    out.par_extend(
        depth
            .data
            .par_chunks(width)
            .enumerate()
            .flat_map_iter(|(v, row)| {
                let ray = RowRays::new(intrinsics, pose, v as f32);
                row.iter()
                    .enumerate()
                    .filter(|&(_, &z)| z > 0.0 && z.is_finite())
                    .map(move |(u, &z)| ray.point(u, z))
            }),
    );
}

/// Voxel planes: per-voxel statistics in a semi-sparse grid, a plane patch
/// per planar 2×2×2 window. Windows touching a changed voxel are re-meshed
/// every `remesh_every` frames, or when the mesh is asked for.
#[derive(Debug)]
pub struct PlanesMapper {
    /// Re-mesh changed windows every this many frames (0: only on demand).
    pub remesh_every: u32,
    epsilon: f64,
    intrinsics: Intrinsics,
    grid: PlaneGrid,
    /// The current frame's runs of pixels (reused buffer).
    runs: Vec<(IVec3, VoxelStats)>,
    /// Voxels changed since the last re-mesh, possibly repeated (appending
    /// is cheaper than a set insert; see [`PlanesMapper::mark_changed`]).
    dirty: Vec<IVec3>,
    /// Length of `dirty` after its last deduplication.
    dirty_unique: usize,
    /// Planar windows and their patches.
    patches: PatchCache,
    /// Windows re-meshed since [`PlanesMapper::changed_groups`], while a
    /// viewer follows the map.
    changed_windows: Option<Vec<IVec3>>,
    frames: u32,
    mesh: Mesh,
    /// Whether `mesh` reflects `patches` and no voxel is dirty.
    assembled: bool,
}

impl PlanesMapper {
    /// An empty map for frames from `intrinsics`.
    pub fn new(config: PlanesConfig, intrinsics: Intrinsics) -> Result<Self> {
        config.validate()?;
        intrinsics.validate()?;
        Ok(PlanesMapper {
            remesh_every: 0,
            epsilon: config.epsilon,
            intrinsics,
            grid: PlaneGrid::new(config.grid)?,
            runs: Vec::new(),
            dirty: Vec::new(),
            dirty_unique: 0,
            patches: PatchCache::default(),
            changed_windows: None,
            frames: 0,
            mesh: Mesh::default(),
            assembled: true,
        })
    }

    /// The planarity noise ε in metres.
    pub fn epsilon(&self) -> f64 {
        self.epsilon
    }

    /// The voxel statistics.
    pub fn grid(&self) -> &PlaneGrid {
        &self.grid
    }

    /// Frames integrated.
    pub fn frames(&self) -> u32 {
        self.frames
    }

    /// Puts back the statistics of a map saved after `frames` frames and
    /// `inserts` grid insertions (see [`PlaneGrid::restore`]); its planes
    /// are found again from them when next meshed.
    pub fn restore(
        &mut self,
        cells: Vec<crate::planes::grid::SavedCell>,
        frames: u32,
        inserts: u32,
    ) -> Result<()> {
        self.grid.restore(cells, inserts)?;
        self.dirty = self.grid.occupied_voxels().map(|(v, _)| v).collect();
        self.dirty_unique = 0;
        self.frames = frames;
        self.assembled = false;
        Ok(())
    }

    /// Adds world points directly (a point cloud rather than a depth frame);
    /// returns how many were added.
    pub fn insert_points(&mut self, points: &[Vec3]) -> usize {
        let inserted = self.grid.insert_points(points);
        self.mark_changed(inserted)
    }

    /// Notes what an insertion changed; returns the points it added.
    fn mark_changed(&mut self, inserted: Inserted) -> usize {
        self.dirty.extend(inserted.changed);
        // Frames revisit the same voxels: deduplicate whenever the list has
        // doubled, which bounds it by twice the distinct voxels.
        if self.dirty.len() > 2 * self.dirty_unique.max(1 << 16) {
            sort_dedup(&mut self.dirty);
            self.dirty_unique = self.dirty.len();
        }
        self.assembled = false;
        inserted.points
    }

    /// Re-meshes every window that touches a voxel changed since the last
    /// re-mesh; returns how many windows were evaluated.
    pub fn remesh(&mut self) -> usize {
        sort_dedup(&mut self.dirty);
        let mut corners: Vec<IVec3> = self.dirty.drain(..).flat_map(window_corners).collect();
        self.dirty_unique = 0;
        sort_dedup(&mut corners);
        let (grid, epsilon) = (&self.grid, self.epsilon);
        let updated: Vec<(IVec3, Option<Patch>)> = corners
            .par_iter()
            .map(|&c| (c, window_patch(grid, c, epsilon)))
            .collect();
        for (corner, patch) in updated {
            match patch {
                Some(p) => self.patches.insert(corner, p),
                None => self.patches.remove(&corner),
            };
        }
        self.assembled = false;
        if let Some(changed) = &mut self.changed_windows {
            changed.extend_from_slice(&corners);
        }
        corners.len()
    }

    /// Starts noting re-meshed windows for a viewer, which sees the map in
    /// groups of [`WINDOW_GROUP`]³ windows; returns every group with a patch now.
    pub fn follow_groups(&mut self) -> Vec<IVec3> {
        self.remesh_dirty();
        self.changed_windows = Some(Vec::new());
        let mut groups: Vec<IVec3> = self.patches.keys().map(|&c| window_group(c)).collect();
        sort_dedup(&mut groups);
        groups
    }

    /// The groups with a window re-meshed since the last call (or
    /// [`PlanesMapper::follow_groups`]), re-meshing what is due first.
    pub fn changed_groups(&mut self) -> Vec<IVec3> {
        self.remesh_dirty();
        let mut groups: Vec<IVec3> = self
            .changed_windows
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default()
            .into_iter()
            .map(window_group)
            .collect();
        sort_dedup(&mut groups);
        groups
    }

    fn remesh_dirty(&mut self) {
        if !self.dirty.is_empty() {
            self.remesh();
        }
    }

    /// The mesh of each group's patches (in the order of `groups`), as of
    /// the last re-mesh; in one pass over the patches.
    pub fn group_meshes(&self, groups: &[IVec3]) -> Vec<Mesh> {
        let slot: HashMap<IVec3, usize, BuildHasherDefault<KeyHasher>> =
            groups.iter().enumerate().map(|(i, &g)| (g, i)).collect();
        let mut members: Vec<Vec<IVec3>> = vec![Vec::new(); groups.len()];
        for &corner in self.patches.keys() {
            if let Some(&i) = slot.get(&window_group(corner)) {
                members[i].push(corner);
            }
        }
        members
            .into_par_iter()
            .map(|mut corners| {
                corners.sort_unstable_by_key(|c| (c.z, c.y, c.x));
                assemble(corners.iter().map(|c| &self.patches[c]))
            })
            .collect()
    }

    /// Windows classified planar (each owns the voxel-sized cube around its
    /// centre vertex: the paper's planar voxels), as of the last re-mesh.
    pub fn planar_count(&self) -> usize {
        self.patches.len()
    }

    /// Bytes of the representation as the paper counts it: 10 floats of 4
    /// bytes per occupied voxel.
    pub fn representation_bytes(&self) -> usize {
        self.grid.occupied_count() * FLOATS_PER_VOXEL * 4
    }

    /// The mesh of every window from scratch, ignoring the cache: what the
    /// incrementally kept mesh equals.
    pub fn extract_mesh(&self) -> Mesh {
        let mut corners: Vec<IVec3> = self
            .grid
            .occupied_voxels()
            .flat_map(|(v, _)| window_corners(v))
            .collect();
        sort_dedup(&mut corners);
        let patches: Vec<Patch> = corners
            .par_iter()
            .filter_map(|&c| window_patch(&self.grid, c, self.epsilon))
            .collect();
        assemble(patches.iter())
    }

    /// The current mesh without updating the kept one (for `&self` callers).
    fn current_mesh(&self) -> Mesh {
        if self.dirty.is_empty() {
            let mut keys: Vec<&IVec3> = self.patches.keys().collect();
            keys.sort_unstable_by_key(|c| (c.z, c.y, c.x));
            assemble(keys.into_iter().map(|k| &self.patches[k]))
        } else {
            self.extract_mesh()
        }
    }
}

/// Windows per side of the groups a viewer receives the map in: a few
/// hundred small polygons per group keeps both the updates and the number
/// of pieces on the viewer's side small.
pub const WINDOW_GROUP: i32 = 8;

/// The viewer's group of the window at `corner`.
fn window_group(corner: IVec3) -> IVec3 {
    corner.div_euclid(IVec3::splat(WINDOW_GROUP))
}

/// Sorts keys (z, then y, then x) and drops repeats.
fn sort_dedup(keys: &mut Vec<IVec3>) {
    keys.par_sort_unstable_by_key(|c| (c.z, c.y, c.x));
    keys.dedup();
}

/// The eight grid vertices whose windows contain voxel `v`.
fn window_corners(v: IVec3) -> impl Iterator<Item = IVec3> {
    (0..8).map(move |i| v + IVec3::new(i & 1, (i >> 1) & 1, (i >> 2) & 1))
}

/// One mesh of the patches, in the given order: each polygon a fan with
/// its own vertices (neighbouring planes differ, so none are shared),
/// normals and colours by the unoriented normal.
fn assemble<'a>(patches: impl Iterator<Item = &'a Patch>) -> Mesh {
    let mut mesh = Mesh::default();
    for p in patches {
        let base = mesh.positions.len() as u32;
        let v = p.vertices();
        if v.len() < 3 {
            continue;
        }
        let colour = normal_color(p.normal);
        mesh.positions.extend_from_slice(v);
        mesh.normals.extend(std::iter::repeat_n(p.normal, v.len()));
        mesh.colors.extend(std::iter::repeat_n(colour, v.len()));
        mesh.triangles
            .extend((1..v.len() as u32 - 1).map(|i| [base, base + i, base + i + 1]));
    }
    mesh
}

impl Mapper for PlanesMapper {
    fn name(&self) -> &'static str {
        "planes"
    }

    fn integrate(&mut self, frame: &Frame, pose: &Pose) -> Result<IntegrateReport> {
        let k = &self.intrinsics;
        if (frame.depth.width, frame.depth.height) != (k.width, k.height) {
            return Err(Error::parameter(
                "frame",
                format!(
                    "depth image is {}×{} but the camera is {}×{}",
                    frame.depth.width, frame.depth.height, k.width, k.height
                ),
            ));
        }
        let start = Instant::now();
        let before = self.grid.occupied_count();
        depth_runs(&self.grid, &frame.depth, k, pose, &mut self.runs);
        let inserted = self.grid.insert_stats(&self.runs);
        let added = self.mark_changed(inserted);
        let inserted = start.elapsed();
        self.frames += 1;
        let due = self.remesh_every > 0 && self.frames.is_multiple_of(self.remesh_every);
        let windows = if due { self.remesh() } else { 0 };
        let meshed = start.elapsed() - inserted;
        Ok(IntegrateReport {
            new_elements: self.grid.occupied_count() - before,
            removed_elements: 0,
            extra: vec![
                ("points", added as f64),
                ("voxels", self.grid.occupied_count() as f64),
                ("remeshed_windows", windows as f64),
                ("planar_voxels", self.planar_count() as f64),
                ("insert_ms", inserted.as_secs_f64() * 1e3),
                ("remesh_ms", meshed.as_secs_f64() * 1e3),
            ],
        })
    }

    fn render_depth(&self, intrinsics: &Intrinsics, pose: &Pose) -> DepthImage {
        render_mesh_depth(&self.current_mesh(), intrinsics, pose)
    }

    fn mesh(&mut self) -> &Mesh {
        if !self.assembled {
            self.remesh();
            self.mesh = self.current_mesh();
            self.assembled = true;
        }
        &self.mesh
    }

    fn stats(&self) -> MapStats {
        MapStats {
            elements: self.grid.occupied_count(),
            vertices: self.assembled.then(|| self.mesh.vertex_count()),
            bytes: self.grid.memory_bytes()
                + self.patches.capacity() * (std::mem::size_of::<(IVec3, Patch)>() + 1),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::distance::MeshDistance;
    use crate::sim::{NoiseModel, PathSpec, Scene, SceneOptions, SimulatedSensor};
    use std::path::Path;

    fn mapper() -> PlanesMapper {
        PlanesMapper::new(PlanesConfig::default(), Intrinsics::kinect()).unwrap()
    }

    /// A regular grid of points `step` apart on the plane through `origin`
    /// spanned by `u` and `w`, covering `[-half, half]²`.
    fn plane_points(origin: DVec3, u: DVec3, w: DVec3, half: f64, step: f64) -> Vec<Vec3> {
        let k = (half / step).round() as i32;
        (-k..=k)
            .flat_map(|i| (-k..=k).map(move |j| (i, j)))
            .map(|(i, j)| {
                (origin + u * (f64::from(i) * step) + w * (f64::from(j) * step)).as_vec3()
            })
            .collect()
    }

    #[test]
    fn a_plane_gives_coplanar_patches_over_every_occupied_voxel() {
        let normal = DVec3::new(0.3, 1.0, 0.2).normalize();
        let u = normal.any_orthonormal_vector();
        let w = normal.cross(u);
        let origin = DVec3::new(0.41, 0.93, -0.27);
        let mut m = mapper();
        m.insert_points(&plane_points(origin, u, w, 0.4, 0.004));
        let mesh = m.mesh().clone();
        assert!(mesh.triangle_count() > 100);
        mesh.check().unwrap();
        for p in &mesh.positions {
            let d = normal.dot(p.as_dvec3() - origin);
            assert!(d.abs() < 1e-5, "vertex {p} is {d} m off the plane");
        }
        // Every occupied voxel away from the sampled square's border has
        // surface at its centroid: the patches tessellate without holes.
        let index = MeshDistance::new(&mesh, 1e-3);
        let mut checked = 0;
        for (v, s) in m.grid().occupied_voxels() {
            let r = s.mean - origin;
            if r.dot(u).abs().max(r.dot(w).abs()) > 0.3 {
                continue;
            }
            let d = index.distance(s.mean.as_vec3());
            assert!(d.is_some_and(|d| d < 1e-5), "voxel {v}: {d:?}");
            checked += 1;
        }
        assert!(checked > 100, "{checked}");
    }

    #[test]
    fn a_plane_through_a_voxel_corner_is_meshed_by_the_window() {
        let mut m = mapper();
        let corner = IVec3::new(7, -3, 12);
        let c = m.grid().corner_position(corner).as_dvec3();
        let normal = DVec3::ONE.normalize();
        let u = normal.any_orthonormal_vector();
        let w = normal.cross(u);
        // A disc of points centred on the vertex: each of the voxels sharing
        // the vertex sees only a wedge of it.
        let pts: Vec<Vec3> = plane_points(c, u, w, 0.045, 0.002)
            .into_iter()
            .filter(|p| (p.as_dvec3() - c).length() < 0.045)
            .collect();
        m.insert_points(&pts);
        for i in 0..8 {
            let v = corner - IVec3::new(i & 1, (i >> 1) & 1, (i >> 2) & 1);
            if let Some(s) = m.grid().voxel(v) {
                assert!(
                    !is_planar(s.eigen().values, DEFAULT_EPSILON),
                    "voxel {v} alone is planar"
                );
            }
        }
        let all = VoxelStats::from_points(&pts.iter().map(|p| p.as_dvec3()).collect::<Vec<_>>());
        assert!(is_planar(all.eigen().values, DEFAULT_EPSILON));
        let patch = window_patch(m.grid(), corner, DEFAULT_EPSILON).expect("window is planar");
        assert_eq!(patch.vertices().len(), 6, "the plane halves the cube");
        assert!(m.mesh().triangle_count() >= 4);
    }

    #[test]
    fn incremental_meshing_equals_batch() {
        let scene = Scene::parse(
            include_str!("../../../../scenes/table.toml"),
            Path::new("scenes/table.toml"),
            &SceneOptions::default(),
        )
        .unwrap();
        let poses = PathSpec::Helix.build(&scene, 6).unwrap();
        let mut sensor = SimulatedSensor::kinect(NoiseModel::Kinect, 5);
        let (mut every, mut deferred) = (mapper(), mapper());
        every.remesh_every = 1;
        for (i, pose) in poses.iter().enumerate().take(4) {
            let frame = sensor.capture(&scene, i as u32 + 1, pose);
            let report = every.integrate(&frame, pose).unwrap();
            assert!(report.get("remeshed_windows").unwrap() > 0.0);
            deferred.integrate(&frame, pose).unwrap();
        }
        let batch = every.extract_mesh();
        assert!(batch.triangle_count() > 1000);
        assert_eq!(every.mesh(), &batch);
        assert_eq!(deferred.mesh(), &batch);
        // What the map predicts from a pose it was built from is its surface.
        let depth = every.render_depth(&sensor.intrinsics, &poses[0]);
        assert!(depth.valid_count() > 10_000);
    }

    #[test]
    fn bad_parameters_are_errors() {
        let k = Intrinsics::kinect();
        let bad_epsilon = PlanesConfig {
            epsilon: -1.0,
            ..PlanesConfig::default()
        };
        assert!(PlanesMapper::new(bad_epsilon, k).is_err());
        let bad_cell = PlanesConfig {
            grid: PlaneGridConfig {
                voxel: 0.05,
                cell: 0.12,
            },
            ..PlanesConfig::default()
        };
        assert!(PlanesMapper::new(bad_cell, k).is_err());
        let mut m = mapper();
        let frame = Frame {
            index: 0,
            timestamp: 0.0,
            depth: DepthImage::new(4, 4),
            color: None,
            pose: None,
        };
        assert!(m.integrate(&frame, &Pose::default()).is_err());
    }
}
