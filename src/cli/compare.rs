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
    ImageF32, Sidecar, check_output_set, check_spares_inputs, difference_set_kind,
    difference_set_paths, read_with_sidecar, sidecar_path, write_difference_set,
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
    /// Output directory (created if missing). Its files (metrics.json, absdiff.tiff, heatmap.png and their
    /// sidecars) replace only files spinedrr wrote; any other file of those names is refused, nothing written.
    #[arg(long)]
    out: PathBuf,
}

fn load(path: &Path) -> anyhow::Result<(ImageF32, Sidecar)> {
    read_with_sidecar(path).with_context(|| format!("reading {} and its sidecar", path.display()))
}

/// Reads mask `path` of the image `image` (described by `image_sidecar`). A mask with a sidecar must
/// have been rendered with the image's camera (size, K, world_to_camera): a mask from another render
/// (stale beside a re-rendered image) is refused, naming both files.
fn read_mask(
    path: &Path,
    image: &Path,
    image_sidecar: &Sidecar,
    size: (u32, u32),
) -> anyhow::Result<Vec<bool>> {
    let sc_path = sidecar_path(path);
    if sc_path.exists() {
        let sc = Sidecar::read(&sc_path)
            .with_context(|| format!("reading the sidecar of mask {}", path.display()))?;
        if !sc.same_camera(image_sidecar) {
            bail!(
                "mask {} does not belong to {}: the mask's sidecar {} has K {:?} and world_to_camera \
                 {:?}, the image's has K {:?} and world_to_camera {:?} (a mask left from another render?)",
                path.display(),
                image.display(),
                sc_path.display(),
                sc.k,
                sc.world_to_camera,
                image_sidecar.k,
                image_sidecar.world_to_camera
            );
        }
    }
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

/// `A_mask_NAME.png` / `B_mask_NAME.png` pairs found beside the two images, keeping only masks their
/// image's sidecar lists among its companions (when it lists any: a mask it does not list is left from
/// an earlier render, and is skipped with a warning).
fn conventional_masks(
    a: (&Path, &Sidecar),
    b: (&Path, &Sidecar),
) -> Vec<(String, PathBuf, PathBuf)> {
    let listed = |(image, sc): (&Path, &Sidecar), mask: &Path| {
        let name = mask
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let ok = sc.companions.is_empty() || sc.companions.contains(&name);
        if !ok {
            eprintln!(
                "warning: skipping mask {}: not part of the output set of {} (left from an earlier render)",
                mask.display(),
                image.display()
            );
        }
        ok
    };
    conventional_mask_files(a.0, b.0)
        .into_iter()
        .filter(|(_, ra, pb)| listed(a, ra) & listed(b, pb))
        .collect()
}

/// Every `A_mask_NAME.png` beside `a` with a `B_mask_NAME.png` beside `b`.
fn conventional_mask_files(a: &Path, b: &Path) -> Vec<(String, PathBuf, PathBuf)> {
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
#[derive(Serialize, Clone)]
struct Inputs {
    reference: String,
    perturbed: String,
}

/// `metrics.json`.
#[derive(Serialize)]
struct Metrics {
    /// `spinedrr` (what [`spinedrr::io::check_ours`] recognises as its own file).
    tool: &'static str,
    kind: &'static str,
    #[serde(flatten)]
    inputs: Inputs,
    view: String,
    perturbation_reference: String,
    perturbation: String,
    /// `image`, `silhouettes` and `landmarks`.
    #[serde(flatten)]
    comparison: Comparison,
}

/// The files of the comparison's output set, each named by `--out`.
fn outputs(out: &Path) -> Vec<(String, PathBuf)> {
    difference_set_paths(out)
        .into_iter()
        .map(|p| ("--out".to_string(), p))
        .collect()
}

/// Every file this comparison reads: both images and their sidecars, the masks and theirs, the landmarks.
fn inputs_of(a: &Args, masks: &[(String, PathBuf, PathBuf)]) -> Vec<(String, PathBuf)> {
    let mut v = Vec::new();
    for (what, img) in [("--reference", &a.reference), ("--perturbed", &a.perturbed)] {
        v.push((format!("the {what} image"), img.clone()));
        v.push((format!("the {what} image's sidecar"), sidecar_path(img)));
    }
    for (name, r, p) in masks {
        for m in [r, p] {
            v.push((format!("mask '{name}'"), m.clone()));
            v.push((format!("the sidecar of mask '{name}'"), sidecar_path(m)));
        }
    }
    if let Some(l) = &a.landmarks {
        v.push(("the --landmarks file".to_string(), l.clone()));
    }
    v
}

/// Refuses a pair that cannot be compared as two renders of one view: a sidecar of another kind (a mask,
/// a depth map), images in different units (an intensity against a line integral), or two views.
fn check_comparable(a: &Args, sa: &Sidecar, sb: &Sidecar) -> anyhow::Result<()> {
    for (path, sc) in [(&a.reference, sa), (&a.perturbed, sb)] {
        if sc.kind != spinedrr::io::kind::DRR {
            bail!(
                "{} is a '{}' image (its sidecar {} says so), not a DRR: compare takes two DRRs",
                path.display(),
                sc.kind,
                sidecar_path(path).display()
            );
        }
    }
    if sa.units != sb.units {
        bail!(
            "the images are in different units: {} holds \"{}\", {} holds \"{}\" (render both the same \
             way: both line integrals, both --intensity, or the same --photons model)",
            a.reference.display(),
            sa.units,
            a.perturbed.display(),
            sb.units
        );
    }
    if sa.view != sb.view {
        bail!(
            "{} is view '{}' and {} is view '{}': compare measures what a perturbation moves in one view, \
             so both must be renders of the same view",
            a.reference.display(),
            sa.view,
            a.perturbed.display(),
            sb.view
        );
    }
    Ok(())
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let (ra, sa) = load(&a.reference)?;
    let (rb, sb) = load(&a.perturbed)?;
    check_comparable(&a, &sa, &sb)?;
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
        conventional_masks((&a.reference, &sa), (&a.perturbed, &sb))
    } else {
        a.masks
            .iter()
            .map(|s| parse_mask_spec(s))
            .collect::<anyhow::Result<_>>()?
    };
    check_spares_inputs(&outputs(&a.out), &inputs_of(&a, &specs))?;
    spinedrr::io::create_output_dir(&a.out, "--out")?;
    check_output_set(&difference_set_paths(&a.out), difference_set_kind)?;
    let size = (ra.width, ra.height);
    let masks = specs
        .iter()
        .map(|(name, r, p)| {
            Ok(MaskPair {
                name: name.clone(),
                width: size.0,
                height: size.1,
                reference: read_mask(r, &a.reference, &sa, size)?,
                perturbed: read_mask(p, &a.perturbed, &sb, size)?,
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

    let diff = abs_difference(&ra, &rb)?;
    let inputs = Inputs {
        reference: a.reference.display().to_string(),
        perturbed: a.perturbed.display().to_string(),
    };
    let metrics = Metrics {
        tool: "spinedrr",
        kind: spinedrr::io::kind::METRICS,
        inputs: inputs.clone(),
        view: sa.view,
        perturbation_reference: sa.perturbation_spec,
        perturbation: sb.perturbation_spec.clone(),
        comparison: result,
    };
    let serde_json::Value::Object(metrics) =
        serde_json::to_value(&metrics).context("encoding metrics.json")?
    else {
        bail!("internal error: metrics.json is not a JSON object");
    };
    write_difference_set(&a.out, &diff, &sb, &inputs, metrics)
        .with_context(|| format!("writing the comparison into {}", a.out.display()))?;
    Ok(())
}
