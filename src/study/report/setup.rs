//! *Setup*: the geometry every number of the report depends on, stated before the findings — per view
//! the source, the central ray's point nearest the world origin (the aim), distances, magnification,
//! detector and K; per target and view where its reference silhouette lies relative to the piercing
//! point and how large it is on the detector, in px and mm. Computed from the effective geometry
//! (the built-in or `geometry.file`, binned) and the reference DRRs under `references/`.

use std::fmt::Write as _;
use std::path::Path;

use glam::DVec3;

use super::layout::num;
use crate::geometry::View;
use crate::io::read_tiff_f32;
use crate::study::config::{SEGMENT_TARGET, StudyConfig};
use crate::study::experiments::reference_image_path;
use crate::study::figures::{FigureEntry, Section};
use crate::study::schema::ProjectionRow;

pub const HEADING: &str = "Setup";

/// `x` to one decimal, without a sign on a value that rounds to zero.
fn one_decimal(x: f64) -> String {
    let s = format!("{x:.1}");
    if s == "-0.0" { "0.0".into() } else { s }
}

fn mm(v: DVec3) -> String {
    // + 0.0 turns −0 into 0.
    let r = |x: f64| x.round() + 0.0;
    format!("({}, {}, {})", r(v.x), r(v.y), r(v.z))
}

/// Where a reference silhouette (pixels > 0) lies: centroid, bounding box, and whether it touches the
/// detector's edge.
struct Footprint {
    centroid: (f64, f64),
    size_px: (u32, u32),
    touches_edge: bool,
}

/// The Setup's "on the detector" cell: the reference silhouette whole or cut, and in how many of the
/// perturbed cells of `projection` the detector cuts it.
fn on_detector(
    reference_cut: bool,
    projection: &[ProjectionRow],
    target: &str,
    view: &str,
) -> String {
    let rows: Vec<&ProjectionRow> = projection
        .iter()
        .filter(|r| r.target == target && r.view == view)
        .collect();
    let cut = rows.iter().filter(|r| r.cut_by_edge).count();
    let reference = if reference_cut {
        "**cut by the edge**"
    } else {
        "whole"
    };
    if cut == 0 {
        reference.to_string()
    } else {
        format!(
            "{reference}; **cut in {cut} of {} perturbed cells**",
            rows.len()
        )
    }
}

/// Whether `target`'s reference silhouette in `view` touches the detector edge (cut off).
pub fn cut_by_edge(out: &Path, target: &str, view: &str) -> bool {
    footprint(out, target, view).is_some_and(|f| f.touches_edge)
}

fn footprint(out: &Path, target: &str, view: &str) -> Option<Footprint> {
    let img = read_tiff_f32(&reference_image_path(out, target, view)).ok()?;
    let (w, h) = (img.width, img.height);
    let (mut n, mut su, mut sv) = (0usize, 0.0, 0.0);
    let (mut u0, mut v0, mut u1, mut v1) = (u32::MAX, u32::MAX, 0, 0);
    for (i, &x) in img.data.iter().enumerate() {
        if x > 0.0 {
            let (u, v) = ((i % w as usize) as u32, (i / w as usize) as u32);
            n += 1;
            su += f64::from(u);
            sv += f64::from(v);
            (u0, v0, u1, v1) = (u0.min(u), v0.min(v), u1.max(u), v1.max(v));
        }
    }
    (n > 0).then(|| Footprint {
        centroid: (su / n as f64, sv / n as f64),
        size_px: (u1 - u0 + 1, v1 - v0 + 1),
        touches_edge: u0 == 0 || v0 == 0 || u1 == w - 1 || v1 == h - 1,
    })
}

/// A view's aim: its distances from the source and (SDD) to the detector, in mm.
struct Aim {
    view: String,
    source_mm: f64,
    sdd_mm: f64,
}

impl Aim {
    fn magnification(&self) -> f64 {
        self.sdd_mm / self.source_mm
    }

    fn to_detector_mm(&self) -> f64 {
        self.sdd_mm - self.source_mm
    }
}

