//! Authentication of the host link: which host messages must be signed, the link key, the
//! replay guard and the counts of refused messages (see [`protocol::signing`]).
//!
//! Without a key the link is unsigned: every message is taken as before, and telemetry says
//! so ([`LinkAuthTelemetry::keyed`] false). With a key, every message that changes what the
//! drone does must come in a valid [`HostToBoard::Signed`] envelope ([`authority`]); `Kill` is
//! always taken. The host heartbeat must be signed too, so that a spoofer cannot hold off the
//! telemetry-lost failsafe of a drone whose real host has gone. Reads (parameter list, get,
//! storage status) are not signed: they change nothing and the key is not among them.
//!
//! The key is provisioned while the motors cannot run: unsigned with [`HostToBoard::SetKey`]
//! while no key is set, later only by a `SetKey` signed with the current key, or over SWD into
//! the parameter record. The board saves it in its parameter record ([`LinkAuth::stored_key`])
//! and loads it at boot with [`LinkAuth::load`].

use protocol::signing::{KeyRecord, LinkKey, ReplayGuard, SignError};
use protocol::{HostToBoard, LinkAuthTelemetry, ParamOp, PilotCommand};
use timebase::Instant;

/// What a host message needs to be taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Authority {
    /// Taken signed or not: `Kill`, reads, and the sensor and frame streams of the lockstep
    /// flavours (the `real` flavour refuses IMU samples whatever their signature).
    Free,
    /// Changes what the drone does: a valid signature once a key is set.
    Signed,
    /// The signed envelope itself: opened, then its inner message is judged.
    Envelope,
    /// Key provisioning: unsigned only while no key is set, and only with the motors off.
    Provisioning,
}

/// What each host message needs. An exhaustive match: a new message does not compile until it
/// is classified here.
pub fn authority(msg: &HostToBoard) -> Authority {
    match msg {
        HostToBoard::Heartbeat(_) => Authority::Signed,
        HostToBoard::FrameChunk(_) | HostToBoard::Imu(_) => Authority::Free,
        HostToBoard::ExternalPosition(_) => Authority::Signed,
        HostToBoard::Command(PilotCommand::Kill) => Authority::Free,
        HostToBoard::Command(PilotCommand::Arm | PilotCommand::Land) => Authority::Signed,
        // Turning the bench's outputs off only stops motors, like a kill.
        HostToBoard::Command(PilotCommand::HilOutputs(false)) => Authority::Free,
        HostToBoard::Command(PilotCommand::HilOutputs(true)) => Authority::Signed,
        HostToBoard::Param(req) => match req.op {
            ParamOp::List(_) | ParamOp::Get(_) | ParamOp::Storage => Authority::Free,
            ParamOp::Set(..) | ParamOp::Save | ParamOp::Acknowledge => Authority::Signed,
        },
        HostToBoard::Signed(_) => Authority::Envelope,
        HostToBoard::SetKey(_) => Authority::Provisioning,
    }
}

/// The link key, the replay guard and the counts.
#[derive(Debug, Clone)]
pub struct LinkAuth {
    key: Option<LinkKey>,
    guard: ReplayGuard,
    counts: LinkAuthTelemetry,
    /// A key provisioned over the link since it was last taken, for the board to store.
    to_store: Option<KeyRecord>,
}

impl Default for LinkAuth {
    fn default() -> Self {
        Self::new()
    }
}

impl LinkAuth {
    /// An unsigned link (no key).
    pub const fn new() -> Self {
        Self {
            key: None,
            guard: ReplayGuard::new(0),
            counts: LinkAuthTelemetry {
                keyed: false,
                accepted: 0,
                unsigned: 0,
                bad_signature: 0,
                replayed: 0,
            },
            to_store: None,
        }
    }

    /// Takes the key stored at boot (flash written over SWD, or a key provisioned earlier):
    /// signed messages must then be newer than its `min_timestamp`.
    pub fn load(&mut self, record: KeyRecord) {
        self.key = Some(record.key);
        self.guard = ReplayGuard::new(record.min_timestamp);
        self.counts.keyed = true;
    }

    /// The key to save with the board's parameters (never sent over the link), its floor
    /// raised to the newest timestamp accepted since boot: after a reboot, messages signed
    /// before the save are refused ([`ReplayGuard::new`]). `None` on an unsigned link.
    pub fn stored_key(&self) -> Option<KeyRecord> {
        self.key.map(|key| KeyRecord {
            key,
            min_timestamp: self.guard.newest(),
        })
    }

