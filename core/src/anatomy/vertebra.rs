//! One parametric lumbar vertebra as a smooth union of signed-distance primitives, in its local frame:
//! origin at the centre of the vertebral body, RAS+ axes (x = patient right, y = anterior, z = superior),
//! so the body is anterior and the spinous process points to −y.
//!
//! Every dimension comes from a [`MorphometryTable`] (default: `assets/morphometry/lumbar.toml`, whose
//! comments cite Panjabi et al. 1992, Zindrick et al. 1987, Zhou et al. 2000 and Panjabi et al. 1993
//! for each value). The parts:
//! * **body**: a prism over a kidney-shaped endplate (posterior wall concave), its lateral and anterior
//!   walls narrowing at mid-height (the waist), endplates concave inside a raised rim;
//! * **pedicles**: elliptic cylinders (isthmus width × height), their axes converging anteriorly at the
//!   level's transverse angle, medial walls at the interpedicular (canal) width, joining the upper body;
//! * **laminae**: plates from each pedicle's posterior end to the midline at the canal's depth, sloping
//!   down and back (inferior edge posterior);
//! * **spinous process**: a tapering plate from the spinolaminar junction, angled posteriorly and
//!   inferiorly, ending in a thickened ellipsoidal tip at the level's spinous length;
//! * **transverse processes**: tapering bars from the pedicle–lamina junction to the level's tip-to-tip
//!   span, swept slightly back (stout at L5);
//! * **articular processes**: superior and inferior plates whose facet planes turn from near-sagittal
//!   (L1) toward coronal (L5) at the table's facet angles; a level's inferior processes sit medial and
//!   posterior of the next level's superior ones, across a joint space, so adjacent levels articulate
//!   without touching.
//!
//! Parts are joined by a polynomial smooth minimum (fillets of about a quarter of `shape.blend_mm`).

use std::collections::BTreeMap;

use glam::{DMat3, DVec2, DVec3};

use super::Structure;
use super::landmarks::Landmarks;
pub use super::level::{Level, parse_levels};
use super::morphometry::{Morphometry, MorphometryTable, ShapeParams};
use super::sdf::{Frame, Placed, Shape, smooth_min};

/// A vertebra's implicit shape in its local frame.
#[derive(Debug, Clone, PartialEq)]
pub struct VertebraShape {
    pub level: Level,
    pub morphometry: Morphometry,
    pub params: ShapeParams,
    parts: Vec<(Structure, Placed)>,
    landmarks: BTreeMap<String, DVec3>,
    pedicle_targets: BTreeMap<String, DVec3>,
}

/// Where a level's superior facet joint sits (local x for the right side, y): above the medial part of
/// the pedicle, just behind its posterior end.
fn joint_centre(m: &Morphometry, s: &ShapeParams) -> DVec2 {
    DVec2::new(
        m.canal_width / 2.0 + 3.0,
        -m.endplate_depth / 2.0 - s.pedicle_length_mm - 2.0,
    )
}

/// The facet plane's outward normal (from the superior toward the inferior articular process: medial
/// and posterior) and its horizontal in-plane direction, for `side` = ±1 (right = +1) at `deg` from the
/// sagittal plane.
fn facet_axes(side: f64, deg: f64) -> (DVec3, DVec3) {
    let (s, c) = deg.to_radians().sin_cos();
    (
        DVec3::new(-side * c, -s, 0.0),
        DVec3::new(-side * s, c, 0.0),
    )
}

/// A plate centred at `centre`, `half` along (`u`, `n`, `u × n`), edges rounded by `radius` (at most
/// the smallest half-size).
fn plate(centre: DVec3, u: DVec3, n: DVec3, half: DVec3, radius: f64) -> Placed {
    Placed {
        frame: Frame {
            origin: centre,
            axes: DMat3::from_cols(u, n, u.cross(n)),
        },
        shape: Shape::RoundedBox {
            half,
            radius: radius.min(half.min_element()),
        },
    }
}

/// A tapered bar from `start` to `end` (end faces centred on them), half-sizes across and along `up`
/// going from `h0` to `h1`, edges rounded by `radius` (at most the smallest half-size).
fn bar(start: DVec3, end: DVec3, up: DVec3, h0: DVec2, h1: DVec2, radius: f64) -> Placed {
    let radius = radius.min(h0.min_element()).min(h1.min_element());
    Placed {
        frame: Frame::along(start, end, up),
        shape: Shape::TaperedBox {
            half_len: (end - start).length() / 2.0,
            start: h0,
            end: h1,
            radius,
        },
    }
}

