//! Bounded memory: a long walk down a simulated corridor with a small active
//! radius writes out chunks whose union is the unbounded map's mesh, while
//! the blocks held in memory stay level.

use depthmesh::map::Mapper;
use depthmesh::sim::{NoiseModel, Scene, SceneOptions, SimulatedSensor};
use depthmesh::tsdf::mapper::TsdfMapper;
use depthmesh::tsdf::TsdfConfig;
use depthmesh::{Intrinsics, Mesh, Pose};
use glam::Vec3;

/// A floor, a wall on the +z side and boxes and posts along it, `length` m long.
fn corridor(length: f32) -> Scene {
    let mut text = format!(
        "[[object]]\nshape = \"plane\"\nsize = [{l}, 6.0]\ntranslation = [{h}, 0.0, 0.0]\nfloor = true\n\
         [[object]]\nshape = \"box\"\nsize = [{l}, 3.0, 0.1]\ntranslation = [{h}, 1.5, 2.0]\n",
        l = length,
        h = 0.5 * length
    );
    for i in 0..(length / 3.0) as usize {
        let x = 1.5 + 3.0 * i as f32;
        text.push_str(&format!(
            "[[object]]\nshape = \"box\"\nsize = [0.6, 0.5, 0.4]\ntranslation = [{x}, 0.25, 1.5]\nrotation = [0.0, {a}, 0.0]\n\
             [[object]]\nshape = \"cylinder\"\nradius = 0.1\nheight = 1.2\ntranslation = [{p}, 0.6, 1.2]\n",
            a = 17.0 * i as f32,
            p = x + 1.2
        ));
    }
    Scene::parse(&text, "corridor.toml".as_ref(), &SceneOptions::default()).unwrap()
}

/// Each triangle as its corners' (position, normal) bits, starting at the
/// smallest corner (winding kept), sorted: the mesh up to vertex and
/// triangle order.
fn triangle_set(meshes: &[Mesh]) -> Vec<[[u32; 6]; 3]> {
    let mut set = Vec::new();
    for m in meshes {
        for t in &m.triangles {
            let corner = |i: u32| {
                let (p, n) = (m.positions[i as usize], m.normals[i as usize]);
                [p.x, p.y, p.z, n.x, n.y, n.z].map(f32::to_bits)
            };
            let mut c = t.map(corner);
            let first = (0..3).min_by_key(|&i| c[i]).unwrap();
            c.rotate_left(first);
            set.push(c);
        }
    }
    set.sort_unstable();
    set
}

#[test]
fn chunks_of_a_long_walk_equal_the_unbounded_map_in_bounded_memory() {
    let length = 36.0;
    let scene = corridor(length);
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
