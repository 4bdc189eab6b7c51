//! Line plots of per-iteration statistics, such as the size of the global mesh.

use super::canvas::{Canvas, Rgb, WHITE};
use super::text::{draw_text_aligned, draw_text_vertical, text_height, text_width, Align};

/// Colour of text, axes and tick marks: near-black reads as black but is softer
/// next to the data colours.
const INK: Rgb = [40, 40, 40];
/// Colour of grid lines, light enough to stay behind the data.
const GRID: Rgb = [225, 225, 225];
/// Colour of the legend frame.
const FRAME: Rgb = [170, 170, 170];

/// One line of a [`LinePlot`].
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    /// Name shown in the legend.
    pub name: String,
    /// Line and marker colour.
    pub colour: Rgb,
    /// Data points `(x, y)`, joined in the given order; non-finite ones are skipped.
    pub points: Vec<(f64, f64)>,
    /// Whether to mark each data point with a dot.
    pub markers: bool,
}

/// A line plot with axes, grid, labels and, for several series, a legend.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LinePlot {
    /// Title above the plot; empty for none.
    pub title: String,
    /// Label under the x axis; empty for none.
    pub x_label: String,
    /// Label beside the y axis; empty for none.
    pub y_label: String,
    /// The lines to draw.
    pub series: Vec<Series>,
}

/// The value range of one axis and its tick spacing.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Axis {
    lo: f64,
    hi: f64,
    step: f64,
}

impl Axis {
    /// An axis over `lo..hi` with about `target` ticks. With `integral` data
    /// (iterations, element counts) the step is at least one, so a short run
    /// is not labelled with fractional iterations.
    fn new(lo: f64, hi: f64, target: u32, integral: bool) -> Axis {
        let (lo, hi) = if (hi - lo).is_finite() && hi > lo {
            (lo, hi)
        } else {
            (0.0, 1.0)
        };
        let step = nice_step(hi - lo, target);
        Axis {
            lo,
            hi,
            step: if integral { step.max(1.0) } else { step },
        }
    }

    /// Tick positions: the multiples of the step within the range.
    fn ticks(&self) -> impl Iterator<Item = f64> + '_ {
        // Tolerance so that an end of the range landing exactly on a tick
        // keeps it despite rounding.
        let first = (self.lo / self.step - 1e-9).ceil() as i64;
        let last = (self.hi / self.step + 1e-9).floor() as i64;
        (first..=last).map(|k| k as f64 * self.step)
    }

    /// Where `v` falls between `start` (at `lo`) and `end` (at `hi`) pixels.
    fn map(&self, v: f64, start: f32, end: f32) -> f32 {
        start + ((v - self.lo) / (self.hi - self.lo)) as f32 * (end - start)
    }

    /// The label for tick value `v`.
    fn label(&self, v: f64) -> String {
        format_tick(v, self.step, self.lo.abs().max(self.hi.abs()))
    }
}

/// The 1, 2 or 5 × 10^k step giving at most about `target` intervals over
/// `span`, because those are the steps people can count along.
fn nice_step(span: f64, target: u32) -> f64 {
    let rough = span / f64::from(target.max(1));
    let magnitude = 10f64.powf(rough.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * magnitude)
        .find(|&s| s >= rough * (1.0 - 1e-9))
        .unwrap_or(10.0 * magnitude)
}

/// Formats a tick value, abbreviating by the axis's largest magnitude so the
/// labels of an axis share a suffix (`200k … 1.2M` would hide the scale
/// change), with just enough decimals to tell ticks `step` apart.
fn format_tick(value: f64, step: f64, largest: f64) -> String {
    if value == 0.0 {
        return "0".to_string();
    }
    // Thousands start at 10k because "5000" is easier to read than "5k".
    let (unit, suffix) = [(1e9, 1e9, "G"), (1e6, 1e6, "M"), (1e4, 1e3, "k")]
        .into_iter()
        .find(|&(threshold, _, _)| largest >= threshold)
        .map_or((1.0, ""), |(_, unit, suffix)| (unit, suffix));
    let decimals = (-(step / unit).log10() - 1e-9).ceil().max(0.0) as usize;
    format!("{:.*}{}", decimals, value / unit, suffix)
}

