//! The records of a flight log, one type per channel. Each is serialised as JSON and described
//! by a JSON Schema generated from the type (its doc comments become the field descriptions),
//! which is what PlotJuggler, Foxglove and Lichtblick read without plug-ins.

use protocol::{
    BatteryState, BatteryTelemetry, Estimate, EstimateFlags, FlightMode, FsmState, Heartbeat,
    LinkErrorCounts, Node, StereoStatus, Telemetry, PROTOCOL_VERSION,
};
use schemars::JsonSchema;
use serde::Serialize;

/// A record type and the one channel it is written to.
pub trait Record: Serialize + JsonSchema {
    /// Topic of the channel.
    const TOPIC: &'static str;
    /// Schema name shown by the viewers.
    const SCHEMA: &'static str;
}

/// Names of the [`EstimateFlags`] bits, bit 0 first.
pub const FLAG_NAMES: [&str; 8] = [
    "too_dark",
    "too_bright",
    "no_texture",
    "no_stereo_match",
    "no_flow_match",
    "history_filling",
    "poor_fit",
    "no_gyro",
];

/// The names of the bits set in `flags`.
pub fn flag_names(flags: EstimateFlags) -> Vec<&'static str> {
    FLAG_NAMES
        .iter()
        .enumerate()
        .filter(|(bit, _)| flags.0 >> bit & 1 == 1)
        .map(|(_, n)| *n)
        .collect()
}

/// An Edge-FS estimate as the autopilot received it.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct EstimateRecord {
    /// Frame sequence number (wrapping).
    pub seq: u16,
    /// Exposure time of the frame on the camera board's clock, µs (wrapping).
    pub capture_us: u32,
    /// Forward velocity, m/s.
    pub forward_mps: f32,
    /// Sideways velocity (positive right), m/s.
    pub sideways_mps: f32,
    /// Nearest obstacle in view, m (null: nothing in range).
    pub obstacle_m: Option<f32>,
    /// Confidence, 0 (none) ..= 255 (best).
    pub quality: u8,
    /// True when no invalidity flag is set.
    pub valid: bool,
    /// The invalidity flags as a number (bit 0: too_dark ... bit 7: no_gyro).
    pub flags: u8,
    /// Names of the flags set.
    pub flag_names: Vec<&'static str>,
    /// Time from exposure to the estimate, µs.
    pub processing_us: u16,
    /// Fraction of the view's columns with a stereo depth, 0..=1.
    pub depth_coverage: f32,
    /// Textured columns nearer than the minimum stereo range.
    pub near_columns: u8,
    /// The frame's own fit before the camera board's temporal filter: forward velocity, m/s
    /// (null: no valid fit).
    pub fit_forward_mps: Option<f32>,
    /// The frame's own fit: sideways velocity (positive right), m/s.
    pub fit_sideways_mps: Option<f32>,
    /// The frame's own fit: confidence, 0 ..= 255.
    pub fit_quality: Option<u8>,
    /// Divergence of the flow (the view's expansion), 1/s (null: none).
    pub divergence_hz: Option<f32>,
    /// Time to contact from the divergence, s (null: none, or the view does not expand).
    pub time_to_contact_s: Option<f32>,
}

impl Record for EstimateRecord {
    const TOPIC: &'static str = "/estimate";
    const SCHEMA: &'static str = "pocket_drone.Estimate";
}

impl From<&Estimate> for EstimateRecord {
    fn from(e: &Estimate) -> Self {
        Self {
            seq: e.seq,
            capture_us: e.capture_us.as_micros(),
            forward_mps: e.forward_mps,
            sideways_mps: e.sideways_mps,
            obstacle_m: e.obstacle_m,
            quality: e.quality,
            valid: e.is_valid(),
            flags: e.flags.0,
            flag_names: flag_names(e.flags),
            processing_us: e.processing_us,
            depth_coverage: e.depth_fraction(),
            near_columns: e.near_columns,
            fit_forward_mps: e.fit.map(|f| f.forward_mps),
            fit_sideways_mps: e.fit.map(|f| f.sideways_mps),
            fit_quality: e.fit.map(|f| f.quality),
            divergence_hz: e.divergence.map(|d| d.rate_hz),
            time_to_contact_s: e.divergence.and_then(|d| d.time_to_contact_s()),
        }
    }
}

