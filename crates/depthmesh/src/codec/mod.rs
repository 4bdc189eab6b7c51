//! Lossless codecs for 16-bit depth images ([`RawDepth`]), for the network
//! and the store.
//!
//! - [`Codec::Raw`]: the values as they are (little-endian), for reference.
//! - [`Codec::Png`]: a 16-bit greyscale PNG, zlib level 6, adaptive filters.
//! - [`Codec::Rvl`]: Wilson's RVL (2017) framed exactly as ROS
//!   `compressed_depth_image_transport` frames it for `16UC1; compressedDepth rvl`,
//!   so streams recorded from ROS decode here ([`rvl`]).
//! - [`Codec::Levels`], the default: the frame's distinct values as a table,
//!   pixels as indices into it, predicted from their neighbours and the
//!   residuals entropy-coded with rANS ([`levels`]). Kinect-class sensors
//!   measure disparity, so a frame holds only a few hundred distinct depths
//!   whose steps grow with distance; in index space a surface is smooth.
//!
//! Every stream but RVL's starts with the same 16-byte header: a 4-byte
//! magic naming the codec, width and height (`u32`), units per metre (`f32`),
//! all little-endian. Decoding never trusts a stream: a truncated, corrupt or
//! mismatched one is an [`Error::Codec`], never a panic, and no stream may
//! claim more pixels than the caller's limit, so nothing allocates more than
//! the limit allows.

mod bits;
pub mod levels;
pub(crate) mod png;
mod rans;
pub(crate) mod raw;
pub mod rvl;

pub use raw::{RawDepth, NO_MEASUREMENT_MAX};

use crate::error::{Error, Result};
use std::fmt;
use std::str::FromStr;

/// A lossless depth codec.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Codec {
    /// Uncompressed values.
    Raw,
    /// 16-bit greyscale PNG, zlib level 6.
    Png,
    /// RVL, bit-compatible with ROS `compressedDepth rvl`.
    Rvl,
    /// Level table, neighbour prediction and rANS: the smallest and, after
    /// RVL, the fastest.
    #[default]
    Levels,
}

impl Codec {
    /// Every codec, the default last.
    pub const ALL: [Codec; 4] = [Codec::Raw, Codec::Png, Codec::Rvl, Codec::Levels];

    /// The codec's name, as [`FromStr`] reads it.
    pub fn name(self) -> &'static str {
        match self {
            Codec::Raw => "raw",
            Codec::Png => "png",
            Codec::Rvl => "rvl",
            Codec::Levels => "levels",
        }
    }

    /// Encodes `depth` into `out`, replacing what it held (its allocation is kept).
    pub fn encode(self, depth: &RawDepth, out: &mut Vec<u8>) {
        Encoder::new(self).encode(depth, out);
    }

    /// Decodes a stream of this codec; `max_pixels` bounds the image size it may claim.
    pub fn decode(self, bytes: &[u8], max_pixels: u64) -> Result<RawDepth> {
        let mut depth = RawDepth::default();
        Decoder::new(self, max_pixels).decode_into(bytes, &mut depth)?;
        Ok(depth)
    }
}

impl fmt::Display for Codec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Codec {
    type Err = Error;

    /// A codec by name; `default` is [`Codec::Levels`]. Errors name `codec`.
    fn from_str(s: &str) -> Result<Self> {
        if s == "default" {
            return Ok(Codec::default());
        }
        Codec::ALL
            .into_iter()
            .find(|c| c.name() == s)
            .ok_or_else(|| {
                Error::parameter(
                    "codec",
                    format!("\"{s}\" is not one of default, raw, png, rvl, levels"),
                )
            })
    }
}

/// Encodes frame after frame with one codec, reusing its working buffers.
#[derive(Debug, Default)]
pub struct Encoder {
    codec: Codec,
    scratch: levels::Scratch,
}

impl Encoder {
    /// An encoder for `codec`.
    pub fn new(codec: Codec) -> Self {
        Encoder {
            codec,
            scratch: levels::Scratch::default(),
        }
    }

    /// The codec it encodes with.
    pub fn codec(&self) -> Codec {
        self.codec
    }

    /// Encodes `depth` into `out`, replacing what it held (its allocation is kept).
    pub fn encode(&mut self, depth: &RawDepth, out: &mut Vec<u8>) {
        out.clear();
        match self.codec {
            Codec::Rvl => rvl::encode(depth, out),
            codec => {
                Header::of(depth).write(codec, out);
                match codec {
                    Codec::Raw => out.extend(depth.data().iter().flat_map(|v| v.to_le_bytes())),
                    Codec::Png => png::encode(depth, out),
                    _ => levels::encode(depth, &mut self.scratch, out),
                }
            }
        }
    }
}

