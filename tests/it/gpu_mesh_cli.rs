//! The GPU backend's mesh DRRs end to end against the raster: `render --backend gpu`, a study with
//! `geometry.backend = "gpu"` and `register --intensity --backend gpu` (lavapipe in CI).

use glam::DVec3;
use spinedrr::anatomy::TriMesh;

use crate::render_models::worst_difference;

/// `render --phantom … --backend gpu` end to end: the DRR, depth map and every silhouette file equal
/// the raster's, the sidecar names the backend and the adapter; so does a spectral DRR's; implants and an
/// open mesh are refused by name with nothing written, and so is a render on a machine without a Vulkan
/// driver.
#[test]
fn cli_backend_gpu_renders_meshes_like_the_raster() {
    let dir = tempfile::tempdir().unwrap();
    let d = |n: &str| dir.path().join(n).display().to_string();
    let geometry = dir.path().join("small.toml");
    std::fs::write(
        &geometry,
        "[detector]\nwidth = 120\nheight = 100\npixel_spacing_mm = [1.2, 1.2]\nsdd_mm = 1000.0\n\n\
         [[view]]\nname = \"ap\"\nsource_mm = [-600.0, 25.0, 10.0]\ntarget_mm = [0.0, 0.0, 0.0]\n",
    )
    .unwrap();
    let render = |backend: &str, sub: &str| {
        std::fs::create_dir_all(dir.path().join(sub)).unwrap();
        crate::common::Spinedrr::new()
            .args([
                "render",
                "--phantom",
                "L2-L4",
                "--geometry",
                &d("small.toml"),
            ])
            .args(["--masks", "--depth", "--backend", backend])
            .args(["--out", &d(&format!("{sub}/drr.tiff"))])
            .outcome()
    };
    let (ok, err) = render("raster", "cpu");
    assert!(ok, "{err}");
    let (ok, err) = render("gpu", "gpu");
    assert!(ok, "{err}");
    let mut names: Vec<String> = std::fs::read_dir(dir.path().join("cpu"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert!(names.len() > 4, "{names:?}");
    for name in &names {
        let (c, g) = (
            dir.path().join("cpu").join(name),
            dir.path().join("gpu").join(name),
        );
        if name.ends_with(".json") {
            if name != "drr.json" {
                continue;
            }
            let side: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(&g).unwrap()).unwrap();
            assert_eq!(side["details"]["backend"], "gpu", "{side}");
            let adapter = side["details"]["gpu_adapter"].as_str().unwrap_or_default();
            assert_eq!(adapter, crate::gpu_ct::gpu().adapter_name(), "{side}");
        } else if name.ends_with(".tiff") {
            let (c, g) = (
                spinedrr::io::read_tiff_f32(&c).unwrap(),
                spinedrr::io::read_tiff_f32(&g).unwrap(),
            );
            let max = c.max();
            assert!(max > 0.0, "{name}");
            let d = worst_difference(&c, &g);
            // Line integrals (μ ≤ 0.06 mm⁻¹: 1e-4 mm of path is < 1e-5) and depths (~1000 mm in f32).
            assert!(d <= 1e-5 * max.max(1.0) + 1e-5, "{name}: {d}");
        } else {
            assert_eq!(
                std::fs::read(&c).unwrap(),
                std::fs::read(&g).unwrap(),
                "{name} differs"
            );
        }
    }
    let mut open = TriMesh::cuboid("lid-less", DVec3::splat(-10.0), DVec3::splat(10.0));
    open.triangles.truncate(10);
    spinedrr::anatomy::meshio::write_mesh(&dir.path().join("open.stl"), &open).unwrap();
    let open_stl = d("open.stl");
    // A spectral DRR: its channels (cortical, cancellous bone, soft tissue) render on the GPU, are
    // finished on the host and summed over the energies on the GPU, to the raster's image within the line
    // integrals' 1e-5; the sidecar and the spectral summary name the adapter and where the sum ran. With
    // the level's two titanium screws (implants: every pixel a screw may cover is paired on the host, so
    // the screws displace the bone as on the CPU) a fourth channel, the same image within 1e-5.
    let spectral = |backend: &str, name: &str, extra: &[&str]| {
        let out = d(&format!("{name}_{backend}.tiff"));
        let (ok, err) = crate::common::Spinedrr::new()
            .args(["render", "--phantom", "L3", "--spectrum", "80"])
            .args(extra)
            .args(["--geometry", &d("small.toml"), "--backend", backend])
            .args(["--out", &out])
            .outcome();
        assert!(ok, "{backend}: {err}");
        spinedrr::io::read_tiff_f32(std::path::Path::new(&out)).unwrap()
    };
    let adapter = crate::gpu_ct::gpu().adapter_name();
    for (name, extra, channel) in [
        ("spectral", "--soft-tissue", "soft_tissue"),
        ("screws", "--screws", "titanium"),
    ] {
        let (c, g) = (
            spectral("raster", name, &[extra]),
            spectral("gpu", name, &[extra]),
        );
        assert!(c.max() > 0.5, "{name}: {}", c.max());
        let worst = worst_difference(&c, &g);
        assert!(worst <= 1e-5 * c.max(), "{name}: {worst} of {}", c.max());
        let side: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(d(&format!("{name}_gpu.json"))).unwrap())
                .unwrap();
        assert_eq!(side["details"]["gpu_adapter"], adapter.as_str(), "{side}");
        assert_eq!(side["details"]["spectral"]["gpu_adapter"], adapter.as_str());
        let channels = side["details"]["spectral"]["channels"].as_array().unwrap();
        assert!(
            channels.iter().any(|c| c == channel),
            "{name}: {channels:?}"
        );
        // As many channel renders as the raster's, the sum on the GPU.
        let raster: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(d(&format!("{name}_raster.json"))).unwrap(),
        )
        .unwrap();
        let cpu_passes = raster["details"]["spectral"]["passes"].as_str().unwrap();
        // The host's pixels of the GPU's channel renders are counted (a screw's among them); a CPU
        // render has none to count.
        let on_cpu = side["details"]["stats"]["gpu_rays_on_cpu"]
            .as_u64()
            .unwrap_or(0);
        assert!(on_cpu > 0, "{name}: {side}");
        assert!(raster["details"]["stats"].get("gpu_rays_on_cpu").is_none());
        assert!(cpu_passes.ends_with("channel renders, then the energy sum"));
        assert_eq!(
            side["details"]["spectral"]["passes"],
            format!("{cpu_passes} on the GPU")
        );
    }
    // The screws displace bone: the image with them is not the image without them plus their own
    // attenuation (which a sum of their meshes would give).
    let (with, without) = (
        spectral("gpu", "screws", &["--screws"]),
        spectral("gpu", "bare", &[]),
    );
    assert!(worst_difference(&with, &without) > 0.1);
    // An open mesh's signed sums mean nothing: refused by name.
    let (ok, err) = crate::common::Spinedrr::new()
        .args(["render", "--geometry", &d("small.toml"), "--backend", "gpu"])
        .args(["--mesh", &open_stl, "--mu-default", "0.02"])
        .args(["--out", &d("refused.tiff")])
        .outcome();
    assert!(!ok && err.contains("closed"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(!dir.path().join("refused.tiff").exists());
    // No Vulkan driver at all: the error says what to install, nothing is written.
    let (ok, err) = crate::common::Spinedrr::new()
        .args([
            "render",
            "--phantom",
            "L3",
            "--geometry",
            &d("small.toml"),
            "--backend",
            "gpu",
        ])
        .args(["--out", &d("none.tiff")])
        .env("VK_ICD_FILENAMES", dir.path().join("no-such-icd.json"))
        .env("VK_DRIVER_FILES", dir.path().join("no-such-icd.json"))
        .outcome();
    assert!(!ok && err.contains("mesa-vulkan-drivers"), "{err}");
    assert!(
        !err.contains("panicked") && !dir.path().join("none.tiff").exists(),
        "{err}"
    );
}

/// A study with `geometry.backend = "gpu"` — the phantom's L1 and a CT target (the synthetic CT's L1,
/// whose image metrics come from its volume DRR): the same tables as the raster's (silhouette metrics
/// identical, intensity metrics within 1e-6), the report names the backend and says the CT's volume DRR
/// ran on the GPU, and the reference DRRs' sidecars — thickness and CT volume — name the adapter. The
/// calibration experiment's intensity registrations of the CT target (its moving DRR the target's volume
/// on the GPU) end within 0.01 mm of the raster study's where the optimum is the true pose, and with the
/// landmark registration's bias where it is not.
#[test]
fn a_study_on_the_gpu_backend_matches_the_raster() {
    use crate::study_hardening::{SMALL, study, write};
    let dir = tempfile::tempdir().unwrap();
    let ct = crate::study_ct::inputs();
    // One plate calibration at σ = 0.1 px, both protocols, each with its AP+LAT intensity registration of
    // the CT target (256² finest level: the study's detector binned by 4).
    let calibration = "[calibration]\nphantoms = [\"plate\"]\nnoise_px = [0.1]\ntrials = 1\n\
        trials_per_unit = 1\nprotocols = [\"intrinsic\", \"full\"]\ntarget = \"syn-L1\"\n\
        silhouette_trials = 0\nintensity_trials = 1\n";
    let run = |backend: &str| {
        let cfg = write(
            dir.path(),
            &format!("{backend}.toml"),
            &format!(
                "{}{calibration}",
                SMALL
                    .replace("binning = 8", "binning = 4")
                    .replace(
                        "experiments = [\"projection\"]",
                        "experiments = [\"projection\", \"calibration\"]"
                    )
                    .replace(
                        "[geometry]\n",
                        &format!(
                            "[[anatomy.ct]]\nname = \"syn\"\nct = {:?}\nseg = {:?}\n\
                             labels = \"totalseg\"\nlevels = [\"L1\"]\n[geometry]\n\
                             backend = \"{backend}\"\n",
                            ct.join("ct.nii").to_str().unwrap(),
                            ct.join("seg.nii").to_str().unwrap(),
                        ),
                    )
            ),
        );
        let out = dir.path().join(backend);
        let (ok, err) = crate::common::outcome(&study(&cfg, &out, &[]));
        assert!(ok, "{backend}: {err}");
        out
    };
    let (cpu, gpu) = (run("raster"), run("gpu"));
    let read = |dir: &std::path::Path, name: &str| {
        std::fs::read_to_string(dir.join("tables").join(name)).unwrap()
    };
    assert_eq!(read(&cpu, "structures.csv"), read(&gpu, "structures.csv"));
    let (c, g) = (read(&cpu, "projection.csv"), read(&gpu, "projection.csv"));
    let header: Vec<&str> = c.lines().next().unwrap().split(',').collect();
    assert_eq!(c.lines().count(), g.lines().count());
    for (lc, lg) in c.lines().zip(g.lines()).skip(1) {
        for ((name, a), b) in header.iter().zip(lc.split(',')).zip(lg.split(',')) {
            let intensity = ["ncc", "ssim", "mutual_information", "gradient", "mean_abs"]
                .iter()
                .any(|p| name.starts_with(p));
            match (a.parse::<f64>(), b.parse::<f64>()) {
                (Ok(x), Ok(y)) if intensity => {
                    assert!(
                        (x - y).abs() <= 1e-6 * x.abs().max(1e-3),
                        "{name}: {a} vs {b}"
                    )
                }
                _ => assert_eq!(a, b, "{name}"),
            }
        }
    }
    let report = crate::common::read_report(&gpu);
    assert!(
        report.contains("gpu backend") && report.contains("GPU backend"),
        "{report}"
    );
    assert!(
        report.contains("volume DRR by Siddon's exact traversal of the piecewise-constant voxels in the GPU's compute shader"),
        "{report}"
    );
    assert!(c.lines().any(|l| l.starts_with("syn-L1,")), "no CT rows");
    // The calibration's rows: everything but the intensity registration's columns is the raster study's.
    // With the full protocol the estimated geometry reproduces the true projections and the optimum is
    // the true pose: the two backends' registrations end within 0.01 mm (mTRE, translation) and 0.01°.
    // With the intrinsic one the optimum is biased, at the end of a shallow valley where the LM's stopping
    // rule, not the image, decides the last hundredths of a millimetre (with the similarity on the host,
    // the two ended 0.023 mm apart here; with the GPU's loop 0.0046 mm); there each backend's bias must
    // be the landmark registration's, as in calibration_study.rs.
    let calibration_rows = |dir: &std::path::Path| {
        let mut r = csv::Reader::from_path(dir.join("tables/calibration.csv")).unwrap();
        let header: Vec<String> = r.headers().unwrap().iter().map(String::from).collect();
        let rows: Vec<Vec<String>> = r
            .records()
            .map(|x| x.unwrap().iter().map(String::from).collect())
            .collect();
        (header, rows)
    };
    let ((header, c), (header_g, g)) = (calibration_rows(&cpu), calibration_rows(&gpu));
    assert_eq!(header, header_g);
    assert_eq!(
        c.len(),
        4,
        "one calibration, two protocols, AP and LAT rows"
    );
    let col = |n: &str| header.iter().position(|h| h == n).unwrap();
    let num = |row: &[String], n: &str| row[col(n)].parse::<f64>().unwrap();
    for (rc, rg) in c.iter().zip(&g) {
        for ((name, a), b) in header.iter().zip(rc).zip(rg) {
            if !name.starts_with("ireg_") {
                assert_eq!(a, b, "{name}");
            }
        }
        let ireg = ["ireg_mtre_mm", "ireg_rot_err_deg", "ireg_trans_err_mm"];
        assert!(
            ireg.iter()
                .all(|n| num(rc, n).is_finite() && num(rg, n).is_finite())
        );
        if rc[col("protocol")] == "full" {
            for n in ireg {
                let (x, y) = (num(rc, n), num(rg, n));
                assert!((x - y).abs() <= 0.01, "full, {n}: raster {x}, gpu {y}");
            }
        } else {
            let lm = num(rc, "reg_mtre_mm");
            for row in [rc, rg] {
                let im = num(row, "ireg_mtre_mm");
                assert!(
                    (im - lm).abs() <= 0.25 * lm + 0.25,
                    "intrinsic: intensity {im} vs landmark {lm} mm"
                );
            }
        }
    }
    for reference in ["L1_ap.json", "syn-L1_ap.json"] {
        let side: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(gpu.join("references").join(reference)).unwrap(),
        )
        .unwrap();
        assert_eq!(
            side["details"]["gpu_adapter"].as_str().unwrap_or_default(),
            crate::gpu_ct::gpu().adapter_name(),
            "{reference}"
        );
    }
    let side: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(gpu.join("references").join("syn-L1_ap.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(side["details"]["renderer"], "ct-volume (Siddon)", "{side}");
}

/// `register --intensity --backend gpu`: the loop renders and compares on the GPU (its sums checked
/// against the raster's paired render first) and lands within 0.01 mm mTRE of the raster's
/// registration; R.json names the backend, the adapter and where each stage ran. So does a CT anatomy's, rendered by the GPU's Siddon shader; a CT
/// is refused for embree by name.
#[test]
fn intensity_registration_on_the_gpu_matches_the_raster() {
    use glam::DVec3;
    use spinedrr::geometry::{RigidTransform, rotation_exp};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let truth = RigidTransform::new(
        rotation_exp(DVec3::new(0.05, 0.1, -0.02)),
        DVec3::new(3.0, 0.0, -4.0),
    );
    let problem = crate::registration_intensity_cli::write_problem(d, &truth);
    std::fs::write(
        d.join("p.json"),
        serde_json::to_vec_pretty(&problem).unwrap(),
    )
    .unwrap();
    use crate::gpu_registration::{register_cli, result_pose, stages_on};
    let register = |backend: &str| register_cli(d, backend);
    let (cpu, gpu) = (register("raster"), register("gpu"));
    assert_eq!(gpu["backend"], "gpu");
    assert_eq!(cpu["backend"], "raster");
    // The meshes' levels ran on the GPU (the host's few pixels scattered into its images), the raster's
    // on the CPU.
    assert!(
        stages_on(&gpu).iter().all(|s| s == "gpu") && !stages_on(&gpu).is_empty(),
        "{gpu}"
    );
    assert!(stages_on(&cpu).iter().all(|s| s == "cpu"), "{cpu}");
    assert_eq!(
        gpu["gpu_adapter"].as_str().unwrap_or_default(),
        crate::gpu_ct::gpu().adapter_name()
    );
    let pose = result_pose;
    // The model's corners and the ball's centre (the body is a 40 × 24 × 30 mm box).
    let targets = crate::gpu_registration::targets();
    let between = spinedrr::registration::intensity::mtre_mm(&pose(&cpu), &pose(&gpu), &targets);
    assert!(
        between <= 0.01,
        "the two registrations differ by {between} mm mTRE"
    );
    assert!(cpu["mtre_mm"].as_f64().unwrap() < 0.5, "{cpu}");

    // A CT anatomy: the same body voxelised (2 mm: the box at 400 HU, the ball at 1200 HU, labelled
    // 22), the fixed images its CPU DRRs at the truth in AP and LAT; registered with the CPU's volume renderer and the
    // GPU's, the two poses within 0.01 mm mTRE, R.json naming the GPU's adapter; embree is refused.
    use spinedrr::anatomy::ct::{VoxelMask, write_ct, write_labels};
    use spinedrr::render::volume::{VolumeRenderOptions, VolumeRenderer};
    let (ct_vol, seg) = crate::gpu_registration::box_and_ball(2.0);
    write_ct(&d.join("ct.nii.gz"), &ct_vol).unwrap();
    write_labels(&d.join("seg.nii.gz"), &seg).unwrap();
    let mask = VoxelMask::from_labels(&seg, &[22]).unwrap();
    let volume =
        VolumeRenderer::new(&ct_vol, &VolumeRenderOptions::default(), Some(&mask)).unwrap();
    // The problem's one view (write_problem's).
    let moving =
        spinedrr::registration::intensity::MovingDrr::Volume(std::sync::Arc::new(volume.into()));
    let mut ct = problem.clone();
    ct["anatomy"] = serde_json::json!({"ct": "ct.nii.gz", "seg": "seg.nii.gz", "label": 22});
    let lat = spinedrr::registration::intensity::binned_view(
        spinedrr::geometry::CArm::default_paper()
            .view("lat")
            .unwrap(),
        8,
    )
    .unwrap();
    // The problem's AP view (write_problem's) and the LAT one, both binned by 8: the loop renders the two
    // views in parallel, on one GPU renderer.
    let mut views = Vec::new();
    for view in [crate::registration_intensity_cli::ap(), lat] {
        let fixed = moving.render_at(&view, &truth).unwrap();
        let file = format!("ct_{}.tiff", view.name);
        spinedrr::io::write_tiff_f32(&d.join(&file), &fixed).unwrap();
        views.push(serde_json::json!({
            "name": view.name,
            "fixed": file,
            "K": view.intrinsics.matrix_rows(),
            "world_to_camera": view.world_to_camera.to_rows(),
            "width": view.intrinsics.width,
            "height": view.intrinsics.height,
        }));
    }
    ct["views"] = views.into();
    // The finest level alone: on this 2-mm-voxel body the binned levels' AP+LAT cost is rough, and from
    // this start the pyramid [2, 1] settles 1.26 mm off (the CPU and the GPU 0.0096 mm apart; started at
    // the truth it stays there), [4, 2, 1] stops at its iteration cap; level [1] reaches the truth.
    ct["levels"] = serde_json::json!([1]);
    std::fs::write(d.join("p.json"), serde_json::to_vec_pretty(&ct).unwrap()).unwrap();
    let (cpu, gpu) = (register("raster"), register("gpu"));
    assert_eq!(gpu["backend"], "gpu", "{gpu}");
    // The CT's loop ran on the GPU (render, similarity and the LM's products), the CPU's on the CPU.
    let on = stages_on;
    assert!(
        on(&gpu).iter().all(|s| s == "gpu") && !on(&gpu).is_empty(),
        "{gpu}"
    );
    assert!(on(&cpu).iter().all(|s| s == "cpu"), "{cpu}");
    assert_eq!(
        gpu["gpu_adapter"].as_str().unwrap_or_default(),
        crate::gpu_ct::gpu().adapter_name()
    );
    let between = spinedrr::registration::intensity::mtre_mm(&pose(&cpu), &pose(&gpu), &targets);
    assert!(
        between <= 0.01,
        "CT: the two registrations differ by {between} mm mTRE"
    );
    assert!(cpu["mtre_mm"].as_f64().unwrap() < 0.5, "{cpu}");
    let (ok, err) = crate::common::run(&[
        "register",
        "--intensity",
        "--backend",
        "embree",
        "--problem",
        &d.join("p.json").display().to_string(),
        "--out",
        &d.join("ct-out.json").display().to_string(),
    ]);
    assert!(!ok && err.contains("CT anatomy"), "{err}");
    assert!(!d.join("ct-out.json").exists());
}
