//! Spectral (polychromatic) DRRs of a CT: the voxels become soft tissue and cortical bone
//! ([`crate::spectral::hu_to_densities`]), each material's mass thickness is one Siddon render of its
//! density grid, and the energy sum ([`EnergyKernel`]) turns them into `−ln(I/I0)`.
//!
//! Implants (a hybrid scene: the CT plus exact meshes) displace the CT exactly: along every ray that
//! meets one, the union of the implants' inside intervals is traced, each CT material's Siddon integral
//! over those intervals is subtracted from its map, and each implant material's own mass thickness (an
//! exact thickness render) is a channel of the energy sum — so the tissue a screw occupies is not counted.

use std::sync::Arc;
use std::time::Instant;

use glam::DVec3;
use rayon::prelude::*;

use super::spectral::{SpectralDrr, energy_sum};
use super::volume::VolumeRenderer;
use super::{Backend, RenderScene, SceneMesh, ThicknessOptions, ThicknessRenderer};
use crate::Result;
use crate::anatomy::TriMesh;
use crate::geometry::{Ray, View};
use crate::io::ImageF32;
use crate::spectral::{
    CT_MATERIALS, Channel, EnergyKernel, Material, MaterialAt, SpectralModel, hu_to_densities,
};

/// The implants of a hybrid CT scene.
struct Implants {
    /// Per implant material: its channel and the render of its meshes' mass thickness (μ = ρ).
    channels: Vec<(Channel, ThicknessRenderer)>,
    /// Every implant mesh (μ = 1): where along a ray the implants are.
    union: ThicknessRenderer,
    /// Meshes and materials, for the sidecar.
    described: Vec<serde_json::Value>,
}

/// The per-material volume renderers of a CT under one spectral model.
pub struct SpectralCtRenderer {
    pub model: SpectralModel,
    pub channels: Vec<Channel>,
    kernel: EnergyKernel,
    renderers: Vec<VolumeRenderer>,
    implants: Option<Implants>,
    /// The channels' renderers on the GPU (the gpu backend: [`Self::on_gpu`]), one per CT material, and
    /// the energy sum there.
    #[cfg(feature = "gpu")]
    gpu: Option<(Vec<super::gpu::GpuCtRenderer>, super::gpu::GpuEnergySum)>,
}

impl SpectralCtRenderer {
    /// From the CT's monochromatic renderer (its grid, placement and mask) and the CT's HU values.
    pub fn new(base: &VolumeRenderer, hu: &[f32], model: SpectralModel) -> Result<Self> {
        let channels = CT_MATERIALS
            .iter()
            .map(|m| Material::named(m).map(Channel::Material))
            .collect::<Result<Vec<_>>>()?;
        let renderers = (0..CT_MATERIALS.len())
            .map(|c| base.with_values(hu, move |h| hu_to_densities(h)[c]))
            .collect::<Result<Vec<_>>>()?;
        Ok(SpectralCtRenderer {
            kernel: model.kernel(&channels),
            model,
            channels,
            renderers,
            implants: None,
            #[cfg(feature = "gpu")]
            gpu: None,
        })
    }

    /// The same renderer with each CT material's channel rendered on the GPU of `ctx` (the same
    /// Siddon or trilinear integral as on the CPU, to ~1e-5) and the energy sum there too (the CPU
    /// kernel's log-sum-exp), one f32 per pixel read back. With implants ([`Self::with_implants`], before
    /// or after), the channels come back to the host, which cuts the implants out of them along each
    /// covered ray's paired crossings (as on the CPU), and the maps go back up for the sum.
    #[cfg(feature = "gpu")]
    pub fn on_gpu(mut self, ctx: Arc<super::gpu::GpuContext>) -> Result<Self> {
        let channels = self
            .renderers
            .iter()
            .map(|r| super::gpu::GpuCtRenderer::new(Arc::clone(&ctx), r))
            .collect::<Result<_>>()?;
        let sum = super::gpu::GpuEnergySum::new(ctx, &self.kernel)?;
        self.gpu = Some((channels, sum));
        Ok(self)
    }

