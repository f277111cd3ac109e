//! Which voxels of a CT a volume DRR renders: those of one segmentation label, those at or above a bone
//! threshold, or both (their intersection).

use crate::anatomy::ct::{CtVolume, LabelMap, VoxelMask};
use crate::{Error, Result};

/// The voxels to render: of label `id` in `seg` (which must be on the CT's grid) when given, and at or
/// above `bone_hu` when given; `None` when neither is given (the whole volume). An empty selection is an
/// error naming what emptied it.
pub fn select_voxels(
    ct: &CtVolume,
    label: Option<(&LabelMap, u16)>,
    bone_hu: Option<f32>,
) -> Result<Option<VoxelMask>> {
    let label = match label {
        Some((seg, id)) => {
            if !ct.same_grid(seg) {
                return Err(Error::invalid(
                    "segmentation",
                    format!(
                        "not on the CT's grid (dims {:?} vs {:?}, or a different affine)",
                        seg.dims, ct.dims
                    ),
                ));
            }
            Some(VoxelMask::from_labels(seg, &[id])?)
        }
        None => None,
    };
    let Some(hu) = bone_hu else {
        return Ok(label);
    };
    let bone = VoxelMask::from_threshold(ct, hu)?;
    match label {
        None => Ok(Some(bone)),
        Some(label) => {
            let keep = label
                .keep
                .iter()
                .zip(&bone.keep)
                .map(|(a, b)| *a && *b)
                .collect();
            VoxelMask::from_keep(ct, keep).map(Some).ok_or_else(|| {
                Error::invalid(
                    "bone_hu",
                    format!("no voxel of the label reaches the threshold of {hu} HU"),
                )
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::DMat4;

    use super::*;

    #[test]
    fn label_and_threshold_intersect() {
        let mut ct = CtVolume::filled([4, 1, 1], 0.0, DMat4::IDENTITY).unwrap();
        let mut seg = LabelMap::filled([4, 1, 1], 0, DMat4::IDENTITY).unwrap();
        ct.values.copy_from_slice(&[500.0, 500.0, 0.0, 500.0]);
        seg.values.copy_from_slice(&[7, 7, 7, 0]);
        let both = select_voxels(&ct, Some((&seg, 7)), Some(150.0))
            .unwrap()
            .unwrap();
        assert_eq!(both.keep, [true, true, false, false]);
        let label = select_voxels(&ct, Some((&seg, 7)), None).unwrap().unwrap();
        assert_eq!(label.keep, [true, true, true, false]);
        assert!(select_voxels(&ct, None, None).unwrap().is_none());
        ct.values.copy_from_slice(&[0.0, 0.0, 0.0, 500.0]);
        let err = select_voxels(&ct, Some((&seg, 7)), Some(150.0)).unwrap_err();
        assert!(err.to_string().contains("150"), "{err}");
    }
}
