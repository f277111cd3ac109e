//! No command writes over a file spinedrr did not write, through the real binary: `phantom` (a
//! hand-placed `landmarks.json`, another program's mesh, a CT named as `--ct`), `render` (the user's
//! `OUT.png`), `mesh` (hand-placed `<stem>_landmarks.json`), `calibrate` (someone's `calibrations.csv`)
//! and `register` (a JSON file of the user's). Each is refused naming the file, and the folder is left
//! byte for byte as it was; each command run twice over its own output succeeds.

use std::path::Path;

use crate::common::{refused_untouched, run, snapshot};

fn s(p: &Path) -> String {
    p.display().to_string()
}

/// [`refused_untouched`] whose message also says why: the file is not spinedrr's, and nothing was written.
fn refused(dir: &Path, args: &[String], needles: &[&str]) {
    let why = ["spinedrr did not write", "nothing was written"];
    refused_untouched(dir, args, &[needles, &why[..]].concat());
}

fn ok(args: &[String]) {
    let (ok, err) = run(args);
    assert!(ok, "{args:?}: {err}");
}

fn args(a: &[&str]) -> Vec<String> {
    a.iter().map(|x| x.to_string()).collect()
}

/// `phantom --levels L3` into `dir` with a coarse mesh, CT and label map (`ct.nii`, `seg.nii.gz`).
pub(crate) fn phantom_args(dir: &Path) -> Vec<String> {
    args(&[
        "phantom",
        "--levels",
        "L3",
        "--no-discs",
        "--voxel-mm",
        "1.5",
        "--ct-voxel-mm",
        "1.5",
        "--ct",
        &s(&dir.join("ct.nii")),
        "--labels-out",
        &s(&dir.join("seg.nii.gz")),
        "--out",
        &s(dir),
    ])
}

#[test]
fn phantom_replaces_only_its_own_files() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    // Hand-placed landmarks (no `tool`) where the phantom writes its own.
    let hand = r#"[{"level": "L3", "landmarks": {"pedicle_left": [1, 2, 3]}}]"#;
    std::fs::write(dir.join("landmarks.json"), hand).unwrap();
    refused(
        dir,
        &phantom_args(dir),
        &["landmarks.json", "a landmarks file"],
    );
    std::fs::remove_file(dir.join("landmarks.json")).unwrap();
    // Another program's STL (3D Slicer names itself in the header) under a phantom mesh's name.
    let mut slicer_stl = b"solid SlicerModel".to_vec();
    slicer_stl.resize(84, b' ');
    std::fs::write(dir.join("L3_cortical.stl"), &slicer_stl).unwrap();
    refused(dir, &phantom_args(dir), &["L3_cortical.stl", "a mesh"]);
    std::fs::remove_file(dir.join("L3_cortical.stl")).unwrap();

    // Into the emptied folder it runs, and again over its own files, byte for byte the same.
    ok(&phantom_args(dir));
    let first = snapshot(dir);
    ok(&phantom_args(dir));
    assert_eq!(
        snapshot(dir),
        first,
        "a second phantom run over its own files"
    );

    // A run of other levels into the same folder says which meshes of the earlier run it left.
    let l2 = args(&[
        "phantom",
        "--levels",
        "L2",
        "--no-discs",
        "--voxel-mm",
        "1.5",
        "--out",
        &s(dir),
    ]);
    let (done, err) = run(&l2);
    assert!(done, "{err}");
    assert!(
        err.contains("L3_cancellous.stl, L3_cortical.stl from an earlier phantom run"),
        "{err}"
    );
    assert!(!err.contains("L2_cortical.stl, "), "{err}");

    // The same CT without spinedrr's name in its NIfTI `descrip` (bytes 148–227) is someone's CT.
    let ct = dir.join("ct.nii");
    let mut bytes = std::fs::read(&ct).unwrap();
    assert!(bytes[148..228].starts_with(b"spinedrr"));
    bytes[148..228].fill(0);
    std::fs::write(&ct, &bytes).unwrap();
    refused(dir, &phantom_args(dir), &["ct.nii", "a NIfTI volume"]);
}

