//! `spinedrr mesh`: the closed surface of one vertebra label of a NIfTI segmentation, optionally
//! smoothed, decimated and with automatic landmarks, written in any mesh format by extension.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use spinedrr::anatomy::ct::{MAX_SMOOTH_ITERATIONS, SurfaceOptions, label_surface, read_labels};
use spinedrr::anatomy::labels::LabelConvention;
use spinedrr::anatomy::{MeshFormat, auto_landmarks, decimate, write_landmarks, write_mesh};

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
    #[arg(long, default_value_t = 0)]
    smooth: usize,
    /// Decimate to this many triangles (quadric edge collapse; the surface stays closed).
    #[arg(long)]
    target_triangles: Option<usize>,
    /// `auto`: also write `<stem>_landmarks.json` beside the mesh, derived from the surface.
    #[arg(long, value_name = "auto")]
    landmarks: Option<String>,
    /// Output mesh (`.stl`, `.obj` or `.ply`).
    #[arg(long)]
    out: PathBuf,
}

/// `dir/stem_landmarks.json` for `dir/stem.ext`.
fn landmarks_path(out: &Path) -> PathBuf {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "mesh".into());
    out.with_file_name(format!("{stem}_landmarks.json"))
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if let Some(l) = &a.landmarks
        && l != "auto"
    {
        bail!("--landmarks {l:?}: the only landmark source is `auto`");
    }
    MeshFormat::from_path(&a.out).with_context(|| format!("--out {}", a.out.display()))?;
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
    if let Some(n) = a.target_triangles {
        if n < mesh.triangles.len() {
            mesh = decimate(&mesh, n).with_context(|| format!("--target-triangles {n}"))?;
        }
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
    if a.landmarks.is_some() {
        let lm = auto_landmarks(&mesh, &a.label)
            .with_context(|| format!("automatic landmarks of label {}", a.label))?;
        let path = landmarks_path(&a.out);
        write_landmarks(&path, std::slice::from_ref(&lm))
            .with_context(|| format!("writing {}", path.display()))?;
        eprintln!("{}: {} landmarks", path.display(), lm.points.len());
    }
    Ok(())
}
