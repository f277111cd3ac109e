//! Metrics against analytic cases, a second method, and OpenCV.

use std::collections::BTreeSet;
use std::f64::consts::PI;

use glam::{DVec2, DVec3};
use spinedrr::analysis::*;
use spinedrr::geometry::{CArm, Perturbation};
use spinedrr::io::ImageF32;
use spinedrr::registration::SplitMix64;

fn disc(w: u32, h: u32, c: DVec2, r: f64) -> Vec<bool> {
    (0..h)
        .flat_map(|v| (0..w).map(move |u| (DVec2::new(u as f64, v as f64) - c).length() <= r))
        .collect()
}

fn circle(c: DVec2, r: f64, n: usize) -> Vec<DVec2> {
    (0..n)
        .map(|k| {
            let a = k as f64 * 2.0 * PI / n as f64;
            c + r * DVec2::new(a.cos(), a.sin())
        })
        .collect()
}

/// Area of the intersection of two discs (radii r1 ≥ r2, centre distance d, partial overlap).
fn lens_area(r1: f64, r2: f64, d: f64) -> f64 {
    r1 * r1 * ((d * d + r1 * r1 - r2 * r2) / (2.0 * d * r1)).acos()
        + r2 * r2 * ((d * d + r2 * r2 - r1 * r1) / (2.0 * d * r2)).acos()
        - 0.5 * ((-d + r1 + r2) * (d + r1 - r2) * (d - r1 + r2) * (d + r1 + r2)).sqrt()
}

#[test]
fn two_discs_dice_iou_hausdorff_match_geometry() {
    let (w, h) = (400, 360);
    let (r1, r2, d) = (100.0, 80.0, 30.0);
    let (c1, c2) = (DVec2::new(190.5, 170.25), DVec2::new(220.5, 170.25));
    let (a, b) = (disc(w, h, c1, r1), disc(w, h, c2, r2));
    let inter = lens_area(r1, r2, d);
    let (sa, sb) = (PI * r1 * r1, PI * r2 * r2);
    let dice_exact = 2.0 * inter / (sa + sb);
    let iou_exact = inter / (sa + sb - inter);
    let (dice, iou) = dice_iou(&a, &b).unwrap();
    // Pixel discretisation of a disc of radius ≥ 80 changes areas by well under 0.2 %.
    assert!((dice - dice_exact).abs() < 2e-3, "{dice} vs {dice_exact}");
    assert!((iou - iou_exact).abs() < 2e-3, "{iou} vs {iou_exact}");
    // Hausdorff of the two circles is d + r1 − r2 (the far side of the offset).
    let exact = d + r1 - r2;
    let dense = ContourDistances::between(&circle(c1, r1, 20000), &circle(c2, r2, 20000)).unwrap();
    assert!(
        (dense.hausdorff() - exact).abs() < 1e-3,
        "{}",
        dense.hausdorff()
    );
    let px = ContourDistances::between(
        &contour_points(&a, w, h).unwrap(),
        &contour_points(&b, w, h).unwrap(),
    )
    .unwrap();
    // Border pixels lie within one pixel inside the true circle.
    assert!((px.hausdorff() - exact).abs() < 1.5, "{}", px.hausdorff());
    assert_eq!(dice_iou(&a, &a).unwrap(), (1.0, 1.0));
    assert!(dice_iou(&a, &b[1..]).is_err());
}

#[test]
fn translated_and_offset_contours_have_distance_equal_to_the_shift() {
    // A straight contour and its perpendicular translate: every nearest distance equals the shift.
    let line: Vec<DVec2> = (0..1000)
        .map(|k| DVec2::new(k as f64 * 0.5, 10.0))
        .collect();
    let shifted: Vec<DVec2> = line.iter().map(|p| *p + DVec2::new(0.0, 2.5)).collect();
    let d = ContourDistances::between(&line, &shifted).unwrap();
    assert!((d.chamfer_mean() - 2.5).abs() < 1e-12);
    assert!((d.hausdorff() - 2.5).abs() < 1e-12);
    assert!((d.hd95() - 2.5).abs() < 1e-12);
    assert!((d.chamfer_sum() - 2.5 * 1000.0).abs() < 1e-9);
    // Concentric circles: the offset curve is at constant distance s.
    let c = DVec2::new(3.0, -7.0);
    let d = ContourDistances::between(&circle(c, 50.0, 50000), &circle(c, 53.0, 50000)).unwrap();
    assert!((d.chamfer_mean() - 3.0).abs() < 1e-4);
    assert!((d.hd95() - 3.0).abs() < 1e-4);
}

