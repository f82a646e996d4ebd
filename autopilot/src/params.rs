//! The autopilot's parameter table: every field of [`AutopilotConfig`] by name, kind, unit and
//! bounds ([`TABLE`]), read and written by index ([`get`], [`set`]) and checked as a whole
//! ([`validate`]).
//!
//! Array fields appear once per axis (`indi_kp_p`, `indi_kp_q`, `indi_kp_r`); durations are
//! `u32` microseconds; `fsm_variant` is 0 (the paper's FSM) or 1 (turn until clear);
//! `velocity_source` is 0 (the Kalman filter on the camera board's output), 1 (the paper's
//! median-5 and observer) or 2 (the Kalman filter on each frame's own fit); `fs_host_action` is
//! 0 (land), 1 (hold) or 2 (kill). The
//! defaults are [`AutopilotConfig::default`]'s. `indi_rate_hz` is read-only: the loop runs at
//! the IMU's [`crate::board::LOOP_RATE_HZ`] whatever it says.
//!
//! A configuration is accepted when every value is within its bounds and the values agree
//! with each other: the INDI filters are stable at the 512 Hz loop
//! ([`SecondOrderFilter::is_stable`]), the thrusts are ordered (arming <= minimum <= hover <=
//! maximum, arming <= blind landing < hover), the G1 clamps hold the G1 start values, the
//! landed height below the flight height and the vision height not above it, the clear distance above the
//! obstacle distance, and the estimate windows within the velocity filter's history. Anything
//! else is rejected with the parameter, the one it disagrees with and the reason
//! ([`Rejected`], its [`Conflict`]), and nothing changes.

use crate::config::AutopilotConfig;
use crate::estimation::VelocitySource;
use crate::failsafe::HostLossAction;
use crate::fsm::FsmVariant;
use crate::guidance::MAX_MEASUREMENT_DELAY;
use crate::indi::SecondOrderFilter;
use protocol::params::{Conflict, ParamField, ParamTable};
use protocol::{ParamEntry, ParamValue};
use timebase::Duration;

pub use protocol::params::Rejected;

impl ParamField for FsmVariant {
    fn to_param(self) -> ParamValue {
        ParamValue::U32(match self {
            FsmVariant::Paper => 0,
            FsmVariant::TurnUntilClear => 1,
        })
    }
    fn from_param(v: ParamValue) -> Option<Self> {
        match v {
            ParamValue::U32(0) => Some(FsmVariant::Paper),
            ParamValue::U32(1) => Some(FsmVariant::TurnUntilClear),
            _ => None,
        }
    }
}

impl ParamField for VelocitySource {
    fn to_param(self) -> ParamValue {
        ParamValue::U32(match self {
            VelocitySource::Kalman => 0,
            VelocitySource::MedianObserver => 1,
            VelocitySource::KalmanFits => 2,
        })
    }
    fn from_param(v: ParamValue) -> Option<Self> {
        match v {
            ParamValue::U32(0) => Some(VelocitySource::Kalman),
            ParamValue::U32(1) => Some(VelocitySource::MedianObserver),
            ParamValue::U32(2) => Some(VelocitySource::KalmanFits),
            _ => None,
        }
    }
}

impl ParamField for HostLossAction {
    fn to_param(self) -> ParamValue {
        ParamValue::U32(match self {
            HostLossAction::Land => 0,
            HostLossAction::Hold => 1,
            HostLossAction::Kill => 2,
        })
    }
    fn from_param(v: ParamValue) -> Option<Self> {
        match v {
            ParamValue::U32(0) => Some(HostLossAction::Land),
            ParamValue::U32(1) => Some(HostLossAction::Hold),
            ParamValue::U32(2) => Some(HostLossAction::Kill),
            _ => None,
        }
    }
}

const PI: f32 = core::f32::consts::PI;
const LOOP_HZ: f32 = crate::board::LOOP_RATE_HZ as f32;

