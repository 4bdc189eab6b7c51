//! The default depth codec: a table of the frame's distinct values, each
//! pixel as its index in the table, predicted from its neighbours, the
//! residuals entropy-coded with rANS under a context of local activity.
//!
//! Why levels: Kinect-class sensors measure disparity, so the depths of one
//! frame take only a few hundred distinct values whose spacing grows with
//! distance (7-Scenes: about 300 per frame, 2 mm apart at 0.8 m, 35 mm at
//! 3.5 m). A plane seen at an angle steps through them one at a time, which
//! in millimetres is a residual of up to 35 but in indices is ±1. Sensors
//! without that quantisation simply get a dense table, which costs about a
//! bit per value in it.
//!
//! Per pixel `x` with left `a`, up `b`, up-left `c` and up-right `d` (indices):
//! the prediction is LOCO-I's median edge detector `MED(a, b, c)`; the
//! residual, wrapped to 16 bits and zig-zagged, is one of 21 symbols (0–7
//! themselves, then one per bit length with the bits below the top one sent
//! raw); the symbol's frequencies are counted per frame in 8 contexts, the
//! bit length of `|a − c| + |b − c| + |d − b|`, and sent with the frame.
//!
//! Payload after the common header, little-endian:
//! - `u32` byte length, then the level table as a bit stream: the count
//!   less one, then each value's gap to the one before less one (the first:
//!   its value), all Elias gamma codes;
//! - 8 frequency tables (one per context, see the codec's `rans` module);
//! - per band of 64 rows: the rANS bytes, then the raw bits, each after its
//!   `u32` length. Bands are predicted independently (a band's first row
//!   from its left neighbours only), so a decoder could take them in
//!   parallel; this one codes them in turn, as a 640×480 frame takes about
//!   2 ms on one core and waking rayon's threads from outside the pool cost
//!   more than that on a busy 2-core machine (measured with `bench codec`).

use super::bits::{BitReader, BitWriter};
use super::rans::{encode_all, encode_table, DecodeTable, Frequencies, RansDecoder};
use super::RawDepth;
use crate::error::{Error, Result};

const NAME: &str = "levels";
/// Contexts: bit lengths 0–6 of the local activity, and 7 for all larger.
const CONTEXTS: usize = 8;
/// Residuals below this are symbols of their own.
const DIRECT: u32 = 8;
/// Symbols: `DIRECT` direct ones, then one per bit length from 4 to 16.
const SYMBOLS: usize = DIRECT as usize + 13;
/// Rows per independently coded band: large enough that a band's first
/// row (predicted less well) and its 8 bytes of lengths are noise, small
/// enough that a 480-row frame could be decoded by 8 threads.
const BAND_ROWS: usize = 64;

/// Symbol counts per code (`context * SYMBOLS + symbol`).
type Counts = [u32; CODES];
const CODES: usize = CONTEXTS * SYMBOLS;

/// Working buffers kept between frames.
#[derive(Debug, Default)]
pub struct Scratch {
    index_of: Vec<u16>,
    levels: Vec<u16>,
    /// Per pixel `context * SYMBOLS + symbol`, which fits a byte.
    codes: Vec<u8>,
    bands: Vec<Band>,
}

/// One band's streams and symbol counts while encoding.
#[derive(Debug)]
struct Band {
    /// Indices of the row above and of this row.
    up: Vec<u16>,
    row: Vec<u16>,
    bits: BitWriter,
    rans: Vec<u8>,
    counts: Counts,
}

impl Default for Band {
    fn default() -> Self {
        Band {
            up: Vec::new(),
            row: Vec::new(),
            bits: BitWriter::default(),
            rans: Vec::new(),
            counts: [0; CODES],
        }
    }
}

