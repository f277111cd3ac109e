//! One view as `mesh.wgsl` leaves it ([`GpuFrame`]), the layout of its accumulator, and the buffers a
//! render works in ([`FrameBuffers`]).

use super::GpuContext;
use crate::Result;

/// Per-mesh slots per pixel (mesh.wgsl's `SLOTS`): a pixel whose ray meets more meshes is evaluated by
/// the host.
const SLOTS: u32 = 6;

/// Words per pixel of the accumulator: the sum, the two balance counters and the number of crossings;
/// with depth and masks also the per-mesh slots (mesh and structure bits, chord, nearest depth).
pub(super) const WORDS_SUM: u32 = 4;
pub(super) const WORDS_ALL: u32 = 4 + 3 * SLOTS;

/// One view as mesh.wgsl's `finish` left it ([`Finished`]), and what the host needs to evaluate the
/// pixels the sums cannot give: their candidate triangles (whose camera-frame corners the host computes
/// in f64 from the view).
pub(crate) struct GpuFrame {
    pub finished: Finished,
    /// (pixel, global triangle) for every pixel the host evaluates, sorted.
    pub pairs: Vec<[u32; 2]>,
}

/// A view's line integrals as mesh.wgsl's `finish` left them: every pixel the sums give, 0 elsewhere,
/// and the pixels the host evaluates.
pub(crate) struct Finished {
    /// Line integrals (μ·mm), row-major (empty when the image stayed on the GPU).
    pub image: Vec<f32>,
    /// With depth or masks, four words per pixel: the nearest silhouette crossing's depth (f32 bits,
    /// +inf when none), the object bits (low word, high word) and the structure bits; else empty.
    pub extra: Vec<u32>,
    /// The pixels the host evaluates (sorted): crossed by a triangle but not balanced, or flagged.
    pub pixels: Vec<u32>,
    /// The pixels the GPU finished and their crossings.
    pub rays: u32,
    pub hits: u64,
}

/// The byte sizes of a render's buffers: a render whose sizes differ allocates new ones.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct FrameSizes {
    pub verts: u64,
    pub acc: u64,
    pub list: u64,
    pub host: u64,
    pub image: u64,
    pub extra: u64,
}

/// The vertex, accumulator, list and image buffers of a render, and their read-back copies.
pub(super) struct FrameBuffers {
    pub sizes: FrameSizes,
    pub verts: wgpu::Buffer,
    pub acc: wgpu::Buffer,
    pub list: wgpu::Buffer,
    pub list_staging: wgpu::Buffer,
    /// `finish`'s pixels for the host and line integrals.
    pub host: wgpu::Buffer,
    pub host_staging: wgpu::Buffer,
    pub image: wgpu::Buffer,
    pub image_staging: wgpu::Buffer,
    /// `finish`'s depth and silhouettes (with the slots).
    pub extra: wgpu::Buffer,
    pub extra_staging: wgpu::Buffer,
    /// The first four words of `list` and of `host` (the counts).
    pub header_staging: wgpu::Buffer,
}

/// Bytes of [`FrameBuffers::header_staging`].
const HEADER_BYTES: u64 = 32;

/// What a render reads back: `collect`'s (pixel, triangle) pairs and what `finish` left.
pub(super) struct ReadBack {
    pub pairs: Vec<u32>,
    pub finished: Finished,
}

