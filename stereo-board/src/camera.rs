//! The camera capture path's bookkeeping, hardware-free: which frames are whole, what went
//! wrong, when capture must be re-armed and when the camera has stopped.
//!
//! The firmware's DCMI and DMA interrupt handlers report events here and act on the answers;
//! the decisions are tested on the host.
//!
//! A frame is whole only if, at the DCMI's frame-end event, the DMA has moved exactly one
//! frame's words into the buffer it just left (transfer complete seen, counter reloaded to a full
//! frame) and neither the DCMI nor the DMA reported an error during it. Arrival alone proves
//! nothing: after one lost word every later DMA buffer would straddle two frames. Any other
//! frame end is torn: it is never processed, and capture is re-armed (DMA and DCMI stopped and
//! restarted), which re-aligns the next frame with the start of a DMA buffer.

use crate::board;
use protocol::CaptureCounts;
use timebase::Instant;

pub mod tcm8230;

/// 32-bit words the DMA moves per frame.
pub const FRAME_WORDS: u16 = (board::FRAME_BYTES / 4) as u16;
const _: () = assert!(board::FRAME_BYTES.is_multiple_of(4) && board::FRAME_BYTES / 4 < 65_536);

/// The DMA stream's state, read in the DCMI frame-end interrupt.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DmaAtFrameEnd {
    /// The stream's transfer-complete flag: it finished a buffer since the last frame end.
    pub transfer_complete: bool,
    /// Words still to move into the current buffer (NDTR).
    pub remaining_words: u16,
}

/// What the frame-end interrupt must do with the frame that just ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameEnd {
    /// The frame is whole: hand the buffer the DMA just left to the frame task.
    Deliver,
    /// The frame is torn: drop it and re-arm capture.
    Rearm,
}

/// Capture-path state of the camera board: counters and the last sign of life of the camera.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CaptureMonitor {
    counts: CaptureCounts,
    /// An error was reported since the last frame end: the frame in flight is bad.
    frame_bad: bool,
    /// Time of the last VSYNC, or of the start of capture.
    last_vsync: Instant,
    /// Number of VSYNC events since boot.
    vsyncs: u32,
}

impl Default for CaptureMonitor {
    fn default() -> Self {
        Self::new()
    }
}

impl CaptureMonitor {
    /// A monitor before capture starts (`const`, so the firmware can keep it in a `static`).
    pub const fn new() -> Self {
        Self {
            counts: CaptureCounts {
                frames_complete: 0,
                frames_torn: 0,
                dcmi_overruns: 0,
                dcmi_sync_errors: 0,
                dma_errors: 0,
                rearms: 0,
                frames_overwritten: 0,
            },
            frame_bad: false,
            last_vsync: Instant::ZERO,
            vsyncs: 0,
        }
    }

    /// Capture (re)starts at `now`: the camera has [`board::CAMERA_STOPPED_FRAMES`] frame
    /// periods from now to show a VSYNC. Frames already in flight are not trusted.
    pub fn on_capture_started(&mut self, now: Instant) {
        self.last_vsync = now;
        self.frame_bad = false;
    }

    /// The camera's VSYNC (start of vertical blanking) was seen at `now`.
    pub fn on_vsync(&mut self, now: Instant) {
        self.last_vsync = self.last_vsync.max(now);
        self.vsyncs = self.vsyncs.wrapping_add(1);
    }

    /// The DCMI reported an overrun: data of the frame in flight was lost.
    pub fn on_dcmi_overrun(&mut self) {
        self.counts.dcmi_overruns = self.counts.dcmi_overruns.saturating_add(1);
        self.frame_bad = true;
    }

    /// The DCMI reported a synchronisation error.
    pub fn on_dcmi_sync_error(&mut self) {
        self.counts.dcmi_sync_errors = self.counts.dcmi_sync_errors.saturating_add(1);
        self.frame_bad = true;
    }

    /// The camera's DMA stream reported a transfer, FIFO or direct-mode error.
    pub fn on_dma_error(&mut self) {
        self.counts.dma_errors = self.counts.dma_errors.saturating_add(1);
        self.frame_bad = true;
    }

    /// An error that stops the stream (a DMA transfer error disables it) needs a re-arm now,
    /// not at the next frame end (which may never come).
    pub fn frame_in_flight_is_bad(&self) -> bool {
        self.frame_bad
    }

    /// The DCMI's frame-end event, with the DMA's state read in the same interrupt.
    pub fn on_frame_end(&mut self, dma: DmaAtFrameEnd) -> FrameEnd {
        let whole = !self.frame_bad && dma.transfer_complete && dma.remaining_words == FRAME_WORDS;
        self.frame_bad = false;
        if whole {
            self.counts.frames_complete = self.counts.frames_complete.wrapping_add(1);
            FrameEnd::Deliver
        } else {
            self.counts.frames_torn = self.counts.frames_torn.saturating_add(1);
            FrameEnd::Rearm
        }
    }

