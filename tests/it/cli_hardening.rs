//! Bad input to `render`, `phantom`, `mesh` and `geometry`, one test per class: the real binary exits
//! non-zero without a panic and names the flag, field or value; the repairs (an inside-out mesh, a
//! nested negative μ) give the image of the correct input.

use std::path::{Path, PathBuf};

use glam::DVec3;
use spinedrr::anatomy::{TriMesh, write_mesh};
use spinedrr::io::read_tiff_f32;

/// A cube of half-side `half` mm centred at `centre`, written as binary STL into `dir/name`.
fn cube(dir: &Path, name: &str, centre: DVec3, half: f64) -> PathBuf {
    let path = dir.join(name);
    let m = TriMesh::cuboid(
        name,
        centre - DVec3::splat(half),
        centre + DVec3::splat(half),
    );
    write_mesh(&path, &m).unwrap();
    path
}

/// Runs and expects a failure without a panic whose stderr contains every one of `needles`.
fn refused<S: AsRef<std::ffi::OsStr>>(args: &[S], needles: &[&str]) -> String {
    let (ok, err) = crate::common::run(args);
    assert!(!ok, "accepted: {err}");
    assert!(!err.contains("panicked"), "{err}");
    for n in needles {
        assert!(err.contains(n), "stderr lacks {n:?}: {err}");
    }
    err
}

fn s(p: &Path) -> String {
    p.display().to_string()
}

#[test]
fn extreme_intrinsics_are_refused_naming_the_field() {
    let d = tempfile::tempdir().unwrap();
    let c = s(&cube(d.path(), "c.stl", DVec3::ZERO, 10.0));
    let out = s(&d.path().join("o.tiff"));
    for (spec, field) in [
        ("skew=1e22", "intrinsics.skew"),
        ("dcx=1e19", "intrinsics.cx"),
        ("dcy=-1e19", "intrinsics.cy"),
        ("df=1e30", "intrinsics.fx"),
    ] {
        for backend in ["raster", "embree", "bvh"] {
            let args = [
                "render",
                "--mesh",
                &c,
                "--perturb",
                spec,
                "--backend",
                backend,
            ];
            refused(&[&args[..], &["--out", &out]].concat(), &[field, "px"]);
        }
    }
    // A geometry file with such a K fails its check, and its render.
    let toml = spinedrr::geometry::DEFAULT_GEOMETRY_TOML;
    for (line, field) in [
        ("skew_px = 1e30", "intrinsics.skew"),
        ("principal_point_px = [1e19, 511.5]", "intrinsics.cx"),
    ] {
        let g = d.path().join("g.toml");
        let text = toml.replacen("[detector]\n", &format!("[detector]\n{line}\n"), 1);
        std::fs::write(&g, text).unwrap();
        refused(&["geometry", "--check", &s(&g)], &[field]);
        refused(
            &["render", "--mesh", &c, "--geometry", &s(&g), "--out", &out],
            &[field],
        );
    }
    assert!(!d.path().join("o.tiff").exists());
}

#[test]
fn absurd_allocations_and_runaway_work_are_refused_up_front() {
    let d = tempfile::tempdir().unwrap();
    let out = s(&d.path().join("ph"));
    let err = refused(
        &[
            "phantom",
            "--levels",
            "L3",
            "--voxel-mm",
            "0.0001",
            "--out",
            &out,
        ],
        &["voxel_mm 0.0001", "samples", "GiB", "limit"],
    );
    assert!(err.contains(" × "), "{err}");
    refused(
        &[
            "mesh",
            "--seg",
            "absent.nii.gz",
            "--label",
            "L1",
            "--smooth",
            "100000",
        ]
        .into_iter()
        .chain(["--out", &s(&d.path().join("m.stl"))])
        .collect::<Vec<_>>(),
        &["--smooth 100000", "limit of 500"],
    );
    // Renders repeated past any benchmark's need, and calibrations with absurd plate poses, are refused
    // before any work (the first used to abort allocating, the second to ask for 115 GB).
    let c = s(&cube(d.path(), "c.stl", DVec3::ZERO, 10.0));
    let tiff = s(&d.path().join("r.tiff"));
    for n in ["4294967295", "1000000000", "10001"] {
        refused(
            &["render", "--mesh", &c, "--repeat", n, "--out", &tiff],
            &[&format!("--repeat {n}"), "at most 10000", "hours"],
        );
    }
    assert!(!Path::new(&tiff).exists());
    for n in ["10000", "1000000"] {
        refused(
            &[
                "calibrate",
                "--phantom",
                "plate",
                "--noise-px",
                "0.5",
                "--poses-per-view",
                n,
                "--out",
                &s(&d.path().join("cal")),
            ],
            &["poses_per_view", n, "200"],
        );
    }
}

