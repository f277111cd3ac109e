//! The GPU backend (`--backend gpu`): compute shaders in WGSL through `wgpu`, on whatever the machine
//! offers — Vulkan, Metal or DX12 — with one code base. Where there is no GPU, Mesa's software Vulkan
//! (lavapipe, Debian's `mesa-vulkan-drivers`) runs the same shaders on the CPU, which is how the tests
//! compare this backend with the CPU renderers.
//!
//! [`GpuContext`] is the device (one per process is enough: it is shared through an `Arc`);
//! [`GpuCtRenderer`] renders CT DRRs (exact Siddon and trilinear) of a [`super::volume::VolumeRenderer`]'s
//! μ grid; [`GpuEnergySum`] finishes a spectral CT DRR from its channels' renders; [`GpuMeshRenderer`]
//! sums mesh DRRs. (The intensity registration's loop on the GPU is `registration::intensity::device`.) Every wgpu call that can fail is checked inside an error scope, so a refused buffer, a shader
//! the driver cannot compile or a lost device is an [`Error`], never a panic.

mod ct;
mod energy;
mod mesh;
mod mesh_frame;
mod mesh_view;
mod project;
mod scatter;

use std::sync::{Arc, Mutex, PoisonError, mpsc};

pub use ct::GpuCtRenderer;
pub use energy::{GpuEnergySum, GpuSpectralDrr};
pub(crate) use mesh::GpuFrame;
pub use mesh::GpuMeshRenderer;
pub(crate) use scatter::scatter;

use crate::{Error, Result};

/// A GPU device and its queue, with what the adapter says about itself.
pub struct GpuContext {
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    limits: wgpu::Limits,
    /// The device was opened with `SHADER_F64` (mesh vertices are then projected on the GPU).
    f64: bool,
    /// Compiled shaders kept for the device's life, by name ([`GpuContext::cached`]).
    cache: Mutex<Vec<(&'static str, Arc<dyn std::any::Any + Send + Sync>)>>,
}

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuContext")
            .field("adapter", &self.adapter_name())
            .finish()
    }
}

/// What to install when no adapter is found.
const NO_ADAPTER_HELP: &str = "the gpu backend needs a Vulkan, Metal or DX12 adapter; on Linux \
    without a GPU (or without its Vulkan driver), Mesa's software Vulkan provides one: \
    apt-get install mesa-vulkan-drivers (scripts/install-deps.sh installs it)";

impl GpuContext {
    /// The process's device: opened by the first call ([`GpuContext::new`]) and shared by every later
    /// one (renderers of many CTs, Python objects), so a device is opened once. A failure is not kept:
    /// the next call tries again.
    pub fn shared() -> Result<Arc<GpuContext>> {
        static SHARED: Mutex<Option<Arc<GpuContext>>> = Mutex::new(None);
        let mut slot = SHARED.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(ctx) = &*slot {
            return Ok(Arc::clone(ctx));
        }
        let ctx = GpuContext::new()?;
        *slot = Some(Arc::clone(&ctx));
        Ok(ctx)
    }

