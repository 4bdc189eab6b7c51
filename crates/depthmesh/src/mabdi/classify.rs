//! Pixel classification of MABDI (thesis §3.2): which pixels of the depth image D
//! show surface the global mesh does not predict.

use crate::image::DepthImage;
use rayon::prelude::*;

/// A depth difference threshold.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Threshold {
    /// A threshold in normalised z-buffer depth for the clipping range
    /// `[near, far]`, as in the thesis. In metres it grows with depth:
    /// `dZ/dz = Z²·(far − near)/(far·near)`, i.e. `value·Z²` m for 0.8–4 m.
    Normalised {
        /// Threshold in normalised depth (the thesis uses 0.01).
        value: f32,
        /// Near clipping distance in metres.
        near: f32,
        /// Far clipping distance in metres.
        far: f32,
    },
    /// A fixed threshold in metres.
    Metres(f32),
}

impl Threshold {
    /// The thesis's 0.01 in normalised depth for a sensor range.
    pub fn thesis(near: f32, far: f32) -> Self {
        Threshold::Normalised {
            value: 0.01,
            near,
            far,
        }
    }

    /// `(a, b)` with the threshold in metres at depth `z` equal to `a + b·z²`,
    /// for loops that should not branch on the kind of threshold.
    pub fn quadratic(&self) -> (f32, f32) {
        match *self {
            Threshold::Normalised { value, near, far } => {
                (0.0, value * (far - near) / (far * near))
            }
            Threshold::Metres(m) => (m, 0.0),
        }
    }

    /// The threshold in metres at depth `z` metres.
    #[inline]
    pub fn at(&self, z: f32) -> f32 {
        let (a, b) = self.quadratic();
        a + b * z * z
    }
}

/// What a pixel of D is, for meshing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum PixelClass {
    /// No measurement (out of range or dropped by the sensor): D_invalid.
    Invalid = 0,
    /// The global mesh predicts this depth: D_known.
    Known = 1,
    /// Next to a depth discontinuity of D: D_boundary.
    Boundary = 2,
    /// Surface the map does not predict: D_n without the throw-away pixels.
    Novel = 3,
}

/// Classifies every pixel of `depth` against `expected` (0 = the map predicts
/// nothing there) into `out`, and returns the number of novel pixels.
///
/// Novel is `|D − E| > novelty(D)` (eq. 3.1), or a measurement where E has no
/// surface. Boundary pixels come from the thesis's differencing filter
/// (eqs. 3.3–3.4, as its code applies it): a pixel whose depth differs from
/// its left or upper neighbour by more than `boundary(D)`. Together with the
/// grid topology of the mesher this drops every triangle that would bridge a
/// depth discontinuity, whichever way its diagonal runs.
pub fn classify(
    depth: &DepthImage,
    expected: &DepthImage,
    novelty: Threshold,
    boundary: Threshold,
    out: &mut Vec<PixelClass>,
) -> usize {
    let w = depth.width as usize;
    // Every pixel is written below: no clearing.
    out.resize(depth.data.len(), PixelClass::Invalid);
    if w == 0 {
        return 0;
    }
    let (b0, b1) = boundary.quadratic();
    let (n0, n1) = novelty.quadratic();
    let valid = |v: f32| v > 0.0 && v < f32::INFINITY;
    out.par_chunks_mut(w)
        .enumerate()
        .map(|(r, row)| {
            let d_row = &depth.data[r * w..(r + 1) * w];
            let e_row = &expected.data[r * w..(r + 1) * w];
            // The first row and column compare with themselves: never a jump.
            let up = &depth.data[r.saturating_sub(1) * w..][..w];
            let class = |d: f32, e: f32, left: f32, above: f32| {
                let jump = b0 + b1 * d * d;
                let differs = |n: f32| valid(n) & ((d - n).abs() > jump);
                let edge = differs(left) | differs(above);
                let new = (e <= 0.0) | ((d - e).abs() > n0 + n1 * d * d);
                match (valid(d), edge, new) {
                    (false, _, _) => PixelClass::Invalid,
                    (true, true, _) => PixelClass::Boundary,
                    (true, false, true) => PixelClass::Novel,
                    (true, false, false) => PixelClass::Known,
                }
            };
            row[0] = class(d_row[0], e_row[0], d_row[0], up[0]);
            let mut novel = usize::from(row[0] == PixelClass::Novel);
            // Zipped slices, without branches on the data, so that the row
            // vectorises.
            let pixels = d_row[1..].iter().zip(&e_row[1..]).zip(&d_row[..w - 1]);
            for (pixel, (((&d, &e), &left), &above)) in
                row[1..].iter_mut().zip(pixels.zip(&up[1..]))
            {
                *pixel = class(d, e, left, above);
                novel += usize::from(*pixel == PixelClass::Novel);
            }
            novel
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(w: u32, h: u32, f: impl Fn(u32, u32) -> f32) -> DepthImage {
        let mut d = DepthImage::new(w, h);
        for v in 0..h {
            for u in 0..w {
                d.data[(v * w + u) as usize] = f(u, v);
            }
        }
        d
    }

    #[test]
    fn thresholds_follow_the_thesis() {
        let t = Threshold::thesis(0.8, 4.0);
        assert!((t.at(1.0) - 0.01).abs() < 1e-6);
        assert!((t.at(4.0) - 0.16).abs() < 1e-6);
        assert_eq!(Threshold::Metres(0.05).at(3.0), 0.05);
    }

    #[test]
    fn novel_known_boundary_invalid() {
        // Left half at 2 m, right half at 3 m; the top row has no measurement.
        let d = image(8, 4, |u, v| {
            if v == 0 {
                0.0
            } else if u < 4 {
                2.0
            } else {
                3.0
            }
        });
        // The map predicts the left half (slightly off, within 0.04 m) but nothing on the right.
        let e = image(8, 4, |u, _| if u < 4 { 2.02 } else { 0.0 });
        let mut classes = Vec::new();
        let t = Threshold::thesis(0.8, 4.0);
        let novel = classify(&d, &e, t, t, &mut classes);
        let at = |u: usize, v: usize| classes[v * 8 + u];
        assert_eq!(at(0, 0), PixelClass::Invalid);
        assert_eq!(at(1, 2), PixelClass::Known);
        assert_eq!(at(4, 2), PixelClass::Boundary); // jump from its left neighbour
        assert_eq!(at(5, 2), PixelClass::Novel);
        assert_eq!(novel, 3 * 3);
        // A prediction 0.1 m off at 2 m (threshold 0.04 m) is novel.
        let e = image(8, 4, |_, _| 2.1);
        let novel = classify(&d, &e, t, t, &mut classes);
        assert_eq!(classes[2 * 8 + 1], PixelClass::Novel);
        assert_eq!(novel, 3 * 4 + 3 * 3);
    }
}
