//! Voxel volumes on a world grid: CT intensities (HU) and segmentation label maps, NIfTI I/O, masks.
//!
//! A [`Volume`] stores its voxels x-fastest (NIfTI's Fortran order): voxel `(i, j, k)` is
//! `values[i + nx · (j + ny · k)]`. Its `index_to_world` affine maps the continuous index of a voxel
//! centre to world millimetres (RAS+), so voxel `(i, j, k)` covers the index box `[i ± ½] × [j ± ½] × [k ± ½]`.

mod mask;
mod nifti;
mod nifti_header;
mod placement;
mod surface;

use std::path::Path;

use glam::{DMat4, DVec3};

use crate::{Error, Result};

pub use mask::VoxelMask;
pub use nifti::{
    MAX_ABS_HU, affine_from_header, looks_like_label_map, read_ct, read_ct_from, read_labels,
    read_labels_from, write_ct, write_labels,
};
pub use nifti_header::MAX_VOXELS;
pub use placement::{
    Alignment, Placed, Placement, anatomical_motion, mask_centre, move_volume, place, rotation_deg,
    volume_centre,
};
pub use surface::{
    MAX_SMOOTH_ITERATIONS, SurfaceOptions, label_surface, largest_component, taubin_smooth,
};

/// A 3-D voxel grid with a world affine.
#[derive(Debug, Clone, PartialEq)]
pub struct Volume<T> {
    /// `[nx, ny, nz]`.
    pub dims: [usize; 3],
    /// `nx · ny · nz` voxels, x fastest.
    pub values: Vec<T>,
    /// Voxel index (voxel centres at integers) → world millimetres, RAS+.
    pub index_to_world: DMat4,
}

/// A CT volume in Hounsfield units.
pub type CtVolume = Volume<f32>;
/// A segmentation: one integer label per voxel, 0 = background.
pub type LabelMap = Volume<u16>;

impl<T: Copy> Volume<T> {
    /// A volume, checked: `values.len() == nx·ny·nz`, no zero dimension, a finite invertible affine
    /// with last row `[0, 0, 0, 1]`.
    pub fn new(dims: [usize; 3], values: Vec<T>, index_to_world: DMat4) -> Result<Self> {
        if dims.contains(&0) {
            return Err(Error::invalid(
                "dims",
                format!("{dims:?} has a zero extent"),
            ));
        }
        let n = dims[0]
            .checked_mul(dims[1])
            .and_then(|v| v.checked_mul(dims[2]));
        if n != Some(values.len()) {
            return Err(Error::invalid(
                "values",
                format!("{} voxels for dims {dims:?}", values.len()),
            ));
        }
        check_affine(&index_to_world)?;
        Ok(Volume {
            dims,
            values,
            index_to_world,
        })
    }

    /// A volume of `dims` filled with `value`.
    pub fn filled(dims: [usize; 3], value: T, index_to_world: DMat4) -> Result<Self> {
        let n = dims.iter().product();
        Volume::new(dims, vec![value; n], index_to_world)
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.values.len()
    }

    /// Always false for a checked volume (no zero dimension); here for clippy's `len` convention.
    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// Linear index of voxel `(i, j, k)`.
    #[inline]
    pub fn linear(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }

    /// Voxel `(i, j, k)`; panics out of range, like slice indexing.
    #[inline]
    pub fn get(&self, i: usize, j: usize, k: usize) -> T {
        self.values[self.linear(i, j, k)]
    }

    /// The inverse affine, world millimetres → continuous voxel index.
    pub fn world_to_index(&self) -> DMat4 {
        self.index_to_world.inverse()
    }

    /// World position of the centre of voxel `(i, j, k)`.
    pub fn voxel_centre(&self, i: usize, j: usize, k: usize) -> DVec3 {
        self.index_to_world
            .transform_point3(DVec3::new(i as f64, j as f64, k as f64))
    }

    /// Voxel spacing along each index axis (mm): the lengths of the affine's columns.
    pub fn spacing_mm(&self) -> DVec3 {
        DVec3::new(
            self.index_to_world.x_axis.truncate().length(),
            self.index_to_world.y_axis.truncate().length(),
            self.index_to_world.z_axis.truncate().length(),
        )
    }

    /// Volume of one voxel (mm³): `|det A|` of the linear part.
    pub fn voxel_volume_mm3(&self) -> f64 {
        self.index_to_world.determinant().abs()
    }

    /// True when `other` has the same dims and (to 1e-6 mm) the same affine.
    pub fn same_grid<U>(&self, other: &Volume<U>) -> bool {
        let a = self.index_to_world.to_cols_array();
        let b = other.index_to_world.to_cols_array();
        self.dims == other.dims && a.iter().zip(b.iter()).all(|(x, y)| (x - y).abs() <= 1e-6)
    }

