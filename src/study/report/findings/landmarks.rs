//! Findings of the landmark table: the LAT/AP shift ratio per target on its fixed landmark set with
//! its geometric decomposition, and the first target's shifts against the paper's.

use super::claim::{Claim, Finding, Geometry, Op, Source, Stat, Transform, Where};
use super::derive::{Mm, column, count, formula, in_mm, points};
use super::{Inputs, sources};
use crate::study::schema::LandmarkRow;

/// Prints claim `id`'s value again at `decimals` decimals, as the claim `new_id`.
fn again(f: &mut Finding, id: &str, new_id: &str, decimals: usize) -> Option<String> {
    let v = f.value(id)?;
    let c = Claim::new(
        new_id,
        v,
        Source::Formula {
            op: Op::Value,
            of: vec![id.to_string()],
        },
    );
    Some(f.say(c.shown(decimals, "")))
}

/// The ratio finding: per target the measured LAT/AP RMS shift at the largest focal Δf on its fixed
/// set (landmarks measured in both views at every focal Δf), the range over the single levels, each
/// segment apart, and for the first level the decomposition into offset and spread.
pub fn ratio(x: &Inputs) -> Option<Finding> {
    if x.ratios.is_empty() {
        return None;
    }
    let t = &x.landmarks;
    let mut f = Finding::new("landmark_ratio");
    // Per target: RMS shifts, their ratio, and the offset and spread of the reference landmarks.
    let mut measured = Vec::new();
    for r in x.ratios {
        let tg = &r.target;
        let df = r.df_px;
        let at = |view: &str| {
            Where::new()
                .is("target", tg)
                .is("view", view)
                .is("family", "focal")
                .is("df_px", df)
                .any("landmark", &r.landmarks)
        };
        let n = r.landmarks.len();
        for (i, view) in ["ap", "lat"].iter().enumerate() {
            let (v, _, src) = column(t, at(view), "shift_px", Transform::Identity, Stat::Rms)?;
            f.keep(
                Claim::new(format!("ratio.{tg}.rms_{view}"), v, src)
                    .shown(3, "px")
                    .about(tg, view, "focal")
                    .cell("df_px", df)
                    .count(n),
            );
            for g in [Geometry::Offset, Geometry::Spread] {
                let (v, _, src) = points(t, at(view), ["ref_u_px", "ref_v_px"], x.piercing[i], g)?;
                let name = if g == Geometry::Offset {
                    "offset"
                } else {
                    "spread"
                };
                f.keep(
                    Claim::new(format!("ratio.{tg}.{name}_{view}"), v, src)
                        .shown(1, "px")
                        .about(tg, view, "focal")
                        .count(n),
                );
            }
            let d = formula(
                &f,
                &format!("ratio.{tg}.d_{view}"),
                Op::Hypot,
                &[
                    format!("ratio.{tg}.offset_{view}"),
                    format!("ratio.{tg}.spread_{view}"),
                ],
            )?;
            f.keep(d.shown(1, "px").about(tg, view, "focal"));
        }
        let m = formula(
            &f,
            &format!("ratio.{tg}.measured"),
            Op::Ratio,
            &[format!("ratio.{tg}.rms_lat"), format!("ratio.{tg}.rms_ap")],
        )?;
        let p = formula(
            &f,
            &format!("ratio.{tg}.predicted"),
            Op::Ratio,
            &[format!("ratio.{tg}.d_lat"), format!("ratio.{tg}.d_ap")],
        )?;
        f.keep(
            m.shown(3, "")
                .about(tg, "lat/ap", "focal")
                .cell("df_px", df),
        );
        f.keep(p.shown(3, "").about(tg, "lat/ap", "focal"));
        measured.push((r, format!("ratio.{tg}.measured")));
    }
    let (levels, segments): (Vec<_>, Vec<_>) =
        measured.iter().partition(|(r, _)| x.pooled(&r.target));
    let mut s = String::from(
        "Landmark shift under a pure focal error, per target on its fixed landmark set (measured in both \
views at every focal Δf), RMS over the set at the largest Δf: ",
    );
    let show = |c: Option<Claim>, f: &mut Finding, d: usize| c.map(|c| f.say(c.shown(d, "")));
    if levels.len() > 1 {
        let ids: Vec<String> = levels.iter().map(|l| l.1.clone()).collect();
        let names: Vec<String> = levels.iter().map(|l| l.0.target.clone()).collect();
        let lo = show(formula(&f, "ratio.levels.min", Op::Min, &ids), &mut f, 2)?;
        let hi = show(formula(&f, "ratio.levels.max", Op::Max, &ids), &mut f, 2)?;
        let n = f.say(count("ratio.levels", &names));
        s.push_str(&format!("LAT/AP is {lo}–{hi} over the {n} single levels"));
    } else if let Some((r, id)) = levels.first() {
        let m = again(&mut f, id, &format!("{id}.2"), 2)?;
        s.push_str(&format!("LAT/AP is {m} for {}", r.target));
    }
    for (i, (r, id)) in segments.iter().enumerate() {
        let m = again(&mut f, id, &format!("{id}.2"), 2)?;
        let kept = f.say(count(&format!("ratio.{}.kept", r.target), &r.landmarks));
        let all: Vec<String> = r.landmarks.iter().chain(&r.left_out).cloned().collect();
        let total = f.say(count(&format!("ratio.{}.all", r.target), &all));
        let what = if super::is_segment(&r.target) {
            "a segment".to_string()
        } else {
            x.cut_note(&r.target, &[])
                .trim()
                .trim_matches(['(', ')'])
                .to_string()
        };
        s.push_str(&format!(
            "{}{m} for {} ({what}: {kept} of its {total} landmarks measured in every cell)",
            if levels.is_empty() && i == 0 {
                "LAT/AP is "
            } else {
                "; "
            },
            r.target,
        ));
    }
    s.push_str(
        ". The ratio is the geometry's, not the anatomy's response: a focal scale moves a point by \
`(α − 1)·|x − c|`, so the ratio equals that of the landmarks' RMS distances from the piercing point, \
`d = √(o² + s²)`, where o is how far off the piercing point the anatomy sits and s how large it is drawn \
(the table below gives both per view; the predicted ratio multiplies back to the measured one).",
    );
    if let Some((r, _)) = levels.first().or(segments.first()) {
        let tg = &r.target;
        let id = |name: &str| format!("ratio.{tg}.{name}");
        let share = |f: &mut Finding, view: &str, which: usize| {
            let (a, b) = (id(&format!("offset_{view}")), id(&format!("spread_{view}")));
            let of = if which == 0 { [a, b] } else { [b, a] };
            let name = if which == 0 { "offset" } else { "spread" };
            formula(f, &id(&format!("{name}_share_{view}")), Op::SharePct, &of)
                .map(|c| f.say(c.shown(0, "%").about(tg, view, "focal")))
        };
        let copy = |f: &mut Finding, name: &str, d: usize| {
            again(f, &id(name), &id(&format!("{name}.shown")), d)
        };
        let (dl, da) = (copy(&mut f, "d_lat", 1)?, copy(&mut f, "d_ap", 1)?);
        let (ol, sl, oa) = (
            share(&mut f, "lat", 0)?,
            share(&mut f, "lat", 1)?,
            share(&mut f, "ap", 0)?,
        );
        let (p, m) = (copy(&mut f, "predicted", 3)?, copy(&mut f, "measured", 3)?);
        s.push_str(&format!(
            " For {tg}: LAT d = {dl} px, of whose d² the offset is {ol} % and the spread {sl} %; AP d = \
{da} px, the offset {oa} %. So {p} = {dl} / {da} against the measured {m}."
        ));
    }
    f.text = s;
    Some(f)
}

