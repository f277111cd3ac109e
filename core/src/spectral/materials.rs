//! Materials: elemental composition by mass and a nominal density, μ/ρ(E) by the mixture rule
//! `(μ/ρ)_mix = Σ w_i (μ/ρ)_i` over the NIST element tables ([`super::nist`]).
//!
//! Compositions (mass fractions) and densities, with their sources:
//! * `air` — dry air near sea level, NIST SRD 126 Table 2 (ρ = 1.205 mg/cm³).
//! * `water` — H₂O (ρ = 1.0).
//! * `adipose`, `soft_tissue`, `cortical_bone` — ICRU Report 44 (1989) as tabulated in NIST SRD 126
//!   Table 2 ("Adipose Tissue", "Tissue, Soft", "Bone, Cortical"; ρ = 0.95, 1.06, 1.92).
//! * `cancellous_bone` — spongiosa of Woodard & White, Br. J. Radiol. 59, 1209 (1986), as in ICRU Report 46
//!   (ρ = 1.18).
//! * `titanium` — Ti-6Al-4V, ASTM F136 nominal (6 % Al, 4 % V; ρ = 4.43).
//! * `steel` — stainless steel 316L, ASTM F138 nominal (18 % Cr, 14 % Ni, 2.5 % Mo, 2 % Mn, 0.75 % Si,
//!   0.03 % C, Fe balance; ρ = 8.0).
//! * `cobalt_chrome` — CoCrMo, ASTM F75 nominal (28 % Cr, 6 % Mo, Co balance; ρ = 8.3).
//! * `peek` — polyether ether ketone, (C₁₉H₁₂O₃)ₙ (ρ = 1.30).
//! * `aluminium`, `copper` (filters; ρ = 2.699, 8.96) and `csi` (CsI, the detector's scintillator; 4.51).
//!
//! The ICRU-44 and air compositions reproduce NIST's own Table 4 μ/ρ of those materials to ≤ 0.05 % over
//! 10–150 keV (checked when this table was written; the pytest suite checks μ/ρ against `xraydb`).

use super::nist::{self, ElementData};
use crate::{Error, Result};

/// A material of the spectral model.
#[derive(Debug, Clone)]
pub struct Material {
    /// Its name as `--mesh FILE:NAME` and the sidecar spell it.
    pub name: &'static str,
    /// What it is, in words.
    pub description: &'static str,
    /// Nominal density, g/cm³.
    pub density_g_cm3: f64,
    /// Source of the composition and density.
    pub source: &'static str,
    /// Mass fraction per element (symbol, w); the fractions sum to 1.
    pub composition: &'static [(&'static str, f64)],
}

const ICRU44: &str = "ICRU Report 44 (1989), via NIST SRD 126 Table 2";

