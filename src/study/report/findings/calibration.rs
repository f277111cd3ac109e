//! The headline of the calibration-in-the-loop experiment: at the phantom reprojection RMS a
//! calibration reports, how far the vertebra's landmarks move when the calibrated K is used with the
//! true extrinsics (a tracked C-arm: the paper's intrinsic-only protocol) and when K and the views' poses
//! are estimated together (a system calibrated as a whole: the errors compensate).

use super::claim::{Claim, Finding, Op, Source, Stat, Transform, Where};
use super::derive::{column, formula};
use super::{Inputs, sources};
use crate::study::schema::CalibrationRow;

/// The range (min and max claims over `ids`, printed) as `a–b`.
fn range(
    f: &mut Finding,
    id: &str,
    ids: &[String],
    decimals: usize,
    unit: &'static str,
) -> Option<String> {
    let lo = formula(f, &format!("{id}.min"), Op::Min, ids)?.shown(decimals, unit);
    let hi = formula(f, &format!("{id}.max"), Op::Max, ids)?.shown(decimals, unit);
    Some(format!("{}–{}", f.say(lo), f.say(hi)))
}

/// The finding (nothing when the calibration experiment did not run with both protocols).
pub fn headline(x: &Inputs) -> Option<Finding> {
    let t = &x.calibration;
    let all = Where::new();
    let protocols = t.distinct(&all, "protocol");
    if !(protocols.iter().any(|p| p == "intrinsic") && protocols.iter().any(|p| p == "full")) {
        return None;
    }
    let views = t.distinct(&all, "view");
    let mut f = Finding::new("calibration_headline");
    let (mut rms, mut shift) = (Vec::new(), [Vec::new(), Vec::new()]);
    for phantom in t.distinct(&all, "phantom") {
        for sigma in t.distinct(&Where::new().is("phantom", &phantom), "noise_px") {
            let cell = Where::new().is("phantom", &phantom).is("noise_px", &sigma);
            // One row per trial: the RMS is the calibration's, the same in every protocol and view.
            let one = cell
                .clone()
                .is("protocol", "intrinsic")
                .is("view", views.first()?);
            let (v, n, src) = column(
                t,
                one,
                "reprojection_rms_px",
                Transform::Identity,
                Stat::Mean,
            )?;
            let id = format!("calibration.{phantom}.{sigma}.rms");
            f.keep(
                Claim::new(&id, v, src)
                    .shown(2, "px")
                    .about(&phantom, "", "calibration")
                    .cell("noise_px", sigma.parse().unwrap_or(f64::NAN))
                    .count(n),
            );
            rms.push(id);
            for (k, protocol) in ["intrinsic", "full"].iter().enumerate() {
                for view in &views {
                    let w = cell.clone().is("protocol", protocol).is("view", view);
                    let (v, n, src) = column(
                        t,
                        w,
                        "landmark_shift_max_px",
                        Transform::Identity,
                        Stat::P95,
                    )?;
                    let id = format!("calibration.{phantom}.{sigma}.{protocol}.{view}.p95");
                    f.keep(
                        Claim::new(&id, v, src)
                            .shown(2, "px")
                            .about(&phantom, view, protocol)
                            .cell("noise_px", sigma.parse().unwrap_or(f64::NAN))
                            .count(n),
                    );
                    shift[k].push(id);
                }
            }
        }
    }
    let n = f.say(
        Claim::new(
            "calibration.trials",
            x.calibration_trials as f64,
            Source::Config {
                key: "calibration.trials".into(),
            },
        )
        .count(1),
    );
    let pct = f.say(Claim::new(
        "calibration_percentile",
        95.0,
        Source::Rule {
            name: "calibration_percentile".into(),
        },
    ));
    let r = range(&mut f, "calibration.rms", &rms, 2, "px")?;
    let a = range(&mut f, "calibration.intrinsic.p95", &shift[0], 1, "px")?;
    let b = range(&mut f, "calibration.full.p95", &shift[1], 2, "px")?;
    let phantoms = t.distinct(&all, "phantom").join(" and ");
    f.text = format!(
        "Calibration in the loop, the figure a navigation user needs: simulated calibrations ({phantoms} \
phantoms, {n} per phantom and detection noise) whose phantom reprojection RMS is {r} px move the \
vertebra's landmarks by {a} px (the {pct}th percentile over calibrations of the largest landmark shift, per \
phantom, noise and view) when the calibrated K is used with the true extrinsics — the **intrinsic** \
protocol: a C-arm whose pose comes from a tracker or a fixed mechanical model, the set-up the paper's \
intrinsic-only perturbations describe — and by {b} px when K and each view's pose are estimated together \
from the same phantom — the **full** protocol: a system calibrated as a whole, where the estimated pose \
absorbs most of the K error. The paper's Δf and piercing perturbations are the errors of the first \
set-up; a system calibrated as a whole sees errors of the second size {}.",
        sources::<CalibrationRow>("calibration_scatter_lat.png")
    );
    Some(f)
}