protocol::param_table! {
    /// The autopilot's parameters, in the order they are listed and stored.
    pub TABLE, ACCESS: AutopilotConfig {
    "att_kp": F32 ["1/s"] 0.0, 10.0, true => |c| c.attitude.kp;
    "att_ki": F32 ["1/s2"] 0.0, 1.0, true => |c| c.attitude.ki;
    "att_max_bias": F32 ["rad/s"] 0.0, 1.0, true => |c| c.attitude.max_bias;
    "att_accel_gate": F32 ["-"] 0.0, 1.0, true => |c| c.attitude.accel_gate;
    "indi_rate_hz": F32 ["Hz"] LOOP_HZ, LOOP_HZ, false => |c| c.indi.rate_hz;
    "indi_g1_p": F32 ["rad/s2"] 0.1, 50_000.0, true => |c| c.indi.g1[0];
    "indi_g1_q": F32 ["rad/s2"] 0.1, 50_000.0, true => |c| c.indi.g1[1];
    "indi_g1_r": F32 ["rad/s2"] 0.1, 50_000.0, true => |c| c.indi.g1[2];
    "indi_g2": F32 ["rad/s2"] 0.0, 1.0e6, true => |c| c.indi.g2;
    "indi_filter_omega": F32 ["rad/s"] 1.0, 1_000.0, true => |c| c.indi.filter_omega;
    "indi_filter_zeta": F32 ["-"] 0.1, 2.0, true => |c| c.indi.filter_zeta;
    "indi_actuator_alpha": F32 ["-"] 0.001, 1.0, true => |c| c.indi.actuator_alpha;
    "indi_kp_p": F32 ["1/s2"] 0.0, 1_000.0, true => |c| c.indi.kp[0];
    "indi_kp_q": F32 ["1/s2"] 0.0, 1_000.0, true => |c| c.indi.kp[1];
    "indi_kp_r": F32 ["1/s2"] 0.0, 1_000.0, true => |c| c.indi.kp[2];
    "indi_kd_p": F32 ["1/s"] 0.0, 200.0, true => |c| c.indi.kd[0];
    "indi_kd_q": F32 ["1/s"] 0.0, 200.0, true => |c| c.indi.kd[1];
    "indi_kd_r": F32 ["1/s"] 0.0, 200.0, true => |c| c.indi.kd[2];
    "indi_max_accel_p": F32 ["rad/s2"] 1.0, 5_000.0, true => |c| c.indi.max_accel_ref[0];
    "indi_max_accel_q": F32 ["rad/s2"] 1.0, 5_000.0, true => |c| c.indi.max_accel_ref[1];
    "indi_max_accel_r": F32 ["rad/s2"] 1.0, 5_000.0, true => |c| c.indi.max_accel_ref[2];
    "indi_max_cmd_p": F32 ["-"] 0.0, 1.0, true => |c| c.indi.max_cmd[0];
    "indi_max_cmd_q": F32 ["-"] 0.0, 1.0, true => |c| c.indi.max_cmd[1];
    "indi_max_cmd_r": F32 ["-"] 0.0, 1.0, true => |c| c.indi.max_cmd[2];
    "indi_arming_thrust": F32 ["-"] 0.0, 0.5, true => |c| c.indi.arming_thrust;
    "indi_adapt": Bool ["-"] false, true, true => |c| c.indi.adapt;
    "indi_mu_g1_p": F32 ["-"] 0.0, 0.1, true => |c| c.indi.mu_g1[0];
    "indi_mu_g1_q": F32 ["-"] 0.0, 0.1, true => |c| c.indi.mu_g1[1];
    "indi_mu_g1_r": F32 ["-"] 0.0, 0.1, true => |c| c.indi.mu_g1[2];
    "indi_mu_g2": F32 ["-"] 0.0, 0.1, true => |c| c.indi.mu_g2;
    "indi_adapt_eps": F32 ["1/s2"] 1.0e-6, 10.0, true => |c| c.indi.adapt_eps;
    "indi_adapt_omega": F32 ["rad/s"] 1.0, 1_000.0, true => |c| c.indi.adapt_omega;
    "indi_adapt_zeta": F32 ["-"] 0.1, 2.0, true => |c| c.indi.adapt_zeta;
    "indi_g1_min": F32 ["rad/s2"] 0.1, 50_000.0, true => |c| c.indi.g1_min;
    "indi_g1_max": F32 ["rad/s2"] 0.1, 50_000.0, true => |c| c.indi.g1_max;
    "indi_g2_max": F32 ["rad/s2"] 0.0, 1.0e6, true => |c| c.indi.g2_max;
    "height_hover_thrust": F32 ["-"] 0.05, 0.95, true => |c| c.height.hover_thrust;
    "height_kp": F32 ["1/m"] 0.0, 5.0, true => |c| c.height.kp;
    "height_ki": F32 ["1/(m s)"] 0.0, 5.0, true => |c| c.height.ki;
    "height_kd": F32 ["s/m"] 0.0, 5.0, true => |c| c.height.kd;
    "height_max_integral": F32 ["-"] 0.0, 1.0, true => |c| c.height.max_integral;
    "height_min_thrust": F32 ["-"] 0.0, 1.0, true => |c| c.height.min_thrust;
    "height_max_thrust": F32 ["-"] 0.0, 1.0, true => |c| c.height.max_thrust;
    "height_rate_tau": F32 ["s"] 0.001, 2.0, true => |c| c.height.rate_tau_s;
    "height_max_tilt_factor": F32 ["-"] 1.0, 3.0, true => |c| c.height.max_tilt_factor;
    "vert_accel_noise": F32 ["m/s2"] 0.001, 10.0, true => |c| c.vertical.accel_noise;
    "vert_baro_offset_walk": F32 ["m/s^0.5"] 0.0, 1.0, true => |c| c.vertical.baro_offset_walk;
    "vert_baro_noise": F32 ["m"] 0.001, 10.0, true => |c| c.vertical.baro_noise_m;
    "vert_fix_noise": F32 ["m"] 0.0001, 1.0, true => |c| c.vertical.fix_noise_m;
    "vert_ground_effect_h": F32 ["m"] 0.0, 2.0, true => |c| c.vertical.ground_effect_height_m;
    "vert_ground_effect_k": F32 ["-"] 1.0, 100.0, true => |c| c.vertical.ground_effect_noise_factor;
    "vert_gate_sigma": F32 ["-"] 1.0, 100.0, true => |c| c.vertical.gate_sigma;
    "ext_pos_enable": Bool ["-"] false, true, true => |c| c.vertical.external_fixes;
    "guid_kp": F32 ["rad s/m"] 0.0, 2.0, true => |c| c.guidance.kp;
    "guid_ki": F32 ["rad/m"] 0.0, 2.0, true => |c| c.guidance.ki;
    "guid_max_bank": F32 ["rad"] 0.0, 0.6, true => |c| c.guidance.max_bank_rad;
    "guid_max_integral": F32 ["rad"] 0.0, 0.3, true => |c| c.guidance.max_integral_rad;
    "guid_max_accel": F32 ["m/s2"] 0.0, 5.0, true => |c| c.guidance.max_accel_mps2;
    "guid_response_lag": F32 ["s"] 0.0, 1.0, true => |c| c.guidance.response_lag_s;
    "ff_threshold": F32 ["m"] 0.0, 5.0, true => |c| c.force_field.threshold_m;
    "ff_gain": F32 ["1/s"] 0.0, 10.0, true => |c| c.force_field.gain;
    "ff_max_speed": F32 ["m/s"] 0.0, 2.0, true => |c| c.force_field.max_speed_mps;
    "fsm_variant": U32 ["enum"] 0, 1, true => |c| c.fsm.variant;
    "fsm_obstacle_dist": F32 ["m"] 0.1, 5.0, true => |c| c.fsm.obstacle_distance_m;
    "fsm_forward_speed": F32 ["m/s"] 0.0, 2.0, true => |c| c.fsm.forward_speed_mps;
    "fsm_hover_time_us": U32 ["us"] 0, 10_000_000, true => |c| c.fsm.hover_time;
    "fsm_turn_angle": F32 ["rad"] 0.0, PI, true => |c| c.fsm.turn_angle_rad;
    "fsm_turn_rate": F32 ["rad/s"] 0.05, 5.0, true => |c| c.fsm.turn_rate_radps;
    "fsm_turn_tolerance": F32 ["rad"] 0.01, 1.0, true => |c| c.fsm.turn_tolerance_rad;
    "fsm_turn_timeout_us": U32 ["us"] 100_000, 20_000_000, true => |c| c.fsm.turn_timeout;
    "fsm_clear_dist": F32 ["m"] 0.1, 10.0, true => |c| c.fsm.clear_distance_m;
    "fsm_clear_confirm": U32 ["-"] 1, 50, true => |c| c.fsm.clear_confirm;
    "fsm_reading_timeout_us": U32 ["us"] 10_000, 5_000_000, true => |c| c.fsm.reading_timeout;
    "fsm_min_clear_depth": F32 ["-"] 0.0, 1.0, true => |c| c.fsm.min_clear_depth;
    "fsm_block_confirm": U32 ["-"] 1, 50, true => |c| c.fsm.block_confirm;
    "fsm_approach_dist": F32 ["m"] 0.0, 10.0, true => |c| c.fsm.approach_distance_m;
    "fsm_approach_speed": F32 ["m/s"] 0.0, 2.0, true => |c| c.fsm.approach_speed_mps;
    "fsm_brake_speed": F32 ["m/s"] 0.0, 1.0, true => |c| c.fsm.brake_speed_mps;
    "fsm_brake_timeout_us": U32 ["us"] 0, 10_000_000, true => |c| c.fsm.brake_timeout;
    "fsm_check_timeout_us": U32 ["us"] 100_000, 30_000_000, true => |c| c.fsm.check_timeout;
    "fsm_max_searches": U32 ["-"] 1, 60, true => |c| c.fsm.max_searches;
    "fsm_forward_timeout_us": U32 ["us"] 1_000_000, 600_000_000, true => |c| c.fsm.forward_timeout;
    "fsm_search_timeout_us": U32 ["us"] 500_000, 60_000_000, true => |c| c.fsm.search_timeout;
    "fsm_contact_time": F32 ["s"] 0.0, 10.0, true => |c| c.fsm.contact_time_s;
    "fs_estimate_timeout_us": U32 ["us"] 40_000, 5_000_000, true => |c| c.failsafe.estimate_timeout;
    "fs_hover_land_us": U32 ["us"] 0, 30_000_000, true => |c| c.failsafe.hover_before_land;
    "fs_imu_timeout_us": U32 ["us"] 2_000, 100_000, true => |c| c.failsafe.imu_timeout;
    "fs_height_timeout_us": U32 ["us"] 20_000, 5_000_000, true => |c| c.failsafe.height_timeout;
    "fs_host_timeout_us": U32 ["us"] 200_000, 60_000_000, true => |c| c.failsafe.host_timeout;
    "fs_host_action": U32 ["enum"] 0, 2, true => |c| c.failsafe.host_action;
    "fs_autonomous_arm": Bool ["-"] false, true, true => |c| c.failsafe.autonomous_arm;
    "target_height": F32 ["m"] 0.2, 3.0, true => |c| c.setpoints.target_height_m;
    "climb_rate": F32 ["m/s"] 0.05, 2.0, true => |c| c.setpoints.climb_rate_mps;
    "land_rate": F32 ["m/s"] 0.05, 2.0, true => |c| c.setpoints.land_rate_mps;
    "blind_land_rate": F32 ["m/s"] 0.05, 2.0, true => |c| c.setpoints.blind_land_rate_mps;
    "landed_height": F32 ["m"] 0.01, 0.5, true => |c| c.setpoints.landed_height_m;
    "landed_time_us": U32 ["us"] 0, 5_000_000, true => |c| c.setpoints.landed_time;
    "land_timeout_us": U32 ["us"] 1_000_000, 120_000_000, true => |c| c.setpoints.land_timeout;
    "land_cut_height": F32 ["m"] 0.0, 1.0, true => |c| c.setpoints.land_cut_height_m;
    "ground_thrust_ratio": F32 ["-"] 0.0, 1.0, true => |c| c.setpoints.ground_thrust_ratio;
    "ground_min_accel": F32 ["g"] 0.5, 1.0, true => |c| c.setpoints.ground_min_specific_force;
    "baro_stuck_us": U32 ["us"] 40_000, 10_000_000, true => |c| c.vertical.baro_stuck;
    "fsm_start_height_tol": F32 ["m"] 0.01, 1.0, true => |c| c.setpoints.fsm_start_height_tolerance_m;
    "blind_land_thrust": F32 ["-"] 0.0, 1.0, true => |c| c.setpoints.blind_land_thrust;
    "blind_land_time_us": U32 ["us"] 0, 20_000_000, true => |c| c.setpoints.blind_land_time;
    "min_quality": U32 ["-"] 0, 255, true => |c| c.estimation.min_quality;
    "median_reset_gap_us": U32 ["us"] 40_000, 5_000_000, true => |c| c.estimation.median_reset_gap;
    "max_estimate": F32 ["m/s"] 0.1, 20.0, true => |c| c.estimation.max_estimate_mps;
    "max_velocity_jump": F32 ["m/s"] 0.05, 5.0, true => |c| c.estimation.max_velocity_jump_mps;
    "max_outliers": U32 ["-"] 0, 20, true => |c| c.estimation.max_consecutive_outliers;
    "min_vision_height": F32 ["m"] 0.0, 2.0, true => |c| c.estimation.min_vision_height_m;
    "max_vision_climb": F32 ["m/s"] 0.05, 5.0, true => |c| c.estimation.max_vision_climb_mps;
    "vision_climb_depth": F32 ["-"] 0.0, 1.0, true => |c| c.estimation.vision_climb_min_depth;
    "min_valid_run": U32 ["-"] 1, 20, true => |c| c.estimation.min_valid_run;
    "velocity_max_age_us": U32 ["us"] 0, 10_000_000, true => |c| c.estimation.velocity_max_age;
    "obs_drag": F32 ["1/s"] 0.0, 5.0, true => |c| c.estimation.observer.drag_per_s;
    "obs_velocity_gain": F32 ["-"] 0.0, 1.0, true => |c| c.estimation.observer.velocity_gain;
    "obs_bias_gain": F32 ["-"] 0.0, 1.0, true => |c| c.estimation.observer.bias_gain;
    "obs_max_bias": F32 ["m/s2"] 0.0, 5.0, true => |c| c.estimation.observer.max_bias_mps2;
    "obs_delay_us": U32 ["us"] 0, MAX_MEASUREMENT_DELAY.as_micros() as u32, true => |c| c.estimation.observer.measurement_delay;
    "obs_max_tilt": F32 ["rad"] 0.0, 1.0, true => |c| c.estimation.observer.max_tilt_rad;
    "velocity_source": U32 ["enum"] 0, 2, true => |c| c.estimation.velocity_source;
    "vkf_drag": F32 ["1/s"] 0.0, 5.0, true => |c| c.estimation.velocity_kf.drag_per_s;
    "vkf_accel_noise": F32 ["m/s2"] 0.001, 10.0, true => |c| c.estimation.velocity_kf.accel_noise;
    "vkf_bias_walk": F32 ["m/s2"] 0.0, 1.0, true => |c| c.estimation.velocity_kf.bias_walk;
    "vkf_bias_sigma0": F32 ["m/s2"] 0.001, 5.0, true => |c| c.estimation.velocity_kf.initial_bias_sigma;
    "vkf_max_bias": F32 ["m/s2"] 0.0, 5.0, true => |c| c.estimation.velocity_kf.max_bias_mps2;
    "vkf_sigma_best": F32 ["m/s"] 0.001, 2.0, true => |c| c.estimation.velocity_kf.sigma_best_mps;
    "vkf_min_quality": U32 ["-"] 1, 255, true => |c| c.estimation.velocity_kf.min_quality;
    "vkf_gate_sigmas": F32 ["-"] 1.0, 100.0, true => |c| c.estimation.velocity_kf.gate_sigmas;
    "vkf_reinit_after": U32 ["-"] 1, 50, true => |c| c.estimation.velocity_kf.reinit_after;
    "vkf_max_tilt": F32 ["rad"] 0.0, 1.0, true => |c| c.estimation.velocity_kf.max_tilt_rad;
    "vkf_room_bias": Bool ["-"] false, true, true => |c| c.estimation.velocity_kf.bias_in_room_frame;
    "est_horizon_us": U32 ["us"] 0, 1_000_000, true => |c| c.estimation.estimate_horizon;
    "est_link_us": U32 ["us"] 0, 100_000, true => |c| c.estimation.estimate_link;
    "est_filter_lag_us": U32 ["us"] 0, 500_000, true => |c| c.estimation.estimate_filter_lag;
    "fit_horizon_us": U32 ["us"] 0, 1_000_000, true => |c| c.estimation.fit_horizon;
    "max_yaw_rate": F32 ["rad/s"] 0.05, 10.0, true => |c| c.estimation.max_yaw_rate_radps;
    "yaw_settle_us": U32 ["us"] 0, 2_000_000, true => |c| c.estimation.yaw_settle;
    "gyro_cal_samples": U32 ["-"] 1, 4_096, true => |c| c.gyro_calibration.samples;
    "gyro_cal_still": F32 ["rad/s"] 0.001, 1.0, true => |c| c.gyro_calibration.still_radps;
    "bat_arm_v": F32 ["V"] 0.0, 5.0, true => |c| c.battery.arm_v;
    "bat_low_v": F32 ["V"] 0.0, 5.0, true => |c| c.battery.low_v;
    "bat_critical_v": F32 ["V"] 0.0, 5.0, true => |c| c.battery.critical_v;
    "bat_resistance": F32 ["ohm"] 0.0, 2.0, true => |c| c.battery.resistance_ohm;
    "bat_full_current": F32 ["A"] 0.0, 100.0, true => |c| c.battery.full_throttle_current_a;
    "bat_filter_tau_us": U32 ["us"] 0, 30_000_000, true => |c| c.battery.filter_tau;
    "vert_camera_climb": Bool ["-"] false, true, true => |c| c.vertical.camera_climb;
    "vert_climb_noise": F32 ["m/s"] 0.001, 10.0, true => |c| c.vertical.climb_noise_mps;
    }
}

