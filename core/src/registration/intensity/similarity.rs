//! The similarities of intensity-based registration, written as normalised residuals.
//!
//! Every similarity here is a weighted mean of normalised cross-correlations of *blocks* of features:
//! `S = Σ_k w_k ⟨â_k, b̂_k⟩` with `Σ w_k = 1` and `x̂ = (x − x̄) / ‖x − x̄‖`. Because `‖â‖ = ‖b̂‖ = 1`,
//! `S = 1 − ½ Σ_k w_k ‖â_k − b̂_k‖²`, so maximising `S` is the least-squares problem on the residual
//! `r_k = √w_k (â_k − b̂_k)` that Levenberg–Marquardt solves.
//! * [`Similarity::Ncc`]: one block, the pixel values (the NCC of [`crate::analysis::ncc`]).
//! * [`Similarity::GradientCorrelation`] (Penney et al. 1998): two blocks of weight ½, the Sobel x and y
//!   responses at interior pixels (the value of [`crate::analysis::gradient_correlation`]).
//! * [`Similarity::GradientNcc`]: one block, the Sobel gradient *vectors* `(gx, gy)` of every interior
//!   pixel correlated together (one NCC of the gradient field, where gradient correlation averages two).
//! * [`Similarity::LocalNcc`]: the image tiled into `patch × patch` pixel patches (edge patches smaller),
//!   one block each, equal weights over the patches where the fixed image is not constant.
//!
//! The moving image is normalised with a small regulariser, `(x − x̄) / √(‖x − x̄‖² + ε_k)`, so a block
//! that empties (anatomy leaving a patch) goes smoothly to zero instead of jumping.

use crate::analysis::{sobel_at, three_rows};
use crate::io::ImageF32;
use crate::{Error, Result};

/// An image similarity for intensity-based registration (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Similarity {
    Ncc,
    GradientCorrelation,
    GradientNcc,
    /// Patch-wise NCC over `patch_px × patch_px` patches of each level's image.
    LocalNcc {
        patch_px: u32,
    },
}

/// Default patch side of [`Similarity::LocalNcc`] (px of each level's image).
pub const DEFAULT_PATCH_PX: u32 = 16;

impl Similarity {
    /// The spellings `ncc`, `gc` (or `gradient-correlation`), `gncc` (or `gradient-ncc`), `lncc` (or
    /// `local-ncc`, with [`DEFAULT_PATCH_PX`]) and `lncc:P` (patch side P px).
    pub fn parse(s: &str) -> Result<Similarity> {
        let bad = || {
            Error::invalid(
                "similarity",
                format!("unknown similarity '{s}' (use ncc, gc, gncc, lncc or lncc:PATCH_PX)"),
            )
        };
        match s {
            "ncc" => Ok(Similarity::Ncc),
            "gc" | "gradient-correlation" => Ok(Similarity::GradientCorrelation),
            "gncc" | "gradient-ncc" => Ok(Similarity::GradientNcc),
            "lncc" | "local-ncc" => Ok(Similarity::LocalNcc {
                patch_px: DEFAULT_PATCH_PX,
            }),
            _ => {
                let p = s.strip_prefix("lncc:").ok_or_else(bad)?;
                match p.parse::<u32>() {
                    Ok(patch_px) if (3..=4096).contains(&patch_px) => {
                        Ok(Similarity::LocalNcc { patch_px })
                    }
                    _ => Err(bad()),
                }
            }
        }
    }

    /// The canonical spelling ([`Similarity::parse`] reads it back).
    pub fn name(&self) -> String {
        match self {
            Similarity::Ncc => "ncc".into(),
            Similarity::GradientCorrelation => "gc".into(),
            Similarity::GradientNcc => "gncc".into(),
            Similarity::LocalNcc { patch_px } => format!("lncc:{patch_px}"),
        }
    }
}

/// Where each block's features sit in the feature vector, and its weight.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    /// `(start, len)` of each block.
    pub blocks: Vec<(usize, usize)>,
    pub weights: Vec<f64>,
    pub len: usize,
}

