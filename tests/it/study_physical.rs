//! The study's physical family (`[perturbations.physical]`): its own table, analytic checks of the
//! assumed cameras and of the landmark shift of a detector moved in its plane, the report's section,
//! and a geometry without a known SDD refused before any work.

use std::path::Path;

use spinedrr::study::StudyTables;
use spinedrr::study::schema::Family;

use crate::common::Spinedrr;

const CONFIG: &str = "experiments = [\"projection\", \"tracking\"]\n\
    [anatomy]\nlevels = [\"L1\"]\nsegment = false\nvoxel_mm = 1.0\nmarker_radius_mm = 4.0\n\
    [perturbations]\ndf_px = [100.0]\npiercing_px = [0.0]\nskew_px = []\npixel_scale = []\n\
    [perturbations.physical]\nsrc_dx_mm = [4.0]\ndet_dx_mm = [3.0]\ndet_dz_mm = [20.0]\n\
    det_roll_deg = [1.5]\n";

fn study(dir: &Path, config: &str) -> (bool, String) {
    let cfg = dir.join("study.toml");
    std::fs::write(&cfg, config).unwrap();
    Spinedrr::new()
        .args(["study", "--config"])
        .arg(&cfg)
        .arg("--out")
        .arg(dir.join("out"))
        .outcome()
}

#[test]
fn physical_cells_have_their_own_table_analytic_cameras_and_a_report_section() {
    let dir = tempfile::tempdir().unwrap();
    let (ok, err) = study(dir.path(), CONFIG);
    assert!(ok, "{err}");
    let out = dir.path().join("out");
    let t = StudyTables::load(&out).unwrap();
    // The intrinsic tables hold no physical row; the physical table one per (view, cell).
    assert!(t.projection.iter().all(|r| r.family != Family::Physical));
    assert_eq!(t.physical.len(), 2 * 4);
    // The default detector: SDD 1350 mm, 0.3 mm pixels, fx 4500 px, piercing point 511.5.
    let (s, p, f, c) = (1350.0, 0.3, 4500.0, 511.5);
    for r in &t.physical {
        let at = |x: f64, y: f64| (x - y).abs() < 1e-6;
        match r.key.as_str() {
            // The focal spot 4 mm along u: the camera moves 4 mm and the foot of its perpendicular
            // 4/p px along u.
            "src_dx_mm" => {
                assert!(at(r.camera_moved_mm, 4.0) && at(r.cx_px, c + 4.0 / p) && at(r.fx_px, f))
            }
            // The detector 3 mm along u: every landmark slides by exactly 3/p px.
            "det_dx_mm" => {
                assert!(at(r.cx_px, c - 3.0 / p) && at(r.camera_moved_mm, 0.0));
                assert!(
                    at(r.landmark_shift_mean_px, 3.0 / p) && at(r.landmark_shift_max_px, 3.0 / p),
                    "{r:?}"
                );
                assert!(at(r.landmark_shift_mean_mm, 3.0), "{r:?}");
                assert!(r.landmarks > 0);
            }
            // 20 mm farther from the source: focal lengths × (S + 20)/S, nothing else.
            "det_dz_mm" => assert!(at(r.fx_px, f * (s + 20.0) / s) && at(r.cx_px, c)),
            // Rolled 1.5°: K as it was, the camera turned 1.5°.
            "det_roll_deg" => assert!(at(r.fx_px, f) && at(r.camera_turned_deg, 1.5)),
            other => panic!("unexpected key {other}"),
        }
        assert!(r.dice < 1.0 && r.dice > 0.5, "{r:?}");
    }
    let report = crate::common::read_report(&out);
    assert!(report.contains("## Physical geometry errors"));
    assert!(
        report.contains(
            "| det_dx_mm = 3 | AP | fx 0, fy 0, cx −10, cy 0 | 0 / 0 | 10 px = 3 mm (10 px)"
        ),
        "{report}"
    );
    assert!(out.join("tables/physical.csv").is_file());

    // Tracking (the default [tracking]): L1 × 3 methods × (Δf 100 and 500 + the 4 physical cells), one
    // noise-free row each.
    assert_eq!(t.tracking.len(), 3 * 6);
    for r in &t.tracking {
        assert!(r.converged, "{r:?}");
        // A detector rolled about its central ray turns that view's camera about its own centre: for
        // one view, a rigid motion of the whole C-arm, which cancels from the relative pose.
        if r.perturbation == "det_roll_deg=1.5" && r.method.views().len() == 1 {
            assert!(r.rel_tre_mm < 1e-6 && r.abs_tre_mm > 0.05, "{r:?}");
            assert!(r.pedicle_rel_err_max_mm < 1e-6 && r.pedicle_abs_err_max_mm > 0.05);
        }
        // The motion: 10 mm and 5° (the default [tracking]).
        assert!((r.motion_mm - 10.0).abs() < 1e-12 && (r.motion_deg - 5.0).abs() < 1e-9);
    }
    assert!(report.contains("## Relative (tracking) error"));
    // The pedicle sentence counts the rows it says it counts (all converged: checked above).
    let over = |f: fn(&spinedrr::study::schema::TrackingRow) -> f64, mm: f64| {
        t.tracking.iter().filter(|r| f(r) > mm).count()
    };
    let sentence = format!(
        "of the {} converged single-level cells above (targets × methods × assumed geometries), {} put a \
         pedicle target more than 1 mm off and {} more than 2 mm in the absolute pose; in the relative \
         pose, {} and {}.",
        t.tracking.len(),
        over(|r| r.pedicle_abs_err_max_mm, 1.0),
        over(|r| r.pedicle_abs_err_max_mm, 2.0),
        over(|r| r.pedicle_rel_err_max_mm, 1.0),
        over(|r| r.pedicle_rel_err_max_mm, 2.0)
    );
    assert!(report.contains(&sentence), "{sentence}");
}

