//! 16-bit greyscale PNG (the format depth datasets are stored in) as a
//! codec payload: zlib level 6 with libpng's adaptive per-row filter choice.

use super::RawDepth;
use crate::error::{Error, Result};

const NAME: &str = "png";

/// Appends `depth` as a PNG file to `out`.
pub(crate) fn encode(depth: &RawDepth, out: &mut Vec<u8>) {
    let mut encoder = png::Encoder::new(&mut *out, depth.width(), depth.height());
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::Sixteen);
    encoder.set_compression(png::Compression::Default);
    encoder.set_adaptive_filter(png::AdaptiveFilterType::Adaptive);
    let bytes: Vec<u8> = depth.data().iter().flat_map(|v| v.to_be_bytes()).collect();
    // Writing into memory a header and data that match cannot fail.
    let mut writer = encoder.write_header().expect("PNG header into memory");
    writer
        .write_image_data(&bytes)
        .expect("PNG data of the header's size into memory");
    writer.finish().expect("PNG end into memory");
}

/// Decodes a PNG payload that must be `width × height` 16-bit grey into `values`.
pub(super) fn decode(payload: &[u8], width: u32, height: u32, values: &mut [u16]) -> Result<()> {
    let corrupt = |e: png::DecodingError| Error::codec(NAME, format!("corrupt PNG: {e}"));
    let mut decoder = png::Decoder::new_with_limits(
        payload,
        // The header's size was checked against the caller's limit; the PNG
        // may not decode to more than that image.
        png::Limits {
            bytes: values.len() * 2 + 1024,
        },
    );
    decoder.set_transformations(png::Transformations::IDENTITY);
    let mut reader = decoder.read_info().map_err(corrupt)?;
    let info = reader.info();
    if info.color_type != png::ColorType::Grayscale || info.bit_depth != png::BitDepth::Sixteen {
        return Err(Error::codec(
            NAME,
            format!(
                "PNG must be 16-bit greyscale, found {}-bit {:?}",
                info.bit_depth as u8, info.color_type
            ),
        ));
    }
    if info.size() != (width, height) {
        return Err(Error::codec(
            NAME,
            format!(
                "PNG is {}×{} but the header says {width}×{height}",
                info.width, info.height
            ),
        ));
    }
    let mut bytes = vec![0u8; values.len() * 2];
    reader.next_frame(&mut bytes).map_err(corrupt)?;
    // Through the end chunk: a PNG cut after its pixel data is still truncated.
    reader.finish().map_err(corrupt)?;
    let end = end_of_png(payload);
    if end != Some(payload.len()) {
        return Err(Error::codec(NAME, "bytes after the PNG's end chunk"));
    }
    for (value, be) in values.iter_mut().zip(bytes.chunks_exact(2)) {
        *value = u16::from_be_bytes([be[0], be[1]]);
    }
    Ok(())
}

/// Where the PNG in `bytes` ends: after its signature, the chunks up to and
/// including `IEND` (each a length, a type, the data and a CRC).
fn end_of_png(bytes: &[u8]) -> Option<usize> {
    let mut at = 8;
    loop {
        let head = bytes.get(at..at + 8)?;
        let length = u32::from_be_bytes([head[0], head[1], head[2], head[3]]) as usize;
        at = at.checked_add(12 + length)?;
        if &head[4..8] == b"IEND" {
            return Some(at);
        }
    }
}
