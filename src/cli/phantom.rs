//! `spinedrr phantom`: build the parametric lumbar phantom and write its meshes and landmarks.

use std::path::{Path, PathBuf};

use anyhow::Context;
use spinedrr::anatomy::ct::{write_ct, write_labels};
use spinedrr::anatomy::labels::LabelConvention;
use spinedrr::anatomy::synthetic_ct::{SyntheticCtOptions, synthetic_ct};
use spinedrr::anatomy::{
    MeshFormat, PhantomOptions, TriMesh, build_phantom, parse_levels, write_landmarks,
    write_mesh_as,
};

#[derive(clap::Args)]
pub struct Args {
    /// Levels: a range `L1-L5`, one level `L3` or a list `L1,L3`.
    #[arg(long, default_value = "L1-L5")]
    levels: String,
    /// Output directory (created if missing). A file of the same name already there is replaced only if
    /// spinedrr wrote it (the meshes' headers and the landmarks' `tool` say so); any other is refused by
    /// name before anything is written. The same holds for --ct and --labels-out.
    #[arg(long)]
    out: PathBuf,
    /// Mesh file format.
    #[arg(long, value_enum, default_value_t = Format::Stl)]
    format: Format,
    /// Grid spacing of the isosurface extraction (mm).
    #[arg(long, default_value_t = 0.6)]
    voxel_mm: f64,
    /// Cortical shell thickness (mm).
    #[arg(long, default_value_t = 1.2)]
    cortical_mm: f64,
    /// Do not build the intervertebral discs.
    #[arg(long)]
    no_discs: bool,
    /// Also build the soft-tissue outline (a 300 × 220 mm elliptic cylinder).
    #[arg(long)]
    soft_tissue: bool,
    /// Also voxelize the phantom into a synthetic CT (Hounsfield units, NIfTI: the name must end in `.nii`
    /// or `.nii.gz`).
    #[arg(long, value_name = "CT.nii.gz")]
    ct: Option<PathBuf>,
    /// Voxel size of the synthetic CT (mm).
    #[arg(long, default_value_t = 0.5, requires = "ct")]
    ct_voxel_mm: f64,
    /// Write the CT's vertebra label map here (NIfTI).
    #[arg(long, value_name = "SEG.nii.gz", requires = "ct")]
    labels_out: Option<PathBuf>,
    /// Label convention of `--labels-out`: totalseg (TotalSegmentator v2) or verse.
    #[arg(long, default_value = "totalseg")]
    labels: String,
}

/// Voxelizes the phantom and writes the CT and, when asked, the label map.
fn write_synthetic_ct(
    phantom: &spinedrr::anatomy::Phantom,
    a: &Args,
    ct_path: &Path,
) -> anyhow::Result<()> {
    let convention: LabelConvention = a.labels.parse()?;
    let opts = SyntheticCtOptions {
        voxel_mm: a.ct_voxel_mm,
        labels: convention,
        ..SyntheticCtOptions::default()
    };
    let (ct, seg) =
        synthetic_ct(phantom, &opts).with_context(|| format!("--ct-voxel-mm {}", a.ct_voxel_mm))?;
    write_ct(ct_path, &ct).with_context(|| format!("writing CT {}", ct_path.display()))?;
    eprintln!(
        "{}: {:?} voxels of {} mm",
        ct_path.display(),
        ct.dims,
        a.ct_voxel_mm
    );
    if let Some(p) = &a.labels_out {
        write_labels(p, &seg).with_context(|| format!("writing label map {}", p.display()))?;
        eprintln!("{}: labels {:?}", p.display(), seg.labels_present());
    }
    Ok(())
}

/// Refuses an output name that is not NIfTI (`.nii` or `.nii.gz`): the file is NIfTI whatever its name.
fn check_nifti_name(flag: &str, path: &Path) -> anyhow::Result<()> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    if !(name.ends_with(".nii") || name.ends_with(".nii.gz")) || name.starts_with(".nii") {
        anyhow::bail!(
            "{flag} {}: the volume is written as NIfTI-1; name it .nii or .nii.gz",
            path.display()
        );
    }
    Ok(())
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum Format {
    Stl,
    Obj,
    Ply,
}

