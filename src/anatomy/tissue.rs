//! Hounsfield units of the phantom's tissues: one table shared by the thickness renderer (through
//! `μ(HU)`) and the synthetic CT, so both DRR models see the same attenuation.

use super::Tissue;

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
