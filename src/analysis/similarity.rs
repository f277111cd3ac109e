//! Image similarity of two DRRs of the same size: NCC, SSIM, mutual information, gradient correlation.

use rayon::prelude::*;

use crate::io::ImageF32;
use crate::{Error, Result};

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
    check_pair(a, b)?;
    pearson(
        a.data.iter().map(|&v| f64::from(v)),
        b.data.iter().map(|&v| f64::from(v)),
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
pub fn ssim(reference: &ImageF32, other: &ImageF32) -> Result<f64> {
    check_pair(reference, other)?;
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
    // Horizontal pass: for each row and valid column, the five windowed moments.
    let horiz: Vec<[f64; 5]> = (0..h)
        .into_par_iter()
        .flat_map_iter(|v| {
            let (ra, rb) = (
                &reference.data[v * w..(v + 1) * w],
                &other.data[v * w..(v + 1) * w],
            );
            (0..wo).map(move |u| {
                let mut m = [0.0; 5];
                for (k, gk) in g.iter().enumerate() {
                    let (x, y) = (f64::from(ra[u + k]), f64::from(rb[u + k]));
                    m[0] += gk * x;
                    m[1] += gk * y;
                    m[2] += gk * x * x;
                    m[3] += gk * y * y;
                    m[4] += gk * x * y;
                }
                m
            })
        })
        .collect();
    // Vertical pass and the SSIM map, summed per output row.
    let total: f64 = (0..ho)
        .into_par_iter()
        .map(|v| {
            (0..wo)
                .map(|u| {
                    let mut m = [0.0; 5];
                    for (k, gk) in g.iter().enumerate() {
                        let hm = &horiz[(v + k) * wo + u];
                        for (mi, hi) in m.iter_mut().zip(hm) {
                            *mi += gk * hi;
                        }
                    }
                    let [ma, mb, saa, sbb, sab] = m;
                    let (va, vb, cab) = (saa - ma * ma, sbb - mb * mb, sab - ma * mb);
                    ((2.0 * ma * mb + c1) * (2.0 * cab + c2))
                        / ((ma * ma + mb * mb + c1) * (va + vb + c2))
                })
                .sum::<f64>()
        })
        .sum();
    Ok(total / (wo * ho) as f64)
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
    check_pair(a, b)?;
    if !(2..=4096).contains(&bins) {
        return Err(Error::invalid(
            "bins",
            format!("must be 2..=4096, got {bins}"),
        ));
    }
    let range = |img: &ImageF32| {
        img.data
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), &v| {
                (l.min(v), h.max(v))
            })
    };
    let ((la, ha), (lb, hb)) = (range(a), range(b));
    let mut joint = vec![0u64; bins * bins];
    for (&x, &y) in a.data.iter().zip(&b.data) {
        joint[bin_of(x, la, ha, bins) * bins + bin_of(y, lb, hb, bins)] += 1;
    }
    let n = a.data.len() as f64;
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

/// Sobel gradients (x, y) of the interior pixels (the one-pixel border is skipped).
fn sobel(img: &ImageF32) -> (Vec<f64>, Vec<f64>) {
    let (w, h) = (img.width as usize, img.height as usize);
    let p = |u: usize, v: usize| f64::from(img.data[v * w + u]);
    let mut gx = Vec::with_capacity(w.saturating_sub(2) * h.saturating_sub(2));
    let mut gy = Vec::with_capacity(gx.capacity());
    for v in 1..h.saturating_sub(1) {
        for u in 1..w.saturating_sub(1) {
            gx.push(
                p(u + 1, v - 1) + 2.0 * p(u + 1, v) + p(u + 1, v + 1)
                    - p(u - 1, v - 1)
                    - 2.0 * p(u - 1, v)
                    - p(u - 1, v + 1),
            );
            gy.push(
                p(u - 1, v + 1) + 2.0 * p(u, v + 1) + p(u + 1, v + 1)
                    - p(u - 1, v - 1)
                    - 2.0 * p(u, v - 1)
                    - p(u + 1, v - 1),
            );
        }
    }
    (gx, gy)
}

/// Gradient correlation (Penney et al. 1998): the mean of the NCCs of the Sobel x and y gradient images.
pub fn gradient_correlation(a: &ImageF32, b: &ImageF32) -> Result<f64> {
    check_pair(a, b)?;
    if a.width < 3 || a.height < 3 {
        return Err(Error::invalid(
            "images",
            "gradient correlation needs at least 3×3 pixels",
        ));
    }
    let ((ax, ay), (bx, by)) = rayon::join(|| sobel(a), || sobel(b));
    let cx = pearson(ax.iter().copied(), bx.iter().copied())?;
    let cy = pearson(ay.iter().copied(), by.iter().copied())?;
    Ok(0.5 * (cx + cy))
}
