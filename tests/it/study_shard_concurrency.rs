//! Two shards started at the same instant on one output folder, both forced to prepare the same shared
//! inputs: the cohort manifest (neither finds one) and the reference render of the one (target, view)
//! both have units of. Both must finish; every unit file must parse with the config's fingerprint; the
//! shared inputs must be byte-identical to an unsharded run's; no temporary may be left; and the
//! assembled tables must equal the unsharded run's.

use std::path::{Path, PathBuf};

use spinedrr::study::StudyConfig;
use spinedrr::study::identity::UnitIdentity;
use spinedrr::study::runner::fingerprint;
use spinedrr::study::shard::{Shard, units_of};
use spinedrr::study::units::{Unit, UnitFile, enumerate_units};

use crate::common::Spinedrr;

/// A one-case TotalSegmentator-layout dataset (`ds/case1/ct.nii.gz`, `segmentations.nii.gz`) made by
/// `spinedrr phantom --ct`, and a study of its L1 in the AP view only.
fn inputs(dir: &Path) -> PathBuf {
    let case = dir.join("ds").join("case1");
    std::fs::create_dir_all(&case).unwrap();
    let (ok, err) = Spinedrr::new()
        .args([
            "phantom",
            "--levels",
            "L1",
            "--no-discs",
            "--voxel-mm",
            "1.5",
        ])
        .args(["--ct-voxel-mm", "1.5", "--ct"])
        .arg(case.join("ct.nii.gz"))
        .arg("--labels-out")
        .arg(case.join("segmentations.nii.gz"))
        .arg("--out")
        .arg(dir.join("mesh"))
        .outcome();
    assert!(ok, "{err}");
    let config = dir.join("study.toml");
    std::fs::write(
        &config,
        r#"experiments = ["projection", "landmarks"]
[anatomy]
levels = []
[[anatomy.dataset]]
name = "syn"
folder = "ds"
layout = "totalseg"
levels = ["L1"]
[geometry]
binning = 4
views = ["ap"]
[perturbations]
df_px = [100, 300, 500]
piercing_px = [0, 20, 50]
"#,
    )
    .unwrap();
    config
}

/// Every file under `dir` (relative path, bytes), sorted.
fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file())
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

fn no_temporaries(dir: &Path) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            no_temporaries(&p);
        } else {
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            assert!(!name.contains(".tmp-"), "temporary left: {}", p.display());
        }
    }
}

#[test]
fn two_shards_at_once_share_inputs_without_tearing() {
    let dir = tempfile::tempdir().unwrap();
    let config = inputs(dir.path());
    let (whole, shared) = (dir.path().join("whole"), dir.path().join("shared"));
    let (ok, err) = Spinedrr::new()
        .args(["study", "--threads", "1", "--config"])
        .arg(&config)
        .arg("--out")
        .arg(&whole)
        .outcome();
    assert!(ok, "{err}");

    // Precondition: both shards have units of the one (target, view), so both render its reference.
    let cfg = StudyConfig::from_file(&config).unwrap();
    let expanded = spinedrr::study::cohort::resolve(&cfg, &dir.path().join("probe")).unwrap();
    let units = enumerate_units(&expanded).unwrap();
    for i in 0..2 {
        let mine = units_of(&expanded, &units, Shard::new(i, 2).unwrap());
        assert!(
            mine.iter().any(|u| matches!(u, Unit::Projection { .. })),
            "shard {i} has no projection unit"
        );
    }

    let mut children: Vec<std::process::Child> = (0..2)
        .map(|i| {
            let mut c = Spinedrr::new()
                .args(["study", "--threads", "1", "--config"])
                .arg(&config)
                .arg("--out")
                .arg(&shared)
                .args(["--shard", &format!("{i}/2")])
                .command();
            c.stderr(std::process::Stdio::piped());
            c.spawn().expect("starting a shard")
        })
        .collect();
    for (i, c) in children.drain(..).enumerate() {
        let out = c.wait_with_output().unwrap();
        assert!(
            out.status.success(),
            "shard {i}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    no_temporaries(&shared);
    // Each unit file carries its unit's identity: the config's fingerprint with the digests of the CT
    // files the unit reads (so never the bare config fingerprint here, every target being a CT's).
    let fp = fingerprint(&expanded).unwrap();
    let ident = UnitIdentity::new(&expanded, &fp, &shared).unwrap();
    let identity: std::collections::HashMap<String, String> =
        units.iter().map(|u| (u.id(), ident.of(u))).collect();
    let unit_files = files(&shared.join("units"));
    assert_eq!(unit_files.len(), units.len());
    for (name, bytes) in &unit_files {
        let f: UnitFile = serde_json::from_slice(bytes)
            .unwrap_or_else(|e| panic!("unit file {name} does not parse: {e}"));
        assert_eq!(Some(&f.fingerprint), identity.get(&f.id), "{name}");
        assert_ne!(f.fingerprint, fp, "{name}");
        assert_eq!(format!("{}.json", f.id), *name);
    }
    assert_eq!(
        files(&shared.join("cohort")),
        files(&whole.join("cohort")),
        "the cohort manifest differs from the unsharded run's"
    );
    let refs = files(&shared.join("references"));
    assert!(
        refs.iter().any(|(n, _)| n.ends_with("_ap.tiff")),
        "{:?}",
        refs.iter().map(|r| &r.0).collect::<Vec<_>>()
    );
    assert!(
        refs == files(&whole.join("references")),
        "the reference renders differ from the unsharded run's"
    );
    let (ok, err) = Spinedrr::new()
        .args(["study", "--threads", "1", "--assemble", "--config"])
        .arg(&config)
        .arg("--out")
        .arg(&shared)
        .outcome();
    assert!(ok, "{err}");
    let csv = |d: &Path| {
        files(&d.join("tables"))
            .into_iter()
            .filter(|(n, _)| n.ends_with(".csv"))
            .collect::<Vec<_>>()
    };
    assert!(csv(&shared) == csv(&whole), "assembled tables differ");
}
