//! What a newcomer meets first (issue 19): results that cannot read as
//! accurate when they are not, one meaning per flag, limits instead of
//! crashes, and output folders that hold one run.

mod common;

use common::{assert_fails_with, depthmesh, ok, scratch};
use depthmesh::mesh::io::read_mesh;
use std::path::Path;

fn arg(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A TUM trajectory of `n` poses one second apart along x.
fn tum_line(n: usize) -> String {
    (0..n)
        .map(|t| format!("{t} {} 0 0 0 0 0 1\n", 0.1 * t as f64))
        .collect()
}

#[test]
fn eval_of_an_estimate_that_lost_most_frames_fails_and_says_how_few_it_covers() {
    let dir = scratch("nc-coverage");
    std::fs::write(dir.join("ref.txt"), tum_line(10)).unwrap();
    // A run lost after its second frame: two poses, both exact.
    std::fs::write(dir.join("est.txt"), tum_line(2)).unwrap();
    let (est, reference) = (dir.join("est.txt"), dir.join("ref.txt"));
    let out = depthmesh(&["eval", "trajectory", arg(&est), arg(&reference)]);
    assert_fails_with(&out, &["covers only 2 of the reference's 10 poses"]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("20 % of the reference's 10 poses"),
        "{stdout}"
    );
    // Asked to accept any coverage, the figures come with it.
    let out = depthmesh(&[
        "eval",
        "trajectory",
        arg(&est),
        arg(&reference),
        "--json",
        "--min-coverage",
        "0",
    ]);
    ok(&out);
    let e: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(e["reference_poses"], 10);
    assert_eq!(e["coverage"], 0.2);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn align_floor_keeps_a_level_floor_level() {
    let dir = scratch("nc-floor");
    let out = dir.join("run");
    // The table scene: a 10 m floor slab of a few large triangles under
    // finely tessellated furniture.
    ok(&depthmesh(&[
        "simulate",
        "--scene",
        "../../scenes/table.toml",
        "--map",
        "planes",
        "--iterations",
        "1",
        "--quiet",
        "--out",
        arg(&out),
    ]));
    let glb = dir.join("scene.glb");
    ok(&depthmesh(&[
        "export",
        arg(&out.join("scene.ply")),
        "-o",
        arg(&glb),
        "--align-floor",
        "--quiet",
    ]));
    let mesh = read_mesh(&glb).unwrap();
    // The slab's corners, 7 m from its centre: levelled, each face's four
    // are at one height. 1 mm over 7 m is 0.008°; the issue saw 27 cm (0.9°).
    let corners: Vec<glam::Vec3> = mesh
        .positions
        .iter()
        .copied()
        .filter(|p| p.x.abs() > 4.99 && p.z.abs() > 4.99)
        .collect();
    assert!(corners.len() >= 8, "{corners:?}");
    let (low, high) = corners
        .iter()
        .fold((f32::MAX, f32::MIN), |(l, h), p| (l.min(p.y), h.max(p.y)));
    for c in &corners {
        let nearest = if (c.y - low).abs() < (c.y - high).abs() {
            low
        } else {
            high
        };
        assert!((c.y - nearest).abs() < 1e-3, "corner {c} of {corners:?}");
    }
    // The floor's top is at height 0 (the slab is 10 cm thick).
    assert!(high.abs() < 1e-3 || low.abs() < 1e-3, "{low} {high}");
    std::fs::remove_dir_all(dir).unwrap();
}
