//! Spectral (polychromatic) DRRs of meshes: each mesh carries a mass thickness per material channel; the
//! channels' path-length maps are rendered once (one thickness render per channel, exact like every
//! thickness DRR), then [`SpectralModel`]'s energy sum turns them into the polychromatic line integral
//! `−ln(I/I0)`.
//!
//! Nested surfaces follow the differential rule per channel: a cancellous core inside a cortical shell
//! carries `+ρ_cancellous` on the cancellous channel and `−ρ_cortical` on the cortical one, so along every
//! ray each channel holds the mass thickness of exactly the material that is there.

use std::sync::Arc;
use std::time::Instant;

use rayon::prelude::*;
use serde_json::json;

use super::{Backend, RenderScene, RenderStats, SceneMesh, ThicknessOptions, ThicknessRenderer};
use crate::anatomy::TriMesh;
use crate::geometry::View;
use crate::io::ImageF32;
use crate::spectral::{Attenuation, Channel, EnergyKernel, MaterialAt, SpectralModel};
use crate::{Error, Result};

/// A closed surface and what it adds per channel: `(channel index, coefficient)`, the coefficient a
/// density (g/cm³) on a material channel or μ (mm⁻¹) on the fixed-μ channel, negative for a core that
/// displaces its shell's material.
#[derive(Debug, Clone)]
pub struct SpectralMesh {
    pub mesh: Arc<TriMesh>,
    pub object: String,
    pub terms: Vec<(usize, f64)>,
    /// An implant displaces every other mesh along each ray where it is
    /// ([`RenderScene::with_implants`]); its terms are absolute.
    pub implant: bool,
}

/// A mesh as the user gives it: its object, what it attenuates with, and whether it is an implant.
#[derive(Debug, Clone)]
pub struct SpectralInput {
    pub mesh: Arc<TriMesh>,
    pub object: String,
    pub attenuation: Attenuation,
    pub implant: bool,
}

/// Channels and the meshes that fill them.
#[derive(Debug, Clone)]
pub struct SpectralScene {
    pub channels: Vec<Channel>,
    pub meshes: Vec<SpectralMesh>,
}

impl SpectralScene {
    /// Checks every term names a channel and has a finite coefficient.
    pub fn new(channels: Vec<Channel>, meshes: Vec<SpectralMesh>) -> Result<Self> {
        for m in &meshes {
            for &(c, k) in &m.terms {
                if c >= channels.len() || !k.is_finite() {
                    return Err(Error::invalid(
                        format!("mesh '{}'", m.mesh.name),
                        format!("term ({c}, {k}): no such channel or not finite"),
                    ));
                }
            }
        }
        Ok(SpectralScene { channels, meshes })
    }

    /// The scene of `items`: a μ mesh fills the fixed-μ channel (keeping the differential-μ convention for
    /// nested μ meshes), a material mesh its material's channel with its density; a material mesh inside
    /// another material mesh displaces it ([`displace_nested`]), and an implant displaces everything
    /// along each ray where it is.
    /// Returns the scene and the warnings of meshes that lie partly inside another.
    pub fn from_meshes(items: Vec<SpectralInput>) -> Result<(Self, Vec<String>)> {
        let mut channels = Vec::new();
        let mut meshes = Vec::new();
        let mut material_of = Vec::new();
        for SpectralInput {
            mesh,
            object,
            attenuation: value,
            implant,
        } in items
        {
            let (terms, material) = match value {
                Attenuation::Mu(mu) => (
                    vec![(Self::channel_index(&mut channels, Channel::FixedMu), mu)],
                    None,
                ),
                Attenuation::Material(m) => {
                    let c = Self::channel_index(&mut channels, Channel::Material(m.material));
                    (vec![(c, m.density_g_cm3)], Some((c, m.density_g_cm3)))
                }
            };
            meshes.push(SpectralMesh {
                mesh,
                object,
                terms,
                implant,
            });
            material_of.push(if implant { None } else { material });
        }
        let warnings = displace_nested(&mut meshes, &material_of);
        Ok((SpectralScene::new(channels, meshes)?, warnings))
    }

