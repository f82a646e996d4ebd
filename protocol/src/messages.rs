//! Every message that crosses a wire, one enum per direction.
//!
//! Units are SI at every boundary (m, m/s, rad, rad/s, m/s², s) in `f32`; timestamps are
//! [`WireTime`]s: microseconds of the sender's monotonic clock, wrapping at 2^32 (after 71.6
//! minutes, longer than any flight of a 40 g drone; on the wire a plain `u32`). Compare them
//! with [`WireTime::wrapping_since`], never with `<`, and bring them back onto a 64-bit
//! timeline with [`timebase::WrapExtender`].
//!
//! Links and directions:
//!
//! | link | direction | enum |
//! |---|---|---|
//! | board-to-board UART | camera board -> autopilot | [`StereoToAutopilot`] |
//! | board-to-board UART | autopilot -> camera board | [`AutopilotToStereo`] |
//! | HIL serial / ground tool | host -> either board | [`HostToBoard`] |
//! | HIL serial / ground tool | either board -> host | [`BoardToHost`] |
//!
//! Adding a variant at the end of an enum is backwards compatible for the decoder's "unknown
//! message" check; changing or reordering fields is not: bump [`PROTOCOL_VERSION`].

pub use crate::node::Node;
use serde::{Deserialize, Serialize};
pub use timebase::WireTime;

/// Version of this wire format. Sent in every frame header and in [`Heartbeat`]; a frame with
/// another version is rejected and counted (see [`LinkErrorCounts::version_mismatch`]).
pub const PROTOCOL_VERSION: u8 = 12;

/// Bytes of one 128x96 stereo frame as the camera delivers it: left and right pixels
/// interleaved, `[L0 R0 L1 R1 ...]`, row-major, top row first.
pub const STEREO_FRAME_BYTES: usize = 128 * 96 * 2;

/// Payload bytes in one [`FrameChunk`] (a full frame is 48 chunks).
pub const FRAME_CHUNK_BYTES: usize = 512;

/// A message type that travels in frames: one enum per direction.
pub trait Message: Serialize + for<'de> Deserialize<'de> {
    /// Number of variants of the enum. A frame whose tag is at least this is an unknown
    /// message (newer peer, or corruption that survived the CRC).
    const VARIANT_COUNT: u32;
    /// Largest encoded frame of this type on the wire (COBS, CRC and delimiter included).
    /// Receive buffers are sized from it.
    const MAX_FRAME_BYTES: usize;
}

/// Periodic liveness message (1 Hz). Lets each side detect a lost link and a peer built with
/// another protocol version.
///
/// Every host that talks to the autopilot (a ground station, `sim-host monitor`, `param`,
/// `hil`) sends one with [`Node::Host`] at least once a second: the telemetry link is the
/// pocket drone's only kill path, so the autopilot refuses to arm without a recent host
/// heartbeat and, armed, lands (or holds or kills, per its `fs_host_action` parameter) when
/// none has come for `fs_host_timeout_us` ([`FailsafeReason::TelemetryLost`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Heartbeat {
    /// Sender.
    pub node: Node,
    /// The sender's [`PROTOCOL_VERSION`].
    pub protocol_version: u8,
    /// Sender uptime, milliseconds.
    pub uptime_ms: u32,
}

impl Heartbeat {
    /// A heartbeat of this build's protocol version.
    pub fn new(node: Node, uptime_ms: u32) -> Self {
        Self {
            node,
            protocol_version: PROTOCOL_VERSION,
            uptime_ms,
        }
    }
}

/// Why an [`Estimate`] must not be used for control. A bit set means "invalid because ...";
/// an estimate is valid when no bit is set.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EstimateFlags(pub u8);

impl EstimateFlags {
    /// The image is too dark (or the camera is covered).
    pub const TOO_DARK: Self = Self(1 << 0);
    /// The image is saturated (too bright).
    pub const TOO_BRIGHT: Self = Self(1 << 1);
    /// Too few edges: a blank wall or a featureless scene.
    pub const NO_TEXTURE: Self = Self(1 << 2);
    /// Too few columns with a confident stereo match: no depth, so no metric velocity.
    pub const NO_STEREO_MATCH: Self = Self(1 << 3);
    /// Too few columns with a confident flow match to fit the flow field.
    pub const NO_FLOW_MATCH: Self = Self(1 << 4);
    /// The flow history is still filling (first frames after start or reset).
    pub const HISTORY_FILLING: Self = Self(1 << 5);
    /// The line fit is poor (residual too large for the estimate to be trusted).
    pub const POOR_FIT: Self = Self(1 << 6);
    /// No recent gyro sample from the autopilot: rotation could not be removed.
    pub const NO_GYRO: Self = Self(1 << 7);
    /// No reason: a valid estimate.
    pub const NONE: Self = Self(0);

