//! Figures (plotters, bitmap backend, embedded DejaVu Sans): line charts with labelled axes and legends,
//! drawn from the assembled CSV tables and written atomically as PNG.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::OnceLock;

use plotters::prelude::*;

use super::tables::Table;
use crate::io::write_atomic_bytes;
use crate::{Error, Result};

const FONT: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");
const SIZE: (u32, u32) = (900, 600);

/// One labelled line of a chart.
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
}

fn plot_err(e: impl std::fmt::Display) -> Error {
    Error::External {
        library: "plotters",
        message: e.to_string(),
    }
}

fn register_font() -> Result<()> {
    static DONE: OnceLock<std::result::Result<(), String>> = OnceLock::new();
    DONE.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, FONT)
            .map_err(|_| "the embedded font does not parse".to_string())
    })
    .clone()
    .map_err(plot_err)
}

/// Draws `series` as a line chart and writes it to `path` (PNG).
pub fn line_chart(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
) -> Result<()> {
    register_font()?;
    let pts = series
        .iter()
        .flat_map(|s| s.points.iter())
        .filter(|p| p.0.is_finite() && p.1.is_finite());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in pts {
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
    }
    if x0 > x1 {
        (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
    }
    let pad = |a: f64, b: f64| {
        if b - a > 1e-12 {
            (b - a) * 0.05
        } else {
            a.abs().max(1.0) * 0.05
        }
    };
    let (px, py) = (pad(x0, x1), pad(y0, y1));
    let mut buf = vec![0u8; (SIZE.0 * SIZE.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 24))
            .margin(15)
            .x_label_area_size(50)
            .y_label_area_size(80)
            .build_cartesian_2d((x0 - px)..(x1 + px), (y0 - py)..(y1 + py))
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(y_label)
            .label_style(("sans-serif", 16))
            .draw()
            .map_err(plot_err)?;
        for (i, s) in series.iter().enumerate() {
            let colour = Palette99::pick(i).to_rgba();
            let pts: Vec<(f64, f64)> = s
                .points
                .iter()
                .copied()
                .filter(|p| p.0.is_finite() && p.1.is_finite())
                .collect();
            chart
                .draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))
                .map_err(plot_err)?
                .label(s.label.clone())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
                });
            chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, 4, colour.filled())))
                .map_err(plot_err)?;
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 16))
            .draw()
            .map_err(plot_err)?;
        root.present().map_err(plot_err)?;
    }
    let img = image::RgbImage::from_raw(SIZE.0, SIZE.1, buf)
        .ok_or_else(|| Error::Numerical("figure buffer size mismatch".into()))?;
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| Error::format(path, e.to_string()))?;
    write_atomic_bytes(path, &png)
}

/// Groups rows passing `keep` by `group` and collects (x, y) points, x-sorted.
fn grouped(
    t: &Table,
    keep: impl Fn(&[String]) -> Result<bool>,
    group: impl Fn(&[String]) -> Result<String>,
    x: &str,
    y: &str,
) -> Result<Vec<Series>> {
    let mut m: BTreeMap<String, Vec<(f64, f64)>> = BTreeMap::new();
    for r in &t.rows {
        if keep(r)? {
            m.entry(group(r)?)
                .or_default()
                .push((t.num(r, x)?, t.num(r, y)?));
        }
    }
    Ok(m.into_iter()
        .map(|(label, mut points)| {
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            Series { label, points }
        })
        .collect())
}

/// Averages the y of points sharing an x (landmarks → mean shift per Δf).
fn mean_per_x(s: Series) -> Series {
    let mut m: BTreeMap<u64, (f64, f64, usize)> = BTreeMap::new();
    for (x, y) in s.points {
        let e = m.entry(x.to_bits()).or_insert((x, 0.0, 0));
        e.1 += y;
        e.2 += 1;
    }
    let mut points: Vec<(f64, f64)> = m.into_values().map(|(x, y, n)| (x, y / n as f64)).collect();
    points.sort_by(|a, b| a.0.total_cmp(&b.0));
    Series {
        label: s.label,
        points,
    }
}

