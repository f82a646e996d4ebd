//! The autopilot's one entry point for host messages: the firmware's `host_rx` task, the
//! simulator and every hardware-in-the-loop board hand each decoded [`HostToBoard`] to
//! [`Autopilot::on_host_message`], so that all of them treat a message alike.
//!
//! An IMU sample is the one message whose handling depends on where the autopilot runs: it
//! carries the host's world time, and only a lockstep flavour (simulator, HIL) may run its
//! control loop on it. It is therefore handed back as [`HostOutcome::Imu`]; a board with its
//! own IMU refuses it and counts the refusal (the firmware's real flavour does).
//!
//! Every message passes [`crate::link_auth::LinkAuth::admit`] first: once a link key is set, a command that is
//! not signed with it is refused and counted ([`crate::link_auth`]).

use protocol::params::{KeySaveError, RecordStore};
use protocol::signing::KeyRecord;
use protocol::{
    AutopilotToStereo, BoardToHost, HostToBoard, ImuSample, Node, ParamError, ParamOp, ParamReply,
    ParamResponse,
};

use crate::Autopilot;
use timebase::Instant;

/// What the caller does after [`Autopilot::on_host_message`].
#[derive(Debug, Clone, PartialEq)]
pub enum HostOutcome {
    /// Handled (or not for this board); nothing to send.
    Done,
    /// Handled; send this answer to the host.
    Reply(BoardToHost),
    /// A request for the camera board: send this to it over the board-to-board link (its
    /// answer comes back through [`Autopilot::take_camera_param_reply`]).
    ToCamera(AutopilotToStereo),
    /// An IMU sample from the host: a lockstep caller runs the control loop on it at the
    /// world time it carries; a board with its own IMU refuses and counts it.
    Imu(ImuSample),
}

impl Autopilot {
    /// Handles one message from the host at board time `now`: a height / position fix, a
    /// pilot command, a parameter request (answered by [`Autopilot::on_param_request`] with
    /// `store`, the board's parameter storage or `None`; one for the camera board's table is
    /// passed on to it, except a set or save while the motors may run, which is refused here).
    /// A host heartbeat keeps the telemetry link alive ([`Autopilot::on_host_heartbeat`]);
    /// frame chunks are for the camera board and dropped here.
    pub fn on_host_message(
        &mut self,
        msg: HostToBoard,
        now: Instant,
        store: Option<&mut dyn RecordStore>,
    ) -> HostOutcome {
        self.host_message(msg, now, store)
    }

    fn host_message(
        &mut self,
        msg: HostToBoard,
        now: Instant,
        store: Option<&mut dyn RecordStore>,
    ) -> HostOutcome {
        let motors_off = !self.mode().motors_enabled();
        let Some(msg) = self.link_auth.admit(msg, motors_off, now) else {
            return HostOutcome::Done;
        };
        match msg {
            HostToBoard::ExternalPosition(pos) => {
                self.on_external_position(&pos, now);
                HostOutcome::Done
            }
            HostToBoard::Command(cmd) => {
                self.on_command(cmd, now);
                HostOutcome::Done
            }
            HostToBoard::Param(req) if req.board == Node::StereoBoard => {
                let changes = matches!(req.op, ParamOp::Set(..) | ParamOp::Save);
                if changes && self.mode().motors_enabled() {
                    HostOutcome::Reply(BoardToHost::Param(ParamResponse {
                        board: req.board,
                        reply: ParamReply::Error(ParamError::Armed),
                    }))
                } else {
                    HostOutcome::ToCamera(AutopilotToStereo::Param(req))
                }
            }
            HostToBoard::Param(req) => {
                HostOutcome::Reply(BoardToHost::Param(self.answer_param(&req, store)))
            }
            HostToBoard::Imu(sample) => HostOutcome::Imu(sample),
            HostToBoard::Heartbeat(hb) => {
                if hb.node == Node::Host {
                    self.on_host_heartbeat(now);
                }
                HostOutcome::Done
            }
            // Opened and provisioning consumed by `LinkAuth::admit`.
            HostToBoard::FrameChunk(_) | HostToBoard::Signed(_) | HostToBoard::SetKey(_) => {
                HostOutcome::Done
            }
        }
    }

    /// Takes the link key stored at boot ([`crate::link_auth::LinkAuth::load`]): from then on every command
    /// but `Kill` must be signed with it.
    pub fn load_link_key(&mut self, record: KeyRecord) {
        self.link_auth.load(record);
    }

    /// Whether the host link has a key (commands must then be signed).
    pub fn link_keyed(&self) -> bool {
        self.link_auth.telemetry().keyed
    }