    /// True when no invalidity bit is set.
    #[inline]
    pub fn is_valid(self) -> bool {
        self.0 == 0
    }
    /// True when every bit of `other` is set in `self`.
    #[inline]
    pub fn contains(self, other: Self) -> bool {
        self.0 & other.0 == other.0
    }
    /// Sets the bits of `other`.
    #[inline]
    pub fn insert(&mut self, other: Self) {
        self.0 |= other.0;
    }
}

impl core::ops::BitOr for EstimateFlags {
    type Output = Self;
    fn bitor(self, rhs: Self) -> Self {
        Self(self.0 | rhs.0)
    }
}

/// Edge-FS result for one processed stereo frame (camera board -> autopilot, at the frame rate).
///
/// Body axes of the camera: forward along the optical axis, sideways positive to the right.
/// Worst case 59 bytes on the wire (tested).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Estimate {
    /// Frame sequence number, wrapping; a gap means frames were dropped.
    pub seq: u16,
    /// Exposure time of the frame, µs (camera board clock).
    pub capture_us: WireTime,
    /// Forward velocity, m/s (positive: moving towards the scene).
    pub forward_mps: f32,
    /// Sideways velocity, m/s (positive: moving to the right).
    pub sideways_mps: f32,
    /// Distance to the nearest obstacle in view, m; `None` when nothing is within range.
    pub obstacle_m: Option<f32>,
    /// Confidence of the velocity estimate, 0 (none) ..= 255 (best); see the Edge-FS docs for
    /// how it is computed.
    pub quality: u8,
    /// Why the estimate is invalid (empty: valid).
    pub flags: EstimateFlags,
    /// Time from frame capture to this estimate, µs (saturates at 65,535).
    pub processing_us: u16,
    /// How much of the view has a stereo depth: the fraction of the searchable columns with a
    /// confident disparity, 0 (none) ..= 255 (all). `obstacle_m == None` over a view with
    /// little depth means "unknown", not "clear".
    pub depth_coverage: u8,
    /// Textured columns whose disparity search ran out of range: something is nearer than the
    /// minimum stereo range there (0..=128).
    pub near_columns: u8,
    /// The frame's own velocity fit, before the camera board's temporal filter, when that fit
    /// is valid (`None`: no valid fit, or the paper's estimator, which has no filter). For a
    /// receiver that filters on its own (the autopilot's velocity Kalman filter): the board's
    /// filter smooths over several frames and, once its track is wrong, flags the right fits
    /// as outliers, so the filtered velocity lags and can stay wrong; the fit of one frame is
    /// noisier but describes exactly its flow window.
    pub fit: Option<FrameFit>,
    /// Vertical velocity, m/s (positive: climbing), from the vertical flow of the image rows
    /// (0 when not estimated). Valid on its own terms: see [`Estimate::up_flags`].
    pub up_mps: f32,
    /// Why [`Estimate::up_mps`] must not be used (empty: valid); the forward and sideways
    /// velocity's validity is [`Estimate::flags`].
    pub up_flags: EstimateFlags,
    /// Coefficient of determination R² of the frame's coupled three-axis flow fit, 0 (the
    /// flow model explains nothing, e.g. no motion) ..= 255 (all of the flow).
    pub fit_r2: u8,
    /// The expansion of the view, from which the time to contact follows
    /// ([`Divergence::time_to_contact_s`]); it needs no stereo range, only flow (`None`: too
    /// few flow columns, too narrow a patch of them, or the paper's estimator).
    pub divergence: Option<Divergence>,
}