#[test]
fn render_never_replaces_the_users_png_beside_its_image() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let out = s(&dir.join("img.tiff"));
    let render = |extra: &[&str]| {
        [
            &args(&["render", "--phantom", "L3", "--view", "lat", "--out", &out])[..],
            &args(extra),
        ]
        .concat()
    };
    std::fs::write(dir.join("img.png"), b"the user's photo").unwrap();
    refused(
        dir,
        &render(&[]),
        &["img.png", "without a spinedrr sidecar"],
    );
    // A TIFF of the user's under the output name (no sidecar beside it).
    std::fs::remove_file(dir.join("img.png")).unwrap();
    std::fs::write(dir.join("img.tiff"), b"II*\0 someone's radiograph").unwrap();
    refused(dir, &render(&[]), &["img.tiff"]);
    std::fs::remove_file(dir.join("img.tiff")).unwrap();
    // Its own set it replaces, with masks or without.
    ok(&render(&["--masks"]));
    ok(&render(&[]));
    ok(&render(&["--masks", "--depth"]));
}

#[test]
fn mesh_calibrate_and_register_replace_only_their_own_files() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    ok(&phantom_args(dir));
    let seg = s(&dir.join("seg.nii.gz"));
    let out = dir.join("L3.stl");
    let mesh = args(&[
        "mesh",
        "--seg",
        &seg,
        "--label",
        "L3",
        "--landmarks",
        "auto",
        "--out",
        &s(&out),
    ]);
    // Hand-placed landmarks where `--landmarks auto` would write (`L3_landmarks.json`).
    let hand = r#"[{"level": "L3", "landmarks": {"spinous_tip": [0, -50, 0]}}]"#;
    std::fs::write(dir.join("L3_landmarks.json"), hand).unwrap();
    refused(dir, &mesh, &["L3_landmarks.json", "a landmarks file"]);
    std::fs::remove_file(dir.join("L3_landmarks.json")).unwrap();
    ok(&mesh);
    ok(&mesh);
    // A render's sidecar is spinedrr's but no landmarks file: the landmarks never replace it.
    let sidecar = dir.join("L3_landmarks.json");
    let phantom_landmarks = std::fs::read(dir.join("landmarks.json")).unwrap();
    assert!(String::from_utf8_lossy(&phantom_landmarks).contains("\"tool\": \"spinedrr\""));
    std::fs::write(&sidecar, br#"{"tool": "spinedrr", "kind": "drr"}"#).unwrap();
    refused(dir, &mesh, &["L3_landmarks.json", "not a landmarks file"]);

    // Someone's calibrations.csv in calibrate's output folder; then its own set twice.
    let cal = dir.join("cal");
    std::fs::create_dir(&cal).unwrap();
    std::fs::write(cal.join("calibrations.csv"), "trial,fx\n0,4500\n").unwrap();
    let calibrate = args(&[
        "calibrate",
        "--phantom",
        "helix",
        "--noise-px",
        "0.2",
        "--trials",
        "2",
        "--quiet",
        "--out",
        &s(&cal),
    ]);
    refused(&cal, &calibrate, &["calibrations.csv", "lists it"]);
    std::fs::remove_file(cal.join("calibrations.csv")).unwrap();
    ok(&calibrate);
    let first = snapshot(&cal);
    ok(&calibrate);
    assert_eq!(
        snapshot(&cal),
        first,
        "the same seed, the same calibrations"
    );

    // A JSON file of the user's as register's --out; then its own result twice.
    let problem = dir.join("P.json");
    let p = crate::registration_cli::problem_json(
        &crate::registration_cli::landmarks(),
        &["ap", "lat"],
    );
    std::fs::write(&problem, p.to_string()).unwrap();
    let result = dir.join("R.json");
    std::fs::write(&result, r#"{"my": "notes"}"#).unwrap();
    let register = args(&["register", "--problem", &s(&problem), "--out", &s(&result)]);
    refused(
        dir,
        &register,
        &["R.json", "without `\"tool\": \"spinedrr\"`"],
    );
    std::fs::remove_file(&result).unwrap();
    ok(&register);
    ok(&register);

    // A record of spinedrr's is replaced only by a record of its kind: a render named after the
    // registration's result or the calibration's record would have replaced them with its sidecar.
    let render = |out: &Path| {
        args(&[
            "render",
            "--phantom",
            "L3",
            "--view",
            "ap",
            "--out",
            &s(out),
        ])
    };
    refused_untouched(
        dir,
        &render(&dir.join("R.tiff")),
        &[
            "R.json",
            "registration record",
            "with a drr record",
            "nothing was written",
        ],
    );
    refused_untouched(
        &cal,
        &render(&cal.join("phantom.tiff")),
        &[
            "phantom.json",
            "calibration record",
            "with a drr record",
            "nothing was written",
        ],
    );
    // And a mask's sidecar of one render is not the sidecar of another.
    let img = dir.join("img");
    std::fs::create_dir(&img).unwrap();
    ok(&[render(&img.join("a.tiff")), args(&["--masks"])].concat());
    refused_untouched(
        &img,
        &render(&img.join("a_mask.tiff")),
        &[
            "a_mask.json",
            "mask record",
            "with a drr record",
            "nothing was written",
        ],
    );
    // A comparison's metrics.json likewise.
    ok(&args(&[
        "compare",
        "--reference",
        &s(&img.join("a.tiff")),
        "--perturbed",
        &s(&img.join("a.tiff")),
        "--out",
        &s(&img.join("cmp")),
    ]));
    refused_untouched(
        &img.join("cmp"),
        &render(&img.join("cmp/metrics.tiff")),
        &[
            "metrics.json",
            "metrics record",
            "with a drr record",
            "nothing was written",
        ],
    );
}

/// What each writer writes is what the ownership check takes for spinedrr's own: the round trip from
/// every mesh format, both landmark formats, a record and a NIfTI volume to the check reading the bytes.
#[test]
fn every_writer_leaves_what_the_check_knows_for_its_own() {
    use spinedrr::anatomy::{Landmarks, MeshFormat, TriMesh, write_landmarks, write_mesh_as};
    use spinedrr::io::{check_ours, check_ours_landmarks};
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let cube = TriMesh::cuboid("c", glam::DVec3::splat(-5.0), glam::DVec3::splat(5.0));
    for (name, format) in [
        ("b.stl", MeshFormat::StlBinary),
        ("c.obj", MeshFormat::Obj),
        ("d.ply", MeshFormat::PlyBinary),
        ("e.ply", MeshFormat::PlyAscii),
    ] {
        let p = dir.join(name);
        write_mesh_as(&p, &cube, format).unwrap();
        check_ours(&p).unwrap_or_else(|e| panic!("{name}: {e}"));
    }
    let lm = Landmarks {
        level: "L3".into(),
        points: [("center".to_string(), glam::DVec3::new(1.0, 2.0, 3.0))].into(),
    };
    for name in ["L3_landmarks.json", "L3_landmarks.mrk.json"] {
        let p = dir.join(name);
        write_landmarks(&p, std::slice::from_ref(&lm)).unwrap();
        check_ours_landmarks(&p).unwrap_or_else(|e| panic!("{name}: {e}"));
        // Landmarks are no record: a sidecar or metrics.json never replaces them.
        assert!(check_ours(&p).is_err(), "{name}");
        // And they read back as they were written.
        let back = spinedrr::anatomy::read_landmarks(&p).unwrap();
        assert_eq!(back.len(), 1);
        assert!((back[0].points["center"] - lm.points["center"]).length() < 1e-9);
    }
    // The phantom's CT and label map (NIfTI, plain and gzip) and its meshes and landmarks.
    ok(&phantom_args(dir));
    for name in [
        "ct.nii",
        "seg.nii.gz",
        "L3_cortical.stl",
        "L3_cancellous.stl",
    ] {
        check_ours(&dir.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
    }
    check_ours_landmarks(&dir.join("landmarks.json")).unwrap();
}
