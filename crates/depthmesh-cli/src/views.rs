//! What a person looks at during a simulated run: the per-iteration
//! dashboard of the MABDI thesis (Fig. 5.1) and the element-count plot.

use crate::draw::canvas::Canvas;
use crate::draw::colormap::{depth_colors, normal_shade, Colormap};
use crate::draw::dashboard::{compose, DashboardPanels, PANEL_HEIGHT, PANEL_WIDTH};
use crate::draw::plot::{LinePlot, Series};
use anyhow::{Context, Result};
use depthmesh::atomic::write_atomic;
use depthmesh::mabdi::classify::PixelClass;
use depthmesh::raster::{Rasterizer, RenderTarget, NO_TRIANGLE};
use depthmesh::session::FrameRecord;
use depthmesh::sim::Scene;
use depthmesh::{DepthImage, Intrinsics, Mesh, Pose};
use glam::Vec3;
use std::io::Write;
use std::path::{Path, PathBuf};

const BACKGROUND: [u8; 3] = [250, 250, 252];
const ENVIRONMENT: [u8; 3] = [150, 150, 150];
/// Opacity of the ground-truth environment drawn over the map.
const ENVIRONMENT_ALPHA: f32 = 0.3;
const PATH_COLOUR: [u8; 3] = [110, 190, 255];
const FRUSTUM_COLOUR: [u8; 3] = [20, 40, 220];
/// Length of the drawn frustum, metres.
const FRUSTUM_DEPTH: f32 = 0.6;

/// What the mapper shows of its last frame, for panels (e)–(f).
pub struct MapperView<'a> {
    /// The map's mesh after the frame.
    pub mesh: &'a Mesh,
    /// Triangles the frame added (S), at the end of the mesh's list.
    pub new_triangles: usize,
    /// The expected depth E, when the back-end predicts one.
    pub expected: Option<&'a DepthImage>,
    /// Pixel classes of the frame.
    pub classes: &'a [PixelClass],
}

/// Renders and writes dashboard images for a run.
pub struct Dashboard {
    /// The back-end's name, for titles and legends.
    map: &'static str,
    dir: PathBuf,
    view_pose: Pose,
    view: Intrinsics,
    sensor: Intrinsics,
    poses: Vec<Pose>,
    environment: Mesh,
    environment_iteration: u32,
    rasterizer: Rasterizer,
    target: RenderTarget,
    environment_target: RenderTarget,
}

impl Dashboard {
    /// Prepares the dashboard folder and a third-person camera that sees the
    /// whole sensor path from above and outside.
    pub fn new(
        map: &'static str,
        scene: &Scene,
        poses: &[Pose],
        sensor: Intrinsics,
        dir: &Path,
    ) -> Result<Self> {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        Ok(Dashboard {
            map,
            dir: dir.to_path_buf(),
            view_pose: third_person_pose(scene, poses),
            view: Intrinsics::from_vertical_fov(PANEL_WIDTH, PANEL_HEIGHT, 45.0),
            sensor,
            poses: poses.to_vec(),
            environment: scene.world_mesh(1).0,
            environment_iteration: 1,
            rasterizer: Rasterizer::new(),
            target: RenderTarget::default(),
            environment_target: RenderTarget::default(),
        })
    }

