//! Geometric probes of a closed mesh: solid moments, line–surface intervals and planar cross-sections.

use glam::{DMat3, DVec3};

use crate::anatomy::TriMesh;

/// Volume, centroid and covariance of the solid a closed outward mesh encloses, by the divergence
/// theorem over the tetrahedra `(r, a, b, c)` (r = mean vertex, for round-off):
/// `V = Σ det/6`, `∫p dV = Σ V_t (a+b+c)/4`, `∫ppᵀ dV = Σ V_t/20 (aaᵀ+bbᵀ+ccᵀ+ssᵀ)`, `s = a+b+c`.
pub fn solid_moments(mesh: &TriMesh) -> (f64, DVec3, DMat3) {
    let r = mesh.vertices.iter().sum::<DVec3>() / mesh.vertices.len().max(1) as f64;
    let (mut vol, mut first, mut second) = (0.0, DVec3::ZERO, DMat3::ZERO);
    let outer = |u: DVec3| DMat3::from_cols(u * u.x, u * u.y, u * u.z);
    for i in 0..mesh.triangles.len() {
        let [a, b, c] = mesh.corners(i).map(|p| p - r);
        let v = a.dot(b.cross(c)) / 6.0;
        let s = a + b + c;
        vol += v;
        first += v * s / 4.0;
        second += (outer(a) + outer(b) + outer(c) + outer(s)) * (v / 20.0);
    }
    if vol == 0.0 {
        return (0.0, r, DMat3::ZERO);
    }
    let mu = first / vol;
    (vol, r + mu, second * (1.0 / vol) - outer(mu))
}

/// The parameter intervals `[t_in, t_out]` where the line `q + t·d` (|d| = 1) is inside the closed
/// mesh, ascending: every triangle crossing (Möller–Trumbore) is an entry when `n·d < 0`, an exit
/// otherwise; nesting depth pairs them.
pub fn line_intervals(mesh: &TriMesh, q: DVec3, d: DVec3) -> Vec<(f64, f64)> {
    let mut hits: Vec<(f64, bool)> = Vec::new();
    for i in 0..mesh.triangles.len() {
        let [a, b, c] = mesh.corners(i);
        let (e1, e2) = (b - a, c - a);
        let p = d.cross(e2);
        let det = e1.dot(p);
        if det.abs() < 1e-14 {
            continue;
        }
        let s = q - a;
        let u = s.dot(p) / det;
        if !(0.0..=1.0).contains(&u) {
            continue;
        }
        let qv = s.cross(e1);
        let v = d.dot(qv) / det;
        if v < 0.0 || u + v > 1.0 {
            continue;
        }
        let t = e2.dot(qv) / det;
        hits.push((t, e1.cross(e2).dot(d) < 0.0));
    }
    hits.sort_by(|x, y| x.0.total_cmp(&y.0));
    let mut out = Vec::new();
    let (mut depth, mut start) = (0i32, 0.0);
    for (t, entry) in hits {
        if entry {
            if depth == 0 {
                start = t;
            }
            depth += 1;
        } else if depth > 0 {
            depth -= 1;
            if depth == 0 {
                out.push((start, t));
            }
        }
    }
    out
}

/// Area and centroid of a planar cross-section of the solid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Section {
    pub area: f64,
    pub centroid: DVec3,
}

