//! CT targets (`[[anatomy.ct]]`): a CT with a vertebra label map, one target per listed level (and the
//! levels together as `<name>-segment`).
//!
//! Which renderer feeds which measurement:
//! * **image metrics and heatmaps** (NCC, SSIM, MI, GC, |ΔDRR|) come from the CT volume DRR — Siddon's
//!   exact ray-driven line integral `∫ μ(HU) dl` through the CT, masked to the level's label — as the
//!   paper renders its DRRs;
//! * **silhouettes and contours** (Dice, IoU, Chamfer, Hausdorff, HD95) come from a thickness render of
//!   the label's closed surface (the 0.5-isosurface of the label mask, as `spinedrr mesh` extracts it),
//!   whose ray-hit masks are exact where a thresholded volume DRR would depend on a threshold; the
//!   surface is split into the phantom's structures from its automatic landmark frame
//!   ([`crate::anatomy::structure_split`]), so per-structure Dice has rows as for the phantom;
//! * **landmarks** are marker spheres at the level's landmarks (automatic landmarks of the label surface,
//!   or the given JSON), rendered alone and measured by blob centroid, as for every target.
//!
//! The views aim at the world origin (AP's central ray through it, the built-in LAT's 32 mm from it), so
//! each target is moved rigidly to put its body centre there: the `center` landmark of the level, or for
//! the segment that of its middle listed level (the phantom's placement rule). With `align = "none"` (the default) the motion is that translation alone — the NIfTI
//! world is RAS+ like the phantom's, so AP and LAT are the scanner's; with `align = "anatomical"` the
//! level is also rotated so its automatic-landmark frame (right, anterior, superior) becomes the world's
//! axes, and AP and LAT are a tilted vertebra's true AP and LAT (see [`crate::anatomy::ct::placement`]).
//! One motion moves the label surfaces, the landmarks and the CT's affine alike.
//!
//! Inputs are read and checked by [`load_input`] before the output folder is touched — the label map
//! first, on the CT's grid, then both cropped to the listed levels' bounding box (plus a margin) so
//! nothing heavy runs on the whole scan; [`build_targets`] meshes them. A dataset of many CTs calls the
//! two for each of its cases.

use std::path::Path;
use std::sync::Arc;

use glam::DVec3;
use rayon::prelude::*;

use super::{Target, target_with_landmarks};
use crate::anatomy::auto_landmarks::{VertebraFrame, analyse};
use crate::anatomy::ct::{
    Alignment, CtVolume, LabelMap, MAX_SMOOTH_ITERATIONS, Placed, SurfaceOptions, VoxelMask,
    label_surface, move_volume, read_ct, read_labels,
};
use crate::anatomy::labels::LabelConvention;
use crate::anatomy::markups::{LandmarkContext, read_landmarks_with};
use crate::anatomy::structure_split::split_structures;
use crate::anatomy::tissue_mu;
use crate::anatomy::{Landmarks, Tissue, TriMesh};
use crate::render::volume::{VolumeMethod, VolumeRenderOptions, VolumeRenderer};
use crate::render::{RenderScene, SceneMesh, VolumeOnBackend};
use crate::study::config::{CtTarget, StudyConfig};
use crate::study::timings::{Phase, Timings};
use crate::{Error, Result};

/// One level of a CT entry: its target name, tag (`L1`, `id31`) and label id.
#[derive(Debug, Clone)]
struct LevelSpec {
    target: String,
    tag: String,
    id: u16,
}

/// A `[[anatomy.ct]]` entry read and checked: volumes on one grid, every label present, landmark sets
/// (when a file is given) matched to the levels.
pub struct CtInput {
    entry: CtTarget,
    ct: CtVolume,
    seg: LabelMap,
    levels: Vec<LevelSpec>,
    landmarks: Option<Vec<Landmarks>>,
}

/// Reads every CT entry's files and checks them (labels present, same grid, landmark sets per level).
/// The label map and landmarks are checked before the (large) CT is read.
pub fn load_inputs(cfg: &StudyConfig) -> Result<Vec<CtInput>> {
    cfg.anatomy.ct.iter().map(load_input).collect()
}

