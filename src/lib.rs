//! spinedrr: projection-domain calibration-sensitivity analysis of vertebral DRRs.
//!
//! Data flows one way through the stages; each module depends only on those before it in this list
//! (and on [`io`], the file layer, which needs only `geometry`):
//!
//! ```text
//! math, geometry -> anatomy -> render -> analysis, registration -> calibration -> study
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
//! * [`study`]: the calibration-sensitivity study: experiments, tables, figures and the report.
//!
//! Every module but [`study`] lives in the `spinedrr-core` crate (`core/`) and is re-exported here: the
//! study, the report and the CLI are cold code that compiles without LLVM's optimisation in the test
//! build, the core's hot loops with it (see the workspace's `Cargo.toml`).

pub use spinedrr_core::{
    Error, Result, VERSION, analysis, anatomy, calibration, error, geometry, io, math,
    registration, render, spectral,
};
pub mod study;
