//! The products `spinedrr` writes through `io`: `--intensity` for mesh and CT renders against the analytic
//! Beer–Lambert law `I = I0 · exp(−L)` of the line-integral render of the same anatomy, one spelling of the
//! line-integral unit for both renderers, and the study's heatmap sidecar (kind, K of the perturbed view).

use std::path::Path;

use glam::{DMat4, DVec3};
use spinedrr::anatomy::ct::{CtVolume, write_ct};
use spinedrr::anatomy::{MU_WATER_PER_MM, TriMesh, write_mesh};
use spinedrr::geometry::CArm;
use spinedrr::io::{ImageF32, Sidecar, read_tiff_f32, units};

const I0: f64 = 1000.0;

/// Runs the binary and fails the test with its stderr when it fails.
fn run_ok(args: &[&str]) {
    let (ok, err) = crate::common::run(args);
    assert!(ok, "{args:?}: {err}");
}

/// A 96 × 80 detector looking along +y at the origin from 1000 mm.
fn small_geometry(dir: &Path) -> String {
    let path = dir.join("geom.toml");
    std::fs::write(
        &path,
        "[detector]\nwidth = 96\nheight = 80\npixel_spacing_mm = [1.2, 1.2]\nsdd_mm = 1350.0\n\n\
         [[view]]\nname = \"ap\"\nsource_mm = [0.0, -1000.0, 0.0]\ntarget_mm = [0.0, 0.0, 0.0]\n",
    )
    .unwrap();
    path.display().to_string()
}

/// Renders `anatomy` twice (line integral, then intensity with I0) and returns both images with their
/// sidecars.
fn line_integral_and_intensity(
    dir: &Path,
    anatomy: &[&str],
    stem: &str,
) -> ((ImageF32, Sidecar), (ImageF32, Sidecar)) {
    let geom = small_geometry(dir);
    let li = dir.join(format!("{stem}.tiff"));
    let int = dir.join(format!("{stem}_i.tiff"));
    let i0 = I0.to_string();
    for (out, extra) in [(&li, vec![]), (&int, vec!["--intensity", i0.as_str()])] {
        let mut args = vec!["render"];
        args.extend_from_slice(anatomy);
        args.extend(["--geometry", &geom, "--perturb", "df=200"]);
        args.extend(extra);
        args.extend(["--out", out.to_str().unwrap()]);
        run_ok(&args);
    }
    let read = |p: &Path| {
        (
            read_tiff_f32(p).unwrap(),
            Sidecar::read(&p.with_extension("json")).unwrap(),
        )
    };
    (read(&li), read(&int))
}

/// Every pixel of `intensity` is `I0 · exp(−L)` of the same pixel of `li` (to f32 rounding); the sidecars
/// say which is which with one spelling per unit.
fn assert_beer_lambert(li: &(ImageF32, Sidecar), intensity: &(ImageF32, Sidecar)) {
    let ((l, ls), (i, is)) = (li, intensity);
    assert_eq!((l.width, l.height), (i.width, i.height));
    assert!(
        l.max() > 0.1,
        "the anatomy must attenuate: max L {}",
        l.max()
    );
    for (k, (&l, &i)) in l.data.iter().zip(&i.data).enumerate() {
        let expected = I0 * (-f64::from(l)).exp();
        assert!(
            (f64::from(i) - expected).abs() <= 1e-6 * expected,
            "pixel {k}: I = {i}, I0·exp(−{l}) = {expected}"
        );
    }
    assert_eq!(ls.units, units::LINE_INTEGRAL);
    assert_eq!(is.units, units::INTENSITY);
    assert_eq!(is.details["I0"], I0);
    assert!(ls.details.get("I0").is_none());
    assert_eq!((is.k, is.perturbation_spec.as_str()), (ls.k, "df=200"));
}

