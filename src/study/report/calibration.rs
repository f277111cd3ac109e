//! The report's calibration section: what the simulated calibrations were, how their phantom figures
//! relate to the vertebra's, the tolerance table and the ambiguity, in plain words.

use std::fmt::Write as _;

use super::layout;
use super::layout::num;
use crate::analysis::percentile;
use crate::study::config::{Protocol, StudyConfig};
use crate::study::figures::{FigureEntry, Section, distinct};
use crate::study::schema::{CalibrationRow, StudyTables, mean_sd};

/// The section heading.
pub const HEADING: &str = "Calibration in the loop: phantom error vs anatomy error";

fn mean(v: &[f64]) -> f64 {
    mean_sd(v).0
}

fn sd(v: &[f64]) -> f64 {
    mean_sd(v).1
}

/// Writes the section (nothing when the experiment did not run).
pub fn section(
    md: &mut String,
    (cfg, first): (&StudyConfig, &str),
    tables: &StudyTables,
    figs: &[FigureEntry],
    n: &mut usize,
) {
    let rows = &tables.calibration;
    if rows.is_empty() {
        return;
    }
    let c = &cfg.calibration;
    // What ran, from the table: the trials (of each cell) with a silhouette and with an intensity
    // registration; the configuration only says why none did.
    let ran = |has: fn(&CalibrationRow) -> bool| {
        distinct(rows.iter().filter(|r| has(r)).map(|r| r.trial)).len()
    };
    let (silhouettes, intensity) = (
        ran(|r| r.dice.is_finite()),
        ran(|r| r.ireg_mtre_mm.is_finite()),
    );
    let trials = distinct(rows.iter().map(|r| r.trial)).len();
    // `ran` trials of each cell did it: every trial, the first few, or none (`key = configured`, and
    // whether the configuration asked for some that produced no value).
    let said = |ran: usize, (what, key, configured): (&str, &str, usize), done: &str| match ran {
        0 => format!(
            "no {what} (`{key} = {configured}`{})",
            if configured > 0 {
                ", none of which produced a value"
            } else {
                ""
            }
        ),
        _ if ran == trials => format!("{done} for every trial"),
        1 => format!("{done} for the first trial of each cell"),
        _ => format!("{done} for the first {ran} trials of each cell"),
    };
    let silhouette = said(
        silhouettes,
        ("silhouette", "silhouette_trials", c.silhouette_trials),
        "Dice and contour distances of the rendered silhouette",
    );
    let registration = said(
        intensity,
        (
            "intensity-based registration",
            "intensity_trials",
            c.intensity_trials,
        ),
        "an intensity-based registration (AP + LAT, NCC, binned pyramid, from the true pose) whose \
fixed images are the vertebra's noise-free DRRs through the true views",
    );
    let _ = writeln!(md, "## {HEADING}\n");
    let _ = writeln!(
        md,
        "A C-arm is calibrated with a phantom of metal balls (BBs), and the calibration is judged by how \
well it reprojects those BBs — the *reconstruction-domain* figure a vendor reports. Here the calibration \
itself is simulated: phantoms {} are imaged with the true geometry, every BB's detected position gets \
Gaussian noise σ ∈ {{{}}} px, and the calibration is estimated again, {} times per phantom and σ. A plate \
(planar BBs, {} tilted poses of {}° per view) is calibrated by Zhang's method (his closed form, refined by \
OpenCV `calibrateCamera`: fx, fy, cx, cy free, skew fixed at 0, no lens distortion); a 3-D phantom (one image per view) by a \
normalised DLT, RQ decomposition and Levenberg–Marquardt of one K with skew and the poses. Each \
estimate is then used on the vertebra ({}) under two protocols: **intrinsic** — K_est with the true \
extrinsics, the paper's intrinsic-only perturbation with magnitudes a real calibration produces — and \
**full** — K_est with each view's estimated extrinsics, the geometry a navigation system would actually \
use. Per trial: the landmark shifts (exact projections of the 3-D landmarks), the homography law's \
residual (intrinsic protocol) and a landmark registration (direct LM over all views); {silhouette}; and \
{registration}.\n",
        c.phantoms.join(", "),
        c.noise_px
            .iter()
            .map(|s| s.to_string())
            .collect::<Vec<_>>()
            .join(", "),
        c.trials,
        c.poses_per_view,
        c.tilt_deg,
        c.target.as_deref().unwrap_or(first),
    );
    layout::figures(md, figs, Section::Calibration, n);
    summary_table(md, rows);
    registration_table(md, rows);
    tolerance_table(md, tables);
    ambiguity_table(md, tables);
}

