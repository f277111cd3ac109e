//! *Pedicle screws*: `screws.csv` and `screw_navigation.csv` in the report — per assumed geometry, the
//! largest on-screen offset of a planned screw's tip drawn with the wrong calibration in each view (px and
//! mm at the screw), the largest drawn axis rotation, and where a navigation system registered with that
//! calibration puts the screw in 3-D. The table has the single levels (each built at the world origin);
//! a paragraph sets the L1–L5 segment's screws beside them under the largest focal offset. Every number
//! is a row of the two tables, the largest over the screws it names.

use std::fmt::Write as _;

use super::grid::{Pitch, short};
use super::shift_ratio::is_segment;
use crate::study::config::Family;
use crate::study::figures::{FigureEntry, Section};
use crate::study::schema::{ScrewNavigationRow, ScrewRow};

pub const HEADING: &str = "Pedicle screws drawn and navigated with the wrong geometry";

/// The largest finite value of `f` over `rows` with the row it came from.
fn largest<'a, R>(rows: &[&'a R], f: impl Fn(&R) -> f64) -> Option<(f64, &'a R)> {
    rows.iter()
        .filter(|r| f(r).is_finite())
        .map(|r| (f(r), *r))
        .max_by(|a, b| a.0.total_cmp(&b.0))
}

/// `x` with `d` decimals, `n/a` when not finite.
fn num(x: f64, d: usize) -> String {
    if x.is_finite() {
        short(x, d)
    } else {
        "n/a".into()
    }
}

/// The assumed geometry of a cell in words, with its physical size where the detector's pitch is known.
fn geometry(family: Family, pert: &str, df: f64, p: f64, pitch: Pitch) -> String {
    match family {
        Family::Focal => pitch.df_words(df),
        Family::Piercing => pitch.p_words(p),
        Family::Joint => format!("{} with {}", pitch.df_words(df), pitch.p_words(p)),
        _ => pert.to_string(),
    }
}

