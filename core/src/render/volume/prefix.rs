//! Running sums of μ along one axis of the clip box: what the Siddon walk ([`super::siddon`]) looks up.
//!
//! Between two crossings of its minor axes a ray stays in one column of voxels along its dominant axis
//! `A` (the other two indices fixed). With `S(i) = Σ_{i' < i} μ(…, i', …)` along that column, the
//! integral of μ over the column from its near face to the continuous coordinate `x` is `S` linearly
//! interpolated at `x` (μ is constant within a voxel), so the ray's stretch in the column costs two
//! lookups whatever the number of voxels it crosses. The sums are kept in f64: a column of 512 bone voxels
//! sums to ~25 mm⁻¹, and a difference of two such sums is exact to ~3·10⁻¹⁵ mm⁻¹, 13 digits below one
//! voxel's μ (f32 sums would keep only one or two digits of a short stretch's value). Built once per
//! renderer and axis, on first use.

use std::fmt;

/// `S` along axis `axis` over the clip box `[lo, hi]`. Entry `(i, j, k)` (relative to `lo`, the prefix
/// axis running `0..=n_axis`) holds the sum of its column's voxels before it. The layout puts the lower
/// of the two other axes fastest, then the prefix axis, then the higher one: the rays of neighbouring
/// pixels walk neighbouring columns (x in an AP view, y in a lateral one), whose sums at the same depth
/// then share cache lines.
pub(crate) struct AxisPrefix {
    pub(crate) sums: Vec<f64>,
    /// Strides of `sums` per axis.
    pub(crate) stride: [isize; 3],
}

impl fmt::Debug for AxisPrefix {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("AxisPrefix")
            .field("len", &self.sums.len())
            .field("stride", &self.stride)
            .finish()
    }
}

impl AxisPrefix {
    /// The running sums of `mu` (a `dims` grid, x fastest) along `axis` over the box `[lo, hi]`.
    pub(crate) fn build(
        mu: &[f32],
        dims: [usize; 3],
        lo: [usize; 3],
        hi: [usize; 3],
        axis: usize,
    ) -> Self {
        let n = [0, 1, 2].map(|a| hi[a] + 1 - lo[a]);
        let (p, q) = match axis {
            0 => (1, 2),
            1 => (0, 2),
            _ => (0, 1),
        };
        let mut stride = [0isize; 3];
        stride[p] = 1;
        stride[axis] = n[p] as isize;
        stride[q] = (n[p] * (n[axis] + 1)) as isize;
        let mu_stride = [1, dims[0], dims[0] * dims[1]];
        let corner: usize = (0..3).map(|a| lo[a] * mu_stride[a]).sum();
        let mut sums = vec![0.0f64; n[p] * (n[axis] + 1) * n[q]];
        // One slab of constant q at a time: rows of n[p] sums, row i + 1 = row i + the box's voxels at
        // depth i along the prefix axis. Sequential on purpose: this runs inside `OnceLock::get_or_init`
        // on the first ray that needs it, usually in a rayon task; a parallel build there could let this
        // thread, while it waits for a stolen half, pick up another ray of the same renderer and re-enter
        // the initialisation (a deadlock). The other threads wait for it, once per renderer and axis.
        sums.chunks_mut(n[p] * (n[axis] + 1))
            .enumerate()
            .for_each(|(k, slab)| {
                for i in 0..n[axis] {
                    let (before, after) = slab.split_at_mut((i + 1) * n[p]);
                    let start = corner + i * mu_stride[axis] + k * mu_stride[q];
                    let prev = &before[i * n[p]..];
                    for (j, (o, &s)) in after[..n[p]].iter_mut().zip(prev).enumerate() {
                        *o = s + f64::from(mu[start + j * mu_stride[p]]);
                    }
                }
            });
        AxisPrefix { sums, stride }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every entry equals the column's direct sum, on every axis of an off-origin box.
    #[test]
    fn prefix_entries_are_column_sums() {
        let dims = [7usize, 5, 4];
        let mu: Vec<f32> = (0..dims.iter().product::<usize>())
            .map(|i| ((i * 37) % 11) as f32 * 0.01)
            .collect();
        let (lo, hi) = ([1, 1, 0], [5, 3, 2]);
        for axis in 0..3 {
            let p = AxisPrefix::build(&mu, dims, lo, hi, axis);
            for k in 0..=(hi[2] - lo[2] + usize::from(axis == 2)) {
                for j in 0..=(hi[1] - lo[1] + usize::from(axis == 1)) {
                    for i in 0..=(hi[0] - lo[0] + usize::from(axis == 0)) {
                        let rel = [i, j, k];
                        let want: f64 = (0..rel[axis])
                            .map(|s| {
                                let mut v = [lo[0] + i, lo[1] + j, lo[2] + k];
                                v[axis] = lo[axis] + s;
                                f64::from(mu[v[0] + dims[0] * (v[1] + dims[1] * v[2])])
                            })
                            .sum();
                        let at = (0..3).map(|a| rel[a] as isize * p.stride[a]).sum::<isize>();
                        assert!(
                            (p.sums[at as usize] - want).abs() < 1e-12,
                            "axis {axis} {rel:?}"
                        );
                    }
                }
            }
        }
    }
}
