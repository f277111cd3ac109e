//! How much a vertebra mesh looks like another: orthographic silhouettes in the three anatomical views
//! (AP: along y onto x–z; LAT: along x onto y–z; axial: along z onto x–y) and their Dice overlap, after
//! centring both solids at their volume centroids and, optionally, rotating the second to the
//! orientation that overlaps best.
//!
//! Used to judge the phantom against vertebrae segmented from real CTs (`examples/phantom_vs_ct.rs`,
//! `tests/it/phantom_morphometry.rs`). Both meshes are taken in RAS+ world axes; the phantom's local axes are
//! the anatomical ones, a CT vertebra's are the scanner's, so a vertebra tilted in the scanner (lordosis,
//! scoliosis, patient rotation) is compared after the rotation search, which is a coordinate descent over
//! rotations about x, y and z (±`max_deg`, steps halving from 4° to 0.5°) maximising the mean of the three
//! views' Dice. Optionally the first mesh is scaled to the second's volume first, so a patient larger or
//! smaller than the morphometry's means is compared by shape.

use glam::{DMat3, DVec2, DVec3};

use super::TriMesh;
use super::auto_landmarks::solid_moments;

/// A silhouette view.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SilhouetteView {
    Ap,
    Lat,
    Axial,
}

impl SilhouetteView {
    pub const ALL: [SilhouetteView; 3] = [
        SilhouetteView::Ap,
        SilhouetteView::Lat,
        SilhouetteView::Axial,
    ];

    pub fn name(self) -> &'static str {
        match self {
            SilhouetteView::Ap => "AP",
            SilhouetteView::Lat => "LAT",
            SilhouetteView::Axial => "axial",
        }
    }

    /// The image's (u, v) coordinates of a point.
    fn project(self, p: DVec3) -> DVec2 {
        match self {
            SilhouetteView::Ap => DVec2::new(p.x, p.z),
            SilhouetteView::Lat => DVec2::new(p.y, p.z),
            SilhouetteView::Axial => DVec2::new(p.x, p.y),
        }
    }
}

/// A square binary image of `n × n` pixels of `pixel_mm`, centred on the origin.
#[derive(Debug, Clone, PartialEq)]
pub struct Silhouette {
    pub n: usize,
    pub pixel_mm: f64,
    /// Row-major, row = v, column = u.
    pub inside: Vec<bool>,
}

impl Silhouette {
    pub fn area_mm2(&self) -> f64 {
        self.inside.iter().filter(|&&b| b).count() as f64 * self.pixel_mm * self.pixel_mm
    }
}

/// The orthographic silhouette of `mesh` (closed: the union of its projected triangles is the
/// projection of the solid) on an `n × n` grid of `pixel_mm` centred on the origin. A pixel is inside
/// when its centre lies in a projected triangle (edges inclusive).
pub fn silhouette(mesh: &TriMesh, view: SilhouetteView, n: usize, pixel_mm: f64) -> Silhouette {
    let mut inside = vec![false; n * n];
    let half = n as f64 / 2.0;
    let to_px = |p: DVec3| view.project(p) / pixel_mm + DVec2::splat(half - 0.5);
    for i in 0..mesh.triangles.len() {
        let [a, b, c] = mesh.corners(i).map(to_px);
        let area = (b - a).perp_dot(c - a);
        if area.abs() < 1e-12 {
            continue;
        }
        let lo = a.min(b).min(c).ceil().max(DVec2::ZERO);
        let hi = a.max(b).max(c).floor().min(DVec2::splat(n as f64 - 1.0));
        if lo.x > hi.x || lo.y > hi.y {
            continue;
        }
        let s = area.signum();
        for y in lo.y as usize..=hi.y as usize {
            for x in lo.x as usize..=hi.x as usize {
                let p = DVec2::new(x as f64, y as f64);
                let w0 = (b - a).perp_dot(p - a) * s;
                let w1 = (c - b).perp_dot(p - b) * s;
                let w2 = (a - c).perp_dot(p - c) * s;
                if w0 >= 0.0 && w1 >= 0.0 && w2 >= 0.0 {
                    inside[y * n + x] = true;
                }
            }
        }
    }
    Silhouette {
        n,
        pixel_mm,
        inside,
    }
}

/// Dice coefficient `2|A∩B| / (|A| + |B|)` of two silhouettes of one grid (1 when both are empty).
pub fn dice(a: &Silhouette, b: &Silhouette) -> f64 {
    let (mut both, mut total) = (0usize, 0usize);
    for (&x, &y) in a.inside.iter().zip(&b.inside) {
        both += usize::from(x && y);
        total += usize::from(x) + usize::from(y);
    }
    if total == 0 {
        1.0
    } else {
        2.0 * both as f64 / total as f64
    }
}

/// `mesh` moved so its solid's volume centroid is at the origin.
pub fn centred(mesh: &TriMesh) -> TriMesh {
    let (_, c, _) = solid_moments(mesh);
    let mut m = mesh.clone();
    m.vertices.iter_mut().for_each(|v| *v -= c);
    m
}

/// The silhouette comparison of two meshes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SilhouetteComparison {
    /// Dice in AP, LAT, axial.
    pub dice: [f64; 3],
    /// Rotation applied to the second mesh (about x, y, z in turn, degrees; zero when not aligned).
    pub rotation_deg: DVec3,
    /// Scale applied to the first mesh (1 unless sizes were matched).
    pub scale: f64,
}