/// Writes every figure whose table exists under `out/tables`.
pub fn write_all(out: &Path) -> Result<()> {
    let (tables, figs) = (out.join("tables"), out.join("figures"));
    let tv = |t: &Table, r: &[String]| -> Result<String> {
        Ok(format!("{} {}", t.str(r, "target")?, t.str(r, "view")?))
    };
    let p = tables.join("projection.csv");
    if p.exists() {
        let t = Table::read(&p)?;
        let joint = |r: &[String]| -> Result<bool> { Ok(t.str(r, "family")? == "joint") };
        for (col, label, file) in [
            ("dice", "Dice", "dice_vs_perturbation.png"),
            ("iou", "IoU", "iou_vs_perturbation.png"),
            (
                "chamfer_mean_px",
                "mean Chamfer distance (px)",
                "chamfer_vs_perturbation.png",
            ),
            ("ssim", "SSIM", "ssim_vs_perturbation.png"),
            ("ncc", "NCC", "ncc_vs_perturbation.png"),
        ] {
            let s = grouped(&t, joint, |r| tv(&t, r), "df_px", col)?;
            let title = format!("{label} vs joint perturbation (Δf with piercing (p, p))");
            line_chart(&figs.join(file), &title, "focal offset Δf (px)", label, &s)?;
        }
    }
    let p = tables.join("landmarks.csv");
    if p.exists() {
        let t = Table::read(&p)?;
        let focal = |r: &[String]| -> Result<bool> { Ok(t.str(r, "family")? == "focal") };
        let mut s: Vec<Series> = grouped(
            &t,
            focal,
            |r| Ok(format!("{} measured", tv(&t, r)?)),
            "df_px",
            "shift_px",
        )?
        .into_iter()
        .map(mean_per_x)
        .collect();
        s.extend(
            grouped(
                &t,
                focal,
                |r| Ok(format!("{} H·x predicted", tv(&t, r)?)),
                "df_px",
                "pred_shift_px",
            )?
            .into_iter()
            .map(mean_per_x),
        );
        line_chart(
            &figs.join("landmark_shift_vs_df.png"),
            "Mean landmark shift vs focal offset",
            "focal offset Δf (px)",
            "mean landmark shift (px)",
            &s,
        )?;
    }
    let p = tables.join("landmarks.csv");
    if p.exists() {
        landmark_overlays(&Table::read(&p)?, &figs)?;
    }
    let p = tables.join("structures.csv");
    if p.exists() {
        structure_figures(&Table::read(&p)?, &figs)?;
    }
    let p = tables.join("registration_summary.csv");
    if p.exists() {
        registration_figures(&Table::read(&p)?, &figs)?;
    }
    Ok(())
}

/// Registration error curves vs Δf, one line per piercing shift, for the first level and the segment.
fn registration_figures(t: &Table, figs: &Path) -> Result<()> {
    let first = match t.rows.first() {
        Some(r) => t.str(r, "target")?.to_string(),
        None => return Ok(()),
    };
    registration_target(t, figs, &first)?;
    if first != "segment" && t.rows.iter().any(|r| r[0] == "segment") {
        registration_target(t, figs, "segment")?;
    }
    Ok(())
}

fn registration_target(t: &Table, figs: &Path, first: &str) -> Result<()> {
    let mut methods: Vec<String> = Vec::new();
    for r in &t.rows {
        let m = t.str(r, "method")?.to_string();
        if !methods.contains(&m) {
            methods.push(m);
        }
    }
    for m in methods {
        let keep = |r: &[String]| -> Result<bool> {
            Ok(t.str(r, "target")? == first && t.str(r, "method")? == m)
        };
        let group = |r: &[String]| -> Result<String> {
            Ok(format!("piercing {:>3} px", t.num(r, "piercing_px")?))
        };
        for (col, label, tag) in [
            (
                "rot_err_deg_mean",
                "rotation error (deg), mean over trials",
                "rot",
            ),
            (
                "trans_err_mm_mean",
                "translation error (mm), mean over trials",
                "trans",
            ),
            (
                "residual_px_mean",
                "reprojection residual (px), mean",
                "residual",
            ),
        ] {
            let s = grouped(t, keep, group, "df_px", col)?;
            let file = format!("registration_{}_{}_{tag}.png", first, m.replace('+', "_"));
            line_chart(
                &figs.join(file),
                &format!("{m} on {first}"),
                "focal offset Δf (px)",
                label,
                &s,
            )?;
        }
    }
    Ok(())
}

/// Per-structure Dice vs Δf (focal family), one figure per (target, view) of the first target.
fn structure_figures(t: &Table, figs: &Path) -> Result<()> {
    let first = match t.rows.first() {
        Some(r) => t.str(r, "target")?.to_string(),
        None => return Ok(()),
    };
    let mut views: Vec<String> = Vec::new();
    for r in &t.rows {
        let v = t.str(r, "view")?.to_string();
        if !views.contains(&v) {
            views.push(v);
        }
    }
    for v in views {
        let keep = |r: &[String]| -> Result<bool> {
            Ok(t.str(r, "target")? == first
                && t.str(r, "view")? == v
                && t.str(r, "family")? == "focal")
        };
        let s = grouped(
            t,
            keep,
            |r| Ok(t.str(r, "structure")?.to_string()),
            "df_px",
            "dice",
        )?;
        let file = figs.join(format!("structures_dice_{first}_{v}.png"));
        let title = format!("Per-structure Dice vs focal offset ({first}, {v})");
        line_chart(&file, &title, "focal offset Δf (px)", "Dice", &s)?;
    }
    Ok(())
}

