//! Findings of the projection tables: silhouette loss per perturbation family, the most and least
//! sensitive structures, and the first target's Dice against the paper's.

use super::claim::{Claim, Finding, Source, Stat, Table, Transform, Where};
use super::derive::{Mm, column, count, count_greater, greater, in_mm, mm_claim, tie};
use super::{Inputs, is_segment, sources};
use crate::study::schema::{ProjectionRow, StructureRow};

/// A perturbation family as the Dice finding names it: (family, wording, the column of its step and
/// whether its largest step is the largest |x − 1| rather than the largest x).
const FAMILIES: [(&str, &str, &str, bool); 5] = [
    ("focal", "a focal error alone", "df_px", false),
    ("piercing", "a piercing shift alone", "dcx_px", false),
    ("joint", "the paper's joint schedule", "df_px", false),
    ("skew", "a skew alone", "skew_px", false),
    ("scale", "a pixel-spacing error alone", "sy", true),
];

/// The family's largest step: the cell text of `col` farthest from 0 (or from 1 when `about_one`).
fn largest_step(t: &Table, family: &str, col: &str, about_one: bool) -> Option<String> {
    let base = if about_one { 1.0 } else { 0.0 };
    t.distinct(&Where::new().is("family", family), col)
        .into_iter()
        .filter_map(|v| Some((v.parse::<f64>().ok()?, v)))
        .max_by(|a, b| (a.0 - base).abs().total_cmp(&(b.0 - base).abs()))
        .map(|(_, v)| v)
}

/// The silhouette loss `1 − Dice` of `target` in `view` in the cell `at` (one row).
fn loss(t: &Table, at: &Where, target: &str, view: &str) -> Option<(f64, Source)> {
    let w = at.clone().is("view", view).is("target", target);
    column(t, w, "dice", Transform::OneMinus, Stat::Value).map(|(v, _, src)| (v, src))
}

