//! Implants in the spectral images: a parametric pedicle screw in a block against its own chord, the
//! phantom's screws, screws placed from a user's plan (meshes and a CT), and a CT's voxels displaced by an
//! implant exactly as the same material meshes are.

use std::sync::Arc;

use glam::DVec3;
use spinedrr::anatomy::TriMesh;
use spinedrr::io::read_tiff_f32;
use spinedrr::render::{Backend, SpectralInput, SpectralRenderer, SpectralScene};
use spinedrr::spectral::{Material, model_from_specs, parse_attenuation};

use crate::cli_hardening::{cube, refused, s};
use crate::spectral::camera;

#[test]
fn a_pedicle_screw_in_a_block_replaces_the_tissue_it_occupies() {
    // One energy: with the screw, L = μ_tissue · (L_block − L_screw) + μ_ti · L_screw, where L_screw is the
    // screw's own chord (a thickness render of the screw alone, μ = 1, no implant logic involved).
    let (lo, hi) = (
        DVec3::new(-40.0, -40.0, 400.0),
        DVec3::new(40.0, 40.0, 500.0),
    );
    let spec = spinedrr::anatomy::screw::ScrewSpec::default();
    // Along x through the block's middle, the head standing out of the block's side (entry at x = 30).
    let (shank, head) = spec
        .meshes(
            "s",
            DVec3::new(30.0, 2.0, 450.0),
            DVec3::new(-12.0, 2.0, 450.0),
        )
        .unwrap();
    let model = || model_from_specs("mono:70", "", "ideal").unwrap();
    let block = TriMesh::cuboid("block", lo, hi);
    let input = |mesh: &TriMesh, material: &str| SpectralInput {
        mesh: Arc::new(mesh.clone()),
        object: mesh.name.clone(),
        attenuation: parse_attenuation(material).unwrap(),
        implant: false,
    };
    let (plain, _) = SpectralScene::from_meshes(vec![input(&block, "soft_tissue")]).unwrap();
    let mut with_screw = plain.clone();
    let ti = spinedrr::spectral::MaterialAt::parse("titanium").unwrap();
    with_screw.add_implant(Arc::new(shank.clone()), "screw".into(), ti);
    with_screw.add_implant(Arc::new(head.clone()), "screw".into(), ti);
    let view = camera();
    let render = |s: &SpectralScene| {
        SpectralRenderer::new(s, model(), Backend::Raster)
            .unwrap()
            .render(&view)
            .unwrap()
            .line_integral
    };
    let (without, with) = (render(&plain), render(&with_screw));
    let chord = |m: &TriMesh| {
        let scene = spinedrr::render::RenderScene::new(vec![spinedrr::render::SceneMesh {
            mesh: Arc::new(m.clone()),
            mu_per_mm: 1.0,
            object: "x".into(),
        }])
        .unwrap();
        Backend::Bvh
            .renderer(scene)
            .unwrap()
            .render(&view, &spinedrr::render::ThicknessOptions::image_only())
            .unwrap()
            .line_integral
    };
    let (l_shank, l_head) = (chord(&shank), chord(&head));
    let mu_t = Material::named("soft_tissue")
        .unwrap()
        .mu_per_mm(70.0, 1.06);
    let mu_ti = ti.material.mu_per_mm(70.0, ti.density_g_cm3);
    let mut screw_pixels = 0;
    for i in 0..without.data.len() {
        // The head lies partly outside the block (x > 40): only its part inside displaces tissue, so
        // check the pixels the head does not reach.
        if l_head.data[i] > 0.0 {
            continue;
        }
        let ls = f64::from(l_shank.data[i]);
        screw_pixels += usize::from(ls > 0.5);
        let expected = f64::from(without.data[i]) + (mu_ti - mu_t) * ls;
        let got = f64::from(with.data[i]);
        assert!(
            (got - expected).abs() < 1e-4 * expected.max(1.0),
            "pixel {i}: {got} vs {expected}"
        );
    }
    assert!(screw_pixels > 50, "{screw_pixels}");
}