#[test]
fn a_physical_grid_needs_a_geometry_with_a_known_sdd() {
    let dir = tempfile::tempdir().unwrap();
    let geometry = dir.path().join("k.toml");
    std::fs::write(
        &geometry,
        "[detector]\nwidth = 256\nheight = 256\n\
         K = [[1125.0, 0.0, 127.5], [0.0, 1125.0, 127.5], [0.0, 0.0, 1.0]]\n\
         [[view]]\nname = \"ap\"\nsource_mm = [0.0, -1000.0, 0.0]\ntarget_mm = [0.0, 0.0, 0.0]\n\
         [[view]]\nname = \"lat\"\nsource_mm = [-900.0, -25.0, 20.0]\ntarget_mm = [0.0, -25.0, 20.0]\n",
    )
    .unwrap();
    // The experiments line first (a top-level key), then the geometry table, then the rest.
    let (experiments, rest) = CONFIG.split_once('\n').unwrap();
    let config = format!(
        "{experiments}\n[geometry]\nfile = \"{}\"\n{rest}",
        geometry.display()
    );
    let started = std::time::Instant::now();
    let (ok, err) = study(dir.path(), &config);
    assert!(
        !ok,
        "a physical grid on an explicit-K geometry was accepted"
    );
    assert!(
        err.contains("perturbations.physical") && err.contains("source-to-detector distance"),
        "{err}"
    );
    assert!(!dir.path().join("out/tables").exists());
    assert!(started.elapsed().as_secs() < 30);

    // The same geometry without physical cells runs; its literature section does not advise adding
    // one (which this geometry refuses) but says what it needs.
    let config = format!(
        "experiments = [\"tracking\"]\n[geometry]\nfile = \"{}\"\n\
         [anatomy]\nlevels = [\"L1\"]\nsegment = false\nvoxel_mm = 1.2\n\
         [perturbations]\ndf_px = [100.0]\npiercing_px = [0.0]\nskew_px = []\npixel_scale = []\n\
         [tracking]\ndf_px = [500.0]\n",
        geometry.display()
    );
    std::fs::remove_dir_all(dir.path().join("out")).ok();
    let (ok, err) = study(dir.path(), &config);
    assert!(ok, "{err}");
    let report = crate::common::read_report(&dir.path().join("out"));
    let section = &report[report
        .find("## The literature beside ours")
        .expect("literature")..];
    assert!(
        section.contains(
            "add its Δf to `[tracking] df_px` (a physical error needs a geometry that gives"
        ) && !section.contains("[perturbations.physical]"),
        "{section}"
    );
}