impl SilhouetteComparison {
    pub fn mean(&self) -> f64 {
        self.dice.iter().sum::<f64>() / 3.0
    }
}

/// Grid of the comparison: 0.5 mm pixels over 160 mm.
const PIXEL_MM: f64 = 0.5;
const GRID: usize = 320;

fn rotation(deg: DVec3) -> DMat3 {
    DMat3::from_rotation_z(deg.z.to_radians())
        * DMat3::from_rotation_y(deg.y.to_radians())
        * DMat3::from_rotation_x(deg.x.to_radians())
}

/// `m` rotated about the origin by `deg` (about x, then y, then z; degrees).
pub fn rotated(m: &TriMesh, deg: DVec3) -> TriMesh {
    let r = rotation(deg);
    let mut out = m.clone();
    out.vertices.iter_mut().for_each(|v| *v = r * *v);
    out
}

/// Silhouette Dice of `a` and `b` in the three views, both centred; when `max_deg > 0`, `b` is also
/// rotated (about its centroid) to the orientation within ±`max_deg` per axis that maximises the mean;
/// with `match_size`, `a` is first scaled about its centroid to the volume of `b` (shape, not size).
pub fn compare_silhouettes(
    a: &TriMesh,
    b: &TriMesh,
    max_deg: f64,
    match_size: bool,
) -> SilhouetteComparison {
    let (mut a, b) = (centred(a), centred(b));
    let scale = if match_size {
        (solid_moments(&b).0 / solid_moments(&a).0).cbrt()
    } else {
        1.0
    };
    a.vertices.iter_mut().for_each(|v| *v *= scale);
    let sa: Vec<Silhouette> = SilhouetteView::ALL
        .iter()
        .map(|&v| silhouette(&a, v, GRID, PIXEL_MM))
        .collect();
    let score = |deg: DVec3| {
        let m = rotated(&b, deg);
        let mut d = [0.0; 3];
        for (k, &v) in SilhouetteView::ALL.iter().enumerate() {
            d[k] = dice(&sa[k], &silhouette(&m, v, GRID, PIXEL_MM));
        }
        d
    };
    let mean = |d: &[f64; 3]| d.iter().sum::<f64>() / 3.0;
    let mut best = (DVec3::ZERO, score(DVec3::ZERO));
    let mut step = 4.0;
    while max_deg > 0.0 && step >= 0.5 {
        let mut improved = true;
        while improved {
            improved = false;
            for axis in 0..3 {
                for sign in [-1.0, 1.0] {
                    let mut deg = best.0;
                    deg[axis] += sign * step;
                    if deg[axis].abs() > max_deg {
                        continue;
                    }
                    let d = score(deg);
                    if mean(&d) > mean(&best.1) + 1e-9 {
                        best = (deg, d);
                        improved = true;
                    }
                }
            }
        }
        step /= 2.0;
    }
    SilhouetteComparison {
        dice: best.1,
        rotation_deg: best.0,
        scale,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn silhouettes_of_a_box_have_its_face_areas_and_dice_is_one_for_itself() {
        let m = TriMesh::cuboid(
            "b",
            DVec3::new(-10.0, -5.0, -3.0),
            DVec3::new(10.0, 5.0, 3.0),
        );
        let ap = silhouette(&m, SilhouetteView::Ap, GRID, PIXEL_MM);
        // Pixel edges fall on the box's faces (pixel centres at half-pixel offsets from them): the areas
        // are exact, 20 × 6 and 10 × 6 mm².
        assert_eq!(ap.area_mm2(), 120.0);
        let lat = silhouette(&m, SilhouetteView::Lat, GRID, PIXEL_MM);
        assert_eq!(lat.area_mm2(), 60.0);
        assert_eq!(dice(&ap, &ap), 1.0);
        // A box and the same box shifted: centring makes them identical.
        let mut moved = m.clone();
        moved
            .vertices
            .iter_mut()
            .for_each(|v| *v += DVec3::new(7.0, -3.0, 2.0));
        let c = compare_silhouettes(&m, &moved, 0.0, false);
        assert!(c.dice.iter().all(|&d| d > 0.999), "{c:?}");
    }

    #[test]
    fn the_rotation_search_undoes_a_tilt() {
        let m = TriMesh::cuboid(
            "b",
            DVec3::new(-20.0, -8.0, -4.0),
            DVec3::new(20.0, 8.0, 4.0),
        );
        let tilted = rotated(&m, DVec3::new(6.0, 0.0, -8.0));
        let plain = compare_silhouettes(&m, &tilted, 0.0, false);
        let aligned = compare_silhouettes(&m, &tilted, 15.0, false);
        assert!(aligned.mean() > 0.98 && aligned.mean() > plain.mean() + 0.02);
        assert!((aligned.rotation_deg - DVec3::new(-6.0, 0.0, 8.0)).length() < 1.5);
        // Size matching: a box and the same box doubled overlap fully once scaled.
        let mut big = m.clone();
        big.vertices.iter_mut().for_each(|v| *v *= 2.0);
        let c = compare_silhouettes(&m, &big, 0.0, true);
        assert!((c.scale - 2.0).abs() < 1e-9 && c.mean() > 0.99, "{c:?}");
    }
}
