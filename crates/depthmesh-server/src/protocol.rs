//! The wire protocol between a sensor client and `depthmesh serve`, over one
//! WebSocket.
//!
//! Control messages are JSON text; frames, status images and the final mesh
//! are binary, each starting with a 4-byte magic. A session goes:
//!
//! ```text
//! client                                   server
//! Hello {token, intrinsics, ...}   ─►
//!                                  ◄─   Welcome {session, window, last_frame}
//! frame (DMF1, binary)             ─►                              (×N, at most
//!                                  ◄─   Verdict {frame, pose, ...}  `window` in
//!                                  ◄─   status image (DMS1, JPEG)   flight)
//! End                              ─►
//!                                  ◄─   Finished {summary}
//!                                  ◄─   mesh (DMM1, binary PLY)
//! ```
//!
//! Any message the server cannot accept is answered with `Error {message}`
//! and the connection is closed; other sessions carry on. Depth travels in
//! the sensor's integer units through a lossless codec, and poses as the
//! `f32`s the library holds, so a streamed session maps exactly what an
//! offline run maps.

use depthmesh::codec::{Codec, Decoder, RawDepth};
use depthmesh::{DepthImage, Intrinsics, Pose};
use glam::{Mat3, Vec3};
use serde::{Deserialize, Serialize};
use std::fmt;

/// Magic of a depth frame (client to server).
pub const FRAME_MAGIC: &[u8; 4] = b"DMF1";
/// Magic of a status image (server to client).
pub const STATUS_MAGIC: &[u8; 4] = b"DMS1";
/// Magic of the final mesh (server to client).
pub const MESH_MAGIC: &[u8; 4] = b"DMM1";

/// JSON messages from the client.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ClientMessage {
    /// Opens a session; must be the first message.
    Hello {
        /// The server's access token.
        token: String,
        /// The session's name (letters, digits, `-`, `_`); generated when absent.
        #[serde(default)]
        session: Option<String>,
        /// The camera the frames come from.
        intrinsics: Intrinsics,
        /// Poses are tracked by the server (frames after the first carry none).
        #[serde(default)]
        track: bool,
        /// A live sensor: the server maps the newest frame and drops the ones
        /// it cannot keep up with, instead of queueing them.
        #[serde(default)]
        realtime: bool,
        /// Send a status image every this many mapped frames (0: never).
        #[serde(default)]
        status_every: u32,
        /// Continue the named session from its store's last checkpoint (a
        /// server with stores); the welcome says which frame it ended at.
        #[serde(default)]
        resume: bool,
    },
    /// No more frames: finish the session and send its summary and mesh.
    End,
}

/// JSON messages from the server.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ServerMessage {
    /// The session is open.
    Welcome {
        /// Its name.
        session: String,
        /// Frames the client may have in flight (sent, no verdict yet).
        window: u32,
        /// A continued session: the index of the last frame it mapped
        /// (send the frames after it).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        last_frame: Option<u64>,
    },
    /// What became of one frame.
    Verdict(Verdict),
    /// The session ended; its run files are written. The mesh follows as a
    /// binary message.
    Finished {
        /// The run's `summary.json`.
        summary: serde_json::Map<String, serde_json::Value>,
    },
    /// The message or frame was refused; the connection closes.
    Error {
        /// What was wrong.
        message: String,
    },
}

/// The server's verdict on one frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Verdict {
    /// The frame's index, as sent.
    pub frame: u64,
    /// The pose it was fused with (row-major rotation, then translation);
    /// `None` when lost or dropped.
    pub pose: Option<[f32; 12]>,
    /// Why tracking lost the frame, if it did.
    pub lost: Option<String>,
    /// Directions of motion tracking left to the motion model (the view
    /// did not pin them down); 0 from a server that does not say.
    #[serde(default)]
    pub weak_directions: u8,
    /// The server dropped the frame unmapped to keep up (realtime only).
    pub dropped: bool,
    /// Milliseconds the server spent mapping it.
    pub ms: f64,
    /// Map elements after the frame.
    pub elements: u64,
}

/// A depth frame as it travels: the binary message's fields.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameMessage {
    /// Frame number.
    pub index: u64,
    /// Timestamp in seconds.
    pub timestamp: f64,
    /// Camera-to-world pose, when the client knows it.
    pub pose: Option<Pose>,
    /// The codec of `payload`.
    pub codec: Codec,
    /// The encoded depth image.
    pub payload: Vec<u8>,
}

/// Why a binary message could not be read.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MalformedFrame(pub String);

impl fmt::Display for MalformedFrame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "malformed frame message: {}", self.0)
    }
}

/// Codecs by their byte on the wire.
const CODECS: [(u8, Codec); 4] = [
    (0, Codec::Raw),
    (1, Codec::Png),
    (2, Codec::Rvl),
    (3, Codec::Levels),
];