/// Every built-in material.
pub const MATERIALS: &[Material] = &[
    Material {
        name: "air",
        description: "dry air near sea level",
        density_g_cm3: 1.205e-3,
        source: "NIST SRD 126 Table 2",
        composition: &[
            ("C", 0.000124),
            ("N", 0.755268),
            ("O", 0.231781),
            ("Ar", 0.012827),
        ],
    },
    Material {
        name: "water",
        description: "liquid water",
        density_g_cm3: 1.0,
        source: "H2O, NIST SRD 126 Table 2",
        composition: &[("H", 0.111898), ("O", 0.888102)],
    },
    Material {
        name: "adipose",
        description: "adipose tissue",
        density_g_cm3: 0.95,
        source: ICRU44,
        composition: &[
            ("H", 0.114),
            ("C", 0.598),
            ("N", 0.007),
            ("O", 0.278),
            ("Na", 0.001),
            ("S", 0.001),
            ("Cl", 0.001),
        ],
    },
    Material {
        name: "soft_tissue",
        description: "soft tissue",
        density_g_cm3: 1.06,
        source: ICRU44,
        composition: &[
            ("H", 0.102),
            ("C", 0.143),
            ("N", 0.034),
            ("O", 0.708),
            ("Na", 0.002),
            ("P", 0.003),
            ("S", 0.003),
            ("Cl", 0.002),
            ("K", 0.003),
        ],
    },
    Material {
        name: "cortical_bone",
        description: "cortical bone",
        density_g_cm3: 1.92,
        source: ICRU44,
        composition: &[
            ("H", 0.034),
            ("C", 0.155),
            ("N", 0.042),
            ("O", 0.435),
            ("Na", 0.001),
            ("Mg", 0.002),
            ("P", 0.103),
            ("S", 0.003),
            ("Ca", 0.225),
        ],
    },
    Material {
        name: "cancellous_bone",
        description: "cancellous bone (spongiosa)",
        density_g_cm3: 1.18,
        source: "Woodard & White, Br. J. Radiol. 59:1209 (1986); ICRU Report 46",
        composition: &[
            ("H", 0.085),
            ("C", 0.404),
            ("N", 0.028),
            ("O", 0.367),
            ("Na", 0.001),
            ("Mg", 0.001),
            ("P", 0.034),
            ("S", 0.002),
            ("Cl", 0.002),
            ("K", 0.001),
            ("Ca", 0.074),
            ("Fe", 0.001),
        ],
    },
    Material {
        name: "titanium",
        description: "titanium alloy Ti-6Al-4V",
        density_g_cm3: 4.43,
        source: "ASTM F136 nominal composition",
        composition: &[("Ti", 0.90), ("Al", 0.06), ("V", 0.04)],
    },
    Material {
        name: "steel",
        description: "stainless steel 316L",
        density_g_cm3: 8.0,
        source: "ASTM F138 nominal composition",
        composition: &[
            ("Fe", 0.6272),
            ("Cr", 0.18),
            ("Ni", 0.14),
            ("Mo", 0.025),
            ("Mn", 0.02),
            ("Si", 0.0075),
            ("C", 0.0003),
        ],
    },
    Material {
        name: "cobalt_chrome",
        description: "cobalt-chromium-molybdenum alloy",
        density_g_cm3: 8.3,
        source: "ASTM F75 nominal composition",
        composition: &[("Co", 0.66), ("Cr", 0.28), ("Mo", 0.06)],
    },
    Material {
        name: "peek",
        description: "polyether ether ketone (C19H12O3)n",
        density_g_cm3: 1.30,
        source: "stoichiometry of the repeat unit",
        composition: &[("C", 0.791561), ("H", 0.041956), ("O", 0.166483)],
    },
    Material {
        name: "aluminium",
        description: "aluminium (filter)",
        density_g_cm3: 2.699,
        source: "NIST SRD 126 Table 1",
        composition: &[("Al", 1.0)],
    },
    Material {
        name: "copper",
        description: "copper (filter)",
        density_g_cm3: 8.96,
        source: "NIST SRD 126 Table 1",
        composition: &[("Cu", 1.0)],
    },
    Material {
        name: "csi",
        description: "caesium iodide (scintillator)",
        density_g_cm3: 4.51,
        source: "NIST SRD 126 Table 2",
        composition: &[("Cs", 0.511549), ("I", 0.488451)],
    },
];

/// Alternative spellings accepted on the command line.
const ALIASES: &[(&str, &str)] = &[
    ("ti", "titanium"),
    ("ti6al4v", "titanium"),
    ("316l", "steel"),
    ("stainless_steel", "steel"),
    ("cocr", "cobalt_chrome"),
    ("cocrmo", "cobalt_chrome"),
    ("bone", "cortical_bone"),
    ("cortical", "cortical_bone"),
    ("cancellous", "cancellous_bone"),
    ("tissue", "soft_tissue"),
    ("fat", "adipose"),
    ("aluminum", "aluminium"),
    ("al", "aluminium"),
    ("cu", "copper"),
];