#[test]
fn anatomy_off_the_detector_is_an_error_unless_allowed() {
    let d = tempfile::tempdir().unwrap();
    let near = s(&cube(d.path(), "near.stl", DVec3::ZERO, 10.0));
    let far = s(&cube(
        d.path(),
        "far.stl",
        DVec3::new(5000.0, 0.0, 0.0),
        10.0,
    ));
    let out = d.path().join("o.tiff");
    let o = s(&out);
    let cases: [&[&str]; 3] = [
        &["--mesh", &far],
        &["--mesh", &near, "--perturb", "dcx=5000"],
        &["--mesh", &near, "--perturb", "alpha=0.001"],
    ];
    for case in cases {
        let args = [&["render"], case, &["--out", &o]].concat();
        refused(
            &args,
            &[
                "nothing of the anatomy is on the detector",
                "--allow-empty",
                "px",
            ],
        );
        assert!(!out.exists());
    }
    let (ok, err) = crate::common::run(&["render", "--mesh", &far, "--allow-empty", "--out", &o]);
    assert!(ok, "{err}");
    assert!(read_tiff_f32(&out).unwrap().data.iter().all(|&v| v == 0.0));
}

#[test]
fn inside_out_meshes_are_flipped_and_a_source_inside_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let outward = TriMesh::cuboid("c", DVec3::splat(-10.0), DVec3::new(10.0, 15.0, 20.0));
    let mut inverted = outward.clone();
    inverted.flip();
    let (a, b) = (d.path().join("out.stl"), d.path().join("inv.stl"));
    write_mesh(&a, &outward).unwrap();
    write_mesh(&b, &inverted).unwrap();
    let render = |mesh: &Path, name: &str| {
        let out = d.path().join(name);
        let (ok, err) = crate::common::run(&["render", "--mesh", &s(mesh), "--out", &s(&out)]);
        assert!(ok, "{err}");
        (read_tiff_f32(&out).unwrap(), err)
    };
    let (reference, err_ref) = render(&a, "a.tiff");
    let (repaired, err) = render(&b, "b.tiff");
    assert!(!err_ref.contains("warning"), "{err_ref}");
    assert!(
        err.contains("inside out") && err.contains("flipped"),
        "{err}"
    );
    assert!(!err.contains("did not pair"), "{err}");
    assert_eq!(reference, repaired);
    // The default AP source is at (0, −1000, 0) mm: inside a 4 m cube.
    let big = s(&cube(d.path(), "room.stl", DVec3::ZERO, 2000.0));
    refused(
        &[
            "render",
            "--mesh",
            &big,
            "--out",
            &s(&d.path().join("r.tiff")),
        ],
        &["X-ray source", "inside mesh", "room"],
    );
}

#[test]
fn mesh_attenuation_is_checked() {
    let d = tempfile::tempdir().unwrap();
    let shell = s(&cube(d.path(), "shell.stl", DVec3::ZERO, 10.0));
    let core = s(&cube(d.path(), "core.stl", DVec3::ZERO, 5.0));
    let o = s(&d.path().join("o.tiff"));
    refused(
        &["render", "--mesh", &format!("{shell}:abc"), "--out", &o],
        &["μ 'abc' is not a number"],
    );
    refused(
        &["render", "--mesh", &format!("{shell}:inf"), "--out", &o],
        &["must be finite"],
    );
    refused(
        &["render", "--mesh", &format!("{shell}:-1"), "--out", &o],
        &["negative", "nested"],
    );
    // Nested differential μ: a core of μ 0.5 in a shell of μ 1 is the shell at 1 plus the core at −0.5.
    let nested = [
        "render",
        "--mesh",
        &format!("{shell}:1"),
        "--mesh",
        &format!("{core}:-0.5"),
    ];
    let (ok, err) = crate::common::run(&[&nested[..], &["--out", &o]].concat());
    assert!(ok, "{err}");
    let img = read_tiff_f32(Path::new(&o)).unwrap();
    // The central ray (the AP view aims at the origin) crosses 20 mm of shell at μ 1 and 10 mm of core
    // at −0.5: 15; a ray through the shell beside the core, 20.
    let centre = img.data[512 * 1024 + 512];
    assert!((f64::from(centre) - 15.0).abs() < 0.05, "{centre}");
    let max = img.data.iter().cloned().fold(0f32, f32::max);
    assert!((f64::from(max) - 20.0).abs() < 0.05, "{max}");
    assert!(img.data.iter().all(|&v| v >= 0.0));
}

