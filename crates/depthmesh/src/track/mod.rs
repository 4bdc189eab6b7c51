//! Camera tracking, the tracking half of KinectFusion (seed 004, §3.1):
//! depth frames without poses become a trajectory.
//!
//! Each frame is smoothed by a bilateral filter ([`filter`]), turned into a
//! three-level pyramid of vertex and normal maps ([`pyramid`]) and aligned
//! by projective point-to-plane ICP ([`icp`]) against what the map predicts
//! from the last good pose — any back-end's [`crate::map::Mapper::render_depth`]
//! — coarse to fine, starting from a constant-velocity guess ([`tracker`])
//! carried across the frames the sensor dropped ([`clock`]).
//! Directions the view barely constrains (a floor, a long wall) keep the
//! guess instead of following the noise ([`degeneracy`]). A frame is lost
//! only when it contradicts the map: too few matches, a large residual, an
//! implausible jump, or points where earlier frames saw empty space
//! ([`free_space`]) at a pose off the motion's course; it is not fused. A
//! frame that kept its course but put points there (something moved into
//! view) is held: followed on, not fused; the frame after it is not held
//! to the map's surface where that frame saw something move in and it may
//! have moved on to ([`moved_in`]). A lost camera is searched for
//! near its last pose, turned on the spot there or carried round what it
//! looked at, by matching the frame's
//! local shape to the map's wherever the camera is
//! ([`global_registration`]), and from the keyframes most like the frame
//! ([`ferns`]); a pose found is verified against the map before the frame
//! is fused, and held to the space seen empty as a followed one is.

pub mod clock;
pub mod degeneracy;
pub mod ferns;
pub mod filter;
pub mod free_space;
pub mod global_registration;
pub mod icp;
pub mod moved_in;
pub mod pyramid;
pub mod tracker;

pub use tracker::{LostReason, Tracked, Tracker, TrackerConfig, TrackerState};
