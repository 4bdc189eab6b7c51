//! Sensor paths: where the simulated camera is, and where it looks, at each iteration.

use super::scene::{HelixParams, Scene};
use crate::camera::Pose;
use crate::error::{Error, Result};
use crate::mesh::Aabb;
use crate::trajectory::read_tum;
use glam::Vec3;
use std::f32::consts::TAU;
use std::fmt;
use std::path::PathBuf;
use std::str::FromStr;

/// `n` evenly spaced fractions from 0 to 1 inclusive (just 0 when `n` is 1).
fn fractions(n: u32) -> impl Iterator<Item = f32> {
    let last = n.saturating_sub(1).max(1) as f32;
    (0..n).map(move |i| i as f32 / last)
}

/// The thesis's helix: `turns` turns around the xz centre of `scene_bounds`,
/// diameters = the bounds' x and z extents + `margin`, rising linearly from
/// `height[0]` to `height[1]` while looking at a point moving linearly from
/// `look_at[0]` to `look_at[1]` (world coordinates, not offset by the centre).
pub fn helix(scene_bounds: Aabb, params: &HelixParams, iterations: u32) -> Vec<Pose> {
    let (centre, extent) = (scene_bounds.center(), scene_bounds.extent());
    let radius_x = 0.5 * (extent.x + params.margin);
    let radius_z = 0.5 * (extent.z + params.margin);
    let [y0, y1] = params.height;
    let [target0, target1] = params.look_at;
    fractions(iterations)
        .map(|t| {
            let angle = TAU * params.turns * t;
            let eye = Vec3::new(
                centre.x + radius_x * angle.sin(),
                y0 + (y1 - y0) * t,
                centre.z + radius_z * angle.cos(),
            );
            Pose::look_at(eye, target0.lerp(target1, t), Vec3::Y)
        })
        .collect()
}

/// A straight path from `from` to `to` at constant speed, always looking at `look_at`.
pub fn line(from: Vec3, to: Vec3, look_at: Vec3, iterations: u32) -> Vec<Pose> {
    fractions(iterations)
        .map(|t| Pose::look_at(from.lerp(to, t), look_at, Vec3::Y))
        .collect()
}

/// A sensor path as chosen on the command line (`--path`).
#[derive(Clone, Debug, PartialEq)]
pub enum PathSpec {
    /// The scene's helix (see [`helix`]).
    Helix,
    /// A pass along the far (−z) side of the scene, at the helix's start
    /// height, across the helix's x diameter, looking at its first target.
    Line,
    /// Poses read from a TUM trajectory file.
    Tum(PathBuf),
}

impl FromStr for PathSpec {
    type Err = Error;

    fn from_str(s: &str) -> Result<Self> {
        match s {
            "helix" => Ok(PathSpec::Helix),
            "line" => Ok(PathSpec::Line),
            _ => match s.strip_prefix("tum:") {
                Some(file) if !file.is_empty() => Ok(PathSpec::Tum(file.into())),
                _ => Err(Error::parameter(
                    "path",
                    format!("\"{s}\" is not a sensor path: use helix, line or tum:FILE"),
                )),
            },
        }
    }
}

impl fmt::Display for PathSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PathSpec::Helix => f.write_str("helix"),
            PathSpec::Line => f.write_str("line"),
            PathSpec::Tum(file) => write!(f, "tum:{}", file.display()),
        }
    }
}

impl PathSpec {
    /// The `iterations` poses (camera-to-world) of this path through `scene`.
    /// Fails on zero iterations, on a TUM file with too few poses, and on a
    /// path whose camera sits on its target or looks straight up or down
    /// (no image orientation is defined there).
    pub fn build(&self, scene: &Scene, iterations: u32) -> Result<Vec<Pose>> {
        let timed = self.build_timed(scene, iterations)?;
        Ok(timed.into_iter().map(|(_, pose)| pose).collect())
    }

