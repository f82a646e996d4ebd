//! Signed host commands on the unmodified `real` autopilot image, measured on the PWM outputs
//! (see docs/protocol.md).
//!
//! The ground station signs its heartbeats, height fixes and commands with a key it provisions
//! at boot (an unsigned `SetKey`, taken once while no key is set). Then, in one run:
//!
//! * an unsigned `Arm`, an `Arm` signed with another key (forged) and an `Arm` signed with the
//!   right key but an old timestamp (replayed) are refused: every motor duty stays 0;
//! * a signed `Arm` is taken: the motors spin;
//! * unsigned `ExternalPosition` fixes claiming 3 m, sent while the drone hovers at 0.5 m, are
//!   ignored: the height in telemetry stays at the signed fixes';
//! * an unsigned `Kill` is taken (it always is), and the accepted `Arm` sent again byte for byte
//!   afterwards is refused as a replay: the motors stay off;
//! * telemetry reports the keyed link and each refusal by kind.
//!
//! A board whose parameter flash holds a record with the key (built by the autopilot
//! library's `params::record_with_key`, the function `cargo xtask flash --key` writes over
//! SWD with) boots keyed: an unsigned `SetKey` and an unsigned `Arm` are refused, an `Arm`
//! signed before the key's stored floor is refused as a replay, a signed `Arm` spins the
//! motors.

use protocol::params::MemSlots;
use protocol::signing::{KeyRecord, LinkKey, SignedMessage, Signer};
use protocol::{
    BoardToHost, Decoder, ExternalPosition, Heartbeat, HostToBoard, LinkAuthTelemetry, Message,
    Node, PilotCommand,
};
use virtual_board::bench::{At, Flow, Options, Setup, run};
use virtual_board::boards::autopilot::Autopilot;
use virtual_board::firmware::Firmware;
use virtual_board::flash::FlashContents;
use virtual_board::host;
use virtual_board::link::Line;
use virtual_board::pilot::{CameraStandIn, Every, MS, Once};

const KEY: LinkKey = LinkKey([0x3C; 32]);
const FORGER_KEY: LinkKey = LinkKey([0xC3; 32]);
/// The height the signed fixes report once armed, m.
const HOVER_M: f32 = 0.5;
/// The height the unsigned fixes claim, m.
const SPOOFED_M: f32 = 3.0;

const PROVISION_AT: u64 = 300 * MS;
const UNSIGNED_ARM_AT: u64 = 1_500 * MS;
const FORGED_ARM_AT: u64 = 1_800 * MS;
const STALE_ARM_AT: u64 = 2_100 * MS;
const SIGNED_ARM_AT: u64 = 2_400 * MS;
const SPOOF_FROM: u64 = 3_000 * MS;
const SPOOF_TO: u64 = 3_600 * MS;
const KILL_AT: u64 = 3_800 * MS;
const REPLAY_AT: u64 = 4_200 * MS;
const END_S: f64 = 4.8;

/// The signing clock of the ground station: virtual time in 10 µs units, offset so that it
/// is never 0.
fn clock(now_ns: u64) -> u64 {
    1_000_000 + now_ns / 10_000
}

struct Ground {
    signer: Signer,
    heartbeats: Every,
    fixes: Every,
    camera: CameraStandIn,
    provision: Once,
    unsigned_arm: Once,
    forged_arm: Once,
    stale_arm: Once,
    signed_arm: Once,
    kill: Once,
    replay: Once,
    /// A signed `Arm` made at boot, sent only after newer signed messages: a stale one.
    stale: HostToBoard,
    /// The accepted `Arm`, kept to be sent again.
    accepted_arm: Option<HostToBoard>,
    telemetry: Decoder<BoardToHost, { BoardToHost::MAX_FRAME_BYTES }>,
    telemetry_read: usize,
    /// Highest duty of any motor in each phase: before the signed `Arm`, flying, after the
    /// kill plus 100 ms.
    max_duty_before_arm: f32,
    max_duty_flying: f32,
    max_duty_after_kill: f32,
    /// Highest telemetry height while the spoofed fixes come (plus 100 ms).
    max_height_spoofed: f32,
    /// Telemetry heights seen while the spoofed fixes come.
    heights_during_spoof: usize,
    link_auth: Option<LinkAuthTelemetry>,
}

