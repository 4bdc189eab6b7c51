//! depthmesh: incremental triangle-mesh maps from depth images.
//!
//! The crate holds the algorithms; the `depthmesh` binary holds the command line.
//! See `ARCHITECTURE.md` at the repository root for where things live.

pub mod atomic;
pub mod camera;
pub mod codec;
pub mod dataset;
pub mod error;
pub mod eval;
pub mod export;
pub mod image;
pub mod linalg;
pub mod mabdi;
pub mod map;
pub mod mesh;
pub mod palette;
pub mod planes;
pub mod raster;
pub mod session;
pub mod sim;
pub mod store;
pub mod track;
pub mod trajectory;
pub mod tsdf;
mod worker_slots;

pub use camera::{Intrinsics, Pose};
pub use error::{Error, Result};
pub use image::{ColorImage, DepthImage, Frame};
pub use mesh::{Aabb, Mesh};