#[test]
fn the_phantom_takes_two_pedicle_screws_per_level() {
    let d = tempfile::tempdir().unwrap();
    let o = d.path().join("s.tiff");
    let (ok, err) = crate::common::run(&[
        "render",
        "--phantom",
        "L2-L3",
        "--screws",
        "--view",
        "lat",
        "--spectrum",
        "80",
        "--out",
        &s(&o),
    ]);
    assert!(ok, "{err}");
    let sc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(o.with_extension("json")).unwrap()).unwrap();
    let meshes = sc["details"]["anatomy"]["meshes"].as_array().unwrap();
    let implants: Vec<&str> = meshes
        .iter()
        .filter(|m| m["implant"] == true)
        .map(|m| m["mesh"].as_str().unwrap())
        .collect();
    assert_eq!(implants.len(), 8, "{implants:?}"); // 2 levels × 2 sides × (shank, head)
    assert!(implants.contains(&"L3_screw_left_shank"), "{implants:?}");
    refused(
        &[
            "render",
            "--mesh",
            "x.stl",
            "--screws",
            "--spectrum",
            "80",
            "--out",
            &s(&o),
        ],
        &["--phantom"],
    );
}

#[test]
fn a_ct_block_renders_as_the_same_block_of_material_meshes() {
    // A CT of two blocks, 0 HU (soft tissue at 1.0 g/cm³) and 800 HU (half soft tissue at 1.10, half
    // cortical bone at 1.92 by volume: 0.55 and 0.96 g/cm³), against material meshes of the same voxel
    // boxes: Siddon per material and the exact mesh render agree, under one energy and a spectrum.
    use spinedrr::anatomy::ct::CtVolume;
    use spinedrr::render::SpectralCtRenderer;
    use spinedrr::render::volume::{VolumeRenderOptions, VolumeRenderer};
    let affine = glam::DMat4::from_translation(DVec3::new(-12.0, -12.0, 440.0));
    let mut ct = CtVolume::filled([24, 24, 24], -1000.0, affine).unwrap();
    let (a, b) = (2..12, 12..22);
    for k in 2..22 {
        for j in 2..22 {
            for i in a.start..b.end {
                let n = ct.linear(i, j, k);
                ct.values[n] = if a.contains(&i) { 0.0 } else { 800.0 };
            }
        }
    }
    // Voxel i covers [i − 0.5, i + 0.5] mm before the translation.
    let cell = |lo: usize, hi: usize| (lo as f64 - 0.5, hi as f64 - 0.5);
    let boxed = |x: (f64, f64)| {
        TriMesh::cuboid(
            "b",
            DVec3::new(x.0 - 12.0, 1.5 - 12.0, 441.5),
            DVec3::new(x.1 - 12.0, 21.5 - 12.0, 461.5),
        )
    };
    let (soft_box, mixed_box) = (boxed(cell(2, 12)), boxed(cell(12, 22)));
    let input = |mesh: &TriMesh, material: &str| SpectralInput {
        mesh: Arc::new(mesh.clone()),
        object: "b".into(),
        attenuation: parse_attenuation(material).unwrap(),
        implant: false,
    };
    let (meshes, _) = SpectralScene::from_meshes(vec![
        input(&soft_box, "soft_tissue@1.0"),
        input(&mixed_box, "soft_tissue@0.55"),
        input(&mixed_box, "cortical_bone@0.96"),
    ])
    .unwrap();
    // A pedicle screw through both blocks, its head standing out of the CT's tissue: as an implant of the
    // material meshes (displacement tested against analytic chords above) and of the CT (each material's
    // Siddon integral over the screw's intervals subtracted).
    let (shank, head) = spinedrr::anatomy::screw::ScrewSpec::default()
        .meshes(
            "s",
            DVec3::new(14.0, 0.5, 451.0),
            DVec3::new(-7.0, -1.0, 452.0),
        )
        .unwrap();
    let ti = spinedrr::spectral::MaterialAt::parse("titanium").unwrap();
    let implants = vec![(Arc::new(shank), ti), (Arc::new(head), ti)];
    let mut with_screw = meshes.clone();
    for (m, material) in &implants {
        with_screw.add_implant(m.clone(), "s".into(), *material);
    }
    let view = camera();
    let base = VolumeRenderer::new(&ct, &VolumeRenderOptions::default(), None).unwrap();
    for spec in ["mono:60", "100"] {
        let model = || model_from_specs(spec, "al:2.5", "csi:0.6").unwrap();
        for screw in [false, true] {
            let ct_renderer = SpectralCtRenderer::new(&base, &ct.values, model()).unwrap();
            let ct_renderer = if screw {
                ct_renderer
                    .with_implants(&implants, Backend::Raster)
                    .unwrap()
            } else {
                ct_renderer
            };
            let from_ct = ct_renderer.render(&view).unwrap().line_integral;
            let scene = if screw { &with_screw } else { &meshes };
            let from_meshes = SpectralRenderer::new(scene, model(), Backend::Raster)
                .unwrap()
                .render(&view)
                .unwrap()
                .line_integral;
            let mut covered = 0;
            for (i, (c, m)) in from_ct.data.iter().zip(&from_meshes.data).enumerate() {
                covered += usize::from(*m > 0.1);
                assert!(
                    (c - m).abs() < 2e-4 * m.max(1.0),
                    "{spec} screw {screw} pixel {i}: CT {c} vs meshes {m}"
                );
            }
            assert!(covered > 500, "{covered}");
            if screw {
                // The screw is in view: titanium outweighs the tissue it displaces.
                let plain = SpectralCtRenderer::new(&base, &ct.values, model())
                    .unwrap()
                    .render(&view)
                    .unwrap()
                    .line_integral;
                let brighter = from_ct
                    .data
                    .iter()
                    .zip(&plain.data)
                    .filter(|(c, p)| **c > **p + 0.5)
                    .count();
                assert!(brighter > 100, "{brighter} pixels show the screw");
            }
        }
    }
}

