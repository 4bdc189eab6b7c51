//! A site on the bus: its stream of frames, its buckets, its settings.
//!
//! Names, for site `S`: the stream `DM_S` holds the subjects
//! `dm.S.posed.SENSOR` (frames with their pose, what the fusion workers
//! fuse) and `dm.S.raw.SENSOR` (frames without one, for a tracker); the
//! key-value buckets `dm-S-meta` (the site's settings, each sensor's
//! camera), `dm-S-leases` (which worker owns which shard; entries expire
//! after the lease time), `dm-S-workers` (each live worker's figures, as
//! heartbeats that expire the same way) and `dm-S-shards` (each shard's last
//! checkpoint: the stream position it includes and its segments), and the
//! object store `dm-S-checkpoints` (the segments: TSDF blocks as the map
//! store compresses them).

use crate::error::{ClusterError, Result};
use crate::outage::ConnectionLog;
use async_nats::jetstream::{self, kv, object_store, stream};
use depthmesh::session::{MapConfig, TsdfSettings};
use depthmesh::tsdf::regions::Regions;
use depthmesh::tsdf::TsdfConfig;
use depthmesh::Intrinsics;
use depthmesh_server::protocol::valid_session_name;
use futures_util::{StreamExt, TryStreamExt};
use serde::{Deserialize, Serialize};
use std::time::Duration;

/// What every worker of a site must agree on: the TSDF's settings, the
/// depth range frames are read with, and how space is cut into shards.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SiteConfig {
    /// Voxel edge, metres.
    pub voxel: f32,
    /// Truncation distance, metres.
    pub truncation: f32,
    /// Weights stop growing here.
    pub max_weight: u16,
    /// Marching cubes meshes voxels fused at least this often.
    pub min_weight: u16,
    /// Nearer depths are dropped, metres.
    pub depth_min: f32,
    /// Farther depths are dropped, metres.
    pub depth_max: f32,
    /// Regions and shards.
    pub regions: Regions,
}

impl SiteConfig {
    /// The TSDF settings.
    pub fn tsdf(&self) -> TsdfConfig {
        let mut c = TsdfConfig::new(self.voxel);
        c.truncation = self.truncation;
        c.max_weight = self.max_weight;
        c.min_weight = self.min_weight;
        c
    }

    /// The site's TSDF as a session's map (a tracker's own map, a viewer's
    /// copy of the site's).
    pub fn map(&self) -> MapConfig {
        MapConfig::Tsdf(TsdfSettings {
            config: self.tsdf(),
            range: (self.depth_min, self.depth_max),
            remesh_every: 0,
            active_radius: None,
        })
    }

    /// Checks every number.
    pub fn validate(&self) -> Result<()> {
        self.tsdf().validate()?;
        self.regions.validate()?;
        if !(self.depth_min >= 0.0 && self.depth_max > self.depth_min && self.depth_max.is_finite())
        {
            return Err(depthmesh::Error::parameter(
                "depth_min",
                format!(
                    "need 0 ≤ depth_min < depth_max, got {} and {}",
                    self.depth_min, self.depth_max
                ),
            )
            .into());
        }
        Ok(())
    }

