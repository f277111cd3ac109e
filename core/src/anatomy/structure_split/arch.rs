//! The posterior elements' models for [`super::split_structures`]: bars and ribbons around axes placed
//! in the landmark frame, measured from the surface by chords ([`Probe`]), and the laminar junction and
//! lamina plane found by probing the mid-sagittal line.

use glam::DVec3;

use super::{LandmarkFrame, no_body};
use crate::Result;
use crate::anatomy::auto_landmarks::line_intervals;
use crate::anatomy::{Structure, TriMesh};

/// One structure's model in the local frame: a bar of radius `radius` around a segment, or around a
/// ribbon (the segment swept `half_height` either way along `up`, between its ends) for a plate: the
/// lamina (swept along its sloping plane) or an articular process (swept across, along its width).
/// Points take the structure whose model surface is nearest.
#[derive(Debug, Clone, Copy)]
pub(super) struct Axis {
    pub(super) structure: Structure,
    pub(super) a: DVec3,
    pub(super) b: DVec3,
    pub(super) half_height: f64,
    /// The ribbon's sweep direction (unit: the superior axis, a lamina's sloping plane, or an articular
    /// process's width).
    pub(super) up: DVec3,
    pub(super) radius: f64,
    /// The cross-section's radius along `up` over `radius` (≤ 1: a part wider than tall, an elliptic bar).
    pub(super) flat: f64,
}

impl Axis {
    /// Signed distance (approximate) from `p` to the model's surface, a bar with flat ends: a part
    /// does not reach past the ends of its axis, where the next part begins.
    pub(super) fn distance(&self, p: DVec3) -> f64 {
        let ab = self.b - self.a;
        let len = ab.length().max(1e-9);
        let t = (p - self.a).dot(ab) / (len * len);
        let d = p - (self.a + t * ab);
        let h = d.dot(self.up);
        let radial = (d - h * self.up
            + (h.abs() - self.half_height).max(0.0) / self.flat * self.up)
            .length();
        let (r, e) = (radial - self.radius, (t - 0.5).abs() * len - 0.5 * len);
        glam::DVec2::new(r.max(0.0), e.max(0.0)).length() + r.max(e).min(0.0)
    }
}

/// The first solid interval (along the anterior axis, mm) behind the canal — more than 3 mm behind the
/// posterior wall at `wall_y` — on the mid-sagittal line at height `z`.
fn behind_canal(mesh: &TriMesh, f: &LandmarkFrame, wall_y: f64, z: f64) -> Option<(f64, f64)> {
    let q = f.world(DVec3::new(0.0071, 0.0, z + 0.0113));
    line_intervals(mesh, q, f.anterior)
        .into_iter()
        .rev()
        .find(|&(_, t1)| t1 < wall_y - 3.0)
}

/// The laminar junction: the first solid behind the canal on the mid-sagittal line, searched from the
/// pedicles' height downward to the inferior endplate; with the arch's height there (mm).
pub(super) fn laminar_junction(
    mesh: &TriMesh,
    f: &LandmarkFrame,
    wall_y: f64,
    z_top: f64,
    z_bottom: f64,
) -> Result<(DVec3, f64)> {
    let mut z = z_top;
    while z >= z_bottom {
        if let Some((t0, t1)) = behind_canal(mesh, f, wall_y, z) {
            let y = t1 - 3.0f64.min(0.5 * (t1 - t0));
            // Centre the junction on the arch's height there.
            let v = line_intervals(mesh, f.world(DVec3::new(0.0071, y, 0.0)), f.superior);
            let (lo, hi) = v
                .iter()
                .copied()
                .find(|(a, b)| *a <= z && *b >= z)
                .unwrap_or((z, z));
            return Ok((DVec3::new(0.0, y, 0.5 * (lo + hi)), hi - lo));
        }
        z -= 1.0;
    }
    Err(no_body(
        "no posterior arch behind the canal on the mid-sagittal line",
    ))
}

/// The direction in which the lamina's plane rises (unit, in the sagittal plane): from the canal's
/// posterior border (the anterior face of the arch on the mid-sagittal line) a quarter of the arch's
/// height above and below the junction; the superior axis where a probe misses.
pub(super) fn lamina_plane(
    mesh: &TriMesh,
    f: &LandmarkFrame,
    wall_y: f64,
    junction: DVec3,
    height: f64,
) -> DVec3 {
    let border = |z: f64| behind_canal(mesh, f, wall_y, z).map(|(_, t1)| t1);
    let dz = 0.25 * height;
    match (border(junction.z + dz), border(junction.z - dz)) {
        (Some(a), Some(b)) if (a - b).abs() < 2.0 * dz => {
            DVec3::new(0.0, a - b, 2.0 * dz).normalize()
        }
        _ => DVec3::Z,
    }
}

