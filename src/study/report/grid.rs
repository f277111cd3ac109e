//! The perturbation grid of the projection experiments in physical terms: what each family's steps
//! mean for the C-arm (an SDD error, a piercing point moved on the detector, a sheared detector, a
//! wrong pixel spacing), from the effective K and pixel spacing of the study's detector.

use std::fmt::Write as _;

use crate::geometry::Intrinsics;
use crate::study::config::{PerturbationGrid, StudyConfig};

/// Values joined with ", " by `show`.
fn list(v: &[f64], show: impl Fn(f64) -> String) -> String {
    v.iter().map(|&x| show(x)).collect::<Vec<_>>().join(", ")
}

/// A number with at most `d` decimals and no trailing zeros.
pub(super) fn short(x: f64, d: usize) -> String {
    let s = format!("{x:.d$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// `short` with a sign: `+0.5`, `−1.96` (a minus sign, not a hyphen).
pub(super) fn signed(x: f64, d: usize) -> String {
    let s = short(x.abs(), d);
    if s.trim_matches(|c| c == '0' || c == '.').is_empty() {
        s
    } else if x < 0.0 {
        format!("−{s}")
    } else {
        format!("+{s}")
    }
}

/// `lo–hi (n levels)` of per-level values with at most `d` decimals, `n/a` without any.
pub(super) fn level_range(levels: &[f64], d: usize) -> String {
    if levels.is_empty() {
        return "n/a".to_string();
    }
    let lo = levels.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = levels.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    format!(
        "{}–{} ({} levels)",
        short(lo, d),
        short(hi, d),
        levels.len()
    )
}

/// The binned detector's pixel pitch along u (mm per px), where the geometry states it (not for an
/// explicit K): the report sizes every intrinsic perturbation in physical units with it — a focal offset
/// Δf px is an SDD error of Δf × pitch mm (f = SDD / pitch), a piercing shift p px a move of p × pitch mm
/// on the detector.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pitch(pub Option<f64>);

impl Pitch {
    pub fn of(cfg: &StudyConfig) -> Pitch {
        Pitch(cfg.pixel_pitch_mm())
    }

    /// `px × pitch` in mm, at most 2 decimals (None without a pitch).
    pub fn mm(&self, px: f64) -> Option<String> {
        self.0.map(|s| short(px * s, 2))
    }

    /// [`Self::mm`] where it says something: not for 0 px.
    fn nonzero_mm(&self, px: f64) -> Option<String> {
        (px != 0.0).then(|| self.mm(px)).flatten()
    }

    /// A Δf in a table cell: `500 (150 mm)`, the SDD error in parentheses; `500` without a pitch.
    pub fn df_cell(&self, df: f64) -> String {
        match self.nonzero_mm(df) {
            Some(mm) => format!("{} ({mm} mm)", short(df, 3)),
            None => short(df, 3),
        }
    }

    /// A piercing shift in a table cell: `50 (15 mm)`, its size on the detector in parentheses.
    pub fn p_cell(&self, p: f64) -> String {
        self.df_cell(p)
    }

    /// A Δf in prose: `Δf = 500 px (an SDD error of 150 mm)`.
    pub fn df_words(&self, df: f64) -> String {
        match self.nonzero_mm(df) {
            Some(mm) => format!("Δf = {} px (an SDD error of {mm} mm)", short(df, 3)),
            None => format!("Δf = {} px", short(df, 3)),
        }
    }

    /// A piercing shift (p, p) in prose: `piercing (30, 30) px (9 mm along u and v on the detector)`.
    pub fn p_words(&self, p: f64) -> String {
        let p3 = short(p, 3);
        match self.nonzero_mm(p) {
            Some(mm) => format!("piercing ({p3}, {p3}) px ({mm} mm along u and v on the detector)"),
            None => format!("piercing ({p3}, {p3}) px"),
        }
    }

    /// The column header's unit note: `px (mm)` with a pitch, `px` without.
    pub fn unit(&self, mm_is: &str) -> String {
        match self.0 {
            Some(_) => format!("px ({mm_is}, mm)"),
            None => "px".into(),
        }
    }
}

/// Writes the grid table: family, steps, and their meaning at `k` (the detector's K) with `spacing`
/// (mm per px, u and v; `None` for a geometry given as K) and `sdd` (mm).
pub fn table(
    md: &mut String,
    g: &PerturbationGrid,
    k: &Intrinsics,
    spacing: Option<[f64; 2]>,
    sdd: Option<f64>,
) {
    let nonzero: Vec<f64> = g
        .piercing_px
        .iter()
        .copied()
        .filter(|p| *p != 0.0)
        .collect();
    let mut rows: Vec<[String; 3]> = Vec::new();
    if !g.df_px.is_empty() {
        let mm = spacing.map_or(String::new(), |s| {
            format!(
                "; as an SDD error of {} mm at {} mm pixels",
                list(&g.df_px, |d| short(d * s[0], 1)),
                short(s[0], 3)
            )
        });
        rows.push([
            "focal (Δf alone)".into(),
            format!("Δf = {} px", list(&g.df_px, |d| short(d, 3))),
            format!(
                "fx and fy {} % larger than {}{mm}",
                list(&g.df_px, |d| short(100.0 * d / k.fx, 2)),
                short(k.fx, 1)
            ),
        ]);
    }
    if !nonzero.is_empty() {
        let mm = spacing.map_or(String::new(), |s| {
            format!(
                ": {} mm along u and along v at the detector",
                list(&nonzero, |p| short(p * s[0], 2))
            )
        });
        rows.push([
            "piercing ((p, p) alone)".into(),
            format!("p = {} px", list(&nonzero, |p| short(p, 3))),
            format!("the piercing point moved by (p, p){mm}"),
        ]);
    }
    let pairs: Vec<String> = g
        .df_px
        .iter()
        .zip(&nonzero)
        .map(|(d, p)| format!("({}, {})", short(*d, 3), short(*p, 3)))
        .collect();
    if !pairs.is_empty() {
        rows.push([
            "joint (the paper's schedule)".into(),
            format!("(Δf, p) = {} px", pairs.join(", ")),
            "the i-th Δf with the i-th non-zero piercing shift".into(),
        ]);
    }
    if !g.skew_px.is_empty() {
        rows.push([
            "skew (s alone)".into(),
            format!("s = {} px", list(&g.skew_px, |s| short(s, 3))),
            format!(
                "the detector's u axis sheared against v by atan(s/fy) = {}°",
                list(&g.skew_px, |s| short((s / k.fy).atan().to_degrees(), 3))
            ),
        ]);
    }
    if !g.pixel_scale.is_empty() {
        let sdd = sdd.map_or(String::new(), |d| {
            format!(
                "; as an SDD error of {} mm along v at {} mm",
                list(&g.pixel_scale, |sy| short((sy - 1.0) * d, 1)),
                short(d, 0)
            )
        });
        rows.push([
            "scale (fy × sy alone)".into(),
            format!("sy = {}", list(&g.pixel_scale, |s| short(s, 4))),
            format!(
                "the v pixel spacing off the assumed by 1/sy − 1 = {} %{sdd}",
                list(&g.pixel_scale, |sy| signed(100.0 * (1.0 / sy - 1.0), 2))
            ),
        ]);
    }
    if rows.is_empty() {
        return;
    }
    let _ = writeln!(
        md,
        "The perturbations of K that the projection, landmark and screw experiments step through \
         (`[perturbations]`; the extrinsics held fixed), in physical terms at this detector's K (fx {}, \
         fy {} px):\n\n| family | steps | what they mean |\n|---|---|---|",
        short(k.fx, 1),
        short(k.fy, 1)
    );
    for r in rows {
        let _ = writeln!(md, "| {} | {} | {} |", r[0], r[1], r[2]);
    }
    let _ = writeln!(md);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steps_are_stated_in_physical_terms() {
        let k = Intrinsics {
            fx: 4500.0,
            fy: 4500.0,
            cx: 511.5,
            cy: 511.5,
            skew: 0.0,
            width: 1024,
            height: 1024,
        };
        let g = PerturbationGrid {
            df_px: vec![100.0, 500.0],
            piercing_px: vec![0.0, 50.0],
            skew_px: vec![4.5],
            pixel_scale: vec![1.02],
            physical: crate::study::config::PhysicalGrid::none(),
        };
        let mut md = String::new();
        table(&mut md, &g, &k, Some([0.3, 0.3]), Some(1350.0));
        // Δf = 100 px at 0.3 mm/px is 30 mm of SDD (fx = SDD/spacing); 2.22 % of 4500.
        assert!(
            md.contains("fx and fy 2.22, 11.11 % larger than 4500; as an SDD error of 30, 150 mm"),
            "{md}"
        );
        assert!(md.contains("15 mm along u and along v"), "{md}");
        assert!(md.contains("(Δf, p) = (100, 50) px"), "{md}");
        // atan(4.5/4500) = 0.0573°.
        assert!(md.contains("atan(s/fy) = 0.057°"), "{md}");
        // 1/1.02 − 1 = −1.96 %; (1.02 − 1)·1350 = 27 mm.
        assert!(
            md.contains("1/sy − 1 = −1.96 %") && md.contains("27 mm along v"),
            "{md}"
        );
    }
}