#[test]
fn screws_at_a_users_landmarks_are_the_screws_given_as_implant_meshes() {
    let d = tempfile::tempdir().unwrap();
    let c = s(&cube(d.path(), "c.stl", DVec3::ZERO, 30.0));
    let (entry, tip) = (DVec3::new(2.0, 25.0, 4.0), DVec3::new(-3.0, -15.0, 6.0));
    let plan = d.path().join("plan.json");
    let set = spinedrr::anatomy::Landmarks {
        level: "L4".into(),
        points: [
            ("left_pedicle_entry".to_string(), entry),
            ("left_pedicle_tip".to_string(), tip),
            ("center".to_string(), DVec3::ZERO),
        ]
        .into_iter()
        .collect(),
    };
    spinedrr::anatomy::write_landmarks(&plan, &[set]).unwrap();
    let (shank, head) = spinedrr::anatomy::screw::ScrewSpec::default()
        .meshes("left", entry, tip)
        .unwrap();
    let (shank_path, head_path) = (d.path().join("shank.stl"), d.path().join("head.stl"));
    spinedrr::anatomy::write_mesh(&shank_path, &shank).unwrap();
    spinedrr::anatomy::write_mesh(&head_path, &head).unwrap();
    let run = |extra: &[String], out: &str| {
        let o = d.path().join(out);
        let mut args: Vec<String> = [
            "render",
            "--mesh",
            &format!("{c}:soft_tissue"),
            "--view",
            "ap",
            "--spectrum",
            "80",
        ]
        .map(String::from)
        .to_vec();
        args.extend(extra.iter().cloned());
        args.extend(["--out".to_string(), s(&o)]);
        let (ok, err) = crate::common::run(&args);
        assert!(ok, "{err}");
        (read_tiff_f32(&o).unwrap().data, o)
    };
    let (planned, o) = run(&["--screws-at".into(), s(&plan)], "planned.tiff");
    let (meshes, _) = run(
        &[
            "--implant".into(),
            format!("{}:titanium", s(&shank_path)),
            "--implant".into(),
            format!("{}:titanium", s(&head_path)),
        ],
        "meshes.tiff",
    );
    let (plain, _) = run(&[], "plain.tiff");
    // The same screw, once from the plan and once through STL files (f32 vertices): the same image.
    let worst = planned
        .iter()
        .zip(&meshes)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(worst < 1e-3, "largest difference {worst}");
    let screw_pixels = planned
        .iter()
        .zip(&plain)
        .filter(|(a, b)| **a > **b + 0.1)
        .count();
    assert!(screw_pixels > 100, "{screw_pixels} pixels show the screw");
    let sc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(o.with_extension("json")).unwrap()).unwrap();
    let screws = &sc["details"]["anatomy"]["screws_at"]["screws"];
    assert_eq!(screws.as_array().unwrap().len(), 1);
    assert_eq!(screws[0]["name"], "left");
    // A plan without a trajectory, and a CT, are refused by name.
    let empty = d.path().join("empty.json");
    let set = spinedrr::anatomy::Landmarks {
        level: "L4".into(),
        points: [("center".to_string(), DVec3::ZERO)].into_iter().collect(),
    };
    spinedrr::anatomy::write_landmarks(&empty, &[set]).unwrap();
    let out = s(&d.path().join("x.tiff"));
    refused(
        &[
            "render",
            "--mesh",
            &format!("{c}:soft_tissue"),
            "--spectrum",
            "80",
            "--screws-at",
            &s(&empty),
            "--out",
            &out,
        ],
        &["--screws-at", "pedicle_entry"],
    );
}

