//! Image similarity of two DRRs of the same size: NCC, SSIM, mutual information, gradient correlation,
//! over the whole image or over a [`Region`] (the `*_in` forms: a windowed measure counts the windows
//! whose centre pixel is in the region).

use rayon::prelude::*;

use super::region::Region;
use crate::io::ImageF32;
use crate::{Error, Result};

fn check_region(a: &ImageF32, region: Option<&Region>) -> Result<()> {
    match region {
        Some(r) if (r.width, r.height) != (a.width, a.height) || r.inside.len() != a.data.len() => {
            Err(Error::invalid(
                "region",
                format!(
                    "{}×{} for {}×{} images",
                    r.width, r.height, a.width, a.height
                ),
            ))
        }
        Some(r) if r.is_empty() => Err(Error::invalid("region", "holds no pixel")),
        _ => Ok(()),
    }
}

/// The values of `img` at the pixels of `region` (every pixel when `None`), in row order.
fn pixels<'a>(
    img: &'a ImageF32,
    region: Option<&'a Region>,
) -> impl Iterator<Item = f32> + Clone + 'a {
    img.data
        .iter()
        .enumerate()
        .filter(move |(i, _)| counts(region, *i))
        .map(|(_, &v)| v)
}

/// Whether pixel `i` counts: every pixel without a region.
#[inline]
fn counts(region: Option<&Region>, i: usize) -> bool {
    region.is_none_or(|r| r.inside[i])
}

fn check_pair(a: &ImageF32, b: &ImageF32) -> Result<()> {
    if (a.width, a.height) != (b.width, b.height) || a.data.len() != b.data.len() {
        return Err(Error::invalid(
            "images",
            format!(
                "sizes differ: {}×{} vs {}×{}",
                a.width, a.height, b.width, b.height
            ),
        ));
    }
    if a.data.iter().chain(&b.data).any(|v| !v.is_finite()) {
        return Err(Error::invalid("images", "contain a non-finite pixel value"));
    }
    Ok(())
}

/// Per row: true when the row is exactly zero in both images (DRR background). A filter window over
/// such rows only sees zeros, so its result is known without filtering (see [`ssim`],
/// [`gradient_correlation`]); skipping them is exact, not an approximation.
fn blank_rows(a: &ImageF32, b: &ImageF32) -> Vec<bool> {
    let w = a.width as usize;
    a.data
        .chunks(w)
        .zip(b.data.chunks(w))
        .map(|(ra, rb)| ra.iter().chain(rb).all(|&v| v == 0.0))
        .collect()
}

/// Pearson correlation of two equally long sequences (accumulated in f64).
fn pearson(
    a: impl Iterator<Item = f64> + Clone,
    b: impl Iterator<Item = f64> + Clone,
) -> Result<f64> {
    let n = a.clone().count() as f64;
    let ma = a.clone().sum::<f64>() / n;
    let mb = b.clone().sum::<f64>() / n;
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.zip(b) {
        let (dx, dy) = (x - ma, y - mb);
        sab += dx * dy;
        saa += dx * dx;
        sbb += dy * dy;
    }
    if saa <= 0.0 || sbb <= 0.0 {
        return Err(Error::Numerical(
            "correlation is undefined for a constant image".into(),
        ));
    }
    Ok(sab / (saa * sbb).sqrt())
}

/// Normalised cross-correlation `Σ (a − ā)(b − b̄) / sqrt(Σ (a − ā)² Σ (b − b̄)²)` over all pixels.
pub fn ncc(a: &ImageF32, b: &ImageF32) -> Result<f64> {
    ncc_in(a, b, None)
}

/// [`ncc`] over the pixels of `region` (all pixels when `None`).
pub fn ncc_in(a: &ImageF32, b: &ImageF32, region: Option<&Region>) -> Result<f64> {
    check_pair(a, b)?;
    check_region(a, region)?;
    pearson(
        pixels(a, region).map(f64::from),
        pixels(b, region).map(f64::from),
    )
}