    /// The counts and whether a key is set.
    pub fn telemetry(&self) -> LinkAuthTelemetry {
        self.counts
    }

    /// A key provisioned over the link since the last call, for the board to write to its
    /// parameter flash (taken once).
    pub fn take_key_to_store(&mut self) -> Option<KeyRecord> {
        self.to_store.take()
    }

    /// Judges `msg` at board time `now`; `motors_off` is true while the motors cannot run.
    /// Returns the message to act on (an envelope's inner message), or `None` when it was
    /// refused (counted) or consumed (a key provisioned).
    pub fn admit(
        &mut self,
        msg: HostToBoard,
        motors_off: bool,
        now: Instant,
    ) -> Option<HostToBoard> {
        let (msg, signed_at) = match msg {
            HostToBoard::Signed(envelope) => {
                let opened = match self.key {
                    Some(key) => envelope.open(&key).and_then(|inner| {
                        self.guard
                            .accept(envelope.link_id, envelope.timestamp, now)
                            .map(|()| inner)
                    }),
                    // An unsigned link takes a signed message's content as it takes unsigned
                    // ones (a keyed host tool works before the key is provisioned), but the
                    // envelope must still hold one message.
                    None => envelope.open_unverified(),
                };
                match opened {
                    Ok(inner) => {
                        self.counts.accepted = self.counts.accepted.saturating_add(1);
                        (inner, self.key.map(|_| envelope.timestamp))
                    }
                    Err(e) => {
                        let count = match e {
                            SignError::BadMac | SignError::BadPayload | SignError::TooLong => {
                                &mut self.counts.bad_signature
                            }
                            SignError::Replay | SignError::Future => &mut self.counts.replayed,
                        };
                        *count = count.saturating_add(1);
                        return None;
                    }
                }
            }
            other => (other, None),
        };
        let keyed = self.key.is_some();
        match authority(&msg) {
            Authority::Free => Some(msg),
            Authority::Signed if !keyed || signed_at.is_some() => Some(msg),
            Authority::Provisioning => {
                let HostToBoard::SetKey(key) = msg else {
                    return None;
                };
                if motors_off && (!keyed || signed_at.is_some()) {
                    self.key = Some(key);
                    let floor = signed_at.unwrap_or(0);
                    self.guard = ReplayGuard::new(floor);
                    self.counts.keyed = true;
                    self.to_store = Some(KeyRecord {
                        key,
                        min_timestamp: floor,
                    });
                } else {
                    self.refuse_unsigned();
                }
                None
            }
            // An envelope cannot hold an envelope ([`SignedMessage::open`]).
            Authority::Signed | Authority::Envelope => {
                self.refuse_unsigned();
                None
            }
        }
    }

