//! One closed-loop flight: world, IMU, camera, the two boards' task graphs on a virtual clock,
//! and the two UART directions between them. Deterministic: the same [`FlightConfig`] gives the
//! same [`FlightResult`], bit for bit.

use super::battery::Battery;
use super::boards::{autopilot_tasks, camera_tasks, send};
use super::camera::CameraParams;
use super::dynamics::Drone;
pub use super::flight_config::FlightConfig;
pub use super::log_row::LogRow;
use super::metrics::{estimate_rmse_mps, velocity_rmse_mps, EstimateCheck, TrackingFigures};
use super::scene::Scene;
use super::sched::{BoardTask, Release, Scheduler, SensorSchedule};
use super::uart::{SimUart, UartStats};
use super::world::World;
use autopilot::app::Autopilot;
use autopilot::ms5611::BaroReading;
use autopilot::tasks::Task as ApTask;
use protocol::{
    AutopilotToStereo, BoardToHost, BoardToHostDecoder, Decoder, Estimate, FailsafeReason,
    FlightMode, Heartbeat, HostToBoard, ImuSample, Message, Node, PilotCommand, StereoToAutopilot,
    WireTime, STEREO_FRAME_BYTES,
};
use std::collections::VecDeque;
use stereo_board::app::StereoBoardApp;
use stereo_board::app::Task as CamTask;
use stereo_board::edge_fs::{Diagnostics, EdgeFsOutput};
use timebase::{Duration, Instant, WorldTime};

use super::US_PER_S;

/// Progress is reported once per this much simulated time.
const PROGRESS_PERIOD: Duration = Duration::from_secs(1);
/// Captures whose true velocity is kept to check the estimates against: far more than the
/// estimates on their way over the link at any time.
const TRUTH_CAPTURES: usize = 32;
/// Salt of the flight's seed for the camera board -> autopilot UART's faults (each direction
/// draws its own random stream).
const S2A_SEED_SALT: u64 = 0x52a;
/// Salt of the flight's seed for the autopilot -> camera board UART's faults.
const A2S_SEED_SALT: u64 = 0xa25;

/// Why a flight ended: the last column of every summary.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EndReason {
    /// The full simulated duration flown.
    Duration,
    /// A wall or obstacle was hit (the flight time ends there).
    Collision,
    /// The autopilot landed, for this reason, and disarmed.
    Landed(FailsafeReason),
    /// The motors stopped without a landing (killed, IMU fault).
    MotorsStopped(FlightMode),
}

impl EndReason {
    /// The summary's words for it: `duration`, `collision`, `landed: low battery`, ...
    pub fn describe(self) -> String {
        match self {
            EndReason::Duration => "duration".into(),
            EndReason::Collision => "collision".into(),
            EndReason::Landed(reason) => format!("landed: {}", landing_words(reason)),
            EndReason::MotorsStopped(mode) => format!("stopped: {}", mode.name()),
        }
    }

    /// Why the flight of `ap` ended, with `collided` when it hit something.
    pub fn of(ap: &Autopilot, armed: bool, collided: bool) -> Self {
        if collided {
            return EndReason::Collision;
        }
        match (armed, ap.mode(), ap.failsafe_reason()) {
            (true, FlightMode::Disarmed, Some(reason)) => EndReason::Landed(reason),
            (true, mode @ (FlightMode::Killed | FlightMode::ImuFault), _) => {
                EndReason::MotorsStopped(mode)
            }
            _ => EndReason::Duration,
        }
    }
}

/// What a summary says of a landing's reason: `no texture` for a lost estimate (what the
/// camera most often lacks), `low battery`, `telemetry lost`, `search exhausted`, ...
fn landing_words(reason: FailsafeReason) -> &'static str {
    match reason {
        FailsafeReason::Command => "command",
        FailsafeReason::EstimateLost => "no texture",
        FailsafeReason::HeightLost => "height lost",
        FailsafeReason::ImuLost => "imu lost",
        FailsafeReason::TelemetryLost => "telemetry lost",
        FailsafeReason::NoWayFound => "search exhausted",
        FailsafeReason::LandTimeout => "land timeout",
        FailsafeReason::BaroFrozen => "barometer frozen",
        FailsafeReason::BatteryLow => "low battery",
        FailsafeReason::BatteryCritical => "critical battery",
    }
}