/// Writes the section (nothing without rows).
pub fn section(
    md: &mut String,
    views: &[String],
    (rows, nav): (&[ScrewRow], &[ScrewNavigationRow]),
    pitch: Pitch,
    (figs, n): (&[FigureEntry], &mut usize),
) {
    let drawn: Vec<&ScrewRow> = rows.iter().filter(|r| !is_segment(&r.target)).collect();
    let navs: Vec<&ScrewNavigationRow> = nav.iter().filter(|r| !is_segment(&r.target)).collect();
    if drawn.is_empty() {
        return;
    }
    let mut levels: Vec<&str> = drawn.iter().map(|r| r.target.as_str()).collect();
    levels.dedup();
    let screws = navs
        .iter()
        .filter(|r| r.perturbation == navs[0].perturbation)
        .count();
    let lengths: Vec<f64> = drawn.iter().map(|r| r.length_mm).collect();
    let _ = writeln!(md, "## {HEADING}\n");
    let _ = writeln!(
        md,
        "Each level's planned pedicle screws ({screws} screws on {} level{}: {}; entry to tip {} mm, \
the phantom's pedicle axes or a user's `…pedicle_entry` / `…pedicle_tip` landmarks) under each assumed \
geometry of the grid, two ways. **Drawn**: the screw at its true pose projected with the assumed view, \
against its true image — an overlay from a tracked pose with the wrong calibration; the tip's offset in \
px of the detector and in mm at the screw (divided by the true magnification at the tip), and the angle \
the drawn axis turns. **Navigated**: the level registered from its landmarks in {} with the assumed views \
(noise-free, from the truth: the calibration's bias), which carries the planned screw to a wrong place in \
3-D — its tip's error (mm) and its axis's (°) — while the registration's reprojection residual (px) says \
how well the overlay seems to fit. Each cell is the largest over the levels' screws \
(`tables/screws.csv`, `tables/screw_navigation.csv`).\n",
        levels.len(),
        if levels.len() == 1 { "" } else { "s" },
        levels.join(", "),
        {
            let (lo, hi) = (
                num(lengths.iter().copied().fold(f64::INFINITY, f64::min), 1),
                num(lengths.iter().copied().fold(f64::NEG_INFINITY, f64::max), 1),
            );
            if lo == hi { lo } else { format!("{lo}–{hi}") }
        },
        views
            .iter()
            .map(|v| v.to_uppercase())
            .collect::<Vec<_>>()
            .join(" and ")
    );
    super::layout::figures(md, figs, Section::Screws, n);
    let mut header = "| assumed geometry |".to_string();
    let mut rule = "|---|".to_string();
    for v in views {
        let v = v.to_uppercase();
        let _ = write!(
            header,
            " {v}: drawn tip (px / mm at the screw) | {v}: drawn axis (°) |"
        );
        rule.push_str("---|---|");
    }
    header.push_str(
        " navigated tip (mm) | navigated axis (°) | residual (px) | screws over 1 / 2 mm |",
    );
    rule.push_str("---|---|---|---|");
    let _ = writeln!(md, "{header}\n{rule}");
    let mut cells: Vec<&str> = Vec::new();
    for r in &drawn {
        if !cells.contains(&r.perturbation.as_str()) {
            cells.push(&r.perturbation);
        }
    }
    for pert in &cells {
        let here: Vec<&ScrewRow> = drawn
            .iter()
            .copied()
            .filter(|r| r.perturbation == *pert)
            .collect();
        let first = here[0];
        let mut line = format!(
            "| {} |",
            geometry(first.family, pert, first.df_px, first.piercing_px, pitch)
        );
        for v in views {
            let in_view: Vec<&ScrewRow> = here.iter().copied().filter(|r| r.view == *v).collect();
            let tip = largest(&in_view, |r| r.tip_px).map_or("n/a".into(), |(px, r)| {
                format!("{} / {}", num(px, 2), num(r.tip_mm, 2))
            });
            let axis = largest(&in_view, |r| r.axis_deg).map_or("n/a".into(), |(a, _)| num(a, 2));
            let _ = write!(line, " {tip} | {axis} |");
        }
        let nav_here: Vec<&ScrewNavigationRow> = navs
            .iter()
            .copied()
            .filter(|r| r.perturbation == *pert && r.converged)
            .collect();
        let tip = largest(&nav_here, |r| r.tip_mm).map_or("n/a".into(), |(x, _)| num(x, 2));
        let axis = largest(&nav_here, |r| r.axis_deg).map_or("n/a".into(), |(x, _)| num(x, 2));
        let residual =
            largest(&nav_here, |r| r.residual_px).map_or("n/a".into(), |(x, _)| num(x, 2));
        let over = |mm: f64| nav_here.iter().filter(|r| r.tip_mm > mm).count();
        let failed = navs
            .iter()
            .filter(|r| r.perturbation == *pert && !r.converged)
            .count();
        let failed = if failed > 0 {
            format!(" ({failed} not converged)")
        } else {
            String::new()
        };
        let _ = writeln!(
            line,
            " {tip} | {axis} | {residual} | {} / {} of {}{failed} |",
            over(1.0),
            over(2.0),
            nav_here.len()
        );
        md.push_str(&line);
    }
    let _ = writeln!(md);
    axis_law(md, &drawn);
    worst(md, &drawn, &navs, pitch);
    segment(md, views, (rows, nav), (&drawn, &navs), pitch);
}