impl Ground {
    fn new() -> Self {
        let stale = HostToBoard::Signed(
            SignedMessage::sign(&KEY, 1, clock(0), &HostToBoard::Command(PilotCommand::Arm))
                .expect("an arm signs"),
        );
        Self {
            signer: Signer::new(KEY, 1),
            heartbeats: Every::ns(1_000 * MS),
            fixes: Every::ns(20 * MS),
            camera: CameraStandIn::new(),
            provision: Once::at(PROVISION_AT),
            unsigned_arm: Once::at(UNSIGNED_ARM_AT),
            forged_arm: Once::at(FORGED_ARM_AT),
            stale_arm: Once::at(STALE_ARM_AT),
            signed_arm: Once::at(SIGNED_ARM_AT),
            kill: Once::at(KILL_AT),
            replay: Once::at(REPLAY_AT),
            stale,
            accepted_arm: None,
            telemetry: Decoder::new_mid_stream(),
            telemetry_read: 0,
            max_duty_before_arm: 0.0,
            max_duty_flying: 0.0,
            max_duty_after_kill: 0.0,
            max_height_spoofed: 0.0,
            heights_during_spoof: 0,
            link_auth: None,
        }
    }

    fn signed(&mut self, msg: &HostToBoard, now: u64) -> HostToBoard {
        self.signer
            .sign(msg, clock(now))
            .expect("a host message signs")
    }

    fn host(&mut self, now: u64, line: &Line) {
        let send = |m: &HostToBoard| line.send_at(now, &host::frame(m));
        if self.provision.due(now) {
            send(&HostToBoard::SetKey(KEY));
        }
        if self.heartbeats.due(now) {
            let hb = HostToBoard::Heartbeat(Heartbeat::new(Node::Host, (now / MS) as u32));
            send(&self.signed(&hb, now));
        }
        if self.fixes.due(now) {
            let height = if now >= SIGNED_ARM_AT { HOVER_M } else { 0.0 };
            let fix = |h: f32| {
                HostToBoard::ExternalPosition(ExternalPosition {
                    timestamp_us: protocol::WireTime((now / 1_000) as u32),
                    position_m: [0.0, 0.0, -h],
                })
            };
            send(&self.signed(&fix(height), now));
            if (SPOOF_FROM..SPOOF_TO).contains(&now) {
                send(&fix(SPOOFED_M));
            }
        }
        let arm = HostToBoard::Command(PilotCommand::Arm);
        if self.unsigned_arm.due(now) {
            send(&arm);
        }
        if self.forged_arm.due(now) {
            let forged = Signer::new(FORGER_KEY, 1)
                .sign(&arm, clock(now))
                .expect("signs");
            send(&forged);
        }
        if self.stale_arm.due(now) {
            send(&self.stale.clone());
        }
        if self.signed_arm.due(now) {
            let signed = self.signed(&arm, now);
            send(&signed);
            self.accepted_arm = Some(signed);
        }
        if self.kill.due(now) {
            send(&HostToBoard::Command(PilotCommand::Kill));
        }
        if self.replay.due(now)
            && let Some(again) = self.accepted_arm.clone()
        {
            send(&again);
        }
    }

    fn read_telemetry(&mut self, now: u64, board: &Autopilot) {
        let sent = board.telemetry.tx.sent_bytes();
        for &byte in sent.get(self.telemetry_read..).unwrap_or(&[]) {
            if let Some(BoardToHost::Telemetry(t)) = self.telemetry.push(byte) {
                if (SPOOF_FROM..SPOOF_TO + 100 * MS).contains(&now) {
                    self.max_height_spoofed = self.max_height_spoofed.max(t.height_m);
                    self.heights_during_spoof += 1;
                }
                self.link_auth = Some(t.link_auth);
            }
        }
        self.telemetry_read = sent.len();
    }
}

