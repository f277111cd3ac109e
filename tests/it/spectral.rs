//! The spectral DRR: a titanium rod in a soft-tissue block against analytic chords (the rod displaces the
//! tissue it occupies), the energy sum against a recomputation, the one-bin spectrum bit for bit the
//! monochromatic DRR, and bad spectral input refused by name.

use std::f64::consts::PI;
use std::sync::Arc;

use glam::{DMat3, DVec3};
use spinedrr::anatomy::TriMesh;
use spinedrr::geometry::{Intrinsics, RigidTransform, View};
use spinedrr::io::read_tiff_f32;
use spinedrr::render::{Backend, SpectralInput, SpectralRenderer, SpectralScene};
use spinedrr::spectral::{Material, model_from_specs, parse_attenuation};

use crate::cli_hardening::{cube, refused, s};

/// A closed prism of `n` facets approximating a cylinder of radius `r` along x from `x0` to `x1`, axis
/// through (y, z) = `(0, zc)`.
fn rod(n: u32, r: f64, x0: f64, x1: f64, zc: f64) -> TriMesh {
    let mut v = Vec::new();
    for x in [x0, x1] {
        for k in 0..n {
            let a = 2.0 * PI * f64::from(k) / f64::from(n);
            v.push(DVec3::new(x, r * a.cos(), zc + r * a.sin()));
        }
    }
    v.push(DVec3::new(x0, 0.0, zc));
    v.push(DVec3::new(x1, 0.0, zc));
    let (c0, c1) = (2 * n, 2 * n + 1);
    let mut t = Vec::new();
    for k in 0..n {
        let k1 = (k + 1) % n;
        // Side quad (outward normal) and the two caps.
        t.push([k, k1, n + k1]);
        t.push([k, n + k1, n + k]);
        t.push([c0, k1, k]);
        t.push([c1, n + k, n + k1]);
    }
    let mut m = TriMesh::new("rod", v, t);
    m.orient_outward();
    m
}

