//! Attenuation of tissue: the Hounsfield units of the phantom's tissues (one table shared by the thickness
//! renderer and the synthetic CT, so both DRR models see the same attenuation) and the one law turning HU
//! into linear attenuation, `μ(HU) = μ_water · max(0, 1 + HU / 1000)`, used by the phantom's render scene
//! and by the CT volume renderer.

use std::ops::{Add, Div, Mul};

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
/// `μ(HU) = μ_water · max(0, 1 + HU / 1000)` (air and below, and NaN, attenuate nothing). Generic over the
/// float type so that the f32 voxel grid of the CT renderer and the f64 tissue table evaluate the same law
/// in their own precision.
#[inline]
pub fn mu_from_hu<F>(hu: F, mu_water_per_mm: F) -> F
where
    F: Copy + PartialOrd + From<i16> + Add<Output = F> + Div<Output = F> + Mul<Output = F>,
{
    let relative = F::from(1) + hu / F::from(1000);
    let zero = F::from(0);
    mu_water_per_mm * if relative > zero { relative } else { zero }
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
        assert_eq!(mu_from_hu(f32::NAN, 0.02f32), 0.0);
        // The f32 law rounds as the direct f32 expression does.
        for hu in [-1024.0f32, -999.5, -3.0, 0.5, 40.0, 700.0, 1200.0, 3071.0] {
            assert_eq!(
                mu_from_hu(hu, 0.0193f32),
                0.0193f32 * (1.0 + hu / 1000.0).max(0.0)
            );
        }
    }
}
