//! `spinedrr compare`: every projection-domain metric between a reference and a perturbed DRR, written
//! as `metrics.json`, plus the absolute-difference image (float TIFF) and its colour heatmap (PNG).
//!
//! Masks come from `--masks [NAME=]REF.png:PERT.png` (repeatable). Without `--masks`, the convention
//! `A_mask_NAME.png` beside `A.tiff` and `B_mask_NAME.png` beside `B.tiff` is used for every NAME
//! present for both images.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use serde::Serialize;
use spinedrr::analysis::{
    Comparison, MaskPair, abs_difference, compare, read_landmarks, read_mask_png,
};
use spinedrr::io::{
    ImageF32, Sidecar, read_with_sidecar, sidecar_path, write_difference, write_json,
};

#[derive(clap::Args)]
pub struct Args {
    /// Reference DRR (float TIFF with a JSON sidecar beside it).
    #[arg(long)]
    reference: PathBuf,
    /// Perturbed DRR (float TIFF with a JSON sidecar beside it).
    #[arg(long)]
    perturbed: PathBuf,
    /// A silhouette pair `[NAME=]REF.png:PERT.png` (repeatable; 0 = outside, non-zero = inside).
    #[arg(long = "masks")]
    masks: Vec<String>,
    /// Landmark JSON {"landmarks": {"name": [x, y, z]}} (world mm), projected with each sidecar's view.
    #[arg(long)]
    landmarks: Option<PathBuf>,
    /// Output directory (created if missing).
    #[arg(long)]
    out: PathBuf,
}

fn load(path: &Path) -> anyhow::Result<(ImageF32, Sidecar)> {
    read_with_sidecar(path).with_context(|| format!("reading {} and its sidecar", path.display()))
}

fn read_mask(path: &Path, size: (u32, u32)) -> anyhow::Result<Vec<bool>> {
    let (w, h, m) =
        read_mask_png(path).with_context(|| format!("reading mask {}", path.display()))?;
    if (w, h) != size {
        bail!(
            "mask {} is {w}×{h}, the images are {}×{}",
            path.display(),
            size.0,
            size.1
        );
    }
    Ok(m)
}

/// Parses `[NAME=]REF.png:PERT.png`; the name defaults to the reference file stem.
fn parse_mask_spec(spec: &str) -> anyhow::Result<(String, PathBuf, PathBuf)> {
    let (name, pair) = match spec.split_once('=') {
        Some((n, p)) => (Some(n.to_string()), p),
        None => (None, spec),
    };
    let Some((r, p)) = pair.rsplit_once(':') else {
        bail!("invalid --masks '{spec}': expected [NAME=]REF.png:PERT.png");
    };
    let r = PathBuf::from(r);
    let name = name.unwrap_or_else(|| {
        r.file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default()
    });
    Ok((name, r, PathBuf::from(p)))
}

/// `A_mask_NAME.png` / `B_mask_NAME.png` pairs found beside the two images.
fn conventional_masks(a: &Path, b: &Path) -> Vec<(String, PathBuf, PathBuf)> {
    let stem = |p: &Path| {
        p.file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    let (sa, sb) = (stem(a), stem(b));
    let dir = a
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let prefix = format!("{sa}_mask_");
    let mut out: Vec<_> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let f = e.file_name().to_string_lossy().into_owned();
            let name = f.strip_prefix(&prefix)?.strip_suffix(".png")?.to_string();
            let pert = b.with_file_name(format!("{sb}_mask_{name}.png"));
            pert.exists().then(|| (name, e.path(), pert))
        })
        .collect();
    out.sort();
    out
}

/// The two images compared (also recorded in the difference images' sidecars).
#[derive(Serialize)]
struct Inputs {
    reference: String,
    perturbed: String,
}

/// `metrics.json`.
#[derive(Serialize)]
struct Metrics {
    #[serde(flatten)]
    inputs: Inputs,
    view: String,
    perturbation_reference: String,
    perturbation: String,
    /// `image`, `silhouettes` and `landmarks`.
    #[serde(flatten)]
    comparison: Comparison,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let (ra, sa) = load(&a.reference)?;
    let (rb, sb) = load(&a.perturbed)?;
    if (ra.width, ra.height) != (rb.width, rb.height) {
        bail!(
            "the images differ in size: {}×{} vs {}×{}",
            ra.width,
            ra.height,
            rb.width,
            rb.height
        );
    }
    let specs = if a.masks.is_empty() {
        conventional_masks(&a.reference, &a.perturbed)
    } else {
        a.masks
            .iter()
            .map(|s| parse_mask_spec(s))
            .collect::<anyhow::Result<_>>()?
    };
    let size = (ra.width, ra.height);
    let masks = specs
        .iter()
        .map(|(name, r, p)| {
            Ok(MaskPair {
                name: name.clone(),
                width: size.0,
                height: size.1,
                reference: read_mask(r, size)?,
                perturbed: read_mask(p, size)?,
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let landmarks = match &a.landmarks {
        Some(p) => {
            read_landmarks(p).with_context(|| format!("reading landmarks {}", p.display()))?
        }
        None => Vec::new(),
    };
    let va = sa.rendered_view(&sidecar_path(&a.reference))?;
    let vb = sb.rendered_view(&sidecar_path(&a.perturbed))?;
    let result =
        compare(&ra, &rb, &masks, &landmarks, Some((&va, &vb))).context("computing metrics")?;

    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let diff = abs_difference(&ra, &rb)?;
    let inputs = Inputs {
        reference: a.reference.display().to_string(),
        perturbed: a.perturbed.display().to_string(),
    };
    write_difference(&a.out, &diff, &sb, &inputs)?;
    let metrics = Metrics {
        inputs,
        view: sa.view,
        perturbation_reference: sa.perturbation_spec,
        perturbation: sb.perturbation_spec,
        comparison: result,
    };
    let path = a.out.join("metrics.json");
    // Through a JSON value: its keys come out sorted, as metrics.json has always had them.
    let metrics = serde_json::to_value(&metrics).context("encoding metrics.json")?;
    write_json(&path, &metrics).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}
