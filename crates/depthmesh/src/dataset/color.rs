//! Colour frames: JPEG (7-Scenes as redistributed) and PNG (TUM, original 7-Scenes).

use super::depth_png::decoding_error;
use crate::error::{Error, Result};
use crate::image::ColorImage;
use std::fs::File;
use std::io::BufReader;
use std::path::Path;

/// Reads an 8-bit colour image, choosing the decoder by the file's extension.
pub(super) fn read_color(path: &Path) -> Result<ColorImage> {
    let extension = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match extension.as_deref() {
        Some("png") => read_png(path),
        Some("jpg" | "jpeg") => read_jpeg(path),
        _ => Err(Error::format(path, "colour images must be .png or .jpg")),
    }
}

fn open(path: &Path) -> Result<BufReader<File>> {
    Ok(BufReader::new(
        File::open(path).map_err(|e| Error::io(path, e))?,
    ))
}

fn read_png(path: &Path) -> Result<ColorImage> {
    let mut decoder = png::Decoder::new(open(path)?);
    // Palette and 16-bit images come out as plain 8-bit channels.
    decoder.set_transformations(png::Transformations::normalize_to_color8());
    let mut reader = decoder.read_info().map_err(|e| decoding_error(path, e))?;
    let mut pixels = vec![0u8; reader.output_buffer_size()];
    let info = reader
        .next_frame(&mut pixels)
        .map_err(|e| decoding_error(path, e))?;
    pack(
        path,
        info.width,
        info.height,
        &pixels,
        info.color_type.samples(),
    )
}

fn read_jpeg(path: &Path) -> Result<ColorImage> {
    let mut decoder = jpeg_decoder::Decoder::new(open(path)?);
    let pixels = decoder
        .decode()
        .map_err(|e| Error::format(path, format!("corrupt JPEG: {e}")))?;
    let info = decoder
        .info()
        .ok_or_else(|| Error::format(path, "JPEG has no image header"))?;
    let channels = match info.pixel_format {
        jpeg_decoder::PixelFormat::L8 => 1,
        jpeg_decoder::PixelFormat::RGB24 => 3,
        other => {
            return Err(Error::format(
                path,
                format!("unsupported JPEG pixel format {other:?} (expected RGB or grey)"),
            ))
        }
    };
    pack(
        path,
        u32::from(info.width),
        u32::from(info.height),
        &pixels,
        channels,
    )
}

/// Packs interleaved 8-bit samples (grey, grey+alpha, RGB or RGBA) as RGB.
fn pack(
    path: &Path,
    width: u32,
    height: u32,
    samples: &[u8],
    channels: usize,
) -> Result<ColorImage> {
    let count = width as usize * height as usize;
    if samples.len() < count * channels {
        return Err(Error::format(
            path,
            "decoded image is shorter than its size says",
        ));
    }
    let data = samples
        .chunks_exact(channels)
        .take(count)
        .map(|p| {
            if channels < 3 {
                [p[0]; 3]
            } else {
                [p[0], p[1], p[2]]
            }
        })
        .collect();
    Ok(ColorImage {
        width,
        height,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atomic::scratch::ScratchDir;
    use crate::dataset::test_util::write_rgb_png;

    #[test]
    fn reads_png_and_jpeg() {
        let dir = ScratchDir::new("color");
        let png_path = dir.path().join("c.png");
        write_rgb_png(&png_path, 2, 1, &[[255, 0, 0], [1, 2, 3]]);
        let image = read_color(&png_path).unwrap();
        assert_eq!((image.width, image.height), (2, 1));
        assert_eq!(image.data, [[255, 0, 0], [1, 2, 3]]);

        // An 8×8 JPEG of one colour, made with cjpeg at quality 100 without subsampling.
        let jpeg_path = dir.path().join("c.JPG");
        std::fs::write(&jpeg_path, include_bytes!("testdata/solid-200-100-50.jpg")).unwrap();
        let image = read_color(&jpeg_path).unwrap();
        assert_eq!((image.width, image.height), (8, 8));
        for p in &image.data {
            let close = |a: u8, b: u8| a.abs_diff(b) <= 2;
            assert!(
                close(p[0], 200) && close(p[1], 100) && close(p[2], 50),
                "{p:?}"
            );
        }

        let bytes = std::fs::read(&jpeg_path).unwrap();
        std::fs::write(&jpeg_path, &bytes[..bytes.len() / 2]).unwrap();
        let e = read_color(&jpeg_path).unwrap_err().to_string();
        assert!(e.starts_with(&jpeg_path.display().to_string()), "{e}");
        let e = read_color(&dir.path().join("c.bmp"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("c.bmp: colour images must be .png or .jpg"),
            "{e}"
        );
    }
}