/// Appends the payload of `depth` to `out`.
pub(super) fn encode(depth: &RawDepth, scratch: &mut Scratch, out: &mut Vec<u8>) {
    let width = depth.width() as usize;
    build_levels(depth.data(), scratch);
    let data = depth.data();
    write_levels(&scratch.levels, out);

    let pixels = depth.data().len();
    scratch.codes.resize(pixels, 0);
    let band_pixels = BAND_ROWS * width;
    scratch
        .bands
        .resize_with(pixels.div_ceil(band_pixels), Band::default);
    let Scratch {
        index_of,
        levels,
        codes,
        bands,
    } = scratch;
    data.chunks(band_pixels)
        .zip(codes.chunks_mut(band_pixels))
        .zip(bands.iter_mut())
        .for_each(|((data, codes), band)| model_band(data, index_of, width, codes, band));
    clear_levels(index_of, levels);

    let mut counts = [0u32; CODES];
    for band in bands.iter() {
        for (total, count) in counts.iter_mut().zip(&band.counts) {
            *total += count;
        }
    }
    let mut table = Vec::with_capacity(CODES);
    for context_counts in counts.chunks_exact(SYMBOLS) {
        let context_counts: &[u32; SYMBOLS] = context_counts.try_into().expect("SYMBOLS counts");
        let freq = Frequencies::normalise(context_counts);
        freq.write(out);
        table.extend(encode_table(&freq));
    }
    codes
        .chunks(band_pixels)
        .zip(bands.iter_mut())
        .for_each(|(codes, band)| {
            encode_all(codes, &table, &mut band.rans);
        });
    for band in bands.iter_mut() {
        let bits = band.bits.finish();
        put_sized(&band.rans, out);
        put_sized(bits, out);
    }
}

/// Decodes a payload into `values`, a `width`-wide image whose size the
/// header gave and the caller bounded.
pub(super) fn decode(
    payload: &[u8],
    width: u32,
    scratch: &mut Scratch,
    values: &mut [u16],
) -> Result<()> {
    let width = width as usize;
    let rest = read_levels(payload, &mut scratch.levels)?;
    let mut tables = Vec::with_capacity(CONTEXTS);
    let mut rest = rest;
    for _ in 0..CONTEXTS {
        let (freq, after) = Frequencies::<SYMBOLS>::read(rest, NAME)?;
        tables.push(DecodeTable::new(&freq));
        rest = after;
    }
    let band_pixels = BAND_ROWS * width;
    let mut streams = Vec::with_capacity(values.len().div_ceil(band_pixels));
    for _ in 0..values.len().div_ceil(band_pixels) {
        let (rans, after) = take_sized(rest)?;
        let (bits, after) = take_sized(after)?;
        streams.push((rans, bits));
        rest = after;
    }
    if !rest.is_empty() {
        return Err(Error::codec(
            NAME,
            format!("{} bytes left after the last band", rest.len()),
        ));
    }
    let levels = &scratch.levels;
    for (band, (rans, bits)) in values.chunks_mut(band_pixels).zip(streams) {
        decode_band(band, width, &tables, levels.len(), rans, bits)?;
        for value in band.iter_mut() {
            *value = levels[usize::from(*value)];
        }
    }
    Ok(())
}

/// The sorted distinct values of `data` into `scratch.levels`, and the
/// index of each among them into `scratch.index_of`, whose other entries
/// are zero and which [`clear_levels`] leaves all zero again.
fn build_levels(data: &[u16], scratch: &mut Scratch) {
    let index_of = &mut scratch.index_of;
    index_of.resize(1 << 16, 0);
    for &v in data {
        index_of[usize::from(v)] = 1;
    }
    scratch.levels.clear();
    // Blocks of 64 marks tested at once (the OR vectorises), as a frame
    // holds a few hundred of the 65536 values.
    for (block, marks) in index_of.chunks_exact_mut(64).enumerate() {
        if marks.iter().fold(0, |any, &m| any | m) == 0 {
            continue;
        }
        for (offset, mark) in marks.iter_mut().enumerate() {
            if *mark != 0 {
                *mark = scratch.levels.len() as u16;
                scratch.levels.push((block * 64 + offset) as u16);
            }
        }
    }
}

