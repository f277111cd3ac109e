//! `[intensity_registration]`: the intensity-based registration experiment — which phantom levels, view
//! sets, similarity, pyramid, X-ray image model, initial-mTRE bins and starts, and the Δf / piercing
//! grid; and its work cells (one per target, view set, Δf, piercing shift and initial-mTRE bin).

use serde::{Deserialize, Serialize};

use super::PhysicalGrid;
use super::fixed_image::{FixedImage, SpectralImageSection};
use crate::anatomy::parse_levels;
use crate::geometry::{CArm, Perturbation};
use crate::registration::intensity::Similarity;
use crate::{Error, Result};

/// Most starts per initial-mTRE bin.
pub const MAX_STARTS_PER_BIN: usize = 1000;

/// What the fixed images show.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FixedScope {
    /// The registered level alone (no neighbours, no discs, no soft tissue).
    Level,
    /// The whole phantom L1–L5 with discs and soft tissue (the realistic radiograph).
    Anatomy,
}

/// `[intensity_registration]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IntensitySection {
    /// Phantom levels registered (each on its own).
    pub targets: Vec<String>,
    /// View sets: a view of `geometry.views`, or several joined by `+` (`ap+lat`: similarities summed).
    pub views: Vec<String>,
    /// `ncc`, `gc`, `gncc`, `lncc` or `lncc:P`.
    pub similarity: String,
    /// Pyramid: binning factors of the study's detector, coarsest first, strictly decreasing.
    pub levels: Vec<u32>,
    /// CMA-ES at the coarsest level before the local refinement.
    pub global: bool,
    /// What the fixed images show: `level` or `anatomy`.
    pub fixed: FixedScope,
    /// Photons per pixel I0 of the fixed images' Poisson noise (0 = noise-free line integrals).
    pub photons: f64,
    /// Gaussian detector blur σ (px of the study's detector) of the fixed images (with photons > 0).
    pub blur_px: f64,
    /// Edges of the initial-mTRE bins (mm, increasing from ≥ 0): starts are uniform within each bin.
    pub init_mtre_mm: Vec<f64>,
    pub starts_per_bin: usize,
    /// Focal offsets Δf (px) of the assumed K.
    pub df_px: Vec<f64>,
    /// Piercing shifts p (px) of the assumed K, applied as (p, p); every Δf with every p.
    pub piercing_px: Vec<f64>,
    /// `[intensity_registration.physical]`: physical errors of the assumed geometry (focal spot or
    /// detector moved, detector rotated), each value of each key alone, after the Δf × piercing cells.
    /// A section without this table has none.
    #[serde(default = "PhysicalGrid::none")]
    pub physical: PhysicalGrid,
    /// The fixed images' models, each with every cell: `mono` (the moving DRR's own model), `spectral`
    /// (`[intensity_registration.spectral]`, no implants), `spectral+screws` (the same with two titanium
    /// pedicle screws per level). A section without this key has `mono` only.
    #[serde(default = "FixedImage::mono_only")]
    pub images: Vec<FixedImage>,
    /// `[intensity_registration.spectral]`: the spectral fixed images' technique.
    pub spectral: SpectralImageSection,
}

impl Default for IntensitySection {
    /// The default study's small grid: L3, AP+LAT, two coarse levels, Δf {0, 300} × piercing {0, 30},
    /// and two physical errors, the focal spot 4 mm along u and the detector rolled 2° (Warmerdam et
    /// al.'s sizes); starts in 0–5 and 5–10 mm.
    fn default() -> Self {
        IntensitySection {
            targets: vec!["L3".into()],
            views: vec!["ap+lat".into()],
            similarity: "ncc".into(),
            levels: vec![16, 8],
            global: true,
            fixed: FixedScope::Level,
            photons: 0.0,
            blur_px: 0.0,
            init_mtre_mm: vec![0.0, 5.0, 10.0],
            starts_per_bin: 1,
            df_px: vec![0.0, 300.0],
            piercing_px: vec![0.0, 30.0],
            physical: PhysicalGrid {
                src_dx_mm: vec![4.0],
                det_roll_deg: vec![2.0],
                ..PhysicalGrid::none()
            },
            images: vec![
                FixedImage::Mono,
                FixedImage::Spectral,
                FixedImage::SpectralScrews,
            ],
            spectral: SpectralImageSection::default(),
        }
    }
}

/// One work cell: every start of one initial-mTRE bin of one (target, view set, Δf, piercing) or (target,
/// view set, physical error).
#[derive(Debug, Clone, PartialEq)]
pub struct IntensityCell {
    pub target: String,
    pub views: String,
    /// Δf and piercing shift (0 for a physical cell).
    pub df_px: f64,
    pub piercing_px: f64,
    /// The physical error of a physical cell (one key alone), else None.
    pub physical: Option<Perturbation>,
    pub bin: usize,
    pub lo_mm: f64,
    pub hi_mm: f64,
    pub starts: usize,
    /// The fixed images' model.
    pub image: FixedImage,
}

