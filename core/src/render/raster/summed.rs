//! The line integral of a band by signed sums instead of paired crossings.
//!
//! For a closed mesh that does not intersect itself, a ray's crossings alternate entry, exit, entry,
//! exit…, so the path length inside is `Σ exit depths − Σ entry depths` (times the ray's path per unit
//! depth) whatever their order: each covered pixel of a triangle adds `± μ · depth` to the pixel's sum
//! and nothing has to be stored, sorted or paired. This is the same geometry as [`RasterView::band_hits`]
//! (edge functions, tie rule, plane depth); only the bookkeeping differs. It is what loops that render
//! one scene thousands of times use (intensity registration).
//!
//! A pixel whose crossings do not balance — per mesh as many entries as exits — lost or doubled a
//! crossing at a vertex (see the module docs of [`super`]); its sum means nothing, and it is handed back
//! to the caller, who integrates that ray the paired way. Balance is checked with two integers per pixel,
//! `Σ s` and `Σ s · g` (`s = ±1`, `g` the mesh), both zero when every mesh balances; a ray that loses an
//! entry and an exit of one mesh, or doubles both, balances and is not detected (it needs two vertex
//! events on one ray). A self-intersecting mesh breaks the alternation: the caller checks a summed render
//! against a paired one before relying on it.

use super::RasterView;

/// Per-thread buffers of [`RasterView::band_line_integral`].
#[derive(Default)]
pub(crate) struct SumScratch {
    /// `Σ ± μ · depth` per band pixel (camera depth, mm).
    sum: Vec<f64>,
    /// `Σ s` and `Σ s · g` per band pixel.
    balance: Vec<[i32; 2]>,
}

impl RasterView<'_> {
    /// Writes the line integral of every pixel of band `band` whose crossings balance into `out` (the
    /// band's pixels, row-major, zeroed by the caller) and pushes the others, as (column, row in band),
    /// onto `unbalanced` (their value in `out` is left 0). Returns how many pixels were covered.
    pub(crate) fn band_line_integral(
        &self,
        band: usize,
        scratch: &mut SumScratch,
        out: &mut [f32],
        unbalanced: &mut Vec<(usize, usize)>,
    ) -> u64 {
        let w = self.intr.width as usize;
        let h = self.intr.height as usize;
        let row0 = band * self.band_rows;
        let row1 = (row0 + self.band_rows).min(h) - 1;
        let cells = (row1 - row0 + 1) * w;
        let (sum, balance) = (&mut scratch.sum, &mut scratch.balance);
        sum.clear();
        sum.resize(cells, 0.0);
        balance.clear();
        balance.resize(cells, [0, 0]);
        let (mut umin, mut umax) = (usize::MAX, 0);
        self.band_triangles(band, |g, _, (u0, u1, v0, v1), edges| {
            // An exit adds its depth, an entry subtracts it.
            let s: i32 = if edges.entry { -1 } else { 1 };
            let weight = f64::from(s) * self.scene.meshes[g].mu_per_mm;
            let tag = [s, s * g as i32];
            umin = umin.min(u0);
            umax = umax.max(u1);
            for v in v0..v1 + 1 {
                let row = edges.row(v as f64);
                let base = (v - row0) * w;
                let (sums, bals) = (
                    &mut sum[base + u0..base + u1 + 1],
                    &mut balance[base + u0..base + u1 + 1],
                );
                // Every box pixel is updated by its coverage (0 or 1), without a branch.
                for (k, (acc, bal)) in sums.iter_mut().zip(bals.iter_mut()).enumerate() {
                    let uf = (u0 + k) as f64;
                    let on = row.covers(uf);
                    *acc += f64::from(u8::from(on)) * weight * row.depth(uf);
                    let m = i32::from(on);
                    bal[0] += m * tag[0];
                    bal[1] += m * tag[1];
                }
            }
        });
        if umin > umax {
            return 0;
        }
        let mut covered = 0;
        for r in 0..=(row1 - row0) {
            let v = (row0 + r) as f64;
            for u in umin..=umax {
                let i = r * w + u;
                if balance[i] != [0, 0] {
                    unbalanced.push((u, r));
                } else if sum[i] != 0.0 {
                    covered += 1;
                    out[i] = (sum[i] * self.path_per_depth(u as f64, v)) as f32;
                }
            }
        }
        covered
    }
}
