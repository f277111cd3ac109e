//! The intensity registration's loop on the GPU (a CT or mesh anatomy on the gpu backend: render, pyramid,
//! smoothing, similarity and the LM's products there) against the CPU's loop on lavapipe: each level's
//! cost, similarity and residual at the same poses for every similarity, with and without 2 × 2 rays per
//! pixel and smoothing, and a Levenberg–Marquardt refinement (Broyden's updates on) ending at the same
//! pose within 0.01 mm mTRE.

use std::sync::Arc;

use glam::{DMat4, DQuat, DVec3};
use spinedrr::anatomy::ct::{CtVolume, LabelMap, VoxelMask};
use spinedrr::geometry::{CArm, RigidTransform, View, rotation_exp};
use spinedrr::io::ImageF32;
use spinedrr::registration::intensity::{
    IntensityOptions, MovingDrr, Objective, Similarity, binned_image, binned_view, mtre_mm, refine,
};
use spinedrr::render::volume::{VolumeRenderOptions, VolumeRenderer};
use spinedrr::render::{Backend, VolumeOnBackend};

/// A box (400 HU, 40 × 24 × 30 mm) with a ball (1200 HU) on one corner, labelled 22, voxelised at
/// `voxel` mm (1 or 2; the grid spans −33…35 mm along x from the same origin whatever the voxel).
pub(crate) fn box_and_ball(voxel: f64) -> (CtVolume, LabelMap) {
    let dims = [68.0, 52.0, 72.0].map(|e: f64| (e / voxel).round() as usize);
    let affine = DMat4::from_scale_rotation_translation(
        DVec3::splat(voxel),
        DQuat::IDENTITY,
        DVec3::new(-33.0, -25.0, -35.0),
    );
    let mut ct = CtVolume::filled(dims, -1000.0, affine).unwrap();
    let mut seg = LabelMap::filled(dims, 0, affine).unwrap();
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let p = ct.voxel_centre(i, j, k);
                let in_box = p.x.abs() < 20.0 && p.y.abs() < 12.0 && p.z.abs() < 15.0;
                let in_ball = (p - DVec3::new(14.0, 6.0, 18.0)).length() < 7.0;
                let n = ct.linear(i, j, k);
                if in_box || in_ball {
                    ct.values[n] = if in_ball { 1200.0 } else { 400.0 };
                    seg.values[n] = 22;
                }
            }
        }
    }
    (ct, seg)
}

/// The box and ball at 1-mm voxels (at 2 mm, gpu_mesh_cli.rs's, the cost is rough enough that
/// refinements end 0.27 mm off the truth, where the last hundredths depend on rounding), masked to its
/// label.
fn body() -> VolumeRenderer {
    let (ct, seg) = box_and_ball(1.0);
    let mask = VoxelMask::from_labels(&seg, &[22]).unwrap();
    VolumeRenderer::new(&ct, &VolumeRenderOptions::default(), Some(&mask)).unwrap()
}

/// `spinedrr register --intensity --backend BACKEND --problem DIR/p.json`: its R.json (written to
/// `DIR/BACKEND.json`), the run asserted to succeed.
pub(crate) fn register_cli(dir: &std::path::Path, backend: &str) -> serde_json::Value {
    let out = dir.join(format!("{backend}.json"));
    let (ok, err) = crate::common::Spinedrr::new()
        .args(["register", "--intensity", "--backend", backend, "--problem"])
        .arg(dir.join("p.json"))
        .arg("--out")
        .arg(&out)
        .outcome();
    assert!(ok, "{backend}: {err}");
    serde_json::from_slice(&std::fs::read(out).unwrap()).unwrap()
}

/// The pose an R.json records.
pub(crate) fn result_pose(r: &serde_json::Value) -> RigidTransform {
    let rows: [[f64; 3]; 3] = serde_json::from_value(r["R"].clone()).unwrap();
    let t: [f64; 3] = serde_json::from_value(r["t"].clone()).unwrap();
    RigidTransform::from_rt(rows, t, "R.json").unwrap()
}