/// How two views magnify their aims, and where the aims are; for AP and LAT, which of the paper's
/// two statements about its LAT vertebra ("closer to the detector" and "larger" than in AP) hold here.
fn magnification_text(a: &Aim, b: &Aim) -> String {
    let (big, small) = if b.magnification() > a.magnification() {
        (b, a)
    } else {
        (a, b)
    };
    let ratio = big.magnification() / small.magnification();
    let mut text = if ratio - 1.0 < 5e-3 {
        format!(
            "{} and {} magnify their aims alike",
            a.view.to_uppercase(),
            b.view.to_uppercase()
        )
    } else {
        format!(
            "{} magnifies its aim {ratio:.2} times as much as {}",
            big.view.to_uppercase(),
            small.view.to_uppercase()
        )
    };
    let place = |v: &Aim| {
        format!(
            "in {} the aim is {} mm from the source and {} mm from the detector",
            v.view.to_uppercase(),
            num(v.source_mm, 0),
            num(v.to_detector_mm(), 0)
        )
    };
    let _ = write!(text, ": {}, {}.", place(a), place(b));
    let (Some(ap), Some(lat)) = (
        [a, b].into_iter().find(|v| v.view == "ap"),
        [a, b].into_iter().find(|v| v.view == "lat"),
    ) else {
        return text;
    };
    let larger = lat.magnification() > ap.magnification() * (1.0 + 5e-3);
    let closer = lat.to_detector_mm() < ap.to_detector_mm() - 0.5;
    let one_sdd = (lat.sdd_mm - ap.sdd_mm).abs() < 0.5;
    let verdict = match (larger, closer) {
        (true, true) => "here both hold",
        (true, false) => "this geometry follows \"larger\"",
        (false, true) => "this geometry follows \"closer to the detector\"",
        (false, false) => "neither holds here",
    };
    let _ = write!(
        text,
        " The paper says its LAT vertebra is both \"closer to the detector\" and \"larger\" than in AP; {}{verdict}.",
        if one_sdd && !(larger && closer) {
            "with one SDD these cannot both hold, and "
        } else {
            ""
        }
    );
    text
}

/// Where the phantom's and CT levels sit: each level's body centre at the world origin, on or off each
/// view's central ray; the phantom's segment moved along z to the views' mean aim height, and whether
/// its reference silhouettes are whole on the detector.
fn placement_text(
    cfg: &StudyConfig,
    carm: &crate::geometry::CArm,
    targets: &[String],
    feet: &[(&String, &View, Footprint)],
) -> String {
    let from_aim: Vec<String> = cfg
        .studied_views(carm)
        .map(|v| {
            let (aim, _) = v.aim();
            if aim.length() < 0.05 {
                format!("on {}'s central ray", v.name.to_uppercase())
            } else {
                format!(
                    "{} mm from {}'s aim {}",
                    num(aim.length(), 1),
                    v.name.to_uppercase(),
                    mm(aim)
                )
            }
        })
        .collect();
    let a = &cfg.anatomy;
    let whose = match (a.levels.is_empty(), a.ct.is_empty() && a.dataset.is_empty()) {
        (false, false) => "Each phantom level's and CT level's body centre",
        (false, true) => "Each single level's body centre",
        _ => {
            "Each CT level's body centre (its `center` landmark; a CT segment's: its middle level's)"
        }
    };
    let mut text = format!("{whose} sits at the world origin: {}.", from_aim.join(", "));
    if targets.iter().any(|t| t == SEGMENT_TARGET) {
        let z: Vec<f64> = cfg.studied_views(carm).map(|v| v.aim().0.z).collect();
        let cut: Vec<String> = feet
            .iter()
            .filter(|(t, _, f)| *t == SEGMENT_TARGET && f.touches_edge)
            .map(|(_, v, _)| v.name.to_uppercase())
            .collect();
        let whole = if cut.is_empty() {
            "whole on the detector in every reference view".to_string()
        } else {
            format!(
                "cut by the detector's edge even so in {}",
                cut.join(" and ")
            )
        };
        let _ = write!(
            text,
            " The segment, taller than a vertebra, is moved along z so that its levels' mean body-centre \
             height is the views' mean aim height, z = {} mm: {whole}.",
            num(z.iter().sum::<f64>() / z.len().max(1) as f64, 1)
        );
    }
    text
}

