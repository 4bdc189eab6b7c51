//! Writers for the synthetic datasets the reader tests build.

use crate::atomic::scratch::ScratchDir;
use std::path::Path;

fn write(
    path: &Path,
    width: u32,
    height: u32,
    color: png::ColorType,
    depth: png::BitDepth,
    bytes: &[u8],
) {
    let file = std::fs::File::create(path).expect("create test PNG");
    let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), width, height);
    encoder.set_color(color);
    encoder.set_depth(depth);
    let mut writer = encoder.write_header().expect("PNG header");
    writer.write_image_data(bytes).expect("PNG data");
    writer.finish().expect("PNG end");
}

/// Writes a 16-bit greyscale PNG (PNG stores samples big-endian).
pub(crate) fn write_png(path: &Path, width: u32, height: u32, values: &[u16]) {
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
    write(
        path,
        width,
        height,
        png::ColorType::Grayscale,
        png::BitDepth::Sixteen,
        &bytes,
    );
}

/// Writes an 8-bit RGB PNG.
pub(crate) fn write_rgb_png(path: &Path, width: u32, height: u32, pixels: &[[u8; 3]]) {
    write(
        path,
        width,
        height,
        png::ColorType::Rgb,
        png::BitDepth::Eight,
        pixels.as_flattened(),
    );
}

/// Writes a 4×3 frames folder of `count` frames: frame `n` has depth
/// `1000 + 100 n` mm everywhere except pixel 0 (none) and pixel 1 (65535),
/// and a camera moved `n` cm along x, turned 90° about y.
pub(crate) fn frames_folder(tag: &str, count: usize) -> ScratchDir {
    let dir = ScratchDir::new(tag);
    std::fs::write(
        dir.path().join("camera-intrinsics.txt"),
        "5.0e+00 0 1.5\n0 5 1\n0 0 1\n",
    )
    .unwrap();
    for n in 0..count {
        let stem = dir.path().join(format!("frame-{n:06}"));
        let mut depth = vec![1000 + 100 * n as u16; 12];
        depth[0] = 0;
        depth[1] = u16::MAX;
        write_png(&stem.with_extension("depth.png"), 4, 3, &depth);
        write_rgb_png(
            &stem.with_extension("color.png"),
            4,
            3,
            &[[n as u8, 0, 0]; 12],
        );
        std::fs::write(
            stem.with_extension("pose.txt"),
            format!("0 0 1 {}\n0 1 0 0\n-1 0 0 0\n0 0 0 1\n", 0.01 * n as f64),
        )
        .unwrap();
    }
    dir
}
