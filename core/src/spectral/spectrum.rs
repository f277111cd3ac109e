//! X-ray tube spectra: TASMIP (Boone & Seibert 1997) for tungsten anodes at 30–140 kV, a user's spectrum
//! file, or one energy; filtration; and the beam-quality numbers a physicist checks a spectrum by (mean
//! energy, first half-value layer in aluminium).

use std::path::Path;
use std::sync::OnceLock;

use serde::Serialize;

use super::materials::{Material, MaterialAt};
use super::nist::{TABLE_MAX_KEV, TABLE_MIN_KEV};
use crate::{Error, Result};

/// The TASMIP coefficient table (see its header for the source).
const TASMIP_CSV: &str = include_str!("../../../assets/xray/tasmip.csv");

/// The tube potentials TASMIP was fitted over (kV).
pub const TASMIP_KV: (f64, f64) = (30.0, 140.0);

/// A photon spectrum: fluence per energy bin (bins centred on `energies_kev`, relative units).
#[derive(Debug, Clone, Serialize)]
pub struct Spectrum {
    /// Where it came from, e.g. `TASMIP 80 kV` or the file's path.
    pub source: String,
    /// Bin centres, keV, increasing.
    pub energies_kev: Vec<f64>,
    /// Photon fluence per bin (relative).
    pub fluence: Vec<f64>,
    /// Filters applied after the source, in order: (material, density g/cm³, thickness mm).
    pub filtration: Vec<(String, f64, f64)>,
}

/// `(energy keV, n_terms, [a0..a3])` per TASMIP row.
fn tasmip_table() -> &'static [(f64, usize, [f64; 4])] {
    static TABLE: OnceLock<Vec<(f64, usize, [f64; 4])>> = OnceLock::new();
    TABLE.get_or_init(|| {
        TASMIP_CSV
            .lines()
            .filter(|l| !l.starts_with('#') && !l.starts_with("energy") && !l.trim().is_empty())
            .map(|l| {
                let f: Vec<f64> = l
                    .split(',')
                    .map(|s| s.trim().parse().expect("the embedded TASMIP table parses"))
                    .collect();
                (f[0], f[1] as usize, [f[2], f[3], f[4], f[5]])
            })
            .collect()
    })
}

impl Spectrum {
    /// TASMIP's spectrum of a constant-potential tungsten tube at `kv` (30–140 kV), in 1-keV bins from
    /// 10 keV to `kv`; photons per mm² per mAs at 1 m, with the inherent filtration of the tube it was
    /// measured on (no added filtration).
    pub fn tasmip(kv: f64) -> Result<Self> {
        let (lo, hi) = TASMIP_KV;
        if !(kv.is_finite() && (lo..=hi).contains(&kv)) {
            return Err(Error::invalid(
                "kVp",
                format!(
                    "{} kV is outside TASMIP's published range, {lo}–{hi} kV; give a spectrum file for \
                     other tube potentials",
                    crate::error::shown(kv)
                ),
            ));
        }
        let (mut energies_kev, mut fluence) = (Vec::new(), Vec::new());
        for &(e, n, a) in tasmip_table() {
            if e > kv {
                break;
            }
            let phi = a[..n]
                .iter()
                .rev()
                .fold(0.0, |acc, &c| acc * kv + c)
                .max(0.0);
            if phi > 0.0 {
                energies_kev.push(e);
                fluence.push(phi);
            }
        }
        Ok(Spectrum {
            source: format!("TASMIP {kv} kV"),
            energies_kev,
            fluence,
            filtration: Vec::new(),
        })
    }

    /// A single energy (a monochromatic beam).
    pub fn monochromatic(e_kev: f64) -> Result<Self> {
        check_energy(e_kev, "energy")?;
        Ok(Spectrum {
            source: format!("monochromatic {e_kev} keV"),
            energies_kev: vec![e_kev],
            fluence: vec![1.0],
            filtration: Vec::new(),
        })
    }

