//! The spectral X-ray model: materials with NIST attenuation data, tube spectra (TASMIP or a file) and
//! their filtration, an energy-integrating detector, and the energy sum that makes a polychromatic image
//! from per-material path lengths. Depends only on the crate's error type; the renderers use it.
//!
//! * `nist`: the elements' μ/ρ and μ_en/ρ (NIST SRD 126) and their log–log spline interpolation.
//! * `materials`: compositions and densities of tissues, implant alloys and filters.
//! * `ct_materials`: Hounsfield units to per-material densities (soft tissue and cortical bone).
//! * `spectrum`: TASMIP spectra, spectrum files, filtration, mean energy and half-value layer.
//! * `detector`: the scintillator's absorbed fraction η(E).
//! * `model`: the detector weights and the per-pixel energy sum (f64, the reference).
//! * `kernel`: the same sum in vectorised f32, what images are made with.
//! * `spec`: the text forms (`--spectrum`, `--filter`, `--detector`, `MU` or `MATERIAL[@DENSITY]`).

mod ct_materials;
mod detector;
mod kernel;
mod materials;
mod model;
mod nist;
mod spec;
mod spectrum;
mod spline;

pub use ct_materials::{CT_MATERIALS, hu_to_densities};
pub use detector::Detector;
pub use kernel::EnergyKernel;
pub use materials::{MATERIALS, Material, MaterialAt};
pub use model::{Channel, SpectralModel};
pub use spec::{Attenuation, apply_filters, model_from_specs, parse_attenuation, parse_spectrum};
pub use spectrum::{Spectrum, TASMIP_KV};
