//! Structure labels for an unlabelled vertebra surface (a CT label's isosurface) from its landmarks:
//! body (with its superior and inferior endplates), left and right pedicles, laminae, spinous process,
//! transverse processes and articular processes — the phantom's [`Structure`] set — one per triangle.
//!
//! **Frame.** From the landmark set (automatic or given, names of [`crate::anatomy::vertebra`]): origin at
//! `center`; superior along `inferior_endplate → superior_endplate`; right along `left_pedicle →
//! right_pedicle` made orthogonal to it; anterior = superior × right (RAS+ is right-handed). Local
//! coordinates `(x, y, z)` are right, anterior, superior.
//!
//! **Body.** The vertebral body is everything anterior of its posterior wall. The wall is measured on the
//! surface: lines along the anterior axis through the lower half of the body (where no pedicle joins it)
//! give the wall's position `y_w(x)` across the body's width, following the posterior concavity of a
//! kidney-shaped endplate; a point is body where `y ≥ y_w(x) − 1 mm` (the midline's wall where the lower
//! body does not reach `x`). Body triangles facing up (down) within 4 mm of the superior (inferior) endplate height are
//! the superior (inferior) endplate.
//!
//! **Posterior elements.** Each part of the neural arch is a segment (its axis) in the frame, placed
//! from landmarks and the surface: a pedicle runs from the posterior wall through its landmark to as far
//! behind it again (the landmark is the pedicle's middle); each lamina runs from its pedicle's end to the
//! laminar junction (the first solid behind the canal on the mid-sagittal line, found by probing); the
//! spinous process from the junction to `spinous_tip`; a transverse process from the pedicle–lamina
//! junction to the most lateral surface point on its side; a superior articular process from the pedicle's
//! end to the highest point of the arch on its side, an inferior one from the middle of the lamina to the
//! lowest point of the arch on its side (off the midline, where the spinous process is). A posterior
//! triangle takes the structure of the nearest axis. Nothing here assumes a primitive shape, so the
//! split follows the anatomy as the landmarks and the surface place it.

use glam::DVec3;

use super::auto_landmarks::{line_intervals, smoothed_normals};
use super::landmarks::Landmarks;
use super::{Structure, TriMesh};
use crate::{Error, Result};

/// Margin by which a point behind the measured posterior wall still counts as body (mm).
const WALL_MARGIN_MM: f64 = 1.0;
/// Height band above/below which body faces are endplates (mm from the endplate landmark).
const ENDPLATE_BAND_MM: f64 = 4.0;
/// Cosine of the largest tilt of an endplate face from the superior axis.
const ENDPLATE_COS: f64 = 0.7;
/// Lateral reach of the posterior-wall probes (mm from the midline).
const WALL_PROBE_HALF_WIDTH_MM: f64 = 45.0;

/// The vertebra's anatomical frame from its landmarks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LandmarkFrame {
    pub origin: DVec3,
    pub right: DVec3,
    pub anterior: DVec3,
    pub superior: DVec3,
}

impl LandmarkFrame {
    /// The frame of a landmark set (see the module documentation); errors name the missing landmark.
    pub fn from_landmarks(lm: &Landmarks) -> Result<LandmarkFrame> {
        let get = |n: &str| {
            lm.get(n).ok_or_else(|| {
                Error::invalid(
                    "landmarks",
                    format!(
                        "level {}: the structure split needs landmark {n:?} (has {:?})",
                        lm.level,
                        lm.points.keys().collect::<Vec<_>>()
                    ),
                )
            })
        };
        let origin = get("center")?;
        let degenerate = |what: &str| {
            Error::invalid(
                "landmarks",
                format!("level {}: {what} coincide, no frame", lm.level),
            )
        };
        let superior = (get("superior_endplate")? - get("inferior_endplate")?)
            .try_normalize()
            .ok_or_else(|| degenerate("the endplate landmarks"))?;
        let r0 = get("right_pedicle")? - get("left_pedicle")?;
        let right = (r0 - r0.dot(superior) * superior)
            .try_normalize()
            .ok_or_else(|| degenerate("the pedicle landmarks (along the superior axis)"))?;
        let anterior = superior.cross(right);
        let f = LandmarkFrame {
            origin,
            right,
            anterior,
            superior,
        };
        if f.local(get("spinous_tip")?).y >= 0.0 {
            return Err(Error::invalid(
                "landmarks",
                format!(
                    "level {}: spinous_tip is not posterior of center in the frame the endplates and \
                     pedicles give (are left and right pedicles swapped?)",
                    lm.level
                ),
            ));
        }
        Ok(f)
    }

