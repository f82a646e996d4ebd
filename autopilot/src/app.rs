//! The autopilot board's task logic: every firmware task body (and the simulator) calls one
//! method of [`Autopilot`], and the task graph is the data in [`TASKS`](crate::tasks::TASKS).
//!
//! [`Autopilot`] holds one value per stage, each in its own module and tested there; its
//! methods pass each stage's typed result to the next:
//!
//! * 512 Hz ([`Autopilot::on_imu`]): IMU sample -> [`GyroCalibration`] -> attitude estimate ->
//!   INDI -> mixer -> motors, flying the [`Setpoints`]; the same sample predicts the vertical
//!   estimator and [`VelocityEstimation`].
//! * Camera board ([`Autopilot::on_stereo_bytes`]): [`CameraLink`] decodes; each Edge-FS
//!   estimate goes to [`VelocityEstimation`] (with a [`VisionContext`]: gates, then the
//!   velocity Kalman filter, or the paper's median-5 and observer) and to [`Avoidance`]
//!   (obstacle readings).
//! * Height: barometer, accelerometer, external height fixes and (with `vert_camera_climb`)
//!   the camera's climb rate -> vertical estimator -> height loop.
//! * 50 Hz ([`Autopilot::guidance_step`]): failsafe -> [`Guidance`]'s height setpoint ->
//!   [`Avoidance`] ([`AvoidanceInput`] -> avoidance FSM and wall force field ->
//!   [`AvoidanceOutput`](crate::avoidance::AvoidanceOutput)) -> [`Guidance`]'s velocity loop on
//!   the [`VelocityState`](crate::estimation::VelocityState) and the height loop ->
//!   [`Setpoints`].
//!
//! Failsafes over all of it. Time is passed in by the caller (a monotonic
//! [`timebase::Instant`]); the library never reads a clock.

use crate::attitude::{attitude_error, AttitudeEstimator, Quat, GRAVITY};
use crate::avoidance::{Avoidance, AvoidanceInput};
use crate::battery::{BatteryMonitor, BatteryState};
use crate::camera_link::{CameraLink, CameraNews};
use crate::config::AutopilotConfig;
use crate::estimation::{VelocityEstimation, VisionContext};
use crate::failsafe::{Failsafe, FailsafeReason, FlightMode, Freshness};
use crate::fsm::{AvoidanceFsm, FsmState};
use crate::guidance::VelocityObserver;
use crate::gyro_calibration::GyroCalibration;
use crate::height::{tilt_compensate, HeightController};
use crate::indi::Indi;
use crate::mixer::{self, MOTORS_OFF};
use crate::ms5611::BaroReading;
use crate::params::{self, Rejected};
use crate::range_rate::Closing;
use crate::setpoints::Guidance;
pub use crate::setpoints::Setpoints;
use crate::velocity_kf::VelocityKf;
use crate::vertical::{VerticalEstimator, FIXES_TO_LEAD};
use protocol::params::{ParamStorage, RecordError, RecordStore, StorageStatus};
use protocol::{
    Estimate, ExternalPosition, GyroAttitude, Heartbeat, ImuSample, LinkErrorCounts, Node,
    ParamError, ParamOp, ParamReply, ParamRequest, ParamResponse, PilotCommand, StereoStatus,
    StereoToAutopilot, Telemetry,
};
use timebase::{Duration, Instant};

/// Ground signature: the low-passed squared body rate stays below this, rad/s.
pub const GROUND_MAX_RATE_RADPS: f32 = 0.5;

/// Low-pass weight per guidance step of the ground signature's specific force and body rate,
/// sampled from the latest IMU sample (a time constant of about 0.1 s at 50 Hz).
const GROUND_LP_ALPHA: f32 = 0.2;

/// The whole autopilot state (fixed size, no heap): the stages in data-flow order.
#[derive(Debug, Clone)]
pub struct Autopilot {
    cfg: AutopilotConfig,
    /// The 512 Hz loop: gyro offset, attitude, INDI; the last corrected gyro, the time of the
    /// last usable sample and the motor throttles.
    gyro_cal: GyroCalibration,
    att: AttitudeEstimator,
    indi: Indi,
    gyro: [f32; 3],
    accel: [f32; 3],
    last_imu: Option<Instant>,
    motors: [f32; 4],
    /// Low-passed squared specific force, (m/s²)², and squared body rate, (rad/s)²: the
    /// ground signature's inputs.
    ground_lp: [f32; 2],
    /// The camera board's link.
    camera: CameraLink,
    /// Height: vertical estimator, the last barometer reading, the height loop (which holds
    /// the height measurement it flies on).
    vertical: VerticalEstimator,
    baro: Option<(Instant, BaroReading)>,
    /// When the barometer's reading last changed, and frozen readings refused since boot.
    baro_changed: Instant,
    baro_frozen: u32,
    /// External height fixes not used (gated, or fixes disabled).
    fixes_refused: u32,
    /// External height fixes the vertical estimator took in a row (see
    /// [`Autopilot::on_external_position`]).
    fixes_in_row: u8,
    height: HeightController,
    /// Horizontal velocity from the Edge-FS estimates.
    estimation: VelocityEstimation,
    /// Obstacle readings, avoidance FSM and force field.
    avoidance: Avoidance,
    /// The setpoints of the 512 Hz loop.
    guidance: Guidance,
    /// Flight mode and timeouts; the RC kill and the refused `Arm` count.
    failsafe: Failsafe,
    rc_kill_latched: bool,
    arm_refused: u32,
    /// The lockstep images' PWM gate ([`PilotCommand::HilOutputs`]); off at boot.
    hil_outputs: bool,
    /// When the host's last heartbeat arrived.
    last_host: Option<Instant>,
    /// The supply voltage: filter, sag compensation, verdict.
    battery: BatteryMonitor,
    /// The parameter storage's state (`None`: a build without storage).
    storage: Option<StorageStatus>,
    /// The host link's key, replay guard and refusal counts.
    pub(crate) link_auth: crate::link_auth::LinkAuth,
}