/// The autopilot's attitude estimate and the body rates.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct AttitudeRecord {
    /// Roll, rad.
    pub roll_rad: f32,
    /// Pitch, rad.
    pub pitch_rad: f32,
    /// Yaw, rad.
    pub yaw_rad: f32,
    /// Body roll rate (gyro x), rad/s (null: not known to the logger).
    pub roll_rate_radps: Option<f32>,
    /// Body pitch rate (gyro y), rad/s (null: not known).
    pub pitch_rate_radps: Option<f32>,
    /// Body yaw rate (gyro z), rad/s (null: not known).
    pub yaw_rate_radps: Option<f32>,
}

impl Record for AttitudeRecord {
    const TOPIC: &'static str = "/attitude";
    const SCHEMA: &'static str = "pocket_drone.Attitude";
}

/// The autopilot's setpoints (what guidance and the FSM ask for).
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct SetpointRecord {
    /// Forward velocity setpoint, m/s.
    pub forward_mps: f32,
    /// Sideways velocity setpoint, m/s.
    pub sideways_mps: f32,
    /// Roll setpoint, rad (null: not reported by the board).
    pub roll_rad: Option<f32>,
    /// Pitch setpoint, rad (null: not reported).
    pub pitch_rad: Option<f32>,
    /// Yaw (heading) setpoint, rad (null: not reported).
    pub yaw_rad: Option<f32>,
    /// Height setpoint, m (null: not reported).
    pub height_m: Option<f32>,
    /// Level-flight collective thrust, 0..=1 (null: not reported).
    pub thrust: Option<f32>,
}

impl Record for SetpointRecord {
    const TOPIC: &'static str = "/setpoint";
    const SCHEMA: &'static str = "pocket_drone.Setpoint";
}

/// Motor duties as commanded (0..=1).
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct MotorsRecord {
    /// Motor 1, front right.
    pub front_right: f32,
    /// Motor 2, rear right.
    pub rear_right: f32,
    /// Motor 3, rear left.
    pub rear_left: f32,
    /// Motor 4, front left.
    pub front_left: f32,
}

impl Record for MotorsRecord {
    const TOPIC: &'static str = "/motors";
    const SCHEMA: &'static str = "pocket_drone.Motors";
}

impl From<[f32; 4]> for MotorsRecord {
    fn from(m: [f32; 4]) -> Self {
        Self {
            front_right: m[0],
            rear_right: m[1],
            rear_left: m[2],
            front_left: m[3],
        }
    }
}

/// Avoidance state machine state and flight mode, by name and by number.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct StateRecord {
    /// FSM state: check, forward, hover, turn, or inactive (before take-off, in failsafes).
    pub fsm_state: &'static str,
    /// FSM state number (0 check, 1 forward, 2 hover, 3 turn; -1 inactive).
    pub fsm_state_id: i16,
    /// Flight mode: disarmed, flying, hover-no-estimate, landing, killed, imu-fault.
    pub mode: &'static str,
    /// Flight mode number (0 disarmed, 1 flying, 2 hover-no-estimate, 3 landing, 4 killed,
    /// 5 imu-fault).
    pub mode_id: u8,
}

impl Record for StateRecord {
    const TOPIC: &'static str = "/state";
    const SCHEMA: &'static str = "pocket_drone.State";
}

impl StateRecord {
    /// The record of an FSM state (`None`: not running) and a flight mode.
    pub fn new(fsm_state: Option<FsmState>, mode: FlightMode) -> Self {
        Self {
            fsm_state: fsm_state.map_or("inactive", FsmState::name),
            fsm_state_id: fsm_state.map_or(-1, |s| {
                FsmState::ALL.iter().position(|a| *a == s).unwrap_or(0) as i16
            }),
            mode: mode.name(),
            mode_id: FlightMode::ALL.iter().position(|m| *m == mode).unwrap_or(0) as u8,
        }
    }
}

/// Velocity, body heading frame.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct VelocityRecord {
    /// Autopilot's forward velocity estimate (what guidance flies on), m/s (null: none yet).
    pub forward_mps: Option<f32>,
    /// Autopilot's sideways velocity estimate, m/s (null: none yet).
    pub sideways_mps: Option<f32>,
    /// True forward velocity (simulator), m/s (null: not known).
    pub true_forward_mps: Option<f32>,
    /// True sideways velocity (simulator), m/s (null: not known).
    pub true_sideways_mps: Option<f32>,
}

impl Record for VelocityRecord {
    const TOPIC: &'static str = "/velocity";
    const SCHEMA: &'static str = "pocket_drone.Velocity";
}

/// A barometer reading as the autopilot received it (MS5611, compensated).
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct BaroRecord {
    /// Pressure, Pa.
    pub pressure_pa: f32,
    /// Temperature, deg C.
    pub temperature_c: f32,
}