impl Material {
    /// The built-in material `name` (case-insensitive; `-` and `_` alike; aliases such as `ti`, `316l`,
    /// `cocr`), or an error listing them.
    pub fn named(name: &str) -> Result<&'static Material> {
        let key = name.trim().to_ascii_lowercase().replace('-', "_");
        let key = ALIASES
            .iter()
            .find(|(a, _)| *a == key)
            .map_or(key.as_str(), |(_, m)| m);
        MATERIALS.iter().find(|m| m.name == key).ok_or_else(|| {
            let names: Vec<&str> = MATERIALS.iter().map(|m| m.name).collect();
            Error::invalid(
                "material",
                format!("unknown material '{name}' (known: {})", names.join(", ")),
            )
        })
    }

    fn elements(&self) -> impl Iterator<Item = (&'static ElementData, f64)> + '_ {
        self.composition.iter().map(|(s, w)| {
            (
                nist::element_by_symbol(s).expect("built-in compositions use embedded elements"),
                *w,
            )
        })
    }

    /// Mass attenuation coefficient μ/ρ (cm²/g) at `e_kev`.
    pub fn mu_rho(&self, e_kev: f64) -> f64 {
        self.elements().map(|(el, w)| w * el.mu_rho(e_kev)).sum()
    }

    /// Mass energy-absorption coefficient μ_en/ρ (cm²/g) at `e_kev` (mixture rule; NIST's Table 4 values
    /// of air, water and the ICRU tissues agree with it to ≤ 0.15 % over 10–150 keV).
    pub fn mu_en_rho(&self, e_kev: f64) -> f64 {
        self.elements().map(|(el, w)| w * el.mu_en_rho(e_kev)).sum()
    }

    /// Linear attenuation (mm⁻¹) at `e_kev` and density `density_g_cm3`.
    pub fn mu_per_mm(&self, e_kev: f64, density_g_cm3: f64) -> f64 {
        self.mu_rho(e_kev) * density_g_cm3 * 0.1
    }
}

/// A material at a density: what `--mesh FILE:MATERIAL[@DENSITY]` names.
#[derive(Debug, Clone, Copy)]
pub struct MaterialAt {
    pub material: &'static Material,
    pub density_g_cm3: f64,
}

impl MaterialAt {
    /// `MATERIAL` (its nominal density) or `MATERIAL@DENSITY` (g/cm³, positive and at most 25).
    pub fn parse(spec: &str) -> Result<Self> {
        let (name, density) = match spec.split_once('@') {
            Some((n, d)) => {
                let d: f64 = d.trim().parse().map_err(|_| {
                    Error::invalid(
                        "density",
                        format!("'{d}' in '{spec}' is not a number (g/cm³)"),
                    )
                })?;
                (n, Some(d))
            }
            None => (spec, None),
        };
        let material = Material::named(name)?;
        let density_g_cm3 = density.unwrap_or(material.density_g_cm3);
        if !(density_g_cm3.is_finite() && density_g_cm3 > 0.0 && density_g_cm3 <= 25.0) {
            return Err(Error::invalid(
                "density",
                format!(
                    "{} g/cm³ in '{spec}' must be positive and at most 25 (osmium, the densest element, is 22.6)",
                    crate::error::shown(density_g_cm3)
                ),
            ));
        }
        Ok(MaterialAt {
            material,
            density_g_cm3,
        })
    }

    /// `name@density` as the sidecar records it.
    pub fn label(&self) -> String {
        format!("{}@{}", self.material.name, self.density_g_cm3)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compositions_sum_to_one_and_use_embedded_elements() {
        for m in MATERIALS {
            let s: f64 = m.composition.iter().map(|(_, w)| w).sum();
            assert!((s - 1.0).abs() < 1e-4, "{}: {s}", m.name);
            for (sym, _) in m.composition {
                assert!(nist::element_by_symbol(sym).is_ok(), "{}: {sym}", m.name);
            }
        }
    }

    #[test]
    fn names_aliases_and_densities_parse_and_bad_ones_are_named() {
        assert_eq!(Material::named("Ti").unwrap().name, "titanium");
        assert_eq!(
            Material::named("cortical-bone").unwrap().name,
            "cortical_bone"
        );
        let m = MaterialAt::parse("steel@7.9").unwrap();
        assert_eq!((m.material.name, m.density_g_cm3), ("steel", 7.9));
        assert_eq!(MaterialAt::parse("peek").unwrap().density_g_cm3, 1.30);
        let e = MaterialAt::parse("unobtainium").unwrap_err().to_string();
        assert!(e.contains("unobtainium") && e.contains("titanium"), "{e}");
        for bad in ["water@", "water@-1", "water@nan", "water@30"] {
            assert!(MaterialAt::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn water_follows_nist_table_4() {
        // NIST SRD 126 Table 4, "Water, Liquid": μ/ρ at 20, 60 and 100 keV.
        let w = Material::named("water").unwrap();
        for (e, nist) in [(20.0, 0.8096), (60.0, 0.2059), (100.0, 0.1707)] {
            assert!((w.mu_rho(e) / nist - 1.0).abs() < 1e-3, "{e} keV");
        }
    }
}
