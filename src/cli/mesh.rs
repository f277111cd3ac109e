//! `spinedrr mesh`: the closed surface of one vertebra label of a NIfTI segmentation, optionally
//! smoothed, decimated, split into structures and with automatic landmarks (our JSON or 3D Slicer
//! markups), written in any mesh format by extension.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use spinedrr::anatomy::ct::{MAX_SMOOTH_ITERATIONS, SurfaceOptions, label_surface, read_labels};
use spinedrr::anatomy::labels::LabelConvention;
use spinedrr::anatomy::markups::{LandmarkFormat, write_landmarks_as};
use spinedrr::anatomy::structure_split::label_structures;
use spinedrr::anatomy::{Landmarks, MeshFormat, TriMesh, auto_landmarks, decimate, write_mesh};
use spinedrr::io::{check_spares_inputs, same_file};

#[derive(clap::Args)]
pub struct Args {
    /// Segmentation (NIfTI-1 `.nii` / `.nii.gz`, integer labels).
    #[arg(long, value_name = "SEG.nii.gz")]
    seg: PathBuf,
    /// Label to mesh: a level name (`L1`, `T12`) in the `--labels` convention, or a raw integer id.
    #[arg(long)]
    label: String,
    /// Label convention of `--seg`: totalseg (TotalSegmentator v2) or verse.
    #[arg(long, default_value = "totalseg")]
    labels: String,
    /// Taubin λ|μ smoothing iterations (0 = none: the exact 0.5-isosurface of the voxel mask; at most
    /// 500).
    #[arg(long, default_value_t = 0, value_parser = super::values::whole::<usize>)]
    smooth: usize,
    /// Decimate to this many triangles (quadric edge collapse; the surface stays closed).
    #[arg(long, value_parser = super::values::whole::<usize>)]
    target_triangles: Option<usize>,
    /// `auto`: also write the landmarks derived from the surface, beside the mesh as
    /// `<stem>_landmarks.json` (or `<stem>_landmarks.mrk.json` for Slicer), or to --landmarks-out.
    #[arg(long, value_name = "auto")]
    landmarks: Option<String>,
    /// Where --landmarks auto writes; a name ending `.mrk.json` is written as 3D Slicer markups.
    #[arg(long, value_name = "FILE")]
    landmarks_out: Option<PathBuf>,
    /// Landmark file format: `spinedrr` (our JSON, world RAS+ mm) or `slicer` (3D Slicer markups,
    /// `.mrk.json`, LPS mm: drag it into Slicer beside the segmentation to check the points). Default:
    /// from the --landmarks-out name, else spinedrr.
    #[arg(long, value_name = "spinedrr|slicer")]
    landmarks_format: Option<String>,
    /// Label every triangle with its structure (body, endplates, pedicles, laminae, spinous, transverse,
    /// articular), split from the surface's automatic landmark frame. PLY and OBJ keep the labels.
    #[arg(long)]
    structures: bool,
    /// Output mesh (`.stl`, `.obj` or `.ply`). An existing file there, or at the landmarks output, is
    /// replaced only if spinedrr wrote it (its header or `tool` says so); any other is refused, nothing written.
    #[arg(long)]
    out: PathBuf,
}

/// `dir/stem_landmarks.json` (or `.mrk.json`) for `dir/stem.ext`.
fn landmarks_path(out: &Path, format: LandmarkFormat) -> PathBuf {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "mesh".into());
    let ext = match format {
        LandmarkFormat::Slicer => "mrk.json",
        _ => "json",
    };
    out.with_file_name(format!("{stem}_landmarks.{ext}"))
}