/// Outcome of a flight.
#[derive(Debug, Clone)]
pub struct FlightResult {
    /// Seed.
    pub seed: u64,
    /// Simulated duration, s.
    pub duration_s: f64,
    /// Time until the first collision, or the full duration, s.
    pub flight_time_s: f64,
    /// Why the flight ended.
    pub end_reason: EndReason,
    /// Number of collisions (contacts entered).
    pub collisions: u32,
    /// RMS error of the autopilot's velocity estimate (what it flies on, [`LogRow::vel_est`])
    /// against the true velocity in the heading frame, forward and sideways together, sampled
    /// at 50 Hz while the avoidance FSM runs, m/s.
    pub vel_rmse_mps: f64,
    /// RMS error of every valid raw Edge-FS estimate (forward and sideways together) against
    /// the true body velocity at its capture time, while airborne, m/s. Rare gross outliers
    /// (which the autopilot's plausibility limit rejects) dominate it.
    pub raw_vel_rmse_mps: f64,
    /// How well the drone followed its setpoints (from the 50 Hz log).
    pub tracking: TrackingFigures,
    /// Smallest clearance minus drone radius while airborne, m.
    pub min_clearance_m: f64,
    /// Horizontal distance flown, m.
    pub distance_m: f64,
    /// 50 Hz log.
    pub log: Vec<LogRow>,
    /// Kept left camera images `(t_s, 128x96 gray)`.
    pub images: Vec<(f64, Vec<u8>)>,
    /// Link statistics camera -> autopilot and autopilot -> camera.
    pub uart: [UartStats; 2],
    /// Estimates received / valid by the autopilot.
    pub estimates: [u64; 2],
    /// Frames dropped by the camera board.
    pub frames_dropped: u32,
    /// Telemetry messages the host decoded from the autopilot's telemetry task (10 Hz while
    /// the host link is up).
    pub telemetry_received: u32,
    /// The scene flown in.
    pub scene: Scene,
    /// Why the autopilot last left normal flight (`Autopilot::failsafe_reason` at the end;
    /// `None`: it flew normally to the end); `Some(FailsafeReason::TelemetryLost)` after a
    /// landing for a lost host link.
    pub failsafe_reason: Option<FailsafeReason>,
    /// Guidance steps at which the obstacle's range rate overruled the velocity estimate
    /// (`Autopilot::velocity_overruled` at the end).
    pub velocity_overruled: u32,
}

/// Counters of a flight so far, as an observer sees them.
#[derive(Debug, Clone, Copy, Default)]
pub struct FlightCounters {
    /// Estimates received / valid by the autopilot.
    pub estimates: [u64; 2],
    /// Frames dropped by the camera board.
    pub frames_dropped: u32,
    /// Contacts with walls and obstacles.
    pub collisions: u32,
    /// Link statistics camera -> autopilot and autopilot -> camera.
    pub uart: [UartStats; 2],
}

/// What a flight shows as it happens (a flight log records it), at simulated world times.
pub trait FlightObserver {
    /// Once before the flight: the room it flies in and the stereo camera's mounting.
    fn on_scene(&mut self, _scene: &Scene, _camera: &CameraParams) {}
    /// An estimate as the autopilot received it (decoded from the wire).
    fn on_estimate(&mut self, _t: WorldTime, _estimate: &Estimate) {}
    /// A stereo frame exposed at `t` (interleaved `[L0 R0 L1 R1 ...]`).
    fn on_frame(&mut self, _t: WorldTime, _frame: &[u8; STEREO_FRAME_BYTES]) {}
    /// After Edge-FS processed a frame: its per-column diagnostics (stereo depths, flow).
    fn on_edge_fs(&mut self, _t: WorldTime, _diagnostics: &Diagnostics) {}
    /// A barometer reading as the autopilot received it.
    fn on_baro(&mut self, _t: WorldTime, _reading: &BaroReading) {}
    /// A battery voltage reading the autopilot received (and judged), and the simulated
    /// battery it came from.
    fn on_battery(&mut self, _t: WorldTime, _ap: &Autopilot, _battery: &Battery) {}
    /// After each 512 Hz control step: the gyro sample the autopilot got (rad/s) and the motor
    /// duties applied (0..=1).
    fn on_control(
        &mut self,
        _t: WorldTime,
        _ap: &Autopilot,
        _gyro_radps: [f32; 3],
        _motors: [f32; 4],
    ) {
    }
    /// After each 50 Hz guidance step, with the log row of that instant.
    fn on_guidance(
        &mut self,
        _t: WorldTime,
        _ap: &Autopilot,
        _row: &LogRow,
        _counters: &FlightCounters,
    ) {
    }
    /// Asked before each event of the flight: true ends it there (Ctrl-C), and the result
    /// covers the time flown.
    fn interrupted(&self) -> bool {
        false
    }
}

