//! The polychromatic image model: a filtered spectrum seen by an energy-integrating detector, and the
//! per-pixel energy sum that turns per-material path lengths into the detected signal.
//!
//! For channel values `a_c` (a material's mass thickness ρ·L in g/cm³·mm, or for a fixed-μ channel the
//! line integral μ·L itself) the detected signal relative to air is
//! `I / I0 = Σ_E w(E) · exp(−Σ_c t_c(E) · a_c)` with `w(E) = Φ(E)·η(E)·E / Σ Φ·η·E` (the normalised
//! energy-integrating weights) and `t_c(E) = (μ/ρ)_c(E) / 10` (cm²/g → per g/cm³·mm) or 1 for fixed μ.
//! Its log `−ln(I/I0)` is the polychromatic line integral, what registration sees.

use serde_json::json;

use super::detector::Detector;
use super::materials::Material;
use super::spectrum::Spectrum;
use crate::{Error, Result};

/// What a channel of path lengths holds.
#[derive(Debug, Clone, Copy)]
pub enum Channel {
    /// Mass thickness ρ·L of a material (g/cm³ · mm).
    Material(&'static Material),
    /// A line integral μ·L with energy-independent μ (the monochromatic `FILE:MU` meshes).
    FixedMu,
}

impl Channel {
    /// Whether two channels are the same (materials by name).
    pub fn same(&self, other: &Channel) -> bool {
        self.name() == other.name()
    }

    /// The channel's name in sidecars: the material's name or `fixed_mu`.
    pub fn name(&self) -> &'static str {
        match self {
            Channel::Material(m) => m.name,
            Channel::FixedMu => "fixed_mu",
        }
    }
}

/// A spectrum and a detector: the weights of the energy sum.
#[derive(Debug, Clone)]
pub struct SpectralModel {
    pub spectrum: Spectrum,
    pub detector: Detector,
    /// `Φ·η·E` per bin, normalised to sum 1.
    pub weights: Vec<f64>,
}

impl SpectralModel {
    /// The model of `spectrum` (already filtered) on `detector`; refused when the detector records nothing.
    pub fn new(spectrum: Spectrum, detector: Detector) -> Result<Self> {
        let raw: Vec<f64> = spectrum
            .energies_kev
            .iter()
            .zip(&spectrum.fluence)
            .map(|(&e, &phi)| phi * detector.efficiency(e) * e)
            .collect();
        let total: f64 = raw.iter().sum();
        if !(total.is_finite() && total > 0.0) {
            return Err(Error::invalid(
                "spectrum",
                format!(
                    "{}: no signal reaches the detector (is the filtration too thick?)",
                    spectrum.source
                ),
            ));
        }
        let weights = raw.iter().map(|w| w / total).collect();
        Ok(SpectralModel {
            spectrum,
            detector,
            weights,
        })
    }

    /// One energy bin: the image is the monochromatic `exp(−Σ μ(E₀)·L)`, rendered in one pass.
    pub fn is_monochromatic(&self) -> bool {
        self.weights.len() == 1
    }

    /// Bins of the energy sum.
    pub fn bins(&self) -> usize {
        self.weights.len()
    }

    /// Attenuation per unit channel value per bin, `table[c * bins + b]`.
    pub fn channel_table(&self, channels: &[Channel]) -> Vec<f64> {
        channels
            .iter()
            .flat_map(|c| {
                self.spectrum.energies_kev.iter().map(move |&e| match c {
                    Channel::Material(m) => m.mu_rho(e) * 0.1,
                    Channel::FixedMu => 1.0,
                })
            })
            .collect()
    }

    /// `−ln(Σ_b w_b · exp(−x_b))`, `x_b = Σ_c table[c][b] · a_c`, for channel values `a`, in f64 and shifted
    /// by the smallest `x_b` (finite where every `exp(−x_b)` underflows); 0 when every `a_c` is 0. The
    /// reference of the vectorised [`super::EnergyKernel`] images are made with.
    pub fn line_integral(&self, table: &[f64], a: &[f64]) -> f64 {
        if a.iter().all(|&x| x == 0.0) {
            return 0.0;
        }
        let bins = self.bins();
        let x: Vec<f64> = (0..bins)
            .map(|b| {
                a.iter()
                    .enumerate()
                    .map(|(c, &ac)| table[c * bins + b] * ac)
                    .sum()
            })
            .collect();
        let m = x.iter().copied().fold(f64::INFINITY, f64::min);
        let signal: f64 = self
            .weights
            .iter()
            .zip(&x)
            .map(|(w, xb)| w * (m - xb).exp())
            .sum();
        m - signal.ln()
    }

    /// The vectorised kernel of `channels`.
    pub fn kernel(&self, channels: &[Channel]) -> super::EnergyKernel {
        super::EnergyKernel::new(&self.weights, &self.channel_table(channels))
    }

    /// What the sidecar records: the spectrum (bins and fluence), its filtration, mean energy and first
    /// Al HVL, the detector and the normalised detector weights.
    pub fn summary(&self) -> serde_json::Value {
        json!({
            "source": self.spectrum.source,
            "filtration": self.spectrum.filtration.iter()
                .map(|(m, rho, mm)| json!({"material": m, "density_g_cm3": rho, "thickness_mm": mm}))
                .collect::<Vec<_>>(),
            "energies_kev": self.spectrum.energies_kev,
            "fluence": self.spectrum.fluence,
            "mean_energy_kev": self.spectrum.mean_energy_kev(),
            "hvl_al_mm": self.spectrum.hvl_al_mm(),
            "detector": self.detector.label(),
            "detector_weights": self.weights,
            "signal": "energy-integrating: sum over bins of fluence x efficiency x energy x transmission",
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spectral::materials::MaterialAt;

    #[test]
    fn one_bin_is_beer_lambert_and_a_spectrum_hardens_through_water() {
        let water = Material::named("water").unwrap();
        let mono = SpectralModel::new(Spectrum::monochromatic(60.0).unwrap(), Detector::default())
            .unwrap();
        let ch = [Channel::Material(water)];
        let t = mono.channel_table(&ch);
        // 100 mm of water at 1 g/cm³: μ(60 keV)·L = 0.2059 cm²/g · 1 g/cm³ · 10 cm.
        assert!((mono.line_integral(&t, &[100.0]) - water.mu_rho(60.0) * 10.0).abs() < 1e-12);
        // Polychromatic: the effective μ = L_eff / thickness falls as the water thickens.
        let al = MaterialAt::parse("al").unwrap();
        let poly = SpectralModel::new(
            Spectrum::tasmip(80.0).unwrap().filtered(al, 2.5).unwrap(),
            Detector::default(),
        )
        .unwrap();
        let t = poly.channel_table(&ch);
        let mu_eff: Vec<f64> = [10.0, 50.0, 100.0, 200.0]
            .iter()
            .map(|&l| poly.line_integral(&t, &[l]) / l)
            .collect();
        assert!(mu_eff.windows(2).all(|w| w[1] < w[0]), "{mu_eff:?}");
        assert_eq!(poly.line_integral(&t, &[0.0]), 0.0);
        // A fixed-μ channel ignores the spectrum.
        let t = poly.channel_table(&[Channel::FixedMu]);
        assert!((poly.line_integral(&t, &[1.7]) - 1.7).abs() < 1e-12);
    }
}
