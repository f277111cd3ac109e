//! Files: atomic writes, float32 TIFF images, PNG previews, masks and heatmaps, the JSON sidecar every
//! image carries, and the products the tool writes (each image with its sidecar).

mod atomic;
mod heatmap;
mod image;
mod output_set;
mod ownership;
mod preview;
mod products;
mod sidecar;
mod xray;

pub use atomic::{
    create_new_with, process_running, remove_stale_temporaries, write_atomic, write_atomic_bytes,
    write_json,
};
pub use heatmap::{format_label, heatmap_rgb, write_heatmap_png};
pub use image::{
    ImageF32, decode_drr_tiff, read_tiff_f32, write_mask_png, write_preview_png, write_tiff_f32,
};
pub use output_set::{
    check_output_paths, check_output_set, check_spares_inputs, create_output_dir, same_file,
};
pub use ownership::{SLICER_DESCRIPTION, TOOL, check_kind, check_ours, check_ours_landmarks};
pub use preview::{png_preview, posterise};
pub use products::{
    DrrProducts, DrrValues, Silhouette, SilhouetteOf, difference_set_kind, difference_set_paths,
    drr_set_kind, drr_set_paths, read_with_sidecar, sibling, write_depth, write_difference,
    write_difference_heatmap, write_difference_set, write_drr, write_drr_set, write_masks,
};
pub use sidecar::{Sidecar, kind, sidecar_path, units};
#[cfg(feature = "gpu")]
pub(crate) use xray::gaussian_taps;
pub use xray::{XrayModel, expected_counts, gaussian_blur, poisson_counts};
