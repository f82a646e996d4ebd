//! The camera board's task logic and task table, hardware-free.
//!
//! The RTIC firmware and `sim-host` call exactly these functions; every task body of the
//! firmware is one call in here. Time is passed in (a [`timebase::Instant`] of the board's
//! monotonic clock, or in the lockstep flavours the world's time as the flight clock); bytes go
//! out through a caller-provided `tx` closure that receives whole encoded frames.
//!
//! | task | trigger | priority | body |
//! |---|---|---|---|
//! | `uart_rx` | bytes from the autopilot link UART (RXNE interrupt, queued) | 3 | [`StereoBoardApp::on_rx_bytes`] |
//! | `host_rx` | bytes from the host UART (RXNE interrupt, queued; HIL and QEMU flavours) | 3 | [`StereoBoardApp::on_host_bytes`] |
//! | `frame` | camera frame complete (DCMI + DMA2) or a HIL frame assembled | 2 | [`StereoBoardApp::on_frame`] |
//! | `status` | every [`STATUS_PERIOD`] | 1 | [`StereoBoardApp::status_tick`] |
//!
//! Each task is one method, called alike by the firmware, the simulator and the software HIL
//! board; it does the task's whole work and hands what the task sends to the caller's `tx`
//! closures (the autopilot link, and the host link where the task has something for it). The
//! simulator alone runs the frame task in its two halves, [`StereoBoardApp::process_frame`]
//! and [`StereoBoardApp::send_estimate`], with the modelled processing time between them
//! (other tasks run meanwhile, as the board's time passes).
//!
//! The receive tasks run above the frame task: they are short, and the autopilot's gyro
//! samples must keep flowing while Edge-FS runs for tens of milliseconds.

use crate::edge_fs::{EdgeFs, EdgeFsOutput, EdgeFsParams};
use protocol::params::{ParamStorage, RecordError, RecordStore, StorageStatus};
use protocol::{
    encode, AutopilotToStereo, BoardToHost, CaptureCounts, Decoder, Estimate, FrameChunk,
    GyroAttitude, Heartbeat, HostToBoard, LinkErrorCounts, Message, Node, ParamRequest,
    ParamResponse, StereoStatus, StereoToAutopilot, FRAME_CHUNK_BYTES, STEREO_FRAME_BYTES,
};
use timebase::{Duration, Instant, WireTime, WorldTime, WrapExtender};

pub use task_table::{TaskId, TaskSpec, Trigger};

/// Period of the status task (Status + Heartbeat to the autopilot).
pub const STATUS_PERIOD: Duration = Duration::from_secs(1);
/// Frame period of the camera (25 fps, [`crate::board::FRAME_PERIOD`]): the frame task's
/// deadline.
pub const FRAME_PERIOD: Duration = crate::board::FRAME_PERIOD;
/// Microseconds per second: the status task's frame rate from its interval.
const US_PER_S: f64 = 1e6;
/// A gyro/attitude sample older than this is not used for derotation.
pub const GYRO_TIMEOUT: Duration = Duration::from_millis(100);

/// The camera board's tasks, in [`TASKS`]'s order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Task {
    /// Bytes from the autopilot.
    UartRx,
    /// Bytes from the host (HIL and QEMU flavours).
    HostRx,
    /// A whole stereo frame: Edge-FS and the estimate to the autopilot.
    Frame,
    /// 1 Hz: status and heartbeat to the autopilot.
    Status,
}

impl TaskId for Task {
    const ALL: &'static [Task] = &[Task::UartRx, Task::HostRx, Task::Frame, Task::Status];
    const TABLE: &'static [TaskSpec<Task>] = TASKS;

    fn index(self) -> usize {
        self as usize
    }
}

