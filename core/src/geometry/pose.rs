//! Rigid transforms (rotation + translation) in f64, and the SO(3) exponential/logarithm.

use glam::{DMat3, DMat4, DVec3};
use serde::{Deserialize, Serialize};

use crate::{Error, Result};

/// A rigid transform `p ↦ R p + t`.
///
/// Used both for `world_to_camera` extrinsics and for object poses `T` (model → world).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RigidTransform {
    pub rotation: DMat3,
    pub translation: DVec3,
}

impl Default for RigidTransform {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl RigidTransform {
    pub const IDENTITY: Self = RigidTransform {
        rotation: DMat3::IDENTITY,
        translation: DVec3::ZERO,
    };

    pub fn new(rotation: DMat3, translation: DVec3) -> Self {
        RigidTransform {
            rotation,
            translation,
        }
    }

    /// Applies the transform to a point.
    #[inline]
    pub fn apply(&self, p: DVec3) -> DVec3 {
        self.rotation * p + self.translation
    }

    /// Applies only the rotation (for directions).
    #[inline]
    pub fn apply_vector(&self, v: DVec3) -> DVec3 {
        self.rotation * v
    }

    /// The inverse transform `p ↦ Rᵀ (p − t)`.
    pub fn inverse(&self) -> Self {
        let rt = self.rotation.transpose();
        RigidTransform {
            rotation: rt,
            translation: -(rt * self.translation),
        }
    }

    /// `self ∘ other`: first `other`, then `self`.
    pub fn compose(&self, other: &RigidTransform) -> Self {
        RigidTransform {
            rotation: self.rotation * other.rotation,
            translation: self.rotation * other.translation + self.translation,
        }
    }

    /// The camera transform of a source at `source` looking at `target`, with world direction `up`
    /// appearing toward the top of the image (−v). Returns `world_to_camera`.
    pub fn look_at(source: DVec3, target: DVec3, up: DVec3) -> Result<Self> {
        let z = target - source;
        if !(z.is_finite() && z.length() > 1e-9) {
            return Err(Error::invalid(
                "view.source_mm/target_mm",
                "source and target must be distinct finite points",
            ));
        }
        let z = z.normalize();
        // Camera +y points down the detector, i.e. opposite to `up` projected onto the image plane.
        let y = -(up - z * up.dot(z));
        if !(y.is_finite() && y.length() > 1e-9) {
            return Err(Error::invalid(
                "view.up",
                "must be finite and not parallel to the central ray",
            ));
        }
        let y = y.normalize();
        let x = y.cross(z);
        // Rows of R are the camera axes in world coordinates.
        let rotation = DMat3::from_cols(x, y, z).transpose();
        Ok(RigidTransform {
            rotation,
            translation: -(rotation * source),
        })
    }

    /// The homogeneous 4×4 matrix `[R t; 0 1]` (glam's column-major `DMat4`).
    pub fn to_mat4(&self) -> DMat4 {
        DMat4::from_mat3_translation(self.rotation, self.translation)
    }

    /// Row-major 4×4 homogeneous matrix `[R t; 0 1]` (the JSON and TOML layout).
    pub fn to_rows(&self) -> [[f64; 4]; 4] {
        self.to_mat4().transpose().to_cols_array_2d()
    }

    /// From a row-major 4×4 matrix, checking that the upper 3×3 block is a rotation (orthonormal,
    /// determinant +1, to 1e-6) and the last row is `[0, 0, 0, 1]`. `field` names the matrix in errors.
    pub fn from_rows(m: [[f64; 4]; 4], field: &str) -> Result<Self> {
        if m.iter().flatten().any(|v| !v.is_finite()) {
            return Err(Error::invalid(field, "contains a non-finite value"));
        }
        if m[3] != [0.0, 0.0, 0.0, 1.0] {
            return Err(Error::invalid(field, "last row must be [0, 0, 0, 1]"));
        }
        // The transpose of the row-major array read column-major is the matrix itself.
        let h = DMat4::from_cols_array_2d(&m).transpose();
        let rotation = DMat3::from_mat4(h);
        check_rotation(&rotation, field)?;
        Ok(RigidTransform {
            rotation,
            translation: h.w_axis.truncate(),
        })
    }

    /// From a row-major rotation and a translation (the registration JSON layout).
    pub fn from_rt(r: [[f64; 3]; 3], t: [f64; 3], field: &str) -> Result<Self> {
        Self::from_rows(
            [
                [r[0][0], r[0][1], r[0][2], t[0]],
                [r[1][0], r[1][1], r[1][2], t[1]],
                [r[2][0], r[2][1], r[2][2], t[2]],
                [0.0, 0.0, 0.0, 1.0],
            ],
            field,
        )
    }