/// The segment's screws (each level at its place in the stack, the stack at the views' mean aim height),
/// beside the single levels', under the largest focal offset of the grid: the scaling about the
/// principal point draws a tip in proportion to its distance from it, which the single levels at the
/// world origin do not show. Every number is a row of the two tables.
fn segment(
    md: &mut String,
    views: &[String],
    (rows, nav): (&[ScrewRow], &[ScrewNavigationRow]),
    (single, single_nav): (&[&ScrewRow], &[&ScrewNavigationRow]),
    pitch: Pitch,
) {
    let seg: Vec<&ScrewRow> = rows.iter().filter(|r| is_segment(&r.target)).collect();
    let Some((df, _)) = largest(
        &seg.iter()
            .copied()
            .filter(|r| r.family == Family::Focal)
            .collect::<Vec<_>>(),
        |r| r.df_px,
    ) else {
        return;
    };
    let cell = |r: &ScrewRow| r.family == Family::Focal && r.df_px == df;
    let (mut parts, mut alone) = (Vec::new(), Vec::new());
    for v in views {
        let of = |rows: &[&ScrewRow]| {
            let here: Vec<&ScrewRow> = rows
                .iter()
                .copied()
                .filter(|r| cell(r) && r.view == *v)
                .collect();
            largest(&here, |r| r.tip_px).map(|(px, r)| (px, r.tip_mm, r.screw.clone()))
        };
        if let (Some((px, mm, screw)), Some((single_px, _, _))) = (of(&seg), of(single)) {
            parts.push(format!(
                "{} px in {} ({} mm at the screw; {} screw)",
                num(px, 2),
                v.to_uppercase(),
                num(mm, 2),
                screw.replace('/', "'s ")
            ));
            alone.push(num(single_px, 2));
        }
    }
    if parts.is_empty() {
        return;
    }
    let nav_of = |rows: &[&ScrewNavigationRow]| {
        let here: Vec<&ScrewNavigationRow> = rows
            .iter()
            .copied()
            .filter(|r| r.family == Family::Focal && r.df_px == df && r.converged)
            .collect();
        largest(&here, |r| r.tip_mm).map(|(x, _)| x)
    };
    let seg_nav: Vec<&ScrewNavigationRow> = nav.iter().filter(|r| is_segment(&r.target)).collect();
    let navigated = match (nav_of(&seg_nav), nav_of(single_nav)) {
        (Some(a), Some(b)) => format!(
            " Navigated, the segment's largest tip error is {} mm against {} mm for the levels alone.",
            num(a, 2),
            num(b, 2)
        ),
        _ => String::new(),
    };
    let mut levels: Vec<&str> = seg
        .iter()
        .filter_map(|r| r.screw.split_once('/').map(|(level, _)| level))
        .collect();
    levels.sort_unstable();
    levels.dedup();
    let _ = writeln!(
        md,
        "In the segment ({}) — the same screws, each level at its place in the stack, the stack moved to the \
views' mean aim height (see Setup; `{}` rows of the tables, not in the table above) — a focal error draws \
a tip in proportion to its distance from the principal point, so the screws far from it are drawn \
further: under {} the largest drawn tip offset is {}, against {} px for the levels alone (each at the \
world origin).{navigated}\n",
        levels.join(", "),
        seg[0].target,
        pitch.df_words(df),
        parts.join(" and "),
        alone.join(" and ")
    );
}

/// The law the intrinsic families obey on the screen: Δf scales the image about the principal point and
/// a piercing shift translates it, so neither turns a drawn screw. Stated only when every such row shows it.
fn axis_law(md: &mut String, drawn: &[&ScrewRow]) {
    let law: Vec<&&ScrewRow> = drawn
        .iter()
        .filter(|r| matches!(r.family, Family::Focal | Family::Piercing | Family::Joint))
        .filter(|r| r.axis_deg.is_finite())
        .collect();
    let Some(most) = law.iter().map(|r| r.axis_deg).max_by(f64::total_cmp) else {
        return;
    };
    if most >= 1e-6 {
        return;
    }
    let turned: Vec<&&ScrewRow> = drawn
        .iter()
        .filter(|r| !matches!(r.family, Family::Focal | Family::Piercing | Family::Joint))
        .collect();
    let others = match largest(&turned, |r| r.axis_deg) {
        Some((a, r)) => format!(
            " The other families do turn it, by up to {}° ({} in {}).",
            num(a, 2),
            r.perturbation,
            r.view.to_uppercase()
        ),
        None => String::new(),
    };
    let _ = writeln!(
        md,
        "A focal or piercing error scales the image about the principal point or shifts it, so it moves a \
drawn screw without turning it: the drawn axis angle is below 10⁻⁶° in all {} such rows.{others}\n",
        law.len()
    );
}

