//! One view's GPU sums as `mesh.wgsl` leaves them ([`GpuFrame`]), the layout of its words, and the
//! buffers a render works in ([`FrameBuffers`]).

use super::GpuContext;
use crate::Result;

/// Per-mesh slots per pixel (mesh.wgsl's `SLOTS`): a pixel whose ray meets more meshes is evaluated by
/// the host.
const SLOTS: u32 = 6;

/// Bits of a slot's first word that hold the mesh + 1 (mesh.wgsl's `ID_BITS`); structure bits above.
const ID_BITS: u32 = 17;

/// Words per pixel of the accumulator: the sum, the two balance counters and the number of crossings;
/// with depth and masks also the per-mesh slots (mesh and structure bits, chord, nearest depth).
pub(super) const WORDS_SUM: u32 = 4;
pub(super) const WORDS_ALL: u32 = 4 + 3 * SLOTS;

/// The flag mesh.wgsl sets in a pixel's count word when the host must evaluate the pixel.
const HOST: u32 = 0x8000_0000;

/// One view's accumulated sums as the shader left them, per pixel `stride` words (see mesh.wgsl's
/// `acc`) — or, when the GPU finished the line integrals itself, those ([`Finished`]) —, the scale of
/// the fixed-point sum, and what the host needs to evaluate the pixels the sums cannot give: their
/// candidate triangles (whose camera-frame corners the host computes in f64 from the view).
pub(crate) struct GpuFrame {
    pub stride: usize,
    /// The per-pixel words (empty when [`Self::finished`] holds the line integrals instead).
    pub words: Vec<u32>,
    pub finished: Option<Finished>,
    pub scale: f64,
    /// Units per mm of a slot's chord (camera depth).
    pub chord_scale: f64,
    /// (pixel, global triangle) for every pixel that is not [`Self::balanced`], sorted.
    pub pairs: Vec<[u32; 2]>,
}

/// A view's line integrals as mesh.wgsl's `finish` left them: every pixel the sums give, 0 elsewhere,
/// and the pixels the host evaluates.
pub(crate) struct Finished {
    /// Line integrals (μ·mm), row-major.
    pub image: Vec<f32>,
    /// The pixels the host evaluates (sorted): crossed by a triangle but not balanced, or flagged.
    pub pixels: Vec<u32>,
    /// The pixels the GPU finished and their crossings.
    pub rays: u32,
    pub hits: u64,
}

impl GpuFrame {
    /// Whether pixel `i`'s sum can be used: its crossings balance (per mesh as many entries as exits,
    /// as far as the two counters tell: see `raster::summed`) and the shader did not flag it (mesh.wgsl's
    /// `HOST`). Otherwise the host evaluates it. (The shader's `clean` also sends the host a pixel whose
    /// chord through a mesh is within rounding of the silhouette threshold; such a pixel is listed in
    /// [`Self::pairs`].)
    #[inline]
    pub fn balanced(&self, i: usize) -> bool {
        let w = &self.words[i * self.stride..];
        w[1] == 0 && w[2] == 0 && w[3] & HOST == 0
    }

    /// Pixel `i`'s `Σ ± μ · depth` (camera depth, μ·mm).
    #[inline]
    pub fn sum(&self, i: usize) -> f64 {
        f64::from(self.words[i * self.stride] as i32) / self.scale
    }

    /// How many triangles covered pixel `i`.
    #[inline]
    pub fn crossings(&self, i: usize) -> u32 {
        self.words[i * self.stride + 3] & !HOST
    }

    /// Whether pixel `i`'s ray can meet a mesh: a triangle covered it, or its centre is near an edge.
    #[inline]
    pub fn touched(&self, i: usize) -> bool {
        self.words[i * self.stride + 3] != 0
    }

    /// Pixel `i`'s per-mesh slots (with depth and masks): per mesh its ray meets, the mesh, its chord
    /// (camera depth, mm), the depth of its nearest crossing, and its crossed triangles' structure bits.
    pub fn slots(&self, i: usize) -> impl Iterator<Item = (usize, f64, f32, u32)> + '_ {
        let w = &self.words[i * self.stride..(i + 1) * self.stride];
        w[4..].chunks_exact(3).filter(|s| s[0] != 0).map(|s| {
            (
                (s[0] & ((1 << ID_BITS) - 1)) as usize - 1,
                f64::from(s[1] as i32) / self.chord_scale,
                f32::from_bits(!s[2]),
                s[0] >> ID_BITS,
            )
        })
    }
}

