//! `reconstruct --store`: killed with SIGKILL at arbitrary points and
//! resumed, a run ends with the mesh and trajectory of a run never
//! interrupted; a damaged store or one written with other settings is
//! refused with a message, and `info` says what a store holds.

mod common;

use common::{assert_fails_with, depthmesh, ok, scratch, simulated_frames_folder};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const FRAMES: u32 = 60;
const TABLE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/table.toml");
const CORRIDOR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/corridor.toml");
const ROOM: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/room.toml");

fn reconstruct(frames: &Path, out: &Path, extra: &[&str], track: bool) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_depthmesh"));
    c.args([
        "reconstruct",
        frames.to_str().unwrap(),
        "--voxel",
        "0.02",
        "--quiet",
    ])
    .args(["--out", out.to_str().unwrap()])
    .args(extra)
    .args(if track { &["--track"][..] } else { &[] })
    .stdout(Stdio::null())
    .stderr(Stdio::piped());
    c
}

/// The store flags of a run that continues `store` if it exists (--force:
/// a run killed before its store was made left only --out).
fn store_args(store: &Path) -> Vec<&str> {
    let mut args = vec![
        "--store",
        store.to_str().unwrap(),
        "--checkpoint-every",
        "4",
        "--force",
    ];
    if store.exists() {
        args.push("--resume");
    }
    args
}

#[test]
fn a_run_killed_and_resumed_ends_as_one_never_interrupted() {
    let dir = scratch("store-kill");
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    simulated_frames_folder(&frames, FRAMES);
    for track in [false, true] {
        let make = |out: &Path, extra: &[&str]| reconstruct(&frames, out, extra, track);
        killed_and_resumed(
            &dir.join(format!("track-{track}")),
            make,
            FRAMES,
            track,
            Kills::Seeded,
        );
    }
    std::fs::remove_dir_all(dir).unwrap();
}

/// `simulate` flags of a tracked run into a 2 cm TSDF, with Kinect noise
/// of `seed`, along `path` for `iterations` poses.
fn tracked_noisy_tsdf<'a>(seed: &'a str, path: &'a str, iterations: &'a str) -> [&'a str; 13] {
    [
        "--map",
        "tsdf",
        "--voxel",
        "0.02",
        "--noise",
        "kinect",
        "--seed",
        seed,
        "--path",
        path,
        "--iterations",
        iterations,
        "--track",
    ]
}

/// `simulate` of `scene` with `args` into `out`, then `extra`, quiet.
fn simulate(scene: &str, args: &[&str], out: &Path, extra: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_depthmesh"));
    c.args(["simulate", "--scene", scene])
        .args(args)
        .args(["--quiet", "--out", out.to_str().unwrap()])
        .args(extra)
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    c
}

#[test]
fn a_simulated_run_killed_and_resumed_sees_the_same_noisy_frames() {
    let dir = scratch("store-simulate");
    // The pass along the table, 21 cm a frame, is tracked with no frame
    // lost; the helix's 24 poses lie over a metre apart, beyond tracking
    // (the camera was lost at the second frame and, before poses found
    // after a loss had to be pinned along their weakest direction, taken
    // up again metres off).
    let args = tracked_noisy_tsdf("7", "line", "24");
    let make = |out: &Path, extra: &[&str]| simulate(TABLE, &args, out, extra);
    killed_and_resumed(&dir, make, 24, true, Kills::Seeded);
    std::fs::remove_dir_all(dir).unwrap();
}