/// The autopilot's table with its accessors, defaults and consistency check ([`validate`]).
pub const AUTOPILOT: ParamTable<AutopilotConfig> = ParamTable {
    specs: TABLE,
    access: ACCESS,
    defaults: <AutopilotConfig as Default>::default,
    consistent,
};

/// Number of parameters.
pub const COUNT: usize = TABLE.len();

/// Version of [`TABLE`] for flash records: see [`protocol::params::table_hash`].
pub const TABLE_HASH: u32 = AUTOPILOT.hash();

/// Index of the parameter called `name`.
pub fn index_of(name: &str) -> Option<usize> {
    AUTOPILOT.index_of(name)
}

/// The value of parameter `index` in `cfg`.
pub fn get(cfg: &AutopilotConfig, index: usize) -> Option<ParamValue> {
    AUTOPILOT.get(cfg, index)
}

/// Writes parameter `index` of `cfg`, if the value has its kind, lies within its bounds and
/// leaves the configuration consistent ([`validate`]); otherwise `cfg` is unchanged.
pub fn set(cfg: &mut AutopilotConfig, index: usize, value: ParamValue) -> Result<(), Rejected> {
    AUTOPILOT.set(cfg, index, value)
}

/// Writes parameter `name` of `cfg` (see [`set`]).
pub fn set_by_name(
    cfg: &mut AutopilotConfig,
    name: &str,
    value: ParamValue,
) -> Result<(), Rejected> {
    AUTOPILOT.set_by_name(cfg, name, value)
}