/// A pose as 12 `f32`s: the rotation row by row, then the translation.
pub fn pose_to_array(p: &Pose) -> [f32; 12] {
    let r = p.rotation.transpose().to_cols_array();
    let t = p.translation;
    [
        r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], t.x, t.y, t.z,
    ]
}

/// The pose of [`pose_to_array`]'s 12 numbers; `None` unless all are finite.
pub fn pose_from_array(a: &[f32; 12]) -> Option<Pose> {
    a.iter().all(|v| v.is_finite()).then(|| {
        let rows = Mat3::from_cols_slice(&a[..9]).transpose();
        Pose::new(rows, Vec3::new(a[9], a[10], a[11]))
    })
}

impl FrameMessage {
    /// The binary message: magic, index `u64`, timestamp `f64`, a flags
    /// byte (bit 0: a pose follows), the pose's 12 `f32`s if any, the
    /// codec's byte, then the payload; all little-endian.
    pub fn encode(&self, out: &mut Vec<u8>) {
        out.clear();
        out.extend_from_slice(FRAME_MAGIC);
        out.extend_from_slice(&self.index.to_le_bytes());
        out.extend_from_slice(&self.timestamp.to_le_bytes());
        out.push(u8::from(self.pose.is_some()));
        if let Some(p) = &self.pose {
            for v in pose_to_array(p) {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        let byte = CODECS
            .iter()
            .find(|(_, c)| *c == self.codec)
            .map(|(b, _)| *b);
        out.push(byte.expect("every codec has a byte"));
        out.extend_from_slice(&self.payload);
    }

    /// Reads a binary frame message; anything short, unknown or non-finite
    /// is an error saying what.
    pub fn decode(bytes: &[u8]) -> Result<FrameMessage, MalformedFrame> {
        let bad = |m: &str| MalformedFrame(m.to_string());
        let mut r = Reader(bytes);
        if r.take(4).ok_or_else(|| bad("shorter than its magic"))? != FRAME_MAGIC {
            return Err(bad("does not start with DMF1"));
        }
        let index = u64::from_le_bytes(r.array().ok_or_else(|| bad("ends in its index"))?);
        let timestamp = f64::from_le_bytes(r.array().ok_or_else(|| bad("ends in its timestamp"))?);
        if !timestamp.is_finite() {
            return Err(bad("timestamp is not finite"));
        }
        let flags = r.take(1).ok_or_else(|| bad("ends before its flags"))?[0];
        if flags > 1 {
            return Err(bad(&format!("unknown flags {flags:#04x}")));
        }
        let pose = if flags == 1 {
            let mut a = [0f32; 12];
            for v in &mut a {
                *v = f32::from_le_bytes(r.array().ok_or_else(|| bad("ends in its pose"))?);
            }
            Some(pose_from_array(&a).ok_or_else(|| bad("pose is not finite"))?)
        } else {
            None
        };
        let byte = r.take(1).ok_or_else(|| bad("ends before its codec"))?[0];
        let codec = CODECS
            .iter()
            .find(|(b, _)| *b == byte)
            .map(|(_, c)| *c)
            .ok_or_else(|| bad(&format!("unknown codec byte {byte}")))?;
        Ok(FrameMessage {
            index,
            timestamp,
            pose,
            codec,
            payload: r.0.to_vec(),
        })
    }
}

/// Depth images read from frame messages, with a decoder per codec and
/// every buffer kept from frame to frame.
#[derive(Debug, Default)]
pub struct DepthReader {
    decoders: Vec<(Codec, Decoder)>,
    raw: RawDepth,
    depth: DepthImage,
}

impl DepthReader {
    /// `msg`'s depth in metres for camera `k` (at most `max_pixels`),
    /// depths outside `range` dropped as the dataset readers drop them. An
    /// image that does not decode, or not to the camera's size, is an error
    /// naming the frame.
    pub fn read(
        &mut self,
        msg: &FrameMessage,
        k: &Intrinsics,
        range: (f32, f32),
        max_pixels: u64,
    ) -> Result<&mut DepthImage, String> {
        let decoder = match self.decoders.iter().position(|(c, _)| *c == msg.codec) {
            Some(i) => &mut self.decoders[i].1,
            None => {
                self.decoders
                    .push((msg.codec, Decoder::new(msg.codec, max_pixels)));
                &mut self.decoders.last_mut().expect("just pushed").1
            }
        };
        decoder
            .decode_into(&msg.payload, &mut self.raw)
            .map_err(|e| format!("frame {}: {e}", msg.index))?;
        if (self.raw.width(), self.raw.height()) != (k.width, k.height) {
            return Err(format!(
                "frame {}: depth image is {}×{} but the intrinsics say {}×{}",
                msg.index,
                self.raw.width(),
                self.raw.height(),
                k.width,
                k.height
            ));
        }
        self.raw.to_metres(&mut self.depth);
        self.depth.clamp_range(range.0, range.1);
        Ok(&mut self.depth)
    }

    /// The last image read (once given back).
    pub fn last(&self) -> &DepthImage {
        &self.depth
    }

    /// Gives back the image [`DepthReader::read`] lent (taken out of it to
    /// make a frame), so its buffer serves the next frame.
    pub fn put_back(&mut self, depth: DepthImage) {
        self.depth = depth;
    }
}

/// A binary message of `magic`, a frame index and a payload (status images).
pub fn tagged(magic: &[u8; 4], frame: u64, payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(12 + payload.len());
    out.extend_from_slice(magic);
    out.extend_from_slice(&frame.to_le_bytes());
    out.extend_from_slice(payload);
    out
}

/// The frame index and payload of a [`tagged`] message with `magic`.
pub fn untag<'a>(magic: &[u8; 4], bytes: &'a [u8]) -> Option<(u64, &'a [u8])> {
    let mut r = Reader(bytes);
    (r.take(4)? == magic).then_some(())?;
    Some((u64::from_le_bytes(r.array()?), r.0))
}

/// Reads a byte slice from the front.
struct Reader<'a>(&'a [u8]);

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        (self.0.len() >= n).then(|| {
            let (head, rest) = self.0.split_at(n);
            self.0 = rest;
            head
        })
    }

    fn array<const N: usize>(&mut self) -> Option<[u8; N]> {
        self.take(N).map(|b| b.try_into().expect("N bytes"))
    }
}

