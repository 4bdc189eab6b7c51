//! 16-bit greyscale depth PNGs, the format of both 7-Scenes (millimetres) and TUM (1/5000 m).

use crate::codec::raw::check_scale;
use crate::codec::RawDepth;
use crate::error::{Error, Result};
use crate::image::DepthImage;
use std::fs::File;
use std::io::BufReader;
use std::path::Path;

/// Reads a 16-bit greyscale depth PNG into `out` in metres (`value / units_per_metre`:
/// 1000 for millimetres, 5000 for TUM), reusing `out`'s allocation.
///
/// Both 0 and 65535 become 0.0 (no measurement): Kinect tools write 65535 for
/// pixels they could not measure, and no structured-light sensor reports 13 m or more.
/// Errors (missing file, corrupt data, wrong bit depth or colour type) name the file.
pub fn read_depth_png(path: &Path, units_per_metre: f32, out: &mut DepthImage) -> Result<()> {
    let mut raw = RawDepth::default();
    read_depth_png_raw(path, units_per_metre, &mut raw)?;
    raw.to_metres(out);
    Ok(())
}

/// Reads a 16-bit greyscale depth PNG into `out` as it is stored, in units of
/// `1 / units_per_metre` metres, reusing `out`'s allocation: what a client
/// sends losslessly. Errors as [`read_depth_png`].
pub fn read_depth_png_raw(path: &Path, units_per_metre: f32, out: &mut RawDepth) -> Result<()> {
    check_scale(units_per_metre)?;
    let mut reader = open(path)?;
    let (width, height) = reader.info().size();
    let mut raw = vec![0u8; reader.output_buffer_size()];
    reader
        .next_frame(&mut raw)
        .map_err(|e| decoding_error(path, e))?;
    let values = out.reset(width, height, units_per_metre);
    for (value, be) in values.iter_mut().zip(raw.chunks_exact(2)) {
        *value = u16::from_be_bytes([be[0], be[1]]);
    }
    Ok(())
}

/// Width and height of a depth PNG, from its header only, so opening a dataset stays cheap.
pub(super) fn depth_png_size(path: &Path) -> Result<(u32, u32)> {
    Ok(open(path)?.info().size())
}

/// Opens a PNG and checks it holds 16-bit grey, so a colour image or an 8-bit
/// depth map given by mistake is refused instead of read as nonsense.
fn open(path: &Path) -> Result<png::Reader<BufReader<File>>> {
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    let mut decoder = png::Decoder::new(BufReader::new(file));
    decoder.set_transformations(png::Transformations::IDENTITY);
    let reader = decoder.read_info().map_err(|e| decoding_error(path, e))?;
    let info = reader.info();
    if info.color_type != png::ColorType::Grayscale || info.bit_depth != png::BitDepth::Sixteen {
        return Err(Error::format(
            path,
            format!(
                "depth PNG must be 16-bit greyscale, found {}-bit {:?}",
                info.bit_depth as u8, info.color_type
            ),
        ));
    }
    Ok(reader)
}

/// Turns a PNG decoding failure into an error naming the file; a file that ends
/// early gets a plain message rather than the reader's "failed to fill whole buffer".
pub(super) fn decoding_error(path: &Path, error: png::DecodingError) -> Error {
    match error {
        png::DecodingError::IoError(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
            Error::format(path, "PNG data ends early (truncated file)")
        }
        png::DecodingError::IoError(e) => Error::io(path, e),
        other => Error::format(path, format!("corrupt PNG: {other}")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atomic::scratch::ScratchDir;
    use crate::dataset::test_util::write_png;

    #[test]
    fn converts_to_metres_and_drops_invalid() {
        let dir = ScratchDir::new("depth-png");
        let path = dir.path().join("d.png");
        write_png(&path, 3, 2, &[0, 1000, 1500, 65535, 4000, 65534]);
        let mut image = DepthImage::new(7, 7);
        read_depth_png(&path, 1000.0, &mut image).unwrap();
        assert_eq!((image.width, image.height), (3, 2));
        assert_eq!(image.data, [0.0, 1.0, 1.5, 0.0, 4.0, 65.534]);
        read_depth_png(&path, 5000.0, &mut image).unwrap();
        assert_eq!(image.data[1], 0.2);
        assert_eq!(depth_png_size(&path).unwrap(), (3, 2));
    }

    #[test]
    fn errors_name_the_file() {
        let dir = ScratchDir::new("depth-png-bad");
        let mut image = DepthImage::default();

        let truncated = dir.path().join("truncated.png");
        // Varied values, so the compressed data is long enough to be cut inside.
        let values: Vec<u16> = (0..64 * 64u32).map(|i| (i * 7919 % 5000) as u16).collect();
        write_png(&truncated, 64, 64, &values);
        let bytes = std::fs::read(&truncated).unwrap();
        std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
        let garbage = dir.path().join("garbage.png");
        std::fs::write(&garbage, b"not a png at all").unwrap();
        let eight_bit = dir.path().join("eight.png");
        let mut encoder = png::Encoder::new(std::fs::File::create(&eight_bit).unwrap(), 2, 2);
        encoder.set_color(png::ColorType::Grayscale);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header().unwrap();
        writer.write_image_data(&[1, 2, 3, 4]).unwrap();
        writer.finish().unwrap();

        for (path, expected) in [
            (&truncated, "truncated"),
            (&garbage, "corrupt PNG"),
            (&eight_bit, "16-bit greyscale, found 8-bit Grayscale"),
        ] {
            let e = read_depth_png(path, 1000.0, &mut image).unwrap_err();
            let message = e.to_string();
            assert!(
                message.starts_with(&path.display().to_string()) && message.contains(expected),
                "{message}"
            );
        }
        let missing = dir.path().join("missing.png");
        let e = read_depth_png(&missing, 1000.0, &mut image).unwrap_err();
        assert!(matches!(e, Error::Io { ref path, .. } if path == &missing));
        assert!(read_depth_png(&garbage, 0.0, &mut image).is_err());
    }
}
