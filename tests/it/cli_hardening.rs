//! Bad input to `render`, `phantom`, `mesh` and `geometry`, one test per class: the real binary exits
//! non-zero without a panic and names the flag, field or value; the repairs (an inside-out mesh, a
//! nested negative μ) give the image of the correct input.

use std::path::{Path, PathBuf};

use glam::DVec3;
use spinedrr::anatomy::{TriMesh, write_mesh};
use spinedrr::io::read_tiff_f32;

/// A cube of half-side `half` mm centred at `centre`, written as binary STL into `dir/name`.
pub(crate) fn cube(dir: &Path, name: &str, centre: DVec3, half: f64) -> PathBuf {
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
pub(crate) fn refused<S: AsRef<std::ffi::OsStr>>(args: &[S], needles: &[&str]) -> String {
    let (ok, err) = crate::common::run(args);
    assert!(!ok, "accepted: {err}");
    assert!(!err.contains("panicked"), "{err}");
    for n in needles {
        assert!(err.contains(n), "stderr lacks {n:?}: {err}");
    }
    err
}

pub(crate) fn s(p: &Path) -> String {
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
    let cases: [(&[&str], &str); 3] = [
        (
            &["--mesh", &far],
            "nothing of the anatomy is on the detector",
        ),
        (
            &["--mesh", &near, "--perturb", "dcx=5000"],
            "nothing of the anatomy is on the detector",
        ),
        // Focal length scaled by 0.001: the cube's image is a tenth of a pixel, between the rays.
        (
            &["--mesh", &near, "--perturb", "alpha=0.001"],
            "smaller than a pixel",
        ),
    ];
    for (case, cause) in cases {
        let args = [&["render"], case, &["--out", &o]].concat();
        refused(&args, &[cause, "--allow-empty", "px"]);
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
        &["'abc' is neither a number (μ in mm⁻¹) nor a material"],
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
    let cases: [(&[&str], &str); 12] = [
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
        (&["--ct", ct, "--mu-default", "2"], "--mu-default"),
        (&["--ct", ct, "--soft-tissue"], "--soft-tissue"),
    ];
    for (case, flag) in cases {
        let args = [&["render"], case, &["--out", &o]].concat();
        let err = refused(&args, &[flag, "cannot be used with"]);
        assert!(!err.contains("reading"), "{err}");
    }
    // A CT takes --backend gpu only (it renders on the CPU without one): a mesh backend is refused by
    // name, before the CT is read.
    for backend in ["bvh", "embree", "raster"] {
        let args = ["render", "--ct", ct, "--backend", backend, "--out", &o];
        let err = refused(&args, &[&format!("--backend {backend}"), "renders meshes"]);
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
    // The first render's own time (it builds the Siddon walk's running sums): reported beside the median.
    assert!(
        timing["first_ms"].as_f64().is_some_and(|t| t > 0.0),
        "first_ms missing or not positive in {timing}"
    );
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
