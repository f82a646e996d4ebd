//! Hardware-in-the-loop: the world simulation of [`crate::sim`] flown by the two boards'
//! lockstep firmwares (the `hil` flavour; the `qemu` flavour in QEMU) over byte streams, one
//! per board's host UART.
//!
//! ```text
//!   sim-host hil                  camera board                         autopilot
//!   world: dynamics, IMU, scene  --FrameChunk--> host UART   host UART <--Imu, ExternalPosition, Command--
//!   camera renderer              <--Estimate----             (USART1)  --Motors, Telemetry, Heartbeat-->
//!                                                link UART <-------> link UART
//! ```
//!
//! The same contract, wherever the boards are:
//!
//! * real boards: each host UART on its own USB-serial adapter (`--stereo /dev/ttyUSB0
//!   --autopilot /dev/ttyUSB1`, 921,600 Bd), the link UARTs wired to each other as in the drone;
//! * the virtual boards (`virtual-board/`, `vboard serve hil`): both `hil` images on emulated
//!   STM32F4s, the link UARTs joined on the bench, each host UART on a TCP socket
//!   (`--stereo tcp:127.0.0.1:4011 --autopilot tcp:127.0.0.1:4012`); `docs/virtual-board.md`;
//! * QEMU (the `qemu` flavour): each host UART on a `-chardev socket`, the link UARTs joined
//!   directly or relayed through this host ([`Relay`]).
//!
//! The camera board's host UART is its second UART, USART2 (PA2/PA3; USART2 in QEMU too), its
//! link UART4 (USART1 in QEMU); the autopilot's host UART is its telemetry port USART1, its link
//! USART2.
//!
//! # Timing: lockstep on world time
//!
//! The boards run on the world's clock, not their own (see `autopilot::lockstep` and the
//! camera board firmware's clock module); only the time source and the sensor transport differ
//! from the real flavour, the flight code is the same.
//!
//! * IMU: every IMU period (512 Hz of world time) the host sends one `ImuSample` stamped with
//!   the world time and waits for the autopilot's `Motors` reply carrying the same timestamp;
//!   only then does it integrate the world one IMU period with those motor commands. The
//!   autopilot releases guidance (50 Hz), gyro-to-camera (128 Hz) and telemetry (10 Hz) from
//!   the same world clock. The world therefore runs exactly as fast as the link allows: slower
//!   than real time in QEMU and on the virtual boards, about real time on a fast serial link.
//! * Height: an `ExternalPosition` (truth + noise) at [`HilConfig::height_rate_hz`], sent just
//!   before the IMU sample of the same instant.
//! * Camera: a frame is rendered at world time `t` (its exposure time on the wire) every
//!   `1 / fps` of world time and streamed as `FrameChunk`s by a writer thread while the
//!   lockstep goes on. The camera board mirrors each `Estimate` to the host; the world is not
//!   allowed to pass the next exposure time before the estimate of the previous frame is back
//!   (it waits, holding the lockstep). So the boards always see frames at `fps` of world time
//!   with at most one frame period of latency, however slow the link.
//! * Arming: a `PilotCommand::Arm` at [`HilConfig::arm_at_s`]; a host `Heartbeat` every
//!   second of world time from the start (without it the autopilot refuses to arm, and lands).
//! * PWM outputs: the autopilot's `hil` image holds its motor outputs at 0 and flies on the
//!   commands it sends back (the simulated drone flies, nothing on the bench turns). Only with
//!   `--outputs` ([`HilConfig::outputs`]) does the host send `PilotCommand::HilOutputs(true)`
//!   at world time 0, before the arm: the outputs then follow the commands, and go to 0 within
//!   60 ms of board time once the host's samples stop (`docs/hardware.md`, "HIL outputs").
//! * Parameters (`--params FILE`, [`HilConfig::params`]): after both heartbeats and before the
//!   world starts, every value of the file is set with a parameter request on the autopilot's
//!   host link (a `[camera]` one passed on by the autopilot to the camera board) and read
//!   back; a refusal, silence or another value read back stops the run, naming the key.
//!
//! A reply that does not come within [`HilConfig::reply_timeout`] (a byte lost in the link)
//! is counted and the world goes on with the previous commands.
//!
//! # Link rates
//!
//! The `hil` flavour runs both host UARTs at 921,600 Bd (`board_support::link::HOST_BAUD`) and
//! takes their bytes by DMA. One frame (24,576 pixel bytes in 48 `FrameChunk`s, 25.2 kB
//! framed) takes 0.27 s of it, so the camera link carries 3.6 frames per second of real time:
//! at `--fps 4` (the default) the world runs at about 0.9x real time on the boards, at 25 fps
//! at 0.15x. The autopilot link needs about 70 B x 512 Hz = 36 kB/s of its 92 kB/s. Four frames
//! per second is also the lowest rate at which one invalid estimate (a gap of two frame
//! periods) stays within the autopilot's 0.5 s estimate timeout. Measured on the virtual boards
//! (`virtual-board/tests/hil.rs`, 2-core machine): 8.5 s of world time at 4 fps in 9.4 s of
//! virtual time (the autopilot's lockstep takes about 1 ms of virtual time per 1.95 ms IMU
//! period; the frames set the pace) and 12 s of wall time. In QEMU 7.2, whose STM32 USART takes
//! one received byte per main-loop iteration (about 11 kB/s into the firmware under `-icount
//! shift=auto`; the `qemu` flavour's host links run at 115,200 Bd), a frame takes about 2.3 s.
//!
//! # The board-to-board UART
//!
//! On hardware the boards are wired to each other, and the bench joins the virtual boards'
//! link UARTs. In QEMU the two firmwares' link UARTs can be joined directly (one QEMU
//! `-chardev socket,server=on`, the other connecting to it), or through this host ([`Relay`]):
//! the relay copies bytes both ways unchanged and decodes them on the way, so the run counts
//! decode errors on the inter-board link too.

use crate::log::records::{EstimateRecord, LinkRecord, MotorsRecord, StateRecord, TruthRecord};
use crate::log::scene3d::{self, BodyPose, CameraMount};
use crate::log::view3d::{View3d, ViewRates, ViewSample};
use crate::log::{ns as log_ns, write_telemetry, FlightLog, TelemetryExtras, Thinner};
use crate::param::{FileSection, LinkClosed, MessageSource, ParamClient, ParamFile};
use crate::sim::dynamics::Drone;
use crate::sim::flight::FlightConfig;
use crate::sim::scene_spec::SceneSpec;
use crate::sim::world::World;
use crate::transport::{is_transient_read_error, open_link, Link};
use anyhow::{anyhow, bail, Context as _};
use protocol::{
    encode, AutopilotToStereo, AutopilotToStereoDecoder, BoardToHost, BoardToHostDecoder, Estimate,
    FlightMode, FrameChunk, Heartbeat, HostToBoard, ImuSample, LinkErrorCounts, Message, Node,
    PilotCommand, StereoToAutopilot, StereoToAutopilotDecoder, Telemetry, WireTime,
    FRAME_CHUNK_BYTES, STEREO_FRAME_BYTES,
};
use std::io::{Read, Write};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Everything that defines a HIL run.
#[derive(Debug, Clone)]
pub struct HilConfig {
    /// World, drone, IMU and camera parameters, scene and seed (the `fly` defaults; the
    /// simulator-only fields such as link faults and processing times are not used).
    pub world: FlightConfig,
    /// Simulated duration, s (world time).
    pub duration_s: f64,
    /// Camera frames per second of world time.
    pub fps: f64,
    /// Height fixes (`ExternalPosition`) per second of world time.
    pub height_rate_hz: f64,
    /// World time of the arm command, s.
    pub arm_at_s: f64,
    /// Longest wait for the autopilot's `Motors` reply to an IMU sample before it counts as
    /// lost, wall time.
    pub reply_timeout: Duration,
    /// Longest wait for the estimate of a frame, from when it was handed to the link (a frame
    /// takes 0.27 s of a 921,600 Bd link, seconds through QEMU's USART), wall time.
    pub frame_timeout: Duration,
    /// Longest wait for both boards' first heartbeat, wall time.
    pub boot_timeout: Duration,
    /// Parameters to send before the flight (`hil --params`): the file's name and its
    /// sections. Each value is set on its board over the autopilot's host link (the camera
    /// board's passed on by the autopilot) and read back; a refusal, silence or a different
    /// read-back ends the run before the world starts, naming the key.
    pub params: Option<(String, Vec<FileSection>)>,
    /// Set (by `hil`'s Ctrl-C handler) to end the flight at the next IMU period; the result
    /// covers the world time flown, so the logs are still written.
    pub interrupt: Option<Arc<AtomicBool>>,
    /// Enable the autopilot's PWM outputs (`hil --outputs`): the motors on the bench turn with
    /// the commands. Off by default: the outputs stay at 0, the commands come back over the
    /// link only.
    pub outputs: bool,
    /// The link key (`hil --key FILE`): heartbeats, height fixes, the arm command and
    /// parameter requests to the autopilot are signed with it. IMU samples and frames are not
    /// (see `autopilot::link_auth`).
    pub key: Option<protocol::signing::LinkKey>,
}

