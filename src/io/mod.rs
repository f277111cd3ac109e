//! Files: atomic writes, float32 TIFF images, PNG previews and the JSON sidecar every image carries.

mod atomic;
mod image;
mod sidecar;

pub use atomic::{write_atomic, write_atomic_bytes};
pub use image::{ImageF32, read_tiff_f32, write_mask_png, write_preview_png, write_tiff_f32};
pub use sidecar::{Sidecar, sidecar_path};
