//! A tracker worker (`depthmesh cluster tracker`): for a sensor that
//! publishes frames without poses, tracks them (the library's session:
//! ICP against its own TSDF of the sensor's frames) and publishes each
//! tracked frame, unchanged but for its pose, on the sensor's posed
//! subject for the fusion workers. A lost frame is not published.
//!
//! Each sensor has one tracker at a time, by a lease as shards have, kept
//! by a [`Keeper`] so that a slow frame does not lose it. A
//! tracker that takes a sensor over tracks it again from its first frame
//! (tracking is deterministic, so it finds the poses its predecessor
//! found) and publishes only the frames after the last one on the posed
//! subject; the frames' message ids make the stream keep a frame published
//! twice in a race once. A tracker that cannot reach the bus for a while
//! keeps its sensor and its session, and goes on from the frame it had
//! reached, unless its lease expired meanwhile.

use crate::error::{ClusterError, Result};
use crate::fetch::frames_by_sensor;
use crate::frames::FrameReader;
use crate::keeper::{Keeper, HANDOVER, STALL};
use crate::outage::Outage;
use crate::site::{Site, SiteConfig};
use async_nats::jetstream::stream::RawMessageErrorKind;
use async_nats::HeaderMap;
use depthmesh::session::{Session, SessionConfig};
use depthmesh::track::TrackerConfig;
use depthmesh::Frame;
use depthmesh_server::protocol::FrameMessage;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// How a tracker runs.
#[derive(Clone, Debug)]
pub struct TrackerOptions {
    /// Its name, unique on the site.
    pub id: String,
    /// Track only this sensor (default: any sensor without a tracker).
    pub sensor: Option<String>,
    /// The tracker's settings.
    pub tracking: TrackerConfig,
}

/// A tracker's figures, as its heartbeat says them.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrackerBeat {
    /// The tracker.
    pub id: String,
    /// The sensor it tracks, if any.
    pub sensor: Option<String>,
    /// Frames tracked (again, after a takeover, from the first).
    pub frames: u64,
    /// Frames lost (not published).
    pub lost: u64,
    /// Frames published with their pose.
    pub published: u64,
    /// Seconds since the Unix epoch when its figures were taken.
    pub at: f64,
}

/// The key of a tracker's heartbeat in the `workers` bucket.
pub fn beat_key(id: &str) -> String {
    format!("tracker.{id}")
}

/// How far a sensor's frames are tracked: in the `meta` bucket under
/// `tracked.SENSOR`, written whenever its tracker has caught up, so that
/// `fetch --wait` knows frames still waiting for a pose.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Tracked {
    /// The sensor's frames tracked (from its first).
    pub frames: u64,
    /// Of those, lost (never published with a pose).
    pub lost: u64,
}

/// The key of a sensor's [`Tracked`] in the `meta` bucket.
pub fn tracked_key(sensor: &str) -> String {
    format!("tracked.{sensor}")
}

/// How far `sensor`'s frames are tracked, if a tracker has said.
pub async fn tracked(site: &Site, sensor: &str) -> Result<Option<Tracked>> {
    let bytes = site
        .meta
        .get(tracked_key(sensor))
        .await
        .map_err(|e| ClusterError::bus("cannot read a tracker's progress", e))?;
    Ok(bytes.and_then(|b| serde_json::from_slice(&b).ok()))
}

/// The key of a sensor's tracker lease in the `leases` bucket.
fn lease_key(sensor: &str) -> String {
    format!("tracker.{sensor}")
}

/// A tracked frame whose publication the bus has not confirmed yet.
struct Unconfirmed {
    index: u64,
    message: bytes::Bytes,
}

/// A sensor being tracked.
struct Tracking {
    sensor: String,
    session: Session,
    /// Depths kept, metres (the site's range).
    range: (f32, f32),
    /// The stream position to look for the sensor's next frame from.
    next: u64,
    /// The last frame index already on the posed subject.
    published_up_to: Option<u64>,
    /// A frame tracked whose publication failed: published again, with the
    /// same message id, before any other frame is read. The session has
    /// tracked it already, so it cannot be tracked again.
    unconfirmed: Option<Unconfirmed>,
    /// Frames tracked and lost, and what was last said of them.
    progress: Tracked,
    said: Option<Tracked>,
}

