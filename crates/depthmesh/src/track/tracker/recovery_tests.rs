//! Tracking that does not give up: weak views, jumps, views the map cannot
//! explain (issue "tracking that does not give up").

use super::tests::{pose_error as error, scene, SceneMap, ROOM};
use super::*;
use crate::sim::{NoiseModel, PathSpec, Scene, SimulatedSensor};
use glam::Vec3;

const TABLE: &str = include_str!("../../../../../scenes/table.toml");
/// One floor and one small box: everything horizontal rests on the box.
const PLANE_AND_BOX: &str = include_str!("../../../../../scenes/plane_and_box.toml");

/// Tracks the first `count` poses of the scene's 200-pose helix (the
/// judged runs' speed: 10–16 cm a frame) with Kinect noise; the worst
/// position error.
fn track_helix(text: &str, count: usize) -> f32 {
    let scene = scene(text);
    let poses = PathSpec::Helix.build(&scene, 200).unwrap();
    // The simulator's Kinect: at lower resolutions thin structures (a
    // table top's edge) lose their normals.
    let mut sensor = SimulatedSensor::kinect(NoiseModel::Kinect, 7);
    let k = sensor.intrinsics;
    let mut tracker = Tracker::new(TrackerConfig::default(), k, poses[0]).unwrap();
    let map = SceneMap::new(&scene, 0);
    let mut worst = 0.0f32;
    for (i, pose) in poses.iter().enumerate().take(count).skip(1) {
        let t = tracker.track(&sensor.capture(&scene, i as u32, pose).depth, &map);
        assert_eq!(t.lost, None, "frame {i}");
        worst = worst.max(error(&t.pose, pose).0);
    }
    worst
}

// The judged runs allow 1 cm of ATE with a fused map; against a perfect
// map the worst frame must stay within that (no margin needed: a weak
// view left to noise drifts by decimetres, see the table's history).
#[test]
fn the_table_scene_is_tracked_with_kinect_noise() {
    let worst = track_helix(TABLE, 25);
    assert!(worst < 0.01, "worst {:.1} mm", worst * 1e3);
}

// The box constrains the orbit weakly (conditioning 1e-5 to 2e-5): with
// those directions left to the motion model alone it drifted 17 cm in
// 25 frames; weighed against it, within a centimetre.
#[test]
fn a_plane_with_one_small_object_is_tracked_with_kinect_noise() {
    let worst = track_helix(PLANE_AND_BOX, 25);
    assert!(worst < 0.01, "worst {:.1} mm", worst * 1e3);
}

/// The first 10 m of a corridor along +x: a floor, a wall on the +z
/// side, and two bays of a box and a post, the boxes turned apart (in
/// `scenes/corridor.toml`, 40 m of bays that differ only in how each
/// box is turned, global registration alone can find a frame in the
/// wrong bay; see the README).
const CORRIDOR: &str = r#"
[[object]]
shape = "plane"
size = [14.0, 8.0]
translation = [5.0, 0.0, 0.0]
floor = true
[[object]]
shape = "box"
size = [14.0, 3.0, 0.1]
translation = [5.0, 1.5, 2.0]
[[object]]
shape = "box"
size = [0.6, 0.5, 0.4]
translation = [1.5, 0.25, 1.5]
[[object]]
shape = "cylinder"
radius = 0.1
height = 1.2
translation = [2.7, 0.6, 1.2]
[[object]]
shape = "box"
size = [0.6, 0.5, 0.4]
translation = [4.5, 0.25, 1.5]
rotation = [0.0, 17.0, 0.0]
[[object]]
shape = "cylinder"
radius = 0.1
height = 1.2
translation = [5.7, 0.6, 1.2]
"#;

/// Walking down the corridor at 10 cm a frame, `x` metres along,
/// looking ahead at the wall (turned 35° about the vertical towards +x)
/// or, with `back` the tangent of the turn, back along it.
fn in_corridor(x: f32, back: Option<f32>) -> Pose {
    let eye = Vec3::new(x, 1.3, -0.5);
    let look = Vec3::new(back.map_or(0.7, |b| -b), -0.5, 1.0);
    Pose::look_at(eye, eye + look, Vec3::Y)
}