/// Checks a whole configuration: every value within its bounds (read-only ones at their fixed
/// value), and the values consistent with each other.
pub fn validate(cfg: &AutopilotConfig) -> Result<(), Rejected> {
    AUTOPILOT.validate(cfg)
}

/// Values that only make sense together: the first pair at fault, both named.
fn consistent(cfg: &AutopilotConfig) -> Result<(), Conflict> {
    let fail = |name, other, reason| Err(Conflict::new(name, other, reason));
    let i = &cfg.indi;
    // The INDI filters step at the loop rate, not at the configured one (read-only, fixed).
    let dt = 1.0 / LOOP_HZ;
    if !SecondOrderFilter::is_stable(i.filter_omega, i.filter_zeta, dt) {
        return fail(
            "indi_filter_omega",
            "indi_filter_zeta",
            "makes the 512 Hz filter unstable with this",
        );
    }
    if !SecondOrderFilter::is_stable(i.adapt_omega, i.adapt_zeta, dt) {
        return fail(
            "indi_adapt_omega",
            "indi_adapt_zeta",
            "makes the 512 Hz filter unstable with this",
        );
    }
    let h = &cfg.height;
    if h.hover_thrust < h.min_thrust {
        return fail(
            "height_hover_thrust",
            "height_min_thrust",
            "must not be below",
        );
    }
    if h.hover_thrust > h.max_thrust {
        return fail(
            "height_hover_thrust",
            "height_max_thrust",
            "must not exceed",
        );
    }
    // Below the arming thrust the INDI holds its commands at zero (on the ground): any thrust
    // commanded in the air must stay above it.
    if h.min_thrust < i.arming_thrust {
        return fail(
            "height_min_thrust",
            "indi_arming_thrust",
            "must not be below",
        );
    }
    // A landing without a height descends on this thrust alone: below hover, and in the air.
    if cfg.setpoints.blind_land_thrust >= h.hover_thrust {
        return fail("blind_land_thrust", "height_hover_thrust", "must be below");
    }
    if cfg.setpoints.blind_land_thrust < i.arming_thrust {
        return fail(
            "blind_land_thrust",
            "indi_arming_thrust",
            "must not be below",
        );
    }
    if i.g1_min > i.g1_max {
        return fail("indi_g1_min", "indi_g1_max", "must not exceed");
    }
    const G1: [&str; 3] = ["indi_g1_p", "indi_g1_q", "indi_g1_r"];
    for (g, name) in i.g1.iter().zip(G1) {
        if *g < i.g1_min {
            return fail(name, "indi_g1_min", "must not be below");
        }
        if *g > i.g1_max {
            return fail(name, "indi_g1_max", "must not exceed");
        }
    }
    if i.g2 > i.g2_max {
        return fail("indi_g2", "indi_g2_max", "must not exceed");
    }
    // Battery thresholds in order: arming above landing, landing above landing at once.
    if cfg.battery.critical_v > cfg.battery.low_v {
        return fail("bat_critical_v", "bat_low_v", "must not exceed");
    }
    if cfg.battery.low_v > cfg.battery.arm_v {
        return fail("bat_low_v", "bat_arm_v", "must not exceed");
    }
    if cfg.fsm.clear_distance_m < cfg.fsm.obstacle_distance_m {
        return fail("fsm_clear_dist", "fsm_obstacle_dist", "must not be below");
    }
    if cfg.setpoints.landed_height_m >= cfg.setpoints.target_height_m {
        return fail("landed_height", "target_height", "must be below");
    }
    // Above the flight height no estimate would ever be fused.
    if cfg.estimation.min_vision_height_m > cfg.setpoints.target_height_m {
        return fail("min_vision_height", "target_height", "must not exceed");
    }
    // A landing that times out cuts the motors below this height: below the flight height.
    if cfg.setpoints.land_cut_height_m >= cfg.setpoints.target_height_m {
        return fail("land_cut_height", "target_height", "must be below");
    }
    // The oldest estimate window (the longest processing time an estimate can report, then the
    // link, the output filter's lag and the window itself) must lie inside the velocity
    // filter's history, or every estimate would be ignored.
    let longest_processing = Duration::from_micros(u64::from(u16::MAX));
    let oldest_window = longest_processing
        + cfg.estimation.estimate_link
        + cfg.estimation.estimate_filter_lag
        + cfg.estimation.estimate_horizon;
    if oldest_window > crate::velocity_kf::MAX_WINDOW_AGE {
        return fail(
            "est_horizon_us",
            "est_filter_lag_us",
            "reaches past the velocity filter's history with this",
        );
    }
    let oldest_fit_window =
        longest_processing + cfg.estimation.estimate_link + cfg.estimation.fit_horizon;
    if oldest_fit_window > crate::velocity_kf::MAX_WINDOW_AGE {
        return fail(
            "fit_horizon_us",
            "est_link_us",
            "reaches past the velocity filter's history with this",
        );
    }
    Ok(())
}