    /// Writes `iteration-NNN.png` for one iteration.
    pub fn draw(
        &mut self,
        iteration: u32,
        scene: &Scene,
        depth: &DepthImage,
        map: &MapperView,
        frames: &[FrameRecord],
    ) -> Result<()> {
        if scene
            .objects
            .iter()
            .any(|o| o.state_at(iteration) != o.state_at(self.environment_iteration))
        {
            self.environment = scene.world_mesh(iteration).0;
        }
        self.environment_iteration = iteration;
        let i = iteration as usize - 1;
        let mesh_view = self.third_person(map.mesh, &map.mesh.triangles, i);
        let start = map.mesh.triangles.len() - map.new_triangles;
        let novel_view = self.third_person(map.mesh, &map.mesh.triangles[start..], i);
        let (lo, hi) = (0.8, 4.0);
        let d = depth_colors(
            &depth.data,
            depth.width,
            depth.height,
            lo,
            hi,
            Colormap::Turbo,
        );
        let e = match map.expected {
            Some(e) => depth_colors(&e.data, e.width, e.height, lo, hi, Colormap::Turbo),
            None => Canvas::new(depth.width, depth.height, [0; 3]),
        };
        let mut classified = Canvas::new(depth.width, depth.height, [255; 3]);
        for (px, c) in classified.pixels.iter_mut().zip(map.classes) {
            if *c == PixelClass::Novel {
                *px = [0; 3];
            }
        }
        let plot = element_plot(self.map, frames, false).render(PANEL_WIDTH, PANEL_HEIGHT);
        let image = compose(
            &DashboardPanels {
                mesh_view: &mesh_view,
                novel_view: &novel_view,
                depth: &d,
                expected: &e,
                classified: &classified,
                plot: &plot,
            },
            &format!(
                "{} iteration {iteration} / {}",
                self.map.to_uppercase(),
                self.poses.len()
            ),
        );
        let png = image.encode_png();
        let path = self.dir.join(format!("iteration-{iteration:03}.png"));
        write_atomic(&path, |w| w.write_all(&png))?;
        Ok(())
    }

    /// Writes the final element counts of the map against the naive method.
    pub fn element_plot(&self, frames: &[FrameRecord], path: &Path) -> Result<()> {
        let png = element_plot(self.map, frames, self.map == "mabdi")
            .render(960, 640)
            .encode_png();
        write_atomic(path, |w| w.write_all(&png))?;
        Ok(())
    }

    /// The map (only `triangles` of it) from the third-person camera, lit and
    /// coloured by vertex colour, under a translucent environment, with the
    /// sensor path and the frustum at pose `i`.
    fn third_person(&mut self, mesh: &Mesh, triangles: &[[u32; 3]], i: usize) -> Canvas {
        let (v, pose) = (self.view, self.view_pose);
        self.rasterizer.render(
            &mesh.positions,
            triangles,
            &v,
            &pose,
            0.05,
            &mut self.target,
        );
        self.rasterizer.render(
            &self.environment.positions,
            &self.environment.triangles,
            &v,
            &pose,
            0.05,
            &mut self.environment_target,
        );
        let light = pose.transform_vector(Vec3::new(-0.3, -0.6, -1.0));
        let mut canvas = Canvas::new(v.width, v.height, BACKGROUND);
        let env = &self.environment;
        for (p, px) in canvas.pixels.iter_mut().enumerate() {
            let t = self.target.triangle[p];
            let mut colour = BACKGROUND;
            if t != NO_TRIANGLE {
                colour = lit_colour(mesh, triangles[t as usize], light);
            }
            let e = self.environment_target.triangle[p];
            let (dm, de) = (
                self.target.depth.data[p],
                self.environment_target.depth.data[p],
            );
            if e != NO_TRIANGLE && (t == NO_TRIANGLE || de < dm - 0.01) {
                let corners = env.triangles[e as usize].map(|k| env.positions[k as usize]);
                let shade = normal_shade(
                    (corners[1] - corners[0]).cross(corners[2] - corners[0]),
                    light,
                );
                for k in 0..3 {
                    let grey = ENVIRONMENT[k] as f32 * shade;
                    colour[k] = (colour[k] as f32 * (1.0 - ENVIRONMENT_ALPHA)
                        + grey * ENVIRONMENT_ALPHA) as u8;
                }
            }
            *px = colour;
        }
        let to_view = pose.inverse();
        let project = |w: Vec3| v.project(to_view.transform_point(w)).map(|s| (s.x, s.y));
        let path: Vec<(f32, f32)> = self
            .poses
            .iter()
            .filter_map(|p| project(p.translation))
            .collect();
        canvas.draw_polyline(&path, 2.0, PATH_COLOUR);
        let sensor = self.poses[i];
        let s = self.sensor;
        let corners = [
            (0.0, 0.0),
            (s.width as f32 - 1.0, 0.0),
            (s.width as f32 - 1.0, s.height as f32 - 1.0),
            (0.0, s.height as f32 - 1.0),
        ]
        .map(|(u, r)| project(sensor.transform_point(s.back_project(u, r, FRUSTUM_DEPTH))));
        let apex = project(sensor.translation);
        for k in 0..4 {
            if let (Some(a), Some(b)) = (corners[k], corners[(k + 1) % 4]) {
                canvas.draw_line(a, b, 1.5, FRUSTUM_COLOUR);
            }
            if let (Some(a), Some(b)) = (apex, corners[k]) {
                canvas.draw_line(a, b, 1.5, FRUSTUM_COLOUR);
            }
        }
        canvas
    }
}

