//! What a user does to fly the autopilot, done on the bench: the ground tool's heartbeat, height
//! fixes and pilot commands over the telemetry port, as `sim-host hil` sends them (a host
//! `Heartbeat` a second, an `ExternalPosition` at 50 Hz of a drone that climbs as one does, a
//! `PilotCommand::Arm` when the user arms), and events scheduled on the bench's stops.
//!
//! A stop lands a little after the instant it was asked for (rigless stops at an instruction
//! boundary, or where a sleeping core wakes), so a schedule never compares a stop's time for
//! equality: [`Once`] and [`Every`] fire at the first stop at or after their instant.

use protocol::{ExternalPosition, Heartbeat, HostToBoard, Node, PilotCommand};

use crate::host;
use crate::link::Line;

/// One nanosecond-stamped millisecond.
pub const MS: u64 = 1_000_000;

/// An instant on the bench's clock that fires once, at the first stop at or after it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Once {
    at_ns: u64,
    fired: bool,
}

impl Once {
    /// Fires at `at_ns` of virtual time.
    #[must_use]
    pub const fn at(at_ns: u64) -> Self {
        Self {
            at_ns,
            fired: false,
        }
    }

    /// Whether it fires at this stop (`now_ns`): true once, at the first stop at or after its
    /// instant.
    pub fn due(&mut self, now_ns: u64) -> bool {
        if self.fired || now_ns < self.at_ns {
            return false;
        }
        self.fired = true;
        true
    }

    /// Whether it has fired.
    #[must_use]
    pub fn fired(&self) -> bool {
        self.fired
    }

    /// Its instant, ns.
    #[must_use]
    pub fn instant_ns(&self) -> u64 {
        self.at_ns
    }
}

/// A period on the bench's clock: fires at the first stop at or after each multiple of it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Every {
    period_ns: u64,
    next_ns: u64,
}

impl Every {
    /// Every `period_ns` (at least 1), starting at 0.
    #[must_use]
    pub const fn ns(period_ns: u64) -> Self {
        Self {
            period_ns: if period_ns == 0 { 1 } else { period_ns },
            next_ns: 0,
        }
    }

    /// Whether it fires at this stop (`now_ns`). Multiples the stops stepped over fire once,
    /// not once each.
    pub fn due(&mut self, now_ns: u64) -> bool {
        if now_ns < self.next_ns {
            return false;
        }
        self.next_ns = (now_ns / self.period_ns + 1) * self.period_ns;
        true
    }
}

/// The ground tool's height-fix period (`sim-host hil` sends 50 per second), ns.
pub const HEIGHT_FIX_PERIOD_NS: u64 = 20 * MS;

/// The ground tool's heartbeat period (every host tool sends one a second), ns.
pub const HEARTBEAT_PERIOD_NS: u64 = 1_000 * MS;

/// The take-off climb rate the ground station's drone flies at: the firmware's own
/// (`climb_rate_mps`, the rate its height setpoint ramps at), m/s.
#[must_use]
pub fn take_off_climb_mps() -> f64 {
    f64::from(
        autopilot::AutopilotConfig::default()
            .setpoints
            .climb_rate_mps,
    )
}

/// How hard the ground station's drone speeds up into its climb and slows at its hover height,
/// m/s^2: a gentle take-off, 0.5 s to the climb rate (a drone's climb does not start in one
/// instant, and the firmware's vertical filter gates a fix stream that says it did).
pub const TAKE_OFF_ACCEL_MPS2: f64 = 1.0;

/// The user at the ground tool: a host heartbeat every [`HEARTBEAT_PERIOD_NS`] and height fixes
/// every [`HEIGHT_FIX_PERIOD_NS`] on the telemetry port from boot, and an `Arm` at the instant
/// the test chooses.
///
/// The fixes are a motion-capture system's: they report where the drone is, which moves as a
/// drone does. On the floor until the `Arm`, then climbing at the firmware's take-off climb rate
/// ([`take_off_climb_mps`], reached and left at [`TAKE_OFF_ACCEL_MPS2`]) to the hover height,
/// until the test's own world takes the height
/// over ([`GroundStation::set_height`]).
#[derive(Debug, Clone)]
pub struct GroundStation {
    heartbeats: Every,
    fixes: Every,
    arm: Once,
    height_m: f64,
    /// The height the drone climbs to once armed, m (`None`: the test's world sets it).
    climb_to_m: Option<f64>,
    /// The climb rate now, m/s.
    climb_mps: f64,
    last_ns: Option<u64>,
    silent: bool,
    send_fixes: bool,
}

impl GroundStation {
    /// Fixes of 0 m (on the floor) until the `Arm` at `arm_at_ns`, then climbing at the take-off
    /// climb rate to `hover_m` and holding there (the bench flies no world: the drone reports
    /// as if it took off and hovered there once armed).
    #[must_use]
    pub fn arming_at(arm_at_ns: u64, hover_m: f64) -> Self {
        Self {
            heartbeats: Every::ns(HEARTBEAT_PERIOD_NS),
            fixes: Every::ns(HEIGHT_FIX_PERIOD_NS),
            arm: Once::at(arm_at_ns),
            height_m: 0.0,
            climb_to_m: Some(hover_m),
            climb_mps: 0.0,
            last_ns: None,
            silent: false,
            send_fixes: true,
        }
    }

