//! The raster never panics and never leaves the image, whatever finite (or infinite) intrinsics it is
//! given: a property test over K entries spread log-uniformly from 1e-300 to f64::MAX, both signs.

use std::sync::Arc;

use glam::DVec3;

use super::{BandScratch, COORD_CLAMP, RasterView, SumScratch, ceil_clamped, floor_clamped};
use crate::anatomy::TriMesh;
use crate::geometry::{Intrinsics, RigidTransform, View};
use crate::render::{RenderScene, SceneMesh};

/// A deterministic stream of extreme values: sign, then a power of ten from −300 to 308, plus the
/// edge cases that make arithmetic overflow.
struct Extremes(u64);

impl Extremes {
    fn next_u64(&mut self) -> u64 {
        // SplitMix64.
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    fn value(&mut self) -> f64 {
        let special = [
            0.0,
            1.0,
            511.5,
            1e19,
            1e22,
            1e30,
            f64::MAX,
            f64::MIN_POSITIVE,
            f64::INFINITY,
        ];
        let r = self.next_u64();
        let sign = if r & 1 == 0 { 1.0 } else { -1.0 };
        if r & 6 == 0 {
            return sign * special[(r >> 3) as usize % special.len()];
        }
        let exp = ((r >> 3) % 609) as i32 - 300;
        sign * 10f64.powi(exp)
    }
}

fn scene() -> RenderScene {
    let cube = TriMesh::cuboid("cube", DVec3::splat(-10.0), DVec3::splat(10.0));
    RenderScene::new(vec![SceneMesh {
        mesh: Arc::new(cube),
        mu_per_mm: 1.0,
        object: "cube".into(),
    }])
    .unwrap()
}

/// Rasterises every band of `k` and checks each visited pixel lies on the detector.
fn raster_all(scene: &RenderScene, k: Intrinsics) {
    let pose = RigidTransform::new(glam::DMat3::IDENTITY, DVec3::new(0.0, 0.0, 1000.0));
    let view = View::new("extreme", k, pose);
    let Some(rv) = RasterView::new(scene, &view, 16) else {
        return;
    };
    let mut scratch = BandScratch::default();
    let mut sums = SumScratch::default();
    for band in 0..(k.height as usize).div_ceil(16) {
        rv.band_hits(band, &mut scratch, |u, row, hits| {
            assert!(
                u < k.width as usize && band * 16 + row < k.height as usize,
                "{k:?}"
            );
            assert!(!hits.is_empty());
        });
        // The signed-sum path visits the same pixels and writes only inside the band.
        let mut out = vec![0f32; 16 * k.width as usize];
        let mut unbalanced = Vec::new();
        rv.band_line_integral(band, &mut sums, &mut out, &mut unbalanced);
        for &(u, row) in &unbalanced {
            assert!(u < k.width as usize && row < 16, "{k:?}");
        }
    }
}

#[test]
fn extreme_intrinsics_never_panic() {
    let scene = scene();
    let mut x = Extremes(11);
    for _ in 0..3000 {
        let k = Intrinsics {
            fx: x.value().abs(),
            fy: x.value().abs(),
            skew: x.value(),
            cx: x.value(),
            cy: x.value(),
            width: 40,
            height: 36,
        };
        raster_all(&scene, k);
    }
}

#[test]
fn sane_intrinsics_still_see_the_cube() {
    // The guard of the property test: a reference K sees the cube's centre pixel.
    let scene = scene();
    let k = Intrinsics {
        fx: 100.0,
        fy: 100.0,
        skew: 0.0,
        cx: 19.5,
        cy: 17.5,
        width: 40,
        height: 36,
    };
    let pose = RigidTransform::new(glam::DMat3::IDENTITY, DVec3::new(0.0, 0.0, 1000.0));
    let rv = RasterView::new(&scene, &View::new("ref", k, pose), 16).unwrap();
    let mut covered = 0;
    let mut scratch = BandScratch::default();
    for band in 0..3 {
        rv.band_hits(band, &mut scratch, |_, _, hits| {
            assert_eq!(hits.len(), 2);
            covered += 1;
        });
    }
    // The cube's 20 mm side at 990–1010 mm depth under f = 100 px spans 2 pixels: 2 × 2 rays.
    assert_eq!(covered, 4);
    // By signed sums the four rays are balanced and 20 mm long times their path per unit depth.
    let mut sums = SumScratch::default();
    let (mut out, mut unbalanced) = (vec![0f32; 16 * 40], Vec::new());
    let mut lit = 0;
    for band in 0..3 {
        out.iter_mut().for_each(|x| *x = 0.0);
        lit += rv.band_line_integral(band, &mut sums, &mut out, &mut unbalanced);
        for (i, &x) in out.iter().enumerate() {
            if x != 0.0 {
                let (u, v) = ((i % 40) as f64, (band * 16 + i / 40) as f64);
                let d = k.back_project(u, v);
                let expect = 20.0 * (d / d.z).length();
                assert!(
                    (f64::from(x) - expect).abs() < 1e-4,
                    "({u}, {v}): {x} vs {expect}"
                );
            }
        }
    }
    assert_eq!((lit, unbalanced.len()), (4, 0));
}

/// The float-only rounding of the vertex boxes agrees with `f64::ceil` / `f64::floor` (clamped) on
/// whole numbers, halves (ties of the rounding trick), numbers a margin away from whole ones, both signs,
/// and values far beyond the clamp.
#[test]
fn vertex_box_rounding_matches_ceil_and_floor() {
    let mut xs = vec![
        0.0,
        -0.0,
        1e-300,
        -1e-300,
        1e300,
        -1e300,
        f64::MAX,
        -f64::MAX,
    ];
    for i in -3000..=3000 {
        let k = f64::from(i) * 0.5;
        for d in [
            0.0,
            0.01,
            -0.01,
            1e-9,
            -1e-9,
            0.25,
            -0.25,
            0.4999999999,
            -0.4999999999,
        ] {
            xs.push(k + d);
        }
    }
    for e in [20, 21, 22, 23, 40, 60] {
        let big = 2f64.powi(e);
        xs.extend([big, -big, big + 0.5, -big - 0.5, big - 0.5, 1.5 * big]);
    }
    for x in xs {
        let c = x.clamp(-COORD_CLAMP, COORD_CLAMP);
        assert_eq!(f64::from(ceil_clamped(x)), c.ceil(), "ceil of {x}");
        assert_eq!(f64::from(floor_clamped(x)), c.floor(), "floor of {x}");
    }
}