/// The camera board's tasks; the RTIC app in `src/firmware` mirrors this table.
pub const TASKS: &[TaskSpec<Task>] = &[
    TaskSpec {
        id: Task::UartRx,
        name: "uart_rx",
        priority: 3,
        trigger: Trigger::Event("bytes from the autopilot link (UART4; USART1 in QEMU), RXNE"),
        deadline: Duration::from_millis(2),
    },
    TaskSpec {
        id: Task::HostRx,
        name: "host_rx",
        priority: 3,
        trigger: Trigger::Event("bytes from the host link (USART2), RXNE; HIL/QEMU flavours"),
        deadline: Duration::from_millis(2),
    },
    TaskSpec {
        id: Task::Frame,
        name: "frame",
        priority: 2,
        trigger: Trigger::Event("frame complete: DCMI + DMA2 stream 1, or HIL frame assembled"),
        deadline: FRAME_PERIOD,
    },
    TaskSpec {
        id: Task::Status,
        name: "status",
        priority: 1,
        trigger: Trigger::Periodic {
            period: STATUS_PERIOD,
        },
        deadline: Duration::from_millis(100),
    },
];

/// Receive buffer of the autopilot link decoder, bytes.
const A2S_N: usize = AutopilotToStereo::MAX_FRAME_BYTES;
/// Receive buffer of the host link decoder, bytes.
const H2B_N: usize = HostToBoard::MAX_FRAME_BYTES;
/// Chunks in one frame.
const CHUNKS_PER_FRAME: usize = STEREO_FRAME_BYTES.div_ceil(FRAME_CHUNK_BYTES);

/// Encodes `msg` into one frame and hands it to `tx`; returns false when it did not fit (never
/// for the message types of this crate: their buffers are sized from `MAX_FRAME_BYTES`).
fn send<M: Message, const N: usize>(msg: &M, tx: &mut impl FnMut(&[u8])) -> bool {
    let mut buf = [0u8; N];
    match encode(msg, &mut buf) {
        Ok(n) => match buf.get(..n) {
            Some(bytes) => {
                tx(bytes);
                true
            }
            None => false,
        },
        Err(_) => false,
    }
}

/// Encodes a message to the autopilot and hands the frame to `tx`.
pub fn send_to_autopilot(msg: &StereoToAutopilot, tx: &mut impl FnMut(&[u8])) -> bool {
    send::<_, { StereoToAutopilot::MAX_FRAME_BYTES }>(msg, tx)
}

/// Encodes a message to the host (HIL bridge, ground tool) and hands the frame to `tx`.
pub fn send_to_host(msg: &BoardToHost, tx: &mut impl FnMut(&[u8])) -> bool {
    send::<_, { BoardToHost::MAX_FRAME_BYTES }>(msg, tx)
}

/// Assembles a stereo frame from [`FrameChunk`]s (HIL: frames arrive over the serial link).
///
/// Chunks must start at a multiple of [`FRAME_CHUNK_BYTES`] and fill their slot exactly (the
/// frame is 48 full chunks); anything else is rejected and counted. A chunk of another frame
/// abandons an incomplete frame, which is counted as dropped. Bounded, never panics.
#[derive(Clone)]
pub struct FrameAssembler {
    buf: [u8; STEREO_FRAME_BYTES],
    frame_id: u16,
    capture_time: WireTime,
    /// Bit i: chunk i received.
    have: u64,
    active: bool,
    complete: u32,
    incomplete: u32,
    bad_chunks: u32,
}

impl Default for FrameAssembler {
    fn default() -> Self {
        Self::new()
    }
}

impl core::fmt::Debug for FrameAssembler {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("FrameAssembler")
            .field("frame_id", &self.frame_id)
            .field("have", &self.have)
            .field("active", &self.active)
            .field("complete", &self.complete)
            .field("incomplete", &self.incomplete)
            .field("bad_chunks", &self.bad_chunks)
            .finish()
    }
}

impl FrameAssembler {
    const ALL: u64 = if CHUNKS_PER_FRAME >= 64 {
        u64::MAX
    } else {
        (1u64 << CHUNKS_PER_FRAME) - 1
    };