impl virtual_board::bench::Probe<Autopilot> for Ground {
    fn at(&mut self, at: &mut At<'_, Autopilot>) -> Flow {
        let now = at.now;
        let board = at.board();
        self.read_telemetry(now, board);
        self.camera.step(now, &board.link.rx);
        self.host(now, &board.telemetry.rx);
        let duty = board
            .motors()
            .iter()
            .map(|m| m.duty as f32)
            .fold(0.0f32, f32::max);
        if now < SIGNED_ARM_AT {
            self.max_duty_before_arm = self.max_duty_before_arm.max(duty);
        } else if (SIGNED_ARM_AT + 100 * MS..KILL_AT).contains(&now) {
            self.max_duty_flying = self.max_duty_flying.max(duty);
        } else if now >= KILL_AT + 100 * MS {
            self.max_duty_after_kill = self.max_duty_after_kill.max(duty);
        }
        Flow::Continue
    }
}

#[test]
fn only_signed_commands_move_the_motors() {
    let firmware = Firmware::real("autopilot").expect("the autopilot image");
    let outcome = run(
        Setup {
            board: Autopilot::new(41).expect("the board"),
            firmware,
            probe: Ground::new(),
        },
        Options::seconds(END_S),
    )
    .expect("the run");
    let report = outcome.report();
    let g = &outcome.probe;
    assert_eq!(
        g.max_duty_before_arm, 0.0,
        "an unsigned, forged or stale Arm ran a motor\n{report}"
    );
    assert!(
        g.max_duty_flying > 0.0,
        "the signed Arm did not spin the motors\n{report}"
    );
    assert!(
        g.heights_during_spoof > 0,
        "no telemetry while spoofed fixes came\n{report}"
    );
    assert!(
        g.max_height_spoofed < 1.0,
        "unsigned fixes moved the height estimate to {} m\n{report}",
        g.max_height_spoofed
    );
    assert_eq!(
        g.max_duty_after_kill, 0.0,
        "the replayed Arm ran a motor after the kill\n{report}"
    );
    let a = g
        .link_auth
        .unwrap_or_else(|| panic!("no telemetry\n{report}"));
    println!("link_auth at the end: {a:?}");
    assert!(a.keyed, "{report}");
    // The unsigned Arm and the 30 unsigned fixes (0.6 s at 50 Hz), a few fixes of slack.
    assert!(
        a.unsigned > 25,
        "unsigned refusals {}\n{report}",
        a.unsigned
    );
    assert_eq!(a.bad_signature, 1, "the forged Arm\n{report}");
    assert_eq!(a.replayed, 2, "the stale and the replayed Arm\n{report}");
    outcome.assert_clean();
}

/// The ground station of a board keyed in its flash: signed heartbeats and fixes, then an
/// unsigned `SetKey`, an unsigned `Arm`, an `Arm` signed before the key's floor and a signed
/// `Arm`.
struct KeyedGround {
    signer: Signer,
    heartbeats: Every,
    fixes: Every,
    camera: CameraStandIn,
    set_key: Once,
    unsigned_arm: Once,
    stale_arm: Once,
    signed_arm: Once,
    telemetry: Decoder<BoardToHost, { BoardToHost::MAX_FRAME_BYTES }>,
    telemetry_read: usize,
    max_duty_before_arm: f32,
    max_duty_flying: f32,
    link_auth: Option<LinkAuthTelemetry>,
}

/// The replay floor stored with the flashed key: below every signing time of [`clock`].
const FLASHED_FLOOR: u64 = 900_000;