    /// A spectrum file: two numbers per line, energy (keV) and photon fluence (any unit; relative), separated
    /// by a comma, tab or spaces; `#` starts a comment; a first line that is not numbers is a header.
    /// Energies must increase and lie in 1–200 keV; fluence must be finite and non-negative, not all 0.
    pub fn from_file(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let where_ = |line: usize| format!("{} line {line}", path.display());
        let (mut energies_kev, mut fluence) = (Vec::new(), Vec::new());
        for (n, raw) in text.lines().enumerate() {
            let line = raw.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            let f: Vec<&str> = line
                .split(|c: char| c == ',' || c.is_whitespace())
                .filter(|s| !s.is_empty())
                .collect();
            let nums: Option<Vec<f64>> = f.iter().map(|s| s.parse().ok()).collect();
            let Some(nums) = nums else {
                if energies_kev.is_empty() && n == first_content_line(&text) {
                    continue; // a header
                }
                return Err(Error::invalid(
                    where_(n + 1),
                    format!("'{raw}' is not two numbers (energy keV, fluence)"),
                ));
            };
            if nums.len() != 2 {
                return Err(Error::invalid(
                    where_(n + 1),
                    format!(
                        "'{raw}' has {} numbers; expected energy keV and fluence",
                        nums.len()
                    ),
                ));
            }
            let (e, phi) = (nums[0], nums[1]);
            check_energy(e, &where_(n + 1))?;
            if let Some(&prev) = energies_kev.last()
                && e <= prev
            {
                return Err(Error::invalid(
                    where_(n + 1),
                    format!("energy {e} keV does not increase (after {prev} keV)"),
                ));
            }
            if !(phi.is_finite() && phi >= 0.0) {
                return Err(Error::invalid(
                    where_(n + 1),
                    format!("fluence {phi} must be finite and non-negative"),
                ));
            }
            energies_kev.push(e);
            fluence.push(phi);
        }
        if fluence.iter().all(|&p| p == 0.0) {
            return Err(Error::invalid(
                path.display().to_string(),
                "the spectrum has no photons (no line with a positive fluence)",
            ));
        }
        Ok(Spectrum {
            source: path.display().to_string(),
            energies_kev,
            fluence,
            filtration: Vec::new(),
        })
    }

    /// The spectrum after `thickness_mm` of `filter` (Beer–Lambert per bin).
    pub fn filtered(mut self, filter: MaterialAt, thickness_mm: f64) -> Result<Self> {
        if !(thickness_mm.is_finite() && (0.0..=100.0).contains(&thickness_mm)) {
            return Err(Error::invalid(
                "filter",
                format!(
                    "{} mm of {} must be between 0 and 100 mm",
                    crate::error::shown(thickness_mm),
                    filter.material.name
                ),
            ));
        }
        for (e, phi) in self.energies_kev.iter().zip(self.fluence.iter_mut()) {
            *phi *= (-filter.material.mu_per_mm(*e, filter.density_g_cm3) * thickness_mm).exp();
        }
        self.filtration.push((
            filter.material.name.to_string(),
            filter.density_g_cm3,
            thickness_mm,
        ));
        Ok(self)
    }

    /// Fluence-weighted mean photon energy, keV.
    pub fn mean_energy_kev(&self) -> f64 {
        let n: f64 = self.fluence.iter().sum();
        self.energies_kev
            .iter()
            .zip(&self.fluence)
            .map(|(e, p)| e * p)
            .sum::<f64>()
            / n
    }

    /// Air kerma (relative): `Σ Φ(E) · E · (μ_en/ρ)_air(E)` behind `al_mm` of aluminium.
    fn air_kerma(&self, al_mm: f64) -> f64 {
        let air = Material::named("air").expect("built-in");
        let al = Material::named("aluminium").expect("built-in");
        self.energies_kev
            .iter()
            .zip(&self.fluence)
            .map(|(&e, &p)| {
                p * e * air.mu_en_rho(e) * (-al.mu_per_mm(e, al.density_g_cm3) * al_mm).exp()
            })
            .sum()
    }