// What a tracked run keeps besides the map is restored too: a run killed
// as soon as it has lost the camera resumes from its last checkpoint,
// before the loss, with the keyframes it had learnt, and finds the camera
// where the uninterrupted run did. (Resumed without its keyframes it finds
// the camera too, but up to a millimetre away: relocalisation's
// candidates come from the map as the keyframes saw it.)
#[test]
fn a_tracked_run_killed_and_resumed_across_a_loss_ends_as_never_interrupted() {
    let dir = scratch("store-jump");
    std::fs::create_dir_all(&dir).unwrap();
    // Around the room's furniture, 2 m out and 1.3 m high, 2° (7 cm) a
    // frame out to 24°; then turned on the spot, 5° a frame, until the
    // furniture has left the view. The frames in between dropped, the
    // camera is next seen 0.74 m away, higher and facing the furniture
    // again (79° from its last view), and moves on sideways.
    let look =
        |eye: glam::Vec3, target: glam::Vec3| depthmesh::Pose::look_at(eye, target, glam::Vec3::Y);
    let centre = glam::Vec3::new(0.0, 0.4, 0.0);
    let around = |degrees: f32| {
        let a = degrees.to_radians();
        glam::Vec3::new(2.0 * a.cos(), 1.3, 2.0 * a.sin())
    };
    let last = around(24.0);
    let poses: Vec<_> = (0..13)
        .map(|i| look(around(2.0 * i as f32), centre))
        .chain((1..=12).map(|i| {
            let turn = glam::Quat::from_rotation_y((5.0 * i as f32).to_radians());
            look(last, last + turn * (centre - last))
        }))
        .chain((0..10).map(|i| {
            let i = i as f32;
            look(glam::Vec3::new(1.3 + 0.03 * i, 1.5, 1.3 - 0.05 * i), centre)
        }))
        .collect();
    let jump = poses[24].translation.distance(poses[25].translation);
    assert!((0.5..=1.0).contains(&jump), "{jump} m");
    let path = format!("tum:{}", tum_path(&dir, "jump.txt", &poses).display());
    let frames = poses.len() as u32;
    let iterations = frames.to_string();
    let args = tracked_noisy_tsdf("5", &path, &iterations);
    let make = |out: &Path, extra: &[&str]| simulate(ROOM, &args, out, extra);
    let kills = Kills::OnMessage("tracking lost", Duration::ZERO, 0..u64::MAX);
    killed_and_resumed(&dir, make, frames, true, kills);
    // The run crossed a loss, and the camera was found again in the frame
    // following lost it (the resumed run's counts equal these).
    let summary = common::summary(&dir.join("reference"));
    assert_eq!(summary["recovered_frames"], 1, "{summary}");
    assert_eq!(summary["lost_frames"], 0, "{summary}");
    std::fs::remove_dir_all(dir).unwrap();
}

