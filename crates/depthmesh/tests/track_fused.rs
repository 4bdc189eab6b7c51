//! Tracking against a map fused from the simulated Kinect, as `simulate
//! --map tsdf --track` does: the cases where the map's own view, not a
//! perfect one, decides.

use depthmesh::camera::Pose;
use depthmesh::map::Mapper;
use depthmesh::sim::{NoiseModel, PathSpec, Scene, SceneOptions, SimulatedSensor};
use depthmesh::track::tracker::{Tracker, TrackerConfig, TrackerState};
use depthmesh::tsdf::mapper::TsdfMapper;
use depthmesh::tsdf::TsdfConfig;

/// The Kinect with noise `seed`, a TSDF of `voxel` metres that has fused
/// its first frame of `scene` (iteration 1) seen from `start`, and a
/// tracker started there, as `simulate --map tsdf --track` starts.
fn started(
    scene: &Scene,
    start: &Pose,
    seed: u64,
    voxel: f32,
) -> (SimulatedSensor, TsdfMapper, Tracker) {
    let mut sensor = SimulatedSensor::kinect(NoiseModel::Kinect, seed);
    let k = sensor.intrinsics;
    let mut map = TsdfMapper::new(TsdfConfig::new(voxel), k, 0.8, 4.0).unwrap();
    map.integrate(&sensor.capture(scene, 1, start), start)
        .unwrap();
    let tracker = Tracker::new(TrackerConfig::default(), k, *start).unwrap();
    (sensor, map, tracker)
}

/// The table scene's first frame (16 cm and 3.6° from the start, no
/// measured motion) tracked against the map of the start's frame, for
/// every one of `seeds`; the worst position error (metres).
fn first_frame_error(seeds: std::ops::Range<u64>) -> f32 {
    let text = include_str!("../../../scenes/table.toml");
    let scene = Scene::parse(text, "table.toml".as_ref(), &SceneOptions::default()).unwrap();
    let poses = PathSpec::Helix.build(&scene, 200).unwrap();
    seeds
        .map(|seed| {
            let (mut sensor, map, mut tracker) = started(&scene, &poses[0], seed, 0.01);
            let t = tracker.track(&sensor.capture(&scene, 2, &poses[1]).depth, &map);
            assert_eq!(t.lost, None, "seed {seed}");
            poses[1].inverse().compose(&t.pose).translation.length()
        })
        .fold(0.0, f32::max)
}

#[test]
fn the_table_scenes_first_frame_is_found_against_its_fused_map() {
    // What pins the first motion along the view (the legs and the table
    // top's ends, seen nearly edge-on) is a few pixels wide in a coarser
    // model view: there the frame landed 3.3 and 4.3 cm off on seeds 0 and
    // 5, and the whole run's ATE was 4.0 and 8.4 cm. Measured within 1.5 mm.
    let worst = first_frame_error(0..6);
    assert!(worst < 0.005, "worst {:.1} mm", worst * 1e3);
}

/// A desk on two side panels beside a stool, on a floor.
const DESK: &str = r#"
name = "desk"
[helix]
height = [0.9, 1.4]
look_at = [[0.1, 0.45, 0.0], [0.1, 0.65, 0.0]]
margin = 3.0
turns = 2.0
[[object]]
name = "floor"
shape = "box"
size = [10.0, 0.1, 10.0]
translation = [0.0, 0.05, 0.0]
floor = true
[[object]]
name = "desk top"
shape = "box"
size = [1.4, 0.05, 0.6]
translation = [0.2, 0.75, -0.1]
[[object]]
name = "side panel a"
shape = "box"
size = [0.04, 0.65, 0.6]
translation = [-0.48, 0.425, -0.1]
[[object]]
name = "side panel b"
shape = "box"
size = [0.04, 0.65, 0.6]
translation = [0.88, 0.425, -0.1]
[[object]]
name = "stool"
shape = "cylinder"
radius = 0.18
height = 0.45
translation = [0.3, 0.325, 0.5]
"#;