/// The worst cell of the grid in words: the largest navigated tip error, with its drawn offset and the
/// registration's residual — every number read from the same rows.
fn worst(md: &mut String, drawn: &[&ScrewRow], navs: &[&ScrewNavigationRow], pitch: Pitch) {
    let converged: Vec<&ScrewNavigationRow> =
        navs.iter().copied().filter(|r| r.converged).collect();
    let Some((tip, n)) = largest(&converged, |r| r.tip_mm) else {
        return;
    };
    let on_screen: Vec<&ScrewRow> = drawn
        .iter()
        .copied()
        .filter(|r| r.target == n.target && r.screw == n.screw && r.perturbation == n.perturbation)
        .collect();
    let views: Vec<String> = on_screen
        .iter()
        .map(|r| {
            format!(
                "{} px drawn in {} ({} px where the navigation draws it)",
                num(r.tip_px, 2),
                r.view.to_uppercase(),
                num(r.nav_tip_px, 2)
            )
        })
        .collect();
    let _ = writeln!(
        md,
        "The largest navigated error of the grid: under {}, the navigation puts {}'s {} screw tip {} mm \
from where it is and turns its axis by {}°, while its registration's residual is {} px; on the screen \
that tip is {}.\n",
        geometry(n.family, &n.perturbation, n.df_px, n.piercing_px, pitch),
        n.target,
        n.screw,
        num(tip, 2),
        num(n.axis_deg, 2),
        num(n.residual_px, 2),
        views.join(", ")
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    fn drawn(target: &str, screw: &str, view: &str, df: f64, tip_px: f64) -> ScrewRow {
        ScrewRow {
            target: target.into(),
            screw: screw.into(),
            view: view.into(),
            family: Family::Focal,
            perturbation: format!("df={df}"),
            df_px: df,
            piercing_px: 0.0,
            length_mm: 45.0,
            tip_px,
            tip_mm: tip_px / 5.0,
            entry_px: tip_px / 2.0,
            entry_mm: tip_px / 10.0,
            axis_deg: 0.0,
            projected_length_px: 150.0,
            nav_tip_px: 1.0,
        }
    }

    fn navigated(target: &str, df: f64, tip_mm: f64) -> ScrewNavigationRow {
        ScrewNavigationRow {
            target: target.into(),
            screw: "L1/left".into(),
            views: "ap+lat".into(),
            family: Family::Focal,
            perturbation: format!("df={df}"),
            df_px: df,
            piercing_px: 0.0,
            tip_mm,
            entry_mm: tip_mm / 2.0,
            axis_deg: 0.1,
            residual_px: 1.0,
            converged: true,
        }
    }

    /// The segment's paragraph reads the largest focal cell's rows: the segment's largest tip per view
    /// with its screw, the single levels' largest in the same cell, and the navigated maxima.
    #[test]
    fn the_segment_paragraph_states_the_largest_focal_cell_of_each_target_kind() {
        let views = vec!["ap".to_string(), "lat".to_string()];
        let mut rows = Vec::new();
        for (df, k) in [(100.0, 1.0), (500.0, 5.0)] {
            rows.push(drawn("L1", "L1/left", "ap", df, 1.0 * k));
            rows.push(drawn("L1", "L1/left", "lat", df, 4.0 * k));
            rows.push(drawn("segment", "L1/right", "ap", df, 8.0 * k));
            rows.push(drawn("segment", "L5/left", "ap", df, 7.0 * k));
            rows.push(drawn("segment", "L5/left", "lat", df, 9.0 * k));
        }
        let nav = vec![
            navigated("L1", 500.0, 1.8),
            navigated("segment", 500.0, 1.2),
            navigated("segment", 100.0, 9.0),
        ];
        let single: Vec<&ScrewRow> = rows.iter().filter(|r| r.target == "L1").collect();
        let single_nav: Vec<&ScrewNavigationRow> =
            nav.iter().filter(|r| r.target == "L1").collect();
        let mut md = String::new();
        segment(
            &mut md,
            &views,
            (&rows, &nav),
            (&single, &single_nav),
            Pitch(None),
        );
        for want in [
            "In the segment (L1, L5) — ",
            "40 px in AP (8 mm at the screw; L1's right screw)",
            "45 px in LAT (9 mm at the screw; L5's left screw)",
            "against 5 and 20 px",
            "largest tip error is 1.2 mm against 1.8 mm",
        ] {
            assert!(md.contains(want), "{want}: {md}");
        }
        // Without segment rows, no paragraph.
        let mut none = String::new();
        segment(
            &mut none,
            &views,
            (
                &single.iter().map(|r| (*r).clone()).collect::<Vec<_>>(),
                &[],
            ),
            (&single, &[]),
            Pitch(None),
        );
        assert!(none.is_empty(), "{none}");
    }
}
