//! Flight artefacts: CSV log, PNG plots (plotters, bitmap backend, text in the embedded font of
//! [`crate::plot_font`]) and an animated GIF (top-down view beside the left camera image).

use super::camera::{HEIGHT, WIDTH};
use super::flight::FlightResult;
use super::scene::{Obstacle, Scene};
use crate::plot_font::{self, FAMILY};
use plotters::prelude::*;
use protocol::{FlightMode, FsmState};
use std::io::Write;
use std::path::Path;

/// Writes the 50 Hz log as CSV.
pub fn write_log_csv(r: &FlightResult, path: &Path) -> anyhow::Result<()> {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path)?);
    writeln!(
        f,
        "t_s,x_m,y_m,height_m,yaw_rad,vf_true_mps,vs_true_mps,vf_est_mps,vs_est_mps,\
         vf_sp_mps,vs_sp_mps,height_sp_m,vf_raw_mps,vs_raw_mps,obstacle_m,clearance_m,fsm_state,mode,\
         m1,m2,m3,m4,roll_err_deg,pitch_err_deg,closing_mps,overrule_mps,contact_s"
    )?;
    for l in &r.log {
        writeln!(
            f,
            "{:.3},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.3},{:.3},{:.3},{:.4},{:.4},{:.3},{:.4},{},{},{:.4},{:.4},{:.4},{:.4},{:.3},{:.3},{:.3},{:.3},{:.3}",
            l.t_s,
            l.pos[0],
            l.pos[1],
            l.pos[2],
            l.yaw,
            l.vel_true[0],
            l.vel_true[1],
            l.vel_est[0],
            l.vel_est[1],
            l.vel_sp[0],
            l.vel_sp[1],
            l.height_sp_m,
            l.vel_raw[0],
            l.vel_raw[1],
            l.obstacle_m,
            l.clearance_m,
            l.fsm_state.map_or("inactive", FsmState::name),
            l.mode.name(),
            l.motors[0],
            l.motors[1],
            l.motors[2],
            l.motors[3],
            l.tilt_err_deg[0],
            l.tilt_err_deg[1],
            l.closing_mps,
            l.overrule_mps,
            l.contact_s
        )?;
    }
    // Explicitly, so a failed write is an error rather than lost when the writer drops.
    f.flush()?;
    Ok(())
}

fn grid<DB: DrawingBackend>(
    chart: &mut ChartContext<
        DB,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
    x: (f64, f64, f64),
    y: (f64, f64, f64),
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    let style = RGBColor(225, 225, 225);
    let mut v = (x.0 / x.2).ceil() * x.2;
    while v <= x.1 {
        chart
            .draw_series(LineSeries::new([(v, y.0), (v, y.1)], style))
            .map_err(|e| anyhow::anyhow!("{e:?}"))?;
        v += x.2;
    }
    let mut v = (y.0 / y.2).ceil() * y.2;
    while v <= y.1 {
        let c = if v.abs() < 1e-9 {
            RGBColor(120, 120, 120)
        } else {
            style
        };
        chart
            .draw_series(LineSeries::new([(x.0, v), (x.1, v)], c))
            .map_err(|e| anyhow::anyhow!("{e:?}"))?;
        v += y.2;
    }
    Ok(())
}

/// Axis labels and tick values (the light grid is drawn by [`grid`]).
fn axes<'a, DB: DrawingBackend + 'a>(
    chart: &mut ChartContext<
        'a,
        DB,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
    x_desc: &str,
    y_desc: &str,
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .label_style((FAMILY, 13))
        .draw()
        .map_err(|e| anyhow::anyhow!("{e:?}"))
}

/// Draws the legend of the labelled series in the upper right corner.
fn legend<'a, DB: DrawingBackend + 'a>(
    chart: &mut ChartContext<
        'a,
        DB,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font((FAMILY, 13))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|e| anyhow::anyhow!("{e:?}"))
}

fn line_key(color: RGBColor) -> impl Fn((i32, i32)) -> PathElement<(i32, i32)> {
    move |(x, y)| PathElement::new([(x, y), (x + 18, y)], color.stroke_width(2))
}