/// The normalised 1D Gaussian of the SSIM window (11 taps, σ = 1.5).
fn gaussian_window() -> [f64; 11] {
    let mut w: [f64; 11] = std::array::from_fn(|i| {
        let x = i as f64 - 5.0;
        (-x * x / (2.0 * 1.5 * 1.5)).exp()
    });
    let s: f64 = w.iter().sum();
    w.iter_mut().for_each(|v| *v /= s);
    w
}

/// Mean SSIM (Wang, Bovik, Sheikh & Simoncelli 2004):
/// `((2 μa μb + C1)(2 σab + C2)) / ((μa² + μb² + C1)(σa² + σb² + C2))` with an 11×11 Gaussian window
/// (σ = 1.5), `C1 = (0.01 L)²`, `C2 = (0.03 L)²`, `L` the reference's data range (max − min; 1 if the
/// reference is constant). Averaged over the pixels where the whole window fits inside the image.
/// A window over zeros in both images has every moment exactly 0, so its SSIM is exactly
/// `C1·C2 / (C1·C2) = 1`: output rows whose 11 input rows are all zero contribute exactly their width.
pub fn ssim(reference: &ImageF32, other: &ImageF32) -> Result<f64> {
    ssim_in(reference, other, None)
}

/// [`ssim`] averaged over the windows whose centre pixel is in `region` (every window when `None`);
/// `L` is still the whole reference's data range.
pub fn ssim_in(reference: &ImageF32, other: &ImageF32, region: Option<&Region>) -> Result<f64> {
    let [whole, inside] = ssim_sums(reference, other, region)?;
    mean_of(if region.is_some() { inside } else { whole })
}

/// [`ssim`] over the whole image and over `region`, from one pass over the SSIM map.
pub fn ssim_whole_and_in(
    reference: &ImageF32,
    other: &ImageF32,
    region: &Region,
) -> Result<(f64, f64)> {
    let [whole, inside] = ssim_sums(reference, other, Some(region))?;
    Ok((mean_of(whole)?, mean_of(inside)?))
}

/// The mean of a (sum, count) pair; an error for no windows.
fn mean_of((sum, n): (f64, usize)) -> Result<f64> {
    if n == 0 {
        return Err(Error::invalid(
            "region",
            "holds no pixel at least 5 px inside the image (SSIM's window)",
        ));
    }
    Ok(sum / n as f64)
}

