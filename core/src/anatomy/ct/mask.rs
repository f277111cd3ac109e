//! Voxel masks: which voxels of a CT grid take part (one vertebra's label, or bone by HU threshold),
//! with the tight index bounding box that lets a renderer skip rays that miss it.

use super::{CtVolume, LabelMap, Volume};
use crate::{Error, Result};

/// A boolean voxel mask on a grid, with the inclusive index bounding box of its set voxels.
#[derive(Debug, Clone, PartialEq)]
pub struct VoxelMask {
    pub dims: [usize; 3],
    pub keep: Vec<bool>,
    /// Inclusive `[lo, hi]` voxel index bounds of the kept voxels.
    pub bbox: ([usize; 3], [usize; 3]),
}

impl VoxelMask {
    /// Voxels of `seg` whose label is in `labels`. Errors if none is present (naming the labels found).
    pub fn from_labels(seg: &LabelMap, labels: &[u16]) -> Result<Self> {
        let keep: Vec<bool> = seg.values.iter().map(|v| labels.contains(v)).collect();
        Self::from_keep(seg, keep).ok_or_else(|| {
            let present = seg.labels_present();
            Error::invalid(
                "label",
                format!("{labels:?} not present in the segmentation (labels present: {present:?})"),
            )
        })
    }

    /// Voxels of `ct` at or above `hu_min` (e.g. 150 HU for bone).
    pub fn from_threshold(ct: &CtVolume, hu_min: f32) -> Result<Self> {
        let keep: Vec<bool> = ct.values.iter().map(|&v| v >= hu_min).collect();
        Self::from_keep(ct, keep)
            .ok_or_else(|| Error::invalid("threshold", format!("no voxel reaches {hu_min} HU")))
    }

    /// A mask from per-voxel flags on the grid of `grid`; `None` when no voxel is kept.
    pub fn from_keep<T: Copy>(grid: &Volume<T>, keep: Vec<bool>) -> Option<Self> {
        let [nx, ny, _] = grid.dims;
        let mut lo = [usize::MAX; 3];
        let mut hi = [0usize; 3];
        for (n, _) in keep.iter().enumerate().filter(|(_, k)| **k) {
            let idx = [n % nx, (n / nx) % ny, n / (nx * ny)];
            for a in 0..3 {
                lo[a] = lo[a].min(idx[a]);
                hi[a] = hi[a].max(idx[a]);
            }
        }
        (lo[0] != usize::MAX).then_some(VoxelMask {
            dims: grid.dims,
            keep,
            bbox: (lo, hi),
        })
    }

    /// Number of kept voxels.
    pub fn count(&self) -> usize {
        self.keep.iter().filter(|&&k| k).count()
    }
}
