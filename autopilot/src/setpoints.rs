//! The guidance stage (50 Hz): the [`Setpoints`] the 512 Hz loop flies.
//!
//! Takes, at each guidance step: the flight mode, the [`VelocityState`] of estimation, the
//! height and the height loop ([`HeightController`]), and avoidance's [`AvoidanceOutput`].
//! Gives: [`Setpoints`] (attitude, level-flight thrust, height, velocity), read by the 512 Hz
//! loop and telemetry, and says when the drone has touched down.
//!
//! One step, in order (the caller, [`Autopilot::guidance_step`], passes the typed results on):
//!
//! 1. [`Guidance::tick`]: the time since the last step.
//! 2. [`Guidance::height_setpoint`]: the height setpoint ramps ([`ramp`]) at the climb rate to
//!    the flight height (take-off, and any change of the target), or down at the landing rate
//!    (faster while no vision velocity is fixed: the drone drifts on its trim) to
//!    [`LAND_SETPOINT_FLOOR_M`] below the floor. [`Guidance::at_flight_height`] then tells
//!    avoidance whether its FSM may start.
//! 3. [`Guidance::fly`]: avoidance's velocity request and the fresh velocity estimate through
//!    the velocity loop ([`VelocityGuidance`]; its trim without one) to roll and pitch, and
//!    avoidance's heading.
//! 4. With a fresh height: the height loop's thrust ([`Guidance::hold_height`]), and
//!    touchdown while landing after [`SetpointConfig::landed_time`] below
//!    [`SetpointConfig::landed_height_m`] or on the ground signature
//!    ([`Guidance::touched_down`]). Without: the blind landing's reduced thrust, and touchdown
//!    [`SetpointConfig::blind_land_time`] after the mode changed ([`Guidance::blind_landing`]).
//!
//! [`Autopilot::guidance_step`]: crate::Autopilot::guidance_step

use crate::attitude::wrap_pi;
use crate::avoidance::AvoidanceOutput;
use crate::estimation::VelocityState;
use crate::failsafe::FlightMode;
use crate::guidance::{GuidanceConfig, TiltSetpoint, VelocityGuidance};
use crate::height::HeightController;
use crate::tasks::GUIDANCE_PERIOD;
use timebase::{Duration, Instant};

/// While landing, the height setpoint ramps down to this height below the floor, m, and stays
/// there: the drone, lagging the ramp, is pushed onto the floor rather than hovering just above
/// it.
pub const LAND_SETPOINT_FLOOR_M: f32 = -0.2;

/// Setpoints the guidance layer hands to the 512 Hz loop (and to telemetry).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Setpoints {
    /// Roll, pitch, yaw setpoint, rad.
    pub attitude_rad: [f32; 3],
    /// Level-flight collective thrust, 0..=1 (tilt-compensated in the 512 Hz loop).
    pub thrust: f32,
    /// Height setpoint, m.
    pub height_m: f32,
    /// Forward and sideways velocity setpoint, m/s.
    pub velocity_mps: [f32; 2],
}

/// Where the height setpoint goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeightTarget {
    /// To [`SetpointConfig::target_height_m`] at [`SetpointConfig::climb_rate_mps`].
    FlightHeight,
    /// Down to [`LAND_SETPOINT_FLOOR_M`] at [`SetpointConfig::land_rate_mps`], or at
    /// [`SetpointConfig::blind_land_rate_mps`] when `blind`.
    Land {
        /// No vision velocity fixed within the failsafe's estimate timeout.
        blind: bool,
    },
}

