//! Calibration phantoms: the BB centres (phantom frame, mm) of a planar plate, a 3-D helix, or a user's
//! own phantom read from JSON, and where each is placed in front of the C-arm's views.
//!
//! BB centres are rounded to `f32` once, when a phantom is made: OpenCV's `calibrateCamera` works on
//! `f32` points, so the reference solver and ours see exactly the same phantom.

use std::path::Path;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::geometry::{CArm, RigidTransform, rotation_exp};
use crate::{Error, Result};

/// Largest number of BBs a phantom may hold (a calibration phantom has tens to a few hundred).
pub const MAX_BBS: usize = 10_000;

/// Which estimator a phantom's geometry calls for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PhantomKind {
    /// All BBs in one plane: several tilted poses, Zhang's method (OpenCV `calibrateCamera`).
    Planar,
    /// BBs spanning 3-D: one image per view, a full projection-matrix calibration (DLT + LM).
    Volumetric,
}

/// A calibration phantom: named BB centres in its own frame (mm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationPhantom {
    pub name: String,
    pub kind: PhantomKind,
    /// BB centres, phantom frame (mm). A plate lies in z = 0, centred on the origin.
    pub bbs_mm: Vec<[f64; 3]>,
}

/// The JSON file of a user's phantom: `{"name"?: "...", "bbs_mm": [[x, y, z], ...]}`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct PhantomFile {
    #[serde(default)]
    name: Option<String>,
    bbs_mm: Vec<[f64; 3]>,
}

/// Rounds to the nearest `f32` (the precision OpenCV calibrates with).
fn f32_exact(p: DVec3) -> [f64; 3] {
    p.to_array().map(|c| f64::from(c as f32))
}

impl CalibrationPhantom {
    /// A planar grid of `rows × cols` BBs at `pitch_mm`, centred on the origin in z = 0.
    pub fn plate(rows: usize, cols: usize, pitch_mm: f64) -> Result<Self> {
        if rows < 2 || cols < 2 || rows * cols > MAX_BBS {
            return Err(Error::invalid(
                "plate",
                format!("needs 2..{MAX_BBS} BBs in at least 2 × 2, got {rows} × {cols}"),
            ));
        }
        if !(pitch_mm.is_finite() && pitch_mm > 0.0) {
            return Err(Error::invalid(
                "plate pitch_mm",
                format!("must be positive, got {pitch_mm}"),
            ));
        }
        let (r0, c0) = ((rows as f64 - 1.0) / 2.0, (cols as f64 - 1.0) / 2.0);
        let bbs_mm = (0..rows)
            .flat_map(|r| (0..cols).map(move |c| (r, c)))
            .map(|(r, c)| {
                f32_exact(DVec3::new(
                    (c as f64 - c0) * pitch_mm,
                    (r as f64 - r0) * pitch_mm,
                    0.0,
                ))
            })
            .collect();
        Self::checked(
            format!("plate {rows}x{cols} @ {pitch_mm} mm"),
            bbs_mm,
            "plate",
        )
    }

    /// The default plate: 10 × 10 BBs at 10 mm pitch (90 mm across).
    pub fn default_plate() -> Self {
        Self::plate(10, 10, 10.0).unwrap_or_else(|e| panic!("the default plate is valid: {e}"))
    }

