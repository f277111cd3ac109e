//! The phantom's dimensions: per-level lumbar morphometry and the shape values shared by all levels,
//! read from a TOML table. The default is `assets/morphometry/lumbar.toml` (embedded), whose comments cite
//! the source table of every number (Panjabi et al. 1992, Zindrick et al. 1987, Zhou et al. 2000,
//! Panjabi et al. 1993) and define how each is measured.

use std::path::Path;

use serde::Deserialize;

use super::level::Level;
use crate::{Error, Result};

/// The embedded default table.
pub const DEFAULT_MORPHOMETRY_TOML: &str = include_str!("../../../assets/morphometry/lumbar.toml");

/// Morphometry of one level (millimetres, degrees); definitions in the data file.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Morphometry {
    pub endplate_width: f64,
    pub endplate_depth: f64,
    pub body_height: f64,
    pub pedicle_width: f64,
    pub pedicle_height: f64,
    pub pedicle_transverse_deg: f64,
    pub canal_width: f64,
    pub canal_depth: f64,
    pub spinous_length: f64,
    pub transverse_span: f64,
    pub transverse_height: f64,
    pub superior_facet_deg: f64,
    pub inferior_facet_deg: f64,
}

/// Shape values no morphometry table gives, the same at every level (millimetres, degrees, fractions).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShapeParams {
    pub body_rim_mm: f64,
    pub endplate_concavity_mm: f64,
    pub posterior_concavity_mm: f64,
    pub waist: f64,
    pub blend_mm: f64,
    pub process_rounding_mm: f64,
    pub pedicle_length_mm: f64,
    pub lamina_thickness_mm: f64,
    pub lamina_height_mm: f64,
    pub lamina_slope_deg: f64,
    pub spinous_height_mm: f64,
    pub spinous_tip_height_mm: f64,
    pub spinous_thickness_mm: f64,
    pub spinous_tip_thickness_mm: f64,
    pub spinous_slope_deg: f64,
    pub transverse_thickness_mm: f64,
    pub transverse_tilt_deg: f64,
    /// The transverse process's root axis behind the pedicle's posterior end (mm; the process arises
    /// from the pedicle–lamina junction, not from the pedicle's lateral wall).
    pub transverse_root_mm: f64,
    pub facet_width_mm: f64,
    pub facet_height_mm: f64,
    pub articular_thickness_mm: f64,
    pub facet_gap_mm: f64,
}

/// All five levels and the shared shape values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MorphometryTable {
    levels: [Morphometry; 5],
    pub shape: ShapeParams,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    /// Rows with a `name` beside the [`Morphometry`] keys (split by hand: serde's `flatten` cannot
    /// refuse unknown keys).
    level: Vec<toml::Table>,
    shape: ShapeParams,
}

impl Default for MorphometryTable {
    fn default() -> Self {
        // The embedded table is parsed and checked by the test `default_table_parses`.
        MorphometryTable::parse(DEFAULT_MORPHOMETRY_TOML, "assets/morphometry/lumbar.toml")
            .expect("the embedded morphometry table is valid")
    }
}

impl MorphometryTable {
    /// The values of `level`.
    pub fn level(&self, level: Level) -> &Morphometry {
        &self.levels[level.index()]
    }

