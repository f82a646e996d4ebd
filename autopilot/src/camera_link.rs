//! The link from the camera board: its decoder and what the board last said about itself.
//!
//! Takes: the bytes from the camera-board UART ([`CameraLink::push`], any chunking) and each
//! decoded message with its arrival time ([`CameraLink::on_message`]). Keeps: the decoder's
//! error counters and the peer's protocol version, the last heartbeat, status report and
//! configuration answer, and the last answer to a parameter request passed on to the board
//! (until the host link takes it). Gives: the messages the rest of the autopilot acts on, as a
//! [`CameraNews`] (an estimate, or the report that the camera stopped).

use protocol::{
    Estimate, Heartbeat, LinkErrorCounts, ParamResponse, StereoStatus, StereoToAutopilot,
    StereoToAutopilotDecoder,
};
use timebase::Instant;

/// What a camera-board message asks of the rest of the autopilot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CameraNews {
    /// An Edge-FS estimate, for estimation and avoidance.
    Estimate(Estimate),
    /// The board's status reports its camera stopped: no estimates will come, fly as blind
    /// from now on instead of waiting out the estimate timeout.
    CameraStopped,
}

/// Decoder and last reports of the camera board.
#[derive(Debug, Clone)]
pub struct CameraLink {
    rx: StereoToAutopilotDecoder,
    heartbeat: Option<(Instant, Heartbeat)>,
    status: Option<StereoStatus>,
    param_reply: Option<ParamResponse>,
}

impl Default for CameraLink {
    fn default() -> Self {
        Self::new()
    }
}

impl CameraLink {
    /// Nothing received yet; the decoder starts mid-stream (the board may be sending already).
    pub fn new() -> Self {
        Self {
            rx: StereoToAutopilotDecoder::new_mid_stream(),
            heartbeat: None,
            status: None,
            param_reply: None,
        }
    }

    /// One received byte; the message it completes, if any (bad frames are counted in
    /// [`CameraLink::errors`]).
    pub fn push(&mut self, byte: u8) -> Option<StereoToAutopilot> {
        self.rx.push(byte)
    }

    /// One decoded message received at `now`: heartbeats, status reports, configuration and
    /// parameter answers are kept here; what the rest of the autopilot acts on is returned.
    pub fn on_message(&mut self, msg: StereoToAutopilot, now: Instant) -> Option<CameraNews> {
        match msg {
            StereoToAutopilot::Estimate(e) => return Some(CameraNews::Estimate(e)),
            StereoToAutopilot::Heartbeat(h) => self.heartbeat = Some((now, h)),
            StereoToAutopilot::Status(s) => {
                self.status = Some(s);
                if s.camera_stopped {
                    return Some(CameraNews::CameraStopped);
                }
            }
            StereoToAutopilot::Param(r) => self.param_reply = Some(r),
        }
        None
    }

    /// Errors decoding the board's bytes since boot.
    pub fn errors(&self) -> LinkErrorCounts {
        self.rx.errors()
    }

    /// The protocol version the board speaks, if it is not ours.
    pub fn peer_version_mismatch(&self) -> Option<u8> {
        self.rx.peer_version_mismatch()
    }

    /// The board's last heartbeat and when it arrived.
    pub fn heartbeat(&self) -> Option<(Instant, Heartbeat)> {
        self.heartbeat
    }

    /// The board's last status report.
    pub fn status(&self) -> Option<StereoStatus> {
        self.status
    }

    /// The board's latest answer to a parameter request, taken once.
    pub fn take_param_reply(&mut self) -> Option<ParamResponse> {
        self.param_reply.take()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::at;
    use crate::test_support::{camera_status as status, forward_estimate};
    use protocol::{Node, ParamError, ParamReply};

    #[test]
    fn reports_are_kept_and_only_estimates_and_a_stopped_camera_are_passed_on() {
        let mut link = CameraLink::new();
        let hb = Heartbeat::new(Node::StereoBoard, 1_000);
        assert_eq!(
            link.on_message(StereoToAutopilot::Heartbeat(hb), at(7)),
            None
        );
        assert_eq!(link.heartbeat(), Some((at(7), hb)));
        assert_eq!(
            link.on_message(StereoToAutopilot::Status(status(false)), at(8)),
            None
        );
        assert_eq!(
            link.on_message(StereoToAutopilot::Status(status(true)), at(9)),
            Some(CameraNews::CameraStopped)
        );
        assert_eq!(link.status(), Some(status(true)));
        let reply = ParamResponse {
            board: Node::StereoBoard,
            reply: ParamReply::Error(ParamError::Armed),
        };
        assert_eq!(
            link.on_message(StereoToAutopilot::Param(reply.clone()), at(10)),
            None
        );
        assert_eq!(link.take_param_reply(), Some(reply));
        assert_eq!(link.take_param_reply(), None, "taken once");
        let est = Estimate {
            seq: 3,
            ..forward_estimate(0.1)
        };
        assert_eq!(
            link.on_message(StereoToAutopilot::Estimate(est), at(11)),
            Some(CameraNews::Estimate(est))
        );
    }
}