    /// [`PathSpec::build`]'s poses with the time each frame is taken at: a
    /// TUM file's own timestamps, so that poses the file leaves out read as
    /// frames the sensor dropped (see [`crate::track::clock`]); the
    /// iteration (1, 2, …) along a helix or a line.
    pub fn build_timed(&self, scene: &Scene, iterations: u32) -> Result<Vec<(f64, Pose)>> {
        if iterations == 0 {
            return Err(Error::parameter("iterations", "must be at least 1"));
        }
        let bounds = scene.object_bounds();
        let poses = match self {
            PathSpec::Helix => numbered(helix(bounds, &scene.helix, iterations)),
            PathSpec::Line => numbered({
                let (c, e) = (bounds.center(), bounds.extent());
                let half = 0.5 * (Vec3::new(e.x, 0.0, e.z) + Vec3::splat(scene.helix.margin));
                let y = scene.helix.height[0];
                line(
                    Vec3::new(c.x - half.x, y, c.z - half.z),
                    Vec3::new(c.x + half.x, y, c.z - half.z),
                    scene.helix.look_at[0],
                    iterations,
                )
            }),
            PathSpec::Tum(file) => {
                let poses = read_tum(file)?;
                if poses.len() < iterations as usize {
                    return Err(Error::format(
                        file,
                        format!(
                            "{} poses, but {iterations} iterations were asked for",
                            poses.len()
                        ),
                    ));
                }
                let poses: Vec<(f64, Pose)> = poses.into_iter().take(iterations as usize).collect();
                // A frame's time places it on the trajectory written and
                // tells the tracker how many frames passed since the last.
                if let Some(i) = (1..poses.len()).find(|&i| {
                    poses[i].0.partial_cmp(&poses[i - 1].0) != Some(std::cmp::Ordering::Greater)
                }) {
                    return Err(Error::format(
                        file,
                        format!(
                            "pose {} at time {} does not come after pose {} at {}: timestamps must increase",
                            i + 1,
                            poses[i].0,
                            i,
                            poses[i - 1].0
                        ),
                    ));
                }
                poses
            }
        };
        if let Some(i) = poses
            .iter()
            .position(|(_, p)| !(p.rotation.is_finite() && p.translation.is_finite()))
        {
            return Err(Error::parameter(
                "path",
                format!(
                    "at iteration {} the {self} path puts the camera on its target or looks straight up or down",
                    i + 1
                ),
            ));
        }
        Ok(poses)
    }
}

