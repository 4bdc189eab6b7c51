//! The scene itself as the model a tracker aligns frames against: what a
//! perfect map would predict. Tracking against it instead of the fused map
//! separates the tracker's own error from the error the map's rendition of
//! the scene adds (thin parts, silhouettes, surface first seen).

use super::sensor::check_range;
use super::{NoiseModel, Scene, SimulatedSensor};
use crate::camera::{Intrinsics, Pose};
use crate::error::Result;
use crate::image::{DepthImage, Frame};
use crate::map::{IntegrateReport, MapStats, Mapper};
use crate::mesh::Mesh;
use std::sync::Mutex;

/// The scene rendered without noise from any pose, as a [`Mapper`] that
/// fuses nothing.
#[derive(Debug)]
pub struct SceneModel {
    scene: Scene,
    near: f32,
    far: f32,
    /// The iteration of the last frame fused: which of a dynamic scene's
    /// objects are present.
    iteration: u32,
    mesh: Mesh,
    /// A noiseless sensor per camera model asked for (a tracker asks for
    /// two, the coarse and the fine view), kept with their buffers.
    sensors: Mutex<Vec<SimulatedSensor>>,
}

impl SceneModel {
    /// The model of `scene` seen within `near`–`far` metres, the range of
    /// the sensor whose frames are tracked.
    pub fn new(scene: Scene, near: f32, far: f32) -> Result<Self> {
        check_range(near, far)?;
        Ok(SceneModel {
            scene,
            near,
            far,
            iteration: 1,
            mesh: Mesh::default(),
            sensors: Mutex::new(Vec::new()),
        })
    }
}

impl Mapper for SceneModel {
    fn name(&self) -> &'static str {
        "scene"
    }

    fn integrate(&mut self, frame: &Frame, _: &Pose) -> Result<IntegrateReport> {
        self.iteration = u32::try_from(frame.index).unwrap_or(u32::MAX);
        Ok(IntegrateReport::default())
    }

    fn render_depth(&self, intrinsics: &Intrinsics, pose: &Pose) -> DepthImage {
        let mut sensors = self.sensors.lock().unwrap_or_else(|e| e.into_inner());
        let at = match sensors.iter().position(|s| s.intrinsics == *intrinsics) {
            Some(at) => at,
            // The range was checked when the model was made, and a tracker
            // asks only for views of the camera it validated: an invalid
            // camera sees nothing rather than failing the run.
            None => {
                match SimulatedSensor::new(*intrinsics, self.near, self.far, NoiseModel::None, 0) {
                    Ok(sensor) => {
                        sensors.push(sensor);
                        sensors.len() - 1
                    }
                    Err(_) => return DepthImage::new(intrinsics.width, intrinsics.height),
                }
            }
        };
        sensors[at].capture(&self.scene, self.iteration, pose).depth
    }

    fn mesh(&mut self) -> &Mesh {
        &self.mesh
    }

    fn stats(&self) -> MapStats {
        MapStats::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::SceneOptions;
    use std::path::Path;

    #[test]
    fn renders_what_a_noiseless_sensor_sees() {
        let text = "[[object]]\nshape = \"box\"\nsize = [4.0, 4.0, 0.1]\n";
        let scene = Scene::parse(text, Path::new("wall.toml"), &SceneOptions::default()).unwrap();
        let k = Intrinsics::from_vertical_fov(64, 48, 60.0);
        let pose = Pose::look_at(
            glam::Vec3::new(0.0, 0.0, 2.0),
            glam::Vec3::ZERO,
            glam::Vec3::Y,
        );
        let model = SceneModel::new(scene.clone(), 0.4, 6.0).unwrap();
        assert!(SceneModel::new(scene.clone(), 6.0, 0.4).is_err());
        let mut sensor = SimulatedSensor::new(k, 0.4, 6.0, NoiseModel::None, 0).unwrap();
        let seen = sensor.capture(&scene, 1, &pose).depth;
        assert_eq!(model.render_depth(&k, &pose).data, seen.data);
        // The wall's face is 1.95 m away along the axis.
        let centre = seen.data[24 * 64 + 32];
        assert!((centre - 1.95).abs() < 1e-3, "{centre}");
    }
}