/// Parameter `index` of `cfg` as it goes on the wire.
pub fn entry(cfg: &AutopilotConfig, index: usize) -> Option<ParamEntry> {
    AUTOPILOT.entry(cfg, index)
}

/// Every value of `cfg` in table order (for a flash record).
pub fn values(cfg: &AutopilotConfig) -> [ParamValue; COUNT] {
    let mut out = [ParamValue::U32(0); COUNT];
    AUTOPILOT.values(cfg, &mut out);
    out
}

/// Bytes of the autopilot's flash record.
pub const RECORD_BYTES: usize = protocol::params::record_bytes(COUNT);

// A save encodes into a buffer of `MAX_RECORD_BYTES`.
const _: () = assert!(COUNT <= protocol::params::MAX_PARAMS);

/// Writes `cfg`'s values as a flash record ([`protocol::params::encode_record`]) into `out`;
/// returns its length, [`RECORD_BYTES`].
pub fn encode_record(
    cfg: &AutopilotConfig,
    out: &mut [u8],
) -> Result<usize, protocol::params::RecordError> {
    AUTOPILOT.encode_record(cfg, out)
}

/// The configuration a flash record holds: every value from the record when the whole record
/// is good and the values agree ([`validate`]); otherwise the defaults and why (a blank
/// sector, a corrupt or older record, another table, a value out of bounds; an inconsistent
/// set of values is reported as [`protocol::params::RecordError::BadValue`] of the parameter
/// at fault).
pub fn decode_record(bytes: &[u8]) -> (AutopilotConfig, Result<(), protocol::params::RecordError>) {
    AUTOPILOT.decode_record(bytes)
}