/// Silhouette loss 1 − Dice per perturbation family at its largest step, both views: the single levels
/// as a range, which view loses more in how many of them, and each segment apart (flagged when cut by
/// the detector edge).
pub fn dice_by_family(x: &Inputs) -> Option<Finding> {
    let t = &x.projection;
    let mut f = Finding::new("dice_by_family");
    let mut parts = Vec::new();
    for (family, what, col, about_one) in FAMILIES {
        let Some(top) = largest_step(t, family, col, about_one) else {
            continue;
        };
        let at = Where::new().is("family", family).is(col, &top);
        let (levels, segments) = x.split_targets(t.distinct(&at, "target"));
        let step: f64 = top.parse().unwrap_or(f64::NAN);
        let cell = |c: Claim| match family {
            "piercing" => c.cell("dcx_px", step).cell("dcy_px", step),
            "joint" => {
                let p = t.number(t.select(&at)[0], "dcx_px");
                c.cell("df_px", step).cell("dcx_px", p).cell("dcy_px", p)
            }
            _ => c.cell(col, step),
        };
        let id = |what: &str| format!("dice.{family}.{what}_mm");
        let where_ = match family {
            "piercing" => format!(
                "piercing ({top}, {top}) px{}",
                in_mm(&mut f, x, &id("p"), step, Mm::Detector)
            ),
            "joint" => {
                let p = t.number(t.select(&at)[0], "dcx_px");
                format!(
                    "Δf = {top} px{} with piercing ({p}, {p}) px{}",
                    in_mm(&mut f, x, &id("df"), step, Mm::Sdd),
                    in_mm(&mut f, x, &id("p"), p, Mm::Detector)
                )
            }
            "skew" => format!("skew {top} px"),
            "scale" => format!("pixel scale sy = {top}"),
            _ => format!(
                "Δf = {top} px{}",
                in_mm(&mut f, x, &id("df"), step, Mm::Sdd)
            ),
        };
        let mut text = format!("Under {what}, {where_},");
        if let [level] = &levels[..] {
            let mut one = |view: &str| {
                let (v, src) = loss(t, &at, level, view)?;
                Some((
                    v,
                    f.say(
                        cell(Claim::new(format!("dice.{family}.{level}.{view}"), v, src))
                            .shown(3, "")
                            .about(level, view, family),
                    ),
                ))
            };
            let (Some(ap), Some(lat)) = (one("ap"), one("lat")) else {
                continue;
            };
            let more = if greater(lat.0, ap.0, 3) {
                "LAT loses more"
            } else if greater(ap.0, lat.0, 3) {
                "AP loses more"
            } else {
                "AP and LAT alike at the printed precision"
            };
            text.push_str(&format!(
                " {level} loses AP {}, LAT {}: {more}",
                ap.1, lat.1
            ));
        } else if !levels.is_empty() {
            let mut range = |view: &str, stat: Stat| {
                let (v, n, src) = column(
                    t,
                    at.clone().is("view", view).any("target", &levels),
                    "dice",
                    Transform::OneMinus,
                    stat,
                )?;
                let name = if stat == Stat::Min { "min" } else { "max" };
                Some(
                    f.say(
                        cell(Claim::new(
                            format!("dice.{family}.levels.{view}.{name}"),
                            v,
                            src,
                        ))
                        .shown(3, "")
                        .about(&levels.join(","), view, family)
                        .count(n),
                    ),
                )
            };
            let (Some(ap0), Some(ap1), Some(lat0), Some(lat1)) = (
                range("ap", Stat::Min),
                range("ap", Stat::Max),
                range("lat", Stat::Min),
                range("lat", Stat::Max),
            ) else {
                continue;
            };
            let mut pairs = Vec::new();
            for level in &levels {
                let mut one = |view: &str| {
                    let (v, src) = loss(t, &at, level, view)?;
                    let id = format!("dice.{family}.{level}.{view}");
                    f.keep(cell(Claim::new(&id, v, src)).about(level, view, family));
                    Some((id, v))
                };
                if let (Some(ap), Some(lat)) = (one("ap"), one("lat")) {
                    pairs.push((ap, lat));
                }
            }
            let n = f.say(count(&format!("dice.{family}.levels"), &levels));
            let ids = |first: bool| -> Vec<[String; 2]> {
                pairs
                    .iter()
                    .map(|(a, l)| {
                        if first {
                            [l.0.clone(), a.0.clone()]
                        } else {
                            [a.0.clone(), l.0.clone()]
                        }
                    })
                    .collect()
            };
            let lat = count_greater(&f, &format!("dice.{family}.lat_more"), ids(true), 3).about(
                &levels.join(","),
                "lat>ap",
                family,
            );
            let ap = count_greater(&f, &format!("dice.{family}.ap_more"), ids(false), 3).about(
                &levels.join(","),
                "ap>lat",
                family,
            );
            let (kl, ka) = (lat.value as usize, ap.value as usize);
            let (lat, ap) = (f.say(lat), f.say(ap));
            let m = pairs.len();
            let direction = if kl == m {
                "LAT loses more in every level".to_string()
            } else if ka == m {
                "AP loses more in every level".to_string()
            } else if kl + ka == 0 {
                "AP and LAT alike (equal at the printed precision) in every level".to_string()
            } else {
                let equal = if kl + ka < m {
                    ", equal at the printed precision in the others"
                } else {
                    ""
                };
                format!("LAT loses more in {lat} of {n} levels, AP in {ap}{equal}")
            };
            let span = |a: String, b: String| if a == b { a } else { format!("{a}–{b}") };
            let (ap_r, lat_r) = (span(ap0, ap1), span(lat0, lat1));
            text.push_str(&format!(
                " the {n} single levels lose AP {ap_r}, LAT {lat_r}: {direction}"
            ));
        }
        // The targets reported apart follow the single levels' clause, or open the sentence without one.
        let opened = text.len();
        let mut sep = if levels.is_empty() { " " } else { "; " };
        for s in &segments {
            let mut one = |view: &str| {
                let (v, src) = loss(t, &at, s, view)?;
                Some(
                    f.say(
                        cell(Claim::new(format!("dice.{family}.{s}.{view}"), v, src))
                            .shown(3, "")
                            .about(s, view, family),
                    ),
                )
            };
            if let (Some(ap), Some(lat)) = (one("ap"), one("lat")) {
                let flag = x.cut_note(s, &t.select(&at.clone().is("target", s)));
                text.push_str(&format!("{sep}{s} AP {ap}, LAT {lat}{flag}"));
                sep = "; ";
            }
        }
        if levels.is_empty() && text.len() == opened {
            continue;
        }
        parts.push(text);
    }
    if parts.is_empty() {
        return None;
    }
    f.text = format!(
        "Silhouette loss `1 − Dice`, per family at its largest step. {} {}.",
        parts.join(". "),
        sources::<ProjectionRow>("dice_vs_perturbation.png")
    );
    Some(f)
}