/// Why an `Arm` command is refused before the flight-mode checks (see
/// [`Autopilot::arm_blocker`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ArmBlock {
    /// The RC kill is engaged (switch, receiver failsafe or silence): only releasing it on the
    /// transmitter clears it, no other command source can.
    RcKill,
    /// The camera board speaks another protocol version (the value): its estimates cannot be
    /// read, so the drone would fly blind.
    PeerVersion(u8),
    /// The boot could not load the saved parameters (why): the defaults in use are not what
    /// was saved. Cleared by a successful save or `ParamOp::Acknowledge`
    /// ([`StorageStatus::blocks_arming`]).
    ParamsNotLoaded(RecordError),
    /// The battery's resting voltage is below [`BatteryConfig::arm_v`](crate::battery::BatteryConfig::arm_v).
    BatteryLow,
}

fn finite3(v: &[f32; 3], max_abs: f32) -> bool {
    v.iter().all(|x| x.is_finite() && x.abs() <= max_abs)
}

impl Autopilot {
    /// A disarmed autopilot.
    pub fn new(config: AutopilotConfig) -> Self {
        Self {
            gyro_cal: GyroCalibration::new(),
            att: AttitudeEstimator::new(config.attitude),
            indi: Indi::new(config.indi),
            gyro: [0.0; 3],
            accel: [0.0, 0.0, -GRAVITY],
            last_imu: None,
            motors: MOTORS_OFF,
            ground_lp: [GRAVITY * GRAVITY, 0.0],
            camera: CameraLink::new(),
            vertical: VerticalEstimator::new(config.vertical),
            baro: None,
            baro_changed: Instant::ZERO,
            baro_frozen: 0,
            fixes_refused: 0,
            fixes_in_row: 0,
            height: HeightController::new(config.height),
            estimation: VelocityEstimation::new(&config.estimation),
            avoidance: Avoidance::new(config.fsm),
            guidance: Guidance::new(config.guidance),
            failsafe: Failsafe::new(config.failsafe),
            rc_kill_latched: false,
            arm_refused: 0,
            hil_outputs: false,
            last_host: None,
            battery: BatteryMonitor::new(config.battery),
            storage: None,
            link_auth: crate::link_auth::LinkAuth::new(),
            cfg: config,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &AutopilotConfig {
        &self.cfg
    }

    /// A disarmed autopilot, if `config` passes [`params::validate`] (otherwise the parameter
    /// at fault and why).
    pub fn try_new(config: AutopilotConfig) -> Result<Self, Rejected> {
        params::validate(&config)?;
        Ok(Self::new(config))
    }

    /// Makes `config` the autopilot's from the next step on, if it passes
    /// [`params::validate`] and the motors cannot run (disarmed, killed, IMU fault); otherwise
    /// nothing changes and the refusal says why. The estimators and the failsafe keep their
    /// state; the INDI (filters and adapted effectiveness) restarts if its part changed.
    pub fn set_config(&mut self, config: AutopilotConfig) -> Result<(), Rejected> {
        if self.failsafe.mode().motors_enabled() {
            return Err(Rejected::refused(ParamError::Armed));
        }
        params::validate(&config)?;
        self.att.set_config(config.attitude);
        if config.indi != self.cfg.indi {
            self.indi = Indi::new(config.indi);
        }
        self.height.set_config(config.height);
        self.vertical.set_config(config.vertical);
        self.guidance.set_config(config.guidance);
        self.estimation.set_config(&config.estimation);
        self.avoidance.set_config(config.fsm);
        self.failsafe.set_config(config.failsafe);
        self.battery.set_config(config.battery);
        self.cfg = config;
        Ok(())
    }

    /// A disarmed autopilot on the configuration saved in `store` ([`params::decode_record`]):
    /// the saved values when the record is good, otherwise the defaults; why is kept for
    /// [`ParamOp::Storage`] and returned (`Err`: the defaults are in use).
    ///
    /// The link key saved with the parameters ([`protocol::params::ParamTable::load_link_key`])
    /// is loaded too: with one, every command but `Kill` must be signed from the first message.
    pub fn from_store(store: &impl RecordStore) -> (Self, Result<(), RecordError>) {
        let (config, status) = params::AUTOPILOT.load(store);
        let mut ap = Self::new(config);
        ap.storage = Some(status);
        if let Some(key) = params::AUTOPILOT.load_link_key(store) {
            ap.link_auth.load(key);
        }
        (ap, status.loaded)
    }

    /// The parameter storage's state (`None`: built without storage, [`Autopilot::new`]).
    pub fn storage(&self) -> Option<StorageStatus> {
        self.storage
    }

    /// Answers a host's parameter request for this board's table ([`params::TABLE`]). A
    /// request for another board's table is refused (`NoSuchBoard`;
    /// [`Autopilot::on_host_message`] passes the camera board's on).
    ///
    /// `store` is the board's parameter storage, `None` on a build without one, where `Save`
    /// and `Storage` are answered `NoStorage`. With one, `Save` is refused while the motors may
    /// run (`Armed`); otherwise the record of the configuration in use
    /// ([`params::encode_record`], with the link key when there is one) is written and read
    /// back, and a failure of either is `SaveFailed`. The write takes as long as the flash's
    /// erase (a second or two for a 128 KiB sector), which is why it waits for the ground.
    pub fn on_param_request(
        &mut self,
        req: &ParamRequest,
        store: Option<&mut dyn RecordStore>,
    ) -> ParamResponse {
        self.answer_param(req, store)
    }

    pub(crate) fn answer_param(
        &mut self,
        req: &ParamRequest,
        store: Option<&mut dyn RecordStore>,
    ) -> ParamResponse {
        let saving = req.board == Node::Autopilot && req.op == ParamOp::Save;
        if saving && store.is_some() && self.storage.is_some() && self.mode().motors_enabled() {
            return ParamResponse {
                board: req.board,
                reply: ParamReply::Error(ParamError::Armed),
            };
        }
        let cfg = self.cfg;
        // The status is counted on a copy, so that `set_config` can borrow the autopilot.
        let mut status = self.storage;
        let key = self.link_auth.stored_key();
        let storage = ParamStorage::of(store, status.as_mut()).map(|s| s.with_key(key));
        let apply = |next| self.set_config(next);
        let response = params::AUTOPILOT.respond(Node::Autopilot, req, &cfg, apply, storage);
        self.storage = status;
        response
    }

    /// The camera board's latest answer to a parameter request passed on to it, for the host
    /// (taken once; a newer answer replaces one not yet taken).
    pub fn take_camera_param_reply(&mut self) -> Option<ParamResponse> {
        self.camera.take_param_reply()
    }

    /// Current flight mode (failsafe state).
    pub fn mode(&self) -> FlightMode {
        self.failsafe.mode()
    }

    /// Current avoidance state (meaningful while [`Autopilot::fsm_active`]).
    pub fn fsm_state(&self) -> FsmState {
        self.avoidance.fsm().state()
    }

    /// True while the avoidance FSM drives the setpoints.
    pub fn fsm_active(&self) -> bool {
        self.avoidance.active()
    }

    /// The avoidance FSM (state, time in state, transition count).
    pub fn fsm(&self) -> &AvoidanceFsm {
        self.avoidance.fsm()
    }

    /// The closing speed on the nearest obstacle at `now`, from its stereo distances.
    pub fn closing(&self, now: Instant) -> Option<Closing> {
        self.avoidance.closing(now)
    }

    /// Guidance steps at which the obstacle's range rate overruled the velocity estimate
    /// ([`Avoidance::cross_check`]).
    pub fn velocity_overruled(&self) -> u32 {
        self.avoidance.overruled()
    }

    /// The forward velocity guidance flew on at its last step in place of the estimate's,
    /// overruled by the obstacle's range rate, m/s (`None`: the estimate stood).
    pub fn velocity_overrule(&self) -> Option<f32> {
        self.avoidance.overrule()
    }

    /// Current setpoints.
    pub fn setpoints(&self) -> Setpoints {
        *self.guidance.setpoints()
    }

    /// Estimated attitude roll, pitch, yaw, rad.
    pub fn attitude(&self) -> [f32; 3] {
        self.att.euler()
    }

    /// Median-filtered `[forward, sideways]` velocity, m/s (`None` before the first valid one).
    pub fn velocity(&self) -> Option<[f32; 2]> {
        self.estimation.median_velocity()
    }

    /// The `[forward, sideways]` velocity guidance flies on, m/s, from the configured
    /// [`VelocitySource`](crate::estimation::VelocitySource) (`None` before the first valid estimate). Between estimates it is
    /// predicted from the attitude.
    pub fn velocity_estimate(&self) -> Option<[f32; 2]> {
        self.estimation
            .state(self.cfg.estimation.velocity_source)
            .velocity_mps
    }

    /// The horizontal velocity Kalman filter.
    pub fn velocity_kf(&self) -> &VelocityKf {
        self.estimation.kf()
    }

    /// The velocity observer of the paper's path (bias, configuration); it runs only when
    /// [`EstimationConfig::velocity_source`](crate::estimation::EstimationConfig::velocity_source) is [`VelocitySource::MedianObserver`](crate::estimation::VelocitySource::MedianObserver).
    pub fn observer(&self) -> &VelocityObserver {
        self.estimation.observer()
    }

    /// Gyro offset from the last ground calibration, rad/s (`None`: not calibrated yet).
    pub fn gyro_offset(&self) -> Option<[f32; 3]> {
        self.gyro_cal.offset()
    }

    /// Valid estimates not used for the velocity because of fast yaw since boot (wrapping).
    pub fn yaw_gated_estimates(&self) -> u32 {
        self.estimation.yaw_gated()
    }

    /// INDI state (G1/G2 estimates etc.).
    pub fn indi(&self) -> &Indi {
        &self.indi
    }

    /// Last motor throttles (FR, RR, RL, FL), 0..=1.
    pub fn motors(&self) -> [f32; 4] {
        self.motors
    }

    /// Errors decoding camera-board bytes (via [`Autopilot::on_stereo_bytes`]) since boot.
    pub fn link_errors(&self) -> LinkErrorCounts {
        self.camera.errors()
    }

    /// Estimates received since boot (valid or not, wrapping).
    pub fn estimates_received(&self) -> u32 {
        self.estimation.estimates_received()
    }

    /// Valid estimates skipped by the plausibility gate since boot (wrapping).
    pub fn velocity_outliers(&self) -> u32 {
        self.estimation.outliers()
    }

    /// The camera board's last heartbeat and when it arrived.
    pub fn stereo_heartbeat(&self) -> Option<(Instant, Heartbeat)> {
        self.camera.heartbeat()
    }

    /// The camera board's last status report.
    pub fn stereo_status(&self) -> Option<StereoStatus> {
        self.camera.status()
    }

    /// Bytes from the camera-board UART, as they arrive (any chunking). Complete frames are
    /// decoded (bad ones counted in [`Autopilot::link_errors`]) and handled: estimates go to
    /// [`Autopilot::on_estimate`] with time `now`. Returns the number of messages decoded.
    pub fn on_stereo_bytes(&mut self, bytes: &[u8], now: Instant) -> usize {
        let mut n = 0;
        for &b in bytes {
            if let Some(msg) = self.camera.push(b) {
                n += 1;
                self.on_stereo_message(msg, now);
            }
        }
        n
    }

    /// One decoded camera-board message (for callers that run their own decoder).
    pub fn on_stereo_message(&mut self, msg: StereoToAutopilot, now: Instant) {
        match self.camera.on_message(msg, now) {
            Some(CameraNews::Estimate(e)) => self.on_estimate(&e, now),
            // The camera board sees no frames: fly as blind from now on instead of waiting out
            // the estimate timeout (a valid estimate ends it).
            Some(CameraNews::CameraStopped) => self.estimation.camera_stopped(),
            None => {}
        }
    }

    fn freshness(&self) -> Freshness {
        Freshness {
            last_valid_estimate: self.estimation.last_valid_estimate(),
            last_imu: self.last_imu,
            last_height: self.height.last_measurement(),
            last_host: self.last_host,
            baro_frozen: self.baro_is_frozen(),
        }
    }

    /// A heartbeat from the host (ground tool, simulator, HIL bridge) arrived at `now`:
    /// the telemetry link is alive (see [`crate::failsafe`]'s host timeout).
    pub fn on_host_heartbeat(&mut self, now: Instant) {
        self.last_host = Some(now);
    }

    /// When the host's last heartbeat arrived (`None`: none since boot).
    pub fn last_host_heartbeat(&self) -> Option<Instant> {
        self.last_host
    }

    /// Why the drone last left normal flight since it was armed (`None`: it has not); after
    /// a landing, why it landed ([`FailsafeReason::TelemetryLost`] for a lost host link).
    pub fn failsafe_reason(&self) -> Option<FailsafeReason> {
        self.failsafe.reason()
    }

    /// 512 Hz: one IMU sample (body frame x forward, y right, z down; gyro rad/s, accel m/s²)
    /// -> attitude estimate -> INDI -> mixer. Returns the motor throttles (FR, RR, RL, FL) in
    /// [0, 1]: all zero unless armed and flying. A sample with non-finite or absurd values
    /// (|gyro| > 35 rad/s, |accel| > 160 m/s²) is dropped; if no usable sample arrives for the
    /// IMU timeout the motors go off (see [`crate::failsafe`]).
    pub fn on_imu(&mut self, imu: &ImuSample, now: Instant) -> [f32; 4] {
        let ok = finite3(&imu.gyro_radps, 35.0) && finite3(&imu.accel_mps2, 160.0);
        // A gap before this sample trips the IMU failsafe even if guidance did not run.
        let f = self.freshness();
        self.failsafe.update(&f, now);
        if !ok {
            if !self.failsafe.imu_fresh(&f, now) || !self.failsafe.mode().motors_enabled() {
                self.motors = MOTORS_OFF;
            }
            return self.motors;
        }
        let dt = match self.last_imu {
            Some(t) if now > t => (now - t).as_secs_f32().min(0.02),
            Some(_) => 0.0,
            None => 1.0 / self.cfg.indi.rate_hz.max(1.0),
        };
        self.last_imu = Some(now);
        if !self.failsafe.mode().motors_enabled()
            && self.gyro_cal.update(
                imu,
                self.cfg.gyro_calibration.samples,
                self.cfg.gyro_calibration.still_radps,
            )
        {
            // Start the attitude again from the accelerometer, without the tilt error the
            // uncorrected gyro built up.
            self.att = AttitudeEstimator::new(self.cfg.attitude);
        }
        let gyro = self.gyro_cal.correct(imu.gyro_radps);
        self.gyro = gyro;
        self.att.update(gyro, imu.accel_mps2, dt);
        self.accel = imu.accel_mps2;

        let q = self.att.quat();
        let [roll, pitch, _] = q.to_euler();
        self.vertical
            .predict(vertical_acceleration(imu.accel_mps2, q), dt);
        self.estimation
            .predict(roll, pitch, gyro[2], dt, now, &self.cfg.estimation);
        let thrust = if self.failsafe.mode().motors_enabled() {
            tilt_compensate(
                self.guidance.setpoints().thrust,
                roll,
                pitch,
                self.cfg.height.max_tilt_factor,
            )
        } else {
            0.0
        };
        let [r_sp, p_sp, y_sp] = self.guidance.setpoints().attitude_rad;
        let err = attitude_error(q, Quat::from_euler(r_sp, p_sp, y_sp));
        let u = self.indi.control(err, gyro, thrust);
        if thrust <= 0.0 {
            self.indi.actuator_update([0.0; 3], gyro);
            self.motors = MOTORS_OFF;
            return self.motors;
        }
        let m = mixer::mix(thrust, u[0], u[1], u[2]);
        self.indi.actuator_update(m.achieved, gyro);
        self.motors = m.throttle;
        self.motors
    }

    /// An Edge-FS estimate from the camera board, received at `now`: its obstacle reading
    /// goes to avoidance ([`Avoidance::on_estimate`]), its velocity through estimation's gates
    /// ([`VelocityEstimation::on_estimate`]) with the height and climb rate of now, and (with
    /// [`VerticalConfig::camera_climb`](crate::vertical::VerticalConfig::camera_climb)) its
    /// valid vertical velocity, turned to the world's climb rate ([`camera_climb_mps`]), to
    /// the vertical estimator, gated there as every measurement.
    pub fn on_estimate(&mut self, est: &Estimate, now: Instant) {
        self.avoidance.on_estimate(est, self.att.euler()[2], now);
        if self.cfg.vertical.camera_climb {
            if let Some(climb) = camera_climb_mps(est, self.att.quat()) {
                self.vertical
                    .on_climb_rate(climb, self.cfg.vertical.climb_noise_mps);
            }
        }
        let ctx = VisionContext {
            now,
            height_m: self.height.height_m(),
            climb_mps: self.height.climb_mps(),
        };
        self.estimation.on_estimate(est, &ctx, &self.cfg.estimation);
    }

    /// An external position fix (motion capture / simulator); only the height (`-z`) is used
    /// (the horizontal position is not: nothing here flies on it), and only with
    /// `ext_pos_enable` set. A fix goes through the vertical estimator's innovation gate
    /// first; one it refuses is counted ([`Autopilot::fixes_refused`]) and goes nowhere. Taken
    /// fixes become the height loop's measurement (as in the paper's lab), and so make the
    /// height fresh for arming, only once [`FIXES_TO_LEAD`] in a row have been taken: a lone
    /// fix moves the estimate but neither the height loop nor the arming check. The estimator
    /// keeps the height when fixes stop.
    pub fn on_external_position(&mut self, pos: &ExternalPosition, now: Instant) {
        if !self.cfg.vertical.external_fixes {
            self.fixes_refused = self.fixes_refused.wrapping_add(1);
            return;
        }
        let h = -pos.position_m[2];
        let in_stream = self.vertical.has_recent_fix();
        if !self.vertical.on_height_fix(h) {
            self.fixes_refused = self.fixes_refused.wrapping_add(1);
            self.fixes_in_row = 0;
            return;
        }
        self.fixes_in_row = if in_stream {
            self.fixes_in_row.saturating_add(1)
        } else {
            1
        };
        if self.fixes_lead() {
            self.height.on_measurement(h, now);
        }
    }

    /// Whether the external fixes are the height loop's measurement now: a stream of
    /// [`FIXES_TO_LEAD`] taken in a row, the last within the estimator's fix hold time.
    /// Otherwise the barometer's estimate is.
    fn fixes_lead(&self) -> bool {
        self.fixes_in_row >= FIXES_TO_LEAD && self.vertical.has_recent_fix()
    }

    /// External height fixes not used: refused by the vertical filter's gate, or all of them
    /// while `ext_pos_enable` is off.
    pub fn fixes_refused(&self) -> u32 {
        self.fixes_refused
    }

    /// A pilot command (RC or host). Kill always wins; arm needs fresh IMU and height, a host
    /// heartbeat within the host timeout (unless autonomous arming is allowed), an
    /// initialised attitude estimate (an accelerometer sample near 1 g), no
    /// [`Autopilot::arm_blocker`], and the drone on the ground (disarmed, killed or after an IMU
    /// fault). Every `Arm` that does not leave the drone flying is counted in
    /// [`Autopilot::arm_refused`]. [`PilotCommand::HilOutputs`] sets
    /// [`Autopilot::hil_outputs`] (enabling only while the motors are off).
    pub fn on_command(&mut self, cmd: PilotCommand, now: Instant) {
        if let PilotCommand::HilOutputs(on) = cmd {
            if !on || !self.failsafe.mode().motors_enabled() {
                self.hil_outputs = on;
            }
            return;
        }
        if cmd == PilotCommand::Arm && (!self.att.initialised() || self.arm_blocker().is_some()) {
            self.arm_refused = self.arm_refused.wrapping_add(1);
            return;
        }
        let before = self.failsafe.mode();
        let f = self.freshness();
        let after = self.failsafe.command(cmd, &f, now);
        if cmd == PilotCommand::Arm && after != FlightMode::Flying {
            // The failsafe refused it: a stale IMU or height, or not on the ground.
            self.arm_refused = self.arm_refused.wrapping_add(1);
        }
        if after == FlightMode::Flying && before != FlightMode::Flying {
            // Take-off: climb from where we are, hold the current heading.
            self.battery.rearm();
            self.height.reset_integral();
            self.guidance
                .take_off(self.height.height_m(), self.att.euler()[2]);
            self.avoidance.stop();
        }
        if !after.motors_enabled() {
            self.motors = MOTORS_OFF;
            self.guidance.motors_off();
        }
    }

    /// The RC kill input: `engaged` while the transmitter's kill switch is on, the receiver
    /// reports failsafe or has gone silent (see [`crate::rc::RcCommands::kill_reason`]). Engaging
    /// kills at once; while engaged, no `Arm` from any source is accepted. Releasing it does not
    /// arm: the drone stays killed until an explicit `Arm`.
    pub fn set_rc_kill(&mut self, engaged: bool, now: Instant) {
        if engaged && !self.rc_kill_latched {
            self.on_command(PilotCommand::Kill, now);
        }
        self.rc_kill_latched = engaged;
    }

    /// What blocks arming now, if anything.
    pub fn arm_blocker(&self) -> Option<ArmBlock> {
        if self.rc_kill_latched {
            Some(ArmBlock::RcKill)
        } else if let Some(Err(e)) = self
            .storage
            .filter(StorageStatus::blocks_arming)
            .map(|s| s.loaded)
        {
            Some(ArmBlock::ParamsNotLoaded(e))
        } else if let Some(v) = self.camera.peer_version_mismatch() {
            Some(ArmBlock::PeerVersion(v))
        } else if !self.battery.arm_ok() {
            Some(ArmBlock::BatteryLow)
        } else {
            None
        }
    }

    /// `Arm` commands refused since boot (wrapping): the attitude not initialised, an
    /// [`Autopilot::arm_blocker`], a stale IMU, height or host heartbeat, or the drone not on the ground
    /// (hovering blind or landing). An `Arm` while already flying changes nothing and is not
    /// counted.
    pub fn arm_refused(&self) -> u32 {
        self.arm_refused
    }

    /// Whether a lockstep (`hil`) image drives its PWM outputs with the motor command: off at
    /// boot, on only after the host's [`PilotCommand::HilOutputs`]`(true)` while the motors
    /// were off. The images on their own sensors ignore it.
    pub fn hil_outputs(&self) -> bool {
        self.hil_outputs
    }

    /// A barometer reading (pressure, temperature) taken at `now`, fused by the vertical
    /// estimator the height loop flies on when no external fixes come. A reading identical to
    /// the ones before it for longer than [`VerticalConfig::baro_stuck`](crate::vertical::VerticalConfig::baro_stuck) is a frozen
    /// sensor's: kept for telemetry, not fused, and counted ([`Autopilot::baro_frozen`]).
    pub fn on_baro(&mut self, reading: &BaroReading, now: Instant) {
        if reading.pressure_pa.is_finite() && reading.temperature_c.is_finite() {
            let same = matches!(self.baro, Some((_, last)) if last == *reading);
            if !same {
                self.baro_changed = now;
            }
            self.baro = Some((now, *reading));
            if self.baro_is_frozen() {
                self.baro_frozen = self.baro_frozen.wrapping_add(1);
                return;
            }
            let running = self.motors.iter().any(|&m| m > 0.0);
            if self.vertical.on_pressure(reading.pressure_pa, running) && !self.fixes_lead() {
                self.height.on_measurement(self.vertical.height_m(), now);
            }
        }
    }

    /// A supply-voltage reading, V, taken at `now` (the firmware's ADC through the divider,
    /// [`crate::board::BATTERY_ADC`]; the simulated battery), judged with the motor duties of
    /// now (see [`crate::battery`]). A flight ends in a landing once it reads low.
    pub fn on_battery(&mut self, volts: f32, now: Instant) {
        let flying = self.failsafe.mode().motors_enabled();
        self.battery.on_sample(volts, &self.motors, flying, now);
    }

    /// The battery monitor (last reading, resting voltage, verdict).
    pub fn battery(&self) -> &BatteryMonitor {
        &self.battery
    }

    /// The last barometer reading and when it was taken.
    pub fn baro(&self) -> Option<(Instant, BaroReading)> {
        self.baro
    }

    /// The barometer's readings have stayed identical for longer than
    /// [`VerticalConfig::baro_stuck`](crate::vertical::VerticalConfig::baro_stuck): a frozen sensor.
    pub fn baro_is_frozen(&self) -> bool {
        matches!(self.baro, Some((t, _))
            if t.since(self.baro_changed) > self.cfg.vertical.baro_stuck)
    }

    /// Frozen barometer readings refused since boot (wrapping).
    pub fn baro_frozen(&self) -> u32 {
        self.baro_frozen
    }

    /// The ground signature: the commanded level-flight thrust well below hover while the
    /// specific force stays near 1 g and the body still (see
    /// [`SetpointConfig::ground_thrust_ratio`](crate::setpoints::SetpointConfig::ground_thrust_ratio)).
    pub fn ground_signature(&self) -> bool {
        let cfg = &self.cfg;
        let min_force = cfg.setpoints.ground_min_specific_force * GRAVITY;
        self.guidance.setpoints().thrust
            < cfg.setpoints.ground_thrust_ratio * cfg.height.hover_thrust
            && self.ground_lp[0] >= min_force * min_force
            && self.ground_lp[1] <= GROUND_MAX_RATE_RADPS * GROUND_MAX_RATE_RADPS
    }

    /// Guidance step (e.g. 50 Hz): failsafes, avoidance FSM, force field, velocity guidance and
    /// the height loop update the setpoints the 512 Hz loop flies.
    pub fn guidance_step(&mut self, now: Instant) {
        let dt = self.guidance.tick(now);
        let [ax, ay, az] = self.accel;
        let [p, q, r] = self.gyro;
        let squares = [ax * ax + ay * ay + az * az, p * p + q * q + r * r];
        for (lp, x) in self.ground_lp.iter_mut().zip(squares) {
            *lp += GROUND_LP_ALPHA * (x - *lp);
        }
        let f = self.freshness();
        let mut mode = self.failsafe.update(&f, now);
        if !mode.motors_enabled() {
            self.rest(mode, now);
            return;
        }
        match self.battery.state() {
            BatteryState::Ok => {}
            BatteryState::Low => mode = self.failsafe.land(FailsafeReason::BatteryLow, now),
            BatteryState::Critical => {
                mode = self.failsafe.land(FailsafeReason::BatteryCritical, now);
                self.guidance.hurry_landing();
            }
        }
        let cfg = &self.cfg;
        let velocity = self.estimation.state(cfg.estimation.velocity_source);
        let h = self.height.height_m();
        let height_sp = self.guidance.height_setpoint(
            mode,
            &velocity,
            now,
            dt,
            cfg.failsafe.estimate_timeout,
            &cfg.setpoints,
        );
        let fresh_velocity = self
            .avoidance
            .cross_check(velocity.fresh(now, cfg.estimation.velocity_max_age), now);
        let request = self.avoidance.step(
            &AvoidanceInput {
                now,
                // A lost host link with the hold action: hover where it is.
                flying: mode == FlightMode::Flying && !self.failsafe.holding(),
                at_flight_height: self.guidance.at_flight_height(h, &cfg.setpoints),
                yaw_rad: self.att.euler()[2],
                held_yaw_rad: self.guidance.setpoints().attitude_rad[2],
                speed_mps: fresh_velocity.map(|[f, s]| libm::sqrtf(f * f + s * s)),
            },
            &cfg.force_field,
            cfg.failsafe.estimate_timeout,
        );
        if request.land {
            // No way to go found within the FSM's timeouts: land where it is.
            self.failsafe.land(FailsafeReason::NoWayFound, now);
        }
        self.guidance.fly(&request, fresh_velocity, dt);
        let height_fresh = matches!(self.height.last_measurement(),
            Some(t) if now.since(t) <= cfg.failsafe.height_timeout);
        let landing = mode == FlightMode::Landing;
        let down = if height_fresh {
            self.guidance
                .hold_height(&mut self.height, height_sp, h, dt, &cfg.setpoints);
            let on_ground = landing && self.ground_signature();
            self.guidance
                .touched_down(landing, h, on_ground, now, &cfg.setpoints)
        } else {
            // Blind landing (the failsafe switched to Landing): reduced thrust, then off.
            self.guidance
                .blind_landing(self.failsafe.since(), now, &cfg.setpoints)
        };
        if down {
            self.touchdown(now);
            return;
        }
        // A landing that does not end (a biased barometer holds the height above the landed
        // height): cut near the floor or on the ground signature once it has taken too long.
        let landing_for = now.since(self.failsafe.since());
        if landing
            && landing_for >= self.cfg.setpoints.land_timeout
            && ((height_fresh && h <= self.cfg.setpoints.land_cut_height_m)
                || self.ground_signature())
        {
            self.failsafe.cut(FailsafeReason::LandTimeout, now);
            self.touchdown(now);
        }
    }

    /// Motors off (disarmed, killed, IMU fault): everything that integrates is held at zero;
    /// standing disarmed on the floor, the barometer's reading is its offset and the drone is
    /// not moving whatever the camera makes of a blank wall.
    fn rest(&mut self, mode: FlightMode, now: Instant) {
        if mode == FlightMode::Disarmed {
            self.vertical.on_ground();
            self.estimation.hold_still(now);
        }
        self.height.reset_integral();
        self.guidance.rest(self.att.euler()[2]);
        self.avoidance.stop();
        self.motors = MOTORS_OFF;
    }

    /// Touchdown confirmed (or a landing cut): disarmed, motors off, integrators empty, the
    /// FSM stopped.
    fn touchdown(&mut self, now: Instant) {
        self.failsafe.landed(now);
        self.guidance.landed();
        self.motors = MOTORS_OFF;
        self.height.reset_integral();
        self.avoidance.stop();
    }

    /// Motor override for the firmware's lower-priority tasks: `Some(all off)` when the motors
    /// must be off now (not armed, killed, or the IMU stale so `on_imu` is not running), `None`
    /// when the 512 Hz loop's output stands.
    pub fn motor_safety(&self, now: Instant) -> Option<[f32; 4]> {
        let f = self.freshness();
        if !self.failsafe.mode().motors_enabled() || !self.failsafe.imu_fresh(&f, now) {
            Some(MOTORS_OFF)
        } else {
            None
        }
    }

    /// The `heartbeat` task's message at board time `now`, to both links (the camera board
    /// and the host): this node, the protocol version and the uptime, ms (wrapping as the
    /// wire's `u32` does).
    pub fn heartbeat(now: Instant) -> Heartbeat {
        Heartbeat::new(Node::Autopilot, now.since(Instant::ZERO).as_millis() as u32)
    }

    /// Gyro and attitude for the camera board's derotation.
    pub fn gyro_attitude(&self, now: Instant) -> GyroAttitude {
        GyroAttitude {
            timestamp_us: now.to_wire(),
            rates_radps: self.gyro,
            attitude_rad: self.att.euler(),
        }
    }

    /// The telemetry task (10 Hz): the supply voltage read this period (`None`: no battery
    /// sense; NaN: a conversion that did not end, counted as rejected), then the telemetry
    /// for the host.
    pub fn telemetry_task(&mut self, volts: Option<f32>, now: Instant) -> Telemetry {
        if let Some(v) = volts {
            self.on_battery(v, now);
        }
        self.telemetry(now)
    }

    /// Telemetry snapshot.
    pub fn telemetry(&self, now: Instant) -> Telemetry {
        Telemetry {
            timestamp_us: now.to_wire(),
            fsm_state: self.avoidance.state(),
            flight_mode: self.failsafe.mode(),
            attitude_rad: self.att.euler(),
            velocity_mps: self.velocity_estimate().unwrap_or([0.0; 2]),
            velocity_setpoint_mps: self.guidance.setpoints().velocity_mps,
            obstacle_m: self.avoidance.obstacle().and_then(|o| o.distance_m),
            height_m: self.height.height_m(),
            baro: self.baro.map(|(_, r)| r),
            link_errors: self.camera.errors(),
            failsafe_reason: self.failsafe.reason(),
            battery: self.battery.telemetry(),
            link_auth: self.link_auth.telemetry(),
        }
    }
}

/// Vertical acceleration (world frame, up, gravity removed), m/s², from a body-frame specific
/// force (x forward, y right, z down; about (0, 0, -g) at rest) and the attitude `q`.
fn vertical_acceleration(accel_mps2: [f32; 3], q: Quat) -> f32 {
    // The specific force's world-down component: its projection on world down in body axes.
    let d = q.down_in_body();
    let down = d[0] * accel_mps2[0] + d[1] * accel_mps2[1] + d[2] * accel_mps2[2];
    -(down + GRAVITY)
}

/// A camera climb rate older than this at its arrival (capture to sending,
/// `Estimate::processing_us`, which saturates at 65.5 ms) is not used: the filter takes it
/// as the climb rate of now.
pub const CLIMB_MAX_AGE: Duration = Duration::from_millis(60);

/// Without a valid forward and sideways velocity the camera's vertical velocity alone is the
/// climb rate only up to this tilt, `cos(0.1 rad)`: at 0.1 rad a horizontal speed of 0.3 m/s
/// adds at most 3 cm/s.
pub const CLIMB_LEVEL_MIN_COS_TILT: f32 = 0.995;

/// The world climb rate (m/s, up) from an estimate's camera-frame velocity and the attitude
/// `q`, when its vertical velocity is valid (`up_flags` empty) and recent
/// ([`CLIMB_MAX_AGE`]). The camera looks along the body x axis: its velocity in body axes (x
/// forward, y right, z down) is `(forward, sideways, -up)`, and the climb rate is minus its
/// projection on world down. The forward and sideways components count only when the
/// estimate's `flags` say they are valid; otherwise the vertical velocity alone is taken, and
/// only near level ([`CLIMB_LEVEL_MIN_COS_TILT`]).
pub fn camera_climb_mps(est: &Estimate, q: Quat) -> Option<f32> {
    let age = Duration::from_micros(u64::from(est.processing_us));
    if !est.up_flags.is_valid() || age > CLIMB_MAX_AGE || !est.up_mps.is_finite() {
        return None;
    }
    let d = q.down_in_body();
    let horizontal = [est.forward_mps, est.sideways_mps];
    let along = if est.is_valid() && horizontal.iter().all(|v| v.is_finite()) {
        d[0] * horizontal[0] + d[1] * horizontal[1]
    } else if d[2] >= CLIMB_LEVEL_MIN_COS_TILT {
        0.0
    } else {
        return None;
    };
    Some(d[2] * est.up_mps - along)
}

#[cfg(test)]
#[path = "app_tests.rs"]
mod tests;