/// The point where `f` crosses zero on the segment `inside + t·dir`, `t ∈ [0, reach]` (bisection;
/// `f(inside) < 0 < f(inside + reach·dir)`).
fn surface_along(f: impl Fn(DVec3) -> f64, inside: DVec3, dir: DVec3, reach: f64) -> DVec3 {
    let (mut lo, mut hi) = (0.0, reach);
    debug_assert!(f(inside) < 0.0 && f(inside + dir * reach) > 0.0);
    for _ in 0..60 {
        let mid = (lo + hi) / 2.0;
        if f(inside + dir * mid) < 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    inside + dir * ((lo + hi) / 2.0)
}

impl VertebraShape {
    /// The shape of `level` with the dimensions of `table`.
    pub fn new(level: Level, table: &MorphometryTable) -> VertebraShape {
        let m = *table.level(level);
        let s = table.shape;
        // The next level's superior facets meet this level's inferior ones (L5: its own geometry).
        let below = Level::ALL
            .get(level.index() + 1)
            .map_or(m, |l| *table.level(*l));
        let (d, h) = (m.endplate_depth / 2.0, m.body_height / 2.0);
        let mut parts = vec![(
            Structure::Body,
            Placed {
                frame: Frame::at(DVec3::ZERO),
                shape: Shape::Body {
                    a: m.endplate_width / 2.0,
                    b: d,
                    half_h: h,
                    radius: s.body_rim_mm,
                    posterior: s.posterior_concavity_mm,
                    waist: s.waist,
                    concavity: s.endplate_concavity_mm,
                },
            },
        )];
        let theta = m.pedicle_transverse_deg.to_radians();
        let zp = h - m.pedicle_height / 2.0 - 1.0; // pedicles join the upper half of the body
        let lp = s.pedicle_length_mm;
        let isthmus = DVec2::new(m.canal_width / 2.0 + m.pedicle_width / 2.0, -d - lp / 2.0);
        // The laminae meet at the midline behind the canal; the spinolaminar junction is the canal's
        // posterior border there.
        // The laminae's upper border 4.5 mm below the upper rim leaves room for the inferior articular
        // processes of the level above.
        let z_lamina = h - 4.5 - s.lamina_height_mm / 2.0;
        let slope = s.lamina_slope_deg.to_radians();
        let lamina_up = DVec3::new(0.0, slope.sin(), slope.cos());
        let round = s.process_rounding_mm;
        let mut pedicle_centres = [DVec3::ZERO; 2];
        let mut pedicle_targets = BTreeMap::new();
        for (k, side) in [-1.0_f64, 1.0].into_iter().enumerate() {
            let pedicle = if side < 0.0 {
                Structure::PedicleLeft
            } else {
                Structure::PedicleRight
            };
            // Axis through the isthmus, running posterolaterally at θ from the sagittal plane.
            let dir = DVec3::new(side * theta.sin(), -theta.cos(), 0.0);
            let c = DVec3::new(side * isthmus.x, isthmus.y, zp);
            let (t0, t1) = (
                (-lp / 2.0 - 5.0) / theta.cos(),
                (lp / 2.0 + 4.0) / theta.cos(),
            );
            parts.push((
                pedicle,
                Placed {
                    frame: Frame {
                        origin: c + dir * ((t0 + t1) / 2.0),
                        axes: DMat3::from_cols(DVec3::Z.cross(dir), DVec3::Z, dir),
                    },
                    shape: Shape::EllipticCylinder {
                        a: m.pedicle_width / 2.0,
                        b: m.pedicle_height / 2.0,
                        half_h: (t1 - t0) / 2.0,
                        radius: 1.5,
                    },
                },
            ));
            let t_mark = (d + isthmus.y + m.canal_depth / 4.0) / theta.cos();
            pedicle_centres[k] = c + dir * t_mark;
            // Lamina: from the pedicle's posterior end to just past the midline.
            let end = c + dir * (lp / 2.0 / theta.cos());
            // A planned screw along the pedicle axis: entry at the pedicle's posterior end, through the
            // isthmus centre, tip in the anterior third of the body (60 % of its half-depth anterior of
            // the centre).
            let tip_t = (0.6 * d - c.y) / theta.cos();
            let name = if side < 0.0 { "left" } else { "right" };
            for (what, p) in [("entry", end), ("isthmus", c), ("tip", c - dir * tip_t)] {
                pedicle_targets.insert(format!("{name}_pedicle_{what}"), p);
            }
            // The oblique bar's anterior face at the midline (its half-thickness over the cosine of its
            // angle to the coronal plane, plus ~1 mm that the fillet between the two laminae fills) lies on
            // the canal's posterior border.
            let lam0 = DVec3::new(end.x, end.y, z_lamina);
            let run = DVec2::new(end.x.abs(), end.y + d + m.canal_depth);
            let cos_psi = run.x / (run + DVec2::new(0.0, s.lamina_thickness_mm / 2.0)).length();
            let y_lamina = -d - m.canal_depth - s.lamina_thickness_mm / 2.0 / cos_psi - 1.0;
            let lam1 = DVec3::new(-side * 2.0, y_lamina, z_lamina);
            let lam_half = DVec2::new(s.lamina_thickness_mm / 2.0, s.lamina_height_mm / 2.0);
            parts.push((
                Structure::Lamina,
                bar(lam0, lam1, lamina_up, lam_half, lam_half, round),
            ));
            // Transverse process: from the pedicle–lamina junction out to half the span.
            let tilt = s.transverse_tilt_deg.to_radians();
            let tp0 = DVec3::new(
                side * (isthmus.x + m.pedicle_width / 2.0 - 2.0),
                end.y - s.transverse_root_mm,
                zp,
            );
            let reach = m.transverse_span / 2.0 - tp0.x.abs();
            let tp1 = DVec3::new(
                side * m.transverse_span / 2.0,
                tp0.y - reach * tilt.tan(),
                zp + 1.0,
            );
            let th = DVec2::new(s.transverse_thickness_mm / 2.0, m.transverse_height / 2.0);
            parts.push((
                Structure::Transverse,
                bar(tp0, tp1, DVec3::Z, th, th * DVec2::new(0.75, 0.6), round),
            ));
            // Superior articular process: lateral/anterior of this level's superior joint.
            let half = DVec3::new(
                s.facet_width_mm / 2.0,
                s.articular_thickness_mm / 2.0,
                s.facet_height_mm / 2.0,
            );
            let off = s.facet_gap_mm / 2.0 + s.articular_thickness_mm / 2.0;
            let j = joint_centre(&m, &s);
            let (n, u) = facet_axes(side, m.superior_facet_deg);
            let sup = DVec3::new(side * j.x, j.y, h + 1.0) - n * off;
            parts.push((Structure::Articular, plate(sup, u, n, half, round)));
            // Inferior articular process: medial/posterior of the next level's superior joint.
            let j = joint_centre(&below, &s);
            let (n, u) = facet_axes(side, m.inferior_facet_deg);
            let inf = DVec3::new(side * j.x, j.y, -h - 1.0) + n * off;
            parts.push((Structure::Articular, plate(inf, u, n, half, round)));
        }
        // Spinous process: from the spinolaminar junction, posterior and inferior, to a thickened tip.
        let alpha = s.spinous_slope_deg.to_radians();
        let sdir = DVec3::new(0.0, -alpha.cos(), -alpha.sin());
        let junction = DVec3::new(0.0, -d - m.canal_depth, z_lamina - 1.0);
        let tip = junction + sdir * m.spinous_length;
        let tip_r = DVec3::new(
            4.0,
            s.spinous_tip_thickness_mm / 2.0,
            s.spinous_tip_height_mm / 2.0,
        );
        let tip_centre = tip - sdir * tip_r.x;
        let spinous = bar(
            junction,
            tip_centre,
            DVec3::Z,
            DVec2::new(s.spinous_thickness_mm / 2.0, s.spinous_height_mm / 2.0),
            DVec2::new(
                s.spinous_thickness_mm / 2.0 * 0.85,
                s.spinous_tip_height_mm / 2.0 * 0.85,
            ),
            round,
        );
        let tip_frame = Frame {
            origin: tip_centre,
            axes: spinous.frame.axes,
        };
        parts.push((Structure::Spinous, spinous));
        parts.push((
            Structure::Spinous,
            Placed {
                frame: tip_frame,
                shape: Shape::Ellipsoid { radii: tip_r },
            },
        ));
        let mut shape = VertebraShape {
            level,
            morphometry: m,
            params: s,
            parts,
            landmarks: BTreeMap::new(),
            pedicle_targets,
        };
        // The spinous tip is the process's most posterior point: the tip ellipsoid's support point in −y.
        let axes = tip_frame.axes;
        let u = axes.transpose() * -DVec3::Y;
        let support = tip_centre + axes * (tip_r * tip_r * u / (tip_r * u).length());
        let toward_tip = (support - tip_centre).normalize();
        shape.landmarks = shape.place_landmarks(pedicle_centres, tip_centre, toward_tip);
        shape
    }

    /// The named landmarks, on or inside the SDF as their names say (surface points found by bisection).
    fn place_landmarks(
        &self,
        pedicles: [DVec3; 2],
        tip_centre: DVec3,
        toward_tip: DVec3,
    ) -> BTreeMap<String, DVec3> {
        let m = &self.morphometry;
        let (d, h) = (m.endplate_depth / 2.0, m.body_height / 2.0);
        let r = self.params.body_rim_mm;
        let f = |p: DVec3| self.sdf(p);
        let top = h - self.params.endplate_concavity_mm;
        let corner = |sy: f64, sz: f64| {
            let c = DVec3::new(0.0, sy * (d - r), sz * (h - r));
            surface_along(f, c, DVec3::new(0.0, sy, sz).normalize(), 3.0 * r)
        };
        [
            ("center", DVec3::ZERO),
            (
                "superior_endplate",
                surface_along(f, DVec3::new(0.0, 0.0, top - 3.0), DVec3::Z, 6.0),
            ),
            (
                "inferior_endplate",
                surface_along(f, DVec3::new(0.0, 0.0, 3.0 - top), -DVec3::Z, 6.0),
            ),
            ("left_pedicle", pedicles[0]),
            ("right_pedicle", pedicles[1]),
            (
                "spinous_tip",
                surface_along(f, tip_centre, toward_tip, 12.0),
            ),
            ("corner_anterior_superior", corner(1.0, 1.0)),
            ("corner_anterior_inferior", corner(1.0, -1.0)),
            ("corner_posterior_superior", corner(-1.0, 1.0)),
            ("corner_posterior_inferior", corner(-1.0, -1.0)),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect()
    }

    /// Signed distance (bound) of the outer (cortical) surface at a local point.
    pub fn sdf(&self, p: DVec3) -> f64 {
        let k = self.params.blend_mm;
        self.parts
            .iter()
            .map(|(_, s)| s.sdf(p))
            .fold(f64::INFINITY, |acc, d| smooth_min(acc, d, k))
    }

    /// The structure of the nearest primitive; body points on the top/bottom faces (outward normal
    /// `n_local` with `|n_z| > 0.7`, within two rim radii of the endplate rim plane, the concavity
    /// included) are the superior/inferior endplates.
    pub fn structure_at(&self, p: DVec3, n_local: DVec3) -> Structure {
        let mut best = (f64::INFINITY, Structure::Unlabelled);
        for (s, prim) in &self.parts {
            let d = prim.sdf(p);
            if d < best.0 {
                best = (d, *s);
            }
        }
        let near_face = self.morphometry.body_height / 2.0
            - 2.0 * self.params.body_rim_mm
            - self.params.endplate_concavity_mm;
        match best.1 {
            Structure::Body if n_local.z > 0.7 && p.z > near_face => Structure::SuperiorEndplate,
            Structure::Body if n_local.z < -0.7 && p.z < -near_face => Structure::InferiorEndplate,
            s => s,
        }
    }

    /// Local bounding box of the shape.
    pub fn bounds(&self) -> (DVec3, DVec3) {
        self.parts.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), (_, p)| {
                let (a, b) = p.bounds();
                (lo.min(a), hi.max(b))
            },
        )
    }

    /// The named landmarks in the local frame (exact, from the parameters).
    pub fn local_landmarks(&self) -> &BTreeMap<String, DVec3> {
        &self.landmarks
    }

    /// The clinical target points of a planned pedicle screw on each side (`{left,right}_pedicle_entry`,
    /// `_isthmus`, `_tip`: the pedicle axis's posterior end, the isthmus centre, and the tip in the
    /// anterior third of the body), mapped to world by `to_world`.
    pub fn pedicle_targets(&self, to_world: impl Fn(DVec3) -> DVec3) -> Landmarks {
        Landmarks {
            level: self.level.name().to_string(),
            points: self
                .pedicle_targets
                .iter()
                .map(|(k, &v)| (k.clone(), to_world(v)))
                .collect(),
        }
    }

    /// Landmarks mapped to world by `to_world`.
    pub fn landmarks(&self, to_world: impl Fn(DVec3) -> DVec3) -> Landmarks {
        Landmarks {
            level: self.level.name().to_string(),
            points: self
                .landmarks
                .iter()
                .map(|(k, &v)| (k.clone(), to_world(v)))
                .collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::anatomy::morphometry::MorphometryTable;

    #[test]
    fn pedicle_targets_follow_a_screw_path_through_the_bone() {
        let table = MorphometryTable::default();
        for level in Level::ALL {
            let v = VertebraShape::new(level, &table);
            let t = v.pedicle_targets(|p| p);
            for side in ["left", "right"] {
                let at = |w: &str| t.points[&format!("{side}_pedicle_{w}")];
                let (entry, isthmus, tip) = (at("entry"), at("isthmus"), at("tip"));
                // The isthmus and the tip lie inside the vertebra (negative signed distance), the tip in
                // the body's anterior half, the entry posterior of the isthmus.
                assert!(v.sdf(isthmus) < 0.0 && v.sdf(tip) < 0.0, "{level:?} {side}");
                assert!(tip.y > 0.0 && entry.y < isthmus.y, "{level:?} {side}");
                // One straight screw path: entry, isthmus and tip collinear.
                let off = (tip - entry).cross(isthmus - entry).length() / (tip - entry).length();
                assert!(off < 1e-9, "{level:?} {side}: {off}");
                // Left is −x (RAS+).
                assert_eq!(isthmus.x < 0.0, side == "left");
            }
        }
    }
}