#[test]
fn the_literature_section_prints_this_runs_tracking_cells() {
    let dir = tempfile::tempdir().unwrap();
    let config = "experiments = [\"tracking\"]\n\
        [anatomy]\nlevels = [\"L1\"]\nsegment = false\nvoxel_mm = 1.0\nmarker_radius_mm = 4.0\n\
        [perturbations.physical]\nsrc_dx_mm = [4.0]\nsrc_dz_mm = [2.0, 50.0]\ndet_dx_mm = [4.0]\n\
        det_roll_deg = [2.0]\n\
        [tracking]\ndf_px = [500.0]\n";
    let (ok, err) = study(dir.path(), config);
    assert!(ok, "{err}");
    let out = dir.path().join("out");
    let t = StudyTables::load(&out).unwrap();
    let report = crate::common::read_report(&out);
    let section = report
        .split("## The literature beside ours")
        .nth(1)
        .expect("the literature section")
        .split("\n## ")
        .next()
        .unwrap();
    // Every row names its cell (method, perturbation, column) and prints that cell of tracking.csv.
    let mut rows = 0;
    for line in section
        .lines()
        .filter(|l| l.contains("`abs_") || l.contains("`rel_"))
    {
        let cols: Vec<&str> = line.split('|').map(str::trim).collect();
        let cell: Vec<&str> = cols[3].split(", ").collect();
        let (method, pert, column) = (cell[0], cell[1], cell[2].trim_matches('`'));
        let r = t
            .tracking
            .iter()
            .find(|r| r.target == "L1" && r.method.name() == method && r.perturbation == pert)
            .unwrap_or_else(|| panic!("no tracking row for {line}"));
        let v = match column {
            "abs_tre_mm" => r.abs_tre_mm,
            "abs_trans_err_mm" => r.abs_trans_err_mm,
            "abs_rot_err_deg" => r.abs_rot_err_deg,
            "rel_trans_err_mm" => r.rel_trans_err_mm,
            "rel_rot_err_deg" => r.rel_rot_err_deg,
            other => panic!("column {other}"),
        };
        let printed: f64 = cols[4]
            .trim_end_matches(" mm")
            .trim_end_matches('°')
            .parse()
            .unwrap_or_else(|_| panic!("not a number: {line}"));
        assert!((printed - v).abs() <= 5e-4, "{line}: tracking.csv has {v}");
        rows += 1;
    }
    assert_eq!(rows, 7, "{section}");
    assert!(!section.contains("not in this run"));
    // No experiment that steps through `[perturbations]` ran and none wrote a reference DRR: the Setup
    // states neither the grid nor an empty table of where the targets lie, but says why.
    assert!(t.projection.is_empty() && t.landmarks.is_empty() && t.screws.is_empty());
    assert!(
        !out.join("references")
            .read_dir()
            .is_ok_and(|mut d| d.next().is_some())
    );
    let setup = &report[report.find("## Setup").unwrap()..];
    let setup = &setup[..setup.find("\n## ").unwrap()];
    for absent in ["perturbations of K", "| target | view | centroid"] {
        assert!(!setup.contains(absent), "{absent}: {setup}");
    }
    assert!(setup.contains("this run wrote none"), "{setup}");
}