#[test]
fn ct_intensity_is_i0_exp_minus_the_line_integral_render() {
    let dir = tempfile::tempdir().unwrap();
    // A 20 mm cube of 700 HU in air, 1 mm voxels centred on the origin.
    let a = DMat4::from_translation(DVec3::splat(-20.0));
    let mut ct = CtVolume::filled([41, 41, 41], -1000.0, a).unwrap();
    for k in 10..30 {
        for j in 10..30 {
            for i in 10..30 {
                let n = ct.linear(i, j, k);
                ct.values[n] = 700.0;
            }
        }
    }
    let ct_path = dir.path().join("ct.nii.gz");
    write_ct(&ct_path, &ct).unwrap();
    let (li, int) =
        line_integral_and_intensity(dir.path(), &["--ct", ct_path.to_str().unwrap()], "ct");
    // The central rays cross the cube's 20 mm (cos of their angle to the axis > 0.9999).
    let chord = 20.0 * MU_WATER_PER_MM * 1.7;
    let centre = f64::from(li.0.get(47, 39));
    assert!((centre - chord).abs() < 1e-3 * chord, "{centre} vs {chord}");
    let centre_i = f64::from(int.0.get(47, 39));
    assert!((centre_i - I0 * (-chord).exp()).abs() < 2e-3 * centre_i);
    assert_beer_lambert(&li, &int);
    assert_eq!(int.1.details["renderer"], "ct-volume");
}

#[test]
fn mesh_intensity_is_i0_exp_minus_the_line_integral_render() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = dir.path().join("box.stl");
    let cuboid = TriMesh::cuboid(
        "box",
        DVec3::new(-10.0, -5.0, -8.0),
        DVec3::new(10.0, 5.0, 8.0),
    );
    write_mesh(&mesh, &cuboid).unwrap();
    let spec = format!("{}:0.5", mesh.display());
    let (li, int) = line_integral_and_intensity(dir.path(), &["--mesh", &spec], "box");
    // The central rays cross the box's 10 mm with μ = 0.5 mm⁻¹.
    let centre_i = f64::from(int.0.get(47, 39));
    assert!(
        (centre_i - I0 * (-5.0f64).exp()).abs() < 2e-2 * centre_i,
        "{centre_i}"
    );
    assert_beer_lambert(&li, &int);
    assert_eq!(int.1.details["renderer"], "thickness");
}

#[test]
fn study_heatmap_has_a_sidecar_of_the_perturbed_view() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("study.toml");
    std::fs::write(
        &cfg,
        "seed = 7\nexperiments = [\"projection\"]\nheatmaps_df_px = [300.0]\n\
         [anatomy]\nlevels = [\"L1\"]\nsegment = false\nvoxel_mm = 1.2\n\
         [geometry]\nviews = [\"lat\"]\nbinning = 4\n\
         [perturbations]\ndf_px = [300.0]\npiercing_px = [0.0]\n",
    )
    .unwrap();
    let out = dir.path().join("out");
    run_ok(&[
        "study",
        "--config",
        cfg.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let png = out.join("figures/heatmap_L1_lat_df300.png");
    let side = Sidecar::read(&png.with_extension("json")).unwrap();
    let img = image::open(&png).unwrap();
    assert_eq!(side.kind, "heatmap");
    assert_eq!(
        (side.view.as_str(), side.perturbation_spec.as_str()),
        ("lat", "df=300")
    );
    assert_eq!(side.perturbation.df_px, 300.0);
    // K is the perturbed view's: Δf = 300 px on both focal lengths, nothing else moves.
    let (k, r) = (side.k, side.k_reference);
    assert_eq!(k[0][0], r[0][0] + 300.0);
    assert_eq!(k[1][1], r[1][1] + 300.0);
    assert_eq!((k[0][1], k[0][2], k[1][2]), (r[0][1], r[0][2], r[1][2]));
    assert_eq!(k[2], [0.0, 0.0, 1.0]);
    // The extrinsics are the default C-arm's LAT view (binning scales K only).
    let lat = CArm::default_paper().view("lat").unwrap().clone();
    assert_eq!(side.world_to_camera, lat.world_to_camera.to_rows());
    // The PNG is the image plus the colour-bar panel, at the sidecar's detector size.
    assert_eq!(img.height(), side.height);
    assert!(img.width() > side.width);
    assert_eq!(side.units, units::LINE_INTEGRAL_DIFFERENCE);
    assert_eq!(side.details["target"], "L1");
    assert_eq!(side.details["colour_bar"]["map"], "viridis");
}
