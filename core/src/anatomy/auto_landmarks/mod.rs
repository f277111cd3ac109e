//! Landmarks of a vertebra derived from its closed outer surface alone (no structure labels, any pose).
//!
//! **Frame.** The left–right axis is the normal of the mid-sagittal symmetry plane: of the three
//! principal axes of the solid's inertia (a bilaterally symmetric solid has its symmetry normal among
//! them), the one whose mirror image of the surface lies closest to the surface. Posterior points from
//! the solid centroid to the farthest surface point in the sagittal plane (the spinous process); the body
//! is the most anterior solid interval of the mid-sagittal line through the centroid. The superior axis is
//! refined as the area-weighted mean normal of the body's flat end faces (normals within 30° of the
//! rough axis, anterior of the posterior body wall, within 10 mm of the mid-sagittal plane), and its sign
//! chosen so the pedicles lie superior of the spinous tip (pedicles join the upper half of a lumbar body,
//! the spinous process slopes caudally). Right = anterior × superior (RAS+ is right-handed).
//!
//! **Landmarks** (names as in [`crate::anatomy::vertebra`]):
//! * `center`: midpoint of the body's anterior–posterior chord on the mid-sagittal line, at the midpoint
//!   of its superior–inferior chord;
//! * `superior_endplate`/`inferior_endplate`: ends of the superior–inferior chord through the centre;
//! * `corner_*`: support points of the mid-sagittal body outline in the four 45° directions
//!   `(±anterior ± superior)/√2` (the apex of the rounded rim);
//! * `left_pedicle`/`right_pedicle`: left–right and superior–inferior position from the centroid of the
//!   narrowest coronal cross-section of each side's arch in the anterior half of the vertebral canal;
//!   the anterior–posterior position a quarter of the canal depth behind the posterior body wall (the
//!   middle of the pedicle, which spans about the anterior half of the canal's side wall);
//! * `spinous_tip`: the end of the spinous process along its own axis (the axis through the centroids of
//!   two coronal sections near the most posterior point; the tip is the centroid of the section 1 mm
//!   inside the end, moved 1 mm along the axis).

mod probes;

use glam::DVec3;

use super::landmarks::Landmarks;
use super::{TriMesh, decimate::SurfaceDistance};
use crate::math::symmetric_eigen;
use crate::{Error, Result};

pub use probes::{Section, line_intervals, section, smoothed_normals, solid_moments};

/// An estimated anatomical frame: origin on the mid-sagittal plane, unit axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VertebraFrame {
    pub origin: DVec3,
    pub right: DVec3,
    pub anterior: DVec3,
    pub superior: DVec3,
}

/// Derives the phantom's landmark set from a closed vertebra surface (see the module documentation).
pub fn auto_landmarks(mesh: &TriMesh, level: &str) -> Result<Landmarks> {
    Ok(analyse(mesh, level)?.0)
}

/// [`auto_landmarks`] with the estimated frame.
pub fn analyse(mesh: &TriMesh, level: &str) -> Result<(Landmarks, VertebraFrame)> {
    mesh.validate("mesh")?;
    let chk = mesh.check();
    if !chk.is_watertight() {
        return Err(Error::invalid(
            "mesh",
            format!("automatic landmarks need a closed surface: {chk:?}"),
        ));
    }
    let (vol, c0, cov) = solid_moments(mesh);
    if vol <= 0.0 {
        return Err(Error::invalid(
            "mesh",
            format!("encloses a non-positive volume ({vol:.1} mm³): triangles point inward"),
        ));
    }
    let lr = symmetry_normal(mesh, c0, &cov);
    let rough = rough_frame(mesh, c0, lr)?;
    let body = Body::measure(mesh, c0, lr, rough)?;
    let (p0, p1) = (pedicle(mesh, &body, 1.0)?, pedicle(mesh, &body, -1.0)?);
    let tip = spinous_tip(mesh, &body)?;
    let flip = (0.5 * (p0 + p1) - tip).dot(body.si) < 0.0;
    let si = if flip { -body.si } else { body.si };
    let right = body.ap.cross(si);
    let (top, bottom) = if flip {
        (body.bottom, body.top)
    } else {
        (body.top, body.bottom)
    };
    let (rp, lp) = if (p0 - body.centre).dot(right) > 0.0 {
        (p0, p1)
    } else {
        (p1, p0)
    };
    let corners = body_corners(mesh, &body, si)?;
    let points = [
        ("center", body.centre),
        ("superior_endplate", top),
        ("inferior_endplate", bottom),
        ("left_pedicle", lp),
        ("right_pedicle", rp),
        ("spinous_tip", tip),
        ("corner_anterior_superior", corners[0]),
        ("corner_anterior_inferior", corners[1]),
        ("corner_posterior_superior", corners[2]),
        ("corner_posterior_inferior", corners[3]),
    ];
    let lm = Landmarks {
        level: level.to_string(),
        points: points.iter().map(|(k, v)| (k.to_string(), *v)).collect(),
    };
    let frame = VertebraFrame {
        origin: body.centre,
        right,
        anterior: body.ap,
        superior: si,
    };
    Ok((lm, frame))
}