#[test]
fn nearest_neighbour_grid_matches_brute_force() {
    let mut rng = SplitMix64::new(5);
    let a: Vec<DVec2> = (0..700)
        .map(|_| DVec2::new(rng.uniform(), rng.uniform()) * 300.0)
        .collect();
    let b: Vec<DVec2> = (0..400)
        .map(|_| DVec2::new(rng.uniform() * 50.0 + 400.0, rng.uniform() * 900.0))
        .collect();
    let got = directed_distances(&a, &b);
    for (p, g) in a.iter().zip(got) {
        let brute = b
            .iter()
            .map(|q| (*p - *q).length())
            .fold(f64::INFINITY, f64::min);
        assert_eq!(g, brute);
    }
}

#[test]
fn opencv_contours_are_the_border_pixels_and_edge_distance_agrees() {
    let (w, h) = (200, 150);
    let a = disc(w, h, DVec2::new(90.3, 70.6), 40.0);
    let b = disc(w, h, DVec2::new(96.1, 73.0), 43.5);
    let from_cv: BTreeSet<(i64, i64)> = contour_points(&a, w, h)
        .unwrap()
        .iter()
        .map(|p| (p.x as i64, p.y as i64))
        .collect();
    let border = border_pixels(&a, w, h).unwrap();
    let direct: BTreeSet<(i64, i64)> = (0..h as i64)
        .flat_map(|v| (0..w as i64).map(move |u| (u, v)))
        .filter(|&(u, v)| border[(v * w as i64 + u) as usize])
        .collect();
    assert_eq!(from_cv, direct);
    assert_eq!(contours(&a, w, h).unwrap().len(), 1);
    // A ring has two boundaries (outer and hole).
    let ring: Vec<bool> = a
        .iter()
        .zip(disc(w, h, DVec2::new(90.3, 70.6), 20.0))
        .map(|(x, y)| *x && !y)
        .collect();
    assert_eq!(contours(&ring, w, h).unwrap().len(), 2);
    // OpenCV's exact distance transform and our nearest-neighbour search measure the same thing.
    let (edge_mean, edge_max) = edge_distance(&a, &b, w, h).unwrap();
    let d = ContourDistances::between(
        &contour_points(&a, w, h).unwrap(),
        &contour_points(&b, w, h).unwrap(),
    )
    .unwrap();
    assert!(
        (edge_mean - d.chamfer_mean()).abs() < 1e-4,
        "{edge_mean} vs {}",
        d.chamfer_mean()
    );
    assert!((edge_max - d.hausdorff()).abs() < 1e-4);
    // Sub-pixel boundary of a disc lies within half a pixel of the true circle.
    for p in subpixel_boundary(&a, w, h).unwrap() {
        assert!(((p - DVec2::new(90.3, 70.6)).length() - 40.0).abs() < 0.75);
    }
}

fn random_image(w: u32, h: u32, seed: u64) -> ImageF32 {
    let mut rng = SplitMix64::new(seed);
    let mut img = ImageF32::zeros(w, h);
    for (i, v) in img.data.iter_mut().enumerate() {
        let (u, y) = ((i % w as usize) as f64, (i / w as usize) as f64);
        *v = ((u * 0.05).sin() * (y * 0.03).cos() + 0.3 * rng.uniform()) as f32;
    }
    img
}

fn negative(a: &ImageF32) -> ImageF32 {
    ImageF32 {
        data: a.data.iter().map(|v| -v).collect(),
        ..a.clone()
    }
}