fn write_one(path: &Path, mesh: &TriMesh, format: MeshFormat) -> anyhow::Result<()> {
    write_mesh_as(path, mesh, format)
        .with_context(|| format!("writing mesh {}", path.display()))?;
    let chk = mesh.check();
    eprintln!(
        "{:<22} {:>8} triangles  {:>9.0} mm³  {}",
        path.file_name()
            .map(|n| n.to_string_lossy())
            .unwrap_or_default(),
        mesh.triangles.len(),
        mesh.volume(),
        if chk.is_watertight() {
            "watertight".to_string()
        } else {
            format!("NOT watertight: {chk:?}")
        }
    );
    Ok(())
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let levels = parse_levels(&a.levels).with_context(|| format!("--levels {:?}", a.levels))?;
    // Check the CT flags before the (slow) phantom build.
    for (flag, path) in [("--ct", &a.ct), ("--labels-out", &a.labels_out)] {
        if let Some(p) = path {
            check_nifti_name(flag, p)?;
        }
    }
    if a.ct.is_some() {
        a.labels.parse::<LabelConvention>()?;
        if !(a.ct_voxel_mm.is_finite() && (0.1..=5.0).contains(&a.ct_voxel_mm)) {
            anyhow::bail!("--ct-voxel-mm {} is outside [0.1, 5] mm", a.ct_voxel_mm);
        }
    }
    let opts = PhantomOptions {
        levels,
        voxel_mm: a.voxel_mm,
        cortical_mm: a.cortical_mm,
        soft_tissue: a.soft_tissue,
        discs: !a.no_discs,
        ..PhantomOptions::default()
    };
    let format = match a.format {
        Format::Stl => MeshFormat::StlBinary,
        Format::Obj => MeshFormat::Obj,
        Format::Ply => MeshFormat::PlyBinary,
    };
    spinedrr::io::create_output_dir(&a.out, "--out")?;
    let phantom = build_phantom(&opts).context("building the phantom")?;
    let mut meshes: Vec<(String, &TriMesh)> = Vec::new();
    for v in &phantom.vertebrae {
        meshes.push((format!("{}_cortical", v.level), &v.cortical));
        meshes.push((format!("{}_cancellous", v.level), &v.cancellous));
    }
    meshes.extend(phantom.discs.iter().map(|d| (d.name.clone(), d)));
    meshes.extend(
        phantom
            .soft_tissue
            .iter()
            .map(|s| ("soft_tissue".to_string(), s)),
    );
    let mesh_path = |stem: &str| a.out.join(format!("{stem}.{}", format.extension()));
    // Every file this run writes, checked before the first is: one already there must be spinedrr's.
    let lm = a.out.join("landmarks.json");
    let mut outputs: Vec<PathBuf> = meshes.iter().map(|(stem, _)| mesh_path(stem)).collect();
    outputs.extend(a.ct.iter().chain(&a.labels_out).cloned());
    spinedrr::io::check_output_paths(&outputs)?;
    spinedrr::io::check_ours_landmarks(&lm)?;
    for (stem, mesh) in &meshes {
        write_one(&mesh_path(stem), mesh, format)?;
    }
    write_landmarks(&lm, &phantom.landmarks())
        .with_context(|| format!("writing {}", lm.display()))?;
    eprintln!("landmarks.json         {} levels", phantom.vertebrae.len());
    if let Some(ct_path) = &a.ct {
        write_synthetic_ct(&phantom, &a, ct_path)?;
    }
    let written: Vec<PathBuf> = meshes.iter().map(|(stem, _)| mesh_path(stem)).collect();
    let earlier = earlier_phantom_meshes(&a.out, &written);
    if !earlier.is_empty() {
        eprintln!(
            "warning: {} also holds {} from an earlier phantom run, which this run did not write \
             (other levels, discs, soft tissue or --format): they are not this phantom's, and \
             landmarks.json now describes this run's levels alone; remove them before using the \
             folder as one phantom",
            a.out.display(),
            earlier.join(", ")
        );
    }
    Ok(())
}

/// The meshes in `dir` named as `spinedrr phantom` names them (`<level>_cortical`, `<level>_cancellous`,
/// `<a>-<b>_disc`, `soft_tissue`; STL, OBJ or PLY) and written by spinedrr, other than `written`: a
/// phantom of an earlier run beside this one's.
fn earlier_phantom_meshes(dir: &Path, written: &[PathBuf]) -> Vec<String> {
    let phantom_name = |name: &str| {
        let Some((stem, ext)) = name.rsplit_once('.') else {
            return false;
        };
        ["stl", "obj", "ply"].contains(&ext)
            && (stem == "soft_tissue"
                || stem.ends_with("_cortical")
                || stem.ends_with("_cancellous")
                || stem.ends_with("_disc"))
    };
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| !written.contains(p))
        .filter(|p| {
            p.file_name()
                .is_some_and(|n| phantom_name(&n.to_string_lossy()))
        })
        .filter(|p| spinedrr::io::check_ours(p).is_ok())
        .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .collect();
    names.sort();
    names
}
