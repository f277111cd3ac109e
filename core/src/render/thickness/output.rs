//! What a thickness render is asked for ([`ThicknessOptions`]) and what it produces ([`ThicknessDrr`]: the
//! line integral, optional depth map and silhouette [`Masks`], and the [`RenderStats`] counters).

use serde::Serialize;

use crate::Result;
use crate::anatomy::Structure;
use crate::io::{ImageF32, Silhouette, SilhouetteOf};

/// Counters of one render.
#[derive(Debug, Clone, Copy, Default, Serialize, PartialEq)]
pub struct RenderStats {
    pub rays_traced: u64,
    pub rays_culled: u64,
    pub hits: u64,
    pub rays_repaired: u64,
    pub rays_unrepaired: u64,
    /// A view the gpu backend rendered: the pixels evaluated on the CPU (those the GPU's sums cannot
    /// give, and every pixel an implant may cover); absent for CPU renders.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gpu_rays_on_cpu: Option<u64>,
    pub render_ms: f64,
}

impl RenderStats {
    /// The counters of two renders (or parts of one) together.
    pub(crate) fn add(mut self, o: RenderStats) -> RenderStats {
        self.rays_traced += o.rays_traced;
        self.rays_culled += o.rays_culled;
        self.hits += o.hits;
        self.rays_repaired += o.rays_repaired;
        self.rays_unrepaired += o.rays_unrepaired;
        self.gpu_rays_on_cpu = match (self.gpu_rays_on_cpu, o.gpu_rays_on_cpu) {
            (None, None) => None,
            (a, b) => Some(a.unwrap_or(0) + b.unwrap_or(0)),
        };
        self
    }
}

/// What a thickness DRR's sidecar records about its making (`details`).
#[derive(Debug, Clone, Serialize)]
pub struct ThicknessDetails {
    /// `thickness`.
    pub renderer: &'static str,
    /// `raster`, `embree`, `bvh` or `gpu`.
    pub backend: &'static str,
    /// The GPU adapter that rendered it (the gpu backend).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gpu_adapter: Option<String>,
    /// What was rendered, as its producer describes it (phantom levels, mesh files, μ).
    pub anatomy: serde_json::Value,
    pub stats: RenderStats,
}

/// Everything a thickness render produces.
#[derive(Debug, Clone)]
pub struct ThicknessDrr {
    /// Line integral `Σ μ L` (μ in mm⁻¹, so unitless; with μ = 1 it is thickness in mm).
    pub line_integral: ImageF32,
    /// Camera-frame depth (mm) of the first surface the ray enters, 0 outside the silhouette (when asked
    /// for).
    pub depth: Option<ImageF32>,
    /// Silhouettes per object and per structure (when asked for).
    pub masks: Option<Masks>,
    pub objects: Vec<String>,
    pub stats: RenderStats,
}

/// Per-pixel silhouette bits of a render.
#[derive(Debug, Clone, PartialEq)]
pub struct Masks {
    /// Per pixel, bit `i` set when the ray passes through object `i` (see [`ThicknessDrr::objects`]).
    pub object_bits: Vec<u64>,
    /// Per pixel, bit `s` set when the ray crosses a triangle labelled with [`Structure`] `s` of a mesh it
    /// passes through.
    pub structure_bits: Vec<u32>,
}

impl Masks {
    /// Silhouette of one object.
    pub fn object(&self, object: usize) -> Vec<bool> {
        self.object_bits
            .iter()
            .map(|b| b >> object & 1 == 1)
            .collect()
    }

    /// Silhouette of every object together.
    pub fn union(&self) -> Vec<bool> {
        self.object_bits.iter().map(|&b| b != 0).collect()
    }

    /// Silhouette of one structure over all objects.
    pub fn structure(&self, s: Structure) -> Vec<bool> {
        self.structure_bits
            .iter()
            .map(|b| b >> s as u32 & 1 == 1)
            .collect()
    }
}

impl ThicknessDrr {
    /// The silhouettes, or an error when the render was not asked for them.
    pub fn masks(&self) -> Result<&Masks> {
        self.masks.as_ref().ok_or_else(|| {
            crate::Error::invalid("render options", "silhouette masks were not requested")
        })
    }

    /// The silhouettes a render's mask files show: all objects together, each object, and each labelled
    /// structure seen in the image (or an error when the render was not asked for masks).
    pub fn silhouettes(&self) -> Result<Vec<Silhouette>> {
        let masks = self.masks()?;
        let mut out = vec![Silhouette {
            of: SilhouetteOf::AllObjects,
            pixels: masks.union(),
        }];
        for (i, name) in self.objects.iter().enumerate() {
            out.push(Silhouette {
                of: SilhouetteOf::Object(name.clone()),
                pixels: masks.object(i),
            });
        }
        for s in Structure::ALL {
            let pixels = masks.structure(s);
            if s != Structure::Unlabelled && pixels.iter().any(|&m| m) {
                out.push(Silhouette {
                    of: SilhouetteOf::Structure(s.name()),
                    pixels,
                });
            }
        }
        Ok(out)
    }

    /// The depth map, or an error when the render was not asked for it.
    pub fn depth(&self) -> Result<&ImageF32> {
        self.depth.as_ref().ok_or_else(|| {
            crate::Error::invalid("render options", "the depth map was not requested")
        })
    }
}

/// Options of a thickness render: which outputs beside the line integral, and culling.
#[derive(Debug, Clone, Copy)]
pub struct ThicknessOptions {
    /// Skip tiles no triangle projects into (no effect on the result, only on speed; the raster visits
    /// only covered pixels anyway).
    pub cull: bool,
    /// Compute silhouette masks (object and structure bits per pixel).
    pub masks: bool,
    /// Compute the first-hit depth map.
    pub depth: bool,
}

impl Default for ThicknessOptions {
    /// Every output, with culling.
    fn default() -> Self {
        ThicknessOptions {
            cull: true,
            masks: true,
            depth: true,
        }
    }
}

impl ThicknessOptions {
    /// The line integral alone (the DRR), with culling.
    pub fn image_only() -> Self {
        ThicknessOptions {
            masks: false,
            depth: false,
            ..Self::default()
        }
    }

    /// The line integral and silhouette masks, no depth map.
    pub fn with_masks() -> Self {
        ThicknessOptions {
            depth: false,
            ..Self::default()
        }
    }
}

/// Splits `v` into `n` bands of `band` elements, or `n` `None`s when `v` is empty (an output not asked for).
pub(super) fn bands<T>(v: &mut [T], band: usize, n: usize) -> Vec<Option<&mut [T]>> {
    if v.is_empty() {
        (0..n).map(|_| None).collect()
    } else {
        v.chunks_mut(band).map(Some).collect()
    }
}