/// Writes the section: the views table, then the targets table.
pub fn section(
    md: &mut String,
    out: &Path,
    cfg: &StudyConfig,
    targets: &[String],
    (projection, grid_used): (&[ProjectionRow], bool),
    (figs, n): (&[FigureEntry], &mut usize),
) {
    let _ = writeln!(md, "## {HEADING}\n");
    let (Ok((g, origin)), Ok(carm)) = (cfg.geometry_config(), cfg.carm()) else {
        let _ = writeln!(
            md,
            "The geometry could not be read again for this section.\n"
        );
        return;
    };
    // Pixel spacing (mm) of the binned detector, where the geometry states it.
    let sp = g.detector.stated_pixel_spacing_mm();
    let _ = writeln!(
        md,
        "Geometry: {origin}, detector binning {} (world frame: mm, RAS+; the aim is the point of the \
         central ray nearest the world origin). The magnification at the aim is SDD / (source–aim \
         distance): an object there is drawn that many times its size on the detector.\n",
        cfg.geometry.binning
    );
    let _ = writeln!(
        md,
        "| view | source (mm) | aim (mm) | source–aim (mm) | SDD (mm) | magnification at the aim | \
         pixel (mm) | detector (px) | detector (mm) | K: fx, fy, cx, cy, skew (px) |\n\
         |---|---|---|---|---|---|---|---|---|---|"
    );
    let mut magnification = Vec::new();
    for view in cfg.studied_views(&carm) {
        let k = &view.intrinsics;
        let (point, dist) = view.aim();
        let aim = sp.map(|s| Aim {
            view: view.name.clone(),
            source_mm: dist,
            sdd_mm: k.fx * s[0],
        });
        let _ = writeln!(
            md,
            "| {} | {} | {} | {:.0} | {} | {} | {} | {} × {} | {} | {:.1}, {:.1}, {:.1}, {:.1}, {:.2} |",
            view.name.to_uppercase(),
            mm(view.source_world()),
            mm(point),
            dist,
            aim.as_ref()
                .map_or("n/a (K given)".into(), |a| format!("{:.0}", a.sdd_mm)),
            aim.as_ref()
                .map_or("n/a".into(), |a| format!("{:.3}", a.magnification())),
            sp.map_or("n/a".into(), |s| format!("{} × {}", s[0], s[1])),
            k.width,
            k.height,
            sp.map_or("n/a".into(), |s| format!(
                "{:.0} × {:.0}",
                f64::from(k.width) * s[0],
                f64::from(k.height) * s[1]
            )),
            k.fx,
            k.fy,
            k.cx,
            k.cy,
            k.skew
        );
        magnification.extend(aim);
    }
    if let [a, b] = magnification.as_slice() {
        let _ = writeln!(md, "\n{}", magnification_text(a, b));
    }
    let _ = writeln!(md);
    super::layout::figures(md, figs, Section::Setup, n);
    // Each target's reference silhouette per view, read once for the placement and the targets table.
    let feet: Vec<(&String, &View, Footprint)> = targets
        .iter()
        .flat_map(|t| cfg.studied_views(&carm).map(move |v| (t, v)))
        .filter_map(|(t, v)| footprint(out, t, &v.name).map(|f| (t, v, f)))
        .collect();
    let a = &cfg.anatomy;
    if !a.levels.is_empty() || !a.ct.is_empty() || !a.dataset.is_empty() {
        let _ = writeln!(md, "\n{}", placement_text(cfg, &carm, targets, &feet));
    }
    // The grid of `[perturbations]`, where an experiment that steps through it ran.
    if let Some(v) = cfg.studied_views(&carm).next().filter(|_| grid_used) {
        let _ = writeln!(md);
        let sdd = g.detector.physical().ok().map(|(_, sdd)| sdd);
        super::grid::table(md, &cfg.perturbations, &v.intrinsics, sp, sdd);
    }
    let mut table = String::new();
    for (t, view, f) in &feet {
        let k = &view.intrinsics;
        let (du, dv) = (f.centroid.0 - k.cx, f.centroid.1 - k.cy);
        let d = du.hypot(dv);
        let at_detector = |px_u: f64, px_v: f64| {
            sp.map_or("n/a".into(), |s| {
                format!("{} × {}", num(px_u * s[0], 1), num(px_v * s[1], 1))
            })
        };
        let _ = writeln!(
            table,
            "| {t} | {} | ({}, {}) | {:.1} | {} | {} × {} | {} | {} |",
            view.name.to_uppercase(),
            one_decimal(du),
            one_decimal(dv),
            d,
            sp.map_or("n/a".into(), |s| num(du.hypot(dv * s[1] / s[0]) * s[0], 1)),
            f.size_px.0,
            f.size_px.1,
            at_detector(f64::from(f.size_px.0), f64::from(f.size_px.1)),
            on_detector(f.touches_edge, projection, t, &view.name)
        );
    }
    if feet.is_empty() {
        let _ = writeln!(
            md,
            "\nWhere each target lies on the detector is measured on its reference DRRs, which the \
             `projection` and `landmarks` experiments write; this run wrote none (`references/` is empty).\n"
        );
        return;
    }
    let _ = writeln!(
        md,
        "\nWhere each target's reference silhouette lies on the detector: its centroid's offset from the \
         piercing point (cx, cy) and its bounding box, in px and in mm at the detector. Under a focal \
         scale α every point moves by (α − 1)·|x − c|, so a target far from the piercing point, or large \
         on the detector, moves more.\n"
    );
    let _ = writeln!(
        md,
        "| target | view | centroid − piercing point (px) | distance (px) | distance (mm at detector) | \
         extent (px) | extent (mm at detector) | on the detector |\n|---|---|---|---|---|---|---|---|\n\
         {table}"
    );
}

