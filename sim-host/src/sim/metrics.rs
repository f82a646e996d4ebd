//! A flight's figures, computed after it from what it recorded: how well it followed its
//! setpoints, from its 50 Hz log (the figures `fly` prints and writes as `track_rmse_mps`,
//! `hover_speed_mps`, `stop_speed_mps` and `height_rmse_m`, and the attitude estimate's error the
//! velocity filter predicts with, `tilt_rmse_deg`), and the velocity errors (`vel_rmse_mps`
//! from the log, the raw Edge-FS error from the estimates as received).
//!
//! All of them use the true state (the simulator's; the tilt error is the autopilot's estimate
//! against it) and only rows in level flight: flight mode `Flying` with the avoidance FSM running (it starts once the take-off
//! ramp has reached the target height, and stops for landing and every failsafe).

use super::log_row::LogRow;
use protocol::{FlightMode, FsmState};

/// Flights below this height (m, when the estimate arrives) do not count towards the raw
/// estimate error: on the floor and during the take-off the view is mostly floor.
pub const ESTIMATE_CHECK_MIN_HEIGHT_M: f64 = 0.3;

/// One valid Edge-FS estimate as the autopilot received it, against the true body velocity
/// at its capture.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EstimateCheck {
    /// Forward and sideways estimate, m/s.
    pub estimate_mps: [f32; 2],
    /// True forward and sideways body velocity at the capture, m/s.
    pub truth_mps: [f32; 2],
    /// True height when the estimate arrived, m.
    pub height_m: f64,
}

/// RMS error per axis of the raw estimates above [`ESTIMATE_CHECK_MIN_HEIGHT_M`], m/s (NaN
/// without one).
pub fn estimate_rmse_mps(checks: &[EstimateCheck]) -> f64 {
    let mut e2 = 0.0f64;
    let mut n = 0u64;
    for c in checks
        .iter()
        .filter(|c| c.height_m > ESTIMATE_CHECK_MIN_HEIGHT_M)
    {
        e2 += ((c.estimate_mps[0] - c.truth_mps[0]) as f64).powi(2)
            + ((c.estimate_mps[1] - c.truth_mps[1]) as f64).powi(2);
        n += 2;
    }
    rms(e2, n)
}

/// RMS error per axis of the autopilot's velocity estimate against the true velocity in the
/// heading frame, over the log rows with the avoidance FSM running and an estimate, m/s (NaN
/// without one).
pub fn velocity_rmse_mps(log: &[LogRow]) -> f64 {
    let mut e2 = 0.0f64;
    let mut n = 0u64;
    for row in log {
        if row.fsm_state.is_some() && row.vel_est.iter().all(|v| v.is_finite()) {
            for k in 0..2 {
                e2 += ((row.vel_est[k] - row.vel_true[k]) as f64).powi(2);
            }
            n += 2;
        }
    }
    rms(e2, n)
}

/// `sqrt(e2 / n)`, NaN for `n == 0`.
fn rms(e2: f64, n: u64) -> f64 {
    if n > 0 {
        (e2 / n as f64).sqrt()
    } else {
        f64::NAN
    }
}

/// Setpoint-tracking figures of one flight. A figure is NaN when the flight has no row it
/// applies to (no `Forward` phase, say).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackingFigures {
    /// RMS of the horizontal velocity error (true velocity in the heading frame minus the
    /// velocity setpoint, forward and sideways as one 2-D vector) while the FSM is in
    /// `Forward`, m/s.
    pub track_rmse_mps: f64,
    /// Mean true horizontal speed while the FSM is in `Hover` (its setpoint is zero), m/s.
    pub hover_speed_mps: f64,
    /// Mean true horizontal speed over the whole stop, `Brake` and `Hover` (the braking from
    /// forward flight included), m/s.
    pub stop_speed_mps: f64,
    /// RMS of true height minus the height setpoint in level flight, m.
    pub height_rmse_m: f64,
    /// RMS of the attitude estimate's roll and pitch error (as one 2-D vector) in level
    /// flight, deg.
    pub tilt_rmse_deg: f64,
    /// How far the drone strayed from where a `Hover` began, within the first
    /// [`HOVER_DRIFT_WINDOW_S`] of it: the largest horizontal distance over every `Hover` of
    /// the flight, m (the true position; the FSM asks for zero velocity there, so any distance
    /// is drift).
    pub hover_drift_m: f64,
}

/// The span of a `Hover` over which [`TrackingFigures::hover_drift_m`] looks, s.
pub const HOVER_DRIFT_WINDOW_S: f64 = 60.0;

impl TrackingFigures {
    /// The figures of a flight's log.
    pub fn from_log(log: &[LogRow]) -> Self {
        let mut track = Mean::default();
        let mut hover = Mean::default();
        let mut stop = Mean::default();
        let mut height = Mean::default();
        let mut tilt = Mean::default();
        // Where and when the current Hover began, and the largest drift of any.
        let mut hover_start: Option<(f64, [f32; 2])> = None;
        let mut drift: Option<f64> = None;
        for row in log.iter().filter(|r| r.mode == FlightMode::Flying) {
            let Some(state) = row.fsm_state else {
                hover_start = None;
                continue;
            };
            if state == FsmState::Hover {
                let (t0, p0) = *hover_start.get_or_insert((row.t_s, [row.pos[0], row.pos[1]]));
                if row.t_s - t0 <= HOVER_DRIFT_WINDOW_S {
                    let d = f64::from((row.pos[0] - p0[0]).hypot(row.pos[1] - p0[1]));
                    drift = Some(drift.map_or(d, |m: f64| m.max(d)));
                }
            } else {
                hover_start = None;
            }
            height.add(f64::from(row.pos[2] - row.height_sp_m).powi(2));
            let [er, ep] = row.tilt_err_deg.map(f64::from);
            tilt.add(er * er + ep * ep);
            let speed = f64::from(row.vel_true[0].hypot(row.vel_true[1]));
            match state {
                FsmState::Forward => {
                    let ef = f64::from(row.vel_true[0] - row.vel_sp[0]);
                    let es = f64::from(row.vel_true[1] - row.vel_sp[1]);
                    track.add(ef * ef + es * es);
                }
                FsmState::Hover => {
                    hover.add(speed);
                    stop.add(speed);
                }
                FsmState::Brake => stop.add(speed),
                FsmState::Check | FsmState::Turn => {}
            }
        }
        Self {
            track_rmse_mps: track.value().sqrt(),
            hover_speed_mps: hover.value(),
            stop_speed_mps: stop.value(),
            height_rmse_m: height.value().sqrt(),
            tilt_rmse_deg: tilt.value().sqrt(),
            hover_drift_m: drift.unwrap_or(f64::NAN),
        }
    }
}