    /// A pose from JSON `text` (`origin` names it in errors): `{"R": [[…]], "t": […]}` (row-major
    /// rotation and translation, mm — the layout of `spinedrr register`'s `R.json`, whose other keys are
    /// ignored) or `{"matrix": [[…] × 4]}` (row-major 4 × 4 `[R t; 0 1]`). The rotation is checked as in
    /// [`RigidTransform::from_rows`].
    pub fn from_json_str(text: &str, origin: &str) -> Result<Self> {
        #[derive(Deserialize)]
        struct PoseFile {
            #[serde(rename = "R")]
            r: Option<[[f64; 3]; 3]>,
            t: Option<[f64; 3]>,
            matrix: Option<[[f64; 4]; 4]>,
        }
        let p: PoseFile = serde_json::from_str(text).map_err(|e| {
            Error::invalid(
                origin,
                format!("not a pose ({{\"R\": [[…]], \"t\": […]}} or {{\"matrix\": …}}): {e}"),
            )
        })?;
        match (p.r, p.t, p.matrix) {
            (Some(r), Some(t), None) => Self::from_rt(r, t, &format!("{origin}: R")),
            (None, None, Some(m)) => Self::from_rows(m, &format!("{origin}: matrix")),
            (None, None, None) => Err(Error::invalid(
                origin,
                "has no pose: give \"R\" (3 × 3 rows) and \"t\" (mm), or \"matrix\" (4 × 4 rows)",
            )),
            (Some(_), None, None) | (None, Some(_), None) => Err(Error::invalid(
                origin,
                "gives only one of \"R\" and \"t\": a pose needs both",
            )),
            _ => Err(Error::invalid(
                origin,
                "gives both \"matrix\" and \"R\"/\"t\": give one",
            )),
        }
    }