/// Width of data lines at text scale 1; lines thicken with the text.
const LINE_WIDTH: f32 = 2.0;
/// Diameter of data point markers, relative to the line width.
const MARKER_SIZE: f32 = 3.0;

/// The points of `series` that can be drawn.
fn finite_points(series: &Series) -> impl Iterator<Item = (f64, f64)> + '_ {
    series
        .points
        .iter()
        .copied()
        .filter(|(x, y)| x.is_finite() && y.is_finite())
}

/// The plot area in canvas pixels (edges inclusive) and the axes mapped onto it.
struct Frame {
    left: i32,
    top: i32,
    right: i32,
    bottom: i32,
    x: Axis,
    y: Axis,
}

impl Frame {
    /// Canvas position of data point `(x, y)`.
    fn to_pixel(&self, (x, y): (f64, f64)) -> (f32, f32) {
        (
            self.x.map(x, self.left as f32, self.right as f32),
            self.y.map(y, self.bottom as f32, self.top as f32),
        )
    }
}

impl LinePlot {
    /// Draws the plot on a white `width × height` canvas. Text grows with the
    /// canvas so that a large standalone figure stays as legible as a panel.
    pub fn render(&self, width: u32, height: u32) -> Canvas {
        let mut canvas = Canvas::new(width, height, WHITE);
        let scale = (width / 480).min(height / 360).max(1);
        let pad = 6 * scale as i32;
        let line_h = text_height(scale) as i32;
        let Some(frame) = self.frame(width, height, scale) else {
            // Too small for a plot area; a blank canvas is the honest result.
            return canvas;
        };
        draw_axes(&mut canvas, &frame, scale);

        let thickness = LINE_WIDTH * scale as f32;
        for series in &self.series {
            let pixels: Vec<(f32, f32)> =
                finite_points(series).map(|p| frame.to_pixel(p)).collect();
            canvas.draw_polyline(&pixels, thickness, series.colour);
            // A lone point has no line to show it.
            if series.markers || pixels.len() == 1 {
                for &p in &pixels {
                    canvas.fill_circle(p, 0.5 * MARKER_SIZE * thickness, series.colour);
                }
            }
        }
        if self.series.len() > 1 {
            self.draw_legend(
                &mut canvas,
                frame.left + 2 * pad,
                frame.top + 2 * pad,
                scale,
            );
        }

        let mid_x = (frame.left + frame.right) / 2;
        draw_text_aligned(
            &mut canvas,
            mid_x,
            pad,
            &self.title,
            scale + 1,
            INK,
            Align::Center,
        );
        let x_label_y = height as i32 - pad - line_h;
        draw_text_aligned(
            &mut canvas,
            mid_x,
            x_label_y,
            &self.x_label,
            scale,
            INK,
            Align::Center,
        );
        let mid_y = (frame.top + frame.bottom) / 2;
        draw_text_vertical(&mut canvas, pad, mid_y, &self.y_label, scale, INK);
        canvas
    }

    /// Fits the data ranges and leaves room around the plot area for the
    /// title, labels and tick labels; `None` if nothing is left for the plot.
    fn frame(&self, width: u32, height: u32, scale: u32) -> Option<Frame> {
        let (pad, line_h) = (6 * scale as i32, text_height(scale) as i32);
        let points = || self.series.iter().flat_map(finite_points);
        // x covers at least [0, 1] and y starts at 0, so growth is seen from
        // the origin and a single point or all-zero data still have a range.
        let (mut x_lo, mut x_hi, mut y_lo, mut y_hi) = (0.0f64, 1.0f64, 0.0f64, 0.0f64);
        for (x, y) in points() {
            (x_lo, x_hi) = (x_lo.min(x), x_hi.max(x));
            (y_lo, y_hi) = (y_lo.min(y * 1.05), y_hi.max(y * 1.05));
        }
        let integral = |v: f64| v.fract() == 0.0;

        let mut top = pad;
        if !self.title.is_empty() {
            top += text_height(scale + 1) as i32 + pad;
        }
        let mut bottom = height as i32 - 1 - pad - line_h - pad;
        if !self.x_label.is_empty() {
            bottom -= line_h + pad;
        }
        let y_ticks = ((bottom - top) / (5 * line_h)).clamp(2, 10) as u32;
        let y = Axis::new(y_lo, y_hi, y_ticks, points().all(|(_, y)| integral(y)));
        // The y tick labels' width decides where the plot area starts.
        let label_w = y
            .ticks()
            .map(|v| text_width(&y.label(v), scale))
            .max()
            .unwrap_or(0);
        let mut left = pad + label_w as i32 + tick_length(scale) + pad;
        if !self.y_label.is_empty() {
            left += line_h + pad;
        }
        // Room for the last x tick label to overhang the plot area.
        let right = width as i32 - 1 - pad - 3 * line_h;
        let x_ticks = ((right - left) / (10 * line_h)).clamp(2, 10) as u32;
        let x = Axis::new(x_lo, x_hi, x_ticks, points().all(|(x, _)| integral(x)));
        (right - left >= 2 && bottom - top >= 2).then_some(Frame {
            left,
            top,
            right,
            bottom,
            x,
            y,
        })
    }