/// Writes the features of `img` under `sim` into `out` (resized), block by block, and returns the layout
/// (the same for every image of this size, so fixed and moving features line up).
pub fn features(sim: Similarity, img: &ImageF32, out: &mut Vec<f64>) -> Result<Layout> {
    let (w, h) = (img.width as usize, img.height as usize);
    out.clear();
    let mut blocks = Vec::new();
    match sim {
        Similarity::Ncc => {
            out.extend(img.data.iter().map(|&v| f64::from(v)));
            blocks.push((0, out.len()));
        }
        Similarity::GradientCorrelation | Similarity::GradientNcc => {
            if w < 3 || h < 3 {
                return Err(Error::invalid(
                    "similarity",
                    "gradient similarities need at least 3×3 pixels",
                ));
            }
            let n = (w - 2) * (h - 2);
            out.resize(2 * n, 0.0);
            let (gx, gy) = out.split_at_mut(n);
            for v in 0..h - 2 {
                let (r0, r1, r2) = three_rows(img, v, w);
                for u in 0..w - 2 {
                    let (x, y) = sobel_at(r0, r1, r2, u);
                    gx[v * (w - 2) + u] = x;
                    gy[v * (w - 2) + u] = y;
                }
            }
            if sim == Similarity::GradientCorrelation {
                blocks.extend([(0, n), (n, n)]);
            } else {
                blocks.push((0, 2 * n));
            }
        }
        Similarity::LocalNcc { patch_px } => {
            let p = patch_px as usize;
            for v0 in (0..h).step_by(p) {
                for u0 in (0..w).step_by(p) {
                    let start = out.len();
                    for v in v0..(v0 + p).min(h) {
                        let row = &img.data[v * w + u0..v * w + (u0 + p).min(w)];
                        out.extend(row.iter().map(|&x| f64::from(x)));
                    }
                    blocks.push((start, out.len() - start));
                }
            }
        }
    }
    let weights = vec![1.0 / blocks.len() as f64; blocks.len()];
    Ok(Layout {
        blocks,
        weights,
        len: out.len(),
    })
}

/// Where each feature of [`features`] comes from in a `w × h` image: its pixel `u + w·v` (for a
/// gradient the first pixel of its 3 × 3 neighbourhood) in bits 0–29 and its kind in bits 30–31 — 0 the
/// value, 1 the Sobel x response, 2 the Sobel y response — in the order [`features`] writes them (the
/// GPU's feature pass, `device/level.wgsl`, reads them).
#[cfg_attr(not(feature = "gpu"), allow(dead_code))]
pub fn feature_sources(sim: Similarity, w: u32, h: u32) -> Result<Vec<u32>> {
    let (wu, hu) = (w as usize, h as usize);
    if wu * hu >= 1 << 30 {
        return Err(Error::invalid(
            "levels",
            format!("a {w}×{h} px level is too large"),
        ));
    }
    let px = |u: usize, v: usize| (u + wu * v) as u32;
    Ok(match sim {
        Similarity::Ncc => (0..wu * hu).map(|i| i as u32).collect(),
        Similarity::GradientCorrelation | Similarity::GradientNcc => {
            if wu < 3 || hu < 3 {
                return Err(Error::invalid(
                    "similarity",
                    "gradient similarities need at least 3×3 pixels",
                ));
            }
            let interior: Vec<u32> = (0..hu - 2)
                .flat_map(|v| (0..wu - 2).map(move |u| px(u, v)))
                .collect();
            let x = interior.iter().map(|&p| p | 1 << 30);
            let y = interior.iter().map(|&p| p | 2 << 30);
            x.chain(y).collect()
        }
        Similarity::LocalNcc { patch_px } => {
            let p = patch_px as usize;
            let mut out = Vec::with_capacity(wu * hu);
            for v0 in (0..hu).step_by(p) {
                for u0 in (0..wu).step_by(p) {
                    for v in v0..(v0 + p).min(hu) {
                        out.extend((u0..(u0 + p).min(wu)).map(|u| px(u, v)));
                    }
                }
            }
            out
        }
    })
}

/// A block's normalisation `x̂ = (x − mean) · scale`, `scale = 1 / √(energy + eps)`, and its energy
/// `‖x − x̄‖²`: the one place both [`normalise`] and [`FixedFeatures::residual`] take it from, so both
/// compute the same numbers.
struct BlockNorm {
    mean: f64,
    scale: f64,
    energy: f64,
}

