//! `report.md`: what this run found (*Findings*, computed from its tables), how each measurement is
//! made, the products, and the paper's reported figures (`reference/paper-results.toml`, embedded)
//! beside ours. Writing to a `String` cannot fail, so `writeln!` results are discarded (`let _`).

mod beside_landmarks;
mod calibration;
mod calibration_physical;
pub mod cohort;
mod comparison;
mod findings;
mod grid;
mod intensity;
mod intensity_spectral;
mod invocation;
mod landmarks;
pub mod latex;
mod layout;
pub mod literature;
mod physical;
mod provenance;
mod registration;
mod screws;
mod setup;
mod shift_ratio;
mod tracking;

use std::fmt::Write as _;
use std::path::Path;

use super::paper::PaperResults;
pub use comparison::{landmark_table, registration_table, silhouette_table};
pub use latex::PaperTable;
pub use layout::slug;
pub use provenance::{INPUTS_CSV, PROVENANCE};

use super::config::StudyConfig;
use super::figures::{self, Section};
use super::identity::InputFile;
use super::schema::{ProjectionRow, StudyTables};
use super::timings::{RunFacts, TimingRow};
use super::units::targets;
use crate::Result;
use crate::io::write_atomic_bytes;
use crate::render::Backend;

const PROJECTION: &str = "Projection: silhouettes and difference images";
const LANDMARKS: &str = "Landmarks: displacement under a focal offset";
const REGISTRATION: &str = "Registration: Kabsch vs direct";
const MEASUREMENT: &str = "How each measurement is made";
const TIMINGS: &str = "Where the time goes (this invocation)";

