//! TSDF fusion of a simulated, noisy scan of the table scene.

use depthmesh::eval::fraction_within;
use depthmesh::map::Mapper;
use depthmesh::sim::{NoiseModel, PathSpec, Scene, SceneOptions, SimulatedSensor};
use depthmesh::tsdf::mapper::TsdfMapper;
use depthmesh::tsdf::TsdfConfig;
use depthmesh::Intrinsics;

#[test]
fn noisy_table_scan_is_within_a_centimetre() {
    let text = include_str!("../../../scenes/table.toml");
    let scene = Scene::parse(text, "table.toml".as_ref(), &SceneOptions::default()).unwrap();
    let k = Intrinsics::from_vertical_fov(320, 240, 60.0);
    let mut sensor = SimulatedSensor::new(k, 0.8, 4.0, NoiseModel::Kinect, 3).unwrap();
    let mut mapper = TsdfMapper::new(TsdfConfig::new(0.01), k, 0.8, 4.0).unwrap();
    let poses = PathSpec::Helix.build(&scene, 20).unwrap();
    for (i, pose) in poses.iter().enumerate() {
        let frame = sensor.capture(&scene, i as u32 + 1, pose);
        mapper.integrate(&frame, pose).unwrap();
    }
    let truth = scene.world_mesh(20).0;
    let within = fraction_within(mapper.mesh(), &truth, 0.01, 0.01).unwrap();
    // Measured 99.2 % at this resolution (99.7 % at 640×480 in the README):
    // the bound lets the share beyond 1 cm grow by half, and no more.
    assert!(
        within >= 0.988,
        "{:.1}% of the mesh within 1 cm",
        within * 100.0
    );
    // Measured 89.8 % within 5 mm (94.9 % at 640×480): a surface fused 4 mm
    // off (86.9 %) fails the bound of 88.5 %.
    let within_5mm = fraction_within(mapper.mesh(), &truth, 0.005, 0.01).unwrap();
    assert!(
        within_5mm >= 0.885,
        "{:.1}% of the mesh within 5 mm",
        within_5mm * 100.0
    );
}