/// Walks 3 m down `corridor` (tracked, none lost), turns about in one
/// frame to look back at `back` (see [`in_corridor`]) and walks 1 m
/// back: the turn frame's result, then each later frame's with its
/// true pose.
fn turn_about(corridor: &str, back: f32) -> (Tracked, Pose, Vec<(Tracked, Pose)>) {
    let corridor = scene(corridor);
    let k = Intrinsics::from_vertical_fov(320, 240, 60.0);
    let mut sensor = SimulatedSensor::new(k, 0.4, 6.0, NoiseModel::Kinect, 3).unwrap();
    let out: Vec<Pose> = (0..30).map(|i| in_corridor(0.1 * i as f32, None)).collect();
    let back: Vec<Pose> = (0..10)
        .map(|i| in_corridor(2.9 - 0.1 * i as f32, Some(back)))
        .collect();
    let map = SceneMap::new(&corridor, 0);
    let mut tracker = Tracker::new(TrackerConfig::default(), k, out[0]).unwrap();
    for (i, pose) in out.iter().enumerate().skip(1) {
        let t = tracker.track(&sensor.capture(&corridor, i as u32, pose).depth, &map);
        assert_eq!(t.lost, None, "frame {i}");
    }
    let mut frames = back.iter().enumerate().map(|(i, pose)| {
        let t = tracker.track(&sensor.capture(&corridor, 30 + i as u32, pose).depth, &map);
        (t, *pose)
    });
    let (turned, at) = frames.next().unwrap();
    (turned, at, frames.collect())
}

// A camera that turns about in one frame (70°, walking back the way it
// came) while the motion model carries it on. On the 20 m walk of
// `bench/track_corridor.sh`, through the pipeline, ICP from the
// prediction settled where the floor and a third of the frame fit (32 %
// of the points matched, above the 25 % bar) and the frames after it
// followed that pose, 4.7 m off by the end, none reported lost; here,
// against the scene itself, the turn was accepted 7 cm and 69° off.
// Where the map has seen surface the frame sees something else (there
// 44 % of those points matched, 92 % or more on every frame tracked
// well): following loses such a pose, never fuses it, and the search
// for the lost camera finds it where it is, or leaves it lost.
#[test]
fn a_camera_that_turns_about_in_one_frame_is_never_followed_to_a_wrong_pose() {
    let (turned, at, back) = turn_about(CORRIDOR, 0.7);
    let (dt, dr) = error(&turned.pose, &at);
    assert!(
        matches!(
            (turned.lost, turned.recovered_from),
            (Some(LostReason::Contradicted(_)), _) | (None, Some(LostReason::Contradicted(_)))
        ),
        "{:?} {:?} at {dt} m, {dr}° of the truth",
        turned.lost,
        turned.recovered_from
    );
    if turned.lost.is_none() {
        assert!(dt < 0.02 && dr < 1.0, "the turn found at {dt} m, {dr}°");
    }
    for (i, (t, pose)) in back.iter().enumerate() {
        if t.lost.is_none() {
            let (dt, dr) = error(&t.pose, pose);
            assert!(dt < 0.02 && dr < 1.0, "frame {i} back: {dt} m, {dr}°");
        }
    }
}

// After such a turn, global registration alone finds the camera
// wherever the map looks alike: on that 20 m walk, in a bay 6 m off;
// here, where both bays look the same, it stayed lost for six frames
// and was then accepted 20 cm off along the corridor. The turn (74°)
// lies between the multiples of [`TURN_STEP_DEGREES`]: the frame
// following loses is found turned on the spot, where it is, and so is
// every frame after it.
#[test]
fn a_camera_that_turns_about_is_found_turned_not_in_a_place_alike() {
    let alike = CORRIDOR.replace("rotation = [0.0, 17.0, 0.0]\n", "");
    let (turned, at, back) = turn_about(&alike, 0.8);
    assert_eq!(turned.lost, None);
    assert!(turned.recovered_from.is_some());
    let (dt, dr) = error(&turned.pose, &at);
    assert!(dt < 0.02 && dr < 1.0, "the turn: {dt} m, {dr}°");
    for (i, (t, pose)) in back.iter().enumerate() {
        assert_eq!(t.lost, None, "frame {i} back");
        let (dt, dr) = error(&t.pose, pose);
        assert!(dt < 0.02 && dr < 1.0, "frame {i} back: {dt} m, {dr}°");
    }
}