#[test]
fn flags_that_do_not_apply_are_refused_by_name() {
    let d = tempfile::tempdir().unwrap();
    let c = s(&cube(d.path(), "c.stl", DVec3::ZERO, 10.0));
    let o = s(&d.path().join("o.tiff"));
    let ct = "absent_ct.nii.gz";
    let cases: [(&[&str], &str); 13] = [
        (&["--mesh", &c, "--bone-hu", "150"], "--bone-hu"),
        (&["--mesh", &c, "--method", "trilinear"], "--method"),
        (&["--mesh", &c, "--mu-water", "0.02"], "--mu-water"),
        (&["--mesh", &c, "--step-mm", "0.5"], "--step-mm"),
        (&["--mesh", &c, "--labels", "verse"], "--labels"),
        (&["--mesh", &c, "--soft-tissue"], "--soft-tissue"),
        (&["--phantom", "L3", "--method", "siddon"], "--method"),
        (&["--phantom", "L3", "--mu-default", "2"], "--mu-default"),
        (&["--ct", ct, "--masks"], "--masks"),
        (&["--ct", ct, "--depth"], "--depth"),
        (&["--ct", ct, "--backend", "bvh"], "--backend"),
        (&["--ct", ct, "--mu-default", "2"], "--mu-default"),
        (&["--ct", ct, "--soft-tissue"], "--soft-tissue"),
    ];
    for (case, flag) in cases {
        let args = [&["render"], case, &["--out", &o]].concat();
        let err = refused(&args, &[flag, "cannot be used with"]);
        assert!(!err.contains("reading"), "{err}");
    }
}

#[test]
fn ct_renders_time_repeats_and_refuse_inapplicable_values() {
    let d = tempfile::tempdir().unwrap();
    let ct = d.path().join("ct.nii");
    let ph = s(&d.path().join("ph"));
    let args = [
        "phantom",
        "--levels",
        "L3",
        "--voxel-mm",
        "1.5",
        "--no-discs",
    ];
    let ct_args = ["--ct", &s(&ct), "--ct-voxel-mm", "2", "--out", &ph];
    let (ok, err) = crate::common::run(&[&args[..], &ct_args[..]].concat());
    assert!(ok, "{err}");
    let o = d.path().join("o.tiff");
    let (ok, err) =
        crate::common::run(&["render", "--ct", &s(&ct), "--repeat", "3", "--out", &s(&o)]);
    assert!(ok, "{err}");
    let timing: serde_json::Value = err
        .lines()
        .find_map(|l| serde_json::from_str(l).ok())
        .unwrap_or_else(|| panic!("no timing JSON in {err}"));
    assert_eq!(timing["repeat"], 3);
    assert_eq!(timing["rays_traced"], 1024 * 1024);
    assert!(timing["median_ms"].as_f64().unwrap() >= timing["min_ms"].as_f64().unwrap());
    let step = [
        "render",
        "--ct",
        &s(&ct),
        "--step-mm",
        "0.5",
        "--out",
        &s(&o),
    ];
    refused(&step, &["--step-mm", "trilinear"]);
    // The CT placed far from where the view aims renders nothing.
    let far = ["render", "--ct", &s(&ct), "--perturb", "dcx=20000", "--out"];
    refused(
        &[&far[..], &[&s(&d.path().join("far.tiff"))]].concat(),
        &["nothing of the anatomy"],
    );
    // A CT output named as something else is refused before anything is built.
    for name in ["x.raw", "x.nii.gz.bak", "x"] {
        let bad = s(&d.path().join(name));
        refused(
            &["phantom", "--levels", "L3", "--ct", &bad, "--out", &ph],
            &[name, ".nii"],
        );
        assert!(!d.path().join(name).exists());
    }
}

