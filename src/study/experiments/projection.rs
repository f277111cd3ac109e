//! Projection experiments of one (target, view, perturbation): whole-object silhouette + contour +
//! image-similarity metrics, per-structure Dice, difference heatmaps, and landmark shifts measured from
//! marker images beside the homography prediction `x' = H x`, `H = K' K⁻¹`.
//!
//! Silhouettes come from the thickness render's ray-hit masks; image metrics and heatmaps from the CT
//! volume DRR when the target has one (CT targets), else from the thickness DRR's line integral.

use super::{Context, Reference, Target};
use crate::Result;
use crate::analysis::{
    MaskPair, REGION_MARGIN_PX, Region, abs_difference, image_metrics_whole_and_in,
    marker_centroid, silhouette_metrics,
};
use crate::anatomy::Structure;
use crate::geometry::{Perturbation, View, apply_homography};
use crate::io::{ImageF32, Sidecar, kind, sidecar_path, units, write_tiff_f32};
use crate::render::{ThicknessDrr, ThicknessOptions, VolumeOnBackend};
use crate::study::config::Experiment;
use crate::study::schema::{Family, LandmarkRow, ProjectionRow, StructureRow, UnitRows};
use crate::study::timings::Phase;
use crate::study::units::NamedPerturbation;
use glam::DVec2;

/// Structures reported in `structures.csv`.
const STRUCTURES: [Structure; 7] = [
    Structure::Body,
    Structure::PedicleLeft,
    Structure::PedicleRight,
    Structure::Lamina,
    Structure::Spinous,
    Structure::Transverse,
    Structure::Articular,
];

/// Runs the projection unit.
pub fn run(ctx: &Context, t: &Target, view_name: &str, np: &NamedPerturbation) -> Result<UnitRows> {
    let view = ctx.carm.view(view_name)?;
    let pv = view.perturbed(&np.perturbation)?;
    let mut rows = UnitRows::default();
    let reference = ctx.reference(t, view)?;
    let tm = &ctx.timings;
    if let Some(a) = &reference.drr {
        let b = tm.time(Phase::RenderTarget, 1, || {
            t.renderer.render(&pv, &ThicknessOptions::with_masks())
        })?;
        let b_volume = t
            .volume
            .as_ref()
            .map(|v| tm.time(Phase::RenderVolume, 1, || v.render(&pv)))
            .transpose()?;
        let images = match (&reference.volume_drr, &b_volume) {
            (Some(ia), Some(ib)) => (ia, ib),
            _ => (&a.line_integral, &b.line_integral),
        };
        tm.time(Phase::Metrics, 1, || -> Result<()> {
            let silhouettes = (a, &b);
            let whole = whole_object(ctx, t, view, np, silhouettes, images)?;
            if np.family == Family::Physical {
                // Its own table: the intrinsic families' tables and analyses stay as they were.
                rows.physical
                    .push(super::physical::row(t, view, &pv, np, &whole)?);
                return Ok(());
            }
            rows.projection.push(whole);
            rows.structures = structures(t, view, np, a, &b)?;
            let q = &np.perturbation;
            let is_heatmap_df = ctx.cfg.heatmaps_df_px.contains(&q.df_px);
            if np.family == Family::Focal && is_heatmap_df {
                let diff = abs_difference(images.0, images.1)?;
                let path = ctx.figures_dir.join(format!(
                    "heatmap_{}_{}_df{}.png",
                    t.name, view.name, q.df_px
                ));
                let details = serde_json::json!({ "target": t.name });
                crate::io::write_difference_heatmap(&path, &diff, view, q, &details)?;
                let tiff = super::difference_image_path(&ctx.out, &t.name, &view.name, q.df_px);
                write_tiff_f32(&tiff, &diff)?;
                let side = Sidecar::new(
                    kind::ABS_DIFFERENCE,
                    units::LINE_INTEGRAL_DIFFERENCE,
                    view,
                    q,
                )?;
                side.with_details(&details)?.write(&sidecar_path(&tiff))?;
            }
            Ok(())
        })?;
    }
    if ctx.cfg.runs(Experiment::Landmarks) && np.family != Family::Physical {
        rows.landmarks = landmarks(ctx, t, view, &pv, np, &reference.markers)?;
    }
    Ok(rows)
}

