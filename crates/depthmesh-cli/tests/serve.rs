//! `depthmesh serve` and `depthmesh stream` as processes, on loopback: a
//! streamed recording gives the mesh `reconstruct` gives, the mesh can be
//! downloaded, and refusals say why. Every server is stopped by its guard.

mod common;

use common::served::{Served, TOKEN};
use common::{
    assert_fails_with, depthmesh, ok, scene_frames_folder, scratch, simulated_frames_folder,
    summary,
};
use depthmesh::sim::{Scene, SceneOptions};
use depthmesh::Pose;
use glam::{Mat3, Vec3};
use serde_json::Value;
use std::path::Path;

fn stream_args<'a>(served: &'a Served, folder: &'a str, out: &'a str) -> Vec<&'a str> {
    vec![
        "stream",
        folder,
        "--server",
        &served.url,
        "--token",
        TOKEN,
        "--rate",
        "max",
        "--quiet",
        "--out",
        out,
    ]
}

#[test]
fn a_folder_streamed_through_serve_gives_the_mesh_reconstruct_gives() {
    let dir = scratch("serve-same");
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    simulated_frames_folder(&frames, 8);
    let served = Served::start(&dir.join("server"), &["--voxel", "0.02"]);
    let offline = dir.join("offline");
    ok(&depthmesh(&[
        "reconstruct",
        frames.to_str().unwrap(),
        "--voxel",
        "0.02",
        "--quiet",
        "--out",
        offline.to_str().unwrap(),
    ]));
    let expected = std::fs::read(offline.join("mesh.ply")).unwrap();
    for codec in ["default", "rvl", "png", "raw"] {
        let out = dir.join(codec);
        let mut args = stream_args(&served, frames.to_str().unwrap(), out.to_str().unwrap());
        args.extend(["--codec", codec, "--session", codec, "--status-every", "4"]);
        args.push("--save-status");
        ok(&depthmesh(&args));
        assert!(
            std::fs::read(out.join("mesh.ply")).unwrap() == expected,
            "{codec}"
        );
        let s: Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap())
                .unwrap();
        assert_eq!(s["frames_sent"], 8);
        assert_eq!(s["frames_mapped"], 8);
        assert_eq!(s["frames_dropped"], 0);
        assert_eq!(s["status_images"], 2);
        assert!(out.join("status/frame-000003.jpg").exists());
        // The server wrote the run's files for the session.
        let server_mesh = dir.join("server").join(codec).join("mesh.ply");
        assert!(std::fs::read(server_mesh).unwrap() == expected);
    }
    let (status, glb) = served.get(&format!(
        "/api/sessions/rvl/mesh.glb?simplify=0.5&token={TOKEN}"
    ));
    assert_eq!(status, 200);
    assert_eq!(&glb[..4], b"glTF");
    let (status, ply) = served.get(&format!("/api/sessions/rvl/mesh.ply?token={TOKEN}"));
    assert_eq!(status, 200);
    assert!(ply == expected);
    let (status, list) = served.get(&format!("/api/sessions?token={TOKEN}"));
    assert_eq!(status, 200);
    let list: Value = serde_json::from_slice(&list).unwrap();
    assert_eq!(list["sessions"].as_array().unwrap().len(), 4);
    assert_eq!(served.get("/api/sessions/rvl/mesh.ply?token=guess").0, 401);
    assert_eq!(
        served.get("/api/sessions/rvl/../../x?token=guess").0 / 100,
        4
    );
    drop(served);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_live_sensor_gets_its_newest_frames_mapped_and_the_dropped_ones_counted() {
    let dir = scratch("serve-realtime");
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    simulated_frames_folder(&frames, 12);
    let served = Served::start(&dir.join("server"), &["--voxel", "0.02"]);
    let out = dir.join("out");
    let mut args = stream_args(&served, frames.to_str().unwrap(), out.to_str().unwrap());
    args[7] = "500";
    args.push("--realtime");
    ok(&depthmesh(&args));
    let s: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let count = |k: &str| s[k].as_u64().unwrap();
    assert_eq!(count("frames_sent"), 12);
    assert_eq!(count("frames_mapped") + count("frames_dropped"), 12);
    assert!(count("frames_mapped") >= 1);
    drop(served);
    std::fs::remove_dir_all(dir).unwrap();
}