/// Landmark registration under the physical cells (`registration_physical.csv`): a detector rolled
/// about the central ray turns the one-view camera rigidly about that ray, so a noise-free one-view
/// registration lands on the true pose turned by exactly the roll about the view's central ray — its
/// translation error is the world origin's distance from that ray × 2 sin(θ/2), computed here from the
/// default geometry alone. The intrinsic table holds no physical row, and the report prints the rows.
#[test]
fn a_detector_roll_registers_one_view_to_the_pose_turned_about_its_central_ray() {
    use glam::DVec3;
    use spinedrr::geometry::{CArm, DEFAULT_GEOMETRY_TOML};

    let dir = tempfile::tempdir().unwrap();
    let config = "experiments = [\"registration\"]\n\
        [anatomy]\nlevels = [\"L1\"]\nsegment = false\nvoxel_mm = 1.0\nmarker_radius_mm = 4.0\n\
        [perturbations]\ndf_px = [100.0]\npiercing_px = [0.0]\nskew_px = []\npixel_scale = []\n\
        [perturbations.physical]\ndet_roll_deg = [1.5]\ndet_dx_mm = [3.0]\n\
        [registration]\nmethods = [\"direct-ap\", \"direct-lat\", \"direct-ap+lat\"]\n\
        df_px = [0.0]\npiercing_px = [0.0]\ntrials = 2\ntrials_per_unit = 2\nnoise_px = 0.0\n";
    let (ok, err) = study(dir.path(), config);
    assert!(ok, "{err}");
    let out = dir.path().join("out");
    let t = StudyTables::load(&out).unwrap();
    assert_eq!(t.registration.len(), 3 * 2);
    assert_eq!(t.registration_physical.len(), 3 * 2 * 2);
    let carm = CArm::from_toml_str(DEFAULT_GEOMETRY_TOML, "default").unwrap();
    let theta = 1.5_f64.to_radians();
    for r in &t.registration_physical {
        assert!(r.converged, "{r:?}");
        // Every row has its twin trial (noise-free: the same answer from another start).
        let twin = t
            .registration_physical
            .iter()
            .find(|o| o.method == r.method && o.key == r.key && o.trial != r.trial)
            .unwrap();
        assert!((twin.tre_mm - r.tre_mm).abs() < 1e-6, "{r:?} {twin:?}");
        assert!(r.pedicle_err_max_mm.is_finite() && r.tre_mm.is_finite());
        let view = match r.method.name() {
            "direct-ap" => "ap",
            "direct-lat" => "lat",
            _ => continue,
        };
        if r.key != "det_roll_deg" {
            continue;
        }
        let v = carm.view(view).unwrap();
        let s = v.source_world();
        let d = v
            .world_to_camera
            .inverse()
            .apply_vector(DVec3::Z)
            .normalize();
        let off_axis = (s - s.dot(d) * d).length();
        let expected = 2.0 * off_axis * (theta / 2.0).sin();
        assert!((r.rot_err_deg - 1.5).abs() < 1e-6, "{r:?}");
        assert!(
            (r.trans_err_mm - expected).abs() < 1e-5,
            "{view}: translation error {} against {expected} (origin {off_axis} mm off the ray)",
            r.trans_err_mm
        );
    }
    // The LAT ray passes 32 mm from the origin, the AP ray through it: the check is not vacuous.
    let lat = t
        .registration_physical
        .iter()
        .find(|r| r.method.name() == "direct-lat" && r.key == "det_roll_deg")
        .unwrap();
    assert!(lat.trans_err_mm > 0.5, "{lat:?}");
    let report = crate::common::read_report(&out);
    assert!(
        report.contains("### Landmark registration of L1 under the physical errors"),
        "{report}"
    );
    assert!(report.contains("| det_roll_deg = 1.5 | direct-lat | 1.500 (all 2 agree) |"));
    assert!(out.join("tables/registration_physical.csv").is_file());
    // Without the projection and landmark experiments (no projection.csv, no landmarks.csv) the report
    // does not describe their measurements.
    assert!(t.projection.is_empty() && t.landmarks.is_empty());
    assert!(!out.join("tables/projection.csv").exists());
    let how = &report[report.find("## How each measurement is made").unwrap()..];
    let how = &how[..how.find("\n## ").unwrap()];
    assert!(how.contains("Thickness DRRs"), "{how}");
    for absent in ["marker sphere", "projection.csv", "Landmark overlays"] {
        assert!(!how.contains(absent), "{absent}: {how}");
    }
}
