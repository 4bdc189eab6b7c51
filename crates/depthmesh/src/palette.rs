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

/// The colour of an unoriented normal (Ryde et al., eqs. 5–7): `n` and `−n`
/// get the same colour, and nearby directions nearby colours.
///
/// Flipping normals into one hemisphere (eq. 5) makes the colour sign-blind;
/// doubling the polar angle stretches that hemisphere over the whole sphere
/// (eqs. 6–7), so the flip's seam maps to the single antipode and no
/// discontinuity remains. The stretched unit vector is shifted and scaled
/// into RGB.
///
/// The paper's pole is z ("say the X-Y plane"); here it is the diagonal
/// (1, 1, 1): with an axis as pole the other two axes both lie on the seam
/// and get one colour, so the floor and the walls of a room would look
/// alike, while the diagonal gives the three axis directions three distinct
/// colours 120° apart in φ.
pub fn normal_color(n: glam::Vec3) -> [u8; 3] {
    let n = n.normalize_or_zero();
    if n == glam::Vec3::ZERO {
        return [128; 3];
    }
    // The diagonal becomes z; x goes to the azimuth origin.
    let pole = glam::Vec3::ONE.normalize();
    let ex = (glam::Vec3::X - pole * pole.x).normalize();
    let ey = pole.cross(ex);
    let n = glam::Vec3::new(n.dot(ex), n.dot(ey), n.dot(pole));
    let n = if n.z < 0.0 { -n } else { n };
    let theta = n.z.clamp(-1.0, 1.0).acos();
    let phi = n.y.atan2(n.x);
    let (s, c) = (2.0 * theta).sin_cos();
    [s * phi.cos(), s * phi.sin(), c].map(|v| (0.5 * (v + 1.0) * 255.0).round() as u8)
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

/// Turbo sampled at 17 evenly spaced points; linear interpolation between
/// them stays within 8 levels of the full 256-entry table, which is invisible
/// and saves carrying the table.
const TURBO: [[u8; 3]; 17] = [
    [48, 18, 59],
    [64, 64, 162],
    [70, 107, 227],
    [66, 148, 255],
    [40, 188, 235],
    [24, 221, 194],
    [50, 242, 152],
    [109, 254, 98],
    [164, 252, 60],
    [203, 237, 52],
    [236, 209, 58],
    [253, 174, 53],
    [251, 129, 34],
    [236, 83, 15],
    [210, 49, 5],
    [172, 23, 1],
    [122, 4, 3],
];

/// Google's Turbo rainbow at `t` in `[0, 1]` (near to far; values outside
/// are clamped, NaN is near): dark blue to dark red, with a lightness that
/// rises and falls smoothly, so depth steps read as edges without the false
/// bands of the classic jet map.
pub fn turbo(t: f32) -> [u8; 3] {
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
    let x = t * (TURBO.len() - 1) as f32;
    let i = (x as usize).min(TURBO.len() - 2);
    let f = x - i as f32;
    let (a, b) = (TURBO[i], TURBO[i + 1]);
    std::array::from_fn(|c| {
        (f32::from(a[c]) + (f32::from(b[c]) - f32::from(a[c])) * f).round() as u8
    })
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

    #[test]
    fn normal_colours_ignore_the_sign_and_have_no_seam() {
        use glam::Vec3;
        let n = Vec3::new(0.3, -0.5, 0.8).normalize();
        assert_eq!(normal_color(n), normal_color(-n));
        // The pole and the seam (eq. 7 at θ = 0 and θ = 90°).
        let pole = Vec3::ONE.normalize();
        // Within a unit of rounding: sin 2θ is ±1e-7 there, not 0.
        let near = |a: [u8; 3], b: [u8; 3]| (0..3).all(|i| a[i].abs_diff(b[i]) <= 1);
        assert!(near(normal_color(pole), [128, 128, 255]));
        assert!(near(normal_color(Vec3::new(1.0, -1.0, 0.0)), [128, 128, 0]));
        // The axes, as the faces of a room: three different colours.
        let (x, y, z) = (
            normal_color(Vec3::X),
            normal_color(Vec3::Y),
            normal_color(Vec3::Z),
        );
        assert!(x != y && y != z && x != z, "{x:?} {y:?} {z:?}");
        // Just on either side of the seam: nearly the same colour.
        let seam = Vec3::new(1.0, -1.0, 0.0).normalize();
        let a = normal_color(seam + pole * 0.004);
        let b = normal_color(seam - pole * 0.004);
        assert!(
            (0..3).all(|i| (i32::from(a[i]) - i32::from(b[i])).abs() <= 4),
            "{a:?} {b:?}"
        );
        assert_eq!(normal_color(Vec3::ZERO), [128; 3]);
    }
}
