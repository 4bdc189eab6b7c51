//! The simulated depth sensor: renders the scene as it is at an iteration,
//! adds the chosen noise and keeps only the sensor's range.

use crate::camera::{Intrinsics, Pose};
use crate::error::{Error, Result};
use crate::image::{DepthImage, Frame};
use crate::mesh::Mesh;
use crate::raster::{ChunkBounds, Geometry, Rasterizer, RenderTarget, NO_TRIANGLE};
use crate::sim::noise::NoiseModel;
use crate::sim::scene::Scene;

/// Rejects a sensor range that is not `0 < near < far` (metres).
pub(crate) fn check_range(near: f32, far: f32) -> Result<()> {
    if near > 0.0 && far > near && far.is_finite() {
        Ok(())
    } else {
        Err(Error::parameter(
            "sensor range",
            format!("need 0 < near < far, got near = {near} m, far = {far} m"),
        ))
    }
}

/// A simulated Kinect-class sensor.
#[derive(Debug)]
pub struct SimulatedSensor {
    /// Pinhole model of the sensor.
    pub intrinsics: Intrinsics,
    /// Minimum range in metres (closer surfaces give no measurement).
    pub near: f32,
    /// Maximum range in metres.
    pub far: f32,
    /// Noise added to the true depth.
    pub noise: NoiseModel,
    /// Seed of the noise; the same seed gives the same images.
    pub seed: u64,
    rasterizer: Rasterizer,
    target: RenderTarget,
    /// The world mesh of the objects present, and the objects' states
    /// ([`Scene::state_at`]) it was built for.
    world: Option<(Vec<Option<glam::Vec3>>, World)>,
}

/// The world as the sensor images it at one iteration.
#[derive(Debug)]
struct World {
    mesh: Mesh,
    /// Boxes of the mesh's triangle chunks, so a render skips what is out of view.
    chunks: ChunkBounds,
    /// Per triangle: whether its object returns no depth (`returns = false`).
    silent: Vec<bool>,
}

impl World {
    fn at(scene: &Scene, iteration: u32) -> World {
        let (mesh, ids) = scene.world_mesh(iteration);
        let silent = ids
            .iter()
            .map(|&i| !scene.objects[i as usize].returns)
            .collect();
        let mut chunks = ChunkBounds::default();
        chunks.extend(&mesh.positions, &mesh.triangles);
        World {
            mesh,
            chunks,
            silent,
        }
    }
}

impl SimulatedSensor {
    /// The MABDI thesis's sensor: 640×480, 60° vertical field of view, 0.8–4.0 m.
    pub fn kinect(noise: NoiseModel, seed: u64) -> Self {
        Self::new(Intrinsics::kinect(), 0.8, 4.0, noise, seed)
            .expect("the built-in sensor is valid")
    }

    /// A sensor with the given model and range; rejects an empty image or a
    /// range that is not `0 < near < far`.
    pub fn new(
        intrinsics: Intrinsics,
        near: f32,
        far: f32,
        noise: NoiseModel,
        seed: u64,
    ) -> Result<Self> {
        intrinsics.validate()?;
        check_range(near, far)?;
        Ok(SimulatedSensor {
            intrinsics,
            near,
            far,
            noise,
            seed,
            rasterizer: Rasterizer::new(),
            target: RenderTarget::default(),
            world: None,
        })
    }

    /// The frame the sensor takes at `iteration` (1-based) from `pose`.
    pub fn capture(&mut self, scene: &Scene, iteration: u32, pose: &Pose) -> Frame {
        let state = scene.state_at(iteration);
        if self.world.as_ref().is_none_or(|(s, _)| *s != state) {
            self.world = Some((state, World::at(scene, iteration)));
        }
        let world = &self.world.as_ref().expect("set above").1;
        let mesh = &world.mesh;
        // A tiny near plane: a surface closer than the minimum range still
        // hides what is behind it, it just gives no measurement.
        let geometry = Geometry {
            positions: &mesh.positions,
            triangles: &mesh.triangles,
            chunks: Some(&world.chunks),
        };
        self.rasterizer.render_visiting(
            geometry,
            &self.intrinsics,
            pose,
            0.01,
            &mut self.target,
            None,
            |_, _| false,
        );
        let mut depth: DepthImage = self.target.depth.clone();
        // Silent surfaces still hide what is behind them.
        if world.silent.contains(&true) {
            for (d, &t) in depth.data.iter_mut().zip(&self.target.triangle) {
                if t != NO_TRIANGLE && world.silent[t as usize] {
                    *d = 0.0;
                }
            }
        }
        self.noise
            .apply(&mut depth, self.near, self.far, self.seed, iteration);
        depth.clamp_range(self.near, self.far);
        Frame {
            index: iteration as usize,
            timestamp: iteration as f64,
            depth,
            color: None,
            pose: Some(*pose),
        }
    }
}