    /// An empty assembler (`const`, so it can be a `static`).
    pub const fn new() -> Self {
        Self {
            buf: [0; STEREO_FRAME_BYTES],
            frame_id: 0,
            capture_time: WireTime(0),
            have: 0,
            active: false,
            complete: 0,
            incomplete: 0,
            bad_chunks: 0,
        }
    }

    /// Takes one chunk. Returns `Some(capture_time)` (the host's exposure time) when it completes
    /// the frame; the frame is then in [`FrameAssembler::frame`] until the next chunk arrives.
    pub fn push(&mut self, chunk: &FrameChunk) -> Option<WireTime> {
        let offset = usize::from(chunk.offset);
        let index = offset / FRAME_CHUNK_BYTES;
        let expected_len = STEREO_FRAME_BYTES
            .saturating_sub(offset)
            .min(FRAME_CHUNK_BYTES);
        if offset % FRAME_CHUNK_BYTES != 0
            || index >= CHUNKS_PER_FRAME
            || chunk.data.len() != expected_len
        {
            self.bad_chunks = self.bad_chunks.saturating_add(1);
            return None;
        }
        if self.active && chunk.frame_id != self.frame_id {
            self.incomplete = self.incomplete.saturating_add(1);
            self.active = false;
        }
        if !self.active {
            self.active = true;
            self.frame_id = chunk.frame_id;
            self.capture_time = chunk.capture_us;
            self.have = 0;
        }
        let slot = self.buf.get_mut(offset..offset + expected_len)?;
        slot.copy_from_slice(&chunk.data);
        self.have |= 1 << index;
        if self.have == Self::ALL {
            self.active = false;
            self.complete = self.complete.saturating_add(1);
            Some(self.capture_time)
        } else {
            None
        }
    }

    /// The frame buffer (complete right after [`FrameAssembler::push`] returned `Some`).
    pub fn frame(&self) -> &[u8; STEREO_FRAME_BYTES] {
        &self.buf
    }

    /// Frame number of the frame being (or last) assembled.
    pub fn frame_id(&self) -> u16 {
        self.frame_id
    }

    /// Frames completed since creation.
    pub fn frames_complete(&self) -> u32 {
        self.complete
    }

    /// Frames abandoned incomplete since creation.
    pub fn frames_incomplete(&self) -> u32 {
        self.incomplete
    }

    /// Chunks rejected (bad offset or length) since creation.
    pub fn bad_chunks(&self) -> u32 {
        self.bad_chunks
    }
}

/// Counters of the camera board, as reported in [`StereoStatus`] (and a few more).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    /// Frames processed since boot.
    pub frames_processed: u32,
    /// Frames dropped since boot: camera overruns, frames arriving while busy, incomplete HIL
    /// frames.
    pub frames_dropped: u32,
    /// Gyro samples ignored because a value was NaN or infinite.
    pub gyro_rejected: u32,
}

/// A frame for the frame task ([`StereoBoardApp::on_frame`]).
#[derive(Clone, Copy)]
pub struct StereoFrame<'a> {
    /// The interleaved stereo frame (`[L0 R0 L1 R1 ...]`).
    pub pixels: &'a [u8; STEREO_FRAME_BYTES],
    /// Its exposure time.
    pub capture: Instant,
    /// When processing starts: picks the gyro sample ([`StereoBoardApp::current_gyro`]).
    pub start: Instant,
}

/// What the frame task did ([`StereoBoardApp::on_frame`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FrameOutcome {
    /// There was no frame to process.
    NoFrame,
    /// The estimate sent to the autopilot (and mirrored to the host).
    Sent(Estimate),
    /// The frame was refilled while it was processed: nothing was sent, the flow history is
    /// cleared and the frame counts as dropped.
    Discarded,
}

impl FrameOutcome {
    /// The estimate sent, if one was.
    pub fn estimate(self) -> Option<Estimate> {
        match self {
            FrameOutcome::Sent(est) => Some(est),
            FrameOutcome::NoFrame | FrameOutcome::Discarded => None,
        }
    }
}