    /// Local coordinates (right, anterior, superior) of a world point.
    pub fn local(&self, p: DVec3) -> DVec3 {
        let d = p - self.origin;
        DVec3::new(d.dot(self.right), d.dot(self.anterior), d.dot(self.superior))
    }

    /// The world point of local coordinates.
    pub fn world(&self, l: DVec3) -> DVec3 {
        self.origin + l.x * self.right + l.y * self.anterior + l.z * self.superior
    }
}

/// The posterior wall `y_w(x)` of the body, sampled every 1 mm across its width.
struct Wall {
    x0: f64,
    y: Vec<Option<f64>>,
    midline: f64,
}

impl Wall {
    fn measure(mesh: &TriMesh, f: &LandmarkFrame, z_probe: f64) -> Result<Wall> {
        // Small offsets keep probe lines off the voxel grid's vertices and edges.
        let line = |x: f64| {
            let q = f.world(DVec3::new(x + 0.0137, 0.0, z_probe + 0.0071));
            line_intervals(mesh, q, f.anterior)
        };
        let mid = line(0.0);
        let &(mid_post, mid_ant) = mid
            .iter()
            .find(|(a, b)| *a <= 0.0 && *b >= 0.0)
            .or(mid.last())
            .ok_or_else(|| no_body("the mid-sagittal line through the lower body misses it"))?;
        if mid_ant - mid_post < 5.0 {
            return Err(no_body("the mid-sagittal chord of the lower body is under 5 mm"));
        }
        let n = (2.0 * WALL_PROBE_HALF_WIDTH_MM) as usize + 1;
        let x0 = -WALL_PROBE_HALF_WIDTH_MM;
        let y = (0..n)
            .map(|i| {
                let x = x0 + i as f64;
                // The body's chord: the most anterior solid interval reaching anterior of the midline wall.
                line(x)
                    .last()
                    .filter(|(a, b)| *b > mid_post && b - a > 3.0)
                    .map(|&(a, _)| a)
            })
            .collect();
        Ok(Wall {
            x0,
            y,
            midline: mid_post,
        })
    }

    /// The wall at `x`, where the lower body's chord reaches it.
    fn at(&self, x: f64) -> Option<f64> {
        let i = (x - self.x0).round();
        if i < 0.0 {
            return None;
        }
        self.y.get(i as usize).copied().flatten()
    }

    /// True when local point `l` is in the body: anterior of the wall at its `x`, or of the wall at the
    /// midline where the lower body does not reach (an endplate rim wider than the waist).
    fn contains(&self, l: DVec3) -> bool {
        l.y >= self.at(l.x).unwrap_or(self.midline) - WALL_MARGIN_MM
    }
}

fn no_body(what: &str) -> Error {
    Error::Numerical(format!("structure split: {what}"))
}

/// One structure's axis in the local frame: a segment, or a vertical ribbon (the segment swept
/// `half_height` up and down the superior axis) for a plate such as the lamina.
#[derive(Debug, Clone, Copy)]
struct Axis {
    structure: Structure,
    a: DVec3,
    b: DVec3,
    half_height: f64,
}

impl Axis {
    fn segment(structure: Structure, a: DVec3, b: DVec3) -> Axis {
        Axis {
            structure,
            a,
            b,
            half_height: 0.0,
        }
    }

