//! Imaging geometry: the pinhole C-arm model shared by every renderer, metric and solver.
//!
//! Conventions (see `DESIGN.md`): world frame in millimetres (RAS+); camera frame is OpenCV's, origin at
//! the X-ray source, +z along the central ray toward the detector, +x along detector rows (u), +y down
//! the detector (v); pixel (u, v) has its centre at integer coordinates; `x ~ K [R | t] X`.

mod carm;
mod intrinsics;
pub mod outline;
mod perturbation;
pub mod physical;
mod pose;
mod view;

pub use carm::{CArm, DEFAULT_GEOMETRY_TOML, DetectorConfig, GeometryConfig, ViewConfig};
pub use intrinsics::{
    Intrinsics, MAX_DETECTOR_PX, MAX_FOCAL_PX, MAX_PRINCIPAL_POINT_PX, MIN_FOCAL_PX,
};
pub use perturbation::{PERTURBATION_KEYS, PHYSICAL_KEYS, Perturbation};
pub use pose::{RigidTransform, rotation_angle_deg, rotation_exp, rotation_log};
pub use view::{Ray, View, apply_homography, box_corners};