impl Default for HilConfig {
    fn default() -> Self {
        Self {
            world: FlightConfig::default(),
            duration_s: 10.0,
            fps: 25.0,
            height_rate_hz: 100.0,
            arm_at_s: 0.5,
            reply_timeout: Duration::from_secs(5),
            frame_timeout: Duration::from_secs(60),
            boot_timeout: Duration::from_secs(60),
            params: None,
            interrupt: None,
            outputs: false,
            key: None,
        }
    }
}

/// One row of the HIL log (every 20 ms of world time).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HilRow {
    /// World time, s.
    pub t_s: f64,
    /// True position x, y (m) and height (m).
    pub pos: [f32; 3],
    /// True horizontal velocity in the world frame, m/s.
    pub vel: [f32; 2],
    /// Motor commands applied, 0..=1.
    pub motors: [f32; 4],
    /// The autopilot's flight mode in its latest telemetry (`None`: none yet).
    pub mode: Option<FlightMode>,
}

/// What a HIL run measured.
#[derive(Debug, Clone, Default)]
pub struct HilResult {
    /// World time flown, s.
    pub sim_s: f64,
    /// Wall time, s.
    pub wall_s: f64,
    /// IMU samples sent.
    pub imu_samples: u64,
    /// `Motors` replies matched to their sample.
    pub motor_replies: u64,
    /// IMU samples whose reply did not come within the timeout.
    pub reply_timeouts: u64,
    /// Frames streamed to the camera board.
    pub frames_sent: u64,
    /// Estimates mirrored back by the camera board.
    pub estimates: u64,
    /// Of those, valid ones (usable for control).
    pub valid_estimates: u64,
    /// How often each `EstimateFlags` bit (0..=7) was set in the estimates.
    pub flag_counts: [u64; 8],
    /// Frames whose estimate did not come within the timeout.
    pub frame_timeouts: u64,
    /// Wall time spent waiting for the autopilot's `Motors` replies, s.
    pub imu_wait_s: f64,
    /// Wall time the world was held for a frame's estimate, s.
    pub frame_wait_s: f64,
    /// Time with the drone airborne (above 2 cm), s.
    pub airborne_s: f64,
    /// Highest height reached, m.
    pub max_height_m: f64,
    /// Height at the end, m.
    pub final_height_m: f64,
    /// Largest horizontal distance from the start position, m.
    pub max_drift_m: f64,
    /// Wall and obstacle contacts.
    pub collisions: u32,
    /// Largest absolute motor command seen (0: the motors never ran).
    pub max_motor: f32,
    /// Decoding errors on the autopilot's host link (host side).
    pub autopilot_link_errors: LinkErrorCounts,
    /// Decoding errors on the camera board's host link (host side).
    pub stereo_link_errors: LinkErrorCounts,
    /// Decoding errors on the relayed board-to-board link (both directions), if relayed.
    pub relay_errors: LinkErrorCounts,
    /// Messages relayed camera board -> autopilot and autopilot -> camera board.
    pub relayed_messages: [u64; 2],
    /// The autopilot's last telemetry (its own count of camera-link errors included).
    pub last_telemetry: Option<Telemetry>,
    /// The log (50 Hz of world time).
    pub log: Vec<HilRow>,
    /// Why the MCAP flight log stopped being written, if it did.
    pub log_error: Option<String>,
    /// Why the flight ended before its duration (interrupted, a board's link closed), if it
    /// did: the result and its log cover the world time flown until then.
    pub ended_early: Option<String>,
}

impl HilResult {
    /// Sum of every decoding error seen on every link.
    pub fn total_link_errors(&self) -> u32 {
        self.autopilot_link_errors.total()
            + self.stereo_link_errors.total()
            + self.relay_errors.total()
            + self.last_telemetry.map_or(0, |t| t.link_errors.total())
    }

    /// A summary like `fly`'s, one fact per line.
    pub fn summary(&self) -> String {
        let mode = self
            .last_telemetry
            .map_or("none (no telemetry)", |t| t.flight_mode.name());
        format!(
            "world time        {:.2} s in {:.1} s wall ({:.3}x real time)\n\
             airborne          {:.2} s, max height {:.2} m, final height {:.2} m\n\
             max drift         {:.2} m (horizontal, from the start)\n\
             collisions        {}\n\
             imu lockstep      {} samples, {} motor replies, {} timeouts, {:.1} s waiting\n\
             camera            {} frames, {} estimates ({} valid; flag bits set {:?}), {} timeouts, world held {:.1} s\n\
             link errors       autopilot host {}, camera host {}, board-to-board relay {}, autopilot's own {}\n\
             relayed messages  camera->autopilot {}, autopilot->camera {}\n\
             final mode        {}{}",
            self.sim_s,
            self.wall_s,
            if self.wall_s > 0.0 { self.sim_s / self.wall_s } else { 0.0 },
            self.airborne_s,
            self.max_height_m,
            self.final_height_m,
            self.max_drift_m,
            self.collisions,
            self.imu_samples,
            self.motor_replies,
            self.reply_timeouts,
            self.imu_wait_s,
            self.frames_sent,
            self.estimates,
            self.valid_estimates,
            self.flag_counts,
            self.frame_timeouts,
            self.frame_wait_s,
            self.autopilot_link_errors.total(),
            self.stereo_link_errors.total(),
            self.relay_errors.total(),
            self.last_telemetry.map_or(0, |t| t.link_errors.total()),
            self.relayed_messages[0],
            self.relayed_messages[1],
            mode,
            self.ended_early
                .as_ref()
                .map_or(String::new(), |why| format!("\nended early       {why}")),
        )
    }
}

/// Relays the board-to-board UART through the host: bytes are copied unchanged both ways and
/// decoded on the way (for counting). Threads end when either side closes.
pub struct Relay {
    seen: Arc<Mutex<RelayCounts>>,
}

#[derive(Debug, Default, Clone, Copy)]
struct RelayCounts {
    s2a: u64,
    a2s: u64,
    s2a_errors: LinkErrorCounts,
    a2s_errors: LinkErrorCounts,
}

impl Relay {
    /// Starts relaying between the camera board's and the autopilot's USART1.
    pub fn start(stereo: Box<dyn Link>, autopilot: Box<dyn Link>) -> anyhow::Result<Self> {
        let seen = Arc::new(Mutex::new(RelayCounts::default()));
        let (s_r, s_w) = (stereo.try_clone_link()?, stereo);
        let (a_r, a_w) = (autopilot.try_clone_link()?, autopilot);
        {
            let seen = Arc::clone(&seen);
            let mut dec = StereoToAutopilotDecoder::new_mid_stream();
            pump(s_r, a_w, move |bytes| {
                let mut g = seen.lock().unwrap_or_else(|e| e.into_inner());
                let mut n = 0;
                dec.feed(bytes, |_: StereoToAutopilot| n += 1);
                g.s2a += n;
                g.s2a_errors = dec.errors();
            });
        }
        {
            let seen = Arc::clone(&seen);
            let mut dec = AutopilotToStereoDecoder::new_mid_stream();
            pump(a_r, s_w, move |bytes| {
                let mut g = seen.lock().unwrap_or_else(|e| e.into_inner());
                let mut n = 0;
                dec.feed(bytes, |_: AutopilotToStereo| n += 1);
                g.a2s += n;
                g.a2s_errors = dec.errors();
            });
        }
        Ok(Self { seen })
    }