fn summary_table(md: &mut String, rows: &[CalibrationRow]) {
    let views = distinct(rows.iter().map(|r| r.view.clone()));
    let protocols = distinct(rows.iter().map(|r| r.protocol));
    let _ = writeln!(
        md,
        "### What each calibration reports and what the vertebra sees\n\nPer phantom and σ: the mean \
reprojection RMS (px per coordinate), the spread of the estimated focal length and piercing point, \
the mean held-out 3-D error, and per protocol and view the 95th percentile over trials of the largest \
landmark shift.\n"
    );
    let mut header = vec![
        "phantom".to_string(),
        "σ (px)".into(),
        "RMS (px)".into(),
        "sd fx (px)".into(),
        "sd cx (px)".into(),
        "held-out (mm)".into(),
    ];
    for p in &protocols {
        for v in &views {
            header.push(format!("p95 shift {p} {v} (px)"));
        }
    }
    let _ = writeln!(md, "| {} |", header.join(" | "));
    let _ = writeln!(md, "|{}", "---|".repeat(header.len()));
    let cells = distinct(
        rows.iter()
            .map(|r| (r.phantom.clone(), r.noise_px.to_bits())),
    );
    for (phantom, bits) in cells {
        let cell: Vec<&CalibrationRow> = rows
            .iter()
            .filter(|r| r.phantom == phantom && r.noise_px.to_bits() == bits)
            .collect();
        let one: Vec<&&CalibrationRow> = cell
            .iter()
            .filter(|r| r.protocol == cell[0].protocol && r.view == cell[0].view)
            .collect();
        let f = |g: fn(&CalibrationRow) -> f64| one.iter().map(|r| g(r)).collect::<Vec<f64>>();
        let mut line = vec![
            phantom.clone(),
            f64::from_bits(bits).to_string(),
            num(mean(&f(|r| r.reprojection_rms_px)), 3),
            num(sd(&f(|r| r.fx)), 2),
            num(sd(&f(|r| r.cx)), 2),
            num(mean(&f(|r| r.heldout_err_mm)), 3),
        ];
        for p in &protocols {
            for v in &views {
                let s: Vec<f64> = cell
                    .iter()
                    .filter(|r| r.protocol == *p && &r.view == v)
                    .map(|r| r.landmark_shift_max_px)
                    .filter(|x| x.is_finite())
                    .collect();
                line.push(num(percentile(&s, 95.0), 3));
            }
        }
        let _ = writeln!(md, "| {} |", line.join(" | "));
    }
    let _ = writeln!(md);
}

/// Mean of the finite values (NaN when none).
fn finite_mean(v: impl Iterator<Item = f64>) -> (f64, usize) {
    let v: Vec<f64> = v.filter(|x| x.is_finite()).collect();
    (mean(&v), v.len())
}

/// A registration cell: phantom, σ (px) and protocol.
type CellKey = (String, f64, Protocol);

/// The registration rows (one per trial and protocol) grouped by cell, in table order.
fn registration_cells<'a>(
    trials: &[&'a CalibrationRow],
) -> Vec<(CellKey, Vec<&'a CalibrationRow>)> {
    let keys = distinct(
        trials
            .iter()
            .map(|r| (r.phantom.clone(), r.noise_px.to_bits(), r.protocol)),
    );
    keys.into_iter()
        .map(|(phantom, bits, protocol)| {
            let cell = trials
                .iter()
                .copied()
                .filter(|r| {
                    r.phantom == phantom && r.noise_px.to_bits() == bits && r.protocol == protocol
                })
                .collect();
            ((phantom, f64::from_bits(bits), protocol), cell)
        })
        .collect()
}

const REGISTRATION_HEADING: &str = "Registration error under the estimated geometry";

/// The registration table of a run without intensity registrations: the landmark registration's mean
/// mTRE per phantom, σ and protocol, over every trial.
fn landmark_only_table(md: &mut String, trials: &[&CalibrationRow]) {
    let _ = writeln!(
        md,
        "### {REGISTRATION_HEADING}\n\nThe mean target registration error (mTRE over the vertebra's \
surface points, mm) of the landmark registration over every trial, when the navigation system uses the \
calibrated geometry (no intensity-based registration ran in this study: `calibration.intensity_trials` \
adds one on the first trials of each cell); n: the trials whose registration ended.\n\n| phantom | σ (px) \
| protocol | landmark mTRE (mm) | n |\n|---|---|---|---|---|"
    );
    for ((phantom, sigma, protocol), cell) in registration_cells(trials) {
        let (lm, n) = finite_mean(cell.iter().map(|r| r.reg_mtre_mm));
        let _ = writeln!(
            md,
            "| {phantom} | {sigma} | {protocol} | {} | {n} |",
            num(lm, 3)
        );
    }
    let _ = writeln!(md);
}