    /// Adds an implant of `material`: it displaces every other mesh along each ray where it is.
    pub fn add_implant(&mut self, mesh: Arc<TriMesh>, object: String, material: MaterialAt) {
        let c = Self::channel_index(&mut self.channels, Channel::Material(material.material));
        self.meshes.push(SpectralMesh {
            mesh,
            object,
            terms: vec![(c, material.density_g_cm3)],
            implant: true,
        });
    }

    /// The index of `channel`, added when new.
    pub fn channel_index(channels: &mut Vec<Channel>, channel: Channel) -> usize {
        match channels.iter().position(|c| c.same(&channel)) {
            Some(i) => i,
            None => {
                channels.push(channel);
                channels.len() - 1
            }
        }
    }

    /// A thickness scene whose mesh μ is `mu(terms)`; meshes with μ = 0 are left out unless they are
    /// implants whose bounding box meets one of the scene's meshes' (their intervals displace the others
    /// even where they add nothing themselves). `None` when every μ is 0.
    fn scene_with(&self, mu: impl Fn(&[(usize, f64)]) -> f64) -> Result<Option<RenderScene>> {
        // Bounds of the meshes this scene attenuates with: an implant that overlaps none of them in space
        // displaces nothing here and is left out.
        let boxes: Vec<(glam::DVec3, glam::DVec3)> = self
            .meshes
            .iter()
            .filter(|m| !m.implant && mu(&m.terms) != 0.0)
            .filter_map(|m| m.mesh.bounds())
            .collect();
        let overlaps = |m: &TriMesh| {
            m.bounds().is_some_and(|(lo, hi)| {
                boxes
                    .iter()
                    .any(|(a, b)| lo.cmple(*b).all() && a.cmple(hi).all())
            })
        };
        let mut implants = Vec::new();
        let mut any = false;
        let meshes: Vec<SceneMesh> = self
            .meshes
            .iter()
            .filter_map(|m| {
                let mu_per_mm = mu(&m.terms);
                any |= mu_per_mm != 0.0;
                (mu_per_mm != 0.0 || (m.implant && overlaps(&m.mesh))).then(|| {
                    implants.push(m.implant);
                    SceneMesh {
                        mesh: Arc::clone(&m.mesh),
                        mu_per_mm,
                        object: m.object.clone(),
                    }
                })
            })
            .collect();
        if !any {
            return Ok(None);
        }
        RenderScene::new(meshes)?.with_implants(implants).map(Some)
    }
}

/// The renderers of a spectral scene under one model: per channel, or one pass for a one-bin spectrum.
pub struct SpectralRenderer {
    pub model: SpectralModel,
    pub channels: Vec<Channel>,
    kernel: EnergyKernel,
    passes: Passes,
    /// The gpu backend's energy sum: the channels (finished on the host, see
    /// `render::thickness::gpu`) are uploaded and summed on the GPU.
    #[cfg(feature = "gpu")]
    gpu_sum: Option<super::gpu::GpuEnergySum>,
}

enum Passes {
    /// One bin: one render with μ_k = Σ_c coefficient · t_c(E₀), the monochromatic DRR itself.
    Monochromatic(Option<ThicknessRenderer>),
    /// Per channel (index, renderer).
    Channels(Vec<(usize, ThicknessRenderer)>),
}

/// A spectral render: the polychromatic line integral and how long each part took.
pub struct SpectralDrr {
    /// `−ln(I/I0)` per pixel.
    pub line_integral: ImageF32,
    /// Time of the channel renders, ms.
    pub channels_ms: f64,
    /// Time of the energy sum, ms.
    pub energy_sum_ms: f64,
    /// Rays that did not pair their crossings, over all passes.
    pub rays_unrepaired: u64,
    /// The gpu backend's mesh renders: the pixels evaluated on the CPU over all passes (see
    /// [`super::RenderStats::gpu_rays_on_cpu`]; an implant's are among them), else `None`.
    pub gpu_rays_on_cpu: Option<u64>,
}

