//! `depthmesh cluster status`: the site's workers, shards, lag per sensor
//! and frames per second, from the heartbeats, leases and checkpoints.

use crate::checkpoint::{read_manifest, shard_key};
use crate::error::{ClusterError, Result};
use crate::fetch::{frames_by_sensor, SensorFrames};
use crate::site::{live_entries, Site, SiteConfig};
use crate::tracker::TrackerBeat;
use crate::worker::Heartbeat;
use async_nats::jetstream::consumer::{pull, DeliverPolicy};
use serde::Serialize;
use std::collections::BTreeMap;
use std::time::Duration;

/// One shard as the site knows it.
#[derive(Clone, Debug, Serialize)]
pub struct ShardStatus {
    /// The shard.
    pub shard: u32,
    /// Its owner, if leased.
    pub owner: Option<String>,
    /// The next stream position it will fuse (its owner's heartbeat, or
    /// after its checkpoint).
    pub next: u64,
    /// The position its last checkpoint includes.
    pub checkpoint: u64,
    /// Frames its last checkpoint had fused.
    pub frames: u64,
    /// Blocks in its last checkpoint.
    pub blocks: u64,
}

/// One sensor's frames and how many of them are not fused everywhere yet.
#[derive(Clone, Debug, Serialize)]
pub struct SensorStatus {
    /// Frames on the stream.
    pub frames: SensorFrames,
    /// Posed frames after the position of the shard furthest behind.
    pub lag: u64,
}

/// The site at one moment.
#[derive(Clone, Debug, Serialize)]
pub struct Status {
    /// The site.
    pub site: String,
    /// Its settings (`None` until its first worker sets them).
    pub settings: Option<SiteConfig>,
    /// The stream's last message.
    pub stream_last: u64,
    /// Live fusion workers.
    pub workers: Vec<Heartbeat>,
    /// Live trackers.
    pub trackers: Vec<TrackerBeat>,
    /// Frames per second of the slowest worker: every worker reads every
    /// frame, so the slowest sets the site's pace.
    pub frames_per_second: f64,
    /// Every shard.
    pub shards: Vec<ShardStatus>,
    /// Every sensor.
    pub sensors: BTreeMap<String, SensorStatus>,
    /// Messages after the position of the shard furthest behind.
    pub lag: u64,
}

/// The site's status now.
pub async fn status(site: &Site) -> Result<Status> {
    // A site no worker has set up yet has frames but no shards.
    let config = site.config().await?;
    let stream_last = site.last_seq().await?;
    let (workers, trackers) = heartbeats(site).await?;
    let mut shards = Vec::new();
    for s in 0..config.map_or(0, |c| c.regions.shards) {
        let owner = site
            .leases
            .get(shard_key(s))
            .await
            .map_err(|e| ClusterError::bus("cannot read a lease", e))?
            .map(|v| String::from_utf8_lossy(&v).into_owned());
        let manifest = read_manifest(site, s)
            .await?
            .map(|(m, _)| m)
            .unwrap_or_default();
        let live = workers
            .iter()
            .flat_map(|w| w.shards.iter())
            .find(|(shard, _)| *shard == s)
            .map(|(_, next)| *next);
        shards.push(ShardStatus {
            shard: s,
            owner,
            next: live.unwrap_or(manifest.seq + 1).max(manifest.seq + 1),
            checkpoint: manifest.seq,
            frames: manifest.frames,
            blocks: manifest.blocks,
        });
    }
    let behind = shards.iter().map(|s| s.next).min().unwrap_or(1);
    let mut sensors = BTreeMap::new();
    for (name, frames) in frames_by_sensor(site).await? {
        let lag = pending(site, &site.posed_subject(&name), behind).await?;
        sensors.insert(name, SensorStatus { frames, lag });
    }
    Ok(Status {
        site: site.name.clone(),
        settings: config,
        stream_last,
        frames_per_second: workers
            .iter()
            .map(|w| w.frames_per_second)
            .reduce(f64::min)
            .unwrap_or(0.0),
        workers,
        trackers,
        shards,
        sensors,
        lag: (stream_last + 1).saturating_sub(behind),
    })
}

/// The live fusion workers' and trackers' last heartbeats.
pub(crate) async fn heartbeats(site: &Site) -> Result<(Vec<Heartbeat>, Vec<TrackerBeat>)> {
    let (mut out, mut trackers) = (Vec::new(), Vec::new());
    for (key, bytes) in live_entries(&site.workers).await? {
        if key.starts_with("tracker.") {
            trackers.extend(serde_json::from_slice::<TrackerBeat>(&bytes));
        } else {
            out.extend(serde_json::from_slice::<Heartbeat>(&bytes));
        }
    }
    out.sort_by(|a, b| a.id.cmp(&b.id));
    trackers.sort_by(|a, b| a.id.cmp(&b.id));
    Ok((out, trackers))
}

/// Messages on `subject` from position `from` on.
async fn pending(site: &Site, subject: &str, from: u64) -> Result<u64> {
    let mut consumer = site
        .stream
        .create_consumer(pull::Config {
            filter_subject: subject.to_string(),
            deliver_policy: DeliverPolicy::ByStartSequence {
                start_sequence: from.max(1),
            },
            inactive_threshold: Duration::from_secs(5),
            ..Default::default()
        })
        .await
        .map_err(|e| ClusterError::bus("cannot count a sensor's waiting frames", e))?;
    let info = consumer
        .info()
        .await
        .map_err(|e| ClusterError::bus("cannot count a sensor's waiting frames", e))?;
    let pending = info.num_pending;
    let name = info.name.clone();
    let _ = site.stream.delete_consumer(&name).await;
    Ok(pending)
}
