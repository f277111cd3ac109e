//! *Calibration of a displaced C-arm*: `calibration_physical.csv` in the report — per physical error,
//! phantom, σ and protocol, the anatomy's landmark shift and registration error with the calibration's
//! geometry beside the nominal geometry's used uncalibrated. Every number is a statistic of the table's
//! rows.

use std::fmt::Write as _;

use super::grid::short;
use crate::analysis::percentile;
use crate::study::config::Protocol;
use crate::study::schema::{CalibrationPhysicalRow, CalibrationRow, mean_sd};

/// Per trial (in order of appearance) the largest landmark shift over its views and the trial's
/// registration mTRE: (95th percentile of the first, mean of the second), over `(trial, shift, mtre)`.
fn stats(rows: impl Iterator<Item = (usize, f64, f64)>) -> (f64, f64) {
    let mut trials: Vec<(usize, f64, f64)> = Vec::new();
    for (t, shift, mtre) in rows {
        match trials.iter_mut().find(|x| x.0 == t) {
            Some(x) => x.1 = x.1.max(shift),
            None => trials.push((t, shift, mtre)),
        }
    }
    let worst: Vec<f64> = trials.iter().map(|x| x.1).collect();
    let mtre: Vec<f64> = trials.iter().map(|x| x.2).collect();
    (percentile(&worst, 95.0), mean_sd(&mtre).0)
}

/// Writes the subsection (nothing without rows); `nominal` is `calibration.csv`, the same trials on the
/// nominal C-arm.
pub fn section(md: &mut String, rows: &[CalibrationPhysicalRow], nominal: &[CalibrationRow]) {
    if rows.is_empty() {
        return;
    }
    let _ = writeln!(
        md,
        "### Calibrating a C-arm displaced by a physical error\n"
    );
    let _ = writeln!(
        md,
        "Here the C-arm differs from its nominal geometry by one key of `[calibration.physical]` (in each \
view's camera axes; see *Physical geometry errors*); the phantom is imaged and calibrated on that displaced \
C-arm, with the detection noise of the nominal trials of the same index, and the vertebra is imaged by it \
too. **full**: the vertebra projected and registered with the estimated K and poses, which can absorb the \
whole error, leaving the calibration noise's; **intrinsic**: the estimated K with the *nominal* poses — a \
tracker or mechanical model that does not know of the error — which absorbs what the error does to K but \
not a camera centre moved or a camera turned. *Uncalibrated*: the nominal geometry used as it is, the \
error's own effect (`tables/calibration_physical.csv`). *Nominal C-arm*: the same trials (same \
detection noise) calibrating the nominal C-arm (`calibration.csv`), the calibration noise's own effect.\n"
    );
    let _ = writeln!(
        md,
        "| error | phantom | σ (px) | protocol | landmark shift, largest over views, 95th percentile over \
trials (px) | landmark registration mTRE, mean over trials (mm) | uncalibrated: largest landmark shift (px), \
mTRE (mm) | nominal C-arm, same trials: shift (px), mTRE (mm) |\n|---|---|---|---|---|---|---|---|"
    );
    let mut cells: Vec<(String, u64, String, u64, Protocol)> = Vec::new();
    for r in rows {
        let c = (
            r.key.clone(),
            r.value.to_bits(),
            r.phantom.clone(),
            r.noise_px.to_bits(),
            r.protocol,
        );
        if !cells.contains(&c) {
            cells.push(c);
        }
    }
    for (key, value, phantom, noise, protocol) in cells {
        let here: Vec<&CalibrationPhysicalRow> = rows
            .iter()
            .filter(|r| {
                r.key == key
                    && r.value.to_bits() == value
                    && r.phantom == phantom
                    && r.noise_px.to_bits() == noise
                    && r.protocol == protocol
            })
            .collect();
        let (shift, mtre) = stats(
            here.iter()
                .map(|r| (r.trial, r.landmark_shift_max_px, r.reg_mtre_mm)),
        );
        let trials: Vec<usize> = here.iter().map(|r| r.trial).collect();
        let (nom_shift, nom_mtre) = stats(
            nominal
                .iter()
                .filter(|r| {
                    r.phantom == phantom
                        && r.noise_px.to_bits() == noise
                        && r.protocol == protocol
                        && trials.contains(&r.trial)
                })
                .map(|r| (r.trial, r.landmark_shift_max_px, r.reg_mtre_mm)),
        );
        let uncal_shift = here
            .iter()
            .map(|r| r.uncalibrated_shift_max_px)
            .fold(f64::NAN, f64::max);
        let uncal_mtre = here.first().map_or(f64::NAN, |r| r.uncalibrated_mtre_mm);
        let show = |x: f64, d: usize| {
            if x.is_finite() {
                short(x, d)
            } else {
                "n/a".to_string()
            }
        };
        let _ = writeln!(
            md,
            "| {key} = {} | {phantom} | {} | {protocol} | {} | {} | {}, {} | {}, {} |",
            short(f64::from_bits(value), 3),
            short(f64::from_bits(noise), 3),
            show(shift, 2),
            show(mtre, 3),
            show(uncal_shift, 2),
            show(uncal_mtre, 3),
            show(nom_shift, 2),
            show(nom_mtre, 3)
        );
    }
    let _ = writeln!(md);
}