/// A plan in the CT file's coordinates moves with the CT's placement: the screw's tip, moved by the
/// sidecar's recorded translation and projected through the sidecar's P, lies where the hybrid image is
/// brighter than the CT alone; the sidecar lists the implants.
#[test]
fn screws_at_a_plan_in_a_ct_move_with_its_placement() {
    use spinedrr::anatomy::ct::{Volume, write_ct};
    let d = tempfile::tempdir().unwrap();
    // A 60 mm block of 300 HU in a 64³ grid of 1 mm voxels whose corner is at (100, 50, 20) mm.
    let affine = glam::DMat4::from_translation(DVec3::new(100.0, 50.0, 20.0));
    let mut v = Volume::filled([64, 64, 64], -1000.0, affine).unwrap();
    for k in 2..62 {
        for j in 2..62 {
            for i in 2..62 {
                let n = v.linear(i, j, k);
                v.values[n] = 300.0;
            }
        }
    }
    let ct = d.path().join("block.nii.gz");
    write_ct(&ct, &v).unwrap();
    let (entry, tip) = (
        DVec3::new(132.0, 100.0, 52.0),
        DVec3::new(130.0, 62.0, 50.0),
    );
    let plan = d.path().join("plan.json");
    let set = spinedrr::anatomy::Landmarks {
        level: "L3".into(),
        points: [
            ("right_pedicle_entry".to_string(), entry),
            ("right_pedicle_tip".to_string(), tip),
        ]
        .into_iter()
        .collect(),
    };
    spinedrr::anatomy::write_landmarks(&plan, &[set]).unwrap();
    let render = |extra: &[&str], out: &str| {
        let o = d.path().join(out);
        let mut args = vec!["render", "--ct", ct.to_str().unwrap(), "--view", "ap"];
        args.extend(["--spectrum", "80", "--out", o.to_str().unwrap()]);
        args.extend(extra);
        let (ok, err) = crate::common::run(&args);
        assert!(ok, "{err}");
        let side: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(o.with_extension("json")).unwrap())
                .unwrap();
        (read_tiff_f32(&o).unwrap(), side)
    };
    let (plain, _) = render(&[], "plain.tiff");
    let (hybrid, side) = render(&["--screws-at", plan.to_str().unwrap()], "hybrid.tiff");
    let spectral = &side["details"]["spectral"];
    assert_eq!(
        spectral["implants"].as_array().unwrap().len(),
        2,
        "{spectral}"
    );
    assert_eq!(spectral["screws_at"]["screws"][0]["name"], "right");
    let t: Vec<f64> =
        serde_json::from_value(side["details"]["placement"]["translation_mm"].clone()).unwrap();
    let p: [[f64; 4]; 3] = serde_json::from_value(side["P"].clone()).unwrap();
    // 8 mm back from the tip along the axis, inside the shank.
    let x = tip + (entry - tip).normalize() * 8.0 + DVec3::new(t[0], t[1], t[2]);
    let row = |r: &[f64; 4]| r[0] * x.x + r[1] * x.y + r[2] * x.z + r[3];
    let (u, w) = (row(&p[0]) / row(&p[2]), row(&p[1]) / row(&p[2]));
    let i = w.round() as usize * hybrid.width as usize + u.round() as usize;
    assert!(
        hybrid.data[i] > plain.data[i] + 1.0,
        "at the moved screw ({u:.1}, {w:.1}): hybrid {} vs CT {}",
        hybrid.data[i],
        plain.data[i]
    );
    // Far from it the CT is untouched.
    let far = (hybrid.height as usize / 2) * hybrid.width as usize + 5;
    assert_eq!(hybrid.data[far], plain.data[far]);
}