/// The reference render (when the projection experiment runs) and reference marker centroids (when the
/// landmark experiment runs). The reference DRR (the CT volume DRR for CT targets) is written to
/// [`super::reference_image_path`]: the report's Setup measures where each target lies from it, and the
/// landmark overlay figure draws on it.
pub fn reference(ctx: &Context, t: &Target, view: &View) -> Result<Reference> {
    let tm = &ctx.timings;
    let drr = if ctx.cfg.runs(Experiment::Projection) {
        Some(tm.time(Phase::RenderTarget, 1, || {
            t.renderer.render(view, &ThicknessOptions::with_masks())
        })?)
    } else {
        None
    };
    let volume_drr = match &t.volume {
        Some(v) if drr.is_some() => Some(tm.time(Phase::RenderVolume, 1, || v.render(view))?),
        _ => None,
    };
    // The reference image is the Setup's evidence of where each target lies on the detector (and
    // whether the detector cuts it), and the landmark overlays' background.
    write_reference_image(ctx, t, view, drr.as_ref(), volume_drr.as_ref())?;
    let markers = if ctx.cfg.runs(Experiment::Landmarks) {
        t.markers
            .iter()
            .map(|m| measure(ctx, m, view))
            .collect::<Result<Vec<_>>>()?
    } else {
        Vec::new()
    };
    Ok(Reference {
        drr,
        volume_drr,
        markers,
    })
}

/// Writes the reference image of `t` in `view` (TIFF + sidecar): the CT volume DRR when there is one,
/// else the thickness DRR's line integral (rendered here when the projection experiment did not).
/// The reference sidecar's `details` key holding the target's side outline: `[[depth, v], …]` (mm, the
/// convex hull of its vertices in the view's camera frame, see [`crate::geometry::outline`]).
pub const OUTLINE_KEY: &str = "outline_depth_v_mm";

fn write_reference_image(
    ctx: &Context,
    t: &Target,
    view: &View,
    drr: Option<&ThicknessDrr>,
    volume_drr: Option<&ImageF32>,
) -> Result<()> {
    let rendered;
    let volume_name = t
        .volume
        .as_ref()
        .map(|v| match v.cpu.details().method.as_str() {
            "trilinear" => "ct-volume (trilinear)",
            _ => "ct-volume (Siddon)",
        });
    let (image, renderer) = match (volume_drr, drr) {
        (Some(v), _) => (v, volume_name.unwrap_or("ct-volume (Siddon)")),
        (None, Some(d)) => (&d.line_integral, "thickness"),
        (None, None) => {
            rendered = ctx.timings.time(Phase::RenderTarget, 1, || {
                t.renderer.render(view, &ThicknessOptions::image_only())
            })?;
            (&rendered.line_integral, "thickness")
        }
    };
    let path = super::reference_image_path(&ctx.out, &t.name, view.name.as_str());
    write_tiff_f32(&path, image)?;
    let mut side = Sidecar::new(
        "drr",
        "line integral ∫μ dl (μ in 1/mm)",
        view,
        &Perturbation::NONE,
    )?;
    side.details.insert("renderer".into(), renderer.into());
    side.details
        .insert("backend".into(), ctx.cfg.geometry.backend_name().into());
    let adapter = if renderer == "thickness" {
        t.renderer.gpu_adapter()
    } else {
        t.volume.as_deref().and_then(VolumeOnBackend::gpu_adapter)
    };
    if let Some(adapter) = adapter {
        side.details.insert("gpu_adapter".into(), adapter.into());
    }
    side.details.insert("target".into(), t.name.clone().into());
    // The target seen from beside the beam (depth along the central ray, offset along v; mm): the
    // report's to-scale drawing of each view.
    let outline = crate::geometry::outline::side_outline(
        t.renderer
            .scene()
            .meshes
            .iter()
            .flat_map(|m| m.mesh.vertices.iter().copied()),
        view,
    );
    let outline: Vec<[f64; 2]> = outline
        .iter()
        .map(|p| [(p.x * 100.0).round() / 100.0, (p.y * 100.0).round() / 100.0])
        .collect();
    side.details.insert(
        OUTLINE_KEY.into(),
        serde_json::to_value(outline).map_err(|e| crate::Error::encode("outline", e))?,
    );
    if let Some(p) = &t.placement {
        let value = serde_json::to_value(p).map_err(|e| crate::Error::encode("placement", e))?;
        side.details.insert("placement".into(), value);
    }
    side.write(&sidecar_path(&path))
}

