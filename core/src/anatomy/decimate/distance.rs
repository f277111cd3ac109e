//! Point-to-surface distances for measuring how far a simplified mesh strays from its original: the
//! exact closest point on each triangle (Ericson 2005, "Real-Time Collision Detection", §5.1.5, Voronoi
//! regions of the triangle) with triangles bucketed in a uniform grid searched in growing shells.

use glam::DVec3;

use crate::anatomy::TriMesh;

/// Closest point to `p` on triangle `abc` (Ericson's Voronoi-region method).
pub fn closest_point_on_triangle(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> DVec3 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = va + vb + vc;
    if denom == 0.0 {
        // Degenerate triangle: fall back to its nearest corner.
        return [a, b, c]
            .into_iter()
            .min_by(|x, y| {
                (*x - p)
                    .length_squared()
                    .total_cmp(&(*y - p).length_squared())
            })
            .unwrap_or(a);
    }
    a + ab * (vb / denom) + ac * (vc / denom)
}

/// Distance queries against one mesh's surface.
pub struct SurfaceDistance<'a> {
    mesh: &'a TriMesh,
    lo: DVec3,
    cell: f64,
    dims: [usize; 3],
    /// CSR buckets: triangles of cell `c` are `items[start[c]..start[c + 1]]`.
    start: Vec<u32>,
    items: Vec<u32>,
}

impl<'a> SurfaceDistance<'a> {
    /// Buckets `mesh`'s triangles in a grid of about one triangle per cell.
    pub fn new(mesh: &'a TriMesh) -> SurfaceDistance<'a> {
        let (lo, hi) = mesh.bounds().unwrap_or((DVec3::ZERO, DVec3::ZERO));
        let ext = (hi - lo).max(DVec3::splat(1e-9));
        let n = mesh.triangles.len().max(1) as f64;
        let cell = ((ext.x * ext.y * ext.z) / n)
            .cbrt()
            .max(ext.max_element() / 256.0);
        let dims = [ext.x, ext.y, ext.z].map(|e| ((e / cell).floor() as usize + 1).min(512));
        let ranges: Vec<([usize; 3], [usize; 3])> = (0..mesh.triangles.len())
            .map(|i| {
                let [a, b, c] = mesh.corners(i);
                let (tl, th) = (a.min(b).min(c), a.max(b).max(c));
                (cell_of(lo, cell, dims, tl), cell_of(lo, cell, dims, th))
            })
            .collect();
        let ncell = dims[0] * dims[1] * dims[2];
        let mut count = vec![0u32; ncell + 1];
        let index = |i: usize, j: usize, k: usize| i + dims[0] * (j + dims[1] * k);
        let each = |r: &([usize; 3], [usize; 3]), f: &mut dyn FnMut(usize)| {
            for k in r.0[2]..=r.1[2] {
                for j in r.0[1]..=r.1[1] {
                    for i in r.0[0]..=r.1[0] {
                        f(index(i, j, k));
                    }
                }
            }
        };
        for r in &ranges {
            each(r, &mut |c| count[c + 1] += 1);
        }
        for c in 0..ncell {
            count[c + 1] += count[c];
        }
        let mut fill = count.clone();
        let mut items = vec![0u32; count[ncell] as usize];
        for (t, r) in ranges.iter().enumerate() {
            each(r, &mut |c| {
                items[fill[c] as usize] = t as u32;
                fill[c] += 1;
            });
        }
        SurfaceDistance {
            mesh,
            lo,
            cell,
            dims,
            start: count,
            items,
        }
    }

    /// Unsigned distance from `p` to the surface (mm).
    pub fn distance(&self, p: DVec3) -> f64 {
        self.nearest(p).map_or(f64::INFINITY, |(_, d)| d)
    }

    /// The triangle nearest to `p` and its distance (mm); `None` for a mesh without triangles.
    pub fn nearest(&self, p: DVec3) -> Option<(usize, f64)> {
        let c = cell_of(self.lo, self.cell, self.dims, p);
        let mut best: Option<(usize, f64)> = None;
        let max_r = *self.dims.iter().max().unwrap_or(&1);
        for r in 0..=max_r {
            self.visit_shell(c, r, &mut |t| {
                let [a, b, cc] = self.mesh.corners(t as usize);
                let d = (closest_point_on_triangle(p, a, b, cc) - p).length();
                if best.is_none_or(|(_, e)| d < e) {
                    best = Some((t as usize, d));
                }
            });
            // Cells beyond shell r are at least r·cell away from p.
            if best.is_some_and(|(_, d)| d <= r as f64 * self.cell) {
                break;
            }
        }
        best
    }

    fn visit_shell(&self, c: [usize; 3], r: usize, f: &mut dyn FnMut(u32)) {
        let r = r as isize;
        let lo = c.map(|x| x as isize - r);
        let hi = c.map(|x| x as isize + r);
        let d = self.dims.map(|x| x as isize);
        for k in lo[2].max(0)..=hi[2].min(d[2] - 1) {
            for j in lo[1].max(0)..=hi[1].min(d[1] - 1) {
                for i in lo[0].max(0)..=hi[0].min(d[0] - 1) {
                    let on_shell = i == lo[0]
                        || i == hi[0]
                        || j == lo[1]
                        || j == hi[1]
                        || k == lo[2]
                        || k == hi[2];
                    if !on_shell {
                        continue;
                    }
                    let cell = i as usize + self.dims[0] * (j as usize + self.dims[1] * k as usize);
                    for &t in &self.items[self.start[cell] as usize..self.start[cell + 1] as usize]
                    {
                        f(t);
                    }
                }
            }
        }
    }
}

fn cell_of(lo: DVec3, cell: f64, dims: [usize; 3], p: DVec3) -> [usize; 3] {
    let q = (p - lo) / cell;
    [q.x, q.y, q.z]
        .map(|x| if x.is_finite() { x.max(0.0) } else { 0.0 })
        .map(|x| x as usize)
        .iter()
        .zip(dims)
        .map(|(&x, d)| x.min(d - 1))
        .collect::<Vec<_>>()
        .try_into()
        .unwrap_or([0, 0, 0])
}

/// One-sided deviation of a point set from a surface.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Deviation {
    pub mean_mm: f64,
    pub max_mm: f64,
}