    /// The same without height fixes: the autopilot flies on its barometer.
    #[must_use]
    pub fn without_fixes(self) -> Self {
        Self {
            send_fixes: false,
            ..self
        }
    }

    /// When the `Arm` goes out, ns.
    #[must_use]
    pub fn arm_at_ns(&self) -> u64 {
        self.arm.instant_ns()
    }

    /// The height the fixes report now, m above the floor.
    #[must_use]
    pub fn height_m(&self) -> f64 {
        self.height_m
    }

    /// The height the next fixes report, m above the floor: the test's world has the height
    /// from now on (the take-off climb stops).
    pub fn set_height(&mut self, height_m: f64) {
        self.height_m = height_m;
        self.climb_to_m = None;
        self.climb_mps = 0.0;
    }

    /// Stops (or resumes) sending anything: the ground link lost.
    pub fn set_silent(&mut self, silent: bool) {
        self.silent = silent;
    }

    /// At every stop: sends what is due on `telemetry` (the line the board hears on its
    /// telemetry port). Returns whether the `Arm` went out at this stop.
    pub fn step(&mut self, now_ns: u64, telemetry: &Line) -> bool {
        let arming = self.arm.due(now_ns);
        let dt_s = self
            .last_ns
            .map_or(0.0, |t| now_ns.saturating_sub(t) as f64 / 1e9);
        self.last_ns = Some(now_ns);
        if let Some(hover_m) = self.climb_to_m
            && self.arm.fired()
            && !arming
        {
            // Speed up to the climb rate, and slow in time to stop at the hover height.
            let to_go = (hover_m - self.height_m).max(0.0);
            let wanted = take_off_climb_mps().min((2.0 * TAKE_OFF_ACCEL_MPS2 * to_go).sqrt());
            let step = TAKE_OFF_ACCEL_MPS2 * dt_s;
            self.climb_mps += (wanted - self.climb_mps).clamp(-step, step);
            self.height_m = (self.height_m + self.climb_mps * dt_s).min(hover_m);
        }
        if self.silent {
            return false;
        }
        if self.heartbeats.due(now_ns) {
            let uptime_ms = (now_ns / MS) as u32;
            let hb = HostToBoard::Heartbeat(Heartbeat::new(Node::Host, uptime_ms));
            telemetry.send_at(now_ns, &host::frame(&hb));
        }
        if self.send_fixes && self.fixes.due(now_ns) {
            let fix = HostToBoard::ExternalPosition(ExternalPosition {
                timestamp_us: protocol::WireTime((now_ns / 1_000) as u32),
                position_m: [0.0, 0.0, -self.height_m as f32],
            });
            telemetry.send_at(now_ns, &host::frame(&fix));
        }
        if arming {
            let arm = HostToBoard::Command(PilotCommand::Arm);
            telemetry.send_at(now_ns, &host::frame(&arm));
        }
        arming
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_late_stop_still_fires_a_schedule_once() {
        let mut once = Once::at(1_500 * MS);
        assert!(!once.due(1_499 * MS + 431));
        assert!(
            once.due(1_500 * MS + 435),
            "the first stop past the instant"
        );
        assert!(!once.due(1_501 * MS + 435), "only once");
        let mut every = Every::ns(20 * MS);
        let fired: Vec<u64> = (0..100u64)
            .map(|k| k * MS + 431)
            .filter(|&t| every.due(t))
            .collect();
        assert_eq!(
            fired,
            vec![
                431,
                20 * MS + 431,
                40 * MS + 431,
                60 * MS + 431,
                80 * MS + 431
            ]
        );
    }

    #[test]
    fn the_ground_station_sends_fixes_and_one_arm() {
        let line = Line::open();
        let mut ground = GroundStation::arming_at(40 * MS, 0.5);
        let arms: usize = (0..2_000u64)
            .map(|k| ground.step(k * MS + 7, &line))
            .filter(|&armed| armed)
            .count();
        assert_eq!(arms, 1);
        let mut decoder = protocol::HostToBoardDecoder::new();
        let mut messages = Vec::new();
        for byte in line.sent_bytes() {
            if let Some(message) = decoder.push(byte) {
                messages.push(message);
            }
        }
        let heights: Vec<f32> = messages
            .iter()
            .filter_map(|m| match m {
                HostToBoard::ExternalPosition(p) => Some(-p.position_m[2]),
                _ => None,
            })
            .collect();
        assert_eq!(heights.len(), 100, "50 a second");
        assert_eq!(
            &heights[..3],
            &[0.0, 0.0, 0.0],
            "on the floor until the arm"
        );
        // Then the take-off: never faster than the climb rate (1 cm per 20 ms fix), and never
        // changing speed faster than the take-off acceleration, up to the hover height.
        let period_s = HEIGHT_FIX_PERIOD_NS as f64 / 1e9;
        let top = take_off_climb_mps() * period_s + 1e-6;
        let climbs: Vec<f64> = heights
            .windows(2)
            .map(|pair| f64::from(pair[1] - pair[0]))
            .collect();
        assert!(
            climbs.iter().all(|&c| (0.0..=top).contains(&c)),
            "{climbs:?}"
        );
        assert!(
            climbs.iter().any(|&c| c > top - 1e-4),
            "the climb rate reached"
        );
        // (Half again for the last step onto the hover height, and the fixes' f32 rounding.)
        let kick = 1.5 * TAKE_OFF_ACCEL_MPS2 * period_s * period_s + 1e-5;
        for pair in climbs.windows(2) {
            assert!((pair[1] - pair[0]).abs() <= kick, "{pair:?}: a jerk");
        }
        assert_eq!(*heights.last().unwrap(), 0.5, "holding at the hover height");
        let heartbeats = messages
            .iter()
            .filter(|m| matches!(m, HostToBoard::Heartbeat(h) if h.node == Node::Host))
            .count();
        assert_eq!(heartbeats, 2, "one a second, the first at boot");
        assert!(
            messages
                .iter()
                .any(|m| *m == HostToBoard::Command(PilotCommand::Arm))
        );
        // The test's world takes the height over: no more climb.
        ground.set_height(0.2);
        ground.step(1_600 * MS + 7, &line);
        assert_eq!(ground.height_m(), 0.2);
    }
}

/// The camera board as the autopilot hears it, without a camera: a valid estimate (hovering
/// still) per 25 fps frame and a heartbeat a second, so that no camera failsafe lands the drone;
/// after [`CameraStandIn::stop_camera`], no estimate and a `Status` with `camera_stopped` each
/// second, as the camera board reports a stopped camera (heartbeats go on).
#[derive(Debug, Clone)]
pub struct CameraStandIn {
    frames: Every,
    heartbeats: Every,
    statuses: Every,
    seq: u16,
    camera_stopped: bool,
}

impl Default for CameraStandIn {
    fn default() -> Self {
        Self::new()
    }
}

impl CameraStandIn {
    /// A camera board with a working camera, its first heartbeat and estimate at 0.
    #[must_use]
    pub const fn new() -> Self {
        Self {
            frames: Every::ns(40 * MS),
            heartbeats: Every::ns(1_000 * MS),
            statuses: Every::ns(1_000 * MS),
            seq: 0,
            camera_stopped: false,
        }
    }

