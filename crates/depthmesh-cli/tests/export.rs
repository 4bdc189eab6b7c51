//! `simplify`, `export` and the mapping commands' `--export`, end to end:
//! chunk limits, coverage, and clear errors with no output for bad input.

use depthmesh::mesh::glb::read_glb;
use depthmesh::mesh::io::{read_mesh, write_mesh};
use depthmesh::Mesh;
use glam::Vec3;
use std::path::{Path, PathBuf};

mod common;
use common::{assert_fails_with as fails_with, depthmesh, ok, scratch};

/// A wavy `n`×`n` height field of 1 cm cells with colours: a stand-in for a scanned floor.
fn terrain(n: u32) -> Mesh {
    let mut m = Mesh::default();
    for j in 0..n {
        for i in 0..n {
            let (x, z) = (i as f32 * 0.01, j as f32 * 0.01);
            m.positions
                .push(Vec3::new(x, 0.05 * (x * 7.0).sin() * (z * 5.0).cos(), z));
            m.colors.push([(i % 256) as u8, (j % 256) as u8, 128]);
        }
    }
    for j in 0..n - 1 {
        for i in 0..n - 1 {
            let k = j * n + i;
            m.triangles.push([k, k + n, k + 1]);
            m.triangles.push([k + 1, k + n, k + n + 1]);
        }
    }
    m
}

fn input(dir: &Path) -> PathBuf {
    let path = dir.join("in.ply");
    write_mesh(&path, &terrain(300)).unwrap();
    path
}