    fn distance(&self, p: DVec3) -> f64 {
        let ab = self.b - self.a;
        let t = ((p - self.a).dot(ab) / ab.length_squared().max(1e-12)).clamp(0.0, 1.0);
        let d = p - (self.a + t * ab);
        let dz = (d.z.abs() - self.half_height).max(0.0);
        DVec3::new(d.x, d.y, dz).length()
    }
}

/// The laminar junction: the first solid behind the canal on the mid-sagittal line, searched from the
/// pedicles' height downward to the inferior endplate; with the arch's height there (mm).
fn laminar_junction(
    mesh: &TriMesh,
    f: &LandmarkFrame,
    wall_y: f64,
    z_top: f64,
    z_bottom: f64,
) -> Result<(DVec3, f64)> {
    let mut z = z_top;
    while z >= z_bottom {
        let q = f.world(DVec3::new(0.0071, 0.0, z + 0.0113));
        let behind = line_intervals(mesh, q, f.anterior)
            .into_iter()
            .filter(|&(_, t1)| t1 < wall_y - 3.0)
            .last();
        if let Some((t0, t1)) = behind {
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
    Err(no_body("no posterior arch behind the canal on the mid-sagittal line"))
}

/// Chords of the solid through points of the local frame.
struct Probe<'a> {
    mesh: &'a TriMesh,
    f: &'a LandmarkFrame,
}

impl Probe<'_> {
    /// The solid interval along local direction `d` through local point `p`, in mm from `p`.
    fn interval(&self, p: DVec3, d: DVec3) -> Option<(f64, f64)> {
        let dw = d.x * self.f.right + d.y * self.f.anterior + d.z * self.f.superior;
        let dw = dw.try_normalize()?;
        // A small offset keeps the line off the voxel grid's vertices and edges.
        let q = self.f.world(p) + 0.0091 * dw.any_orthonormal_vector();
        line_intervals(self.mesh, q, dw)
            .into_iter()
            .find(|(a, b)| *a <= 0.0 && *b >= 0.0)
    }

    /// Length of the chord along `d` through `p` (0 outside the solid).
    fn chord(&self, p: DVec3, d: DVec3) -> f64 {
        self.interval(p, d).map_or(0.0, |(a, b)| b - a)
    }

    /// Distance from `p` to the surface along `d` (0 outside the solid).
    fn reach(&self, p: DVec3, d: DVec3) -> f64 {
        self.interval(p, d).map_or(0.0, |(_, b)| b)
    }
}

