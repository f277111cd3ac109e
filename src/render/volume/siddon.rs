//! Exact radiological path through a voxel grid: Siddon (Med. Phys. 12, 1985) in the incremental form of
//! Jacobs, Sundermann, De Sutter, Christiaens & Lemahieu (1998).
//!
//! In continuous index space the ray is `p(t) = p0 + t·dp` (t in world mm). Voxel `i` spans
//! `[i − ½, i + ½]` on each axis, so the plane crossings along axis `a` are equally spaced in t by
//! `Δt_a = 1 / |dp_a|`. Starting in the voxel that contains the entry point, each step moves to the
//! nearest next crossing `t_a`, adds `μ(voxel) · (t_a − t)` and advances one voxel along axis `a`:
//! `∫ μ dl = Σ_voxels μ_v · ℓ_v` exactly, in O(voxels crossed).

use glam::DVec3;

use super::VolumeRenderer;

/// `Σ μ_v ℓ_v` over the voxels the segment `t ∈ [t0, t1]` crosses (the segment is inside the clip box).
///
/// The walk is organised around the ray's dominant axis `a` (largest `|dp_a|`, so `Δt_a` is the smallest
/// plane spacing). Between two crossings of the minor axes the ray crosses whole `a`-slabs of identical
/// length `Δt_a`: those runs are summed without per-voxel decisions (`Δt_a · Σ μ`, several accumulators),
/// which is where a DRR ray spends nearly all its voxels. Minor-axis crossings and the ends take the
/// general step. The visited voxels and lengths are exactly those of Jacobs' three-way step.
pub(crate) fn integrate(r: &VolumeRenderer, p0: DVec3, dp: DVec3, t0: f64, t1: f64) -> f64 {
    let abs = dp.abs();
    if abs.x >= abs.y && abs.x >= abs.z {
        walk::<0>(r, p0, dp, t0, t1)
    } else if abs.y >= abs.z {
        walk::<1>(r, p0, dp, t0, t1)
    } else {
        walk::<2>(r, p0, dp, t0, t1)
    }
}