/// Silhouette and contour metrics of the thickness renders' masks, image metrics of `images`.
fn whole_object(
    ctx: &Context,
    t: &Target,
    view: &View,
    np: &NamedPerturbation,
    (a, b): (&ThicknessDrr, &ThicknessDrr),
    images: (&ImageF32, &ImageF32),
) -> Result<ProjectionRow> {
    let k = view.intrinsics;
    let pair = MaskPair {
        name: t.name.clone(),
        width: k.width,
        height: k.height,
        reference: a.masks()?.union(),
        perturbed: b.masks()?.union(),
    };
    let s = silhouette_metrics(&pair)?;
    let region = Region::around(
        &pair.reference,
        &pair.perturbed,
        k.width,
        k.height,
        REGION_MARGIN_PX,
    )?;
    let (det, im) =
        ctx.isolated_metrics(|| image_metrics_whole_and_in(images.0, images.1, &region))?;
    let q = &np.perturbation;
    Ok(ProjectionRow {
        target: t.name.clone(),
        view: view.name.clone(),
        family: np.family,
        df_px: q.df_px,
        dcx_px: q.dcx_px,
        dcy_px: q.dcy_px,
        skew_px: q.skew_px,
        sy: q.sy,
        cut_by_edge: pair.touches_edge(),
        dice: s.dice,
        iou: s.iou,
        chamfer_mean_px: s.chamfer_mean_px,
        hausdorff_px: s.hausdorff_px,
        hd95_px: s.hd95_px,
        edge_distance_mean_px: s.edge_distance_mean_px,
        ncc: im.ncc,
        ssim: im.ssim,
        mutual_information_nats: im.mutual_information_nats,
        gradient_correlation: im.gradient_correlation,
        region_margin_px: REGION_MARGIN_PX,
        region_px: region.len(),
        ncc_detector: det.ncc,
        ssim_detector: det.ssim,
        mutual_information_nats_detector: det.mutual_information_nats,
        gradient_correlation_detector: det.gradient_correlation,
        mean_abs_diff: det.mean_abs_diff,
    })
}

fn structures(
    t: &Target,
    view: &View,
    np: &NamedPerturbation,
    a: &ThicknessDrr,
    b: &ThicknessDrr,
) -> Result<Vec<StructureRow>> {
    let q = &np.perturbation;
    let mut rows = Vec::new();
    for s in STRUCTURES {
        let (ma, mb) = (a.masks()?.structure(s), b.masks()?.structure(s));
        if !ma.iter().any(|x| *x) {
            continue;
        }
        let (dice, iou) = crate::analysis::dice_iou(&ma, &mb)?;
        rows.push(StructureRow {
            target: t.name.clone(),
            view: view.name.clone(),
            family: np.family,
            df_px: q.df_px,
            dcx_px: q.dcx_px,
            dcy_px: q.dcy_px,
            structure: s.name().to_string(),
            dice,
            iou,
        });
    }
    Ok(rows)
}

/// Blob centroid of a marker rendered alone in `view` ([`marker_centroid`]); `None` when the marker's
/// search disc is not wholly on the detector.
fn measure(ctx: &Context, m: &super::Marker, view: &View) -> Result<Option<DVec2>> {
    ctx.timings.time(Phase::RenderMarkers, 1, || {
        marker_centroid(
            &m.renderer,
            view,
            m.position,
            ctx.cfg.anatomy.marker_radius_mm,
        )
    })
}

fn landmarks(
    ctx: &Context,
    t: &Target,
    view: &View,
    pv: &View,
    np: &NamedPerturbation,
    reference: &[Option<DVec2>],
) -> Result<Vec<LandmarkRow>> {
    // Intrinsic families only (the physical family's shifts are exact projections, in physical.csv).
    let h = view.homography_to(pv);
    let q = &np.perturbation;
    let mut rows = Vec::new();
    for (m, x_ref) in t.markers.iter().zip(reference) {
        // Off the detector: the row stays, with NaN measurements (it shows in the table, not lost).
        let nan = DVec2::splat(f64::NAN);
        let x = x_ref.unwrap_or(nan);
        let y = measure(ctx, m, pv)?.unwrap_or(nan);
        let p = apply_homography(&h, x);
        rows.push(LandmarkRow {
            target: t.name.clone(),
            view: view.name.clone(),
            family: np.family,
            df_px: q.df_px,
            dcx_px: q.dcx_px,
            dcy_px: q.dcy_px,
            landmark: m.name.clone(),
            ref_u_px: x.x,
            ref_v_px: x.y,
            meas_u_px: y.x,
            meas_v_px: y.y,
            shift_px: (y - x).length(),
            pred_u_px: p.x,
            pred_v_px: p.y,
            pred_shift_px: (p - x).length(),
            pred_error_px: (y - p).length(),
        });
    }
    Ok(rows)
}
