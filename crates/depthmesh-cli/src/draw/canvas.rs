//! An RGB raster for dashboards and plots.
//!
//! Positions are signed and may fall outside the canvas; everything clips
//! silently, because plot and overlay positions come from data that can land
//! off-screen, and a clipped line is better than a run that dies at iteration
//! 29. In the floating-point API the centre of pixel `(x, y)` is at `(x, y)`,
//! so a one-pixel line between integer positions comes out crisp rather than
//! smeared over two rows.

use depthmesh::ColorImage;

/// An 8-bit RGB colour.
pub type Rgb = [u8; 3];

/// Black.
pub const BLACK: Rgb = [0, 0, 0];

/// White.
pub const WHITE: Rgb = [255, 255, 255];

/// A row-major RGB image to draw on.
#[derive(Clone, Debug, PartialEq)]
pub struct Canvas {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Row-major pixels, `width * height` of them.
    pub pixels: Vec<Rgb>,
}

impl Canvas {
    /// A canvas of the given size filled with `background`.
    pub fn new(width: u32, height: u32, background: Rgb) -> Self {
        Canvas {
            width,
            height,
            pixels: vec![background; width as usize * height as usize],
        }
    }

    fn index(&self, x: i64, y: i64) -> Option<usize> {
        let inside =
            (0..i64::from(self.width)).contains(&x) && (0..i64::from(self.height)).contains(&y);
        inside.then(|| y as usize * self.width as usize + x as usize)
    }

    /// The colour at `(x, y)`, or `None` outside the canvas.
    #[cfg(test)]
    pub fn get(&self, x: i32, y: i32) -> Option<Rgb> {
        self.index(x.into(), y.into()).map(|i| self.pixels[i])
    }

    /// Paints `(x, y)`; does nothing outside the canvas.
    pub fn set(&mut self, x: i32, y: i32, colour: Rgb) {
        if let Some(i) = self.index(x.into(), y.into()) {
            self.pixels[i] = colour;
        }
    }

    /// Mixes `colour` into `(x, y)` with weight `alpha` in `[0, 1]`; this is
    /// how anti-aliased edges get their partial coverage.
    fn blend(&mut self, x: i64, y: i64, colour: Rgb, alpha: f32) {
        if let Some(i) = self.index(x, y) {
            let old = self.pixels[i];
            self.pixels[i] = std::array::from_fn(|c| {
                (f32::from(old[c]) + (f32::from(colour[c]) - f32::from(old[c])) * alpha).round()
                    as u8
            });
        }
    }

    /// Fills the `width × height` rectangle whose top-left pixel is `(x, y)`.
    pub fn fill_rect(&mut self, x: i32, y: i32, width: u32, height: u32, colour: Rgb) {
        let x0 = i64::from(x).clamp(0, self.width.into());
        let y0 = i64::from(y).clamp(0, self.height.into());
        let x1 = (i64::from(x) + i64::from(width)).clamp(0, self.width.into());
        let y1 = (i64::from(y) + i64::from(height)).clamp(0, self.height.into());
        for row in y0..y1 {
            let start = row as usize * self.width as usize;
            self.pixels[start + x0 as usize..start + x1 as usize].fill(colour);
        }
    }

    /// Paints every pixel within the clipped bounding box `[x0, x1] × [y0, y1]`
    /// with the coverage `coverage(px, py)` returns for its centre. All the
    /// anti-aliased shapes are distance fields fed through here.
    fn paint_coverage(
        &mut self,
        (x0, y0): (f32, f32),
        (x1, y1): (f32, f32),
        colour: Rgb,
        coverage: impl Fn(f32, f32) -> f32,
    ) {
        if ![x0, y0, x1, y1].iter().all(|v| v.is_finite()) {
            return;
        }
        // Clamping in f32 before the cast keeps far off-screen shapes from
        // turning into huge loops.
        let xs = x0.floor().max(0.0) as i64..=x1.ceil().min(self.width as f32 - 1.0) as i64;
        let ys = y0.floor().max(0.0) as i64..=y1.ceil().min(self.height as f32 - 1.0) as i64;
        for py in ys {
            for px in xs.clone() {
                let alpha = coverage(px as f32, py as f32).clamp(0.0, 1.0);
                if alpha > 0.0 {
                    self.blend(px, py, colour, alpha);
                }
            }
        }
    }

