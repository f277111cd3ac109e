//! `spinedrr compare` end to end on files written the way the renderer writes them.

use std::path::Path;

use glam::{DVec2, DVec3};
use serde_json::Value;
use spinedrr::geometry::{CArm, Perturbation, View};
use spinedrr::io::{
    ImageF32, Sidecar, read_tiff_f32, sidecar_path, write_mask_png, write_tiff_f32,
};

use crate::common::Spinedrr;

const N: u32 = 256;

/// A smooth synthetic "DRR" of a disc of radius r around c, and its mask.
fn blob(c: DVec2, r: f64) -> (ImageF32, Vec<bool>) {
    let mut img = ImageF32::zeros(N, N);
    let mut mask = vec![false; (N * N) as usize];
    for v in 0..N {
        for u in 0..N {
            let d = (DVec2::new(u as f64, v as f64) - c).length();
            let i = (v * N + u) as usize;
            img.data[i] = (r * r - d * d).max(0.0).sqrt() as f32;
            mask[i] = d <= r;
        }
    }
    (img, mask)
}

fn write_case(dir: &Path, stem: &str, view: &View, p: &Perturbation, c: DVec2, r: f64) {
    let (img, mask) = blob(c, r);
    let tiff = dir.join(format!("{stem}.tiff"));
    write_tiff_f32(&tiff, &img).unwrap();
    Sidecar::new("drr", "mm", view, p)
        .unwrap()
        .write(&sidecar_path(&tiff))
        .unwrap();
    write_mask_png(&dir.join(format!("{stem}_mask_body.png")), N, N, &mask).unwrap();
    let ring: Vec<bool> = mask
        .iter()
        .zip(blob(c, r * 0.5).1)
        .map(|(a, b)| *a && !b)
        .collect();
    write_mask_png(&dir.join(format!("{stem}_mask_ring.png")), N, N, &ring).unwrap();
}

fn small_view() -> View {
    let ap = CArm::default_paper().view("ap").unwrap().clone();
    let mut k = ap.intrinsics;
    (k.width, k.height, k.fx, k.fy, k.cx, k.cy) = (N, N, 1100.0, 1100.0, 127.5, 127.5);
    View::new("ap", k, ap.world_to_camera)
}