    /// Opens the highest-performance adapter the system offers (a discrete GPU before an integrated
    /// one, a hardware one before lavapipe), with every limit the adapter supports.
    pub fn new() -> Result<Arc<GpuContext>> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends: wgpu::Backends::PRIMARY,
            ..wgpu::InstanceDescriptor::new_without_display_handle()
        });
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: None,
            apply_limit_buckets: false,
        }))
        .map_err(|e| Error::Resource(format!("no GPU adapter found ({e}): {NO_ADAPTER_HELP}")))?;
        let info = adapter.get_info();
        let limits = adapter.limits();
        let f64 = adapter.features().contains(wgpu::Features::SHADER_F64);
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("spinedrr"),
            required_features: if f64 {
                wgpu::Features::SHADER_F64
            } else {
                wgpu::Features::empty()
            },
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| {
            Error::Resource(format!(
                "GPU adapter {} refused a device: {e}",
                describe(&info)
            ))
        })?;
        // Every call below runs in an error scope; an error outside one (a bug) is reported, not a panic.
        device.on_uncaptured_error(Arc::new(|e| {
            eprintln!("warning: GPU error outside an error scope: {e}");
        }));
        Ok(Arc::new(GpuContext {
            device,
            queue,
            info,
            limits,
            f64,
            cache: Mutex::new(Vec::new()),
        }))
    }

    /// The value `make` built the first time `name` was asked for (compiled shaders that every
    /// registration level shares), built inside an error scope: a failure is returned, not kept.
    pub(crate) fn cached<T: Send + Sync + 'static>(
        &self,
        name: &'static str,
        make: impl FnOnce(&wgpu::Device) -> T,
    ) -> Result<Arc<T>> {
        let mut cache = self.cache.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some((_, v)) = cache.iter().find(|(n, _)| *n == name) {
            return Arc::clone(v)
                .downcast::<T>()
                .map_err(|_| Error::Internal(format!("GPU cache entry {name} has another type")));
        }
        let value = Arc::new(self.checked(&format!("compiling {name}"), || make(&self.device))?);
        cache.push((name, value.clone()));
        Ok(value)
    }

    /// Whether shaders may compute in f64 (the adapter has `SHADER_F64`).
    pub(crate) fn has_f64(&self) -> bool {
        self.f64
    }

    /// The adapter as a sidecar records it: name, backend, device type and driver.
    pub fn adapter_name(&self) -> String {
        describe(&self.info)
    }

    /// Whether the adapter is a software rasteriser (lavapipe, WARP): timings there say nothing about a
    /// GPU.
    pub fn is_software(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    /// Runs `f` with validation and out-of-memory errors captured: a wgpu error becomes an
    /// [`Error::External`] naming `what`.
    pub(crate) fn checked<T>(&self, what: &str, f: impl FnOnce() -> T) -> Result<T> {
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let value = f();
        let errors = [
            pollster::block_on(validation.pop()),
            pollster::block_on(oom.pop()),
        ];
        match errors.into_iter().flatten().next() {
            None => Ok(value),
            Some(e) => Err(Error::External {
                library: "wgpu",
                message: format!("{what} on {}: {e}", self.adapter_name()),
            }),
        }
    }

    /// Waits for the queue's work; a lost device or a timeout is an error naming `what`.
    pub(crate) fn wait(&self, what: &str) -> Result<()> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| Error::External {
                library: "wgpu",
                message: format!("{what} on {}: {e}", self.adapter_name()),
            })
    }

    /// The contents of `staging` (a `MAP_READ` buffer) once the queue's work is done: mapped, copied out
    /// and unmapped; `what` names them in an error.
    pub(crate) fn read_back<T: bytemuck::Pod>(
        &self,
        staging: &wgpu::Buffer,
        what: &str,
    ) -> Result<Vec<T>> {
        self.read_back_first(staging, staging.size(), what)
    }

    /// The first `bytes` bytes of `staging` (a multiple of 4; none when 0), as [`Self::read_back`].
    pub(crate) fn read_back_first<T: bytemuck::Pod>(
        &self,
        staging: &wgpu::Buffer,
        bytes: u64,
        what: &str,
    ) -> Result<Vec<T>> {
        if bytes == 0 {
            return Ok(Vec::new());
        }
        let (sender, receiver) = mpsc::channel();
        staging.map_async(wgpu::MapMode::Read, ..bytes, move |r| {
            let _ = sender.send(r);
        });
        self.wait(&format!("computing {what}"))?;
        receiver
            .recv()
            .map_err(|_| Error::Internal("the GPU read-back never reported".into()))?
            .map_err(|e| Error::External {
                library: "wgpu",
                message: format!("reading {what} back from {}: {e}", self.adapter_name()),
            })?;
        let data: Vec<T> = {
            let mapped = staging
                .get_mapped_range(..bytes)
                .map_err(|e| Error::External {
                    library: "wgpu",
                    message: format!("mapping {what} of {}: {e}", self.adapter_name()),
                })?;
            bytemuck::cast_slice(&mapped).to_vec()
        };
        staging.unmap();
        Ok(data)
    }

    /// The largest 3-D texture edge the adapter takes.
    pub(crate) fn max_texture_3d(&self) -> u32 {
        self.limits.max_texture_dimension_3d
    }

    /// The largest storage buffer binding (bytes).
    pub(crate) fn max_storage_binding(&self) -> u64 {
        self.limits.max_storage_buffer_binding_size
    }

    /// The most workgroups one dispatch may have along an axis.
    pub(crate) fn max_workgroups(&self) -> u32 {
        self.limits.max_compute_workgroups_per_dimension
    }
}