    /// Messages relayed (camera -> autopilot, autopilot -> camera) and decoding errors (both
    /// directions added up) so far.
    pub fn counts(&self) -> ([u64; 2], LinkErrorCounts) {
        let g = *self.seen.lock().unwrap_or_else(|e| e.into_inner());
        ([g.s2a, g.a2s], add_errors(g.s2a_errors, g.a2s_errors))
    }
}

fn add_errors(a: LinkErrorCounts, b: LinkErrorCounts) -> LinkErrorCounts {
    LinkErrorCounts {
        crc: a.crc + b.crc,
        cobs: a.cobs + b.cobs,
        too_long: a.too_long + b.too_long,
        too_short: a.too_short + b.too_short,
        unknown_message: a.unknown_message + b.unknown_message,
        malformed: a.malformed + b.malformed,
        version_mismatch: a.version_mismatch + b.version_mismatch,
    }
}

/// Reads `from` on a thread until it ends, fails, `stop` is set, or `on_chunk` returns false.
fn read_chunks(
    mut from: Box<dyn Link>,
    stop: Arc<AtomicBool>,
    mut on_chunk: impl FnMut(&[u8]) -> bool + Send + 'static,
) {
    std::thread::spawn(move || {
        let mut buf = [0u8; 1024];
        while !stop.load(Ordering::Relaxed) {
            match from.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => {
                    if !on_chunk(buf.get(..n).unwrap_or(&[])) {
                        break;
                    }
                }
                Err(e) if is_transient_read_error(&e) => {}
                Err(_) => break,
            }
        }
    });
}

/// Copies `from` to `to` on a thread, showing every chunk to `tap` first.
fn pump(from: Box<dyn Link>, mut to: Box<dyn Link>, mut tap: impl FnMut(&[u8]) + Send + 'static) {
    read_chunks(from, Arc::new(AtomicBool::new(false)), move |bytes| {
        tap(bytes);
        to.write_all(bytes).is_ok()
    });
}

/// A reader thread decoding `BoardToHost` messages from a board into a channel.
struct BoardRx {
    rx: Receiver<BoardToHost>,
    errors: Arc<Mutex<LinkErrorCounts>>,
}

impl BoardRx {
    fn start(link: Box<dyn Link>, stop: Arc<AtomicBool>) -> Self {
        let (tx, rx) = mpsc::channel();
        let errors = Arc::new(Mutex::new(LinkErrorCounts::default()));
        let errs = Arc::clone(&errors);
        let mut dec = BoardToHostDecoder::new_mid_stream();
        read_chunks(link, stop, move |bytes| {
            let mut open = true;
            dec.feed(bytes, |m| open &= tx.send(m).is_ok());
            *errs.lock().unwrap_or_else(|e| e.into_inner()) = dec.errors();
            open
        });
        Self { rx, errors }
    }

    fn errors(&self) -> LinkErrorCounts {
        *self.errors.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// Encodes one host message into `out`.
/// The signer of the host's messages to the autopilot (none without a key).
fn host_signer(cfg: &HilConfig) -> crate::key::HostSigner {
    cfg.key.map_or_else(crate::key::HostSigner::default, |k| {
        crate::key::HostSigner::with_key(k, crate::key::link_id::HIL)
    })
}

fn push_msg(msg: &HostToBoard, out: &mut Vec<u8>) -> anyhow::Result<()> {
    let mut buf = [0u8; HostToBoard::MAX_FRAME_BYTES];
    let n = encode(msg, &mut buf).map_err(|e| anyhow!("encoding a host message: {e:?}"))?;
    out.extend_from_slice(buf.get(..n).unwrap_or(&[]));
    Ok(())
}

/// The chunks of one interleaved frame, encoded.
pub fn encode_frame(
    frame: &[u8; STEREO_FRAME_BYTES],
    frame_id: u16,
    capture_us: u32,
) -> anyhow::Result<Vec<u8>> {
    let mut out = Vec::with_capacity(STEREO_FRAME_BYTES + STEREO_FRAME_BYTES / 16);
    for (i, data) in frame.chunks(FRAME_CHUNK_BYTES).enumerate() {
        let msg = HostToBoard::FrameChunk(FrameChunk {
            frame_id,
            capture_us: WireTime(capture_us),
            offset: (i * FRAME_CHUNK_BYTES) as u16,
            data: data
                .try_into()
                .map_err(|_| anyhow!("frame chunk larger than {FRAME_CHUNK_BYTES} bytes"))?,
        });
        push_msg(&msg, &mut out)?;
    }
    Ok(out)
}

/// Waits for a first heartbeat on a board's host link (the board is up and its USART
/// receives: bytes sent earlier are lost).
fn wait_heartbeat(rx: &BoardRx, name: &str, timeout: Duration) -> anyhow::Result<()> {
    let deadline = Instant::now() + timeout;
    loop {
        let left = deadline
            .checked_duration_since(Instant::now())
            .ok_or_else(|| anyhow!("no heartbeat from the {name} within {timeout:?}"))?;
        match rx.rx.recv_timeout(left) {
            Ok(BoardToHost::Heartbeat(_)) => return Ok(()),
            Ok(_) => {}
            Err(RecvTimeoutError::Timeout) => {
                bail!("no heartbeat from the {name} within {timeout:?}")
            }
            Err(RecvTimeoutError::Disconnected) => bail!("the {name}'s link closed"),
        }
    }
}

/// Runs the world against the two boards' host links (and, optionally, relays their
/// board-to-board UART). `progress` is called with the world time about once per world
/// second.
pub fn run(
    cfg: &HilConfig,
    stereo: Box<dyn Link>,
    autopilot: Box<dyn Link>,
    relay: Option<&Relay>,
    progress: &mut dyn FnMut(f64),
) -> anyhow::Result<HilResult> {
    run_logged(cfg, stereo, autopilot, relay, progress, None)
}

/// [`run`], recording the flight into `log` (see [`HilRecorder`] for what goes in). A failed
/// write stops the recording and is reported in [`HilResult::log_error`]; the flight goes on.
pub fn run_logged(
    cfg: &HilConfig,
    stereo: Box<dyn Link>,
    autopilot: Box<dyn Link>,
    relay: Option<&Relay>,
    progress: &mut dyn FnMut(f64),
    log: Option<&mut FlightLog>,
) -> anyhow::Result<HilResult> {
    let positive = |v: f64| v.is_finite() && v > 0.0;
    if !positive(cfg.fps) || !positive(cfg.height_rate_hz) {
        bail!("fps and height rate must be positive");
    }
    let mut world = World::new(&cfg.world)?;
    let start_xy = [world.start[0], world.start[1]];

    let stop = Arc::new(AtomicBool::new(false));
    let ap_rx = BoardRx::start(autopilot.try_clone_link()?, Arc::clone(&stop));
    let cam_rx = BoardRx::start(stereo.try_clone_link()?, Arc::clone(&stop));
    let mut ap_tx = autopilot;
    // Frames are written by their own thread: a frame takes 0.27 s of a 921,600 Bd link.
    let (frame_tx, frame_rx): (Sender<Vec<u8>>, Receiver<Vec<u8>>) = mpsc::channel();
    {
        let mut link = stereo;
        std::thread::spawn(move || {
            while let Ok(bytes) = frame_rx.recv() {
                if link.write_all(&bytes).is_err() {
                    break;
                }
            }
        });
    }
    let result = (|| {
        wait_heartbeat(&ap_rx, "autopilot", cfg.boot_timeout)?;
        wait_heartbeat(&cam_rx, "camera board", cfg.boot_timeout)?;
        if let Some((file, sections)) = &cfg.params {
            send_params(file, sections, &mut ap_tx, &ap_rx, cfg)?;
        }
        let recorder = HilRecorder::new(log, &world);
        lockstep(
            cfg, &mut world, &mut ap_tx, &ap_rx, &cam_rx, &frame_tx, relay, start_xy, progress,
            recorder,
        )
    })();
    stop.store(true, Ordering::Relaxed);
    result
}

/// Sets and reads back every value of `sections` over the autopilot's host link, before the
/// world starts (the boards are disarmed); the first failure is the error.
fn send_params(
    file: &str,
    sections: &[FileSection],
    ap_tx: &mut Box<dyn Link>,
    ap_rx: &BoardRx,
    cfg: &HilConfig,
) -> anyhow::Result<()> {
    let timeout = cfg.reply_timeout;
    for section in sections {
        let source: MessageSource<'_> = Box::new(|wait| match ap_rx.rx.recv_timeout(wait) {
            Ok(m) => Ok(Some(m)),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => Err(LinkClosed),
        });
        let mut c =
            ParamClient::with_source(Box::new(&mut **ap_tx), source, section.board, timeout);
        c.sign_with(host_signer(cfg));
        section
            .send_and_verify(&mut c, file)
            .context("not flying: the boards do not run the parameter file")?;
    }
    Ok(())
}

