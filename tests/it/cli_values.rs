//! Values no render, registration or reader may take at face value, one test per family on the real
//! binary: negative numbers given to flags, attenuations that overflow the image, files whose voxels are
//! not Hounsfield units, a source inside the CT's anatomy, landmark files of the wrong shape.

use std::path::Path;

use glam::DVec3;

use crate::cli_hardening::{cube, refused, s};

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
        &["not finite", "--mu-water 1e38 mm⁻¹", "HU up to 1000"],
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

/// A binary STL of a 10 mm square in the plane z = 0, both sides (each triangle also wound backwards):
/// closed, 200 mm² of surface, no volume.
fn flat_stl(dir: &Path) -> String {
    let (a, b, c, d) = (
        [0f32, 0.0, 0.0],
        [10.0, 0.0, 0.0],
        [10.0, 10.0, 0.0],
        [0.0, 10.0, 0.0],
    );
    let triangles = [[a, b, c], [a, c, d], [a, c, b], [a, d, c]];
    let mut bytes = vec![0u8; 80];
    bytes.extend((triangles.len() as u32).to_le_bytes());
    for [p, q, r] in triangles {
        for v in [[0f32; 3], p, q, r] {
            for x in v {
                bytes.extend(x.to_le_bytes());
            }
        }
        bytes.extend([0, 0]);
    }
    let path = dir.join("flat.stl");
    std::fs::write(&path, bytes).unwrap();
    s(&path)
}

/// An image of zeros is explained by its cause: what attenuates nothing (a mesh with μ = 0, a surface
/// enclosing no volume, a CT all air), a target between the rays, or anatomy off the detector; label 0,
/// the background, is refused wherever a label is read. It used to say "nothing of the anatomy is on the
/// detector" for all of them, quoting a bounding box on the detector.
#[test]
fn an_image_of_zeros_names_its_cause() {
    use spinedrr::geometry::CArm;
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("o.tiff");
    let o = s(&out);
    let c = s(&cube(d.path(), "c.stl", DVec3::ZERO, 10.0));
    refused(
        &["render", "--mesh", &format!("{c}:0"), "--out", &o],
        &["nothing attenuates", "has μ = 0 mm⁻¹", "--allow-empty"],
    );
    let flat = flat_stl(d.path());
    refused(
        &["render", "--mesh", &format!("{flat}:0.05"), "--out", &o],
        &[
            "nothing attenuates",
            "encloses no volume",
            "0 mm³ within 200 mm² of surface",
        ],
    );
    // One mesh that attenuates is enough: a zero image then has another cause.
    let err = refused(
        &[
            "render",
            "--mesh",
            &format!("{c}:0"),
            "--mesh",
            &format!("{flat}:0.05"),
            "--out",
            &o,
        ],
        &["has μ = 0", "encloses no volume"],
    );
    assert!(!err.contains("not on the detector"), "{err}");
    // A 0.2 µm cube centred between four rays (half a pixel from each pixel centre's ray, at the depth
    // where the view aims): on the detector, yet no ray crosses it.
    let ap = CArm::default_paper().view("ap").unwrap().clone();
    let (aim, distance) = ap.aim();
    let between = ap.pixel_ray(511.5, 511.5);
    let centre = between.origin + between.dir * distance;
    assert!((centre - aim).length() < 1.0, "{centre} vs {aim}");
    let tiny = s(&cube(d.path(), "tiny.stl", centre, 1e-4));
    refused(
        &["render", "--mesh", &tiny, "--out", &o],
        &[
            "meets the detector",
            "no ray through a pixel centre",
            "smaller than a pixel",
        ],
    );
    // A CT all air; label 0 of a segmentation.
    let air = cube_ct(d.path(), "air.nii", -1000.0, -1000.0);
    refused(
        &["render", "--ct", &air, "--out", &o],
        &[
            "nothing attenuates",
            "at or below −1000 HU",
            "the whole volume",
        ],
    );
    let ct = cube_ct(d.path(), "ct.nii", 1000.0, -1000.0);
    let seg = cube_ct(d.path(), "seg.nii", 29.0, 0.0);
    refused(
        &[
            "render", "--ct", &ct, "--seg", &seg, "--label", "0", "--out", &o,
        ],
        &["label 0 is the background"],
    );
    assert!(!out.exists(), "a refused render wrote {o}");
}
