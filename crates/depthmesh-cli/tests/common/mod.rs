//! Helpers shared by the command-line tests: run the binary, a scratch
//! folder per test, and the checks every failure must pass.

#[allow(dead_code)] // not every test file needs it
pub mod nats;
#[allow(dead_code)] // not every test file needs it
pub mod served;
#[allow(dead_code)] // not every test file needs it
pub mod webdriver;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs `depthmesh` with `args` from the CLI crate's folder.
pub fn depthmesh(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_depthmesh"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("the binary runs")
}

/// A fresh, empty folder for one test (`name` keeps tests apart).
pub fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("depthmesh-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The command succeeded; otherwise show what it said.
#[allow(dead_code)] // not every test file needs it
pub fn ok(output: &Output) {
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
}

/// The `summary.json` a run wrote into `out`.
#[allow(dead_code)] // not every test file needs it
pub fn summary(out: &std::path::Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap()
}

/// The command failed with a message containing every one of `needles`, and no panic.
#[allow(dead_code)] // not every test file needs it
pub fn assert_fails_with(output: &Output, needles: &[&str]) {
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        !output.status.success(),
        "expected failure, got success; stderr: {stderr}"
    );
    assert!(!stderr.contains("panicked"), "panic: {stderr}");
    for n in needles {
        assert!(stderr.contains(n), "stderr lacks {n:?}: {stderr}");
    }
}

/// The table scene the tests simulate.
#[allow(dead_code)] // not every test file needs it
pub fn table_scene() -> depthmesh::sim::Scene {
    scene("table")
}

/// `scenes/NAME.toml`.
#[allow(dead_code)] // not every test file needs it
pub fn scene(name: &str) -> depthmesh::sim::Scene {
    let options = depthmesh::sim::SceneOptions::default();
    let file = format!("../../scenes/{name}.toml");
    depthmesh::sim::Scene::load(Path::new(&file), &options).unwrap()
}

/// The table scene's 200-pose helix with frames 100-103 left out (the
/// camera reappears 0.79 m away) and cut at frame 160 (see [`jump_path`]);
/// written as a run writes its poses, the search after the jump turns on
/// digits beyond them: at full precision the camera was found again a few
/// frames after the jump, where written so it is lost until frame 140 and
/// is offered the table turned a quarter.
#[allow(dead_code)] // not every test file needs it
pub fn table_jump_path(dir: &Path) -> (String, usize) {
    jump_path(dir, "table", 100..104, 160)
}

/// `scenes/SCENE.toml`'s 200-pose helix with the frames `gap` left out
/// and cut at frame `end`, written to `dir/jump.txt` as a run writes its
/// poses (6 decimals), the poses numbered anew: the camera reads as
/// carried off between two frames; the `--path` value and the number of
/// poses.
#[allow(dead_code)] // not every test file needs it
pub fn jump_path(
    dir: &Path,
    scene_name: &str,
    gap: std::ops::Range<usize>,
    end: usize,
) -> (String, usize) {
    gapped_path(dir, scene_name, gap, end, |i, _| i as f64)
}

/// [`jump_path`] with the helix's own times (1, 2, …) kept: the frames
/// left out read as frames the sensor dropped while the camera moved on.
#[allow(dead_code)] // not every test file needs it
pub fn dropped_path(
    dir: &Path,
    scene_name: &str,
    gap: std::ops::Range<usize>,
    end: usize,
) -> (String, usize) {
    gapped_path(dir, scene_name, gap, end, |_, t| t)
}

/// The helix of [`jump_path`], each kept pose timed by `time` of its
/// place in the file and its time on the helix.
#[allow(dead_code)] // not every test file needs it
fn gapped_path(
    dir: &Path,
    scene_name: &str,
    gap: std::ops::Range<usize>,
    end: usize,
    time: impl Fn(usize, f64) -> f64,
) -> (String, usize) {
    let helix = depthmesh::sim::PathSpec::Helix
        .build_timed(&scene(scene_name), 200)
        .unwrap();
    let poses: Vec<_> = helix[..gap.start]
        .iter()
        .chain(&helix[gap.end..end])
        .enumerate()
        .map(|(i, &(t, pose))| (time(i, t), pose))
        .collect();
    let file = dir.join("jump.txt");
    std::fs::write(&file, depthmesh::trajectory::format_tum(&poses)).unwrap();
    (format!("tum:{}", file.display()), poses.len())
}

/// The colour the frames folder gives a point of the table scene: the
/// floor and the bottom of the legs red, everything higher green.
#[allow(dead_code)] // not every test file needs it
pub fn scene_colour(p: glam::Vec3) -> [u8; 3] {
    if p.y < 0.2 {
        [200, 40, 40]
    } else {
        [40, 200, 40]
    }
}

/// Writes a 16-bit greyscale depth PNG.
#[allow(dead_code)] // not every test file needs it
pub fn write_depth_png(path: &Path, width: u32, height: u32, values: &[u16]) {
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
    let mut encoder = png::Encoder::new(std::fs::File::create(path).unwrap(), width, height);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::Sixteen);
    let mut writer = encoder.write_header().unwrap();
    writer.write_image_data(&bytes).unwrap();
}