    /// From the next stop on, the camera is reported stopped and no estimate is sent.
    pub fn stop_camera(&mut self) {
        self.camera_stopped = true;
        self.statuses = Every::ns(1_000 * MS);
    }

    /// Estimates sent so far (the sequence number of the last one).
    #[must_use]
    pub fn estimates_sent(&self) -> u16 {
        self.seq
    }

    /// Sends what is due at this stop (`now`, ns) on `link`, the autopilot's camera-link input.
    pub fn step(&mut self, now: u64, link: &Line) {
        use protocol::{
            CaptureCounts, Estimate, EstimateFlags, FrameFit, LinkErrorCounts, Message,
            StereoStatus, StereoToAutopilot,
        };
        let mut buffer = [0u8; StereoToAutopilot::MAX_FRAME_BYTES];
        let mut send = |message: &StereoToAutopilot| {
            if let Ok(n) = protocol::encode(message, &mut buffer) {
                link.send_at(now, &buffer[..n]);
            }
        };
        if self.heartbeats.due(now) {
            send(&StereoToAutopilot::Heartbeat(Heartbeat::new(
                Node::StereoBoard,
                (now / MS) as u32,
            )));
        }
        if self.camera_stopped {
            if self.statuses.due(now) {
                send(&StereoToAutopilot::Status(StereoStatus {
                    uptime_ms: (now / MS) as u32,
                    frame_rate_hz: 0.0,
                    frames_processed: u32::from(self.seq),
                    frames_dropped: 0,
                    link_errors: LinkErrorCounts::default(),
                    max_processing_us: 5_000,
                    capture: CaptureCounts::default(),
                    camera_stopped: true,
                }));
            }
            return;
        }
        if self.frames.due(now) {
            self.seq = self.seq.wrapping_add(1);
            let still = FrameFit {
                forward_mps: 0.0,
                sideways_mps: 0.0,
                quality: 200,
            };
            send(&StereoToAutopilot::Estimate(Estimate {
                seq: self.seq,
                capture_us: protocol::WireTime((now / 1_000) as u32),
                forward_mps: 0.0,
                sideways_mps: 0.0,
                obstacle_m: None,
                quality: 200,
                flags: EstimateFlags::NONE,
                processing_us: 5_000,
                depth_coverage: 255,
                near_columns: 0,
                fit: Some(still),
                up_mps: 0.0,
                up_flags: EstimateFlags::NO_FLOW_MATCH,
                fit_r2: 0,
                divergence: None,
            }));
        }
    }
}