/// The camera turns about in the corridor with bays alike, tracked
/// against a map fused from the poses found, not the scene itself:
/// looking back, the walls and floor explain the frame wherever it lies
/// along the corridor, and only the bays' edges that face the camera
/// say where. Every pose accepted after the turn is the camera's, and
/// the last frame of the walk back is tracked where the camera is.
/// Before the search's poses had to be pinned by the points facing
/// their weakest direction, four of these six runs took one 16–18 cm
/// off along the corridor, and fused the frames after it there; before
/// the frame after the camera was found started from the walk across
/// the loss, two more stayed where the camera was found while it walked
/// on 10 cm a frame, and ended 9 and 30 cm off.
#[test]
fn a_camera_turned_about_in_a_fused_map_is_not_found_off_along_the_corridor() {
    use crate::map::Mapper;
    use crate::tsdf::{mapper::TsdfMapper, TsdfConfig};
    let alike = scene(&CORRIDOR.replace("rotation = [0.0, 17.0, 0.0]\n", ""));
    let k = Intrinsics::from_vertical_fov(320, 240, 60.0);
    let out: Vec<Pose> = (0..30).map(|i| in_corridor(0.1 * i as f32, None)).collect();
    for back in [0.8, 1.0] {
        let backs = (0..10).map(|i| in_corridor(2.9 - 0.1 * i as f32, Some(back)));
        for seed in 0..3 {
            let mut sensor = SimulatedSensor::new(k, 0.4, 6.0, NoiseModel::Kinect, seed).unwrap();
            let mut map = TsdfMapper::new(TsdfConfig::new(0.02), k, 0.4, 6.0).unwrap();
            let mut tracker = Tracker::new(TrackerConfig::default(), k, out[0]).unwrap();
            map.integrate(&sensor.capture(&alike, 0, &out[0]), &out[0])
                .unwrap();
            let mut last = None;
            for (i, pose) in out.iter().copied().chain(backs.clone()).enumerate().skip(1) {
                let frame = sensor.capture(&alike, i as u32, &pose);
                let t = tracker.track(&frame.depth, &map);
                let run = format!("tangent {back}, seed {seed}, frame {i}");
                if i < out.len() {
                    assert_eq!(t.lost, None, "{run}");
                } else if t.lost.is_none() {
                    let (dt, dr) = error(&t.pose, &pose);
                    assert!(dt < 0.05 && dr < 5.0, "{run}: {dt} m, {dr}°");
                }
                if t.lost.is_none() {
                    map.integrate(&frame, &t.pose).unwrap();
                }
                last = Some((t, pose));
            }
            let (t, pose) = last.unwrap();
            let run = format!("tangent {back}, seed {seed}, last frame");
            assert_eq!(t.lost, None, "{run}");
            let (dt, dr) = error(&t.pose, &pose);
            assert!(dt < 0.02 && dr < 1.0, "{run}: {dt} m, {dr}°");
        }
    }
}

/// A camera on a circle around the room, `degrees` around.
fn around_room(degrees: f32) -> Pose {
    let a = degrees.to_radians();
    let eye = Vec3::new(2.0 * a.cos(), 1.3, 2.0 * a.sin());
    Pose::look_at(eye, Vec3::new(0.0, 0.4, 0.0), Vec3::Y)
}

/// Tracks the frames seen from `poses` in `scene` (the map), all of
/// them; the camera then jumps 0.5–1 m to `next`.
fn track_before_jump(
    sensor: &mut SimulatedSensor,
    scene: &Scene,
    poses: &[Pose],
    next: Pose,
) -> Tracker {
    let last = poses[poses.len() - 1];
    let jump = last.translation.distance(next.translation);
    assert!((0.5..=1.0).contains(&jump), "{jump}");
    let map = SceneMap::new(scene, 0);
    let mut tracker = Tracker::new(TrackerConfig::default(), sensor.intrinsics, poses[0]).unwrap();
    for (i, pose) in poses.iter().enumerate().skip(1) {
        let t = tracker.track(&sensor.capture(scene, i as u32, pose).depth, &map);
        assert_eq!(t.lost, None, "frame {i}");
    }
    tracker
}