/// Entropy (nats) of the image's own histogram over [min, max] with `bins` bins.
fn entropy(a: &ImageF32, bins: usize) -> f64 {
    let (lo, hi) = a
        .data
        .iter()
        .fold((f32::MAX, f32::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    let mut hist = vec![0.0; bins];
    for &v in &a.data {
        let t = f64::from(v - lo) / f64::from(hi - lo);
        hist[((t * bins as f64) as usize).min(bins - 1)] += 1.0;
    }
    let n = a.data.len() as f64;
    hist.iter()
        .filter(|&&c| c > 0.0)
        .map(|&c| -(c / n) * (c / n).ln())
        .sum()
}

#[test]
fn identical_and_negative_images() {
    let a = random_image(64, 48, 1);
    let neg = negative(&a);
    assert!((ncc(&a, &a).unwrap() - 1.0).abs() < 1e-12);
    assert!((ssim(&a, &a).unwrap() - 1.0).abs() < 1e-12);
    assert!((gradient_correlation(&a, &a).unwrap() - 1.0).abs() < 1e-12);
    assert!((ncc(&a, &neg).unwrap() + 1.0).abs() < 1e-12);
    assert!((gradient_correlation(&a, &neg).unwrap() + 1.0).abs() < 1e-12);
    // MI of an image with itself is its entropy; negation is a bijection of the bins.
    let h = entropy(&a, 32);
    assert!((mutual_information(&a, &a, 32).unwrap() - h).abs() < 1e-12);
    assert!((mutual_information(&a, &neg, 32).unwrap() - h).abs() < 1e-9);
    // An independent image shares little information.
    let other = random_image(64, 48, 2);
    let noise = ImageF32 {
        data: other.data.iter().zip(&a.data).map(|(x, y)| x - y).collect(),
        ..a.clone()
    };
    assert!(mutual_information(&a, &noise, 32).unwrap() < h);
    let constant = ImageF32 {
        data: vec![1.0; a.data.len()],
        ..a.clone()
    };
    assert!(ncc(&a, &constant).is_err());
    assert!(ncc(&a, &ImageF32::zeros(3, 3)).is_err());
}

/// SSIM by direct 11×11 window sums (no separable filtering), straight from Wang et al.'s definition.
fn ssim_brute(a: &ImageF32, b: &ImageF32) -> f64 {
    ssim_brute_in(a, b, None)
}

/// The windowed SSIM averaged over the windows centred in `region` (all when `None`).
fn ssim_brute_in(a: &ImageF32, b: &ImageF32, region: Option<&[bool]>) -> f64 {
    let (w, h) = (a.width as usize, a.height as usize);
    let mut windows = 0usize;
    let g: Vec<f64> = (0..11)
        .map(|i| (-((i as f64 - 5.0).powi(2)) / 4.5).exp())
        .collect();
    let gs: f64 = g.iter().sum::<f64>().powi(2);
    let (lo, hi) = a
        .data
        .iter()
        .fold((f32::MAX, f32::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    let l = f64::from(hi - lo);
    let (c1, c2) = ((0.01 * l).powi(2), (0.03 * l).powi(2));
    let mut total = 0.0;
    for v in 0..h - 10 {
        for u in 0..w - 10 {
            if region.is_some_and(|r| !r[(v + 5) * w + u + 5]) {
                continue;
            }
            windows += 1;
            let (mut ma, mut mb) = (0.0, 0.0);
            for j in 0..11 {
                for i in 0..11 {
                    let k = g[i] * g[j] / gs;
                    ma += k * f64::from(a.data[(v + j) * w + u + i]);
                    mb += k * f64::from(b.data[(v + j) * w + u + i]);
                }
            }
            let (mut va, mut vb, mut cab) = (0.0, 0.0, 0.0);
            for j in 0..11 {
                for i in 0..11 {
                    let k = g[i] * g[j] / gs;
                    let x = f64::from(a.data[(v + j) * w + u + i]) - ma;
                    let y = f64::from(b.data[(v + j) * w + u + i]) - mb;
                    va += k * x * x;
                    vb += k * y * y;
                    cab += k * x * y;
                }
            }
            total += ((2.0 * ma * mb + c1) * (2.0 * cab + c2))
                / ((ma * ma + mb * mb + c1) * (va + vb + c2));
        }
    }
    total / windows as f64
}

#[test]
fn ssim_matches_the_windowed_definition() {
    let a = random_image(40, 31, 3);
    let b = random_image(40, 31, 4);
    for other in [&b, &negative(&a)] {
        let fast = ssim(&a, other).unwrap();
        let brute = ssim_brute(&a, other);
        assert!((fast - brute).abs() < 1e-9, "{fast} vs {brute}");
    }
}

/// `img` with rows `rows` set to zero (DRR background), for the blank-row shortcuts.
fn with_blank_rows(img: &ImageF32, rows: impl Iterator<Item = usize>) -> ImageF32 {
    let mut out = img.clone();
    let w = img.width as usize;
    for v in rows {
        out.data[v * w..(v + 1) * w].fill(0.0);
    }
    out
}

#[test]
fn blank_background_rows_give_the_windowed_definition() {
    // Zero bands in both images (top, a 14-row middle band, bottom), and one band zero in `a` only.
    let bands = || (0..12).chain(20..34).chain(50..61);
    let a = with_blank_rows(&random_image(40, 61, 5), bands().chain(40..44));
    let b = with_blank_rows(&random_image(40, 61, 6), bands());
    let (fast, brute) = (ssim(&a, &b).unwrap(), ssim_brute(&a, &b));
    assert!((fast - brute).abs() < 1e-9, "SSIM {fast} vs {brute}");
    let (fast, brute) = (
        gradient_correlation(&a, &b).unwrap(),
        gradient_correlation_brute(&a, &b),
    );
    assert!((fast - brute).abs() < 1e-10, "GC {fast} vs {brute}");
}

#[test]
fn landmark_shifts_follow_the_homography_law() {
    let carm = CArm::default_paper();
    let lms: Vec<Landmark> = [[0.0, 0.0, 0.0], [20.0, 5.0, -12.0], [-30.0, -40.0, 10.0]]
        .iter()
        .enumerate()
        .map(|(i, p)| Landmark {
            name: format!("l{i}"),
            position: DVec3::from(*p),
        })
        .collect();
    for view in ["ap", "lat"] {
        let r = carm.view(view).unwrap();
        // Focal scaling about the principal point: ‖Δx‖ = |α − 1| ‖x − c‖.
        let p = r.perturbed(&Perturbation::focal(300.0)).unwrap();
        let alpha = p.intrinsics.fx / r.intrinsics.fx;
        let c = DVec2::new(r.intrinsics.cx, r.intrinsics.cy);
        for s in landmark_shifts(r, &p, &lms) {
            let expect = (alpha - 1.0).abs() * (DVec2::from(s.reference_px) - c).length();
            assert!(
                (s.shift_px - expect).abs() < 1e-9,
                "{view} {}: {} vs {expect}",
                s.name,
                s.shift_px
            );
            assert!((s.predicted_shift_px - expect).abs() < 1e-9);
        }
        // A piercing shift moves every landmark by (Δcx, Δcy).
        let p = r.perturbed(&Perturbation::piercing(20.0, -10.0)).unwrap();
        for s in landmark_shifts(r, &p, &lms) {
            let d = DVec2::from(s.perturbed_px) - DVec2::from(s.reference_px);
            assert!((d - DVec2::new(20.0, -10.0)).length() < 1e-9);
        }
    }
}

#[test]
fn blob_centroid_finds_a_subpixel_gaussian() {
    let centre = DVec2::new(40.37, 22.81);
    let mut img = ImageF32::zeros(80, 50);
    for v in 0..50 {
        for u in 0..80 {
            let r2 = (DVec2::new(u as f64, v as f64) - centre).length_squared();
            img.data[v * 80 + u] = (-r2 / 8.0).exp() as f32;
        }
    }
    let got = blob_centroid(&img, DVec2::new(42.0, 21.0), 14.0).unwrap();
    // f32 pixel values limit the centroid to ~1e-6 px.
    assert!((got - centre).length() < 1e-5, "{got:?}");
    assert!(blob_centroid(&ImageF32::zeros(10, 10), DVec2::new(5.0, 5.0), 3.0).is_none());
    assert!(blob_centroid(&img, DVec2::new(-100.0, 5.0), 3.0).is_none());
    assert!(blob_centroid(&img, DVec2::new(f64::NAN, 5.0), 3.0).is_none());
}

#[test]
fn heatmap_png_and_landmark_json() {
    let dir = tempfile::tempdir().unwrap();
    let a = random_image(64, 64, 9);
    let b = ImageF32 {
        data: a.data.iter().map(|v| v * 0.5).collect(),
        ..a.clone()
    };
    let d = abs_difference(&a, &b).unwrap();
    for (x, (y, z)) in d.data.iter().zip(a.data.iter().zip(&b.data)) {
        assert_eq!(*x, (y - z).abs());
    }
    let path = dir.path().join("h.png");
    let carm = CArm::default_paper();
    let side = spinedrr::io::Sidecar::new(
        "heatmap",
        "test",
        carm.view("ap").unwrap(),
        &Perturbation::parse("none").unwrap(),
    )
    .unwrap();
    spinedrr::io::write_heatmap_png(&path, &d, &side).unwrap();
    assert!(dir.path().join("h.json").exists());
    let png = image::open(&path).unwrap().into_rgb8();
    assert_eq!(png.dimensions(), (64 + 130, 64));
    // The hottest pixel is viridis(1), the coldest viridis(0).
    let imax = d
        .data
        .iter()
        .enumerate()
        .max_by(|x, y| x.1.total_cmp(y.1))
        .unwrap()
        .0;
    let top = colorous::VIRIDIS.eval_continuous(1.0);
    assert_eq!(
        png.get_pixel((imax % 64) as u32, (imax / 64) as u32).0,
        [top.r, top.g, top.b]
    );
    assert_eq!(spinedrr::io::format_label(0.1234), "0.123");
    assert_eq!(spinedrr::io::format_label(2.5e-5), "2.50e-5");

    let lms = parse_landmarks(
        r#"{"level": "L1", "landmarks": {"a": [1, 2, 3], "b": [0, 0, 1]}}"#,
        "x.json",
    )
    .unwrap();
    assert_eq!(lms.len(), 2);
    let lms = parse_landmarks(
        r#"[{"level": "L2", "landmarks": {"a": [1, 2, 3]}}]"#,
        "x.json",
    )
    .unwrap();
    assert_eq!(lms[0].name, "L2/a");
    let e = parse_landmarks(r#"{"landmarks": {"a": [1, 2]}}"#, "bad.json")
        .unwrap_err()
        .to_string();
    assert!(e.contains("bad.json"), "{e}");
}

/// Penney's gradient correlation from explicit Sobel images and two-pass Pearson correlations.
#[allow(clippy::needless_range_loop)] // explicit kernel indices are the point of this oracle
fn gradient_correlation_brute(a: &ImageF32, b: &ImageF32) -> f64 {
    gradient_correlation_brute_in(a, b, None)
}

/// [`gradient_correlation_brute`] over the Sobel responses centred in `region` (all when `None`).
#[allow(clippy::needless_range_loop)]
fn gradient_correlation_brute_in(a: &ImageF32, b: &ImageF32, region: Option<&[bool]>) -> f64 {
    let (w, h) = (a.width as usize, a.height as usize);
    let sobel = |img: &ImageF32, dx: bool| -> Vec<f64> {
        let p = |u: usize, v: usize| f64::from(img.data[v * w + u]);
        let mut out = Vec::new();
        for v in 1..h - 1 {
            for u in 1..w - 1 {
                if region.is_some_and(|r| !r[v * w + u]) {
                    continue;
                }
                let (k, kt) = ([[-1.0, 0.0, 1.0], [-2.0, 0.0, 2.0], [-1.0, 0.0, 1.0]], dx);
                let mut s = 0.0;
                for j in 0..3 {
                    for i in 0..3 {
                        let c = if kt { k[j][i] } else { k[i][j] };
                        s += c * p(u + i - 1, v + j - 1);
                    }
                }
                out.push(s);
            }
        }
        out
    };
    let pearson = |x: &[f64], y: &[f64]| {
        let n = x.len() as f64;
        let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
        let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
        let sxx: f64 = x.iter().map(|a| (a - mx).powi(2)).sum();
        let syy: f64 = y.iter().map(|b| (b - my).powi(2)).sum();
        sxy / (sxx * syy).sqrt()
    };
    0.5 * (pearson(&sobel(a, true), &sobel(b, true)) + pearson(&sobel(a, false), &sobel(b, false)))
}

/// The pixels of `img` in `region`, as a one-row image (an independent path to the region NCC and MI).
fn pixels_in(img: &ImageF32, region: &[bool]) -> ImageF32 {
    let data: Vec<f32> = img
        .data
        .iter()
        .zip(region)
        .filter(|(_, r)| **r)
        .map(|(v, _)| *v)
        .collect();
    let mut out = ImageF32::zeros(data.len() as u32, 1);
    out.data = data;
    out
}

#[test]
fn region_similarities_are_the_definitions_restricted_to_the_region() {
    // Two images with background bands, and a region around two offset discs.
    let bands = || (0..8).chain(52..61);
    let a = with_blank_rows(&random_image(48, 61, 31), bands());
    let b = with_blank_rows(&random_image(48, 61, 32), bands().chain(30..33));
    let region = Region::around(
        &disc(48, 61, DVec2::new(20.0, 28.0), 9.0),
        &disc(48, 61, DVec2::new(26.0, 31.0), 9.0),
        48,
        61,
        4,
    )
    .unwrap();
    let r = Some(&region);
    let inside = Some(region.inside.as_slice());
    let (fast, brute) = (ssim_in(&a, &b, r).unwrap(), ssim_brute_in(&a, &b, inside));
    assert!((fast - brute).abs() < 1e-9, "SSIM {fast} vs {brute}");
    let (fast, brute) = (
        gradient_correlation_in(&a, &b, r).unwrap(),
        gradient_correlation_brute_in(&a, &b, inside),
    );
    assert!((fast - brute).abs() < 1e-10, "GC {fast} vs {brute}");
    let (pa, pb) = (pixels_in(&a, &region.inside), pixels_in(&b, &region.inside));
    assert_eq!(pa.data.len(), region.len());
    let (fast, other) = (ncc_in(&a, &b, r).unwrap(), ncc(&pa, &pb).unwrap());
    assert!((fast - other).abs() < 1e-12, "NCC {fast} vs {other}");
    let fast = mutual_information_in(&a, &b, 16, r).unwrap();
    let other = mutual_information(&pa, &pb, 16).unwrap();
    assert!((fast - other).abs() < 1e-12, "MI {fast} vs {other}");
    // One pass gives both, bit for bit.
    assert_eq!(
        ssim_whole_and_in(&a, &b, &region).unwrap(),
        (ssim(&a, &b).unwrap(), ssim_in(&a, &b, r).unwrap())
    );
    assert_eq!(
        gradient_correlation_whole_and_in(&a, &b, &region).unwrap(),
        (
            gradient_correlation(&a, &b).unwrap(),
            gradient_correlation_in(&a, &b, r).unwrap()
        )
    );
    let (whole, inside) = image_metrics_whole_and_in(&a, &b, &region).unwrap();
    assert_eq!(whole, image_metrics(&a, &b).unwrap());
    assert_eq!(inside, image_metrics_in(&a, &b, r).unwrap());
    // The whole image as a region is the whole-image measure; an empty or mis-sized region is an error.
    let all = Region {
        width: 48,
        height: 61,
        inside: vec![true; 48 * 61],
    };
    assert_eq!(ssim_in(&a, &b, Some(&all)).unwrap(), ssim(&a, &b).unwrap());
    let none = Region {
        inside: vec![false; 48 * 61],
        ..all.clone()
    };
    assert!(ssim_in(&a, &b, Some(&none)).is_err());
    let small = Region {
        width: 47,
        inside: vec![true; 47 * 61],
        ..all
    };
    assert!(ncc_in(&a, &b, Some(&small)).is_err());
}

#[test]
fn gradient_correlation_matches_explicit_sobel_images() {
    let a = random_image(57, 43, 21);
    let b = random_image(57, 43, 22);
    let fast = gradient_correlation(&a, &b).unwrap();
    let brute = gradient_correlation_brute(&a, &b);
    assert!((fast - brute).abs() < 1e-10, "{fast} vs {brute}");
}
