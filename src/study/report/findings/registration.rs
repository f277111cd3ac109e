//! Findings of the registration summary: each method's error per perturbation family at its largest
//! step (single levels as a range, single-view AP against LAT), and the first target's ranges and
//! trends against the paper's.

use super::claim::{Claim, Finding, Source, Stat, Table, Transform, Where};
use super::derive::{Mm, column, count, count_greater, in_mm, interval, mm_claim, trend};
use super::{Inputs, sources};
use crate::study::schema::RegistrationSummaryRow;

/// The grid's values of `col` (as cell text), ascending.
fn grid(t: &Table, col: &str) -> Vec<String> {
    let mut v: Vec<(f64, String)> = t
        .distinct(&Where::new(), col)
        .into_iter()
        .filter_map(|s| Some((s.parse().ok()?, s)))
        .collect();
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    v.into_iter().map(|x| x.1).collect()
}

/// The range of `col` for `method` over the rows of `at` (its min and max claims, printed as `a–b`), or
/// the one value when `at` holds one target; `unit` follows.
fn range(
    f: &mut Finding,
    t: &Table,
    at: &Where,
    id: &str,
    (method, col, unit): (&str, &str, &'static str),
    (target, family): (&str, &str),
) -> Option<String> {
    let w = at.clone().is("method", method);
    let cells: Vec<(String, f64)> =
        w.0.iter()
            .filter(|(k, v)| (k.as_str() == "df_px" || k.as_str() == "piercing_px") && v.len() == 1)
            .filter_map(|(k, v)| Some((k.clone(), v[0].parse().ok()?)))
            .collect();
    let mut one = |stat: Stat, name: &str| {
        let (v, n, src) = column(t, w.clone(), col, Transform::Identity, stat)?;
        let mut c = Claim::new(format!("{id}.{method}.{col}.{name}"), v, src)
            .shown(3, unit)
            .about(target, method, family)
            .count(n);
        for (k, x) in &cells {
            c = c.cell(k, *x);
        }
        Some(f.say(c))
    };
    let u = spaced(unit);
    if t.distinct(&w, "target").len() == 1 {
        return Some(format!("{}{u}", one(Stat::Value, "value")?));
    }
    Some(format!(
        "{}–{}{u}",
        one(Stat::Min, "min")?,
        one(Stat::Max, "max")?
    ))
}

/// Registration error at each family's largest step: Kabsch and two-view direct as ranges over the
/// single levels (a level the detector's edge cuts among them: the trials observe the landmarks
/// analytically), and single-view translation AP against LAT with the direction per level.
pub fn by_family(x: &Inputs) -> Option<Finding> {
    let t = &x.registration;
    let (dfs, ps) = (grid(t, "df_px"), grid(t, "piercing_px"));
    // Each family's largest step is the grid value farthest from 0; "alone" holds the other at 0.
    let top = |g: &[String]| {
        g.iter()
            .max_by(|a, b| {
                let v = |x: &String| x.parse::<f64>().map_or(0.0, f64::abs);
                v(a).total_cmp(&v(b))
            })
            .cloned()
    };
    let (df_top, p_top) = (top(&dfs)?, top(&ps)?);
    let zero_of = |g: &[String]| g.iter().find(|v| v.parse::<f64>() == Ok(0.0)).cloned();
    let (df_zero, p_zero) = (zero_of(&dfs), zero_of(&ps));
    let (levels, _) = x.split_segments(t.distinct(&Where::new(), "target"));
    if levels.is_empty() {
        return None;
    }
    let methods = t.distinct(&Where::new(), "method");
    let has = |m: &str| methods.iter().any(|x| x == m);
    let mut f = Finding::new("registration_by_family");
    let mut families = Vec::new();
    let (df_v, p_v) = (
        df_top.parse::<f64>().unwrap_or(f64::NAN),
        p_top.parse::<f64>().unwrap_or(f64::NAN),
    );
    let (df_mm, p_mm) = (
        in_mm(&mut f, x, "registration.df_mm", df_v, Mm::Sdd),
        in_mm(&mut f, x, "registration.p_mm", p_v, Mm::Detector),
    );
    if let Some(p0) = p_zero.filter(|_| df_top != "0") {
        families.push((
            "focal",
            "a focal error alone",
            format!("Δf = {df_top} px{df_mm}"),
            df_top.clone(),
            p0,
        ));
    }
    if let Some(d0) = df_zero.filter(|_| p_top != "0") {
        families.push((
            "piercing",
            "a piercing shift alone",
            format!("piercing ({p_top}, {p_top}) px{p_mm}"),
            d0,
            p_top.clone(),
        ));
    }
    if df_top != "0" && p_top != "0" {
        families.push((
            "joint",
            "both together",
            format!("Δf = {df_top} px{df_mm} with piercing ({p_top}, {p_top}) px{p_mm}"),
            df_top.clone(),
            p_top.clone(),
        ));
    }
    let mut parts = Vec::new();
    for (family, what, cell, df, p) in families {
        let at = Where::new()
            .is("df_px", &df)
            .is("piercing_px", &p)
            .any("target", &levels);
        let id = format!("registration.{family}");
        let joined = levels.join(",");
        let who = (joined.as_str(), family);
        let mut said = Vec::new();
        // Kabsch and the two-view direct solver, and the single views' translations side by side; a run
        // with none of those (one view, say) states each of its methods instead.
        let featured = ["kabsch", "direct-ap+lat"];
        let paired = has("direct-ap") && has("direct-lat");
        let shown: Vec<&str> = if featured.iter().any(|m| has(m)) || paired {
            featured.to_vec()
        } else {
            methods.iter().map(String::as_str).collect()
        };
        for &m in &shown {
            if !has(m) {
                continue;
            }
            let r = range(&mut f, t, &at, &id, (m, "rot_err_deg_mean", "°"), who)?;
            let tr = range(&mut f, t, &at, &id, (m, "trans_err_mm_mean", "mm"), who)?;
            said.push(format!("{m} {r} and {tr}"));
        }
        if paired {
            let a = range(
                &mut f,
                t,
                &at,
                &id,
                ("direct-ap", "trans_err_mm_mean", "mm"),
                who,
            )?;
            let l = range(
                &mut f,
                t,
                &at,
                &id,
                ("direct-lat", "trans_err_mm_mean", "mm"),
                who,
            )?;
            let mut pairs = Vec::new();
            for level in &levels {
                let mut one = |m: &str| {
                    let w = at.clone().is("target", level).is("method", m);
                    let (v, _, src) =
                        column(t, w, "trans_err_mm_mean", Transform::Identity, Stat::Value)?;
                    let cid = format!("{id}.{level}.{m}.trans");
                    f.keep(Claim::new(&cid, v, src).about(level, m, family));
                    Some(cid)
                };
                if let (Some(a), Some(l)) = (one("direct-ap"), one("direct-lat")) {
                    pairs.push([a, l]);
                }
            }
            let n = pairs.len();
            let swapped: Vec<[String; 2]> =
                pairs.iter().map(|[a, l]| [l.clone(), a.clone()]).collect();
            let lat = count_greater(&f, &format!("{id}.lat_smaller"), pairs.clone(), 3);
            let ap = count_greater(&f, &format!("{id}.ap_smaller"), swapped, 3);
            let (kl, ka) = (lat.value as usize, ap.value as usize);
            let (lat, ap) = (f.say(lat), f.say(ap));
            let every = if n == 1 { "" } else { " in every level" };
            let direction = if kl == n {
                format!("LAT smaller{every}")
            } else if ka == n {
                format!("AP smaller{every}")
            } else if kl + ka == 0 {
                format!("alike at the printed precision{every}")
            } else {
                let equal = if kl + ka < n {
                    ", equal at the printed precision in the others"
                } else {
                    ""
                };
                format!("LAT smaller in {lat} of them, AP in {ap}{equal}")
            };
            said.push(format!(
                "single-view translation direct-ap {a} against direct-lat {l}, {direction}"
            ));
        }
        parts.push(format!("under {what}, {cell}: {}", said.join("; ")));
    }
    if parts.is_empty() {
        return None;
    }
    let sigma = f.say(
        Claim::new(
            "registration.noise_px",
            x.noise_px,
            Source::Config {
                key: "registration.noise_px".into(),
            },
        )
        .shown(decimals(x.noise_px), "px"),
    );
    let over = if levels.len() == 1 {
        format!("for {}", levels[0])
    } else {
        format!(
            "a range over the {} single levels",
            f.say(count("registration.levels", &levels))
        )
    };
    f.text = format!(
        "Registration error at each family's largest step, as the mean over a cell's trials (landmarks \
observed with Gaussian noise σ = {sigma} px), {over}: {} {}; each cell's confidence interval is in the \
registration section.",
        parts.join("; "),
        sources::<RegistrationSummaryRow>(&format!("registration_{}_rot.png", x.first))
    );
    Some(f)
}

/// A unit after a number: degrees close up, others after a space.
fn spaced(unit: &str) -> String {
    if unit == "°" {
        unit.into()
    } else {
        format!(" {unit}")
    }
}

/// The fewest decimals (at most 3) that print `v` exactly.
fn decimals(v: f64) -> usize {
    (0..=3)
        .find(|&d| format!("{v:.d$}").parse::<f64>() == Ok(v))
        .unwrap_or(3)
}

/// The paper's four ranges: (method, column, paper key, what).
const PAPER: [(&str, &str, &str, &str, &str); 4] = [
    (
        "kabsch",
        "rot_err_deg_mean",
        "registration.kabsch_rotation_deg",
        "rotation",
        "°",
    ),
    (
        "kabsch",
        "trans_err_mm_mean",
        "registration.kabsch_translation_mm",
        "translation",
        "mm",
    ),
    (
        "direct-ap+lat",
        "rot_err_deg_mean",
        "registration.direct_rotation_deg",
        "rotation",
        "°",
    ),
    (
        "direct-ap+lat",
        "trans_err_mm_mean",
        "registration.direct_translation_mm",
        "translation",
        "mm",
    ),
];

/// The first target's ranges over Δf > 0 and every piercing shift against the paper's (inside,
/// overlapping or outside), and each error's trend with Δf per piercing shift against the paper's.
pub fn versus_paper(x: &Inputs) -> Option<Finding> {
    let t = &x.registration;
    let first = x.first;
    let nonzero: Vec<String> = grid(t, "df_px")
        .into_iter()
        .filter(|v| v.parse::<f64>().is_ok_and(|d| d > 0.0))
        .collect();
    let ps = grid(t, "piercing_px");
    if nonzero.is_empty() {
        return None;
    }
    let at = Where::new().is("target", first).any("df_px", &nonzero);
    let mut f = Finding::new("registration_versus_paper");
    let span = |f: &mut Finding, col: &str| {
        let mut one = |stat: Stat, name: &str| {
            let (v, _, src) = column(t, at.clone(), col, Transform::Identity, stat)?;
            Some(
                f.say(
                    Claim::new(format!("registration.span.{col}.{name}"), v, src)
                        .shown(decimals(v), "px"),
                ),
            )
        };
        Some((one(Stat::Min, "min")?, one(Stat::Max, "max")?))
    };
    let (d0, d1) = span(&mut f, "df_px")?;
    let (p0, p1) = span(&mut f, "piercing_px")?;
    // The spans in mm at this detector (the paper's px are at its own, unstated, detector).
    let mm = match &x.pitch {
        Some((reference, pitch)) => {
            let mut m = |col: &str, name: &str| {
                let v = f
                    .value(&format!("registration.span.{col}.{name}"))
                    .unwrap_or(f64::NAN);
                f.say(mm_claim(
                    &format!("registration.span.{col}.{name}_mm"),
                    v,
                    *pitch,
                    reference,
                ))
            };
            let (a, b, c, d) = (
                m("df_px", "min"),
                m("df_px", "max"),
                m("piercing_px", "min"),
                m("piercing_px", "max"),
            );
            format!(" (SDD errors of {a}–{b} mm, {c}–{d} mm along u and v on the detector)")
        }
        None => String::new(),
    };
    let paper_trend = &x.paper.registration.trend_with_df;
    let g = &x.paper.geometry;
    let mut span_paper = Vec::new();
    for (key, list) in [
        ("geometry.focal_perturbation_px", &g.focal_perturbation_px),
        (
            "geometry.piercing_perturbation_px",
            &g.piercing_perturbation_px,
        ),
    ] {
        for index in [0, list.len().saturating_sub(1)] {
            let v = *list.get(index)?;
            span_paper.push(
                f.say(
                    Claim::new(
                        format!("paper.{key}.{index}"),
                        v,
                        Source::Paper {
                            key: key.into(),
                            index: Some(index),
                            mean_over_entries: false,
                        },
                    )
                    .shown(decimals(v), "px"),
                ),
            );
        }
    }
    let said_trend = f.fact(
        "paper.registration.trend_with_df",
        paper_trend,
        "paper",
        vec!["registration.trend_with_df".into()],
    );
    let mut parts = Vec::new();
    for (m, col, key, what, unit) in PAPER {
        let r = &x.paper.registration;
        let theirs = match key {
            "registration.kabsch_rotation_deg" => r.kabsch_rotation_deg,
            "registration.kabsch_translation_mm" => r.kabsch_translation_mm,
            "registration.direct_rotation_deg" => r.direct_rotation_deg,
            _ => r.direct_translation_mm,
        };
        let id = format!("registration.{first}.{m}.{col}");
        let mut ours = Vec::new();
        for (stat, name) in [(Stat::Min, "min"), (Stat::Max, "max")] {
            let Some((v, n, src)) = column(
                t,
                at.clone().is("method", m),
                col,
                Transform::Identity,
                stat,
            ) else {
                break;
            };
            ours.push((
                format!("{id}.{name}"),
                v,
                f.say(
                    Claim::new(format!("{id}.{name}"), v, src)
                        .shown(3, unit)
                        .about(first, m, "focal,joint")
                        .count(n),
                ),
            ));
        }
        let [(lo_id, lo, lo_s), (hi_id, hi, hi_s)] = <[_; 2]>::try_from(ours).ok()?;
        let mut paper = Vec::new();
        for (i, &value) in theirs.iter().enumerate() {
            let pid = format!("paper.{key}.{i}");
            paper.push((
                pid.clone(),
                f.say(
                    Claim::new(
                        &pid,
                        value,
                        Source::Paper {
                            key: key.into(),
                            index: Some(i),
                            mean_over_entries: false,
                        },
                    )
                    .shown(decimals(value), unit),
                ),
            ));
        }
        let verdict = f.fact(
            &format!("{id}.interval"),
            interval(lo, hi, theirs[0], theirs[1]),
            "interval",
            vec![lo_id, hi_id, paper[0].0.clone(), paper[1].0.clone()],
        );
        // The trend with Δf at each piercing shift: the smallest against the largest Δf > 0.
        let ci = col.replace("_mean", "_ci95");
        let (d_first, d_last) = (nonzero.first()?, nonzero.last()?);
        let mut facts = Vec::new();
        for p in &ps {
            let mut ids = Vec::new();
            let mut values = Vec::new();
            for (d, c) in [
                (d_first, col),
                (d_last, col),
                (d_first, ci.as_str()),
                (d_last, ci.as_str()),
            ] {
                let w = Where::new()
                    .is("target", first)
                    .is("method", m)
                    .is("df_px", d)
                    .is("piercing_px", p);
                let rows = t.select(&w);
                let (Some(&i), 1) = (rows.first(), rows.len()) else {
                    break;
                };
                let v = t.number(i, c);
                let cid = format!("{id}.p{p}.df{d}.{c}");
                f.keep(
                    Claim::new(
                        &cid,
                        v,
                        Source::Column {
                            table: t.file(),
                            column: c.into(),
                            transform: Transform::Identity,
                            stat: Stat::Value,
                            filter: w,
                            rows,
                        },
                    )
                    .about(first, m, "focal,joint"),
                );
                ids.push(cid);
                values.push(v);
            }
            if let [a, b, ca, cb] = values[..] {
                let fid = format!("{id}.p{p}.trend");
                f.fact(&fid, trend(a, b, ca, cb), "trend", ids);
                facts.push(fid);
            }
        }
        let mut counts = Vec::new();
        for word in ["rising", "falling", "flat"] {
            let k = facts
                .iter()
                .filter(|id| f.facts.iter().any(|x| &x.id == *id && x.word == word))
                .count();
            if k == 0 {
                continue;
            }
            let said = f.say(
                Claim::new(
                    format!("{id}.{word}"),
                    k as f64,
                    Source::CountWord {
                        facts: facts.clone(),
                        word: word.into(),
                    },
                )
                .count(facts.len()),
            );
            counts.push(format!("{word} at {said}"));
        }
        let (u, (p_lo, p_hi)) = (spaced(unit), (&paper[0].1, &paper[1].1));
        let shifts = f.say(count(&format!("{id}.trends"), &facts));
        parts.push(format!(
            "{m} {what} {lo_s}–{hi_s}{u} against the paper's {p_lo}–{p_hi}{u} ({verdict}); from Δf \
{d_first} to {d_last} px it is {} of the {shifts} piercing shifts",
            counts.join(", ")
        ));
    }
    f.text = format!(
        "Registration of {first} against the paper, over Δf {d0}–{d1} px and piercing {p0}–{p1} px{mm} (the \
paper's ranges span Δf {}–{} px and piercing {}–{} px), by interval (inside, overlapping or outside the \
paper's range) and by trend (the paper reports each error {said_trend} with Δf; ours is called rising or \
falling when the change exceeds the two cells' confidence intervals together, else flat): {}. Our trials observe synthetic landmarks through the \
true K and solve with the perturbed one, so the error is the calibration error's own; a piercing shift of \
p px moves the solution sideways by about `z·p/f`, which dominates our translation ranges {}.",
        span_paper[0],
        span_paper[1],
        span_paper[2],
        span_paper[3],
        parts.join("; "),
        sources::<RegistrationSummaryRow>(&format!("registration_{first}_trans.png"))
    );
    Some(f)
}