/// The principal axis whose mirror plane through the centroid maps the surface closest onto itself.
fn symmetry_normal(mesh: &TriMesh, c0: DVec3, cov: &glam::DMat3) -> DVec3 {
    // The covariance is symmetric, so its column-major array is its row-major one.
    let axes = symmetric_eigen(cov.to_cols_array_2d()).vector_columns();
    let sd = SurfaceDistance::new(mesh);
    let step = (mesh.vertices.len() / 3000).max(1);
    let score = |e: DVec3| -> f64 {
        mesh.vertices
            .iter()
            .step_by(step)
            .map(|&v| sd.distance(v - 2.0 * (v - c0).dot(e) * e))
            .sum()
    };
    let mut best = (f64::INFINITY, DVec3::X);
    for j in 0..3 {
        let e = axes.col(j).normalize();
        let s = score(e);
        if s < best.0 {
            best = (s, e);
        }
    }
    best.1
}

/// Rough anterior axis: from the farthest sagittal-plane point (the spinous process) to the centroid.
fn rough_frame(mesh: &TriMesh, c0: DVec3, lr: DVec3) -> Result<DVec3> {
    let proj = |v: DVec3| {
        let d = v - c0;
        d - d.dot(lr) * lr
    };
    let far = mesh
        .vertices
        .iter()
        .map(|&v| proj(v))
        .max_by(|a, b| a.length_squared().total_cmp(&b.length_squared()))
        .ok_or_else(|| Error::invalid("mesh", "has no vertices"))?;
    (-far)
        .try_normalize()
        .ok_or_else(|| Error::Numerical("vertebra frame: degenerate sagittal extent".into()))
}

/// The vertebral body measured on the mid-sagittal plane.
#[derive(Debug, Clone, Copy)]
struct Body {
    lr: DVec3,
    ap: DVec3,
    si: DVec3,
    centre: DVec3,
    top: DVec3,
    bottom: DVec3,
    /// Anterior–posterior chord ends, signed along `ap` from `centre`.
    y_ant: f64,
    y_post: f64,
    /// Canal depth: posterior body wall to the anterior face of the arch (mm).
    canal_mm: f64,
}

impl Body {
    fn measure(mesh: &TriMesh, c0: DVec3, lr: DVec3, ap0: DVec3) -> Result<Body> {
        let ap0 = (ap0 - ap0.dot(lr) * lr).normalize();
        // Normals smoothed over a few edges: a tilted endplate's voxel staircase (an unsmoothed CT
        // label surface) would otherwise pull the axis onto the voxel grid's.
        let normals = smoothed_normals(mesh);
        // The rough axis points at the spinous process, which can slope far caudally (≈ 40° on a real
        // L1): first turn it to the body's principal face direction nearest to it.
        let si1 = body_face_axis(mesh, &normals, c0, lr, ap0)?;
        let ap1 = si1.cross(lr) * si1.cross(lr).dot(ap0).signum();
        let EndFaces { n_sum, up, down } = EndFaces::measure(mesh, &normals, c0, lr, ap1)?;
        let si = (n_sum - n_sum.dot(lr) * lr).normalize();
        let ap = si.cross(lr) * si.cross(lr).dot(ap1).signum();
        let mut z_mid = 0.5 * (up.0 / up.1 + down.0 / down.1);
        let mut centre = c0 + z_mid * si;
        let (mut y_ant, mut y_post, mut lam) = (0.0, 0.0, None);
        for _ in 0..2 {
            let q = c0 + z_mid * si;
            let iv = line_intervals(mesh, q, ap);
            let k = iv.len().checked_sub(1).ok_or_else(|| no_body("anterior"))?;
            let (t0, t1) = iv[k];
            lam = k.checked_sub(1).map(|j| iv[j].1);
            let y_c = 0.5 * (t0 + t1);
            let zq = q + y_c * ap;
            let vert = line_intervals(mesh, zq, si);
            let &(z0, z1) = vert
                .iter()
                .find(|(a, b)| *a <= 0.0 && *b >= 0.0)
                .ok_or_else(|| no_body("superior–inferior"))?;
            centre = zq + 0.5 * (z0 + z1) * si;
            z_mid += 0.5 * (z0 + z1);
            (y_ant, y_post) = (t1 - y_c, t0 - y_c);
            lam = lam.map(|l| l - y_c);
        }
        let half_h = {
            let vert = line_intervals(mesh, centre, si);
            let &(z0, z1) = vert
                .iter()
                .find(|(a, b)| *a <= 0.0 && *b >= 0.0)
                .ok_or_else(|| no_body("superior–inferior"))?;
            (z0, z1)
        };
        // The arch may miss the body's mid-height on the mid-sagittal line (laminae slope caudally):
        // then the nearest height over the body's where it is met.
        let lam = lam
            .or_else(|| arch_front(mesh, centre, ap, si, y_post, half_h))
            .ok_or_else(|| {
                Error::Numerical("vertebra frame: no posterior arch behind the body".into())
            })?;
        Ok(Body {
            lr,
            ap,
            si,
            centre,
            top: centre + half_h.1 * si,
            bottom: centre + half_h.0 * si,
            y_ant,
            y_post,
            canal_mm: y_post - lam,
        })
    }

