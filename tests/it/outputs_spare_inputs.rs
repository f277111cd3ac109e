//! No command replaces one of its own inputs, and no output replaces a file of another kind: the real
//! binary, one case per command (`mesh`, `register`, `compare`, `render`), each refused naming the output
//! and the input, with every file left byte for byte as it was.

use std::path::{Path, PathBuf};

use crate::common::run;

fn s(p: &Path) -> String {
    p.display().to_string()
}

/// Every file under `dir` with its bytes.
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut v: Vec<(PathBuf, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file())
        .map(|p| {
            let b = std::fs::read(&p).unwrap();
            (p, b)
        })
        .collect();
    v.sort();
    v
}

/// Runs `args`, expects a refusal without a panic naming every one of `needles`, and that `dir` is
/// unchanged.
fn refused_untouched(dir: &Path, args: &[String], needles: &[&str]) {
    let before = snapshot(dir);
    let (ok, err) = run(args);
    assert!(!ok, "accepted: {args:?}");
    assert!(!err.contains("panicked"), "{err}");
    for n in needles {
        assert!(err.contains(n), "stderr lacks {n:?}: {err}");
    }
    assert_eq!(snapshot(dir), before, "{args:?} changed the folder");
}

fn args(a: &[&str]) -> Vec<String> {
    a.iter().map(|x| x.to_string()).collect()
}

/// A phantom level's mesh, landmarks, CT and labels in `dir` (`spinedrr phantom`).
fn phantom(dir: &Path) {
    let (ok, err) = run(&args(&[
        "phantom",
        "--levels",
        "L3",
        "--no-discs",
        "--voxel-mm",
        "1.5",
        "--ct-voxel-mm",
        "2",
        "--ct",
        &s(&dir.join("ct.nii.gz")),
        "--labels-out",
        &s(&dir.join("seg.nii.gz")),
        "--out",
        &s(dir),
    ]));
    assert!(ok, "{err}");
}

#[test]
fn mesh_and_register_never_write_over_their_input() {
    let d = tempfile::tempdir().unwrap();
    phantom(d.path());
    let seg = s(&d.path().join("seg.nii.gz"));
    let stl = s(&d.path().join("L3_cortical.stl"));
    refused_untouched(
        d.path(),
        &args(&[
            "mesh",
            "--seg",
            &seg,
            "--label",
            "L3",
            "--landmarks",
            "auto",
            "--landmarks-out",
            &seg,
            "--out",
            &stl,
        ]),
        &["--seg", "seg.nii.gz", "replace an input"],
    );
    // Label 0 is the background, not a structure to mesh.
    refused_untouched(
        d.path(),
        &args(&["mesh", "--seg", &seg, "--label", "0", "--out", &stl]),
        &["--label \"0\"", "background"],
    );
    let problem = d.path().join("problem.json");
    std::fs::write(&problem, "{}").unwrap();
    refused_untouched(
        d.path(),
        &args(&["register", "--problem", &s(&problem), "--out", &s(&problem)]),
        &["--problem", "replace an input"],
    );
}

#[test]
fn compare_and_render_never_replace_an_input_or_another_kind_of_file() {
    let d = tempfile::tempdir().unwrap();
    phantom(d.path());
    let lm = d.path().join("landmarks.json");
    assert!(lm.exists());
    let cortical = format!("{}:0.05", s(&d.path().join("L3_cortical.stl")));
    // A render whose sidecar (landmarks.json) would replace the landmarks file.
    refused_untouched(
        d.path(),
        &args(&[
            "render",
            "--mesh",
            &cortical,
            "--view",
            "ap",
            "--out",
            &s(&d.path().join("landmarks.tiff")),
        ]),
        &[
            "landmarks.json",
            "a landmarks file",
            "not a spinedrr sidecar",
        ],
    );
    // Two renders, then a comparison whose output set lands on the reference image.
    let sub = d.path().join("cmp");
    std::fs::create_dir(&sub).unwrap();
    for (name, spec) in [("absdiff", "none"), ("pert", "df=300")] {
        let (ok, err) = run(&args(&[
            "render",
            "--mesh",
            &cortical,
            "--view",
            "ap",
            "--perturb",
            spec,
            "--out",
            &s(&sub.join(format!("{name}.tiff"))),
        ]));
        assert!(ok, "{err}");
    }
    refused_untouched(
        &sub,
        &args(&[
            "compare",
            "--reference",
            &s(&sub.join("absdiff.tiff")),
            "--perturbed",
            &s(&sub.join("pert.tiff")),
            "--out",
            &s(&sub),
        ]),
        &["--out", "--reference", "replace an input"],
    );
    // The same comparison into a folder of its own works.
    let (ok, err) = run(&args(&[
        "compare",
        "--reference",
        &s(&sub.join("absdiff.tiff")),
        "--perturbed",
        &s(&sub.join("pert.tiff")),
        "--landmarks",
        &s(&lm),
        "--out",
        &s(&d.path().join("metrics")),
    ]));
    assert!(ok, "{err}");
    let metrics: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(d.path().join("metrics/metrics.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(metrics["tool"], "spinedrr");
}