/// Chords of the solid through points of the local frame.
pub(super) struct Probe<'a> {
    pub(super) mesh: &'a TriMesh,
    pub(super) f: &'a LandmarkFrame,
}

impl Probe<'_> {
    /// The solid interval along local direction `d` through local point `p`, in mm from `p`.
    fn interval(&self, p: DVec3, d: DVec3) -> Option<(f64, f64)> {
        let d = d.try_normalize()?;
        let dw = d.x * self.f.right + d.y * self.f.anterior + d.z * self.f.superior;
        // A small offset (fixed in the frame) keeps the line off the voxel grid's vertices and edges.
        let q = self.f.world(p + 0.0091 * d.any_orthonormal_vector());
        line_intervals(self.mesh, q, dw)
            .into_iter()
            .find(|(a, b)| *a <= 0.0 && *b >= 0.0)
    }

    /// Length of the chord along `d` through `p` (0 outside the solid).
    pub(super) fn chord(&self, p: DVec3, d: DVec3) -> f64 {
        self.interval(p, d).map_or(0.0, |(a, b)| b - a)
    }

    /// Distance from `p` to the surface along `d` (0 outside the solid).
    pub(super) fn reach(&self, p: DVec3, d: DVec3) -> f64 {
        self.interval(p, d).map_or(0.0, |(_, b)| b)
    }

    /// The bar model of the part from `a` to `b`, measured at its middle: radius half its horizontal
    /// thickness across the axis, and — for a plate taller than thick — a ribbon of its height
    /// (`height`, or the vertical chord there) less that radius. A steep axis is a plain bar (an
    /// articular process whose middle misses the solid, see [`Probe::plate`]).
    pub(super) fn bar(
        &self,
        structure: Structure,
        a: DVec3,
        b: DVec3,
        height: Option<f64>,
    ) -> Axis {
        self.bar_at(structure, a, b, height, 0.5)
    }

    /// The model of a steep plate from `a` to `b` (an articular process): measured in the horizontal
    /// section through its middle, its thickness (the shortest horizontal chord) gives the radius, its
    /// width (the chord across that) the ribbon's half-height along the width's direction; the axis is
    /// moved to the centre of both chords. A middle outside the solid gives the plain bar.
    pub(super) fn plate(&self, structure: Structure, a: DVec3, b: DVec3) -> Axis {
        let m = a.lerp(b, 0.5);
        let dir_at = |k: usize| {
            let t = k as f64 * std::f64::consts::PI / 12.0;
            DVec3::new(t.cos(), t.sin(), 0.0)
        };
        let thinnest = (0..12)
            .filter_map(|k| self.interval(m, dir_at(k)).map(|iv| (dir_at(k), iv)))
            .min_by(|p, q| (p.1.1 - p.1.0).total_cmp(&(q.1.1 - q.1.0)));
        let Some((dt, (t0, t1))) = thinnest else {
            return self.bar(structure, a, b, None);
        };
        let dw = DVec3::Z.cross(dt);
        let (w0, w1) = self.interval(m, dw).unwrap_or((t0, t1));
        let shift = 0.5 * (t0 + t1) * dt + 0.5 * (w0 + w1) * dw;
        let radius = 0.5 * (t1 - t0);
        Axis {
            structure,
            a: a + shift,
            b: b + shift,
            half_height: (0.5 * (w1 - w0) - radius).max(0.0),
            up: dw,
            radius,
            flat: 1.0,
        }
    }

    /// [`Probe::bar`] measured at fraction `at` of the way from `a` to `b`.
    pub(super) fn bar_at(
        &self,
        structure: Structure,
        a: DVec3,
        b: DVec3,
        height: Option<f64>,
        at: f64,
    ) -> Axis {
        let m = a.lerp(b, at);
        let dir = b - a;
        let flat = DVec3::new(dir.x, dir.y, 0.0);
        let steep = flat.length() < dir.z.abs();
        let across = if steep {
            DVec3::X
        } else {
            flat.cross(DVec3::Z).normalize_or_zero()
        };
        let radius = 0.5 * self.chord(m, across);
        let half_height = if steep {
            0.0
        } else {
            (0.5 * height.unwrap_or_else(|| self.chord(m, DVec3::Z)) - radius).max(0.0)
        };
        Axis {
            structure,
            a,
            b,
            half_height,
            up: DVec3::Z,
            radius,
            flat: 1.0,
        }
    }
}