/// The first target's mean shift over the paper's landmarks at focal Δf 100 px against the paper's
/// table (whose Δf the paper does not state).
pub fn versus_paper(x: &Inputs) -> Option<Finding> {
    let t = &x.landmarks;
    let first = x.first;
    let theirs: Vec<String> = x.paper.landmark_shift_px.keys().cloned().collect();
    let matched: Vec<String> = t
        .distinct(&Where::new().is("target", first), "landmark")
        .into_iter()
        .filter(|l| theirs.contains(l))
        .collect();
    if matched.is_empty() {
        return None;
    }
    let mut f = Finding::new("landmarks_versus_paper");
    let mut ours = Vec::new();
    for view in ["ap", "lat"] {
        let (v, n, src) = column(
            t,
            Where::new()
                .is("target", first)
                .is("view", view)
                .is("family", "focal")
                .is("df_px", "100")
                .any("landmark", &matched),
            "shift_px",
            Transform::Identity,
            Stat::Mean,
        )?;
        ours.push(
            f.say(
                Claim::new(format!("landmarks.{first}.{view}.mean"), v, src)
                    .shown(2, "px")
                    .about(first, view, "focal")
                    .cell("df_px", 100.0)
                    .count(n),
            ),
        );
    }
    let mut paper = Vec::new();
    for (i, view) in ["ap", "lat"].iter().enumerate() {
        paper.push(
            f.say(
                Claim::new(
                    format!("paper.landmark_shift_px.{view}.mean"),
                    x.paper.mean_landmark_shift(i),
                    Source::Paper {
                        key: "landmark_shift_px".into(),
                        index: Some(i),
                        mean_over_entries: true,
                    },
                )
                .shown(2, "px")
                .count(theirs.len()),
            ),
        );
    }
    let mm = in_mm(&mut f, x, "landmarks_versus_paper.df_mm", 100.0, Mm::Sdd);
    let k = f.say(count("landmarks.matched", &matched));
    let n = f.say(count("landmarks.paper", &theirs));
    f.text = format!(
        "Over the {k} of the paper's {n} landmarks that {first} has, at focal Δf 100 px{mm} our mean shift is \
AP {} px, LAT {} px; the paper's table gives AP {}, LAT {} px (mean of all its landmarks) without stating \
its Δf (and its text disagrees with its table), so only the LAT > AP ordering is comparable {}.",
        ours[0],
        ours[1],
        paper[0],
        paper[1],
        sources::<LandmarkRow>(&format!("landmark_overlay_{first}_lat.png"))
    );
    Some(f)
}