    /// `n` BBs on a helix of `radius_mm` about the z axis, `turns` turns over `height_mm`, centred on the
    /// origin (the classic C-arm geometric-calibration phantom).
    pub fn helix(n: usize, radius_mm: f64, height_mm: f64, turns: f64) -> Result<Self> {
        if !(6..=MAX_BBS).contains(&n) {
            return Err(Error::invalid(
                "helix",
                format!("needs 6..{MAX_BBS} BBs, got {n}"),
            ));
        }
        for (k, v) in [
            ("radius_mm", radius_mm),
            ("height_mm", height_mm),
            ("turns", turns),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::invalid(
                    format!("helix {k}"),
                    format!("must be positive, got {v}"),
                ));
            }
        }
        let bbs_mm = (0..n)
            .map(|i| {
                let s = i as f64 / (n as f64 - 1.0);
                let a = std::f64::consts::TAU * turns * s;
                f32_exact(DVec3::new(
                    radius_mm * a.cos(),
                    radius_mm * a.sin(),
                    (s - 0.5) * height_mm,
                ))
            })
            .collect();
        Self::checked(
            format!("helix {n} BBs r{radius_mm} h{height_mm}"),
            bbs_mm,
            "helix",
        )
    }

    /// The default helix: 40 BBs, radius 40 mm, 2 turns over 80 mm.
    pub fn default_helix() -> Self {
        Self::helix(40, 40.0, 80.0, 2.0)
            .unwrap_or_else(|e| panic!("the default helix is valid: {e}"))
    }

    /// Parses a phantom JSON document; `origin` names it in errors.
    pub fn from_json_str(text: &str, origin: &str) -> Result<Self> {
        let f: PhantomFile = serde_json::from_str(text).map_err(|e| {
            Error::format(
                origin,
                format!("expected {{\"bbs_mm\": [[x, y, z], ...]}}: {e}"),
            )
        })?;
        let bbs: Vec<[f64; 3]> = f
            .bbs_mm
            .iter()
            .map(|p| f32_exact(DVec3::from(*p)))
            .collect();
        let name = f.name.unwrap_or_else(|| origin.to_string());
        Self::checked(name, bbs, origin).map_err(|e| match e {
            Error::Invalid { message, .. } | Error::Format { message, .. } => {
                Error::format(origin, message)
            }
            other => other,
        })
    }

    /// Reads a phantom JSON file.
    pub fn from_file(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Self::from_json_str(&text, &path.display().to_string())
    }

    /// Classifies and checks BB centres: finite, distinct, not collinear, enough for the unknowns of
    /// the estimator the geometry calls for (a plane: 4 BBs, a homography per pose; 3-D: 6 BBs, the 11
    /// unknowns of a projection matrix).
    fn checked(name: String, bbs_mm: Vec<[f64; 3]>, field: &str) -> Result<Self> {
        let pts: Vec<DVec3> = bbs_mm.iter().map(|p| DVec3::from(*p)).collect();
        if pts.len() > MAX_BBS {
            return Err(Error::invalid(
                field,
                format!("{} BBs (at most {MAX_BBS})", pts.len()),
            ));
        }
        if let Some(i) = pts.iter().position(|p| !p.is_finite()) {
            return Err(Error::invalid(field, format!("BB {i} is not finite")));
        }
        for (i, a) in pts.iter().enumerate() {
            if let Some(j) = pts[..i].iter().position(|b| (*a - *b).length() < 1e-6) {
                return Err(Error::invalid(
                    field,
                    format!("BBs {j} and {i} are at the same place"),
                ));
            }
        }
        let kind = match spread(&pts) {
            Spread::Point | Spread::Line => {
                return Err(Error::invalid(
                    field,
                    "the BBs are collinear: a calibration needs BBs spanning a plane or a volume",
                ));
            }
            Spread::Plane => PhantomKind::Planar,
            Spread::Volume => PhantomKind::Volumetric,
        };
        let need = match kind {
            PhantomKind::Planar => 4,
            PhantomKind::Volumetric => 6,
        };
        if pts.len() < need {
            return Err(Error::invalid(
                field,
                format!(
                    "{} BBs: a {} phantom needs at least {need} (the unknowns of {})",
                    pts.len(),
                    if kind == PhantomKind::Planar {
                        "planar"
                    } else {
                        "3-D"
                    },
                    if kind == PhantomKind::Planar {
                        "a homography per pose, 8"
                    } else {
                        "a projection matrix, 11"
                    }
                ),
            ));
        }
        let mut p = CalibrationPhantom { name, kind, bbs_mm };
        if kind == PhantomKind::Planar {
            p.move_to_plane_frame();
        }
        Ok(p)
    }

    /// Moves a planar phantom into its own plane frame: centroid at the origin, plane z = 0 (what Zhang's
    /// method expects of the object points).
    fn move_to_plane_frame(&mut self) {
        let pts = self.points();
        let c = centroid(&pts);
        let (_, axes) = principal_axes(&pts, c);
        // Rows of R are the plane axes (largest spread first), the normal last.
        let r = glam::DMat3::from_cols(axes[2], axes[1], axes[0]).transpose();
        let r = if r.determinant() < 0.0 {
            glam::DMat3::from_cols(-axes[2], axes[1], axes[0]).transpose()
        } else {
            r
        };
        self.bbs_mm = pts
            .iter()
            .map(|p| {
                let q = r * (*p - c);
                f32_exact(DVec3::new(q.x, q.y, 0.0))
            })
            .collect();
    }

    /// The BB centres as vectors.
    pub fn points(&self) -> Vec<DVec3> {
        self.bbs_mm.iter().map(|p| DVec3::from(*p)).collect()
    }

    /// The radius of the smallest origin-centred sphere holding every BB (mm).
    pub fn extent_mm(&self) -> f64 {
        self.points().iter().map(|p| p.length()).fold(0.0, f64::max)
    }
}

/// How far a point set spreads: a point, a line, a plane or a volume.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Spread {
    Point,
    Line,
    Plane,
    Volume,
}

fn centroid(pts: &[DVec3]) -> DVec3 {
    pts.iter().fold(DVec3::ZERO, |a, p| a + *p) / pts.len().max(1) as f64
}

/// Standard deviations along the principal axes (ascending) and the axes.
fn principal_axes(pts: &[DVec3], c: DVec3) -> ([f64; 3], [DVec3; 3]) {
    let mut m = [[0.0; 3]; 3];
    for p in pts {
        let d = (*p - c).to_array();
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] += d[i] * d[j] / pts.len() as f64;
            }
        }
    }
    let e = crate::math::symmetric_eigen(m);
    (
        e.values.map(|v| v.max(0.0).sqrt()),
        e.vectors.map(DVec3::from),
    )
}