/// An observer that ignores everything.
pub struct NoObserver;

impl FlightObserver for NoObserver {}

/// A frame waiting for the camera board.
struct PendingFrame {
    ready: WorldTime,
    capture: Instant,
    frame: Box<[u8; STEREO_FRAME_BYTES]>,
}

/// Runs one flight. `progress` is called with the simulated time (s) about once per simulated
/// second.
pub fn run_flight(
    cfg: &FlightConfig,
    progress: &mut dyn FnMut(f64),
) -> anyhow::Result<FlightResult> {
    run_flight_observed(cfg, progress, &mut NoObserver)
}

/// [`run_flight`], showing the flight to `observer` as it happens.
pub fn run_flight_observed(
    cfg: &FlightConfig,
    progress: &mut dyn FnMut(f64),
    observer: &mut dyn FlightObserver,
) -> anyhow::Result<FlightResult> {
    let mut flight = Flight::new(cfg)?;
    observer.on_scene(&flight.world.scene, &flight.world.camera.params);
    let end = WorldTime::from_micros((cfg.duration_s * US_PER_S) as u64);
    let mut next_progress = WorldTime::ZERO + PROGRESS_PERIOD;
    let mut t = WorldTime::ZERO;
    let mut flown = end;
    while t < end {
        if observer.interrupted() {
            flown = t;
            break;
        }
        let next = flight.next_event(t, end);
        // Physics up to the event.
        if next > t {
            flight
                .world
                .step(&flight.motors, (next - t).as_secs_f64(), next);
        }
        t = next;
        if cfg.stop_on_collision && flight.world.first_contact_s.is_some() {
            break;
        }
        if t >= next_progress {
            progress(t.as_secs_f64());
            next_progress += PROGRESS_PERIOD;
        }
        flight.link_arrivals(t, observer);
        flight.camera_board(t, observer);
        flight.exposure(t, observer);
        flight.host_and_sensors(t, observer);
        flight.periodic_tasks(t, observer);
    }
    Ok(flight.result(flown, end))
}

/// What a flight records for its figures, which are computed from it afterwards.
#[derive(Default)]
struct FlightRecord {
    log: Vec<LogRow>,
    images: Vec<(f64, Vec<u8>)>,
    frames: u32,
    /// Estimates received / valid by the autopilot.
    estimates: [u64; 2],
    /// Each valid estimate against the true velocity at its capture.
    estimate_checks: Vec<EstimateCheck>,
    /// Telemetry messages the host decoded.
    telemetry_received: u32,
}

/// One flight in progress: the world, both boards' task logic, the links between them and
/// the host, and the event clocks. Each method handles one kind of event at world time `t`.
struct Flight<'a> {
    cfg: &'a FlightConfig,
    world: World,
    ap: Autopilot,
    cb: Box<StereoBoardApp>,
    /// Camera board -> autopilot, autopilot -> camera board.
    s2a: SimUart,
    a2s: SimUart,
    /// The simulator's own decoder on the camera board's link (a logic analyser on the wire).
    tap: Decoder<StereoToAutopilot, { StereoToAutopilot::MAX_FRAME_BYTES }>,
    /// What the host hears of the autopilot's telemetry link.
    host_rx: BoardToHostDecoder,
    sched: Scheduler,
    releases: Vec<Release>,
    sensors: SensorSchedule,
    arm_at: WorldTime,
    host_cut_at: WorldTime,
    armed: bool,
    motors: [f64; 4],
    /// A read-out frame on its way to the camera board, and when the board is free again.
    pending: Option<PendingFrame>,
    busy_until: WorldTime,
    /// Camera board results waiting for their processing time to pass.
    outbox: VecDeque<(WorldTime, Instant, EdgeFsOutput)>,
    /// The true body velocity at each recent capture time (as the estimates carry it).
    truth_at_capture: VecDeque<(WireTime, [f32; 2])>,
    rxbuf: Vec<u8>,
    /// The last estimate as received, for the log.
    latest: LatestEstimate,
    record: FlightRecord,
}