/// `poses` with their iteration (1, 2, …) as the time they are taken at.
fn numbered(poses: Vec<Pose>) -> Vec<(f64, Pose)> {
    (1..).map(f64::from).zip(poses).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::scene::SceneOptions;
    use std::path::Path;

    fn table() -> Scene {
        Scene::parse(
            include_str!("../../../../scenes/table.toml"),
            Path::new("scenes/table.toml"),
            &SceneOptions::default(),
        )
        .unwrap()
    }

    /// Panics unless `target` projects to the image centre, in front of the camera, upright.
    fn assert_looks_at(pose: &Pose, target: Vec3) {
        let t = pose.inverse().transform_point(target);
        assert!(t.x.abs() < 1e-4 && t.y.abs() < 1e-4 && t.z > 0.0, "{t}");
        assert!(pose.inverse().transform_vector(Vec3::Y).y < 0.0);
    }

    #[test]
    fn helix_follows_the_thesis_geometry() {
        let scene = table();
        let bounds = scene.object_bounds();
        let poses = helix(bounds, &scene.helix, 30);
        assert_eq!(poses.len(), 30);
        // Table: x extent 1.0, z extent 0.75, centred at the origin in xz.
        let (rx, rz) = (0.5 * (1.0 + 4.0), 0.5 * (0.75 + 4.0));
        assert!(poses[0]
            .translation
            .abs_diff_eq(Vec3::new(0.0, 0.75, rz), 1e-4));
        // Two whole turns end where they began, but higher.
        assert!(poses[29]
            .translation
            .abs_diff_eq(Vec3::new(0.0, 1.5, rz), 1e-4));
        for (i, pose) in poses.iter().enumerate() {
            let t = i as f32 / 29.0;
            let p = pose.translation;
            assert!((p.y - (0.75 + 0.75 * t)).abs() < 1e-5);
            let ellipse = (p.x / rx).powi(2) + (p.z / rz).powi(2);
            assert!((ellipse - 1.0).abs() < 1e-4);
            assert_looks_at(pose, Vec3::new(0.0, 0.4 + 0.2 * t, 0.0));
        }
        // A quarter of a turn in (t = 1/8): on the +x side.
        let quarter = helix(bounds, &scene.helix, 9)[1].translation;
        assert!((quarter.x - rx).abs() < 1e-4 && quarter.z.abs() < 1e-4);
    }

    #[test]
    fn helix_is_centred_on_the_bounds_and_single_pose_is_the_start() {
        let bounds = Aabb {
            min: Vec3::new(1.0, 0.0, -3.0),
            max: Vec3::new(3.0, 1.0, -1.0),
        };
        let params = HelixParams::default();
        let poses = helix(bounds, &params, 1);
        assert_eq!(poses.len(), 1);
        assert!(poses[0]
            .translation
            .abs_diff_eq(Vec3::new(2.0, 0.75, -2.0 + 3.0), 1e-5));
        assert!(helix(bounds, &params, 0).is_empty());
    }

    #[test]
    fn line_path_crosses_the_far_side() {
        let scene = table();
        let poses = PathSpec::Line.build(&scene, 5).unwrap();
        let (rx, rz) = (2.5, 2.375);
        assert!(poses[0]
            .translation
            .abs_diff_eq(Vec3::new(-rx, 0.75, -rz), 1e-5));
        assert!(poses[4]
            .translation
            .abs_diff_eq(Vec3::new(rx, 0.75, -rz), 1e-5));
        assert!(poses[2]
            .translation
            .abs_diff_eq(Vec3::new(0.0, 0.75, -rz), 1e-5));
        for pose in &poses {
            assert_looks_at(pose, Vec3::new(0.0, 0.4, 0.0));
        }
    }

    #[test]
    fn path_spec_parses_and_prints() {
        for s in ["helix", "line", "tum:run/trajectory.txt"] {
            assert_eq!(s.parse::<PathSpec>().unwrap().to_string(), s);
        }
        for bad in ["spiral", "tum:", "Helix", ""] {
            let e = bad.parse::<PathSpec>().unwrap_err().to_string();
            assert!(
                e.contains("path") && e.contains("helix, line or tum:FILE"),
                "{e}"
            );
        }
    }

    #[test]
    fn tum_path_takes_the_first_poses_and_their_times_and_names_a_bad_file() {
        let dir = std::env::temp_dir().join(format!("depthmesh-sim-path-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("traj.txt");
        let poses: Vec<(f64, Pose)> = helix(table().object_bounds(), &HelixParams::default(), 4)
            .into_iter()
            .enumerate()
            .map(|(i, p)| (i as f64, p))
            .collect();
        std::fs::write(&file, crate::trajectory::format_tum(&poses)).unwrap();
        let spec = PathSpec::Tum(file.clone());
        let scene = table();
        let got = spec.build(&scene, 3).unwrap();
        assert_eq!(got.len(), 3);
        assert!(got[2].translation.abs_diff_eq(poses[2].1.translation, 1e-5));
        let e = spec.build(&scene, 5).unwrap_err().to_string();
        assert!(e.contains("traj.txt") && e.contains("4 poses"), "{e}");
        // The file's times, gaps and all, are the frames'.
        let gapped = [(0.5, poses[0].1), (0.6, poses[1].1), (1.1, poses[2].1)];
        std::fs::write(&file, crate::trajectory::format_tum(&gapped)).unwrap();
        let times: Vec<f64> = spec
            .build_timed(&scene, 3)
            .unwrap()
            .iter()
            .map(|(t, _)| *t)
            .collect();
        assert_eq!(times, [0.5, 0.6, 1.1]);
        let numbered: Vec<f64> = PathSpec::Helix
            .build_timed(&scene, 3)
            .unwrap()
            .iter()
            .map(|(t, _)| *t)
            .collect();
        assert_eq!(numbered, [1.0, 2.0, 3.0]);
        // Times that do not increase place no frame: refused, named.
        let back = [(0.5, poses[0].1), (0.6, poses[1].1), (0.6, poses[2].1)];
        std::fs::write(&file, crate::trajectory::format_tum(&back)).unwrap();
        let e = spec.build(&scene, 3).unwrap_err().to_string();
        assert!(
            e.contains("traj.txt") && e.contains("pose 3 at time 0.6"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn degenerate_paths_are_errors() {
        let mut scene = table();
        assert!(PathSpec::Helix.build(&scene, 0).is_err());
        // Margin 0 around a single point: the camera sits on its target.
        scene.objects.retain(|o| o.floor);
        scene.objects[0].mesh.positions = vec![Vec3::new(0.0, 0.4, 0.0)];
        scene.helix.margin = 0.0;
        scene.helix.height = [0.4, 0.4];
        scene.helix.look_at = [Vec3::new(0.0, 0.4, 0.0); 2];
        let e = PathSpec::Helix.build(&scene, 3).unwrap_err().to_string();
        assert!(e.contains("iteration 1"), "{e}");
    }
}