/// A frames folder in `frames` of a camera 2 m from a 20 m wall (and
/// `objects`, scene-file text), sliding `step` metres a frame along it for
/// `count` frames.
fn sliding_along_a_wall(frames: &Path, objects: &str, count: usize, step: f32) {
    std::fs::create_dir_all(frames).unwrap();
    let wall = format!(
        "[[object]]\nname = \"wall\"\nshape = \"box\"\nsize = [20.0, 20.0, 0.1]\n{objects}"
    );
    let wall = Scene::parse(&wall, Path::new("wall.toml"), &SceneOptions::default()).unwrap();
    let poses: Vec<Pose> = (0..count)
        .map(|i| Pose::new(Mat3::IDENTITY, Vec3::new(step * i as f32, 0.0, -2.0)))
        .collect();
    scene_frames_folder(frames, &wall, &poses);
}

#[test]
fn a_streamed_weak_view_is_counted_as_the_server_counts_it() {
    let dir = scratch("serve-weak");
    let frames = dir.join("frames");
    // Sliding along a wall 2 m in front of it: the wall leaves the motion
    // along it to the motion model.
    sliding_along_a_wall(&frames, "", 6, 0.02);
    let served = Served::start(&dir.join("server"), &["--voxel", "0.02"]);
    let out = dir.join("out");
    let mut args = stream_args(&served, frames.to_str().unwrap(), out.to_str().unwrap());
    args.extend(["--session", "wall", "--track"]);
    ok(&depthmesh(&args));
    let client = summary(&out);
    let server = summary(&dir.join("server").join("wall"));
    assert_eq!(client["frames_lost"], 0, "{client}");
    let weak = client["frames_weak"].as_u64().unwrap();
    assert!(weak >= 3, "{client}");
    assert_eq!(server["weak_frames"], weak, "{server}");
    drop(served);
    std::fs::remove_dir_all(dir).unwrap();
}