impl FrameBuffers {
    pub fn new(device: &wgpu::Device, sizes: FrameSizes) -> Self {
        use wgpu::BufferUsages as U;
        let buffer = |label, size, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        let work = U::STORAGE | U::COPY_SRC | U::COPY_DST;
        let read = U::MAP_READ | U::COPY_DST;
        FrameBuffers {
            sizes,
            verts: buffer("mesh vertices", sizes.verts, U::STORAGE | U::COPY_DST),
            acc: buffer("mesh sums", sizes.acc, work),
            list: buffer("mesh pixels for the host", sizes.list, work),
            list_staging: buffer("mesh pixels read back", sizes.list, read),
            host: buffer("mesh pixels the host finishes", sizes.host, work),
            host_staging: buffer("mesh pixels the host finishes, read back", sizes.host, read),
            image: buffer("mesh DRR", sizes.image, U::STORAGE | U::COPY_SRC),
            image_staging: buffer("mesh DRR read back", sizes.image, read),
            extra: buffer(
                "mesh depth and silhouettes",
                sizes.extra,
                U::STORAGE | U::COPY_SRC,
            ),
            extra_staging: buffer("mesh depth and silhouettes read back", sizes.extra, read),
            header_staging: buffer("mesh lists' counts read back", HEADER_BYTES, read),
        }
    }

    /// Records the copies of what a render leaves that come back whatever it holds: the lists'
    /// counts, (with `image`) `finish`'s image and (with `full`) its depth and silhouettes.
    pub fn copy_out(&self, encoder: &mut wgpu::CommandEncoder, full: bool, image: bool) {
        let half = HEADER_BYTES / 2;
        encoder.copy_buffer_to_buffer(&self.list, 0, &self.header_staging, 0, half);
        encoder.copy_buffer_to_buffer(&self.host, 0, &self.header_staging, half, half);
        if image {
            encoder.copy_buffer_to_buffer(&self.image, 0, &self.image_staging, 0, self.sizes.image);
        }
        if full {
            encoder.copy_buffer_to_buffer(&self.extra, 0, &self.extra_staging, 0, self.sizes.extra);
        }
    }

    /// Reads back what the render left once the queue's work is done: the lists' counts first, then
    /// only the entries they hold (a second copy), so a render's read-back is its finished pixels and
    /// its lists' entries, not the lists' capacity. `Err(entries)` when a list overflowed `capacity`:
    /// the entries the longer list wanted. Without `image`, the image stays on the GPU (empty here).
    pub fn read(
        &self,
        ctx: &GpuContext,
        full: bool,
        capacity: u32,
        image: bool,
    ) -> Result<std::result::Result<ReadBack, u32>> {
        let header = ctx.read_back::<u32>(&self.header_staging, "the mesh DRR's list counts")?;
        let half = (HEADER_BYTES / 8) as usize;
        let (n_pairs, n_host) = (header[0], header[half]);
        if n_pairs > capacity || n_host > capacity {
            return Ok(Err(n_pairs.max(n_host)));
        }
        let (pair_bytes, host_bytes) = (8 * u64::from(n_pairs), 4 * u64::from(n_host));
        if pair_bytes + host_bytes > 0 {
            ctx.checked("reading the mesh DRR's lists", || {
                let mut encoder = ctx.device.create_command_encoder(&Default::default());
                if pair_bytes > 0 {
                    encoder.copy_buffer_to_buffer(&self.list, 4, &self.list_staging, 0, pair_bytes);
                }
                if host_bytes > 0 {
                    encoder.copy_buffer_to_buffer(
                        &self.host,
                        16,
                        &self.host_staging,
                        0,
                        host_bytes,
                    );
                }
                ctx.queue.submit([encoder.finish()]);
            })?;
        }
        let pairs = ctx.read_back_first(&self.list_staging, pair_bytes, "the mesh DRR's pixels")?;
        let image = if image {
            ctx.read_back::<f32>(&self.image_staging, "the mesh DRR")?
        } else {
            Vec::new()
        };
        let extra = if full {
            ctx.read_back::<u32>(&self.extra_staging, "the mesh DRR's depth and silhouettes")?
        } else {
            Vec::new()
        };
        let mut pixels: Vec<u32> =
            ctx.read_back_first(&self.host_staging, host_bytes, "the mesh DRR's host pixels")?;
        pixels.sort_unstable();
        Ok(Ok(ReadBack {
            pairs,
            finished: Finished {
                image,
                extra,
                pixels,
                rays: header[half + 1],
                hits: u64::from(header[half + 2]) | u64::from(header[half + 3]) << 32,
            },
        }))
    }
}
