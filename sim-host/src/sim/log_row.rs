//! The flight log's row: what a flight records at 50 Hz, for the metrics, the plots and the
//! log files.

use protocol::{FlightMode, FsmState};

/// One log row (50 Hz).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LogRow {
    /// Time, s.
    pub t_s: f64,
    /// True position (x north, y east), m, and height, m.
    pub pos: [f32; 3],
    /// True yaw, rad.
    pub yaw: f32,
    /// True velocity in the body's heading frame: forward, sideways, m/s.
    pub vel_true: [f32; 2],
    /// Autopilot's velocity estimate, what guidance flies on (`Autopilot::velocity_estimate`:
    /// the velocity Kalman filter by default, the observer over the median-5 of the gated
    /// Edge-FS estimates in paper mode; predicted from the attitude in between): forward,
    /// sideways, m/s (NaN: none yet).
    pub vel_est: [f32; 2],
    /// Velocity setpoint: forward, sideways, m/s.
    pub vel_sp: [f32; 2],
    /// Height setpoint, m.
    pub height_sp_m: f32,
    /// Latest raw Edge-FS estimate received: forward, sideways, m/s (NaN: invalid).
    pub vel_raw: [f32; 2],
    /// Obstacle distance the autopilot holds, m (NaN: none).
    pub obstacle_m: f32,
    /// The autopilot's closing speed on that obstacle from its stereo distances (the range
    /// rate), m/s (NaN: none).
    pub closing_mps: f32,
    /// The forward velocity guidance flew on in place of the estimate's when the range rate
    /// overruled it, m/s (NaN: the estimate stood).
    pub overrule_mps: f32,
    /// Time to contact of the latest Edge-FS estimate (the flow's divergence), s (NaN: none,
    /// or the view does not expand).
    pub contact_s: f32,
    /// Clearance to the nearest wall/obstacle minus the drone radius, m.
    pub clearance_m: f32,
    /// FSM state (`None`: the state machine is not running).
    pub fsm_state: Option<FsmState>,
    /// Flight mode.
    pub mode: FlightMode,
    /// Motor throttles.
    pub motors: [f32; 4],
    /// Error of the autopilot's attitude estimate against the truth: roll, pitch, deg (each
    /// 0.6 deg is 0.1 m/s² of error in the velocity filter's model).
    pub tilt_err_deg: [f32; 2],
}