    /// Draws an anti-aliased line with round caps, `thickness` pixels wide.
    pub fn draw_line(&mut self, from: (f32, f32), to: (f32, f32), thickness: f32, colour: Rgb) {
        let r = thickness * 0.5;
        let (dx, dy) = (to.0 - from.0, to.1 - from.1);
        let len2 = dx * dx + dy * dy;
        let lo = (from.0.min(to.0) - r - 1.0, from.1.min(to.1) - r - 1.0);
        let hi = (from.0.max(to.0) + r + 1.0, from.1.max(to.1) + r + 1.0);
        self.paint_coverage(lo, hi, colour, |px, py| {
            let t = if len2 > 0.0 {
                (((px - from.0) * dx + (py - from.1) * dy) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let (ex, ey) = (px - (from.0 + t * dx), py - (from.1 + t * dy));
            r + 0.5 - (ex * ex + ey * ey).sqrt()
        });
    }

    /// Draws line segments joining consecutive `points`.
    pub fn draw_polyline(&mut self, points: &[(f32, f32)], thickness: f32, colour: Rgb) {
        for pair in points.windows(2) {
            self.draw_line(pair[0], pair[1], thickness, colour);
        }
    }

    /// Draws an anti-aliased filled disc.
    pub fn fill_circle(&mut self, centre: (f32, f32), radius: f32, colour: Rgb) {
        let lo = (centre.0 - radius - 1.0, centre.1 - radius - 1.0);
        let hi = (centre.0 + radius + 1.0, centre.1 + radius + 1.0);
        self.paint_coverage(lo, hi, colour, |px, py| {
            radius + 0.5 - (px - centre.0).hypot(py - centre.1)
        });
    }

    /// Copies `src` with its top-left corner at `(x, y)`.
    pub fn blit(&mut self, src: &Canvas, x: i32, y: i32) {
        for sy in 0..src.height {
            let row = &src.pixels[sy as usize * src.width as usize..][..src.width as usize];
            let ty = i64::from(y) + i64::from(sy);
            for (sx, &colour) in row.iter().enumerate() {
                if let Some(i) = self.index(i64::from(x) + sx as i64, ty) {
                    self.pixels[i] = colour;
                }
            }
        }
    }

    /// Copies `src` (unless empty) resampled to `width × height` with its top-left corner at
    /// `(x, y)`. Each target pixel averages the source area it covers, so the
    /// thin lines of a 640×480 render survive being shown smaller instead of
    /// breaking up as they would with nearest-neighbour sampling.
    pub fn blit_scaled(&mut self, src: &Canvas, x: i32, y: i32, width: u32, height: u32) {
        if src.pixels.is_empty() || width == 0 || height == 0 {
            // Nothing to show: an empty image has no colour to stretch.
        } else if (width, height) == (src.width, src.height) {
            self.blit(src, x, y);
        } else {
            self.blit(&src.resampled(width, height), x, y);
        }
    }

    /// Box-filters to `width × height`, one axis at a time.
    fn resampled(&self, width: u32, height: u32) -> Canvas {
        let (sw, tw) = (self.width as usize, width as usize);
        let columns = box_weights(self.width, width);
        let mut rows_resampled = vec![[0.0f32; 3]; tw * self.height as usize];
        for (src_row, out_row) in self
            .pixels
            .chunks_exact(sw)
            .zip(rows_resampled.chunks_exact_mut(tw))
        {
            for (out, (first, weights)) in out_row.iter_mut().zip(&columns) {
                for (p, w) in src_row[*first..].iter().zip(weights) {
                    for c in 0..3 {
                        out[c] += f32::from(p[c]) * w;
                    }
                }
            }
        }
        let mut out = Canvas::new(width, height, BLACK);
        for (out_row, (first, weights)) in out
            .pixels
            .chunks_exact_mut(tw)
            .zip(box_weights(self.height, height))
        {
            for (tx, out_pixel) in out_row.iter_mut().enumerate() {
                let mut sum = [0.0f32; 3];
                for (k, w) in weights.iter().enumerate() {
                    let p = rows_resampled[(first + k) * tw + tx];
                    for c in 0..3 {
                        sum[c] += p[c] * w;
                    }
                }
                *out_pixel = sum.map(|v| v.round().clamp(0.0, 255.0) as u8);
            }
        }
        out
    }

    /// The canvas as an 8-bit RGB PNG file.
    ///
    /// # Panics
    /// If the canvas has no pixels: PNG cannot represent a zero-sized image.
    pub fn encode_png(&self) -> Vec<u8> {
        let mut out = Vec::new();
        let mut encoder = png::Encoder::new(&mut out, self.width, self.height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        // Writing into a Vec cannot fail on I/O, so the only error left is an
        // invalid (empty) image, which is a caller bug.
        let mut writer = encoder
            .write_header()
            .expect("PNG header for a non-empty canvas");
        writer
            .write_image_data(self.pixels.as_flattened())
            .expect("PNG data for a non-empty canvas");
        writer.finish().expect("PNG trailer");
        out
    }
}

/// 3D renders arrive as colour images; this lets them be composed without a copy.
impl From<ColorImage> for Canvas {
    fn from(image: ColorImage) -> Self {
        Canvas {
            width: image.width,
            height: image.height,
            pixels: image.data,
        }
    }
}

/// For each of `dst` target pixels along one axis: the first source pixel it
/// overlaps and the weights of the source pixels from there on, as fractions
/// of the target pixel's footprint (so they sum to one).
fn box_weights(src: u32, dst: u32) -> Vec<(usize, Vec<f32>)> {
    let ratio = f64::from(src) / f64::from(dst);
    (0..dst)
        .map(|i| {
            let (a, b) = (f64::from(i) * ratio, f64::from(i + 1) * ratio);
            let first = a.floor() as usize;
            let end = (b.ceil() as usize).min(src as usize);
            let weights = (first..end)
                .map(|s| ((b.min(s as f64 + 1.0) - a.max(s as f64)) / (b - a)) as f32)
                .collect();
            (first, weights)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    const RED: Rgb = [255, 0, 0];

    fn count(canvas: &Canvas, colour: Rgb) -> usize {
        canvas.pixels.iter().filter(|&&p| p == colour).count()
    }

    #[test]
    fn drawing_outside_clips_without_panicking() {
        let mut c = Canvas::new(10, 8, WHITE);
        c.set(-1, 0, RED);
        c.set(10, 0, RED);
        c.set(0, 8, RED);
        c.set(i32::MIN, i32::MAX, RED);
        assert_eq!(count(&c, RED), 0);
        assert_eq!(c.get(-1, 0), None);
        assert_eq!(c.get(10, 7), None);

        c.fill_rect(-5, -5, 7, 7, RED);
        assert_eq!(count(&c, RED), 4);
        c.fill_rect(i32::MAX, i32::MAX, u32::MAX, u32::MAX, RED);
        c.fill_rect(i32::MIN, i32::MIN, u32::MAX, 2, RED);

        c.draw_line((-1e9, -1e9), (1e9, 1e9), 3.0, RED);
        c.draw_line((f32::NAN, 0.0), (5.0, f32::INFINITY), 1.0, RED);
        c.fill_circle((100.0, 100.0), 5.0, RED);
        c.fill_circle((-3.0, 4.0), 4.5, RED);

        let big = Canvas::new(30, 30, RED);
        c.blit(&big, -10, -10);
        c.blit(&big, i32::MIN, i32::MAX);
        c.blit_scaled(&big, 5, 5, 100, 3);
        assert_eq!(count(&c, RED), 80);
        c.blit_scaled(&Canvas::new(0, 0, BLACK), 0, 0, 4, 4);
        c.blit_scaled(&Canvas::new(3, 3, BLACK), 0, 0, 0, 4);
        assert_eq!(count(&c, RED), 80);
    }

    #[test]
    fn horizontal_line_at_integer_row_is_crisp() {
        let mut c = Canvas::new(20, 5, WHITE);
        c.draw_line((2.0, 2.0), (17.0, 2.0), 1.0, BLACK);
        assert_eq!(count(&c, BLACK), 16);
        assert_eq!(count(&c, WHITE), 100 - 16);
    }

    #[test]
    fn thick_line_and_markers_cover_their_centres() {
        let mut c = Canvas::new(40, 40, WHITE);
        c.draw_polyline(&[(5.0, 5.0), (30.0, 30.0), (30.0, 5.0)], 3.0, RED);
        assert_eq!(c.get(17, 17), Some(RED));
        assert_eq!(c.get(30, 12), Some(RED));
        assert_eq!(c.get(31, 12), Some(RED));
        assert_eq!(c.get(5, 30), Some(WHITE));
        c.fill_circle((5.0, 35.0), 2.5, BLACK);
        assert_eq!(c.get(5, 35), Some(BLACK));
    }

    #[test]
    fn scaled_blit_averages_areas() {
        let mut checker = Canvas::new(4, 2, BLACK);
        for x in (0..4).step_by(2) {
            checker.set(x, 0, WHITE);
            checker.set(x, 1, WHITE);
        }
        let mut c = Canvas::new(2, 1, RED);
        c.blit_scaled(&checker, 0, 0, 2, 1);
        assert_eq!(c.pixels, vec![[128; 3]; 2]);

        // Upscaling by an integer factor repeats pixels exactly.
        let mut up = Canvas::new(8, 4, RED);
        up.blit_scaled(&checker, 0, 0, 8, 4);
        assert_eq!(up.get(0, 3), Some(WHITE));
        assert_eq!(up.get(1, 0), Some(WHITE));
        assert_eq!(up.get(2, 0), Some(BLACK));
    }

    #[test]
    fn png_round_trips() {
        let mut c = Canvas::new(7, 3, [10, 20, 30]);
        c.set(6, 2, RED);
        let bytes = c.encode_png();
        let decoder = png::Decoder::new(bytes.as_slice());
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (7, 3));
        assert_eq!(info.color_type, png::ColorType::Rgb);
        assert_eq!(info.bit_depth, png::BitDepth::Eight);
        assert_eq!(&buf[..info.buffer_size()], c.pixels.as_flattened());
    }
}