#[test]
fn an_output_folder_that_is_a_file_is_named_not_file_exists() {
    let d = tempfile::tempdir().unwrap();
    let file = d.path().join("taken");
    std::fs::write(&file, "mine").unwrap();
    let f = s(&file);
    for args in [
        vec!["phantom", "--levels", "L3", "--voxel-mm", "2", "--out", &f],
        vec![
            "calibrate",
            "--phantom",
            "helix",
            "--noise-px",
            "0.5",
            "--trials",
            "2",
            "--out",
            &f,
        ],
    ] {
        let err = refused(&args, &["--out", "taken", "is a file, not a folder"]);
        assert!(!err.contains("File exists"), "{err}");
    }
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "mine");
}

/// A negative number given to a flag is that flag's value, not an unknown flag `-1`: a count says it must
/// be a whole number ≥ 0 (naming the flag and the value), and a value that may be negative is taken.
#[test]
fn negative_numbers_are_values_that_the_flag_judges() {
    let d = tempfile::tempdir().unwrap();
    let out = s(&d.path().join("o"));
    let tiff = s(&d.path().join("o.tiff"));
    for (args, flag) in [
        (
            vec![
                "render",
                "--phantom",
                "L3",
                "--repeat",
                "-1",
                "--out",
                &tiff,
            ],
            "--repeat",
        ),
        (
            vec![
                "calibrate",
                "--phantom",
                "plate",
                "--noise-px",
                "0.1",
                "--trials",
                "-5",
                "--out",
                &out,
            ],
            "--trials",
        ),
        (
            vec!["study", "--quick", "--threads", "-2", "--out", &out],
            "--threads",
        ),
        (
            vec!["study", "--quick", "--max-units", "-3", "--out", &out],
            "--max-units",
        ),
        (
            vec![
                "register",
                "--problem",
                "p.json",
                "--seed",
                "-7",
                "--out",
                &out,
            ],
            "--seed",
        ),
        (
            vec![
                "mesh", "--seg", "x.nii", "--labels", "1", "--smooth", "-1", "--out", &out,
            ],
            "--smooth",
        ),
    ] {
        let err = refused(
            &args,
            &[flag, "is negative", "must be a whole number from 0 to"],
        );
        assert!(!err.contains("unexpected argument"), "{err}");
    }
    // A fraction for a count is named as such.
    refused(
        &[
            "render",
            "--phantom",
            "L3",
            "--repeat",
            "2.5",
            "--out",
            &tiff,
        ],
        &["--repeat", "2.5 is not whole"],
    );
    // A negative value where the flag's own rule refuses it reaches that rule.
    refused(
        &[
            "calibrate",
            "--phantom",
            "plate",
            "--noise-px",
            "-1",
            "--out",
            &out,
        ],
        &["noise-px", "≥ 0"],
    );
    assert!(!Path::new(&out).exists() && !Path::new(&tiff).exists());
}

/// A 20 mm cube of `hu` in air, 1 mm voxels, written as `dir/name` (NIfTI).
fn cube_ct(dir: &Path, name: &str, hu: f32, air: f32) -> String {
    block_ct(dir, name, hu, air, 1.0, 2..22)
}

/// A 24³ grid of `voxel_mm` voxels holding `hu` in voxels `fill` along each axis and `air` elsewhere.
fn block_ct(
    dir: &Path,
    name: &str,
    hu: f32,
    air: f32,
    voxel_mm: f64,
    fill: std::ops::Range<usize>,
) -> String {
    use spinedrr::anatomy::ct::{Volume, write_ct};
    let affine = glam::DMat4::from_scale(DVec3::splat(voxel_mm));
    let mut v = Volume::filled([24, 24, 24], air, affine).unwrap();
    for k in fill.clone() {
        for j in fill.clone() {
            for i in fill.clone() {
                let n = v.linear(i, j, k);
                v.values[n] = hu;
            }
        }
    }
    let path = dir.join(name);
    write_ct(&path, &v).unwrap();
    s(&path)
}

