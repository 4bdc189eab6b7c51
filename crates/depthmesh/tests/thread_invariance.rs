//! Results do not depend on the number of threads: TSDF fusion (with
//! colour), the rasterizer and simplification give bit-identical output on
//! pools of one and two threads, whatever `RAYON_NUM_THREADS` says.

use depthmesh::mesh::simplify::{simplify, SimplifyParams};
use depthmesh::raster::{Rasterizer, RenderTarget};
use depthmesh::sim::{NoiseModel, PathSpec, Scene, SceneOptions, SimulatedSensor};
use depthmesh::tsdf::mesh::MeshCache;
use depthmesh::tsdf::{TsdfConfig, TsdfVolume};
use depthmesh::{ColorImage, Intrinsics, Mesh, Pose};
use glam::Vec3;

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

/// Runs `work` on a pool of exactly `threads` threads.
fn in_pool<T: Send>(threads: usize, work: impl FnOnce() -> T + Send) -> Result<T> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?;
    Ok(pool.install(work))
}

/// A mesh's contents as bytes (floats by their bits, so that -0.0 and 0.0
/// differ): positions, normals, colours and triangles.
fn bytes(mesh: &Mesh) -> Vec<u8> {
    let floats = mesh
        .positions
        .iter()
        .chain(&mesh.normals)
        .flat_map(|p| p.to_array());
    let mut out: Vec<u8> = floats.flat_map(f32::to_le_bytes).collect();
    out.extend(mesh.colors.iter().flatten());
    out.extend(
        mesh.triangles
            .iter()
            .flatten()
            .flat_map(|i| i.to_le_bytes()),
    );
    out
}

/// One block's voxels: key, distances, weights and colours.
type Voxels = (glam::IVec3, Vec<i16>, Vec<u16>, Vec<[u8; 3]>);

fn table() -> Scene {
    let text = include_str!("../../../scenes/table.toml");
    Scene::parse(text, "table.toml".as_ref(), &SceneOptions::default()).unwrap()
}

/// A wavy height field of `n × n` quads (2·n² triangles), a stand-in for a
/// dense scanned surface, with a colour per vertex.
fn height_field(n: u32) -> Mesh {
    let mut mesh = Mesh::default();
    for j in 0..=n {
        for i in 0..=n {
            let (x, z) = (i as f32 / n as f32, j as f32 / n as f32);
            let y = 0.05 * (9.0 * x).sin() * (7.0 * z).cos() + 0.01 * (41.0 * x * z).sin();
            mesh.positions.push(Vec3::new(x, y, z));
            mesh.colors.push([(i % 256) as u8, (j % 256) as u8, 7]);
        }
    }
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i;
            let (b, c, d) = (a + 1, a + n + 1, a + n + 2);
            mesh.triangles.push([a, c, b]);
            mesh.triangles.push([b, c, d]);
        }
    }
    mesh.compute_vertex_normals();
    mesh
}

/// Fuses noisy simulated frames of the table, with a colour image made from
/// each pixel's depth and position, and returns every block's voxels
/// (sorted by key) and the mesh.
fn fuse_table() -> (Vec<Voxels>, Mesh) {
    let scene = table();
    let k = Intrinsics::from_vertical_fov(160, 120, 60.0);
    let mut sensor = SimulatedSensor::new(k, 0.8, 4.0, NoiseModel::Kinect, 5).unwrap();
    let mut config = TsdfConfig::new(0.02);
    config.color = true;
    let mut volume = TsdfVolume::new(config).unwrap();
    let mut cache = MeshCache::new(1);
    for (i, pose) in PathSpec::Helix.build(&scene, 6).unwrap().iter().enumerate() {
        let frame = sensor.capture(&scene, i as u32 + 1, pose);
        let mut color = ColorImage::new(k.width, k.height);
        for (p, (c, d)) in color.data.iter_mut().zip(&frame.depth.data).enumerate() {
            *c = [(d * 60.0) as u8, (p % 251) as u8, (i * 40) as u8];
        }
        volume
            .integrate(&frame.depth, Some(&color), &k, pose)
            .unwrap();
        cache.update(&volume);
    }
    let mut blocks: Vec<_> = volume
        .blocks()
        .iter()
        .map(|b| {
            let color = b.color.as_deref().map(|c| c.to_vec()).unwrap_or_default();
            (b.key, b.tsdf.to_vec(), b.weight.to_vec(), color)
        })
        .collect();
    blocks.sort_by_key(|b| (b.0.x, b.0.y, b.0.z));
    (blocks, cache.assemble())
}

#[test]
fn tsdf_fusion_with_colour_is_the_same_on_one_and_two_threads() -> Result<()> {
    let (blocks1, mesh1) = in_pool(1, fuse_table)?;
    let (blocks2, mesh2) = in_pool(2, fuse_table)?;
    assert!(mesh1.triangle_count() > 1000 && !mesh1.colors.is_empty());
    assert!(blocks1 == blocks2, "the voxels differ");
    assert!(bytes(&mesh1) == bytes(&mesh2), "the meshes differ");
    Ok(())
}

/// Depth and triangle ids of a dense mesh rendered from a few poses; a
/// copy of the mesh lies exactly on it, so every pixel is a depth tie that
/// the triangle ids must break the same way.
fn render_views() -> Vec<(Vec<u32>, Vec<u32>)> {
    let mut mesh = height_field(150);
    let copy = mesh.clone();
    mesh.append(&copy);
    let k = Intrinsics::from_vertical_fov(320, 240, 60.0);
    let mut rasterizer = Rasterizer::new();
    let mut target = RenderTarget::default();
    [
        Vec3::new(0.5, 1.0, -0.6),
        Vec3::new(-0.4, 0.6, 0.5),
        Vec3::new(1.5, 0.3, 1.4),
    ]
    .iter()
    .map(|&eye| {
        let pose = Pose::look_at(eye, Vec3::new(0.5, 0.0, 0.5), Vec3::Y);
        rasterizer.render(
            &mesh.positions,
            &mesh.triangles,
            &k,
            &pose,
            0.01,
            &mut target,
        );
        let depth = target.depth.data.iter().map(|d| d.to_bits()).collect();
        (depth, target.triangle.clone())
    })
    .collect()
}

#[test]
fn the_rasterizer_draws_the_same_pixels_on_one_and_two_threads() -> Result<()> {
    let one = in_pool(1, render_views)?;
    let two = in_pool(2, render_views)?;
    let seen = one[0].0.iter().filter(|&&d| d != 0).count();
    assert!(seen > 10_000, "only {seen} pixels see the mesh");
    for (view, (a, b)) in one.iter().zip(&two).enumerate() {
        assert!(a.0 == b.0, "depth differs in view {view}");
        assert!(a.1 == b.1, "triangle ids differ in view {view}");
    }
    Ok(())
}

#[test]
fn simplification_is_the_same_on_one_and_two_threads() -> Result<()> {
    // Above the size at which the simplifier splits the mesh into chunks.
    let mesh = height_field(200);
    assert!(mesh.triangle_count() >= 80_000);
    let params = SimplifyParams::ratio(0.1);
    let one = in_pool(1, || simplify(&mesh, &params))??;
    let two = in_pool(2, || simplify(&mesh, &params))??;
    assert!(one.mesh.triangle_count() <= mesh.triangle_count() / 10 + 2);
    assert!(bytes(&one.mesh) == bytes(&two.mesh), "the meshes differ");
    assert_eq!(one.error.to_bits(), two.error.to_bits());
    Ok(())
}
