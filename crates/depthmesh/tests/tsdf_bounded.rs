//! Bounded memory: a long walk down a simulated corridor with a small active
//! radius writes out chunks whose union is the unbounded map's mesh, while
//! the blocks held in memory stay level; a walk that comes back continues
//! the blocks it left in an archive, and its map equals the unbounded one.

use depthmesh::error::Result;
use depthmesh::map::Mapper;
use depthmesh::sim::{NoiseModel, Scene, SceneOptions, SimulatedSensor};
use depthmesh::tsdf::archive::BlockArchive;
use depthmesh::tsdf::mapper::TsdfMapper;
use depthmesh::tsdf::TsdfConfig;
use depthmesh::tsdf::{Block, KeyMap};
use depthmesh::{Intrinsics, Mesh, Pose};
use glam::{IVec3, Vec3};

/// `scenes/corridor.toml`: a floor, a wall on the +z side and boxes and
/// posts along it, 40 m long.
fn corridor() -> Scene {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/corridor.toml");
    Scene::load(path.as_ref(), &SceneOptions::default()).unwrap()
}

/// The triangles of `meshes`, sorted (see [`Mesh::triangle_records`]).
fn triangle_set(meshes: &[Mesh]) -> Vec<[[u32; 6]; 3]> {
    let mut set = Vec::new();
    for m in meshes {
        m.triangle_records(&mut set);
    }
    set.sort_unstable();
    set
}

#[test]
fn chunks_of_a_long_walk_equal_the_unbounded_map_in_bounded_memory() {
    let scene = corridor();
    let k = Intrinsics::from_vertical_fov(160, 120, 60.0);
    let mut sensor = SimulatedSensor::new(k, 0.8, 4.0, NoiseModel::None, 0).unwrap();
    // Walking along +x, looking ahead to the wall and the floor.
    let poses: Vec<Pose> = (0..136)
        .map(|i| {
            let eye = Vec3::new(0.5 + 0.25 * i as f32, 1.3, -0.5);
            Pose::look_at(eye, eye + Vec3::new(0.7, -0.5, 1.0), Vec3::Y)
        })
        .collect();
    let config = TsdfConfig::new(0.05);
    let mut unbounded = TsdfMapper::new(config, k, 0.8, 4.0).unwrap();
    let mut bounded = TsdfMapper::new(config, k, 0.8, 4.0).unwrap();
    // Beyond the sensor's reach: nothing seen is clipped.
    let radius = bounded.reach() + 0.05;
    assert!(radius < 6.0, "reach {radius} m");
    bounded.set_active_radius(radius).unwrap();
    let mut chunks = Vec::new();
    let mut resident = Vec::new();
    for (i, pose) in poses.iter().enumerate() {
        let frame = sensor.capture(&scene, i as u32 + 1, pose);
        unbounded.integrate(&frame, pose).unwrap();
        bounded.integrate(&frame, pose).unwrap();
        chunks.push(bounded.take_evicted());
        resident.push(bounded.volume().blocks().len());
    }
    let whole = unbounded.mesh().clone();
    chunks.push(bounded.mesh().clone());
    assert!(
        whole.triangle_count() > 20_000,
        "{} triangles",
        whole.triangle_count()
    );
    assert!(chunks[..chunks.len() - 1]
        .iter()
        .any(|c| !c.triangles.is_empty()));
    assert!(
        triangle_set(&chunks) == triangle_set(&[whole]),
        "the chunks differ from the unbounded mesh"
    );

    let total = unbounded.volume().blocks().len();
    assert_eq!(
        bounded.evicted_blocks() + bounded.volume().blocks().len(),
        total
    );
    assert!(
        bounded.peak_blocks() * 3 < total,
        "peak {} of {total} blocks",
        bounded.peak_blocks()
    );
    // Level, not growing: the last third of the walk holds no more than the middle third.
    let third = resident.len() / 3;
    let max = |r: &[usize]| *r.iter().max().unwrap();
    let (middle, last) = (
        max(&resident[third..2 * third]),
        max(&resident[2 * third..]),
    );
    assert!(
        last * 10 <= middle * 12,
        "resident blocks grow: {middle} in the middle third, {last} in the last"
    );
}