/// Voxels of margin kept around the listed levels when the volumes are cropped on reading.
const CROP_MARGIN_VOXELS: usize = 2;

/// Reads and checks one `[[anatomy.ct]]` entry (or one case of a dataset, given as such an entry):
/// levels present in the label map, landmark sets per level, the label map on the CT's grid; then both
/// volumes cropped to the levels' bounding box plus [`CROP_MARGIN_VOXELS`].
pub fn load_input(c: &CtTarget) -> Result<CtInput> {
    if c.smooth_iterations > MAX_SMOOTH_ITERATIONS {
        return Err(Error::invalid(
            "anatomy.ct.smooth_iterations",
            format!(
                "target '{}': {} is more than the limit of {MAX_SMOOTH_ITERATIONS}",
                c.name, c.smooth_iterations
            ),
        ));
    }
    let conv = c.labels;
    let levels: Vec<LevelSpec> = c
        .level_targets()?
        .into_iter()
        .map(|(target, id)| LevelSpec {
            tag: target[c.name.len() + 1..].to_string(),
            target,
            id,
        })
        .collect();
    let seg = read_labels(&c.seg)?;
    let present = seg.labels_present();
    for (l, spec) in levels.iter().zip(&c.levels) {
        if !present.contains(&l.id) {
            return Err(Error::invalid(
                "anatomy.ct.levels",
                format!(
                    "target '{}': level {spec:?} (label {} in the {conv} convention) is not in {} \
                     (labels present: {present:?})",
                    c.name,
                    l.id,
                    c.seg.display()
                ),
            ));
        }
    }
    let landmarks = match &c.landmarks {
        Some(path) => Some(match_landmarks(path, &seg, conv, &levels)?),
        None => None,
    };
    let ct = read_ct(&c.ct)?;
    ct.check_grid_of(&c.ct, &seg, &c.seg)
        .map_err(|e| Error::invalid("anatomy.ct.seg", format!("target '{}': {e}", c.name)))?;
    let ids: Vec<u16> = levels.iter().map(|l| l.id).collect();
    let (lo, hi) = VoxelMask::from_labels(&seg, &ids)?.bbox;
    let lo = lo.map(|v| v.saturating_sub(CROP_MARGIN_VOXELS));
    let hi = [0, 1, 2].map(|a| (hi[a] + CROP_MARGIN_VOXELS).min(ct.dims[a] - 1));
    Ok(CtInput {
        entry: c.clone(),
        ct: ct.crop(lo, hi)?,
        seg: seg.crop(lo, hi)?,
        levels,
        landmarks,
    })
}

/// The landmark set of each level from `path`, matched by level name or id in the entry's convention.
fn match_landmarks(
    path: &Path,
    seg: &LabelMap,
    conv: LabelConvention,
    levels: &[LevelSpec],
) -> Result<Vec<Landmarks>> {
    // Any landmark format; VerSe centroids are voxel coordinates of this label map's grid.
    let ctx = LandmarkContext {
        seg: Some((seg, conv)),
        ..LandmarkContext::default()
    };
    let sets = read_landmarks_with(path, &ctx)
        .map_err(|e| Error::invalid("anatomy.ct.landmarks", e.to_string()))?;
    let empty = |s: &Landmarks| s.points.is_empty();
    if sets.is_empty() || sets.iter().any(empty) {
        return Err(Error::invalid(
            "anatomy.ct.landmarks",
            format!(
                "{} holds a landmark set with no points (or no set)",
                path.display()
            ),
        ));
    }
    levels
        .iter()
        .map(|l| {
            sets.iter()
                .find(|s| conv.resolve(&s.level).ok() == Some(l.id))
                .map(|s| Landmarks {
                    level: l.tag.clone(),
                    points: s.points.clone(),
                })
                .ok_or_else(|| {
                    let names: Vec<&str> = sets.iter().map(|s| s.level.as_str()).collect();
                    Error::invalid(
                        "anatomy.ct.landmarks",
                        format!(
                            "{} has no set for level {} (label {}; sets: {names:?})",
                            path.display(),
                            l.tag,
                            l.id
                        ),
                    )
                })
        })
        .collect()
}

