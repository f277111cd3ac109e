//! The phantom voxelized into a synthetic CT (Hounsfield units) and a matching label map, so the mesh
//! (thickness) DRR and the CT volume DRR can be compared on one anatomy.
//!
//! Each voxel's HU is the mean of `s³` point samples of [`Phantom::classify`] on a regular sub-grid of
//! the voxel (a box-filter partial-volume model; `s = 1` samples the centre only). Labels are assigned
//! at the voxel centre: the level's id in the chosen [`LabelConvention`] where a vertebra's SDF < 0.

use glam::{DMat4, DVec3};
use rayon::prelude::*;

use super::ct::{CtVolume, LabelMap, Volume};
use super::labels::{self, LabelConvention};
use super::{Phantom, Tissue};
use crate::{Error, Result};

/// Hounsfield units of the phantom's tissues.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TissueHu {
    pub air: f32,
    pub soft_tissue: f32,
    pub disc: f32,
    pub cortical: f32,
    pub cancellous: f32,
}

impl Default for TissueHu {
    fn default() -> Self {
        // The table the thickness renderer uses too, so both DRR models see the same attenuation.
        let hu = |t| super::tissue_hu(t) as f32;
        TissueHu {
            air: hu(Tissue::Air),
            soft_tissue: hu(Tissue::SoftTissue),
            disc: hu(Tissue::Disc),
            cortical: hu(Tissue::Cortical),
            cancellous: hu(Tissue::Cancellous),
        }
    }
}

impl TissueHu {
    pub fn of(&self, t: Tissue) -> f32 {
        match t {
            Tissue::Air => self.air,
            Tissue::SoftTissue => self.soft_tissue,
            Tissue::Disc => self.disc,
            Tissue::Cortical => self.cortical,
            Tissue::Cancellous => self.cancellous,
        }
    }
}

/// Options of [`synthetic_ct`].
#[derive(Debug, Clone, PartialEq)]
pub struct SyntheticCtOptions {
    /// Isotropic voxel size (mm).
    pub voxel_mm: f64,
    /// Sub-samples per axis per voxel (partial-volume averaging).
    pub supersample: usize,
    /// Air margin around the phantom's meshes (mm).
    pub margin_mm: f64,
    pub hu: TissueHu,
    pub labels: LabelConvention,
}

impl Default for SyntheticCtOptions {
    fn default() -> Self {
        SyntheticCtOptions {
            voxel_mm: 0.5,
            supersample: 2,
            margin_mm: 5.0,
            hu: TissueHu::default(),
            labels: LabelConvention::TotalSegmentator,
        }
    }
}

/// Voxelizes `phantom` on an axis-aligned RAS+ grid covering its meshes plus the margin.
pub fn synthetic_ct(phantom: &Phantom, opts: &SyntheticCtOptions) -> Result<(CtVolume, LabelMap)> {
    if !(opts.voxel_mm.is_finite() && opts.voxel_mm > 0.0) {
        return Err(Error::invalid(
            "voxel_mm",
            format!("{} must be positive", opts.voxel_mm),
        ));
    }
    if !(1..=8).contains(&opts.supersample) {
        return Err(Error::invalid(
            "supersample",
            format!("{} not in 1..=8", opts.supersample),
        ));
    }
    let (lo, hi) = phantom_bounds(phantom)?;
    let (lo, hi) = (
        lo - DVec3::splat(opts.margin_mm),
        hi + DVec3::splat(opts.margin_mm),
    );
    let h = opts.voxel_mm;
    let n = ((hi - lo) / h).ceil();
    // A float HU and a 16-bit label per voxel.
    super::check_grid_size(&format!("CT voxel_mm {h}"), (n + DVec3::ONE).to_array(), 6)?;
    let dims = [n.x as usize + 1, n.y as usize + 1, n.z as usize + 1];
    let affine = DMat4::from_scale_rotation_translation(DVec3::splat(h), Default::default(), lo);
    let ids: Vec<u16> = phantom
        .vertebrae
        .iter()
        .map(|v| {
            labels::Level::parse(v.level.name())
                .and_then(|l| opts.labels.id(l))
                .unwrap_or(0)
        })
        .collect();
    let [nx, ny, nz] = dims;
    let s = opts.supersample;
    let mut hu = vec![0f32; nx * ny * nz];
    let mut lab = vec![0u16; nx * ny * nz];
    hu.par_chunks_mut(nx * ny)
        .zip(lab.par_chunks_mut(nx * ny))
        .enumerate()
        .for_each(|(k, (hs, ls))| {
            for j in 0..ny {
                for i in 0..nx {
                    let c = DVec3::new(i as f64, j as f64, k as f64);
                    let mut sum = 0.0f64;
                    for (a, b, d) in sub_offsets(s) {
                        let p = affine.transform_point3(c + DVec3::new(a, b, d));
                        sum += f64::from(opts.hu.of(phantom.classify(p)));
                    }
                    hs[i + nx * j] = (sum / (s * s * s) as f64) as f32;
                    let p = affine.transform_point3(c);
                    ls[i + nx * j] = phantom
                        .vertebrae
                        .iter()
                        .position(|v| v.sdf(p) < 0.0)
                        .map_or(0, |m| ids[m]);
                }
            }
        });
    Ok((
        Volume::new(dims, hu, affine)?,
        Volume::new(dims, lab, affine)?,
    ))
}

/// Offsets (in voxels) of the `s³` sub-sample centres of a voxel.
fn sub_offsets(s: usize) -> impl Iterator<Item = (f64, f64, f64)> {
    let f = move |n: usize| (n as f64 + 0.5) / s as f64 - 0.5;
    (0..s * s * s).map(move |n| (f(n % s), f((n / s) % s), f(n / (s * s))))
}

fn phantom_bounds(p: &Phantom) -> Result<(DVec3, DVec3)> {
    let meshes = p
        .vertebrae
        .iter()
        .map(|v| &v.cortical)
        .chain(p.discs.iter())
        .chain(p.soft_tissue.iter());
    meshes
        .filter_map(|m| m.bounds())
        .reduce(|(a, b), (c, d)| (a.min(c), b.max(d)))
        .ok_or_else(|| Error::invalid("phantom", "has no mesh to voxelize"))
}