/// Writes `out/report.md`; everything above the timing section depends only on the config and the
/// tables, the timing section (`rows`, `run`) on this invocation.
pub fn write(
    out: &Path,
    cfg: &StudyConfig,
    tables: &StudyTables,
    rows: &[TimingRow],
    (run, inputs): (&RunFacts, &[InputFile]),
) -> Result<()> {
    let paper = PaperResults::embedded()?;
    let targets = targets(cfg);
    let first = targets.first().cloned().unwrap_or_default();
    let mut md = String::new();
    let _ = writeln!(md, "# spinedrr sensitivity study\n");
    provenance::line(&mut md, out, cfg, (run, inputs))?;
    let _ = writeln!(
        md,
        "spinedrr {}. Targets: {}; views: {}; seed {}; detector binning {}; {} backend. The full \
configuration is `study.toml`.\n",
        env!("CARGO_PKG_VERSION"),
        targets.join(", "),
        cfg.geometry.views.join(", "),
        cfg.seed,
        cfg.geometry.binning,
        cfg.geometry.backend_name()
    );
    let figs = figures::manifest::read(&out.join("figures"))?;
    let experiments = [
        (!tables.projection.is_empty(), PROJECTION),
        (!tables.landmarks.is_empty(), LANDMARKS),
        (!tables.physical.is_empty(), physical::HEADING),
        (
            !tables.registration_summary.is_empty() || !tables.registration_physical.is_empty(),
            REGISTRATION,
        ),
        (!tables.calibration.is_empty(), calibration::HEADING),
        (!tables.intensity_summary.is_empty(), intensity::HEADING),
        (!tables.tracking.is_empty(), tracking::HEADING),
        (!tables.screws.is_empty(), screws::HEADING),
        (!tables.tracking.is_empty(), literature::HEADING),
    ];
    // The findings first: the contents list their section only when there is one (a study of
    // intensity registration alone has none).
    let mut findings_md = String::new();
    let piercing: std::collections::BTreeMap<String, (f64, f64)> = cfg
        .carm()
        .map(|c| {
            c.views
                .iter()
                .map(|v| (v.name.clone(), (v.intrinsics.cx, v.intrinsics.cy)))
                .collect()
        })
        .unwrap_or_default();
    let ratios = shift_ratio::ratios(&tables.landmarks, &piercing);
    let at = |v: &str| piercing.get(v).map_or([f64::NAN; 2], |c| [c.0, c.1]);
    findings::section(
        &mut findings_md,
        tables,
        &findings::Context {
            out,
            paper: &paper,
            first: &first,
            ratios: &ratios,
            piercing: [at("ap"), at("lat")],
            noise_px: cfg.registration.noise_px,
            calibration_trials: cfg.calibration.trials,
            pitch: grid::Pitch::of(cfg).0,
        },
    )?;
    let mut headings = vec![setup::HEADING.to_string()];
    if !findings_md.is_empty() {
        headings.push("Findings".to_string());
    }
    if !cfg.anatomy.dataset.is_empty() {
        headings.push(cohort::HEADING.to_string());
    }
    headings.extend(experiments.iter().filter(|e| e.0).map(|e| e.1.to_string()));
    headings.extend([MEASUREMENT, "Products", TIMINGS].map(String::from));
    layout::contents(&mut md, &headings);
    let mut n = 0;
    setup::section(
        &mut md,
        out,
        cfg,
        &targets,
        (
            &tables.projection,
            !(tables.projection.is_empty()
                && tables.landmarks.is_empty()
                && tables.screws.is_empty()),
        ),
        (&figs, &mut n),
    );
    md.push_str(&findings_md);
    let pitch = grid::Pitch::of(cfg);
    shift_ratio::table(&mut md, &ratios, pitch);
    cohort::section(&mut md, out, cfg, (tables, &ratios), (&figs, &mut n));
    if !tables.projection.is_empty() {
        let _ = writeln!(md, "## {PROJECTION}\n");
        layout::figures(&mut md, &figs, Section::Projection, &mut n);
        silhouette_section(&mut md, &tables.projection, &paper, &first, pitch);
    }
    if !tables.landmarks.is_empty() {
        let _ = writeln!(md, "## {LANDMARKS}\n");
        layout::figures(&mut md, &figs, Section::Landmarks, &mut n);
        landmarks::section(&mut md, &tables.landmarks, &paper, &first, pitch);
    }
    let carm = cfg.carm().ok();
    physical::section(&mut md, &tables.physical, carm.as_ref(), &first);
    if !tables.registration_summary.is_empty() || !tables.registration_physical.is_empty() {
        let _ = writeln!(md, "## {REGISTRATION}\n");
        layout::figures(&mut md, &figs, Section::Registration, &mut n);
        registration_section(
            &mut md,
            tables,
            &paper,
            &first,
            (cfg.registration.noise_px, pitch),
            &carm
                .as_ref()
                .map(|c| cfg.studied_views(c).collect::<Vec<_>>())
                .unwrap_or_default(),
        );
    }
    calibration::section(&mut md, (cfg, &first), tables, &figs, &mut n);
    calibration_physical::section(&mut md, &tables.calibration_physical, &tables.calibration);
    intensity::section(&mut md, cfg, tables, &figs, &mut n);
    beside_landmarks::section(&mut md, &tables.intensity_summary, pitch);
    intensity_spectral::section(&mut md, cfg, &tables.intensity_summary, pitch);
    tracking::section(&mut md, cfg, &tables.tracking, &first);
    screws::section(
        &mut md,
        &cfg.geometry.views,
        (&tables.screws, &tables.screw_navigation),
        pitch,
        (&figs, &mut n),
    );
    literature::section(&mut md, &tables.tracking, (&first, pitch.0.is_some()))?;
    renderers_section(&mut md, cfg, tables);
    // The .tex tables first: the products list names what is on disk.
    write_latex_tables(out, tables, &paper, &first, pitch)?;
    layout::products(&mut md, out)?;
    invocation::section(&mut md, out, rows, run);
    write_atomic_bytes(&out.join("report.md"), md.as_bytes())
}

