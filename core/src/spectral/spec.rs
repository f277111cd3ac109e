//! The text forms of the spectral model that the CLI and the Python module share: `--spectrum`,
//! `--filter`, `--detector` and a mesh's attenuation (`MU` or `MATERIAL[@DENSITY]`).

use std::path::Path;

use super::detector::Detector;
use super::materials::MaterialAt;
use super::model::SpectralModel;
use super::spectrum::Spectrum;
use crate::{Error, Result};

/// What a mesh attenuates with: μ (mm⁻¹, energy-independent) or a material at a density.
#[derive(Debug, Clone, Copy)]
pub enum Attenuation {
    Mu(f64),
    Material(MaterialAt),
}

/// A spectrum spec: a tube potential in kV (`80`: TASMIP), `mono:E` (keV), or a spectrum file.
pub fn parse_spectrum(spec: &str) -> Result<Spectrum> {
    if let Some(e) = spec.strip_prefix("mono:") {
        let e: f64 = e.trim().parse().map_err(|_| {
            Error::invalid(
                "spectrum",
                format!("'{e}' in '{spec}' is not an energy in keV"),
            )
        })?;
        return Spectrum::monochromatic(e);
    }
    if let Ok(kv) = spec.trim().parse::<f64>() {
        return Spectrum::tasmip(kv);
    }
    let path = Path::new(spec);
    if !path.is_file() {
        return Err(Error::invalid(
            "spectrum",
            format!(
                "'{spec}' is neither a tube potential in kV (e.g. 80), `mono:E` (keV) nor an existing \
                 spectrum file"
            ),
        ));
    }
    Spectrum::from_file(path)
}

/// `spectrum` behind the filters of `list`, comma-separated `MATERIAL[@DENSITY]:MM` (e.g. `al:2.5,cu:0.1`).
pub fn apply_filters(mut spectrum: Spectrum, list: &str) -> Result<Spectrum> {
    for item in list.split(',').filter(|s| !s.trim().is_empty()) {
        let bad = |why: String| Error::invalid("filter", format!("'{item}' in '{list}': {why}"));
        let (m, mm) = item
            .rsplit_once(':')
            .ok_or_else(|| bad("not MATERIAL[@DENSITY]:MM (e.g. al:2.5)".into()))?;
        let mm: f64 = mm
            .trim()
            .parse()
            .map_err(|_| bad(format!("thickness '{mm}' is not a number (mm)")))?;
        spectrum = spectrum.filtered(MaterialAt::parse(m)?, mm)?;
    }
    Ok(spectrum)
}

/// The model of a spectrum spec, a filter list (may be empty) and a detector spec.
pub fn model_from_specs(spectrum: &str, filters: &str, detector: &str) -> Result<SpectralModel> {
    let s = apply_filters(parse_spectrum(spectrum)?, filters)?;
    SpectralModel::new(s, Detector::parse(detector)?)
}

/// `MU` (a finite number, mm⁻¹) or `MATERIAL[@DENSITY]`.
pub fn parse_attenuation(value: &str) -> Result<Attenuation> {
    match value.trim().parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(Attenuation::Mu(v)),
        Ok(v) => Err(Error::invalid("mu", format!("{v} must be finite"))),
        Err(_) => MaterialAt::parse(value)
            .map(Attenuation::Material)
            .map_err(|e| {
                Error::invalid(
                    "attenuation",
                    format!("'{value}' is neither a number (μ in mm⁻¹) nor a material: {e}"),
                )
            }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs_parse_and_bad_ones_say_why() {
        let m = model_from_specs("80", "al:2.5, cu:0.1", "csi:0.6").unwrap();
        assert_eq!(m.spectrum.filtration.len(), 2);
        assert_eq!(model_from_specs("mono:60", "", "ideal").unwrap().bins(), 1);
        for (s, f, d) in [
            ("80", "al", "ideal"),
            ("80", "al:x", "ideal"),
            ("80", "gold:1", "ideal"),
            ("nope.csv", "", "ideal"),
            ("mono:x", "", "ideal"),
            ("80", "", "csi"),
        ] {
            assert!(model_from_specs(s, f, d).is_err(), "{s} {f} {d}");
        }
        assert!(matches!(parse_attenuation("0.02"), Ok(Attenuation::Mu(_))));
        assert!(matches!(
            parse_attenuation("ti@4.5"),
            Ok(Attenuation::Material(_))
        ));
        assert!(parse_attenuation("inf").is_err());
        assert!(parse_attenuation("kryptonite").is_err());
    }
}