/// Decodes frame after frame of one codec, bounding their size and reusing
/// its working buffers.
#[derive(Debug)]
pub struct Decoder {
    codec: Codec,
    max_pixels: u64,
    scratch: levels::Scratch,
}

impl Decoder {
    /// A decoder for `codec` that refuses any image of more than `max_pixels`.
    pub fn new(codec: Codec, max_pixels: u64) -> Self {
        Decoder {
            codec,
            max_pixels,
            scratch: levels::Scratch::default(),
        }
    }

    /// Decodes `bytes` into `out`, reusing its allocation. On error `out`
    /// holds no meaningful image.
    pub fn decode_into(&mut self, bytes: &[u8], out: &mut RawDepth) -> Result<()> {
        if self.codec == Codec::Rvl {
            return rvl::decode(bytes, self.max_pixels, out);
        }
        let (header, payload) = Header::read(self.codec, bytes, self.max_pixels)?;
        let values = out.reset(header.width, header.height, header.units_per_metre);
        match self.codec {
            Codec::Raw => decode_raw(payload, values),
            Codec::Png => png::decode(payload, header.width, header.height, values),
            _ => levels::decode(payload, header.width, &mut self.scratch, values),
        }
    }
}

/// The uncompressed payload: every value, little-endian, and nothing more.
fn decode_raw(payload: &[u8], values: &mut [u16]) -> Result<()> {
    if payload.len() != values.len() * 2 {
        return Err(Error::codec(
            "raw",
            format!(
                "{} payload bytes for {} pixels (expected {})",
                payload.len(),
                values.len(),
                values.len() * 2
            ),
        ));
    }
    for (value, le) in values.iter_mut().zip(payload.chunks_exact(2)) {
        *value = u16::from_le_bytes([le[0], le[1]]);
    }
    Ok(())
}

/// The header of every stream but RVL's.
struct Header {
    width: u32,
    height: u32,
    units_per_metre: f32,
}

impl Header {
    const LEN: usize = 16;

    fn of(depth: &RawDepth) -> Self {
        Header {
            width: depth.width(),
            height: depth.height(),
            units_per_metre: depth.units_per_metre(),
        }
    }

    /// The magic of a codec's stream. RVL streams begin with ROS's own
    /// header instead, so [`Header`] never reads or writes theirs.
    fn magic(codec: Codec) -> &'static [u8; 4] {
        match codec {
            Codec::Raw => b"DMR1",
            Codec::Png => b"DMP1",
            Codec::Rvl => b"DMV1",
            Codec::Levels => b"DML1",
        }
    }

    fn write(&self, codec: Codec, out: &mut Vec<u8>) {
        out.extend_from_slice(Header::magic(codec));
        out.extend_from_slice(&self.width.to_le_bytes());
        out.extend_from_slice(&self.height.to_le_bytes());
        out.extend_from_slice(&self.units_per_metre.to_le_bytes());
    }

    /// The header of a `codec` stream and the payload after it.
    fn read(codec: Codec, bytes: &[u8], max_pixels: u64) -> Result<(Header, &[u8])> {
        let name = codec.name();
        if bytes.len() < Header::LEN {
            return Err(Error::codec(
                name,
                format!("{} bytes is shorter than the header", bytes.len()),
            ));
        }
        let (head, payload) = bytes.split_at(Header::LEN);
        let word = |i: usize| [head[i], head[i + 1], head[i + 2], head[i + 3]];
        if &word(0) != Header::magic(codec) {
            return Err(Error::codec(
                name,
                format!(
                    "starts with {:?}, not the {name} magic {:?} (another codec's stream?)",
                    String::from_utf8_lossy(&head[..4]),
                    String::from_utf8_lossy(Header::magic(codec))
                ),
            ));
        }
        let header = Header {
            width: u32::from_le_bytes(word(4)),
            height: u32::from_le_bytes(word(8)),
            units_per_metre: f32::from_le_bytes(word(12)),
        };
        check_size(name, header.width, header.height, max_pixels)?;
        raw::check_scale(header.units_per_metre).map_err(|e| Error::codec(name, e.to_string()))?;
        Ok((header, payload))
    }
}

/// A stream's image must have pixels, and no more than the caller allows.
fn check_size(codec: &'static str, width: u32, height: u32, max_pixels: u64) -> Result<()> {
    let pixels = u64::from(width) * u64::from(height);
    if pixels == 0 {
        return Err(Error::codec(
            codec,
            format!("image size {width}×{height} has no pixels"),
        ));
    }
    if pixels > max_pixels {
        return Err(Error::codec(
            codec,
            format!("image size {width}×{height} is over the limit of {max_pixels} pixels"),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests;
