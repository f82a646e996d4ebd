//! `sim-host param` against the virtual autopilot: the real image's telemetry UART served on
//! TCP ([`virtual_board::serve::TcpBridge`]), the ground tool run as a user runs it against a
//! board on a serial port. The firmware lists its whole table, takes a value within bounds
//! (answering with the value now in use) and refuses one outside them, and every frame it sent
//! decodes. With both images joined on their link, `--board camera` reaches the camera-board
//! firmware through the autopilot.
//!
//! Saved parameters, on both boards: a record in the parameter sector at power-on (what an
//! earlier save left, encoded by the board library's `params::encode_record`, the bytes the
//! firmware's save programs) is what the firmware boots with; a corrupted one means the
//! defaults, reported to the host and in the log.
//!
//! Power cuts: the library's save (`ParamTable::save`, the code the images run: slot choice,
//! sequence number, read-back) runs on the bench's flash array
//! ([`virtual_board::flash::FlashArray`], erase to `0xFF`, programming only clears bits) with the
//! supply cut at every instant of it; the library then loads the last complete record and never
//! the defaults while one exists, and the unmodified autopilot image powered up on the array a
//! cut left (mid-erase, after the erase, halfway, one word short, before the read-back) boots on
//! it. A first save cut short leaves no complete record: the image runs on the defaults with
//! arming blocked until `ack` or a save.
//!
//! A save on the image drives rigless's flash interface model through the unlock, the sector
//! erase (its `BSY` held for the erase time) and the program sequence without a reset or a
//! sequence error; rigless 0.4.0 does not put programmed bytes into the array and our SoC
//! cannot (see [`virtual_board::flash`]), so the firmware's read-back finds the sector
//! unchanged and the save is answered as failed there.
//!
//! The tool is `VBOARD_SIM_HOST` (set by `cargo xtask vboard`, which builds it), else the main
//! workspace's `target/debug/sim-host`.

use rigless::mcu::Mcu as _;
use std::net::TcpListener;
use std::path::PathBuf;
use std::process::{Child, Command};

use autopilot::AutopilotConfig;
use autopilot::params::{self, TABLE};
use protocol::params::{ParamStorage, ParamTable, RecordError, StorageStatus};
use protocol::{BoardToHost, ParamError, ParamReply, ParamValue};
use virtual_board::bench::{Options, Setup, run};
use virtual_board::boards::autopilot::Autopilot;
use virtual_board::firmware::Firmware;
use virtual_board::flash::{FlashArray, FlashContents, PowerCut};
use virtual_board::host;
use virtual_board::serve::TcpBridge;

fn sim_host() -> PathBuf {
    let path = std::env::var_os("VBOARD_SIM_HOST").map_or_else(
        || PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/debug/sim-host"),
        PathBuf::from,
    );
    assert!(
        path.is_file(),
        "{} is missing: build it (`cargo build -p sim-host`) or run `cargo xtask vboard`",
        path.display()
    );
    path
}

/// Starts `sim-host param --port tcp:... ARGS` on a fresh local port. The tool's timeout is
/// wall time, the bench's clock virtual time (paced at most real time, far slower on a loaded
/// machine): a retry would send a second request, and the end of the run (the tool's
/// disconnect) would cut a second save off mid-erase, its flash left unlocked (every time with
/// a 2 s timeout). So the tool waits up to 600 s, which it never does: the end of the run
/// closes the port and the tool with it.
fn start_tool(args: &[&str]) -> (TcpListener, Child) {
    let listener = TcpListener::bind("127.0.0.1:0").expect("a local port");
    let port = listener.local_addr().unwrap().port();
    let tool = Command::new(sim_host())
        .args(["param", "--port", &format!("tcp:127.0.0.1:{port}")])
        .args(["--timeout", "600"])
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("sim-host param starts");
    (listener, tool)
}

