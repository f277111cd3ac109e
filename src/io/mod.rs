//! Files: atomic writes, float32 TIFF images, PNG previews, masks and heatmaps, the JSON sidecar every
//! image carries, and the products the tool writes (each image with its sidecar).

mod atomic;
mod heatmap;
mod image;
mod products;
mod sidecar;

pub use atomic::{write_atomic, write_atomic_bytes, write_json};
pub use heatmap::{format_label, heatmap_rgb, write_heatmap_png};
pub use image::{ImageF32, read_tiff_f32, write_mask_png, write_preview_png, write_tiff_f32};
pub use products::{
    DrrValues, Silhouette, SilhouetteOf, read_with_sidecar, sibling, write_depth, write_difference,
    write_difference_heatmap, write_drr, write_masks,
};
pub use sidecar::{Sidecar, kind, sidecar_path, units};