/// No render writes a non-finite pixel: an attenuation so large that μ × path length overflows float32
/// (a mesh's μ, the CT's μ of water) is refused naming the value, a file whose voxels are not Hounsfield
/// units is refused on reading, and a label map given as a CT is rendered with a warning saying so.
#[test]
fn absurd_attenuations_are_refused_never_written_as_infinities() {
    let d = tempfile::tempdir().unwrap();
    let c = s(&cube(d.path(), "c.stl", DVec3::ZERO, 10.0));
    let out = d.path().join("o.tiff");
    let o = s(&out);
    refused(
        &["render", "--mesh", &format!("{c}:1e307"), "--out", &o],
        &["not finite", "largest μ is 1e307 mm⁻¹"],
    );
    let ct = cube_ct(d.path(), "ct.nii", 1000.0, -1000.0);
    refused(
        &["render", "--ct", &ct, "--mu-water", "1e38", "--out", &o],
        &["not finite", "HU"],
    );
    let absurd = cube_ct(d.path(), "absurd.nii", 3e38, -1000.0);
    refused(
        &["render", "--ct", &absurd, "--out", &o],
        &["absurd.nii", "beyond ±100000 HU", "3e38"],
    );
    // An absurd photon count is quoted as a number a reader can read.
    let err = refused(
        &["render", "--mesh", &c, "--photons", "1e308", "--out", &o],
        &["I0 = 1e308", "at most 1e12"],
    );
    assert!(!err.contains("10000000000"), "{err}");
    // A trilinear step that would sample each voxel a billion times is refused up front.
    refused(
        &[
            "render",
            "--ct",
            &ct,
            "--method",
            "trilinear",
            "--step-mm",
            "1e-9",
            "--out",
            &o,
        ],
        &["step_mm", "1e-9 mm", "at least 0.01 mm"],
    );
    assert!(!out.exists(), "a refused render wrote {o}");
    // The same CT with sane values renders, without the label-map warning.
    let (ok, err) = crate::common::run(&["render", "--ct", &ct, "--out", &o]);
    assert!(ok && !err.contains("label map"), "{err}");
    let labels = cube_ct(d.path(), "labels.nii", 22.0, 0.0);
    let (ok, err) = crate::common::run(&["render", "--ct", &labels, "--out", &o]);
    assert!(ok, "{err}");
    assert!(
        err.contains("looks like a label map") && err.contains("--seg"),
        "{err}"
    );
}

/// A CT whose anatomy encloses the X-ray source is refused as a mesh around the source is; a source in the
/// scan's air margin (μ = 0) is not.
#[test]
fn a_source_inside_the_cts_anatomy_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let o = s(&d.path().join("o.tiff"));
    // 24 voxels of 100 mm of soft tissue: a 2.4 m block around the isocentre and the source.
    let huge = block_ct(d.path(), "huge.nii", 40.0, 40.0, 100.0, 0..24);
    for view in ["ap", "lat"] {
        refused(
            &["render", "--ct", &huge, "--view", view, "--out", &o],
            &[
                "X-ray source",
                &format!("view '{view}'"),
                "inside the CT's anatomy",
            ],
        );
    }
    assert!(!d.path().join("o.tiff").exists());
    // The same 2.4 m grid with tissue only in its central 200 mm: the source is in air, which is fine.
    let margin = block_ct(d.path(), "margin.nii", 40.0, -1000.0, 100.0, 11..13);
    let (ok, err) = crate::common::run(&["render", "--ct", &margin, "--out", &o]);
    assert!(ok, "{err}");
}

/// A landmark file of the wrong shape is described in the user's terms (which entry, which field, what
/// it holds), never by the reader's internal type names.
#[test]
fn a_malformed_landmark_file_is_described_not_named_by_internal_types() {
    let d = tempfile::tempdir().unwrap();
    let c = s(&cube(d.path(), "c.stl", DVec3::ZERO, 10.0));
    let drr = s(&d.path().join("r.tiff"));
    let (ok, err) = crate::common::run(&["render", "--mesh", &c, "--out", &drr]);
    assert!(ok, "{err}");
    for (text, says) in [
        ("{\"foo\": 1}", "missing field `landmarks`"),
        ("[1, 2]", "entry 0 of the array is a number, not an object"),
        ("{\"landmarks\": {\"a\": [1, 2]}}", "invalid length 2"),
        ("{\"landmarks\": {\"a\": [1, 2, 3]}", "not JSON"),
        ("\"L3\"", "the file is a string, not an object"),
    ] {
        let lm = d.path().join("lm.json");
        std::fs::write(&lm, text).unwrap();
        let out = s(&d.path().join("cmp"));
        let err = refused(
            &[
                "compare",
                "--reference",
                &drr,
                "--perturbed",
                &drr,
                "--landmarks",
                &s(&lm),
                "--out",
                &out,
            ],
            &["lm.json", says],
        );
        for internal in [
            "untagged",
            "enum",
            "LandmarkFile",
            "LandmarkSet",
            "Discriminant",
        ] {
            assert!(!err.contains(internal), "{internal} in: {err}");
        }
    }
}
