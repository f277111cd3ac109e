//! Attenuation of tissue: the Hounsfield units of the phantom's tissues (one table shared by the thickness
//! renderer and the synthetic CT, so both DRR models see the same attenuation) and the one law turning HU
//! into linear attenuation, `μ(HU) = μ_water · max(0, 1 + HU / 1000)`, used by the phantom's render scene
//! and by the CT volume renderer.

use super::Tissue;

/// Linear attenuation of water at the effective energy of a fluoroscope (~70 keV), mm⁻¹.
pub const MU_WATER_PER_MM: f64 = 0.0193;

/// CT number of a phantom tissue (HU): cortical bone ~1200, cancellous ~250, disc ~90, soft tissue ~40.
pub fn tissue_hu(t: Tissue) -> f64 {
    match t {
        Tissue::Air => -1000.0,
        Tissue::SoftTissue => 40.0,
        Tissue::Disc => 90.0,
        Tissue::Cortical => 1200.0,
        Tissue::Cancellous => 250.0,
    }
}

/// Linear attenuation (mm⁻¹) of a voxel or tissue of CT number `hu`:
/// `μ(HU) = μ_water · max(0, 1 + HU / 1000)` (air and below attenuate nothing).
#[inline]
pub fn mu_from_hu(hu: f64, mu_water_per_mm: f64) -> f64 {
    mu_water_per_mm * (1.0 + hu / 1000.0).max(0.0)
}

/// Attenuation of a phantom tissue (mm⁻¹), `μ(tissue_hu(t))` with [`MU_WATER_PER_MM`].
pub fn tissue_mu(t: Tissue) -> f64 {
    mu_from_hu(tissue_hu(t), MU_WATER_PER_MM)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn water_air_and_bone_follow_the_hounsfield_definition() {
        // HU = 1000 (μ − μ_water) / μ_water, inverted.
        assert_eq!(mu_from_hu(0.0, MU_WATER_PER_MM), MU_WATER_PER_MM);
        assert_eq!(mu_from_hu(-1000.0, MU_WATER_PER_MM), 0.0);
        assert_eq!(mu_from_hu(-3024.0, MU_WATER_PER_MM), 0.0);
        assert!((tissue_mu(Tissue::Cortical) - 2.2 * MU_WATER_PER_MM).abs() < 1e-15);
    }
}
