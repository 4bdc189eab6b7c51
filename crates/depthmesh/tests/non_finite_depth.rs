//! Depth that is not a number or infinite, handed to the library by a
//! caller that did not clean its images, counts as no measurement: every
//! back-end builds exactly the map it builds with those pixels set to 0.

use depthmesh::mabdi::{MabdiConfig, MabdiMapper};
use depthmesh::map::Mapper;
use depthmesh::planes::mapper::{PlanesConfig, PlanesMapper};
use depthmesh::sim::{NoiseModel, PathSpec, Scene, SceneOptions, SimulatedSensor};
use depthmesh::tsdf::mapper::TsdfMapper;
use depthmesh::tsdf::TsdfConfig;
use depthmesh::{Frame, Intrinsics, Mesh, Pose};

const NEAR: f32 = 0.8;
const FAR: f32 = 4.0;

/// Simulated frames of the table, each twice: with every 7th, 11th and
/// 13th pixel set to NaN, +∞ and −∞, and with those pixels set to 0.
fn frames(k: Intrinsics) -> Vec<(Frame, Frame, Pose)> {
    let text = include_str!("../../../scenes/table.toml");
    let scene = Scene::parse(text, "table.toml".as_ref(), &SceneOptions::default()).unwrap();
    let mut sensor = SimulatedSensor::new(k, NEAR, FAR, NoiseModel::Kinect, 2).unwrap();
    let poses = PathSpec::Helix.build(&scene, 4).unwrap();
    poses
        .iter()
        .enumerate()
        .map(|(i, pose)| {
            let mut bad = sensor.capture(&scene, i as u32 + 1, pose);
            let mut clean = bad.clone();
            for (p, (b, c)) in bad
                .depth
                .data
                .iter_mut()
                .zip(&mut clean.depth.data)
                .enumerate()
            {
                let odd = [(7, f32::NAN), (11, f32::INFINITY), (13, f32::NEG_INFINITY)]
                    .into_iter()
                    .find(|(every, _)| p % every == 0);
                if let Some((_, value)) = odd {
                    *b = value;
                    *c = 0.0;
                }
            }
            (bad, clean, *pose)
        })
        .collect()
}

/// The mesh `mapper` builds from the frames with bad pixels, or the clean ones.
fn map(mut mapper: impl Mapper, frames: &[(Frame, Frame, Pose)], bad: bool) -> Mesh {
    for (with_bad, clean, pose) in frames {
        mapper
            .integrate(if bad { with_bad } else { clean }, pose)
            .unwrap();
    }
    mapper.mesh().clone()
}

/// Builds a mapper twice and checks both maps are the same and not empty.
fn same_map<M: Mapper>(name: &str, make: impl Fn() -> M) {
    let frames = frames(camera());
    let with_bad = map(make(), &frames, true);
    let clean = map(make(), &frames, false);
    assert!(clean.triangle_count() > 100, "{name}: empty map");
    assert!(
        with_bad.triangle_count() == clean.triangle_count() && with_bad == clean,
        "{name}: {} triangles from frames with NaN and infinities, {} without",
        with_bad.triangle_count(),
        clean.triangle_count()
    );
}

/// The simulated camera: small, so the tests take a fraction of a second.
fn camera() -> Intrinsics {
    Intrinsics::from_vertical_fov(160, 120, 60.0)
}

#[test]
fn tsdf_fusion_ignores_non_finite_depth() {
    same_map("tsdf", || {
        TsdfMapper::new(TsdfConfig::new(0.02), camera(), NEAR, FAR).unwrap()
    });
}

#[test]
fn voxel_planes_ignore_non_finite_depth() {
    same_map("planes", || {
        PlanesMapper::new(PlanesConfig::default(), camera()).unwrap()
    });
}

#[test]
fn mabdi_ignores_non_finite_depth() {
    same_map("mabdi", || {
        MabdiMapper::new(MabdiConfig::thesis(camera(), NEAR, FAR)).unwrap()
    });
}
