//! The parametric lumbar phantom: closed meshes whose volumes match the SDF, landmarks consistent with the
//! SDF, published morphometry, the placement rule and tissue classification.

use glam::DVec3;
use rayon::prelude::*;
use spinedrr::anatomy::{
    Level, Phantom, PhantomOptions, Structure, Tissue, TriMesh, build_phantom, parse_levels,
};

fn phantom() -> &'static Phantom {
    crate::common::phantom_with_soft_tissue()
}

/// Bound on the SDFs' gradient norm, checked by `sdf_gradient_is_bounded`.
const LIPSCHITZ: f64 = 4.0;

/// Volume of `{f < 0}` by adaptive point counting: a cube whose centre is farther from the surface than
/// its half-diagonal times a Lipschitz bound is wholly in or out; others are split down to `min_cell` and
/// counted by their centre. Independent of the mesher (no interpolation, no triangles). The grid is
/// offset by an irrational-looking fraction of a cell so that no flat face of the phantom (they sit at
/// round coordinates) lies on a plane of cell centres, where counting by centre is biased.
fn sdf_volume(f: &(dyn Fn(DVec3) -> f64 + Sync), lo: DVec3, hi: DVec3) -> f64 {
    const TOP: f64 = 4.0;
    const MIN_CELL: f64 = 0.25;
    const JITTER: DVec3 = DVec3::new(0.0371, 0.0593, 0.0217);
    fn cell(f: &(dyn Fn(DVec3) -> f64 + Sync), c: DVec3, s: f64) -> f64 {
        let d = f(c);
        let reach = s * 0.87 * LIPSCHITZ;
        if d > reach {
            0.0
        } else if d < -reach {
            s * s * s
        } else if s <= MIN_CELL {
            if d < 0.0 { s * s * s } else { 0.0 }
        } else {
            let q = s / 4.0;
            let mut v = 0.0;
            for k in 0..8 {
                let o = DVec3::new(
                    if k & 1 == 0 { -q } else { q },
                    if k & 2 == 0 { -q } else { q },
                    if k & 4 == 0 { -q } else { q },
                );
                v += cell(f, c + o, s / 2.0);
            }
            v
        }
    }
    let n = ((hi - lo) / TOP).ceil();
    let (nx, ny, nz) = (n.x as usize, n.y as usize, n.z as usize);
    (0..nx * ny * nz)
        .into_par_iter()
        .map(|i| {
            let idx = DVec3::new(
                (i % nx) as f64,
                ((i / nx) % ny) as f64,
                (i / (nx * ny)) as f64,
            );
            cell(f, lo + JITTER + (idx + 0.5) * TOP, TOP)
        })
        .sum()
}

fn padded_bounds(m: &TriMesh) -> (DVec3, DVec3) {
    let (lo, hi) = m.bounds().unwrap();
    (lo - DVec3::splat(3.0), hi + DVec3::splat(3.0))
}

fn assert_closed_with_volume(m: &TriMesh, f: &(dyn Fn(DVec3) -> f64 + Sync)) {
    let chk = m.check();
    assert!(chk.is_watertight(), "{}: {chk:?}", m.name);
    let (lo, hi) = padded_bounds(m);
    let expected = sdf_volume(f, lo, hi);
    let rel = m.volume() / expected - 1.0;
    eprintln!(
        "{}: {} triangles, volume {:.0} mm³ (SDF {:.0}, {:+.2} %)",
        m.name,
        m.triangles.len(),
        m.volume(),
        expected,
        rel * 100.0
    );
    assert!(
        rel.abs() < 0.01,
        "{}: mesh {} vs SDF {expected}",
        m.name,
        m.volume()
    );
}

#[test]
fn every_vertebra_mesh_is_closed_and_matches_the_sdf_volume() {
    let p = phantom();
    assert_eq!(p.vertebrae.len(), 5);
    for v in &p.vertebrae {
        let c = p.cortical_mm;
        assert_closed_with_volume(&v.cortical, &|x| v.sdf(x));
        assert_closed_with_volume(&v.cancellous, &|x| v.sdf(x) + c);
        assert!(v.cancellous.volume() < v.cortical.volume());
        assert_eq!(v.cortical.labels.len(), v.cortical.triangles.len());
    }
}