    /// The GPU adapter the channels render on ([`Self::on_gpu`]), else `None`.
    pub fn gpu_adapter(&self) -> Option<String> {
        #[cfg(feature = "gpu")]
        if let Some((g, _)) = &self.gpu {
            return g.first().map(super::gpu::GpuCtRenderer::adapter_name);
        }
        None
    }

    /// Each CT material's mass-thickness map of `view` (on the GPU with [`Self::on_gpu`]).
    fn channel_maps(&self, view: &View) -> Result<Vec<ImageF32>> {
        #[cfg(feature = "gpu")]
        if let Some((channels, _)) = &self.gpu {
            return channels.iter().map(|c| c.render(view)).collect();
        }
        Ok(self.renderers.iter().map(|r| r.render(view)).collect())
    }

    /// The same CT with `implants` (closed meshes, world mm, each of a material and density) in it,
    /// displacing the voxels they occupy; their renders use `backend`.
    pub fn with_implants(
        mut self,
        implants: &[(Arc<TriMesh>, MaterialAt)],
        backend: Backend,
    ) -> Result<Self> {
        if implants.is_empty() {
            return Ok(self);
        }
        let mut channels: Vec<(Channel, ThicknessRenderer)> = Vec::new();
        let mut labels: Vec<String> = Vec::new();
        for (_, m) in implants {
            let label = m.material.name.to_string();
            if labels.contains(&label) {
                continue;
            }
            let meshes = implants
                .iter()
                .filter(|(_, o)| o.material.name == m.material.name)
                .map(|(mesh, o)| SceneMesh {
                    mesh: mesh.clone(),
                    mu_per_mm: o.density_g_cm3,
                    object: mesh.name.clone(),
                })
                .collect();
            channels.push((
                Channel::Material(m.material),
                backend.renderer(RenderScene::new(meshes)?)?,
            ));
            labels.push(label);
        }
        let union = backend.renderer(RenderScene::new(
            implants
                .iter()
                .map(|(mesh, _)| SceneMesh {
                    mesh: mesh.clone(),
                    mu_per_mm: 1.0,
                    object: mesh.name.clone(),
                })
                .collect(),
        )?)?;
        let described = implants
            .iter()
            .map(|(mesh, m)| serde_json::json!({"mesh": mesh.name, "material": m.label()}))
            .collect();
        let mut all = self.channels.clone();
        all.extend(channels.iter().map(|(c, _)| *c));
        self.kernel = self.model.kernel(&all);
        self.channels = all;
        // On the GPU already: the energy sum over the implants' channels too.
        #[cfg(feature = "gpu")]
        if let Some((renderers, sum)) = &mut self.gpu
            && let Some(first) = renderers.first()
        {
            *sum = super::gpu::GpuEnergySum::new(Arc::clone(first.context()), &self.kernel)?;
        }
        self.implants = Some(Implants {
            channels,
            union,
            described,
        });
        Ok(self)
    }

    /// Each CT material's Siddon integral over the implants' intervals of every ray that meets one,
    /// subtracted from its map (`maps[c]` of `renderers[c]`).
    fn displace(
        &self,
        implants: &Implants,
        view: &View,
        maps: &mut [crate::io::ImageF32],
    ) -> Result<()> {
        let covered = implants
            .union
            .render(view, &ThicknessOptions::image_only())?
            .line_integral;
        let w = view.intrinsics.width as usize;
        let m = view.pixel_to_world_dir();
        let origin = view.source_world();
        let corrections: Vec<(usize, Vec<f64>)> = covered
            .data
            .par_iter()
            .enumerate()
            .filter(|(_, l)| **l > 0.0)
            .map(|(i, _)| {
                let dir = (m * DVec3::new((i % w) as f64, (i / w) as f64, 1.0)).normalize();
                let (intervals, _) = implants.union.trace_intervals(origin, dir);
                let ray = Ray { origin, dir };
                let sub = self
                    .renderers
                    .iter()
                    .map(|r| {
                        intervals
                            .iter()
                            .map(|&(a, b)| r.segment_integral(&ray, a, b))
                            .sum()
                    })
                    .collect();
                (i, sub)
            })
            .collect();
        for (i, sub) in corrections {
            for (map, s) in maps.iter_mut().zip(sub) {
                map.data[i] = (f64::from(map.data[i]) - s).max(0.0) as f32;
            }
        }
        Ok(())
    }

