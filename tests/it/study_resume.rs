//! Determinism and resumption of `spinedrr study`: an interrupted run continued gives the same bytes as
//! an uninterrupted one, 1 and 2 threads give the same bytes, and a bad config fails before any work.

use spinedrr::study::config::{Experiment, RegistrationMethod};
use std::path::Path;
use std::process::Output;

use crate::common::{Spinedrr, csv_tables as tables};

/// Runs `spinedrr ARGS --out OUT`.
fn spinedrr(args: &[&str], out: &Path) -> Output {
    Spinedrr::new().args(args).arg("--out").arg(out).output()
}

#[test]
fn interrupted_and_resumed_run_equals_uninterrupted_runs_at_any_thread_count() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (a, b, c) = (
        dir.path().join("a"),
        dir.path().join("b"),
        dir.path().join("c"),
    );
    let first = spinedrr(
        &["study", "--quick", "--threads", "2", "--max-units", "7"],
        &a,
    );
    assert!(
        first.status.success(),
        "{}",
        String::from_utf8_lossy(&first.stderr)
    );
    assert!(
        tables(&a).is_empty(),
        "an interrupted run must not write tables that look complete"
    );
    assert_eq!(std::fs::read_dir(a.join("units")).unwrap().count(), 7);
    assert!(
        spinedrr(&["study", "--quick", "--threads", "2"], &a)
            .status
            .success()
    );
    assert!(
        spinedrr(&["study", "--quick", "--threads", "1"], &b)
            .status
            .success()
    );
    assert!(
        spinedrr(&["study", "--quick", "--threads", "2"], &c)
            .status
            .success()
    );
    let (ta, tb, tc) = (tables(&a), tables(&b), tables(&c));
    // projection, landmarks, registration + summary + physical, intensity_registration + bins + summary,
    // physical, tracking, screws + screw_navigation.
    assert_eq!(ta.len(), 13);
    assert!(ta == tb, "resumed run differs from the 1-thread run");
    assert!(tb == tc, "1 and 2 threads differ");
    // Everything but the timing section (a measurement of the invocation, not of the data).
    let report = |d: &Path| {
        let md = crate::common::read_report(d);
        let cut = md.find("## Where the time goes").expect("timing section");
        // The provenance line holds this invocation's date and thread count.
        let p = spinedrr::study::report::PROVENANCE;
        assert_eq!(md.matches(p).count(), 1);
        md[..cut]
            .lines()
            .filter(|l| !l.starts_with(p))
            .collect::<Vec<_>>()
            .join("\n")
    };
    assert_eq!(report(&a), report(&b));
}

fn bad_config(text: &str, key: &str) {
    let dir = tempfile::tempdir().expect("temp dir");
    let cfg = dir.path().join("study.toml");
    std::fs::write(&cfg, text).unwrap();
    let out = dir.path().join("out");
    let o = spinedrr(&["study", "--config", cfg.to_str().unwrap()], &out);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "accepted: {text}");
    assert!(
        err.contains(key),
        "error for {text:?} does not name '{key}': {err}"
    );
    assert!(
        !out.exists(),
        "work started before the config was validated"
    );
}

#[test]
fn bad_configs_fail_before_work_and_name_the_key() {
    bad_config("sede = 3\n", "sede");
    bad_config("[anatomy]\nlevels = [\"L9\"]\n", "anatomy.levels");
    bad_config(
        "[registration]\nmethods = [\"magic\"]\n",
        "registration.methods",
    );
    bad_config("[registration]\ntrials = 0\n", "registration.trials");
    bad_config("[geometry]\nviews = [\"oblique\"]\n", "geometry.views");
    bad_config("[anatomy]\nvoxel_mm = -1.0\n", "anatomy.voxel_mm");
    bad_config("experiments = [\"everything\"]\n", "experiments");
    // The physical family and the tracking experiment.
    for (text, key) in [
        (
            "[perturbations.physical]\ndet_dz_mm = [0.0]\n",
            "perturbations.physical.det_dz_mm",
        ),
        (
            "[perturbations.physical]\ndet_dz_mm = [5.0, 5.0]\n",
            "perturbations.physical.det_dz_mm",
        ),
        (
            "[perturbations.physical]\nsrc_dx_mm = [900.0]\n",
            "perturbations.physical.src_dx_mm",
        ),
        ("[perturbations.physical]\ndet_dz = [5.0]\n", "det_dz"),
        ("[tracking]\nmethods = []\n", "tracking.methods"),
        ("[tracking]\ndf_px = [-5000.0]\n", "tracking.df_px"),
        (
            "[tracking]\ntranslation_mm = [1e9, 0.0, 0.0]\n",
            "tracking.translation_mm",
        ),
        (
            "[tracking]\nrotation_deg = [0.0, 0.0, 0.0]\ntranslation_mm = [0.0, 0.0, 0.0]\n",
            "the motion is zero",
        ),
        (
            "[tracking]\nmethods = [\"direct-ap\", \"direct-ap\"]\n",
            "tracking.methods",
        ),
    ] {
        bad_config(text, key);
    }
}

#[test]
fn example_config_parses() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/study.toml");
    let cfg = spinedrr::study::StudyConfig::from_file(&path).expect("examples/study.toml");
    assert_eq!(cfg, spinedrr::study::StudyConfig::default());
}

#[test]
fn trial_chunking_does_not_change_registration_results() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut cfg = spinedrr::study::StudyConfig::quick();
    cfg.experiments = vec![Experiment::Registration];
    cfg.registration.methods = vec![RegistrationMethod::DirectApLat, RegistrationMethod::Kabsch];
    let run = |per_unit: usize, name: &str| {
        let mut c = cfg.clone();
        c.registration.trials_per_unit = per_unit;
        let path = dir.path().join(format!("{name}.toml"));
        std::fs::write(&path, toml::to_string(&c).unwrap()).unwrap();
        let out = dir.path().join(name);
        let o = spinedrr(&["study", "--config", path.to_str().unwrap()], &out);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read(out.join("tables/registration.csv")).unwrap()
    };
    let (one, three) = (run(1, "one"), run(3, "three"));
    assert_eq!(
        one, three,
        "trial results depend on how trials are chunked into units"
    );
}
