//! Why LAT landmarks move more than AP ones, computed per target. With the extrinsics fixed a focal
//! scale α moves every point by (α − 1)·|x − c| (c the piercing point), so on a fixed landmark set the
//! RMS shift is (α − 1)·d with d² = mean |x − c|² = o² + s²: o the distance of the landmarks' centroid
//! from the piercing point (where the anatomy sits), s their RMS spread about it (how large it is drawn:
//! size × magnification). The LAT/AP ratio of RMS shifts is then d_LAT / d_AP, whatever α.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use crate::study::figures::distinct;
use crate::study::schema::{Family, LandmarkRow};

/// Offset, spread and RMS distance (px) of a landmark set from the piercing point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spread {
    pub offset: f64,
    pub spread: f64,
}

impl Spread {
    /// The RMS distance from the piercing point: √(o² + s²).
    pub fn rms_distance(&self) -> f64 {
        self.offset.hypot(self.spread)
    }
}

pub use crate::study::config::is_segment;

/// One target's ratio on its fixed landmark set.
#[derive(Debug, Clone, PartialEq)]
pub struct TargetRatio {
    pub target: String,
    /// The landmarks measured (finite) in both views at every focal Δf.
    pub landmarks: Vec<String>,
    /// The others (off the detector or not measured in some cell).
    pub left_out: Vec<String>,
    /// The largest focal Δf (px), where the shifts are compared.
    pub df_px: f64,
    pub rms_shift_ap: f64,
    pub rms_shift_lat: f64,
    pub ap: Spread,
    pub lat: Spread,
}

impl TargetRatio {
    pub fn measured(&self) -> f64 {
        self.rms_shift_lat / self.rms_shift_ap
    }
    pub fn predicted(&self) -> f64 {
        self.lat.rms_distance() / self.ap.rms_distance()
    }
}

pub(super) fn spread(points: &[(f64, f64)], c: (f64, f64)) -> Spread {
    let n = points.len() as f64;
    let (mu, mv) = points
        .iter()
        .fold((0.0, 0.0), |(a, b), p| (a + p.0 / n, b + p.1 / n));
    let s2 = points
        .iter()
        .map(|p| (p.0 - mu).powi(2) + (p.1 - mv).powi(2))
        .sum::<f64>()
        / n;
    Spread {
        offset: (mu - c.0).hypot(mv - c.1),
        spread: s2.sqrt(),
    }
}

/// Per target with AP and LAT focal rows: the ratio on its fixed landmark set; `piercing` maps a view
/// to its piercing point (cx, cy).
pub fn ratios(rows: &[LandmarkRow], piercing: &BTreeMap<String, (f64, f64)>) -> Vec<TargetRatio> {
    let focal: Vec<&LandmarkRow> = rows.iter().filter(|r| r.family == Family::Focal).collect();
    let (Some(&c_ap), Some(&c_lat)) = (piercing.get("ap"), piercing.get("lat")) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for target in distinct(focal.iter().map(|r| r.target.as_str())) {
        let mine: Vec<&&LandmarkRow> = focal.iter().filter(|r| r.target == target).collect();
        let dfs = distinct(mine.iter().map(|r| r.df_px));
        let Some(df) = dfs.iter().copied().reduce(f64::max) else {
            continue;
        };
        let ok = |r: &LandmarkRow| {
            [r.ref_u_px, r.ref_v_px, r.meas_u_px, r.meas_v_px, r.shift_px]
                .iter()
                .all(|x| x.is_finite())
        };
        let (mut keep, mut left_out) = (Vec::new(), Vec::new());
        for name in distinct(mine.iter().map(|r| r.landmark.as_str())) {
            let every = ["ap", "lat"].iter().all(|v| {
                dfs.iter().all(|&d| {
                    mine.iter()
                        .any(|r| r.view == *v && r.df_px == d && r.landmark == name && ok(r))
                })
            });
            if every {
                keep.push(name.to_string());
            } else {
                left_out.push(name.to_string());
            }
        }
        if keep.is_empty() {
            continue;
        }
        let at = |view: &str| -> Vec<&LandmarkRow> {
            mine.iter()
                .filter(|r| r.view == view && r.df_px == df && keep.contains(&r.landmark))
                .map(|r| **r)
                .collect()
        };
        let (ap, lat) = (at("ap"), at("lat"));
        let rms = |v: &[&LandmarkRow]| {
            (v.iter().map(|r| r.shift_px.powi(2)).sum::<f64>() / v.len() as f64).sqrt()
        };
        let refs = |v: &[&LandmarkRow]| -> Vec<(f64, f64)> {
            v.iter().map(|r| (r.ref_u_px, r.ref_v_px)).collect()
        };
        out.push(TargetRatio {
            target: target.to_string(),
            landmarks: keep,
            left_out,
            df_px: df,
            rms_shift_ap: rms(&ap),
            rms_shift_lat: rms(&lat),
            ap: spread(&refs(&ap), c_ap),
            lat: spread(&refs(&lat), c_lat),
        });
    }
    out
}

/// The decomposition table.
pub fn table(md: &mut String, r: &[TargetRatio], pitch: super::grid::Pitch) {
    if r.is_empty() {
        return;
    }
    let _ = writeln!(
        md,
        "| target | landmarks (left out) | Δf, {} | RMS shift AP (px) | RMS shift LAT (px) | LAT/AP \
         measured | AP offset o, spread s (px) | LAT offset o, spread s (px) | √(o² + s²) AP, LAT (px) | \
         LAT/AP predicted |\n|---|---|---|---|---|---|---|---|---|---|",
        pitch.unit("SDD error")
    );
    for t in r {
        let left = if t.left_out.is_empty() {
            String::new()
        } else {
            format!(" ({}: {})", t.left_out.len(), t.left_out.join(", "))
        };
        let _ = writeln!(
            md,
            "| {} | {}{left} | {} | {:.3} | {:.3} | {:.3} | {:.1}, {:.1} | {:.1}, {:.1} | {:.1}, {:.1} | {:.3} |",
            t.target,
            t.landmarks.len(),
            pitch.df_cell(t.df_px),
            t.rms_shift_ap,
            t.rms_shift_lat,
            t.measured(),
            t.ap.offset,
            t.ap.spread,
            t.lat.offset,
            t.lat.spread,
            t.ap.rms_distance(),
            t.lat.rms_distance(),
            t.predicted()
        );
    }
    let _ = writeln!(md);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offset_and_spread_make_up_the_rms_distance() {
        // Points (0, 0), (4, 0), (2, 2), (2, −2) about (2, 0); piercing point (5, 4): o = √(9 + 16) = 5,
        // s² = (4 + 4 + 4 + 4)/4 = 4; mean |x − c|² = (41 + 17 + 13 + 45)/4 = 29 = 25 + 4.
        let s = spread(
            &[(0.0, 0.0), (4.0, 0.0), (2.0, 2.0), (2.0, -2.0)],
            (5.0, 4.0),
        );
        assert!((s.offset - 5.0).abs() < 1e-12 && (s.spread - 2.0).abs() < 1e-12);
        assert!((s.rms_distance() - 29f64.sqrt()).abs() < 1e-12);
    }
}