    /// A key provisioned over the link since the last call, for the board to store (taken
    /// once; [`crate::link_auth::LinkAuth::take_key_to_store`]) with
    /// [`Autopilot::save_link_key`].
    pub fn take_link_key_to_store(&mut self) -> Option<KeyRecord> {
        self.link_auth.take_key_to_store()
    }

    /// Writes the link key into `store` beside the saved parameters, which stay as saved
    /// ([`protocol::params::ParamTable::save_link_key`]; unsaved changes stay unsaved), so that
    /// the next boot loads it ([`Autopilot::from_store`]). Nothing to do on an unsigned link.
    /// Refused while the motors may run, like a parameter save (the flash stalls the core for
    /// the erase); `Record` when the storage holds only bad records (the key is then saved
    /// with the next parameter save).
    pub fn save_link_key(&self, store: &mut impl RecordStore) -> Result<(), KeySaveError> {
        if self.mode().motors_enabled() {
            return Err(KeySaveError::SaveFailed);
        }
        match self.link_auth.stored_key() {
            Some(key) => crate::params::AUTOPILOT.save_link_key(store, &key),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::at;
    use crate::AutopilotConfig;
    use protocol::{
        ExternalPosition, FrameChunk, Heartbeat, Node, ParamOp, ParamReply, ParamRequest,
        PilotCommand, WireTime,
    };

    fn fix(height_m: f32) -> ExternalPosition {
        ExternalPosition {
            timestamp_us: WireTime(0),
            position_m: [0.0, 0.0, -height_m],
        }
    }

    #[test]
    fn a_stream_of_position_fixes_reaches_the_height() {
        let mut ap = Autopilot::new(AutopilotConfig::default());
        for _ in 0..crate::vertical::FIXES_TO_LEAD {
            let out = ap.on_host_message(HostToBoard::ExternalPosition(fix(1.25)), at(1_000), None);
            assert_eq!(out, HostOutcome::Done);
        }
        assert!((ap.telemetry(at(1_000)).height_m - 1.25).abs() < 1e-3);
    }

    #[test]
    fn with_a_key_unsigned_commands_change_nothing_and_signed_ones_act() {
        use protocol::signing::{LinkKey, Signer};
        let key = LinkKey([1; 32]);
        let mut ap = Autopilot::new(AutopilotConfig::default());
        ap.load_link_key(KeyRecord {
            key,
            min_timestamp: 0,
        });
        let before = ap.telemetry(at(1_000)).height_m;
        ap.on_host_message(HostToBoard::ExternalPosition(fix(1.25)), at(1_000), None);
        assert_eq!(
            ap.telemetry(at(1_000)).height_m,
            before,
            "an unsigned fix is ignored"
        );
        ap.on_host_message(HostToBoard::Command(PilotCommand::Arm), at(1_000), None);
        assert_eq!(
            ap.arm_refused(),
            0,
            "an unsigned arm never reaches the arm checks"
        );
        assert_eq!(ap.telemetry(at(1_000)).link_auth.unsigned, 2);
        let mut signer = Signer::new(key, 1);
        let fixes = crate::vertical::FIXES_TO_LEAD;
        for k in 0..u64::from(fixes) {
            let signed = signer
                .sign(&HostToBoard::ExternalPosition(fix(1.25)), 10 + k)
                .unwrap();
            ap.on_host_message(signed, at(1_000), None);
        }
        assert!((ap.telemetry(at(1_000)).height_m - 1.25).abs() < 1e-3);
        assert_eq!(ap.telemetry(at(1_000)).link_auth.accepted, u32::from(fixes));
    }

    #[test]
    fn a_key_provisioned_over_the_link_is_kept_across_a_reboot_and_a_save() {
        use protocol::params::{MemSlots, ParamValue};
        use protocol::signing::{LinkKey, Signer};
        let key = LinkKey([7; 32]);
        let param = |op| {
            HostToBoard::Param(ParamRequest {
                board: Node::Autopilot,
                op,
            })
        };
        let mut flash = MemSlots::<1024>::blank();
        let (mut ap, _) = Autopilot::from_store(&flash);
        assert!(!ap.telemetry(at(0)).link_auth.keyed);
        // A parameter set but not saved, then the key.
        let gain = ParamOp::Set("guid_kp".try_into().unwrap(), ParamValue::F32(0.3));
        ap.on_host_message(param(gain), at(0), Some(&mut flash));
        assert_eq!(ap.config().guidance.kp, 0.3);
        ap.on_host_message(HostToBoard::SetKey(key), at(0), Some(&mut flash));
        assert!(ap.take_link_key_to_store().is_some());
        assert_eq!(ap.save_link_key(&mut flash), Ok(()));
        // The reboot loads the key, and the parameters as saved (the set was not).
        let (mut ap, _) = Autopilot::from_store(&flash);
        assert!(ap.telemetry(at(0)).link_auth.keyed);
        assert_eq!(ap.config(), &AutopilotConfig::default());
        ap.on_host_message(
            HostToBoard::SetKey(LinkKey([9; 32])),
            at(0),
            Some(&mut flash),
        );
        assert_eq!(ap.telemetry(at(0)).link_auth.unsigned, 1, "the key is set");
        // A signed save keeps the key in the record it writes.
        let mut signer = Signer::new(key, 2);
        let save = signer.sign(&param(ParamOp::Save), 100).unwrap();
        let HostOutcome::Reply(BoardToHost::Param(r)) =
            ap.on_host_message(save, at(0), Some(&mut flash))
        else {
            panic!("a save is answered");
        };
        assert_eq!(r.reply, ParamReply::Saved);
        let (mut ap, _) = Autopilot::from_store(&flash);
        let arm = HostToBoard::Command(PilotCommand::Arm);
        ap.on_host_message(arm.clone(), at(0), None);
        assert_eq!(ap.telemetry(at(0)).link_auth.unsigned, 1);
        ap.on_host_message(signer.sign(&arm, 200).unwrap(), at(0), None);
        assert_eq!(ap.telemetry(at(0)).link_auth.accepted, 1);
    }

    #[test]
    fn a_parameter_request_is_answered_for_the_autopilot_table_only() {
        let mut ap = Autopilot::new(AutopilotConfig::default());
        let ask = |board| {
            HostToBoard::Param(ParamRequest {
                board,
                op: ParamOp::List(0),
            })
        };
        let HostOutcome::Reply(BoardToHost::Param(r)) =
            ap.on_host_message(ask(Node::Autopilot), at(0), None)
        else {
            panic!("a parameter request must be answered");
        };
        assert!(matches!(r.reply, ParamReply::Entry(_)));
        let HostOutcome::Reply(BoardToHost::Param(r)) =
            ap.on_host_message(ask(Node::Host), at(0), None)
        else {
            panic!("a request for another board must be answered too");
        };
        assert_eq!(r.reply, ParamReply::Error(ParamError::NoSuchBoard));
    }

    #[test]
    fn a_camera_parameter_request_is_passed_on_and_its_answer_back() {
        let mut ap = Autopilot::new(AutopilotConfig::default());
        let req = ParamRequest {
            board: Node::StereoBoard,
            op: ParamOp::List(3),
        };
        assert_eq!(
            ap.on_host_message(HostToBoard::Param(req.clone()), at(0), None),
            HostOutcome::ToCamera(AutopilotToStereo::Param(req))
        );
        assert_eq!(ap.take_camera_param_reply(), None);
        let answer = ParamResponse {
            board: Node::StereoBoard,
            reply: ParamReply::Error(ParamError::UnknownIndex),
        };
        ap.on_stereo_message(protocol::StereoToAutopilot::Param(answer.clone()), at(0));
        assert_eq!(ap.take_camera_param_reply(), Some(answer));
        assert_eq!(ap.take_camera_param_reply(), None, "taken once");
    }

    #[test]
    fn an_arm_without_sensors_is_refused_and_counted() {
        let mut ap = Autopilot::new(AutopilotConfig::default());
        let out = ap.on_host_message(HostToBoard::Command(PilotCommand::Arm), at(0), None);
        assert_eq!(out, HostOutcome::Done);
        assert_eq!(ap.arm_refused(), 1);
    }

    #[test]
    fn an_imu_sample_is_handed_back_to_the_caller() {
        let mut ap = Autopilot::new(AutopilotConfig::default());
        let sample = ImuSample {
            timestamp_us: WireTime(7),
            gyro_radps: [0.0; 3],
            accel_mps2: [0.0, 0.0, -9.81],
        };
        assert_eq!(
            ap.on_host_message(HostToBoard::Imu(sample), at(0), None),
            HostOutcome::Imu(sample)
        );
    }

    #[test]
    fn heartbeats_and_frame_chunks_change_nothing() {
        let mut ap = Autopilot::new(AutopilotConfig::default());
        let before = ap.telemetry(at(0));
        let hb = HostToBoard::Heartbeat(Heartbeat::new(Node::Host, 0));
        assert_eq!(ap.on_host_message(hb, at(0), None), HostOutcome::Done);
        let chunk = HostToBoard::FrameChunk(FrameChunk {
            frame_id: 0,
            capture_us: WireTime(0),
            offset: 0,
            data: heapless::Vec::new(),
        });
        assert_eq!(ap.on_host_message(chunk, at(0), None), HostOutcome::Done);
        assert_eq!(ap.telemetry(at(0)), before);
    }
}