/// The whole camera-board state: Edge-FS, link decoders, latest gyro sample, counters.
///
/// Fixed size, no heap (about 10 kB); `const fn new`, so the firmware keeps it in a `static`
/// in CCM. Frame buffers are not in here (DMA targets live in SRAM).
pub struct StereoBoardApp {
    edge_fs: EdgeFs,
    params: EdgeFsParams,
    rx: Decoder<AutopilotToStereo, A2S_N>,
    host_rx: Decoder<HostToBoard, H2B_N>,
    host_clock: WrapExtender<WorldTime>,
    gyro: Option<(GyroAttitude, Instant)>,
    peer_uptime_ms: Option<u32>,
    seq: u16,
    counters: Counters,
    last_status: Instant,
    last_status_frames: u32,
    max_processing_us: u32,
    capture: CaptureCounts,
    camera_stopped: bool,
    /// The parameter storage's state (`None`: no storage, [`StereoBoardApp::new`] alone).
    storage: Option<StorageStatus>,
}

impl StereoBoardApp {
    /// A board running Edge-FS with `params`.
    pub const fn new(params: EdgeFsParams) -> Self {
        Self {
            edge_fs: EdgeFs::new(params),
            params,
            rx: Decoder::new_mid_stream(),
            host_rx: Decoder::new_mid_stream(),
            host_clock: WrapExtender::new(),
            gyro: None,
            peer_uptime_ms: None,
            seq: 0,
            counters: Counters {
                frames_processed: 0,
                frames_dropped: 0,
                gyro_rejected: 0,
            },
            last_status: Instant::ZERO,
            last_status_frames: 0,
            max_processing_us: 0,
            capture: CaptureCounts {
                frames_complete: 0,
                frames_torn: 0,
                dcmi_overruns: 0,
                dcmi_sync_errors: 0,
                dma_errors: 0,
                rearms: 0,
                frames_overwritten: 0,
            },
            camera_stopped: false,
            storage: None,
        }
    }

    /// Boot with parameter storage: the Edge-FS parameters saved in `store`
    /// ([`crate::params::CAMERA`]'s record) when the record is good, otherwise the defaults;
    /// why is kept for [`protocol::ParamOp::Storage`] and returned (`Err`: the defaults are in
    /// use). Saves then go to the store given to [`StereoBoardApp::on_rx_bytes`].
    pub fn load_params(&mut self, store: &dyn RecordStore) -> Result<(), RecordError> {
        let (params, status) = crate::params::CAMERA.load(store);
        self.set_params(params);
        self.storage = Some(status);
        status.loaded
    }

    /// The parameter storage's state (`None`: no storage was loaded).
    pub fn storage(&self) -> Option<StorageStatus> {
        self.storage
    }

    /// The Edge-FS parameters in use.
    pub fn params(&self) -> &EdgeFsParams {
        &self.params
    }

    /// The estimator (for diagnostics).
    pub fn edge_fs(&self) -> &EdgeFs {
        &self.edge_fs
    }

    /// Counters since boot.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// Errors decoding autopilot messages since boot.
    pub fn link_errors(&self) -> LinkErrorCounts {
        self.rx.errors()
    }

    /// Errors decoding host messages since boot.
    pub fn host_link_errors(&self) -> LinkErrorCounts {
        self.host_rx.errors()
    }

    /// Valid messages received from the autopilot since boot (wrapping).
    pub fn link_frames_ok(&self) -> u32 {
        self.rx.frames_ok()
    }

    /// The autopilot's uptime in its last heartbeat, ms.
    pub fn peer_uptime_ms(&self) -> Option<u32> {
        self.peer_uptime_ms
    }

    /// The gyro sample used for a frame processed at `now`: the latest one, if it arrived
    /// within [`GYRO_TIMEOUT`].
    pub fn current_gyro(&self, now: Instant) -> Option<&GyroAttitude> {
        match &self.gyro {
            Some((g, at)) if now.since(*at) <= GYRO_TIMEOUT => Some(g),
            _ => None,
        }
    }

