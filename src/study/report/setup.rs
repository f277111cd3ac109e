//! *Setup*: the geometry every number of the report depends on, stated before the findings — per view
//! the source, the central ray's point nearest the world origin (the aim), distances, magnification,
//! detector and K; per target and view where its reference silhouette lies relative to the piercing
//! point and how large it is on the detector, in px and mm. Computed from the effective geometry
//! (the built-in or `geometry.file`, binned) and the reference DRRs under `references/`.

use std::fmt::Write as _;
use std::path::Path;

use glam::DVec3;

use super::layout::num;
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
        if let Some(s) = sp {
            magnification.push((view.name.clone(), k.fx * s[0] / dist));
        }
        let sdd = sp.map(|s| k.fx * s[0]);
        let _ = writeln!(
            md,
            "| {} | {} | {} | {:.0} | {} | {} | {} | {} × {} | {} | {:.1}, {:.1}, {:.1}, {:.1}, {:.2} |",
            view.name.to_uppercase(),
            mm(view.source_world()),
            mm(point),
            dist,
            sdd.map_or("n/a (K given)".into(), |s| format!("{s:.0}")),
            sdd.map_or("n/a".into(), |s| format!("{:.3}", s / dist)),
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
    }
    if let [(a, ma), (b, mb)] = magnification.as_slice() {
        let (big, small, ratio) = if mb > ma {
            (b, a, mb / ma)
        } else {
            (a, b, ma / mb)
        };
        let _ = writeln!(
            md,
            "\n{} magnifies its aim {ratio:.2} times as much as {}: the anatomy there is nearer the \
             source (and so farther from the detector) in {} than in {}, and drawn larger. The paper says \
             its LAT vertebra is both \"closer to the detector\" and \"larger\"; with one SDD these \
             cannot both hold, and this geometry follows \"larger\" in {}.",
            big.to_uppercase(),
            small.to_uppercase(),
            big.to_uppercase(),
            small.to_uppercase(),
            big.to_uppercase()
        );
    }
    let _ = writeln!(md);
    super::layout::figures(md, figs, Section::Setup, n);
    if targets.iter().any(|t| t == SEGMENT_TARGET) {
        let z: Vec<f64> = cfg.studied_views(&carm).map(|v| v.aim().0.z).collect();
        let _ = writeln!(
            md,
            "\nEach single level sits where the views aim (its body centre at the world origin); the \
             segment, taller than a vertebra, is moved along z so that its levels' mean body-centre height \
             is the views' mean aim height, z = {} mm, keeping it whole on the detector in both views.",
            num(z.iter().sum::<f64>() / z.len().max(1) as f64, 1)
        );
    }
    // The grid of `[perturbations]`, where an experiment that steps through it ran.
    if let Some(v) = cfg.studied_views(&carm).next().filter(|_| grid_used) {
        let _ = writeln!(md);
        let sdd = g.detector.physical().ok().map(|(_, sdd)| sdd);
        super::grid::table(md, &cfg.perturbations, &v.intrinsics, sp, sdd);
    }
    let mut table = String::new();
    let mut rows = 0;
    for t in targets {
        for view in cfg.studied_views(&carm) {
            let k = &view.intrinsics;
            let Some(f) = footprint(out, t, &view.name) else {
                continue;
            };
            rows += 1;
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
    }
    if rows == 0 {
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