    fn refuse_unsigned(&mut self) {
        self.counts.unsigned = self.counts.unsigned.saturating_add(1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::at;
    use protocol::signing::{SignedMessage, Signer};
    use protocol::{Heartbeat, Node, ParamRequest};

    const KEY: LinkKey = LinkKey([0x5A; 32]);
    const ARM: HostToBoard = HostToBoard::Command(PilotCommand::Arm);
    const KILL: HostToBoard = HostToBoard::Command(PilotCommand::Kill);

    fn keyed() -> LinkAuth {
        let mut a = LinkAuth::new();
        a.load(KeyRecord {
            key: KEY,
            min_timestamp: 0,
        });
        a
    }

    #[test]
    fn an_unkeyed_link_takes_everything_and_says_so() {
        let mut a = LinkAuth::new();
        assert_eq!(a.admit(ARM, true, at(0)), Some(ARM));
        let signed = Signer::new(KEY, 1).sign(&ARM, 10).unwrap();
        assert_eq!(a.admit(signed, true, at(0)), Some(ARM));
        assert!(!a.telemetry().keyed);
        assert_eq!(a.telemetry().unsigned, 0);
    }

    #[test]
    fn a_keyed_link_refuses_unsigned_commands_but_not_kill() {
        let mut a = keyed();
        assert_eq!(a.admit(ARM, true, at(0)), None);
        let hb = HostToBoard::Heartbeat(Heartbeat::new(Node::Host, 0));
        assert_eq!(a.admit(hb, true, at(0)), None);
        assert_eq!(a.admit(KILL, false, at(0)), Some(KILL));
        let list = HostToBoard::Param(ParamRequest {
            board: Node::Autopilot,
            op: ParamOp::List(0),
        });
        assert_eq!(a.admit(list.clone(), true, at(0)), Some(list));
        assert_eq!(a.telemetry().unsigned, 2);
    }

    #[test]
    fn signed_forged_and_replayed_are_told_apart() {
        let mut a = keyed();
        let signed = Signer::new(KEY, 1).sign(&ARM, 1_000).unwrap();
        assert_eq!(a.admit(signed.clone(), true, at(0)), Some(ARM));
        assert_eq!(a.admit(signed, true, at(10)), None, "replay");
        let forged = Signer::new(LinkKey([1; 32]), 1).sign(&ARM, 2_000).unwrap();
        assert_eq!(a.admit(forged, true, at(20)), None, "another key");
        let t = a.telemetry();
        assert_eq!((t.accepted, t.replayed, t.bad_signature), (1, 1, 1));
    }

    #[test]
    fn a_key_is_provisioned_once_unsigned_then_only_signed() {
        let mut a = LinkAuth::new();
        assert_eq!(a.admit(HostToBoard::SetKey(KEY), false, at(0)), None);
        assert!(!a.telemetry().keyed, "not while the motors may run");
        assert_eq!(a.admit(HostToBoard::SetKey(KEY), true, at(0)), None);
        assert!(a.telemetry().keyed);
        assert_eq!(a.take_key_to_store().map(|r| r.key), Some(KEY));
        assert_eq!(a.take_key_to_store(), None);
        // A second unsigned SetKey cannot take the link over.
        let other = LinkKey([9; 32]);
        assert_eq!(a.admit(HostToBoard::SetKey(other), true, at(0)), None);
        assert_eq!(a.take_key_to_store(), None);
        assert_eq!(a.telemetry().unsigned, 2);
        // Signed with the current key it changes the key, and the old key is then refused.
        let change = Signer::new(KEY, 1)
            .sign(&HostToBoard::SetKey(other), 5_000)
            .unwrap();
        assert_eq!(a.admit(change, true, at(0)), None);
        let r = a.take_key_to_store().unwrap();
        assert_eq!((r.key, r.min_timestamp), (other, 5_000));
        let old = Signer::new(KEY, 1).sign(&ARM, 6_000).unwrap();
        assert_eq!(a.admit(old, true, at(0)), None);
        let new = Signer::new(other, 1).sign(&ARM, 6_000).unwrap();
        assert_eq!(a.admit(new, true, at(0)), Some(ARM));
    }

    #[test]
    fn the_stored_key_refuses_what_was_signed_before_the_save() {
        let mut a = LinkAuth::new();
        assert_eq!(a.stored_key(), None);
        a.load(KeyRecord {
            key: KEY,
            min_timestamp: 100,
        });
        assert_eq!(a.stored_key().map(|r| r.min_timestamp), Some(100));
        let signed = Signer::new(KEY, 1).sign(&ARM, 5_000).unwrap();
        assert_eq!(a.admit(signed.clone(), true, at(0)), Some(ARM));
        let stored = a.stored_key().unwrap();
        assert_eq!((stored.key, stored.min_timestamp), (KEY, 5_000));
        let mut rebooted = LinkAuth::new();
        rebooted.load(stored);
        assert_eq!(
            rebooted.admit(signed, true, at(0)),
            None,
            "replayed after a reboot"
        );
    }

    #[test]
    fn a_signed_set_key_is_refused_while_flying() {
        let mut a = keyed();
        let change = Signer::new(KEY, 1)
            .sign(&HostToBoard::SetKey(LinkKey([3; 32])), 5_000)
            .unwrap();
        assert_eq!(a.admit(change, false, at(0)), None);
        assert_eq!(a.take_key_to_store(), None);
    }

    #[test]
    fn a_stored_key_refuses_timestamps_from_before_its_floor() {
        let mut a = LinkAuth::new();
        a.load(KeyRecord {
            key: KEY,
            min_timestamp: 10_000,
        });
        let old = HostToBoard::Signed(SignedMessage::sign(&KEY, 0, 9_999, &ARM).unwrap());
        assert_eq!(a.admit(old, true, at(0)), None);
        assert_eq!(a.telemetry().replayed, 1);
    }
}