/// Per phantom, σ and protocol: the landmark and the intensity registration's mean mTRE, and what
/// the comparison says.
fn registration_table(md: &mut String, rows: &[CalibrationRow]) {
    let Some(first_view) = rows.first().map(|r| r.view.clone()) else {
        return;
    };
    // One row per trial and protocol (the registration uses every view; rows repeat it per view).
    let trials: Vec<&CalibrationRow> = rows.iter().filter(|r| r.view == first_view).collect();
    if !trials.iter().any(|r| r.ireg_mtre_mm.is_finite()) {
        landmark_only_table(md, &trials);
        return;
    }
    let _ = writeln!(
        md,
        "### {REGISTRATION_HEADING}\n\nThe mean target registration error \
(mTRE over the vertebra's surface points, mm) of the landmark registration — over every trial, and over \
the trials that also ran the intensity-based registration (the first n of each cell) — and of the \
intensity-based registration, when the navigation system uses the calibrated geometry. The intensity \
registration is local (it starts at the true pose): where the calibrated geometry's optimum lies beyond \
its capture range (not measured in this experiment), it stops short and its mTRE understates the bias.\n"
    );
    let _ = writeln!(
        md,
        "| phantom | σ (px) | protocol | landmark mTRE, all (mm) | landmark mTRE, same n (mm) | \
intensity mTRE (mm) | n |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|---|---|");
    let mut intensity: Vec<(CellKey, f64)> = Vec::new();
    for ((phantom, sigma, protocol), cell) in registration_cells(&trials) {
        let (lm, _) = finite_mean(cell.iter().map(|r| r.reg_mtre_mm));
        let (im, ni) = finite_mean(cell.iter().map(|r| r.ireg_mtre_mm));
        let (lm_same, _) = finite_mean(
            cell.iter()
                .filter(|r| r.ireg_mtre_mm.is_finite())
                .map(|r| r.reg_mtre_mm),
        );
        if ni > 0 {
            intensity.push(((phantom.clone(), sigma, protocol), im));
        }
        let _ = writeln!(
            md,
            "| {phantom} | {sigma} | {protocol} | {} | {} | {} | {ni} |",
            num(lm, 3),
            num(lm_same, 3),
            num(im, 3)
        );
    }
    let _ = writeln!(md);
    if let Some(text) = intensity_protocols(&intensity) {
        let _ = writeln!(md, "{text}\n");
    }
}

/// The intensity registration's mean mTRE under the two protocols: each protocol's worst cell, and
/// cell by cell (the same phantom, σ and trials under both) what the full geometry leaves of the
/// intrinsic-only mTRE. `None` without a cell that has both.
fn intensity_protocols(cells: &[(CellKey, f64)]) -> Option<String> {
    let worst = |p: Protocol| {
        cells
            .iter()
            .filter(|((_, _, q), v)| *q == p && v.is_finite())
            .max_by(|a, b| a.1.total_cmp(&b.1))
    };
    let (Some(((pi, si, _), wi)), Some(((pf, sf, _), wf))) =
        (worst(Protocol::Intrinsic), worst(Protocol::Full))
    else {
        return None;
    };
    let left: Vec<f64> = cells
        .iter()
        .filter(|((_, _, q), _)| *q == Protocol::Intrinsic)
        .filter_map(|((ph, s, _), i)| {
            let (_, f) = cells
                .iter()
                .find(|((p2, s2, q), _)| p2 == ph && s2 == s && *q == Protocol::Full)?;
            (i.is_finite() && f.is_finite() && *i > 0.0).then(|| 100.0 * f / i)
        })
        .collect();
    let (lo, hi) = left
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| {
            (lo.min(x), hi.max(x))
        });
    let mut text = format!(
        "With K_est and the true extrinsics the intensity registration's mean mTRE reaches {} mm in the \
worst cell ({pi}, σ = {si} px); with the full estimated geometry {} mm in its worst ({pf}, σ = {sf} px).",
        num(*wi, 3),
        num(*wf, 3)
    );
    if !left.is_empty() {
        let span = if format!("{lo:.1}") == format!("{hi:.1}") {
            format!("{lo:.1} %")
        } else {
            format!("{lo:.1}–{hi:.1} %")
        };
        let _ = write!(
            text,
            " Cell by cell (the same trials under both protocols) the full geometry leaves {span} of the \
intrinsic-only mTRE over the {} cells{}.",
            left.len(),
            if hi < 100.0 {
                ": the intensity registration, matching the DRR to the image, absorbs into the pose what \
the estimated geometry projects differently, as the landmark registration does"
            } else {
                ""
            }
        );
    }
    Some(text)
}

