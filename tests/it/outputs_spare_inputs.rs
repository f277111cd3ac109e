//! No command replaces one of its own inputs, and no output replaces a file of another kind: the real
//! binary, one case per command (`mesh`, `register`, `compare`, `render`), each refused naming the output
//! and the input, with every file left byte for byte as it was.

use std::path::Path;

use crate::common::{refused_untouched, run};

fn s(p: &Path) -> String {
    p.display().to_string()
}

fn args(a: &[&str]) -> Vec<String> {
    a.iter().map(|x| x.to_string()).collect()
}

/// A phantom level's mesh, landmarks, CT and labels in `dir` (`spinedrr phantom`).
fn phantom(dir: &Path) {
    let (ok, err) = run(&crate::outputs_only_ours::phantom_args(dir));
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
            "a landmarks file of spinedrr's, not a record",
            "spinedrr did not write",
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
