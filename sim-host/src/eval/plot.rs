//! PNG plots of the evaluation (plotters, bitmap backend).
//!
//! Text uses the embedded font of [`crate::plot_font`]. Per take (`boardB_takeT.png`): top
//! panel forward velocity, bottom panel sideways velocity (data set convention) over time;
//! black = ground truth, red = Edge-FS; the grey band marks the evaluation window. Summary
//! (`summary.png`): per take bars of MSE on a log scale, top x, bottom y; red = this run, blue =
//! the paper's Edge-FS, green = the paper's Farnebäck (where published).

use super::paper_table::paper_row;
use super::TakeResult;
use crate::plot_font::{self, FAMILY};
use anyhow::{anyhow, Result};
use plotters::prelude::*;
use std::path::Path;

fn err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("plotting failed: {e:?}")
}

/// Plots one take's estimate vs ground truth.
pub fn plot_take(r: &TakeResult, path: &Path) -> Result<()> {
    plot_font::register();
    let root = BitMapBackend::new(path, (1000, 700)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let panels = root.split_evenly((2, 1));
    let s = &r.series;
    let t0 = s.time_s.first().copied().unwrap_or(0.0);
    let t1 = s.time_s.last().copied().unwrap_or(1.0).max(t0 + 1e-3);
    let titles = ["forward velocity (x)", "sideways velocity (y)"];
    for ((panel, (est, gt)), title) in panels
        .iter()
        .zip([(&s.est_x, &s.gt_x), (&s.est_y, &s.gt_y)])
        .zip(titles)
    {
        let finite = est.iter().chain(gt.iter()).filter(|v| v.is_finite());
        let (lo, hi) = finite.fold((-0.5f64, 0.5f64), |(a, b), &v| (a.min(v), b.max(v)));
        let (lo, hi) = (lo.max(-3.0) - 0.1, hi.min(3.0) + 0.1);
        let mut chart = ChartBuilder::on(panel)
            .margin(12)
            .caption(
                format!("board {} take {}: {title}", r.board, r.take),
                (FAMILY, 20),
            )
            .x_label_area_size(36)
            .y_label_area_size(56)
            .build_cartesian_2d(t0..t1, lo..hi)
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("time [s]")
            .y_desc("velocity [m/s]")
            .label_style((FAMILY, 14))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(err)?;
        let (a, b) = s.window;
        let (wa, wb) = (
            s.time_s[a.min(s.time_s.len() - 1)],
            s.time_s[b.min(s.time_s.len() - 1)],
        );
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(wa, lo), (wb, hi)],
                RGBColor(235, 235, 235).filled(),
            )))
            .map_err(err)?;
        let mut g = (lo / 0.5).ceil() * 0.5;
        while g <= hi {
            let style = if g == 0.0 {
                BLACK.stroke_width(2)
            } else {
                RGBColor(200, 200, 200).stroke_width(1)
            };
            chart
                .draw_series(LineSeries::new([(t0, g), (t1, g)], style))
                .map_err(err)?;
            g += 0.5;
        }
        let pts = |v: &Vec<f64>| -> Vec<(f64, f64)> {
            s.time_s
                .iter()
                .zip(v)
                .filter(|(_, y)| y.is_finite())
                .map(|(&t, &y)| (t, y.clamp(lo, hi)))
                .collect()
        };
        chart
            .draw_series(LineSeries::new(pts(gt), BLACK.stroke_width(2)))
            .map_err(err)?
            .label("motion capture")
            .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLACK.stroke_width(2)));
        chart
            .draw_series(LineSeries::new(pts(est), RED.stroke_width(2)))
            .map_err(err)?
            .label("Edge-FS")
            .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], RED.stroke_width(2)));
        chart
            .configure_series_labels()
            .label_font((FAMILY, 14))
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(err)?;
    }
    root.present().map_err(err)?;
    Ok(())
}

/// Plots MSE per take (this run vs the published numbers).
pub fn plot_summary(results: &[TakeResult], path: &Path) -> Result<()> {
    plot_font::register();
    let root = BitMapBackend::new(path, (1000, 700)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let panels = root.split_evenly((2, 1));
    let n = results.len().max(1) as f64;
    let lg = |v: f64| {
        if v.is_finite() && v > 0.0 {
            v.log10().clamp(-4.0, 0.5)
        } else {
            -4.0
        }
    };
    for (axis, panel) in panels.iter().enumerate() {
        let title = if axis == 0 {
            "forward (x)"
        } else {
            "sideways (y)"
        };
        let mut chart = ChartBuilder::on(panel)
            .margin(12)
            .caption(
                format!("MSE per take, {title}: red this run, blue paper Edge-FS, green paper Farneback"),
                (FAMILY, 18),
            )
            .x_label_area_size(36)
            .y_label_area_size(64)
            .build_cartesian_2d(0.0..n, -4.0..0.5)
            .map_err(err)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .disable_x_axis()
            .y_desc("MSE [(m/s)^2]")
            .y_label_formatter(&|v| format!("1e{v:.0}"))
            .y_labels(5)
            .label_style((FAMILY, 13))
            .draw()
            .map_err(err)?;
        chart
            .draw_series(results.iter().enumerate().map(|(k, r)| {
                Text::new(
                    format!("b{}t{}", r.board, r.take),
                    (k as f64 + 0.3, 0.45),
                    (FAMILY, 13).into_font(),
                )
            }))
            .map_err(err)?;
        for d in -4..=0 {
            chart
                .draw_series(LineSeries::new(
                    [(0.0, d as f64), (n, d as f64)],
                    RGBColor(200, 200, 200).stroke_width(1),
                ))
                .map_err(err)?;
        }
        for (k, r) in results.iter().enumerate() {
            let ours = if axis == 0 { r.x.mse } else { r.y.mse };
            let mut bars = vec![(ours, RED)];
            if let Some(p) = paper_row(r.board, r.take) {
                let (e, f) = if axis == 0 {
                    (p.edgefs[1], p.farneback[1])
                } else {
                    (p.edgefs[4], p.farneback[4])
                };
                bars.push((e, BLUE));
                bars.push((f, GREEN));
            }
            for (j, (v, color)) in bars.into_iter().enumerate() {
                let x0 = k as f64 + 0.1 + 0.27 * j as f64;
                chart
                    .draw_series(std::iter::once(Rectangle::new(
                        [(x0, -4.0), (x0 + 0.25, lg(v))],
                        color.filled(),
                    )))
                    .map_err(err)?;
            }
        }
    }
    root.present().map_err(err)?;
    Ok(())
}