/// (sum, count) of the SSIM map over every window and over the windows centred in `region` (every
/// window when `None`).
fn ssim_sums(
    reference: &ImageF32,
    other: &ImageF32,
    region: Option<&Region>,
) -> Result<[(f64, usize); 2]> {
    check_pair(reference, other)?;
    check_region(reference, region)?;
    let (w, h) = (reference.width as usize, reference.height as usize);
    if w < 11 || h < 11 {
        return Err(Error::invalid(
            "images",
            "SSIM needs images of at least 11×11 pixels",
        ));
    }
    let (lo, hi) = reference
        .data
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    let range = if hi > lo { f64::from(hi - lo) } else { 1.0 };
    let (c1, c2) = ((0.01 * range).powi(2), (0.03 * range).powi(2));
    let g = gaussian_window();
    let (wo, ho) = (w - 10, h - 10);
    let blank = blank_rows(reference, other);
    // The windows of output row v are centred on image row v + 5, columns u + 5.
    let centred = |v: usize, u: usize| counts(region, (v + 5) * w + u + 5);
    let windows: Vec<usize> = match region {
        None => vec![wo; ho],
        Some(_) => (0..ho)
            .map(|v| (0..wo).filter(|&u| centred(v, u)).count())
            .collect(),
    };
    // Per output row: a vertical pass over the 11 input rows into five moment rows (a, b, a², b², ab),
    // then a horizontal pass; tap-outer loops over contiguous rows vectorise and stay in cache.
    let rows: Vec<(f64, f64)> = (0..ho)
        .into_par_iter()
        .map(|v| {
            if blank[v..v + 11].iter().all(|&z| z) {
                return (wo as f64, windows[v] as f64);
            }
            let mut cols: [Vec<f64>; 5] = std::array::from_fn(|_| vec![0.0; w]);
            for (j, gj) in g.iter().enumerate() {
                let r = (v + j) * w;
                let (ra, rb) = (&reference.data[r..r + w], &other.data[r..r + w]);
                let [c0, c1, c2, c3, c4] = &mut cols;
                for u in 0..w {
                    let (x, y) = (f64::from(ra[u]), f64::from(rb[u]));
                    c0[u] += gj * x;
                    c1[u] += gj * y;
                    c2[u] += gj * x * x;
                    c3[u] += gj * y * y;
                    c4[u] += gj * x * y;
                }
            }
            let mut m: [Vec<f64>; 5] = std::array::from_fn(|_| vec![0.0; wo]);
            for (mi, ci) in m.iter_mut().zip(&cols) {
                for (k, gk) in g.iter().enumerate() {
                    for (o, c) in mi.iter_mut().zip(&ci[k..k + wo]) {
                        *o += gk * c;
                    }
                }
            }
            let (mut all, mut inside) = (0.0, 0.0);
            #[allow(clippy::needless_range_loop)] // u indexes five moment rows and the region
            for u in 0..wo {
                let (ma, mb) = (m[0][u], m[1][u]);
                let (va, vb, cab) = (m[2][u] - ma * ma, m[3][u] - mb * mb, m[4][u] - ma * mb);
                let s = ((2.0 * ma * mb + c1) * (2.0 * cab + c2))
                    / ((ma * ma + mb * mb + c1) * (va + vb + c2));
                all += s;
                if centred(v, u) {
                    inside += s;
                }
            }
            (all, inside)
        })
        .collect();
    // Rows summed in row order: a parallel reduction's order depends on thread scheduling, and the
    // same images must give the same SSIM to the last bit on any machine.
    let (all, inside) = rows
        .iter()
        .fold((0.0, 0.0), |(a, b), (x, y)| (a + x, b + y));
    Ok([(all, wo * ho), (inside, windows.iter().sum())])
}

/// Bin index of `v` among `bins` equal bins spanning `[lo, hi]` (the maximum goes in the last bin).
fn bin_of(v: f32, lo: f32, hi: f32, bins: usize) -> usize {
    if hi <= lo {
        return 0;
    }
    let t = f64::from(v - lo) / f64::from(hi - lo);
    ((t * bins as f64) as usize).min(bins - 1)
}

/// Mutual information `Σ p(a,b) ln(p(a,b) / (p(a) p(b)))` in nats, from a joint histogram of `bins ×
/// bins` equal-width bins, each image binned over its own [min, max]. 64 bins is the usual choice for
/// DRRs of ~1 Mpx.
pub fn mutual_information(a: &ImageF32, b: &ImageF32, bins: usize) -> Result<f64> {
    mutual_information_in(a, b, bins, None)
}