/// Take-off, flight height and landing: the height setpoint's ramps and the touchdown.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SetpointConfig {
    /// Flight height after take-off, m above the floor.
    pub target_height_m: f32,
    /// Height-setpoint climb rate during take-off, m/s.
    pub climb_rate_mps: f32,
    /// Height-setpoint descent rate when landing, m/s.
    pub land_rate_mps: f32,
    /// Descent rate instead of `land_rate_mps` while no vision velocity has been fused for
    /// the failsafe's estimate timeout, m/s: the drone then drifts on its trim (an
    /// accelerometer bias of 0.01 g is 0.1 m/s² of unobserved acceleration), so the sooner
    /// it is down, the shorter the drift.
    pub blind_land_rate_mps: f32,
    /// Below this height the drone counts as on the floor, m (height integrator off, touchdown).
    pub landed_height_m: f32,
    /// Touchdown confirmed after this long below `landed_height_m` while landing.
    pub landed_time: Duration,
    /// The avoidance FSM starts once the height is within this of the target, m.
    pub fsm_start_height_tolerance_m: f32,
    /// A landing that has not touched down after this long (a biased barometer that reads the
    /// floor as higher than it is) cuts the motors once the height estimate is below
    /// `land_cut_height_m` or the drone shows the ground signature.
    pub land_timeout: Duration,
    /// After `land_timeout`, the motors are cut below this height estimate, m.
    pub land_cut_height_m: f32,
    /// Ground signature (touchdown whatever the height says): the level-flight thrust below
    /// this fraction of the hover thrust while the specific force stays above
    /// `ground_min_specific_force` g and the body rates below [`GROUND_MAX_RATE_RADPS`](crate::app::GROUND_MAX_RATE_RADPS). In the
    /// air that little thrust makes the drone fall (its specific force drops with the
    /// thrust); only the floor holds it at 1 g. 0 turns the signature off.
    pub ground_thrust_ratio: f32,
    /// Ground signature: the low-passed specific force stays above this fraction of g.
    pub ground_min_specific_force: f32,
    /// Level-flight thrust when landing without a height measurement (0..=1, below hover).
    pub blind_land_thrust: f32,
    /// Landing without a height measurement: motors off after this long.
    pub blind_land_time: Duration,
}

impl Default for SetpointConfig {
    fn default() -> Self {
        Self {
            target_height_m: 1.0,
            climb_rate_mps: 0.5,
            land_rate_mps: 0.3,
            blind_land_rate_mps: 0.6,
            landed_height_m: 0.06,
            landed_time: Duration::from_millis(500),
            fsm_start_height_tolerance_m: 0.15,
            land_timeout: Duration::from_secs(10),
            land_cut_height_m: 0.3,
            ground_thrust_ratio: 0.6,
            ground_min_specific_force: 0.9,
            blind_land_thrust: 0.5,
            blind_land_time: Duration::from_secs(3),
        }
    }
}

/// The height setpoint of one guidance step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeightSetpoint {
    /// Height setpoint, m.
    pub height_m: f32,
    /// Its rate of change, m/s (the height loop's feed-forward).
    pub rate_mps: f32,
}

/// One step of `dt` s of the height setpoint from `from_m` towards `target`.
pub fn ramp(from_m: f32, target: HeightTarget, dt: f32, cfg: &SetpointConfig) -> HeightSetpoint {
    match target {
        HeightTarget::Land { blind } => {
            let rate = if blind {
                cfg.blind_land_rate_mps
            } else {
                cfg.land_rate_mps
            };
            let rate_mps = -rate.abs();
            HeightSetpoint {
                height_m: (from_m + rate_mps * dt).max(LAND_SETPOINT_FLOOR_M),
                rate_mps,
            }
        }
        HeightTarget::FlightHeight => {
            let target = cfg.target_height_m;
            let climb = cfg.climb_rate_mps.abs();
            let step = climb * dt;
            if from_m < target - step {
                HeightSetpoint {
                    height_m: from_m + step,
                    rate_mps: climb,
                }
            } else if from_m > target + step {
                HeightSetpoint {
                    height_m: from_m - step,
                    rate_mps: -climb,
                }
            } else {
                HeightSetpoint {
                    height_m: target,
                    rate_mps: 0.0,
                }
            }
        }
    }
}

