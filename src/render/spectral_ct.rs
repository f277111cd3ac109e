//! Spectral (polychromatic) DRRs of a CT: the voxels become soft tissue and cortical bone
//! ([`crate::spectral::hu_to_densities`]), each material's mass thickness is one Siddon render of its
//! density grid, and the energy sum ([`EnergyKernel`]) turns them into `−ln(I/I0)`.

use std::time::Instant;

use super::spectral::{SpectralDrr, energy_sum};
use super::volume::VolumeRenderer;
use crate::Result;
use crate::geometry::View;
use crate::spectral::{
    CT_MATERIALS, Channel, EnergyKernel, Material, SpectralModel, hu_to_densities,
};

/// The per-material volume renderers of a CT under one spectral model.
pub struct SpectralCtRenderer {
    pub model: SpectralModel,
    pub channels: Vec<Channel>,
    kernel: EnergyKernel,
    renderers: Vec<VolumeRenderer>,
}

impl SpectralCtRenderer {
    /// From the CT's monochromatic renderer (its grid, placement and mask) and the CT's HU values.
    pub fn new(base: &VolumeRenderer, hu: &[f32], model: SpectralModel) -> Result<Self> {
        let channels = CT_MATERIALS
            .iter()
            .map(|m| Material::named(m).map(Channel::Material))
            .collect::<Result<Vec<_>>>()?;
        let renderers = (0..CT_MATERIALS.len())
            .map(|c| base.with_values(hu, move |h| hu_to_densities(h)[c]))
            .collect::<Result<Vec<_>>>()?;
        Ok(SpectralCtRenderer {
            kernel: model.kernel(&channels),
            model,
            channels,
            renderers,
        })
    }

    /// Renders `view`.
    pub fn render(&self, view: &View) -> SpectralDrr {
        let t0 = Instant::now();
        let maps: Vec<_> = self.renderers.iter().map(|r| r.render(view)).collect();
        let channels_ms = t0.elapsed().as_secs_f64() * 1e3;
        let t1 = Instant::now();
        let line_integral = energy_sum(&self.kernel, &maps);
        SpectralDrr {
            line_integral,
            channels_ms,
            energy_sum_ms: t1.elapsed().as_secs_f64() * 1e3,
            rays_unrepaired: 0,
        }
    }

    /// What the sidecar records: the model and the channels with the HU conversion.
    pub fn summary(&self) -> serde_json::Value {
        let mut s = self.model.summary();
        s["channels"] = serde_json::json!(CT_MATERIALS);
        s["hu_conversion"] = serde_json::json!(
            "HU <= 100: soft tissue at 1 + HU/1000 g/cm3; 100-1500 HU: soft tissue (1.10 g/cm3) and cortical \
             bone (1.92 g/cm3) mixed by volume, bone fraction (HU - 100)/1400; >= 1500 HU: cortical bone at \
             1.92 (1 + HU/1000)/2.5 g/cm3"
        );
        s
    }
}