#[test]
fn compare_writes_metrics_heatmap_and_difference() {
    let dir = tempfile::tempdir().unwrap();
    let view = small_view();
    let pert = Perturbation::focal(110.0); // α = 1.1
    let c = DVec2::new(127.5, 127.5);
    write_case(dir.path(), "ref", &view, &Perturbation::NONE, c, 50.0);
    write_case(dir.path(), "pert", &view, &pert, c, 55.0);
    let lm = dir.path().join("lm.json");
    std::fs::write(
        &lm,
        r#"{"level": "L1", "landmarks": {"c": [0, 0, 0], "p": [10, 0, 20]}}"#,
    )
    .unwrap();
    let out = dir.path().join("out");
    let o = Spinedrr::new()
        .args(["compare", "--reference"])
        .arg(dir.path().join("ref.tiff"))
        .arg("--perturbed")
        .arg(dir.path().join("pert.tiff"))
        .arg("--landmarks")
        .arg(&lm)
        .arg("--out")
        .arg(&out)
        .output();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let m: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    // Landmarks: focal scaling by α about the principal point, ‖Δx‖ = (α − 1) ‖x − c‖.
    for l in m["landmarks"].as_array().unwrap() {
        let x = DVec2::new(
            l["reference_px"][0].as_f64().unwrap(),
            l["reference_px"][1].as_f64().unwrap(),
        );
        let expect = 0.1 * (x - c).length();
        assert!(
            (l["shift_px"].as_f64().unwrap() - expect).abs() < 1e-9,
            "{l}"
        );
        assert!((l["predicted_shift_px"].as_f64().unwrap() - expect).abs() < 1e-9);
    }
    let centre = view.project(DVec3::ZERO);
    assert!((centre - c).length() < 1e-9);
    // Silhouettes by naming convention: body, ring, and their union "vertebra" (= body here).
    let sil = m["silhouettes"].as_array().unwrap();
    let names: Vec<&str> = sil.iter().map(|s| s["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["body", "ring", "vertebra"]);
    // Concentric discs r = 50 and 55: Dice = 2·50² / (50² + 55²) analytically, contours 5 px apart.
    let dice_exact = 2.0 * 2500.0 / (2500.0 + 3025.0);
    assert!(
        (sil[0]["dice"].as_f64().unwrap() - dice_exact).abs() < 5e-3,
        "{}",
        sil[0]
    );
    assert!((sil[0]["chamfer_mean_px"].as_f64().unwrap() - 5.0).abs() < 1.0);
    assert!((sil[0]["hausdorff_px"].as_f64().unwrap() - 5.0).abs() < 1.5);
    // The half-pixel boundary sits on the true circles to within about half a pixel.
    assert!((sil[0]["chamfer_mean_subpixel_px"].as_f64().unwrap() - 5.0).abs() < 0.5);
    assert_eq!(sil[0]["dice"], sil[2]["dice"]);
    let ncc = m["image"]["ncc"].as_f64().unwrap();
    assert!(ncc > 0.5 && ncc < 1.0);
    // The difference image is |A − B| and both outputs carry sidecars.
    let a = read_tiff_f32(&dir.path().join("ref.tiff")).unwrap();
    let b = read_tiff_f32(&dir.path().join("pert.tiff")).unwrap();
    let d = read_tiff_f32(&out.join("absdiff.tiff")).unwrap();
    for ((x, y), z) in a.data.iter().zip(&b.data).zip(&d.data) {
        assert_eq!((x - y).abs(), *z);
    }
    let heat = image::open(out.join("heatmap.png")).unwrap();
    assert_eq!(heat.width(), N + 130);
    for f in ["absdiff.json", "heatmap.json"] {
        assert!(Sidecar::read(&out.join(f)).is_ok(), "{f}");
    }
}

#[test]
fn compare_reports_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let view = small_view();
    let c = DVec2::new(127.5, 127.5);
    write_case(dir.path(), "ref", &view, &Perturbation::NONE, c, 50.0);
    write_case(
        dir.path(),
        "pert",
        &view,
        &Perturbation::focal(50.0),
        c,
        52.0,
    );
    let run = |extra: &[&str], remove: Option<&str>| {
        if let Some(f) = remove {
            std::fs::remove_file(dir.path().join(f)).unwrap();
        }
        Spinedrr::new()
            .current_dir(dir.path())
            .args([
                "compare",
                "--reference",
                "ref.tiff",
                "--perturbed",
                "pert.tiff",
                "--out",
                "o",
            ])
            .args(extra)
            .outcome()
    };
    let (ok, err) = run(&["--masks", "ref_mask_body.png"], None);
    assert!(!ok && err.contains("REF.png:PERT.png"), "{err}");
    let (ok, err) = run(&["--masks", "ref_mask_body.png:missing.png"], None);
    assert!(!ok && err.contains("missing.png"), "{err}");
    std::fs::write(dir.path().join("bad.json"), "{\"landmarks\": 3}").unwrap();
    let (ok, err) = run(&["--landmarks", "bad.json"], None);
    assert!(!ok && err.contains("bad.json"), "{err}");
    // A landmark file in a non-world frame, or a unit we do not know: refused, naming the value.
    for (file, text, word) in [
        (
            "voxel.json",
            r#"{"frame": "voxel IJK", "landmarks": {"c": [10, 20, 30]}}"#,
            "voxel IJK",
        ),
        (
            "inch.json",
            r#"{"units": "inch", "landmarks": {"c": [1, 2, 3]}}"#,
            "inch",
        ),
    ] {
        std::fs::write(dir.path().join(file), text).unwrap();
        let (ok, err) = run(&["--landmarks", file], None);
        assert!(!ok && err.contains(file) && err.contains(word), "{err}");
    }
    // A landmark behind the source (the AP source sits at y = −1000 mm, looking along +y) has no
    // projection: refused, naming it, instead of a mirrored point on the detector.
    std::fs::write(
        dir.path().join("behind.json"),
        r#"{"landmarks": {"ok": [0, 0, 0], "tail": [0, -1500, 0]}}"#,
    )
    .unwrap();
    let (ok, err) = run(&["--landmarks", "behind.json"], None);
    assert!(
        !ok && err.contains("'tail'") && err.contains("behind"),
        "{err}"
    );
    // Centimetres and LPS+ are converted: (1, 0, 2) cm is (10, 0, 20) mm; LPS+ (−10, 0, 20) is RAS+
    // (10, 0, 20): both project where the mm RAS+ point does.
    let expect = small_view().project(DVec3::new(10.0, 0.0, 20.0));
    for (i, text) in [
        r#"{"units": "cm", "landmarks": {"p": [1, 0, 2]}}"#,
        r#"{"frame": "world LPS+", "landmarks": {"p": [-10, 0, 20]}}"#,
    ]
    .iter()
    .enumerate()
    {
        let file = format!("conv{i}.json");
        std::fs::write(dir.path().join(&file), text).unwrap();
        let (ok, err) = run(&["--landmarks", &file], None);
        assert!(ok, "{err}");
        let m: Value = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join("o/metrics.json")).unwrap(),
        )
        .unwrap();
        let x = &m["landmarks"][0]["reference_px"];
        let got = DVec2::new(x[0].as_f64().unwrap(), x[1].as_f64().unwrap());
        assert!((got - expect).length() < 1e-9, "{text}: {got} vs {expect}");
    }
    let (ok, err) = run(&[], Some("pert.json"));
    assert!(!ok && err.contains("pert.json"), "{err}");
}