/// Entry and exit parameters of the ray `o + t d` through the axis-aligned box `[lo, hi]`.
fn slab(o: DVec3, d: DVec3, lo: DVec3, hi: DVec3) -> Option<(f64, f64)> {
    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
    for i in 0..3 {
        let (a, b) = ((lo[i] - o[i]) / d[i], (hi[i] - o[i]) / d[i]);
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    (t1 > t0).then_some((t0, t1))
}

/// A 64 × 64 camera at the world origin looking along +z (f = 1000 px).
fn camera() -> View {
    let k = Intrinsics {
        fx: 1000.0,
        fy: 1000.0,
        skew: 0.0,
        cx: 31.5,
        cy: 31.5,
        width: 64,
        height: 64,
    };
    View::new("test", k, RigidTransform::new(DMat3::IDENTITY, DVec3::ZERO))
}

/// Renders a soft-tissue block with a titanium rod (radius 4 mm along x, axis at depth `zc`) under the
/// mono and an 80 kV spectrum, and checks every pixel against the analytic chords: the tissue's chord is the
/// block's less its overlap with the rod (the rod displaces the tissue), the rod's its circle chord.
fn rod_in_block(zc: f64, implant: bool) {
    let (lo, hi) = (
        DVec3::new(-40.0, -40.0, 400.0),
        DVec3::new(40.0, 40.0, 500.0),
    );
    let (r, x_half) = (4.0, 20.0);
    let input = |mesh, name: &str, material: &str, implant| SpectralInput {
        mesh,
        object: name.to_string(),
        attenuation: parse_attenuation(material).unwrap(),
        implant,
    };
    let items = vec![
        input(
            Arc::new(TriMesh::cuboid("block", lo, hi)),
            "block",
            "soft_tissue",
            false,
        ),
        input(
            Arc::new(rod(720, r, -x_half, x_half, zc)),
            "rod",
            "titanium",
            implant,
        ),
    ];
    let (scene, warnings) = SpectralScene::from_meshes(items).unwrap();
    assert_eq!(
        warnings.is_empty(),
        implant || zc + r < hi.z,
        "{warnings:?}"
    );
    let view = camera();
    let tissue = Material::named("soft_tissue").unwrap();
    let ti = Material::named("titanium").unwrap();
    let (rho_t, rho_ti) = (tissue.density_g_cm3, ti.density_g_cm3);
    for spec in ["mono:60", "80"] {
        let model = model_from_specs(spec, "al:2.5", "csi:0.6").unwrap();
        let energies = model.spectrum.energies_kev.clone();
        let weights = model.weights.clone();
        let renderer = SpectralRenderer::new(&scene, model, Backend::Raster).unwrap();
        let drr = renderer.render(&view).unwrap();
        let mut rod_pixels = 0;
        for v in 0..64u32 {
            for u in 0..64u32 {
                let d = DVec3::new(
                    (f64::from(u) - 31.5) / 1000.0,
                    (f64::from(v) - 31.5) / 1000.0,
                    1.0,
                )
                .normalize();
                let (t0, t1) = slab(DVec3::ZERO, d, lo, hi).expect("every ray crosses the block");
                // The rod: the circle (y, z − zc) of radius r in the ray's (y, z) projection.
                let (a, b, c) = (d.y * d.y + d.z * d.z, -2.0 * d.z * zc, zc * zc - r * r);
                let disc = b * b - 4.0 * a * c;
                let (mut l_rod, mut overlap) = (0.0, 0.0);
                if disc > 0.0 {
                    let (s0, s1) = (
                        (-b - disc.sqrt()) / (2.0 * a),
                        (-b + disc.sqrt()) / (2.0 * a),
                    );
                    // Skip rays near the rod's tangent (facets differ from the circle there) or its caps.
                    let dist = (d.y * zc).abs() / a.sqrt();
                    if dist > 0.8 * r || (d.x * s1).abs() > x_half - 1.0 {
                        continue;
                    }
                    l_rod = s1 - s0;
                    overlap = (s1.min(t1) - s0.max(t0)).max(0.0);
                    rod_pixels += 1;
                }
                let l_tissue = (t1 - t0) - overlap;
                // −ln Σ w exp(−Σ μ L), recomputed here from the model's weights and the materials' μ/ρ.
                let signal: f64 = energies
                    .iter()
                    .zip(&weights)
                    .map(|(&e, w)| {
                        let x =
                            tissue.mu_per_mm(e, rho_t) * l_tissue + ti.mu_per_mm(e, rho_ti) * l_rod;
                        w * (-x).exp()
                    })
                    .sum();
                let expected = -signal.ln();
                let got = f64::from(drr.line_integral.data[(v * 64 + u) as usize]);
                assert!(
                    (got - expected).abs() < 2e-5 * expected.max(1.0),
                    "{spec} zc {zc} implant {implant} pixel ({u}, {v}): {got} vs {expected} (rod \
                     chord {l_rod} mm, in tissue {overlap} mm)"
                );
            }
        }
        assert!(rod_pixels > 100, "{spec}: {rod_pixels} rod pixels");
    }
}

#[test]
fn a_titanium_rod_in_tissue_has_its_analytic_chord_and_displaces_the_tissue() {
    // Inside the block: displaced because it lies inside the block's surface (or as an implant).
    rod_in_block(450.0, false);
    rod_in_block(450.0, true);
    // Through the block's back face (2 mm in, 6 mm out): an implant displaces exactly the overlap; a plain
    // material mesh cannot be nested and is warned about.
    rod_in_block(498.0, true);
}

#[test]
fn a_one_bin_spectrum_is_the_monochromatic_drr_bit_for_bit() {
    let d = tempfile::tempdir().unwrap();
    let c = s(&cube(d.path(), "c.stl", DVec3::new(0.0, 0.0, 0.0), 30.0));
    let run = |extra: &[&str], out: &str| {
        let o = d.path().join(out);
        let mut args = vec![
            "render".to_string(),
            "--view".into(),
            "lat".into(),
            "--intensity".into(),
            "1000".into(),
        ];
        args.extend(extra.iter().map(|x| x.to_string()));
        args.extend(["--out".to_string(), s(&o)]);
        let (ok, err) = crate::common::run(&args);
        assert!(ok, "{err}");
        read_tiff_f32(&o).unwrap().data
    };
    let mono = run(&["--mesh", &format!("{c}:0.0193")], "mono.tiff");
    let one_bin = run(
        &["--mesh", &format!("{c}:0.0193"), "--spectrum", "mono:70"],
        "one.tiff",
    );
    assert!(mono.iter().any(|&x| x < 1000.0));
    assert_eq!(mono, one_bin);
    // A material mesh at one energy is the μ mesh with μ = μ/ρ(E) · ρ / 10.
    let mu = Material::named("water").unwrap().mu_per_mm(70.0, 1.0);
    let as_mu = run(&["--mesh", &format!("{c}:{mu}")], "as_mu.tiff");
    let as_material = run(
        &["--mesh", &format!("{c}:water"), "--spectrum", "mono:70"],
        "water.tiff",
    );
    assert_eq!(as_mu, as_material);
    // The sidecar records the spectrum and its beam quality.
    let o = d.path().join("poly.tiff");
    let (ok, err) = crate::common::run(&[
        "render",
        "--mesh",
        &format!("{c}:water"),
        "--view",
        "lat",
        "--spectrum",
        "80",
        "--filter",
        "al:2.5",
        "--out",
        &s(&o),
    ]);
    assert!(ok, "{err}");
    let sc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(o.with_extension("json")).unwrap()).unwrap();
    let sp = &sc["details"]["spectral"];
    assert_eq!(
        sp["energies_kev"].as_array().unwrap().len(),
        sp["fluence"].as_array().unwrap().len()
    );
    let mean = sp["mean_energy_kev"].as_f64().unwrap();
    let hvl = sp["hvl_al_mm"].as_f64().unwrap();
    assert!(
        (35.0..60.0).contains(&mean) && (2.0..6.0).contains(&hvl),
        "{mean} {hvl}"
    );
}

