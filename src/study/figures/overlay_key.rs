//! The text of the landmark overlays: the band under the panes (what the marks mean, and the key of
//! landmark numbers to names, wrapped to the figure's width), the numbered and tagged labels in white
//! boxes, and the marks' colours. Every text is [`FONT`] px, so a two-pane figure (1520 px) shown at the
//! report's 1000-px width keeps it at least 12 px high.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::chart::plot_err;
use super::labels::PixelBox;
use crate::Result;

/// Text size (px) of tick labels, numbers, tags, legend and key.
pub(super) const FONT: u32 = 20;
/// Height (px) of a row of the band under the panes, and its padding.
const BAND_ROW: u32 = 34;
const BAND_PAD: u32 = 12;

pub(super) const REF_COLOUR: RGBColor = RGBColor(0, 220, 90);
pub(super) const MEAS_COLOUR: RGBColor = RGBColor(255, 60, 40);
pub(super) const PRED_COLOUR: RGBColor = RGBColor(80, 170, 255);

/// A mark of the band: what it draws before its text.
pub(super) enum Mark {
    Reference,
    Measured,
    Arrow,
    Predicted,
    Number(usize),
    Nothing,
}

pub(super) fn text_width(text: &str, font: u32) -> f64 {
    ("sans-serif", font).into_font().box_size(text).map_or(
        0.6 * f64::from(font) * text.chars().count() as f64,
        |(w, _)| f64::from(w),
    )
}

/// Width of a mark's symbol before its text (px).
const MARK_W: f64 = 40.0;
const ITEM_GAP: f64 = 28.0;

/// The band's items in rows at a figure `figure_width` px wide: the legend (arrows ×`g`), then the key
/// of `names` by number from a new row, with a note when the numbers repeat over `levels`.
pub(super) fn band_rows(
    g: f64,
    names: &[String],
    levels: bool,
    figure_width: u32,
) -> Vec<Vec<(Mark, String)>> {
    let legend = vec![
        (Mark::Reference, "reference position".to_string()),
        (Mark::Measured, "measured under the perturbed K".to_string()),
        (Mark::Arrow, format!("measured shift ×{g}")),
        (Mark::Predicted, format!("H·x predicted (×{g})")),
    ];
    let mut key: Vec<(Mark, String)> = names
        .iter()
        .enumerate()
        .map(|(i, n)| (Mark::Number(i + 1), n.clone()))
        .collect();
    if levels {
        key.push((
            Mark::Nothing,
            "(the same number on every level; levels tagged at the left)".into(),
        ));
    }
    let width = f64::from(figure_width) - 2.0 * f64::from(BAND_PAD);
    let mut rows = Vec::new();
    for items in [legend, key] {
        let mut row: Vec<(Mark, String)> = Vec::new();
        let mut used = 0.0;
        for (m, t) in items {
            let w = MARK_W + text_width(&t, FONT) + ITEM_GAP;
            if used + w > width && !row.is_empty() {
                rows.push(std::mem::take(&mut row));
                used = 0.0;
            }
            used += w;
            row.push((m, t));
        }
        if !row.is_empty() {
            rows.push(row);
        }
    }
    rows
}

/// Height (px) of a band of `rows`.
pub(super) fn band_height(rows: &[Vec<(Mark, String)>]) -> u32 {
    2 * BAND_PAD + BAND_ROW * rows.len() as u32
}

/// Draws the band's `rows` on `root` from `top` (px) down.
pub(super) fn draw_band<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    top: u32,
    rows: &[Vec<(Mark, String)>],
) -> Result<()> {
    let mut y = (top + BAND_PAD) as i32;
    for row in rows {
        let mut x = f64::from(BAND_PAD);
        let cy = y + BAND_ROW as i32 / 2;
        for (mark, text) in row {
            let c = (x as i32 + 16, cy);
            match mark {
                Mark::Reference => root.draw(&Circle::new(c, 6, REF_COLOUR.stroke_width(3))),
                Mark::Measured => root.draw(&Circle::new(c, 4, MEAS_COLOUR.filled())),
                Mark::Arrow => root.draw(&PathElement::new(
                    vec![(c.0 - 14, cy), (c.0 + 14, cy)],
                    MEAS_COLOUR.stroke_width(3),
                )),
                Mark::Predicted => root.draw(&Cross::new(c, 7, PRED_COLOUR.stroke_width(3))),
                Mark::Number(n) => {
                    number_box(root, (x as i32, cy - label_size("0").1 as i32 / 2), *n)
                }
                Mark::Nothing => Ok(()),
            }
            .map_err(plot_err)?;
            let tx = if matches!(mark, Mark::Nothing) {
                x
            } else {
                x + MARK_W
            };
            root.draw(&Text::new(text.clone(), (tx as i32, cy), left_middle()))
                .map_err(plot_err)?;
            x = tx + text_width(text, FONT) + ITEM_GAP;
        }
        y += BAND_ROW as i32;
    }
    Ok(())
}

/// A landmark number in a white box with a thin border, top-left corner at `(x, y)`.
fn number_box<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    (x, y): (i32, i32),
    n: usize,
) -> std::result::Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let t = n.to_string();
    let (w, h) = label_size(&t);
    let (w, h) = (w as i32, h as i32);
    root.draw(&Rectangle::new([(x, y), (x + w, y + h)], WHITE.filled()))?;
    root.draw(&Rectangle::new(
        [(x, y), (x + w, y + h)],
        RGBColor(60, 60, 60).stroke_width(1),
    ))?;
    root.draw(&Text::new(
        t,
        (x + w / 2, y + h / 2 + FONT as i32 / 10),
        centred(),
    ))
}

/// The box (w, h) of a number or tag label.
pub(super) fn label_size(text: &str) -> (f64, f64) {
    (text_width(text, FONT) + 10.0, f64::from(FONT) + 4.0)
}

/// [`FONT`]-px black text anchored at its centre.
fn centred() -> TextStyle<'static> {
    use plotters::style::text_anchor::{HPos, Pos, VPos};
    ("sans-serif", FONT)
        .into_font()
        .color(&BLACK)
        .pos(Pos::new(HPos::Center, VPos::Center))
}

/// [`FONT`]-px black text anchored at its left edge's middle.
fn left_middle() -> TextStyle<'static> {
    use plotters::style::text_anchor::{HPos, Pos, VPos};
    ("sans-serif", FONT)
        .into_font()
        .color(&BLACK)
        .pos(Pos::new(HPos::Left, VPos::Center))
}

pub(super) fn corner(x: f64, y: f64) -> (i32, i32) {
    (x.round() as i32, y.round() as i32)
}

/// `text` centred in a white box `b`.
pub(super) fn draw_label<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    b: PixelBox,
    text: &str,
) -> Result<()> {
    root.draw(&Rectangle::new(
        [corner(b.x0, b.y0), corner(b.x1, b.y1)],
        WHITE.mix(0.9).filled(),
    ))
    .map_err(plot_err)?;
    root.draw(&Text::new(
        text.to_string(),
        // Digits have no descent: centring the em box sets them high by about a tenth of the font.
        corner(
            (b.x0 + b.x1) / 2.0,
            (b.y0 + b.y1) / 2.0 + 0.1 * f64::from(FONT),
        ),
        centred(),
    ))
    .map_err(plot_err)
}
