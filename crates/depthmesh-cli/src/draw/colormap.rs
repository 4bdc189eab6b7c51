//! Colours for depth images, iterations and shading.

use glam::Vec3;

use super::canvas::{Canvas, Rgb, BLACK};

/// How [`depth_colors`] turns a normalised depth into a colour.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Colormap {
    /// Google's Turbo rainbow: near is dark blue, far is dark red. Its
    /// lightness rises and falls smoothly, so depth steps read as edges
    /// without the false bands of the classic jet map.
    Turbo,
}

impl Colormap {
    /// The colour for `t` in `[0, 1]` (near to far); values outside are clamped.
    pub fn color(self, t: f32) -> Rgb {
        match self {
            Colormap::Turbo => depthmesh::palette::turbo(t),
        }
    }
}

/// Renders a row-major metric depth image, mapping `min..=max` metres across
/// `map`. Pixels without a measurement (zero or not finite) are black.
///
/// # Panics
/// If `depth` does not hold `width * height` values.
pub fn depth_colors(
    depth: &[f32],
    width: u32,
    height: u32,
    min: f32,
    max: f32,
    map: Colormap,
) -> Canvas {
    assert_eq!(
        depth.len(),
        width as usize * height as usize,
        "depth image size"
    );
    let range = max - min;
    let pixels = depth
        .iter()
        .map(|&d| {
            if d > 0.0 && d.is_finite() {
                // A degenerate range (a flat wall) shows as the near colour.
                map.color(if range > 0.0 { (d - min) / range } else { 0.0 })
            } else {
                BLACK
            }
        })
        .collect();
    Canvas {
        width,
        height,
        pixels,
    }
}

/// Share of brightness that faces turned away from the light keep, so that
/// their shape still shows instead of a flat black silhouette.
const AMBIENT: f32 = 0.3;

/// Brightness factor in `[AMBIENT, 1]` for a surface with `normal` lit from
/// `light_dir` (pointing towards the light); neither needs to be unit length.
/// Lighting is two-sided because mesh triangles from different depth images
/// are not consistently oriented.
pub fn normal_shade(normal: Vec3, light_dir: Vec3) -> f32 {
    let lambert = normal
        .normalize_or_zero()
        .dot(light_dir.normalize_or_zero())
        .abs();
    AMBIENT + (1.0 - AMBIENT) * lambert
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_endpoints_and_invalid_pixels() {
        let depth = [0.0, 1.0, 3.0, 5.0, 9.0, f32::NAN, -1.0];
        let c = depth_colors(&depth, 7, 1, 1.0, 5.0, Colormap::Turbo);
        assert_eq!(c.pixels[0], BLACK);
        assert_eq!(c.pixels[1], [48, 18, 59]);
        assert_eq!(c.pixels[2], [164, 252, 60], "the middle sample");
        assert_eq!(c.pixels[3], [122, 4, 3]);
        assert_eq!(c.pixels[4], [122, 4, 3], "beyond max clamps");
        assert_eq!(&c.pixels[5..], &[BLACK, BLACK]);
    }

    #[test]
    fn degenerate_range_does_not_produce_nan_colours() {
        let c = depth_colors(&[2.0, 2.0], 2, 1, 2.0, 2.0, Colormap::Turbo);
        assert_eq!(c.pixels, vec![[48, 18, 59]; 2]);
        assert_eq!(Colormap::Turbo.color(f32::NAN), [48, 18, 59]);
    }

    #[test]
    #[should_panic(expected = "depth image size")]
    fn mismatched_size_is_a_bug() {
        depth_colors(&[1.0; 3], 2, 2, 0.0, 1.0, Colormap::Turbo);
    }

    #[test]
    fn shading_is_two_sided_with_ambient_floor() {
        let up = Vec3::Z;
        assert_eq!(normal_shade(up, Vec3::Z * 3.0), 1.0);
        assert_eq!(normal_shade(-up, Vec3::Z), 1.0);
        assert_eq!(normal_shade(up, Vec3::X), AMBIENT);
        assert_eq!(normal_shade(Vec3::ZERO, Vec3::X), AMBIENT);
    }
}