fn tolerance_table(md: &mut String, tables: &StudyTables) {
    let t = &tables.calibration_tolerance;
    if t.is_empty() {
        return;
    }
    let _ = writeln!(
        md,
        "### Tolerance: how good must the calibration be?\n\nThe detection noise σ, and the reprojection \
RMS a calibration at that noise reports, at which the 95th percentile over calibrations of the largest \
vertebral landmark shift reaches 0.5, 1 and 2 px (linear interpolation in σ through the noise-free \
point; '> max σ' when the largest σ studied stays below the threshold). Read it as: *if your \
calibration with this phantom reports an RMS below this value, 95% of such calibrations move no \
landmark of this vertebra by more than the threshold in this view.*\n"
    );
    let _ = writeln!(
        md,
        "| phantom | protocol | view | threshold (px) | σ at threshold (px) | RMS at threshold (px) |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|---|");
    for r in t {
        let (s, rms) = if r.above_grid {
            ("> max σ".to_string(), "—".to_string())
        } else {
            (num(r.max_noise_px, 3), num(r.max_reprojection_rms_px, 3))
        };
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {s} | {rms} |",
            r.phantom, r.protocol, r.view, r.threshold_px
        );
    }
    let _ = writeln!(md);
}

fn ambiguity_table(md: &mut String, tables: &StudyTables) {
    let a = &tables.calibration_ambiguity;
    if a.is_empty() {
        return;
    }
    let _ = writeln!(
        md,
        "### The ambiguity: equal phantom RMS, different anatomy\n\nFor each phantom, σ, protocol and view, \
the two calibrations whose reprojection RMS agrees within 5% but whose largest landmark shift differs \
most (calibration_ambiguity.csv). Many combinations of focal length, piercing point and pose reproduce \
the phantom equally well — for plate views the focal length and the plate's distance are nearly \
exchangeable — so the RMS alone cannot tell a calibration that keeps the vertebra in place from one \
that moves it.\n"
    );
    let _ = writeln!(
        md,
        "| phantom | σ (px) | protocol | view | RMS A / B (px) | shift A / B (px) | ratio | Δfx A / B (px) |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|---|---|---|");
    for r in a
        .iter()
        .filter(|r| r.protocol == Protocol::Full)
        .chain(a.iter().filter(|r| r.protocol == Protocol::Intrinsic))
    {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {:.3} / {:.3} | {:.3} / {:.3} | {:.1} | {:.1} / {:.1} |",
            r.phantom,
            r.noise_px,
            r.protocol,
            r.view,
            r.rms_a_px,
            r.rms_b_px,
            r.shift_a_px,
            r.shift_b_px,
            r.ratio,
            r.dfx_a_px,
            r.dfx_b_px
        );
    }
    let _ = writeln!(md);
}

#[cfg(test)]
mod tests {
    use super::intensity_protocols;
    use crate::study::config::Protocol::{Full, Intrinsic};

    /// Each protocol's worst cell is named, and the two protocols are compared cell by cell, never
    /// one cell's intrinsic error against another cell's full one.
    #[test]
    fn the_protocols_are_compared_cell_by_cell() {
        let cells = [
            (("plate".to_string(), 0.1, Intrinsic), 1.0),
            (("plate".to_string(), 0.1, Full), 0.01),
            (("helix".to_string(), 0.5, Intrinsic), 25.0),
            (("helix".to_string(), 0.5, Full), 0.025),
            (("helix".to_string(), 1.0, Intrinsic), 1.0),
            (("helix".to_string(), 1.0, Full), 0.04),
        ];
        let text = intensity_protocols(&cells).expect("both protocols");
        assert!(
            text.starts_with(
                "With K_est and the true extrinsics the intensity registration's mean mTRE reaches \
                 25.000 mm in the worst cell (helix, σ = 0.5 px); with the full estimated geometry \
                 0.040 mm in its worst (helix, σ = 1 px)."
            ),
            "{text}"
        );
        // 0.01 / 1 = 1 %, 0.025 / 25 = 0.1 %, 0.04 / 1 = 4 %.
        assert!(
            text.contains(
                "the full geometry leaves 0.1–4.0 % of the intrinsic-only mTRE over the 3 cells:"
            ),
            "{text}"
        );
        assert_eq!(intensity_protocols(&cells[..1]), None);
    }
}
