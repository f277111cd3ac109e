//! Landmark overlay figures: reference landmark positions on the detector with the measured displacement
//! (magnified) and the homography prediction.

use std::path::Path;

use plotters::prelude::*;

use super::{SIZE, encode_png, plot_err, register_font};
use crate::Result;
use crate::study::tables::Table;

/// Magnification of displacement vectors in the overlay figures (shifts are a few px on a 1000-px image).
const OVERLAY_GAIN: f64 = 10.0;

/// Landmark overlay per target and view at the largest focal Δf: reference positions (circles), measured
/// displacement (red, ×[`OVERLAY_GAIN`]) and the H·x prediction (blue cross at the tip).
pub fn landmark_overlays(t: &Table, figs: &Path) -> Result<()> {
    let mut targets: Vec<String> = Vec::new();
    for r in &t.rows {
        let target = t.str(r, "target")?;
        if !targets.iter().any(|x| x == target) {
            targets.push(target.to_string());
        }
    }
    for target in &targets {
        target_overlays(t, target, figs)?;
    }
    Ok(())
}

/// The overlays of one target, one per view.
fn target_overlays(t: &Table, target: &str, figs: &Path) -> Result<()> {
    let focal: Vec<&Vec<String>> = t
        .rows
        .iter()
        .filter(|r| r[0] == target && r[2] == "focal")
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
        let file = figs.join(format!("landmark_overlay_{target}_{v}.png"));
        let title = format!("{target} {v}: landmark shifts at Δf {df_max} px (×{OVERLAY_GAIN})");
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
