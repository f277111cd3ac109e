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
//! kidney-shaped endplate; a point is body where `y ≥ y_w(x) − 1 mm`; beyond the lower body's lateral
//! reach (an endplate rim wider than the waist, or a pedicle bulging past the body's side) the wall of
//! the outermost chord on that side applies. Body triangles facing up (down) within 4 mm of the superior
//! (inferior) endplate height are the superior (inferior) endplate.
//!
//! **Posterior elements.** Each part of the neural arch is a segment (its axis) in the frame, placed
//! from landmarks and the surface. A pedicle's axis passes through its landmark, converging anteriorly
//! as its medial wall does (the wall's slope measured 2 mm either side of the landmark), from the
//! posterior wall to where the canal's lateral wall turns medially into the lamina (at least as far
//! behind the landmark as the wall is before it); it does not rise above the superior endplate. Each
//! lamina runs from its pedicle's end to the laminar junction (the first solid behind the canal on the
//! mid-sagittal line, found by probing), a ribbon in the plane the canal's posterior border slopes in
//! there (laminae slope down and back); the spinous process from the junction to `spinous_tip`; a
//! transverse process from the pedicle–lamina junction to the most lateral surface point on its side; a
//! superior articular process from the top of the pedicle's end to the highest point of the arch on its
//! side, an inferior one from the lamina's lower border to the lowest point of the arch on its side (off
//! the midline, where the spinous process is). The articular processes are plates: in the horizontal
//! section through the middle of their axis, the shortest chord is their thickness and the chord across
//! it their width, and the axis moves to the centre of both. A posterior triangle takes the structure of
//! the nearest model (a bar, or a ribbon for a plate, around its axis; [`arch`]). Nothing here assumes
//! a primitive shape, so the split follows the anatomy as the landmarks and the surface place it.

mod arch;

use glam::DVec3;

use super::auto_landmarks::{line_intervals, smoothed_normals};
use super::landmarks::Landmarks;
use super::{Structure, TriMesh};
use crate::{Error, Result};
use arch::{Axis, Probe, lamina_plane, laminar_junction};

/// Margin by which a point behind the measured posterior wall still counts as body (mm).
const WALL_MARGIN_MM: f64 = 1.5;
/// Height band above/below which body faces are endplates (mm from the endplate landmark).
const ENDPLATE_BAND_MM: f64 = 4.0;
/// Cosine of the largest tilt of an endplate face from the superior axis.
const ENDPLATE_COS: f64 = 0.7;
/// Steepest convergence of a pedicle's axis measured from its medial wall (mm lateral per mm posterior).
const MAX_PEDICLE_SLOPE: f64 = 0.8;
/// Farthest a pedicle reaches behind its landmark (mm).
const MAX_PEDICLE_HALF_LENGTH_MM: f64 = 15.0;
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
        DVec3::new(
            d.dot(self.right),
            d.dot(self.anterior),
            d.dot(self.superior),
        )
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
            return Err(no_body(
                "the mid-sagittal chord of the lower body is under 5 mm",
            ));
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

    /// The wall at `x`, or beyond the lower body's lateral reach (an endplate rim wider than the
    /// waist) at its outermost measured chord on that side.
    fn at_or_beyond(&self, x: f64) -> f64 {
        if let Some(y) = self.at(x) {
            return y;
        }
        let centre = (-self.x0).round() as usize;
        let side: Box<dyn Iterator<Item = &Option<f64>>> = if x < 0.0 {
            Box::new(self.y[..centre].iter())
        } else {
            Box::new(self.y[centre..].iter().rev())
        };
        side.flatten().next().copied().unwrap_or(self.midline)
    }

    /// True when local point `l` is in the body: anterior of the wall at its `x`.
    fn contains(&self, l: DVec3) -> bool {
        l.y >= self.at_or_beyond(l.x) - WALL_MARGIN_MM
    }
}