/// A camera above and outside the scene's objects and the sensor path,
/// looking at the objects.
fn third_person_pose(scene: &Scene, poses: &[Pose]) -> Pose {
    let bounds = scene.object_bounds();
    let centre = bounds.center();
    let reach = poses
        .iter()
        .map(|p| (p.translation - centre).length())
        .fold(bounds.extent().length() * 0.5, f32::max);
    let eye = centre + Vec3::new(-0.55, 0.75, 1.0).normalize() * reach * 1.9;
    Pose::look_at(eye, centre, Vec3::Y)
}

/// A triangle's vertex colour (grey without colours), lit two-sided.
fn lit_colour(mesh: &Mesh, [a, b, c]: [u32; 3], light: Vec3) -> [u8; 3] {
    let corners = [a, b, c].map(|k| mesh.positions[k as usize]);
    let shade = normal_shade(
        (corners[1] - corners[0]).cross(corners[2] - corners[0]),
        light,
    );
    let base = mesh
        .colors
        .get(a as usize)
        .copied()
        .unwrap_or([200, 200, 200]);
    base.map(|x| (x as f32 * shade) as u8)
}

/// Writes `mesh` alone, lit and in its colours, from the dashboard's
/// third-person camera, half as close so the objects fill the image.
pub fn write_view(scene: &Scene, poses: &[Pose], mesh: &Mesh, path: &Path) -> Result<()> {
    let far = third_person_pose(scene, poses);
    let centre = scene.object_bounds().center();
    let eye = centre + (far.translation - centre) * 0.5;
    let pose = Pose::look_at(eye, centre, Vec3::Y);
    let view = Intrinsics::from_vertical_fov(1280, 960, 45.0);
    let mut target = RenderTarget::default();
    Rasterizer::new().render(
        &mesh.positions,
        &mesh.triangles,
        &view,
        &pose,
        0.05,
        &mut target,
    );
    let light = pose.transform_vector(Vec3::new(-0.3, -0.6, -1.0));
    let mut canvas = Canvas::new(view.width, view.height, BACKGROUND);
    for (px, &t) in canvas.pixels.iter_mut().zip(&target.triangle) {
        if t != NO_TRIANGLE {
            *px = lit_colour(mesh, mesh.triangles[t as usize], light);
        }
    }
    let png = canvas.encode_png();
    write_atomic(path, |w| w.write_all(&png))?;
    Ok(())
}

/// The plot of map size by iteration; with `compare`, also the cumulative
/// count of the thesis's traditional method that meshes every whole frame.
fn element_plot(map: &str, frames: &[FrameRecord], compare: bool) -> LinePlot {
    let counts: Vec<(f64, f64)> = frames
        .iter()
        .map(|f| (f.frame as f64, f.total_elements as f64))
        .collect();
    let mut series = vec![Series {
        name: map.to_uppercase(),
        colour: [30, 90, 200],
        points: counts,
        markers: true,
    }];
    if compare {
        let mut sum = 0.0;
        let naive = frames
            .iter()
            .map(|f| {
                sum += f.report.get("naive_elements").unwrap_or(0.0);
                (f.frame as f64, sum)
            })
            .collect();
        series.push(Series {
            name: "traditional (every frame meshed)".into(),
            colour: [210, 60, 40],
            points: naive,
            markers: true,
        });
    }
    LinePlot {
        title: if compare {
            "Elements in the global mesh".into()
        } else {
            String::new()
        },
        x_label: "iteration".into(),
        y_label: "number of elements".into(),
        series,
    }
}
