//! Line integral of the trilinearly interpolated μ field by the midpoint rule:
//! `∫ μ dl ≈ Σ_n μ̃(p(t0 + (n + ½) h)) · h` with `h = (t1 − t0) / N`, `N = ⌈(t1 − t0) / step⌉`, where
//! `μ̃` interpolates the eight voxel centres around a point (coordinates clamped to the grid, so the
//! field is constant-extended half a voxel beyond the outer centres, like the voxel model).

use glam::DVec3;

use super::VolumeRenderer;

/// Midpoint-rule integral of trilinear μ over `t ∈ [t0, t1]` with steps of at most `step` mm.
pub(crate) fn integrate(
    r: &VolumeRenderer,
    p0: DVec3,
    dp: DVec3,
    t0: f64,
    t1: f64,
    step: f64,
) -> f64 {
    let len = t1 - t0;
    let n = (len / step).ceil().max(1.0) as usize;
    let h = len / n as f64;
    let mut p = p0 + (t0 + 0.5 * h) * dp;
    let dpos = h * dp;
    let mut sum = 0.0f64;
    for _ in 0..n {
        sum += sample(r, p);
        p += dpos;
    }
    sum * h
}

/// Trilinear interpolation of μ at continuous index `p` (clamped to `[0, n − 1]` per axis).
#[inline]
pub(crate) fn sample(r: &VolumeRenderer, p: DVec3) -> f64 {
    let [nx, ny, nz] = r.dims;
    let axis = |x: f64, n: usize| -> (usize, usize, f64) {
        let x = x.clamp(0.0, (n - 1) as f64);
        let i0 = (x.floor() as usize).min(n.saturating_sub(2));
        let i1 = (i0 + 1).min(n - 1);
        (i0, i1, x - i0 as f64)
    };
    let (x0, x1, fx) = axis(p.x, nx);
    let (y0, y1, fy) = axis(p.y, ny);
    let (z0, z1, fz) = axis(p.z, nz);
    let at = |i: usize, j: usize, k: usize| f64::from(r.mu[i + nx * (j + ny * k)]);
    let lerp = |a: f64, b: f64, f: f64| a + (b - a) * f;
    let c00 = lerp(at(x0, y0, z0), at(x1, y0, z0), fx);
    let c10 = lerp(at(x0, y1, z0), at(x1, y1, z0), fx);
    let c01 = lerp(at(x0, y0, z1), at(x1, y0, z1), fx);
    let c11 = lerp(at(x0, y1, z1), at(x1, y1, z1), fx);
    lerp(lerp(c00, c10, fy), lerp(c01, c11, fy), fz)
}