/// Zeroes the entries [`build_levels`] set, ready for the next frame.
fn clear_levels(index_of: &mut [u16], levels: &[u16]) {
    for &level in levels {
        index_of[usize::from(level)] = 0;
    }
}

fn write_levels(levels: &[u16], out: &mut Vec<u8>) {
    let mut bits = BitWriter::default();
    bits.put_gamma(levels.len() as u32 - 1);
    let mut next = 0u32;
    for &level in levels {
        bits.put_gamma(u32::from(level) - next);
        next = u32::from(level) + 1;
    }
    put_sized(bits.finish(), out);
}

/// Appends a `u32` length and the bytes, as [`take_sized`] reads them.
fn put_sized(bytes: &[u8], out: &mut Vec<u8>) {
    out.extend_from_slice(&(bytes.len() as u32).to_le_bytes());
    out.extend_from_slice(bytes);
}

/// Reads the level table into `levels`, returning the bytes after it.
fn read_levels<'a>(payload: &'a [u8], levels: &mut Vec<u16>) -> Result<&'a [u8]> {
    let (table, rest) = take_sized(payload)?;
    let mut bits = BitReader::new(table, NAME);
    let count = bits.get_gamma()? as usize + 1;
    if count > 1 << 16 {
        return Err(Error::codec(
            NAME,
            format!("{count} levels in a 16-bit image"),
        ));
    }
    levels.clear();
    let mut next = 0u32;
    for _ in 0..count {
        let value = next + bits.get_gamma()?;
        let Ok(level) = u16::try_from(value) else {
            return Err(Error::codec(NAME, format!("level {value} is over 16 bits")));
        };
        levels.push(level);
        next = value + 1;
    }
    if !bits.at_end() {
        return Err(Error::codec(NAME, "level table longer than its levels"));
    }
    Ok(rest)
}

/// A `u32` length and that many bytes, from the start of `bytes`.
fn take_sized(bytes: &[u8]) -> Result<(&[u8], &[u8])> {
    let Some((length, rest)) = bytes.split_first_chunk::<4>() else {
        return Err(Error::codec(NAME, "payload ends early (truncated)"));
    };
    let length = u32::from_le_bytes(*length) as usize;
    if rest.len() < length {
        return Err(Error::codec(
            NAME,
            format!(
                "a section of {length} bytes where {} remain (truncated)",
                rest.len()
            ),
        ));
    }
    Ok(rest.split_at(length))
}

/// Walks a row of `width` pixels in order, calling `pixel(x, prediction,
/// context)`, which returns the pixel's index (known when encoding, decoded
/// when decoding). Neighbours slide along in registers: left `a`, up `b`,
/// up-left `c`, up-right `d`; at the left edge `a` and `c` are `b`, at the
/// right `d` is `b`; a band's first row (no `up`) predicts from the left
/// alone in context 0.
#[inline(always)]
fn walk_row<E>(
    up: Option<&[u16]>,
    width: usize,
    mut pixel: impl FnMut(usize, u16, usize) -> Result<u16, E>,
) -> Result<(), E> {
    let Some(up) = up else {
        let mut a = 0;
        for x in 0..width {
            a = pixel(x, a, 0)?;
        }
        return Ok(());
    };
    let first = i32::from(up[0]);
    let (mut a, mut b, mut c) = (first, first, first);
    for x in 0..width {
        let d = up.get(x + 1).map_or(b, |&d| i32::from(d));
        // LOCO-I's median edge detector, median(a, b, a + b - c), without branches.
        let prediction = (a + b - c).clamp(a.min(b), a.max(b));
        let activity = (a - c).unsigned_abs() + (b - c).unsigned_abs() + (d - b).unsigned_abs();
        let context = (32 - activity.leading_zeros()).min(CONTEXTS as u32 - 1);
        a = i32::from(pixel(x, prediction as u16, context as usize)?);
        c = b;
        b = d;
    }
    Ok(())
}