/// The lockstep loop (see the module docs).
#[allow(clippy::too_many_arguments)]
fn lockstep(
    cfg: &HilConfig,
    world: &mut World,
    ap_tx: &mut Box<dyn Link>,
    ap_rx: &BoardRx,
    cam_rx: &BoardRx,
    frame_tx: &Sender<Vec<u8>>,
    relay: Option<&Relay>,
    start_xy: [f64; 2],
    progress: &mut dyn FnMut(f64),
    mut rec: HilRecorder<'_>,
) -> anyhow::Result<HilResult> {
    const IMU_HZ: u64 = 512;
    let wall0 = Instant::now();
    let end_us = (cfg.duration_s * 1e6) as u64;
    let frame_period_us = (1e6 / cfg.fps) as u64;
    let height_period_us = (1e6 / cfg.height_rate_hz) as u64;
    let arm_us = (cfg.arm_at_s * 1e6) as u64;
    let physics_dt_us = cfg.world.physics_dt_us.max(1);
    let mut r = HilResult {
        max_height_m: 0.0,
        ..Default::default()
    };
    let mut k = 0u64;
    let mut t = 0u64;
    let mut next_frame = 100_000u64;
    let mut next_height = 0u64;
    let mut next_heartbeat = 0u64;
    let mut next_log = 0u64;
    let mut next_progress = 1_000_000u64;
    let mut armed = false;
    let mut outputs_pending = cfg.outputs;
    let mut motors = [0.0f32; 4];
    let mut frame_id = 0u16;
    let mut signer = host_signer(cfg);
    // Exposure time (wire) of the frame whose estimate is awaited, and when it was sent.
    let mut in_flight: Option<(u32, Instant)> = None;
    let mut frame = Box::new([0u8; STEREO_FRAME_BYTES]);
    let mut out = Vec::new();

    'flight: while t < end_us {
        if cfg
            .interrupt
            .as_ref()
            .is_some_and(|f| f.load(Ordering::Relaxed))
        {
            r.ended_early = Some("interrupted".into());
            break;
        }
        // Camera: hold the world at the exposure time until the previous frame is answered.
        if t >= next_frame {
            if let Some((_, sent)) = in_flight {
                let held = Instant::now();
                let deadline = sent + cfg.frame_timeout;
                while in_flight.is_some() {
                    let left = deadline.saturating_duration_since(Instant::now());
                    if left.is_zero() {
                        r.frame_timeouts += 1;
                        break;
                    }
                    match cam_rx.rx.recv_timeout(left) {
                        Ok(BoardToHost::Estimate(e)) => {
                            rec.estimate(t, &e);
                            on_estimate(&e, &mut r, &mut in_flight)
                        }
                        Ok(_) => {}
                        Err(RecvTimeoutError::Timeout) => {}
                        Err(RecvTimeoutError::Disconnected) => {
                            r.ended_early = Some("the camera board's link closed".into());
                            break 'flight;
                        }
                    }
                }
                r.frame_wait_s += held.elapsed().as_secs_f64();
            }
            world.render(&mut frame);
            let capture = t as u32;
            if frame_tx
                .send(encode_frame(&frame, frame_id, capture)?)
                .is_err()
            {
                r.ended_early = Some("the camera board's link closed".into());
                break;
            }
            rec.frame(t, &frame);
            in_flight = Some((capture, Instant::now()));
            frame_id = frame_id.wrapping_add(1);
            r.frames_sent += 1;
            next_frame += frame_period_us;
        }
        while let Ok(m) = cam_rx.rx.try_recv() {
            if let BoardToHost::Estimate(e) = m {
                rec.estimate(t, &e);
                on_estimate(&e, &mut r, &mut in_flight);
            }
        }

        // Autopilot: the host's heartbeat (the autopilot lands without it), height fix, arm,
        // then the IMU sample of this instant.
        out.clear();
        if t >= next_heartbeat {
            next_heartbeat += u64::from(autopilot::app::HEARTBEAT_PERIOD_US);
            let hb = Heartbeat::new(Node::Host, (t / 1000) as u32);
            push_msg(&signer.wrap(HostToBoard::Heartbeat(hb))?, &mut out)?;
        }
        if t >= next_height {
            next_height += height_period_us;
            push_msg(
                &signer.wrap(HostToBoard::ExternalPosition(world.height_fix(t)))?,
                &mut out,
            )?;
        }
        if outputs_pending {
            outputs_pending = false;
            push_msg(
                &signer.wrap(HostToBoard::Command(PilotCommand::HilOutputs(true)))?,
                &mut out,
            )?;
        }
        if !armed && t >= arm_us {
            armed = true;
            push_msg(
                &signer.wrap(HostToBoard::Command(PilotCommand::Arm))?,
                &mut out,
            )?;
        }
        let s = world.imu_sample();
        let stamp = WireTime(t as u32);
        push_msg(
            &HostToBoard::Imu(ImuSample {
                timestamp_us: stamp,
                gyro_radps: s.gyro.to_f32(),
                accel_mps2: s.accel.to_f32(),
            }),
            &mut out,
        )?;
        if let Err(e) = ap_tx.write_all(&out) {
            r.ended_early = Some(format!("writing to the autopilot: {e}"));
            break;
        }
        r.imu_samples += 1;
        let waiting = Instant::now();
        let deadline = waiting + cfg.reply_timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match ap_rx.rx.recv_timeout(left) {
                Ok(BoardToHost::Motors(m)) if m.timestamp_us == stamp => {
                    motors = m.throttle.map(|v| {
                        if v.is_finite() {
                            v.clamp(0.0, 1.0)
                        } else {
                            0.0
                        }
                    });
                    r.motor_replies += 1;
                    rec.motors(t, motors);
                    break;
                }
                Ok(BoardToHost::Telemetry(tel)) => {
                    rec.telemetry(t, &tel, s.gyro.to_f32(), &world.drone, &r, [ap_rx, cam_rx]);
                    r.last_telemetry = Some(tel);
                }
                Ok(_) => {}
                Err(RecvTimeoutError::Timeout) => {
                    r.reply_timeouts += 1;
                    break;
                }
                Err(RecvTimeoutError::Disconnected) => {
                    r.ended_early = Some("the autopilot's link closed".into());
                    break 'flight;
                }
            }
        }
        r.imu_wait_s += waiting.elapsed().as_secs_f64();
        r.max_motor = motors.iter().fold(r.max_motor, |a, &b| a.max(b));

        // World: one IMU period with these motor commands.
        k += 1;
        let t_next = k * 1_000_000 / IMU_HZ;
        let cmd = motors.map(f64::from);
        while t < t_next {
            let step = physics_dt_us.min(t_next - t);
            let dt = step as f64 * 1e-6;
            t += step;
            world.step(&cmd, dt, t);
        }
        r.collisions = world.collisions;
        r.airborne_s = world.airborne_s;
        let p = world.drone.state.pos;
        let h = -p.z;
        r.max_height_m = r.max_height_m.max(h);
        r.final_height_m = h;
        let drift = ((p.x - start_xy[0]).powi(2) + (p.y - start_xy[1]).powi(2)).sqrt();
        r.max_drift_m = r.max_drift_m.max(drift);
        if t >= next_log {
            next_log += 20_000;
            rec.truth(t, &world.drone, r.collisions);
            r.log.push(HilRow {
                t_s: t as f64 * 1e-6,
                pos: [p.x as f32, p.y as f32, h as f32],
                vel: [
                    world.drone.state.vel.x as f32,
                    world.drone.state.vel.y as f32,
                ],
                motors,
                mode: r.last_telemetry.map(|t| t.flight_mode),
            });
        }
        if t >= next_progress {
            progress(t as f64 * 1e-6);
            next_progress += 1_000_000;
        }
    }
    // Late telemetry and estimates.
    while let Ok(m) = ap_rx.rx.try_recv() {
        if let BoardToHost::Telemetry(tel) = m {
            r.last_telemetry = Some(tel);
        }
    }
    while let Ok(m) = cam_rx.rx.try_recv() {
        if let BoardToHost::Estimate(e) = m {
            on_estimate(&e, &mut r, &mut in_flight);
        }
    }
    r.sim_s = t as f64 * 1e-6;
    r.wall_s = wall0.elapsed().as_secs_f64();
    r.log_error = rec.error.map(|e| format!("{e:#}"));
    r.autopilot_link_errors = ap_rx.errors();
    r.stereo_link_errors = cam_rx.errors();
    if let Some(relay) = relay {
        let (n, e) = relay.counts();
        r.relayed_messages = n;
        r.relay_errors = e;
    }
    Ok(r)
}

