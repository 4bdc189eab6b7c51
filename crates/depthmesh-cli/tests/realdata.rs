//! The real-data check: 7-Scenes kitchen frames 0–99, tracked and fused,
//! every 15th frame of 0–299 tracked, every 10th tracked backwards, the
//! frames either side of a gap tracked, and every 5th of 150–299
//! relocalised in the map of 0–149.
//! Ignored by `cargo test`; `.ci/realdata` runs it with `--ignored`, with
//! `DEPTHMESH_SHARED` pointing at the folder that holds `data/` (and fails
//! when that folder is missing, rather than passing without it).
//!
//! The fused mesh is compared with a small stored summary of the expected
//! one, `kitchen_expected.json`: its triangle count and its distances from
//! a fixed set of probe points (on the surface, a few centimetres off it,
//! and spread through the room). `DEPTHMESH_WRITE_EXPECTED=1` rewrites that
//! summary from the current code instead of checking against it.

mod common;

use common::{depthmesh, eval_json_with, ok, scratch, summary};
use depthmesh::eval::distance::MeshDistance;
use depthmesh::eval::sample_surface;
use depthmesh::mesh::io::read_mesh;
use depthmesh::Mesh;
use glam::Vec3;
use serde_json::Value;
use std::path::{Path, PathBuf};

const FRAMES: &str = "0..100";
/// Probe distances are measured up to this far from the mesh.
const RADIUS: f32 = 0.5;

fn kitchen() -> PathBuf {
    let shared = std::env::var_os("DEPTHMESH_SHARED")
        .expect("DEPTHMESH_SHARED must name the folder holding data/ (.ci/realdata sets it)");
    let kitchen = PathBuf::from(shared).join("data/7scenes-redkitchen");
    assert!(kitchen.is_dir(), "{} is missing", kitchen.display());
    kitchen
}

/// Runs `reconstruct` on frames `frames` (`A..B`) of `data` with `extra`
/// flags, into a scratch folder named for `name`, which it returns.
fn reconstruct(data: &Path, frames: &str, name: &str, extra: &[&str]) -> PathBuf {
    let out = scratch(name);
    let mut args = vec!["reconstruct", data.to_str().unwrap(), "--frames", frames];
    args.extend(extra);
    args.extend(["--quiet", "--out", out.to_str().unwrap()]);
    ok(&depthmesh(&args));
    out
}

fn expected_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/kitchen_expected.json")
}

/// Tracks frames `frames` of the folder `data` with `extra` flags
/// (`--stride`), asserts none was lost, and gives the trajectory's error
/// against the folder's poses (`eval trajectory` with `eval_extra`).
fn tracked_without_loss(data: &Path, frames: &str, extra: &[&str], eval_extra: &[&str]) -> Value {
    let mut flags = vec!["--track"];
    flags.extend(extra);
    // A folder of its own per run: the tests may run side by side.
    let name = format!("real-track-{frames}{}", extra.concat());
    let out = reconstruct(data, frames, &name, &flags);
    let s = summary(&out);
    let e = eval_json_with(&out.join("trajectory.txt"), data, eval_extra);
    println!(
        "tracked kitchen frames {frames} {extra:?}: lost frames {}, {e}",
        s["lost_frames"]
    );
    assert_eq!(s["lost_frames"], 0, "{s}");
    std::fs::remove_dir_all(out).unwrap();
    e
}

#[test]
#[ignore = "needs the 7-Scenes frames; run by .ci/realdata"]
fn kitchen_frames_are_tracked_within_two_centimetres_without_loss() {
    // Judged against the same frames' poses: every one must be covered.
    let e = tracked_without_loss(&kitchen(), FRAMES, &[], &["--frames", FRAMES]);
    assert_eq!(e["matched"], 100);
    // Measured 1.36 cm RMSE and 3.83 cm at worst against the folder's
    // poses; the bounds are the project's 2 cm target and 5.5 cm.
    let ate = e["ate_rmse_cm"].as_f64().unwrap();
    assert!(ate < 2.0, "ATE {ate} cm");
    let worst = e["ate_max_cm"].as_f64().unwrap();
    assert!(worst < 5.5, "worst pose {worst} cm off");
}

/// Every 15th frame lands up to 9.7 cm and 7.5° from where the last
/// motion predicts it (the folder's poses; a median of 3.6 cm and 3.2°):
/// the scheduled iterations leave such a frame short of its pose, and only
/// those past the schedule bring it in. A view the kitchen already pins
/// well is pinned little better there, so the rule that keeps them also
/// counts the points they bring into agreement: judged by the view's
/// conditioning alone, three of the 20 frames were lost.
#[test]
#[ignore = "needs the 7-Scenes frames; run by .ci/realdata"]
fn every_fifteenth_kitchen_frame_is_tracked_without_loss() {
    // The 20 frames cover 7 % of the folder's poses.
    let e = tracked_without_loss(
        &kitchen(),
        "0..300",
        &["--stride", "15"],
        &["--min-coverage", "0.05"],
    );
    assert_eq!(e["matched"], 20);
    // Measured 4.63 cm (2.15 after rigid alignment), as the README's
    // strides table gives it.
    let ate = e["ate_rmse_cm"].as_f64().unwrap();
    assert!(ate < 6.0, "ATE {ate} cm");
}

