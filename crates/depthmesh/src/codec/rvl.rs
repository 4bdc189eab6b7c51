//! RVL (Wilson, "Fast lossless depth image compression", 2017) as ROS
//! `compressed_depth_image_transport` writes it for `16UC1; compressedDepth rvl`.
//!
//! A ROS stream, all little-endian:
//!
//! | bytes | field |
//! |---|---|
//! | 0..4 | `ConfigHeader.format`, `i32`, 0 (`INV_DEPTH`) |
//! | 4..12 | `ConfigHeader.depthParam[2]`, `f32`; unused by ROS for 16-bit images (zero) |
//! | 12..16 | width (`cols`), `u32` |
//! | 16..20 | height (`rows`), `u32` |
//! | 20.. | the RVL payload |
//!
//! The payload is a sequence of 32-bit little-endian words, each holding
//! eight 4-bit nibbles, the first in the most significant bits; the last word
//! is padded with zero nibbles. Numbers are variable-length: 3 bits per
//! nibble, least significant first, the nibble's top bit set when more
//! follow. The pixels, row-major, are coded as alternating runs: a count of
//! zeros, a count of non-zeros, then each non-zero as the zig-zag of its
//! difference from the previous non-zero (`(d << 1) ^ (d >> 31)`, from 0).
//!
//! ROS leaves `depthParam` zero for 16-bit images and means millimetres
//! (REP 118). depthmesh writes units per metre into `depthParam[0]` when
//! they are not 1000, which ROS ignores, and reads 0 as millimetres.
//! Differences wrap modulo 2^16 when decoding, as in ROS's decoder, so the
//! variant that takes differences of signed 16-bit values (the PyPI `rvl`
//! package) decodes too.

use super::raw::check_scale;
use super::{check_size, RawDepth};
use crate::error::{Error, Result};

const NAME: &str = "rvl";
/// ROS's `ConfigHeader` and the width and height after it.
const HEADER_LEN: usize = 20;
/// ROS's `INV_DEPTH`, the only `ConfigHeader.format` it writes.
const INV_DEPTH: i32 = 0;
/// The scale ROS means by a zero `depthParam[0]`: millimetres.
const ROS_UNITS_PER_METRE: f32 = 1000.0;

/// Writes `depth` as a ROS `compressedDepth rvl` stream into `out`.
pub fn encode(depth: &RawDepth, out: &mut Vec<u8>) {
    let units = depth.units_per_metre();
    let param = if units == ROS_UNITS_PER_METRE {
        0.0
    } else {
        units
    };
    out.extend_from_slice(&INV_DEPTH.to_le_bytes());
    out.extend_from_slice(&param.to_le_bytes());
    out.extend_from_slice(&0f32.to_le_bytes());
    out.extend_from_slice(&depth.width().to_le_bytes());
    out.extend_from_slice(&depth.height().to_le_bytes());
    encode_payload(depth.data(), out);
}

/// Reads a ROS `compressedDepth rvl` stream of at most `max_pixels` into `out`.
pub fn decode(bytes: &[u8], max_pixels: u64, out: &mut RawDepth) -> Result<()> {
    if bytes.len() < HEADER_LEN {
        return Err(Error::codec(
            NAME,
            format!("{} bytes is shorter than the header", bytes.len()),
        ));
    }
    let word = |i: usize| [bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]];
    let format = i32::from_le_bytes(word(0));
    if format != INV_DEPTH {
        return Err(Error::codec(
            NAME,
            format!("ConfigHeader format {format} is not INV_DEPTH (0)"),
        ));
    }
    let param = f32::from_le_bytes(word(4));
    let units = if param == 0.0 {
        ROS_UNITS_PER_METRE
    } else {
        param
    };
    check_scale(units).map_err(|e| Error::codec(NAME, e.to_string()))?;
    let (width, height) = (u32::from_le_bytes(word(12)), u32::from_le_bytes(word(16)));
    check_size(NAME, width, height, max_pixels)?;
    decode_payload(&bytes[HEADER_LEN..], out.reset(width, height, units))
}

/// Appends the bare RVL payload of `values` (no header) to `out`.
pub fn encode_payload(values: &[u16], out: &mut Vec<u8>) {
    let mut writer = NibbleWriter {
        out,
        word: 0,
        count: 0,
    };
    let mut previous = 0u16;
    let mut rest = values;
    while !rest.is_empty() {
        let zeros = rest.iter().take_while(|&&v| v == 0).count();
        let nonzeros = rest[zeros..].iter().take_while(|&&v| v != 0).count();
        writer.number(zeros as u64);
        writer.number(nonzeros as u64);
        for &value in &rest[zeros..zeros + nonzeros] {
            let delta = i32::from(value) - i32::from(previous);
            writer.number(u64::from(((delta << 1) ^ (delta >> 31)) as u32));
            previous = value;
        }
        rest = &rest[zeros + nonzeros..];
    }
    writer.finish();
}