/// Top-down trajectory with the room and obstacles (x north up, y east right; 1 m grid);
/// collisions in red, start in green.
pub fn plot_trajectory(r: &FlightResult, path: &Path) -> anyhow::Result<()> {
    let s = &r.scene;
    let px_per_m = 600.0 / s.size_x.max(s.size_y) as f64;
    plot_font::register();
    let w = (s.size_y as f64 * px_per_m) as u32 + 100;
    let h = (s.size_x as f64 * px_per_m) as u32 + 110;
    let root = BitMapBackend::new(path, (w, h)).into_drawing_area();
    let e = |e: DrawingAreaErrorKind<_>| anyhow::anyhow!("{e:?}");
    root.fill(&WHITE).map_err(e)?;
    let root = root.margin(20, 20, 20, 20);
    // Plot coordinates: horizontal = east (y), vertical = north (x).
    let mut chart = plan_chart(
        &root,
        s,
        format!("seed {}: trajectory (start green, collisions red)", r.seed),
        16,
    )?;
    let airborne: Vec<(f64, f64)> = r
        .log
        .iter()
        .filter(|l| l.pos[2] > 0.05)
        .map(|l| (l.pos[1] as f64, l.pos[0] as f64))
        .collect();
    chart
        .draw_series(LineSeries::new(
            airborne,
            ShapeStyle::from(&BLUE).stroke_width(2),
        ))
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    if let Some(l) = r.log.first() {
        chart
            .draw_series([Circle::new(
                (l.pos[1] as f64, l.pos[0] as f64),
                6,
                GREEN.filled(),
            )])
            .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    }
    let hits = r
        .log
        .iter()
        .filter(|l| l.clearance_m <= 0.0 && l.pos[2] > 0.05)
        .map(|l| Circle::new((l.pos[1] as f64, l.pos[0] as f64), 4, RED.filled()));
    chart
        .draw_series(hits)
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    root.present().map_err(e)?;
    Ok(())
}

/// A plan of the room on `area` (horizontal east, vertical north, m, 1 m grid) with its walls
/// and obstacles, captioned `caption` in `size` points.
fn plan_chart<'a, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, plotters::coord::Shift>,
    s: &Scene,
    caption: String,
    size: u32,
) -> anyhow::Result<
    ChartContext<
        'a,
        DB,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
>
where
    DB::ErrorType: 'static,
{
    let mut chart = ChartBuilder::on(area)
        .caption(caption, (FAMILY, size))
        .x_label_area_size(35)
        .y_label_area_size(45)
        .build_cartesian_2d(0.0..s.size_y as f64, 0.0..s.size_x as f64)
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    axes(&mut chart, "east [m]", "north [m]")?;
    grid(
        &mut chart,
        (0.0, s.size_y as f64, 1.0),
        (0.0, s.size_x as f64, 1.0),
    )?;
    draw_room(&mut chart, s)?;
    Ok(chart)
}

/// The room's walls and obstacles on a plan chart (horizontal east, vertical north, m).
fn draw_room<DB: DrawingBackend>(
    chart: &mut ChartContext<
        DB,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
    s: &Scene,
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    let wall = ShapeStyle::from(&BLACK).stroke_width(3);
    let (sx, sy) = (s.size_x as f64, s.size_y as f64);
    chart
        .draw_series(LineSeries::new(
            [(0.0, 0.0), (sy, 0.0), (sy, sx), (0.0, sx), (0.0, 0.0)],
            wall,
        ))
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    for ob in &s.obstacles {
        match ob {
            Obstacle::Cylinder { x, y, radius, .. } => {
                let pts: Vec<(f64, f64)> = (0..=36)
                    .map(|k| {
                        let a = k as f64 * std::f64::consts::TAU / 36.0;
                        (
                            *y as f64 + *radius as f64 * a.sin(),
                            *x as f64 + *radius as f64 * a.cos(),
                        )
                    })
                    .collect();
                chart
                    .draw_series(LineSeries::new(pts, wall))
                    .map_err(|e| anyhow::anyhow!("{e:?}"))?;
            }
            Obstacle::Panel { a, b, .. } => {
                chart
                    .draw_series(LineSeries::new(
                        [(a[1] as f64, a[0] as f64), (b[1] as f64, b[0] as f64)],
                        wall,
                    ))
                    .map_err(|e| anyhow::anyhow!("{e:?}"))?;
            }
            Obstacle::Box { min, max, .. } => {
                let (x0, y0, x1, y1) = (min[0] as f64, min[1] as f64, max[0] as f64, max[1] as f64);
                chart
                    .draw_series(LineSeries::new(
                        [(y0, x0), (y1, x0), (y1, x1), (y0, x1), (y0, x0)],
                        wall,
                    ))
                    .map_err(|e| anyhow::anyhow!("{e:?}"))?;
            }
        }
    }
    Ok(())
}

