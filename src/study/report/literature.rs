//! *The literature beside ours*: the published sensitivity results of `reference/literature.toml`
//! (embedded), each beside the tracking.csv cell of this run whose setup comes closest, and what differs.
//! Every number of ours is a cell of this run's `tracking.csv` (the first target's row); a cell the run
//! did not compute is said to be missing, never filled in.

use std::fmt::Write as _;

use serde::Deserialize;

use super::grid::short;
use crate::study::schema::TrackingRow;
use crate::{Error, Result};

pub const HEADING: &str = "The literature beside ours";

/// `reference/literature.toml`.
pub const LITERATURE_TOML: &str = include_str!("../../../reference/literature.toml");

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Literature {
    study: Vec<Study>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Study {
    cite: String,
    setup: String,
    differs: String,
    claim: Vec<Claim>,
}

/// A published number and the cell of ours set beside it.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Claim {
    published: String,
    value: f64,
    unit: String,
    pub method: String,
    pub perturbation: String,
    pub column: String,
}

fn literature() -> Result<Literature> {
    toml::from_str(LITERATURE_TOML)
        .map_err(|e| Error::format("reference/literature.toml", e.to_string()))
}

/// The value of `column` in `row` (the tracking.csv columns a claim may name).
pub fn cell(row: &TrackingRow, column: &str) -> Option<f64> {
    Some(match column {
        "abs_tre_mm" => row.abs_tre_mm,
        "abs_trans_err_mm" => row.abs_trans_err_mm,
        "abs_rot_err_deg" => row.abs_rot_err_deg,
        "rel_tre_mm" => row.rel_tre_mm,
        "rel_trans_err_mm" => row.rel_trans_err_mm,
        "rel_rot_err_deg" => row.rel_rot_err_deg,
        _ => return None,
    })
}

/// Writes the section (nothing without tracking rows).
/// `physical`: whether the geometry states its detector in mm (`sdd_mm`, `pixel_spacing_mm`), which
/// the physical errors need; an explicit K does not.
pub fn section(
    md: &mut String,
    rows: &[TrackingRow],
    (first, physical): (&str, bool),
) -> Result<()> {
    if rows.is_empty() {
        return Ok(());
    }
    let lit = literature()?;
    let _ = writeln!(md, "## {HEADING}\n");
    let add = if physical {
        "add its perturbation to `[perturbations.physical]` or `[tracking] df_px`"
    } else {
        "add its Δf to `[tracking] df_px` (a physical error needs a geometry that gives `sdd_mm` and \
`pixel_spacing_mm`; this one gives an explicit K)"
    };
    let _ = writeln!(
        md,
        "Published sensitivity results (as their abstracts state them, `reference/literature.toml`) beside \
the cell of this run's `tables/tracking.csv` whose setup comes closest, for {first}. The cells were chosen \
by setup, not to match: each study's last line says why the numbers need not agree. A cell this run did \
not compute says so; {add}.\n"
    );
    for s in &lit.study {
        let _ = writeln!(md, "**{}.** Setup: {}.\n", s.cite, s.setup);
        let _ = writeln!(
            md,
            "| published | theirs | our cell ({first}) | ours |\n|---|---|---|---|"
        );
        for c in &s.claim {
            let row = rows.iter().find(|r| {
                r.target == first && r.method.name() == c.method && r.perturbation == c.perturbation
            });
            let ours = match row.and_then(|r| cell(r, &c.column).map(|v| (r, v))) {
                Some((r, v)) if r.converged && v.is_finite() => with_unit(v, &c.unit),
                Some(_) => "not converged".to_string(),
                None => "not in this run".to_string(),
            };
            let _ = writeln!(
                md,
                "| {} | {} | {}, {}, `{}` | {ours} |",
                c.published,
                with_unit(c.value, &c.unit),
                c.method,
                c.perturbation,
                c.column
            );
        }
        let _ = writeln!(md, "\nWhat differs: {}.\n", s.differs);
    }
    Ok(())
}

/// `1.7°`, `2.7 mm`: at most 3 decimals, a degree sign without a space.
fn with_unit(v: f64, unit: &str) -> String {
    if unit == "°" {
        format!("{}°", short(v, 3))
    } else {
        format!("{} {unit}", short(v, 3))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_literature_file_parses_and_names_tracking_columns() {
        let lit = literature().unwrap();
        assert_eq!(lit.study.len(), 4);
        for s in &lit.study {
            for c in &s.claim {
                assert!(
                    crate::geometry::Perturbation::parse(&c.perturbation).is_ok(),
                    "{}",
                    c.perturbation
                );
                assert!(
                    c.method
                        .parse::<crate::study::config::RegistrationMethod>()
                        .is_ok()
                );
                assert!(
                    [
                        "abs_tre_mm",
                        "abs_trans_err_mm",
                        "abs_rot_err_deg",
                        "rel_tre_mm",
                        "rel_trans_err_mm",
                        "rel_rot_err_deg"
                    ]
                    .contains(&c.column.as_str()),
                    "{}",
                    c.column
                );
                assert!(c.value.is_finite() && c.value > 0.0);
            }
        }
    }
}