// So is the space the frames saw empty, which a pose found after a loss
// is held to. The table's helix with frames 100-103 left out (0.79 m),
// noise seed 1: the uninterrupted run refuses the place where the table
// looks the same turned a quarter and finds the camera where it is; killed
// at the loss and resumed without the space its frames saw, the run took
// the camera to that place, 3.5 m off, and mapped on from there.
#[test]
fn a_tracked_run_killed_at_a_jump_refuses_a_look_alike_place_once_resumed() {
    let dir = scratch("store-look-alike");
    std::fs::create_dir_all(&dir).unwrap();
    let (path, frames) = common::table_jump_path(&dir);
    let iterations = frames.to_string();
    let args = [
        "--map",
        "tsdf",
        "--noise",
        "kinect",
        "--seed",
        "1",
        "--path",
        &path,
        "--iterations",
        &iterations,
        "--track",
    ];
    let make = |out: &Path, extra: &[&str]| simulate(TABLE, &args, out, extra);
    // Killed a second after the loss at frame 101 (the lost frames'
    // searches take longer), resumed from a checkpoint at or past the last
    // good frame, 100, and before the camera is found again (frame 140):
    // the space its frames saw can come only from the store.
    let kills = Kills::OnMessage("tracking lost", Duration::from_secs(1), 100..140);
    killed_and_resumed(&dir, make, frames as u32, true, kills);
    // The camera was lost at the jump and found again where it is.
    let reference = dir.join("reference");
    let e = common::eval_json(
        &reference.join("trajectory.txt"),
        &reference.join("groundtruth.txt"),
    );
    let worst = e["ate_max_cm"].as_f64().unwrap();
    assert!(worst < 10.0, "a frame was taken {worst} cm off");
    assert!(e["matched"].as_u64().unwrap() > 100, "{e}");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn mabdi_and_planes_runs_killed_and_resumed_end_as_never_interrupted() {
    for map in ["mabdi", "planes"] {
        let dir = scratch(&format!("store-{map}"));
        let args = [
            "--map",
            map,
            "--noise",
            "kinect",
            "--seed",
            "3",
            "--iterations",
            "30",
        ];
        let make = |out: &Path, extra: &[&str]| simulate(TABLE, &args, out, extra);
        killed_and_resumed(&dir, make, 30, false, Kills::Seeded);
        std::fs::remove_dir_all(dir).unwrap();
    }
}

/// Where [`killed_and_resumed`] kills a run.
#[derive(Clone)]
enum Kills<'a> {
    /// At seeded times within about a whole run, at most four times.
    Seeded,
    /// Once, this long after it reports this message; the store must then
    /// hold a number of frames in the range.
    OnMessage(&'a str, Duration, std::ops::Range<u64>),
}

/// Kills a run with `--store` (made by `make(out, extra flags)`) as `kills`
/// says, resumes it to the end, and compares with a run never interrupted.
fn killed_and_resumed(
    dir: &Path,
    make: impl Fn(&Path, &[&str]) -> Command,
    frames: u32,
    track: bool,
    kills: Kills,
) {
    let reference = dir.join("reference");
    let start = Instant::now();
    assert!(make(&reference, &[]).status().unwrap().success());
    let (run, store, kills) = match kills {
        Kills::Seeded => interrupted(dir, &make, start.elapsed()),
        Kills::OnMessage(message, then, holding) => {
            interrupted_on_message(dir, &make, message, then, holding)
        }
    };
    for file in ["mesh.ply", "trajectory.txt"] {
        assert!(
            std::fs::read(run.join(file)).unwrap() == std::fs::read(reference.join(file)).unwrap(),
            "{file} differs after {kills} kills (tracking {track})"
        );
    }
    // The counts over the records, kept as frames come, include those
    // before the resume.
    let (resumed, uninterrupted) = (common::summary(&run), common::summary(&reference));
    for key in ["frames_fused", "lost_frames", "weak_frames"] {
        assert_eq!(resumed.get(key), uninterrupted.get(key), "{key}");
    }
    let stats = std::fs::read_to_string(run.join("stats.csv")).unwrap();
    assert_eq!(
        stats.lines().count(),
        frames as usize + 1,
        "a row per frame"
    );
    let info = store_info(&store);
    assert_eq!(info["records"], frames);
    assert_eq!(info["tracked"], track, "{info}");
    if track {
        // The tracker's free space went into the store with its state.
        assert!(info["free_space_regions"].as_u64().unwrap() > 0, "{info}");
    }
    let held = match info["map"].as_str().unwrap() {
        "tsdf" => "blocks",
        "planes" => "cells",
        _ => "triangles",
    };
    assert!(info[held].as_u64().unwrap() > 0, "{info}");
    // The store exports as the mesh the run wrote does.
    let exported = |input: &Path, name: &str| -> usize {
        let glb = dir.join(name);
        ok(&depthmesh(&[
            "export",
            input.to_str().unwrap(),
            "-o",
            glb.to_str().unwrap(),
            "--quiet",
        ]));
        depthmesh::mesh::glb::read_glb(&glb)
            .unwrap()
            .iter()
            .map(|m| m.mesh.triangle_count())
            .sum()
    };
    let from_store = exported(&store, "from-store.glb");
    assert!(from_store > 0);
    assert_eq!(from_store, exported(&run.join("mesh.ply"), "from-mesh.glb"));
}

/// `depthmesh info` of `store`, which must succeed.
fn store_info(store: &Path) -> serde_json::Value {
    let info = depthmesh(&["info", store.to_str().unwrap()]);
    ok(&info);
    serde_json::from_slice(&info.stdout).unwrap()
}

/// Runs `make(DIR/run, store flags)` and kills it with SIGKILL at seeded
/// points within `within` (about a whole run), at most four times, then
/// resumes it to the end; returns the run's folder, its store and the kills.
fn interrupted(
    dir: &Path,
    make: impl Fn(&Path, &[&str]) -> Command,
    within: Duration,
) -> (PathBuf, PathBuf, u32) {
    let store = dir.join("map.store");
    let run = dir.join("run");
    // A small linear congruential generator: the same kill points every
    // time, spread over the run.
    let mut seed = 12_345u64;
    let mut kills = 0;
    let window = (within.as_millis() as u64 * 9 / 10).max(20);
    let deadline = Instant::now() + Duration::from_secs(120);
    while kills < 4 && Instant::now() < deadline {
        let mut child = make(&run, &store_args(&store)).spawn().unwrap();
        seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        std::thread::sleep(Duration::from_millis(10 + (seed >> 33) % window));
        match child.try_wait().unwrap() {
            Some(status) => {
                // Finished before the kill: nothing more to interrupt, or,
                // before any kill, start over (the machine ran it faster
                // than the run it was timed by).
                let mut err = String::new();
                std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut err).unwrap();
                assert!(status.success(), "{err}");
                if kills > 0 {
                    break;
                }
                std::fs::remove_file(&store).unwrap();
                std::fs::remove_dir_all(&run).unwrap();
            }
            None => {
                child.kill().unwrap();
                child.wait().unwrap();
                kills += 1;
            }
        }
    }
    assert!(kills > 0, "the run always finished before it was killed");
    resume_to_the_end(&make, &run, &store);
    (run, store, kills)
}