    /// Draws a framed legend with its top-left corner at `(x, y)`.
    fn draw_legend(&self, canvas: &mut Canvas, x: i32, y: i32, scale: u32) {
        let s = scale as i32;
        let (pad, text_h, sample_w) = (5 * s, text_height(scale) as i32, 20 * s);
        let name_w = self
            .series
            .iter()
            .map(|series| text_width(&series.name, scale))
            .max()
            .unwrap_or(0) as i32;
        let rows = self.series.len() as i32;
        let width = pad + sample_w + pad + name_w + pad;
        let height = pad + rows * text_h + (rows - 1) * pad + pad;
        canvas.fill_rect(x, y, width as u32, height as u32, FRAME);
        canvas.fill_rect(x + 1, y + 1, (width - 2) as u32, (height - 2) as u32, WHITE);
        let thickness = LINE_WIDTH * scale as f32;
        for (i, series) in (0i32..).zip(&self.series) {
            let row_y = y + pad + i * (text_h + pad);
            let mid = (row_y + text_h / 2) as f32;
            let (x0, x1) = ((x + pad) as f32, (x + pad + sample_w) as f32);
            canvas.draw_line((x0, mid), (x1, mid), thickness, series.colour);
            if series.markers {
                let centre = ((x0 + x1) / 2.0, mid);
                canvas.fill_circle(centre, 0.5 * MARKER_SIZE * thickness, series.colour);
            }
            let name_x = x + 2 * pad + sample_w;
            draw_text_aligned(canvas, name_x, row_y, &series.name, scale, INK, Align::Left);
        }
    }
}

/// Length of the tick marks outside the plot area.
fn tick_length(scale: u32) -> i32 {
    4 * scale as i32
}