#[test]
fn a_desk_seen_end_on_is_followed_without_sliding_along_the_view() {
    // Frames 68-75 of the 200-frame helix look at the desk end-on, across
    // a side panel. The model view's coarsest level (40×30) keeps normals
    // on little but the floor; ICP started there slid along the view (from
    // a map fused from the true poses up to frame 67 and a motion measured
    // from them: 1.5 cm off at frame 70, 8 cm at 71, 60 cm by frame 75).
    let scene = Scene::parse(DESK, "desk.toml".as_ref(), &SceneOptions::default()).unwrap();
    let poses = PathSpec::Helix.build(&scene, 200).unwrap();
    let mut sensor = SimulatedSensor::kinect(NoiseModel::Kinect, 4);
    let k = sensor.intrinsics;
    let mut map = TsdfMapper::new(TsdfConfig::new(0.01), k, 0.8, 4.0).unwrap();
    let frame =
        |sensor: &mut SimulatedSensor, i: usize| sensor.capture(&scene, i as u32 + 1, &poses[i]);
    for (i, pose) in poses.iter().enumerate().take(66) {
        map.integrate(&frame(&mut sensor, i), pose).unwrap();
    }
    let state = TrackerState::moving(poses[66], poses[65].inverse().compose(&poses[66]));
    map.integrate(&frame(&mut sensor, 66), &poses[66]).unwrap();
    let mut tracker = Tracker::restore(TrackerConfig::default(), k, state).unwrap();
    for (i, pose) in poses.iter().enumerate().take(75).skip(67) {
        let f = frame(&mut sensor, i);
        let t = tracker.track(&f.depth, &map);
        assert_eq!(t.lost, None, "frame {}", i + 1);
        let error = pose.inverse().compose(&t.pose).translation.length();
        // Measured at most 9.1 mm.
        assert!(error < 0.015, "frame {}: {:.1} mm off", i + 1, error * 1e3);
        map.integrate(&f, &t.pose).unwrap();
    }
}

/// The room scene's camera circling the furniture 2° a frame, then
/// stopping and turning on the spot towards a wall ever faster (7.0°,
/// 9.3°, 12.3° and 15.6° over its last four frames), tracked against the
/// map it fuses, as `simulate --map tsdf --voxel 0.02 --track`
/// does; per tracked frame, whether it was lost and how far it is off
/// (metres).
fn speeding_turn(seed: u64) -> Vec<(bool, f32)> {
    use glam::Vec3;
    let text = include_str!("../../../scenes/room.toml");
    let scene = Scene::parse(text, "room.toml".as_ref(), &SceneOptions::default()).unwrap();
    let around = |degrees: f32| {
        let a = degrees.to_radians();
        Vec3::new(2.0 * a.cos(), 1.3, 2.0 * a.sin())
    };
    let (centre, up) = (Vec3::new(0.0, 0.4, 0.0), Vec3::Y);
    let mut poses: Vec<Pose> = (0..13)
        .map(|i| Pose::look_at(around(2.0 * i as f32), centre, up))
        .collect();
    let eye = around(24.0);
    let wall = Vec3::new(eye.x, 0.9, 3.0);
    poses.extend((1..5).map(|k| Pose::look_at(eye, centre.lerp(wall, k as f32 / 10.0), up)));
    let (mut sensor, mut map, mut tracker) = started(&scene, &poses[0], seed, 0.02);
    let mut result = Vec::new();
    for (i, pose) in poses.iter().enumerate().skip(1) {
        let f = sensor.capture(&scene, i as u32 + 1, pose);
        let t = tracker.track(&f.depth, &map);
        result.push((
            t.lost.is_some(),
            pose.inverse().compose(&t.pose).translation.length(),
        ));
        if t.lost.is_none() {
            map.integrate(&f, &t.pose).unwrap();
        }
    }
    result
}

/// No frame of `frames` (whether lost, how far off in metres; the first
/// is frame 2) is lost or further off than `within`.
fn assert_none_lost_within(seed: u64, frames: impl IntoIterator<Item = (bool, f32)>, within: f32) {
    for (frame, (lost, error)) in frames.into_iter().enumerate() {
        assert!(!lost, "seed {seed}, frame {} lost", frame + 2);
        assert!(
            error < within,
            "seed {seed}, frame {}: {:.1} mm off",
            frame + 2,
            error * 1e3
        );
    }
}

#[test]
fn a_turn_that_speeds_up_is_followed_without_sliding() {
    // A turn faster than the last one starts ICP centimetres off. With only
    // the scheduled iterations (3 at half resolution, 1 at full) one of the
    // last two frames was left 9.6–10.6 cm off, where the floor and a side
    // wall fit it, on every seed 0–5 (on three, the last frame then 29–30
    // cm), nothing reported lost. Going on until the update settles: at
    // most 2 mm off on those seeds.
    for seed in 0..3 {
        assert_none_lost_within(seed, speeding_turn(seed), 0.01);
    }
}