/// Runs `make(DIR/run, store flags)` and kills it with SIGKILL as soon as
/// it reports `message` on its standard error, then resumes it to the end;
/// returns the run's folder, its store and the kills (1).
fn interrupted_on_message(
    dir: &Path,
    make: impl Fn(&Path, &[&str]) -> Command,
    message: &str,
    then: Duration,
    holding: std::ops::Range<u64>,
) -> (PathBuf, PathBuf, u32) {
    use std::io::BufRead;
    let store = dir.join("map.store");
    let run = dir.join("run");
    let mut child = make(&run, &store_args(&store)).spawn().unwrap();
    let stderr = std::io::BufReader::new(child.stderr.take().unwrap());
    let said = stderr.lines().any(|line| line.unwrap().contains(message));
    assert!(said, "the run ended without reporting \"{message}\"");
    std::thread::sleep(then);
    child.kill().unwrap();
    child.wait().unwrap();
    let info = store_info(&store);
    let records = info["records"].as_u64().unwrap();
    assert!(
        holding.contains(&records),
        "killed holding {records} frames"
    );
    resume_to_the_end(&make, &run, &store);
    (run, store, 1)
}

/// Resumes the run of `make` in `run` from `store` and lets it finish.
fn resume_to_the_end(make: impl Fn(&Path, &[&str]) -> Command, run: &Path, store: &Path) {
    let last = make(run, &store_args(store)).output().unwrap();
    assert!(
        last.status.success(),
        "{}",
        String::from_utf8_lossy(&last.stderr)
    );
}