/// The record that puts `key` into a board's parameter slots as they are (read over SWD by
/// `cargo xtask flash --key`): the newest good record's values (the defaults on erased
/// flash), numbered one after it, for the other slot ([`ParamTable::record_with_key`]).
/// Returns the slot to write and the record's length in `out`.
pub fn record_with_key(
    slots: &dyn protocol::params::RecordStore,
    key: &protocol::signing::KeyRecord,
    out: &mut [u8],
) -> Result<(usize, usize), protocol::params::RecordError> {
    AUTOPILOT.record_with_key(slots, key, out)
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use protocol::params::RecordError;
    use protocol::ParamError;
    use std::string::{String, ToString};

    #[test]
    fn a_saved_configuration_loads_back_and_a_bad_record_means_defaults() {
        let mut c = AutopilotConfig::default();
        set_by_name(&mut c, "guid_kp", ParamValue::F32(0.3)).unwrap();
        set_by_name(&mut c, "indi_adapt", ParamValue::Bool(false)).unwrap();
        set_by_name(&mut c, "fsm_variant", ParamValue::U32(1)).unwrap();
        // A flash sector: the record, then erased bytes.
        let mut sector = [0xffu8; 1024];
        assert_eq!(encode_record(&c, &mut sector), Ok(RECORD_BYTES));
        assert_eq!(decode_record(&sector), (c, Ok(())));

        let d = AutopilotConfig::default();
        assert_eq!(decode_record(&[0xff; 1024]), (d, Err(RecordError::Blank)));
        let mut torn = sector;
        torn[RECORD_BYTES / 2] ^= 0x10;
        assert_eq!(decode_record(&torn), (d, Err(RecordError::BadCrc)));
        let mut older = sector;
        older[4] = 0;
        assert_eq!(decode_record(&older).0, d);
        // Consistent values only: a record whose hover thrust is below its minimum thrust
        // (each value within its own bounds) is refused as a whole.
        let mut bad = c;
        bad.height.hover_thrust = 0.1;
        protocol::params::encode_record(TABLE, &values(&bad), &mut sector).unwrap();
        let at = index_of("height_hover_thrust").unwrap() as u16;
        assert_eq!(decode_record(&sector), (d, Err(RecordError::BadValue(at))));
    }

    #[test]
    fn the_table_is_well_formed_and_the_defaults_are_valid() {
        assert_eq!(TABLE.len(), ACCESS.len());
        let d = AutopilotConfig::default();
        validate(&d).unwrap();
        for (i, spec) in TABLE.iter().enumerate() {
            assert!(
                spec.name.len() <= protocol::params::PARAM_NAME_LEN,
                "{}",
                spec.name
            );
            assert!(
                spec.unit.len() <= protocol::params::PARAM_UNIT_LEN,
                "{}",
                spec.unit
            );
            assert_eq!(index_of(spec.name), Some(i), "{} appears twice", spec.name);
            assert_eq!(get(&d, i).unwrap().kind(), spec.kind, "{}", spec.name);
        }
    }

    #[test]
    fn every_writable_parameter_reaches_its_field_and_only_it() {
        let d = AutopilotConfig::default();
        for (i, spec) in TABLE.iter().enumerate() {
            if !spec.writable {
                let mut c = d;
                let v = get(&d, i).unwrap();
                assert_eq!(set(&mut c, i, v).unwrap_err().error, ParamError::ReadOnly);
                continue;
            }
            // Set a bound that differs from the default (or the other one).
            let v = if get(&d, i) == Some(spec.max) {
                spec.min
            } else {
                spec.max
            };
            let mut c = d;
            match set(&mut c, i, v) {
                Ok(()) => {
                    assert_eq!(get(&c, i), Some(v), "{}", spec.name);
                    assert_ne!(c, d, "{} changed nothing", spec.name);
                    for j in (0..COUNT).filter(|&j| j != i) {
                        assert_eq!(
                            get(&c, j),
                            get(&d, j),
                            "{} changed {}",
                            spec.name,
                            TABLE[j].name
                        );
                    }
                }
                Err(r) => {
                    assert_eq!(r.error, ParamError::Inconsistent, "{}", spec.name);
                    assert_eq!(c, d);
                }
            }
        }
    }

    #[test]
    fn bad_values_are_rejected_with_the_parameter_and_reason() {
        let mut c = AutopilotConfig::default();
        let i = index_of("target_height").unwrap();
        let r = set(&mut c, i, ParamValue::F32(10.0)).unwrap_err();
        assert_eq!((r.index, r.error), (Some(i), ParamError::OutOfBounds));
        assert_eq!(r.name(), "target_height");
        let r = set(&mut c, i, ParamValue::F32(f32::NAN)).unwrap_err();
        assert_eq!(r.error, ParamError::OutOfBounds);
        let r = set(&mut c, i, ParamValue::U32(1)).unwrap_err();
        assert_eq!(r.error, ParamError::WrongKind);
        let r = set_by_name(&mut c, "no_such_thing", ParamValue::U32(1)).unwrap_err();
        assert_eq!(r.error, ParamError::UnknownName);
        // Within bounds but below the minimum thrust.
        let r = set_by_name(&mut c, "height_hover_thrust", ParamValue::F32(0.1)).unwrap_err();
        assert_eq!(
            (r.name(), r.error),
            ("height_hover_thrust", ParamError::Inconsistent)
        );
        let r = set_by_name(&mut c, "fsm_variant", ParamValue::U32(2)).unwrap_err();
        assert_eq!(r.error, ParamError::OutOfBounds);
        assert_eq!(c, AutopilotConfig::default());
        set_by_name(&mut c, "fsm_variant", ParamValue::U32(1)).unwrap();
        assert_eq!(c.fsm.variant, FsmVariant::TurnUntilClear);
        set_by_name(&mut c, "fs_hover_land_us", ParamValue::U32(1_500_000)).unwrap();
        assert_eq!(c.failsafe.hover_before_land, Duration::from_millis(1_500));
    }

    #[test]
    fn an_estimate_window_older_than_the_filter_history_is_inconsistent() {
        let mut c = AutopilotConfig::default();
        // Each within its bounds, together reaching past the velocity filter's history (where
        // every estimate would be ignored and the drone would dead-reckon into a wall).
        set_by_name(&mut c, "est_horizon_us", ParamValue::U32(900_000)).unwrap();
        set_by_name(&mut c, "est_filter_lag_us", ParamValue::U32(150_000)).unwrap();
        let r = set_by_name(&mut c, "est_horizon_us", ParamValue::U32(1_000_000)).unwrap_err();
        assert_eq!(
            (r.name(), r.error),
            ("est_horizon_us", ParamError::Inconsistent)
        );
        let r = set_by_name(&mut c, "est_filter_lag_us", ParamValue::U32(300_000)).unwrap_err();
        assert_eq!(r.error, ParamError::Inconsistent);
        assert_eq!(c.estimation.estimate_filter_lag, Duration::from_millis(150));
        assert!(validate(&AutopilotConfig::default()).is_ok());
    }

    /// Sets `name` to `v` on the defaults and returns the refusal as a user reads it.
    fn refusal(name: &str, v: ParamValue) -> (Rejected, String) {
        let mut c = AutopilotConfig::default();
        let r = set_by_name(&mut c, name, v).unwrap_err();
        assert_eq!(c, AutopilotConfig::default(), "{name}: nothing changes");
        assert_eq!(r.error, ParamError::Inconsistent, "{name}");
        (r, r.to_string())
    }

    #[test]
    fn dependent_bounds_are_refused_naming_both_parameters() {
        // Each value within its own bounds; the pair is what fails.
        let cases: [(&str, ParamValue, &str); 8] = [
            // Semi-implicit Euler at 1/512 s diverges there (each alone is allowed).
            (
                "indi_filter_omega",
                ParamValue::F32(500.0),
                "indi_filter_zeta",
            ),
            (
                "indi_adapt_omega",
                ParamValue::F32(900.0),
                "indi_adapt_zeta",
            ),
            (
                "blind_land_thrust",
                ParamValue::F32(0.8),
                "height_hover_thrust",
            ),
            (
                "blind_land_thrust",
                ParamValue::F32(0.05),
                "indi_arming_thrust",
            ),
            (
                "height_min_thrust",
                ParamValue::F32(0.05),
                "indi_arming_thrust",
            ),
            (
                "indi_arming_thrust",
                ParamValue::F32(0.3),
                "height_min_thrust",
            ),
            ("min_vision_height", ParamValue::F32(1.5), "target_height"),
            ("fsm_obstacle_dist", ParamValue::F32(4.0), "fsm_clear_dist"),
        ];
        for (name, v, other) in cases {
            let (r, text) = refusal(name, v);
            assert_eq!(r.name(), name);
            let c = r.conflict.expect("a conflict names the pair");
            assert!(
                [c.name, c.other].contains(&name) && [c.name, c.other].contains(&other),
                "{name}: {c:?}"
            );
            assert!(text.contains(name) && text.contains(other), "{text}");
        }
        // The zeta half of the filter pair is refused the same way.
        let mut c = AutopilotConfig::default();
        set_by_name(&mut c, "indi_filter_omega", ParamValue::F32(300.0)).unwrap();
        let r = set_by_name(&mut c, "indi_filter_zeta", ParamValue::F32(2.0)).unwrap_err();
        assert_eq!(r.name(), "indi_filter_zeta");
        assert!(r.to_string().contains("indi_filter_omega"), "{r}");
        assert_eq!(c.indi.filter_zeta, 0.55);
    }

    #[test]
    fn a_whole_configuration_out_of_bounds_is_rejected() {
        let mut c = AutopilotConfig::default();
        c.guidance.max_bank_rad = 1.2;
        let r = validate(&c).unwrap_err();
        assert_eq!(
            (r.name(), r.error),
            ("guid_max_bank", ParamError::OutOfBounds)
        );
        let mut c = AutopilotConfig::default();
        c.indi.rate_hz = 400.0;
        assert_eq!(validate(&c).unwrap_err().name(), "indi_rate_hz");
    }

    #[test]
    fn entries_carry_value_default_and_bounds() {
        let mut c = AutopilotConfig::default();
        set_by_name(&mut c, "guid_kp", ParamValue::F32(0.3)).unwrap();
        let e = entry(&c, index_of("guid_kp").unwrap()).unwrap();
        assert_eq!(e.name.as_str(), "guid_kp");
        assert_eq!(e.value, ParamValue::F32(0.3));
        assert_eq!(e.default, ParamValue::F32(0.2));
        assert_eq!(usize::from(e.count), COUNT);
        assert!(entry(&c, COUNT).is_none());
    }
}
