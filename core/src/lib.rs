//! spinedrr-core: the computing half of spinedrr (projection-domain calibration-sensitivity analysis of
//! vertebral DRRs): everything but the study and the CLI, which are the `spinedrr` crate; it re-exports
//! these modules, so `spinedrr::render::…` and `spinedrr_core::render::…` name the same items.
//!
//! Data flows one way through the stages; each module depends only on those before it in this list
//! (and on [`io`], the file layer, which needs only `geometry`):
//!
//! ```text
//! math, geometry -> anatomy -> render -> analysis, registration -> calibration
//! ```
//!
//! * [`math`]: the small dense linear algebra (symmetric eigen-decomposition, Cholesky solve); depends
//!   on nothing else in the crate.
//! * [`geometry`]: the pinhole C-arm model (`Intrinsics`, `View`, `CArm`, `Perturbation`), rigid
//!   transforms and the one `project` function.
//! * [`spectral`]: materials (NIST μ/ρ), tube spectra (TASMIP), the detector and the polychromatic energy
//!   sum; depends on nothing else in the crate.
//! * [`anatomy`]: triangle meshes, mesh files, the parametric lumbar phantom and its landmarks.
//! * [`render`]: thickness DRRs of meshes (the raster, Embree or the pure-Rust BVH) and CT volume DRRs.
//! * [`io`]: atomic writes, float32 TIFF images, PNG previews and the JSON sidecar every image carries.
//! * [`analysis`]: projection-domain metrics (landmark shifts, contours, overlap, image similarity).
//! * [`registration`]: landmark 2D–3D registration (LM over SE(3), two-view Kabsch, OpenCV PnP).
//! * [`calibration`]: simulated C-arm calibration with BB phantoms (Zhang via OpenCV; DLT + RQ + LM).

pub mod analysis;
pub mod anatomy;
pub mod calibration;
pub mod error;
pub mod geometry;
pub mod io;
pub mod math;
pub mod registration;
pub mod render;
pub mod spectral;

pub use error::{Error, Result};

/// The tool version written into every sidecar.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");