impl Record for BaroRecord {
    const TOPIC: &'static str = "/baro";
    const SCHEMA: &'static str = "pocket_drone.Baro";
}

/// The flight battery: the voltage the autopilot read and its verdict.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct BatteryRecord {
    /// Supply voltage read (under load), V.
    pub voltage_v: f32,
    /// The autopilot's filtered voltage with the sag under thrust added back, V.
    pub resting_v: f32,
    /// The autopilot's verdict: `ok`, `low` (lands) or `critical` (lands at once).
    pub state: &'static str,
    /// The verdict as a number (0 ok, 1 low, 2 critical), for plotting.
    pub state_id: u8,
    /// True open-circuit voltage (simulator), V (null: not known).
    pub true_resting_v: Option<f32>,
    /// True current drawn (simulator), A (null: not known).
    pub true_current_a: Option<f32>,
    /// True state of charge (simulator), 0..1 (null: not known).
    pub true_charge: Option<f32>,
}

impl BatteryRecord {
    /// The record of a telemetry battery report, without the simulator's truth.
    pub fn new(b: &BatteryTelemetry) -> Self {
        Self {
            voltage_v: b.voltage_v,
            resting_v: b.resting_v,
            state: b.state.name(),
            state_id: BatteryState::ALL
                .iter()
                .position(|s| *s == b.state)
                .unwrap_or(0) as u8,
            true_resting_v: None,
            true_current_a: None,
            true_charge: None,
        }
    }
}

impl Record for BatteryRecord {
    const TOPIC: &'static str = "/battery";
    const SCHEMA: &'static str = "pocket_drone.Battery";
}

/// The host link's authentication: whether a key is set and the refused commands.
#[derive(Debug, Clone, Copy, Serialize, JsonSchema)]
pub struct LinkAuthRecord {
    /// A link key is set (false: an unsigned link, anyone on it can command the drone).
    pub keyed: bool,
    /// Signed messages accepted since boot.
    pub accepted: u32,
    /// Commands refused unsigned since boot.
    pub unsigned: u32,
    /// Signed messages refused for a wrong signature since boot.
    pub bad_signature: u32,
    /// Signed messages refused as replays (or too far in the future) since boot.
    pub replayed: u32,
}

impl LinkAuthRecord {
    /// The record of a telemetry report.
    pub fn new(a: &protocol::LinkAuthTelemetry) -> Self {
        Self {
            keyed: a.keyed,
            accepted: a.accepted,
            unsigned: a.unsigned,
            bad_signature: a.bad_signature,
            replayed: a.replayed,
        }
    }
}

impl Record for LinkAuthRecord {
    const TOPIC: &'static str = "/link_auth";
    const SCHEMA: &'static str = "pocket_drone.LinkAuth";
}

/// Height above the floor.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct HeightRecord {
    /// Autopilot's height estimate, m.
    pub height_m: f32,
    /// Height setpoint, m (null: not reported).
    pub setpoint_m: Option<f32>,
    /// True height (simulator), m (null: not known).
    pub true_m: Option<f32>,
}

impl Record for HeightRecord {
    const TOPIC: &'static str = "/height";
    const SCHEMA: &'static str = "pocket_drone.Height";
}

/// Decoding errors of one link, by kind.
#[derive(Debug, Clone, Copy, Default, Serialize, JsonSchema)]
pub struct LinkErrorsRecord {
    /// CRC mismatches.
    pub crc: u32,
    /// Bad COBS encoding.
    pub cobs: u32,
    /// Frames longer than the largest message.
    pub too_long: u32,
    /// Frames shorter than a header and CRC.
    pub too_short: u32,
    /// Unknown message kinds.
    pub unknown_message: u32,
    /// Payloads that do not decode.
    pub malformed: u32,
    /// Frames of another protocol version.
    pub version_mismatch: u32,
    /// All of them.
    pub total: u32,
}

impl From<LinkErrorCounts> for LinkErrorsRecord {
    fn from(e: LinkErrorCounts) -> Self {
        Self {
            crc: e.crc,
            cobs: e.cobs,
            too_long: e.too_long,
            too_short: e.too_short,
            unknown_message: e.unknown_message,
            malformed: e.malformed,
            version_mismatch: e.version_mismatch,
            total: e.total(),
        }
    }
}