/// The byte sizes of a render's buffers: a render whose sizes differ allocates new ones.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct FrameSizes {
    pub verts: u64,
    pub acc: u64,
    pub list: u64,
    pub host: u64,
    pub image: u64,
}

/// The vertex, accumulator, list and image buffers of a render, and their read-back copies.
pub(super) struct FrameBuffers {
    pub sizes: FrameSizes,
    pub verts: wgpu::Buffer,
    pub acc: wgpu::Buffer,
    pub staging: wgpu::Buffer,
    pub list: wgpu::Buffer,
    pub list_staging: wgpu::Buffer,
    /// `finish`'s pixels for the host and line integrals.
    pub host: wgpu::Buffer,
    pub host_staging: wgpu::Buffer,
    pub image: wgpu::Buffer,
    pub image_staging: wgpu::Buffer,
    /// The first four words of `list` and of `host` (the counts).
    pub header_staging: wgpu::Buffer,
}

/// Bytes of [`FrameBuffers::header_staging`].
const HEADER_BYTES: u64 = 32;

/// What a render reads back: `collect`'s (pixel, triangle) pairs, and either every pixel's words or
/// `finish`'s image and host list.
pub(super) struct ReadBack {
    pub pairs: Vec<u32>,
    pub words: Vec<u32>,
    pub finished: Option<Finished>,
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
            staging: buffer("mesh sums read back", sizes.acc, read),
            list: buffer("mesh pixels for the host", sizes.list, work),
            list_staging: buffer("mesh pixels read back", sizes.list, read),
            host: buffer("mesh pixels the host finishes", sizes.host, work),
            host_staging: buffer("mesh pixels the host finishes, read back", sizes.host, read),
            image: buffer("mesh DRR", sizes.image, U::STORAGE | U::COPY_SRC),
            image_staging: buffer("mesh DRR read back", sizes.image, read),
            header_staging: buffer("mesh lists' counts read back", HEADER_BYTES, read),
        }
    }

    /// Records the copies of what a render leaves that come back whatever it holds: the lists'
    /// counts, and (with `full`) every pixel's words or (without) `finish`'s image.
    pub fn copy_out(&self, encoder: &mut wgpu::CommandEncoder, full: bool) {
        let half = HEADER_BYTES / 2;
        encoder.copy_buffer_to_buffer(&self.list, 0, &self.header_staging, 0, half);
        encoder.copy_buffer_to_buffer(&self.host, 0, &self.header_staging, half, half);
        if full {
            encoder.copy_buffer_to_buffer(&self.acc, 0, &self.staging, 0, self.sizes.acc);
        } else {
            encoder.copy_buffer_to_buffer(&self.image, 0, &self.image_staging, 0, self.sizes.image);
        }
    }

    /// Reads back what the render left once the queue's work is done: the lists' counts first, then
    /// only the entries they hold (a second copy), so a render's read-back is its image and its
    /// lists' entries, not the lists' capacity. `None` when a list overflowed `capacity`.
    pub fn read(&self, ctx: &GpuContext, full: bool, capacity: u32) -> Result<Option<ReadBack>> {
        let header = ctx.read_back::<u32>(&self.header_staging, "the mesh DRR's list counts")?;
        let half = (HEADER_BYTES / 8) as usize;
        let (n_pairs, n_host) = (header[0], if full { 0 } else { header[half] });
        if n_pairs > capacity || n_host > capacity {
            return Ok(None);
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
        if full {
            let words = ctx.read_back::<u32>(&self.staging, "the mesh DRR")?;
            return Ok(Some(ReadBack {
                pairs,
                words,
                finished: None,
            }));
        }
        let image = ctx.read_back::<f32>(&self.image_staging, "the mesh DRR")?;
        let mut pixels: Vec<u32> =
            ctx.read_back_first(&self.host_staging, host_bytes, "the mesh DRR's host pixels")?;
        pixels.sort_unstable();
        Ok(Some(ReadBack {
            pairs,
            words: Vec::new(),
            finished: Some(Finished {
                image,
                pixels,
                rays: header[half + 1],
                hits: u64::from(header[half + 2]) | u64::from(header[half + 3]) << 32,
            }),
        }))
    }
}