/// Tracks the frames seen from `poses` in `scene` (the map) after a
/// jump: how many are lost before the camera is found again. Once found
/// it must stay found, and whatever is accepted must be right (2 cm, 1°:
/// a few times the tracking error, far below a wrong basin).
fn frames_until_found(
    tracker: &mut Tracker,
    sensor: &mut SimulatedSensor,
    scene: &Scene,
    poses: &[Pose],
) -> usize {
    let map = SceneMap::new(scene, 0);
    let mut found_at = None;
    for (i, pose) in poses.iter().enumerate() {
        let t = tracker.track(&sensor.capture(scene, 100 + i as u32, pose).depth, &map);
        if t.lost.is_some() {
            assert!(found_at.is_none(), "lost again at {i}: {:?}", t.lost);
            continue;
        }
        let (dt, dr) = error(&t.pose, pose);
        assert!(dt < 0.02 && dr < 1.0, "frame {i}: {dt} m, {dr}°");
        found_at.get_or_insert(i);
    }
    found_at.expect("never found again")
}

#[test]
fn a_camera_that_jumps_is_found_again_within_ten_frames() {
    let room = scene(ROOM);
    let k = Intrinsics::from_vertical_fov(320, 240, 60.0);
    let mut sensor = SimulatedSensor::new(k, 0.4, 6.0, NoiseModel::Kinect, 3).unwrap();
    // 2° (7 cm) a frame out to 80°; the frames while the camera goes
    // back are dropped, and it is next seen at 60°, 0.69 m away, then
    // moving back the other way.
    let out: Vec<Pose> = (0..=40).map(|i| around_room(2.0 * i as f32)).collect();
    let back: Vec<Pose> = (0..12)
        .map(|i| around_room(60.0 - 2.0 * i as f32))
        .collect();
    let mut tracker = track_before_jump(&mut sensor, &room, &out, back[0]);
    assert!(tracker.keyframes() > 1);
    let found_at = frames_until_found(&mut tracker, &mut sensor, &room, &back);
    assert!(found_at < 10, "found after {found_at} frames");
}

// Frames the sensor drops while the camera moves on (a USB hiccup, a
// busy machine) leave a gap the motion model spans when told of it: the
// camera is followed across, not lost and searched for.
#[test]
fn a_camera_whose_frames_were_dropped_is_followed_across_the_gap() {
    let room = scene(ROOM);
    let k = Intrinsics::from_vertical_fov(320, 240, 60.0);
    let mut sensor = SimulatedSensor::new(k, 0.4, 6.0, NoiseModel::Kinect, 5).unwrap();
    // 2° (7 cm) a frame round the room; eight frames dropped after the
    // 30th (16°, 0.56 m), then on as before.
    let out: Vec<Pose> = (0..=30).map(|i| around_room(2.0 * i as f32)).collect();
    let on: Vec<Pose> = (39..50).map(|i| around_room(2.0 * i as f32)).collect();
    let mut tracker = track_before_jump(&mut sensor, &room, &out, on[0]);
    let map = SceneMap::new(&room, 0);
    for (i, pose) in on.iter().enumerate() {
        let steps = if i == 0 { 9 } else { 1 };
        let frame = sensor.capture(&room, 100 + i as u32, pose).depth;
        let t = tracker.track_after(&frame, steps, &map);
        assert_eq!(t.lost, None, "frame {i}");
        assert!(
            !t.relocalised && t.recovered_from.is_none(),
            "frame {i} was searched for"
        );
        let (dt, dr) = error(&t.pose, pose);
        assert!(dt < 0.01 && dr < 0.5, "frame {i}: {dt} m, {dr}°");
    }
}

// A sensor that drops every other frame while the camera speeds up: the
// motion measured across each two-interval frame is the velocity, split
// over the intervals, so the next frame is predicted where it is. Holding
// the velocity measured before the drops predicted each frame 7 cm short.
#[test]
fn a_camera_that_speeds_up_while_every_other_frame_is_dropped_is_predicted_at_its_speed() {
    let room = scene(ROOM);
    let k = Intrinsics::from_vertical_fov(320, 240, 60.0);
    let mut sensor = SimulatedSensor::new(k, 0.4, 6.0, NoiseModel::Kinect, 7).unwrap();
    let map = SceneMap::new(&room, 0);
    // 2° (7 cm) a frame interval round the room, then 3° (10.5 cm) with
    // every other frame dropped: 6° between the frames that arrive.
    let mut tracker = Tracker::new(TrackerConfig::default(), k, around_room(0.0)).unwrap();
    for i in 1..=20 {
        let pose = around_room(2.0 * i as f32);
        let t = tracker.track(&sensor.capture(&room, i, &pose).depth, &map);
        assert_eq!(t.lost, None, "frame {i}");
    }
    for j in 1..=8 {
        let pose = around_room(40.0 + 6.0 * j as f32);
        let t = tracker.track_after(&sensor.capture(&room, 20 + j, &pose).depth, 2, &map);
        assert_eq!(t.lost, None, "frame {j} after the drops began");
        let (dt, dr) = error(&t.pose, &pose);
        assert!(dt < 0.01 && dr < 0.5, "frame {j}: {dt} m, {dr}°");
        // The first is predicted at the old speed; from the second on, at
        // the speed the first measured.
        if j >= 2 {
            assert!(
                t.deviation < 0.01,
                "frame {j}: {} m from the prediction",
                t.deviation
            );
        }
    }
}