/// Link health and status counters.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct LinkRecord {
    /// Errors the autopilot saw decoding the camera board's bytes, since boot.
    pub camera_link_errors: LinkErrorsRecord,
    /// Errors this host saw decoding the boards' bytes (null: no host link).
    pub host_link_errors: Option<LinkErrorsRecord>,
    /// Estimates received (simulator: by the autopilot; HIL and monitor: by this host).
    pub estimates_received: u64,
    /// Of those, valid ones.
    pub estimates_valid: u64,
    /// Frames the camera board dropped (null: not known).
    pub frames_dropped: Option<u32>,
    /// Bytes lost on the camera -> autopilot UART (simulator), or null.
    pub camera_to_autopilot_bytes_lost: Option<u64>,
    /// Bytes corrupted on the camera -> autopilot UART (simulator), or null.
    pub camera_to_autopilot_bytes_corrupted: Option<u64>,
    /// Bytes lost on the autopilot -> camera UART (simulator), or null.
    pub autopilot_to_camera_bytes_lost: Option<u64>,
    /// Replies or estimates that did not come in time (HIL), or null.
    pub timeouts: Option<u64>,
}

impl Record for LinkRecord {
    const TOPIC: &'static str = "/link";
    const SCHEMA: &'static str = "pocket_drone.Link";
}

/// The camera board's status report, as the autopilot last received it.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct StereoStatusRecord {
    /// Camera board uptime, ms.
    pub uptime_ms: u32,
    /// Measured frame rate, Hz.
    pub frame_rate_hz: f32,
    /// Frames processed since boot.
    pub frames_processed: u32,
    /// Frames dropped since boot.
    pub frames_dropped: u32,
    /// Errors the camera board saw decoding the autopilot's bytes.
    pub link_errors: LinkErrorsRecord,
    /// Longest Edge-FS processing time, µs.
    pub max_processing_us: u32,
}

impl Record for StereoStatusRecord {
    const TOPIC: &'static str = "/stereo_status";
    const SCHEMA: &'static str = "pocket_drone.StereoStatus";
}

impl From<&StereoStatus> for StereoStatusRecord {
    fn from(s: &StereoStatus) -> Self {
        Self {
            uptime_ms: s.uptime_ms,
            frame_rate_hz: s.frame_rate_hz,
            frames_processed: s.frames_processed,
            frames_dropped: s.frames_dropped,
            link_errors: s.link_errors.into(),
            max_processing_us: s.max_processing_us,
        }
    }
}

/// The simulated drone as it really is (simulator and HIL only).
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct TruthRecord {
    /// Position north, m.
    pub x_m: f32,
    /// Position east, m.
    pub y_m: f32,
    /// Height above the floor, m.
    pub height_m: f32,
    /// Yaw, rad (null: not logged).
    pub yaw_rad: Option<f32>,
    /// Clearance from the rotor tips to the nearest wall or obstacle, m (null: not logged).
    pub clearance_m: Option<f32>,
    /// Contacts with walls and obstacles so far.
    pub collisions: u32,
}

impl Record for TruthRecord {
    const TOPIC: &'static str = "/truth";
    const SCHEMA: &'static str = "pocket_drone.Truth";
}

/// A board's liveness report.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct HeartbeatRecord {
    /// Sender: stereo_board, autopilot or host.
    pub node: &'static str,
    /// The sender's protocol version.
    pub protocol_version: u8,
    /// True when it is this host's protocol version.
    pub version_matches: bool,
    /// Sender uptime, ms.
    pub uptime_ms: u32,
}

impl Record for HeartbeatRecord {
    const TOPIC: &'static str = "/heartbeat";
    const SCHEMA: &'static str = "pocket_drone.Heartbeat";
}

impl From<&Heartbeat> for HeartbeatRecord {
    fn from(h: &Heartbeat) -> Self {
        Self {
            node: match h.node {
                Node::StereoBoard => "stereo_board",
                Node::Autopilot => "autopilot",
                Node::Host => "host",
            },
            protocol_version: h.protocol_version,
            version_matches: h.protocol_version == PROTOCOL_VERSION,
            uptime_ms: h.uptime_ms,
        }
    }
}

/// A board's own clock at the message logged at the same time (the log's times are the
/// host's).
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct BoardClockRecord {
    /// The message whose timestamp this is: telemetry, motors or estimate.
    pub message: &'static str,
    /// The board's timestamp, µs (wrapping `u32`).
    pub board_time_us: u32,
}

impl Record for BoardClockRecord {
    const TOPIC: &'static str = "/board_clock";
    const SCHEMA: &'static str = "pocket_drone.BoardClock";
}

impl BoardClockRecord {
    /// The timestamp of a telemetry message.
    pub fn telemetry(t: &Telemetry) -> Self {
        Self {
            message: "telemetry",
            board_time_us: t.timestamp_us.as_micros(),
        }
    }
}