/// The setpoints, the velocity loop and the guidance step's timing and touchdown timer.
#[derive(Debug, Clone)]
pub struct Guidance {
    sp: Setpoints,
    velocity: VelocityGuidance,
    last_step: Option<Instant>,
    /// Since when the drone has been below the landed height while landing.
    below_landed_since: Option<Instant>,
    /// Land at the blind descent rate whatever the velocity ([`Guidance::hurry_landing`]).
    hurry: bool,
}

impl Guidance {
    /// All setpoints zero, velocity loop with empty integrators.
    pub fn new(cfg: GuidanceConfig) -> Self {
        Self {
            sp: Setpoints {
                attitude_rad: [0.0; 3],
                thrust: 0.0,
                height_m: 0.0,
                velocity_mps: [0.0; 2],
            },
            velocity: VelocityGuidance::new(cfg),
            last_step: None,
            below_landed_since: None,
            hurry: false,
        }
    }

    /// Takes the velocity loop's new configuration, keeping the state.
    pub fn set_config(&mut self, cfg: GuidanceConfig) {
        self.velocity.set_config(cfg);
    }

    /// The current setpoints.
    #[inline]
    pub fn setpoints(&self) -> &Setpoints {
        &self.sp
    }

    /// The velocity loop.
    pub fn velocity_loop(&self) -> &VelocityGuidance {
        &self.velocity
    }

    /// A guidance step at `now`: the time since the last one, s (one period for the first,
    /// 0 if time did not advance, at most 0.1 s).
    pub fn tick(&mut self, now: Instant) -> f32 {
        let dt = match self.last_step {
            Some(t) if now > t => (now - t).as_secs_f32().min(0.1),
            Some(_) => 0.0,
            None => GUIDANCE_PERIOD.as_secs_f32(),
        };
        self.last_step = Some(now);
        dt
    }

    /// Take-off from `height_m` on heading `yaw_rad`: the height setpoint starts there, level,
    /// no velocity, integrators empty.
    pub fn take_off(&mut self, height_m: f32, yaw_rad: f32) {
        self.velocity.reset();
        self.sp.height_m = height_m;
        self.sp.attitude_rad = [0.0, 0.0, yaw_rad];
        self.sp.velocity_mps = [0.0; 2];
        self.below_landed_since = None;
        self.hurry = false;
    }

    /// Until the next take-off, landings descend at
    /// [`SetpointConfig::blind_land_rate_mps`] (a critically low battery).
    pub fn hurry_landing(&mut self) {
        self.hurry = true;
    }

    /// Motors off: no thrust.
    pub fn motors_off(&mut self) {
        self.sp.thrust = 0.0;
    }

    /// On the ground with the motors off, on heading `yaw_rad`: level, no thrust, no velocity,
    /// integrators empty.
    pub fn rest(&mut self, yaw_rad: f32) {
        self.velocity.reset();
        self.sp.thrust = 0.0;
        self.sp.velocity_mps = [0.0; 2];
        self.sp.attitude_rad = [0.0, 0.0, yaw_rad];
    }

    /// Touched down: no thrust, integrators empty, touchdown timer cleared.
    pub fn landed(&mut self) {
        self.sp.thrust = 0.0;
        self.velocity.reset();
        self.below_landed_since = None;
    }

    /// Step 2: the height setpoint for `mode` (landing, blind if `velocity` has no fix within
    /// the failsafe's estimate timeout at `now`; otherwise to the flight height).
    pub fn height_setpoint(
        &mut self,
        mode: FlightMode,
        velocity: &VelocityState,
        now: Instant,
        dt: f32,
        estimate_timeout: Duration,
        cfg: &SetpointConfig,
    ) -> HeightSetpoint {
        let target = match mode {
            FlightMode::Landing => HeightTarget::Land {
                blind: self.hurry || !velocity.fixed_within(now, estimate_timeout),
            },
            _ => HeightTarget::FlightHeight,
        };
        let sp = ramp(self.sp.height_m, target, dt, cfg);
        self.sp.height_m = sp.height_m;
        sp
    }

