//! A view: intrinsics plus world→camera extrinsics. Owns the one projection function of the tool.

use glam::{DMat3, DVec2, DVec3};
use serde::{Deserialize, Serialize};

use super::{Intrinsics, Perturbation, RigidTransform};

/// A ray `origin + t · dir` with a unit direction (world frame, mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    pub origin: DVec3,
    pub dir: DVec3,
}

/// One C-arm acquisition: a named view with its intrinsics and `world_to_camera`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct View {
    pub name: String,
    pub intrinsics: Intrinsics,
    pub world_to_camera: RigidTransform,
    /// The source-to-detector distance (mm): the camera z of the detector plane, known when the view
    /// came from a geometry file with a physical detector (`sdd_mm` and `pixel_spacing_mm`, not an
    /// explicit `K`). Physical perturbations ([`Perturbation::is_physical`]) need it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sdd_mm: Option<f64>,
}

impl View {
    pub fn new(
        name: impl Into<String>,
        intrinsics: Intrinsics,
        world_to_camera: RigidTransform,
    ) -> Self {
        View {
            name: name.into(),
            intrinsics,
            world_to_camera,
            sdd_mm: None,
        }
    }

    /// The same view with its source-to-detector distance (mm) known.
    pub fn with_sdd(self, sdd_mm: f64) -> View {
        View {
            sdd_mm: Some(sdd_mm),
            ..self
        }
    }

    /// The pinhole projection `x ~ K [R | t] X` of a world point to pixel coordinates.
    #[inline]
    pub fn project(&self, world: DVec3) -> DVec2 {
        self.intrinsics
            .project_camera(self.world_to_camera.apply(world))
    }

    /// Depth (camera z, mm) of a world point.
    #[inline]
    pub fn depth(&self, world: DVec3) -> f64 {
        self.world_to_camera.apply(world).z
    }

    /// The central ray's point nearest the world origin (where the view aims), and the source's
    /// distance to it.
    pub fn aim(&self) -> (DVec3, f64) {
        let c = self.source_world();
        let axis = self
            .world_to_camera
            .inverse()
            .apply_vector(DVec3::Z)
            .normalize();
        let d = (-c).dot(axis);
        (c + axis * d, d)
    }

    /// The X-ray source (camera centre) in world coordinates, `−Rᵀ t`.
    pub fn source_world(&self) -> DVec3 {
        self.world_to_camera.inverse().translation
    }

    /// The matrix that maps homogeneous pixels `[u, v, 1]` to (unnormalised) world directions: `Rᵀ K⁻¹`.
    pub fn pixel_to_world_dir(&self) -> DMat3 {
        self.world_to_camera.rotation.transpose() * self.intrinsics.matrix().inverse()
    }

    /// The ray from the source through the centre of pixel (u, v) (integer = pixel centre).
    pub fn pixel_ray(&self, u: f64, v: f64) -> Ray {
        let d_cam = self.intrinsics.back_project(u, v);
        Ray {
            origin: self.source_world(),
            dir: self
                .world_to_camera
                .rotation
                .transpose()
                .mul_vec3(d_cam)
                .normalize(),
        }
    }

    /// The assumed view under `p`: its physical part moves the camera
    /// ([`super::physical::assumed_camera`], which needs [`View::sdd_mm`]), then its intrinsic part
    /// changes `K` with the extrinsics fixed.
    pub fn perturbed(&self, p: &Perturbation) -> crate::Result<View> {
        let moved = if p.is_physical() {
            let sdd = self.sdd_mm.ok_or_else(|| {
                crate::Error::invalid(
                    "perturbation",
                    format!(
                        "'{p}' moves the focal spot or the detector in mm, but view '{}' has no \
                         known source-to-detector distance (its geometry gives an explicit K): \
                         give [detector] sdd_mm and pixel_spacing_mm instead of K",
                        self.name
                    ),
                )
            })?;
            super::physical::assumed_camera(self, p, sdd)?
        } else {
            self.clone()
        };
        Ok(View {
            intrinsics: p.apply_intrinsic(&moved.intrinsics)?,
            ..moved
        })
    }