/// Per-triangle [`Structure`] codes of a closed vertebra surface from its landmarks (see the module
/// documentation), in triangle order.
pub fn split_structures(mesh: &TriMesh, lm: &Landmarks) -> Result<Vec<u8>> {
    mesh.validate("mesh")?;
    let f = LandmarkFrame::from_landmarks(lm)?;
    let l = |n: &str| lm.get(n).map(|p| f.local(p)).unwrap_or(DVec3::ZERO);
    let (sup, inf) = (l("superior_endplate"), l("inferior_endplate"));
    let (ped_l, ped_r, tip) = (l("left_pedicle"), l("right_pedicle"), l("spinous_tip"));
    let wall = Wall::measure(mesh, &f, 0.5 * inf.z)?;
    let verts: Vec<DVec3> = mesh.vertices.iter().map(|&v| f.local(v)).collect();
    let z_ped = 0.5 * (ped_l.z + ped_r.z);
    let (junction, arch_height) = laminar_junction(mesh, &f, wall.midline, z_ped, inf.z)?;
    let probe = Probe { mesh, f: &f };
    // Plates are ribbons as tall as they are beyond their thickness, measured at their middle: the
    // spinous process across its midpoint, each lamina by the arch's height at the junction (lower on
    // the lamina the inferior articular processes continue it downward).
    let spinous_mid = 0.5 * (junction + tip);
    let spinous_half = (0.5 * probe.chord(spinous_mid, DVec3::Z)
        - 0.5 * probe.chord(spinous_mid, DVec3::X))
    .max(0.0);
    let mut axes = vec![Axis {
        half_height: spinous_half,
        ..Axis::segment(Structure::Spinous, junction, tip)
    }];
    for (side, ped, s) in [
        (-1.0, ped_l, Structure::PedicleLeft),
        (1.0, ped_r, Structure::PedicleRight),
    ] {
        let start = DVec3::new(ped.x, wall.at(ped.x).unwrap_or(wall.midline), ped.z);
        let end = DVec3::new(ped.x, 2.0 * ped.y - wall.midline, ped.z);
        // A pedicle is taller than wide: its height at the landmark beyond its half-width to the canal.
        let ped_half = (0.5 * probe.chord(ped, DVec3::Z) - probe.reach(ped, -side * DVec3::X)).max(0.0);
        axes.push(Axis {
            half_height: ped_half,
            ..Axis::segment(s, start, end)
        });
        let lamina_mid = 0.5 * (end + junction);
        let across = (junction - end).cross(DVec3::Z).normalize_or_zero();
        let lamina_half = (0.5 * arch_height - 0.5 * probe.chord(lamina_mid, across)).max(0.0);
        axes.push(Axis {
            half_height: lamina_half,
            ..Axis::segment(Structure::Lamina, end, junction)
        });
        let posterior = |v: &&DVec3| v.y < wall.midline - 2.0;
        let off_midline = |v: &&DVec3| side * v.x > 0.35 * ped.x.abs();
        let pick = |key: &dyn Fn(&DVec3) -> f64| {
            verts
                .iter()
                .filter(posterior)
                .filter(off_midline)
                .max_by(|a, b| key(a).total_cmp(&key(b)))
                .copied()
        };
        let lateral = pick(&|v| side * v.x).ok_or_else(|| no_body("no posterior element on a side"))?;
        let highest = pick(&|v| v.z).unwrap_or(end);
        let lowest = pick(&|v| -v.z).unwrap_or(end);
        let root = DVec3::new(ped.x, ped.y.min(0.5 * (ped.y + end.y)), ped.z);
        axes.push(Axis::segment(Structure::Transverse, root, lateral));
        axes.push(Axis::segment(Structure::Articular, end, highest));
        axes.push(Axis::segment(
            Structure::Articular,
            0.5 * (end + junction),
            lowest,
        ));
    }
    let normals = smoothed_normals(mesh);
    let labels = (0..mesh.triangles.len())
        .map(|i| {
            let [a, b, c] = mesh.triangles[i].map(|k| verts[k as usize]);
            let g = (a + b + c) / 3.0;
            if wall.contains(g) {
                let n = normals[i].dot(f.superior);
                let s = if n > ENDPLATE_COS && g.z > sup.z - ENDPLATE_BAND_MM {
                    Structure::SuperiorEndplate
                } else if n < -ENDPLATE_COS && g.z < inf.z + ENDPLATE_BAND_MM {
                    Structure::InferiorEndplate
                } else {
                    Structure::Body
                };
                return s as u8;
            }
            axes.iter()
                .min_by(|p, q| p.distance(g).total_cmp(&q.distance(g)))
                .map_or(Structure::Unlabelled, |x| x.structure) as u8
        })
        .collect();
    Ok(labels)
}

/// Labels `mesh`'s triangles with [`split_structures`].
pub fn label_structures(mesh: &mut TriMesh, lm: &Landmarks) -> Result<()> {
    mesh.labels = split_structures(mesh, lm)?;
    Ok(())
}

/// Automatic landmarks of a closed vertebra surface ([`super::auto_landmarks`]), with the surface
/// labelled by structure from them. A split that fails (no body chord or arch where the landmarks put
/// them) leaves the surface unlabelled; the landmarks are returned either way.
pub fn auto_landmarks_and_structures(mesh: &mut TriMesh, level: &str) -> Result<Landmarks> {
    let lm = super::auto_landmarks(mesh, level)?;
    match split_structures(mesh, &lm) {
        Ok(labels) => mesh.labels = labels,
        Err(_) => mesh.labels.clear(),
    }
    Ok(lm)
}
