//! Camera tracking, the tracking half of KinectFusion (seed 004, §3.1):
//! depth frames without poses become a trajectory.
//!
//! Each frame is smoothed by a bilateral filter ([`filter`]), turned into a
//! three-level pyramid of vertex and normal maps ([`pyramid`]) and aligned
//! by projective point-to-plane ICP ([`icp`]) against what the map predicts
//! from the last good pose — any back-end's [`crate::map::Mapper::render_depth`]
//! — coarse to fine, starting from a constant-velocity guess ([`tracker`]).
//! An alignment with too few matches, a large residual, a direction left
//! unconstrained (a single wall) or an implausible jump is reported as lost,
//! and the frame is not fused; the next frame searches wider around the last
//! good pose.

pub mod filter;
pub mod icp;
pub mod pyramid;
pub mod tracker;

pub use tracker::{LostReason, Tracked, Tracker, TrackerConfig};