/// [`mutual_information`] of the pixels of `region` (all pixels when `None`), each image binned over
/// its own [min, max] within the region.
pub fn mutual_information_in(
    a: &ImageF32,
    b: &ImageF32,
    bins: usize,
    region: Option<&Region>,
) -> Result<f64> {
    check_pair(a, b)?;
    check_region(a, region)?;
    if !(2..=4096).contains(&bins) {
        return Err(Error::invalid(
            "bins",
            format!("must be 2..=4096, got {bins}"),
        ));
    }
    let range = |img: &ImageF32| {
        pixels(img, region).fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), v| {
            (l.min(v), h.max(v))
        })
    };
    let ((la, ha), (lb, hb)) = (range(a), range(b));
    let mut joint = vec![0u64; bins * bins];
    let mut n = 0u64;
    for (x, y) in pixels(a, region).zip(pixels(b, region)) {
        joint[bin_of(x, la, ha, bins) * bins + bin_of(y, lb, hb, bins)] += 1;
        n += 1;
    }
    let n = n as f64;
    let mut pa = vec![0.0; bins];
    let mut pb = vec![0.0; bins];
    for i in 0..bins {
        for j in 0..bins {
            let p = joint[i * bins + j] as f64 / n;
            pa[i] += p;
            pb[j] += p;
        }
    }
    let mut mi = 0.0;
    for i in 0..bins {
        for j in 0..bins {
            let p = joint[i * bins + j] as f64 / n;
            if p > 0.0 {
                mi += p * (p / (pa[i] * pb[j])).ln();
            }
        }
    }
    Ok(mi)
}

/// Sobel x and y responses at interior pixel `u + 1` of the three rows `r0, r1, r2`.
#[inline]
pub(crate) fn sobel_at(r0: &[f32], r1: &[f32], r2: &[f32], u: usize) -> (f64, f64) {
    let f = |r: &[f32], k: usize| f64::from(r[k]);
    let gx = f(r0, u + 2) - f(r0, u) + 2.0 * (f(r1, u + 2) - f(r1, u)) + f(r2, u + 2) - f(r2, u);
    let gy =
        f(r2, u) - f(r0, u) + 2.0 * (f(r2, u + 1) - f(r0, u + 1)) + f(r2, u + 2) - f(r0, u + 2);
    (gx, gy)
}

/// Rows `v, v + 1, v + 2` of an image of width `w`.
pub(crate) fn three_rows(img: &ImageF32, v: usize, w: usize) -> (&[f32], &[f32], &[f32]) {
    let r = |k: usize| &img.data[(v + k) * w..(v + k + 1) * w];
    (r(0), r(1), r(2))
}

/// Correlation moments `[n, Σx, Σy, Σx², Σy², Σxy]` of one gradient component pair.
type Moments = [f64; 6];

fn add_moments(m: &mut Moments, x: f64, y: f64) {
    m[0] += 1.0;
    m[1] += x;
    m[2] += y;
    m[3] += x * x;
    m[4] += y * y;
    m[5] += x * y;
}

fn correlation(m: &Moments) -> Result<f64> {
    let [n, sx, sy, sxx, syy, sxy] = *m;
    let (vx, vy, cxy) = (sxx - sx * sx / n, syy - sy * sy / n, sxy - sx * sy / n);
    if vx <= 0.0 || vy <= 0.0 {
        return Err(Error::Numerical(
            "gradient correlation is undefined for an image without gradients".into(),
        ));
    }
    Ok(cxy / (vx * vy).sqrt())
}

/// Gradient correlation (Penney et al. 1998): the mean of the NCCs of the Sobel x and y gradient images.
pub fn gradient_correlation(a: &ImageF32, b: &ImageF32) -> Result<f64> {
    gradient_correlation_in(a, b, None)
}

/// [`gradient_correlation`] over the Sobel responses centred on pixels of `region` (all when `None`).
pub fn gradient_correlation_in(a: &ImageF32, b: &ImageF32, region: Option<&Region>) -> Result<f64> {
    let [whole, inside] = gradient_moments(a, b, region)?;
    moments_correlation(if region.is_some() { &inside } else { &whole })
}

/// [`gradient_correlation`] over the whole image and over `region`, from one pass of Sobel responses.
pub fn gradient_correlation_whole_and_in(
    a: &ImageF32,
    b: &ImageF32,
    region: &Region,
) -> Result<(f64, f64)> {
    let [whole, inside] = gradient_moments(a, b, Some(region))?;
    Ok((moments_correlation(&whole)?, moments_correlation(&inside)?))
}

/// The x and y gradient moments of a pass.
type GradientMoments = (Moments, Moments);