/// The tie tolerance of the structure finding (%): a mirror pair such as the two pedicles differs only
/// by the pixel grid.
const TIE_PCT: f64 = 2.0;

/// The most and least sensitive structures at the largest focal Δf: mean 1 − Dice over the single levels
/// (or, without any, the targets reported apart: segments and cut targets) and the views the rows have.
pub fn structures(x: &Inputs) -> Option<Finding> {
    let t = &x.structures;
    let top = largest_step(t, "focal", "df_px", false)?;
    let at = Where::new().is("family", "focal").is("df_px", &top);
    let (levels, segments) = x.split_targets(t.distinct(&at, "target"));
    // Levels the detector's edge cuts in some cell are left out of the levels' means, and said so.
    let left_out = match segments
        .iter()
        .filter(|t| !is_segment(t))
        .collect::<Vec<_>>()
    {
        cut if levels.is_empty() || cut.is_empty() => String::new(),
        cut => {
            let names: Vec<&str> = cut.iter().map(|t| t.as_str()).collect();
            let names = match names.split_last() {
                Some((last, rest)) if !rest.is_empty() => format!("{} and {last}", rest.join(", ")),
                _ => names.join(""),
            };
            let verb = if cut.len() == 1 { "is" } else { "are" };
            format!(
                "; {names}, cut by the detector edge in some cell, {verb} left out of the means"
            )
        }
    };
    let (targets, over) = if levels.is_empty() {
        (segments, "the targets reported apart")
    } else {
        (levels, "the single levels")
    };
    let at = at.any("target", &targets);
    let df: f64 = top.parse().ok()?;
    // The views the mean runs over, as the rows have them.
    let views = t.distinct(&at, "view");
    let over_views = match views.as_slice() {
        [one] => format!("the {} view", one.to_uppercase()),
        [_, _] => "both views".to_string(),
        more => format!("the {} views", more.len()),
    };
    let mut f = Finding::new("structures");
    let mut loss: Vec<(String, f64, Claim)> = t
        .distinct(&at, "structure")
        .into_iter()
        .filter_map(|s| {
            let (v, n, src) = column(
                t,
                at.clone().is("structure", &s),
                "dice",
                Transform::OneMinus,
                Stat::Mean,
            )?;
            let c = Claim::new(format!("structure.{s}"), v, src)
                .shown(3, "")
                .about(&targets.join(","), &views.join(","), "focal")
                .cell("df_px", df)
                .count(n);
            Some((s, v, c))
        })
        .collect();
    loss.sort_by(|a, b| b.1.total_cmp(&a.1));
    let (most, least) = (loss.first()?.1, loss.last()?.1);
    let tol = f.say(Claim::new(
        "tie_pct",
        TIE_PCT,
        Source::Rule {
            name: "tie_pct".into(),
        },
    ));
    let tied = |v: f64, extreme: f64| tie(v, extreme, TIE_PCT);
    let top_set: Vec<usize> = (0..loss.len()).filter(|&i| tied(loss[i].1, most)).collect();
    let bottom: Vec<usize> = (0..loss.len())
        .filter(|&i| tied(loss[i].1, least))
        .collect();
    let first = targets.first()?.clone();
    let fig = format!("structures_dice_{first}.png");
    let df_text = format!(
        "{top} px{}",
        in_mm(&mut f, x, "structures.df_mm", df, Mm::Sdd)
    );
    if top_set.len() == loss.len() {
        let (lo, hi) = (
            f.say(loss[loss.len() - 1].2.clone()),
            f.say(loss[0].2.clone()),
        );
        f.fact(
            "structures.all_tied",
            "tied",
            "tie",
            vec![
                loss[0].2.id.clone(),
                loss[loss.len() - 1].2.id.clone(),
                "tie_pct".into(),
            ],
        );
        f.text = format!(
            "At focal Δf {df_text} every structure loses alike (mean `1 − Dice` over {over} and \
{over_views} {lo}–{hi}, within {tol} % of each other){left_out} {}.",
            sources::<StructureRow>(&fig)
        );
        return Some(f);
    }
    let group = |idx: &[usize], f: &mut Finding, name: &str| {
        let names: Vec<&str> = idx.iter().map(|&i| loss[i].0.as_str()).collect();
        let values: Vec<String> = idx.iter().map(|&i| f.say(loss[i].2.clone())).collect();
        if idx.len() > 1 {
            for &i in &idx[1..] {
                f.fact(
                    &format!("structures.{name}.tie.{}", loss[i].0),
                    "tied",
                    "tie",
                    vec![
                        loss[idx[0]].2.id.clone(),
                        loss[i].2.id.clone(),
                        "tie_pct".into(),
                    ],
                );
            }
        }
        let note = if idx.len() > 1 {
            format!(", tied within {tol} %")
        } else {
            String::new()
        };
        (names.join(" and "), values.join(" and "), note)
    };
    let (top_names, top_values, top_note) = group(&top_set, &mut f, "most");
    let (low_names, low_values, low_note) = group(&bottom, &mut f, "least");
    f.text = format!(
        "At focal Δf {df_text} the most sensitive structure{} {top_names} (mean `1 − Dice` over \
{over} and {over_views} {top_values}{top_note}) and the least sensitive {low_names} \
({low_values}{low_note}){left_out} {}.",
        if top_set.len() > 1 { "s are" } else { " is" },
        sources::<StructureRow>(&fig)
    );
    Some(f)
}

