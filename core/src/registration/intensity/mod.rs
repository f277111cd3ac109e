//! Intensity-based 2D–3D registration of a rigid vertebra pose `T` (model → world, as in landmark
//! registration; rotation about the vertebra centre), with DRRs rendered through the **assumed** K
//! matched to fixed images of one view or several (similarities summed over views).
//!
//! * `moving`: the moving DRR (the camera moves, not the anatomy: nothing is rebuilt per evaluation);
//! * `objective`: the least-squares form of a level's similarity;
//! * `similarity`: NCC, gradient correlation, gradient NCC and patch-wise NCC as normalised residuals;
//! * `pyramid`: binned detectors and their K;
//! * `cmaes` (global stage at the coarsest level) and `lm` (Levenberg–Marquardt refinement per level);
//! * `register`: the pipeline; `evaluate`: mTRE, starts uniform in initial mTRE, success and capture
//!   range (van de Kraats et al. 2005); `anatomy`: phantom targets and fluoroscopy-like fixed images;
//!   `problem`: the `P.json` file of `spinedrr register --intensity` and its `R.json` record;
//! * `device` (the gpu feature): a CT level's evaluation and the LM's products on the GPU.

mod anatomy;
mod cmaes;
#[cfg(feature = "gpu")]
mod device;
mod evaluate;
mod lm;
mod moving;
mod objective;
mod problem;
mod pyramid;
mod register;
mod similarity;

pub use anatomy::{
    MAX_TARGET_POINTS, MovingScope, fixed_image, level_alone, level_targets, phantom_moving,
    phantom_renderer,
};
pub use cmaes::{CmaesOptions, CmaesResult, minimize};
pub use evaluate::{
    BinSummary, CAPTURE_MIN_STARTS, CAPTURE_SUCCESS_RATE, SUCCESS_MTRE_MM, TrialOutcome,
    capture_range_mm, initial_mtres, mtre_mm, projected_tre_px, start_at_mtre, subsample,
    summarise,
};
pub use lm::{LmOptions, LmResult, refine};
pub use moving::{MeshDrr, MovingDrr};
pub use objective::{Evaluation, Objective, Residual, pose_of};
pub use problem::{LoadedIntensityProblem, run_intensity_problem};
pub use pyramid::{binned_image, binned_view, subsampled_image, subsampled_view};
pub use register::{
    IntensityOptions, IntensityProblem, IntensityResult, IntensityView, StageReport, check_visible,
    register_intensity,
};
pub use similarity::{DEFAULT_PATCH_PX, FixedFeatures, Similarity};
