//! `spinedrr calibrate`'s products: `calibrations.csv` (one row per trial and view: K_est, the view's
//! estimated extrinsics and their error, reprojection RMS, held-out 3-D error) and `phantom.json` (BB
//! centres, the true geometry and every placement it imaged), computed first and written atomically
//! only when every trial succeeded.

use std::path::{Path, PathBuf};

use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::acquisition::check_sigma;
use super::phantom::{CalibrationPhantom, PhantomKind};
use super::trial::{CalibrationSetup, SetupOptions, TrialResult, run_trial};
use crate::geometry::{CArm, Intrinsics, rotation_log};
use crate::io::{write_atomic_bytes, write_json};
use crate::registration::pose_errors;
use crate::{Error, Result};

/// Largest number of trials of one run.
pub const MAX_TRIALS: usize = 1_000_000;

/// One row of `calibrations.csv`: trial `trial`, view `view`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationRow {
    pub trial: usize,
    pub view: String,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub skew: f64,
    /// Estimated world → camera rotation as an axis-angle vector (rad).
    pub rx_rad: f64,
    pub ry_rad: f64,
    pub rz_rad: f64,
    /// Estimated world → camera translation (mm).
    pub tx_mm: f64,
    pub ty_mm: f64,
    pub tz_mm: f64,
    /// Geodesic angle between the estimated and true camera rotations (deg).
    pub rot_err_deg: f64,
    /// Distance between the estimated and true X-ray source positions (mm).
    pub source_err_mm: f64,
    /// RMS reprojection error per coordinate over every calibration BB (px): the vendor's figure.
    pub reprojection_rms_px: f64,
    /// Mean 3-D error of the held-out BBs triangulated from every view (mm).
    pub heldout_err_mm: f64,
}

/// The rows of one trial.
pub fn rows_of(trial: usize, carm: &CArm, r: &TrialResult) -> Vec<CalibrationRow> {
    let k: Intrinsics = r.k();
    carm.views
        .iter()
        .zip(&r.views)
        .map(|(truth, est)| {
            let w = rotation_log(est.world_to_camera.rotation);
            let t = est.world_to_camera.translation;
            let e = pose_errors(&est.world_to_camera, &truth.world_to_camera);
            CalibrationRow {
                trial,
                view: truth.name.clone(),
                fx: k.fx,
                fy: k.fy,
                cx: k.cx,
                cy: k.cy,
                skew: k.skew,
                rx_rad: w.x,
                ry_rad: w.y,
                rz_rad: w.z,
                tx_mm: t.x,
                ty_mm: t.y,
                tz_mm: t.z,
                rot_err_deg: e.rot_err_deg,
                source_err_mm: (est.source_world() - truth.source_world()).length(),
                reprojection_rms_px: r.calibration.rms_px,
                heldout_err_mm: r.heldout_err_mm,
            }
        })
        .collect()
}

/// `phantom.json`.
#[derive(Debug, Clone, Serialize)]
pub struct PhantomRecord {
    /// `spinedrr` ([`crate::io::TOOL`]).
    pub tool: &'static str,
    /// `calibration` ([`crate::io::kind::CALIBRATION`]).
    pub kind: &'static str,
    /// The other file of the output set (`calibrations.csv`), which this record vouches for as
    /// spinedrr's own when a later run replaces it ([`crate::io::check_output_paths`]).
    pub companions: Vec<String>,
    pub phantom: CalibrationPhantom,
    /// The true K (row-major) and detector size.
    #[serde(rename = "K")]
    pub k: [[f64; 3]; 3],
    pub width: u32,
    pub height: u32,
    /// The true views: name and world → camera (row-major 4×4).
    pub views: Vec<NamedMatrix>,
    /// Every calibration image: view, phantom → world and phantom → camera (row-major 4×4).
    pub placements: Vec<PlacementRecord>,
    /// BBs (phantom indices) used by the fit.
    pub fit_bbs: Vec<usize>,
    /// Held-out BBs (world mm).
    pub heldout_bbs_world_mm: Vec<[f64; 3]>,
    pub options: SetupOptions,
    pub noise_px: f64,
    pub trials: usize,
    pub seed: u64,
    pub estimator: &'static str,
}

#[derive(Debug, Clone, Serialize)]
pub struct NamedMatrix {
    pub name: String,
    pub world_to_camera: [[f64; 4]; 4],
}

#[derive(Debug, Clone, Serialize)]
pub struct PlacementRecord {
    pub view: String,
    pub phantom_to_world: [[f64; 4]; 4],
    pub phantom_to_camera: [[f64; 4]; 4],
}

/// Which calibration method the user asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum MethodChoice {
    /// Zhang's method for a planar phantom, DLT + LM for a 3-D one.
    #[default]
    Auto,
    /// Zhang's method; the phantom must be planar.
    Zhang,
    /// The 3-D method (DLT + LM); the BBs must span a volume.
    Dlt,
}

impl MethodChoice {
    /// Checks the choice against the phantom's geometry.
    pub fn check(self, phantom: &CalibrationPhantom) -> Result<()> {
        match (self, phantom.kind) {
            (MethodChoice::Zhang, PhantomKind::Volumetric) => Err(Error::invalid(
                "method",
                format!(
                    "phantom '{}' is not planar: Zhang's method needs BBs in one plane (use dlt)",
                    phantom.name
                ),
            )),
            (MethodChoice::Dlt, PhantomKind::Planar) => Err(Error::invalid(
                "method",
                format!(
                    "the BBs of phantom '{}' are coplanar: the 3-D method (DLT) needs BBs spanning a \
                     volume (use zhang)",
                    phantom.name
                ),
            )),
            _ => Ok(()),
        }
    }
}