/// Where each stage of an R.json ran (`similarity_on`).
pub(crate) fn stages_on(r: &serde_json::Value) -> Vec<String> {
    r["stages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["similarity_on"].as_str().unwrap().to_string())
        .collect()
}

/// The model's corners and the ball's centre.
pub(crate) fn targets() -> Vec<DVec3> {
    (0..8)
        .map(|i| {
            DVec3::new(
                if i & 1 == 0 { -20.0 } else { 20.0 },
                if i & 2 == 0 { -12.0 } else { 12.0 },
                if i & 4 == 0 { -15.0 } else { 15.0 },
            )
        })
        .chain([DVec3::new(14.0, 6.0, 18.0)])
        .collect()
}

/// The default C-arm's AP and LAT binned by 8 (128²), the body placed at the isocentre.
fn views() -> Vec<View> {
    let carm = CArm::default_paper();
    ["ap", "lat"]
        .map(|v| binned_view(carm.view(v).unwrap(), 8).unwrap())
        .to_vec()
}

/// The level's views (rendered `ss` times finer than the level of binning `b`) and fixed images.
fn level(fixed: &[ImageF32], b: u32, ss: u32) -> Vec<(View, ImageF32)> {
    views()
        .iter()
        .zip(fixed)
        .map(|(v, f)| (binned_view(v, b / ss).unwrap(), binned_image(f, b)))
        .collect()
}

#[test]
fn the_gpu_loop_evaluates_and_refines_like_the_cpu_loop() {
    let cpu_moving = MovingDrr::Volume(Arc::new(body().into()));
    let gpu_moving = MovingDrr::Volume(Arc::new(
        VolumeOnBackend::new(body(), Backend::Gpu).unwrap(),
    ));
    loops_agree(&cpu_moving, &gpu_moving);
}

/// The box and ball as meshes (μ of 400 and 1200 HU at 0.02 mm⁻¹ per 1000 HU above air): the GPU's loop
/// renders each view with the mesh shader, evaluates the host's few pixels and writes them into the
/// image on the GPU, where the level is compared; against the same renders compared on the host, and
/// against the raster's loop, as for the CT.
#[test]
fn the_gpu_loop_evaluates_and_refines_mesh_levels_like_the_cpu_loop() {
    use spinedrr::anatomy::TriMesh;
    use spinedrr::registration::intensity::MeshDrr;
    use spinedrr::render::{RenderScene, SceneMesh};
    let scene = RenderScene::new(vec![
        SceneMesh {
            mesh: Arc::new(TriMesh::cuboid(
                "box",
                DVec3::new(-20.0, -12.0, -15.0),
                DVec3::new(20.0, 12.0, 15.0),
            )),
            mu_per_mm: 0.028,
            object: "box".into(),
        },
        SceneMesh {
            mesh: Arc::new(TriMesh::icosphere(
                "ball",
                DVec3::new(14.0, 6.0, 18.0),
                7.0,
                3,
            )),
            mu_per_mm: 0.044,
            object: "ball".into(),
        },
    ])
    .unwrap();
    let moving =
        |backend: Backend| MovingDrr::Mesh(MeshDrr::new(backend.renderer(scene.clone()).unwrap()));
    loops_agree(&moving(Backend::Raster), &moving(Backend::Gpu));
}

/// A mesh that overlaps itself (two boxes in one mesh): its signed sums count the overlap twice, so the
/// objective does not trust them, and the GPU's level takes the CPU's paired renders, uploaded — the
/// same costs and residuals as the host's comparison of those renders.
#[test]
fn a_self_overlapping_mesh_is_compared_on_the_gpu_from_paired_renders() {
    use spinedrr::anatomy::TriMesh;
    use spinedrr::registration::intensity::MeshDrr;
    use spinedrr::render::{RenderScene, SceneMesh};
    let a = TriMesh::cuboid(
        "a",
        DVec3::new(-20.0, -12.0, -15.0),
        DVec3::new(10.0, 12.0, 15.0),
    );
    let b = TriMesh::cuboid(
        "b",
        DVec3::new(0.0, -8.0, -10.0),
        DVec3::new(20.0, 8.0, 10.0),
    );
    let n = a.vertices.len() as u32;
    let merged = TriMesh {
        name: "overlapping".into(),
        vertices: a.vertices.iter().chain(&b.vertices).copied().collect(),
        triangles: a
            .triangles
            .iter()
            .copied()
            .chain(b.triangles.iter().map(|t| t.map(|i| i + n)))
            .collect(),
        labels: Vec::new(),
    };
    let scene = RenderScene::new(vec![SceneMesh {
        mesh: Arc::new(merged),
        mu_per_mm: 0.03,
        object: "overlapping".into(),
    }])
    .unwrap();
    let gpu_renderer = Backend::Gpu.renderer(scene.clone()).unwrap();
    let view = &views()[0];
    let (mut summed, mut paired) = (ImageF32::zeros(0, 0), ImageF32::zeros(0, 0));
    gpu_renderer
        .render_line_integral_summed_into(view, &mut summed)
        .unwrap();
    gpu_renderer
        .render_line_integral_into(view, &mut paired)
        .unwrap();
    let d = crate::render_models::worst_difference(&summed, &paired);
    assert!(d > 0.1, "the sums must differ from the paired render ({d})");
    let truth = RigidTransform::new(
        rotation_exp(DVec3::new(0.02, 0.0, -0.03)),
        DVec3::new(1.0, 2.0, 0.0),
    );
    let cpu_moving = MovingDrr::Mesh(MeshDrr::new(Backend::Raster.renderer(scene).unwrap()));
    let gpu_moving = MovingDrr::Mesh(MeshDrr::new(gpu_renderer));
    let fixed: Vec<ImageF32> = views()
        .iter()
        .map(|v| cpu_moving.render_at(v, &truth).unwrap())
        .collect();
    let objective = || {
        Objective::new(
            &gpu_moving,
            1,
            level(&fixed, 1, 1),
            Similarity::Ncc,
            0.0,
            RigidTransform::IDENTITY,
            DVec3::ZERO,
            20.0,
        )
        .unwrap()
    };
    let (gpu, host) = (objective(), objective().on_host());
    assert!(gpu.on_device() && !host.on_device());
    for p in [[0.0; 6], [0.3, -0.2, 0.1, 0.5, -0.4, 0.2]] {
        let (mut rg, mut rh) = (Vec::new(), Vec::new());
        let eg = gpu.evaluate(&p, Some(&mut rg)).unwrap();
        let eh = host.evaluate(&p, Some(&mut rh)).unwrap();
        assert!((eg.cost - eh.cost).abs() <= 1e-6, "{eg:?} vs {eh:?}");
        let peak = rh.iter().fold(0f64, |m, x| m.max(x.abs()));
        let worst = rg
            .iter()
            .zip(&rh)
            .fold(0f64, |m, (x, y)| m.max((x - y).abs()));
        assert!(worst <= 1e-5 * peak, "{worst} of {peak}");
    }
}

/// `gpu_moving`'s loop (on the GPU) against the same renders compared on the host and against
/// `cpu_moving`'s loop: each level's cost, similarities and residuals at three poses for every
/// similarity, with and without 2 × 2 rays and smoothing; then a finest-level refinement from the start
/// to the truth on both, the Jacobian's poses batched or one by one giving the same refinement.
fn loops_agree(cpu_moving: &MovingDrr, gpu_moving: &MovingDrr) {
    let truth = RigidTransform::new(
        rotation_exp(DVec3::new(0.03, -0.05, 0.02)),
        DVec3::new(2.0, -1.0, 3.0),
    );
    let fixed: Vec<ImageF32> = views()
        .iter()
        .map(|v| cpu_moving.render_at(v, &truth).unwrap())
        .collect();
    let start = RigidTransform::IDENTITY;
    let targets = targets();
    let centre = targets.iter().fold(DVec3::ZERO, |a, &p| a + p) / targets.len() as f64;
    let rho = 20.0;
    let poses: [[f64; 6]; 3] = [
        [0.0; 6],
        [0.4, -0.3, 0.2, 1.0, -0.5, 0.7],
        [-1.0, 0.5, 0.8, -0.6, 1.2, -0.4],
    ];
    for (sim, b, ss, smooth) in [
        ("ncc", 1, 1, 0.0),
        ("ncc", 2, 2, 1.0),
        ("gc", 2, 2, 1.0),
        ("gncc", 2, 1, 0.0),
        ("lncc:8", 1, 1, 0.0),
        ("lncc:8", 2, 2, 1.0),
    ] {
        let sim = Similarity::parse(sim).unwrap();
        let objective = |moving| {
            Objective::supersampled(
                moving,
                1,
                ss,
                level(&fixed, b, ss),
                sim,
                smooth,
                start,
                centre,
                rho,
            )
            .unwrap()
        };
        let (cpu, gpu) = (objective(cpu_moving), objective(gpu_moving));
        let host = objective(gpu_moving).on_host();
        assert!(
            !cpu.on_device() && gpu.on_device() && !host.on_device(),
            "{sim:?}"
        );
        for p in &poses {
            let what = format!("{sim:?} b {b} ss {ss} smooth {smooth} at {p:?}");
            let eval = |o: &Objective| {
                let mut r = Vec::new();
                let e = o.evaluate(p, Some(&mut r)).unwrap();
                (e, r)
            };
            let ((ec, rc), (eg, rg), (eh, rh)) = (eval(&cpu), eval(&gpu), eval(&host));
            let close = |a: &[f64], b: &[f64], tol: f64| {
                assert_eq!(a.len(), b.len(), "{what}");
                let peak = a.iter().fold(0f64, |m, x| m.max(x.abs()));
                let worst = a.iter().zip(b).fold(0f64, |m, (x, y)| m.max((x - y).abs()));
                assert!(worst <= tol * peak, "{what}: {worst} apart, peak {peak}");
            };
            // The GPU's pyramid, smoothing and similarity against the CPU's on the same (GPU) renders:
            // f32 (compensated sums) against f64 arithmetic, the costs and similarities within 1e-6, the
            // residuals within 1e-5 of their peak. The smoothed images may differ by an ulp (each
            // rounds its own sum to f32), which patch-wise NCC divides by the small spread of an 8 × 8
            // patch: 1e-5 and 1e-4 there.
            let (tol, rtol) = match (sim, smooth > 0.0) {
                (Similarity::LocalNcc { .. }, true) => (1e-5, 1e-4),
                _ => (1e-6, 1e-5),
            };
            assert!((eh.cost - eg.cost).abs() <= tol, "{what}: {eh:?} vs {eg:?}");
            close(&eh.per_view, &eg.per_view, tol);
            close(&rh, &rg, rtol);
            // And against the CPU's loop (CPU renders): the renders differ within 1e-5 of their peak
            // (gpu_ct.rs), which a similarity normalising small blocks amplifies; NCC and the gradient
            // similarities stay within 1e-5.
            if !matches!(sim, Similarity::LocalNcc { .. }) {
                assert!(
                    (ec.cost - eg.cost).abs() <= 1e-5,
                    "{what}: {ec:?} vs {eg:?}"
                );
                close(&ec.per_view, &eg.per_view, 1e-5);
                close(&rc, &rg, 1e-4);
            }
        }
    }

    // A refinement at the finest level from the start (the truth is turned 3.5° and moved 3.7 mm from it): both end at
    // the truth, within 0.01 mm mTRE of each other.
    // The default finest-level settings (Broyden's updates on).
    let lm = IntensityOptions::default().lm;
    let sim = Similarity::Ncc;
    let objective = |moving| {
        Objective::new(moving, 1, level(&fixed, 1, 1), sim, 0.0, start, centre, rho).unwrap()
    };
    let (cpu, gpu) = (objective(cpu_moving), objective(gpu_moving));
    let p0 = [0.0; 6];
    let (c, g) = (
        refine(&cpu, p0, &lm).unwrap(),
        refine(&gpu, p0, &lm).unwrap(),
    );
    // The Jacobian's six poses in one dispatch or one after another: the same arithmetic per view, so
    // the same refinement to the bit.
    let sequential = objective(gpu_moving).columns_one_by_one();
    let s = refine(&sequential, p0, &lm).unwrap();
    assert_eq!(s.p, g.p);
    assert_eq!(sequential.evaluations(), gpu.evaluations());
    let (pc, pg) = (cpu.pose(&c.p), gpu.pose(&g.p));
    let between = mtre_mm(&pc, &pg, &targets);
    let (off, gpu_off) = (
        mtre_mm(&pc, &truth, &targets),
        mtre_mm(&pg, &truth, &targets),
    );
    eprintln!(
        "cpu {} ({} it, {} evals), gpu {} ({} it, {} evals): {between} mm apart, cpu {off} mm off the truth",
        c.stop,
        c.iterations,
        cpu.evaluations(),
        g.stop,
        g.iterations,
        gpu.evaluations()
    );
    assert!(between <= 0.01, "{between} mm apart");
    assert!(
        off < 0.01 && gpu_off < 0.01,
        "the refinements end {off} (CPU) and {gpu_off} mm (GPU) off the truth"
    );
}

/// The phantom's L3 as a 1-mm CT registered with the GPU's loop on registration_intensity_ct.rs's
/// problem and schedule (bins 8, 4, 2 of a 512² detector: CMA-ES and smoothing on the coarse levels,
/// 2 × 2 rays per pixel and Broyden's updates on the finest) from its first and third starts (3.9 and
/// 9.4 mm mTRE: one inside the finest levels' basin, one the global stage must bring there): every stage
/// runs on the GPU and ends where the CPU's registrations end, within 0.05 mm of the truth.
#[test]
fn a_ct_level_registers_with_the_gpu_loop() {
    use spinedrr::registration::intensity::{CmaesOptions, register_intensity};
    let problem = crate::registration_intensity_ct::l3_problem(Backend::Gpu);
    let opts = IntensityOptions {
        levels: vec![8, 4, 2],
        ..IntensityOptions::default()
    };
    for (i, init) in crate::registration_intensity_ct::starts(&problem, 3)
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != 1)
    {
        let o = IntensityOptions {
            cmaes: CmaesOptions {
                seed: 100 + i as u64,
                ..opts.cmaes
            },
            ..opts.clone()
        };
        let r = register_intensity(&problem, init, &o).unwrap();
        assert!(
            r.stages.iter().all(|s| s.similarity_on == "gpu"),
            "{:?}",
            r.stages
        );
        let m = mtre_mm(&r.pose, &RigidTransform::IDENTITY, &problem.targets);
        let m0 = mtre_mm(init, &RigidTransform::IDENTITY, &problem.targets);
        eprintln!(
            "start {i}: {m0} mm → {m} mm, {} evaluations, {:.1} s",
            r.evaluations, r.seconds
        );
        assert!(m <= 0.05, "start {i} ({m0} mm): ends {m} mm off the truth");
    }
}