impl<'a> Flight<'a> {
    fn new(cfg: &'a FlightConfig) -> anyhow::Result<Self> {
        let world = World::new(cfg)?;
        let ap = Autopilot::try_new(cfg.autopilot)
            .map_err(|r| anyhow::anyhow!("autopilot configuration refused: {r}"))?;
        let mut tasks = autopilot_tasks();
        tasks.extend(camera_tasks());
        Ok(Self {
            cfg,
            world,
            ap,
            cb: Box::new(StereoBoardApp::new(cfg.edge_fs)),
            s2a: SimUart::new(cfg.baud, cfg.faults_s2a.clone(), cfg.seed ^ S2A_SEED_SALT),
            a2s: SimUart::new(cfg.baud, cfg.faults_a2s.clone(), cfg.seed ^ A2S_SEED_SALT),
            tap: Decoder::new(),
            host_rx: BoardToHostDecoder::new(),
            sched: Scheduler::new(tasks),
            releases: Vec::new(),
            sensors: SensorSchedule::new(
                cfg.camera.fps,
                cfg.mocap.then_some(cfg.height_rate_hz),
                Some(cfg.baro.rate_hz),
            ),
            arm_at: WorldTime::from_micros((cfg.arm_at_s * US_PER_S) as u64),
            host_cut_at: WorldTime::from_micros(
                cfg.host_link_cut_at_s
                    .map_or(u64::MAX, |s| (s * US_PER_S) as u64),
            ),
            armed: false,
            motors: [0.0; 4],
            pending: None,
            busy_until: WorldTime::ZERO,
            outbox: VecDeque::new(),
            truth_at_capture: VecDeque::new(),
            rxbuf: Vec::new(),
            latest: LatestEstimate::NONE,
            record: FlightRecord::default(),
        })
    }

    /// The time of the next event after `t`: a physics step at the latest, never past `end`.
    fn next_event(&self, t: WorldTime, end: WorldTime) -> WorldTime {
        let mut next = end.min(t + self.cfg.physics_dt);
        next = next.min(self.sensors.next());
        if let Some(r) = self.sched.next_release() {
            next = next.min(r);
        }
        if let Some(p) = &self.pending {
            next = next.min(p.ready);
        }
        if let Some((r, _, _)) = self.outbox.front() {
            next = next.min(*r);
        }
        if !self.armed {
            next = next.min(self.arm_at);
        }
        next.max(t)
    }

    /// UART arrivals in both directions (the RX idle-line tasks).
    fn link_arrivals(&mut self, t: WorldTime, observer: &mut dyn FlightObserver) {
        self.rxbuf.clear();
        self.s2a.receive(t, &mut self.rxbuf);
        if !self.rxbuf.is_empty() {
            // The autopilot's stereo_rx task decodes the bytes itself; the simulator taps the
            // same bytes with its own decoder for the figures.
            self.ap.on_stereo_bytes(&self.rxbuf, t.as_flight_clock());
            let (record, latest) = (&mut self.record, &mut self.latest);
            let (truth, height_m) = (&self.truth_at_capture, -self.world.drone.state.pos.z);
            self.tap.feed(&self.rxbuf, |m| {
                if let StereoToAutopilot::Estimate(e) = m {
                    observer.on_estimate(t, &e);
                    record.estimates[0] += 1;
                    *latest = LatestEstimate {
                        velocity_mps: [f32::NAN; 2],
                        contact_s: nan_opt(e.divergence.and_then(|d| d.time_to_contact_s())),
                    };
                    if e.is_valid() {
                        record.estimates[1] += 1;
                        latest.velocity_mps = [e.forward_mps, e.sideways_mps];
                        if let Some(&(_, v)) = truth.iter().find(|(c, _)| *c == e.capture_us) {
                            record.estimate_checks.push(EstimateCheck {
                                estimate_mps: [e.forward_mps, e.sideways_mps],
                                truth_mps: v,
                                height_m,
                            });
                        }
                    }
                }
            });
        }
        self.rxbuf.clear();
        self.a2s.receive(t, &mut self.rxbuf);
        // The simulated camera board's clock is the world's.
        let cb_now = t.as_flight_clock();
        if !self.rxbuf.is_empty() {
            let s2a = &mut self.s2a;
            self.cb
                .on_rx_bytes(&self.rxbuf, cb_now, &mut |b: &[u8]| s2a.write(t, b), None);
        }
    }

