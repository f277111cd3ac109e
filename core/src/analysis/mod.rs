//! Projection-domain metrics between a reference and a perturbed projection: landmark shifts (with the
//! homography prediction), silhouette contours (OpenCV `findContours`), Chamfer / Hausdorff / HD95 /
//! edge-based contour distances, Dice and IoU, NCC / SSIM / mutual information / gradient correlation,
//! and absolute differences (written as heatmaps by `io`).
//!
//! Every function is pure (no global state, no printing), so a study can call them in parallel.

mod compare;
mod contours;
mod difference;
mod distances;
mod landmarks;
mod markers;
mod overlap;
mod region;
mod similarity;

pub use compare::{
    Comparison, ImageMetrics, MI_BINS, MaskPair, SilhouetteMetrics, compare, image_metrics,
    image_metrics_in, image_metrics_whole_and_in, read_mask_png, silhouette_metrics, union_masks,
};
pub use contours::{border_pixels, contour_points, contours, subpixel_boundary};
pub use difference::abs_difference;
pub use distances::{ContourDistances, directed_distances, edge_distance, percentile};
pub use landmarks::{
    Landmark, LandmarkShift, blob_centroid, landmark_shifts, parse_landmarks, read_landmarks,
};
pub use markers::marker_centroid;
pub use overlap::dice_iou;
pub use region::{REGION_MARGIN_PX, Region};
pub use similarity::{
    gradient_correlation, gradient_correlation_in, gradient_correlation_whole_and_in,
    mutual_information, mutual_information_in, ncc, ncc_in, ssim, ssim_in, ssim_whole_and_in,
};
pub(crate) use similarity::{sobel_at, three_rows};