/// The divergence of the horizontal image flow: how fast the view expands, and the time to
/// contact that follows from it without any range measurement.
///
/// For a surface facing the camera at distance `Z` approached at speed `F`, the flow at column
/// `x` (px from the image centre) is `x·F/Z` plus a uniform part from sideways motion and
/// rotation, so the slope of flow against column is `F/Z`, and `Z/F` is the time to contact.
/// Over a scene of several depths it is a flow-weighted average; a sideways motion past a
/// surface that is not facing the camera adds to it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Divergence {
    /// Slope of the derotated horizontal flow against the column, 1/s (positive: the view
    /// expands, the camera closes on the scene ahead).
    pub rate_hz: f32,
    /// Standard error of [`Self::rate_hz`], 1/s.
    pub sigma_hz: f32,
}

impl Divergence {
    /// Time to contact at the current closing speed, s: `1 / rate_hz`; `None` when the view
    /// does not expand (not approaching) or the rate is not finite.
    pub fn time_to_contact_s(&self) -> Option<f32> {
        (self.rate_hz.is_finite() && self.rate_hz > 0.0).then(|| 1.0 / self.rate_hz)
    }

    /// The time to contact at `k` standard errors towards contact, s: `1 / (rate + k·sigma)`,
    /// the short end of the time's uncertainty; `None` when even that rate is not an approach.
    pub fn time_to_contact_within_s(&self, k: f32) -> Option<f32> {
        let rate = self.rate_hz + k * self.sigma_hz;
        (rate.is_finite() && rate > 0.0).then(|| 1.0 / rate)
    }

    /// Standard error of [`Self::time_to_contact_s`], s (first order: `sigma / rate²`);
    /// `None` when there is no time to contact.
    pub fn time_to_contact_sigma_s(&self) -> Option<f32> {
        self.time_to_contact_s()
            .map(|t| self.sigma_hz * t * t)
            .filter(|s| s.is_finite())
    }
}

/// One frame's Edge-FS velocity fit, before any filtering across frames (see
/// [`Estimate::fit`]). Same axes as [`Estimate`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FrameFit {
    /// Forward velocity, m/s (positive: moving towards the scene).
    pub forward_mps: f32,
    /// Sideways velocity, m/s (positive: moving to the right).
    pub sideways_mps: f32,
    /// Confidence of this fit, 0 (none) ..= 255 (best), as [`Estimate::quality`].
    pub quality: u8,
}

impl Estimate {
    /// True when the estimate may be used for control.
    pub fn is_valid(&self) -> bool {
        self.flags.is_valid()
    }

    /// [`Estimate::depth_coverage`] as a fraction, 0..=1.
    pub fn depth_fraction(&self) -> f32 {
        f32::from(self.depth_coverage) / 255.0
    }
}

/// Counters of link errors seen by a decoder, by kind (see [`crate::Decoder`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkErrorCounts {
    /// Frames whose CRC did not match.
    pub crc: u32,
    /// Frames that were not valid COBS.
    pub cobs: u32,
    /// Frames longer than the receive buffer.
    pub too_long: u32,
    /// Frames too short to hold a header and CRC, including empty frames.
    pub too_short: u32,
    /// Frames with an unknown message tag.
    pub unknown_message: u32,
    /// Frames whose payload did not decode as the message type.
    pub malformed: u32,
    /// Frames from a peer speaking another protocol version.
    pub version_mismatch: u32,
}

/// Counters of the camera capture path (DCMI + DMA) since boot, as the camera board counts them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CaptureCounts {
    /// Frames that arrived whole: the DMA had moved exactly one frame's bytes at the frame end.
    pub frames_complete: u32,
    /// Frames rejected at the frame end because the DMA had moved another byte count (a short
    /// frame, or a stream misaligned by lost data); never processed.
    pub frames_torn: u32,
    /// DCMI overruns (the DMA did not empty the DCMI FIFO in time; the frame is rejected).
    pub dcmi_overruns: u32,
    /// DCMI synchronisation errors (embedded sync codes out of order; the frame is rejected).
    pub dcmi_sync_errors: u32,
    /// DMA transfer, FIFO or direct-mode errors on the camera stream (the frame is rejected).
    pub dma_errors: u32,
    /// Times capture was stopped and restarted to regain frame alignment.
    pub rearms: u32,
    /// Frames whose buffer the DMA began to refill before their processing ended (estimate
    /// discarded, flow history cleared).
    pub frames_overwritten: u32,
}

