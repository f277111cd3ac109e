//! The elements' photon attenuation data (NIST SRD 126, Hubbell & Seltzer, Table 3), embedded from
//! `assets/xray/nist_elements.csv`, and their interpolation.
//!
//! μ/ρ and μ_en/ρ are interpolated with a natural cubic spline in (ln E, ln μ/ρ), one spline per interval
//! between absorption edges, the interpolation NIST's tables are meant to be read with: on the tabulated
//! grid (10, 15, 20, 30, … keV) log–log *linear* interpolation errs by up to 4 % between grid points, the
//! cubic by ≤ 0.3 % (water, hydroxyapatite, Ti, Fe against the finer Elam tables of `xraydb`, measured when
//! this was written).

use std::sync::OnceLock;

use super::spline::NaturalSpline;
use crate::{Error, Result};

/// The embedded table (see its header for the source).
const NIST_ELEMENTS_CSV: &str = include_str!("../../../assets/xray/nist_elements.csv");

/// Lowest and highest photon energy (keV) the embedded tables cover.
pub const TABLE_MIN_KEV: f64 = 1.0;
pub const TABLE_MAX_KEV: f64 = 200.0;

/// One element's tables: edge-free segments, each a spline of ln μ/ρ and of ln μ_en/ρ against ln E.
#[derive(Debug)]
pub(crate) struct ElementData {
    #[cfg_attr(not(test), allow(dead_code))]
    pub z: u8,
    pub symbol: String,
    /// (lowest energy of the segment in keV, ln μ/ρ spline, ln μ_en/ρ spline), by increasing energy.
    segments: Vec<(f64, NaturalSpline, NaturalSpline)>,
}

impl ElementData {
    fn segment(&self, e_kev: f64) -> &(f64, NaturalSpline, NaturalSpline) {
        // The last segment starting at or below E: at an edge energy itself, the above-edge side.
        let i = self.segments.partition_point(|s| s.0 <= e_kev);
        &self.segments[i.saturating_sub(1)]
    }

    /// μ/ρ (cm²/g) at `e_kev`.
    pub fn mu_rho(&self, e_kev: f64) -> f64 {
        self.segment(e_kev).1.eval(e_kev.ln()).exp()
    }

    /// μ_en/ρ (cm²/g) at `e_kev`.
    pub fn mu_en_rho(&self, e_kev: f64) -> f64 {
        self.segment(e_kev).2.eval(e_kev.ln()).exp()
    }
}

/// Every embedded element, parsed once.
pub(crate) fn elements() -> &'static [ElementData] {
    static TABLE: OnceLock<Vec<ElementData>> = OnceLock::new();
    TABLE.get_or_init(|| parse(NIST_ELEMENTS_CSV).expect("the embedded NIST table parses"))
}

/// The element with atomic number `z`, or an error naming the elements there are.
#[cfg(test)]
pub(crate) fn element(z: u8) -> Result<&'static ElementData> {
    elements().iter().find(|e| e.z == z).ok_or_else(|| {
        let have: Vec<String> = elements().iter().map(|e| e.symbol.clone()).collect();
        Error::invalid(
            "element",
            format!(
                "Z = {z} has no embedded attenuation data (there are {})",
                have.join(", ")
            ),
        )
    })
}

/// The element with chemical symbol `symbol` (as written in the table, e.g. `Ca`).
pub(crate) fn element_by_symbol(symbol: &str) -> Result<&'static ElementData> {
    elements()
        .iter()
        .find(|e| e.symbol == symbol)
        .ok_or_else(|| {
            Error::invalid(
                "element",
                format!("'{symbol}' has no embedded attenuation data"),
            )
        })
}

/// Rows `z,symbol,E_MeV,mu_rho,mu_en_rho` (after `#` comments and a header) into per-element segments.
/// Two rows at one energy are an absorption edge when μ/ρ jumps up by more than 1 %; a repeated row
/// (same energy, same value within 1 %) is dropped.
fn parse(text: &str) -> Result<Vec<ElementData>> {
    type Row = (f64, f64, f64);
    let mut by_z: Vec<(u8, String, Vec<Row>)> = Vec::new();
    for (n, line) in text.lines().enumerate() {
        if line.starts_with('#') || line.starts_with("z,") || line.trim().is_empty() {
            continue;
        }
        let bad = || Error::invalid("nist_elements.csv", format!("line {}: '{line}'", n + 1));
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 5 {
            return Err(bad());
        }
        let z: u8 = f[0].parse().map_err(|_| bad())?;
        let num = |s: &str| s.trim().parse::<f64>().map_err(|_| bad());
        let row = (num(f[2])? * 1e3, num(f[3])?, num(f[4])?);
        match by_z.last_mut() {
            Some(last) if last.0 == z => last.2.push(row),
            _ => by_z.push((z, f[1].to_string(), vec![row])),
        }
    }
    by_z.into_iter()
        .map(|(z, symbol, rows)| {
            let mut segments: Vec<Vec<Row>> = vec![Vec::new()];
            for r in rows {
                let cur = segments.last_mut().expect("one segment");
                match cur.last() {
                    Some(prev) if prev.0 == r.0 && r.1 > prev.1 * 1.01 => segments.push(vec![r]),
                    Some(prev) if prev.0 == r.0 => {}
                    _ => cur.push(r),
                }
            }
            let segments = segments
                .into_iter()
                .map(|s| {
                    if s.len() < 2 {
                        return Err(Error::invalid(
                            "nist_elements.csv",
                            format!("Z = {z}: an edge segment with one row"),
                        ));
                    }
                    let x: Vec<f64> = s.iter().map(|r| r.0.ln()).collect();
                    Ok((
                        s[0].0,
                        NaturalSpline::new(x.clone(), s.iter().map(|r| r.1.ln()).collect()),
                        NaturalSpline::new(x, s.iter().map(|r| r.2.ln()).collect()),
                    ))
                })
                .collect::<Result<Vec<_>>>()?;
            Ok(ElementData {
                z,
                symbol,
                segments,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tabulated_values_come_back_and_edges_split_the_table() {
        // At a tabulated energy the spline returns the table's value (NIST Table 3, Ti, 60 keV: 0.7661).
        let ti = element(22).unwrap();
        assert!((ti.mu_rho(60.0) / 0.7661 - 1.0).abs() < 1e-9);
        // The iodine K edge (33.17 keV): μ/ρ jumps by ~5.5× across it.
        let i = element_by_symbol("I").unwrap();
        let (below, above) = (i.mu_rho(33.16), i.mu_rho(33.17));
        assert!(above / below > 5.0, "{below} {above}");
        // Molybdenum's K edge at 20.0 keV: 20 keV itself is read above the edge (NIST: 80.54).
        let mo = element(42).unwrap();
        assert!((mo.mu_rho(20.0) / 80.54 - 1.0).abs() < 2e-3);
        assert!(element(92).is_err());
    }
}
