//! [`RawDepth`]: a depth image in the sensor's own integer units, the form in
//! which depth travels over the network and is stored, so nothing is lost to
//! a round trip through metres in `f32`.

use crate::error::{Error, Result};
use crate::image::DepthImage;

/// The raw value some sensors and tools (Kinect drivers, 7-Scenes) write for a
/// pixel they could not measure, besides 0. No structured-light or
/// time-of-flight sensor reports 65.535 m in millimetres.
pub const NO_MEASUREMENT_MAX: u16 = u16::MAX;

/// A depth image in integer sensor units: `value / units_per_metre` metres
/// (1000 for millimetres, 5000 for TUM RGB-D); 0 and 65535 mean no measurement.
///
/// The scale is kept as units per metre rather than metres per unit because
/// the common scales (1000, 5000) are exact in `f32` while 0.001 is not, and
/// [`RawDepth::to_metres`] must give bit for bit the depths the dataset
/// readers give.
#[derive(Clone, Debug, PartialEq)]
pub struct RawDepth {
    width: u32,
    height: u32,
    units_per_metre: f32,
    data: Vec<u16>,
}

impl Default for RawDepth {
    /// A 1×1 millimetre image with no measurement.
    fn default() -> Self {
        RawDepth {
            width: 1,
            height: 1,
            units_per_metre: 1000.0,
            data: vec![0],
        }
    }
}

impl RawDepth {
    /// An image of `width × height` row-major `data` in units of
    /// `1 / units_per_metre` metres. Errors name the field at fault: the
    /// size must be at least 1×1 and match `data`, the scale finite and positive.
    pub fn new(width: u32, height: u32, units_per_metre: f32, data: Vec<u16>) -> Result<Self> {
        check_scale(units_per_metre)?;
        if width == 0 || height == 0 {
            return Err(Error::parameter(
                "raw depth size",
                format!("{width}×{height} has no pixels"),
            ));
        }
        if data.len() as u64 != u64::from(width) * u64::from(height) {
            return Err(Error::parameter(
                "raw depth data",
                format!("{} values for a {width}×{height} image", data.len()),
            ));
        }
        Ok(RawDepth {
            width,
            height,
            units_per_metre,
            data,
        })
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Sensor units per metre (1000 for millimetres).
    pub fn units_per_metre(&self) -> f32 {
        self.units_per_metre
    }

    /// Metres per sensor unit (0.001 for millimetres), for display.
    pub fn scale(&self) -> f64 {
        1.0 / f64::from(self.units_per_metre)
    }

    /// Row-major values, `width * height` of them.
    pub fn data(&self) -> &[u16] {
        &self.data
    }

    /// The values, giving up the image.
    pub fn into_data(self) -> Vec<u16> {
        self.data
    }

    /// Makes this a `width × height` image of zeros at the given scale,
    /// keeping the allocation, and returns its values to fill. Used by the
    /// decoders, which have checked the size against their limit.
    pub(crate) fn reset(&mut self, width: u32, height: u32, units_per_metre: f32) -> &mut [u16] {
        self.width = width;
        self.height = height;
        self.units_per_metre = units_per_metre;
        self.data.clear();
        self.data.resize(width as usize * height as usize, 0);
        &mut self.data
    }

    /// Depth in metres into `out` (reusing its allocation): `value /
    /// units_per_metre`, with 0 and 65535 both becoming 0.0 (no measurement),
    /// exactly as the dataset readers convert depth PNGs.
    pub fn to_metres(&self, out: &mut DepthImage) {
        out.reset(self.width, self.height);
        for (depth, &value) in out.data.iter_mut().zip(&self.data) {
            *depth = unit_to_metres(value, self.units_per_metre);
        }
    }

    /// Quantises a depth image in metres (the simulator's) to units of
    /// `1 / units_per_metre` metres, rounding to nearest. Pixels with no
    /// measurement (0, negative, not finite) and depths too far for 16 bits
    /// (65535 units or more, which would read as "no measurement") become 0.
    pub fn from_metres(depth: &DepthImage, units_per_metre: f32) -> Result<RawDepth> {
        let mut raw = RawDepth::default();
        raw.set_from_metres(depth, units_per_metre)?;
        Ok(raw)
    }

    /// [`RawDepth::from_metres`] into this image, keeping its allocation.
    pub fn set_from_metres(&mut self, depth: &DepthImage, units_per_metre: f32) -> Result<()> {
        check_scale(units_per_metre)?;
        if depth.width == 0 || depth.height == 0 {
            return Err(Error::parameter(
                "depth image size",
                format!("{}×{} has no pixels", depth.width, depth.height),
            ));
        }
        let values = self.reset(depth.width, depth.height, units_per_metre);
        for (value, &metres) in values.iter_mut().zip(&depth.data) {
            let units = (f64::from(metres) * f64::from(units_per_metre)).round();
            // NaN fails both comparisons, so it also becomes "no measurement".
            *value = if units >= 1.0 && units < f64::from(NO_MEASUREMENT_MAX) {
                units as u16
            } else {
                0
            };
        }
        Ok(())
    }
}

/// One raw value in metres; 0 and 65535 are no measurement (0.0).
#[inline]
pub(crate) fn unit_to_metres(value: u16, units_per_metre: f32) -> f32 {
    if value == NO_MEASUREMENT_MAX {
        0.0
    } else {
        f32::from(value) / units_per_metre
    }
}

/// A scale must be a finite positive number of units per metre.
pub(crate) fn check_scale(units_per_metre: f32) -> Result<()> {
    if units_per_metre.is_finite() && units_per_metre > 0.0 {
        Ok(())
    } else {
        Err(Error::parameter(
            "depth scale",
            format!("{units_per_metre} units per metre must be positive"),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metres_are_exactly_the_readers_and_invalid_values_are_none() {
        let raw = RawDepth::new(2, 2, 1000.0, vec![0, 1234, 65535, 65534]).unwrap();
        let mut depth = DepthImage::default();
        raw.to_metres(&mut depth);
        assert_eq!(depth.data, [0.0, 1234.0 / 1000.0, 0.0, 65.534]);
        assert_eq!(raw.scale(), 0.001);
    }

    #[test]
    fn quantising_metres_rounds_and_drops_what_16_bits_cannot_hold() {
        let depth = DepthImage {
            width: 3,
            height: 2,
            data: vec![1.2344, 1.2346, 0.0, -1.0, f32::NAN, 70.0],
        };
        let raw = RawDepth::from_metres(&depth, 1000.0).unwrap();
        assert_eq!(raw.data(), [1234, 1235, 0, 0, 0, 0]);
        // Metres → units → metres moves a depth by at most half a unit.
        let mut back = DepthImage::default();
        raw.to_metres(&mut back);
        for (a, b) in depth.data[..2].iter().zip(&back.data) {
            assert!((a - b).abs() <= 0.0005 + 1e-6, "{a} {b}");
        }
    }

    #[test]
    fn bad_sizes_and_scales_are_refused_by_name() {
        for (result, field) in [
            (RawDepth::new(0, 3, 1000.0, vec![]), "raw depth size"),
            (RawDepth::new(2, 2, 1000.0, vec![1; 3]), "raw depth data"),
            (RawDepth::new(1, 1, 0.0, vec![1]), "depth scale"),
            (RawDepth::new(1, 1, f32::NAN, vec![1]), "depth scale"),
            (
                RawDepth::from_metres(&DepthImage::default(), 1000.0),
                "depth image size",
            ),
        ] {
            let e = result.unwrap_err().to_string();
            assert!(e.starts_with(&format!("invalid {field}")), "{e}");
        }
    }
}