impl BlockNorm {
    fn of(b: &[f64], eps: f64) -> Self {
        let mean = b.iter().sum::<f64>() / b.len().max(1) as f64;
        let mut energy = 0.0;
        for &x in b {
            let c = x - mean;
            energy += c * c;
        }
        let d = (energy + eps).sqrt();
        let scale = if d > 0.0 { 1.0 / d } else { 0.0 };
        BlockNorm {
            mean,
            scale,
            energy,
        }
    }

    #[inline]
    fn apply(&self, x: f64) -> f64 {
        (x - self.mean) * self.scale
    }
}

/// Centres each block of `x` and divides it by `√(energy + eps[k])`; returns each block's energy
/// `‖x_k − x̄_k‖²` (before normalisation).
pub fn normalise(x: &mut [f64], layout: &Layout, eps: &[f64]) -> Vec<f64> {
    layout
        .blocks
        .iter()
        .zip(eps)
        .map(|(&(s, n), &e)| {
            let b = &mut x[s..s + n];
            let norm = BlockNorm::of(b, e);
            b.iter_mut().for_each(|v| *v = norm.apply(*v));
            norm.energy
        })
        .collect()
}

/// The fixed image's side of one view: its normalised features, the layout, and the weights (blocks
/// where the fixed image is constant get weight 0; the others share the weight equally).
#[derive(Debug, Clone)]
pub struct FixedFeatures {
    pub sim: Similarity,
    pub layout: Layout,
    pub normalised: Vec<f64>,
    pub energy: Vec<f64>,
}

impl FixedFeatures {
    /// The features of `fixed` (`what` names the image in errors).
    pub fn new(sim: Similarity, fixed: &ImageF32, what: &str) -> Result<Self> {
        let mut x = Vec::new();
        let mut layout = features(sim, fixed, &mut x)?;
        let energy = normalise(&mut x, &layout, &vec![0.0; layout.blocks.len()]);
        let max_e = energy.iter().copied().fold(0.0, f64::max);
        if max_e <= 0.0 || !max_e.is_finite() {
            return Err(Error::invalid(
                what,
                "the fixed image is constant (or not finite): nothing to register to",
            ));
        }
        // Patches without structure carry no correlation; 1e-6 of the largest energy is rounding.
        let used: Vec<bool> = energy.iter().map(|&e| e > 1e-6 * max_e).collect();
        let n_used = used.iter().filter(|&&u| u).count() as f64;
        layout.weights = used
            .iter()
            .map(|&u| if u { 1.0 / n_used } else { 0.0 })
            .collect();
        Ok(FixedFeatures {
            sim,
            layout,
            normalised: x,
            energy,
        })
    }

    /// Regularisers of the moving normalisation: `1e-6` of each fixed block's energy, scaled by `gain`
    /// (moving-to-fixed energy ratio, so the regulariser follows the moving image's units).
    pub fn moving_eps(&self, gain: f64) -> Vec<f64> {
        self.energy.iter().map(|&e| 1e-6 * e * gain).collect()
    }

    /// Writes `√w_k (m̂_k − f̂_k)` of the moving image into `out` and returns the similarity
    /// `Σ w_k ⟨m̂_k, f̂_k⟩`; `scratch` holds the moving features.
    pub fn residual(
        &self,
        moving: &ImageF32,
        eps: &[f64],
        scratch: &mut Vec<f64>,
        out: &mut Vec<f64>,
    ) -> Result<f64> {
        let layout = features(self.sim, moving, scratch)?;
        if layout.len != self.layout.len {
            return Err(Error::Internal(
                "moving and fixed features differ in size".into(),
            ));
        }
        // [`normalise`] fused into the residual's pass (the same [`BlockNorm`]), without writing the
        // normalised features back.
        out.clear();
        out.reserve(layout.len);
        let mut s = 0.0;
        for (k, (&(st, n), &e)) in self.layout.blocks.iter().zip(eps).enumerate() {
            let w = self.layout.weights[k];
            let sw = w.sqrt();
            let (m, f) = (&scratch[st..st + n], &self.normalised[st..st + n]);
            let norm = BlockNorm::of(m, e);
            let mut dot = 0.0;
            for (&x, &b) in m.iter().zip(f) {
                let a = norm.apply(x);
                dot += a * b;
                out.push(sw * (a - b));
            }
            s += w * dot;
        }
        Ok(s)
    }