#[test]
fn sdf_gradient_is_bounded() {
    // The adaptive volume count relies on |f(p) − f(q)| ≤ LIPSCHITZ·|p − q|: check on random pairs.
    let p = phantom();
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut rnd = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    for v in &p.vertebrae {
        let (lo, hi) = padded_bounds(&v.cortical);
        for _ in 0..200_000 {
            let x = lo + (hi - lo) * DVec3::new(rnd(), rnd(), rnd());
            let d = DVec3::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5).normalize() * 0.01;
            let g = (v.sdf(x + d) - v.sdf(x)).abs() / 0.01;
            assert!(g < LIPSCHITZ, "{}: gradient {g} at {x:?}", v.level);
        }
    }
}

#[test]
fn discs_and_soft_tissue_are_closed_and_match_their_sdf() {
    let p = phantom();
    assert_eq!(p.discs.len(), 4);
    for (m, d) in p.discs.iter().zip(&p.disc_shapes) {
        assert_closed_with_volume(m, &|x| d.sdf(x));
    }
    let s = p.soft_tissue.as_ref().unwrap();
    let shape = p.soft_tissue_shape.unwrap();
    assert!(s.check().is_watertight());
    // Coarse (3 mm) mesh of a large smooth cylinder: compare with the analytic volume of the rounded
    // elliptic cylinder, π a b (2h) minus the rim rounding (small): within 1 %.
    let (lo, hi) = padded_bounds(s);
    let expected = sdf_volume(&|x| shape.sdf(x), lo, hi);
    assert!(
        (s.volume() / expected - 1.0).abs() < 0.01,
        "{} vs {expected}",
        s.volume()
    );
}

#[test]
fn landmarks_relate_to_the_sdf_as_expected() {
    let p = phantom();
    for v in &p.vertebrae {
        let lm = &v.landmarks;
        assert_eq!(lm.level, v.level.name());
        let sdf = |name: &str| v.sdf(lm.get(name).unwrap_or_else(|| panic!("{name} missing")));
        // Deep inside: body centre (half the smallest body dimension) and pedicle centres.
        assert!(
            sdf("center") < -10.0,
            "{}: center {}",
            lm.level,
            sdf("center")
        );
        assert!(sdf("left_pedicle") < -2.5 && sdf("right_pedicle") < -2.5);
        // On the surface: spinous tip, endplate centres, the four mid-sagittal body corners.
        for name in [
            "spinous_tip",
            "superior_endplate",
            "inferior_endplate",
            "corner_anterior_superior",
            "corner_anterior_inferior",
            "corner_posterior_superior",
            "corner_posterior_inferior",
        ] {
            assert!(
                sdf(name).abs() < 0.05,
                "{} {name}: sdf {}",
                lm.level,
                sdf(name)
            );
        }
        // Anatomical order in the vertebra's own frame.
        let local = |n: &str| v.local_to_world.inverse().apply(lm.get(n).unwrap());
        assert!(local("left_pedicle").x < 0.0 && local("right_pedicle").x > 0.0);
        assert!(local("spinous_tip").y < local("left_pedicle").y);
        assert!(local("corner_anterior_superior").y > 0.0 && local("superior_endplate").z > 0.0);
        assert!(lm.points.len() == 10);
    }
}