/// One level meshed, in CT world coordinates, with its anatomical frame when the entry aligns to it.
struct LevelSurface {
    mesh: TriMesh,
    landmarks: Landmarks,
    frame: Option<VertebraFrame>,
}

/// Builds the targets of one CT entry: per level, then the segment when asked.
pub fn build_targets(
    cfg: &StudyConfig,
    input: CtInput,
    timings: &Timings,
    pool: &rayon::ThreadPool,
) -> Result<Vec<Target>> {
    let CtInput {
        entry,
        ct,
        seg,
        levels,
        landmarks,
    } = input;
    let n_targets = levels.len() + usize::from(entry.segment);
    let surfaces = timings.time(Phase::Anatomy, n_targets as u64, || {
        pool.install(|| {
            levels
                .par_iter()
                .enumerate()
                .map(|(i, l)| {
                    let given = landmarks.as_ref().map(|s| &s[i]);
                    level_surface(&seg, l, given, &entry)
                })
                .collect::<Result<Vec<_>>>()
        })
    })?;
    let mut out = Vec::new();
    for (l, s) in levels.iter().zip(&surfaces) {
        out.push(assemble(
            cfg,
            &l.target,
            &ct,
            &seg,
            &[l.id],
            std::slice::from_ref(s),
            level_placement(s, entry.align)?,
            entry.method,
            timings,
        )?);
    }
    if entry.segment {
        let ids: Vec<u16> = levels.iter().map(|l| l.id).collect();
        let middle = &surfaces[(surfaces.len() - 1) / 2];
        out.push(assemble(
            cfg,
            &entry.segment_target(),
            &ct,
            &seg,
            &ids,
            &surfaces,
            level_placement(middle, entry.align)?,
            entry.method,
            timings,
        )?);
    }
    Ok(out)
}

/// The label's closed surface (largest component, unsmoothed: `spinedrr mesh`'s defaults), labelled by
/// structure, its landmarks (the given set, or automatic ones of the surface) and, to align to, its
/// automatic frame.
fn level_surface(
    seg: &LabelMap,
    l: &LevelSpec,
    given: Option<&Landmarks>,
    entry: &CtTarget,
) -> Result<LevelSurface> {
    let align = entry.align;
    let context = |e: Error| {
        Error::invalid(
            "anatomy.ct.levels",
            format!("target '{}' (label {}): {e}", l.target, l.id),
        )
    };
    let opts = SurfaceOptions {
        smooth_iterations: entry.smooth_iterations,
        ..SurfaceOptions::default()
    };
    let mut mesh = label_surface(seg, l.id, &opts).map_err(|e| {
        Error::invalid(
            "anatomy.ct.smooth_iterations",
            format!("target '{}' (label {}): {e}", l.target, l.id),
        )
    })?;
    // Automatic landmarks read flat endplates: name the remedy for a stair-stepped surface.
    let spacing = seg.spacing_mm();
    let hint = |e: Error| {
        let thick = spacing.max_element() > 1.5 * spacing.min_element();
        if thick && entry.smooth_iterations == 0 {
            context(Error::Numerical(format!(
                "{e} (the label map's {:.2} × {:.2} × {:.2} mm voxels leave stair steps on the \
                 surface: set smooth_iterations = 10 for this entry, or give landmarks)",
                spacing.x, spacing.y, spacing.z
            )))
        } else {
            context(e)
        }
    };
    mesh.name = l.tag.clone();
    // The automatic landmarks label the surface by structure (per-structure Dice) and give the frame to
    // align to; with given landmarks and no alignment, a surface they cannot be found on stays unlabelled.
    let auto = match (given, align, analyse(&mesh, &l.tag)) {
        (Some(_), Alignment::None, Err(_)) => None,
        (_, _, found) => Some(found.map_err(hint)?),
    };
    match auto.as_ref().map(|(lm, _)| split_structures(&mesh, lm)) {
        Some(Ok(labels)) => mesh.labels = labels,
        _ => mesh.labels.clear(),
    }
    let frame = auto.as_ref().map(|(_, f)| *f);
    let landmarks = match (given, auto) {
        (Some(s), _) => s.clone(),
        (None, Some((lm, _))) => lm,
        (None, None) => return Err(Error::Internal("no landmarks for a CT level".into())),
    };
    let frame = (align == Alignment::Anatomical).then_some(frame).flatten();
    Ok(LevelSurface {
        mesh,
        landmarks,
        frame,
    })
}