/// The first target's LAT Dice at focal Δf 100 and 500 px and its smallest AP Dice over the joint
/// schedule, against the paper's.
pub fn versus_paper(x: &Inputs) -> Option<Finding> {
    let t = &x.projection;
    let first = x.first;
    let mut f = Finding::new("dice_versus_paper");
    let lat = |f: &mut Finding, df: &str| {
        let (v, _, src) = column(
            t,
            Where::new()
                .is("target", first)
                .is("view", "lat")
                .is("family", "focal")
                .is("df_px", df),
            "dice",
            Transform::Identity,
            Stat::Value,
        )?;
        Some(
            f.say(
                Claim::new(format!("dice.{first}.lat.focal.df{df}"), v, src)
                    .shown(3, "")
                    .about(first, "lat", "focal")
                    .cell("df_px", df.parse().unwrap_or(f64::NAN)),
            ),
        )
    };
    let (a, b) = (lat(&mut f, "100")?, lat(&mut f, "500")?);
    let mm = match &x.pitch {
        Some((reference, pitch)) => {
            let (m100, m500) = (
                f.say(mm_claim(
                    "dice_versus_paper.df100_mm",
                    100.0,
                    *pitch,
                    reference,
                )),
                f.say(mm_claim(
                    "dice_versus_paper.df500_mm",
                    500.0,
                    *pitch,
                    reference,
                )),
            );
            format!(" (SDD errors of {m100} / {m500} mm)")
        }
        None => String::new(),
    };
    let paper = |f: &mut Finding, key: &str, v: f64| {
        f.say(
            Claim::new(
                format!("paper.{key}"),
                v,
                Source::Paper {
                    key: key.into(),
                    index: None,
                    mean_over_entries: false,
                },
            )
            .shown(3, ""),
        )
    };
    let s = &x.paper.silhouette;
    let (pa, pb) = (
        paper(
            &mut f,
            "silhouette.lat_dice.at_df_100",
            s.lat_dice.at_df_100,
        ),
        paper(
            &mut f,
            "silhouette.lat_dice.at_df_500",
            s.lat_dice.at_df_500,
        ),
    );
    let min = column(
        t,
        Where::new()
            .is("target", first)
            .is("view", "ap")
            .is("family", "joint"),
        "dice",
        Transform::Identity,
        Stat::Min,
    )
    .map(|(v, n, src)| {
        f.say(
            Claim::new(format!("dice.{first}.ap.joint.min"), v, src)
                .shown(3, "")
                .about(first, "ap", "joint")
                .count(n),
        )
    });
    let pmin = paper(&mut f, "silhouette.ap_dice_min", s.ap_dice_min);
    let ap = min.map_or(String::new(), |m| {
        format!(", and the smallest AP Dice over the joint schedule {m} against its > {pmin}")
    });
    f.text = format!(
        "{first} LAT Dice at focal Δf 100 / 500 px{mm} is {a} / {b} against the paper's {pa} / {pb}{ap}: a \
focal change scales the silhouette about the piercing point by `(f + Δf)/f`, so overlap falls in every \
view; the paper's near-unity AP Dice cannot come from this pinhole model, and we report what the model gives \
{}.",
        sources::<ProjectionRow>("dice_vs_perturbation.png")
    );
    Some(f)
}
