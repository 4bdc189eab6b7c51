//! The depthmesh mapping service (Mouser's client/server, seed 004): sensor
//! clients stream losslessly compressed depth over a WebSocket to
//! `depthmesh serve`, which runs a library [`depthmesh::session::Session`]
//! per client and answers each frame with a verdict and, on request, a
//! status image. Kept apart from the library so that tokio and axum reach
//! only the binary.

#![warn(missing_docs)]

pub mod client;
mod connection;
pub mod external;
mod jpeg;
pub mod protocol;
pub mod server;
mod view;
pub mod watcher;
mod web;
mod worker;

pub use client::{stream, FrameSource, Progress, SourceFrame, StreamOptions, StreamResult};
pub use external::ExternalView;
pub use server::{Limits, ServeOptions, Server};