    /// The camera board: results leave after their processing time; a read-out frame starts
    /// Edge-FS.
    fn camera_board(&mut self, t: WorldTime, observer: &mut dyn FlightObserver) {
        let cb_now = t.as_flight_clock();
        while self.outbox.front().is_some_and(|(r, _, _)| *r <= t) {
            if let Some((_, capture, out)) = self.outbox.pop_front() {
                let s2a = &mut self.s2a;
                self.cb
                    .send_estimate(&out, capture, cb_now, &mut |b: &[u8]| s2a.write(t, b));
            }
        }
        if self.pending.as_ref().is_some_and(|p| p.ready <= t) {
            if let Some(p) = self.pending.take() {
                // Edge-FS starts now (gyro sample as of now); the estimate leaves when the
                // modelled processing time is over.
                let out = self.cb.process_frame(&p.frame, p.capture, cb_now);
                observer.on_edge_fs(t, self.cb.edge_fs().diagnostics());
                let done = t + self.cfg.processing;
                self.busy_until = done;
                self.outbox.push_back((done, p.capture, out));
            }
        }
    }

    /// The camera's exposure: a frame rendered, read out to the camera board (or dropped while
    /// the board is busy).
    fn exposure(&mut self, t: WorldTime, observer: &mut dyn FlightObserver) {
        if !self.sensors.frame.due(t) {
            return;
        }
        let mut frame = Box::new([0u8; STEREO_FRAME_BYTES]);
        self.world.render(&mut frame);
        observer.on_frame(t, &frame);
        let state = &self.world.drone.state;
        let vb = state.att.rotate_inv(state.vel);
        self.truth_at_capture
            .push_back((t.to_wire(), [vb.x as f32, vb.y as f32]));
        if self.truth_at_capture.len() > TRUTH_CAPTURES {
            self.truth_at_capture.pop_front();
        }
        self.record.frames += 1;
        let keep = self.cfg.keep_image_every;
        if keep > 0 && self.record.frames.is_multiple_of(keep) {
            let left = frame.iter().step_by(2).copied().collect();
            self.record.images.push((t.as_secs_f64(), left));
        }
        let ready = t + self.cfg.readout;
        if self.pending.is_some() || self.busy_until > ready {
            self.cb.frame_dropped();
        } else {
            self.pending = Some(PendingFrame {
                ready,
                capture: t.as_flight_clock(),
                frame,
            });
        }
    }

    /// The host's heartbeat and height fixes (motion capture) on the autopilot's host link
    /// until it is cut, the barometer on the autopilot's SPI bus, and the host's arm command.
    fn host_and_sensors(&mut self, t: WorldTime, observer: &mut dyn FlightObserver) {
        let host_link = t < self.host_cut_at;
        // The autopilot's clock is the world's.
        let now = t.as_flight_clock();
        let ap = &mut self.ap;
        // Due first: the clock runs on while the link is cut.
        if self.sensors.host_heartbeat.due(t) && host_link {
            let hb = Heartbeat::new(Node::Host, t.since(WorldTime::ZERO).as_millis() as u32);
            ap.on_host_message(HostToBoard::Heartbeat(hb), now, None);
        }
        if self.sensors.height_fix.due(t) {
            let fix = self.world.height_fix(t);
            if host_link {
                ap.on_host_message(HostToBoard::ExternalPosition(fix), now, None);
            }
        }
        if self.sensors.baro.due(t) {
            let reading = self.world.baro_reading(t, &self.motors);
            ap.on_baro(&reading, now);
            observer.on_baro(t, &reading);
        }
        if !self.armed && t >= self.arm_at {
            self.armed = true;
            ap.on_host_message(HostToBoard::Command(PilotCommand::Arm), now, None);
        }
    }