fn no_body(what: &str) -> Error {
    Error::Numerical(format!("structure split: {what}"))
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
    let lamina_up = lamina_plane(mesh, &f, wall.midline, junction, arch_height);
    let mut axes = vec![probe.bar(Structure::Spinous, junction, tip, None)];
    for (side, ped, s) in [
        (-1.0, ped_l, Structure::PedicleLeft),
        (1.0, ped_r, Structure::PedicleRight),
    ] {
        // A pedicle's half-width is its reach to the canal (laterally it runs into the transverse
        // process); taller than wide, it is a ribbon.
        let w = probe.reach(ped, -side * DVec3::X);
        // Its axis converges anteriorly as its medial wall does: the wall's lateral shift per mm
        // posterior, measured 2 mm either side of the landmark.
        let k = ((probe.reach(ped + 2.0 * DVec3::Y, -side * DVec3::X)
            - probe.reach(ped - 2.0 * DVec3::Y, -side * DVec3::X))
            / 4.0)
            .clamp(0.0, MAX_PEDICLE_SLOPE);
        let on_axis = |y: f64| DVec3::new(ped.x - side * k * (y - ped.y), y, ped.z);
        let start = on_axis(wall.at(ped.x).unwrap_or(wall.midline));
        // The pedicle ends where the canal's lateral wall turns medially into the lamina: the reach
        // from its axis to the canal grows past twice the isthmus's.
        let mut y_end = ped.y;
        while y_end > ped.y - MAX_PEDICLE_HALF_LENGTH_MM {
            let r = probe.reach(on_axis(y_end - 0.5), -side * DVec3::X);
            if r <= 0.0 || r > 2.0 * w {
                break;
            }
            y_end -= 0.5;
        }
        let end = on_axis(y_end.min(2.0 * ped.y - wall.midline));
        // It joins the upper body below the superior endplate (above that its landmark's vertical
        // chord runs into the superior articular process); wider than tall, it is an elliptic bar.
        let v = (0.5 * probe.chord(ped, DVec3::Z))
            .min(sup.z - ped.z)
            .max(0.5);
        axes.push(Axis {
            structure: s,
            a: start,
            b: end,
            half_height: (v - w).max(0.0),
            up: DVec3::Z,
            radius: w,
            flat: (v / w).min(1.0),
        });
        // The lamina's height is the arch's at the junction, its plane sloping as the canal's
        // posterior border does there: lower on the lamina the inferior articular processes continue
        // it downward.
        let lamina_start = DVec3::new(end.x, end.y, junction.z);
        let mut lamina = probe.bar(Structure::Lamina, lamina_start, junction, Some(arch_height));
        lamina.up = lamina_up;
        axes.push(lamina);
        let posterior = |v: &&DVec3| v.y < wall.midline - 2.0;
        let off_midline = |v: &&DVec3| side * v.x > 0.35 * ped.x.abs();
        // The extreme of the arch on this side along `key`: the centroid of the surface within 1 mm of
        // it (a voxel surface has many vertices tied for the extreme).
        let pick = |key: &dyn Fn(&DVec3) -> f64| {
            let arch = || verts.iter().filter(posterior).filter(off_midline);
            let top = arch().map(key).fold(f64::NEG_INFINITY, f64::max);
            let (sum, n) = arch()
                .filter(|v| key(v) >= top - 1.0)
                .fold((DVec3::ZERO, 0usize), |(s, n), v| (s + *v, n + 1));
            (n > 0).then(|| sum / n as f64)
        };
        let lateral =
            pick(&|v| side * v.x).ok_or_else(|| no_body("no posterior element on a side"))?;
        let highest = pick(&|v| v.z).unwrap_or(end);
        let lowest = pick(&|v| -v.z).unwrap_or(end);
        // The transverse process arises at the pedicle–lamina junction.
        let root = end;
        // Measured in its lateral part, clear of the articular processes above its root.
        axes.push(probe.bar_at(Structure::Transverse, root, lateral, None, 0.7));
        // The superior articular process rises from the top of the pedicle's end; the inferior one
        // hangs from the lamina's lower border.
        let top = end + 0.25 * probe.chord(ped, DVec3::Z) * DVec3::Z;
        axes.push(probe.plate(Structure::Articular, top, highest));
        let below = 0.5 * (lamina_start + junction) - lamina.half_height * lamina.up;
        axes.push(probe.plate(Structure::Articular, below, lowest));
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
