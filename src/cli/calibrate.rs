//! `spinedrr calibrate`: a Monte-Carlo simulation of a C-arm calibration with a BB phantom, writing
//! `calibrations.csv` and `phantom.json`.

use std::path::PathBuf;

use anyhow::Context;
use spinedrr::calibration::output::{
    CalibrateRequest, MethodChoice, check_outcome_paths, product_paths, run_request, write_outcome,
};
use spinedrr::calibration::{CalibrationPhantom, Detection, SetupOptions};
use spinedrr::geometry::CArm;

#[derive(clap::Args)]
#[command(
    after_help = "Each trial images the phantom with the true geometry (--geometry or the built-in \
AP + LAT C-arm), adds Gaussian detection noise of --noise-px to every BB, and calibrates: a plate (or a \
planar FILE) by Zhang's method (his closed form refined by OpenCV calibrateCamera: fx, fy, cx, cy free, \
skew fixed at 0, no distortion), a helix (or a 3-D FILE) by a normalised DLT per view, RQ, then LM of one K with skew and \
the poses. calibrations.csv has one row per trial and view: K_est, the view's estimated world→camera \
pose and its error, the reprojection RMS and the mean 3-D error of held-out BBs triangulated from all \
views. phantom.json records the BB centres, the true K and views, and every placement imaged."
)]
pub struct Args {
    /// plate (10 × 10 BBs, 10 mm pitch, 5 tilted poses per view), helix (40 BBs, r 40 mm, 2 turns over
    /// 80 mm, one image per view) or FILE.json: {"name"?: "...", "bbs_mm": [[x, y, z], ...]}.
    #[arg(long)]
    phantom: String,
    /// auto (Zhang for planar BBs, DLT + LM for 3-D BBs), zhang or dlt (an error when the phantom's
    /// geometry does not fit the method).
    #[arg(long, default_value = "auto", value_parser = ["auto", "zhang", "dlt"])]
    method: String,
    /// Detection noise σ (px) added to both coordinates of every BB.
    #[arg(long)]
    noise_px: f64,
    /// Number of Monte-Carlo calibrations.
    #[arg(long, default_value_t = 100, value_parser = super::values::whole::<usize>)]
    trials: usize,
    /// C-arm geometry TOML (default: the built-in AP + LAT geometry; `spinedrr geometry` prints it).
    #[arg(long)]
    geometry: Option<PathBuf>,
    /// Plate tilt (deg) of each pose.
    #[arg(long, default_value_t = 30.0)]
    tilt_deg: f64,
    /// Plate poses per view.
    #[arg(long, default_value_t = 5, value_parser = super::values::whole::<usize>)]
    poses_per_view: usize,
    /// Measure BBs from rendered spheres of this radius (mm) instead of their exact projections.
    #[arg(long)]
    bb_radius_mm: Option<f64>,
    /// Master seed (trial i draws from a seed derived from it).
    #[arg(long, default_value_t = 0, value_parser = super::values::whole::<u64>)]
    seed: u64,
    /// Output folder (created; calibrations.csv and phantom.json are replaced atomically, and only when
    /// spinedrr wrote them: another file of either name is refused).
    #[arg(long)]
    out: PathBuf,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let phantom = match a.phantom.as_str() {
        "plate" => CalibrationPhantom::default_plate(),
        "helix" => CalibrationPhantom::default_helix(),
        file => CalibrationPhantom::from_file(std::path::Path::new(file))
            .with_context(|| format!("reading phantom {file}"))?,
    };
    let carm = match &a.geometry {
        Some(p) => {
            CArm::from_file(p).with_context(|| format!("reading geometry {}", p.display()))?
        }
        None => CArm::default_paper(),
    };
    // Before the trials: a folder holding someone else's files is refused at once.
    check_outcome_paths(&a.out)?;
    let req = CalibrateRequest {
        method: match a.method.as_str() {
            "zhang" => MethodChoice::Zhang,
            "dlt" => MethodChoice::Dlt,
            _ => MethodChoice::Auto,
        },
        phantom,
        carm,
        options: SetupOptions {
            tilt_deg: a.tilt_deg,
            poses_per_view: a.poses_per_view,
            detection: match a.bb_radius_mm {
                Some(radius_mm) => Detection::Rendered { radius_mm },
                None => Detection::Projected,
            },
            ..SetupOptions::default()
        },
        noise_px: a.noise_px,
        trials: a.trials,
        seed: a.seed,
    };
    let bar = (!a.quiet).then(|| {
        let b = indicatif::ProgressBar::new(a.trials as u64);
        if let Ok(style) =
            indicatif::ProgressStyle::with_template("calibrating {bar:40} {pos}/{len} trials {eta}")
        {
            b.set_style(style);
        }
        b
    });
    let tick = || {
        if let Some(b) = &bar {
            b.inc(1);
        }
    };
    let outcome = run_request(&req, &tick)?;
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    write_outcome(&a.out, &outcome)?;
    let n = outcome.rows.len().max(1) as f64;
    let mean = |f: fn(&spinedrr::calibration::output::CalibrationRow) -> f64| {
        outcome.rows.iter().map(f).sum::<f64>() / n
    };
    println!(
        "{} trials: mean fx {:.2} px, reprojection RMS {:.4} px, held-out 3-D error {:.4} mm",
        a.trials,
        mean(|r| r.fx),
        mean(|r| r.reprojection_rms_px),
        mean(|r| r.heldout_err_mm)
    );
    for p in product_paths(&a.out) {
        println!("wrote {}", p.display());
    }
    Ok(())
}