    /// Capture was stopped and restarted (after a torn frame, an error, or a stopped camera).
    /// The frame in flight is abandoned; the camera's last sign of life stays what it was, so a
    /// dead camera stays reported however often capture is re-armed.
    pub fn on_rearm(&mut self) {
        self.counts.rearms = self.counts.rearms.saturating_add(1);
        self.frame_bad = false;
    }

    /// A delivered frame's buffer was being refilled before its processing ended.
    pub fn on_frame_overwritten(&mut self) {
        self.counts.frames_overwritten = self.counts.frames_overwritten.saturating_add(1);
    }

    /// True when no VSYNC came for [`board::CAMERA_STOPPED_FRAMES`] frame periods up to
    /// `now`.
    pub fn camera_stopped(&self, now: Instant) -> bool {
        let limit = board::FRAME_PERIOD.saturating_mul(u64::from(board::CAMERA_STOPPED_FRAMES));
        now.since(self.last_vsync) > limit
    }

    /// VSYNC events since boot (wrapping).
    pub fn vsyncs(&self) -> u32 {
        self.vsyncs
    }

    /// The counters since boot.
    pub fn counts(&self) -> CaptureCounts {
        self.counts
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const WHOLE: DmaAtFrameEnd = DmaAtFrameEnd {
        transfer_complete: true,
        remaining_words: FRAME_WORDS,
    };

    #[test]
    fn a_frame_is_whole_only_with_exactly_one_frame_of_words() {
        let mut m = CaptureMonitor::new();
        assert_eq!(m.on_frame_end(WHOLE), FrameEnd::Deliver);
        // Short frame: the DMA has not finished its buffer.
        let short = DmaAtFrameEnd {
            transfer_complete: false,
            remaining_words: 64,
        };
        assert_eq!(m.on_frame_end(short), FrameEnd::Rearm);
        // Misaligned: the buffer finished mid-frame, part of the next one is already in.
        let straddling = DmaAtFrameEnd {
            transfer_complete: true,
            remaining_words: FRAME_WORDS - 64,
        };
        assert_eq!(m.on_frame_end(straddling), FrameEnd::Rearm);
        let c = m.counts();
        assert_eq!((c.frames_complete, c.frames_torn), (1, 2));
    }

    #[test]
    fn an_error_during_a_frame_tears_it_even_if_the_count_matches() {
        for report in [
            CaptureMonitor::on_dcmi_overrun as fn(&mut CaptureMonitor),
            CaptureMonitor::on_dcmi_sync_error,
            CaptureMonitor::on_dma_error,
        ] {
            let mut m = CaptureMonitor::new();
            report(&mut m);
            assert!(m.frame_in_flight_is_bad());
            assert_eq!(m.on_frame_end(WHOLE), FrameEnd::Rearm);
            // The next frame is judged on its own.
            assert_eq!(m.on_frame_end(WHOLE), FrameEnd::Deliver);
        }
        let mut m = CaptureMonitor::new();
        m.on_dcmi_overrun();
        m.on_dcmi_sync_error();
        m.on_dma_error();
        m.on_rearm();
        m.on_frame_overwritten();
        let c = m.counts();
        assert_eq!(
            (
                c.dcmi_overruns,
                c.dcmi_sync_errors,
                c.dma_errors,
                c.rearms,
                c.frames_overwritten
            ),
            (1, 1, 1, 1, 1)
        );
        assert!(!m.frame_in_flight_is_bad(), "a re-arm starts a clean frame");
    }

    #[test]
    fn the_camera_is_stopped_after_five_frame_periods_without_vsync() {
        let period = board::FRAME_PERIOD.as_micros();
        let mut m = CaptureMonitor::new();
        m.on_capture_started(Instant::from_micros(1_000));
        assert!(!m.camera_stopped(Instant::from_micros(1_000 + 5 * period)));
        assert!(
            m.camera_stopped(Instant::from_micros(1_001 + 5 * period)),
            "never a VSYNC since start"
        );
        m.on_vsync(Instant::from_micros(10 * period));
        assert!(!m.camera_stopped(Instant::from_micros(14 * period)));
        assert!(m.camera_stopped(Instant::from_micros(15 * period + 1)));
        // A late-handled older VSYNC does not move the clock back.
        m.on_vsync(Instant::from_micros(9 * period));
        assert!(m.camera_stopped(Instant::from_micros(15 * period + 1)));
        assert_eq!(m.vsyncs(), 2);
        // Re-arming a dead camera does not make it look alive.
        m.on_rearm();
        assert!(m.camera_stopped(Instant::from_micros(15 * period + 2)));
    }
}
