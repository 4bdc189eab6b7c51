//! Colours that encode map quantities, shared by mesh files and images.

/// A distinct, bright colour for each iteration, so that neighbouring
/// iterations stand apart when a mesh is coloured by the iteration that added
/// each part (MABDI's figures). Hues step by the golden angle, starting at yellow.
pub fn iteration_color(iteration: u32) -> [u8; 3] {
    let hue = (60.0 + 137.507_77 * iteration.saturating_sub(1) as f32) % 360.0;
    // Alternate the lightness a little so even close hues differ.
    let value = if iteration.is_multiple_of(2) {
        0.85
    } else {
        1.0
    };
    hsv_to_rgb(hue, 0.85, value)
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
    fn consecutive_iterations_differ() {
        for i in 1..60 {
            let (a, b) = (iteration_color(i), iteration_color(i + 1));
            let diff: i32 = (0..3).map(|k| (a[k] as i32 - b[k] as i32).abs()).sum();
            assert!(diff > 60, "iterations {i} and {} look alike", i + 1);
        }
        assert_eq!(hsv_to_rgb(0.0, 1.0, 1.0), [255, 0, 0]);
        assert_eq!(hsv_to_rgb(120.0, 1.0, 1.0), [0, 255, 0]);
    }
}