    /// The periodic tasks of both boards due at `t`, highest priority first.
    fn periodic_tasks(&mut self, t: WorldTime, observer: &mut dyn FlightObserver) {
        self.releases.clear();
        self.sched.due(t, &mut self.releases);
        for i in 0..self.releases.len() {
            let task = self.releases[i].task;
            self.run_task(task, t, observer);
        }
    }

    /// One task body, as the board's firmware runs it.
    fn run_task(&mut self, task: BoardTask, t: WorldTime, observer: &mut dyn FlightObserver) {
        // Both boards' clocks are the world's.
        let now = t.as_flight_clock();
        let ap = &mut self.ap;
        match task {
            BoardTask::Autopilot(ApTask::ImuIndi) => {
                let s = self.world.imu_sample();
                let out = ap.on_imu(
                    &ImuSample {
                        timestamp_us: t.to_wire(),
                        gyro_radps: s.gyro.to_f32(),
                        accel_mps2: s.accel.to_f32(),
                    },
                    now,
                );
                self.motors = out.map(|m| m as f64);
                observer.on_control(t, ap, s.gyro.to_f32(), out);
            }
            BoardTask::Autopilot(ApTask::Guidance) => {
                ap.guidance_step(now);
                if let Some(off) = ap.motor_safety(now) {
                    self.motors = off.map(|m| m as f64);
                }
                let world = &self.world;
                let row = log_row(ap, &world.drone, &world.scene, t, self.latest, self.motors);
                let counters = FlightCounters {
                    estimates: self.record.estimates,
                    frames_dropped: self.cb.counters().frames_dropped,
                    collisions: world.collisions,
                    uart: [self.s2a.stats(), self.a2s.stats()],
                };
                observer.on_guidance(t, ap, &row, &counters);
                self.record.log.push(row);
            }
            BoardTask::Autopilot(ApTask::GyroTx) => {
                let msg = AutopilotToStereo::GyroAttitude(ap.gyro_attitude(now));
                send(&msg, &mut |b: &[u8]| self.a2s.write(t, b));
            }
            BoardTask::Autopilot(ApTask::Heartbeat) => {
                let msg = AutopilotToStereo::Heartbeat(Autopilot::heartbeat(now));
                send(&msg, &mut |b: &[u8]| self.a2s.write(t, b));
            }
            BoardTask::Autopilot(ApTask::Telemetry) => {
                // The supply voltage on the autopilot's ADC, through the divider.
                let volts = self.world.battery.as_ref().map(|battery| {
                    let lsb = f64::from(autopilot::board::BATTERY_ADC.volts_per_count);
                    ((battery.terminal_v() / lsb).round() * lsb) as f32
                });
                let telemetry = ap.telemetry_task(volts, now);
                if let Some(battery) = &self.world.battery {
                    observer.on_battery(t, ap, battery);
                }
                if t < self.host_cut_at {
                    let (host_rx, record) = (&mut self.host_rx, &mut self.record);
                    send(&BoardToHost::Telemetry(telemetry), &mut |b: &[u8]| {
                        for &byte in b {
                            if let Some(BoardToHost::Telemetry(_)) = host_rx.push(byte) {
                                record.telemetry_received += 1;
                            }
                        }
                    });
                }
            }
            BoardTask::Stereo(CamTask::Status) => {
                let s2a = &mut self.s2a;
                // No capture path to report and no host link: the simulated camera board's
                // frames come from the world, straight into its frame task.
                self.cb.status_tick(
                    now,
                    None,
                    &mut |b: &[u8]| s2a.write(t, b),
                    &mut |_: &[u8]| {},
                );
            }
            // Event-driven: run where their event happens (a frame, link bytes).
            BoardTask::Autopilot(ApTask::StereoRx | ApTask::HostRx)
            | BoardTask::Stereo(CamTask::UartRx | CamTask::HostRx | CamTask::Frame) => {}
        }
    }

