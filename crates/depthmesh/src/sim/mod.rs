//! The simulator's world: scenes of objects, the sensor's path through them
//! and the noise of its depth images.
//!
//! Rendering the depth a sensor sees is the rasterizer's job; this module
//! only says what there is to see, from where, and how it is corrupted.

pub mod noise;
pub mod path;
pub mod scene;
pub mod shapes;

pub use noise::NoiseModel;
pub use path::PathSpec;
pub use scene::{HelixParams, Scene, SceneObject, SceneOptions};
