//! Writes frames as a 7-Scenes frames folder, the layout
//! [`super::Dataset::open`] reads and other tools read too: simulated
//! frames saved so are mapped again, by depthmesh or another tool, and the
//! results compared on the same depth.

use crate::atomic::write_atomic;
use crate::camera::{Intrinsics, Pose};
use crate::codec::png::encode as encode_png;
use crate::codec::RawDepth;
use crate::error::{Error, Result};
use crate::image::DepthImage;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Depth PNG units per metre in a frames folder: millimetres.
const UNITS_PER_METRE: f32 = 1000.0;

/// A frames folder being written, one frame at a time (its buffers reused).
#[derive(Debug)]
pub struct FramesWriter {
    dir: PathBuf,
    raw: RawDepth,
    png: Vec<u8>,
}

impl FramesWriter {
    /// Creates `dir` (and its parents) and writes its
    /// `camera-intrinsics.txt` (the 3×3 camera matrix, as 7-Scenes has it;
    /// the size comes from the depth images).
    pub fn create(dir: &Path, intrinsics: &Intrinsics) -> Result<FramesWriter> {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        let k = intrinsics;
        write_atomic(&dir.join("camera-intrinsics.txt"), |w| {
            writeln!(w, "{} 0 {}", k.fx, k.cx)?;
            writeln!(w, "0 {} {}", k.fy, k.cy)?;
            writeln!(w, "0 0 1")
        })?;
        Ok(FramesWriter {
            dir: dir.to_path_buf(),
            raw: RawDepth::default(),
            png: Vec::new(),
        })
    }

    /// Writes frame `number`: `depth` as a 16-bit PNG in millimetres
    /// (rounded to the nearest; no measurement, and depths of 65.535 m or
    /// more, as 0) and `pose` (camera-to-world) as a 4×4 matrix, row by
    /// row, each number as the shortest decimal that reads back to the same
    /// `f32`.
    pub fn write(&mut self, number: usize, depth: &DepthImage, pose: &Pose) -> Result<()> {
        self.raw.set_from_metres(depth, UNITS_PER_METRE)?;
        self.png.clear();
        encode_png(&self.raw, &mut self.png);
        let stem = self.dir.join(format!("frame-{number:06}"));
        let png = &self.png;
        write_atomic(&stem.with_extension("depth.png"), |w| w.write_all(png))?;
        let (r, t) = (pose.rotation, pose.translation);
        write_atomic(&stem.with_extension("pose.txt"), |w| {
            for row in 0..3 {
                let (x, y, z) = (r.col(0)[row], r.col(1)[row], r.col(2)[row]);
                writeln!(w, "{x} {y} {z} {}", t[row])?;
            }
            writeln!(w, "0 0 0 1")
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atomic::scratch::ScratchDir;
    use crate::dataset::{Dataset, DatasetOptions};
    use glam::{Mat3, Vec3};

    #[test]
    fn frames_written_read_back_as_they_were() {
        let dir = ScratchDir::new("frames-writer");
        let k = Intrinsics::from_vertical_fov(8, 6, 60.0);
        let mut depth = DepthImage::new(8, 6);
        for (i, d) in depth.data.iter_mut().enumerate() {
            // Some pixels without a measurement, some too far for 16 bits.
            *d = match i % 7 {
                0 => 0.0,
                1 => 70.0,
                _ => 0.5 + i as f32 * 0.0371,
            };
        }
        let poses = [
            Pose::IDENTITY,
            Pose::new(
                Mat3::from_axis_angle(Vec3::new(0.3, -1.0, 0.2).normalize(), 0.7),
                Vec3::new(0.123_456_7, -2.5, 1.0e-3),
            ),
        ];
        let mut writer = FramesWriter::create(dir.path(), &k).unwrap();
        for (i, pose) in poses.iter().enumerate() {
            writer.write(i, &depth, pose).unwrap();
        }
        let options = DatasetOptions {
            depth_min: 0.0,
            depth_max: 100.0,
            ..DatasetOptions::default()
        };
        let dataset = Dataset::open(dir.path(), &options).unwrap();
        assert_eq!(dataset.intrinsics(), k);
        assert_eq!(dataset.len(), poses.len());
        for (i, pose) in poses.iter().enumerate() {
            let frame = dataset.frame(i).unwrap();
            assert_eq!(frame.pose, Some(*pose));
            for (read, &written) in frame.depth.data.iter().zip(&depth.data) {
                let expected = if written < 65.0 { written } else { 0.0 };
                assert!(
                    (read - expected).abs() <= 0.0005,
                    "{read} against {written}"
                );
            }
        }
    }
}