impl IntensityCell {
    /// File-name-safe id.
    pub fn id(&self) -> String {
        let views = self.views.replace('+', "_");
        let id = match &self.physical {
            Some(p) => format!(
                "int_{}_{views}_{}_b{}",
                self.target,
                p.to_string().replace(['=', ','], ""),
                self.bin
            ),
            None => format!(
                "int_{}_{views}_df{}_p{}_b{}",
                self.target, self.df_px, self.piercing_px, self.bin
            ),
        };
        match self.image {
            FixedImage::Mono => id,
            other => format!("{id}_{}", other.id()),
        }
    }

    /// The assumed geometry's error in words.
    pub fn error_text(&self) -> String {
        match &self.physical {
            Some(p) => format!("the physical error {p}"),
            None => format!("Δf = {} px, piercing = {} px", self.df_px, self.piercing_px),
        }
    }

    pub fn describe(&self) -> String {
        format!(
            "intensity registration of '{}' in {} under {}, initial mTRE {}–{} mm, {} fixed images",
            self.target,
            self.views,
            self.error_text(),
            self.lo_mm,
            self.hi_mm,
            self.image
        )
    }

    /// The seed key of this cell's starts: the same for every fixed-image model, so `mono` and
    /// `spectral` start from the same poses with the same optimiser seeds (a paired comparison).
    pub fn seed_key(&self) -> String {
        match &self.physical {
            Some(p) => format!("int/{}/{}/{p}/{}", self.target, self.views, self.bin),
            None => format!(
                "int/{}/{}/{}/{}/{}",
                self.target, self.views, self.df_px, self.piercing_px, self.bin
            ),
        }
    }

    /// The assumed geometry's perturbation (intrinsic, or the physical error).
    pub fn perturbation(&self) -> Perturbation {
        match self.physical {
            Some(p) => p,
            None => Perturbation {
                df_px: self.df_px,
                ..Perturbation::piercing(self.piercing_px, self.piercing_px)
            },
        }
    }
}

impl IntensitySection {
    /// The quick grid's section: the last view set, Δf {0, 300} without piercing, one start in 0–5 mm,
    /// the first fixed-image model only (a spectral one with screws, whose starts fail, costs five times
    /// a monochromatic one; its technique is still validated and the screws experiment renders it), the
    /// pyramid's binning divided by `extra_binning` (the quick grid's coarser detector), so its pixels
    /// stay the same size.
    pub fn quick(&self, extra_binning: u32) -> Self {
        let mut levels: Vec<u32> = self
            .levels
            .iter()
            .map(|b| (b / extra_binning.max(1)).max(1))
            .collect();
        levels.dedup();
        IntensitySection {
            views: self.views.last().cloned().into_iter().collect(),
            levels,
            init_mtre_mm: vec![0.0, 5.0],
            starts_per_bin: 1,
            df_px: vec![0.0, 300.0],
            piercing_px: vec![0.0],
            physical: self.physical.first_only(),
            images: self.images.first().copied().into_iter().collect(),
            ..self.clone()
        }
    }

    /// The similarity (validated).
    pub fn similarity(&self) -> Result<Similarity> {
        Similarity::parse(&self.similarity)
            .map_err(|e| Error::invalid("intensity_registration.similarity", e.to_string()))
    }

    /// The view names of a view set (`ap+lat` → `["ap", "lat"]`).
    pub fn view_names(set: &str) -> Vec<&str> {
        set.split('+').collect()
    }

    /// Every cell in table order: target, view set, fixed-image model, then Δf, piercing, bin, then each
    /// physical error (validated before; a grid that fails to parse has none here), bin.
    pub fn cells(&self) -> Vec<IntensityCell> {
        let mut out = Vec::new();
        let physical = self.physical.cells().unwrap_or_default();
        for t in &self.targets {
            for v in &self.views {
                for &image in &self.images {
                    let cell = |df_px, piercing_px, physical, bin, w: &[f64]| IntensityCell {
                        target: t.clone(),
                        views: v.clone(),
                        df_px,
                        piercing_px,
                        physical,
                        bin,
                        lo_mm: w[0],
                        hi_mm: w[1],
                        starts: self.starts_per_bin,
                        image,
                    };
                    for &df_px in &self.df_px {
                        for &piercing_px in &self.piercing_px {
                            for (bin, w) in self.init_mtre_mm.windows(2).enumerate() {
                                out.push(cell(df_px, piercing_px, None, bin, w));
                            }
                        }
                    }
                    for p in &physical {
                        for (bin, w) in self.init_mtre_mm.windows(2).enumerate() {
                            out.push(cell(0.0, 0.0, Some(*p), bin, w));
                        }
                    }
                }
            }
        }
        out
    }