/// An archive in memory: what a map store keeps, without the file.
#[derive(Debug, Default)]
struct Shelf(KeyMap<Block>);

impl BlockArchive for Shelf {
    fn keys(&self) -> Result<Vec<IVec3>> {
        Ok(self.0.keys().copied().collect())
    }

    fn put(&mut self, blocks: Vec<(Block, u32)>) -> Result<()> {
        self.0.extend(blocks.into_iter().map(|(b, _)| (b.key, b)));
        Ok(())
    }

    fn get(&self, keys: &[IVec3]) -> Result<Vec<Block>> {
        Ok(keys.iter().map(|k| self.0[k].clone()).collect())
    }
}

#[test]
fn a_walk_that_comes_back_continues_the_blocks_it_left_in_the_archive() {
    let scene = corridor();
    let k = Intrinsics::from_vertical_fov(160, 120, 60.0);
    let mut sensor = SimulatedSensor::new(k, 0.8, 4.0, NoiseModel::None, 0).unwrap();
    // 20 m along +x looking ahead, then back along −x looking the other way.
    let poses: Vec<Pose> = (0..160)
        .map(|i| {
            let (x, ahead) = if i < 80 {
                (0.5 + 0.25 * i as f32, 0.7)
            } else {
                (0.5 + 0.25 * (159 - i) as f32, -0.7)
            };
            let eye = Vec3::new(x, 1.3, -0.5);
            Pose::look_at(eye, eye + Vec3::new(ahead, -0.5, 1.0), Vec3::Y)
        })
        .collect();
    let config = TsdfConfig::new(0.05);
    let mut unbounded = TsdfMapper::new(config, k, 0.8, 4.0).unwrap();
    let mut archived = TsdfMapper::new(config, k, 0.8, 4.0).unwrap();
    let mut chunked = TsdfMapper::new(config, k, 0.8, 4.0).unwrap();
    let radius = archived.reach() + 0.05;
    archived.set_active_radius(radius).unwrap();
    archived.set_archive(Box::new(Shelf::default())).unwrap();
    chunked.set_active_radius(radius).unwrap();
    let mut chunks = Vec::new();
    for (i, pose) in poses.iter().enumerate() {
        let frame = sensor.capture(&scene, i as u32 + 1, pose);
        unbounded.integrate(&frame, pose).unwrap();
        archived.integrate(&frame, pose).unwrap();
        chunked.integrate(&frame, pose).unwrap();
        chunks.push(chunked.take_evicted());
    }
    let whole = triangle_set(&[unbounded.mesh().clone()]);
    let mut pieces = Vec::new();
    archived
        .mesh_all(|m| {
            pieces.push(m);
            Ok(())
        })
        .unwrap();
    assert!(pieces.len() > 1, "meshed in one piece");
    assert!(whole.len() > 20_000, "{} triangles", whole.len());
    assert!(
        archived.loaded_blocks().unwrap() > 100,
        "{:?} blocks brought back",
        archived.loaded_blocks()
    );
    assert!(
        archived.peak_blocks() * 3 < unbounded.volume().blocks().len() * 2,
        "peak {} of {} blocks",
        archived.peak_blocks(),
        unbounded.volume().blocks().len()
    );
    assert!(
        triangle_set(&pieces) == whole,
        "the archived map differs from the unbounded one"
    );
    // A viewer who joins now is sent every part, archived ones included,
    // and they hold the same triangles.
    let parts = archived.follow_parts();
    let meshes: Vec<Mesh> = archived.part_meshes(&parts).into_iter().flatten().collect();
    assert_eq!(meshes.len(), parts.len(), "a part could not be meshed");
    assert!(
        triangle_set(&meshes) == whole,
        "the viewer's parts differ from the unbounded map"
    );
    // Without the archive the region walked back through starts empty:
    // its chunks hold other triangles.
    chunks.push(chunked.mesh().clone());
    assert!(triangle_set(&chunks) != whole);
}
