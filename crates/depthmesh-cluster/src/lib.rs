//! depthmesh beyond one machine, on NATS JetStream (seed 004's several
//! robots, one map): sensors publish compressed frames to a site's stream,
//! workers share the site's TSDF by space (shards of regions, one owner
//! each, claimed with leases in a key-value bucket), checkpoint their
//! shards with the stream position they include into an object store, and
//! take over a dead worker's shards from its last checkpoint, replaying the
//! frames after it, so that no frame is lost and none is fused twice.
//! Sensors without poses are tracked once each, by a tracker worker that
//! publishes their frames again with the poses it found.
//!
//! Everything distributed is JetStream's: the stream orders and keeps the
//! frames, leases expire with the bucket's age limit, checkpoints are
//! committed by compare-and-set on a revision. This crate only decides what
//! to fuse and when to save it.

#![warn(missing_docs)]

pub mod checkpoint;
pub mod error;
pub mod fetch;
pub mod frames;
pub mod fuse;
pub mod keeper;
pub mod outage;
pub mod publish;
pub mod site;
pub mod status;
pub mod tracker;
pub mod view;
pub mod worker;

pub use error::{ClusterError, Result};
pub use site::{Site, SiteConfig};