/// Magnification of displacement vectors in the overlay figures (shifts are a few px on a 1000-px image).
const OVERLAY_GAIN: f64 = 10.0;

/// Landmark overlay per view of the first target at the largest focal Δf: reference positions (circles),
/// measured displacement (red, ×[`OVERLAY_GAIN`]) and the H·x prediction (blue cross at the tip).
fn landmark_overlays(t: &Table, figs: &Path) -> Result<()> {
    let first = match t.rows.first() {
        Some(r) => t.str(r, "target")?.to_string(),
        None => return Ok(()),
    };
    let focal: Vec<&Vec<String>> = t
        .rows
        .iter()
        .filter(|r| r[0] == first && r[2] == "focal")
        .collect();
    let df_max = focal
        .iter()
        .filter_map(|r| t.num(r, "df_px").ok())
        .fold(f64::NEG_INFINITY, f64::max);
    let mut views: Vec<String> = Vec::new();
    for r in &focal {
        if !views.contains(&r[1]) {
            views.push(r[1].clone());
        }
    }
    for v in views {
        let mut pts = Vec::new();
        for r in focal.iter().filter(|r| r[1] == v) {
            if t.num(r, "df_px")? != df_max {
                continue;
            }
            let g = |c: &str| t.num(r, c);
            let (x, m, p) = (
                (g("ref_u_px")?, g("ref_v_px")?),
                (g("meas_u_px")?, g("meas_v_px")?),
                (g("pred_u_px")?, g("pred_v_px")?),
            );
            if [x.0, x.1, m.0, m.1, p.0, p.1].iter().all(|a| a.is_finite()) {
                pts.push((t.str(r, "landmark")?.to_string(), x, m, p));
            }
        }
        let file = figs.join(format!("landmark_overlay_{first}_{v}.png"));
        let title = format!("{first} {v}: landmark shifts at Δf {df_max} px (×{OVERLAY_GAIN})");
        overlay_chart(&file, &title, &pts)?;
    }
    Ok(())
}

type OverlayPoint = (String, (f64, f64), (f64, f64), (f64, f64));

fn overlay_chart(path: &Path, title: &str, pts: &[OverlayPoint]) -> Result<()> {
    register_font()?;
    let tip = |x: (f64, f64), y: (f64, f64)| {
        (
            x.0 + OVERLAY_GAIN * (y.0 - x.0),
            x.1 + OVERLAY_GAIN * (y.1 - x.1),
        )
    };
    let all: Vec<(f64, f64)> = pts.iter().flat_map(|p| [p.1, tip(p.1, p.2)]).collect();
    let (mut u0, mut u1, mut v0, mut v1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(u, v) in &all {
        (u0, u1, v0, v1) = (u0.min(u), u1.max(u), v0.min(v), v1.max(v));
    }
    if u0 > u1 {
        (u0, u1, v0, v1) = (0.0, 1.0, 0.0, 1.0);
    }
    let m = 0.1 * (u1 - u0).max(v1 - v0).max(10.0);
    let mut buf = vec![0u8; (SIZE.0 * SIZE.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        // v grows downward on the detector: the y axis runs from v1 (bottom) to v0 (top).
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 22))
            .margin(15)
            .x_label_area_size(50)
            .y_label_area_size(80)
            .build_cartesian_2d((u0 - m)..(u1 + m), (v1 + m)..(v0 - m))
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .x_desc("u (px)")
            .y_desc("v (px)")
            .label_style(("sans-serif", 16))
            .draw()
            .map_err(plot_err)?;
        for (name, x, meas, pred) in pts {
            let el = PathElement::new(vec![*x, tip(*x, *meas)], RED.stroke_width(2));
            chart.draw_series(std::iter::once(el)).map_err(plot_err)?;
            let c = Circle::new(*x, 4, BLACK.filled());
            chart.draw_series(std::iter::once(c)).map_err(plot_err)?;
            let cross = Cross::new(tip(*x, *pred), 6, BLUE.stroke_width(2));
            chart
                .draw_series(std::iter::once(cross))
                .map_err(plot_err)?;
            let label = Text::new(name.clone(), *x, ("sans-serif", 13));
            chart
                .draw_series(std::iter::once(label))
                .map_err(plot_err)?;
        }
        root.present().map_err(plot_err)?;
    }
    encode_png(path, buf)
}

fn encode_png(path: &Path, buf: Vec<u8>) -> Result<()> {
    let img = image::RgbImage::from_raw(SIZE.0, SIZE.1, buf)
        .ok_or_else(|| Error::Numerical("figure buffer size mismatch".into()))?;
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| Error::format(path, e.to_string()))?;
    write_atomic_bytes(path, &png)
}