/// The room scene with a person (a box 0.4 × 1.7 × 0.3 m) walking 10 cm
/// a frame across the view of a camera circling the furniture 2° a
/// frame, 1 m in front of it, from 1.5 m to one side of the view's
/// middle at the first frame to 1.5 m to the other at the 31st; per
/// tracked frame, whether it was lost (held frames are not), whether it
/// was held, and how far it is off (metres), and the share of pixels the
/// person hides at the frame they do most.
fn walked_through(seed: u64) -> (Vec<(bool, bool, f32)>, f32) {
    use glam::Vec3;
    let around = |degrees: f32| {
        let a = degrees.to_radians();
        Vec3::new(2.0 * a.cos(), 1.3, 2.0 * a.sin())
    };
    let centre = Vec3::new(0.0, 0.4, 0.0);
    let poses: Vec<Pose> = (0..36)
        .map(|i| Pose::look_at(around(2.0 * i as f32), centre, Vec3::Y))
        .collect();
    // Across the view of frame 16 (the middle of the walk), 1 m ahead.
    let eye = around(32.0);
    let ahead = (centre - eye).with_y(0.0).normalize();
    let across = ahead.cross(Vec3::Y);
    let middle = (eye + ahead).with_y(0.85);
    let start = middle - 1.5 * across;
    let room = include_str!("../../../scenes/room.toml");
    let person = format!(
        "[[object]]\nname = \"person\"\nshape = \"box\"\nsize = [0.4, 1.7, 0.3]\n\
         translation = [{}, {}, {}]\nfloor = true\n\
         motion = {{ by = [{}, 0.0, {}], from = 1, until = 31 }}\n",
        start.x,
        start.y,
        start.z,
        3.0 * across.x,
        3.0 * across.z
    );
    let options = SceneOptions::default();
    let empty = Scene::parse(room, "room.toml".as_ref(), &options).unwrap();
    let scene = Scene::parse(&format!("{room}\n{person}"), "walk.toml".as_ref(), &options).unwrap();
    let mut clear = SimulatedSensor::kinect(NoiseModel::None, 0);
    let (mut sensor, mut map, mut tracker) = started(&scene, &poses[0], seed, 0.01);
    let (mut result, mut hidden) = (Vec::new(), 0.0f32);
    for (i, pose) in poses.iter().enumerate().skip(1) {
        let iteration = i as u32 + 1;
        let f = sensor.capture(&scene, iteration, pose);
        let with = clear.capture(&scene, iteration, pose).depth;
        let without = clear.capture(&empty, iteration, pose).depth;
        let changed = with
            .data
            .iter()
            .zip(&without.data)
            .filter(|(a, b)| (*a - *b).abs() > 0.05);
        hidden = hidden.max(changed.count() as f32 / with.data.len() as f32);
        let t = tracker.track(&f.depth, &map);
        let off = pose.inverse().compose(&t.pose);
        result.push((
            t.lost.is_some() && !t.held,
            t.held,
            off.translation.length(),
        ));
        if t.lost.is_none() {
            map.integrate(&f, &t.pose).unwrap();
        }
    }
    (result, hidden)
}

#[test]
fn a_person_walking_through_the_view_does_not_lose_the_camera() {
    // The person stands where the map saw empty space, so the frames are
    // held (followed on, not fused), and they hide the map's surface:
    // that counted against the frame, which was lost at the 16th (69 % of
    // its points on the map's surface matching it) and not found again
    // for twelve frames, until the person had gone. Frames 6-27 are held
    // within 1.5 mm on both seeds; frame 29, the person gone, lands 1.4 cm
    // off (frames fused while the person was under the bar of points in
    // space seen empty put their edge in the map).
    for seed in 0..2 {
        let (frames, hidden) = walked_through(seed);
        assert!(
            hidden > 0.2,
            "the person hides only {:.0} % of the view",
            hidden * 100.0
        );
        let held = frames.iter().filter(|f| f.1).count();
        assert!(held >= 20, "seed {seed}: {held} frames held");
        let frames = frames.into_iter().map(|(lost, _, error)| (lost, error));
        assert_none_lost_within(seed, frames, 0.02);
    }
}