/// Runs a tracker until `stop` is set; then gives its sensor back.
pub async fn run(site: &Site, options: &TrackerOptions, stop: &AtomicBool) -> Result<()> {
    let mut site = site.clone();
    let site = &mut site;
    let mut reader = FrameReader::default();
    let mut beat = TrackerBeat {
        id: options.id.clone(),
        ..TrackerBeat::default()
    };
    let mut tracking: Option<Tracking> = None;
    let keeper = Keeper::start(site, STALL);
    let mut next_beat = Instant::now();
    let mut outage = Outage::default();
    let who = format!("tracker {}", options.id);
    while !stop.load(Ordering::Relaxed) {
        let turn: Result<()> = async {
            keeper.alive();
            // Before the next frame: another tracker may have the sensor.
            let lost = keeper.lost().await;
            if let Some(t) = tracking.take_if(|t| lost.contains(&lease_key(&t.sensor))) {
                eprintln!("tracker {}: lease of sensor {} lost", options.id, t.sensor);
            }
            if Instant::now() >= next_beat {
                site.refresh_lease().await?;
                next_beat = Instant::now() + site.lease_ttl / 4;
                if tracking.is_none() {
                    tracking = claim(site, options, &keeper).await?;
                }
                beat.sensor = tracking.as_ref().map(|t| t.sensor.clone());
                beat.at = SystemTime::now()
                    .duration_since(UNIX_EPOCH)
                    .map_or(0.0, |d| d.as_secs_f64());
                let bytes = serde_json::to_vec(&beat).expect("heartbeat serialises");
                keeper.beat(beat_key(&options.id), bytes).await?;
            }
            let Some(t) = &mut tracking else {
                // Look for work again soon, not only at the next heartbeat.
                tokio::time::sleep(Duration::from_millis(200)).await;
                tracking = claim(site, options, &keeper).await?;
                return Ok(());
            };
            if !step(site, t, &mut reader, &mut beat).await? {
                if t.said.as_ref() != Some(&t.progress) {
                    let bytes = serde_json::to_vec(&t.progress).expect("progress serialises");
                    site.meta
                        .put(tracked_key(&t.sensor), bytes.into())
                        .await
                        .map_err(|e| ClusterError::bus("cannot record a tracker's progress", e))?;
                    t.said = Some(t.progress.clone());
                }
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
            Ok(())
        }
        .await;
        // A failed turn keeps the sensor and its session: a frame whose
        // publication failed is published again first (see `step`), and a
        // sensor whose lease expired meanwhile is dropped at the top of a
        // turn, once the keeper has found the lease lost.
        outage.after(&who, turn).await?;
    }
    let handover = async {
        if let Some(t) = tracking {
            keeper.give_back(&lease_key(&t.sensor)).await;
        }
        keeper.end_beat(&beat_key(&options.id)).await;
    };
    // Past the limit (the bus gone) the lease expires instead.
    let _ = tokio::time::timeout(HANDOVER, handover).await;
    Ok(())
}

/// Takes a sensor that publishes frames without poses and has no tracker.
async fn claim(site: &Site, options: &TrackerOptions, keeper: &Keeper) -> Result<Option<Tracking>> {
    let config = match site.config().await? {
        Some(c) => c,
        None => return Ok(None),
    };
    for (sensor, frames) in frames_by_sensor(site).await? {
        if frames.raw == 0 || options.sensor.as_ref().is_some_and(|s| *s != sensor) {
            continue;
        }
        // The lease names this tracker, not the sensor: its keeper tells
        // a renewal of its own applied late from another tracker's lease.
        let Ok(lease_revision) = site
            .leases
            .create(lease_key(&sensor), options.id.clone().into())
            .await
        else {
            continue;
        };
        let key = lease_key(&sensor);
        keeper
            .hold(key.clone(), options.id.clone().into_bytes(), lease_revision)
            .await;
        let started = start(site, options, &config, &sensor).await;
        if started.is_err() {
            // Not kept: a lease renewed for a sensor nobody tracks would
            // hold it up for as long as this tracker lives.
            keeper.give_back(&key).await;
        }
        return started.map(Some);
    }
    Ok(None)
}

/// Starts tracking `sensor`, whose lease is ours, after the frames already
/// on its posed subject.
async fn start(
    site: &Site,
    options: &TrackerOptions,
    config: &SiteConfig,
    sensor: &str,
) -> Result<Tracking> {
    let camera = site.sensor(sensor).await?.ok_or_else(|| {
        ClusterError::site(&site.name, format!("sensor {sensor} published no camera"))
    })?;
    let session = Session::new(SessionConfig {
        intrinsics: camera,
        map: config.map(),
        tracking: Some(options.tracking.clone()),
    })?;
    let published_up_to = last_posed_index(site, sensor).await?;
    eprintln!(
        "tracker {}: tracking sensor {sensor} (frames up to {published_up_to:?} already posed)",
        options.id
    );
    Ok(Tracking {
        sensor: sensor.to_string(),
        session,
        range: (config.depth_min, config.depth_max),
        next: 1,
        published_up_to,
        unconfirmed: None,
        progress: Tracked::default(),
        said: None,
    })
}

/// The index of the last frame on `sensor`'s posed subject.
async fn last_posed_index(site: &Site, sensor: &str) -> Result<Option<u64>> {
    match site
        .stream
        .get_last_raw_message_by_subject(&site.posed_subject(sensor))
        .await
    {
        Ok(m) => FrameMessage::decode(&m.payload)
            .map(|f| Some(f.index))
            .map_err(|e| ClusterError::site(&site.name, format!("sensor {sensor}: {e}"))),
        Err(e) if e.kind() == RawMessageErrorKind::NoMessageFound => Ok(None),
        Err(e) => Err(ClusterError::bus("cannot read the last posed frame", e)),
    }
}

/// Tracks the sensor's next frame and publishes it; `false` when there is
/// none yet. A step that fails leaves `t` as it was or with its frame
/// [`Tracking::unconfirmed`], so the next one goes on from there.
async fn step(
    site: &Site,
    t: &mut Tracking,
    reader: &mut FrameReader,
    beat: &mut TrackerBeat,
) -> Result<bool> {
    if t.unconfirmed.is_some() {
        publish(site, t, beat).await?;
        return Ok(true);
    }
    let msg = match site
        .stream
        .raw_message_builder()
        .sequence(t.next)
        .next_by_subject(site.raw_subject(&t.sensor))
        .send()
        .await
    {
        Ok(m) => m,
        Err(e) if e.kind() == RawMessageErrorKind::NoMessageFound => return Ok(false),
        Err(e) => return Err(ClusterError::bus("cannot read the next frame", e)),
    };
    let camera = reader.camera(site, &t.sensor).await?;
    let range = t.range;
    let tracked = tokio::task::block_in_place(|| -> Result<Option<(u64, depthmesh::Pose)>> {
        let frame = match reader.read(&msg.payload, camera, range) {
            Ok(f) => f,
            Err(why) => {
                eprintln!(
                    "sensor {}: message {} skipped: {why}",
                    t.sensor, msg.sequence
                );
                return Ok(None);
            }
        };
        let index = frame.index;
        let input = Frame {
            index: index as usize,
            timestamp: frame.timestamp,
            depth: std::mem::take(frame.depth),
            color: None,
            pose: frame.pose,
        };
        let pose = t.session.push(&input).map(|o| o.record.pose);
        reader.put_back(input.depth);
        Ok(pose?.map(|p| (index, p)))
    })?;
    // Only now: a failed request above reads the same message again.
    t.next = msg.sequence + 1;
    beat.frames += 1;
    t.progress.frames += 1;
    let Some((index, pose)) = tracked else {
        beat.lost += 1;
        t.progress.lost += 1;
        return Ok(true);
    };
    if t.published_up_to.is_some_and(|p| index <= p) {
        return Ok(true);
    }
    let mut out = FrameMessage::decode(&msg.payload).expect("read above");
    out.pose = Some(pose);
    let mut bytes = Vec::with_capacity(msg.payload.len() + 48);
    out.encode(&mut bytes);
    t.unconfirmed = Some(Unconfirmed {
        index,
        message: bytes.into(),
    });
    publish(site, t, beat).await?;
    Ok(true)
}

/// Publishes `t`'s unconfirmed frame on the posed subject. Its message id
/// makes the stream keep it once when an earlier try was stored but its
/// reply lost: the stream's duplicate window (ten minutes) outlasts
/// [`crate::outage::RIDE_OUT`].
async fn publish(site: &Site, t: &mut Tracking, beat: &mut TrackerBeat) -> Result<()> {
    let Some(Unconfirmed { index, message }) = &t.unconfirmed else {
        return Ok(());
    };
    let index = *index;
    let mut headers = HeaderMap::new();
    let subject = site.posed_subject(&t.sensor);
    headers.insert("Nats-Msg-Id", Site::frame_id(&subject, index).as_str());
    site.js
        .publish_with_headers(subject, headers, message.clone())
        .await
        .map_err(|e| ClusterError::bus(&format!("cannot publish frame {index}"), e))?
        .await
        .map_err(|e| ClusterError::bus(&format!("frame {index} was not stored"), e))?;
    t.unconfirmed = None;
    t.published_up_to = Some(index);
    beat.published += 1;
    Ok(())
}