/// A running mean (NaN while empty).
#[derive(Default)]
struct Mean {
    sum: f64,
    n: u64,
}

impl Mean {
    fn add(&mut self, x: f64) {
        self.sum += x;
        self.n += 1;
    }

    fn value(&self) -> f64 {
        if self.n == 0 {
            f64::NAN
        } else {
            self.sum / self.n as f64
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(mode: FlightMode, fsm: Option<FsmState>, v: [f32; 2], sp: [f32; 2], h: f32) -> LogRow {
        LogRow {
            t_s: 0.0,
            pos: [0.0, 0.0, h],
            yaw: 0.0,
            vel_true: v,
            vel_est: v,
            vel_sp: sp,
            height_sp_m: 1.0,
            vel_raw: v,
            obstacle_m: f32::NAN,
            closing_mps: f32::NAN,
            overrule_mps: f32::NAN,
            contact_s: f32::NAN,
            clearance_m: 1.0,
            fsm_state: fsm,
            mode,
            motors: [0.5; 4],
            tilt_err_deg: [0.0; 2],
        }
    }

    #[test]
    fn figures_come_from_level_flight_rows_of_their_phase() {
        use FlightMode::*;
        use FsmState::*;
        let log = [
            // Take-off (FSM not running) and landing rows are not level flight.
            row(Flying, None, [2.0, 0.0], [0.0, 0.0], 0.2),
            row(Landing, Some(Forward), [2.0, 0.0], [0.3, 0.0], 0.5),
            // Forward: errors (0.3, 0.4) and (0, 0) -> RMS of |e| = sqrt(0.25 / 2).
            row(Flying, Some(Forward), [0.6, 0.4], [0.3, 0.0], 1.1),
            row(Flying, Some(Forward), [0.3, 0.0], [0.3, 0.0], 0.9),
            // Brake: speed 0.9 (the stop only); Hover: speeds 0.5 and 0.1.
            row(Flying, Some(Brake), [0.0, 0.9], [0.0, 0.0], 1.0),
            row(Flying, Some(Hover), [0.3, 0.4], [0.0, 0.0], 1.0),
            row(Flying, Some(Hover), [0.0, 0.1], [0.0, 0.0], 1.0),
            row(Flying, Some(Check), [0.0, 0.0], [0.0, 0.0], 1.2),
        ];
        let f = TrackingFigures::from_log(&log);
        assert!(
            (f.track_rmse_mps - (0.25f64 / 2.0).sqrt()).abs() < 1e-6,
            "{f:?}"
        );
        assert!((f.hover_speed_mps - 0.3).abs() < 1e-6, "{f:?}");
        assert!((f.stop_speed_mps - 0.5).abs() < 1e-6, "{f:?}");
        // Heights 1.1, 0.9, 1.0, 1.0, 1.0, 1.2 against 1.0.
        let want = ((0.01 + 0.01 + 0.04) / 6.0f64).sqrt();
        assert!((f.height_rmse_m - want).abs() < 1e-6, "{f:?}");
    }

    #[test]
    fn a_phase_never_flown_is_nan() {
        let log = [row(
            FlightMode::Flying,
            Some(FsmState::Check),
            [0.0; 2],
            [0.0; 2],
            1.0,
        )];
        let f = TrackingFigures::from_log(&log);
        assert!(f.track_rmse_mps.is_nan() && f.hover_speed_mps.is_nan());
        assert!(f.hover_drift_m.is_nan());
        assert_eq!(f.height_rmse_m, 0.0);
    }

    #[test]
    fn hover_drift_is_the_largest_distance_from_each_hovers_start_within_its_window() {
        use FlightMode::Flying;
        use FsmState::*;
        let at = |t_s: f64, state: FsmState, x: f32, y: f32| LogRow {
            t_s,
            pos: [x, y, 1.0],
            ..row(Flying, Some(state), [0.0; 2], [0.0; 2], 1.0)
        };
        let w = HOVER_DRIFT_WINDOW_S;
        let log = [
            // The first hover drifts 0.5 m (3-4-5), then comes back.
            at(1.0, Hover, 1.0, 1.0),
            at(2.0, Hover, 1.3, 1.4),
            at(3.0, Hover, 1.0, 1.1),
            // Forward ends it; a new hover starts from where it is.
            at(4.0, Forward, 5.0, 5.0),
            at(5.0, Hover, 6.0, 6.0),
            at(5.0 + w, Hover, 6.2, 6.0),
            // Past the window: not counted.
            at(5.1 + w, Hover, 9.0, 6.0),
        ];
        let f = TrackingFigures::from_log(&log);
        assert!((f.hover_drift_m - 0.5).abs() < 1e-6, "{f:?}");
    }
}