    /// Reads and checks a table file.
    pub fn from_toml_file(path: &Path) -> Result<MorphometryTable> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        MorphometryTable::parse(&text, &path.display().to_string())
    }

    /// Parses and checks a table; `origin` names the source in errors.
    pub fn parse(text: &str, origin: &str) -> Result<MorphometryTable> {
        let file: File = toml::from_str(text)
            .map_err(|e| Error::invalid(format!("morphometry {origin}"), e.to_string()))?;
        let mut levels: [Option<Morphometry>; 5] = [None; 5];
        for mut row in file.level {
            let name = match row.remove("name") {
                Some(toml::Value::String(s)) => s,
                other => {
                    return Err(Error::invalid(
                        format!("morphometry {origin}: level.name"),
                        format!("{other:?} is not a level name"),
                    ));
                }
            };
            let l = Level::parse(&name).map_err(|_| {
                Error::invalid(
                    format!("morphometry {origin}: level.name"),
                    format!("{name:?} is not one of L1 … L5"),
                )
            })?;
            let m: Morphometry = toml::Value::Table(row).try_into().map_err(|e| {
                Error::invalid(format!("morphometry {origin}: level {name}"), e.to_string())
            })?;
            if levels[l.index()].replace(m).is_some() {
                return Err(Error::invalid(
                    format!("morphometry {origin}: level.name"),
                    format!("{l} appears twice"),
                ));
            }
        }
        let out = levels
            .into_iter()
            .enumerate()
            .map(|(i, m)| {
                m.ok_or_else(|| {
                    Error::invalid(
                        format!("morphometry {origin}: level"),
                        format!("{} is missing", Level::ALL[i]),
                    )
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let table = MorphometryTable {
            levels: out.try_into().expect("one row per level"),
            shape: file.shape,
        };
        table.check(origin)?;
        Ok(table)
    }

    fn check(&self, origin: &str) -> Result<()> {
        let within = |field: String, v: f64, lo: f64, hi: f64| {
            if v.is_finite() && (lo..=hi).contains(&v) {
                Ok(())
            } else {
                Err(Error::invalid(
                    format!("morphometry {origin}: {field}"),
                    format!("{v} is outside [{lo}, {hi}]"),
                ))
            }
        };
        for (l, m) in Level::ALL.iter().zip(&self.levels) {
            let f = |k: &str| format!("{l}.{k}");
            within(f("endplate_width"), m.endplate_width, 20.0, 80.0)?;
            within(f("endplate_depth"), m.endplate_depth, 15.0, 60.0)?;
            within(f("body_height"), m.body_height, 12.0, 45.0)?;
            within(f("pedicle_width"), m.pedicle_width, 3.0, 25.0)?;
            within(f("pedicle_height"), m.pedicle_height, 5.0, 25.0)?;
            within(
                f("pedicle_transverse_deg"),
                m.pedicle_transverse_deg,
                0.0,
                45.0,
            )?;
            within(f("canal_width"), m.canal_width, 10.0, 40.0)?;
            within(f("canal_depth"), m.canal_depth, 8.0, 30.0)?;
            within(f("spinous_length"), m.spinous_length, 10.0, 50.0)?;
            within(
                f("transverse_span"),
                m.transverse_span,
                m.canal_width + 2.0 * m.pedicle_width + 10.0,
                140.0,
            )?;
            within(f("transverse_height"), m.transverse_height, 4.0, 25.0)?;
            within(f("superior_facet_deg"), m.superior_facet_deg, 0.0, 80.0)?;
            within(f("inferior_facet_deg"), m.inferior_facet_deg, 0.0, 80.0)?;
            // The pedicles must sit inside the body's upper half.
            within(
                f("pedicle_height"),
                m.pedicle_height,
                5.0,
                m.body_height * 0.8,
            )?;
        }
        let s = &self.shape;
        let f = |k: &str| format!("shape.{k}");
        within(f("body_rim_mm"), s.body_rim_mm, 0.5, 4.0)?;
        within(
            f("endplate_concavity_mm"),
            s.endplate_concavity_mm,
            0.0,
            3.0,
        )?;
        within(
            f("posterior_concavity_mm"),
            s.posterior_concavity_mm,
            0.0,
            6.0,
        )?;
        within(f("waist"), s.waist, 0.0, 0.15)?;
        within(f("blend_mm"), s.blend_mm, 0.0, 6.0)?;
        within(f("process_rounding_mm"), s.process_rounding_mm, 0.5, 5.0)?;
        within(f("pedicle_length_mm"), s.pedicle_length_mm, 4.0, 20.0)?;
        within(f("lamina_thickness_mm"), s.lamina_thickness_mm, 3.0, 12.0)?;
        within(f("lamina_height_mm"), s.lamina_height_mm, 10.0, 35.0)?;
        within(f("lamina_slope_deg"), s.lamina_slope_deg, 0.0, 60.0)?;
        within(f("spinous_height_mm"), s.spinous_height_mm, 6.0, 30.0)?;
        within(
            f("spinous_tip_height_mm"),
            s.spinous_tip_height_mm,
            6.0,
            30.0,
        )?;
        within(f("spinous_thickness_mm"), s.spinous_thickness_mm, 3.0, 12.0)?;
        within(
            f("spinous_tip_thickness_mm"),
            s.spinous_tip_thickness_mm,
            3.0,
            15.0,
        )?;
        within(f("spinous_slope_deg"), s.spinous_slope_deg, 0.0, 45.0)?;
        within(
            f("transverse_thickness_mm"),
            s.transverse_thickness_mm,
            3.0,
            12.0,
        )?;
        within(f("transverse_tilt_deg"), s.transverse_tilt_deg, 0.0, 40.0)?;
        within(f("transverse_root_mm"), s.transverse_root_mm, -5.0, 10.0)?;
        within(f("facet_width_mm"), s.facet_width_mm, 6.0, 25.0)?;
        within(f("facet_height_mm"), s.facet_height_mm, 6.0, 25.0)?;
        within(
            f("articular_thickness_mm"),
            s.articular_thickness_mm,
            3.0,
            12.0,
        )?;
        within(f("facet_gap_mm"), s.facet_gap_mm, 1.0, 6.0)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_table_parses() {
        let t = MorphometryTable::default();
        assert_eq!(t.level(Level::L1).pedicle_transverse_deg, 11.0);
        // Facets meet: a level's inferior facet angle is the next level's superior one.
        for w in Level::ALL.windows(2) {
            assert_eq!(
                t.level(w[0]).inferior_facet_deg,
                t.level(w[1]).superior_facet_deg
            );
        }
    }

    #[test]
    fn bad_tables_name_the_field() {
        let bad =
            DEFAULT_MORPHOMETRY_TOML.replacen("endplate_width = 44.5", "endplate_width = -4", 1);
        let e = MorphometryTable::parse(&bad, "x.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("x.toml") && e.contains("L3.endplate_width"),
            "{e}"
        );
        let bad = DEFAULT_MORPHOMETRY_TOML.replacen("name = \"L4\"", "name = \"L3\"", 1);
        let e = MorphometryTable::parse(&bad, "x.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("twice"), "{e}");
        let bad = DEFAULT_MORPHOMETRY_TOML.replacen("waist =", "waste =", 1);
        let e = MorphometryTable::parse(&bad, "x.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("waste"), "{e}");
    }
}
