//! *Landmarks*: the paper's landmark-shift table beside ours, and which rows of `landmarks.csv` have no
//! measurement (a marker the detector's edge cuts). Writing to a `String` cannot fail, so `writeln!`
//! results are discarded.

use std::fmt::Write as _;

use super::{comparison, grid};
use crate::study::paper::PaperResults;
use crate::study::schema::LandmarkRow;

/// The landmark section's table and the unmeasured rows.
pub fn section(
    md: &mut String,
    rows: &[LandmarkRow],
    paper: &PaperResults,
    first: &str,
    pitch: grid::Pitch,
) {
    let t = comparison::landmark_table(rows, paper, first, pitch);
    let _ = writeln!(md, "### {}\n", t.caption);
    let _ = writeln!(md, "{}", t.to_markdown());
    if let Some(text) = unmeasured_landmarks(rows) {
        let _ = writeln!(md, "{text}\n");
    }
}

/// Which rows of `landmarks.csv` have no measurement (a marker whose search disc is not wholly on the
/// detector, [`crate::analysis::marker_centroid`]), per target and view, landmark by landmark with its
/// number of cells; `None` when every landmark was measured.
fn unmeasured_landmarks(rows: &[LandmarkRow]) -> Option<String> {
    let missing: Vec<&LandmarkRow> = rows.iter().filter(|r| !r.shift_px.is_finite()).collect();
    if missing.is_empty() {
        return None;
    }
    // Per (target, view), the cells of each landmark.
    let mut groups: std::collections::BTreeMap<
        (&str, &str),
        std::collections::BTreeMap<&str, usize>,
    > = std::collections::BTreeMap::new();
    for r in &missing {
        *groups
            .entry((r.target.as_str(), r.view.as_str()))
            .or_default()
            .entry(r.landmark.as_str())
            .or_default() += 1;
    }
    let parts: Vec<String> = groups
        .into_iter()
        .map(|((target, view), names)| {
            let mut names: Vec<(&str, usize)> = names.into_iter().collect();
            names.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(b.0)));
            let names: Vec<String> = names
                .iter()
                .map(|(n, c)| format!("{n} in {c} cell{}", if *c == 1 { "" } else { "s" }))
                .collect();
            format!("{target} {}: {}", view.to_uppercase(), names.join(", "))
        })
        .collect();
    let in_reference = missing.iter().filter(|r| !r.ref_u_px.is_finite()).count();
    let where_cut = if in_reference == 0 {
        "each whole in the reference view and cut in the perturbed one".to_string()
    } else {
        format!("{in_reference} of them already cut in the reference view")
    };
    Some(format!(
        "A marker whose search disc is not wholly on the detector is not measured (a cut blob's centroid \
is biased): {} of {} rows of landmarks.csv have NaN measurements, {} ({where_cut}).",
        missing.len(),
        rows.len(),
        parts.join("; ")
    ))
}

#[cfg(test)]
mod tests {
    use super::unmeasured_landmarks;
    use crate::study::config::Family;
    use crate::study::schema::LandmarkRow;

    fn row(target: &str, view: &str, landmark: &str, reference: f64, measured: f64) -> LandmarkRow {
        LandmarkRow {
            target: target.into(),
            view: view.into(),
            family: Family::Focal,
            df_px: 100.0,
            dcx_px: 0.0,
            dcy_px: 0.0,
            landmark: landmark.into(),
            ref_u_px: reference,
            ref_v_px: reference,
            meas_u_px: measured,
            meas_v_px: measured,
            shift_px: measured - reference,
            pred_u_px: 0.0,
            pred_v_px: 0.0,
            pred_shift_px: 0.0,
            pred_error_px: 0.0,
        }
    }

    #[test]
    fn unmeasured_landmarks_are_counted_per_target_view_and_landmark() {
        let nan = f64::NAN;
        let mut rows = vec![row("L1", "ap", "L1/center", 500.0, 501.0); 5];
        assert_eq!(unmeasured_landmarks(&rows), None);
        rows.push(row("segment", "lat", "L5/tip", 1000.0, nan));
        rows.push(row("segment", "lat", "L5/corner", 1000.0, nan));
        rows.push(row("segment", "lat", "L5/tip", 1000.0, nan));
        let text = unmeasured_landmarks(&rows).expect("three rows unmeasured");
        assert!(
            text.contains(
                "3 of 8 rows of landmarks.csv have NaN measurements, segment LAT: L5/tip in 2 cells, \
                 L5/corner in 1 cell (each whole in the reference view and cut in the perturbed one)."
            ),
            "{text}"
        );
        rows.push(row("L2", "ap", "L2/tip", nan, nan));
        let text = unmeasured_landmarks(&rows).expect("four rows unmeasured");
        assert!(
            text.contains(
                "4 of 9 rows of landmarks.csv have NaN measurements, L2 AP: L2/tip in 1 cell; segment LAT: \
                 L5/tip in 2 cells, L5/corner in 1 cell (1 of them already cut in the reference view)."
            ),
            "{text}"
        );
    }
}