/// Whether the tool succeeded, and what it printed (stdout, then stderr).
fn tool_output(tool: Child) -> (bool, String) {
    let out = tool.wait_with_output().expect("the tool ends");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

/// The flash interface's `CR` and `SR` of a part.
fn flash_registers(soc: &virtual_board::soc::Soc) -> (u64, u64) {
    use rigless::soc::stm32f427::generated::flash::Register;
    let registers = soc
        .mcu
        .bus()
        .registers("FLASH")
        .expect("the flash interface's registers");
    (registers.get(Register::Cr), registers.get(Register::Sr))
}

/// What one run of the tool against a freshly booted board left.
struct Session {
    ok: bool,
    out: String,
    replies: Vec<ParamReply>,
    log: String,
    resets: usize,
    told: Vec<String>,
    flash_cr: u64,
    flash_sr: u64,
}

/// Boots the autopilot image, runs `sim-host param --port tcp:... ARGS` against its telemetry
/// UART until the tool disconnects; returns whether it succeeded, its output, and the
/// parameter answers the firmware sent.
fn param(args: &[&str]) -> (bool, String, Vec<ParamReply>) {
    let s = param_on(FlashContents::erased(), args);
    (s.ok, s.out, s.replies)
}

/// The same on a board whose flash holds `flash` at power-on; also the firmware's log, the
/// resets, what rigless's models told the session, and the flash interface's `CR` and `SR`.
fn param_on(flash: FlashContents, args: &[&str]) -> Session {
    let firmware = Firmware::real("autopilot").expect("the autopilot image");
    let (listener, tool) = start_tool(args);
    let bridge = TcpBridge::accept(&listener, |b: &mut Autopilot| &mut b.telemetry, Some(1.0))
        .expect("the tool connects");
    let outcome = run(
        Setup {
            board: Autopilot::new(3).expect("the board").with_flash(flash),
            firmware,
            probe: bridge,
        },
        Options::seconds(60.0),
    )
    .expect("the run");
    let report = outcome.report();
    outcome.assert_clean();
    let log = outcome.log.text();
    let resets = outcome.session.resets().len();
    let told = outcome
        .session
        .told()
        .map(|t| format!("{t:?}"))
        .collect::<Vec<_>>();
    let (flash_cr, flash_sr) = flash_registers(&outcome.board().soc);
    let sent = outcome.board().telemetry.tx.sent_bytes();
    let (messages, errors) = host::decode_board_to_host(&sent);
    assert_eq!(errors, 0, "the firmware's own frames decode\n{report}");
    assert_eq!(
        outcome.probe.ended.as_deref(),
        Some("the client disconnected"),
        "the tool ended the run\n{report}"
    );
    drop(outcome);
    let (ok, out) = tool_output(tool);
    let replies = messages
        .into_iter()
        .filter_map(|m| match m {
            BoardToHost::Param(r) => Some(r.reply),
            _ => None,
        })
        .collect();
    Session {
        ok,
        out,
        replies,
        log,
        resets,
        told,
        flash_cr,
        flash_sr,
    }
}

/// The parameter sector as a save of `cfg` leaves it.
fn saved(cfg: &AutopilotConfig) -> Vec<u8> {
    let mut record = vec![0u8; params::RECORD_BYTES];
    assert_eq!(
        params::encode_record(cfg, &mut record),
        Ok(params::RECORD_BYTES)
    );
    record
}

fn with_target_height(h: f32) -> AutopilotConfig {
    let mut cfg = AutopilotConfig::default();
    params::set_by_name(&mut cfg, "target_height", ParamValue::F32(h)).expect("in bounds");
    cfg
}

#[test]
fn a_saved_record_is_what_the_firmware_boots_with() {
    let record = saved(&with_target_height(0.8));
    let s = param_on(
        FlashContents::param_sector(&record),
        &["get", "target_height"],
    );
    assert!(s.ok, "{}", s.out);
    assert!(s.out.contains(" 0.8 "), "{}", s.out);
    assert!(
        s.log.contains("parameters: the saved record is in use"),
        "{}",
        s.log
    );
    let s = param_on(FlashContents::param_sector(&record), &["storage"]);
    assert!(s.ok, "{}", s.out);
    assert!(
        s.out
            .contains("the saved parameters are in use; saves since boot: 0, failed: 0"),
        "{}",
        s.out
    );
    println!(
        "saved target_height 0.8 read back after a power cycle: {}",
        s.out.trim()
    );
}

/// `record` renumbered as save number `sequence` (the header's sequence word, the CRC-32 over
/// everything before it recomputed): what the `sequence`-th save programs.
fn numbered(mut record: Vec<u8>, sequence: u32) -> Vec<u8> {
    record[12..16].copy_from_slice(&sequence.to_le_bytes());
    let n = record.len();
    let crc = crc32(&record[..n - 4]);
    record[n - 4..].copy_from_slice(&crc.to_le_bytes());
    record
}

/// CRC-32 (ISO-HDLC: reflected polynomial 0xEDB88320, all-ones start and final XOR), the
/// record's.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = u32::MAX;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// Two slots (sectors 11 and 10): the image boots on the good record with the higher save
/// number, whichever slot holds it; a save cut short in one slot (half its words programmed,
/// the rest erased) leaves the other slot's record in use, not the defaults and no block.
#[test]
fn the_image_boots_on_the_newest_complete_record_of_its_two_slots() {
    let older = numbered(saved(&with_target_height(0.8)), 1);
    let newer = numbered(saved(&with_target_height(0.6)), 2);
    assert_eq!(
        crc32(&saved(&AutopilotConfig::default())[..params::RECORD_BYTES - 4]).to_le_bytes(),
        saved(&AutopilotConfig::default())[params::RECORD_BYTES - 4..],
        "the test's CRC is the record's"
    );
    let s = param_on(
        FlashContents::param_slots(&older, &newer),
        &["get", "target_height"],
    );
    assert!(s.ok, "{}", s.out);
    assert!(
        s.out.contains(" 0.6 "),
        "the second slot's newer record: {}",
        s.out
    );

    let mut cut = newer.clone();
    let half = (params::RECORD_BYTES / 8) * 4;
    cut[half..].fill(0xff);
    let s = param_on(
        FlashContents::param_slots(&older, &cut),
        &["get", "target_height"],
    );
    assert!(s.ok, "{}", s.out);
    assert!(
        s.out.contains(" 0.8 "),
        "the last complete record: {}",
        s.out
    );
    assert!(
        s.log.contains("parameters: the saved record is in use"),
        "{}",
        s.log
    );
    println!("two slots: newest record (slot 2) in use; a save cut mid-program boots on slot 1");
}

#[test]
fn a_corrupted_or_missing_record_means_the_defaults_and_says_why() {
    let mut record = saved(&with_target_height(0.8));
    record[params::RECORD_BYTES / 2] ^= 0x08;
    let s = param_on(
        FlashContents::param_sector(&record),
        &["get", "target_height"],
    );
    assert!(s.ok, "{}", s.out);
    assert!(s.out.contains(" 1 "), "the default, 1 m: {}", s.out);
    assert!(s.log.contains("parameters: defaults (BadCrc)"), "{}", s.log);
    let s = param_on(FlashContents::param_sector(&record), &["storage"]);
    assert!(
        s.out.contains("defaults in use: corrupt record (bad CRC)"),
        "{}",
        s.out
    );
    let s = param_on(FlashContents::erased(), &["storage"]);
    assert!(
        s.out
            .contains("defaults in use: nothing saved (erased flash)"),
        "{}",
        s.out
    );
    assert!(s.log.contains("parameters: defaults (Blank)"), "{}", s.log);
}

#[test]
fn a_save_runs_the_flash_sequence_without_a_reset() {
    let s = param_on(FlashContents::erased(), &["save"]);
    // Through the whole erase (rigless holds BSY for 1 s at x32) the watchdog was given the
    // save's timeout: the 50 ms one would have reset the board.
    assert_eq!(s.resets, 0, "{}", s.log);
    assert!(s.told.is_empty(), "rigless's models told: {:?}", s.told);
    // Locked again, no error flag left (PGSERR, PGPERR, PGAERR, WRPERR, OPERR), not busy.
    assert_eq!(s.flash_cr >> 31, 1, "CR {:#x}", s.flash_cr);
    assert_eq!(s.flash_sr & 0x1_00f2, 0, "SR {:#x}", s.flash_sr);
    // rigless 0.4.0 drops the programmed words (module docs): the read-back differs.
    assert!(
        s.replies
            .iter()
            .all(|r| *r == ParamReply::Error(ParamError::SaveFailed)),
        "{:?}",
        s.replies
    );
    assert!(!s.replies.is_empty());
    assert!(
        s.log.contains("parameters: not saved (SaveFailed)"),
        "{}",
        s.log
    );
    // The erase held the save (and, by the ap lock, the control loop) for rigless's 1 s.
    let ms: u32 = s
        .log
        .split("parameters: not saved (SaveFailed) in ")
        .nth(1)
        .and_then(|rest| rest.split(" ms").next())
        .and_then(|n| n.trim().parse().ok())
        .unwrap_or_else(|| panic!("no save line in\n{}", s.log));
    assert!(
        (1_000..1_100).contains(&ms),
        "the save took {ms} ms; told {:?}; CR {:#x} SR {:#x}",
        s.told,
        s.flash_cr,
        s.flash_sr
    );
    println!("save on the virtual autopilot: the erase held it {ms} ms, no reset");
}

#[test]
fn the_virtual_autopilot_lists_its_parameters() {
    let (ok, out, replies) = param(&["list"]);
    assert!(ok, "{out}");
    assert_eq!(out.lines().count(), TABLE.len(), "{out}");
    for (line, spec) in out.lines().zip(TABLE) {
        assert!(
            line.contains(&format!(" {} ", spec.name)),
            "{line} / {}",
            spec.name
        );
    }
    // One answer per entry (more only if a request was retried).
    assert!(replies.len() >= TABLE.len(), "{} answers", replies.len());
    println!(
        "param list against the virtual autopilot: {} entries",
        TABLE.len()
    );
}

#[test]
fn the_virtual_autopilot_takes_a_value_in_bounds_and_refuses_one_outside() {
    let (ok, out, replies) = param(&["set", "target_height", "0.8"]);
    assert!(ok, "{out}");
    assert!(
        out.contains("target_height") && out.contains(" 0.8 "),
        "{out}"
    );
    assert!(
        replies.iter().any(|r| matches!(r, ParamReply::Entry(e)
            if e.name == "target_height" && e.value == ParamValue::F32(0.8))),
        "{replies:?}"
    );
    let (ok, out, _) = param(&["set", "target_height", "9"]);
    assert!(!ok, "{out}");
    assert!(out.contains("outside [0.2 ..= 3]"), "{out}");
}

/// What one run of `sim-host param --board camera ARGS` against both real images left.
struct CameraSession {
    ok: bool,
    out: String,
    /// The camera-board firmware's parameter answers on the link.
    answers: Vec<ParamReply>,
    /// The autopilot's answers for the camera board's table on the telemetry port.
    passed_back: usize,
    log: String,
    resets: usize,
    told: Vec<String>,
    flash_cr: u64,
    flash_sr: u64,
    wall_s: f64,
}

/// Boots both real images joined on their link (the camera board's flash holding `flash`),
/// runs `sim-host param --board camera ARGS` against the autopilot's telemetry UART until the
/// tool disconnects; what the tool printed, what the camera-board firmware answered on the link
/// and logged, and its flash interface's `CR` and `SR`.
fn camera_param(flash: FlashContents, args: &[&str]) -> CameraSession {
    use protocol::{Decoder, StereoToAutopilot};
    use std::sync::Arc;
    use virtual_board::bench::{OnBarrier, Watching, run_pair};
    use virtual_board::boards::camera::CameraBoard;
    use virtual_board::frames::Recorded;

    let recorded = Recorded::from_take(&virtual_board::frames::data_set_take_1(), 40)
        .expect("the data set's take 1");
    let (camera_end, autopilot_end) = virtual_board::link::join();
    let camera = CameraBoard::with_link(Box::new(recorded), camera_end.clone())
        .expect("board")
        .with_flash(flash);
    let autopilot = Autopilot::with_link(1, autopilot_end.clone()).expect("board");
    let camera_rx: Arc<dyn OnBarrier> = Arc::new(camera_end.rx.clone());
    let autopilot_rx: Arc<dyn OnBarrier> = Arc::new(autopilot_end.rx.clone());

    let tool_args: Vec<&str> = ["--board", "camera"].iter().chain(args).copied().collect();
    let (listener, tool) = start_tool(&tool_args);
    let bridge = TcpBridge::accept(&listener, |b: &mut Autopilot| &mut b.telemetry, Some(1.0))
        .expect("the tool connects");
    let (cam, ap) = run_pair(
        Setup {
            board: camera,
            firmware: Firmware::real("stereo-board").expect("the camera-board image"),
            probe: Watching,
        },
        Setup {
            board: autopilot,
            firmware: Firmware::real("autopilot").expect("the autopilot image"),
            probe: bridge,
        },
        Options::seconds(20.0),
        vec![camera_rx],
        vec![autopilot_rx],
    )
    .expect("the run");
    let report = format!("{}\n{}", cam.report(), ap.report());
    cam.assert_clean();
    ap.assert_clean();
    assert_eq!(
        ap.probe.ended.as_deref(),
        Some("the client disconnected"),
        "the tool ended the run\n{report}"
    );
    let (flash_cr, flash_sr) = flash_registers(&cam.board().soc);
    // The camera-board firmware itself answered on the link.
    let mut decoder: Decoder<StereoToAutopilot, 256> = Decoder::new_mid_stream();
    let mut answers = Vec::new();
    decoder.feed(&camera_end.tx.sent_bytes(), |m| {
        if let StereoToAutopilot::Param(r) = m {
            answers.push(r.reply);
        }
    });
    assert_eq!(decoder.errors().total(), 0, "{report}");
    // And the autopilot passed its answers back to the tool.
    let (messages, errors) = host::decode_board_to_host(&ap.board().telemetry.tx.sent_bytes());
    assert_eq!(errors, 0, "{report}");
    let passed_back = messages
        .iter()
        .filter(|m| matches!(m, BoardToHost::Param(r) if r.board == protocol::Node::StereoBoard))
        .count();
    let log = cam.log.text();
    let resets = cam.session.resets().len();
    let told = cam.session.told().map(|t| format!("{t:?}")).collect();
    let wall_s = ap.wall_s;
    drop((cam, ap));
    let (ok, out) = tool_output(tool);
    CameraSession {
        ok,
        out,
        answers,
        passed_back,
        log,
        resets,
        told,
        flash_cr,
        flash_sr,
        wall_s,
    }
}

/// `sim-host param --board camera` against both real images joined on their link: the
/// autopilot passes the request on over the board-to-board UART, the camera-board firmware
/// answers, and the answer comes back on the telemetry port.
#[test]
fn the_virtual_camera_board_takes_a_parameter_through_the_autopilot() {
    let s = camera_param(FlashContents::erased(), &["set", "stereo_shift", "-4"]);
    assert!(s.ok, "{}", s.out);
    assert!(
        s.out.contains("stereo_shift") && s.out.contains(" -4 "),
        "{}",
        s.out
    );
    // The camera-board firmware answered with the value now in use.
    assert!(
        s.answers.iter().any(|r| matches!(r, ParamReply::Entry(e)
            if e.name == "stereo_shift" && e.value == ParamValue::I32(-4))),
        "{:?}",
        s.answers
    );
    assert!(s.passed_back >= 2, "get then set: {}", s.passed_back);
    println!(
        "camera param through the autopilot on the bench: {} link answers, wall {:.1} s",
        s.answers.len(),
        s.wall_s
    );
}

/// The camera board's parameter sector as a save of `p` leaves it.
fn camera_saved(p: &stereo_board::edge_fs::EdgeFsParams) -> Vec<u8> {
    use stereo_board::params::{RECORD_BYTES, encode_record};
    let mut record = vec![0u8; RECORD_BYTES];
    assert_eq!(encode_record(p, &mut record), Ok(RECORD_BYTES));
    record
}

/// The camera-board image boots on the record in its parameter sector (what an earlier save
/// left), and on the defaults when the record is corrupt, saying why in its log and to the
/// host.
#[test]
fn the_virtual_camera_board_boots_on_its_saved_parameters() {
    let mut p = stereo_board::edge_fs::EdgeFsParams::default_config();
    stereo_board::params::CAMERA
        .set_by_name(&mut p, "stereo_shift", ParamValue::I32(-4))
        .expect("in bounds");
    let record = camera_saved(&p);
    let s = camera_param(
        FlashContents::param_sector(&record),
        &["get", "stereo_shift"],
    );
    assert!(s.ok, "{}", s.out);
    assert!(s.out.contains(" -4 "), "{}", s.out);
    assert!(
        s.log.contains("parameters: the saved record is in use"),
        "{}",
        s.log
    );

    let mut corrupt = record.clone();
    corrupt[stereo_board::params::RECORD_BYTES / 2] ^= 0x08;
    let s = camera_param(FlashContents::param_sector(&corrupt), &["storage"]);
    assert!(s.ok, "{}", s.out);
    assert!(
        s.out.contains("defaults in use: corrupt record (bad CRC)"),
        "{}",
        s.out
    );
    assert!(s.log.contains("parameters: defaults (BadCrc)"), "{}", s.log);
    println!("camera board: saved stereo_shift -4 in use after a power cycle; corrupt -> defaults");
}

/// A save on the camera board drives the flash interface through unlock, erase and program
/// under the save's watchdog timeout (the board's own 2 s would leave no margin over the
/// datasheet's 2 s worst-case erase; rigless holds the erase 1 s): no reset. rigless 0.4.0
/// keeps the array's bytes, so the read-back fails, as on the autopilot.
#[test]
fn a_camera_board_save_runs_the_flash_sequence_without_a_reset() {
    let s = camera_param(FlashContents::erased(), &["save"]);
    assert_eq!(s.resets, 0, "{}", s.log);
    assert!(s.told.is_empty(), "rigless's models told: {:?}", s.told);
    assert_eq!(
        s.flash_cr >> 31,
        1,
        "locked again: CR {:#x}\n{}\n{}",
        s.flash_cr,
        s.out,
        s.log
    );
    assert_eq!(s.flash_sr & 0x1_00f2, 0, "SR {:#x}", s.flash_sr);
    assert!(
        !s.answers.is_empty()
            && s.answers
                .iter()
                .all(|r| *r == ParamReply::Error(ParamError::SaveFailed)),
        "{:?}",
        s.answers
    );
    assert!(
        s.log.contains("parameters: not saved (SaveFailed"),
        "{}",
        s.log
    );
    println!("camera save on the bench: flash sequence run, no reset");
}

/// Two slots after a library save (`ParamTable::save`, the images' code) of `table` for each
/// of `saves` with the power kept, then one more of `last` with the supply cut at `cut`.
fn cut_save_of<C: Copy>(table: &ParamTable<C>, saves: &[C], last: &C, cut: PowerCut) -> FlashArray {
    let mut array = FlashArray::erased();
    let mut status = StorageStatus::booted(Err(RecordError::Blank));
    for cfg in saves {
        let storage = ParamStorage {
            store: &mut array,
            status: &mut status,
            key: None,
        };
        assert_eq!(table.save(cfg, storage), ParamReply::Saved);
    }
    let mut array = array.cut_at(cut);
    let storage = ParamStorage {
        store: &mut array,
        status: &mut status,
        key: None,
    };
    let reply = table.save(last, storage);
    assert!(
        !array.powered(),
        "the cut {cut:?} fell inside the save: {reply:?}"
    );
    array
}

/// The autopilot's two slots after saves of each `target_height` of `saves`, then one of
/// `last` cut at `cut` ([`cut_save_of`]).
fn cut_save(saves: &[f32], last: f32, cut: PowerCut) -> FlashArray {
    let saves: Vec<AutopilotConfig> = saves.iter().map(|&h| with_target_height(h)).collect();
    cut_save_of(&params::AUTOPILOT, &saves, &with_target_height(last), cut)
}

/// Every instant of a save of a `words`-word record the supply can be cut at.
fn every_cut(words: usize) -> Vec<PowerCut> {
    let mut cuts = vec![
        PowerCut::BeforeErase,
        PowerCut::MidErase,
        PowerCut::AfterErase,
    ];
    cuts.extend((1..words).map(PowerCut::AfterWords));
    cuts.push(PowerCut::BeforeVerify);
    cuts
}

/// The supply cut at every instant of a save (each word of the record): while a complete
/// record is in the other slot the library boots on the last complete one, never the defaults,
/// and nothing blocks arming; the record is complete once its last word is programmed. A first
/// save cut after its first word leaves no complete record: the defaults, with arming blocked.
#[test]
fn a_save_cut_at_any_instant_leaves_the_last_complete_record() {
    let words = params::RECORD_BYTES / 4;
    // The second save writes slot 1 beside slot 0's record; the third erases slot 0's older
    // record beside slot 1's newer one.
    for (before, last) in [(&[0.8][..], 0.6), (&[0.8, 0.6][..], 0.7)] {
        let previous = before[before.len() - 1];
        for cut in every_cut(words) {
            let array = cut_save(before, last, cut);
            let (cfg, status) = params::AUTOPILOT.load(&array);
            let expected = if cut == PowerCut::BeforeVerify {
                last
            } else {
                previous
            };
            assert_eq!(
                cfg,
                with_target_height(expected),
                "{cut:?} after {before:?}"
            );
            assert_eq!(status.loaded, Ok(()), "{cut:?} after {before:?}");
            assert!(!status.blocks_arming());
        }
    }
    let mut blocked = 0;
    for cut in every_cut(words) {
        let array = cut_save(&[], 0.6, cut);
        let (cfg, status) = params::AUTOPILOT.load(&array);
        match cut {
            PowerCut::BeforeVerify => {
                assert_eq!(cfg, with_target_height(0.6));
                assert_eq!(status.loaded, Ok(()));
            }
            PowerCut::AfterWords(_) => {
                assert_eq!(cfg, AutopilotConfig::default(), "{cut:?}");
                assert!(
                    status.blocks_arming(),
                    "{cut:?}: a record that failed to load, {:?}",
                    status.loaded
                );
                blocked += 1;
            }
            _ => {
                assert_eq!(cfg, AutopilotConfig::default(), "{cut:?}");
                assert_eq!(status.loaded, Err(RecordError::Blank), "{cut:?}");
                assert!(!status.blocks_arming(), "{cut:?}: nothing was saved");
            }
        }
    }
    assert_eq!(blocked, words - 1);
    println!(
        "power cut at each of {} instants of a {words}-word save: the last complete record",
        every_cut(words).len()
    );
}

/// The unmodified autopilot image powered up on the flash a save cut short left: the last
/// complete record is in use (mid-erase of the older slot, after the erase, halfway through
/// and one word short of the record), the new one once its last word is programmed.
#[test]
fn the_image_boots_on_the_last_complete_record_after_a_save_cut_short() {
    let words = params::RECORD_BYTES / 4;
    let cases = [
        (&[0.8, 0.6][..], 0.7, PowerCut::MidErase, " 0.6 "),
        (&[0.8][..], 0.6, PowerCut::AfterErase, " 0.8 "),
        (&[0.8][..], 0.6, PowerCut::AfterWords(words / 2), " 0.8 "),
        (&[0.8][..], 0.6, PowerCut::AfterWords(words - 1), " 0.8 "),
        (&[0.8][..], 0.6, PowerCut::BeforeVerify, " 0.6 "),
    ];
    for (before, last, cut, expected) in cases {
        let array = cut_save(before, last, cut);
        let s = param_on(array.contents(), &["get", "target_height"]);
        assert!(s.ok, "{cut:?}: {}", s.out);
        assert!(s.out.contains(expected), "{cut:?}: {}", s.out);
        assert!(
            s.log.contains("parameters: the saved record is in use"),
            "{cut:?}\n{}",
            s.log
        );
        println!("cut {cut:?} of the save after {before:?}: the image uses{expected}m");
    }
}

/// The unmodified autopilot image powered up after its first save was cut short: half a
/// record fails to load, so the defaults are in use and arming is blocked until `ack` or a
/// save; a cut before the first word leaves erased flash, nothing saved, no block.
#[test]
fn a_first_save_cut_short_boots_on_the_defaults_with_arming_blocked() {
    let words = params::RECORD_BYTES / 4;
    let array = cut_save(&[], 0.6, PowerCut::AfterWords(words / 2));
    let s = param_on(array.contents(), &["storage"]);
    assert!(s.ok, "{}", s.out);
    assert!(
        s.out.contains("defaults in use: ")
            && s.out.contains("; arming blocked until `ack` or a save"),
        "{}",
        s.out
    );
    assert!(s.log.contains("parameters: defaults ("), "{}", s.log);
    println!("first save cut at word {}: {}", words / 2, s.out.trim());

    let array = cut_save(&[], 0.6, PowerCut::AfterErase);
    let s = param_on(array.contents(), &["storage"]);
    assert!(s.ok, "{}", s.out);
    assert!(
        s.out
            .contains("defaults in use: nothing saved (erased flash)")
            && !s.out.contains("arming blocked"),
        "{}",
        s.out
    );
}

fn with_stereo_shift(shift: i32) -> stereo_board::edge_fs::EdgeFsParams {
    let mut p = stereo_board::edge_fs::EdgeFsParams::default_config();
    stereo_board::params::CAMERA
        .set_by_name(&mut p, "stereo_shift", ParamValue::I32(shift))
        .expect("in bounds");
    p
}

/// The camera board's save cut at every instant: the last complete record, as on the
/// autopilot; and the camera-board image powered up beside a second save cut halfway through
/// its record boots on the first.
#[test]
fn a_camera_board_save_cut_short_leaves_the_last_complete_record() {
    use stereo_board::params::{CAMERA, RECORD_BYTES};
    let words = RECORD_BYTES / 4;
    let first = with_stereo_shift(-4);
    let second = with_stereo_shift(3);
    for cut in every_cut(words) {
        let array = cut_save_of(&CAMERA, &[first], &second, cut);
        let (p, status) = CAMERA.load(&array);
        let expected = if cut == PowerCut::BeforeVerify {
            second
        } else {
            first
        };
        assert_eq!(p, expected, "{cut:?}");
        assert_eq!(status.loaded, Ok(()), "{cut:?}");
    }
    let array = cut_save_of(&CAMERA, &[first], &second, PowerCut::AfterWords(words / 2));
    let s = camera_param(array.contents(), &["get", "stereo_shift"]);
    assert!(s.ok, "{}", s.out);
    assert!(s.out.contains(" -4 "), "{}", s.out);
    assert!(
        s.log.contains("parameters: the saved record is in use"),
        "{}",
        s.log
    );
    println!(
        "camera board: save cut at word {} of {words}: stereo_shift -4 of the first record in use",
        words / 2
    );
}