/// Mean and maximum distance from the vertices of `from` to the surface of `to` (the one-sided,
/// vertex-sampled Hausdorff distance).
pub fn deviation(from: &TriMesh, to: &TriMesh) -> Deviation {
    use rayon::prelude::*;
    let sd = SurfaceDistance::new(to);
    let d: Vec<f64> = from.vertices.par_iter().map(|&p| sd.distance(p)).collect();
    if d.is_empty() {
        return Deviation::default();
    }
    Deviation {
        mean_mm: d.iter().sum::<f64>() / d.len() as f64,
        max_mm: d.iter().copied().fold(0.0, f64::max),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_search_equals_brute_force() {
        let m = TriMesh::icosphere("s", DVec3::new(1.0, -2.0, 0.5), 7.0, 3);
        let sd = SurfaceDistance::new(&m);
        for i in 0..200 {
            let t = i as f64;
            let p =
                DVec3::new((t * 0.37).sin(), (t * 0.91).cos(), (t * 0.13).sin()) * (3.0 + t * 0.1);
            let brute = (0..m.triangles.len())
                .map(|k| {
                    let [a, b, c] = m.corners(k);
                    (closest_point_on_triangle(p, a, b, c) - p).length()
                })
                .fold(f64::INFINITY, f64::min);
            assert!((sd.distance(p) - brute).abs() < 1e-12, "point {i}");
        }
    }

    #[test]
    fn closest_point_regions() {
        let (a, b, c) = (DVec3::ZERO, DVec3::X, DVec3::Y);
        let cp = |p| closest_point_on_triangle(p, a, b, c);
        let near = |p: DVec3, q: DVec3| (cp(p) - q).length() < 1e-15;
        assert!(near(DVec3::new(0.2, 0.2, 3.0), DVec3::new(0.2, 0.2, 0.0)));
        assert!(near(DVec3::new(-1.0, -1.0, 0.0), a));
        assert!(near(DVec3::new(0.5, -2.0, 1.0), DVec3::new(0.5, 0.0, 0.0)));
        let h = cp(DVec3::new(1.0, 1.0, 0.0));
        assert!((h - DVec3::new(0.5, 0.5, 0.0)).length() < 1e-15);
    }
}