/// The symbol of a zig-zagged residual, and the raw bits that complete it.
#[inline(always)]
fn symbol_of(zigzag: u32) -> (u8, u32, u32) {
    if zigzag < DIRECT {
        return (zigzag as u8, 0, 0);
    }
    let length = 32 - zigzag.leading_zeros();
    (
        (length + DIRECT - 4) as u8,
        zigzag - (1 << (length - 1)),
        length - 1,
    )
}

/// Codes and raw bits of one band of values, mapped to indices a row at a time.
fn model_band(data: &[u16], index_of: &[u16], width: usize, codes: &mut [u8], band: &mut Band) {
    band.bits.clear();
    let (mut up, mut row) = (std::mem::take(&mut band.up), std::mem::take(&mut band.row));
    let rows = data.chunks_exact(width).zip(codes.chunks_exact_mut(width));
    for (y, (values, codes)) in rows.enumerate() {
        row.clear();
        row.extend(values.iter().map(|&v| index_of[usize::from(v)]));
        let walked = walk_row(
            (y > 0).then_some(&up[..]),
            width,
            |x, prediction, context| {
                let index = row[x];
                let residual = index.wrapping_sub(prediction) as i16;
                let zigzag = ((residual << 1) ^ (residual >> 15)) as u16;
                let (symbol, extra, extra_bits) = symbol_of(u32::from(zigzag));
                if extra_bits > 0 {
                    band.bits.put(extra, extra_bits);
                }
                codes[x] = (context * SYMBOLS) as u8 + symbol;
                Ok::<_, std::convert::Infallible>(index)
            },
        );
        let Ok(()) = walked;
        std::mem::swap(&mut up, &mut row);
    }
    // Counted after, four bytes at a time into four tables, so that
    // counting the same code again does not wait on its own store.
    let mut counts = [[0u32; CODES]; 4];
    let mut quads = codes.chunks_exact(4);
    for quad in &mut quads {
        for (set, &code) in counts.iter_mut().zip(quad) {
            set[usize::from(code)] += 1;
        }
    }
    for &code in quads.remainder() {
        counts[0][usize::from(code)] += 1;
    }
    (band.up, band.row) = (up, row);
    band.counts = [0; CODES];
    for set in &counts {
        for (total, count) in band.counts.iter_mut().zip(set) {
            *total += count;
        }
    }
}

/// Decodes one band's indices into `band`, checking each against the table.
fn decode_band(
    band: &mut [u16],
    width: usize,
    tables: &[DecodeTable],
    level_count: usize,
    rans: &[u8],
    bits: &[u8],
) -> Result<()> {
    let mut decoder = RansDecoder::new(rans, NAME)?;
    let mut bits = BitReader::new(bits, NAME);
    for y in 0..band.len() / width {
        let (done, rest) = band.split_at_mut(y * width);
        let up = y.checked_sub(1).map(|u| &done[u * width..]);
        let row = &mut rest[..width];
        walk_row(up, width, |x, prediction, context| {
            let symbol = u32::from(decoder.get(y * width + x, &tables[context])?);
            let zigzag = if symbol < DIRECT {
                symbol
            } else {
                let length = symbol + 4 - DIRECT;
                (1 << (length - 1)) | bits.get(length - 1)?
            } as u16;
            let residual = (zigzag >> 1) ^ 0u16.wrapping_sub(zigzag & 1);
            let index = prediction.wrapping_add(residual);
            if usize::from(index) >= level_count {
                return Err(Error::codec(
                    NAME,
                    format!("index {index} past the {level_count} levels (corrupt)"),
                ));
            }
            row[x] = index;
            Ok(index)
        })?;
    }
    decoder.finish()?;
    if !bits.at_end() {
        return Err(Error::codec(NAME, "raw bits left after the band (corrupt)"));
    }
    Ok(())
}
