//! The per-iteration dashboard: six panels laid out like Fig. 5.1 of the thesis.

use super::canvas::{Canvas, Rgb, BLACK, WHITE};
use super::text::{draw_text_aligned, text_height, text_width, Align};

/// Width of each panel in the dashboard. Render the plot at this size so that
/// it is not resampled; 640×480 sensor images shrink to it by an exact 3/4.
pub const PANEL_WIDTH: u32 = 480;
/// Height of each panel in the dashboard.
pub const PANEL_HEIGHT: u32 = 360;

/// Space around and between panels.
const MARGIN: u32 = 16;
/// Space between a caption and its panel.
const CAPTION_GAP: u32 = 6;
/// Text scale of the panel captions, when they fit.
const CAPTION_SCALE: u32 = 2;
/// Text scale of the title.
const TITLE_SCALE: u32 = 3;
const TITLE_BAR: Rgb = [45, 52, 64];
const CAPTION_INK: Rgb = [30, 30, 30];
/// Frame around each panel, so the white plot panel and black image borders
/// both have a visible edge.
const PANEL_FRAME: Rgb = [160, 160, 160];
/// Fills the part of a panel that an image of another aspect ratio leaves.
const LETTERBOX: Rgb = [235, 235, 235];

/// The six images of one dashboard, in any size; each is scaled to fit its panel.
#[derive(Clone, Copy, Debug)]
pub struct DashboardPanels<'a> {
    /// (a) Third-person view of the global mesh coloured by iteration, with
    /// the sensor frustum and path.
    pub mesh_view: &'a Canvas,
    /// (b) The same view showing only the novel surface.
    pub novel_view: &'a Canvas,
    /// (d) The depth image D.
    pub depth: &'a Canvas,
    /// (e) The expected depth image E rendered from the global mesh.
    pub expected: &'a Canvas,
    /// (f) The classified image.
    pub classified: &'a Canvas,
    /// (c) The plot of the size of the global mesh.
    pub plot: &'a Canvas,
}