impl SpectralRenderer {
    /// Builds the per-channel (or the one monochromatic) renderers with `backend`.
    pub fn new(scene: &SpectralScene, model: SpectralModel, backend: Backend) -> Result<Self> {
        let table = model.channel_table(&scene.channels);
        let bins = model.bins();
        let passes = if model.is_monochromatic() {
            let mu = |terms: &[(usize, f64)]| terms.iter().map(|&(c, k)| k * table[c * bins]).sum();
            Passes::Monochromatic(match scene.scene_with(mu)? {
                Some(s) => Some(backend.renderer(s)?),
                None => None,
            })
        } else {
            let mut v = Vec::new();
            for c in 0..scene.channels.len() {
                let only_c =
                    |terms: &[(usize, f64)]| terms.iter().filter(|t| t.0 == c).map(|t| t.1).sum();
                if let Some(s) = scene.scene_with(only_c)? {
                    v.push((c, backend.renderer(s)?));
                }
            }
            Passes::Channels(v)
        };
        let kernel = model.kernel(&scene.channels);
        #[cfg(feature = "gpu")]
        let gpu_sum = match (&passes, backend) {
            (Passes::Channels(_), Backend::Gpu) => Some(super::gpu::GpuEnergySum::new(
                super::gpu::GpuContext::shared()?,
                &kernel,
            )?),
            _ => None,
        };
        Ok(SpectralRenderer {
            kernel,
            model,
            channels: scene.channels.clone(),
            passes,
            #[cfg(feature = "gpu")]
            gpu_sum,
        })
    }

    /// Renders `view`.
    pub fn render(&self, view: &View) -> Result<SpectralDrr> {
        let opts = ThicknessOptions::image_only();
        let t0 = Instant::now();
        let blank = || ImageF32::zeros(view.intrinsics.width, view.intrinsics.height);
        match &self.passes {
            Passes::Monochromatic(r) => {
                let (line_integral, stats) = match r {
                    Some(r) => {
                        let d = r.render(view, &opts)?;
                        (d.line_integral, d.stats)
                    }
                    None => (blank(), RenderStats::default()),
                };
                Ok(SpectralDrr {
                    line_integral,
                    channels_ms: t0.elapsed().as_secs_f64() * 1e3,
                    energy_sum_ms: 0.0,
                    rays_unrepaired: stats.rays_unrepaired,
                    gpu_rays_on_cpu: stats.gpu_rays_on_cpu,
                })
            }
            Passes::Channels(rs) => {
                let mut maps = vec![None; self.channels.len()];
                let mut stats = RenderStats::default();
                for (c, r) in rs {
                    let d = r.render(view, &opts)?;
                    stats = stats.add(d.stats);
                    maps[*c] = Some(d.line_integral);
                }
                let channels_ms = t0.elapsed().as_secs_f64() * 1e3;
                let t1 = Instant::now();
                let maps: Vec<ImageF32> =
                    maps.into_iter().map(|m| m.unwrap_or_else(blank)).collect();
                let line_integral = self.energy_sum(&maps)?;
                Ok(SpectralDrr {
                    line_integral,
                    channels_ms,
                    energy_sum_ms: t1.elapsed().as_secs_f64() * 1e3,
                    rays_unrepaired: stats.rays_unrepaired,
                    gpu_rays_on_cpu: stats.gpu_rays_on_cpu,
                })
            }
        }
    }

    /// Whether the energy sum runs on the GPU.
    fn gpu_sums(&self) -> bool {
        #[cfg(feature = "gpu")]
        if self.gpu_sum.is_some() {
            return true;
        }
        false
    }

    /// The energy sum of `maps`: on the GPU with the gpu backend, else the CPU kernel.
    fn energy_sum(&self, maps: &[ImageF32]) -> Result<ImageF32> {
        #[cfg(feature = "gpu")]
        if let Some(sum) = &self.gpu_sum {
            return sum.sum_maps(maps);
        }
        Ok(energy_sum(&self.kernel, maps))
    }

    /// The GPU adapter the channel renders run on (the gpu backend), else `None`.
    pub fn gpu_adapter(&self) -> Option<String> {
        match &self.passes {
            Passes::Monochromatic(r) => r.as_ref().and_then(ThicknessRenderer::gpu_adapter),
            Passes::Channels(v) => v.first().and_then(|(_, r)| r.gpu_adapter()),
        }
    }

