//! The site's map: assembled from the shards' checkpoints (`cluster
//! fetch`), or fused afresh from the whole stream in one process (`cluster
//! replay`, the reference a cluster must equal).

use crate::checkpoint::{load_shard, read_manifest, Manifest};
use crate::error::{ClusterError, Result};
use crate::fuse::{Fused, Fuser, StreamReader};
use crate::site::Site;
use crate::tracker::tracked;
use depthmesh::mesh::Mesh;
use futures_util::TryStreamExt;
use serde::Serialize;
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

/// Frames on the stream per sensor: with their pose, and waiting for one.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct SensorFrames {
    /// Posed frames.
    pub posed: u64,
    /// Frames without a pose.
    pub raw: u64,
}

/// Frames the stream holds, by sensor.
pub async fn frames_by_sensor(site: &Site) -> Result<BTreeMap<String, SensorFrames>> {
    let mut out: BTreeMap<String, SensorFrames> = BTreeMap::new();
    let subjects = site
        .stream
        .info_with_subjects(format!("dm.{}.>", site.name))
        .await
        .map_err(|e| ClusterError::bus("cannot count the stream's frames", e))?;
    let counts: Vec<(String, usize)> = subjects
        .try_collect()
        .await
        .map_err(|e| ClusterError::bus("cannot count the stream's frames", e))?;
    for (subject, count) in counts {
        if let Some((sensor, posed)) = site.sensor_of(&subject) {
            let e = out.entry(sensor.to_string()).or_default();
            if posed {
                e.posed += count as u64;
            } else {
                e.raw += count as u64;
            }
        }
    }
    Ok(out)
}

/// Frames of sensors without poses not tracked yet.
async fn untracked_frames(site: &Site) -> Result<u64> {
    let mut waiting = 0;
    for (sensor, frames) in frames_by_sensor(site).await? {
        if frames.raw > 0 {
            let done = tracked(site, &sensor).await?.map_or(0, |t| t.frames);
            waiting += frames.raw.saturating_sub(done);
        }
    }
    Ok(waiting)
}

/// What an assembled map includes.
#[derive(Clone, Debug, Default, Serialize)]
pub struct FetchReport {
    /// The stream's last message when the map was assembled.
    pub stream_last: u64,
    /// Every shard's checkpoint includes the stream up to here.
    pub included: u64,
    /// Whether that is the whole stream.
    pub complete: bool,
    /// Shards, and those never checkpointed.
    pub shards: u32,
    /// Shards never checkpointed (their blocks are missing).
    pub shards_missing: u32,
    /// Posed frames on the stream.
    pub frames_in_stream: u64,
    /// Fewest and most posed frames any shard fused.
    pub frames_fused_min: u64,
    /// See `frames_fused_min`.
    pub frames_fused_max: u64,
    /// Whether every shard fused every posed frame of the stream, once.
    pub every_frame_fused_once: bool,
    /// Frames no shard could read.
    pub frames_rejected: u64,
    /// Frames of sensors without poses that their tracker lost (never
    /// published with a pose, so never fused).
    pub frames_lost: u64,
    /// Blocks in the map.
    pub blocks: u64,
    /// Bytes of checkpoint segments read.
    pub checkpoint_bytes: u64,
    /// Triangles of the mesh.
    pub triangles: u64,
    /// Seconds to assemble.
    pub seconds: f64,
}

/// Every shard's manifest (`None` for a shard never checkpointed).
async fn manifests(site: &Site, shards: u32) -> Result<Vec<Option<Manifest>>> {
    let mut out = Vec::with_capacity(shards as usize);
    for s in 0..shards {
        out.push(read_manifest(site, s).await?.map(|(m, _)| m));
    }
    Ok(out)
}