    /// Checks that `other` (read from `other_path`) lies on this volume's grid (read from `path`), as a
    /// label map must lie on its CT's: the same dims and, to 1e-3 mm, the same index→world affine. The
    /// error names the label file and the field that differs (`dim`, or the affine's voxel axes —
    /// `srow`/`pixdim` — or origin) with both values.
    pub fn check_grid_of<U>(
        &self,
        path: &Path,
        other: &Volume<U>,
        other_path: &Path,
    ) -> Result<()> {
        let whose = format!("the CT's ({})", path.display());
        if self.dims != other.dims {
            return Err(Error::format(
                other_path,
                format!(
                    "dim {:?} differs from {whose} {:?}: the label map must be on the CT's grid \
                     (resample it onto the CT)",
                    other.dims, self.dims
                ),
            ));
        }
        let (a, b) = (self.index_to_world, other.index_to_world);
        let names = ["i", "j", "k"];
        for (c, name) in names.iter().enumerate() {
            let (ca, cb) = (a.col(c).truncate(), b.col(c).truncate());
            if (ca - cb).abs().max_element() > 1e-3 {
                return Err(Error::format(
                    other_path,
                    format!(
                        "affine (sform/qform) voxel axis {name} is {:?} mm, {whose} is {:?} mm: the \
                         label map's orientation or spacing disagrees with the CT's (resample it onto \
                         the CT)",
                        cb.to_array(),
                        ca.to_array()
                    ),
                ));
            }
        }
        let (oa, ob) = (a.col(3).truncate(), b.col(3).truncate());
        if (oa - ob).abs().max_element() > 1e-3 {
            return Err(Error::format(
                other_path,
                format!(
                    "affine (sform/qform) origin (voxel 0, 0, 0) is at {:?} mm, {whose} at {:?} mm: \
                     the label map is shifted against the CT (resample it onto the CT)",
                    ob.to_array(),
                    oa.to_array()
                ),
            ));
        }
        Ok(())
    }

    /// The sub-volume of voxels `lo..=hi` (inclusive index bounds) at the same world positions: voxel
    /// `(i, j, k)` of the crop is voxel `lo + (i, j, k)` of `self` (affine `A · T(lo)`).
    pub fn crop(&self, lo: [usize; 3], hi: [usize; 3]) -> Result<Volume<T>> {
        if (0..3).any(|a| lo[a] > hi[a] || hi[a] >= self.dims[a]) {
            return Err(Error::invalid(
                "crop",
                format!("{lo:?}..={hi:?} is not inside dims {:?}", self.dims),
            ));
        }
        let dims = [0, 1, 2].map(|a| hi[a] - lo[a] + 1);
        let mut values = Vec::with_capacity(dims.iter().product());
        for k in lo[2]..=hi[2] {
            for j in lo[1]..=hi[1] {
                let row = self.linear(lo[0], j, k);
                values.extend_from_slice(&self.values[row..row + dims[0]]);
            }
        }
        let shift = DVec3::new(lo[0] as f64, lo[1] as f64, lo[2] as f64);
        Volume::new(
            dims,
            values,
            self.index_to_world * DMat4::from_translation(shift),
        )
    }

    /// The same grid with other values.
    pub fn map<U, F: Fn(T) -> U + Sync>(&self, f: F) -> Volume<U> {
        Volume {
            dims: self.dims,
            values: self.values.iter().map(|&v| f(v)).collect(),
            index_to_world: self.index_to_world,
        }
    }
}

impl LabelMap {
    /// The distinct non-zero labels present, ascending.
    pub fn labels_present(&self) -> Vec<u16> {
        let mut seen = vec![false; u16::MAX as usize + 1];
        for &v in &self.values {
            seen[v as usize] = true;
        }
        (1..=u16::MAX).filter(|&l| seen[l as usize]).collect()
    }

    /// Number of voxels carrying `label`.
    pub fn count(&self, label: u16) -> usize {
        self.values.iter().filter(|&&v| v == label).count()
    }
}

/// Rejects a non-finite, singular or non-affine 4×4 index→world matrix.
pub fn check_affine(m: &DMat4) -> Result<()> {
    let a = m.to_cols_array();
    if a.iter().any(|v| !v.is_finite()) {
        return Err(Error::invalid("affine", "has non-finite entries"));
    }
    if m.row(3) != glam::DVec4::new(0.0, 0.0, 0.0, 1.0) {
        return Err(Error::invalid(
            "affine",
            format!("last row must be [0, 0, 0, 1], got {:?}", m.row(3)),
        ));
    }
    let det = m.determinant();
    let scale =
        m.x_axis.truncate().length() * m.y_axis.truncate().length() * m.z_axis.truncate().length();
    if scale == 0.0 || det.abs() <= 1e-9 * scale {
        return Err(Error::invalid(
            "affine",
            format!("is singular (determinant {det:e}): voxel axes are degenerate"),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crop_keeps_every_voxel_at_its_world_position() {
        let a = DMat4::from_cols_array(&[
            0.0, 0.9, 0.0, 0.0, -0.8, 0.0, 0.0, 0.0, 0.0, 0.0, 1.25, 0.0, 5.0, -3.0, 100.0, 1.0,
        ]);
        let dims = [7, 6, 5];
        let n: usize = dims.iter().product();
        let vol = Volume::new(dims, (0..n as u32).collect(), a).unwrap();
        let (lo, hi) = ([2, 1, 0], [5, 4, 3]);
        let c = vol.crop(lo, hi).unwrap();
        assert_eq!(c.dims, [4, 4, 4]);
        for k in 0..4 {
            for j in 0..4 {
                for i in 0..4 {
                    let (oi, oj, ok) = (i + lo[0], j + lo[1], k + lo[2]);
                    assert_eq!(c.get(i, j, k), vol.get(oi, oj, ok));
                    let d = c.voxel_centre(i, j, k) - vol.voxel_centre(oi, oj, ok);
                    assert!(d.length() < 1e-12);
                }
            }
        }
        assert!(vol.crop([0, 0, 0], [7, 0, 0]).is_err());
        assert!(vol.crop([3, 0, 0], [2, 0, 0]).is_err());
    }
}