    /// What the sidecar records beside the model: the channels (and the GPU adapter that rendered them,
    /// on the gpu backend).
    pub fn summary(&self) -> serde_json::Value {
        let mut s = self.model.summary();
        s["channels"] = json!(self.channels.iter().map(|c| c.name()).collect::<Vec<_>>());
        if let Some(adapter) = self.gpu_adapter() {
            s["gpu_adapter"] = adapter.into();
        }
        s["passes"] = json!(match &self.passes {
            Passes::Monochromatic(_) => "one render at the single energy".to_string(),
            Passes::Channels(v) if self.gpu_sums() => {
                format!(
                    "{} channel renders, then the energy sum on the GPU",
                    v.len()
                )
            }
            Passes::Channels(v) => format!("{} channel renders, then the energy sum", v.len()),
        });
        s
    }
}

/// The polychromatic line integral of per-channel maps (all of one size), per pixel
/// [`EnergyKernel::line_integral`], in parallel over rows.
pub fn energy_sum(kernel: &EnergyKernel, maps: &[ImageF32]) -> ImageF32 {
    let (w, h) = (maps[0].width, maps[0].height);
    let mut out = ImageF32::zeros(w, h);
    out.data
        .par_chunks_mut(w.max(1) as usize)
        .enumerate()
        .for_each_init(
            || (vec![0.0f32; maps.len()], kernel.scratch()),
            |(a, y), (v, row)| {
                let base = v * w as usize;
                for (u, px) in row.iter_mut().enumerate() {
                    for (c, m) in maps.iter().enumerate() {
                        a[c] = m.data[base + u];
                    }
                    *px = kernel.line_integral(a, y);
                }
            },
        );
    out
}

/// Makes every material mesh that lies inside another material mesh displace it: the innermost material
/// mesh containing it (all of up to 64 of its vertices, spread over the vertex list, inside by winding
/// number) gets its material's density subtracted on the inner mesh's terms, so the inner surface's
/// volume holds only the inner material. `material_of[i]` is mesh `i`'s (channel, density), `None` for a
/// fixed-μ mesh (which keeps the differential-μ convention and is left alone). Returns a warning per mesh
/// that lies partly inside another (its overlap is counted twice).
pub fn displace_nested(
    meshes: &mut [SpectralMesh],
    material_of: &[Option<(usize, f64)>],
) -> Vec<String> {
    let samples = |m: &TriMesh| -> Vec<glam::DVec3> {
        let n = m.vertices.len();
        let step = n.div_ceil(64).max(1);
        m.vertices.iter().step_by(step).copied().collect()
    };
    let mut warnings = Vec::new();
    let mut added = Vec::new();
    for (i, inner) in meshes.iter().enumerate() {
        if material_of[i].is_none() {
            continue;
        }
        let pts = samples(&inner.mesh);
        let mut containers = Vec::new();
        for (j, outer) in meshes.iter().enumerate() {
            if i == j || material_of[j].is_none() {
                continue;
            }
            let inside = pts
                .iter()
                .filter(|p| outer.mesh.winding_number(**p).abs() > 0.5)
                .count();
            if inside == pts.len() {
                containers.push(j);
            } else if inside > 0 {
                warnings.push(format!(
                    "mesh '{}' lies partly inside mesh '{}' ({inside} of {} sampled vertices): where they \
                     overlap both materials are counted",
                    inner.mesh.name,
                    outer.mesh.name,
                    pts.len()
                ));
            }
        }
        // The innermost container: the one inside all the others (the smallest bounding box).
        let innermost = containers.into_iter().min_by(|&a, &b| {
            let vol = |k: usize| {
                meshes[k]
                    .mesh
                    .bounds()
                    .map_or(0.0, |(lo, hi)| (hi - lo).x * (hi - lo).y * (hi - lo).z)
            };
            vol(a).total_cmp(&vol(b))
        });
        if let Some(j) = innermost {
            let (c, rho) = material_of[j].expect("containers are material meshes");
            added.push((i, (c, -rho)));
        }
    }
    for (i, term) in added {
        meshes[i].terms.push(term);
    }
    warnings
}