    /// The height setpoint has reached the flight height and the drone at `height_m` is
    /// within [`SetpointConfig::fsm_start_height_tolerance_m`] of it.
    pub fn at_flight_height(&self, height_m: f32, cfg: &SetpointConfig) -> bool {
        let target = cfg.target_height_m;
        self.sp.height_m == target && (height_m - target).abs() <= cfg.fsm_start_height_tolerance_m
    }

    /// Step 3: avoidance's request flown on `velocity` (`None`: no fresh estimate, the trim
    /// attitude) over `dt` s. The velocity setpoint is the velocity loop's reference on its
    /// way to the request.
    pub fn fly(&mut self, request: &AvoidanceOutput, velocity: Option<[f32; 2]>, dt: f32) {
        let v_sp = request.velocity_mps;
        let tilt: TiltSetpoint = match velocity {
            Some(v) => self.velocity.step(v_sp, v, dt),
            _ => self.velocity.hold(),
        };
        self.sp.velocity_mps = self.velocity.reference().unwrap_or(v_sp);
        self.sp.attitude_rad = [tilt.roll_rad, tilt.pitch_rad, wrap_pi(request.yaw_sp_rad)];
    }

    /// Step 4 with a fresh height `height_m`: the height loop's thrust for `sp` over `dt` s
    /// (its integrator runs above the landed height).
    pub fn hold_height(
        &mut self,
        height: &mut HeightController,
        sp: HeightSetpoint,
        height_m: f32,
        dt: f32,
        cfg: &SetpointConfig,
    ) {
        let airborne = height_m > cfg.landed_height_m;
        self.sp.thrust = height.step(sp.height_m, sp.rate_mps, dt, airborne);
    }

    /// Step 4 with a fresh height `height_m`, after [`Guidance::hold_height`]: true at
    /// touchdown (`landing`, and below the landed height or `on_ground` (the ground signature,
    /// [`crate::Autopilot::ground_signature`]) for the landed time).
    pub fn touched_down(
        &mut self,
        landing: bool,
        height_m: f32,
        on_ground: bool,
        now: Instant,
        cfg: &SetpointConfig,
    ) -> bool {
        if landing && (height_m <= cfg.landed_height_m || on_ground) {
            let since = *self.below_landed_since.get_or_insert(now);
            now.since(since) >= cfg.landed_time
        } else {
            self.below_landed_since = None;
            false
        }
    }