    fn local(&self, p: DVec3) -> DVec3 {
        let d = p - self.centre;
        DVec3::new(d.dot(self.lr), d.dot(self.ap), d.dot(self.si))
    }
}

/// The anterior face of the posterior arch on the mid-sagittal line (mm along `ap` from `centre`),
/// searched 1 mm at a time above and below `centre` within the body's height `(z0, z1)`.
fn arch_front(
    mesh: &TriMesh,
    centre: DVec3,
    ap: DVec3,
    si: DVec3,
    y_post: f64,
    (z0, z1): (f64, f64),
) -> Option<f64> {
    let steps = z0.abs().max(z1).ceil() as i32;
    (1..=steps)
        .flat_map(|k| [-k, k])
        .map(f64::from)
        .filter(|&dz| dz >= z0 && dz <= z1)
        .find_map(|dz| {
            line_intervals(mesh, centre + dz * si, ap)
                .into_iter()
                .rev()
                .find(|&(_, t1)| t1 < y_post - 1.0)
                .map(|(_, t1)| t1)
        })
}

/// Of the two principal directions of the body's surface normals in the mid-sagittal plane (the
/// eigenvectors of `Σ A n nᵀ` over the faces anterior of the posterior wall along `ap0`, within 10 mm of
/// the plane: for a body's sagittal outline, its endplate and wall directions), the one nearer to
/// `lr × ap0`: the endplate normal whenever the rough axis is within 45° of it.
fn body_face_axis(
    mesh: &TriMesh,
    normals: &[DVec3],
    c0: DVec3,
    lr: DVec3,
    ap0: DVec3,
) -> Result<DVec3> {
    let body0 = most_anterior(mesh, c0, ap0)?;
    let si0 = lr.cross(ap0);
    let (mut uu, mut uv, mut vv) = (0.0, 0.0, 0.0);
    for (i, n) in normals.iter().enumerate() {
        let [a, b, c] = mesh.corners(i);
        let g = (a + b + c) / 3.0 - c0;
        if g.dot(ap0) < body0.0 + 2.0 || g.dot(lr).abs() > 10.0 {
            continue;
        }
        let area = 0.5 * (b - a).cross(c - a).length();
        let (u, v) = (n.dot(ap0), n.dot(si0));
        uu += area * u * u;
        uv += area * u * v;
        vv += area * v * v;
    }
    // Principal angle from the ap0 axis: tan 2θ = 2·uv / (uu − vv); the other is θ + 90°.
    let theta = 0.5 * (2.0 * uv).atan2(uu - vv);
    let d1 = (theta.cos(), theta.sin());
    let d2 = (-theta.sin(), theta.cos());
    let (u, v) = if d1.1.abs() >= d2.1.abs() { d1 } else { d2 };
    let si = (u * ap0 + v * si0) * v.signum();
    si.try_normalize()
        .ok_or_else(|| Error::Numerical("vertebra frame: no body faces to orient by".into()))
}

/// The flat superior/inferior faces of the body: their area-weighted normal sum (signed to point along
/// the axis) and, per side, the area-weighted height along the axis tried and the area.
struct EndFaces {
    n_sum: DVec3,
    up: (f64, f64),
    down: (f64, f64),
}

impl EndFaces {
    /// Faces whose normal is within 30° of `lr × ap`, anterior of the body's posterior wall along `ap`
    /// (the most anterior interval from `c0`) and within 10 mm of the mid-sagittal plane.
    fn measure(
        mesh: &TriMesh,
        normals: &[DVec3],
        c0: DVec3,
        lr: DVec3,
        ap: DVec3,
    ) -> Result<EndFaces> {
        let body0 = most_anterior(mesh, c0, ap)?;
        let si0 = lr.cross(ap);
        let mut f = EndFaces {
            n_sum: DVec3::ZERO,
            up: (0.0, 0.0),
            down: (0.0, 0.0),
        };
        for (i, n) in normals.iter().enumerate() {
            let [a, b, c] = mesh.corners(i);
            let g = (a + b + c) / 3.0 - c0;
            if g.dot(ap) < body0.0 + 2.0 || g.dot(lr).abs() > 10.0 {
                continue;
            }
            let area = 0.5 * (b - a).cross(c - a).length();
            let cos = n.dot(si0);
            if cos.abs() < 30f64.to_radians().cos() {
                continue;
            }
            f.n_sum += area * *n * cos.signum();
            let acc = if cos > 0.0 { &mut f.up } else { &mut f.down };
            acc.0 += area * g.dot(si0);
            acc.1 += area;
        }
        if f.up.1 <= 0.0 || f.down.1 <= 0.0 {
            return Err(Error::Numerical(
                "vertebra frame: no flat superior/inferior body faces found".into(),
            ));
        }
        Ok(f)
    }
}

