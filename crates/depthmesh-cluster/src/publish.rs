//! A sensor's frames onto a site's stream (`depthmesh stream --nats`):
//! compressed with the service's codec, each with a message id so a
//! client that restarts and publishes a frame again is kept once.

use crate::error::{ClusterError, Result};
use crate::site::Site;
use async_nats::jetstream::context::PublishAckFuture;
use async_nats::HeaderMap;
use depthmesh::codec::{Codec, Encoder, RawDepth};
use depthmesh_server::protocol::FrameMessage;
use depthmesh_server::FrameSource;
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// Publications awaiting the stream's acknowledgement: enough to keep the
/// link busy, few enough that a failure is noticed within a few frames.
const IN_FLIGHT: usize = 32;

/// How to publish.
#[derive(Clone, Debug)]
pub struct PublishOptions {
    /// The sensor's name (its subject).
    pub sensor: String,
    /// The depth codec.
    pub codec: Codec,
    /// Frames per second, or `None`: as fast as the bus takes them.
    pub rate: Option<f64>,
    /// Leave the poses to a tracker: every frame goes to the raw subject,
    /// the first with its pose (where the tracked trajectory starts).
    pub track: bool,
}

/// What a publication did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Published {
    /// Frames the stream stored.
    pub frames: u64,
    /// Frames it already held (published before, same sensor and index).
    pub duplicates: u64,
    /// Frames published with their pose (the rest wait for a tracker).
    pub posed: u64,
    /// Payload bytes sent.
    pub bytes: u64,
    /// Seconds it took.
    pub seconds: f64,
}

/// Publishes every frame of `source` as sensor `options.sensor` of `site`;
/// `progress` is told the frames acknowledged so far.
pub async fn publish(
    site: &Site,
    source: &mut dyn FrameSource,
    options: &PublishOptions,
    mut progress: impl FnMut(&Published),
) -> Result<Published> {
    site.register_sensor(&options.sensor, &source.intrinsics())
        .await?;
    let start = Instant::now();
    let mut encoder = Encoder::new(options.codec);
    let mut raw = RawDepth::default();
    let mut out = Published::default();
    let mut waiting: VecDeque<(u64, PublishAckFuture)> = VecDeque::new();
    let mut sent = 0u64;
    while let Some(frame) = source.next_frame(&mut raw) {
        let frame = frame.map_err(|e| ClusterError::site(&site.name, format!("source: {e}")))?;
        if let Some(rate) = options.rate {
            let due = start + Duration::from_secs_f64(sent as f64 / rate);
            tokio::time::sleep_until(due.into()).await;
        }
        let pose = frame.pose.filter(|_| !options.track || sent == 0);
        let mut msg = FrameMessage {
            index: frame.index,
            timestamp: frame.timestamp,
            pose,
            codec: options.codec,
            payload: Vec::new(),
        };
        encoder.encode(&raw, &mut msg.payload);
        let mut bytes = Vec::with_capacity(msg.payload.len() + 80);
        msg.encode(&mut bytes);
        let posed = pose.is_some() && !options.track;
        let subject = match posed {
            true => site.posed_subject(&options.sensor),
            false => site.raw_subject(&options.sensor),
        };
        let mut headers = HeaderMap::new();
        headers.insert(
            "Nats-Msg-Id",
            Site::frame_id(&subject, frame.index).as_str(),
        );
        out.bytes += bytes.len() as u64;
        out.posed += u64::from(posed);
        let ack = site
            .js
            .publish_with_headers(subject, headers, bytes.into())
            .await
            .map_err(|e| ClusterError::bus(&format!("cannot publish frame {}", frame.index), e))?;
        waiting.push_back((frame.index, ack));
        sent += 1;
        if waiting.len() >= IN_FLIGHT {
            settle(waiting.pop_front(), &mut out).await?;
            progress(&out);
        }
    }
    while !waiting.is_empty() {
        settle(waiting.pop_front(), &mut out).await?;
        progress(&out);
    }
    out.seconds = start.elapsed().as_secs_f64();
    Ok(out)
}

/// Waits for one publication's acknowledgement and counts it.
async fn settle(waiting: Option<(u64, PublishAckFuture)>, out: &mut Published) -> Result<()> {
    let Some((index, ack)) = waiting else {
        return Ok(());
    };
    let ack = ack
        .await
        .map_err(|e| ClusterError::bus(&format!("frame {index} was not stored"), e))?;
    if ack.duplicate {
        out.duplicates += 1;
    } else {
        out.frames += 1;
    }
    Ok(())
}