// Without a measured motion ICP starts from no motion; a first frame
// beyond its reach is found by global registration against what the
// start saw, not lost or left where ICP stopped.
#[test]
fn a_first_frame_far_from_the_start_is_found_by_global_registration() {
    let room = scene(ROOM);
    let k = Intrinsics::from_vertical_fov(320, 240, 60.0);
    let mut sensor = SimulatedSensor::new(k, 0.4, 6.0, NoiseModel::Kinect, 3).unwrap();
    let (start, first) = (around_room(0.0), around_room(12.0));
    let mut tracker = Tracker::new(TrackerConfig::default(), k, start).unwrap();
    let t = tracker.track(
        &sensor.capture(&room, 1, &first).depth,
        &SceneMap::new(&room, 0),
    );
    assert_eq!(t.lost, None);
    assert!(!t.relocalised);
    let (dt, dr) = error(&t.pose, &first);
    assert!(dt < 0.01 && dr < 0.5, "{dt} m, {dr}°");
}

/// A camera `radius` from the room's centre at `height`, `degrees`
/// around, looking at `target`.
fn in_room(degrees: f32, radius: f32, height: f32, target: Vec3) -> Pose {
    let a = degrees.to_radians();
    let eye = Vec3::new(radius * a.cos(), height, radius * a.sin());
    Pose::look_at(eye, target, Vec3::Y)
}

#[test]
fn a_camera_that_jumps_away_from_every_keyframe_is_found_again_within_ten_frames() {
    let room = scene(ROOM);
    let k = Intrinsics::from_vertical_fov(320, 240, 60.0);
    let mut sensor = SimulatedSensor::new(k, 0.4, 6.0, NoiseModel::Kinect, 11).unwrap();
    // Around the room at 2 m and 1.3 m high, 2° (7 cm) a frame out to
    // 80°; then, the frames in between dropped, the camera is next seen
    // closer, higher and turned 40° towards the wall on its left, and
    // moves on sideways.
    let target = Vec3::new(0.0, 0.4, 0.0);
    let out: Vec<Pose> = (0..=40)
        .map(|i| in_room(2.0 * i as f32, 2.0, 1.3, target))
        .collect();
    let wall = Vec3::new(-2.5, 0.8, 0.0);
    let back: Vec<Pose> = (0..12)
        .map(|i| {
            let eye = Vec3::new(0.6 + 0.03 * i as f32, 1.6, 1.4 - 0.05 * i as f32);
            Pose::look_at(eye, wall, Vec3::Y)
        })
        .collect();
    let mut tracker = track_before_jump(&mut sensor, &room, &out, back[0]);
    // No keyframe is within ICP's reach of where the camera reappears:
    // finding it takes more than ICP from the keyframes.
    for (i, pose) in back.iter().enumerate() {
        for key in &tracker.state().keyframe_poses {
            let (dt, dr) = error(key, pose);
            assert!(
                dt > 0.3 || dr > 20.0,
                "frame {i} near a keyframe: {dt} m {dr}°"
            );
        }
    }
    let found_at = frames_until_found(&mut tracker, &mut sensor, &room, &back);
    assert!(found_at < 10, "found after {found_at} frames");
}

/// A Kinect-noise sensor (noise seed `seed`) and a tracker that has
/// learnt keyframes of `scene` all around it, every 10°.
fn keyframes_around(scene: &Scene, seed: u64) -> (SimulatedSensor, Tracker) {
    let k = Intrinsics::from_vertical_fov(320, 240, 60.0);
    let mut sensor = SimulatedSensor::new(k, 0.4, 6.0, NoiseModel::Kinect, seed).unwrap();
    let mut tracker = Tracker::new(TrackerConfig::default(), k, Pose::IDENTITY).unwrap();
    for i in 0..36 {
        let pose = around_room(10.0 * i as f32);
        tracker.learn_view(&sensor.capture(scene, i, &pose).depth, &pose);
    }
    (sensor, tracker)
}

