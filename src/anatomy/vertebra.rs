//! One parametric lumbar vertebra as a smooth union of signed-distance primitives, in its local frame:
//! origin at the centre of the vertebral body, RAS+ axes (x = patient right, y = anterior, z = superior),
//! so the body is anterior and the spinous process points to −y.
//!
//! Dimensions follow the typical adult lumbar morphometry reported by Panjabi et al. (Spine 1992,
//! "Human lumbar vertebrae: quantitative three-dimensional anatomy"), Zindrick et al. (Spine 1987,
//! pedicle morphology) and Zhou et al. (Eur Spine J 2000): upper endplate width ≈ 40–50 mm and depth
//! ≈ 30–38 mm, both growing caudally; body height ≈ 24–28 mm; pedicle width ≈ 7–18 mm (narrow at L1,
//! widest at L5) and height ≈ 13–16 mm; spinal canal ≈ 21–25 mm wide and ≈ 16–19 mm deep; spinous
//! process ≈ 20–30 mm long from the lamina; transverse-process span ≈ 70–90 mm (longest at L3).

use std::collections::BTreeMap;
use std::fmt;

use glam::DVec3;

use super::Structure;
use super::landmarks::Landmarks;
use super::sdf::{Frame, Placed, Shape, smooth_min};
use crate::{Error, Result};

/// A lumbar level.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Level {
    L1,
    L2,
    L3,
    L4,
    L5,
}

impl Level {
    pub const ALL: [Level; 5] = [Level::L1, Level::L2, Level::L3, Level::L4, Level::L5];

    /// 0 for L1 … 4 for L5 (cranial to caudal).
    pub fn index(self) -> usize {
        self as usize
    }

    pub fn name(self) -> &'static str {
        ["L1", "L2", "L3", "L4", "L5"][self.index()]
    }

    /// Parses `L1` … `L5` (case-insensitive).
    pub fn parse(s: &str) -> Result<Level> {
        let t = s.trim();
        Level::ALL
            .into_iter()
            .find(|l| l.name().eq_ignore_ascii_case(t))
            .ok_or_else(|| {
                Error::invalid("levels", format!("{t:?} is not one of L1, L2, L3, L4, L5"))
            })
    }
}

