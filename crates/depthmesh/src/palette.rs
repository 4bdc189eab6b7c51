//! Colours that encode map quantities, shared by mesh files and images.

/// Hue of iteration 1, a yellow like the first iteration in the thesis figures.
const FIRST_HUE: f32 = 55.0;
/// 360° / φ²: consecutive hues land far apart, and no hue repeats however many
/// iterations there are, unlike a cycled palette.
const GOLDEN_ANGLE: f32 = 137.507_76;

/// A bright colour for the surface added in `iteration` (1-based), clearly
/// different from those of the neighbouring iterations, so a mesh coloured by
/// the iteration that added each part reads like the thesis's figures.
pub fn iteration_color(iteration: u32) -> [u8; 3] {
    let steps = (iteration as f32 - 1.0) * GOLDEN_ANGLE;
    hsv_to_rgb(FIRST_HUE + steps.rem_euclid(360.0), 0.8, 1.0)
}

/// HSV (hue in degrees, saturation and value in 0..=1) to 8-bit RGB.
pub fn hsv_to_rgb(hue: f32, saturation: f32, value: f32) -> [u8; 3] {
    let h = (hue.rem_euclid(360.0)) / 60.0;
    let c = value * saturation;
    let x = c * (1.0 - (h % 2.0 - 1.0).abs());
    let (r, g, b) = match h as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = value - c;
    [r, g, b].map(|v| ((v + m) * 255.0).round().clamp(0.0, 255.0) as u8)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn iteration_colours_are_bright_and_distinct() {
        let first = iteration_color(1);
        assert!(
            first[0] > 200 && first[1] > 200 && first[2] < 100,
            "yellow: {first:?}"
        );
        let colours: Vec<[u8; 3]> = (0..40).map(iteration_color).collect();
        for c in &colours {
            assert_eq!(c.iter().max(), Some(&255), "full value: {c:?}");
        }
        for pair in colours.windows(2) {
            let distance: i32 = (0..3)
                .map(|i| (i32::from(pair[0][i]) - i32::from(pair[1][i])).abs())
                .sum();
            assert!(distance > 150, "{pair:?}");
        }
        assert_eq!(hsv_to_rgb(0.0, 1.0, 1.0), [255, 0, 0]);
        assert_eq!(hsv_to_rgb(120.0, 1.0, 1.0), [0, 255, 0]);
    }
}
