//! Reading a site's stream in order and fusing it: what a worker does for
//! its shards and a replay does for the whole map.

use crate::error::{ClusterError, Result};
use crate::frames::FrameReader;
use crate::site::{Site, SiteConfig};
use async_nats::jetstream::message::StreamMessage;
use async_nats::jetstream::stream::RawMessageErrorKind;
use depthmesh::mesh::Mesh;
use depthmesh::tsdf::mesh::extract_blocks;
use depthmesh::tsdf::TsdfVolume;
use glam::IVec3;
use std::collections::VecDeque;
use std::time::Instant;
use tokio::task::JoinHandle;

/// Messages fetched ahead of the one being fused, so the bus's round trips
/// overlap the fusion.
const READ_AHEAD: u64 = 4;

/// Messages of the stream by sequence number, fetched a few ahead.
pub struct StreamReader {
    site: Site,
    ahead: VecDeque<(u64, JoinHandle<Result<Option<StreamMessage>>>)>,
}

impl StreamReader {
    /// A reader of `site`'s stream.
    pub fn new(site: &Site) -> Self {
        StreamReader {
            site: site.clone(),
            ahead: VecDeque::new(),
        }
    }

    /// Message `seq` (`None` if it was deleted), fetching the ones after
    /// it up to `last` meanwhile.
    pub async fn get(&mut self, seq: u64, last: u64) -> Result<Option<StreamMessage>> {
        while self.ahead.front().is_some_and(|(s, _)| *s != seq) {
            if let Some((_, task)) = self.ahead.pop_front() {
                task.abort();
            }
        }
        let mut next = self.ahead.back().map_or(seq, |(s, _)| s + 1);
        while next <= last.min(seq + READ_AHEAD) {
            let site = self.site.clone();
            self.ahead
                .push_back((next, tokio::spawn(async move { fetch(&site, next).await })));
            next += 1;
        }
        match self.ahead.pop_front() {
            Some((_, task)) => task
                .await
                .map_err(|e| ClusterError::Bus(format!("message {seq}: {e}")))?,
            None => fetch(&self.site, seq).await,
        }
    }
}

/// One message of the stream.
async fn fetch(site: &Site, seq: u64) -> Result<Option<StreamMessage>> {
    match site.stream.get_raw_message(seq).await {
        Ok(m) => Ok(Some(m)),
        Err(e) if e.kind() == RawMessageErrorKind::NoMessageFound => Ok(None),
        Err(e) => Err(ClusterError::bus(&format!("cannot read message {seq}"), e)),
    }
}

/// What a message was.
#[derive(Debug, PartialEq)]
pub enum Fused {
    /// A posed frame, fused into the blocks asked for.
    Frame,
    /// Not for fusion (a frame waiting for its pose, on a raw subject).
    Skipped,
    /// A posed frame that could not be read, and why; nothing was fused.
    Rejected(String),
}

/// Where a fuser's time went, in seconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FuseTimes {
    /// Decoding frames into depth images (every worker decodes every frame).
    pub decode: f64,
    /// Finding the blocks a frame touches and fusing those asked for.
    pub integrate: f64,
}

/// A TSDF volume fed from the stream.
pub struct Fuser {
    /// The site's settings.
    pub config: SiteConfig,
    /// The blocks fused so far.
    pub volume: TsdfVolume,
    /// Time spent so far.
    pub times: FuseTimes,
    reader: FrameReader,
}

impl Fuser {
    /// An empty map with the site's settings.
    pub fn new(config: SiteConfig) -> Result<Self> {
        Ok(Fuser {
            config,
            volume: TsdfVolume::new(config.tsdf())?,
            times: FuseTimes::default(),
            reader: FrameReader::default(),
        })
    }

    /// Fuses `msg` into the blocks `keep` accepts (the rest of the frame is
    /// other shards'). Runs on the calling thread, in parallel inside.
    pub async fn fuse(
        &mut self,
        site: &Site,
        msg: &StreamMessage,
        keep: impl Fn(IVec3) -> bool + Sync,
    ) -> Result<Fused> {
        let Some((sensor, true)) = site.sensor_of(msg.subject.as_str()) else {
            return Ok(Fused::Skipped);
        };
        let camera = self.reader.camera(site, sensor).await?;
        let range = (self.config.depth_min, self.config.depth_max);
        let volume = &mut self.volume;
        let reader = &mut self.reader;
        let times = &mut self.times;
        tokio::task::block_in_place(|| {
            let start = Instant::now();
            let frame = match reader.read(&msg.payload, camera, range) {
                Ok(f) => f,
                Err(why) => return Ok(Fused::Rejected(format!("{sensor}: {why}"))),
            };
            let Some(pose) = frame.pose else {
                let why = format!("{sensor}: frame {} has no pose", frame.index);
                return Ok(Fused::Rejected(why));
            };
            let decoded = Instant::now();
            volume.integrate_where(frame.depth, None, &frame.camera, &pose, keep)?;
            times.decode += decoded.duration_since(start).as_secs_f64();
            times.integrate += decoded.elapsed().as_secs_f64();
            Ok(Fused::Frame)
        })
    }

    /// The mesh of every block, in key order (so the same map is the same file).
    pub fn mesh(&self) -> Mesh {
        let mut keys: Vec<IVec3> = self.volume.blocks().iter().map(|b| b.key).collect();
        keys.sort_unstable_by_key(|k| (k.x, k.y, k.z));
        extract_blocks(&self.volume, &keys, self.config.min_weight)
    }
}