fn no_body(what: &str) -> Error {
    Error::Numerical(format!(
        "vertebra frame: the mid-sagittal {what} line misses the vertebral body"
    ))
}

/// The most anterior solid interval along `q + t·ap`.
fn most_anterior(mesh: &TriMesh, q: DVec3, ap: DVec3) -> Result<(f64, f64)> {
    line_intervals(mesh, q, ap)
        .last()
        .copied()
        .ok_or_else(|| no_body("anterior"))
}

/// One pedicle (`side` = ±1 along the symmetry normal as estimated).
fn pedicle(mesh: &TriMesh, body: &Body, side: f64) -> Result<DVec3> {
    let (start, end) = (body.y_post - 0.5, body.y_post - body.canal_mm / 2.0);
    let mut best: Option<Section> = None;
    let mut y = start;
    while y >= end {
        let o = body.centre + y * body.ap;
        let s = section(mesh, o, body.ap, |m| side * body.local(m).x > 1.0);
        if s.area > 1.0 && best.is_none_or(|b| s.area < b.area) {
            best = Some(s);
        }
        y -= 0.25;
    }
    let s = best.ok_or_else(|| {
        Error::Numerical("vertebra frame: no pedicle behind the vertebral body".into())
    })?;
    let l = body.local(s.centroid);
    let y_ped = body.y_post - body.canal_mm / 4.0;
    Ok(body.centre + l.x * body.lr + y_ped * body.ap + l.z * body.si)
}

/// The end of the spinous process along its own axis.
fn spinous_tip(mesh: &TriMesh, body: &Body) -> Result<DVec3> {
    let y_min = mesh
        .vertices
        .iter()
        .map(|&v| body.local(v).y)
        .fold(f64::INFINITY, f64::min);
    let mid = |m: DVec3| body.local(m).x.abs() < 15.0;
    let near = section(mesh, body.centre + (y_min + 4.0) * body.ap, body.ap, mid);
    let far = section(mesh, body.centre + (y_min + 10.0) * body.ap, body.ap, mid);
    if near.area <= 0.0 || far.area <= 0.0 {
        return Err(Error::Numerical(
            "vertebra frame: no spinous process at the posterior end".into(),
        ));
    }
    let axis = (near.centroid - far.centroid).normalize();
    let end = mesh
        .vertices
        .iter()
        .filter(|&&v| mid(v) && body.local(v).y < y_min + 10.0)
        .map(|&v| (v - near.centroid).dot(axis))
        .fold(f64::NEG_INFINITY, f64::max);
    let s = section(mesh, near.centroid + (end - 1.0) * axis, axis, mid);
    if s.area <= 0.0 {
        return Err(Error::Numerical(
            "vertebra frame: empty spinous section".into(),
        ));
    }
    Ok(s.centroid + axis)
}

/// Support points of the mid-sagittal body outline in the directions (±anterior ± superior)/√2:
/// anterior-superior, anterior-inferior, posterior-superior, posterior-inferior.
fn body_corners(mesh: &TriMesh, body: &Body, si: DVec3) -> Result<[DVec3; 4]> {
    let h_top = (body.top - body.centre).dot(si).abs();
    let h_bot = (body.bottom - body.centre).dot(si).abs();
    let h = h_top.max(h_bot) + 2.0;
    let pts: Vec<DVec3> = probes::section_points(mesh, body.centre, body.lr)
        .into_iter()
        .filter(|&p| {
            let l = body.local(p);
            l.y >= body.y_post - 2.0 && l.y <= body.y_ant + 2.0 && l.z.abs() <= h
        })
        .collect();
    if pts.is_empty() {
        return Err(no_body("sagittal"));
    }
    let support = |dir: DVec3| {
        pts.iter()
            .copied()
            .max_by(|a, b| {
                (*a - body.centre)
                    .dot(dir)
                    .total_cmp(&(*b - body.centre).dot(dir))
            })
            .unwrap_or(body.centre)
    };
    Ok([
        support(body.ap + si),
        support(body.ap - si),
        support(-body.ap + si),
        support(-body.ap - si),
    ])
}