/// Camera-board health, sent once per second.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StereoStatus {
    /// Uptime, ms.
    pub uptime_ms: u32,
    /// Processed frames per second over the last interval, Hz.
    pub frame_rate_hz: f32,
    /// Frames processed since boot.
    pub frames_processed: u32,
    /// Frames dropped since boot (camera overrun or processing too slow).
    pub frames_dropped: u32,
    /// Errors decoding messages from the autopilot since boot.
    pub link_errors: LinkErrorCounts,
    /// Worst processing time per frame over the last interval, µs.
    pub max_processing_us: u32,
    /// The capture path's counters.
    pub capture: CaptureCounts,
    /// The camera has sent no frame (VSYNC) for several frame periods: no estimates will come,
    /// the autopilot must fly as blind.
    pub camera_stopped: bool,
}

/// Messages from the camera board to the autopilot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StereoToAutopilot {
    /// Liveness and version.
    Heartbeat(Heartbeat),
    /// Edge-FS result of one frame.
    Estimate(Estimate),
    /// Periodic health report.
    Status(StereoStatus),
    /// The answer to a [`AutopilotToStereo::Param`] request (the autopilot passes it on to
    /// the host as [`BoardToHost::Param`]).
    Param(crate::ParamResponse),
}

impl Message for StereoToAutopilot {
    const VARIANT_COUNT: u32 = 4;
    const MAX_FRAME_BYTES: usize = 128;
}

/// Gyro and attitude sample for derotation (autopilot -> camera board, at 100 Hz or more).
///
/// Body frame: x forward, y right, z down (the camera looks along x).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GyroAttitude {
    /// Sample time, µs (autopilot clock).
    pub timestamp_us: WireTime,
    /// Body rates p, q, r (roll, pitch, yaw rate), rad/s.
    pub rates_radps: [f32; 3],
    /// Attitude roll, pitch, yaw (ZYX Euler angles), rad.
    pub attitude_rad: [f32; 3],
}

/// Edge-FS parameters that can be changed at run time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EdgeFsConfig {
    /// SAD half-window W, px (the window is 2W+1 columns wide). 1..=12.
    pub half_window: u8,
    /// Search range D, px: flow is searched over -D..=D, disparity over 0..=D. 1..=20.
    pub search_range: u8,
    /// Longest time horizon of the flow history, frames. 1..=9.
    pub max_horizon: u8,
    /// Horizontal stereo misalignment of the camera pair, px (calibration): at infinity a
    /// feature sits this much further left in the left image. -20..=20.
    pub stereo_shift: i8,
}

/// Why an [`EdgeFsConfig`] was rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ConfigError {
    /// `half_window` outside 1..=12.
    HalfWindow,
    /// `search_range` outside 1..=20.
    SearchRange,
    /// `max_horizon` outside 1..=9.
    MaxHorizon,
    /// `stereo_shift` outside -20..=20.
    StereoShift,
}

impl EdgeFsConfig {
    /// Largest accepted half-window, px.
    pub const MAX_HALF_WINDOW: u8 = 12;
    /// Largest accepted search range, px.
    pub const MAX_SEARCH_RANGE: u8 = 20;
    /// Largest accepted flow horizon, frames.
    pub const MAX_HORIZON: u8 = 9;
    /// Largest accepted stereo shift magnitude, px.
    pub const MAX_STEREO_SHIFT: i8 = 20;

    /// Checks every field's range. Within these ranges at least 64 of the 128 columns remain
    /// measurable (128 - 2W - D - |shift| >= 64), so no combination needs a separate check.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if !(1..=Self::MAX_HALF_WINDOW).contains(&self.half_window) {
            return Err(ConfigError::HalfWindow);
        }
        if !(1..=Self::MAX_SEARCH_RANGE).contains(&self.search_range) {
            return Err(ConfigError::SearchRange);
        }
        if !(1..=Self::MAX_HORIZON).contains(&self.max_horizon) {
            return Err(ConfigError::MaxHorizon);
        }
        if !(-Self::MAX_STEREO_SHIFT..=Self::MAX_STEREO_SHIFT).contains(&self.stereo_shift) {
            return Err(ConfigError::StereoShift);
        }
        Ok(())
    }
}

