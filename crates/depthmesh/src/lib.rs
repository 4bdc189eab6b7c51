//! depthmesh: incremental triangle-mesh maps from depth images.
//!
//! The crate holds the algorithms; the `depthmesh` binary holds the command line.
//! See `ARCHITECTURE.md` at the repository root for where things live.

pub mod atomic;
pub mod camera;
pub mod error;
pub mod image;
pub mod mesh;

pub use camera::{Intrinsics, Pose};
pub use error::{Error, Result};
pub use image::{ColorImage, DepthImage, Frame};
pub use mesh::{Aabb, Mesh};