#[test]
fn a_view_the_map_only_half_explains_is_found_at_its_pose() {
    // The map has seen the room but not the wall the camera, coming
    // back, faces: most of the frame falls where the map's view is
    // empty, and contradicts nothing there.
    let room = scene(ROOM);
    let mut mapped = scene(ROOM);
    mapped.objects.retain(|o| o.name != "wall -z");
    assert_eq!(mapped.objects.len() + 1, room.objects.len());
    let (mut sensor, mut tracker) = keyframes_around(&mapped, 7);
    let map = SceneMap::new(&mapped, 0);
    let pose = Pose::look_at(
        Vec3::new(-0.2, 1.3, 2.0),
        Vec3::new(0.0, 0.9, -3.0),
        Vec3::Y,
    );
    let t = tracker.relocalise(&sensor.capture(&room, 99, &pose).depth, &map);
    assert_eq!(t.lost, None);
    assert!(t.relocalised);
    // Less than half of the frame matches the map (the bar for the
    // whole frame once was a half); it is accepted because what falls
    // on the map's surface matches it (at least `verify_inlier_fraction`).
    assert!(t.inlier_fraction < 0.5, "{}", t.inlier_fraction);
    let (dt, dr) = error(&t.pose, &pose);
    assert!(dt < 0.02 && dr < 1.0, "{dt} m {dr}°");
}

#[test]
fn a_candidate_is_judged_from_where_icp_took_it_not_where_it_started() {
    // Two starts 6 cm and 3° either side of the camera: ICP carries
    // both to it, and the view they are scored by must be the map's
    // from there (see `Tracker::relocalise_from`).
    let room = scene(ROOM);
    let (mut sensor, mut tracker) = keyframes_around(&room, 3);
    let map = SceneMap::new(&room, 0);
    let pose = around_room(25.0);
    tracker.prepare(&sensor.capture(&room, 50, &pose).depth);
    let off = |x: f32, degrees: f32| {
        let q = glam::Quat::from_rotation_y(degrees.to_radians());
        pose.compose(&Pose::from_quat(q, Vec3::new(x, 0.0, 0.0)))
    };
    let starts = [off(0.06, 3.0), off(-0.06, -3.0)];
    let found = tracker.relocalise_from(&starts, &mut Vec::new(), false, &map);
    assert_eq!(found.lost, None);
    let (dt, dr) = error(&found.pose, &pose);
    assert!(dt < 0.01 && dr < 0.5, "{dt} m {dr}°");
    let judged_there = map.poses.borrow().iter().any(|p| {
        let (dt, dr) = error(p, &found.pose);
        dt < 1e-6 && dr < 1e-4
    });
    assert!(judged_there, "no view of the map from the pose found");
}

#[test]
fn a_view_from_outside_the_mapped_area_is_never_accepted() {
    let room = scene(ROOM);
    // Another place: boxes in the air, no floor, nothing like the room.
    let elsewhere = scene(
        r#"
[[object]]
shape = "box"
size = [0.6, 0.3, 0.4]
translation = [0.3, 0.9, 0.2]
[[object]]
shape = "box"
size = [0.2, 0.8, 0.2]
translation = [-0.5, 0.6, -0.3]
[[object]]
shape = "sphere"
radius = 0.3
translation = [0.0, 0.3, 0.6]
"#,
    );
    let (mut sensor, mut tracker) = keyframes_around(&room, 5);
    assert!(tracker.keyframes() > 3);
    // The map is the room; the frames show another place from the same
    // kind of poses.
    let map = SceneMap::new(&room, 0);
    for i in 0..12 {
        let pose = around_room(30.0 * i as f32);
        let t = tracker.relocalise(&sensor.capture(&elsewhere, 50 + i, &pose).depth, &map);
        assert!(t.lost.is_some(), "view {i} accepted at {:?}", t.pose);
    }
    // The room itself, from the same poses, is found.
    let pose = around_room(95.0);
    let t = tracker.relocalise(&sensor.capture(&room, 99, &pose).depth, &map);
    assert_eq!(t.lost, None);
    assert!(t.relocalised);
}
