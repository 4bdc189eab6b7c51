//! Depth and colour images, and the frame that carries them through the pipeline.

use crate::camera::Pose;

/// A depth image in metres along the optical axis; `0.0` means no measurement.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DepthImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Row-major depths, `width * height` of them.
    pub data: Vec<f32>,
}

impl DepthImage {
    /// An image of the given size with no measurements.
    pub fn new(width: u32, height: u32) -> Self {
        DepthImage {
            width,
            height,
            data: vec![0.0; width as usize * height as usize],
        }
    }

    /// Resizes to `width × height` and clears every pixel, keeping the allocation.
    pub fn reset(&mut self, width: u32, height: u32) {
        self.width = width;
        self.height = height;
        self.data.clear();
        self.data.resize(width as usize * height as usize, 0.0);
    }

    /// Depth at column `u`, row `v`.
    #[inline]
    pub fn get(&self, u: u32, v: u32) -> f32 {
        self.data[v as usize * self.width as usize + u as usize]
    }

    /// Number of pixels with a measurement.
    pub fn valid_count(&self) -> usize {
        self.data.iter().filter(|&&d| d > 0.0).count()
    }

    /// Removes measurements outside `[min, max]` metres (and any non-finite value).
    pub fn clamp_range(&mut self, min: f32, max: f32) {
        for d in &mut self.data {
            if !(d.is_finite() && *d >= min && *d <= max) {
                *d = 0.0;
            }
        }
    }
}

/// An 8-bit RGB image.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ColorImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Row-major pixels.
    pub data: Vec<[u8; 3]>,
}

impl ColorImage {
    /// A black image of the given size.
    pub fn new(width: u32, height: u32) -> Self {
        ColorImage {
            width,
            height,
            data: vec![[0; 3]; width as usize * height as usize],
        }
    }
}

/// One sensor frame: a depth image, optionally colour and a pose.
#[derive(Clone, Debug, Default)]
pub struct Frame {
    /// Position in the stream (frame number of the dataset or simulator iteration).
    pub index: usize,
    /// Timestamp in seconds (the dataset's own, or the frame number).
    pub timestamp: f64,
    /// Depth in metres.
    pub depth: DepthImage,
    /// Colour, when the source has it.
    pub color: Option<ColorImage>,
    /// Camera-to-world pose, when the source knows it.
    pub pose: Option<Pose>,
}