/// A tracked live sensor the server cannot keep up with: the frames it
/// passes over are told to the tracker (predicted across, not read as
/// frames the sensor dropped), so the run counts no sensor drops and
/// loses nothing, while the client counts what the server dropped.
#[test]
fn a_tracked_live_sensor_counts_the_frames_the_server_passed_over_apart() {
    let dir = scratch("serve-realtime-tracked");
    let frames = dir.join("frames");
    // A post turned 45° in front of the wall pins the motion along it,
    // and a bar tilted 45° above it the height, which the post's upright
    // faces leave free: the frames the server maps may be any few of the
    // 40, the first of them followed with no motion yet measured.
    let objects = "[[object]]\nname = \"post\"\nshape = \"box\"\nsize = [0.2, 1.0, 0.2]\n\
                   translation = [0.0, 0.0, -0.5]\nrotation = [0.0, 45.0, 0.0]\n\
                   [[object]]\nname = \"bar\"\nshape = \"box\"\nsize = [1.0, 0.2, 0.2]\n\
                   translation = [0.0, 0.65, -0.5]\nrotation = [45.0, 0.0, 0.0]\n";
    sliding_along_a_wall(&frames, objects, 40, 0.005);
    let served = Served::start(&dir.join("server"), &["--voxel", "0.02"]);
    let out = dir.join("out");
    let mut args = stream_args(&served, frames.to_str().unwrap(), out.to_str().unwrap());
    args[7] = "250";
    args.extend(["--realtime", "--track", "--session", "live"]);
    ok(&depthmesh(&args));
    let client = summary(&out);
    let server = summary(&dir.join("server").join("live"));
    let count = |s: &Value, k: &str| s[k].as_u64().unwrap();
    assert_eq!(count(&client, "frames_sent"), 40);
    assert!(count(&client, "frames_dropped") > 0, "{client}");
    assert!(count(&client, "frames_mapped") >= 3, "{client}");
    assert_eq!(count(&client, "frames_lost"), 0, "{client}");
    assert_eq!(count(&server, "dropped_frames"), 0, "{server}");
    drop(served);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn refusals_name_their_reason() {
    let dir = scratch("serve-refusals");
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    simulated_frames_folder(&frames, 2);
    let served = Served::start(&dir.join("server"), &[]);
    let out = dir.join("out");
    let mut args = stream_args(&served, frames.to_str().unwrap(), out.to_str().unwrap());
    args[5] = "guess";
    assert_fails_with(&depthmesh(&args), &["wrong token"]);
    let mut args = stream_args(&served, frames.to_str().unwrap(), out.to_str().unwrap());
    args.extend(["--session", "../escape"]);
    assert_fails_with(&depthmesh(&args), &["session name"]);
    assert!(!dir.join("escape").exists());
    drop(served);
    // Listening beyond this machine needs a token; nothing is bound.
    assert_fails_with(
        &depthmesh(&[
            "serve",
            "--bind",
            "0.0.0.0:0",
            "--out",
            dir.to_str().unwrap(),
        ]),
        &["--token"],
    );
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_server_killed_mid_session_continues_it_from_its_store() {
    let dir = scratch("serve-store");
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    simulated_frames_folder(&frames, 40);
    let f = frames.to_str().unwrap();
    let offline = dir.join("offline");
    let o = offline.to_str().unwrap();
    ok(&depthmesh(&[
        "reconstruct",
        f,
        "--voxel",
        "0.02",
        "--track",
        "--quiet",
        "--out",
        o,
    ]));
    let server = dir.join("server");
    let flags = ["--voxel", "0.02", "--store", "--checkpoint-every", "4"];
    let served = Served::start(&server, &flags);
    let first = dir.join("first");
    let mut args = stream_args(&served, f, first.to_str().unwrap());
    // At 20 frames/s, not as fast as the server maps.
    let rate = args.iter().position(|a| *a == "max").unwrap();
    args[rate] = "20";
    args.extend(["--session", "walk", "--track"]);
    let mut client = std::process::Command::new(env!("CARGO_BIN_EXE_depthmesh"))
        .args(&args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // Halfway through the 2 s the client takes at 20 frames/s.
    std::thread::sleep(std::time::Duration::from_millis(1000));
    drop(served); // SIGKILL
    assert!(
        !client.wait().unwrap().success(),
        "the client outlived its server"
    );
    let served = Served::start(&server, &flags);
    let second = dir.join("second");
    let mut args = stream_args(&served, f, second.to_str().unwrap());
    args.extend(["--session", "walk", "--track", "--resume"]);
    ok(&depthmesh(&args));
    let s: Value =
        serde_json::from_str(&std::fs::read_to_string(second.join("summary.json")).unwrap())
            .unwrap();
    let sent = s["frames_sent"].as_u64().unwrap();
    assert!(sent > 0 && sent < 40, "{sent} frames sent after the crash");
    // The session ends as one never interrupted: the offline run's mesh and trajectory.
    for file in ["mesh.ply", "trajectory.txt"] {
        assert!(
            std::fs::read(server.join("walk").join(file)).unwrap()
                == std::fs::read(offline.join(file)).unwrap(),
            "{file}"
        );
    }
    assert!(
        std::fs::read(second.join("mesh.ply")).unwrap()
            == std::fs::read(offline.join("mesh.ply")).unwrap()
    );
    let summary = common::summary(&server.join("walk"));
    assert_eq!(summary["frames"], 40, "{summary}");
    // A new session may not take a name whose store is there, and a server
    // without stores continues nothing.
    let mut args = stream_args(
        &served,
        f,
        dir.join("again").to_str().unwrap().to_owned().leak(),
    );
    args.extend(["--session", "walk"]);
    assert_fails_with(&depthmesh(&args), &["--resume"]);
    drop(served);
    let plain = Served::start(&dir.join("plain"), &["--voxel", "0.02"]);
    let mut args = stream_args(
        &plain,
        f,
        dir.join("none").to_str().unwrap().to_owned().leak(),
    );
    args.extend(["--session", "walk", "--resume"]);
    assert_fails_with(&depthmesh(&args), &["no stores"]);
    drop(plain);
    std::fs::remove_dir_all(dir).unwrap();
}
