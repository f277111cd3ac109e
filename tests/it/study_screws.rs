//! The screws experiment end to end on a small grid (phantom L1, AP and LAT at 2× binning, Δf {100, 500},
//! piercing {50}, two physical errors): the drawn offsets obey the projection laws computed here from the
//! sidecar's own projection matrix (a focal error scales about the principal point, a piercing shift
//! translates, neither turns a screw), the mm at the screw are the px divided by the true magnification,
//! and the navigated screw agrees with the tracking experiment's pedicle error — two code paths, one
//! registration: the error of a rigid pose is convex along the screw, so its largest value over the
//! pedicle points (entry, isthmus, tip, on one line) is at the entry or the tip.

use std::path::Path;

use glam::{DVec2, DVec3};
use spinedrr::io::{Sidecar, sidecar_path};
use spinedrr::study::StudyTables;
use spinedrr::study::schema::Family;

use crate::common::Spinedrr;

const CONFIG: &str = r#"seed = 5
experiments = ["screws", "tracking"]
[anatomy]
levels = ["L1"]
segment = false
voxel_mm = 1.0
[geometry]
views = ["ap", "lat"]
binning = 2
[perturbations]
df_px = [100.0, 500.0]
piercing_px = [0.0, 50.0]
skew_px = []
pixel_scale = []
[perturbations.physical]
src_dx_mm = [4.0]
det_roll_deg = [2.0]
[tracking]
methods = ["direct-ap+lat"]
df_px = [100.0, 500.0]
"#;

fn study(cfg: &Path, out: &Path) -> (bool, String) {
    Spinedrr::new()
        .args(["study", "--config", cfg.to_str().unwrap(), "--out"])
        .arg(out)
        .outcome()
}

/// `P · [X, 1]` dehomogenised, and the third row (camera depth for a P = K[R|t] with K's last row 0 0 1).
fn project(p: &[[f64; 4]; 3], x: DVec3) -> (DVec2, f64) {
    let row = |r: &[f64; 4]| r[0] * x.x + r[1] * x.y + r[2] * x.z + r[3];
    let w = row(&p[2]);
    (DVec2::new(row(&p[0]) / w, row(&p[1]) / w), w)
}

#[test]
fn drawn_screws_obey_the_projection_laws_and_navigated_ones_the_tracking_experiment() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("study.toml");
    std::fs::write(&cfg, CONFIG).unwrap();
    let out = dir.path().join("out");
    let (ok, err) = study(&cfg, &out);
    assert!(ok, "{err}");
    let t = StudyTables::load(&out).unwrap();
    // 2 screws × 2 views × (2 Δf + 1 piercing + 1 joint + 2 physical).
    assert_eq!(t.screws.len(), 2 * 2 * 6);
    assert_eq!(t.screw_navigation.len(), 2 * 6);
    for view in ["ap", "lat"] {
        let path = out.join(format!("references/screws/L1_{view}_spectral.tiff"));
        let side = Sidecar::read(&sidecar_path(&path)).unwrap();
        let p = side.p.expect("P in the sidecar");
        let k = side.k;
        let (f, c) = (k[0][0], DVec2::new(k[0][2], k[1][2]));
        let screws: Vec<(String, DVec3, DVec3)> = side.details["planned_screws"]
            .as_array()
            .unwrap()
            .iter()
            .map(|s| {
                let v = |key: &str| {
                    DVec3::from(serde_json::from_value::<[f64; 3]>(s[key].clone()).unwrap())
                };
                (
                    s["name"].as_str().unwrap().to_string(),
                    v("entry"),
                    v("tip"),
                )
            })
            .collect();
        assert_eq!(screws.len(), 2);
        for r in t.screws.iter().filter(|r| r.view == view) {
            let (_, entry, tip) = screws.iter().find(|s| s.0 == r.screw).unwrap();
            let (u_tip, z_tip) = project(&p, *tip);
            let (u_entry, _) = project(&p, *entry);
            let expected = match r.family {
                // u' − c = (f + Δf)/f · (u − c).
                Family::Focal => Some((r.df_px / f).abs() * (u_tip - c).length()),
                // u' = u + (p, p).
                Family::Piercing => Some(r.piercing_px * 2f64.sqrt()),
                Family::Joint => {
                    Some(((u_tip - c) * (r.df_px / f) + DVec2::splat(r.piercing_px)).length())
                }
                _ => None,
            };
            if let Some(e) = expected {
                assert!(
                    (r.tip_px - e).abs() <= 1e-7 * (1.0 + e),
                    "{view} {} {}: tip {} px, law {e}",
                    r.screw,
                    r.perturbation,
                    r.tip_px
                );
                assert!(
                    r.axis_deg < 1e-9,
                    "{} turned by {}",
                    r.perturbation,
                    r.axis_deg
                );
            }
            assert!(
                (r.tip_mm - r.tip_px * z_tip / f).abs() <= 1e-9 * (1.0 + r.tip_mm),
                "{}: {} mm from {} px at depth {z_tip}",
                r.perturbation,
                r.tip_mm,
                r.tip_px
            );
            assert!((r.projected_length_px - (u_tip - u_entry).length()).abs() < 1e-7);
            assert!((r.length_mm - (*tip - *entry).length()).abs() < 1e-9);
        }
        // A detector rolled 2° about the central ray turns every drawn axis by 2° (seen end-on the
        // angle is undefined).
        for r in t
            .screws
            .iter()
            .filter(|r| r.view == view && r.perturbation == "det_roll_deg=2")
        {
            if r.projected_length_px > 20.0 {
                assert!(
                    (r.axis_deg - 2.0).abs() < 0.05,
                    "{view} roll: {}",
                    r.axis_deg
                );
            }
        }
    }
    // Navigation against the tracking experiment's absolute pedicle error of the same registration.
    let mut compared = 0;
    for tr in &t.tracking {
        let worst = t
            .screw_navigation
            .iter()
            .filter(|n| n.target == tr.target && n.perturbation == tr.perturbation)
            .map(|n| n.tip_mm.max(n.entry_mm))
            .fold(f64::NEG_INFINITY, f64::max);
        assert!(
            (worst - tr.pedicle_abs_err_max_mm).abs() <= 1e-5 * (1.0 + worst),
            "{}: navigated screws {worst} mm, tracking's pedicle points {} mm",
            tr.perturbation,
            tr.pedicle_abs_err_max_mm
        );
        compared += 1;
    }
    assert_eq!(compared, 4, "Δf 100, 500 and the two physical cells");
    for n in &t.screw_navigation {
        assert!(n.converged && n.axis_deg >= 0.0 && n.residual_px >= 0.0);
    }
    let report = crate::common::read_report(&out);
    assert!(report.contains("## Pedicle screws drawn and navigated with the wrong geometry"));
    assert!(report.contains("figures/screws_L1.png"));
    let png = image::open(out.join("figures/screws_L1.png")).unwrap();
    assert!(png.width() >= 900 && png.height() >= 900);
}
