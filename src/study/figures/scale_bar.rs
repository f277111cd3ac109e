//! A scale bar for detector images: a bar of a round length in mm at the detector (or in detector px
//! when the pixel spacing is not known), in a white box at the lower right of a pane, so AP and LAT
//! panes drawn at one scale can be compared by eye.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::chart::plot_err;
use super::labels::PixelBox;
use crate::Result;

/// The largest of 1, 2 and 5 times a power of ten not above `x` (`x` > 0).
pub fn round_length(x: f64) -> f64 {
    let p = 10f64.powf(x.log10().floor());
    [5.0, 2.0, 1.0]
        .into_iter()
        .map(|m| m * p)
        .find(|&l| l <= x * (1.0 + 1e-12))
        .unwrap_or(p)
}

/// What a scale bar shows: its length in detector px and its label.
#[derive(Debug, Clone, PartialEq)]
pub struct ScaleBar {
    pub detector_px: f64,
    pub label: String,
}

impl ScaleBar {
    /// A bar about a fifth of a window `span_px` detector pixels wide: a round number of mm at the
    /// detector when `mm_per_px` (u spacing) is known, else a round number of px.
    pub fn for_span(span_px: f64, mm_per_px: Option<f64>) -> ScaleBar {
        let target = (span_px / 5.0).max(1e-9);
        match mm_per_px {
            Some(s) if s > 0.0 => {
                let mm = round_length(target * s);
                ScaleBar {
                    detector_px: mm / s,
                    label: format!("{} mm at the detector", trim(mm)),
                }
            }
            _ => {
                let px = round_length(target);
                ScaleBar {
                    detector_px: px,
                    label: format!("{} px", trim(px)),
                }
            }
        }
    }

    /// Draws the bar `screen_per_px` screen px per detector px long, with its label above it, in a
    /// white box whose lower-right corner is `corner`; returns the box (an obstacle for labels).
    pub fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
        corner: (i32, i32),
        screen_per_px: f64,
        font_px: u32,
    ) -> Result<PixelBox> {
        let font = ("sans-serif", font_px).into_font();
        let (tw, th) = font.box_size(&self.label).unwrap_or((
            (0.6 * f64::from(font_px) * self.label.chars().count() as f64) as u32,
            font_px,
        ));
        let bar = (self.detector_px * screen_per_px).round().max(1.0) as i32;
        let (pad, gap, thick) = (8, 6, 5);
        let w = bar.max(tw as i32) + 2 * pad;
        let h = th as i32 + gap + thick + 2 * pad;
        let (x1, y1) = corner;
        let (x0, y0) = (x1 - w, y1 - h);
        root.draw(&Rectangle::new(
            [(x0, y0), (x1, y1)],
            WHITE.mix(0.85).filled(),
        ))
        .map_err(plot_err)?;
        root.draw(&Text::new(
            self.label.clone(),
            (x0 + pad, y0 + pad),
            font.color(&BLACK),
        ))
        .map_err(plot_err)?;
        let by = y1 - pad - thick;
        root.draw(&Rectangle::new(
            [(x0 + pad, by), (x0 + pad + bar, by + thick)],
            BLACK.filled(),
        ))
        .map_err(plot_err)?;
        Ok(PixelBox {
            x0: f64::from(x0),
            y0: f64::from(y0),
            x1: f64::from(x1),
            y1: f64::from(y1),
        })
    }
}

/// `x` without a trailing `.0`.
fn trim(x: f64) -> String {
    let s = format!("{x}");
    s.strip_suffix(".0").map_or(s.clone(), str::to_string)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_lengths_are_1_2_5_times_a_power_of_ten_not_above_the_target() {
        for (x, l) in [
            (7.3, 5.0),
            (19.9, 10.0),
            (20.0, 20.0),
            (0.42, 0.2),
            (100.0, 100.0),
        ] {
            assert!(
                (round_length(x) - l).abs() < 1e-12,
                "{x} → {}",
                round_length(x)
            );
        }
    }

    #[test]
    fn a_bar_is_a_round_number_of_mm_at_the_detector_about_a_fifth_of_the_window() {
        // 600 px at 0.3 mm: a fifth is 36 mm → a 20-mm bar of 66.7 px.
        let b = ScaleBar::for_span(600.0, Some(0.3));
        assert_eq!(b.label, "20 mm at the detector");
        assert!((b.detector_px - 20.0 / 0.3).abs() < 1e-9);
        // Without a spacing: px.
        let b = ScaleBar::for_span(600.0, None);
        assert_eq!((b.detector_px, b.label.as_str()), (100.0, "100 px"));
    }
}