/// [`integrate`] for dominant axis `A`. A constant axis makes every per-axis index below a constant, so
/// the walk's state lives in registers rather than in arrays indexed at run time; plane crossings are
/// products with the precomputed `1 / dp_A` rather than divisions on the loop's critical path; and a run
/// ends exactly before the slab of the next event, so each event takes one general step, not two
/// (together: the real CT's 1024² AP DRR 547 → 403 ms on 2 cores, release, `cargo bench --bench all --
/// real_ct`).
fn walk<const A: usize>(r: &VolumeRenderer, p0: DVec3, dp: DVec3, t0: f64, t1: f64) -> f64 {
    let (b, c) = ((A + 1) % 3, (A + 2) % 3);
    let [nx, ny, _] = r.dims;
    let stride = [1isize, nx as isize, (nx * ny) as isize];
    // The voxel of the entry point: sample just inside the entry to avoid ties.
    let t_probe = t0 + 1e-9 * (t1 - t0);
    let entry = p0 + t_probe * dp;
    let mut idx = [0isize; 3];
    let mut step = [0isize; 3];
    let mut t_next = [f64::INFINITY; 3];
    let mut dt = [f64::INFINITY; 3];
    for a in 0..3 {
        let v = (entry[a] + 0.5).floor() as isize;
        idx[a] = v.clamp(r.lo[a] as isize, r.hi[a] as isize);
        if dp[a] > 0.0 {
            step[a] = 1;
            dt[a] = 1.0 / dp[a];
            t_next[a] = (idx[a] as f64 + 0.5 - p0[a]) / dp[a];
        } else if dp[a] < 0.0 {
            step[a] = -1;
            dt[a] = -1.0 / dp[a];
            t_next[a] = (idx[a] as f64 - 0.5 - p0[a]) / dp[a];
        }
    }
    let (lo, hi) = (r.lo.map(|v| v as isize), r.hi.map(|v| v as isize));
    let mu = &r.mu[..];
    let (sa, dta) = (step[A] * stride[A], dt[A]);
    let inv_dta = 1.0 / dta;
    // Exact distance to the far plane of voxel i along the dominant axis: `(i ± ½ − p0_A) / dp_A`, as a
    // product with `1 / dp_A` (within an ulp of the quotient).
    let (far_offset, inv_dpa) = (0.5 * step[A] as f64 - p0[A], 1.0 / dp[A]);
    let far_plane = |i: isize| (i as f64 + far_offset) * inv_dpa;
    let mut lin = idx[0] * stride[0] + idx[1] * stride[1] + idx[2] * stride[2];
    let mut t = t0;
    let mut sum = 0.0f64;
    loop {
        let t_minor = t_next[b].min(t_next[c]);
        let t_event = t_minor.min(t1);
        if t_next[A] < t_event {
            // Finish this slab, then run over the whole slabs that end before the next event: as many
            // as the quotient says, less any whose far plane (computed as the general step computes it)
            // does not lie strictly before the event, so that the slab after the run holds the event
            // (and lies inside the clip box: the event is at most the segment's end).
            sum += f64::from(mu[lin as usize]) * (t_next[A] - t);
            t = t_next[A];
            idx[A] += step[A];
            if idx[A] < lo[A] || idx[A] > hi[A] {
                return sum;
            }
            lin += sa;
            let mut whole = ((t_event - t) * inv_dta) as isize;
            while whole > 0 && far_plane(idx[A] + (whole - 1) * step[A]) >= t_event {
                whole -= 1;
            }
            if whole > 0 {
                let last = idx[A] + (whole - 1) * step[A];
                if last < lo[A] || last > hi[A] {
                    // Never expected (the run ends inside the clip box); keep the general step.
                    t_next[A] = far_plane(idx[A]);
                    continue;
                }
                let mut acc = [0.0f32; 4];
                let mut k = 0;
                while k + 4 <= whole {
                    for (j, x) in acc.iter_mut().enumerate() {
                        *x += mu[(lin + j as isize * sa) as usize];
                    }
                    lin += 4 * sa;
                    k += 4;
                }
                while k < whole {
                    acc[0] += mu[lin as usize];
                    lin += sa;
                    k += 1;
                }
                sum += f64::from((acc[0] + acc[1]) + (acc[2] + acc[3])) * dta;
                idx[A] += whole * step[A];
                t = far_plane(idx[A] - step[A]);
            }
            t_next[A] = far_plane(idx[A]);
            continue;
        }
        if t_event >= t1 {
            return sum + f64::from(mu[lin as usize]) * (t1 - t);
        }
        // A minor-axis crossing inside the current slab (two copies, so that each indexes its axis by a
        // constant).
        sum += f64::from(mu[lin as usize]) * (t_minor - t);
        t = t_minor;
        macro_rules! cross {
            ($m:expr) => {{
                idx[$m] += step[$m];
                if idx[$m] < lo[$m] || idx[$m] > hi[$m] {
                    return sum;
                }
                lin += step[$m] * stride[$m];
                t_next[$m] += dt[$m];
            }};
        }
        if t_next[b] <= t_next[c] {
            cross!(b)
        } else {
            cross!(c)
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::DMat4;

    use super::super::{VolumeMethod, VolumeRenderer};
    use super::*;

    /// Siddon's original form: every plane crossing of the segment, sorted; each interval belongs to the
    /// voxel that contains its midpoint.
    fn sorted_crossings(r: &VolumeRenderer, p0: DVec3, dp: DVec3, t0: f64, t1: f64) -> f64 {
        let mut ts = vec![t0, t1];
        for a in 0..3 {
            if dp[a] == 0.0 {
                continue;
            }
            for i in r.lo[a]..=r.hi[a] + 1 {
                let t = (i as f64 - 0.5 - p0[a]) / dp[a];
                if t > t0 && t < t1 {
                    ts.push(t);
                }
            }
        }
        ts.sort_by(f64::total_cmp);
        let [nx, ny, _] = r.dims;
        ts.windows(2)
            .map(|w| {
                let m = p0 + 0.5 * (w[0] + w[1]) * dp;
                let i = [0, 1, 2].map(|a| ((m[a] + 0.5).floor() as usize).clamp(r.lo[a], r.hi[a]));
                f64::from(r.mu[i[0] + nx * (i[1] + ny * i[2])]) * (w[1] - w[0])
            })
            .sum()
    }

    #[test]
    fn slab_runs_match_sorted_plane_crossings() {
        let dims = [37usize, 29, 23];
        let n = dims.iter().product::<usize>();
        // Deterministic pseudo-random μ, with runs of zeros (air).
        let mu: Vec<f32> = (0..n)
            .map(|i| {
                let x = (i as u64).wrapping_mul(6364136223846793005).rotate_left(17) % 1000;
                if x < 150 { 0.0 } else { x as f32 * 1e-4 }
            })
            .collect();
        let r = VolumeRenderer {
            dims,
            mu,
            world_to_index: DMat4::IDENTITY,
            lo: [0, 0, 0],
            hi: dims.map(|d| d - 1),
            method: VolumeMethod::Siddon,
            mu_water: 1.0,
            step_mm: 0.5,
        };
        let (mut checked, mut per_axis) = (0, [0usize; 3]);
        for k in 0..400 {
            let f = k as f64;
            // Rays from outside the box in all octants, some nearly axis-aligned.
            let origin = DVec3::new(
                18.0 + 60.0 * (f * 0.37).sin(),
                14.0 + 60.0 * (f * 0.73).cos(),
                11.0 + 50.0 * (f * 1.31).sin(),
            );
            let target = DVec3::new(
                18.0 + 10.0 * (f * 2.1).cos(),
                14.0 + 8.0 * (f * 1.7).sin(),
                11.0 + 6.0 * (f * 0.9).cos(),
            );
            let mut dir = (target - origin).normalize();
            if k % 10 == 0 {
                dir = (dir * DVec3::new(1.0, 1e-3, 1e-3)).normalize();
            }
            let Some((t0, t1)) = r.clip(origin, dir) else {
                continue;
            };
            let got = integrate(&r, origin, dir, t0, t1);
            let want = sorted_crossings(&r, origin, dir, t0, t1);
            assert!(
                (got - want).abs() <= 1e-5 * want.abs().max(1e-3),
                "ray {k}: {got} vs {want}"
            );
            checked += 1;
            let abs = dir.abs();
            per_axis[if abs.x >= abs.y && abs.x >= abs.z {
                0
            } else if abs.y >= abs.z {
                1
            } else {
                2
            }] += 1;
        }
        assert!(checked > 300);
        // Every dominant axis's walk is exercised.
        assert!(per_axis.iter().all(|&n| n >= 40), "{per_axis:?}");
    }
}