#[test]
fn compare_refuses_what_is_not_two_drrs_of_one_view() {
    let dir = tempfile::tempdir().unwrap();
    let view = small_view();
    let c = DVec2::new(127.5, 127.5);
    write_case(dir.path(), "ref", &view, &Perturbation::NONE, c, 50.0);
    let compare_with = |stem: &str| {
        Spinedrr::new()
            .current_dir(dir.path())
            .args(["compare", "--reference", "ref.tiff", "--perturbed"])
            .arg(format!("{stem}.tiff"))
            .args(["--out", "o"])
            .outcome()
    };
    let sidecar = |stem: &str, kind: &str, units: &str, v: &View| {
        Sidecar::new(kind, units, v, &Perturbation::focal(50.0))
            .unwrap()
            .write(&dir.path().join(format!("{stem}.json")))
            .unwrap();
    };
    let refused = |stem: &str, needles: &[&str]| {
        let (ok, err) = compare_with(stem);
        assert!(!ok && !err.contains("panicked"), "{stem}: {err}");
        for n in needles {
            assert!(err.contains(n), "{stem}: stderr lacks {n:?}: {err}");
        }
        assert!(!dir.path().join("o").exists(), "{stem}: wrote output");
    };
    // A mask's (or a depth map's) sidecar: not a DRR.
    write_case(
        dir.path(),
        "mask",
        &view,
        &Perturbation::focal(50.0),
        c,
        52.0,
    );
    sidecar("mask", "mask", "mm", &view);
    refused("mask", &["mask.tiff", "'mask' image", "not a DRR"]);
    // An intensity image against a line integral.
    write_case(
        dir.path(),
        "int",
        &view,
        &Perturbation::focal(50.0),
        c,
        52.0,
    );
    sidecar("int", "drr", "intensity I0·exp(−∫μ dl)", &view);
    refused("int", &["different units", "intensity"]);
    // A LAT render against an AP render.
    write_case(
        dir.path(),
        "lat",
        &view,
        &Perturbation::focal(50.0),
        c,
        52.0,
    );
    let mut lat = view.clone();
    lat.name = "lat".into();
    sidecar("lat", "drr", "mm", &lat);
    refused("lat", &["view 'ap'", "view 'lat'", "same view"]);
    // Integer samples, and a stack of two pages, beside a valid DRR sidecar.
    let (img, _) = blob(c, 52.0);
    let ints: Vec<u16> = img.data.iter().map(|&x| x as u16).collect();
    let file = std::fs::File::create(dir.path().join("int16.tiff")).unwrap();
    let mut enc = tiff::encoder::TiffEncoder::new(file).unwrap();
    enc.write_image::<tiff::encoder::colortype::Gray16>(N, N, &ints)
        .unwrap();
    sidecar("int16", "drr", "mm", &view);
    refused("int16", &["int16.tiff", "16-bit unsigned integer samples"]);
    let file = std::fs::File::create(dir.path().join("stack.tiff")).unwrap();
    let mut enc = tiff::encoder::TiffEncoder::new(file).unwrap();
    for _ in 0..2 {
        enc.write_image::<tiff::encoder::colortype::Gray32Float>(N, N, &img.data)
            .unwrap();
    }
    sidecar("stack", "drr", "mm", &view);
    refused("stack", &["stack.tiff", "more than one page"]);
    // Not vacuous: the same pair as DRRs of one view in one unit compares.
    write_case(
        dir.path(),
        "pert",
        &view,
        &Perturbation::focal(50.0),
        c,
        52.0,
    );
    let (ok, err) = compare_with("pert");
    assert!(ok, "{err}");
}