    /// The latest gyro/attitude sample from the autopilot, whatever its age. In the HIL
    /// flavours its timestamp is the world time of the host's simulation (see the firmware's
    /// clock).
    pub fn latest_gyro(&self) -> Option<&GyroAttitude> {
        self.gyro.as_ref().map(|(g, _)| g)
    }

    /// Frame task, first half (for a caller that models the processing time, the simulator;
    /// [`StereoBoardApp::on_frame`] is the whole task): runs Edge-FS on one interleaved frame
    /// exposed at `capture` (`now`: when processing starts, to pick the gyro sample).
    pub fn process_frame(
        &mut self,
        frame: &[u8; STEREO_FRAME_BYTES],
        capture: Instant,
        now: Instant,
    ) -> EdgeFsOutput {
        let gyro = self.current_gyro(now).copied();
        self.edge_fs.process(frame, capture, gyro.as_ref())
    }

    /// Frame task, second half (see [`StereoBoardApp::process_frame`]): wraps `out` into the
    /// next [`Estimate`] (processing time = `done - capture`, saturating at the wire's
    /// 65,535 µs) and sends it to the autopilot.
    pub fn send_estimate(
        &mut self,
        out: &EdgeFsOutput,
        capture: Instant,
        done: Instant,
        tx: &mut impl FnMut(&[u8]),
    ) -> Estimate {
        let processing = done.since(capture).as_micros();
        let processing_us = u16::try_from(processing).unwrap_or(u16::MAX);
        self.max_processing_us = self
            .max_processing_us
            .max(u32::try_from(processing).unwrap_or(u32::MAX));
        let est = Estimate {
            seq: self.seq,
            // The wire carries the wrapping low 32 bits.
            capture_us: capture.to_wire(),
            forward_mps: out.forward_mps,
            sideways_mps: out.sideways_mps,
            obstacle_m: out.obstacle_m,
            quality: out.quality,
            flags: out.flags,
            processing_us,
            depth_coverage: out.depth_coverage,
            near_columns: out.near_columns,
            fit: out.fit,
            up_mps: out.up_mps,
            up_flags: out.up_flags,
            fit_r2: out.fit_r2,
            divergence: out.divergence,
        };
        self.seq = self.seq.wrapping_add(1);
        self.counters.frames_processed = self.counters.frames_processed.wrapping_add(1);
        send_to_autopilot(&StereoToAutopilot::Estimate(est), tx);
        est
    }

    /// `frame` task: counts the `lost` frames (ended while the task was busy), then runs
    /// Edge-FS on `frame`, if there is one, and asks `finish` whether the frame stayed intact
    /// while it was processed (`Some(now)`: intact, processing done at `now`; `None`: its
    /// buffer was refilled meanwhile). An intact frame's [`Estimate`] goes to the autopilot
    /// (`to_autopilot`) and is mirrored to the host (`to_host`); processing time =
    /// done - capture, saturating at the wire's 65,535 µs. A refilled frame sends nothing,
    /// clears the flow history and counts as dropped.
    pub fn on_frame(
        &mut self,
        lost: u32,
        frame: Option<StereoFrame<'_>>,
        finish: impl FnOnce() -> Option<Instant>,
        to_autopilot: &mut impl FnMut(&[u8]),
        to_host: &mut impl FnMut(&[u8]),
    ) -> FrameOutcome {
        for _ in 0..lost {
            self.frame_dropped();
        }
        let Some(frame) = frame else {
            return FrameOutcome::NoFrame;
        };
        let out = self.process_frame(frame.pixels, frame.capture, frame.start);
        let Some(done) = finish() else {
            self.discard_processed_frame();
            return FrameOutcome::Discarded;
        };
        let est = self.send_estimate(&out, frame.capture, done, to_autopilot);
        send_to_host(&BoardToHost::Estimate(est), to_host);
        FrameOutcome::Sent(est)
    }

    /// A frame the board could not process (camera overrun, still busy with the previous one).
    pub fn frame_dropped(&mut self) {
        self.counters.frames_dropped = self.counters.frames_dropped.saturating_add(1);
    }