    /// Step 4 without a height (the failsafe switched to landing at `since`): reduced
    /// thrust; true once it has run for the blind landing time.
    pub fn blind_landing(&mut self, since: Instant, now: Instant, cfg: &SetpointConfig) -> bool {
        self.sp.thrust = cfg.blind_land_thrust.clamp(0.0, 1.0);
        now.since(since) >= cfg.blind_land_time
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::height::HeightConfig;
    use crate::test_support::at;
    use crate::AutopilotConfig;

    fn close(a: f32, b: f32) -> bool {
        (a - b).abs() < 1e-6
    }

    #[test]
    fn the_height_setpoint_climbs_to_the_flight_height_and_stays() {
        let cfg = AutopilotConfig::default();
        let mut h = 0.0;
        let mut steps = 0;
        while h != cfg.setpoints.target_height_m {
            let sp = ramp(h, HeightTarget::FlightHeight, 0.02, &cfg.setpoints);
            assert!(sp.height_m > h);
            h = sp.height_m;
            steps += 1;
            assert!(steps < 1_000);
        }
        let expected =
            (cfg.setpoints.target_height_m / (cfg.setpoints.climb_rate_mps * 0.02)).ceil() as i32;
        assert!((steps - expected).abs() <= 1, "{steps} steps");
        assert_eq!(
            ramp(h, HeightTarget::FlightHeight, 0.02, &cfg.setpoints),
            HeightSetpoint {
                height_m: cfg.setpoints.target_height_m,
                rate_mps: 0.0
            }
        );
        // Above it: down at the climb rate.
        let sp = ramp(2.0, HeightTarget::FlightHeight, 0.1, &cfg.setpoints);
        assert!(close(sp.height_m, 2.0 - cfg.setpoints.climb_rate_mps * 0.1));
        assert_eq!(sp.rate_mps, -cfg.setpoints.climb_rate_mps);
    }

    #[test]
    fn landing_descends_faster_when_blind_and_stops_below_the_floor() {
        let cfg = AutopilotConfig::default();
        let seen = ramp(
            1.0,
            HeightTarget::Land { blind: false },
            0.1,
            &cfg.setpoints,
        );
        let blind = ramp(1.0, HeightTarget::Land { blind: true }, 0.1, &cfg.setpoints);
        assert_eq!(seen.rate_mps, -cfg.setpoints.land_rate_mps);
        assert_eq!(blind.rate_mps, -cfg.setpoints.blind_land_rate_mps);
        assert!(blind.height_m < seen.height_m);
        assert!(close(
            seen.height_m,
            1.0 - cfg.setpoints.land_rate_mps * 0.1
        ));
        let floor = ramp(
            -0.19,
            HeightTarget::Land { blind: true },
            0.1,
            &cfg.setpoints,
        );
        assert_eq!(floor.height_m, LAND_SETPOINT_FLOOR_M);
    }

    #[test]
    fn the_step_time_starts_at_one_period_and_is_bounded() {
        let mut g = Guidance::new(GuidanceConfig::default());
        assert!(close(g.tick(at(5_000_000)), GUIDANCE_PERIOD.as_secs_f32()));
        assert!(close(g.tick(at(5_020_000)), 0.02));
        assert_eq!(g.tick(at(5_020_000)), 0.0);
        assert_eq!(g.tick(at(5_000_000)), 0.0);
        assert!(close(g.tick(at(9_000_000)), 0.1));
    }

    #[test]
    fn the_velocity_request_becomes_the_attitude_and_without_an_estimate_the_trim() {
        let cfg = AutopilotConfig::default();
        let mut g = Guidance::new(cfg.guidance);
        g.take_off(0.0, 0.3);
        let request = AvoidanceOutput {
            velocity_mps: [0.3, 0.0],
            yaw_sp_rad: 7.0,
            land: false,
        };
        // The velocity setpoint is the reference on its way to the request.
        g.fly(&request, Some([0.0, 0.0]), 0.02);
        let first = g.setpoints().velocity_mps;
        g.fly(&request, Some([0.0, 0.0]), 0.02);
        let sp = *g.setpoints();
        assert!(
            first[0] < sp.velocity_mps[0] && sp.velocity_mps[0] < 0.3,
            "{sp:?}"
        );
        assert_eq!(sp.velocity_mps[1], 0.0);
        assert!(sp.attitude_rad[1] < 0.0, "nose down to speed up: {sp:?}");
        assert_eq!(sp.attitude_rad[0], 0.0);
        assert!(close(sp.attitude_rad[2], wrap_pi(7.0)));
        // No fresh estimate: the integral part only.
        let trim = g.velocity_loop().trim();
        g.fly(&request, None, 0.02);
        assert_eq!(g.setpoints().attitude_rad[1], trim.pitch_rad);
        // On the ground everything is zeroed but the heading.
        g.rest(0.5);
        assert_eq!(g.velocity_loop().integral(), [0.0; 2]);
        assert_eq!(g.setpoints().attitude_rad, [0.0, 0.0, 0.5]);
        assert_eq!(g.setpoints().velocity_mps, [0.0; 2]);
    }

    #[test]
    fn the_fsm_may_start_once_setpoint_and_drone_are_at_the_flight_height() {
        let cfg = AutopilotConfig::default();
        let mut g = Guidance::new(cfg.guidance);
        let hover = VelocityState {
            velocity_mps: None,
            last_fix: None,
        };
        g.take_off(cfg.setpoints.target_height_m - 0.005, 0.0);
        assert!(!g.at_flight_height(cfg.setpoints.target_height_m, &cfg.setpoints));
        g.height_setpoint(
            FlightMode::Flying,
            &hover,
            at(0),
            0.02,
            cfg.failsafe.estimate_timeout,
            &cfg.setpoints,
        );
        assert!(g.at_flight_height(cfg.setpoints.target_height_m, &cfg.setpoints));
        let tol = cfg.setpoints.fsm_start_height_tolerance_m;
        assert!(g.at_flight_height(cfg.setpoints.target_height_m - tol * 0.9, &cfg.setpoints));
        assert!(!g.at_flight_height(cfg.setpoints.target_height_m - tol * 1.1, &cfg.setpoints));
        // Landing: blind without a recent fix.
        let seen = VelocityState {
            velocity_mps: Some([0.0; 2]),
            last_fix: Some(at(1_000_000)),
        };
        let sp = g.height_setpoint(
            FlightMode::Landing,
            &seen,
            at(1_000_000),
            0.02,
            cfg.failsafe.estimate_timeout,
            &cfg.setpoints,
        );
        assert_eq!(sp.rate_mps, -cfg.setpoints.land_rate_mps);
        let sp = g.height_setpoint(
            FlightMode::Landing,
            &hover,
            at(1_000_000),
            0.02,
            cfg.failsafe.estimate_timeout,
            &cfg.setpoints,
        );
        assert_eq!(sp.rate_mps, -cfg.setpoints.blind_land_rate_mps);
        assert_eq!(g.setpoints().height_m, sp.height_m);
    }

    #[test]
    fn touchdown_needs_the_landed_time_below_the_landed_height_while_landing() {
        let cfg = AutopilotConfig::default();
        let mut g = Guidance::new(cfg.guidance);
        let mut height = HeightController::new(HeightConfig::default());
        let sp = HeightSetpoint {
            height_m: LAND_SETPOINT_FLOOR_M,
            rate_mps: -cfg.setpoints.land_rate_mps,
        };
        let low = cfg.setpoints.landed_height_m;
        let mut hold = |g: &mut Guidance, h: f32, landing: bool, t: u64| {
            g.hold_height(&mut height, sp, h, 0.02, &cfg.setpoints);
            g.touched_down(landing, h, false, at(t), &cfg.setpoints)
        };
        // Below it, but not landing: nothing.
        assert!(!hold(&mut g, low, false, 0));
        assert!(!hold(&mut g, low, true, 1_000_000));
        // Bounced up: the timer restarts.
        assert!(!hold(&mut g, low + 0.1, true, 1_400_000));
        assert!(!hold(&mut g, low, true, 1_500_000));
        assert!(!hold(
            &mut g,
            low,
            true,
            1_500_000 + cfg.setpoints.landed_time.as_micros() - 1
        ));
        assert!(hold(
            &mut g,
            low,
            true,
            1_500_000 + cfg.setpoints.landed_time.as_micros()
        ));
        assert!(g.setpoints().thrust >= 0.0);
        g.landed();
        assert_eq!(g.setpoints().thrust, 0.0);
        // High above the landed height (a biased barometer), the ground signature alone
        // touches down after the same landed time.
        let high = low + 0.3;
        assert!(!g.touched_down(true, high, true, at(3_000_000), &cfg.setpoints));
        assert!(!g.touched_down(
            true,
            high,
            true,
            at(3_000_000 + cfg.setpoints.landed_time.as_micros() - 1),
            &cfg.setpoints
        ));
        assert!(g.touched_down(
            true,
            high,
            true,
            at(3_000_000 + cfg.setpoints.landed_time.as_micros()),
            &cfg.setpoints
        ));
    }

    #[test]
    fn a_blind_landing_runs_on_reduced_thrust_for_its_time() {
        let cfg = AutopilotConfig::default();
        let mut g = Guidance::new(cfg.guidance);
        assert!(!g.blind_landing(
            at(1_000),
            at(1_000 + cfg.setpoints.blind_land_time.as_micros() - 1),
            &cfg.setpoints
        ));
        assert_eq!(g.setpoints().thrust, cfg.setpoints.blind_land_thrust);
        assert!(g.blind_landing(
            at(1_000),
            at(1_000 + cfg.setpoints.blind_land_time.as_micros()),
            &cfg.setpoints
        ));
    }
}
