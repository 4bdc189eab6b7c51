//! JPEG encoding of the images the server sends (status and depth views).

pub use jpeg_encoder::ColorType;

/// JPEG quality: shading and colour-mapped depth survive it well at a
/// tenth of a PNG's size.
const QUALITY: u8 = 80;

/// `pixels` (`width`×`height`, laid out as `color` says) as a JPEG in
/// `out`; `None` if it cannot be encoded (an image larger than JPEG's
/// 65,535 pixels a side).
pub fn encode<'a>(
    pixels: &[u8],
    width: u32,
    height: u32,
    color: ColorType,
    out: &'a mut Vec<u8>,
) -> Option<&'a [u8]> {
    out.clear();
    let (w, h) = (u16::try_from(width).ok()?, u16::try_from(height).ok()?);
    jpeg_encoder::Encoder::new(&mut *out, QUALITY)
        .encode(pixels, w, h, color)
        .ok()?;
    Some(out)
}