#[test]
fn endplate_labels_sit_on_the_body_faces() {
    // The body's sizes are measured against the cited morphometry table, level by level, in
    // tests/phantom_morphometry.rs.
    let p = phantom();
    for v in &p.vertebrae {
        let inv = v.local_to_world.inverse();
        // Endplate labels exist on both faces and sit at the top/bottom of the body.
        for (s, sign) in [
            (Structure::SuperiorEndplate, 1.0),
            (Structure::InferiorEndplate, -1.0),
        ] {
            let z: Vec<f64> = (0..v.cortical.triangles.len())
                .filter(|&i| v.cortical.label(i) == s)
                .map(|i| inv.apply(v.cortical.corners(i)[0]).z * sign)
                .collect();
            // Within two rim radii and the concavity of the rim plane (the labelling rule), 0.5 mm slack.
            let sh = &v.shape.params;
            let face = v.shape.morphometry.body_height / 2.0
                - 2.0 * sh.body_rim_mm
                - sh.endplate_concavity_mm
                - 0.5;
            assert!(
                z.len() > 100 && z.iter().all(|&z| z > face),
                "{} {s:?}",
                v.level
            );
        }
    }
}

#[test]
fn middle_level_sits_at_the_origin_and_levels_stack_downward() {
    let p = phantom();
    let centres: Vec<DVec3> = p
        .vertebrae
        .iter()
        .map(|v| v.landmarks.get("center").unwrap())
        .collect();
    assert!(centres[2].length() < 1e-12, "L3 centre {:?}", centres[2]);
    assert!(centres.windows(2).all(|c| c[0].z > c[1].z + 30.0));
    // Lordosis: L1 and L5 lie posterior of L3 (convex anteriorly).
    assert!(centres[0].y < 0.0 && centres[4].y < 0.0);
    // Disc height: gap between L3 inferior endplate and L4 superior endplate centres.
    let gap = p.vertebrae[2].landmarks.get("inferior_endplate").unwrap()
        - p.vertebrae[3].landmarks.get("superior_endplate").unwrap();
    assert!((gap.length() - 10.0).abs() < 1e-9);
    // Adjacent vertebrae do not overlap (sampled on the lower one's vertices).
    for w in p.vertebrae.windows(2) {
        assert!(
            w[1].cortical
                .vertices
                .iter()
                .step_by(7)
                .all(|&x| w[0].sdf(x) > 0.0)
        );
    }
}

#[test]
fn single_level_is_centred_and_classification_matches_sdfs() {
    let opts = PhantomOptions {
        levels: parse_levels("L4").unwrap(),
        discs: false,
        ..PhantomOptions::default()
    };
    let p = build_phantom(&opts).unwrap();
    assert_eq!(p.vertebrae.len(), 1);
    assert_eq!(p.vertebrae[0].level, Level::L4);
    assert!(p.vertebrae[0].landmarks.get("center").unwrap().length() < 1e-12);
    assert_eq!(p.classify(DVec3::ZERO), Tissue::Cancellous);
    let top = p.vertebrae[0].landmarks.get("superior_endplate").unwrap();
    assert_eq!(p.classify(top - DVec3::Z * 0.5), Tissue::Cortical);
    assert_eq!(p.classify(top + DVec3::Z * 0.5), Tissue::Air);
    let full = phantom();
    let disc_mid = (full.vertebrae[1]
        .landmarks
        .get("inferior_endplate")
        .unwrap()
        + full.vertebrae[2]
            .landmarks
            .get("superior_endplate")
            .unwrap())
        / 2.0;
    assert_eq!(full.classify(disc_mid), Tissue::Disc);
    assert_eq!(
        full.classify(DVec3::new(100.0, 0.0, 0.0)),
        Tissue::SoftTissue
    );
    assert_eq!(full.classify(DVec3::new(200.0, 0.0, 0.0)), Tissue::Air);
}

#[test]
fn level_specs_parse_or_fail_clearly() {
    assert_eq!(parse_levels("L1-L5").unwrap(), Level::ALL.to_vec());
    assert_eq!(parse_levels("l3").unwrap(), vec![Level::L3]);
    assert_eq!(parse_levels("L3, L1").unwrap(), vec![Level::L1, Level::L3]);
    for bad in ["L6", "L5-L1", "", "T12", "L1,,L2"] {
        let e = parse_levels(bad).unwrap_err().to_string();
        assert!(e.contains("levels"), "{bad}: {e}");
    }
}