/// The placement that puts a level's body centre at the world origin, aligned as the entry asks.
fn level_placement(s: &LevelSurface, align: Alignment) -> Result<Placed> {
    let centre = Some(body_centre(s));
    Placed::new("body-centre", centre, align, s.frame.as_ref()).map_err(|e| {
        Error::invalid(
            "anatomy.ct.align",
            format!("level {}: {e}", s.landmarks.level),
        )
    })
}

/// Where a level's body is: its `center` landmark, else the centroid of its surface's vertices.
fn body_centre(s: &LevelSurface) -> DVec3 {
    s.landmarks.get("center").unwrap_or_else(|| {
        s.mesh.vertices.iter().sum::<DVec3>() / s.mesh.vertices.len().max(1) as f64
    })
}

/// One target from the levels `ids` with their `surfaces`, moved by the `placed` motion: the label surfaces as
/// the thickness scene, the CT cropped to the labels' bounding box and masked to them as the volume.
#[allow(clippy::too_many_arguments)]
fn assemble(
    cfg: &StudyConfig,
    name: &str,
    ct: &CtVolume,
    seg: &LabelMap,
    ids: &[u16],
    surfaces: &[LevelSurface],
    placed: Placed,
    method: VolumeMethod,
    timings: &Timings,
) -> Result<Target> {
    let motion = placed.motion();
    let volume = timings.time(Phase::Scene, 1, || -> Result<VolumeOnBackend> {
        let mask = VoxelMask::from_labels(seg, ids)?;
        // One voxel of margin keeps the crop's box strictly around the label.
        let (lo, hi) = mask.bbox;
        let lo = lo.map(|v| v.saturating_sub(1));
        let hi = [0, 1, 2].map(|a| (hi[a] + 1).min(ct.dims[a] - 1));
        let mut ct_crop = ct.crop(lo, hi)?;
        let seg_crop = seg.crop(lo, hi)?;
        move_volume(&mut ct_crop, &motion);
        let mask = VoxelMask::from_labels(&seg_crop, ids)?;
        let opts = VolumeRenderOptions {
            method,
            ..VolumeRenderOptions::default()
        };
        VolumeOnBackend::new(
            VolumeRenderer::new(&ct_crop, &opts, Some(&mask))?,
            cfg.geometry.backend,
        )
    })?;
    let meshes = surfaces
        .iter()
        .map(|s| {
            let mut m = s.mesh.clone();
            m.transform(&motion);
            SceneMesh {
                mesh: Arc::new(m),
                mu_per_mm: tissue_mu(Tissue::Cortical),
                object: s.landmarks.level.clone(),
            }
        })
        .collect();
    let renderer = timings.time(Phase::Scene, 1, || {
        cfg.geometry.backend.renderer(RenderScene::new(meshes)?)
    })?;
    let sets = surfaces
        .iter()
        .map(|s| Landmarks {
            level: s.landmarks.level.clone(),
            points: s
                .landmarks
                .points
                .iter()
                .map(|(k, p)| (k.clone(), motion.apply(*p)))
                .collect(),
        })
        .collect();
    let mut t = target_with_landmarks(cfg, name, renderer, sets, surfaces.len() > 1, timings)?;
    t.volume = Some(Arc::new(volume));
    t.placement = Some(placed);
    Ok(t)
}