    /// The flight's result after `flown` of the planned `end`, its figures computed from
    /// what it recorded.
    fn result(self, flown: WorldTime, end: WorldTime) -> FlightResult {
        let cfg = self.cfg;
        let world = self.world;
        let record = self.record;
        FlightResult {
            seed: cfg.seed,
            duration_s: if flown < end {
                flown.as_secs_f64()
            } else {
                cfg.duration_s
            },
            flight_time_s: world
                .first_contact_s
                .unwrap_or(cfg.duration_s.min(flown.as_secs_f64())),
            end_reason: EndReason::of(&self.ap, self.armed, world.first_contact_s.is_some()),
            collisions: world.collisions,
            vel_rmse_mps: velocity_rmse_mps(&record.log),
            raw_vel_rmse_mps: estimate_rmse_mps(&record.estimate_checks),
            tracking: TrackingFigures::from_log(&record.log),
            min_clearance_m: if world.min_clearance_m.is_finite() {
                world.min_clearance_m
            } else {
                f64::NAN
            },
            distance_m: world.distance_m,
            log: record.log,
            images: record.images,
            uart: [self.s2a.stats(), self.a2s.stats()],
            estimates: record.estimates,
            frames_dropped: self.cb.counters().frames_dropped,
            telemetry_received: record.telemetry_received,
            scene: world.scene,
            failsafe_reason: self.ap.failsafe_reason(),
            velocity_overruled: self.ap.velocity_overruled(),
        }
    }
}

/// The last Edge-FS estimate the autopilot received, as the log shows it.
#[derive(Debug, Clone, Copy)]
struct LatestEstimate {
    /// Forward and sideways velocity, m/s (NaN: invalid).
    velocity_mps: [f32; 2],
    /// Time to contact, s (NaN: none, or the view does not expand).
    contact_s: f32,
}

impl LatestEstimate {
    /// No estimate yet.
    const NONE: Self = Self {
        velocity_mps: [f32::NAN; 2],
        contact_s: f32::NAN,
    };
}

fn nan_opt(v: Option<f32>) -> f32 {
    v.unwrap_or(f32::NAN)
}

fn log_row(
    ap: &Autopilot,
    drone: &Drone,
    scene: &Scene,
    t: WorldTime,
    latest: LatestEstimate,
    motors: [f64; 4],
) -> LogRow {
    let s = &drone.state;
    let (_, _, yaw) = s.att.to_euler();
    let (sy, cy) = yaw.sin_cos();
    // Velocity in the heading frame (level body axes).
    let vf = s.vel.x * cy + s.vel.y * sy;
    let vs = -s.vel.x * sy + s.vel.y * cy;
    let now = t.as_flight_clock();
    let tel = ap.telemetry(now);
    let v = ap.velocity_estimate();
    let h = -s.pos.z as f32;
    LogRow {
        t_s: t.as_secs_f64(),
        pos: [s.pos.x as f32, s.pos.y as f32, h],
        yaw: yaw as f32,
        vel_true: [vf as f32, vs as f32],
        vel_est: [nan_opt(v.map(|v| v[0])), nan_opt(v.map(|v| v[1]))],
        vel_sp: tel.velocity_setpoint_mps,
        height_sp_m: ap.setpoints().height_m,
        vel_raw: latest.velocity_mps,
        obstacle_m: nan_opt(tel.obstacle_m),
        closing_mps: nan_opt(ap.closing(now).map(|c| c.mps)),
        overrule_mps: nan_opt(ap.velocity_overrule()),
        contact_s: latest.contact_s,
        clearance_m: scene.clearance(s.pos.x as f32, s.pos.y as f32, h)
            - drone.params.radius_m as f32,
        fsm_state: tel.fsm_state,
        mode: tel.flight_mode,
        motors: motors.map(|m| m as f32),
        tilt_err_deg: {
            let (roll, pitch, _) = s.att.to_euler();
            let [r_est, p_est, _] = ap.attitude();
            [
                (r_est - roll as f32).to_degrees(),
                (p_est - pitch as f32).to_degrees(),
            ]
        },
    }
}