    /// Row-major rotation.
    pub fn rotation_rows(&self) -> [[f64; 3]; 3] {
        self.rotation.transpose().to_cols_array_2d()
    }
}

fn check_rotation(r: &DMat3, field: &str) -> Result<()> {
    let should_be_identity = r.transpose() * *r;
    let dev = (should_be_identity - DMat3::IDENTITY)
        .to_cols_array()
        .iter()
        .fold(0.0f64, |a, v| a.max(v.abs()));
    if dev > 1e-6 {
        return Err(Error::invalid(
            field,
            format!("rotation block is not orthonormal (|RᵀR − I| = {dev:.2e})"),
        ));
    }
    if r.determinant() < 0.0 {
        return Err(Error::invalid(
            field,
            "rotation block has determinant −1 (a reflection)",
        ));
    }
    Ok(())
}

/// Rodrigues' formula: the rotation by `|w|` radians about `w / |w|`.
pub fn rotation_exp(w: DVec3) -> DMat3 {
    let theta = w.length();
    if theta < 1e-12 {
        // Second-order expansion keeps this exact to rounding for tiny angles.
        let k = skew(w);
        return DMat3::IDENTITY + k + 0.5 * k * k;
    }
    DMat3::from_axis_angle(w / theta, theta)
}

/// The axis-angle vector of a rotation (inverse of [`rotation_exp`]), stable near 0 and π.
pub fn rotation_log(r: DMat3) -> DVec3 {
    let vee = vee_of_antisymmetric_part(r);
    let (s, c) = sin_cos_of_angle(r, vee);
    let theta = s.atan2(c);
    if s > 1e-6 {
        return vee * (theta / (2.0 * s));
    }
    if c > 0.0 {
        // θ ≈ 0: vee / 2 is the axis-angle vector to first order.
        return 0.5 * vee;
    }
    // θ ≈ π: axis from the largest diagonal entry of (R + I) / 2 = a aᵀ.
    let b = (r + DMat3::IDENTITY) * 0.5;
    let cols = [b.x_axis, b.y_axis, b.z_axis];
    let diag = [b.x_axis.x, b.y_axis.y, b.z_axis.z];
    let i = (0..3)
        .max_by(|&a, &b| diag[a].total_cmp(&diag[b]))
        .unwrap_or(0);
    let axis = cols[i] / diag[i].max(1e-300).sqrt();
    axis.normalize_or_zero() * theta
}

/// Geodesic angle of a rotation in degrees: `atan2(‖vee(R − Rᵀ)‖ / 2, (tr R − 1) / 2)`.
///
/// Unlike `acos((tr R − 1) / 2)` this keeps full precision near zero (down to ~1e-14°).
pub fn rotation_angle_deg(r: DMat3) -> f64 {
    let (s, c) = sin_cos_of_angle(r, vee_of_antisymmetric_part(r));
    s.atan2(c).to_degrees()
}

/// `vee(R − Rᵀ) = 2 sin θ · axis`.
fn vee_of_antisymmetric_part(r: DMat3) -> DVec3 {
    DVec3::new(
        r.y_axis.z - r.z_axis.y,
        r.z_axis.x - r.x_axis.z,
        r.x_axis.y - r.y_axis.x,
    )
}

/// `(sin θ, cos θ)` of a rotation from its antisymmetric part and its trace.
fn sin_cos_of_angle(r: DMat3, vee: DVec3) -> (f64, f64) {
    (
        0.5 * vee.length(),
        0.5 * (r.x_axis.x + r.y_axis.y + r.z_axis.z - 1.0),
    )
}

/// The cross-product matrix `[w]×`.
pub(crate) fn skew(w: DVec3) -> DMat3 {
    DMat3::from_cols(
        DVec3::new(0.0, w.z, -w.y),
        DVec3::new(-w.z, 0.0, w.x),
        DVec3::new(w.y, -w.x, 0.0),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_log_round_trip() {
        for w in [
            DVec3::new(0.1, -0.2, 0.3),
            DVec3::new(1e-9, 0.0, 2e-9),
            DVec3::new(0.0, 3.0, 0.0),
            DVec3::new(3.1, 0.2, -0.1),
        ] {
            let back = rotation_log(rotation_exp(w));
            assert!((back - w).length() < 1e-9, "{w:?} -> {back:?}");
        }
    }

    #[test]
    fn angle_matches_axis_angle_norm() {
        for deg in [1e-9, 1e-6, 0.5, 45.0, 179.0] {
            let r = rotation_exp(DVec3::new(1.0, 2.0, -2.0).normalize() * f64::to_radians(deg));
            let got = rotation_angle_deg(r);
            assert!((got - deg).abs() <= 1e-9 * deg.max(1.0), "{deg} -> {got}");
        }
    }

    #[test]
    fn look_at_axes() {
        let t =
            RigidTransform::look_at(DVec3::new(0.0, -1000.0, 0.0), DVec3::ZERO, DVec3::Z).unwrap();
        // The target is on the optical axis at depth 1000.
        assert!((t.apply(DVec3::ZERO) - DVec3::new(0.0, 0.0, 1000.0)).length() < 1e-12);
        // World up (+z) maps to camera −y (top of the image).
        assert!((t.apply_vector(DVec3::Z) - DVec3::new(0.0, -1.0, 0.0)).length() < 1e-12);
        let back = RigidTransform::from_rows(t.to_rows(), "m").unwrap();
        assert_eq!(back, t);
        // The 4×4 matrix maps homogeneous points as the transform maps points.
        let p = DVec3::new(3.0, -7.0, 11.0);
        let h = t.to_mat4() * p.extend(1.0);
        assert!((h.truncate() - t.apply(p)).length() < 1e-12 && h.w == 1.0);
        assert_eq!(t.to_rows()[1][3], t.translation.y);
        assert_eq!(t.rotation_rows()[0][1], t.rotation.y_axis.x);
        assert!(
            t.inverse()
                .compose(&t)
                .apply(DVec3::ONE)
                .abs_diff_eq(DVec3::ONE, 1e-12)
        );
    }

    #[test]
    fn pose_files_read_both_layouts_and_refuse_half_a_pose() {
        let r = rotation_exp(DVec3::new(0.1, -0.2, 0.3));
        let t = DVec3::new(1.0, 2.0, -3.0);
        let pose = RigidTransform::new(r, t);
        let rt =
            serde_json::json!({"R": pose.rotation_rows(), "t": t.to_array(), "residual_px": 0.1});
        let m = serde_json::json!({"matrix": pose.to_rows()});
        for text in [rt.to_string(), m.to_string()] {
            let back = RigidTransform::from_json_str(&text, "p.json").unwrap();
            let p = DVec3::new(10.0, -4.0, 7.0);
            assert!((back.apply(p) - pose.apply(p)).length() < 1e-12);
        }
        for (text, needle) in [
            (r#"{"t": [0, 0, 0]}"#, "only one"),
            (r#"{"name": "x"}"#, "has no pose"),
            (
                r#"{"R": [[1,0,0],[0,1,0],[0,0,-1]], "t": [0,0,0]}"#,
                "reflection",
            ),
            ("[1, 2]", "not a pose"),
        ] {
            let e = RigidTransform::from_json_str(text, "p.json")
                .unwrap_err()
                .to_string();
            assert!(e.contains("p.json") && e.contains(needle), "{e}");
        }
    }

    #[test]
    fn rejects_reflection_and_garbage() {
        let mut m = RigidTransform::IDENTITY.to_rows();
        m[0][0] = -1.0;
        assert!(RigidTransform::from_rows(m, "m").is_err());
        m[0][0] = f64::NAN;
        assert!(RigidTransform::from_rows(m, "m").is_err());
        m[0][0] = 2.0;
        assert!(RigidTransform::from_rows(m, "m").is_err());
    }
}