fn moments_correlation((mx, my): &GradientMoments) -> Result<f64> {
    Ok(0.5 * (correlation(mx)? + correlation(my)?))
}

/// The gradient moments over every interior pixel and over those in `region` (all when `None`).
fn gradient_moments(
    a: &ImageF32,
    b: &ImageF32,
    region: Option<&Region>,
) -> Result<[GradientMoments; 2]> {
    check_pair(a, b)?;
    check_region(a, region)?;
    if a.width < 3 || a.height < 3 {
        return Err(Error::invalid(
            "images",
            "gradient correlation needs at least 3×3 pixels",
        ));
    }
    // One pass over the rows: the Sobel responses of both images feed the correlation moments
    // directly (gradients have near-zero mean, so the one-pass variance loses nothing in f64). Three
    // rows of zeros in both images give zero responses: they only count pixels (adding +0 to the
    // other moments changes nothing), so they are counted without being filtered.
    let w = a.width as usize;
    let blank = blank_rows(a, b);
    let rows: Vec<[GradientMoments; 2]> = (0..a.height as usize - 2)
        .into_par_iter()
        .map(|v| {
            let mut all: GradientMoments = ([0.0; 6], [0.0; 6]);
            let mut inside: GradientMoments = ([0.0; 6], [0.0; 6]);
            // The responses of row v are centred on image row v + 1, columns u + 1.
            let centred = |u: usize| counts(region, (v + 1) * w + u + 1);
            if blank[v..v + 3].iter().all(|&z| z) {
                let n = (0..w - 2).filter(|&u| centred(u)).count() as f64;
                (all.0[0], all.1[0]) = ((w - 2) as f64, (w - 2) as f64);
                (inside.0[0], inside.1[0]) = (n, n);
                return [all, inside];
            }
            let ((a0, a1, a2), (b0, b1, b2)) = (three_rows(a, v, w), three_rows(b, v, w));
            for u in 0..w - 2 {
                let (ax, ay) = sobel_at(a0, a1, a2, u);
                let (bx, by) = sobel_at(b0, b1, b2, u);
                add_moments(&mut all.0, ax, bx);
                add_moments(&mut all.1, ay, by);
                if centred(u) {
                    add_moments(&mut inside.0, ax, bx);
                    add_moments(&mut inside.1, ay, by);
                }
            }
            [all, inside]
        })
        .collect();
    // Row moments summed in row order, so the result does not depend on thread scheduling.
    let mut total: [GradientMoments; 2] = [([0.0; 6], [0.0; 6]); 2];
    for row in &rows {
        for (t, r) in total.iter_mut().zip(row) {
            for k in 0..6 {
                t.0[k] += r.0[k];
                t.1[k] += r.1[k];
            }
        }
    }
    Ok(total)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth blob with a ridge, centred at `(cx, cy)`, on a `w × h` image.
    fn blob(w: u32, h: u32, cx: f64, cy: f64) -> ImageF32 {
        let mut img = ImageF32::zeros(w, h);
        for v in 0..h {
            for u in 0..w {
                let (x, y) = (f64::from(u) - cx, f64::from(v) - cy);
                let r2 = x * x + y * y;
                let value = (-r2 / 800.0).exp() + 0.3 * (x / 7.0).sin() * (-r2 / 3000.0).exp();
                img.data[(v * w + u) as usize] = value as f32;
            }
        }
        img
    }

    #[test]
    fn ssim_and_gradient_correlation_do_not_depend_on_the_thread_count() {
        let (a, b) = (blob(301, 257, 150.0, 120.0), blob(301, 257, 153.5, 118.0));
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    (
                        ssim(&a, &b).unwrap().to_bits(),
                        gradient_correlation(&a, &b).unwrap().to_bits(),
                    )
                })
        };
        let serial = run(1);
        for threads in [2, 3, 8] {
            for _ in 0..5 {
                assert_eq!(run(threads), serial, "{threads} threads");
            }
        }
    }
}