/// The cross-section of the solid by the plane through `origin` with unit normal `n`, counting only the
/// boundary segments whose midpoint satisfies `keep` (exact when `keep` selects whole loops). Each
/// triangle crossing the plane gives a segment oriented along `n × N` (counter-clockwise about `n` for
/// an outward mesh); area and centroid follow from the shoelace/Green formulas
/// `A = ½Σ(p×q)`, `Ā·x̄ = ⅙Σ(p+q)(p×q)`.
pub fn section(mesh: &TriMesh, origin: DVec3, n: DVec3, keep: impl Fn(DVec3) -> bool) -> Section {
    let (e1, e2) = n.any_orthonormal_pair();
    let (mut area2, mut mx, mut my) = (0.0, 0.0, 0.0);
    for i in 0..mesh.triangles.len() {
        let c = mesh.corners(i);
        let d = c.map(|p| (p - origin).dot(n));
        let side = d.map(|x| x >= 0.0);
        if side[0] == side[1] && side[1] == side[2] {
            continue;
        }
        let mut pts = [DVec3::ZERO; 2];
        let mut k = 0;
        for e in 0..3 {
            let f = (e + 1) % 3;
            if side[e] != side[f] && k < 2 {
                pts[k] = c[e] + (c[f] - c[e]) * (d[e] / (d[e] - d[f]));
                k += 1;
            }
        }
        let (mut p, mut q) = (pts[0], pts[1]);
        let tangent = n.cross((c[1] - c[0]).cross(c[2] - c[0]));
        if (q - p).dot(tangent) < 0.0 {
            std::mem::swap(&mut p, &mut q);
        }
        if !keep(0.5 * (p + q)) {
            continue;
        }
        let (px, py) = ((p - origin).dot(e1), (p - origin).dot(e2));
        let (qx, qy) = ((q - origin).dot(e1), (q - origin).dot(e2));
        let cr = px * qy - qx * py;
        area2 += cr;
        mx += (px + qx) * cr;
        my += (py + qy) * cr;
    }
    if area2 == 0.0 {
        return Section {
            area: 0.0,
            centroid: origin,
        };
    }
    let area = area2 / 2.0;
    Section {
        area,
        centroid: origin + e1 * (mx / (6.0 * area)) + e2 * (my / (6.0 * area)),
    }
}

/// The points where the plane cuts the mesh edges (the section outline's vertices).
pub fn section_points(mesh: &TriMesh, origin: DVec3, n: DVec3) -> Vec<DVec3> {
    let mut out = Vec::new();
    for i in 0..mesh.triangles.len() {
        let c = mesh.corners(i);
        let d = c.map(|p| (p - origin).dot(n));
        for e in 0..3 {
            let f = (e + 1) % 3;
            if (d[e] >= 0.0) != (d[f] >= 0.0) {
                out.push(c[e] + (c[f] - c[e]) * (d[e] / (d[e] - d[f])));
            }
        }
    }
    out
}

/// Rounds of neighbour averaging in [`smoothed_normals`] (about one edge length each).
const NORMAL_SMOOTHING_ROUNDS: usize = 4;

/// Unit triangle normals of the surface averaged over a few edge lengths (area-weighted vertex normals,
/// each round replaced by the sum over the triangles around the vertex), so a voxel staircase — the
/// isosurface of a tilted plane — reads as the plane it approximates.
pub fn smoothed_normals(mesh: &TriMesh) -> Vec<DVec3> {
    let mut vn = vec![DVec3::ZERO; mesh.vertices.len()];
    for (i, t) in mesh.triangles.iter().enumerate() {
        let [a, b, c] = mesh.corners(i);
        let n = (b - a).cross(c - a); // area-weighted
        for &k in t {
            vn[k as usize] += n;
        }
    }
    for _ in 0..NORMAL_SMOOTHING_ROUNDS {
        let mut acc = vn.clone();
        for t in &mesh.triangles {
            let s: DVec3 = t.iter().map(|&k| vn[k as usize]).sum();
            for &k in t {
                acc[k as usize] += s;
            }
        }
        vn = acc.into_iter().map(|v| v.normalize_or_zero()).collect();
    }
    mesh.triangles
        .iter()
        .map(|t| {
            t.iter()
                .map(|&k| vn[k as usize])
                .sum::<DVec3>()
                .normalize_or_zero()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_moments_sections_and_lines_are_exact() {
        let m = TriMesh::cuboid("b", DVec3::new(-1.0, -2.0, -3.0), DVec3::new(3.0, 2.0, 5.0));
        let (v, c, cov) = solid_moments(&m);
        assert!((v - 4.0 * 4.0 * 8.0).abs() < 1e-9);
        assert!((c - DVec3::new(1.0, 0.0, 1.0)).length() < 1e-12);
        // Variance of a uniform interval of length L is L²/12.
        assert!((cov.z_axis.z - 64.0 / 12.0).abs() < 1e-9);
        assert!(cov.x_axis.y.abs() < 1e-9);
        let s = section(&m, DVec3::new(0.0, 0.0, 1.0), DVec3::Z, |_| true);
        assert!((s.area - 16.0).abs() < 1e-9);
        assert!((s.centroid - DVec3::new(1.0, 0.0, 1.0)).length() < 1e-9);
        let iv = line_intervals(&m, DVec3::new(0.5, 0.3, 0.0), DVec3::Z);
        assert_eq!(iv.len(), 1);
        assert!((iv[0].0 + 3.0).abs() < 1e-12 && (iv[0].1 - 5.0).abs() < 1e-12);
    }
}