/// What `sim-host hil` records into its MCAP flight log, on world time: every estimate the
/// camera board mirrors, the autopilot's telemetry (state and mode by name, attitude with the
/// gyro sample last sent, velocity and its setpoint, height, link counters of the board and of
/// this host) with the true velocity and height beside it, the motor duties at 128 Hz, the true
/// pose at 50 Hz, and the left and right images of the frames sent, about 5 per second.
pub struct HilRecorder<'a> {
    log: Option<&'a mut FlightLog>,
    error: Option<anyhow::Error>,
    images: Thinner,
    motors: Thinner,
    view: View3d,
    /// The autopilot's last telemetry, what the 3D view shows it believes.
    last_telemetry: Option<Telemetry>,
}

impl<'a> HilRecorder<'a> {
    /// Records into `log` (if any) a flight in `world`, starting with the room in 3D.
    fn new(log: Option<&'a mut FlightLog>, world: &World) -> Self {
        let mount = CameraMount {
            forward_m: world.camera.params.forward_offset_m,
            baseline_m: world.camera.params.baseline_m,
        };
        let mut recorder = Self {
            log,
            error: None,
            images: Thinner::new(5.0),
            motors: Thinner::new(128.0),
            view: View3d::new(ViewRates::default(), mount),
            last_telemetry: None,
        };
        recorder.with_view(|view, log| view.start(log, 0, Some(&world.scene)));
        recorder
    }

    fn with_view(&mut self, f: impl FnOnce(&mut View3d, &mut FlightLog) -> anyhow::Result<()>) {
        if let Some(log) = self.log.as_deref_mut() {
            if let Err(e) = f(&mut self.view, log) {
                self.error = Some(e);
                self.log = None;
            }
        }
    }

    fn with(&mut self, f: impl FnOnce(&mut FlightLog) -> anyhow::Result<()>) {
        if let Some(log) = self.log.as_deref_mut() {
            if let Err(e) = f(log) {
                self.error = Some(e);
                self.log = None;
            }
        }
    }

    fn estimate(&mut self, t_us: u64, e: &Estimate) {
        self.with(|log| log.write(log_ns(t_us), &EstimateRecord::from(e)));
    }

    fn frame(&mut self, t_us: u64, frame: &[u8; STEREO_FRAME_BYTES]) {
        if self.images.take(t_us) {
            self.with(|log| log.stereo_frame(log_ns(t_us), frame));
        }
    }

    fn motors(&mut self, t_us: u64, motors: [f32; 4]) {
        if self.motors.take(t_us) {
            self.with(|log| log.write(log_ns(t_us), &MotorsRecord::from(motors)));
        }
    }

    fn truth(&mut self, t_us: u64, drone: &Drone, collisions: u32) {
        let s = &drone.state;
        let (roll, pitch, yaw) = s.att.to_euler();
        if let Some(tel) = self.last_telemetry {
            let state = StateRecord::new(tel.fsm_state, tel.flight_mode);
            let label = format!("{} / {}", state.fsm_state, state.mode);
            let sample = ViewSample {
                truth: Some(BodyPose {
                    position: scene3d::world_point(s.pos.x as f32, s.pos.y as f32, -s.pos.z as f32),
                    orientation: scene3d::body_orientation(roll as f32, pitch as f32, yaw as f32),
                }),
                attitude_rad: tel.attitude_rad,
                velocity_mps: tel.velocity_mps,
                height_m: tel.height_m,
                obstacle_m: tel.obstacle_m,
                state: &label,
            };
            self.with_view(|view, log| view.step(log, t_us, &sample));
        }
        self.with(|log| {
            log.write(
                log_ns(t_us),
                &TruthRecord {
                    x_m: s.pos.x as f32,
                    y_m: s.pos.y as f32,
                    height_m: -s.pos.z as f32,
                    yaw_rad: Some(yaw as f32),
                    clearance_m: None,
                    collisions,
                },
            )
        });
    }

    fn telemetry(
        &mut self,
        t_us: u64,
        tel: &Telemetry,
        gyro_radps: [f32; 3],
        drone: &Drone,
        r: &HilResult,
        host: [&BoardRx; 2],
    ) {
        let s = &drone.state;
        let (_, _, yaw) = s.att.to_euler();
        let (sy, cy) = yaw.sin_cos();
        let true_v = [
            (s.vel.x * cy + s.vel.y * sy) as f32,
            (-s.vel.x * sy + s.vel.y * cy) as f32,
        ];
        let host_errors = add_errors(host[0].errors(), host[1].errors());
        let t = log_ns(t_us);
        self.last_telemetry = Some(*tel);
        self.with(|log| {
            write_telemetry(
                log,
                t,
                tel,
                &TelemetryExtras {
                    gyro_radps: Some(gyro_radps),
                    true_velocity_mps: Some(true_v),
                    true_height_m: Some(-s.pos.z as f32),
                },
            )?;
            log.write(
                t,
                &LinkRecord {
                    camera_link_errors: tel.link_errors.into(),
                    host_link_errors: Some(host_errors.into()),
                    estimates_received: r.estimates,
                    estimates_valid: r.valid_estimates,
                    frames_dropped: None,
                    camera_to_autopilot_bytes_lost: None,
                    camera_to_autopilot_bytes_corrupted: None,
                    autopilot_to_camera_bytes_lost: None,
                    timeouts: Some(r.reply_timeouts + r.frame_timeouts),
                },
            )
        });
    }
}

/// Counts an estimate mirrored by the camera board; clears the awaited frame if it is its.
fn on_estimate(e: &Estimate, r: &mut HilResult, in_flight: &mut Option<(u32, Instant)>) {
    r.estimates += 1;
    r.valid_estimates += u64::from(e.is_valid());
    for (bit, n) in r.flag_counts.iter_mut().enumerate() {
        *n += u64::from(e.flags.0 >> bit & 1);
    }
    if in_flight.is_some_and(|(c, _)| c == e.capture_us.as_micros()) {
        *in_flight = None;
    }
}

