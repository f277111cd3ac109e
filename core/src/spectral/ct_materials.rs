//! CT voxels as materials: the conversion from Hounsfield units to per-material densities the spectral CT
//! render uses, a two-component model in the spirit of Schneider, Bortfeld & Schlegel (Phys. Med. Biol.
//! 45:459, 2000), continuous and piecewise linear in HU like the monochromatic `μ(HU)`:
//!
//! * HU ≤ 100: soft tissue (ICRU 44) at the water-equivalent density `1 + HU/1000` g/cm³ (air at −1000
//!   HU and below: nothing; lung and fat are soft tissue at their low density);
//! * 100 < HU < 1500: a mixture by volume of that tissue at 1.10 g/cm³ (its density at 100 HU) and cortical
//!   bone (ICRU 44, 1.92 g/cm³), the bone's volume fraction `f = (HU − 100) / 1400`;
//! * HU ≥ 1500: cortical bone, its density scaled by `(1 + HU/1000) / 2.5` (denser than 1.92 above 1500 HU).
//!
//! Thresholding into air, soft tissue and bone (DeepDRR's conversion) would make a voxel at 349 HU and one
//! at 351 HU different materials; the mixture changes continuously, so a small HU change makes a small
//! image change, and each material's density is linear in HU within a segment, which keeps the per-material
//! Siddon integrals exact over the voxel grid.

/// The materials of the CT channels, in [`hu_to_densities`]' order.
pub const CT_MATERIALS: [&str; 2] = ["soft_tissue", "cortical_bone"];

/// Where soft tissue turns into the soft-tissue–bone mixture, and where the mixture is all bone (HU).
const MIX_FROM_HU: f32 = 100.0;
const BONE_AT_HU: f32 = 1500.0;
/// The densities at those points (g/cm³).
const SOFT_AT_MIX: f32 = 1.10;
const CORTICAL: f32 = 1.92;

/// Partial densities (g/cm³ of the voxel) of soft tissue and cortical bone in a voxel of `hu`.
#[inline]
pub fn hu_to_densities(hu: f32) -> [f32; 2] {
    if hu.is_nan() || hu <= -1000.0 {
        [0.0, 0.0]
    } else if hu <= MIX_FROM_HU {
        [1.0 + hu / 1000.0, 0.0]
    } else if hu < BONE_AT_HU {
        let f = (hu - MIX_FROM_HU) / (BONE_AT_HU - MIX_FROM_HU);
        [(1.0 - f) * SOFT_AT_MIX, f * CORTICAL]
    } else {
        [
            0.0,
            CORTICAL * (1.0 + hu / 1000.0) / (1.0 + BONE_AT_HU / 1000.0),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_conversion_is_continuous_and_follows_its_anchors() {
        assert_eq!(hu_to_densities(-1000.0), [0.0, 0.0]);
        assert_eq!(hu_to_densities(f32::NAN), [0.0, 0.0]);
        assert_eq!(hu_to_densities(0.0), [1.0, 0.0]);
        assert!((hu_to_densities(MIX_FROM_HU)[0] - SOFT_AT_MIX).abs() < 1e-6);
        let at_bone = hu_to_densities(BONE_AT_HU);
        assert!(at_bone[0].abs() < 1e-6 && (at_bone[1] - CORTICAL).abs() < 1e-6);
        // No jump anywhere: neighbouring HU give neighbouring densities.
        let mut prev = hu_to_densities(-1000.0);
        for i in -9990..30000 {
            let d = hu_to_densities(i as f32 * 0.1);
            assert!(
                (d[0] - prev[0]).abs() < 1e-3 && (d[1] - prev[1]).abs() < 1e-3,
                "{i}"
            );
            prev = d;
        }
    }
}