    /// Checks every key against the study's views (`study_views`) and C-arm.
    pub fn validate(&self, carm: &CArm, study_views: &[String]) -> Result<()> {
        let key = |k: &str| format!("intensity_registration.{k}");
        if self.targets.is_empty() {
            return Err(Error::invalid(
                key("targets"),
                "must list at least one level",
            ));
        }
        for (i, t) in self.targets.iter().enumerate() {
            let levels =
                parse_levels(t).map_err(|e| Error::invalid(key("targets"), e.to_string()))?;
            if levels.len() != 1 {
                return Err(Error::invalid(
                    key("targets"),
                    format!("'{t}' must name one phantom level (L1 … L5)"),
                ));
            }
            if self.targets[..i].contains(t) {
                return Err(Error::invalid(
                    key("targets"),
                    format!("'{t}' is listed twice"),
                ));
            }
        }
        if self.views.is_empty() {
            return Err(Error::invalid(
                key("views"),
                "must list at least one view set",
            ));
        }
        for (i, set) in self.views.iter().enumerate() {
            let names = Self::view_names(set);
            for (j, n) in names.iter().enumerate() {
                if !study_views.iter().any(|v| v == n) {
                    return Err(Error::invalid(
                        key("views"),
                        format!(
                            "'{set}': view '{n}' is not one of geometry.views ({})",
                            study_views.join(", ")
                        ),
                    ));
                }
                if names[..j].contains(n) {
                    return Err(Error::invalid(
                        key("views"),
                        format!("'{set}' repeats '{n}'"),
                    ));
                }
            }
            if self.views[..i].contains(set) {
                return Err(Error::invalid(
                    key("views"),
                    format!("'{set}' is listed twice"),
                ));
            }
        }
        self.similarity()?;
        if self.levels.is_empty() {
            return Err(Error::invalid(
                key("levels"),
                "must list at least one binning factor",
            ));
        }
        if self.levels.iter().any(|&b| b == 0 || b > 64)
            || self.levels.windows(2).any(|w| w[1] >= w[0])
        {
            return Err(Error::invalid(
                key("levels"),
                format!(
                    "binning factors must be 1…64, coarsest first and strictly decreasing, got {:?}",
                    self.levels
                ),
            ));
        }
        if !(self.photons.is_finite() && self.photons >= 0.0) {
            return Err(Error::invalid(
                key("photons"),
                format!(
                    "must be ≥ 0 photons per pixel (0 = noise-free), got {}",
                    self.photons
                ),
            ));
        }
        if !(self.blur_px.is_finite() && self.blur_px >= 0.0) {
            return Err(Error::invalid(
                key("blur_px"),
                format!("must be a finite σ ≥ 0 px, got {}", self.blur_px),
            ));
        }
        if self.blur_px > 0.0 && self.photons == 0.0 {
            return Err(Error::invalid(
                key("blur_px"),
                "blur is part of the X-ray image model: set photons > 0 too",
            ));
        }
        let e = &self.init_mtre_mm;
        if e.len() < 2
            || e.iter().any(|x| !x.is_finite())
            || e[0] < 0.0
            || e.windows(2).any(|w| w[1] <= w[0])
        {
            return Err(Error::invalid(
                key("init_mtre_mm"),
                format!("bin edges must be ≥ 2 finite, increasing values from ≥ 0 mm, got {e:?}"),
            ));
        }
        if self.starts_per_bin == 0 || self.starts_per_bin > MAX_STARTS_PER_BIN {
            return Err(Error::invalid(
                key("starts_per_bin"),
                format!(
                    "must be 1…{MAX_STARTS_PER_BIN}, got {}",
                    self.starts_per_bin
                ),
            ));
        }
        for (k, list) in [("df_px", &self.df_px), ("piercing_px", &self.piercing_px)] {
            if list.is_empty() {
                return Err(Error::invalid(key(k), "must list at least one value"));
            }
            for (i, x) in list.iter().enumerate() {
                if !x.is_finite() {
                    return Err(Error::invalid(key(k), format!("{x} is not finite")));
                }
                if list[..i].contains(x) {
                    return Err(Error::invalid(key(k), format!("{x} is listed twice")));
                }
            }
        }
        self.physical.cells_of(&key("physical"))?;
        if self.images.is_empty() {
            return Err(Error::invalid(
                key("images"),
                "must list at least one of mono, spectral, spectral+screws",
            ));
        }
        super::validate::unique(&key("images"), &self.images, |i| i.name())?;
        if self.images.iter().any(|i| i.is_spectral()) {
            self.spectral.model()?;
        }
        for c in self.cells().iter().filter(|c| c.bin == 0) {
            for n in Self::view_names(&c.views) {
                let v = carm.view(n)?;
                v.perturbed(&c.perturbation()).map_err(|e| {
                    let k = if c.physical.is_some() {
                        "physical"
                    } else {
                        "df_px"
                    };
                    Error::invalid(key(k), format!("{} in view '{n}': {e}", c.error_text()))
                })?;
            }
        }
        Ok(())
    }
}