    /// The detector window of `width × height` pixels whose first pixel is pixel `(u0, v0)` of this
    /// view: the same source, orientation and rays, with the principal point moved to
    /// `(cx − u0, cy − v0)`, so window pixel `(i, j)` sees what pixel `(u0 + i, v0 + j)` sees. Rendering
    /// a window costs its pixels only (a small object's image without a full-detector buffer).
    pub fn window(&self, u0: u32, v0: u32, width: u32, height: u32) -> crate::Result<View> {
        let k = self.intrinsics;
        let fits =
            |o: u32, n: u32, total: u32| n > 0 && o.checked_add(n).is_some_and(|e| e <= total);
        if !(fits(u0, width, k.width) && fits(v0, height, k.height)) {
            return Err(crate::Error::invalid(
                "window",
                format!(
                    "{width}×{height} px at ({u0}, {v0}) is not inside the {}×{} detector",
                    k.width, k.height
                ),
            ));
        }
        Ok(View {
            name: self.name.clone(),
            intrinsics: super::Intrinsics {
                cx: k.cx - f64::from(u0),
                cy: k.cy - f64::from(v0),
                width,
                height,
                ..k
            },
            world_to_camera: self.world_to_camera,
            sdd_mm: self.sdd_mm,
        })
    }

    /// Whether `other` has this view's source and orientation (to 1e-9 mm and 1e-12), so that the two
    /// images are related by the homography [`View::homography_to`].
    pub fn same_pose(&self, other: &View) -> bool {
        let (a, b) = (&self.world_to_camera, &other.world_to_camera);
        (a.rotation - b.rotation).abs_diff_eq(DMat3::ZERO, 1e-12)
            && (a.translation - b.translation).length() <= 1e-9
    }

    /// The homography `H = K' K⁻¹` that maps this view's pixels to those of `other` when both share
    /// source and orientation (the analytic law of an intrinsic perturbation).
    pub fn homography_to(&self, other: &View) -> DMat3 {
        other.intrinsics.matrix() * self.intrinsics.matrix().inverse()
    }
}

/// Applies a homography to a pixel.
pub fn apply_homography(h: &DMat3, x: DVec2) -> DVec2 {
    let p = *h * DVec3::new(x.x, x.y, 1.0);
    DVec2::new(p.x / p.z, p.y / p.z)
}

/// The eight corners of the box `lo`–`hi`.
pub fn box_corners(lo: DVec3, hi: DVec3) -> [DVec3; 8] {
    std::array::from_fn(|i| {
        DVec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view() -> View {
        let k = Intrinsics {
            fx: 4500.0,
            fy: 4400.0,
            skew: 1.5,
            cx: 500.0,
            cy: 520.0,
            width: 1024,
            height: 1024,
        };
        let t = RigidTransform::look_at(
            DVec3::new(-300.0, -900.0, 100.0),
            DVec3::new(10.0, 5.0, -3.0),
            DVec3::new(0.1, 0.0, 1.0),
        )
        .unwrap();
        View::new("x", k, t)
    }

    #[test]
    fn pixel_ray_projects_back_to_its_pixel() {
        let v = view();
        for (u, w) in [(0.0, 0.0), (511.5, 511.5), (1023.0, 17.25), (-40.0, 2000.0)] {
            let r = v.pixel_ray(u, w);
            let p = v.project(r.origin + 850.0 * r.dir);
            assert!((p - DVec2::new(u, w)).length() < 1e-9, "{u},{w} -> {p:?}");
            let q = v.pixel_to_world_dir() * DVec3::new(u, w, 1.0);
            assert!((q.normalize() - r.dir).length() < 1e-12);
        }
    }

    #[test]
    fn a_window_sees_the_rays_of_its_pixels_in_the_full_view() {
        let v = view();
        let w = v.window(300, 410, 40, 25).unwrap();
        assert_eq!((w.intrinsics.width, w.intrinsics.height), (40, 25));
        for (i, j) in [(0.0, 0.0), (39.0, 24.0), (17.5, 3.25)] {
            let (a, b) = (w.pixel_ray(i, j), v.pixel_ray(300.0 + i, 410.0 + j));
            assert!((a.origin - b.origin).length() < 1e-9 && (a.dir - b.dir).length() < 1e-12);
        }
        let x = DVec3::new(-40.0, 30.0, 12.0);
        assert!((w.project(x) + DVec2::new(300.0, 410.0) - v.project(x)).length() < 1e-9);
        assert!(v.window(1000, 0, 25, 10).is_err());
        assert!(v.window(0, 0, 0, 10).is_err());
    }

    #[test]
    fn homography_law_for_points() {
        let v = view();
        let p = Perturbation::parse("df=300,dcx=20,dcy=-10,skew=2").unwrap();
        let vp = v.perturbed(&p).unwrap();
        let h = v.homography_to(&vp);
        for x in [DVec3::new(1.0, 2.0, 3.0), DVec3::new(-40.0, 30.0, 12.0)] {
            let predicted = apply_homography(&h, v.project(x));
            assert!((predicted - vp.project(x)).length() < 1e-9);
        }
    }
}
