//! *Physical geometry errors*: the physical family's table (`physical.csv`) in the report — per error
//! and view, the assumed camera's change, the first target's landmark shift and silhouette loss, and
//! the range of the single levels' mean shifts. Every number is a cell of `physical.csv` or a
//! difference of one from the study's reference K.

use std::fmt::Write as _;

use super::grid::{short, signed};
use super::shift_ratio::is_segment;
use crate::geometry::CArm;
use crate::study::schema::PhysicalRow;

pub const HEADING: &str = "Physical geometry errors: focal spot and detector moved";

/// Writes the section (nothing without rows). `carm` is the study's C-arm (binning applied): the
/// reference K each row's K' is set against.
pub fn section(md: &mut String, rows: &[PhysicalRow], carm: Option<&CArm>, first: &str) {
    if rows.is_empty() {
        return;
    }
    let _ = writeln!(md, "## {HEADING}\n");
    let pitch = carm
        .and_then(|c| c.views.first())
        .and_then(|v| v.sdd_mm.map(|s| s / v.intrinsics.fx));
    let _ = writeln!(
        md,
        "In each row the assumed (calibrated) focal spot or detector differs from the true one by one key, and \
the target is rendered with the camera the assumed geometry amounts to, `P' = K'[R'|t']` \
(`tables/physical.csv`; the derivation is in `core/src/geometry/physical.rs`). Keys are in the view's camera axes — x along the detector \
rows (u), y down the detector (v), z along the central ray from the source to the detector — and rotations \
are right-handed about the axis through the piercing point. Unlike the intrinsic families above, these \
change the camera's pose with K (`camera moved / turned`), so no homography maps one image to the other: \
each landmark shift is the exact projection of the target's landmark through the true and the assumed \
camera, counted when it lands on the detector{}.\n",
        pitch.map_or(String::new(), |p| format!(
            ", in px and in mm at the detector (× the {} mm pixel pitch)",
            short(p, 3)
        ))
    );
    let _ = writeln!(
        md,
        "| error | view | K' − K (px) | camera moved (mm) / turned (°) | {first}: landmark shift, mean (max) | \
{first}: 1 − Dice | single levels: mean landmark shift, range (px) |\n|---|---|---|---|---|---|---|"
    );
    let mut cells: Vec<(&str, u64, &str)> = Vec::new();
    for r in rows {
        let c = (r.key.as_str(), r.value.to_bits(), r.view.as_str());
        if !cells.contains(&c) {
            cells.push(c);
        }
    }
    for (key, bits, view) in cells {
        let value = f64::from_bits(bits);
        let here: Vec<&PhysicalRow> = rows
            .iter()
            .filter(|r| r.key == key && r.value.to_bits() == bits && r.view == view)
            .collect();
        let k = carm.and_then(|c| c.view(view).ok()).map(|v| v.intrinsics);
        let dk = here.first().zip(k).map_or("n/a".to_string(), |(r, k)| {
            let mut parts = vec![
                format!("fx {}", signed(r.fx_px - k.fx, 1)),
                format!("fy {}", signed(r.fy_px - k.fy, 1)),
            ];
            if (r.skew_px - k.skew).abs() >= 0.05 {
                parts.push(format!("s {}", signed(r.skew_px - k.skew, 1)));
            }
            parts.push(format!("cx {}", signed(r.cx_px - k.cx, 1)));
            parts.push(format!("cy {}", signed(r.cy_px - k.cy, 1)));
            parts.join(", ")
        });
        let pose = here.first().map_or("n/a".to_string(), |r| {
            format!(
                "{} / {}",
                short(r.camera_moved_mm, 2),
                short(r.camera_turned_deg, 2)
            )
        });
        let of_first = here.iter().find(|r| r.target == first);
        let shift = of_first.map_or("n/a".to_string(), |r| {
            let mm = if r.landmark_shift_mean_mm.is_finite() {
                format!(" = {} mm", short(r.landmark_shift_mean_mm, 2))
            } else {
                String::new()
            };
            format!(
                "{} px{mm} ({} px), {} landmarks",
                short(r.landmark_shift_mean_px, 2),
                short(r.landmark_shift_max_px, 2),
                r.landmarks
            )
        });
        let loss = of_first.map_or("n/a".to_string(), |r| {
            let cut = if r.cut_by_edge {
                " (cut by the detector edge)"
            } else {
                ""
            };
            format!("{}{cut}", short(1.0 - r.dice, 4))
        });
        let levels: Vec<f64> = here
            .iter()
            .filter(|r| !is_segment(&r.target) && !r.cut_by_edge)
            .map(|r| r.landmark_shift_mean_px)
            .filter(|x| x.is_finite())
            .collect();
        let range = super::grid::level_range(&levels, 2);
        let _ = writeln!(
            md,
            "| {key} = {} | {} | {dk} | {pose} | {shift} | {loss} | {range} |",
            short(value, 3),
            view.to_uppercase()
        );
    }
    let _ = writeln!(md);
}