/// Binding `binding` of a compute shader's bind group layout.
pub(crate) fn compute_entry(binding: u32, ty: wgpu::BindingType) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty,
        count: None,
    }
}

/// A buffer binding of type `ty` (uniform, or storage read-only or read-write).
pub(crate) fn buffer_binding(ty: wgpu::BufferBindingType) -> wgpu::BindingType {
    wgpu::BindingType::Buffer {
        ty,
        has_dynamic_offset: false,
        min_binding_size: None,
    }
}

/// Binding kinds of [`buffer_layout`].
pub(crate) const UNIFORM: wgpu::BufferBindingType = wgpu::BufferBindingType::Uniform;
pub(crate) const READ: wgpu::BufferBindingType =
    wgpu::BufferBindingType::Storage { read_only: true };
pub(crate) const WRITE: wgpu::BufferBindingType =
    wgpu::BufferBindingType::Storage { read_only: false };

/// A compute shader's bind group layout of buffers (binding `i` of kind `kinds[i]`) and the pipeline
/// layout of that one group.
pub(crate) fn buffer_layout(
    device: &wgpu::Device,
    label: &str,
    kinds: &[wgpu::BufferBindingType],
) -> (wgpu::BindGroupLayout, wgpu::PipelineLayout) {
    let entries: Vec<_> = (0u32..)
        .zip(kinds)
        .map(|(i, &k)| compute_entry(i, buffer_binding(k)))
        .collect();
    let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some(label),
        entries: &entries,
    });
    let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(label),
        bind_group_layouts: &[Some(&layout)],
        immediate_size: 0,
    });
    (layout, pipeline_layout)
}

/// The compute pipeline of `entry` in `module`.
pub(crate) fn compute_pipeline(
    device: &wgpu::Device,
    layout: &wgpu::PipelineLayout,
    module: &wgpu::ShaderModule,
    entry: &str,
) -> wgpu::ComputePipeline {
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(entry),
        layout: Some(layout),
        module,
        entry_point: Some(entry),
        compilation_options: Default::default(),
        cache: None,
    })
}

/// An uninitialised buffer of `bytes` (at least 16) with `usage`.
pub(crate) fn buffer(
    device: &wgpu::Device,
    label: &str,
    bytes: u64,
    usage: wgpu::BufferUsages,
) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: bytes.max(16),
        usage,
        mapped_at_creation: false,
    })
}

/// A storage buffer holding `bytes` (one unused 16-byte entry when empty: an empty binding is not
/// allowed).
pub(crate) fn storage_init(device: &wgpu::Device, label: &str, bytes: &[u8]) -> wgpu::Buffer {
    use wgpu::util::DeviceExt;
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents: if bytes.is_empty() { &[0; 16] } else { bytes },
        usage: wgpu::BufferUsages::STORAGE,
    })
}

/// A uniform buffer holding `bytes`.
pub(crate) fn uniform_init(device: &wgpu::Device, label: &str, bytes: &[u8]) -> wgpu::Buffer {
    use wgpu::util::DeviceExt;
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents: bytes,
        usage: wgpu::BufferUsages::UNIFORM,
    })
}

/// The bind group of `layout` with `buffers[i]` (whole) at binding `i`.
pub(crate) fn bind_buffers(
    device: &wgpu::Device,
    label: &str,
    layout: &wgpu::BindGroupLayout,
    buffers: &[&wgpu::Buffer],
) -> wgpu::BindGroup {
    let entries: Vec<_> = (0u32..)
        .zip(buffers)
        .map(|(binding, b)| wgpu::BindGroupEntry {
            binding,
            resource: b.as_entire_binding(),
        })
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some(label),
        layout,
        entries: &entries,
    })
}

fn describe(info: &wgpu::AdapterInfo) -> String {
    let mut s = format!("{} ({:?}, {:?}", info.name, info.backend, info.device_type);
    if !info.driver.is_empty() {
        s.push_str(&format!(", {} {}", info.driver, info.driver_info));
    }
    s.push(')');
    s
}
