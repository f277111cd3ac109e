//! One view's GPU sums as `mesh.wgsl` leaves them ([`GpuFrame`]), and the layout of its words.

use glam::DVec3;

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
/// `acc`), the scale of the fixed-point sum, and what the host needs to evaluate the pixels the sums
/// cannot give: their candidate triangles and the camera-frame vertices.
pub(crate) struct GpuFrame {
    pub stride: usize,
    pub words: Vec<u32>,
    pub scale: f64,
    /// Units per mm of a slot's chord (camera depth).
    pub chord_scale: f64,
    /// (pixel, global triangle) for every pixel that is not [`Self::balanced`], sorted.
    pub pairs: Vec<[u32; 2]>,
    /// Camera-frame vertices (source at the origin), by global vertex index.
    pub cam: Vec<DVec3>,
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