/// A colour and what it means in a panel, shown beside the caption.
type KeyEntry = (Rgb, &'static str);

/// Captions and colour keys of the panels, in grid order.
const CAPTIONS: [[(&str, &[KeyEntry]); 3]; 2] = [
    [
        ("(a) global mesh M", &[]),
        ("(b) novel surface S", &[]),
        ("(c) size of global mesh", &[]),
    ],
    [
        ("(d) depth D", &[]),
        ("(e) expected depth E", &[]),
        (
            "(f) classified",
            &[(BLACK, "added"), (WHITE, "thrown away")],
        ),
    ],
];

/// Text scale of colour keys: small, as they are read once and then known.
const KEY_SCALE: u32 = 1;

/// Lays the panels out in a captioned 2×3 grid under a title bar showing `title`.
pub fn compose(panels: &DashboardPanels, title: &str) -> Canvas {
    let images = [
        [panels.mesh_view, panels.novel_view, panels.plot],
        [panels.depth, panels.expected, panels.classified],
    ];
    let title_h = text_height(TITLE_SCALE) + 2 * MARGIN;
    let caption_h = text_height(CAPTION_SCALE) + CAPTION_GAP;
    let row_h = caption_h + PANEL_HEIGHT + MARGIN;
    let width = 3 * PANEL_WIDTH + 4 * MARGIN;
    let height = title_h + MARGIN + 2 * row_h;

    let mut canvas = Canvas::new(width, height, WHITE);
    canvas.fill_rect(0, 0, width, title_h, TITLE_BAR);
    draw_text_aligned(
        &mut canvas,
        (width / 2) as i32,
        MARGIN as i32,
        title,
        TITLE_SCALE,
        WHITE,
        Align::Center,
    );

    for (row, (images, captions)) in (0u32..).zip(images.iter().zip(&CAPTIONS)) {
        for (col, (image, &(caption, key))) in (0u32..).zip(images.iter().zip(captions)) {
            let x = (MARGIN + col * (PANEL_WIDTH + MARGIN)) as i32;
            let y = (title_h + MARGIN + row * row_h) as i32;
            draw_text_aligned(
                &mut canvas,
                x,
                y,
                caption,
                CAPTION_SCALE,
                CAPTION_INK,
                Align::Left,
            );
            let key_y = y + (text_height(CAPTION_SCALE) - text_height(KEY_SCALE)) as i32;
            draw_key(&mut canvas, key, x + PANEL_WIDTH as i32, key_y);
            draw_panel(&mut canvas, image, x, y + caption_h as i32);
        }
    }
    canvas
}

/// Width of the swatch, and of the space after it, in a colour key.
const SWATCH: u32 = 8 * KEY_SCALE;
/// Space between the entries of a colour key.
const KEY_SPACING: u32 = 12 * KEY_SCALE;

/// Width of a colour key as [`draw_key`] draws it.
fn key_width(key: &[KeyEntry]) -> u32 {
    let entries: u32 = key
        .iter()
        .map(|(_, label)| SWATCH + SWATCH / 2 + text_width(label, KEY_SCALE))
        .sum();
    entries + KEY_SPACING * (key.len() as u32).saturating_sub(1)
}

/// Draws a row of framed colour swatches with labels, ending at `right`.
fn draw_key(canvas: &mut Canvas, key: &[KeyEntry], right: i32, y: i32) {
    let mut x = right - key_width(key) as i32;
    for &(colour, label) in key {
        canvas.fill_rect(x, y, SWATCH, SWATCH, PANEL_FRAME);
        canvas.fill_rect(x + 1, y + 1, SWATCH - 2, SWATCH - 2, colour);
        x += (SWATCH + SWATCH / 2) as i32;
        draw_text_aligned(canvas, x, y, label, KEY_SCALE, CAPTION_INK, Align::Left);
        x += (text_width(label, KEY_SCALE) + KEY_SPACING) as i32;
    }
}

/// Draws `image` scaled to fit a framed panel at `(x, y)`, keeping its aspect
/// ratio so that depth images are not distorted.
fn draw_panel(canvas: &mut Canvas, image: &Canvas, x: i32, y: i32) {
    canvas.fill_rect(x - 1, y - 1, PANEL_WIDTH + 2, PANEL_HEIGHT + 2, PANEL_FRAME);
    canvas.fill_rect(x, y, PANEL_WIDTH, PANEL_HEIGHT, LETTERBOX);
    if image.width == 0 || image.height == 0 {
        return;
    }
    // Compare aspect ratios by cross-multiplying to stay in integers.
    let (w, h) = if u64::from(image.width) * u64::from(PANEL_HEIGHT)
        >= u64::from(image.height) * u64::from(PANEL_WIDTH)
    {
        let h = u64::from(PANEL_WIDTH) * u64::from(image.height) / u64::from(image.width);
        (PANEL_WIDTH, (h as u32).max(1))
    } else {
        let w = u64::from(PANEL_HEIGHT) * u64::from(image.width) / u64::from(image.height);
        ((w as u32).max(1), PANEL_HEIGHT)
    };
    let (dx, dy) = ((PANEL_WIDTH - w) / 2, (PANEL_HEIGHT - h) / 2);
    canvas.blit_scaled(image, x + dx as i32, y + dy as i32, w, h);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn captions_and_keys_fit_their_panels() {
        for &(caption, key) in CAPTIONS.iter().flatten() {
            let gap = if key.is_empty() { 0 } else { KEY_SPACING };
            assert!(
                text_width(caption, CAPTION_SCALE) + gap + key_width(key) <= PANEL_WIDTH,
                "{caption}"
            );
        }
    }

    #[test]
    fn compose_has_a_fixed_size_whatever_the_inputs() {
        let vga = Canvas::new(640, 480, [200, 0, 0]);
        let plot = Canvas::new(PANEL_WIDTH, PANEL_HEIGHT, WHITE);
        let tall = Canvas::new(10, 1000, BLACK);
        let empty = Canvas::new(0, 0, BLACK);
        let panels = DashboardPanels {
            mesh_view: &vga,
            novel_view: &tall,
            depth: &vga,
            expected: &empty,
            classified: &Canvas::new(1, 1, BLACK),
            plot: &plot,
        };
        let out = compose(&panels, "iteration 7 / 30");
        let expected_height = text_height(TITLE_SCALE)
            + 2 * MARGIN
            + MARGIN
            + 2 * (text_height(CAPTION_SCALE) + CAPTION_GAP + PANEL_HEIGHT + MARGIN);
        assert_eq!(
            (out.width, out.height),
            (3 * PANEL_WIDTH + 4 * MARGIN, expected_height)
        );
        assert_eq!(out.pixels.len(), (out.width * out.height) as usize);

        // The 4:3 image fills panel (a) exactly: red at both corners inside the frame.
        let (ax, ay) = (
            MARGIN as i32,
            (text_height(TITLE_SCALE) + 3 * MARGIN + text_height(CAPTION_SCALE) + CAPTION_GAP)
                as i32,
        );
        assert_eq!(out.get(ax, ay), Some([200, 0, 0]));
        assert_eq!(
            out.get(ax + PANEL_WIDTH as i32 - 1, ay + PANEL_HEIGHT as i32 - 1),
            Some([200, 0, 0])
        );
        assert_eq!(out.get(ax - 1, ay), Some(PANEL_FRAME));
        // The tall image is pillarboxed in panel (b).
        let bx = ax + (PANEL_WIDTH + MARGIN) as i32;
        assert_eq!(out.get(bx, ay), Some(LETTERBOX));
        assert_eq!(out.get(bx + PANEL_WIDTH as i32 / 2, ay), Some(BLACK));
    }
}
