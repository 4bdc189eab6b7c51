//! Bitmap text from the 8×8 ASCII font, scaled by whole pixels.
//!
//! Glyphs are drawn proportionally: each one is trimmed to the columns it
//! actually uses and followed by a one-pixel gap. The font is monospaced by
//! design, but at 8 pixels per character the long panel captions would not fit
//! a panel at a readable size; trimming saves about a quarter of the width.

use font8x8::legacy::BASIC_LEGACY;

use super::canvas::{Canvas, Rgb};

/// Height of a line of text at scale 1, in pixels.
const GLYPH_HEIGHT: u32 = 8;
/// Blank columns between glyphs at scale 1.
const GAP: u32 = 1;
/// Advance of a space (which has no columns to trim) at scale 1.
const SPACE: u32 = 4;

/// Where the anchor position sits along a line of text.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Align {
    /// The anchor is the start of the text.
    Left,
    /// The anchor is the middle of the text.
    Center,
    /// The anchor is the end of the text.
    Right,
}

/// A glyph's rows (bit 0 is the leftmost column), its first used column and
/// its advance without the gap. Characters outside printable ASCII show as `?`
/// so a stray unit symbol is visible as a mistake rather than silently dropped.
fn glyph(c: char) -> ([u8; 8], u32, u32) {
    let code = if c.is_ascii_graphic() || c == ' ' {
        c as usize
    } else {
        '?' as usize
    };
    let rows = BASIC_LEGACY[code];
    let used = rows.iter().fold(0u8, |m, r| m | r);
    if used == 0 {
        (rows, 0, SPACE)
    } else {
        let first = used.trailing_zeros();
        let last = 7 - used.leading_zeros();
        (rows, first, last - first + 1)
    }
}

/// Width of `text` in pixels when drawn at `scale`.
pub fn text_width(text: &str, scale: u32) -> u32 {
    let font_px: u32 = text.chars().map(|c| glyph(c).2 + GAP).sum();
    font_px.saturating_sub(GAP).saturating_mul(scale)
}

/// Height of a line of text in pixels when drawn at `scale`.
pub fn text_height(scale: u32) -> u32 {
    GLYPH_HEIGHT * scale
}

/// Draws `text` along a run: `place(along, down)` maps a pixel's offset along
/// the text and down from its top edge to a canvas position, which is all that
/// differs between horizontal and rotated text.
fn draw_run(
    canvas: &mut Canvas,
    text: &str,
    scale: u32,
    colour: Rgb,
    place: impl Fn(i64, i64) -> (i64, i64),
) {
    let scale = i64::from(scale);
    let mut pen = 0i64;
    for c in text.chars() {
        let (rows, first, width) = glyph(c);
        for (row, bits) in (0i64..).zip(rows) {
            for col in 0..width {
                if bits >> (first + col) & 1 == 0 {
                    continue;
                }
                for sy in 0..scale {
                    for sx in 0..scale {
                        let (x, y) = place(pen + i64::from(col) * scale + sx, row * scale + sy);
                        // Positions beyond i32 are off-canvas anyway.
                        if let (Ok(x), Ok(y)) = (i32::try_from(x), i32::try_from(y)) {
                            canvas.set(x, y, colour);
                        }
                    }
                }
            }
        }
        pen += i64::from(width + GAP) * scale;
    }
}

/// Draws `text` with its top edge at `y`, positioned horizontally so that `x`
/// is its start, middle or end according to `align`.
pub fn draw_text_aligned(
    canvas: &mut Canvas,
    x: i32,
    y: i32,
    text: &str,
    scale: u32,
    colour: Rgb,
    align: Align,
) {
    let width = i64::from(text_width(text, scale));
    let left = i64::from(x)
        - match align {
            Align::Left => 0,
            Align::Center => width / 2,
            Align::Right => width,
        };
    draw_run(canvas, text, scale, colour, |along, down| {
        (left + along, i64::from(y) + down)
    });
}

