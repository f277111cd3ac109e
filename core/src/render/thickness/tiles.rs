//! The traced path of a thickness render: rays through pixel centres, pixels grouped in
//! [`TILE`] × [`TILE`] tiles, tiles no projected triangle touches skipped, and each tile's pixels handed
//! out in packets of [`PACKET`] rays (two 4 × 2 blocks per 4 × 4 tile). Used by the renderer's tracer
//! backends and by the Embree benchmark floor, so both trace exactly the same rays.

use glam::{DMat3, DVec3};
use rayon::prelude::*;

use crate::geometry::View;
use crate::render::scene::RenderScene;
use crate::render::tracer::{PACKET, RayPacket};

/// Side of the square pixel tiles used for culling and scheduling.
pub const TILE: u32 = 4;

/// Per-view constants of ray generation: `dir ∝ Rᵀ K⁻¹ [u, v, 1]ᵀ` from the source.
pub(crate) struct Camera {
    pub source: DVec3,
    pixel_to_dir: DMat3,
    /// The camera's optical axis in the world frame (`dir · axis_z` turns distance into depth).
    pub axis_z: DVec3,
    pub width: u32,
    pub height: u32,
}

impl Camera {
    pub fn new(view: &View) -> Self {
        Camera {
            source: view.source_world(),
            pixel_to_dir: view.pixel_to_world_dir(),
            axis_z: view.world_to_camera.rotation.transpose().z_axis,
            width: view.intrinsics.width,
            height: view.intrinsics.height,
        }
    }

    /// Unit direction of the ray through pixel position (u, v).
    #[inline]
    pub fn dir(&self, u: f64, v: f64) -> DVec3 {
        (self.pixel_to_dir * DVec3::new(u, v, 1.0)).normalize()
    }
}

/// Which tiles of a view are traced.
pub(crate) struct TilePlan {
    tiles_x: usize,
    /// Per tile (row-major), whether a triangle may be seen there; `None`: trace every tile.
    coverage: Option<Vec<bool>>,
}

impl TilePlan {
    /// The tiles of `view` to trace: with `cull`, those touched by a projected triangle's bounding box.
    pub fn new(scene: &RenderScene, view: &View, cull: bool) -> Self {
        let tiles_x = (view.intrinsics.width as usize).div_ceil(TILE as usize);
        let coverage = if cull {
            tile_coverage(scene, view, tiles_x)
        } else {
            None
        };
        TilePlan { tiles_x, coverage }
    }

    /// Calls `trace(packet, pixels)` for every packet of tile row `band` (`rows` rows starting at row
    /// `band · TILE`), tile by tile, with `pixels[lane]` = (u, row within the band) of ray `lane`.
    /// Returns the number of pixels culled.
    pub fn for_each_packet(
        &self,
        cam: &Camera,
        band: usize,
        rows: usize,
        mut trace: impl FnMut(&RayPacket, &[(usize, usize)]),
    ) -> u64 {
        let w = cam.width as usize;
        let v0 = band * TILE as usize;
        let mut culled = 0u64;
        for tx in 0..self.tiles_x {
            let u0 = tx * TILE as usize;
            let u1 = (u0 + TILE as usize).min(w);
            if let Some(cov) = &self.coverage
                && !cov[band * self.tiles_x + tx]
            {
                culled += ((u1 - u0) * rows) as u64;
                continue;
            }
            let pixels: Vec<(usize, usize)> = (0..rows)
                .flat_map(|r| (u0..u1).map(move |u| (u, r)))
                .collect();
            for chunk in pixels.chunks(PACKET) {
                let mut packet = RayPacket::default();
                for &(u, r) in chunk {
                    packet.push(cam.source, cam.dir(u as f64, (v0 + r) as f64));
                }
                trace(&packet, chunk);
            }
        }
        culled
    }
}

/// Marks the tiles touched by the projected bounding box of any triangle (plus one pixel of margin:
/// the ray through a pixel centre next to the box may still graze it). `None` (no culling) when a
/// vertex lies at or behind the source plane, where projection is not a bound. Vertices and triangles
/// are processed in parallel; each worker marks its own map and the maps are OR-ed.
fn tile_coverage(scene: &RenderScene, view: &View, tiles_x: usize) -> Option<Vec<bool>> {
    let k = &view.intrinsics;
    let tiles_y = (k.height as usize).div_ceil(TILE as usize);
    let inv_t = 1.0 / TILE as f64;
    let n_tiles = tiles_x * tiles_y;
    let mut cov = vec![false; n_tiles];
    for m in &scene.meshes {
        let mesh = &m.mesh;
        // Per vertex, the (unclamped) tile range of its one-pixel neighbourhood.
        let ranges: Option<Vec<[i32; 4]>> = mesh
            .vertices
            .par_iter()
            .with_min_len(4096)
            .map(|&p| {
                let c = view.world_to_camera.apply(p);
                if c.z.is_nan() || c.z <= 1e-6 {
                    return None;
                }
                let q = k.project_camera(c);
                Some([
                    floor_i32((q.x - 1.0) * inv_t),
                    floor_i32((q.y - 1.0) * inv_t),
                    floor_i32((q.x + 1.0) * inv_t),
                    floor_i32((q.y + 1.0) * inv_t),
                ])
            })
            .collect();
        let ranges = ranges?;
        let (tx_max, ty_max) = (tiles_x as i32 - 1, tiles_y as i32 - 1);
        let mark = |mut map: Vec<bool>, tris: &[[u32; 3]]| {
            for tri in tris {
                let [a, b, c] = tri.map(|i| ranges[i as usize]);
                let x0 = a[0].min(b[0]).min(c[0]).max(0);
                let y0 = a[1].min(b[1]).min(c[1]).max(0);
                let x1 = a[2].max(b[2]).max(c[2]).min(tx_max);
                let y1 = a[3].max(b[3]).max(c[3]).min(ty_max);
                for ty in y0..=y1 {
                    let row = ty as usize * tiles_x;
                    if x0 <= x1 {
                        map[row + x0 as usize..=row + x1 as usize].fill(true);
                    }
                }
            }
            map
        };
        let mesh_cov = mesh
            .triangles
            .par_chunks(8192)
            .fold(|| vec![false; n_tiles], mark)
            .reduce_with(|mut a, b| {
                a.iter_mut().zip(&b).for_each(|(x, &y)| *x |= y);
                a
            });
        if let Some(mc) = mesh_cov {
            cov.iter_mut().zip(&mc).for_each(|(x, &y)| *x |= y);
        }
    }
    Some(cov)
}

/// `floor(x)` as an integer, saturating (avoids a libm call on targets without SSE4.1 rounding).
#[inline]
fn floor_i32(x: f64) -> i32 {
    let i = x as i32;
    if (i as f64) > x { i - 1 } else { i }
}