/// Messages from the autopilot to the camera board.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AutopilotToStereo {
    /// Liveness and version.
    Heartbeat(Heartbeat),
    /// Latest gyro and attitude, for derotation.
    GyroAttitude(GyroAttitude),
    /// A host's request for the camera board's parameter table, passed on by the autopilot
    /// (answered with [`StereoToAutopilot::Param`]).
    Param(crate::ParamRequest),
}

impl Message for AutopilotToStereo {
    const VARIANT_COUNT: u32 = 3;
    const MAX_FRAME_BYTES: usize = 64;
}

/// One piece of a stereo frame streamed to the camera board in HIL (host -> camera board).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FrameChunk {
    /// Frame number, wrapping; all chunks of one frame carry the same number.
    pub frame_id: u16,
    /// Exposure time of the frame, µs (host simulation clock).
    pub capture_us: WireTime,
    /// Byte offset of `data` inside the [`STEREO_FRAME_BYTES`]-byte interleaved frame.
    pub offset: u16,
    /// Interleaved pixel bytes, at most [`FRAME_CHUNK_BYTES`].
    pub data: heapless::Vec<u8, FRAME_CHUNK_BYTES>,
}

/// One IMU sample (host -> autopilot in HIL; also logged by the autopilot).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ImuSample {
    /// Sample time, µs.
    pub timestamp_us: WireTime,
    /// Body rates p, q, r, rad/s (body frame x forward, y right, z down).
    pub gyro_radps: [f32; 3],
    /// Specific force, m/s² (body frame; about [0, 0, -9.81] at rest, level).
    pub accel_mps2: [f32; 3],
}

/// External position fix (host -> autopilot): motion capture in the paper's flights, the
/// simulator's truth plus noise here. The autopilot uses the height only.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ExternalPosition {
    /// Measurement time, µs.
    pub timestamp_us: WireTime,
    /// Position in the room frame (x north, y east, z down), m. Height above the floor is `-z`.
    pub position_m: [f32; 3],
}

/// Pilot command from a ground tool or the HIL host (the RC equivalent). A kill always wins.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PilotCommand {
    /// Arm the motors and start the autonomous flight.
    Arm,
    /// Land, then disarm.
    Land,
    /// Motors off immediately.
    Kill,
    /// Lockstep (`hil`) images only: drive the PWM outputs with the motor command (`true`) or
    /// hold them at 0 (`false`, the state at boot; the command still goes back to the host).
    /// Enabling is accepted only while the motors are off; other images ignore it.
    HilOutputs(bool),
}

/// Messages from a host (HIL bridge, simulator, ground tool) to a board.
// The frame chunk dominates the size; boxing is not an option without a heap, and a receiver
// holds one decoded message at a time.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HostToBoard {
    /// Liveness and version.
    Heartbeat(Heartbeat),
    /// A piece of a stereo frame (camera board, HIL).
    FrameChunk(FrameChunk),
    /// An IMU sample (autopilot, HIL).
    Imu(ImuSample),
    /// An external position / height fix (autopilot).
    ExternalPosition(ExternalPosition),
    /// Arm, land, kill, or the `hil` image's PWM outputs on or off (autopilot).
    Command(PilotCommand),
    /// List, read, write or save a board's parameters (answered with
    /// [`BoardToHost::Param`]).
    Param(crate::ParamRequest),
    /// A message signed with the link key (see [`crate::signing`]).
    Signed(crate::envelope::SignedMessage),
    /// Provision the link key (autopilot): accepted unsigned only while disarmed and no key is
    /// set; a key already set is changed only by a signed `SetKey`, disarmed.
    SetKey(crate::envelope::LinkKey),
}

impl Message for HostToBoard {
    const VARIANT_COUNT: u32 = 8;
    const MAX_FRAME_BYTES: usize = 560;
}

/// Motor commands (autopilot -> host in HIL).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MotorCommand {
    /// Time of the control step that produced the command, µs.
    pub timestamp_us: WireTime,
    /// Throttle of motors 1..4 (front-right, rear-right, rear-left, front-left), each 0..=1.
    pub throttle: [f32; 4],
}

/// The autopilot's flight mode: what its failsafe allows the motors to do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FlightMode {
    /// On the ground, motors off.
    Disarmed,
    /// Armed and flying normally (take-off, avoidance).
    Flying,
    /// Valid velocity estimates lost: hovering level, waiting for them to come back.
    HoverNoEstimate,
    /// Descending to land (commanded or failsafe), then disarm.
    Landing,
    /// Killed by command: motors off until the next arm.
    Killed,
    /// IMU data stale or invalid: motors off until the next arm.
    ImuFault,
}

