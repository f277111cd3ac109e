//! How the findings' values are derived: column statistics and point geometry of a [`Table`]'s rows,
//! formulas and counts of other claims, and the rules that decide categorical words (interval, trend,
//! tie, an order beyond the printed precision). `python/tests/test_findings.py` reimplements each.

use super::Inputs;
use super::claim::{Claim, Finding, Geometry, Op, Source, Stat, Table, Transform, Where};

/// What a size in px is in mm: a focal offset's SDD error, or a piercing shift's move on the detector (a
/// shift (p, p): p px along u and p px along v, so its mm is per axis, as the prose says).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Mm {
    Sdd,
    Detector,
}

/// `px` in mm as the prose prints it beside the px — ` (an SDD error of 150 mm)` or
/// ` (15 mm along u and v on the detector)` — recorded as the printed claim `id`
/// ([`Source::Detector`]); empty where the study has no reference sidecar with a pixel pitch (an
/// explicit-K geometry, no projection run).
pub fn in_mm(f: &mut Finding, x: &Inputs, id: &str, px: f64, what: Mm) -> String {
    let Some((reference, pitch)) = &x.pitch else {
        return String::new();
    };
    let mm = f.say(mm_claim(id, px, *pitch, reference));
    match what {
        Mm::Sdd => format!(" (an SDD error of {mm} mm)"),
        Mm::Detector => format!(" ({mm} mm along u and v on the detector)"),
    }
}

/// The claim of `px` × `pitch` mm: whole millimetres without decimals, else one.
pub fn mm_claim(id: &str, px: f64, pitch: f64, reference: &str) -> Claim {
    let v = px * pitch;
    let decimals = if (v - v.round()).abs() < 1e-6 { 0 } else { 1 };
    Claim::new(
        id,
        v,
        Source::Detector {
            px,
            reference: reference.into(),
        },
    )
    .shown(decimals, "mm")
}

/// `interval`: where [a, b] lies against the paper's [lo, hi].
pub fn interval(a: f64, b: f64, lo: f64, hi: f64) -> &'static str {
    if a >= lo && b <= hi {
        "inside"
    } else if b < lo || a > hi {
        "outside"
    } else {
        "overlapping"
    }
}

/// `trend`: from the first to the last value (each with its 95 % confidence half-width; NaN counts as
/// 0), `rising` or `falling` when they differ by more than the two half-widths together, else `flat`.
pub fn trend(first: f64, last: f64, ci_first: f64, ci_last: f64) -> &'static str {
    let ci = |c: f64| if c.is_finite() { c } else { 0.0 };
    let margin = ci(ci_first) + ci(ci_last);
    if last - first > margin {
        "rising"
    } else if first - last > margin {
        "falling"
    } else {
        "flat"
    }
}

/// Whether `a > b` beyond `decimals` decimals: printed alike they are a tie, not an order.
pub fn greater(a: f64, b: f64, decimals: usize) -> bool {
    a > b && format!("{a:.decimals$}") != format!("{b:.decimals$}")
}

/// A [`Source::CountGreater`] claim over `pairs` of `f`'s claims.
pub fn count_greater(f: &Finding, id: &str, pairs: Vec<[String; 2]>, decimals: usize) -> Claim {
    let k = pairs
        .iter()
        .filter(|[a, b]| match (f.value(a), f.value(b)) {
            (Some(a), Some(b)) => greater(a, b, decimals),
            _ => false,
        })
        .count();
    let n = pairs.len();
    Claim::new(id, k as f64, Source::CountGreater { pairs, decimals }).count(n)
}

/// `tie`: a and b differ by at most `pct` % of the larger magnitude.
pub fn tie(a: f64, b: f64, pct: f64) -> bool {
    (a - b).abs() <= pct / 100.0 * a.abs().max(b.abs())
}

/// A column statistic of `table` over the rows matching `w` (`None` without any finite cell).
pub fn column(
    table: &Table,
    w: Where,
    column: &str,
    transform: Transform,
    stat: Stat,
) -> Option<(f64, usize, Source)> {
    let rows = table.select(&w);
    let v: Vec<f64> = rows
        .iter()
        .map(|&i| table.number(i, column))
        .map(|x| match transform {
            Transform::Identity => x,
            Transform::OneMinus => 1.0 - x,
        })
        .filter(|x| x.is_finite())
        .collect();
    if v.is_empty() || (stat == Stat::Value && rows.len() != 1) {
        return None;
    }
    let n = v.len() as f64;
    let value = match stat {
        Stat::Value => v[0],
        Stat::Mean => v.iter().sum::<f64>() / n,
        Stat::Min => v.iter().copied().fold(f64::INFINITY, f64::min),
        Stat::Max => v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        Stat::Rms => (v.iter().map(|x| x * x).sum::<f64>() / n).sqrt(),
        Stat::P95 => crate::analysis::percentile(&v, 95.0),
    };
    Some((
        value,
        v.len(),
        Source::Column {
            table: table.file(),
            column: column.into(),
            transform,
            stat,
            filter: w,
            rows,
        },
    ))
}

/// The offset or spread of the points (`u`, `v`) of the rows matching `w` about `c`.
pub fn points(
    table: &Table,
    w: Where,
    [u, v]: [&str; 2],
    c: [f64; 2],
    geometry: Geometry,
) -> Option<(f64, usize, Source)> {
    let rows = table.select(&w);
    let p: Vec<(f64, f64)> = rows
        .iter()
        .map(|&i| (table.number(i, u), table.number(i, v)))
        .collect();
    if p.is_empty() || p.iter().any(|q| !q.0.is_finite() || !q.1.is_finite()) {
        return None;
    }
    let s = crate::study::report::shift_ratio::spread(&p, (c[0], c[1]));
    let value = match geometry {
        Geometry::Offset => s.offset,
        Geometry::Spread => s.spread,
    };
    Some((
        value,
        p.len(),
        Source::Points {
            table: table.file(),
            columns: [u.into(), v.into()],
            about: c,
            geometry,
            filter: w,
            rows,
        },
    ))
}

/// A formula claim of the claims `of` of `f` (`None` when one is missing).
pub fn formula<S: AsRef<str>>(f: &Finding, id: &str, op: Op, of: &[S]) -> Option<Claim> {
    let v = of
        .iter()
        .map(|a| f.value(a.as_ref()))
        .collect::<Option<Vec<f64>>>()?;
    Some(
        Claim::new(
            id,
            op.apply(&v),
            Source::Formula {
                op,
                of: of.iter().map(|a| a.as_ref().to_string()).collect(),
            },
        )
        .count(v.len()),
    )
}

/// A count claim of `items`.
pub fn count(id: &str, items: &[String]) -> Claim {
    Claim::new(
        id,
        items.len() as f64,
        Source::Count {
            items: items.to_vec(),
        },
    )
    .count(items.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rules_decide_their_words() {
        assert_eq!(interval(0.1, 0.3, 0.05, 0.37), "inside");
        assert_eq!(interval(0.14, 0.7, 0.05, 0.37), "overlapping");
        assert_eq!(interval(0.01, 0.7, 0.05, 0.37), "overlapping");
        assert_eq!(interval(0.4, 0.7, 0.05, 0.37), "outside");
        assert_eq!(trend(1.0, 3.0, 0.5, 0.5), "rising");
        assert_eq!(trend(3.0, 1.0, 0.5, f64::NAN), "falling");
        assert_eq!(trend(1.0, 1.8, 0.5, 0.5), "flat");
        assert!(tie(0.289, 0.288, 2.0) && !tie(0.3, 0.2, 2.0));
    }
}
