//! What `spinedrr render` refuses before it writes an image: a `--mesh FILE:MU` whose μ is not a number,
//! an X-ray source inside a mesh, an image on which nothing of the anatomy landed, and a negative line
//! integral (a negative μ not nested in a denser surface); and [`RenderRun`], what the mesh and the CT
//! renders share.

use std::path::{Path, PathBuf};

use anyhow::bail;
use glam::{DVec2, DVec3};
use spinedrr::anatomy::TriMesh;
use spinedrr::geometry::{Perturbation, View};
use spinedrr::io::{DrrValues, ImageF32};
use spinedrr::render::RenderScene;
use spinedrr::spectral::{Attenuation, parse_attenuation};

/// What the mesh and the CT renders share: the view, the perturbation, the output and its checks.
pub struct RenderRun<'a> {
    /// The reference view (recorded in the sidecar).
    pub view: &'a View,
    /// The view under the perturbation (what the rays follow).
    pub rendered: &'a View,
    pub perturbation: &'a Perturbation,
    pub values: DrrValues,
    pub repeat: u32,
    pub allow_empty: bool,
    pub out: &'a Path,
}

/// `FILE[:MU]` or `FILE:MATERIAL[@DENSITY]`: a trailing `:MU` is the attenuation (mm⁻¹), which must be a
/// finite number; a trailing `:NAME` must be a built-in material (`spinedrr render --help` lists them).
/// A spec that names an existing file, or whose last `:` part ends in a mesh extension, is a path (which
/// may contain `:`).
pub fn split_mesh_spec(spec: &str, default_mu: f64) -> anyhow::Result<(PathBuf, Attenuation)> {
    let Some((path, value)) = spec.rsplit_once(':') else {
        return Ok((PathBuf::from(spec), Attenuation::Mu(default_mu)));
    };
    let is_mesh_name = [".stl", ".obj", ".ply"]
        .iter()
        .any(|e| value.to_ascii_lowercase().ends_with(e));
    if is_mesh_name || Path::new(spec).is_file() {
        return Ok((PathBuf::from(spec), Attenuation::Mu(default_mu)));
    }
    match parse_attenuation(value) {
        Ok(v) => Ok((PathBuf::from(path), v)),
        Err(e) => bail!("--mesh {spec}: {e}"),
    }
}

/// `--implant FILE:MATERIAL[@DENSITY][:POSE]`: the mesh, its attenuation (as [`split_mesh_spec`]) and
/// the pose file, when the last `:` part ends in `.json`.
pub fn split_implant_spec(spec: &str) -> anyhow::Result<(PathBuf, Attenuation, Option<PathBuf>)> {
    let (mesh, pose) = match spec.rsplit_once(':') {
        Some((rest, p)) if p.to_ascii_lowercase().ends_with(".json") => {
            (rest, Some(PathBuf::from(p)))
        }
        _ => (spec, None),
    };
    let (path, attenuation) = split_mesh_spec(mesh, 0.0)?;
    Ok((path, attenuation, pose))
}

/// The corners of the bounding box of `meshes` (world mm), what [`check_not_empty`] projects to say where
/// the anatomy landed.
pub fn mesh_corners<'a>(meshes: impl IntoIterator<Item = &'a TriMesh>) -> Vec<DVec3> {
    let (lo, hi) = meshes
        .into_iter()
        .filter_map(|m| m.bounds())
        .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(a, b), (l, h)| {
            (a.min(l), b.max(h))
        });
    spinedrr::geometry::box_corners(lo, hi).to_vec()
}

/// Refuses a render whose X-ray source lies inside a mesh (winding number above ½): its rays start in
/// the material, and no DRR of it means anything.
pub fn check_source_outside(view: &View, meshes: &[(&str, &TriMesh)]) -> anyhow::Result<()> {
    let s = view.source_world();
    for (name, mesh) in meshes {
        if mesh.winding_number(s).abs() > 0.5 {
            bail!(
                "the X-ray source of view '{}' (world [{:.1}, {:.1}, {:.1}] mm) lies inside mesh '{name}': \
                 the anatomy must lie between the source and the detector (check the mesh's units and \
                 position, or the geometry)",
                view.name,
                s.x,
                s.y,
                s.z
            );
        }
    }
    Ok(())
}

/// The pixel box `(lo, hi)` the world points `corners` project to on `view`'s detector plane; `None` when
/// one lies at or behind the source (it has no projection).
fn projected_box(view: &View, corners: &[DVec3]) -> Option<(DVec2, DVec2)> {
    if corners.iter().any(|&c| view.depth(c) <= 0.0) {
        return None;
    }
    Some(
        corners
            .iter()
            .map(|&c| view.project(c))
            .fold((DVec2::INFINITY, DVec2::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p), hi.max(p))
            }),
    )
}

/// Where the anatomy with world bounding-box corners `corners` lands on the detector of `view`, in words.
fn where_it_projects(view: &View, corners: &[DVec3]) -> String {
    let Some((lo, hi)) = projected_box(view, corners) else {
        let behind = corners.iter().filter(|&&c| view.depth(c) <= 0.0).count();
        return format!(
            "{behind} of its {} bounding-box corners lie behind the source",
            corners.len()
        );
    };
    format!(
        "its bounding box projects to u ∈ [{:.4e}, {:.4e}], v ∈ [{:.4e}, {:.4e}] px, the detector is {} × \
         {} px",
        lo.x, hi.x, lo.y, hi.y, view.intrinsics.width, view.intrinsics.height
    )
}

/// The size (px) of the bounding box's image when it overlaps the detector's area (every corner in front
/// of the source), else `None`.
fn image_on_detector(view: &View, corners: &[DVec3]) -> Option<DVec2> {
    let (lo, hi) = projected_box(view, corners)?;
    let (w, h) = (
        f64::from(view.intrinsics.width),
        f64::from(view.intrinsics.height),
    );
    (lo.x < w && hi.x > 0.0 && lo.y < h && hi.y > 0.0).then_some(hi - lo)
}

