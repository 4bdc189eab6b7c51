//! The browser view of a session: the map as keyed parts (see
//! [`depthmesh::session::view`]) pushed to each viewer as they change, with
//! the sensor's trajectory, live figures and the latest status and depth
//! images.
//!
//! ```text
//! session thread ──feed──► hub (current parts, per-viewer pending) ──socket──► browser
//! ```
//!
//! The session's thread publishes at most every [`feed::TICK`] into the
//! [`hub::ViewHub`], which keeps the current version of every part and,
//! for each viewer, only the newest pending version of each part: a slow
//! or paused browser costs the mapping nothing and, when it catches up,
//! gets each part once. A viewer that connects late is given the current
//! map first, then the updates.

pub mod feed;
pub mod hub;
pub mod socket;
pub mod wire;