/// Estimated (the autopilot's velocity estimate: solid, raw Edge-FS: dots) vs true (black) velocity over time,
/// forward on top, sideways below; grid 1 s x 0.1 m/s.
pub fn plot_velocity(r: &FlightResult, path: &Path) -> anyhow::Result<()> {
    let t_end = r.log.last().map(|l| l.t_s).unwrap_or(1.0).max(1.0);
    let w = (t_end * 20.0).clamp(800.0, 6000.0) as u32;
    plot_font::register();
    let root = BitMapBackend::new(path, (w, 700)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let areas = root.split_evenly((2, 1));
    for (axis, area) in areas.iter().enumerate() {
        let area = area.margin(10, 10, 10, 10);
        let name = if axis == 0 { "forward" } else { "sideways" };
        let mut chart = ChartBuilder::on(&area)
            .caption(format!("{name} velocity, body frame"), (FAMILY, 16))
            .x_label_area_size(35)
            .y_label_area_size(50)
            .build_cartesian_2d(0.0..t_end, -0.6..0.6)
            .map_err(|e| anyhow::anyhow!("{e:?}"))?;
        axes(&mut chart, "time [s]", "velocity [m/s]")?;
        grid(&mut chart, (0.0, t_end, 10.0), (-0.6, 0.6, 0.1))?;
        let series = |f: &dyn Fn(&super::flight::LogRow) -> f32| -> Vec<(f64, f64)> {
            r.log
                .iter()
                .filter(|l| f(l).is_finite())
                .map(|l| (l.t_s, (f(l) as f64).clamp(-0.6, 0.6)))
                .collect()
        };
        chart
            .draw_series(
                series(&|l| l.vel_raw[axis])
                    .into_iter()
                    .map(|p| Circle::new(p, 1, RGBColor(255, 160, 0).filled())),
            )
            .map_err(|e| anyhow::anyhow!("{e:?}"))?
            .label("Edge-FS (raw)")
            .legend(|(x, y)| Circle::new((x + 9, y), 3, RGBColor(255, 160, 0).filled()));
        chart
            .draw_series(LineSeries::new(series(&|l| l.vel_sp[axis]), GREEN))
            .map_err(|e| anyhow::anyhow!("{e:?}"))?
            .label("setpoint")
            .legend(line_key(GREEN));
        chart
            .draw_series(LineSeries::new(series(&|l| l.vel_est[axis]), BLUE))
            .map_err(|e| anyhow::anyhow!("{e:?}"))?
            .label("estimate")
            .legend(line_key(BLUE));
        chart
            .draw_series(LineSeries::new(series(&|l| l.vel_true[axis]), BLACK))
            .map_err(|e| anyhow::anyhow!("{e:?}"))?
            .label("truth")
            .legend(line_key(BLACK));
        legend(&mut chart)?;
    }
    root.present().map_err(|e| anyhow::anyhow!("{e:?}"))?;
    Ok(())
}

/// Splits a series at non-finite values into runs, so a gap in the data (no obstacle in
/// range) is a gap in the line instead of a jump.
fn runs(points: impl Iterator<Item = (f64, f64)>) -> Vec<Vec<(f64, f64)>> {
    let mut out: Vec<Vec<(f64, f64)>> = vec![Vec::new()];
    for p in points {
        if p.1.is_finite() {
            if let Some(last) = out.last_mut() {
                last.push(p);
            }
        } else if out.last().is_some_and(|l| !l.is_empty()) {
            out.push(Vec::new());
        }
    }
    out.retain(|r| !r.is_empty());
    out
}

/// Step lines of a discrete signal on named levels (level `i` at y = `i`, labelled `names[i]`).
fn plot_levels<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    caption: &str,
    (t_start, t_end): (f64, f64),
    names: &[&str],
    level: impl Fn(&super::flight::LogRow) -> usize,
    r: &FlightResult,
    color: RGBColor,
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    let err = |e: &dyn std::fmt::Debug| anyhow::anyhow!("{e:?}");
    let top = names.len() as f64 - 0.5;
    let mut chart = ChartBuilder::on(area)
        .caption(caption, (FAMILY, 16))
        .x_label_area_size(30)
        .y_label_area_size(130)
        .build_cartesian_2d(t_start..t_end, -0.5..top)
        .map_err(|e| err(&e))?;
    let label = |y: &f64| {
        let i = y.round();
        if (y - i).abs() < 1e-6 && i >= 0.0 {
            names.get(i as usize).copied().unwrap_or("").to_string()
        } else {
            String::new()
        }
    };
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc("time [s]")
        .y_labels(names.len() * 2 + 1)
        .y_label_formatter(&label)
        .label_style((FAMILY, 13))
        .draw()
        .map_err(|e| err(&e))?;
    let step = if t_end - t_start > 20.0 { 10.0 } else { 1.0 };
    grid(&mut chart, (t_start, t_end, step), (0.0, top - 0.5, 1.0))?;
    chart
        .draw_series(LineSeries::new(
            r.log
                .iter()
                .filter(|l| (t_start..=t_end).contains(&l.t_s))
                .map(|l| (l.t_s, level(l) as f64)),
            ShapeStyle::from(&color).stroke_width(2),
        ))
        .map_err(|e| err(&e))?;
    Ok(())
}