/// Decodes a bare RVL payload into exactly `out.len()` pixels. The payload
/// must be whole words and end where the pixels do.
pub fn decode_payload(bytes: &[u8], out: &mut [u16]) -> Result<()> {
    if !bytes.len().is_multiple_of(4) {
        return Err(Error::codec(
            NAME,
            format!("payload of {} bytes is not whole 32-bit words", bytes.len()),
        ));
    }
    let mut reader = NibbleReader {
        bytes,
        position: 0,
        word: 0,
        left: 0,
    };
    let mut previous = 0u16;
    let mut filled = 0;
    // As ROS's decoder: a run of zeros, then a run of non-zeros, even when
    // the zeros end the image (the encoder writes the empty run).
    while filled < out.len() {
        let zeros = reader.run(out.len() - filled)?;
        out[filled..filled + zeros].fill(0);
        filled += zeros;
        let nonzeros = reader.run(out.len() - filled)?;
        for value in &mut out[filled..filled + nonzeros] {
            let zigzag = reader.number()?;
            if zigzag > MAX_ZIGZAG {
                return Err(reader.corrupt(format!("difference code {zigzag} is over 17 bits")));
            }
            let delta = ((zigzag >> 1) as i32) ^ -((zigzag & 1) as i32);
            previous = previous.wrapping_add(delta as u16);
            *value = previous;
        }
        filled += nonzeros;
    }
    if reader.position != bytes.len() {
        return Err(reader.corrupt(format!(
            "{} bytes left after the last pixel",
            bytes.len() - reader.position
        )));
    }
    Ok(())
}

/// The largest zig-zag difference of two 16-bit values (±65535).
const MAX_ZIGZAG: u64 = (1 << 17) - 1;
/// Nibbles of the longest number a valid stream holds: a run of 2^32 pixels.
const MAX_NIBBLES: u32 = 11;

struct NibbleWriter<'a> {
    out: &'a mut Vec<u8>,
    word: u32,
    count: u32,
}

impl NibbleWriter<'_> {
    fn number(&mut self, mut value: u64) {
        loop {
            let mut nibble = (value & 7) as u32;
            value >>= 3;
            if value != 0 {
                nibble |= 8;
            }
            self.word = (self.word << 4) | nibble;
            self.count += 1;
            if self.count == 8 {
                self.out.extend_from_slice(&self.word.to_le_bytes());
                self.word = 0;
                self.count = 0;
            }
            if value == 0 {
                return;
            }
        }
    }

    fn finish(self) {
        if self.count > 0 {
            let word = self.word << (4 * (8 - self.count));
            self.out.extend_from_slice(&word.to_le_bytes());
        }
    }
}

struct NibbleReader<'a> {
    bytes: &'a [u8],
    position: usize,
    word: u32,
    left: u32,
}

impl NibbleReader<'_> {
    fn number(&mut self) -> Result<u64> {
        let mut value = 0u64;
        for shift in 0..MAX_NIBBLES {
            if self.left == 0 {
                let Some(b) = self.bytes.get(self.position..self.position + 4) else {
                    return Err(Error::codec(
                        NAME,
                        "payload ends before the last pixel (truncated)",
                    ));
                };
                self.word = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
                self.position += 4;
                self.left = 8;
            }
            let nibble = self.word >> 28;
            self.word <<= 4;
            self.left -= 1;
            value |= u64::from(nibble & 7) << (3 * shift);
            if nibble & 8 == 0 {
                return Ok(value);
            }
        }
        Err(self.corrupt(format!("a number runs over {MAX_NIBBLES} nibbles")))
    }

    /// A run length, which cannot be more than the pixels still to decode.
    fn run(&mut self, remaining: usize) -> Result<usize> {
        let run = self.number()?;
        if run > remaining as u64 {
            return Err(self.corrupt(format!("a run of {run} pixels where {remaining} remain")));
        }
        Ok(run as usize)
    }

    fn corrupt(&self, message: String) -> Error {
        Error::codec(
            NAME,
            format!("corrupt payload at byte {}: {message}", self.position),
        )
    }
}
