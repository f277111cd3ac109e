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
pub(crate) fn camera() -> View {
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