    /// First half-value layer in aluminium (mm): the thickness that halves the air kerma (narrow beam),
    /// by bisection to 1e-6 mm.
    pub fn hvl_al_mm(&self) -> f64 {
        let half = 0.5 * self.air_kerma(0.0);
        let (mut lo, mut hi) = (0.0, 1.0);
        while self.air_kerma(hi) > half && hi < 1e3 {
            hi *= 2.0;
        }
        while hi - lo > 1e-6 {
            let mid = 0.5 * (lo + hi);
            if self.air_kerma(mid) > half {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }
}

fn first_content_line(text: &str) -> usize {
    text.lines()
        .position(|l| !l.split('#').next().unwrap_or("").trim().is_empty())
        .unwrap_or(0)
}

fn check_energy(e: f64, field: &str) -> Result<()> {
    if e.is_finite() && (TABLE_MIN_KEV..=TABLE_MAX_KEV).contains(&e) {
        Ok(())
    } else {
        Err(Error::invalid(
            field,
            format!(
                "photon energy {} keV is outside the attenuation tables' {TABLE_MIN_KEV}–{TABLE_MAX_KEV} keV",
                crate::error::shown(e)
            ),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tasmip_spans_10_kev_to_kvp_and_refuses_potentials_outside_its_fit() {
        let s = Spectrum::tasmip(80.0).unwrap();
        assert_eq!(s.energies_kev.first(), Some(&10.0));
        assert!(*s.energies_kev.last().unwrap() <= 80.0);
        assert!(s.fluence.iter().all(|&p| p > 0.0));
        // Tungsten's Kα lines (57.98, 59.32 keV; K edge 69.5 keV) stand above the bremsstrahlung around
        // them at 100 kV.
        let s = Spectrum::tasmip(100.0).unwrap();
        let at = |e: f64| s.fluence[s.energies_kev.iter().position(|&x| x == e).unwrap()];
        assert!(at(59.0) > 1.3 * at(55.0), "{} {}", at(59.0), at(55.0));
        for bad in [29.0, 150.0, f64::NAN] {
            assert!(Spectrum::tasmip(bad).is_err());
        }
    }

    #[test]
    fn filtration_hardens_the_beam() {
        let al = MaterialAt::parse("aluminium").unwrap();
        let s = Spectrum::tasmip(80.0).unwrap();
        let f = s.clone().filtered(al, 2.5).unwrap();
        assert!(f.mean_energy_kev() > s.mean_energy_kev() + 2.0);
        assert!(f.hvl_al_mm() > s.hvl_al_mm());
        // One energy: the HVL is ln 2 / μ_Al(E) exactly (to the bisection's 1e-6 mm).
        let m = Spectrum::monochromatic(60.0).unwrap();
        let mu = al.material.mu_per_mm(60.0, al.density_g_cm3);
        assert!((m.hvl_al_mm() - std::f64::consts::LN_2 / mu).abs() < 2e-6);
    }

    #[test]
    fn spectrum_files_parse_and_bad_lines_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("s.csv");
        std::fs::write(
            &p,
            "energy_kev,fluence\n20, 1.0\n30\t2.0 # peak\n\n40 0.5\n",
        )
        .unwrap();
        let s = Spectrum::from_file(&p).unwrap();
        assert_eq!(s.energies_kev, vec![20.0, 30.0, 40.0]);
        assert_eq!(s.fluence, vec![1.0, 2.0, 0.5]);
        for (text, needle) in [
            ("20 1\n20 2\n", "does not increase"),
            ("20 1\n300 2\n", "outside"),
            ("20 1\n30 -2\n", "non-negative"),
            ("20 1\nthirty 2\n", "line 2"),
            ("20 1 3\n", "3 numbers"),
            ("20 0\n", "no photons"),
        ] {
            std::fs::write(&p, text).unwrap();
            let e = Spectrum::from_file(&p).unwrap_err().to_string();
            assert!(e.contains(needle), "{text:?}: {e}");
        }
    }
}
