//! The autopilot's configuration: each stage's own, composed. The parameter table
//! ([`crate::params`]) names every field.

use crate::attitude::AttitudeConfig;
use crate::battery::BatteryConfig;
use crate::estimation::EstimationConfig;
use crate::failsafe::FailsafeConfig;
use crate::force_field::ForceFieldConfig;
use crate::fsm::FsmConfig;
use crate::guidance::GuidanceConfig;
use crate::gyro_calibration::GyroCalibrationConfig;
use crate::height::HeightConfig;
use crate::indi::IndiConfig;
use crate::setpoints::{SetpointConfig, LAND_SETPOINT_FLOOR_M};
use crate::tasks::GUIDANCE_PERIOD;
use crate::vertical::VerticalConfig;
use timebase::Duration;

/// Every tunable of the autopilot, with pocket-drone defaults, one configuration per stage.
/// Units are on each field.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct AutopilotConfig {
    /// Attitude estimator.
    pub attitude: AttitudeConfig,
    /// INDI attitude control.
    pub indi: IndiConfig,
    /// Height loop.
    pub height: HeightConfig,
    /// Vertical estimator (barometer, accelerometer, external height fixes).
    pub vertical: VerticalConfig,
    /// Velocity guidance.
    pub guidance: GuidanceConfig,
    /// Wall force field.
    pub force_field: ForceFieldConfig,
    /// Avoidance FSM.
    pub fsm: FsmConfig,
    /// Failsafe timings.
    pub failsafe: FailsafeConfig,
    /// Battery thresholds and sag model.
    pub battery: BatteryConfig,
    /// Take-off, flight height and landing.
    pub setpoints: SetpointConfig,
    /// Horizontal velocity estimation.
    pub estimation: EstimationConfig,
    /// Ground gyro calibration.
    pub gyro_calibration: GyroCalibrationConfig,
}

impl AutopilotConfig {
    /// The longest time from the camera board's estimates stopping (a cut link, a dead board)
    /// to every motor at 0, for a drone flying at up to `setpoints.target_height_m`: the estimate
    /// timeout, then as [`AutopilotConfig::camera_stopped_motors_off`].
    pub fn link_loss_motors_off(&self) -> Duration {
        self.failsafe.estimate_timeout + self.camera_stopped_motors_off()
    }

    /// The longest time from the host's last heartbeat to every motor at 0, with the
    /// default host action (land) for a drone flying at up to `setpoints.target_height_m` (the host
    /// timeout, then a landing as in [`AutopilotConfig::camera_stopped_motors_off`] at the
    /// slower of the two landing rates, without the hover).
    pub fn host_loss_motors_off(&self) -> Duration {
        let ramp_m = self.setpoints.target_height_m.max(0.0) - LAND_SETPOINT_FLOOR_M;
        let rate = self
            .setpoints
            .land_rate_mps
            .abs()
            .min(self.setpoints.blind_land_rate_mps.abs())
            .max(0.01);
        self.failsafe.host_timeout
            + Duration::from_micros(((ramp_m / rate) * 1e6) as u64)
            + self.setpoints.landed_time
            + GUIDANCE_PERIOD
    }

    /// The longest time from the camera board's `Status` reporting its camera stopped to every
    /// motor at 0 (the report ends the estimates at once): the hover before landing; the
    /// height setpoint's ramp at `setpoints.blind_land_rate_mps` from the target height down to its stop
    /// 0.2 m below the floor (not just to the floor: the drone lags the ramp, by more the
    /// faster it is, and is down when the setpoint stops at the latest); the touchdown
    /// confirmation; one guidance period.
    pub fn camera_stopped_motors_off(&self) -> Duration {
        let ramp_m = self.setpoints.target_height_m.max(0.0) - LAND_SETPOINT_FLOOR_M;
        let descent_s = ramp_m / self.setpoints.blind_land_rate_mps.abs().max(0.01);
        self.failsafe.hover_before_land
            + Duration::from_micros((descent_s * 1e6) as u64)
            + self.setpoints.landed_time
            + GUIDANCE_PERIOD
    }
}
