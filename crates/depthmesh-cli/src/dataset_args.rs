//! The flags that select a recorded dataset's frames, shared by the
//! commands that read one.

use anyhow::Result;
use clap::Args;
use depthmesh::dataset::{DatasetOptions, FrameRange, IntrinsicsSpec};

/// Which frames of a dataset, and its camera when the folder does not say.
#[derive(Args, Debug, Clone)]
pub struct DatasetArgs {
    /// Frame numbers to use, half-open: A..B, A.. or ..B.
    #[arg(long)]
    pub frames: Option<FrameRange>,
    /// Use every K-th frame.
    #[arg(long, default_value_t = 1)]
    pub stride: usize,
    /// Intrinsics fx,fy,cx,cy[,width,height] or a file (3×3 K, or "w h fx fy cx cy").
    #[arg(long)]
    pub intrinsics: Option<String>,
    /// Depth PNG units per metre, for folders not in the layout's own
    /// (default 1000, millimetres, for 7-Scenes; 5000 for TUM; e.g. 4000 for
    /// some RealSense recordings).
    #[arg(long, allow_negative_numbers = true)]
    pub depth_scale: Option<f32>,
}

impl DatasetArgs {
    /// Dataset options with these flags; the rest as `base` says.
    pub fn options(&self, base: DatasetOptions) -> Result<DatasetOptions> {
        Ok(DatasetOptions {
            frames: self.frames,
            stride: self.stride,
            intrinsics: self
                .intrinsics
                .as_deref()
                .map(IntrinsicsSpec::from_arg)
                .transpose()?,
            depth_units_per_metre: self.depth_scale,
            ..base
        })
    }
}