/// Three panels over time (grid 10 s): the FSM state and the flight mode by name as step
/// lines, and the obstacle distance the autopilot holds (gray, m, clipped to 4 m, gaps where
/// nothing is in range) with the true clearance (black, m).
pub fn plot_fsm(r: &FlightResult, path: &Path) -> anyhow::Result<()> {
    let t_end = r.log.last().map(|l| l.t_s).unwrap_or(1.0).max(1.0);
    let w = (t_end * 20.0).clamp(800.0, 6000.0) as u32;
    plot_font::register();
    let root = BitMapBackend::new(path, (w, 800)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let (states, bottom) = root.margin(10, 10, 10, 10).split_vertically(460);
    let (fsm_area, mode_area) = states.split_vertically(200);
    let err = |e: &dyn std::fmt::Debug| anyhow::anyhow!("{e:?}");

    let mut fsm_names = vec!["inactive"];
    fsm_names.extend(FsmState::ALL.iter().map(|s| s.name()));
    let fsm_level = |l: &super::flight::LogRow| {
        l.fsm_state
            .and_then(|s| FsmState::ALL.iter().position(|&x| x == s))
            .map_or(0, |i| i + 1)
    };
    plot_levels(
        &fsm_area,
        "FSM state",
        (0.0, t_end),
        &fsm_names,
        fsm_level,
        r,
        BLUE,
    )?;
    let mode_names: Vec<&str> = FlightMode::ALL.iter().map(|m| m.name()).collect();
    let mode_level = |l: &super::flight::LogRow| {
        FlightMode::ALL
            .iter()
            .position(|&m| m == l.mode)
            .unwrap_or(0)
    };
    plot_levels(
        &mode_area,
        "flight mode",
        (0.0, t_end),
        &mode_names,
        mode_level,
        r,
        RED,
    )?;

    let mut chart = ChartBuilder::on(&bottom)
        .caption("obstacle distance and true clearance", (FAMILY, 16))
        .x_label_area_size(35)
        .y_label_area_size(50)
        .build_cartesian_2d(0.0..t_end, 0.0..4.0)
        .map_err(|e| err(&e))?;
    axes(&mut chart, "time [s]", "metres")?;
    grid(&mut chart, (0.0, t_end, 10.0), (0.0, 4.0, 0.5))?;
    let gray = RGBColor(160, 160, 160);
    for (i, run) in runs(
        r.log
            .iter()
            .map(|l| (l.t_s, (l.obstacle_m as f64).clamp(0.0, 4.0))),
    )
    .into_iter()
    .enumerate()
    {
        let s = chart
            .draw_series(LineSeries::new(run, gray))
            .map_err(|e| err(&e))?;
        if i == 0 {
            s.label("obstacle distance (Edge-FS) [m]")
                .legend(line_key(gray));
        }
    }
    chart
        .draw_series(LineSeries::new(
            r.log
                .iter()
                .map(|l| (l.t_s, (l.clearance_m as f64).clamp(0.0, 4.0))),
            BLACK,
        ))
        .map_err(|e| err(&e))?
        .label("true clearance [m]")
        .legend(line_key(BLACK));
    legend(&mut chart)?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

/// How much of a flight before its first contact [`plot_contact`] shows, s.
pub const CONTACT_WINDOW_S: f64 = 10.0;

/// Why a flight touched: the last [`CONTACT_WINDOW_S`] before its first contact (and half a
/// second after) in one picture. Left, the room's plan with the obstacles, the path over the
/// window (blue, the start of the window green, the contact red). Right, over time: forward
/// and sideways velocity, truth (black) and the autopilot's estimate (blue); the FSM state;
/// the obstacle distance the autopilot holds (gray) and the true clearance (black).
pub fn plot_contact(r: &FlightResult, path: &Path) -> anyhow::Result<()> {
    let err = |e: &dyn std::fmt::Debug| anyhow::anyhow!("{e:?}");
    let t_contact = r.flight_time_s;
    let (t0, t1) = ((t_contact - CONTACT_WINDOW_S).max(0.0), t_contact + 0.5);
    let window: Vec<&super::flight::LogRow> = r
        .log
        .iter()
        .filter(|l| (t0..=t1).contains(&l.t_s))
        .collect();
    plot_font::register();
    let root = BitMapBackend::new(path, (1400, 820)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let root = root.margin(10, 10, 10, 10);
    let (plan_area, right) = root.split_horizontally(600);

    let s = &r.scene;
    let mut plan = plan_chart(
        &plan_area,
        s,
        format!(
            "{} seed {}: contact at {t_contact:.1} s, the {CONTACT_WINDOW_S:.0} s before",
            s.name, r.seed
        ),
        15,
    )?;
    let at = |l: &&super::flight::LogRow| (l.pos[1] as f64, l.pos[0] as f64);
    plan.draw_series(LineSeries::new(
        window.iter().map(at),
        ShapeStyle::from(&BLUE).stroke_width(2),
    ))
    .map_err(|e| err(&e))?;
    if let Some(first) = window.first() {
        plan.draw_series([Circle::new(at(first), 6, GREEN.filled())])
            .map_err(|e| err(&e))?;
    }
    if let Some(hit) = window.iter().find(|l| l.t_s >= t_contact) {
        plan.draw_series([Circle::new(at(hit), 6, RED.filled())])
            .map_err(|e| err(&e))?;
    }

    let panels = right.split_evenly((3, 1));
    let mut velocity = ChartBuilder::on(&panels[0])
        .caption("velocity: truth (black), estimate (blue)", (FAMILY, 15))
        .x_label_area_size(30)
        .y_label_area_size(50)
        .build_cartesian_2d(t0..t1, -0.6..0.6)
        .map_err(|e| err(&e))?;
    axes(&mut velocity, "time [s]", "fwd / side [m/s]")?;
    grid(&mut velocity, (t0, t1, 1.0), (-0.6, 0.6, 0.2))?;
    for axis in 0..2 {
        let width = if axis == 0 { 2 } else { 1 };
        for (pick, color) in [(0, BLACK), (1, BLUE)] {
            let series = window.iter().map(|l| {
                let v = if pick == 0 {
                    l.vel_true[axis]
                } else {
                    l.vel_est[axis]
                };
                (l.t_s, f64::from(v).clamp(-0.6, 0.6))
            });
            for run in runs(series) {
                velocity
                    .draw_series(LineSeries::new(
                        run,
                        ShapeStyle::from(&color).stroke_width(width),
                    ))
                    .map_err(|e| err(&e))?;
            }
        }
    }
    let mut fsm_names = vec!["inactive"];
    fsm_names.extend(FsmState::ALL.iter().map(|s| s.name()));
    plot_levels(
        &panels[1],
        "FSM state",
        (t0, t1),
        &fsm_names,
        |l| {
            l.fsm_state
                .and_then(|s| FsmState::ALL.iter().position(|&x| x == s))
                .map_or(0, |i| i + 1)
        },
        r,
        BLUE,
    )?;
    let mut distance = ChartBuilder::on(&panels[2])
        .caption(
            "obstacle distance (gray) and true clearance (black)",
            (FAMILY, 15),
        )
        .x_label_area_size(30)
        .y_label_area_size(50)
        .build_cartesian_2d(t0..t1, 0.0..4.0)
        .map_err(|e| err(&e))?;
    axes(&mut distance, "time [s]", "metres")?;
    grid(&mut distance, (t0, t1, 1.0), (0.0, 4.0, 0.5))?;
    for run in runs(
        window
            .iter()
            .map(|l| (l.t_s, f64::from(l.obstacle_m).clamp(0.0, 4.0))),
    ) {
        distance
            .draw_series(LineSeries::new(run, RGBColor(160, 160, 160)))
            .map_err(|e| err(&e))?;
    }
    distance
        .draw_series(LineSeries::new(
            window
                .iter()
                .map(|l| (l.t_s, f64::from(l.clearance_m).clamp(0.0, 4.0))),
            BLACK,
        ))
        .map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

const PAL_GRAY: u8 = 240; // indices 0..240: gray ramp
const C_WHITE: u8 = 240;
const C_BLACK: u8 = 241;
const C_BLUE: u8 = 242;
const C_RED: u8 = 243;
const C_GREEN: u8 = 244;
const C_LIGHT: u8 = 245;

fn palette() -> Vec<u8> {
    let mut p = Vec::with_capacity(256 * 3);
    for i in 0..PAL_GRAY as u32 {
        let g = (i * 255 / (PAL_GRAY as u32 - 1)) as u8;
        p.extend_from_slice(&[g, g, g]);
    }
    for c in [
        [255, 255, 255],
        [0, 0, 0],
        [30, 80, 230],
        [230, 30, 30],
        [20, 170, 40],
        [235, 235, 235],
    ] {
        p.extend_from_slice(&c);
    }
    p.resize(256 * 3, 0);
    p
}

/// Animated GIF, played at 4x speed: top-down view (trail, drone, heading; red when in
/// contact) beside the left camera image.
pub fn write_gif(r: &FlightResult, path: &Path) -> anyhow::Result<()> {
    if r.images.is_empty() {
        return Ok(());
    }
    let s: &Scene = &r.scene;
    let side = 2 * HEIGHT as u16; // 192 px top view height
    let scale = (side as f32 - 8.0) / s.size_x.max(s.size_y);
    let top_w = (s.size_y * scale) as u16 + 8;
    let top_h = (s.size_x * scale) as u16 + 8;
    let cam_w = WIDTH as u16;
    let w = top_w + 8 + cam_w;
    let h = top_h.max(side);
    let mut enc = gif::Encoder::new(std::fs::File::create(path)?, w, h, &palette())?;
    enc.set_repeat(gif::Repeat::Infinite)?;
    let dt = if r.images.len() > 1 {
        r.images[1].0 - r.images[0].0
    } else {
        0.2
    };
    let to_px = |x: f32, y: f32| -> (i32, i32) {
        // North up: x maps to rows from the bottom, y (east) to columns.
        (
            (4.0 + y * scale) as i32,
            (top_h as f32 - 4.0 - x * scale) as i32,
        )
    };
    let mut buf = vec![C_WHITE; w as usize * h as usize];
    let mut li = 0usize;
    for (t, img) in &r.images {
        buf.fill(C_WHITE);
        let put = |buf: &mut Vec<u8>, px: i32, py: i32, c: u8| {
            if px >= 0 && py >= 0 && (px as u16) < w && (py as u16) < h {
                buf[py as usize * w as usize + px as usize] = c;
            }
        };
        // Room outline and obstacles (sampled clearance).
        for py in 0..top_h as i32 {
            for px in 0..top_w as i32 {
                let y = (px as f32 - 4.0) / scale;
                let x = (top_h as f32 - 4.0 - py as f32) / scale;
                let inside = x >= 0.0 && y >= 0.0 && x <= s.size_x && y <= s.size_y;
                let c = if !inside || s.clearance(x, y, 1.0) < 1.0 / scale {
                    C_BLACK
                } else {
                    C_LIGHT
                };
                put(&mut buf, px, py, c);
            }
        }
        while li + 1 < r.log.len() && r.log[li + 1].t_s <= *t {
            li += 1;
        }
        for l in r.log.iter().take(li + 1).filter(|l| l.pos[2] > 0.05) {
            let (px, py) = to_px(l.pos[0], l.pos[1]);
            put(&mut buf, px, py, C_BLUE);
        }
        if let Some(l) = r.log.get(li) {
            let (px, py) = to_px(l.pos[0], l.pos[1]);
            let c = if l.clearance_m <= 0.0 { C_RED } else { C_GREEN };
            for dy in -2..=2 {
                for dx in -2..=2 {
                    put(&mut buf, px + dx, py + dy, c);
                }
            }
            for k in 0..12 {
                let (hx, hy) = (
                    l.pos[0] + k as f32 * 0.02 * l.yaw.cos(),
                    l.pos[1] + k as f32 * 0.02 * l.yaw.sin(),
                );
                let (px, py) = to_px(hx, hy);
                put(&mut buf, px, py, C_RED);
            }
        }
        let x0 = top_w as usize + 8;
        for (k, &v) in img.iter().enumerate() {
            let (u, row) = (k % WIDTH, k / WIDTH);
            let c = (v as u32 * (PAL_GRAY as u32 - 1) / 255) as u8;
            buf[row * w as usize + x0 + u] = c;
        }
        let mut frame = gif::Frame::from_indexed_pixels(w, h, buf.clone(), None);
        frame.delay = (dt * 25.0).round().clamp(2.0, 500.0) as u16;
        enc.write_frame(&frame)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_split_at_gaps_and_drop_empty_ones() {
        let pts = [
            (0.0, f64::NAN),
            (1.0, 1.0),
            (2.0, 2.0),
            (3.0, f64::NAN),
            (4.0, f64::NAN),
            (5.0, 3.0),
        ];
        let r = runs(pts.into_iter());
        assert_eq!(r, vec![vec![(1.0, 1.0), (2.0, 2.0)], vec![(5.0, 3.0)]]);
        assert!(runs([(0.0, f64::NAN)].into_iter()).is_empty());
    }

    #[test]
    fn a_contact_is_drawn_with_its_window_start_and_the_contact() {
        let cfg = super::super::flight::FlightConfig {
            duration_s: 4.0,
            ..Default::default()
        };
        let mut r = super::super::flight::run_flight(&cfg, &mut |_| {}).unwrap();
        // The picture of a contact at 3.5 s: the window is the whole flight here.
        r.flight_time_s = 3.5;
        let path = std::env::temp_dir().join(format!("contact-{}.png", std::process::id()));
        plot_contact(&r, &path).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        let _ = std::fs::remove_file(&path);
        assert_eq!(img.dimensions(), (1400, 820));
        let count = |want: [u8; 3]| img.pixels().filter(|p| p.0 == want).count();
        assert!(count([255, 0, 0]) > 50, "the contact's red marker");
        assert!(count([0, 255, 0]) > 50, "the window's green start");
        assert!(
            count([0, 0, 255]) > 200,
            "the path and the estimate in blue"
        );
    }
}