#[test]
fn bad_spectral_input_is_refused_by_name() {
    let d = tempfile::tempdir().unwrap();
    let c = s(&cube(d.path(), "c.stl", DVec3::ZERO, 30.0));
    let out = s(&d.path().join("o.tiff"));
    let spec = d.path().join("spec.csv");
    std::fs::write(&spec, "20 1\n20 2\n").unwrap();
    for (args, needles) in [
        (
            vec!["--mesh", &format!("{c}:water")],
            vec!["material", "--spectrum"],
        ),
        (
            vec!["--mesh", &format!("{c}:unobtainium"), "--spectrum", "80"],
            vec!["unobtainium", "titanium"],
        ),
        (
            vec!["--mesh", &c, "--spectrum", "160"],
            vec!["160", "30–140"],
        ),
        (
            vec!["--mesh", &c, "--spectrum", &s(&spec)],
            vec!["line 2", "does not increase"],
        ),
        (
            vec!["--mesh", &c, "--spectrum", "80", "--filter", "cu:-1"],
            vec!["--filter", "copper"],
        ),
        (
            vec!["--mesh", &c, "--spectrum", "80", "--detector", "csi"],
            vec!["--detector", "csi"],
        ),
        (vec!["--mesh", &c, "--filter", "al:1"], vec!["--spectrum"]),
        (
            vec!["--mesh", &c, "--detector", "ideal"],
            vec!["--spectrum"],
        ),
        (
            vec!["--mesh", &c, "--spectrum", "80", "--masks"],
            vec!["--masks"],
        ),
        (
            vec!["--mesh", &format!("{c}:ti@-3"), "--spectrum", "80"],
            vec!["ti@-3", "positive"],
        ),
    ] {
        let mut a = vec!["render", "--view", "lat", "--out", &out];
        a.extend(args);
        refused(&a, &needles);
    }
    assert!(!d.path().join("o.tiff").exists());
    // A spectrum file or an implant where an output would go is refused and left as it was.
    let clash = d.path().join("o.json");
    std::fs::write(&clash, "60 1\n80 1\n").unwrap();
    refused(
        &[
            "render",
            "--view",
            "lat",
            "--mesh",
            &c,
            "--spectrum",
            &s(&clash),
            "--out",
            &out,
        ],
        &["is also the --spectrum file"],
    );
    assert_eq!(std::fs::read_to_string(&clash).unwrap(), "60 1\n80 1\n");
}

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