    /// What differs between `self` and `other`, for a refusal.
    fn differences(&self, other: &SiteConfig) -> String {
        self.fields()
            .into_iter()
            .zip(other.fields())
            .filter(|((_, a), (_, b))| a != b)
            .map(|((name, here), (_, there))| format!("{name} is {there} there, {here} here"))
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// Each setting by name, as a person writes it.
    fn fields(&self) -> [(&'static str, String); 8] {
        [
            ("voxel", self.voxel.to_string()),
            ("truncation", self.truncation.to_string()),
            ("max_weight", self.max_weight.to_string()),
            ("min_weight", self.min_weight.to_string()),
            ("depth_min", self.depth_min.to_string()),
            ("depth_max", self.depth_max.to_string()),
            ("region_blocks", self.regions.region_blocks.to_string()),
            ("shards", self.regions.shards.to_string()),
        ]
    }
}

/// One site's resources on the bus.
#[derive(Clone)]
pub struct Site {
    /// The site's name.
    pub name: String,
    /// The JetStream context.
    pub js: jetstream::Context,
    /// The stream of frames.
    pub stream: stream::Stream,
    /// Settings and sensors.
    pub meta: kv::Store,
    /// Shard leases.
    pub leases: kv::Store,
    /// Worker heartbeats.
    pub workers: kv::Store,
    /// Shard checkpoints (manifests).
    pub shards: kv::Store,
    /// Checkpoint segments.
    pub checkpoints: object_store::ObjectStore,
    /// How long a lease or a heartbeat lives without renewal.
    pub lease_ttl: Duration,
}

/// A new site's lease time: a dead worker's shards wait this long.
const DEFAULT_LEASE: Duration = Duration::from_secs(10);

/// The key of the site's settings in `meta`.
const CONFIG_KEY: &str = "config";

impl Site {
    /// Connects to the bus at `url` and opens site `name`, creating its
    /// stream and buckets if this is the first to use them. `lease` sets
    /// how long a shard's lease and a worker's heartbeat live unrenewed;
    /// `None` keeps the site's (10 s for a new site).
    pub async fn connect(url: &str, name: &str, lease: Option<Duration>) -> Result<Site> {
        check_name(name)?;
        if lease.is_some_and(|l| l < Duration::from_millis(500)) {
            return Err(depthmesh::Error::parameter(
                "lease",
                format!("{lease:?} is too short to renew (at least 0.5 s)"),
            )
            .into());
        }
        Site::build(bus(url).await?, name, lease).await
    }

    /// The site's resources on the bus `js`, made where missing.
    async fn build(js: jetstream::Context, name: &str, lease: Option<Duration>) -> Result<Site> {
        let stream_name = format!("DM_{name}");
        let stream = made_or_opened(
            js.get_or_create_stream(stream::Config {
                name: stream_name.clone(),
                subjects: vec![format!("dm.{name}.posed.*"), format!("dm.{name}.raw.*")],
                storage: stream::StorageType::File,
                // A sensor that publishes a frame again (a restarted
                // client) is kept once within this window.
                duplicate_window: Duration::from_secs(600),
                ..Default::default()
            }),
            || js.get_stream(&stream_name),
        )
        .await
        .map_err(|e| ClusterError::bus("cannot open the site's stream", e))?;
        let bucket = |suffix: &str| format!("dm-{name}-{suffix}");
        let meta = open_kv(&js, &bucket("meta"), Duration::ZERO, false).await?;
        let lease_ttl = lease.unwrap_or(DEFAULT_LEASE);
        let leases = open_kv(&js, &bucket("leases"), lease_ttl, lease.is_some()).await?;
        let workers = open_kv(&js, &bucket("workers"), lease_ttl, lease.is_some()).await?;
        let shards = open_kv(&js, &bucket("shards"), Duration::ZERO, false).await?;
        let store = format!("dm-{name}-checkpoints");
        let checkpoints = match js.get_object_store(&store).await {
            Ok(s) => s,
            Err(_) => made_or_opened(
                js.create_object_store(object_store::Config {
                    bucket: store.clone(),
                    storage: stream::StorageType::File,
                    ..Default::default()
                }),
                || js.get_object_store(&store),
            )
            .await
            .map_err(|e| ClusterError::bus("cannot create the checkpoint store", e))?,
        };
        let lease_ttl = match leases.status().await {
            Ok(s) if s.max_age() > Duration::ZERO => s.max_age(),
            _ => lease_ttl,
        };
        Ok(Site {
            name: name.to_string(),
            js,
            stream,
            meta,
            leases,
            workers,
            shards,
            checkpoints,
            lease_ttl,
        })
    }

    /// Opens site `name` on the bus at `url` if it exists (frames were
    /// published to it or a worker ran), without creating anything.
    pub async fn open(url: &str, name: &str) -> Result<Site> {
        check_name(name)?;
        let js = bus(url).await?;
        if js.get_stream(format!("DM_{name}")).await.is_err() {
            return Err(ClusterError::site(
                name,
                format!("no such site on {url}: nothing was published to it and no worker ran"),
            ));
        }
        Site::build(js, name, None).await
    }

    /// Reads the site's lease time again: a worker started with
    /// `--lease-seconds` may have changed it since this process connected.
    pub async fn refresh_lease(&mut self) -> Result<()> {
        // The bucket's own status is what it was when opened: ask its stream.
        let info = self
            .js
            .get_stream(format!("KV_{}", self.leases.name))
            .await
            .map_err(|e| ClusterError::bus("cannot read the lease time", e))?
            .get_info()
            .await
            .map_err(|e| ClusterError::bus("cannot read the lease time", e))?;
        if info.config.max_age > Duration::ZERO {
            self.lease_ttl = info.config.max_age;
        }
        Ok(())
    }

    /// The subject of posed frames from `sensor`.
    pub fn posed_subject(&self, sensor: &str) -> String {
        format!("dm.{}.posed.{sensor}", self.name)
    }

    /// The subject of frames without poses from `sensor`.
    pub fn raw_subject(&self, sensor: &str) -> String {
        format!("dm.{}.raw.{sensor}", self.name)
    }

    /// The message id of frame `index` on `subject`: the stream keeps one
    /// message per id (within its duplicate window), so a frame published
    /// again, by a restarted client or by two trackers in a race, is kept
    /// once. The subject is part of it: a frame's posed copy is another message.
    pub fn frame_id(subject: &str, index: u64) -> String {
        format!("{subject}#{index}")
    }

    /// The sensor a subject of this site names, and whether its frames are posed.
    pub fn sensor_of<'a>(&self, subject: &'a str) -> Option<(&'a str, bool)> {
        let rest = subject
            .strip_prefix("dm.")?
            .strip_prefix(self.name.as_str())?;
        if let Some(s) = rest.strip_prefix(".posed.") {
            return Some((s, true));
        }
        rest.strip_prefix(".raw.").map(|s| (s, false))
    }

    /// The site's settings, if any worker or replay has set them.
    pub async fn config(&self) -> Result<Option<SiteConfig>> {
        let Some(bytes) = self
            .meta
            .get(CONFIG_KEY)
            .await
            .map_err(|e| ClusterError::bus("cannot read the site's settings", e))?
        else {
            return Ok(None);
        };
        serde_json::from_slice(&bytes)
            .map(Some)
            .map_err(|e| ClusterError::site(&self.name, format!("unreadable settings: {e}")))
    }

    /// Makes `wanted` the site's settings if it has none; refuses, saying
    /// what differs, if it has others.
    pub async fn settle_config(&self, wanted: &SiteConfig) -> Result<()> {
        wanted.validate()?;
        let bytes = serde_json::to_vec(wanted).expect("settings serialise");
        if self.meta.create(CONFIG_KEY, bytes.into()).await.is_ok() {
            return Ok(());
        }
        match self.config().await? {
            Some(c) if c == *wanted => Ok(()),
            Some(c) => Err(ClusterError::site(
                &self.name,
                format!("its map has other settings: {}", wanted.differences(&c)),
            )),
            None => Err(ClusterError::Bus(
                "the site's settings could be neither created nor read".into(),
            )),
        }
    }

    /// The settings, which a worker or a replay must have set.
    pub async fn required_config(&self) -> Result<SiteConfig> {
        self.config().await?.ok_or_else(|| {
            ClusterError::site(&self.name, "has no map settings yet: no worker has run")
        })
    }

    /// The camera of `sensor`, as its first frames were published with.
    pub async fn sensor(&self, sensor: &str) -> Result<Option<Intrinsics>> {
        let Some(bytes) = self
            .meta
            .get(format!("sensor.{sensor}"))
            .await
            .map_err(|e| ClusterError::bus("cannot read a sensor's camera", e))?
        else {
            return Ok(None);
        };
        serde_json::from_slice(&bytes).map(Some).map_err(|e| {
            ClusterError::site(
                &self.name,
                format!("sensor {sensor}: unreadable camera: {e}"),
            )
        })
    }

    /// Records `sensor`'s camera; a sensor publishing again must have the same one.
    pub async fn register_sensor(&self, sensor: &str, k: &Intrinsics) -> Result<()> {
        if !valid_session_name(sensor) {
            return Err(ClusterError::site(
                &self.name,
                format!("{sensor:?}: a sensor name is 1 to 64 letters, digits, '-' or '_'"),
            ));
        }
        let bytes = serde_json::to_vec(k).expect("intrinsics serialise");
        let key = format!("sensor.{sensor}");
        if self.meta.create(&key, bytes.into()).await.is_ok() {
            return Ok(());
        }
        match self.sensor(sensor).await? {
            Some(known) if known == *k => Ok(()),
            Some(known) => Err(ClusterError::site(
                &self.name,
                format!("sensor {sensor} was published with another camera: {known:?}, now {k:?}"),
            )),
            None => Err(ClusterError::Bus(format!(
                "sensor {sensor}'s camera could be neither recorded nor read"
            ))),
        }
    }

    /// The sequence number of the stream's last message (0 when empty).
    pub async fn last_seq(&self) -> Result<u64> {
        let info = self
            .stream
            .get_info()
            .await
            .map_err(|e| ClusterError::bus("cannot read the stream's state", e))?;
        Ok(info.state.last_sequence)
    }
}

/// The entries `store` holds now, key and value, deleted ones left out.
///
/// Listed from its stream's subjects in one request, then read sixteen at
/// a time. `kv::Store::keys` instead runs a consumer that waits for every
/// entry pending when it started, which can wait long for heartbeats that
/// expire meanwhile (nats-server issue 3481), and workers balancing, the
/// status and the browser view read the heartbeats often.
pub async fn live_entries(store: &kv::Store) -> Result<Vec<(String, bytes::Bytes)>> {
    let subjects: Vec<(String, usize)> = store
        .stream
        .info_with_subjects(format!("{}>", store.prefix))
        .await
        .map_err(|e| ClusterError::bus("cannot list a bucket's keys", e))?
        .try_collect()
        .await
        .map_err(|e| ClusterError::bus("cannot list a bucket's keys", e))?;
    let keys = subjects
        .into_iter()
        .filter_map(|(subject, _)| Some(subject.strip_prefix(store.prefix.as_str())?.to_string()));
    let read: Vec<Option<(String, bytes::Bytes)>> = futures_util::stream::iter(keys)
        .map(|key| async move {
            let value = store
                .get(&key)
                .await
                .map_err(|e| ClusterError::bus("cannot read a bucket's entry", e))?;
            Ok::<_, ClusterError>(value.map(|v| (key, v)))
        })
        .buffer_unordered(READS_AT_ONCE)
        .try_collect()
        .await?;
    // None: gone since listed, or deleted (its marker keeps the subject).
    let mut out: Vec<_> = read.into_iter().flatten().collect();
    out.sort_by(|a, b| a.0.cmp(&b.0));
    Ok(out)
}

/// Entries [`live_entries`] asks for at once: one after another, a site of
/// many workers and trackers would pay a round trip to the bus for each
/// (a status over a network link, or a worker balancing, waited that long).
const READS_AT_ONCE: usize = 16;

/// A JetStream context on the bus at `url`; the connection's drops and
/// returns are said on stderr.
async fn bus(url: &str) -> Result<jetstream::Context> {
    let log = ConnectionLog::new(url);
    async_nats::ConnectOptions::new()
        .event_callback(move |event| {
            let said = log.on(&event);
            async move {
                if let Some(said) = said {
                    eprintln!("{said}");
                }
            }
        })
        .connect(url)
        .await
        .map(jetstream::new)
        .map_err(|e| ClusterError::bus(&format!("cannot connect to {url}"), e))
}

/// A site's name becomes part of subjects and bucket names: letters,
/// digits, '-' and '_' only.
fn check_name(name: &str) -> Result<()> {
    if valid_session_name(name) {
        return Ok(());
    }
    Err(ClusterError::site(
        name,
        "a site name is 1 to 64 letters, digits, '-' or '_'",
    ))
}

/// Gives the existing bucket whose stream `config` describes that config
/// (what matters: its `max_age`, the lease time).
async fn give_age(js: &jetstream::Context, config: stream::Config) -> Result<(), String> {
    js.update_stream(config)
        .await
        .map(|_| ())
        .map_err(|e| e.to_string())
}

/// What `make` made or, if it failed, what `open` then finds: another
/// process may have made it between this one's look and its create
/// (twelve opening a new site at once: "subjects overlap with an existing
/// stream", for the site's stream and for the checkpoint store). The
/// create's error is kept when the open fails too.
async fn made_or_opened<T, E, F, O>(
    make: impl std::future::Future<Output = std::result::Result<T, E>>,
    open: impl FnOnce() -> O,
) -> std::result::Result<T, E>
where
    O: std::future::Future<Output = std::result::Result<T, F>>,
{
    match make.await {
        Ok(made) => Ok(made),
        Err(e) => open().await.map_err(|_| e),
    }
}

/// Opens the key-value bucket `bucket` (one value per key, entries that
/// live `max_age`, or for ever when zero), creating it when missing, or
/// giving it `max_age` when `update`.
///
/// The bucket's stream is made here, as the key-value API lays it out,
/// rather than by the client's own call, which first reads account
/// figures that servers before 2.10 (Debian's) do not report.
async fn open_kv(
    js: &jetstream::Context,
    bucket: &str,
    max_age: Duration,
    update: bool,
) -> Result<kv::Store> {
    let config = stream::Config {
        name: format!("KV_{bucket}"),
        subjects: vec![format!("$KV.{bucket}.>")],
        max_messages_per_subject: 1,
        max_age,
        storage: stream::StorageType::File,
        allow_rollup: true,
        deny_delete: true,
        allow_direct: true,
        discard: stream::DiscardPolicy::New,
        num_replicas: 1,
        ..Default::default()
    };
    let exists = js.get_key_value(bucket).await.is_ok();
    let made = match (exists, update) {
        (true, false) => Ok(()),
        (true, true) => give_age(js, config).await,
        (false, _) => match js.create_stream(config.clone()).await {
            Ok(_) => Ok(()),
            // Another process may have created it meanwhile, with its own
            // age: a worker started with --lease-seconds beside a tracker
            // that made the bucket first kept the tracker's default lease,
            // and lost its leases to an outage shorter than its own.
            Err(e) if update => give_age(js, config)
                .await
                .map_err(|u| format!("{e}; then, updating it: {u}")),
            Err(e) => js
                .get_key_value(bucket)
                .await
                .map(|_| ())
                .map_err(|_| e.to_string()),
        },
    };
    made.map_err(|e| ClusterError::bus(&format!("cannot create bucket {bucket}"), e))?;
    js.get_key_value(bucket)
        .await
        .map_err(|e| ClusterError::bus(&format!("cannot open bucket {bucket}"), e))
}