/// What `spinedrr calibrate` asks for.
#[derive(Debug, Clone)]
pub struct CalibrateRequest {
    pub method: MethodChoice,
    pub phantom: CalibrationPhantom,
    pub carm: CArm,
    pub options: SetupOptions,
    pub noise_px: f64,
    pub trials: usize,
    pub seed: u64,
}

/// The trials' rows and the phantom record, before anything is written.
pub struct CalibrateOutcome {
    pub rows: Vec<CalibrationRow>,
    pub record: PhantomRecord,
    pub setup: CalibrationSetup,
}

/// The seed of trial `i`.
pub fn trial_seed(seed: u64, i: usize) -> u64 {
    let mut z = seed ^ (i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Validates the request, then runs every trial in parallel (`progress` is called once per finished
/// trial). Nothing is written.
pub fn run_request(
    req: &CalibrateRequest,
    progress: &(dyn Fn() + Sync),
) -> Result<CalibrateOutcome> {
    check_sigma(req.noise_px)?;
    req.method.check(&req.phantom)?;
    if req.trials == 0 || req.trials > MAX_TRIALS {
        return Err(Error::invalid(
            "trials",
            format!("must be between 1 and {MAX_TRIALS}, got {}", req.trials),
        ));
    }
    let setup = CalibrationSetup::new(&req.carm, &req.phantom, req.options)?;
    if setup.residuals() < setup.unknowns() {
        return Err(Error::invalid(
            "phantom",
            format!(
                "{} BB coordinates for {} unknowns: too few BBs",
                setup.residuals(),
                setup.unknowns()
            ),
        ));
    }
    let results = (0..req.trials)
        .into_par_iter()
        .map(|i| {
            let r = run_trial(&setup, req.noise_px, trial_seed(req.seed, i))
                .map_err(|e| Error::Numerical(format!("calibration trial {i}: {e}")));
            progress();
            r
        })
        .collect::<Result<Vec<_>>>()?;
    let rows = results
        .iter()
        .enumerate()
        .flat_map(|(i, r)| rows_of(i, &req.carm, r))
        .collect();
    let k = req.carm.views[0].intrinsics;
    let record = PhantomRecord {
        tool: crate::io::TOOL,
        kind: crate::io::kind::CALIBRATION,
        companions: vec![CSV_NAME.to_string()],
        phantom: req.phantom.clone(),
        k: k.matrix_rows(),
        width: k.width,
        height: k.height,
        views: req
            .carm
            .views
            .iter()
            .map(|v| NamedMatrix {
                name: v.name.clone(),
                world_to_camera: v.world_to_camera.to_rows(),
            })
            .collect(),
        placements: setup
            .ideal
            .iter()
            .map(|im| PlacementRecord {
                view: im.view.clone(),
                phantom_to_world: im.phantom_to_world.to_rows(),
                phantom_to_camera: im.phantom_to_camera.to_rows(),
            })
            .collect(),
        fit_bbs: setup.fit_bbs.clone(),
        heldout_bbs_world_mm: setup
            .heldout_world
            .iter()
            .map(|p: &DVec3| p.to_array())
            .collect(),
        options: req.options,
        noise_px: req.noise_px,
        trials: req.trials,
        seed: req.seed,
        estimator: match req.phantom.kind {
            PhantomKind::Planar => {
                "zhang (closed form, refined by OpenCV calibrateCamera; skew fixed at 0)"
            }
            PhantomKind::Volumetric => "normalised DLT + RQ, then LM of K (skew free) and poses",
        },
    };
    Ok(CalibrateOutcome {
        rows,
        record,
        setup,
    })
}

const CSV_NAME: &str = "calibrations.csv";

/// The two product paths under `out`, the record `phantom.json` last.
pub fn product_paths(out: &Path) -> [PathBuf; 2] {
    [out.join(CSV_NAME), out.join("phantom.json")]
}

/// Checks that both products can be written into `out`: a file already in their place must be
/// spinedrr's ([`crate::io::check_output_paths`]: `phantom.json` a record of spinedrr's,
/// `calibrations.csv` listed by it); `out` may not exist yet (nothing to replace), but must not be a file.
/// Nothing is written.
pub fn check_outcome_paths(out: &Path) -> Result<()> {
    if !out.exists() {
        return Ok(());
    }
    if !out.is_dir() {
        // The refusal of an output folder that is a file, by name.
        return crate::io::create_output_dir(out, "--out");
    }
    crate::io::check_output_set(&product_paths(out), |p| {
        (p.extension()? == "json").then_some(crate::io::kind::CALIBRATION)
    })
}

/// Writes `calibrations.csv` and then its record `phantom.json` into `out` (created if absent), each
/// atomically, after [`check_outcome_paths`].
pub fn write_outcome(out: &Path, o: &CalibrateOutcome) -> Result<()> {
    crate::io::create_output_dir(out, "--out")?;
    check_outcome_paths(out)?;
    let [csv_path, json_path] = product_paths(out);
    let mut w = csv::Writer::from_writer(Vec::new());
    for r in &o.rows {
        w.serialize(r)
            .map_err(|e| Error::encode("calibrations.csv", e))?;
    }
    let bytes = w
        .into_inner()
        .map_err(|e| Error::encode("calibrations.csv", e))?;
    write_atomic_bytes(&csv_path, &bytes)?;
    write_json(&json_path, &o.record)
}