impl FlightMode {
    /// Every mode, in declaration order (plots and tables list them in this order).
    pub const ALL: [FlightMode; 6] = [
        FlightMode::Disarmed,
        FlightMode::Flying,
        FlightMode::HoverNoEstimate,
        FlightMode::Landing,
        FlightMode::Killed,
        FlightMode::ImuFault,
    ];

    /// True when the motors may run.
    pub fn motors_enabled(self) -> bool {
        matches!(
            self,
            FlightMode::Flying | FlightMode::HoverNoEstimate | FlightMode::Landing
        )
    }

    /// Short lower-case name for logs, tables and plots.
    pub fn name(self) -> &'static str {
        match self {
            FlightMode::Disarmed => "disarmed",
            FlightMode::Flying => "flying",
            FlightMode::HoverNoEstimate => "hover-no-estimate",
            FlightMode::Landing => "landing",
            FlightMode::Killed => "killed",
            FlightMode::ImuFault => "imu-fault",
        }
    }
}

/// Why the autopilot last left normal flight (a failsafe or a command), as telemetry reports
/// it: the reason stands from the mode change it caused until the next arming, so that after a
/// landing it still says why the drone came down.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FailsafeReason {
    /// A pilot command (`Land` or `Kill`, from the host or the RC).
    Command,
    /// No valid velocity estimate for the estimate timeout (hover, then land).
    EstimateLost,
    /// No height measurement for the height timeout (blind landing).
    HeightLost,
    /// No usable IMU sample for the IMU timeout (motors off).
    ImuLost,
    /// No heartbeat from the host (the telemetry link, the only kill path) for
    /// `fs_host_timeout_us`: the `fs_host_action` (land, hold or kill) was taken.
    TelemetryLost,
    /// The avoidance state machine found no way to go and asked to land.
    NoWayFound,
    /// A landing had not touched down after `land_timeout_us`: motors cut near the floor.
    LandTimeout,
    /// The barometer's raw readings stayed identical for `baro_stuck_us` (a frozen sensor):
    /// its heights are no longer used.
    BaroFrozen,
    /// The battery's resting voltage fell below `bat_low_v`: land.
    BatteryLow,
    /// The battery's resting voltage fell below `bat_critical_v`: land at once, descending fast.
    BatteryCritical,
}

impl FailsafeReason {
    /// Short lower-case name for logs, tables and plots.
    pub fn name(self) -> &'static str {
        match self {
            FailsafeReason::Command => "command",
            FailsafeReason::EstimateLost => "estimate-lost",
            FailsafeReason::HeightLost => "height-lost",
            FailsafeReason::ImuLost => "imu-lost",
            FailsafeReason::TelemetryLost => "telemetry-lost",
            FailsafeReason::NoWayFound => "no-way-found",
            FailsafeReason::LandTimeout => "land-timeout",
            FailsafeReason::BaroFrozen => "baro-frozen",
            FailsafeReason::BatteryLow => "battery-low",
            FailsafeReason::BatteryCritical => "battery-critical",
        }
    }
}

/// The autopilot's avoidance state machine state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FsmState {
    /// Evaluate whether the way ahead is clear.
    Check,
    /// Fly forward at constant speed.
    Forward,
    /// Hold zero velocity before turning.
    Hover,
    /// Turn (by a fixed angle, or until clear).
    Turn,
    /// Stop from forward flight (zero velocity requested) until the drone is still, then
    /// `Hover`. Declared last so that the other states keep their wire values.
    Brake,
}

impl FsmState {
    /// Every state, in declaration order (plots and tables list them in this order, and logs
    /// number them by it).
    pub const ALL: [FsmState; 5] = [
        FsmState::Check,
        FsmState::Forward,
        FsmState::Hover,
        FsmState::Turn,
        FsmState::Brake,
    ];

    /// Short lower-case name for logs, tables and plots.
    pub fn name(self) -> &'static str {
        match self {
            FsmState::Check => "check",
            FsmState::Forward => "forward",
            FsmState::Hover => "hover",
            FsmState::Turn => "turn",
            FsmState::Brake => "brake",
        }
    }
}

