//! One plate calibration (5 views × 100 BBs, Zhang's method through OpenCV `calibrateCamera`; target
//! ≤ 5 ms) and one helix calibration (DLT + RQ + LM of K with skew and two poses; target ≤ 1 ms), and a
//! whole Monte-Carlo trial of each (extrinsics and held-out triangulation included) beside them.

use criterion::Criterion;
use spinedrr::calibration::acquisition::with_noise;
use spinedrr::calibration::{
    CalibrationPhantom, CalibrationSetup, SetupOptions, calibrate, run_trial,
};
use spinedrr::geometry::CArm;

/// This module's benchmarks (see `main.rs`).
pub fn run(c: &mut Criterion) {
    let full = CArm::default_paper();
    let ap_only = CArm {
        views: vec![full.view("ap").unwrap().clone()],
    };
    let plate = CalibrationPhantom::default_plate();
    let helix = CalibrationPhantom::default_helix();
    // 5 plate poses in one view: 5 images × 100 BBs.
    let plate_setup = CalibrationSetup::new(&ap_only, &plate, SetupOptions::default()).unwrap();
    assert_eq!(plate_setup.ideal.len(), 5);
    let helix_setup = CalibrationSetup::new(&full, &helix, SetupOptions::default()).unwrap();
    let (w, h) = (1024, 1024);
    let plate_images = with_noise(&plate_setup.ideal, 0.3, 1);
    let helix_images = with_noise(&helix_setup.ideal, 0.3, 1);
    let (pb, hb) = (plate.points(), helix.points());
    let mut g = c.benchmark_group("calibration");
    g.sample_size(30);
    g.bench_function("plate calibration, 5 views x 100 BBs (OpenCV Zhang)", |b| {
        b.iter(|| calibrate(plate.kind, &plate_images, &pb, w, h).unwrap())
    });
    g.bench_function("helix calibration, 2 views x 32 BBs (DLT + RQ + LM)", |b| {
        b.iter(|| calibrate(helix.kind, &helix_images, &hb, w, h).unwrap())
    });
    let plate_two = CalibrationSetup::new(&full, &plate, SetupOptions::default()).unwrap();
    g.bench_function("plate Monte-Carlo trial, AP + LAT (10 images)", |b| {
        b.iter(|| run_trial(&plate_two, 0.3, 1).unwrap())
    });
    g.bench_function("helix Monte-Carlo trial, AP + LAT", |b| {
        b.iter(|| run_trial(&helix_setup, 0.3, 1).unwrap())
    });
    g.finish();
}