impl fmt::Display for Level {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Parses a level list: a range `L1-L5`, a single level `L3`, or a comma list `L1,L3` (ranges allowed
/// inside the list). Returns the distinct levels, cranial to caudal.
pub fn parse_levels(spec: &str) -> Result<Vec<Level>> {
    let mut out = Vec::new();
    for part in spec.split(',') {
        let part = part.trim();
        if part.is_empty() {
            return Err(Error::invalid("levels", format!("empty item in {spec:?}")));
        }
        if let Some((a, b)) = part.split_once('-') {
            let (a, b) = (Level::parse(a)?, Level::parse(b)?);
            if a > b {
                return Err(Error::invalid(
                    "levels",
                    format!("range {part:?} runs caudal to cranial"),
                ));
            }
            out.extend(Level::ALL[a.index()..=b.index()].iter().copied());
        } else {
            out.push(Level::parse(part)?);
        }
    }
    out.sort();
    out.dedup();
    Ok(out)
}

/// Morphometry of one level (millimetres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Morphometry {
    pub endplate_width: f64,
    pub endplate_depth: f64,
    pub body_height: f64,
    pub pedicle_width: f64,
    pub pedicle_height: f64,
    pub canal_width: f64,
    pub canal_depth: f64,
    pub spinous_length: f64,
    pub transverse_span: f64,
}

impl Morphometry {
    /// Typical adult values per level (see the module documentation for the sources of the ranges).
    pub fn of(level: Level) -> Morphometry {
        // endplate w, d, body h, pedicle w, h, canal w, d, spinous length, transverse span
        const T: [[f64; 9]; 5] = [
            [41.0, 31.0, 25.0, 7.5, 15.5, 22.0, 17.0, 26.0, 72.0],
            [43.0, 32.5, 25.5, 8.5, 15.0, 22.5, 17.0, 27.0, 80.0],
            [45.0, 34.0, 26.0, 10.0, 14.5, 23.0, 17.0, 28.0, 88.0],
            [47.0, 35.0, 26.5, 12.0, 14.0, 23.5, 17.5, 26.0, 84.0],
            [49.0, 35.5, 26.0, 15.0, 13.5, 25.0, 18.0, 22.0, 86.0],
        ];
        let t = T[level.index()];
        Morphometry {
            endplate_width: t[0],
            endplate_depth: t[1],
            body_height: t[2],
            pedicle_width: t[3],
            pedicle_height: t[4],
            canal_width: t[5],
            canal_depth: t[6],
            spinous_length: t[7],
            transverse_span: t[8],
        }
    }
}

/// Fillet size of the smooth union between parts (mm).
const BLEND_MM: f64 = 2.0;
/// Rounding radius of the body rim (mm).
const BODY_RIM_MM: f64 = 2.0;
/// Length of the pedicle from the posterior body wall to the lamina (mm).
const PEDICLE_LENGTH_MM: f64 = 9.0;

/// A vertebra's implicit shape in its local frame.
#[derive(Debug, Clone, PartialEq)]
pub struct VertebraShape {
    pub level: Level,
    pub morphometry: Morphometry,
    parts: Vec<(Structure, Placed)>,
    landmarks: BTreeMap<String, DVec3>,
}

impl VertebraShape {
    pub fn new(level: Level) -> VertebraShape {
        let m = Morphometry::of(level);
        let (b, h) = (m.endplate_depth / 2.0, m.body_height / 2.0);
        let zp = h - m.pedicle_height / 2.0 - 1.5; // pedicles join the upper half of the body
        let xp = m.canal_width / 2.0 + m.pedicle_width / 2.0;
        let y_ped_end = -b - PEDICLE_LENGTH_MM;
        let y_lamina = -b - m.canal_depth - 3.0; // lamina mid-plane at the midline
        let zl = zp - 3.0;
        let mut parts = vec![(
            Structure::Body,
            Placed {
                frame: Frame::at(DVec3::ZERO),
                shape: Shape::EllipticCylinder {
                    a: m.endplate_width / 2.0,
                    b,
                    half_h: h,
                    radius: BODY_RIM_MM,
                },
            },
        )];
        let spin0 = DVec3::new(0.0, y_lamina + 1.0, zl - 2.0);
        let tip = DVec3::new(0.0, y_lamina + 1.0 - m.spinous_length, zl - 6.0);
        parts.push((
            Structure::Spinous,
            segment_box(spin0, tip, 3.0, 10.0, DVec3::Z),
        ));
        for side in [-1.0, 1.0] {
            let pedicle = if side < 0.0 {
                Structure::PedicleLeft
            } else {
                Structure::PedicleRight
            };
            let (y0, y1) = (-b + 6.0, y_ped_end);
            parts.push((
                pedicle,
                Placed {
                    // Cylinder axis (local z) along −y; local x = world x, local y = world z.
                    frame: Frame {
                        origin: DVec3::new(side * xp, (y0 + y1) / 2.0, zp),
                        axes: glam::DMat3::from_cols(DVec3::X, DVec3::Z, -DVec3::Y),
                    },
                    shape: Shape::EllipticCylinder {
                        a: m.pedicle_width / 2.0,
                        b: m.pedicle_height / 2.0,
                        half_h: (y0 - y1) / 2.0,
                        radius: 1.5,
                    },
                },
            ));
            let lam0 = DVec3::new(side * xp, y_ped_end - 1.0, zl);
            let lam1 = DVec3::new(0.0, y_lamina, zl);
            parts.push((
                Structure::Lamina,
                segment_box(lam0, lam1, 3.0, 9.0, DVec3::Z),
            ));
            let tp0 = DVec3::new(side * xp, -b - 0.7 * PEDICLE_LENGTH_MM, zp);
            let tp1 = DVec3::new(side * m.transverse_span / 2.0, tp0.y - 6.0, zp + 1.0);
            parts.push((
                Structure::Transverse,
                segment_box(tp0, tp1, 3.0, 5.0, DVec3::Z),
            ));
            let sup = DVec3::new(side * (xp + 2.0), y_ped_end - 3.0, h + 3.0);
            parts.push((
                Structure::Articular,
                upright_box(sup, DVec3::new(3.5, 5.0, 7.0)),
            ));
            let inf = DVec3::new(side * (xp - 6.0), -b - m.canal_depth - 1.0, -h - 1.0);
            parts.push((
                Structure::Articular,
                upright_box(inf, DVec3::new(3.5, 5.0, 8.0)),
            ));
        }
        let r = BODY_RIM_MM;
        let (cy, cz) = (
            b - r + r * std::f64::consts::FRAC_1_SQRT_2,
            h - r + r * std::f64::consts::FRAC_1_SQRT_2,
        );
        let landmarks: BTreeMap<String, DVec3> = [
            ("center", DVec3::ZERO),
            ("superior_endplate", DVec3::new(0.0, 0.0, h)),
            ("inferior_endplate", DVec3::new(0.0, 0.0, -h)),
            (
                "left_pedicle",
                DVec3::new(-xp, -b - PEDICLE_LENGTH_MM / 2.0, zp),
            ),
            (
                "right_pedicle",
                DVec3::new(xp, -b - PEDICLE_LENGTH_MM / 2.0, zp),
            ),
            ("spinous_tip", tip),
            ("corner_anterior_superior", DVec3::new(0.0, cy, cz)),
            ("corner_anterior_inferior", DVec3::new(0.0, cy, -cz)),
            ("corner_posterior_superior", DVec3::new(0.0, -cy, cz)),
            ("corner_posterior_inferior", DVec3::new(0.0, -cy, -cz)),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect();
        VertebraShape {
            level,
            morphometry: m,
            parts,
            landmarks,
        }
    }

    /// Signed distance (bound) of the outer (cortical) surface at a local point.
    pub fn sdf(&self, p: DVec3) -> f64 {
        self.parts
            .iter()
            .map(|(_, s)| s.sdf(p))
            .fold(f64::INFINITY, |acc, d| smooth_min(acc, d, BLEND_MM))
    }

    /// The structure of the nearest primitive; body points on the top/bottom faces (outward normal
    /// `n_local` with `|n_z| > 0.7`, within two rim radii of the endplate plane) are the
    /// superior/inferior endplates.
    pub fn structure_at(&self, p: DVec3, n_local: DVec3) -> Structure {
        let mut best = (f64::INFINITY, Structure::Unlabelled);
        for (s, prim) in &self.parts {
            let d = prim.sdf(p);
            if d < best.0 {
                best = (d, *s);
            }
        }
        let near_face = self.morphometry.body_height / 2.0 - 2.0 * BODY_RIM_MM;
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

/// A rounded box from `start` to `end` (its end faces centred on them), `half_thick` across (local y)
/// and `half_height` along `up` (local z).
fn segment_box(start: DVec3, end: DVec3, half_thick: f64, half_height: f64, up: DVec3) -> Placed {
    Placed {
        frame: Frame::along(start, end, up),
        shape: Shape::RoundedBox {
            half: DVec3::new((end - start).length() / 2.0, half_thick, half_height),
            radius: 1.5,
        },
    }
}

fn upright_box(centre: DVec3, half: DVec3) -> Placed {
    Placed {
        frame: Frame::at(centre),
        shape: Shape::RoundedBox { half, radius: 1.5 },
    }
}
