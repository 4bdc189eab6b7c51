//! Command-line tests of camera tracking: `--track` on simulated sequences
//! and `eval trajectory`.

mod common;

use common::{assert_fails_with, depthmesh, ok, scratch, summary};
use serde_json::Value;

#[test]
fn a_noisy_simulated_sequence_is_tracked_within_a_centimetre() {
    let dir = scratch("track-room");
    let out = dir.join("out");
    ok(&depthmesh(&[
        "simulate",
        "--scene",
        "../../scenes/room.toml",
        "--map",
        "tsdf",
        "--voxel",
        "0.02",
        "--track",
        "--noise",
        "kinect",
        "--path",
        "line",
        "--iterations",
        "20",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ]));
    let s = summary(&out);
    assert_eq!(s["tracking"], true);
    assert_eq!(s["lost"], 0, "{s}");
    let ate = s["ate_rmse_cm"].as_f64().unwrap();
    assert!(ate < 1.0, "ATE {ate} cm");
    let stats = std::fs::read_to_string(out.join("stats.csv")).unwrap();
    assert!(stats
        .lines()
        .next()
        .unwrap()
        .ends_with(",conditioning,lost"));
    // The evaluation command agrees with the summary.
    let eval = depthmesh(&[
        "eval",
        "trajectory",
        out.join("trajectory.txt").to_str().unwrap(),
        out.join("groundtruth.txt").to_str().unwrap(),
        "--json",
    ]);
    ok(&eval);
    let e: Value = serde_json::from_slice(&eval.stdout).unwrap();
    assert_eq!(e["matched"], 20);
    assert!((e["ate_rmse_cm"].as_f64().unwrap() - ate).abs() < 1e-3);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn staring_at_a_flat_wall_is_tracked_not_lost() {
    let dir = scratch("track-wall");
    std::fs::write(
        dir.join("wall.toml"),
        "[[object]]\nname = \"wall\"\nshape = \"box\"\nsize = [20.0, 20.0, 0.1]\n",
    )
    .unwrap();
    // Sliding along the wall 2 m in front of it, looking at it.
    let poses: String = (0..6)
        .map(|i| format!("{i} {} 0 -2 0 0 0 1\n", 0.02 * i as f32))
        .collect();
    std::fs::write(dir.join("path.txt"), poses).unwrap();
    let out = dir.join("out");
    let path = format!("tum:{}", dir.join("path.txt").display());
    let run = depthmesh(&[
        "simulate",
        "--scene",
        dir.join("wall.toml").to_str().unwrap(),
        "--map",
        "tsdf",
        "--voxel",
        "0.02",
        "--track",
        "--path",
        &path,
        "--iterations",
        "6",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ]);
    ok(&run);
    let stderr = String::from_utf8_lossy(&run.stderr);
    // Nothing contradicts the map: the motions the wall leaves free come
    // from the motion model, and every frame is fused.
    assert!(!stderr.contains("tracking lost"), "{stderr}");
    let s = summary(&out);
    assert_eq!(s["lost"], 0);
    assert_eq!(s["lost_frames"], 0);
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