/// Draws `text` rotated a quarter turn anticlockwise, reading bottom to top
/// as a y-axis label does, with its left edge (the glyph tops) at `x` and
/// centred vertically on `y`.
pub fn draw_text_vertical(
    canvas: &mut Canvas,
    x: i32,
    y: i32,
    text: &str,
    scale: u32,
    colour: Rgb,
) {
    let bottom = i64::from(y) + i64::from(text_width(text, scale)) / 2;
    draw_run(canvas, text, scale, colour, |along, down| {
        (i64::from(x) + down, bottom - along)
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::draw::canvas::{BLACK, WHITE};

    /// Bounding box `(x0, y0, x1, y1)` of the black pixels, inclusive.
    fn ink_bounds(c: &Canvas) -> Option<(i32, i32, i32, i32)> {
        let mut bounds: Option<(i32, i32, i32, i32)> = None;
        for y in 0..c.height as i32 {
            for x in 0..c.width as i32 {
                if c.get(x, y) == Some(BLACK) {
                    let b = bounds.get_or_insert((x, y, x, y));
                    *b = (b.0.min(x), b.1.min(y), b.2.max(x), b.3.max(y));
                }
            }
        }
        bounds
    }

    #[test]
    fn width_is_proportional_and_scales() {
        assert_eq!(text_width("", 3), 0);
        assert!(text_width("i", 1) < text_width("M", 1));
        assert!(text_width("M", 1) <= 8);
        assert_eq!(text_width("Mi", 2), 2 * text_width("Mi", 1));
        assert_eq!(
            text_width("ab", 1),
            text_width("a", 1) + GAP + text_width("b", 1)
        );
        assert_eq!(text_height(2), 16);
        // Non-ASCII falls back to '?' rather than vanishing.
        assert_eq!(text_width("é", 1), text_width("?", 1));
    }

    #[test]
    fn drawn_text_spans_its_measured_width() {
        let mut c = Canvas::new(100, 30, WHITE);
        draw_text_aligned(&mut c, 10, 5, "Hello", 2, BLACK, Align::Left);
        let (x0, _, x1, y1) = ink_bounds(&c).unwrap();
        assert_eq!(x0, 10);
        assert_eq!((x1 - x0 + 1) as u32, text_width("Hello", 2));
        assert!(y1 < 5 + text_height(2) as i32);
    }

    #[test]
    fn alignment_moves_the_anchor() {
        let w = text_width("MMM", 1) as i32;
        let mut right = Canvas::new(60, 10, WHITE);
        draw_text_aligned(&mut right, 50, 0, "MMM", 1, BLACK, Align::Right);
        assert_eq!(ink_bounds(&right).unwrap().2, 49);
        let mut centre = Canvas::new(60, 10, WHITE);
        draw_text_aligned(&mut centre, 30, 0, "MMM", 1, BLACK, Align::Center);
        assert_eq!(ink_bounds(&centre).unwrap().0, 30 - w / 2);
    }

    #[test]
    fn vertical_text_runs_upwards_centred() {
        let mut c = Canvas::new(20, 60, WHITE);
        draw_text_vertical(&mut c, 4, 30, "Hello", 1, BLACK);
        let (x0, y0, x1, y1) = ink_bounds(&c).unwrap();
        assert!(x0 >= 4 && x1 < 4 + 8);
        assert_eq!((y1 - y0 + 1) as u32, text_width("Hello", 1));
        assert!((y0 + y1 - 60).abs() <= 1);
        // 'H' starts at the bottom.
        assert_eq!(c.get(x0, y1), Some(BLACK));
    }

    #[test]
    fn text_off_canvas_is_clipped() {
        // What falls on the canvas is the same window of the text drawn whole.
        let mut c = Canvas::new(10, 10, WHITE);
        draw_text_aligned(&mut c, -30, 3, "clipped text", 2, BLACK, Align::Left);
        let mut whole = Canvas::new(text_width("clipped text", 2) + 10, 30, WHITE);
        draw_text_aligned(&mut whole, 0, 3, "clipped text", 2, BLACK, Align::Left);
        assert!(ink_bounds(&c).is_some());
        for y in 0..10 {
            for x in 0..10 {
                assert_eq!(c.get(x, y), whole.get(x + 30, y), "pixel ({x}, {y})");
            }
        }
        // Text far outside draws nothing (no wrap-around at the integer limits).
        let mut far = Canvas::new(10, 10, WHITE);
        draw_text_aligned(&mut far, i32::MAX, i32::MIN, "far", 3, BLACK, Align::Left);
        draw_text_aligned(&mut far, i32::MIN, 0, "far", 3, BLACK, Align::Right);
        draw_text_vertical(&mut far, 2, i32::MIN, "far", 1, BLACK);
        assert_eq!(ink_bounds(&far), None);
    }
}
