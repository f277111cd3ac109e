//! `spinedrr phantom`: build the parametric lumbar phantom and write its meshes and landmarks.

use std::path::{Path, PathBuf};

use anyhow::Context;
use spinedrr::anatomy::{
    MeshFormat, PhantomOptions, TriMesh, build_phantom, parse_levels, write_landmarks,
    write_mesh_as,
};

#[derive(clap::Args)]
pub struct Args {
    /// Levels: a range `L1-L5`, one level `L3` or a list `L1,L3`.
    #[arg(long, default_value = "L1-L5")]
    levels: String,
    /// Output directory (created if missing).
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
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum Format {
    Stl,
    Obj,
    Ply,
}

fn write_one(dir: &Path, stem: &str, mesh: &TriMesh, format: MeshFormat) -> anyhow::Result<()> {
    let path = dir.join(format!("{stem}.{}", format.extension()));
    write_mesh_as(&path, mesh, format)
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
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let phantom = build_phantom(&opts).context("building the phantom")?;
    for v in &phantom.vertebrae {
        write_one(
            &a.out,
            &format!("{}_cortical", v.level),
            &v.cortical,
            format,
        )?;
        write_one(
            &a.out,
            &format!("{}_cancellous", v.level),
            &v.cancellous,
            format,
        )?;
    }
    for d in &phantom.discs {
        write_one(&a.out, &d.name, d, format)?;
    }
    if let Some(s) = &phantom.soft_tissue {
        write_one(&a.out, "soft_tissue", s, format)?;
    }
    let lm = a.out.join("landmarks.json");
    write_landmarks(&lm, &phantom.landmarks())
        .with_context(|| format!("writing {}", lm.display()))?;
    eprintln!("landmarks.json         {} levels", phantom.vertebrae.len());
    Ok(())
}