/// Assembles the map from the shards' last checkpoints. With `wait`, first
/// waits (at most that long) until every shard's checkpoint includes the
/// whole stream, i.e. every frame published so far is fused.
pub async fn fetch(site: &Site, wait: Option<Duration>) -> Result<(Mesh, FetchReport)> {
    let start = Instant::now();
    // Waiting covers a site whose first worker has not started yet.
    let config = loop {
        match (site.config().await?, wait) {
            (Some(c), _) => break c,
            (None, Some(limit)) if start.elapsed() < limit => {
                tokio::time::sleep(Duration::from_millis(200)).await
            }
            (None, _) => break site.required_config().await?,
        }
    };
    let shards = config.regions.shards;
    let (all, last) = loop {
        // Trackers first: the frames they still have to publish come
        // after the last message read next.
        let untracked = untracked_frames(site).await?;
        let last = site.last_seq().await?;
        let all = manifests(site, shards).await?;
        let caught_up = untracked == 0
            && all
                .iter()
                .all(|m| m.as_ref().is_some_and(|m| m.seq >= last));
        match wait {
            Some(limit) if !caught_up => {
                if start.elapsed() > limit {
                    let behind = all
                        .iter()
                        .filter(|m| m.as_ref().is_none_or(|m| m.seq < last));
                    return Err(ClusterError::site(
                        &site.name,
                        format!(
                            "{} of {shards} shards had not fused up to message {last} after {:.0} s",
                            behind.count(),
                            limit.as_secs_f64()
                        ),
                    ));
                }
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
            _ => break (all, last),
        }
    };
    let sensors = frames_by_sensor(site).await?;
    let posed: u64 = sensors.values().map(|f| f.posed).sum();
    let mut lost = 0;
    for (sensor, frames) in &sensors {
        if frames.raw > 0 {
            lost += tracked(site, sensor).await?.map_or(0, |t| t.lost);
        }
    }
    let mut fuser = Fuser::new(config)?;
    let mut report = FetchReport {
        stream_last: last,
        shards,
        frames_in_stream: posed,
        frames_lost: lost,
        frames_fused_min: u64::MAX,
        ..FetchReport::default()
    };
    report.included = all
        .iter()
        .map(|m| m.as_ref().map_or(0, |m| m.seq))
        .min()
        .unwrap_or(0);
    report.complete = report.included >= last;
    for (shard, manifest) in all.iter().enumerate() {
        let Some(m) = manifest else {
            report.shards_missing += 1;
            report.frames_fused_min = 0;
            continue;
        };
        // The revision matters only to a commit on top of it.
        let (m, _, blocks) = load_shard(site, shard as u32, m.clone(), None).await?;
        let m = &m;
        report.blocks += blocks.len() as u64;
        report.checkpoint_bytes += m.segment_bytes;
        report.frames_fused_min = report.frames_fused_min.min(m.frames);
        report.frames_fused_max = report.frames_fused_max.max(m.frames);
        report.frames_rejected = report.frames_rejected.max(m.rejected);
        fuser.volume.restore(blocks.into_values().collect(), 0)?;
    }
    report.frames_fused_min = report.frames_fused_min.min(report.frames_fused_max);
    report.every_frame_fused_once = report.complete
        && report.frames_fused_min == report.frames_fused_max
        && report.frames_fused_max + report.frames_rejected == posed;
    let mesh = tokio::task::block_in_place(|| fuser.mesh());
    report.triangles = mesh.triangle_count() as u64;
    report.seconds = start.elapsed().as_secs_f64();
    Ok((mesh, report))
}

/// What a replay fused.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ReplayReport {
    /// The last message read.
    pub stream_last: u64,
    /// Posed frames fused.
    pub frames: u64,
    /// Posed frames that could not be read.
    pub frames_rejected: u64,
    /// Blocks in the map.
    pub blocks: u64,
    /// Triangles of the mesh.
    pub triangles: u64,
    /// Seconds it took.
    pub seconds: f64,
    /// Frames per second.
    pub fps: f64,
}

/// Fuses the site's whole stream as it is now, in the stream's order, in
/// this process: the map the cluster must equal.
pub async fn replay(
    site: &Site,
    mut progress: impl FnMut(u64, u64),
) -> Result<(Mesh, ReplayReport)> {
    let config = site.required_config().await?;
    let start = Instant::now();
    let last = site.last_seq().await?;
    let mut fuser = Fuser::new(config)?;
    let mut reader = StreamReader::new(site);
    let mut report = ReplayReport {
        stream_last: last,
        ..ReplayReport::default()
    };
    for seq in 1..=last {
        let Some(msg) = reader.get(seq, last).await? else {
            continue;
        };
        match fuser.fuse(site, &msg, |_| true).await? {
            Fused::Frame => report.frames += 1,
            Fused::Rejected(why) => {
                eprintln!("message {seq} rejected: {why}");
                report.frames_rejected += 1;
            }
            Fused::Skipped => {}
        }
        progress(seq, last);
    }
    let fused = start.elapsed().as_secs_f64();
    let mesh = tokio::task::block_in_place(|| fuser.mesh());
    report.blocks = fuser.volume.blocks().len() as u64;
    report.triangles = mesh.triangle_count() as u64;
    report.seconds = start.elapsed().as_secs_f64();
    report.fps = report.frames as f64 / fused.max(1e-9);
    Ok((mesh, report))
}