/// Writes the log as CSV.
pub fn write_log_csv(r: &HilResult, path: &std::path::Path) -> anyhow::Result<()> {
    let mut s = String::from("t_s,x_m,y_m,h_m,vx_mps,vy_mps,m1,m2,m3,m4,mode\n");
    for row in &r.log {
        s.push_str(&format!(
            "{:.3},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{}\n",
            row.t_s,
            row.pos[0],
            row.pos[1],
            row.pos[2],
            row.vel[0],
            row.vel[1],
            row.motors[0],
            row.motors[1],
            row.motors[2],
            row.motors[3],
            row.mode.map_or("none", FlightMode::name)
        ));
    }
    std::fs::write(path, s).with_context(|| format!("writing {}", path.display()))
}

/// `sim-host hil`: fly the simulated world with the boards' lockstep firmwares in the loop: on
/// the real boards, on the virtual boards or in QEMU.
#[derive(Debug, clap::Args)]
pub struct HilArgs {
    /// The camera board's host link: a serial device (/dev/ttyUSB0) or tcp:HOST:PORT (`vboard
    /// serve hil`, a QEMU `-chardev socket,server=on`).
    #[arg(long)]
    pub stereo: String,
    /// The autopilot's host link (same forms as --stereo).
    #[arg(long)]
    pub autopilot: String,
    /// Relay the board-to-board UART through this host: the camera board's link UART (USART1
    /// in QEMU) ...
    #[arg(long, requires = "relay_autopilot")]
    pub relay_stereo: Option<String>,
    /// ... and the autopilot's (USART2; for two QEMUs: wired boards and the virtual boards do
    /// not need it).
    #[arg(long, requires = "relay_stereo")]
    pub relay_autopilot: Option<String>,
    /// Baud rate of serial devices.
    #[arg(long, default_value_t = 921_600)]
    pub baud: u32,
    /// World time to fly, s.
    #[arg(long, default_value_t = 10.0)]
    pub duration: f64,
    /// Scene preset (room, room-obstacles, corridor, plain-room, office).
    #[arg(long, default_value = "room")]
    pub scenario: String,
    /// Scene file (TOML, see docs/scenes.md) instead of a preset.
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Seed of the world (textures, sensor noise).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Camera frames per second of world time (each frame takes 0.27 s of a 921,600 Bd link;
    /// the world waits for the link; see the docs).
    #[arg(long, default_value_t = 4.0)]
    pub fps: f64,
    /// World time of the arm command, s: once the autopilot counts the camera board's estimates
    /// (its flow history fills with the 10th frame, at 2.35 s at 4 fps, and the autopilot
    /// counts the third valid estimate in a row, at 2.85 s; armed earlier, the failsafe lands
    /// before it sees one).
    #[arg(long, default_value_t = 3.0)]
    pub arm_at: f64,
    /// Longest wait for a reply from a board, s (wall time).
    #[arg(long, default_value_t = 5.0)]
    pub reply_timeout: f64,
    /// Directory for the logs (hil_log.csv, and flight.mcap unless --mcap says otherwise).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Where to write the MCAP flight log (default: flight.mcap in --out, if given).
    #[arg(long)]
    pub mcap: Option<PathBuf>,
    /// Serve the log's channels live over the Foxglove WebSocket protocol on 127.0.0.1 as
    /// they are written (see `--live-port`).
    #[arg(long)]
    pub live: bool,
    /// Port of the live view (0: any free port; the address is printed at the start).
    #[arg(long, default_value_t = crate::log::live::DEFAULT_PORT)]
    pub live_port: u16,
    /// Board parameters (TOML, `[autopilot]` and `[camera]`, as `fly --params`; see
    /// docs/parameters.md): set on the boards and read back before the flight; any refusal or
    /// mismatch stops the run before arming.
    #[arg(long)]
    pub params: Option<PathBuf>,
    /// Drive the autopilot's PWM outputs with its motor commands (motors on the bench turn).
    /// Without it they stay at 0 and the commands are seen in the `Motors` replies and the log.
    #[arg(long)]
    pub outputs: bool,
    /// The link key file (`sim-host key new`): commands to the autopilot are signed with it.
    #[arg(long)]
    pub key: Option<PathBuf>,
}

/// Runs `sim-host hil`.
pub fn run_cli(args: &HilArgs) -> anyhow::Result<()> {
    let cfg = HilConfig {
        world: FlightConfig {
            scene: SceneSpec::from_cli(args.scene.as_deref(), &args.scenario)?,
            seed: args.seed,
            ..FlightConfig::default()
        },
        duration_s: args.duration,
        fps: args.fps,
        arm_at_s: args.arm_at,
        outputs: args.outputs,
        reply_timeout: Duration::from_secs_f64(args.reply_timeout.max(0.01)),
        params: match &args.params {
            Some(path) => Some((
                path.display().to_string(),
                ParamFile::load_sections(path)?.1,
            )),
            None => None,
        },
        interrupt: Some(crate::interrupt_flag()?),
        key: args.key.as_deref().map(crate::key::load_key).transpose()?,
        ..HilConfig::default()
    };
    let stereo = open_link(&args.stereo, args.baud)?;
    let autopilot = open_link(&args.autopilot, args.baud)?;
    let relay = match (&args.relay_stereo, &args.relay_autopilot) {
        (Some(s), Some(a)) => Some(Relay::start(
            open_link(s, args.baud)?,
            open_link(a, args.baud)?,
        )?),
        _ => None,
    };
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let mcap_path = args
        .mcap
        .clone()
        .or_else(|| args.out.as_ref().map(|d| d.join("flight.mcap")));
    let mut mcap = mcap_path.as_deref().map(FlightLog::create).transpose()?;
    if args.live {
        let log = mcap.as_mut().ok_or_else(|| {
            anyhow::anyhow!("hil --live serves the flight log's channels: give --out or --mcap")
        })?;
        log.serve_live(crate::log::live::LiveServer::start_announced(
            args.live_port,
        )?);
    }
    let r = run_logged(
        &cfg,
        stereo,
        autopilot,
        relay.as_ref(),
        &mut |t| {
            eprint!("\rworld time {t:.0} s");
        },
        mcap.as_mut(),
    );
    let r = match r {
        Ok(r) => r,
        Err(e) => {
            // What was recorded before the failure stays readable.
            if let Some(log) = mcap {
                let _ = log.finish();
            }
            return Err(e);
        }
    };
    eprintln!();
    if let Some((file, sections)) = &cfg.params {
        let n: usize = sections.iter().map(|s| s.values.len()).sum();
        println!("parameters        {n} from {file} set and read back");
    }
    println!("{}", r.summary());
    if let Some(dir) = &args.out {
        write_log_csv(&r, &dir.join("hil_log.csv"))?;
        println!("log               {}", dir.join("hil_log.csv").display());
    }
    if let Some(log) = mcap {
        let summary = log.finish()?;
        println!(
            "flight log        {} ({} messages on {} channels, MCAP)",
            summary.path.display(),
            summary.total(),
            summary.counts.len()
        );
    }
    match r.ended_early.as_deref() {
        None | Some("interrupted") => {}
        Some(why) => bail!("the flight ended early ({why}); its logs are written"),
    }
    if let Some(e) = &r.log_error {
        bail!("the flight log stopped early: {e}");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    //! The host side of the lockstep against two software boards on loopback TCP that run the
    //! boards' own libraries the way the lockstep firmwares do (world clock from the IMU
    //! timestamps, `autopilot::lockstep::WorldTimers` releasing the periodic tasks, Edge-FS
    //! at the frames' exposure times). Fast, no firmware: `virtual-board/tests/hil.rs` flies
    //! the `hil` images on the virtual boards.
    use super::*;
    use autopilot::app::{Autopilot, AutopilotConfig};
    use autopilot::lockstep::{WorldClock, WorldTimers};
    use autopilot::HostOutcome;
    use protocol::{Heartbeat, HostToBoardDecoder, MotorCommand, Node};
    use std::net::{TcpListener, TcpStream};
    use stereo_board::app::{send_to_host, FrameAssembler, StereoBoardApp};
    use stereo_board::edge_fs::EdgeFsParams;

    type Wire = Arc<Mutex<Vec<u8>>>;

    fn send_host(stream: &mut TcpStream, msg: &BoardToHost) {
        let mut out = Vec::new();
        send_to_host(msg, &mut |b| out.extend_from_slice(b));
        let _ = stream.write_all(&out);
    }

    fn take(wire: &Wire) -> Vec<u8> {
        std::mem::take(&mut *wire.lock().unwrap())
    }

    /// The autopilot firmware's lockstep flavour, in software.
    fn autopilot_board(mut s: TcpStream, to_camera: Wire, from_camera: Wire) {
        let mut ap = Autopilot::new(AutopilotConfig::default());
        let (mut clock, mut timers) = (WorldClock::new(), WorldTimers::new());
        let mut dec = HostToBoardDecoder::new();
        send_host(
            &mut s,
            &BoardToHost::Heartbeat(Heartbeat::new(Node::Autopilot, 0)),
        );
        let mut buf = [0u8; 512];
        while let Ok(n) = s.read(&mut buf) {
            if n == 0 {
                return;
            }
            let mut msgs = Vec::new();
            dec.feed(&buf[..n], |m| msgs.push(m));
            for m in msgs {
                let now = clock.now_us();
                match ap.on_host_message(m, now, None) {
                    HostOutcome::Imu(imu) => {
                        let now = clock.observe(imu.timestamp_us);
                        ap.on_stereo_bytes(&take(&from_camera), now);
                        let throttle = ap.on_imu(&imu, now);
                        let reply = MotorCommand {
                            timestamp_us: WireTime(now as u32),
                            throttle,
                        };
                        send_host(&mut s, &BoardToHost::Motors(reply));
                        let due = timers.due(now);
                        if due.guidance {
                            ap.guidance_step(now);
                        }
                        if due.gyro_tx {
                            let msg = AutopilotToStereo::GyroAttitude(ap.gyro_attitude(now));
                            let mut w = to_camera.lock().unwrap();
                            crate::sim::boards::send(&msg, &mut |b| w.extend_from_slice(b));
                        }
                        if due.telemetry {
                            send_host(&mut s, &BoardToHost::Telemetry(ap.telemetry(now)));
                        }
                        if let Some(answer) = ap.take_camera_param_reply() {
                            send_host(&mut s, &BoardToHost::Param(answer));
                        }
                    }
                    HostOutcome::Reply(reply) => send_host(&mut s, &reply),
                    HostOutcome::ToCamera(msg) => {
                        {
                            let mut w = to_camera.lock().unwrap();
                            crate::sim::boards::send(&msg, &mut |b| w.extend_from_slice(b));
                        }
                        // As the firmware's link task: the answer goes to the host as it comes
                        // (the camera board answers on its own thread).
                        let deadline = Instant::now() + Duration::from_secs(2);
                        while Instant::now() < deadline {
                            ap.on_stereo_bytes(&take(&from_camera), clock.now_us());
                            if let Some(answer) = ap.take_camera_param_reply() {
                                send_host(&mut s, &BoardToHost::Param(answer));
                                break;
                            }
                            std::thread::sleep(Duration::from_millis(1));
                        }
                    }
                    HostOutcome::Done => {}
                }
            }
        }
    }

    /// The camera board firmware's lockstep flavour, in software.
    fn camera_board(mut s: TcpStream, to_autopilot: Wire, from_autopilot: Wire) {
        let mut cb = Box::new(StereoBoardApp::new(EdgeFsParams::default_config()));
        let mut frames = Box::new(FrameAssembler::new());
        send_host(
            &mut s,
            &BoardToHost::Heartbeat(Heartbeat::new(Node::StereoBoard, 0)),
        );
        let mut world = timebase::Instant::ZERO;
        let mut buf = [0u8; 4096];
        // Until the first frame the board also answers the autopilot link as bytes come (the
        // parameter requests before a flight); from then on at each frame, as before.
        let mut first_frame_seen = false;
        s.set_read_timeout(Some(Duration::from_millis(2))).unwrap();
        loop {
            let n = match s.read(&mut buf) {
                Ok(0) => return,
                Ok(n) => n,
                Err(e) if is_transient_read_error(&e) => {
                    if !first_frame_seen {
                        let mut w = to_autopilot.lock().unwrap();
                        cb.on_rx_bytes(
                            &take(&from_autopilot),
                            world,
                            &mut |b| w.extend_from_slice(b),
                            None,
                        );
                    }
                    continue;
                }
                Err(_) => return,
            };
            let mut ready = None;
            cb.on_host_bytes(&buf[..n], &mut frames, |_, t| ready = Some(t));
            if let Some(capture) = ready {
                first_frame_seen = true;
                world = world.max(capture);
                let mut w = to_autopilot.lock().unwrap();
                cb.on_rx_bytes(
                    &take(&from_autopilot),
                    world,
                    &mut |b| w.extend_from_slice(b),
                    None,
                );
                let out = cb.process_frame(frames.frame(), capture, world);
                let est = cb.send_estimate(&out, capture, world, &mut |b| w.extend_from_slice(b));
                drop(w);
                send_host(&mut s, &BoardToHost::Estimate(est));
            }
        }
    }

    fn pair() -> (TcpStream, TcpStream) {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let c = TcpStream::connect(l.local_addr().unwrap()).unwrap();
        let (s, _) = l.accept().unwrap();
        c.set_nodelay(true).unwrap();
        s.set_nodelay(true).unwrap();
        (c, s)
    }

    /// The two software boards, wired to each other; returns the host ends (camera,
    /// autopilot).
    fn software_boards() -> (TcpStream, TcpStream) {
        let (a2s, s2a): (Wire, Wire) = Default::default();
        let (ap_host, ap_board) = pair();
        let (cam_host, cam_board) = pair();
        {
            let (a, b) = (Arc::clone(&a2s), Arc::clone(&s2a));
            std::thread::spawn(move || autopilot_board(ap_board, a, b));
        }
        {
            let (a, b) = (Arc::clone(&s2a), Arc::clone(&a2s));
            std::thread::spawn(move || camera_board(cam_board, a, b));
        }
        (cam_host, ap_host)
    }

    fn fly_with(sections: Vec<FileSection>) -> anyhow::Result<HilResult> {
        let (cam_host, ap_host) = software_boards();
        let cfg = HilConfig {
            duration_s: 0.2,
            fps: 10.0,
            reply_timeout: Duration::from_secs(2),
            params: Some(("p.toml".into(), sections)),
            ..HilConfig::default()
        };
        run(
            &cfg,
            Box::new(cam_host),
            Box::new(ap_host),
            None,
            &mut |_| {},
        )
    }

    #[test]
    fn params_are_set_and_read_back_on_both_boards_before_the_flight() {
        let (_, sections) = ParamFile::parse_sections(
            "[camera]\nstereo_shift = -3\nhalf_window = 5\n[autopilot]\ntarget_height = 0.8\n",
            "p.toml",
        )
        .unwrap();
        let r = fly_with(sections).unwrap();
        assert_eq!(
            r.motor_replies,
            r.imu_samples,
            "the flight ran: {}",
            r.summary()
        );
        assert!(r.imu_samples > 100, "{}", r.summary());

        // A value the board refuses (read-only on the autopilot) stops the run, naming it.
        let refused = vec![FileSection {
            board: Node::Autopilot,
            values: vec![("indi_rate_hz".into(), protocol::ParamValue::F32(512.0))],
        }];
        let e = format!("{:#}", fly_with(refused).unwrap_err());
        assert!(
            e.contains("not flying")
                && e.contains("[autopilot] indi_rate_hz")
                && e.contains("read-only"),
            "{e}"
        );

        // A read-back that differs from the value sent (the key set twice: the board holds the
        // second) stops it too.
        let v = protocol::ParamValue::I32;
        let twice = vec![FileSection {
            board: Node::StereoBoard,
            values: vec![
                ("stereo_shift".into(), v(-3)),
                ("stereo_shift".into(), v(4)),
            ],
        }];
        let e = format!("{:#}", fly_with(twice).unwrap_err());
        assert!(
            e.contains("p.toml: [camera] stereo_shift: set to -3, but the board reads back 4"),
            "{e}"
        );
    }

    /// Flies the software boards for up to 30 s of world time, calling `at_one_second` with
    /// the autopilot's host end once world time passes 1 s; returns the result, the CSV and
    /// the MCAP file's bytes.
    fn fly_until(
        name: &str,
        interrupt: Option<Arc<AtomicBool>>,
        at_one_second: impl FnOnce(&TcpStream),
    ) -> (HilResult, String, Vec<u8>) {
        let (cam_host, ap_host) = software_boards();
        let ap_host_end = ap_host.try_clone().unwrap();
        let cfg = HilConfig {
            duration_s: 30.0,
            fps: 10.0,
            reply_timeout: Duration::from_secs(2),
            interrupt,
            ..HilConfig::default()
        };
        let dir = std::env::temp_dir().join(format!("hil-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut log = FlightLog::create(&dir.join("flight.mcap")).unwrap();
        let mut once = Some(at_one_second);
        let r = run_logged(
            &cfg,
            Box::new(cam_host),
            Box::new(ap_host),
            None,
            &mut |t| {
                if t >= 1.0 {
                    if let Some(f) = once.take() {
                        f(&ap_host_end);
                    }
                }
            },
            Some(&mut log),
        )
        .expect("the flight ends with a result");
        drop(ap_host_end);
        log.finish().expect("the log is finished");
        write_log_csv(&r, &dir.join("hil_log.csv")).unwrap();
        let csv = std::fs::read_to_string(dir.join("hil_log.csv")).unwrap();
        let mcap = std::fs::read(dir.join("flight.mcap")).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        (r, csv, mcap)
    }

    /// The CSV's last row is whole (as many fields as the header) and its time is `sim_s`'s.
    fn assert_whole_csv(csv: &str, r: &HilResult) {
        assert!(csv.ends_with('\n'), "{csv}");
        let mut lines = csv.lines();
        let columns = lines.next().unwrap().split(',').count();
        let last = lines.last().expect("rows");
        assert_eq!(last.split(',').count(), columns, "{last}");
        let t: f64 = last.split(',').next().unwrap().parse().unwrap();
        assert!(t <= r.sim_s && t > r.sim_s - 0.05, "{t} {}", r.sim_s);
    }

    /// The MCAP file has its summary and footer, and every message reads.
    fn assert_finished_mcap(bytes: &[u8]) -> usize {
        let summary = mcap::Summary::read(bytes).expect("a summary section");
        assert!(summary.is_some_and(|s| !s.channels.is_empty()));
        let mut n = 0;
        for m in mcap::MessageStream::new(bytes).unwrap() {
            m.expect("a whole message");
            n += 1;
        }
        n
    }

    #[test]
    fn an_interrupt_ends_the_flight_with_its_logs_whole() {
        let flag = Arc::new(AtomicBool::new(false));
        let set = Arc::clone(&flag);
        let (r, csv, mcap) = fly_until("interrupt", Some(flag), move |_| {
            set.store(true, Ordering::SeqCst)
        });
        assert_eq!(
            r.ended_early.as_deref(),
            Some("interrupted"),
            "{}",
            r.summary()
        );
        assert!(r.sim_s >= 1.0 && r.sim_s < 1.1, "{}", r.summary());
        assert!(r.summary().contains("ended early       interrupted"));
        assert_whole_csv(&csv, &r);
        assert!(assert_finished_mcap(&mcap) > 100);
    }

    #[test]
    fn a_closed_link_ends_the_flight_with_its_logs_whole() {
        // The autopilot's host link closed under the flight (a USB adapter unplugged).
        let (r, csv, mcap) = fly_until("closed", None, |autopilot| {
            autopilot.shutdown(std::net::Shutdown::Both).unwrap()
        });
        let why = r.ended_early.clone().unwrap_or_default();
        assert!(why.contains("autopilot"), "{}", r.summary());
        assert!(r.sim_s >= 1.0 && r.sim_s < 1.1, "{}", r.summary());
        assert_whole_csv(&csv, &r);
        assert!(assert_finished_mcap(&mcap) > 100);
    }

    #[test]
    fn lockstep_flies_software_boards_off_the_floor() {
        let (cam_host, ap_host) = software_boards();
        // Armed at 1 s, as a user arms on valid estimates: the 10 fps camera's first valid one
        // comes once its flow history has filled, about 0.9 s in.
        let cfg = HilConfig {
            duration_s: 3.0,
            fps: 10.0,
            arm_at_s: 1.0,
            ..HilConfig::default()
        };
        let mcap_path =
            std::env::temp_dir().join(format!("hil-lockstep-{}.mcap", std::process::id()));
        let mut log = FlightLog::create(&mcap_path).unwrap();
        let r = run_logged(
            &cfg,
            Box::new(cam_host),
            Box::new(ap_host),
            None,
            &mut |_| {},
            Some(&mut log),
        )
        .unwrap();
        let logged = log.finish().unwrap();
        let s = r.summary();
        assert_eq!(r.log_error, None);
        // The log holds what the run saw, channel by channel, in time order.
        let bytes = std::fs::read(&mcap_path).unwrap();
        let _ = std::fs::remove_file(&mcap_path);
        let mut counts = std::collections::BTreeMap::new();
        let mut last_ns = 0;
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            let m = m.unwrap();
            assert!(m.log_time >= last_ns, "{} out of order", m.channel.topic);
            last_ns = m.log_time;
            *counts.entry(m.channel.topic.clone()).or_insert(0u64) += 1;
        }
        let count = |t: &str| counts.get(t).copied().unwrap_or(0);
        assert_eq!(count("/estimate"), r.estimates, "{counts:?}");
        assert_eq!(
            count("/camera/left"),
            15,
            "frames at 0.1 s, 0.3 s ... 2.9 s"
        );
        assert_eq!(count("/camera/right"), 15);
        assert_eq!(count("/truth"), r.log.len() as u64);
        assert!(
            (380..=386).contains(&count("/motors")),
            "128 Hz: {counts:?}"
        );
        assert!(
            (25..=31).contains(&count("/state")),
            "10 Hz telemetry: {counts:?}"
        );
        for t in ["/attitude", "/setpoint", "/velocity", "/height", "/link"] {
            assert_eq!(count(t), count("/state"), "{t}");
        }
        // The host link carries no barometer (heights come as external fixes), so telemetry has
        // no reading to log.
        assert_eq!(count("/baro"), 0, "{counts:?}");
        assert_eq!(
            logged
                .counts
                .iter()
                .map(|(t, n)| (t.to_string(), *n))
                .collect::<Vec<_>>(),
            counts.into_iter().collect::<Vec<_>>()
        );
        assert_eq!(r.imu_samples, 3 * 512, "{s}");
        assert_eq!(r.motor_replies, r.imu_samples, "{s}");
        assert_eq!(r.reply_timeouts + r.frame_timeouts, 0, "{s}");
        assert_eq!(r.frames_sent, 29, "{s}");
        assert!(r.estimates + 1 >= r.frames_sent, "{s}");
        assert!(r.valid_estimates >= 10, "{s}");
        assert_eq!(r.total_link_errors(), 0, "{s}");
        assert!(r.max_height_m > 0.7 && r.max_height_m < 1.4, "{s}");
        assert_eq!(r.collisions, 0, "{s}");
        assert!(r.max_drift_m < 0.5, "{s}");
        assert!(r.last_telemetry.is_some(), "{s}");
    }

    #[test]
    fn frame_chunks_reassemble_on_the_board() {
        let mut frame = Box::new([0u8; STEREO_FRAME_BYTES]);
        for (i, b) in frame.iter_mut().enumerate() {
            *b = (i * 7 % 251) as u8;
        }
        let bytes = encode_frame(&frame, 3, 123_456).unwrap();
        let mut cb = Box::new(StereoBoardApp::new(EdgeFsParams::default_config()));
        let mut asm = Box::new(FrameAssembler::new());
        let mut got = None;
        cb.on_host_bytes(&bytes, &mut asm, |f, t| {
            got = Some((f == &*frame, t.as_micros()))
        });
        assert_eq!(got, Some((true, 123_456)));
    }
}