/// The spread of a point set: a principal standard deviation below 1e-6 of the largest (and 1e-9 mm)
/// counts as flat.
pub fn spread(pts: &[DVec3]) -> Spread {
    if pts.len() < 2 {
        return Spread::Point;
    }
    let (sd, _) = principal_axes(pts, centroid(pts));
    let flat = |s: f64| s <= 1e-6 * sd[2] || s < 1e-9;
    match (flat(sd[0]), flat(sd[1]), flat(sd[2])) {
        (_, _, true) => Spread::Point,
        (_, true, _) => Spread::Line,
        (true, _, _) => Spread::Plane,
        _ => Spread::Volume,
    }
}

/// One image of a calibration: the phantom placed at `phantom_to_world` and imaged in view `view`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Placement {
    pub view: String,
    pub phantom_to_world: RigidTransform,
}

/// The most plate poses per view a calibration takes (Zhang's estimate settles within 10–20).
pub const MAX_POSES_PER_VIEW: usize = 200;

/// Where a phantom is placed for each image: a plate faces each view's source at the world origin
/// (the vertebra's place), tilted by `tilt_deg` about `poses_per_view` axes evenly spread in its plane; a
/// 3-D phantom sits once at the world origin in its own frame and is imaged in every view.
pub fn placements(
    carm: &CArm,
    phantom: &CalibrationPhantom,
    tilt_deg: f64,
    poses_per_view: usize,
) -> Result<Vec<Placement>> {
    match phantom.kind {
        PhantomKind::Volumetric => Ok(carm
            .views
            .iter()
            .map(|v| Placement {
                view: v.name.clone(),
                phantom_to_world: RigidTransform::IDENTITY,
            })
            .collect()),
        PhantomKind::Planar => {
            if !(tilt_deg.is_finite() && tilt_deg > 0.0 && tilt_deg < 80.0) {
                return Err(Error::invalid(
                    "tilt_deg",
                    format!("a plate's tilt must be in (0°, 80°), got {tilt_deg}"),
                ));
            }
            if !(2..=MAX_POSES_PER_VIEW).contains(&poses_per_view) {
                return Err(Error::invalid(
                    "poses_per_view",
                    format!(
                        "{poses_per_view}: Zhang's method needs at least 2 plate poses per view, and more \
                         than {MAX_POSES_PER_VIEW} only grow the joint refinement's memory and time (10 000 poses \
                         per view once asked for a 115 GB allocation)"
                    ),
                ));
            }
            let mut out = Vec::new();
            for v in &carm.views {
                let centre = v.world_to_camera.apply(DVec3::ZERO);
                for j in 0..poses_per_view {
                    let phi = std::f64::consts::TAU * j as f64 / poses_per_view as f64;
                    let axis = DVec3::new(phi.cos(), phi.sin(), 0.0);
                    let to_camera =
                        RigidTransform::new(rotation_exp(axis * tilt_deg.to_radians()), centre);
                    out.push(Placement {
                        view: v.name.clone(),
                        phantom_to_world: v.world_to_camera.inverse().compose(&to_camera),
                    });
                }
            }
            Ok(out)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapes_are_classified_and_bad_phantoms_named() {
        assert_eq!(
            CalibrationPhantom::default_plate().kind,
            PhantomKind::Planar
        );
        assert_eq!(CalibrationPhantom::default_plate().bbs_mm.len(), 100);
        assert_eq!(
            CalibrationPhantom::default_helix().kind,
            PhantomKind::Volumetric
        );
        let e =
            CalibrationPhantom::from_json_str(r#"{"bbs_mm": [[0,0,0],[1,1,1],[2,2,2]]}"#, "f.json")
                .unwrap_err()
                .to_string();
        assert!(e.contains("f.json") && e.contains("collinear"), "{e}");
        let e = CalibrationPhantom::from_json_str(
            r#"{"bbs_mm": [[0,0,0],[1,0,0],[0,1,0],[0,0,1],[1,1,1]]}"#,
            "f.json",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("at least 6"), "{e}");
        // A tilted plane is planar, moved into z = 0 with its spacing kept.
        let tilted = r#"{"bbs_mm": [[0,0,0],[10,0,10],[0,10,0],[10,10,10],[5,5,5]]}"#;
        let p = CalibrationPhantom::from_json_str(tilted, "t.json").unwrap();
        assert_eq!(p.kind, PhantomKind::Planar);
        assert!(p.bbs_mm.iter().all(|b| b[2] == 0.0));
        let d = (DVec3::from(p.bbs_mm[0]) - DVec3::from(p.bbs_mm[2])).length();
        assert!((d - 10.0).abs() < 1e-5, "{d}");
    }
}