#[cfg(test)]
mod tests {
    use super::{Aim, magnification_text};

    fn aim(view: &str, source_mm: f64, sdd_mm: f64) -> Aim {
        Aim {
            view: view.into(),
            source_mm,
            sdd_mm,
        }
    }

    #[test]
    fn the_papers_two_statements_are_checked_against_the_geometry() {
        // The built-in geometry: one SDD of 1350 mm, LAT's aim 100 mm nearer the source.
        assert_eq!(
            magnification_text(&aim("ap", 1000.0, 1350.0), &aim("lat", 900.0, 1350.0)),
            "LAT magnifies its aim 1.11 times as much as AP: in AP the aim is 1000 mm from the source \
             and 350 mm from the detector, in LAT the aim is 900 mm from the source and 450 mm from the \
             detector. The paper says its LAT vertebra is both \"closer to the detector\" and \"larger\" \
             than in AP; with one SDD these cannot both hold, and this geometry follows \"larger\"."
        );
        // A shorter SDD in LAT: 1100 / 800 = 1.375 > 1.35, 300 mm < 350 mm from the detector.
        let both = magnification_text(&aim("ap", 1000.0, 1350.0), &aim("lat", 800.0, 1100.0));
        assert!(
            both.starts_with("LAT magnifies its aim 1.02 times as much as AP"),
            "{both}"
        );
        assert!(both.ends_with("than in AP; here both hold."), "{both}");
        // LAT farther from the source with one SDD: closer to the detector and smaller.
        let closer = magnification_text(&aim("lat", 1100.0, 1350.0), &aim("ap", 1000.0, 1350.0));
        assert!(
            closer.starts_with("AP magnifies its aim 1.10 times as much as LAT: in LAT"),
            "{closer}"
        );
        assert!(
            closer.ends_with(
                "cannot both hold, and this geometry follows \"closer to the detector\"."
            ),
            "{closer}"
        );
        // Views of other names: no word about the paper's AP and LAT.
        let other = magnification_text(&aim("pa", 1000.0, 1350.0), &aim("obl", 1000.0, 1350.0));
        assert_eq!(
            other,
            "PA and OBL magnify their aims alike: in PA the aim is 1000 mm from the source and 350 mm \
             from the detector, in OBL the aim is 1000 mm from the source and 350 mm from the detector."
        );
    }
}
