//! The two DRR models on one anatomy: the thickness DRR of the phantom's meshes and the CT volume DRR of
//! its synthetic CT must agree (NCC ≥ 0.99), and Embree must match the reference BVH on the phantom.

use spinedrr::anatomy::synthetic_ct::{SyntheticCtOptions, synthetic_ct};
use spinedrr::anatomy::{PhantomOptions, parse_levels};
use spinedrr::geometry::{CArm, GeometryConfig, View};
use spinedrr::io::ImageF32;
use spinedrr::render::volume::{VolumeMethod, VolumeRenderOptions, VolumeRenderer};
use spinedrr::render::{Backend, RenderScene, SceneMesh, ThicknessOptions, phantom_scene};

/// The default C-arm with a coarser detector (same field of view) so the tests stay quick.
fn coarse_carm(downscale: u32) -> CArm {
    let mut cfg: GeometryConfig =
        toml::from_str(spinedrr::geometry::DEFAULT_GEOMETRY_TOML).unwrap();
    cfg.detector.width /= downscale;
    cfg.detector.height /= downscale;
    cfg.detector.pixel_spacing_mm = cfg
        .detector
        .pixel_spacing_mm
        .map(|p| p.map(|s| s * downscale as f64));
    cfg.build().unwrap()
}

fn ncc(a: &ImageF32, b: &ImageF32) -> f64 {
    let n = a.data.len() as f64;
    let ma = a.data.iter().map(|&x| x as f64).sum::<f64>() / n;
    let mb = b.data.iter().map(|&x| x as f64).sum::<f64>() / n;
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (&x, &y) in a.data.iter().zip(&b.data) {
        let (x, y) = (x as f64 - ma, y as f64 - mb);
        sab += x * y;
        saa += x * x;
        sbb += y * y;
    }
    sab / (saa * sbb).sqrt()
}

fn view(c: &CArm, name: &str) -> View {
    c.view(name).unwrap().clone()
}

#[test]
fn volume_drr_of_the_synthetic_ct_matches_the_thickness_drr() {
    let phantom = crate::common::phantom(&PhantomOptions {
        levels: parse_levels("L3").unwrap(),
        discs: false,
        ..PhantomOptions::default()
    })
    .unwrap();
    let (ct, _) = synthetic_ct(
        &phantom,
        &SyntheticCtOptions {
            voxel_mm: 0.5,
            ..SyntheticCtOptions::default()
        },
    )
    .unwrap();
    let thickness = Backend::Embree
        .renderer(phantom_scene(&phantom).unwrap())
        .unwrap();
    let volume = VolumeRenderer::new(
        &ct,
        &VolumeRenderOptions {
            method: VolumeMethod::Siddon,
            ..VolumeRenderOptions::default()
        },
        None,
    )
    .unwrap();
    let carm = coarse_carm(4);
    for name in ["ap", "lat"] {
        let v = view(&carm, name);
        let a = thickness
            .render(&v, &ThicknessOptions::default())
            .unwrap()
            .line_integral;
        // The CT is air (−1000 HU, μ = 0) outside the vertebra, so both images integrate bone only.
        let b = volume.render(&v);
        let r = ncc(&a, &b);
        assert!(r >= 0.99, "{name}: NCC {r}");
        let (sa, sb): (f64, f64) = (
            a.data.iter().map(|&x| x as f64).sum(),
            b.data.iter().map(|&x| x as f64).sum(),
        );
        assert!(
            (sa / sb - 1.0).abs() < 0.03,
            "{name}: integrated attenuation differs: {sa} vs {sb}"
        );
    }
}

/// Largest per-pixel absolute difference of two images of one size.
pub(crate) fn worst_difference(a: &ImageF32, b: &ImageF32) -> f32 {
    assert_eq!((a.width, a.height), (b.width, b.height));
    a.data
        .iter()
        .zip(&b.data)
        .map(|(p, q)| (p - q).abs())
        .fold(0f32, f32::max)
}

#[test]
fn embree_and_raster_match_the_reference_backend_on_the_phantom() {
    let phantom = crate::common::phantom(&PhantomOptions {
        levels: parse_levels("L2-L4").unwrap(),
        ..PhantomOptions::default()
    })
    .unwrap();
    // μ = 1 mm⁻¹ on every surface: pixel values are summed path lengths in mm.
    let scene = phantom_scene(&phantom).unwrap();
    let scene = RenderScene::new(
        scene
            .meshes
            .into_iter()
            .map(|m| SceneMesh {
                mu_per_mm: 1.0,
                ..m
            })
            .collect(),
    )
    .unwrap();
    let e = Backend::Embree.renderer(scene.clone()).unwrap();
    let r = Backend::Raster.renderer(scene.clone()).unwrap();
    let b = Backend::Bvh.renderer(scene).unwrap();
    let carm = coarse_carm(2);
    for (name, e) in [("ap", &e), ("lat", &e), ("ap", &r), ("lat", &r)] {
        let v = view(&carm, name);
        let x = e.render(&v, &ThicknessOptions::default()).unwrap();
        let y = b.render(&v, &ThicknessOptions::default()).unwrap();
        let worst = worst_difference(&x.line_integral, &y.line_integral);
        assert!(
            worst <= 1e-4,
            "{} {name}: worst per-pixel difference {worst} mm",
            e.backend_name()
        );
        assert!(x.stats.rays_traced > 10_000);
        assert_eq!(x.stats.rays_unrepaired, 0);
    }
    // The raster's signed-sum line integral (the intensity-registration loop's path) against the
    // reference backend's paired crossings, also through a skewed K with a shifted piercing point and
    // from an oblique pose.
    let skewed = |v: View| View {
        intrinsics: spinedrr::geometry::Intrinsics {
            skew: 4.0,
            cx: v.intrinsics.cx + 37.0,
            cy: v.intrinsics.cy - 21.0,
            ..v.intrinsics
        },
        ..v
    };
    let oblique = |v: View| View {
        world_to_camera: v
            .world_to_camera
            .compose(&spinedrr::geometry::RigidTransform::new(
                glam::DMat3::from_euler(glam::EulerRot::XYZ, 0.2, -0.3, 0.1),
                glam::DVec3::new(3.0, -4.0, 2.0),
            )),
        ..v
    };
    let mut summed = ImageF32::zeros(0, 0);
    for name in ["ap", "lat"] {
        for v in [
            view(&carm, name),
            skewed(view(&carm, name)),
            oblique(view(&carm, name)),
        ] {
            let stats = r.render_line_integral_summed_into(&v, &mut summed).unwrap();
            let y = b.render(&v, &ThicknessOptions::default()).unwrap();
            assert_eq!(
                (summed.width, summed.height),
                (y.line_integral.width, y.line_integral.height)
            );
            let worst = worst_difference(&summed, &y.line_integral);
            assert!(
                worst <= 1e-4,
                "summed raster {name}: worst difference {worst} mm"
            );
            assert!(stats.rays_traced > 10_000, "{stats:?}");
            assert_eq!(stats.rays_unrepaired, 0);
        }
    }
}