/// Refuses an image in which every pixel is 0 unless `allow_empty`. The message says why: `no_attenuation`
/// (asked only then) names what attenuates nothing — every mesh with μ = 0 or enclosing no volume, every
/// rendered voxel air — and otherwise, where the anatomy's bounding box lands: off the detector (placed
/// elsewhere, a huge perturbation, a CT whose world position is not where the view aims) or on it.
/// `rendered` is the view the rays followed (perturbed K), `corners` the anatomy's world bounding box.
pub fn check_not_empty(
    line_integral: &ImageF32,
    rendered: &View,
    perturbation: &str,
    corners: &[DVec3],
    allow_empty: bool,
    no_attenuation: impl FnOnce() -> Option<String>,
) -> anyhow::Result<()> {
    if allow_empty || line_integral.data.iter().any(|&v| v != 0.0) {
        return Ok(());
    }
    let what = format!(
        "every pixel of the {} × {} DRR of view '{}' under perturbation {perturbation} is 0",
        line_integral.width, line_integral.height, rendered.name
    );
    let place = where_it_projects(rendered, corners);
    let cause = if let Some(nothing) = no_attenuation() {
        format!("nothing attenuates: {nothing}; {what} ({place})")
    } else if let Some(size) = image_on_detector(rendered, corners) {
        let why = if size.min_element() < 1.0 {
            "smaller than a pixel, it fell between the rays through the pixel centres"
        } else {
            "is the anatomy hollow, or thinner than the rays' spacing?"
        };
        format!(
            "{what}, although the anatomy's bounding box meets the detector ({place}; its image spans \
             {:.2} × {:.2} px): no ray through a pixel centre crossed it ({why})",
            size.x, size.y
        )
    } else {
        format!("nothing of the anatomy is on the detector: {what} ({place})")
    };
    bail!("{cause}; nothing was written. Pass --allow-empty to write an empty image anyway")
}

/// What attenuates nothing in a mesh scene, when that is every mesh: a mesh with μ = 0, or one whose
/// surface encloses no volume (flat or degenerate: |V| ≤ 10⁻⁹ · area^1.5, the volume a closed surface of
/// that area could hold scaled down a billion times). `None` when some mesh attenuates.
pub fn mesh_zero_cause(scene: &RenderScene) -> Option<String> {
    if scene.meshes.is_empty() {
        return None;
    }
    scene
        .meshes
        .iter()
        .map(|m| {
            let name = &m.mesh.name;
            if m.mu_per_mm == 0.0 {
                return Some(format!("mesh '{name}' has μ = 0 mm⁻¹"));
            }
            let (volume, area) = (m.mesh.volume(), m.mesh.area());
            (volume.abs() <= 1e-9 * area.powf(1.5)).then(|| {
                format!(
                    "mesh '{name}' encloses no volume ({} mm³ within {} mm² of surface): a flat or \
                     degenerate surface has no path length",
                    spinedrr::error::shown(volume.abs()),
                    spinedrr::error::shown(area)
                )
            })
        })
        .collect::<Option<Vec<_>>>()
        .map(|v| v.join("; "))
}

/// Refuses a line integral with a non-finite pixel: μ × path length overflowed the image's float32 range
/// (≈ 3.4e38), which only an absurd attenuation can do; `cause` says which values made it (asked only
/// when a pixel is not finite). Nothing is written.
pub fn check_finite(
    line_integral: &ImageF32,
    cause: impl FnOnce() -> String,
) -> anyhow::Result<()> {
    let count = line_integral.data.iter().filter(|v| !v.is_finite()).count();
    if count == 0 {
        return Ok(());
    }
    bail!(
        "{count} of the {} × {} pixels of the line integral are not finite: μ × path length overflowed \
         float32 (≈ 3.4e38); {}; nothing was written",
        line_integral.width,
        line_integral.height,
        cause()
    )
}

/// What [`check_finite`] says of a mesh render: the mesh with the largest |μ|, beside what real
/// materials attenuate (lead, about the densest in an X-ray room, ≈ 100 mm⁻¹ at 20 keV; bone < 1 mm⁻¹).
pub fn mesh_mu_cause(scene: &RenderScene) -> String {
    match scene
        .meshes
        .iter()
        .max_by(|a, b| a.mu_per_mm.abs().total_cmp(&b.mu_per_mm.abs()))
    {
        Some(m) => format!(
            "the largest μ is {:e} mm⁻¹ (mesh '{}'), where lead at 20 keV attenuates about 100 mm⁻¹",
            m.mu_per_mm, m.mesh.name
        ),
        None => "there is no mesh".to_string(),
    }
}

/// Refuses a line integral that is negative anywhere beyond rounding: a negative μ is the differential
/// μ of a surface nested in a denser one (a cancellous core in a cortical shell); alone it attenuates
/// negatively, which no material does.
pub fn check_not_negative(line_integral: &ImageF32) -> anyhow::Result<()> {
    let (min, max) = line_integral
        .data
        .iter()
        .fold((0f32, 0f32), |(a, b), &v| (a.min(v), b.max(v)));
    let tolerance = 1e-4 * f64::from(max).max(1.0);
    if f64::from(min) >= -tolerance {
        return Ok(());
    }
    let count = line_integral
        .data
        .iter()
        .filter(|&&v| f64::from(v) < -tolerance)
        .count();
    bail!(
        "the line integral is negative at {count} pixels (down to {min}): a negative μ is only valid for a \
         surface nested inside one whose μ is at least as large (differential μ); nothing was written"
    )
}