/// The trajectory error `e` (of `eval trajectory`) is below `rmse` cm,
/// and below `aligned` cm after rigid alignment.
fn assert_ate_below(e: &Value, rmse: f64, aligned: f64) {
    let ate = e["ate_rmse_cm"].as_f64().unwrap();
    assert!(ate < rmse, "ATE {ate} cm");
    let after = e["ate_rmse_aligned_cm"].as_f64().unwrap();
    assert!(after < aligned, "ATE after rigid alignment {after} cm");
}

/// The kitchen played backwards, every 10th frame (frames 299, 289, …, 9,
/// a third of a second apart, renumbered from 0 in a folder of links, as
/// `bench/track_reversed.sh 0 300 10` plays them): a path none of the
/// tracker's settings was chosen on, every motion the other way round.
#[test]
#[ignore = "needs the 7-Scenes frames; run by .ci/realdata"]
fn the_kitchen_played_backwards_every_tenth_frame_is_tracked_without_loss() {
    let reversed = linked_frames(
        "real-reversed-frames",
        (0..300).rev().step_by(10).enumerate(),
    );
    let e = tracked_without_loss(&reversed, "0..30", &[], &[]);
    assert_eq!(e["matched"], 30);
    // Measured 7.76 cm, 3.45 after rigid alignment (Open3D's dense SLAM on
    // the same frames: 139.25 and 57.34); the folder's pose of frame 299,
    // where the run starts, lies 5–7 cm from every tracker's trajectory.
    assert_ate_below(&e, 9.5, 4.5);
    std::fs::remove_dir_all(reversed).unwrap();
}

/// A scratch folder named for `name` with the camera's intrinsics and,
/// for each `(number, frame)` of `frames`, links to kitchen frame `frame`'s
/// files as frame `number`'s.
fn linked_frames(name: &str, frames: impl Iterator<Item = (usize, usize)>) -> PathBuf {
    let kitchen = kitchen();
    let folder = scratch(name);
    std::fs::copy(
        kitchen.join("camera-intrinsics.txt"),
        folder.join("camera-intrinsics.txt"),
    )
    .unwrap();
    for (number, frame) in frames {
        for file in ["depth.png", "color.jpg", "pose.txt"] {
            std::os::unix::fs::symlink(
                kitchen.join(format!("frame-{frame:06}.{file}")),
                folder.join(format!("frame-{number:06}.{file}")),
            )
            .unwrap();
        }
    }
    folder
}

/// The kitchen's default gap (`bench/track_gap.sh`): frames 150–219 left
/// out, so the camera reappears 0.35 m and 41° from where it was last
/// seen. Following loses frame 220 and the search finds the camera in that
/// frame, so no frame is lost.
#[test]
#[ignore = "needs the 7-Scenes frames; run by .ci/realdata"]
fn a_kitchen_camera_that_jumps_is_found_where_it_reappears() {
    let gap = linked_frames(
        "real-gap-frames",
        (0..300).filter(|i| !(150..220).contains(i)).map(|i| (i, i)),
    );
    let e = tracked_without_loss(&gap, "0..300", &[], &[]);
    assert_eq!(e["matched"], 230);
    // Measured 3.92 cm, 2.09 after rigid alignment: the 3 cm is met
    // only after alignment (the README's gap table says why), and these
    // bounds hold the run to what it does.
    assert_ate_below(&e, 4.5, 2.6);
    std::fs::remove_dir_all(gap).unwrap();
}

/// Relocalisation with no prior pose, as the README's default split
/// measures it (`eval relocalise` with the map of frames 0–149 and every
/// 5th frame of 150–299 as queries, the kitchen's gap bench's): every query
/// frame the map explains is found, and no pose is accepted off the
/// references refined against the map. Against the folder's poses 4 of
/// the 30 are off by 5–8 cm or up to 3°, where the map explains the frame
/// better at the pose found than at the reference (see the README), so
/// that count is printed, not held to 0.
#[test]
#[ignore = "needs the 7-Scenes frames; run by .ci/realdata"]
fn kitchen_frames_are_relocalised_with_no_prior_pose() {
    let data = kitchen();
    let output = depthmesh(&[
        "eval",
        "relocalise",
        data.to_str().unwrap(),
        "--map-frames",
        "0..150",
        "--query-frames",
        "150..300",
        "--stride",
        "5",
    ]);
    ok(&output);
    let r: Value = serde_json::from_slice(&output.stdout).unwrap();
    println!("relocalised kitchen frames 150..300 every 5th in the map of 0..150: {r}");
    assert_eq!(r["queries"], 30, "{r}");
    // Measured: 8 of 8 explained found, 17 of 17 against the refined
    // references, none of those wrong; the issue asks 80 % and 0 %.
    for share in ["found_share", "found_share_refined"] {
        let found = r[share].as_f64().unwrap();
        assert!(found >= 0.8, "{share} {found}: {r}");
    }
    assert!(r["explained_refined"].as_u64().unwrap() >= 10, "{r}");
    assert_eq!(r["wrongly_accepted_refined"], 0, "{r}");
}