    /// Total energy of the fixed blocks that carry weight.
    pub fn used_energy(&self) -> f64 {
        self.energy
            .iter()
            .zip(&self.layout.weights)
            .filter(|(_, w)| **w > 0.0)
            .map(|(e, _)| e)
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn blob(w: u32, h: u32, cx: f64, cy: f64) -> ImageF32 {
        let mut img = ImageF32::zeros(w, h);
        for v in 0..h {
            for u in 0..w {
                let (x, y) = (f64::from(u) - cx, f64::from(v) - cy);
                let r2 = x * x + y * y;
                img.data[(v * w + u) as usize] =
                    ((-r2 / 200.0).exp() + 0.3 * (x / 5.0).sin() * (-r2 / 900.0).exp()) as f32;
            }
        }
        img
    }

    #[test]
    fn ncc_and_gradient_correlation_equal_the_analysis_metrics() {
        let (a, b) = (blob(61, 47, 30.0, 22.0), blob(61, 47, 32.5, 21.0));
        for (sim, expect) in [
            (Similarity::Ncc, crate::analysis::ncc(&b, &a).unwrap()),
            (
                Similarity::GradientCorrelation,
                crate::analysis::gradient_correlation(&b, &a).unwrap(),
            ),
        ] {
            let f = FixedFeatures::new(sim, &a, "fixed").unwrap();
            let eps = vec![0.0; f.layout.blocks.len()];
            let (mut s, mut r) = (Vec::new(), Vec::new());
            let got = f.residual(&b, &eps, &mut s, &mut r).unwrap();
            assert!((got - expect).abs() < 1e-12, "{sim:?}: {got} vs {expect}");
            // S = 1 − ½‖r‖² when every block is unit norm.
            let half_r2 = 0.5 * r.iter().map(|x| x * x).sum::<f64>();
            assert!((1.0 - half_r2 - got).abs() < 1e-12, "{sim:?}");
        }
    }

    /// Each feature recomputed from its source code (value, or the Sobel formula on the 3 × 3
    /// neighbourhood written out here) is the feature `features` wrote, for every similarity.
    #[test]
    fn feature_sources_name_each_feature_s_pixel_and_kind() {
        let img = blob(23, 17, 10.0, 8.0);
        let at = |u: usize, v: usize| f64::from(img.data[u + 23 * v]);
        for name in ["ncc", "gc", "gncc", "lncc:5"] {
            let sim = Similarity::parse(name).unwrap();
            let mut x = Vec::new();
            features(sim, &img, &mut x).unwrap();
            let src = feature_sources(sim, 23, 17).unwrap();
            assert_eq!(src.len(), x.len(), "{name}");
            for (code, want) in src.iter().zip(&x) {
                let p = (code & 0x3fff_ffff) as usize;
                let (u, v) = (p % 23, p / 23);
                let got = match code >> 30 {
                    0 => at(u, v),
                    1 => {
                        (at(u + 2, v) - at(u, v))
                            + 2.0 * (at(u + 2, v + 1) - at(u, v + 1))
                            + (at(u + 2, v + 2) - at(u, v + 2))
                    }
                    _ => {
                        (at(u, v + 2) - at(u, v))
                            + 2.0 * (at(u + 1, v + 2) - at(u + 1, v))
                            + (at(u + 2, v + 2) - at(u + 2, v))
                    }
                };
                assert!((got - want).abs() < 1e-12, "{name}: {got} vs {want}");
            }
        }
    }

    #[test]
    fn every_similarity_is_one_on_identical_images_and_lower_when_shifted() {
        let (a, b) = (blob(64, 64, 30.0, 30.0), blob(64, 64, 33.0, 30.0));
        for name in ["ncc", "gc", "gncc", "lncc:8"] {
            let sim = Similarity::parse(name).unwrap();
            assert_eq!(Similarity::parse(&sim.name()).unwrap(), sim);
            let f = FixedFeatures::new(sim, &a, "fixed").unwrap();
            let eps = f.moving_eps(1.0);
            let (mut s, mut r) = (Vec::new(), Vec::new());
            let same = f.residual(&a, &eps, &mut s, &mut r).unwrap();
            let shifted = f.residual(&b, &eps, &mut s, &mut r).unwrap();
            assert!((same - 1.0).abs() < 1e-5, "{name}: {same}");
            assert!(shifted < same - 1e-3, "{name}: {shifted}");
        }
        assert!(Similarity::parse("mi").is_err());
        assert!(Similarity::parse("lncc:1").is_err());
    }
}