/// Draws the grid, the axis lines, and the ticks with their labels.
fn draw_axes(canvas: &mut Canvas, frame: &Frame, scale: u32) {
    let Frame {
        left,
        top,
        right,
        bottom,
        ..
    } = *frame;
    let (tick, gap, line_h) = (
        tick_length(scale),
        3 * scale as i32,
        text_height(scale) as i32,
    );
    for v in frame.x.ticks() {
        let x = frame.to_pixel((v, 0.0)).0.round() as i32;
        canvas.fill_rect(x, top, 1, (bottom - top) as u32, GRID);
        canvas.fill_rect(x, bottom, 1, tick as u32, INK);
        let label = frame.x.label(v);
        draw_text_aligned(
            canvas,
            x,
            bottom + tick + gap,
            &label,
            scale,
            INK,
            Align::Center,
        );
    }
    for v in frame.y.ticks() {
        let y = frame.to_pixel((0.0, v)).1.round() as i32;
        canvas.fill_rect(left + 1, y, (right - left) as u32, 1, GRID);
        canvas.fill_rect(left - tick, y, tick as u32, 1, INK);
        let label = frame.y.label(v);
        draw_text_aligned(
            canvas,
            left - tick - gap,
            y - line_h / 2,
            &label,
            scale,
            INK,
            Align::Right,
        );
    }
    canvas.fill_rect(left, top, 1, (bottom - top + 1) as u32, INK);
    canvas.fill_rect(left, bottom, (right - left + 1) as u32, 1, INK);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn series(name: &str, colour: Rgb, points: Vec<(f64, f64)>) -> Series {
        Series {
            name: name.to_string(),
            colour,
            points,
            markers: true,
        }
    }

    fn plot(series: Vec<Series>) -> LinePlot {
        LinePlot {
            title: "Size of global mesh".into(),
            x_label: "iteration".into(),
            y_label: "number of elements".into(),
            series,
        }
    }

    fn count(canvas: &Canvas, colour: Rgb) -> usize {
        canvas.pixels.iter().filter(|&&p| p == colour).count()
    }

    #[test]
    fn steps_are_one_two_or_five_times_a_power_of_ten() {
        assert_eq!(nice_step(612_162.0 * 1.05, 5), 200_000.0);
        assert_eq!(nice_step(612_162.0, 7), 100_000.0);
        assert_eq!(nice_step(30.0, 6), 5.0);
        assert_eq!(nice_step(1.0, 5), 0.2);
        assert_eq!(nice_step(10.0, 10), 1.0);
        let axis = Axis::new(0.0, 612_162.0 * 1.05, 5, true);
        assert_eq!(
            axis.ticks().collect::<Vec<_>>(),
            vec![0.0, 200_000.0, 400_000.0, 600_000.0]
        );
        // Integral data keeps whole steps even over a tiny range.
        assert_eq!(Axis::new(0.0, 1.0, 5, true).ticks().count(), 2);
        // A degenerate range falls back instead of dividing by zero.
        assert_eq!(Axis::new(3.0, 3.0, 5, false), Axis::new(0.0, 1.0, 5, false));
    }

    #[test]
    fn tick_labels_abbreviate_by_axis_magnitude() {
        assert_eq!(format_tick(0.0, 200_000.0, 1.3e6), "0");
        assert_eq!(format_tick(1_200_000.0, 200_000.0, 1.3e6), "1.2M");
        assert_eq!(format_tick(400_000.0, 200_000.0, 1.3e6), "0.4M");
        assert_eq!(format_tick(12_000.0, 2_000.0, 15_000.0), "12k");
        assert_eq!(format_tick(5_000.0, 1_000.0, 9_000.0), "5000");
        assert_eq!(format_tick(0.6000000001, 0.2, 1.0), "0.6");
        assert_eq!(format_tick(-20.0, 10.0, 30.0), "-20");
    }

    #[test]
    fn awkward_data_renders_without_panicking() {
        let cases = [
            vec![],
            vec![series("empty", [200, 0, 0], vec![])],
            vec![series("one", [200, 0, 0], vec![(1.0, 5.0)])],
            vec![series(
                "zeros",
                [200, 0, 0],
                vec![(0.0, 0.0), (1.0, 0.0), (2.0, 0.0)],
            )],
            vec![series(
                "big",
                [200, 0, 0],
                (0..=2000)
                    .map(|i| (f64::from(i), f64::from(i) * 1e6))
                    .collect(),
            )],
            vec![series(
                "nan",
                [200, 0, 0],
                vec![
                    (f64::NAN, 1.0),
                    (1.0, f64::INFINITY),
                    (2.0, -3.0),
                    (3.0, 0.5),
                ],
            )],
        ];
        for series in cases {
            let name = series
                .first()
                .map_or("none".to_string(), |s| s.name.clone());
            for (w, h) in [(480, 360), (60, 40), (1, 1)] {
                let canvas = plot(series.clone()).render(w, h);
                assert_eq!((canvas.width, canvas.height), (w, h));
                if w == 480 {
                    // Axes at least are drawn inside the plot area.
                    let ink = (60..460).flat_map(|x| (40..320).map(move |y| (x, y)));
                    let drawn = ink
                        .filter(|&(x, y)| canvas.get(x, y) != Some(WHITE))
                        .count();
                    assert!(drawn > 100, "{name}: {drawn}");
                }
                if w == 480 && (name == "one" || name == "big") {
                    assert!(
                        count(&canvas, [200, 0, 0]) > 0,
                        "{name} {w}×{h} has its data"
                    );
                }
            }
        }
    }

    #[test]
    fn legend_appears_only_for_several_series() {
        let naive = series("naive", [0, 0, 200], vec![(1.0, 100.0), (2.0, 250.0)]);
        let mabdi = series("MABDI", [200, 0, 0], vec![(1.0, 90.0), (2.0, 120.0)]);
        let one = plot(vec![mabdi.clone()]).render(480, 360);
        let two = plot(vec![mabdi, naive]).render(480, 360);
        assert_eq!(count(&one, FRAME), 0);
        assert!(count(&two, FRAME) > 0);
    }
}