/// Autopilot telemetry for a ground tool (autopilot -> host, about 10 Hz).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Telemetry {
    /// Autopilot time, µs.
    pub timestamp_us: WireTime,
    /// Avoidance state machine state (`None`: the state machine is not running).
    pub fsm_state: Option<FsmState>,
    /// Flight mode.
    pub flight_mode: FlightMode,
    /// Attitude roll, pitch, yaw, rad.
    pub attitude_rad: [f32; 3],
    /// The velocity the guidance flies on (the autopilot's filtered estimate), forward and
    /// sideways, m/s; zero while it has none.
    pub velocity_mps: [f32; 2],
    /// Velocity setpoint, forward and sideways, m/s.
    pub velocity_setpoint_mps: [f32; 2],
    /// Nearest obstacle from the camera board, m (`None`: nothing in range).
    pub obstacle_m: Option<f32>,
    /// Height above the floor, m.
    pub height_m: f32,
    /// The last barometer reading (`None`: no barometer, or none read yet).
    pub baro: Option<BaroTelemetry>,
    /// Errors decoding messages from the camera board since boot.
    pub link_errors: LinkErrorCounts,
    /// Why the drone last left normal flight since it was armed (`None`: it has not).
    pub failsafe_reason: Option<FailsafeReason>,
    /// The battery (`None`: no supply voltage read yet).
    pub battery: Option<BatteryTelemetry>,
    /// The host link's authentication: whether a key is set and the refused commands.
    pub link_auth: LinkAuthTelemetry,
}

/// The host link's authentication as telemetry reports it (counts since boot, saturating).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkAuthTelemetry {
    /// A link key is set: commands must be signed. `false`: an unsigned link, anyone on it
    /// can command the drone.
    pub keyed: bool,
    /// Signed messages accepted.
    pub accepted: u32,
    /// Commands refused because they were not signed (or a `SetKey` not allowed now).
    pub unsigned: u32,
    /// Signed messages refused for a wrong MAC or a bad payload (forged, or another key).
    pub bad_signature: u32,
    /// Signed messages refused for an old (replayed) or too new timestamp.
    pub replayed: u32,
}

/// The flight battery as the autopilot judges it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BatteryState {
    /// Above the low threshold.
    Ok,
    /// Below the low threshold: the autopilot lands.
    Low,
    /// Below the critical threshold: the autopilot lands at once, descending fast.
    Critical,
}

impl BatteryState {
    /// Every state, in declaration order (logs number them by it).
    pub const ALL: [BatteryState; 3] =
        [BatteryState::Ok, BatteryState::Low, BatteryState::Critical];

    /// Short lower-case name for logs and tables.
    pub fn name(self) -> &'static str {
        match self {
            BatteryState::Ok => "ok",
            BatteryState::Low => "low",
            BatteryState::Critical => "critical",
        }
    }
}

/// The flight battery, as telemetry reports it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BatteryTelemetry {
    /// The last supply voltage read, V (under load: it sags while the motors draw current).
    pub voltage_v: f32,
    /// The filtered voltage with the sag under thrust added back (an estimate of the
    /// battery's resting voltage), V: what the thresholds compare.
    pub resting_v: f32,
    /// The autopilot's verdict (latched for the flight once `Low` or `Critical`).
    pub state: BatteryState,
}

/// A compensated barometer reading (the autopilot's MS5611), as telemetry reports it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BaroTelemetry {
    /// Pressure, Pa.
    pub pressure_pa: f32,
    /// Temperature, °C.
    pub temperature_c: f32,
}

/// Messages from a board to a host (HIL bridge, ground tool).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BoardToHost {
    /// Liveness and version.
    Heartbeat(Heartbeat),
    /// Motor commands (autopilot, HIL).
    Motors(MotorCommand),
    /// Autopilot telemetry.
    Telemetry(Telemetry),
    /// An Edge-FS estimate (camera board in HIL, mirrored to the host).
    Estimate(Estimate),
    /// The answer to a [`HostToBoard::Param`] request.
    Param(crate::ParamResponse),
}

impl Message for BoardToHost {
    const VARIANT_COUNT: u32 = 5;
    const MAX_FRAME_BYTES: usize = 160;
}