/// Probe points for a mesh: points on its surface, the same points moved
/// 2–4 cm off it, and a lattice through its bounding box.
fn probes(mesh: &Mesh) -> Vec<Vec3> {
    let on: Vec<Vec3> = sample_surface(mesh, 0.02);
    let step = (on.len() / 150).max(1);
    let on: Vec<Vec3> = on.into_iter().step_by(step).take(150).collect();
    let off = on.iter().map(|p| *p + Vec3::new(0.02, -0.03, 0.025));
    let b = mesh.bounds();
    let lattice = (0..125).map(|i| {
        let t = Vec3::new((i % 5) as f32, ((i / 5) % 5) as f32, (i / 25) as f32);
        b.min + (b.max - b.min) * (t + 0.5) / 5.0
    });
    on.iter().copied().chain(off).chain(lattice).collect()
}

/// Distances from `points` to `mesh`, `None` beyond [`RADIUS`].
fn distances(mesh: &Mesh, points: &[Vec3]) -> Vec<Option<f32>> {
    let index = MeshDistance::new(mesh, RADIUS);
    points.iter().map(|p| index.distance(*p)).collect()
}

#[test]
#[ignore = "needs the 7-Scenes frames; run by .ci/realdata"]
fn kitchen_frames_fuse_into_the_expected_mesh() {
    let out = reconstruct(&kitchen(), FRAMES, "real-fuse", &[]);
    let mesh = read_mesh(&out.join("mesh.ply")).unwrap();
    std::fs::remove_dir_all(out).unwrap();
    if std::env::var_os("DEPTHMESH_WRITE_EXPECTED").is_some() {
        let points = probes(&mesh);
        // One probe a line, to the tenth of a millimetre: a small file.
        let rows: Vec<String> = points
            .iter()
            .zip(distances(&mesh, &points))
            .map(|(p, d)| {
                let d = d.map_or("null".into(), |d| format!("{d:.5}"));
                format!("    [{:.5}, {:.5}, {:.5}, {d}]", p.x, p.y, p.z)
            })
            .collect();
        let text = format!(
            "{{\n  \"made_by\": \"depthmesh reconstruct 7scenes-redkitchen --frames {FRAMES} \
             (1 cm TSDF, given poses)\",\n  \"triangles\": {},\n  \"radius_m\": {RADIUS},\n  \
             \"probes_x_y_z_distance_m\": [\n{}\n  ]\n}}\n",
            mesh.triangle_count(),
            rows.join(",\n")
        );
        std::fs::write(expected_path(), text).unwrap();
        println!("wrote {}", expected_path().display());
        return;
    }
    let expected: Value =
        serde_json::from_str(&std::fs::read_to_string(expected_path()).unwrap()).unwrap();
    let want_triangles = expected["triangles"].as_u64().unwrap() as f64;
    let rows = expected["probes_x_y_z_distance_m"].as_array().unwrap();
    let points: Vec<Vec3> = rows
        .iter()
        .map(|r| Vec3::from_array(std::array::from_fn(|i| r[i].as_f64().unwrap() as f32)))
        .collect();
    let got = distances(&mesh, &points);
    // A probe with no surface within the radius before and after agrees;
    // one that gained or lost its surface is off by the whole radius.
    let mut deltas: Vec<f32> = rows
        .iter()
        .zip(&got)
        .map(|(r, d)| {
            let want = r[3].as_f64().map(|w| w as f32);
            (want.unwrap_or(RADIUS) - d.unwrap_or(RADIUS)).abs()
        })
        .collect();
    deltas.sort_by(f32::total_cmp);
    let mean = deltas.iter().sum::<f32>() / deltas.len() as f32;
    let p95 = deltas[deltas.len() * 95 / 100];
    let triangles = mesh.triangle_count() as f64;
    println!(
        "fused kitchen frames {FRAMES}: {triangles} triangles (expected {want_triangles}), \
         probe distances off by {:.2} mm on average, {:.2} mm at the 95th percentile ({} probes)",
        mean * 1e3,
        p95 * 1e3,
        deltas.len()
    );
    // The expected mesh is this code's own; the bounds let fusion change a
    // little (2 % more or fewer triangles, probes off by 1 mm on average,
    // 3 mm for 95 % of them) but not move the surface by half a voxel.
    assert!(
        (triangles / want_triangles - 1.0).abs() < 0.02,
        "{triangles} triangles, expected about {want_triangles}"
    );
    assert!(mean < 0.001, "probes off by {mean} m on average");
    assert!(p95 < 0.003, "probes off by {p95} m at the 95th percentile");
}
