//! The two boards as the simulator runs them: each board's task table turned into scheduler
//! tasks, and the task bodies, which call the boards' own libraries.
//!
//! * Autopilot: `autopilot::app::Autopilot` and `autopilot::app::TASKS`. The `stereo_rx` task
//!   decodes the UART bytes with `protocol::Decoder` and hands each estimate to
//!   `Autopilot::on_estimate` (the same as the firmware's task body).
//! * Camera board: [`CameraBoard`] below. TEMPORARY ADAPTER: the camera board's task logic and
//!   table belong in `stereo_board::app` (being written concurrently); until it is there this
//!   module holds an equivalent minimal shell around `stereo_board::edge_fs::EdgeFs` (frame ->
//!   `Estimate` frame bytes; `GyroAttitude` bytes in for derotation; status + heartbeat).

use super::sched::{Board, SimTask};
use protocol::{
    encode, AutopilotToStereo, Decoder, Estimate, GyroAttitude, Heartbeat, Message, Node,
    StereoStatus, StereoToAutopilot, STEREO_FRAME_BYTES,
};
use stereo_board::edge_fs::{EdgeFs, EdgeFsParams};

/// Scheduler tasks from the autopilot's table (`autopilot::app::TASKS`).
pub fn autopilot_tasks() -> Vec<SimTask> {
    autopilot::app::TASKS
        .iter()
        .map(|t| SimTask {
            board: Board::Autopilot,
            name: t.name,
            priority: t.priority,
            period_us: match t.trigger {
                autopilot::app::Trigger::Periodic { period_us } => Some(period_us),
                autopilot::app::Trigger::Event(_) => None,
            },
        })
        .collect()
}

/// Camera-board task table (temporary, mirrors what `stereo_board::app` will declare).
pub const CAMERA_TASKS: &[(&str, u8, Option<u32>)] = &[
    ("frame", 2, None),
    ("uart_rx", 3, None),
    ("status", 1, Some(1_000_000)),
];

/// Scheduler tasks of the camera board.
pub fn camera_tasks() -> Vec<SimTask> {
    CAMERA_TASKS
        .iter()
        .map(|&(name, priority, period_us)| SimTask {
            board: Board::Stereo,
            name,
            priority,
            period_us,
        })
        .collect()
}

/// Largest autopilot-to-camera frame.
const A2S_N: usize = AutopilotToStereo::MAX_FRAME_BYTES;

/// Minimal camera-board task logic (temporary adapter, see the module docs).
pub struct CameraBoard {
    edge_fs: Box<EdgeFs>,
    rx: Decoder<AutopilotToStereo, A2S_N>,
    gyro: Option<GyroAttitude>,
    seq: u16,
    frames_processed: u32,
    frames_dropped: u32,
    max_processing_us: u32,
    last_status_frames: u32,
}

impl CameraBoard {
    /// A camera board running Edge-FS with `params`.
    pub fn new(params: EdgeFsParams) -> Self {
        Self {
            edge_fs: Box::new(EdgeFs::new(params)),
            rx: Decoder::new(),
            gyro: None,
            seq: 0,
            frames_processed: 0,
            frames_dropped: 0,
            max_processing_us: 0,
            last_status_frames: 0,
        }
    }

    /// Frame task: one interleaved frame exposed at `capture_us`, processed until `now_us`;
    /// the encoded `Estimate` goes to `tx`. Returns the estimate (for the simulator's log).
    pub fn on_frame(
        &mut self,
        frame: &[u8; STEREO_FRAME_BYTES],
        capture_us: u64,
        now_us: u64,
        tx: &mut impl FnMut(&[u8]),
    ) -> Estimate {
        let out = self.edge_fs.process(frame, capture_us, self.gyro.as_ref());
        let processing_us = now_us.saturating_sub(capture_us).min(u16::MAX as u64) as u16;
        self.max_processing_us = self.max_processing_us.max(processing_us as u32);
        let est = Estimate {
            seq: self.seq,
            capture_us: capture_us as u32,
            forward_mps: out.forward_mps,
            sideways_mps: out.sideways_mps,
            obstacle_m: out.obstacle_m,
            quality: out.quality,
            flags: out.flags,
            processing_us,
        };
        self.seq = self.seq.wrapping_add(1);
        self.frames_processed = self.frames_processed.wrapping_add(1);
        send(&StereoToAutopilot::Estimate(est), tx);
        est
    }

    /// A frame the board had no time for.
    pub fn frame_dropped(&mut self) {
        self.frames_dropped = self.frames_dropped.wrapping_add(1);
    }

    /// UART RX task: bytes from the autopilot.
    pub fn on_rx_bytes(&mut self, bytes: &[u8], _now_us: u64) {
        let gyro = &mut self.gyro;
        self.rx.feed(bytes, |m| {
            if let AutopilotToStereo::GyroAttitude(g) = m {
                *gyro = Some(g);
            }
        });
    }

    /// Status task (1 Hz): status and heartbeat.
    pub fn status_tick(&mut self, now_us: u64, tx: &mut impl FnMut(&[u8])) {
        let rate = self.frames_processed.wrapping_sub(self.last_status_frames) as f32;
        self.last_status_frames = self.frames_processed;
        let uptime_ms = (now_us / 1000) as u32;
        send(
            &StereoToAutopilot::Status(StereoStatus {
                uptime_ms,
                frame_rate_hz: rate,
                frames_processed: self.frames_processed,
                frames_dropped: self.frames_dropped,
                link_errors: self.rx.errors(),
                max_processing_us: self.max_processing_us,
            }),
            tx,
        );
        self.max_processing_us = 0;
        send(
            &StereoToAutopilot::Heartbeat(Heartbeat::new(Node::StereoBoard, uptime_ms)),
            tx,
        );
    }

    /// Frames dropped so far.
    pub fn frames_dropped(&self) -> u32 {
        self.frames_dropped
    }
}

/// Encodes one message and hands the frame bytes to `tx`.
pub fn send<M: Message>(msg: &M, tx: &mut impl FnMut(&[u8])) {
    let mut buf = [0u8; 640];
    if let Ok(n) = encode(msg, &mut buf) {
        tx(&buf[..n]);
    }
}