/// The landmark file and its format from the flags (checked before any work).
fn landmark_output(a: &Args) -> anyhow::Result<Option<(PathBuf, LandmarkFormat)>> {
    match &a.landmarks {
        None => {
            if a.landmarks_out.is_some() || a.landmarks_format.is_some() {
                bail!("--landmarks-out and --landmarks-format need --landmarks auto");
            }
            return Ok(None);
        }
        Some(l) if l != "auto" => bail!("--landmarks {l:?}: the only landmark source is `auto`"),
        Some(_) => {}
    }
    let format = match (&a.landmarks_format, &a.landmarks_out) {
        (Some(f), _) => f
            .parse::<LandmarkFormat>()
            .with_context(|| format!("--landmarks-format {f:?}"))?,
        (None, Some(p)) => LandmarkFormat::for_output(p),
        (None, None) => LandmarkFormat::Spinedrr,
    };
    if format == LandmarkFormat::Verse {
        bail!("--landmarks-format verse: VerSe centroid files are read, not written");
    }
    let path = a
        .landmarks_out
        .clone()
        .unwrap_or_else(|| landmarks_path(&a.out, format));
    Ok(Some((path, format)))
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let lm_out = landmark_output(&a)?;
    MeshFormat::from_path(&a.out).with_context(|| format!("--out {}", a.out.display()))?;
    let mut outputs = vec![("--out".to_string(), a.out.clone())];
    if let Some((p, _)) = &lm_out {
        outputs.push((
            "the landmarks output (--landmarks-out)".to_string(),
            p.clone(),
        ));
        if same_file(p, &a.out) {
            bail!(
                "--landmarks-out {} is also the mesh --out: both would be written to one file",
                p.display()
            );
        }
    }
    check_spares_inputs(&outputs, &[("the --seg file".to_string(), a.seg.clone())])?;
    spinedrr::io::check_ours(&a.out)?;
    if let Some((p, _)) = &lm_out {
        spinedrr::io::check_ours_landmarks(p)?;
    }
    if a.smooth > MAX_SMOOTH_ITERATIONS {
        bail!(
            "--smooth {}: more than the limit of {MAX_SMOOTH_ITERATIONS} Taubin iterations",
            a.smooth
        );
    }
    let convention: LabelConvention = a.labels.parse()?;
    let id = convention
        .resolve(&a.label)
        .with_context(|| format!("--label {:?}", a.label))?;
    let seg =
        read_labels(&a.seg).with_context(|| format!("reading segmentation {}", a.seg.display()))?;
    let opts = SurfaceOptions {
        smooth_iterations: a.smooth,
        ..SurfaceOptions::default()
    };
    let mut mesh = label_surface(&seg, id, &opts)
        .with_context(|| format!("label {} ({id}) of {}", a.label, a.seg.display()))?;
    mesh.name = a.label.clone();
    if let Some(n) = a.target_triangles
        && n < mesh.triangles.len()
    {
        mesh = decimate(&mesh, n).with_context(|| format!("--target-triangles {n}"))?;
    }
    let lm = if lm_out.is_some() || a.structures {
        Some(
            auto_landmarks(&mesh, &a.label)
                .with_context(|| format!("automatic landmarks of label {}", a.label))?,
        )
    } else {
        None
    };
    if a.structures
        && let Some(lm) = &lm
    {
        label_structures(&mut mesh, lm)
            .with_context(|| format!("splitting label {} into structures", a.label))?;
        eprintln!("structures: {}", structure_summary(&mesh));
    }
    write_mesh(&a.out, &mesh).with_context(|| format!("writing mesh {}", a.out.display()))?;
    let chk = mesh.check();
    eprintln!(
        "{}: {} triangles, {:.0} mm³, {}",
        a.out.display(),
        mesh.triangles.len(),
        mesh.volume(),
        if chk.is_watertight() {
            "watertight".to_string()
        } else {
            format!("NOT watertight: {chk:?}")
        }
    );
    if let (Some((path, format)), Some(lm)) = (lm_out, lm) {
        write_landmarks_as(&path, std::slice::from_ref::<Landmarks>(&lm), format)
            .with_context(|| format!("writing {}", path.display()))?;
        eprintln!("{}: {} landmarks", path.display(), lm.points.len());
    }
    Ok(())
}

/// "body 41%, pedicle_left 4%, …": each structure's share of the surface area.
fn structure_summary(mesh: &TriMesh) -> String {
    let mut area = [0.0f64; 256];
    for i in 0..mesh.triangles.len() {
        let [p, q, r] = mesh.corners(i);
        area[mesh.labels[i] as usize] += 0.5 * (q - p).cross(r - p).length();
    }
    let total: f64 = area.iter().sum::<f64>().max(f64::MIN_POSITIVE);
    spinedrr::anatomy::Structure::ALL
        .iter()
        .filter(|s| area[**s as usize] > 0.0)
        .map(|s| format!("{} {:.0}%", s.name(), 100.0 * area[*s as usize] / total))
        .collect::<Vec<_>>()
        .join(", ")
}
