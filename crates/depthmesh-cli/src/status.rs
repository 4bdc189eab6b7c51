//! `--status-every N`: the map seen from the camera, shaded, as
//! `status/frame-NNNNNN.png` every N frames (KinectFusion's status view).

use crate::draw::canvas::Canvas;
use anyhow::{Context, Result};
use depthmesh::atomic::write_atomic;
use depthmesh::session::status::StatusImage;
use depthmesh::session::Session;
use depthmesh::{Intrinsics, Pose};
use std::io::Write;
use std::path::PathBuf;

/// Writes a status image every `every` frames (0: never).
pub struct StatusWriter {
    every: usize,
    dir: PathBuf,
    frames: usize,
    image: StatusImage,
}

impl StatusWriter {
    /// Status images into `dir`, every `every` frames.
    pub fn new(every: usize, dir: PathBuf) -> Self {
        StatusWriter {
            every,
            dir,
            frames: 0,
            image: StatusImage::default(),
        }
    }

    /// Counts a frame and, when due and the frame was fused at `pose`,
    /// writes the map seen from there.
    pub fn after_frame(
        &mut self,
        session: &Session,
        k: &Intrinsics,
        pose: Option<Pose>,
        frame: usize,
    ) -> Result<()> {
        self.frames += 1;
        let (Some(pose), true) = (
            pose,
            self.every > 0 && self.frames.is_multiple_of(self.every),
        ) else {
            return Ok(());
        };
        std::fs::create_dir_all(&self.dir)
            .with_context(|| format!("cannot create {}", self.dir.display()))?;
        self.image.draw(session.backend(), k, &pose);
        let mut canvas = Canvas::new(k.width, k.height, [0; 3]);
        for (px, &g) in canvas.pixels.iter_mut().zip(&self.image.pixels) {
            *px = [g; 3];
        }
        let png = canvas.encode_png();
        write_atomic(&self.dir.join(format!("frame-{frame:06}.png")), |w| {
            w.write_all(&png)
        })?;
        Ok(())
    }
}