/// Writes `poses` to `dir/name` as a TUM trajectory (timestamps 0, 1, …)
/// for `--path tum:FILE`; its path.
fn tum_path(dir: &Path, name: &str, poses: &[depthmesh::Pose]) -> PathBuf {
    let mut text = String::new();
    for (i, pose) in poses.iter().enumerate() {
        let q = glam::Quat::from_mat3(&pose.rotation);
        let t = pose.translation;
        text.push_str(&format!(
            "{i} {} {} {} {} {} {} {}\n",
            t.x, t.y, t.z, q.x, q.y, q.z, q.w
        ));
    }
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

/// A walk `out` m down `scenes/corridor.toml` looking ahead, turning round
/// and coming back looking the other way, 0.25 m a frame: its TUM poses, in
/// `dir`, and its frames.
fn there_and_back(dir: &Path, out: f32) -> (PathBuf, u32) {
    let half = (out / 0.25) as u32;
    let poses: Vec<_> = (0..2 * half)
        .map(|i| {
            let (x, ahead) = if i < half {
                (0.5 + 0.25 * i as f32, 0.7)
            } else {
                (0.5 + 0.25 * (2 * half - 1 - i) as f32, -0.7)
            };
            let eye = glam::Vec3::new(x, 1.3, -0.5);
            depthmesh::Pose::look_at(eye, eye + glam::Vec3::new(ahead, -0.5, 1.0), glam::Vec3::Y)
        })
        .collect();
    (tum_path(dir, "walk.txt", &poses), 2 * half)
}

#[test]
fn a_bounded_walk_there_and_back_killed_and_resumed_equals_the_unbounded_map() {
    let dir = scratch("store-bounded");
    std::fs::create_dir_all(&dir).unwrap();
    let (poses, frames) = there_and_back(&dir, 16.0);
    let path = format!("tum:{}", poses.display());
    let iterations = frames.to_string();
    let args = [
        "--map",
        "tsdf",
        "--voxel",
        "0.05",
        "--path",
        &path,
        "--iterations",
        &iterations,
    ];
    let make = |out: &Path, extra: &[&str]| simulate(CORRIDOR, &args, out, extra);
    let unbounded = dir.join("unbounded");
    let start = Instant::now();
    assert!(make(&unbounded, &[]).status().unwrap().success());
    // Beyond the simulated Kinect's reach (5.85 m at 5 cm voxels): every
    // measurement is fused, so the bounded map can equal the unbounded one.
    let bounded = |out: &Path, extra: &[&str]| {
        let mut args = vec!["--active-radius", "6"];
        args.extend(extra);
        make(out, &args)
    };
    let (run, store, kills) = interrupted(&dir, bounded, start.elapsed());
    let triangles = |path: &Path| {
        let mut set = Vec::new();
        depthmesh::mesh::io::read_mesh(path)
            .unwrap()
            .triangle_records(&mut set);
        set.sort_unstable();
        set
    };
    let whole = triangles(&unbounded.join("mesh.ply"));
    assert!(whole.len() > 20_000, "{} triangles", whole.len());
    assert!(
        triangles(&run.join("mesh.ply")) == whole,
        "the bounded map differs from the unbounded one after {kills} kills"
    );
    let summary = common::summary(&run);
    assert!(summary["peak_blocks"].as_u64().unwrap() > 0, "{summary}");
    assert!(summary["chunks"].as_u64().unwrap() > 0, "{summary}");
    // The store holds the whole map, not only what was in memory.
    let info = store_info(&store);
    let unbounded_blocks = common::summary(&unbounded)["map_bytes"].as_u64().unwrap() / (512 * 4);
    assert_eq!(info["blocks"].as_u64().unwrap(), unbounded_blocks, "{info}");
    assert!(
        info["resident_blocks"].as_u64().unwrap() < unbounded_blocks,
        "{info}"
    );
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_damaged_store_or_other_settings_are_refused() {
    let dir = scratch("store-refused");
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    simulated_frames_folder(&frames, 6);
    let store = dir.join("map.store");
    let s = store.to_str().unwrap();
    let out = dir.join("out");
    let o = out.to_str().unwrap();
    let f = frames.to_str().unwrap();
    // `reconstruct` of the frames into --out with the store, at `voxel`.
    let run = |voxel: &str, extra: &[&str]| {
        let mut args = vec!["reconstruct", f, "--voxel", voxel, "--quiet", "--out", o];
        args.extend(["--store", s]);
        args.extend(extra);
        depthmesh(&args)
    };
    ok(&run("0.02", &[]));
    // Another voxel size: the store says which setting differs.
    assert_fails_with(&run("0.03", &["--resume"]), &["voxel"]);
    // A store is not overwritten by a run that does not continue it.
    assert_fails_with(&run("0.02", &["--force"]), &["--resume"]);
    // Truncated, or overwritten in the middle: refused, naming the file.
    let bytes = std::fs::read(&store).unwrap();
    std::fs::write(&store, &bytes[..bytes.len() / 3]).unwrap();
    assert_fails_with(&depthmesh(&["info", s]), &["map.store"]);
    let mut damaged = bytes.clone();
    for b in &mut damaged[4096..bytes.len().min(4096 * 4)] {
        *b = 0xA5;
    }
    std::fs::write(&store, &damaged).unwrap();
    assert_fails_with(&run("0.02", &["--resume"]), &["map.store"]);
    std::fs::write(&store, b"not a store").unwrap();
    assert_fails_with(&depthmesh(&["info", s]), &["not a store"]);
    std::fs::remove_dir_all(dir).unwrap();
}
