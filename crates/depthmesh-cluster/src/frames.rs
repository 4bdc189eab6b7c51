//! Frames as they travel on a site's stream: the mapping service's frame
//! message (index, timestamp, pose, depth in the sensor's units through a
//! lossless codec), read back into metres for fusion.

use crate::error::{ClusterError, Result};
use crate::site::Site;
use depthmesh::{DepthImage, Intrinsics, Pose};
use depthmesh_server::protocol::{DepthReader, FrameMessage};
use std::collections::HashMap;

/// Reads frame messages into depth images, reusing its buffers, and keeps
/// the sensors' cameras it has looked up.
#[derive(Default)]
pub struct FrameReader {
    depth: DepthReader,
    cameras: HashMap<String, Intrinsics>,
}

/// A frame read from the stream.
pub struct ReadFrame<'a> {
    /// The sensor's frame number.
    pub index: u64,
    /// Its timestamp, seconds.
    pub timestamp: f64,
    /// Where it was taken from, when known.
    pub pose: Option<Pose>,
    /// Its depth in metres, outside the site's range set to 0 (taken out
    /// to make a frame, it is given back with [`FrameReader::put_back`]).
    pub depth: &'a mut DepthImage,
    /// The sensor's camera.
    pub camera: Intrinsics,
}

impl FrameReader {
    /// The camera of `sensor`, looked up on the site the first time.
    pub async fn camera(&mut self, site: &Site, sensor: &str) -> Result<Intrinsics> {
        if let Some(k) = self.cameras.get(sensor) {
            return Ok(*k);
        }
        let k = site.sensor(sensor).await?.ok_or_else(|| {
            ClusterError::site(&site.name, format!("sensor {sensor} published no camera"))
        })?;
        self.cameras.insert(sensor.to_string(), k);
        Ok(k)
    }

    /// Reads a frame message taken with `camera`; depth outside `range`
    /// (metres) is dropped as the dataset readers drop it. A message that
    /// is not one is an error saying why (the caller skips it).
    pub fn read(
        &mut self,
        payload: &[u8],
        camera: Intrinsics,
        range: (f32, f32),
    ) -> Result<ReadFrame<'_>, String> {
        let msg = FrameMessage::decode(payload).map_err(|e| e.to_string())?;
        let pixels = u64::from(camera.width) * u64::from(camera.height);
        let depth = self.depth.read(&msg, &camera, range, pixels)?;
        Ok(ReadFrame {
            index: msg.index,
            timestamp: msg.timestamp,
            pose: msg.pose,
            depth,
            camera,
        })
    }

    /// Gives back a depth image taken out of a [`ReadFrame`].
    pub fn put_back(&mut self, depth: DepthImage) {
        self.depth.put_back(depth);
    }
}