/// Whether `name` may name a session: 1 to 64 letters, digits, `-` or `_`,
/// so it is safe as a folder name and in a URL.
pub fn valid_session_name(name: &str) -> bool {
    (1..=64).contains(&name.len())
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_')
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(pose: Option<Pose>) -> FrameMessage {
        FrameMessage {
            index: 12345678901,
            timestamp: 1305031102.175304,
            pose,
            codec: Codec::Rvl,
            payload: vec![1, 2, 3, 250],
        }
    }

    #[test]
    fn frames_round_trip_bit_for_bit() {
        let pose = Pose::new(
            Mat3::from_rotation_y(0.3) * Mat3::from_rotation_x(-1.1),
            Vec3::new(1.5, -0.25, 3.0e-7),
        );
        for f in [frame(None), frame(Some(pose))] {
            let mut bytes = Vec::new();
            f.encode(&mut bytes);
            assert_eq!(FrameMessage::decode(&bytes).unwrap(), f);
        }
    }

    #[test]
    fn every_truncation_and_corruption_of_a_frame_is_an_error() {
        let mut bytes = Vec::new();
        frame(Some(Pose::IDENTITY)).encode(&mut bytes);
        // Header: magic 4, index 8, timestamp 8, flags 1, pose 48, codec 1.
        for n in 0..70 {
            assert!(FrameMessage::decode(&bytes[..n]).is_err(), "{n} bytes");
        }
        let mut wrong = bytes.clone();
        wrong[0] = b'X';
        assert!(FrameMessage::decode(&wrong).is_err());
        let mut flags = bytes.clone();
        flags[20] = 7;
        assert!(FrameMessage::decode(&flags).is_err());
        let mut codec = bytes.clone();
        codec[69] = 99;
        assert!(FrameMessage::decode(&codec)
            .unwrap_err()
            .0
            .contains("codec"));
        let mut nan = bytes.clone();
        nan[21..25].copy_from_slice(&f32::NAN.to_le_bytes());
        assert!(FrameMessage::decode(&nan).unwrap_err().0.contains("pose"));
    }

    #[test]
    fn control_messages_round_trip_and_unknown_ones_are_refused() {
        let hello = ClientMessage::Hello {
            token: "t".into(),
            session: Some("kitchen-1".into()),
            intrinsics: Intrinsics::kinect(),
            track: true,
            realtime: false,
            status_every: 5,
            resume: true,
        };
        let text = serde_json::to_string(&hello).unwrap();
        assert_eq!(serde_json::from_str::<ClientMessage>(&text).unwrap(), hello);
        assert!(serde_json::from_str::<ClientMessage>(r#"{"type":"shutdown"}"#).is_err());
        let extra = text.replacen('{', r#"{"bogus":1,"#, 1);
        assert!(serde_json::from_str::<ClientMessage>(&extra).is_err());
    }

    #[test]
    fn session_names_cannot_leave_their_folder() {
        for ok in ["a", "kitchen_2", "A-b-9"] {
            assert!(valid_session_name(ok));
        }
        for bad in ["", "..", "a/b", "a\\b", "naïve", ".hidden", &"x".repeat(65)] {
            assert!(!valid_session_name(bad), "{bad}");
        }
    }

    #[test]
    fn tagged_messages_carry_their_frame() {
        let m = tagged(STATUS_MAGIC, 42, b"jpeg");
        assert_eq!(untag(STATUS_MAGIC, &m), Some((42, &b"jpeg"[..])));
        assert_eq!(untag(MESH_MAGIC, &m), None);
        assert_eq!(untag(STATUS_MAGIC, &m[..7]), None);
    }
}