impl virtual_board::bench::Probe<Autopilot> for KeyedGround {
    fn at(&mut self, at: &mut At<'_, Autopilot>) -> Flow {
        let now = at.now;
        let board = at.board();
        let sent = board.telemetry.tx.sent_bytes();
        for &byte in sent.get(self.telemetry_read..).unwrap_or(&[]) {
            if let Some(BoardToHost::Telemetry(t)) = self.telemetry.push(byte) {
                self.link_auth = Some(t.link_auth);
            }
        }
        self.telemetry_read = sent.len();
        self.camera.step(now, &board.link.rx);
        let line = &board.telemetry.rx;
        let send = |m: &HostToBoard| line.send_at(now, &host::frame(m));
        let mut signed = |m: &HostToBoard| self.signer.sign(m, clock(now)).expect("signs");
        if self.heartbeats.due(now) {
            let hb = HostToBoard::Heartbeat(Heartbeat::new(Node::Host, (now / MS) as u32));
            send(&signed(&hb));
        }
        if self.fixes.due(now) {
            let height = if now >= SIGNED_ARM_AT { HOVER_M } else { 0.0 };
            let fix = HostToBoard::ExternalPosition(ExternalPosition {
                timestamp_us: protocol::WireTime((now / 1_000) as u32),
                position_m: [0.0, 0.0, -height],
            });
            send(&signed(&fix));
        }
        let arm = HostToBoard::Command(PilotCommand::Arm);
        if self.set_key.due(now) {
            send(&HostToBoard::SetKey(FORGER_KEY));
        }
        if self.unsigned_arm.due(now) {
            send(&arm);
        }
        if self.stale_arm.due(now) {
            let stale = SignedMessage::sign(&KEY, 7, FLASHED_FLOOR, &arm).expect("signs");
            send(&HostToBoard::Signed(stale));
        }
        if self.signed_arm.due(now) {
            send(&signed(&arm));
        }
        let duty = board
            .motors()
            .iter()
            .map(|m| m.duty as f32)
            .fold(0.0f32, f32::max);
        if now < SIGNED_ARM_AT {
            self.max_duty_before_arm = self.max_duty_before_arm.max(duty);
        } else if now >= SIGNED_ARM_AT + 100 * MS {
            self.max_duty_flying = self.max_duty_flying.max(duty);
        }
        Flow::Continue
    }
}

#[test]
fn a_key_in_the_parameter_flash_is_loaded_at_boot() {
    let mut record = vec![0u8; protocol::params::MAX_RECORD_BYTES];
    let key = KeyRecord {
        key: KEY,
        min_timestamp: FLASHED_FLOOR,
    };
    let (slot, n) =
        autopilot::params::record_with_key(&MemSlots::<1024>::blank(), &key, &mut record)
            .expect("a record for erased flash");
    assert_eq!(slot, 0, "erased flash: the first slot");
    let ground = KeyedGround {
        signer: Signer::new(KEY, 1),
        heartbeats: Every::ns(1_000 * MS),
        fixes: Every::ns(20 * MS),
        camera: CameraStandIn::new(),
        set_key: Once::at(PROVISION_AT),
        unsigned_arm: Once::at(UNSIGNED_ARM_AT),
        stale_arm: Once::at(STALE_ARM_AT),
        signed_arm: Once::at(SIGNED_ARM_AT),
        telemetry: Decoder::new_mid_stream(),
        telemetry_read: 0,
        max_duty_before_arm: 0.0,
        max_duty_flying: 0.0,
        link_auth: None,
    };
    let outcome = run(
        Setup {
            board: Autopilot::new(43)
                .expect("the board")
                .with_flash(FlashContents::param_sector(&record[..n])),
            firmware: Firmware::real("autopilot").expect("the autopilot image"),
            probe: ground,
        },
        Options::seconds(3.0),
    )
    .expect("the run");
    let report = outcome.report();
    let g = &outcome.probe;
    assert!(
        outcome.log.text().contains("link key: loaded"),
        "the boot did not load the key\n{report}"
    );
    assert_eq!(
        g.max_duty_before_arm, 0.0,
        "an unsigned or stale Arm ran a motor\n{report}"
    );
    assert!(
        g.max_duty_flying > 0.0,
        "the Arm signed with the flashed key did not spin the motors\n{report}"
    );
    let a = g
        .link_auth
        .unwrap_or_else(|| panic!("no telemetry\n{report}"));
    println!("link_auth at the end: {a:?}");
    assert!(a.keyed, "{report}");
    assert_eq!(a.unsigned, 2, "the unsigned SetKey and Arm\n{report}");
    assert_eq!(a.replayed, 1, "the Arm signed at the floor\n{report}");
    assert_eq!(a.bad_signature, 0, "{report}");
    outcome.assert_clean();
}