/// `simulate --track` (2 cm TSDF) of a 20 m wall at z = 0 along the TUM
/// path `poses`, with `extra` flags. Returns the run and its output folder.
#[allow(dead_code)] // not every test file needs it
pub fn track_wall_path(dir: &Path, poses: &str, extra: &[&str]) -> (Output, PathBuf) {
    std::fs::write(
        dir.join("wall.toml"),
        "[[object]]\nname = \"wall\"\nshape = \"box\"\nsize = [20.0, 20.0, 0.1]\n",
    )
    .unwrap();
    std::fs::write(dir.join("path.txt"), poses).unwrap();
    let out = dir.join("out");
    let path = format!("tum:{}", dir.join("path.txt").display());
    let scene = dir.join("wall.toml");
    let iterations = poses.lines().count().to_string();
    let mut args = vec![
        "simulate",
        "--scene",
        scene.to_str().unwrap(),
        "--map",
        "tsdf",
        "--voxel",
        "0.02",
        "--track",
        "--path",
        &path,
        "--iterations",
        &iterations,
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    (depthmesh(&args), out)
}

/// Six tracked frames of [`track_wall_path`]: the first sees the wall, then
/// the camera turns round to face nothing at all, so every frame after the
/// first is lost and not fused.
#[allow(dead_code)] // not every test file needs it
pub fn turn_away_from_a_wall(dir: &Path, extra: &[&str]) -> (Output, PathBuf) {
    let poses: String = (0..6)
        .map(|i| match i {
            0 => "0 0 0 -2 0 0 0 1\n".to_string(),
            i => format!("{i} 0 0 -2 0 1 0 0\n"),
        })
        .collect();
    track_wall_path(dir, &poses, extra)
}

/// Writes an 8-bit RGB PNG.
#[allow(dead_code)] // not every test file needs it
pub fn write_rgb_png(path: &Path, width: u32, height: u32, rgb: &[u8]) {
    let mut encoder = png::Encoder::new(std::fs::File::create(path).unwrap(), width, height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    encoder
        .write_header()
        .unwrap()
        .write_image_data(rgb)
        .unwrap();
}

/// A 7-Scenes style frames folder of the simulated table, 160×120,
/// `frames` frames along the helix: depth, poses, and colour by [`scene_colour`] (black where the
/// sensor sees nothing).
#[allow(dead_code)] // not every test file needs it
pub fn simulated_frames_folder(dir: &Path, frames: u32) {
    use depthmesh::sim::PathSpec;
    let scene = table_scene();
    let poses = PathSpec::Helix.build(&scene, frames).unwrap();
    scene_frames_folder(dir, &scene, &poses);
}

/// [`simulated_frames_folder`]'s first `frames` frames along a helix five
/// times as long: a camera moving 16 cm and 4° a frame, as `simulate
/// --iterations 200` does, which tracking follows. Along the short helix
/// it moves 80 cm and 20° a frame, and tracking loses it on most frames,
/// where a small change to the search changes which frames are posed.
#[allow(dead_code)] // not every test file needs it
pub fn followable_frames_folder(dir: &Path, frames: u32) {
    use depthmesh::sim::PathSpec;
    let scene = table_scene();
    let poses = PathSpec::Helix.build(&scene, 5 * frames).unwrap();
    scene_frames_folder(dir, &scene, &poses[..frames as usize]);
}

/// A 7-Scenes style frames folder of `scene` seen from `poses`, 160×120, as
/// [`simulated_frames_folder`].
#[allow(dead_code)] // not every test file needs it
pub fn scene_frames_folder(dir: &Path, scene: &depthmesh::sim::Scene, poses: &[depthmesh::Pose]) {
    use depthmesh::sim::{NoiseModel, SimulatedSensor};
    let k = depthmesh::Intrinsics::from_vertical_fov(160, 120, 60.0);
    let mut sensor = SimulatedSensor::new(k, 0.8, 4.0, NoiseModel::None, 0).unwrap();
    let mut writer = depthmesh::dataset::FramesWriter::create(dir, &k).unwrap();
    for (i, pose) in poses.iter().enumerate() {
        let frame = sensor.capture(scene, i as u32 + 1, pose);
        writer.write(i, &frame.depth, pose).unwrap();
        let rgb: Vec<u8> = (0..k.height)
            .flat_map(|v| (0..k.width).map(move |u| (u, v)))
            .zip(&frame.depth.data)
            .flat_map(|((u, v), &d)| match d > 0.0 {
                true => scene_colour(pose.transform_point(k.back_project(u as f32, v as f32, d))),
                false => [0; 3],
            })
            .collect();
        let colour = dir.join(format!("frame-{i:06}.color.png"));
        write_rgb_png(&colour, k.width, k.height, &rgb);
    }
}

/// `eval trajectory --json` of `estimate` against `reference` (a TUM file
/// or a dataset folder), which must succeed.
#[allow(dead_code)] // not every test file needs it
pub fn eval_json(estimate: &std::path::Path, reference: &std::path::Path) -> serde_json::Value {
    eval_json_with(estimate, reference, &[])
}

/// [`eval_json`] with `extra` flags.
#[allow(dead_code)] // not every test file needs it
pub fn eval_json_with(
    estimate: &std::path::Path,
    reference: &std::path::Path,
    extra: &[&str],
) -> serde_json::Value {
    let mut args = vec![
        "eval",
        "trajectory",
        estimate.to_str().unwrap(),
        reference.to_str().unwrap(),
        "--json",
    ];
    args.extend_from_slice(extra);
    let eval = depthmesh(&args);
    ok(&eval);
    serde_json::from_slice(&eval.stdout).unwrap()
}