    /// The frame just processed was not intact (its buffer was being refilled before
    /// processing ended): the flow history (which now holds that frame) is cleared and the
    /// frame counts as dropped.
    fn discard_processed_frame(&mut self) {
        self.edge_fs.reset();
        self.frame_dropped();
    }

    /// `uart_rx` task: bytes from the autopilot, as they arrive. Gyro/attitude samples are kept
    /// for derotation (non-finite ones are rejected and counted); a parameter request is
    /// answered through `tx` ([`StereoBoardApp::on_param_request`], saving to `store` on a
    /// board with parameter storage); heartbeats record the peer's uptime.
    pub fn on_rx_bytes(
        &mut self,
        bytes: &[u8],
        now: Instant,
        tx: &mut impl FnMut(&[u8]),
        store: Option<&mut dyn RecordStore>,
    ) {
        self.rx_bytes(bytes, now, tx, store);
    }

    fn rx_bytes(
        &mut self,
        bytes: &[u8],
        now: Instant,
        tx: &mut impl FnMut(&[u8]),
        mut store: Option<&mut (dyn RecordStore + '_)>,
    ) {
        for &byte in bytes {
            if let Some(msg) = self.rx.push(byte) {
                self.handle_autopilot(msg, now, tx, store.as_deref_mut());
            }
        }
    }

    fn handle_autopilot(
        &mut self,
        msg: AutopilotToStereo,
        now: Instant,
        tx: &mut impl FnMut(&[u8]),
        store: Option<&mut (dyn RecordStore + '_)>,
    ) {
        match msg {
            AutopilotToStereo::Heartbeat(hb) => self.peer_uptime_ms = Some(hb.uptime_ms),
            AutopilotToStereo::GyroAttitude(g) => {
                let finite = g
                    .rates_radps
                    .iter()
                    .chain(g.attitude_rad.iter())
                    .all(|v| v.is_finite());
                if finite {
                    self.gyro = Some((g, now));
                } else {
                    self.counters.gyro_rejected = self.counters.gyro_rejected.saturating_add(1);
                }
            }
            AutopilotToStereo::Param(req) => {
                let answer = self.answer_param(&req, store);
                send_to_autopilot(&StereoToAutopilot::Param(answer), tx);
            }
        }
    }

    /// Answers a parameter request for this board's table ([`crate::params::TABLE`]), passed
    /// on by the autopilot from the host. A set takes effect from the next frame on and clears
    /// the flow history. A request for another board's table is refused (`NoSuchBoard`).
    ///
    /// `store` is the board's parameter storage, `None` on a board without one, where `Save`
    /// and `Storage` are answered `NoStorage`. With one, `Save` writes the record of the
    /// parameters in use and reads it back, and a failure of either is `SaveFailed`. The write
    /// holds the board for the flash's erase (a second or two for a 128 KiB sector: no frame is
    /// processed meanwhile); the autopilot passes a save on only while its motors are off.
    /// `Storage` is answered once [`StereoBoardApp::load_params`] ran.
    pub fn on_param_request(
        &mut self,
        req: &ParamRequest,
        store: Option<&mut dyn RecordStore>,
    ) -> ParamResponse {
        self.answer_param(req, store)
    }

    fn answer_param(
        &mut self,
        req: &ParamRequest,
        store: Option<&mut (dyn RecordStore + '_)>,
    ) -> ParamResponse {
        let current = self.params;
        // The status is counted on a copy, so that `set_params` can borrow the board.
        let mut status = self.storage;
        let storage = ParamStorage::of(store, status.as_mut());
        let apply = |next| {
            self.set_params(next);
            Ok(())
        };
        let response =
            crate::params::CAMERA.respond(Node::StereoBoard, req, &current, apply, storage);
        self.storage = status;
        response
    }

    /// Makes `params` Edge-FS's from the next frame on (the flow history restarts). The caller
    /// checks them ([`crate::params::CAMERA`]'s `validate`); out-of-range values are clamped.
    pub fn set_params(&mut self, params: EdgeFsParams) {
        self.params = params;
        self.edge_fs.set_params(params);
    }

    /// `host_rx` task (HIL and QEMU flavours): bytes from the host. Frame chunks are assembled
    /// in `frames`; each completed frame is handed to `on_frame_ready` with its exposure time:
    /// the host's world time (its wrapping wire clock, unwrapped) as the flight clock, which is
    /// what the lockstep flavours run on. `on_frame_ready` returns true when the frame replaced
    /// one not processed yet, which counts as dropped, as do frames abandoned incomplete.
    /// Other host messages are ignored by the camera board.
    pub fn on_host_bytes(
        &mut self,
        bytes: &[u8],
        frames: &mut FrameAssembler,
        mut on_frame_ready: impl FnMut(&[u8; STEREO_FRAME_BYTES], Instant) -> bool,
    ) {
        for &byte in bytes {
            if let Some(HostToBoard::FrameChunk(chunk)) = self.host_rx.push(byte) {
                let before = frames.frames_incomplete();
                let done = frames.push(&chunk);
                let lost = frames.frames_incomplete().wrapping_sub(before);
                self.counters.frames_dropped = self.counters.frames_dropped.saturating_add(lost);
                if let Some(capture) = done {
                    let capture = self.host_clock.extend(capture).as_flight_clock();
                    if on_frame_ready(frames.frame(), capture) {
                        self.frame_dropped();
                    }
                }
            }
        }
    }

    /// `status` task: takes the capture path's state (`capture`: its counts and whether the
    /// camera stopped, as the firmware's DCMI bookkeeping [`crate::camera::CaptureMonitor`]
    /// tells them; `None`: no camera, the last state stands), sends [`StereoStatus`] and a
    /// [`Heartbeat`] to the autopilot (`to_autopilot`) and a heartbeat to the host (`to_host`:
    /// a HIL host starts streaming once it sees one). The frame rate is over the time since
    /// the previous call (or since boot); the worst processing time restarts with each
    /// interval.
    pub fn status_tick(
        &mut self,
        now: Instant,
        capture: Option<(CaptureCounts, bool)>,
        to_autopilot: &mut impl FnMut(&[u8]),
        to_host: &mut impl FnMut(&[u8]),
    ) -> StereoStatus {
        if let Some((counts, stopped)) = capture {
            self.capture = counts;
            self.camera_stopped = stopped;
        }
        let interval_us = now.since(self.last_status).as_micros();
        let frames = self
            .counters
            .frames_processed
            .wrapping_sub(self.last_status_frames);
        let frame_rate_hz = if interval_us > 0 {
            (f64::from(frames) * US_PER_S / interval_us as f64) as f32
        } else {
            0.0
        };
        self.last_status = now;
        self.last_status_frames = self.counters.frames_processed;
        // Uptime in ms wraps with the u32 on the wire (after 49 days).
        let uptime_ms = now.since(Instant::ZERO).as_millis() as u32;
        let status = StereoStatus {
            uptime_ms,
            frame_rate_hz,
            frames_processed: self.counters.frames_processed,
            frames_dropped: self.counters.frames_dropped,
            link_errors: self.rx.errors(),
            max_processing_us: self.max_processing_us,
            capture: self.capture,
            camera_stopped: self.camera_stopped,
        };
        self.max_processing_us = 0;
        let heartbeat = Heartbeat::new(Node::StereoBoard, uptime_ms);
        send_to_autopilot(&StereoToAutopilot::Status(status), to_autopilot);
        send_to_autopilot(&StereoToAutopilot::Heartbeat(heartbeat), to_autopilot);
        send_to_host(&BoardToHost::Heartbeat(heartbeat), to_host);
        status
    }

    /// Time since the last gyro sample arrived, if any (for status displays).
    pub fn gyro_age(&self, now: Instant) -> Option<Duration> {
        self.gyro.as_ref().map(|(_, at)| now.since(*at))
    }
}

#[cfg(test)]
mod tests;