/// The paper's tables of the non-empty `tables` as `tables/<name>.tex` (booktabs).
fn write_latex_tables(
    out: &Path,
    tables: &StudyTables,
    paper: &PaperResults,
    first: &str,
    pitch: grid::Pitch,
) -> Result<()> {
    let dir = out.join("tables");
    if !tables.projection.is_empty() {
        silhouette_table(&tables.projection, paper, first, pitch).write_latex(&dir)?;
    }
    if !tables.landmarks.is_empty() {
        landmark_table(&tables.landmarks, paper, first, pitch).write_latex(&dir)?;
    }
    if !tables.registration_summary.is_empty() {
        registration_table(&tables.registration_summary, paper, first).write_latex(&dir)?;
    }
    Ok(())
}

/// What renders the thickness DRRs with `backend`.
fn backend_words(backend: Backend) -> &'static str {
    match backend {
        Backend::Raster => {
            "the raster backend: primary rays rasterised with exact edge functions (a view with a \
vertex at or behind the source plane is traced with Embree instead)"
        }
        Backend::Embree => {
            "the Embree backend: Intel Embree ray tracing, all hits in one traversal"
        }
        Backend::Bvh => "the BVH backend: the pure-Rust f64 BVH with a watertight triangle test",
        Backend::Gpu => {
            "the GPU backend: compute shaders through wgpu summing each covered pixel's signed \
plane depths (exit − entry), with the pixels near an edge or whose crossings do not balance evaluated \
by the raster's edge functions on the CPU (path lengths within ~1e-4 mm of the raster's, the same \
silhouettes); the adapter is named in the reference DRRs' sidecars (`references/*.json`, \
`details.gpu_adapter`)"
        }
    }
}

/// Which renderer feeds which measurement, per kind of target: how the measurements of the tables this
/// run wrote are made (a table the run did not write gets no bullet: the landmark markers only with
/// `landmarks.csv`, the image metrics only with `projection.csv`).
fn renderers_section(md: &mut String, cfg: &StudyConfig, tables: &StudyTables) {
    let (projection, landmarks) = (!tables.projection.is_empty(), !tables.landmarks.is_empty());
    let _ = writeln!(md, "## {MEASUREMENT}\n");
    let _ = writeln!(
        md,
        "- Thickness DRRs (Σ μ·L through closed surfaces) are rendered by {}.",
        backend_words(cfg.geometry.backend)
    );
    if landmarks {
        let _ = writeln!(
            md,
            "- Landmark shifts: a small marker sphere at each 3-D landmark is rendered alone and its blob \
centroid measured, in the reference and the perturbed view; the homography prediction H·x is beside it."
        );
    }
    if projection {
        let _ = writeln!(
            md,
            "- Phantom levels and mesh targets: silhouettes, contours and image metrics (NCC, SSIM, MI, GC, \
heatmaps) all come from the thickness DRR. `mean_abs_diff` is the mean |a − b| of the two DRRs, in \
their units (unitless line integrals), over the whole detector."
        );
        let _ = writeln!(
            md,
            "- NCC, SSIM, MI and gradient correlation in `projection.csv` are taken over the anatomy's \
region: the union of the reference and perturbed silhouettes dilated by {} px (`region_margin_px`; \
`region_px` pixels), SSIM and GC counting the windows centred there. The whole detector's values are the \
`*_detector` columns: its empty background, identical in both images, pulls them toward 1 (SSIM) \
whatever the anatomy does.",
            crate::analysis::REGION_MARGIN_PX
        );
    }
    if !cfg.anatomy.ct.is_empty() {
        let names: Vec<&str> = cfg.anatomy.ct.iter().map(|c| c.name.as_str()).collect();
        let _ = writeln!(
            md,
            "- CT targets ({}): image metrics and heatmaps come from the CT volume DRR (the line \
integral of μ(HU) through the CT, masked to the level's label), as the paper renders DRRs; \
silhouettes and contours from a thickness render of the label's closed surface (its ray-hit mask); \
landmarks are automatic landmarks of that surface unless a landmarks file is given. Each CT target is \
moved so its body centre sits at the world origin, as the phantom's levels (see Setup). The label surface is split into the phantom's \
structures from its automatic landmark frame, so structures.csv has per-structure rows for CT targets too.",
            names.join(", ")
        );
        let _ = writeln!(md, "{}", ct_alignment_note(cfg));
    }
    if landmarks {
        let _ = writeln!(
            md,
            "- Landmark overlays are drawn on each target's reference DRR \
(`references/<target>_<view>.tiff`, with its JSON sidecar)."
        );
    }
    let _ = writeln!(md);
}

