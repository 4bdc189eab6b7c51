//! The simulator's world: scenes of objects, the sensor's path through them
//! and the noise of its depth images.
//!
//! [`sensor`] puts them together: it renders the scene with the rasterizer,
//! adds the noise and keeps the sensor's range.

pub mod model;
pub mod noise;
pub mod path;
pub mod scene;
pub mod sensor;
pub mod shapes;

pub use model::SceneModel;
pub use noise::NoiseModel;
pub use path::PathSpec;
pub use scene::{HelixParams, Scene, SceneObject, SceneOptions};
pub use sensor::SimulatedSensor;