    /// Renders `view`.
    pub fn render(&self, view: &View) -> Result<SpectralDrr> {
        #[cfg(feature = "gpu")]
        if let Some((channels, sum)) = &self.gpu
            && self.implants.is_none()
        {
            let d = sum.render(channels, view)?;
            return Ok(SpectralDrr {
                line_integral: d.line_integral,
                channels_ms: d.channels_ms,
                energy_sum_ms: d.energy_sum_ms,
                rays_unrepaired: 0,
                gpu_rays_on_cpu: None,
            });
        }
        let t0 = Instant::now();
        let mut maps = self.channel_maps(view)?;
        let mut gpu_rays_on_cpu = None;
        if let Some(implants) = &self.implants {
            self.displace(implants, view, &mut maps)?;
            for (_, r) in &implants.channels {
                let d = r.render(view, &ThicknessOptions::image_only())?;
                if let Some(n) = d.stats.gpu_rays_on_cpu {
                    gpu_rays_on_cpu = Some(gpu_rays_on_cpu.unwrap_or(0) + n);
                }
                maps.push(d.line_integral);
            }
        }
        let channels_ms = t0.elapsed().as_secs_f64() * 1e3;
        let t1 = Instant::now();
        #[cfg(feature = "gpu")]
        let line_integral = match &self.gpu {
            Some((_, sum)) => sum.sum_maps(&maps)?,
            None => energy_sum(&self.kernel, &maps),
        };
        #[cfg(not(feature = "gpu"))]
        let line_integral = energy_sum(&self.kernel, &maps);
        Ok(SpectralDrr {
            line_integral,
            channels_ms,
            energy_sum_ms: t1.elapsed().as_secs_f64() * 1e3,
            rays_unrepaired: 0,
            gpu_rays_on_cpu,
        })
    }

    /// What the sidecar records: the model and the channels with the HU conversion.
    pub fn summary(&self) -> serde_json::Value {
        let mut s = self.model.summary();
        s["channels"] = serde_json::json!(
            self.channels
                .iter()
                .map(|c| match c {
                    Channel::Material(m) => m.name,
                    Channel::FixedMu => "fixed_mu",
                })
                .collect::<Vec<_>>()
        );
        if let Some(adapter) = self.gpu_adapter() {
            s["gpu_adapter"] = adapter.into();
        }
        if let Some(i) = &self.implants {
            s["implants"] = serde_json::json!(i.described);
            let mut how =
                "each CT material's Siddon integral over the union of the implants' inside \
                           intervals of every ray is subtracted (exact)"
                    .to_string();
            if self.gpu_adapter().is_some() {
                how.push_str(
                    "; the CT's channels rendered on the GPU, the implants cut out of them on the host, \
                     the implants' channels and the energy sum on the GPU",
                );
            }
            s["implant_displacement"] = how.into();
        }
        s["hu_conversion"] = serde_json::json!(
            "HU <= 100: soft tissue at 1 + HU/1000 g/cm3; 100-1500 HU: soft tissue (1.10 g/cm3) and cortical \
             bone (1.92 g/cm3) mixed by volume, bone fraction (HU - 100)/1400; >= 1500 HU: cortical bone at \
             1.92 (1 + HU/1000)/2.5 g/cm3"
        );
        s
    }
}

/// `implants` (given in a CT file's world, like its landmarks) moved by `motion`, the CT's placement, so
/// they stay where they were in the anatomy.
pub fn moved_implants(
    implants: &[(Arc<TriMesh>, MaterialAt)],
    motion: &crate::geometry::RigidTransform,
) -> Vec<(Arc<TriMesh>, MaterialAt)> {
    implants
        .iter()
        .map(|(mesh, material)| {
            let mut m = (**mesh).clone();
            m.transform(motion);
            (Arc::new(m), *material)
        })
        .collect()
}
