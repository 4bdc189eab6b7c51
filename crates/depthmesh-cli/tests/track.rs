//! Command-line tests of camera tracking: `--track` on simulated sequences
//! and `eval trajectory`.

mod common;

use common::{assert_fails_with, depthmesh, eval_json, ok, scratch, summary};
use serde_json::Value;
use std::path::{Path, PathBuf};

#[test]
fn a_noisy_simulated_sequence_is_tracked_within_a_centimetre() {
    let dir = scratch("track-room");
    let out = dir.join("out");
    track_room_line(&out, 20, &[]);
    let s = summary(&out);
    assert_eq!(s["tracking"], true);
    assert_eq!(s["lost"], 0, "{s}");
    let ate = s["ate_rmse_cm"].as_f64().unwrap();
    // Measured 0.34 cm; the bound is a fifth above it (0.86–0.92 cm before
    // the weak-view work of the tracker).
    assert!(ate < 0.4, "ATE {ate} cm");
    let stats = std::fs::read_to_string(out.join("stats.csv")).unwrap();
    assert!(stats.lines().next().unwrap().ends_with(
        ",conditioning,lost,icp_iterations,weak_directions,weak_axes,relocalised,recovered,held"
    ));
    let e = eval_json(&out.join("trajectory.txt"), &out.join("groundtruth.txt"));
    assert_eq!(e["matched"], 20);
    // Drift: the worst frame is 0.48 cm off (measured; 0.45 before the
    // cheaper first frame); a bound a seventh above that fails a tracker
    // that drifts faster even while its RMSE stays within its bound.
    let worst = e["ate_max_cm"].as_f64().unwrap();
    assert!(worst < 0.55, "the camera drifted {worst} cm from its path");
    // The trajectory's shape, rigidly aligned: measured 0.18 cm.
    let aligned = e["ate_rmse_aligned_cm"].as_f64().unwrap();
    assert!(aligned < 0.22, "aligned ATE {aligned} cm");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_fast_start_pinned_by_a_thin_pole_stays_on_its_path() {
    // The sofa room's first frame moves 16 cm with no motion measured, and
    // along the sofa only the lamp's 4 cm pole pins the camera. Projective
    // association alone lost the pole there: ATE 17.17 cm (2.46 aligned),
    // the first frames sliding on to 16 cm. With the start's window at the
    // coarser levels: 2.18 cm (1.89 aligned), measured.
    let dir = scratch("track-sofa");
    let out = dir.join("out");
    track_simulated("sofa_room", &out, 200, &["--seed", "1"]);
    let s = summary(&out);
    assert_eq!(s["lost"], 0, "{s}");
    let ate = s["ate_rmse_cm"].as_f64().unwrap();
    assert!(ate < 3.0, "ATE {ate} cm");
    let aligned = s["ate_rmse_aligned_cm"].as_f64().unwrap();
    assert!(aligned < 2.0, "aligned ATE {aligned} cm");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn saved_simulated_frames_are_tracked_as_the_simulator_tracked_them() {
    let dir = scratch("track-saved-frames");
    let sim = dir.join("sim");
    track_room_line(&sim, 12, &["--save-frames"]);
    let frames = sim.join("frames");
    let names: Vec<String> = std::fs::read_dir(&frames)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    assert_eq!(names.len(), 1 + 2 * 12, "{names:?}");
    assert!(
        names.contains(&"frame-000012.pose.txt".to_owned()),
        "{names:?}"
    );
    // The folder read back as a dataset and tracked from its first pose:
    // were its depth units, intrinsics or pose convention wrong, the
    // estimates would be far from the simulator's true poses.
    let out = dir.join("rec");
    track_folder(&frames, &out);
    assert_eq!(summary(&out)["lost_frames"], 0);
    let e = eval_json(&out.join("trajectory.txt"), &sim.join("groundtruth.txt"));
    assert_eq!(e["matched"], 12);
    // Measured 0.40 cm, against 0.35 cm for the simulator's own run of
    // these frames (depth not yet rounded to millimetres).
    let ate = e["ate_rmse_cm"].as_f64().unwrap();
    assert!(ate < 0.5, "ATE {ate} cm");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn tracking_against_the_scene_itself_leaves_only_the_trackers_error() {
    let dir = scratch("track-scene-model");
    let (map, scene) = (dir.join("map"), dir.join("scene"));
    track_room_line(&map, 20, &[]);
    track_room_line(&scene, 20, &["--track-against", "scene"]);
    let (m, s) = (summary(&map), summary(&scene));
    assert_eq!(m["tracked_against"], "map", "{m}");
    assert_eq!(s["tracked_against"], "scene", "{s}");
    assert_eq!(s["lost"], 0, "{s}");
    // The map is fused either way, from the poses found.
    assert_eq!(s["frames_fused"], 20, "{s}");
    let (against_map, against_scene) = (
        m["ate_rmse_cm"].as_f64().unwrap(),
        s["ate_rmse_cm"].as_f64().unwrap(),
    );
    // Measured: 0.025 cm against the scene, 0.34 against the 2 cm map.
    assert!(against_scene < 0.05, "{against_scene} cm against the scene");
    assert!(
        against_scene < 0.5 * against_map,
        "{against_scene} against {against_map} cm"
    );
    // Without --track there is nothing to align.
    let out = dir.join("untracked");
    assert_fails_with(
        &depthmesh(&[
            "simulate",
            "--scene",
            "../../scenes/room.toml",
            "--track-against",
            "scene",
            "--iterations",
            "2",
            "--quiet",
            "--out",
            out.to_str().unwrap(),
        ]),
        &["--track-against scene", "--track"],
    );
    assert!(!out.exists());
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn tracking_against_the_map_the_true_poses_build_fuses_that_map() {
    let dir = scratch("track-true-map");
    let (tracked, given) = (dir.join("tracked"), dir.join("given"));
    track_room_line(&tracked, 20, &["--track-against", "true-map"]);
    simulate_scene("room", &given, 20, &ROOM_LINE);
    let s = summary(&tracked);
    assert_eq!(s["tracked_against"], "true-map", "{s}");
    assert_eq!(s["lost"], 0, "{s}");
    // The map is the one the true poses build, byte for byte ...
    let mesh = |run: &std::path::Path| std::fs::read(run.join("mesh.ply")).unwrap();
    assert!(mesh(&tracked) == mesh(&given), "the meshes differ");
    // ... while the poses written and measured are the tracked ones.
    let ate = s["ate_rmse_cm"].as_f64().unwrap();
    assert!(ate > 0.0 && ate < 0.5, "ATE {ate} cm");
    std::fs::remove_dir_all(dir).unwrap();
}

/// The room along a line, into a 2 cm TSDF.
const ROOM_LINE: [&str; 4] = ["--voxel", "0.02", "--path", "line"];

/// Tracks `scenes/SCENE.toml`'s helix with the frames `gap` left out and
/// cut at frame 160 ([`common::jump_path`]), noise seed `seed`, and
/// asserts that every frame tracked lies within 10 cm of the camera and
/// that at least `tracked` were; the scratch folder and the run's.
fn track_across_jump(
    scene: &str,
    gap: std::ops::Range<usize>,
    seed: &str,
    tracked: u64,
) -> (PathBuf, PathBuf) {
    let dir = scratch(&format!("track-{scene}-jump"));
    let (path, frames) = common::jump_path(&dir, scene, gap, 160);
    let out = dir.join("out");
    track_simulated(
        scene,
        &out,
        frames as u32,
        &["--path", &path, "--seed", seed],
    );
    let e = eval_json(&out.join("trajectory.txt"), &out.join("groundtruth.txt"));
    let worst = e["ate_max_cm"].as_f64().unwrap();
    assert!(worst < 10.0, "a frame was taken {worst} cm off");
    let matched = e["matched"].as_u64().unwrap();
    assert!(matched >= tracked, "{matched} frames tracked");
    (dir, out)
}

/// Column `name` of the run's `stats.csv` in `out`, a field a frame.
fn stats_column(out: &Path, name: &str) -> Vec<String> {
    let stats = std::fs::read_to_string(out.join("stats.csv")).unwrap();
    let mut lines = stats.lines();
    let header = lines.next().unwrap();
    let column = header.split(',').position(|c| c == name);
    let column = column.unwrap_or_else(|| panic!("stats.csv has no {name} column: {header}"));
    lines
        .map(|r| r.split(',').nth(column).unwrap_or_default().to_owned())
        .collect()
}

/// `reconstruct --track` (2 cm TSDF) of the frames folder `frames` from
/// its first pose, into `out`.
fn track_folder(frames: &Path, out: &Path) {
    ok(&depthmesh(&[
        "reconstruct",
        frames.to_str().unwrap(),
        "--voxel",
        "0.02",
        "--track",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ]));
}

/// Tracks `iterations` frames of the room along a line with Kinect noise
/// (2 cm TSDF) into `out`, with `extra` flags.
fn track_room_line(out: &std::path::Path, iterations: u32, extra: &[&str]) {
    let mut args = ROOM_LINE.to_vec();
    args.extend_from_slice(extra);
    track_simulated("room", out, iterations, &args);
}

/// Tracks `iterations` frames of `scenes/SCENE.toml` with Kinect noise into
/// a TSDF in `out`, with `extra` flags.
fn track_simulated(scene: &str, out: &std::path::Path, iterations: u32, extra: &[&str]) {
    let mut args = vec!["--track"];
    args.extend_from_slice(extra);
    simulate_scene(scene, out, iterations, &args);
}

/// Simulates `iterations` frames of `scenes/SCENE.toml` with Kinect noise
/// into a TSDF in `out`, with `extra` flags.
fn simulate_scene(scene: &str, out: &std::path::Path, iterations: u32, extra: &[&str]) {
    let scene = format!("../../scenes/{scene}.toml");
    let iterations = iterations.to_string();
    let mut args = vec![
        "simulate",
        "--scene",
        &scene,
        "--map",
        "tsdf",
        "--noise",
        "kinect",
        "--iterations",
        &iterations,
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    ok(&depthmesh(&args));
}

/// Asserts `e[key]` is `want` to within 1e-3.
fn assert_near(e: &Value, key: &str, want: f64) {
    let got = e[key].as_f64().unwrap();
    assert!(
        (got - want).abs() < 1e-3,
        "{key} {got}, expected {want}: {e}"
    );
}

#[test]
fn eval_measures_a_known_offset_in_centimetres() {
    // A reference turning and moving, and an estimate 3 cm beside it
    // along x, one frame short: a raw error of exactly 3 cm at every pose,
    // nothing after a rigid alignment, no relative error.
    let dir = scratch("eval-offset");
    let line = |t: usize, dx: f32| {
        let a = 0.1 * t as f32;
        let (s, c) = (a / 2.0).sin_cos();
        format!("{t} {} {} 0.5 0 {s} 0 {c}\n", 0.2 * t as f32 + dx, a.sin())
    };
    let reference: String = (0..10).map(|t| line(t, 0.0)).collect();
    let estimate: String = (0..9).map(|t| line(t, 0.03)).collect();
    std::fs::write(dir.join("ref.txt"), reference).unwrap();
    std::fs::write(dir.join("est.txt"), estimate).unwrap();
    let e = eval_json(&dir.join("est.txt"), &dir.join("ref.txt"));
    assert_eq!(e["matched"], 9);
    assert_near(&e, "ate_rmse_cm", 3.0);
    assert_near(&e, "ate_max_cm", 3.0);
    assert_near(&e, "ate_rmse_aligned_cm", 0.0);
    assert_near(&e, "rpe_translation_mm", 0.0);
    assert_near(&e, "rpe_rotation_deg", 0.0);
    // One pose 6 cm off instead: RMSE √((8·3² + 6²) / 9) = √12 cm, max 6 cm.
    let bumped: String = (0..9)
        .map(|t| line(t, if t == 4 { 0.06 } else { 0.03 }))
        .collect();
    std::fs::write(dir.join("est.txt"), bumped).unwrap();
    let e = eval_json(&dir.join("est.txt"), &dir.join("ref.txt"));
    assert_near(&e, "ate_rmse_cm", 12f64.sqrt());
    assert_near(&e, "ate_max_cm", 6.0);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_tracked_run_that_fuses_nothing_past_its_first_frame_fails() {
    let dir = scratch("track-away");
    let (run, out) = common::turn_away_from_a_wall(&dir, &["--quiet"]);
    // Its files are written, so the person can see why, but it is a failure.
    assert!(!run.status.success());
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(stderr.contains("frame 2: tracking lost"), "{stderr}");
    assert!(
        stderr.contains("nothing past the first frame was fused"),
        "{stderr}"
    );
    let s = summary(&out);
    assert_eq!(s["lost_frames"], 5);
    assert_eq!(s["frames_fused"], 1);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn staring_at_a_flat_wall_is_tracked_not_lost() {
    let dir = scratch("track-wall");
    // Sliding along the wall 2 m in front of it, looking at it.
    let poses: String = (0..6)
        .map(|i| format!("{i} {} 0 -2 0 0 0 1\n", 0.02 * i as f32))
        .collect();
    let (run, out) = common::track_wall_path(&dir, &poses, &["--quiet"]);
    ok(&run);
    let stderr = String::from_utf8_lossy(&run.stderr);
    // Nothing contradicts the map: the motions the wall leaves free come
    // from the motion model, and every frame is fused.
    assert!(!stderr.contains("tracking lost"), "{stderr}");
    let s = summary(&out);
    assert_eq!(s["lost"], 0);
    assert_eq!(s["lost_frames"], 0);
    // ...and the run says so, in stats.csv and in the summary: frames that
    // left motions along the wall to the motion model (measured: all 5
    // tracked).
    let directions = stats_column(&out, "weak_directions");
    let weak = directions
        .iter()
        .filter(|w| w.parse().is_ok_and(|w: u8| w > 0))
        .count();
    assert!(weak >= 3, "{directions:?}");
    assert_eq!(s["weak_frames"], weak, "{s}");
    let trajectory = std::fs::read_to_string(out.join("trajectory.txt")).unwrap();
    let poses: Vec<Vec<f64>> = trajectory
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split_whitespace().map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(poses.len(), 6);
    // What the wall constrains, the distance to it, stays right (1 cm,
    // half a voxel of the 2 cm map).
    for p in &poses {
        assert!((p[3] + 2.0).abs() < 0.01, "{p:?}");
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn eval_names_what_it_cannot_read() {
    let dir = scratch("eval-bad");
    std::fs::write(dir.join("est.txt"), "0 0 0 0 0 0 0 1\n").unwrap();
    std::fs::write(dir.join("bad.txt"), "0 0 0 0 0 0 0\n").unwrap();
    let est = dir.join("est.txt");
    let bad = dir.join("bad.txt");
    assert_fails_with(
        &depthmesh(&[
            "eval",
            "trajectory",
            est.to_str().unwrap(),
            bad.to_str().unwrap(),
        ]),
        &["bad.txt", "line 1", "expected 8 fields"],
    );
    assert_fails_with(
        &depthmesh(&[
            "eval",
            "trajectory",
            dir.join("missing.txt").to_str().unwrap(),
            est.to_str().unwrap(),
        ]),
        &["missing.txt"],
    );
    let late = dir.join("late.txt");
    std::fs::write(&late, "5 0 0 0 0 0 0 1\n").unwrap();
    assert_fails_with(
        &depthmesh(&[
            "eval",
            "trajectory",
            est.to_str().unwrap(),
            late.to_str().unwrap(),
        ]),
        &["no estimated pose"],
    );
    std::fs::remove_dir_all(dir).unwrap();
}

/// `eval relocalise` on the simulated room: mapped from a circle of 30
/// views with their true poses, queried from six views between them, whose
/// poses in the folder are 7 cm off the truth along x (a reference that
/// drifted, as 7-Scenes' does by centimetres). Each query is found at its
/// true pose: wrong against the folder's poses, right against the folder's
/// poses refined against the map, which come back to the truth.
#[test]
fn eval_relocalise_judges_against_the_reference_refined_against_the_map() {
    use depthmesh::sim::{NoiseModel, Scene, SceneOptions, SimulatedSensor};
    use depthmesh::Pose;
    use glam::Vec3;
    let dir = scratch("eval-relocalise");
    let room = std::path::Path::new("../../scenes/room.toml");
    let scene = Scene::load(room, &SceneOptions::default()).unwrap();
    let around = |degrees: f32, radius: f32, height: f32| {
        let a = degrees.to_radians();
        let eye = Vec3::new(radius * a.cos(), height, radius * a.sin());
        Pose::look_at(eye, Vec3::new(0.0, 0.4, 0.0), Vec3::Y)
    };
    let k = depthmesh::Intrinsics::from_vertical_fov(320, 240, 60.0);
    let mut sensor = SimulatedSensor::new(k, 0.4, 6.0, NoiseModel::None, 0).unwrap();
    let mut writer = depthmesh::dataset::FramesWriter::create(&dir, &k).unwrap();
    let drift = Vec3::new(0.07, 0.0, 0.0);
    for i in 0..36 {
        let (pose, written) = if i < 30 {
            let pose = around(12.0 * i as f32, 2.0, 1.3);
            (pose, pose)
        } else {
            let truth = around(60.0 * (i - 30) as f32 + 6.0, 1.9, 1.35);
            let drifted = Pose::from_quat(truth.quat(), truth.translation + drift);
            (truth, drifted)
        };
        let frame = sensor.capture(&scene, 1, &pose);
        writer.write(i, &frame.depth, &written).unwrap();
    }
    let out = depthmesh(&[
        "eval",
        "relocalise",
        dir.to_str().unwrap(),
        "--map-frames",
        "0..30",
        "--query-frames",
        "30..36",
    ]);
    ok(&out);
    let e: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(e["queries"], 6, "{e}");
    assert_eq!(e["accepted"], 6, "{e}");
    // Off the folder's poses by the drift...
    assert_eq!(e["wrongly_accepted"], 6, "{e}");
    // ...and at the map's own pose near them, which the refinement finds.
    assert_eq!(e["references_refined"], 6, "{e}");
    let moved = e["refinement_max_cm"].as_f64().unwrap();
    assert!((6.0..8.0).contains(&moved), "{e}");
    assert_eq!(e["wrongly_accepted_refined"], 0, "{e}");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn the_bare_end_of_a_corridor_does_not_run_away_with_the_camera() {
    // `bench/track_corridor.sh`'s straight walk (noise seed 1): 20 m at
    // 10 cm a frame along a wall with a box and a post every 3 m; the last
    // 20 frames see only the floor and the wall, which leave the motion
    // along the corridor free for depth alone. ICP's iterations past its
    // schedule, kept whatever they did, wandered along it there and the
    // motion model took that up: 21.55 cm ATE (1.3 m off at the end).
    // Kept only when they pin the view better: 3.66 cm, measured.
    let dir = scratch("track-corridor");
    let mut scene = String::from(
        "name = \"corridor\"\n[[object]]\nshape = \"plane\"\nsize = [30.0, 8.0]\n\
         translation = [10.0, 0.0, 0.0]\nfloor = true\n[[object]]\nshape = \"box\"\n\
         size = [30.0, 3.0, 0.1]\ntranslation = [10.0, 1.5, 2.0]\n",
    );
    for i in 0..6 {
        let x = 1.5 + 3.0 * i as f32;
        scene += &format!(
            "[[object]]\nshape = \"box\"\nsize = [0.6, 0.5, 0.4]\ntranslation = [{x}, 0.25, 1.5]\n\
             rotation = [0.0, {}, 0.0]\n[[object]]\nshape = \"cylinder\"\nradius = 0.1\n\
             height = 1.2\ntranslation = [{}, 0.6, 1.2]\n",
            17 * i,
            x + 1.2
        );
    }
    std::fs::write(dir.join("corridor.toml"), scene).unwrap();
    // Looking ahead along +x and down, turned 35° towards the wall.
    let q = "0.2949773843087508 -0.18422627651047424 0.9357759557194179 0.0580722178571292";
    let path: String = (0..200)
        .map(|i| format!("{i} {} 1.3 -0.5 {q}\n", 0.1 * i as f64))
        .collect();
    std::fs::write(dir.join("straight.txt"), path).unwrap();
    let out = dir.join("out");
    let (scene, path) = (dir.join("corridor.toml"), dir.join("straight.txt"));
    ok(&depthmesh(&[
        "simulate",
        "--scene",
        scene.to_str().unwrap(),
        "--map",
        "tsdf",
        "--track",
        "--noise",
        "kinect",
        "--path",
        &format!("tum:{}", path.display()),
        "--iterations",
        "200",
        "--seed",
        "1",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ]));
    let s = summary(&out);
    assert_eq!(s["lost_frames"], 0, "{s}");
    let ate = s["ate_rmse_cm"].as_f64().unwrap();
    assert!(ate < 6.0, "ATE {ate} cm");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_camera_followed_across_a_jump_to_a_look_alike_place_is_not_fused_there() {
    // The chairs' helix with frames 100-103 left out (0.81 m round the
    // orbit), noise seed 0: ICP followed the camera to where the chairs and
    // the table look as they do from its own pose, every frame after it
    // was fused there, and a twenty-fifth of the map's surface lay more
    // than 2 cm off the scene (96.7 % within). Held to the space the frames
    // before saw empty, that frame is lost, and the camera is searched for
    // and found where it is.
    map_stays_whole_across_jump("chairs", 100..104, "0", 120);
}

#[test]
fn a_box_followed_across_a_jump_is_not_fused_on_floor_seen_bare() {
    // The plane and box's helix with frames 140-144 left out (0.62 m),
    // noise seed 0: ICP followed the camera 0.57 m and 13 degrees off, to
    // where the box stands on floor the frames before saw bare, and every
    // frame after it was fused there. The box, 25 cm high, stood within
    // the 16-24 cm above the floor that 8 cm cells of the space seen empty
    // leave clear, and put 0.73 % of the frame there, under the bar; with
    // 4 cm cells that frame is lost, and nothing after it is fused.
    map_stays_whole_across_jump("plane_and_box", 140..145, "0", 140);
}

#[test]
fn a_camera_carried_round_the_chairs_is_found_within_a_frame() {
    // The chairs' helix with frames 60-64 left out and the rest numbered
    // anew: the camera is carried 0.90 m (17 degrees) further round the
    // table between two frames. Neither the turns on the spot nor global
    // registration found it for 24 frames, while it went on round; looked
    // for carried round what it looked at, it is found in the frame after
    // the one that lost it, and every frame is within 10 cm.
    map_stays_whole_across_jump("chairs", 60..65, "0", 153);
}

#[test]
fn a_camera_carried_round_the_table_is_found_within_a_frame() {
    // The table's helix with frames 100-103 left out and the rest numbered
    // anew: the camera is carried 0.79 m round the table between two
    // frames. The poses found there pinned the carry round the table only
    // by the table's sides, whose points hardly move along it, and were
    // refused as ambiguous: 11 frames were lost. Taken as pinned, the
    // right pose was still not among the three carried poses refined, and
    // the camera was found 3 frames later at the table's mirror image, 3 m
    // off (the table is alike turned half round).
    map_stays_whole_across_jump("table", 100..104, "0", 155);
}

#[test]
fn a_camera_carried_round_the_sofa_room_is_found_in_the_jump_frame() {
    // The sofa room's helix with frames 60-64 left out and the rest
    // numbered anew: the camera is carried round the room's middle, while
    // the middle of its view is the sofa, 1.3 m ahead. Every pose carried
    // round the sofa was contradicted, and 18 frames were lost; carried
    // round a point twice as far, the camera is found in the jump frame.
    // The map is not held to the other jumps' 2 cm: over 200 frames,
    // tracked without a jump, the sofa room's map is 98.5 % within it,
    // and lost for 18 frames it was 96.5 %, as it is found (96.2 %).
    let (dir, _) = track_across_jump("sofa_room", 60..65, "0", 155);
    std::fs::remove_dir_all(dir).unwrap();
}

/// [`track_across_jump`], and the map's surface stays within 2 cm of the
/// scene (but for a two-hundredth of it): nothing was fused at a wrong
/// place.
fn map_stays_whole_across_jump(scene: &str, gap: std::ops::Range<usize>, seed: &str, tracked: u64) {
    let (dir, out) = track_across_jump(scene, gap, seed, tracked);
    let within = summary(&out)["surface_within_2cm"].as_f64().unwrap();
    assert!(within >= 0.995, "map surface within 2 cm: {within}");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_person_walking_into_a_mapped_room_is_followed_and_not_fused() {
    // The room's helix (100 frames, Kinect noise), frames 60-79 taken with
    // a person-sized box standing between the camera and the furniture,
    // where the frames before saw through to the wall: those frames put
    // up to a tenth of their points in space seen empty. They keep their
    // course, so the camera is followed through them without fusing them,
    // and every frame before and after is fused (lost and searched for
    // instead, the camera was found again eleven frames after the person
    // had gone).
    let dir = scratch("track-person");
    let room = std::fs::read_to_string("../../scenes/room.toml").unwrap();
    let person = "[[object]]\nname = \"person\"\nshape = \"box\"\nsize = [0.45, 1.7, 0.3]\n\
                  translation = [0.3, 0.85, 1.3]\nfloor = true\n";
    std::fs::write(dir.join("person.toml"), format!("{room}\n{person}")).unwrap();
    let rooms = [
        ("../../scenes/room.toml".to_owned(), dir.join("room")),
        (
            dir.join("person.toml").display().to_string(),
            dir.join("person"),
        ),
    ];
    for (scene, out) in &rooms {
        ok(&depthmesh(&[
            "simulate",
            "--scene",
            scene,
            "--map",
            "tsdf",
            "--noise",
            "kinect",
            "--iterations",
            "100",
            "--save-frames",
            "--quiet",
            "--out",
            out.to_str().unwrap(),
        ]));
    }
    let mix = dir.join("mix");
    std::fs::create_dir(&mix).unwrap();
    let frames = |run: &PathBuf| run.join("frames");
    let intrinsics = "camera-intrinsics.txt";
    std::fs::copy(frames(&rooms[0].1).join(intrinsics), mix.join(intrinsics)).unwrap();
    for i in 1..=100 {
        let from = if (60..80).contains(&i) {
            &rooms[1].1
        } else {
            &rooms[0].1
        };
        for kind in ["depth.png", "pose.txt"] {
            let name = format!("frame-{i:06}.{kind}");
            std::fs::copy(frames(from).join(&name), mix.join(&name)).unwrap();
        }
    }
    let out = dir.join("rec");
    track_folder(&mix, &out);
    let s = summary(&out);
    let held = s["lost_frames"].as_u64().unwrap();
    assert!((1..=20).contains(&held), "{held} frames not fused: {s}");
    // Each was held, followed on, not a lost camera, and reads so.
    assert_eq!(s["held_frames"].as_u64(), Some(held), "{s}");
    let rows = stats_column(&out, "held");
    assert_eq!(rows.iter().filter(|&c| c == "1").count() as u64, held);
    let trajectory = std::fs::read_to_string(out.join("trajectory.txt")).unwrap();
    let fused: Vec<u32> = trajectory
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split_whitespace().next().unwrap().parse::<f64>().unwrap() as u32)
        .collect();
    for i in (1..60).chain(80..=100) {
        assert!(fused.contains(&i), "frame {i} was not fused");
    }
    let e = eval_json(&out.join("trajectory.txt"), &mix);
    let worst = e["ate_max_cm"].as_f64().unwrap();
    assert!(worst < 3.0, "a frame was taken {worst} cm off");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn frames_dropped_while_the_camera_moves_are_followed_across() {
    // The table's helix with frames 100-103 dropped (0.79 m). Numbered
    // anew, the camera reads as carried off and is lost until the search
    // finds it (the test below); with the helix's times kept the gap is
    // four frames the motion model spans, and the camera is followed
    // across it, every frame fused where the camera is.
    let dir = scratch("track-table-dropped");
    let (path, frames) = common::dropped_path(&dir, "table", 100..104, 160);
    let out = dir.join("out");
    track_simulated("table", &out, frames as u32, &["--path", &path]);
    let s = summary(&out);
    assert_eq!(s["lost_frames"], 0);
    assert_eq!(s["dropped_frames"], 4);
    let e = eval_json(&out.join("trajectory.txt"), &out.join("groundtruth.txt"));
    assert_eq!(e["matched"].as_u64(), Some(frames as u64));
    let worst = e["ate_max_cm"].as_f64().unwrap();
    assert!(worst < 2.0, "a frame was taken {worst} cm off");
    // The trajectory keeps the frames' own times: 100, then 105.
    let trajectory = std::fs::read_to_string(out.join("trajectory.txt")).unwrap();
    let times: Vec<f64> = trajectory
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split_whitespace().next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(times[99..101], [100.0, 105.0]);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_camera_that_jumps_is_never_taken_to_a_table_turned_a_quarter() {
    // The table scene's helix with frames 100-103 left out (0.79 m), noise
    // seed 1: the camera was relocalised 3.3 m off, the table turned a
    // quarter about it, verified against the map's view and tracked on
    // from there. The space the frames before saw empty refuses that
    // place, and the camera is found where it is.
    // Every frame tracked lies where the camera is, and the camera is
    // followed after the jump: at most 100 frames came before it.
    let (dir, _) = track_across_jump("table", 100..104, "1", 110);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_second_frame_keeps_the_height_a_post_leaves_free_where_the_run_started() {
    // A camera 2 m from a wall, a post turned 45° 1.5 m in front of it:
    // the post's upright faces pin all but the height. The second frame,
    // 2.5-6 cm along the wall, is followed with no motion measured, and
    // ICP from the guess of no motion climbed the wall along the height
    // (fused 19-23 cm up it for 2.5-4 cm along, nothing reported).
    use depthmesh::sim::{Scene, SceneOptions};
    use depthmesh::Pose;
    use glam::{Mat3, Vec3};
    let text = "[[object]]\nshape = \"box\"\nsize = [20.0, 20.0, 0.1]\n\
                [[object]]\nshape = \"box\"\nsize = [0.2, 1.0, 0.2]\n\
                translation = [0.0, 0.0, -0.5]\nrotation = [0.0, 45.0, 0.0]\n";
    let wall = Scene::parse(text, Path::new("wall.toml"), &SceneOptions::default()).unwrap();
    let dir = scratch("track-wall-and-post");
    for slide in [0.025, 0.03, 0.04, 0.06] {
        let frames = dir.join(format!("frames-{slide}"));
        let poses = [0.0, slide].map(|x| Pose::new(Mat3::IDENTITY, Vec3::new(x, 0.0, -2.0)));
        common::scene_frames_folder(&frames, &wall, &poses);
        let out = dir.join(format!("out-{slide}"));
        track_folder(&frames, &out);
        assert_eq!(summary(&out)["lost_frames"], 0, "slid {slide} m");
        let e = eval_json(&out.join("trajectory.txt"), &frames);
        let worst = e["ate_max_cm"].as_f64().unwrap();
        assert!(
            worst < 0.5,
            "slid {slide} m: the second frame {worst} cm off"
        );
    }
    std::fs::remove_dir_all(dir).unwrap();
}