/// Which CT entries were rotated into their levels' anatomical frames (`align`), and what that means.
fn ct_alignment_note(cfg: &StudyConfig) -> String {
    use crate::anatomy::ct::Alignment;
    let with = |a: Alignment| -> Vec<String> {
        let entries = cfg.anatomy.ct.iter().filter(|c| c.align == a);
        entries.map(|c| format!("`{}`", c.name)).collect()
    };
    let (aligned, kept) = (with(Alignment::Anatomical), with(Alignment::None));
    let mut note = String::from("- CT alignment (`align`):");
    if !aligned.is_empty() {
        note += &format!(
            " {}: `anatomical` — each level (the segment: its middle level) is also rotated so the right, \
anterior and superior axes of its automatic landmark frame become the world's, so AP and LAT are the \
vertebra's own AP and LAT whatever its tilt in the scanner;",
            aligned.join(", ")
        );
    }
    if !kept.is_empty() {
        note += &format!(
            " {}: `none` — translated only, so AP and LAT are along the scanner's axes (a tilted vertebra is \
seen tilted);",
            kept.join(", ")
        );
    }
    note.pop();
    note.push('.');
    for c in &cfg.anatomy.ct {
        let method = match c.method {
            crate::render::volume::VolumeMethod::Siddon => {
                "Siddon's exact traversal of the piecewise-constant voxels"
            }
            crate::render::volume::VolumeMethod::Trilinear => {
                "trilinear interpolation of μ, sampled at ≤ half the smallest voxel spacing (smooth \
across thick slices)"
            }
        };
        let gpu = if cfg.geometry.backend == crate::render::Backend::Gpu {
            " in the GPU's compute shader (`geometry.backend = \"gpu\"`; the adapter is named in the \
reference DRRs' sidecars)"
        } else {
            ""
        };
        note += &format!(
            "\n- CT `{}`: volume DRR by {method}{gpu}; label surfaces {}.",
            c.name,
            match c.smooth_iterations {
                0 => "unsmoothed (the exact 0.5-isosurface of the voxels)".to_string(),
                n => format!("smoothed by {n} Taubin λ|μ iterations (thick slices leave steps)"),
            }
        );
    }
    note
}

fn silhouette_section(
    md: &mut String,
    rows: &[ProjectionRow],
    paper: &PaperResults,
    first: &str,
    pitch: grid::Pitch,
) {
    let t = comparison::silhouette_table(rows, paper, first, pitch);
    let _ = writeln!(md, "### {}\n", t.caption);
    let _ = writeln!(md, "{}", t.to_markdown());
    let _ = writeln!(
        md,
        "A pure focal change scales the silhouette about the piercing point by α_f = (f + Δf)/f, so Dice \
falls even for a vertebra on the central ray; the paper's AP Dice > 0.997 cannot come from this model. We report \
what the model gives rather than tuning to the paper.\n"
    );
}

fn registration_section(
    md: &mut String,
    tables: &StudyTables,
    paper: &PaperResults,
    first: &str,
    (noise_px, pitch): (f64, grid::Pitch),
    views: &[&crate::geometry::View],
) {
    let rows = &tables.registration_summary;
    if !rows.is_empty() {
        let t = comparison::registration_table(rows, paper, first);
        let _ = writeln!(md, "### {}\n", t.caption);
        let _ = write!(md, "{}", t.to_markdown());
        let t = registration::cells_table(rows, first, noise_px, pitch);
        let _ = writeln!(md, "\n### {}\n", t.caption);
        let _ = write!(md, "{}", t.to_markdown());
        let _ = writeln!(md);
        if let Some(note) = registration::single_view_note(rows, first, views) {
            let _ = writeln!(md, "{note}\n");
        }
    }
    registration::physical_section(md, &tables.registration_physical, first, noise_px);
}
