//! spinedrr: projection-domain calibration-sensitivity analysis of vertebral DRRs.
//!
//! Data flows one way through the stages, each a module that depends only on those above it:
//!
//! ```text
//! anatomy  -> geometry -> render -> analysis -> registration -> study
//! ```
//!
//! * [`geometry`]: the pinhole C-arm model (`Intrinsics`, `View`, `CArm`, `Perturbation`) and the one
//!   `project` function.
//! * [`anatomy`]: triangle meshes, mesh files, the parametric lumbar phantom and its landmarks.
//! * [`render`]: thickness DRRs through Embree or the pure-Rust BVH, images and their JSON sidecars.
//! * [`analysis`]: projection-domain metrics (landmark shifts, contours, overlap, image similarity).
//! * [`registration`]: landmark 2D–3D registration (LM over SE(3), two-view Kabsch, OpenCV PnP).

pub mod analysis;
pub mod anatomy;
pub mod error;
pub mod geometry;
pub mod io;
pub mod registration;
pub mod render;
pub mod study;

pub use error::{Error, Result};

/// The tool version written into every sidecar.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");