fn arg(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn export_chunks_cover_the_mesh_within_the_limit() {
    let dir = scratch("chunks");
    let input = input(&dir);
    let out = dir.join("map.glb");
    ok(&depthmesh(&[
        "export",
        arg(&input),
        "-o",
        arg(&out),
        "--chunk-vertices",
        "20000",
        "--collision",
        "--quiet",
    ]));
    let nodes = read_glb(&out).unwrap();
    let render: Vec<_> = nodes.iter().filter(|n| !n.collision).collect();
    assert!(render.len() >= 5, "{} chunks", render.len());
    assert!(render.iter().all(|n| n.mesh.vertex_count() <= 20_000));
    assert_eq!(
        nodes.len(),
        2 * render.len(),
        "one collision mesh per chunk"
    );
    let triangles: usize = render.iter().map(|n| n.mesh.triangle_count()).sum();
    assert_eq!(triangles, 2 * 299 * 299);
    // The joined chunks are the input again (read_mesh joins the render nodes).
    let joined = read_mesh(&out).unwrap();
    let mut a: Vec<[u32; 3]> = joined
        .positions
        .iter()
        .map(|p| p.to_array().map(f32::to_bits))
        .collect();
    let mut b: Vec<[u32; 3]> = terrain(300)
        .positions
        .iter()
        .map(|p| p.to_array().map(f32::to_bits))
        .collect();
    a.sort();
    a.dedup();
    b.sort();
    assert_eq!(a, b);
    for n in nodes.iter().filter(|n| n.collision) {
        assert!(
            n.mesh.triangle_count() * 20 < triangles / render.len(),
            "collision is coarse"
        );
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn export_scales_turns_and_simplifies() {
    let dir = scratch("units");
    let input = input(&dir);
    let out = dir.join("unreal.glb");
    ok(&depthmesh(&[
        "export",
        arg(&input),
        "-o",
        arg(&out),
        "--scale",
        "50",
        "--up",
        "z",
        "--simplify",
        "0.1",
        "--quiet",
    ]));
    let mesh = read_mesh(&out).unwrap();
    assert!(mesh.triangle_count() <= 2 * 299 * 299 / 10 + 10);
    let b = mesh.bounds();
    // 2.99 m becomes 149.5 units; y-up becomes z-up (z → −y).
    assert!((b.extent().x - 149.5).abs() < 1e-3, "{b:?}");
    assert!(
        (b.min.y + 149.5).abs() < 1e-3 && b.max.y.abs() < 1e-3,
        "{b:?}"
    );
    assert!(b.extent().z < 0.11 * 50.0, "{b:?}");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn simplify_writes_the_target_in_any_format() {
    let dir = scratch("simplify");
    let input = input(&dir);
    for name in ["out.ply", "out.obj", "out.glb"] {
        let out = dir.join(name);
        ok(&depthmesh(&[
            "simplify",
            arg(&input),
            "-o",
            arg(&out),
            "--ratio",
            "0.05",
            "--quiet",
        ]));
        let mesh = read_mesh(&out).unwrap();
        assert!(mesh.triangle_count() <= 2 * 299 * 299 / 20 + 2, "{name}");
        assert_eq!(mesh.colors.len(), mesh.vertex_count(), "{name}");
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn bad_input_fails_clearly_and_writes_nothing() {
    let dir = scratch("bad");
    let input = input(&dir);
    let garbage = dir.join("garbage.ply");
    std::fs::write(&garbage, b"this is not a mesh\n").unwrap();
    let missing = dir.join("missing.ply");
    let out = dir.join("out.glb");
    let o = arg(&out);
    let cases: Vec<(Vec<&str>, Vec<&str>)> = vec![
        (
            vec!["simplify", arg(&missing), "-o", o, "--ratio", "0.5"],
            vec!["missing.ply"],
        ),
        (vec!["export", arg(&missing), "-o", o], vec!["missing.ply"]),
        (
            vec!["simplify", arg(&garbage), "-o", o, "--ratio", "0.5"],
            vec!["garbage.ply", "PLY"],
        ),
        (vec!["export", arg(&garbage), "-o", o], vec!["garbage.ply"]),
        (
            vec!["simplify", arg(&input), "-o", o, "--ratio", "0"],
            vec!["--ratio"],
        ),
        (
            vec!["simplify", arg(&input), "-o", o, "--ratio", "1.5"],
            vec!["--ratio"],
        ),
        (vec!["simplify", arg(&input), "-o", o], vec!["ratio"]),
        (
            vec!["simplify", arg(&input), "-o", o, "--max-error=-1"],
            vec!["--max-error"],
        ),
        (
            vec!["export", arg(&input), "-o", o, "--chunk-vertices", "0"],
            vec!["--chunk-vertices"],
        ),
        (
            vec!["export", arg(&input), "-o", o, "--simplify", "2"],
            vec!["--simplify"],
        ),
        (
            vec!["export", arg(&input), "-o", o, "--scale=-1"],
            vec!["--scale"],
        ),
        (
            vec!["export", arg(&input), "-o", o, "--format", "fbx"],
            vec!["--format", "fbx"],
        ),
    ];
    for (args, needles) in &cases {
        fails_with(&depthmesh(args), needles);
    }
    let unknown = dir.join("out.fbx");
    fails_with(
        &depthmesh(&["export", arg(&input), "-o", arg(&unknown)]),
        &["out.fbx", "--format"],
    );
    let mut left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    assert_eq!(left, ["garbage.ply", "in.ply"]);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn simulate_exports_its_final_mesh() {
    let dir = scratch("simulate");
    ok(&depthmesh(&[
        "simulate",
        "--scene",
        "../../scenes/table.toml",
        "--iterations",
        "2",
        "--quiet",
        "--export",
        "glb",
        "--simplify",
        "0.3",
        "--out",
        arg(&dir),
    ]));
    let ply = read_mesh(&dir.join("mesh.ply")).unwrap();
    let glb = read_mesh(&dir.join("mesh.glb")).unwrap();
    assert!(glb.triangle_count() > 0);
    assert!(glb.triangle_count() < ply.triangle_count() / 2);
    // A bad export flag stops the run before it maps anything.
    let bad = scratch("simulate-bad");
    fails_with(
        &depthmesh(&[
            "simulate",
            "--scene",
            "../../scenes/table.toml",
            "--iterations",
            "2",
            "--quiet",
            "--export",
            "glb",
            "--simplify",
            "0",
            "--out",
            arg(&bad),
        ]),
        &["--simplify"],
    );
    assert!(!bad.join("mesh.ply").exists());
    std::fs::remove_dir_all(dir).unwrap();
    std::fs::remove_dir_all(bad).unwrap();
}
