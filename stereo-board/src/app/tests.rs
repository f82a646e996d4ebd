//! Host tests of the camera board's task logic.

extern crate std;

use super::*;
use protocol::params::MemStore;
use protocol::{
    AutopilotToStereoDecoder, EstimateFlags, ParamError, ParamName, ParamOp, ParamReply,
    ParamValue, StereoToAutopilotDecoder,
};
use std::{boxed::Box, vec, vec::Vec};

/// The board-clock instant `us` µs after boot.
fn at(us: u64) -> Instant {
    Instant::from_micros(us)
}

/// A textured synthetic stereo frame: vertical bars, the right image shifted by `disp` px.
fn frame(phase: usize, disp: usize) -> Box<[u8; STEREO_FRAME_BYTES]> {
    let mut f = Box::new([0u8; STEREO_FRAME_BYTES]);
    for y in 0..96 {
        for x in 0..128 {
            let l = ((x + phase) * 37 % 101) as u8;
            let r = ((x + phase + disp) * 37 % 101) as u8;
            let i = 2 * (y * 128 + x);
            f[i] = l.wrapping_mul(2);
            f[i + 1] = r.wrapping_mul(2);
        }
    }
    f
}

/// The frame task on `f` exposed at `capture`, processing started and done at `now`; the
/// estimate it sent to `tx`.
fn run_frame(
    board: &mut StereoBoardApp,
    f: &[u8; STEREO_FRAME_BYTES],
    capture: Instant,
    now: Instant,
    tx: &mut impl FnMut(&[u8]),
) -> Estimate {
    let frame = StereoFrame {
        pixels: f,
        capture,
        start: now,
    };
    let outcome = board.on_frame(0, Some(frame), || Some(now), tx, &mut |_| {});
    outcome
        .estimate()
        .expect("an intact frame sends an estimate")
}

fn app() -> Box<StereoBoardApp> {
    Box::new(StereoBoardApp::new(EdgeFsParams::default_config()))
}

/// Collects every frame sent through `tx` and decodes them as the autopilot would.
fn decode_out(bytes: &[u8]) -> (Vec<StereoToAutopilot>, LinkErrorCounts) {
    let mut dec = StereoToAutopilotDecoder::new();
    let mut out = Vec::new();
    dec.feed(bytes, |m| out.push(m));
    (out, dec.errors())
}

fn enc<M: Message>(msg: &M) -> Vec<u8> {
    let mut buf = vec![0u8; M::MAX_FRAME_BYTES];
    let n = encode(msg, &mut buf).expect("fits");
    buf.truncate(n);
    buf
}

fn gyro(t: u32, yaw: f32) -> GyroAttitude {
    GyroAttitude {
        timestamp_us: WireTime(t),
        rates_radps: [0.01, -0.02, 0.3],
        attitude_rad: [0.0, 0.05, yaw],
    }
}

#[test]
fn task_table_is_consistent() {
    let mut names: Vec<_> = TASKS.iter().map(|t| t.name).collect();
    names.sort_unstable();
    names.dedup();
    assert_eq!(names.len(), TASKS.len(), "task names are unique");
    assert!(task_table::is_indexed_by(TASKS, Task::ALL));
    let prio = |t: Task| t.spec().priority;
    assert!(
        prio(Task::UartRx) > prio(Task::Frame),
        "gyro keeps flowing during Edge-FS"
    );
    assert!(prio(Task::Frame) > prio(Task::Status));
    assert_eq!(
        Task::Status.spec().trigger,
        Trigger::Periodic {
            period: STATUS_PERIOD
        }
    );
    assert!(TASKS
        .iter()
        .all(|t| t.deadline > Duration::ZERO && t.priority >= 1));
}

#[test]
fn frame_task_sends_the_edge_fs_result_as_an_estimate() {
    let mut board = app();
    let mut reference = Box::new(EdgeFs::new(EdgeFsParams::default_config()));
    let mut wire = Vec::new();
    let mut sent = Vec::new();
    for i in 0..8u64 {
        let f = frame(i as usize, 3);
        let capture = (1u64 << 32) + 40_000 * i;
        let expected = reference.process(&f, at(capture), None);
        let est = run_frame(
            &mut board,
            &f,
            at(capture),
            at(capture + 12_345),
            &mut |b| wire.extend_from_slice(b),
        );
        assert_eq!(est.seq, i as u16);
        assert_eq!(
            est.capture_us,
            WireTime(capture as u32),
            "wire carries the low 32 bits"
        );
        assert_eq!(est.forward_mps.to_bits(), expected.forward_mps.to_bits());
        assert_eq!(est.sideways_mps.to_bits(), expected.sideways_mps.to_bits());
        assert_eq!(est.obstacle_m, expected.obstacle_m);
        assert_eq!(est.quality, expected.quality);
        assert_eq!(est.flags, expected.flags);
        assert!(
            est.flags.contains(EstimateFlags::NO_GYRO),
            "no gyro received yet"
        );
        assert_eq!(est.processing_us, 12_345);
        sent.push(est);
    }
    let (msgs, errors) = decode_out(&wire);
    assert_eq!(errors.total(), 0);
    let decoded: Vec<_> = msgs
        .into_iter()
        .map(|m| match m {
            StereoToAutopilot::Estimate(e) => e,
            other => panic!("unexpected {other:?}"),
        })
        .collect();
    assert_eq!(decoded, sent);
    assert_eq!(board.counters().frames_processed, 8);
}

#[test]
fn frame_task_counts_lost_frames_and_mirrors_the_estimate_to_the_host() {
    let mut board = app();
    let f = frame(0, 3);
    let frame = StereoFrame {
        pixels: &f,
        capture: at(1_000),
        start: at(2_000),
    };
    let mut host = Vec::new();
    let outcome = board.on_frame(2, Some(frame), || Some(at(9_000)), &mut |_| {}, &mut |b| {
        host.extend_from_slice(b)
    });
    let est = outcome.estimate().expect("sent");
    assert_eq!(est.processing_us, 8_000);
    assert_eq!(board.counters().frames_dropped, 2);
    let mut dec = protocol::BoardToHostDecoder::new();
    let mut got = Vec::new();
    dec.feed(&host, |m| got.push(m));
    assert_eq!(got, vec![BoardToHost::Estimate(est)]);
    let none = board.on_frame(
        1,
        None,
        || panic!("no frame to finish"),
        &mut |_| {},
        &mut |_| {},
    );
    assert_eq!(none, FrameOutcome::NoFrame);
    assert_eq!(board.counters().frames_dropped, 3);
}

#[test]
fn processing_time_saturates() {
    let mut board = app();
    let f = frame(0, 2);
    let est = run_frame(&mut board, &f, at(0), at(10_000_000), &mut |_| {});
    assert_eq!(est.processing_us, u16::MAX);
    let out = board.process_frame(&f, at(100), at(50));
    let est = board.send_estimate(&out, at(100), at(50), &mut |_| {});
    assert_eq!(
        est.processing_us, 0,
        "a clock going backwards saturates at 0"
    );
}

#[test]
fn gyro_from_the_link_is_used_for_derotation_until_stale() {
    let mut board = app();
    let mut reference = Box::new(EdgeFs::new(EdgeFsParams::default_config()));
    let g = gyro(7, 0.4);
    board.on_rx_bytes(
        &enc(&AutopilotToStereo::GyroAttitude(g)),
        at(1_000),
        &mut |_| panic!("a gyro sample is not answered"),
        None,
    );
    assert_eq!(
        board.current_gyro(at(1_000 + GYRO_TIMEOUT.as_micros())),
        Some(&g)
    );
    assert_eq!(
        board.current_gyro(at(1_001 + GYRO_TIMEOUT.as_micros())),
        None
    );
    assert_eq!(
        board.gyro_age(at(5_000)),
        Some(Duration::from_micros(4_000))
    );
    for i in 0..6u64 {
        let f = frame(2 * i as usize, 4);
        let now = 1_000 + 10_000 * i;
        let expected = reference.process(&f, at(now), Some(&g));
        let est = run_frame(&mut board, &f, at(now), at(now), &mut |_| {});
        assert_eq!(est.forward_mps.to_bits(), expected.forward_mps.to_bits());
        assert_eq!(est.flags, expected.flags);
        assert!(!est.flags.contains(EstimateFlags::NO_GYRO));
    }
    let est = run_frame(
        &mut board,
        &frame(20, 4),
        at(500_000),
        at(500_000),
        &mut |_| {},
    );
    assert!(
        est.flags.contains(EstimateFlags::NO_GYRO),
        "stale sample not used"
    );
}

#[test]
fn non_finite_gyro_is_rejected_and_counted() {
    let mut board = app();
    let mut g = gyro(1, 0.0);
    g.rates_radps[1] = f32::NAN;
    board.on_rx_bytes(
        &enc(&AutopilotToStereo::GyroAttitude(g)),
        at(10),
        &mut |_| {},
        None,
    );
    g.rates_radps[1] = 0.0;
    g.attitude_rad[0] = f32::INFINITY;
    board.on_rx_bytes(
        &enc(&AutopilotToStereo::GyroAttitude(g)),
        at(10),
        &mut |_| {},
        None,
    );
    assert_eq!(board.current_gyro(at(10)), None);
    assert_eq!(board.counters().gyro_rejected, 2);
}

/// Sends one parameter request over the autopilot link and returns the board's one answer.
fn ask(board: &mut StereoBoardApp, node: Node, op: ParamOp) -> ParamReply {
    let mut wire = Vec::new();
    let req = AutopilotToStereo::Param(ParamRequest { board: node, op });
    board.on_rx_bytes(&enc(&req), at(0), &mut |b| wire.extend_from_slice(b), None);
    let (msgs, errors) = decode_out(&wire);
    assert_eq!(errors.total(), 0);
    match msgs.as_slice() {
        [StereoToAutopilot::Param(r)] => {
            assert_eq!(r.board, node);
            r.reply.clone()
        }
        other => panic!("one parameter answer expected, got {other:?}"),
    }
}

#[test]
fn parameters_are_listed_read_and_set_over_the_link() {
    let mut board = app();
    let name = |n: &str| ParamName::try_from(n).unwrap();
    let ParamReply::Entry(first) = ask(&mut board, Node::StereoBoard, ParamOp::List(0)) else {
        panic!("entry 0");
    };
    assert_eq!(usize::from(first.count), crate::params::COUNT);
    assert_eq!(first.name.as_str(), "half_window");

    // A signed value is set, answered with the value now in use, and reaches Edge-FS.
    let set = ParamOp::Set(name("stereo_shift"), ParamValue::I32(-6));
    let ParamReply::Entry(e) = ask(&mut board, Node::StereoBoard, set) else {
        panic!("set stereo_shift");
    };
    assert_eq!(
        (e.value, e.default),
        (ParamValue::I32(-6), ParamValue::I32(0))
    );
    assert_eq!(board.params().stereo_shift_px, -6);
    assert_eq!(board.edge_fs().params().stereo_shift_px, -6);
    let ParamReply::Entry(e) = ask(
        &mut board,
        Node::StereoBoard,
        ParamOp::Get(name("stereo_shift")),
    ) else {
        panic!("get stereo_shift");
    };
    assert_eq!(e.value, ParamValue::I32(-6));

    // Refusals change nothing.
    let before = *board.params();
    let cases = [
        (
            ParamOp::Set(name("stereo_shift"), ParamValue::I32(-21)),
            ParamError::OutOfBounds,
        ),
        (
            ParamOp::Set(name("half_window"), ParamValue::F32(3.0)),
            ParamError::WrongKind,
        ),
        (
            ParamOp::Set(name("no_such"), ParamValue::U32(1)),
            ParamError::UnknownName,
        ),
        (
            ParamOp::List(crate::params::COUNT as u16),
            ParamError::UnknownIndex,
        ),
        (ParamOp::Save, ParamError::NoStorage),
    ];
    for (op, want) in cases {
        assert_eq!(
            ask(&mut board, Node::StereoBoard, op.clone()),
            ParamReply::Error(want),
            "{op:?}"
        );
    }
    assert_eq!(
        ask(&mut board, Node::Autopilot, ParamOp::List(0)),
        ParamReply::Error(ParamError::NoSuchBoard)
    );
    assert_eq!(*board.params(), before);
}

/// One parameter request over the link of a board with storage `store`; the one answer.
fn ask_stored(board: &mut StereoBoardApp, store: &mut MemStore<512>, op: ParamOp) -> ParamReply {
    let mut wire = Vec::new();
    let req = AutopilotToStereo::Param(ParamRequest {
        board: Node::StereoBoard,
        op,
    });
    board.on_rx_bytes(
        &enc(&req),
        at(0),
        &mut |b| wire.extend_from_slice(b),
        Some(store),
    );
    match decode_out(&wire).0.as_slice() {
        [StereoToAutopilot::Param(r)] => r.reply.clone(),
        other => panic!("one parameter answer expected, got {other:?}"),
    }
}

#[test]
fn parameters_saved_over_the_link_load_at_the_next_boot() {
    let name = |n: &str| ParamName::try_from(n).unwrap();
    let mut sector = MemStore::<512>::blank();
    let mut board = app();
    assert_eq!(board.load_params(&sector), Err(RecordError::Blank));
    assert_eq!(*board.params(), EdgeFsParams::default_config());
    let set = ParamOp::Set(name("stereo_shift"), ParamValue::I32(-4));
    assert!(matches!(
        ask_stored(&mut board, &mut sector, set),
        ParamReply::Entry(_)
    ));
    assert_eq!(
        ask_stored(&mut board, &mut sector, ParamOp::Save),
        ParamReply::Saved
    );
    assert_eq!(
        ask_stored(&mut board, &mut sector, ParamOp::Storage),
        ParamReply::Storage(StorageStatus {
            loaded: Err(RecordError::Blank),
            saves: 1,
            failed_saves: 0,
            acknowledged: false,
        })
    );
    // The record is the table's, with its version, where the flash sector starts; the first
    // save is numbered 1 (the free function numbers 0, so the CRC differs too).
    let mut record = [0u8; crate::params::RECORD_BYTES];
    crate::params::encode_record(board.params(), &mut record).unwrap();
    let (header, crc_at) = (protocol::params::RECORD_HEADER_BYTES, record.len() - 4);
    assert_eq!(&sector.bytes[..12], &record[..12]);
    assert_eq!(protocol::params::record_sequence(&sector.bytes), Some(1));
    assert_eq!(&sector.bytes[header..crc_at], &record[header..crc_at]);

    // The next boot runs Edge-FS on the saved value and says so.
    let mut next = app();
    assert_eq!(next.load_params(&sector), Ok(()));
    assert_eq!(next.params().stereo_shift_px, -4);
    assert_eq!(next.edge_fs().params().stereo_shift_px, -4);
    assert!(matches!(
        ask_stored(&mut next, &mut sector, ParamOp::Storage),
        ParamReply::Storage(StorageStatus {
            loaded: Ok(()),
            saves: 0,
            ..
        })
    ));

    // A flash that refuses is a failed save, counted; the saved record stays.
    sector.refuse = true;
    assert_eq!(
        ask_stored(&mut next, &mut sector, ParamOp::Save),
        ParamReply::Error(ParamError::SaveFailed)
    );
    assert_eq!(next.storage().map(|s| s.failed_saves), Some(1));

    // A corrupt or older record means the defaults, and why.
    let mut corrupt = sector.clone();
    corrupt.bytes[20] ^= 0x04;
    let mut third = app();
    assert_eq!(third.load_params(&corrupt), Err(RecordError::BadCrc));
    assert_eq!(*third.params(), EdgeFsParams::default_config());
    let mut older = sector.clone();
    older.bytes[4] = 0;
    assert!(matches!(
        app().load_params(&older),
        Err(RecordError::FormatVersion(_) | RecordError::BadCrc)
    ));
    // A board without storage says so.
    assert_eq!(
        ask(&mut app(), Node::StereoBoard, ParamOp::Storage),
        ParamReply::Error(ParamError::NoStorage)
    );
}

#[test]
fn link_errors_are_counted_and_the_next_frame_still_decodes() {
    let mut board = app();
    let mut bytes = vec![0x13, 0x77, 0x42, 0x00, 0xff, 0x01, 0x00];
    let mut corrupt = enc(&AutopilotToStereo::Heartbeat(Heartbeat::new(
        Node::Autopilot,
        5,
    )));
    corrupt[2] ^= 0x10;
    bytes.extend_from_slice(&corrupt);
    bytes.extend_from_slice(&enc(&AutopilotToStereo::Heartbeat(Heartbeat::new(
        Node::Autopilot,
        1234,
    ))));
    board.on_rx_bytes(&bytes, at(0), &mut |_| {}, None);
    // Three bad frames; the first is taken for the tail of a frame sent before the board
    // listened (the link joins mid-stream) and is not counted.
    assert_eq!(board.link_errors().total(), 2, "{:?}", board.link_errors());
    assert_eq!(board.peer_uptime_ms(), Some(1234));
    assert_eq!(board.link_frames_ok(), 1);
}

#[test]
fn status_tick_reports_rate_counters_and_heartbeat() {
    let mut board = app();
    board.status_tick(at(0), None, &mut |_| {}, &mut |_| {});
    for i in 0..25u64 {
        let t = 40_000 * i;
        run_frame(
            &mut board,
            &frame(i as usize, 2),
            at(t),
            at(t + 5_000 + i),
            &mut |_| {},
        );
    }
    board.frame_dropped();
    // The leading delimiter aligns the link (joined mid-stream); the garbage after it counts.
    board.on_rx_bytes(&[0, 1, 2, 3, 0], at(0), &mut |_| {}, None);
    let mut wire = Vec::new();
    let status = board.status_tick(
        at(1_000_000),
        None,
        &mut |b| wire.extend_from_slice(b),
        &mut |_| {},
    );
    assert!(
        (status.frame_rate_hz - 25.0).abs() < 1e-4,
        "{}",
        status.frame_rate_hz
    );
    assert_eq!(status.frames_processed, 25);
    assert_eq!(status.frames_dropped, 1);
    assert_eq!(status.max_processing_us, 5_024);
    assert_eq!(status.uptime_ms, 1_000);
    assert_eq!(status.link_errors.total(), 1);
    let (msgs, errors) = decode_out(&wire);
    assert_eq!(errors.total(), 0);
    assert_eq!(
        msgs,
        vec![
            StereoToAutopilot::Status(status),
            StereoToAutopilot::Heartbeat(Heartbeat::new(Node::StereoBoard, 1_000)),
        ]
    );
    let next = board.status_tick(at(2_000_000), None, &mut |_| {}, &mut |_| {});
    assert_eq!(next.frame_rate_hz, 0.0);
    assert_eq!(
        next.max_processing_us, 0,
        "worst time restarts each interval"
    );
}

#[test]
fn status_carries_the_capture_counters_and_a_stopped_camera() {
    use crate::camera::{CaptureMonitor, DmaAtFrameEnd, FRAME_WORDS};
    let mut board = app();
    let mut camera = CaptureMonitor::new();
    camera.on_capture_started(at(0));
    camera.on_dcmi_overrun();
    let whole = DmaAtFrameEnd {
        transfer_complete: true,
        remaining_words: FRAME_WORDS,
    };
    camera.on_frame_end(whole);
    camera.on_rearm();
    camera.on_frame_end(whole);
    let now = 1_000_000;
    let capture = Some((camera.counts(), camera.camera_stopped(at(now))));
    let mut wire = Vec::new();
    let status = board.status_tick(
        at(now),
        capture,
        &mut |b| wire.extend_from_slice(b),
        &mut |_| {},
    );
    assert!(status.camera_stopped, "no VSYNC for a second");
    assert_eq!(status.capture, camera.counts());
    let c = status.capture;
    assert_eq!(
        (c.dcmi_overruns, c.frames_torn, c.rearms, c.frames_complete),
        (1, 1, 1, 1)
    );
    let (msgs, _) = decode_out(&wire);
    assert_eq!(msgs.first(), Some(&StereoToAutopilot::Status(status)));

    camera.on_vsync(at(now));
    let capture = Some((camera.counts(), camera.camera_stopped(at(now + 1))));
    assert!(
        !board
            .status_tick(at(now + 1), capture, &mut |_| {}, &mut |_| {})
            .camera_stopped
    );
}

#[test]
fn a_frame_overwritten_during_processing_sends_nothing_and_clears_the_history() {
    let mut board = app();
    let mut wire = Vec::new();
    for i in 0..12u64 {
        let t = 40_000 * i;
        run_frame(&mut board, &frame(i as usize, 4), at(t), at(t), &mut |b| {
            wire.extend_from_slice(b)
        });
    }
    let sent = decode_out(&wire).0.len();
    let f = frame(12, 4);
    let refilled = StereoFrame {
        pixels: &f,
        capture: at(480_000),
        start: at(480_000),
    };
    let outcome = board.on_frame(
        0,
        Some(refilled),
        || None,
        &mut |b| wire.extend_from_slice(b),
        &mut |_| {},
    );
    assert_eq!(outcome, FrameOutcome::Discarded);
    assert_eq!(decode_out(&wire).0.len(), sent, "nothing sent");
    assert_eq!(board.counters().frames_dropped, 1);
    // The history restarts: the next estimate is flagged as still filling.
    let f = frame(13, 4);
    let est = run_frame(&mut board, &f, at(520_000), at(520_000), &mut |_| {});
    assert!(
        est.flags.contains(EstimateFlags::HISTORY_FILLING),
        "{:?}",
        est.flags
    );
}

#[test]
fn stereo_range_set_over_the_link_bounds_the_default_modes_disparity_search() {
    // A scene at 12 px disparity: found with the default range (15), out of reach at 8.
    let run = |range: Option<u32>| {
        let mut board = app();
        if let Some(range) = range {
            let name = ParamName::try_from("stereo_range").unwrap();
            let set = ParamOp::Set(name, ParamValue::U32(range));
            let ParamReply::Entry(e) = ask(&mut board, Node::StereoBoard, set) else {
                panic!("set stereo_range");
            };
            assert_eq!(e.value, ParamValue::U32(range));
        }
        let f = frame(0, 12);
        run_frame(&mut board, &f, at(0), at(0), &mut |_| {});
        let d = board.edge_fs().diagnostics().disparity_px;
        let max = d.iter().copied().fold(0.0f32, f32::max);
        (board.params().stereo_range, max)
    };
    let (range, wide) = run(None);
    assert_eq!(range, 15);
    let (range, narrow) = run(Some(8));
    assert_eq!(range, 8, "the set reaches the default mode's stereo range");
    assert!(
        wide > 11.0,
        "default range finds the 12 px disparity: {wide}"
    );
    assert!(
        narrow <= 8.5,
        "no disparity beyond the configured range: {narrow}"
    );
}

fn chunks(f: &[u8; STEREO_FRAME_BYTES], frame_id: u16, capture_us: u32) -> Vec<FrameChunk> {
    f.chunks(FRAME_CHUNK_BYTES)
        .enumerate()
        .map(|(i, data)| FrameChunk {
            frame_id,
            capture_us: WireTime(capture_us),
            offset: (i * FRAME_CHUNK_BYTES) as u16,
            data: heapless::Vec::from_slice(data).unwrap(),
        })
        .collect()
}

#[test]
fn assembler_rebuilds_a_frame_from_chunks_in_any_order() {
    let f = frame(5, 3);
    let mut cs = chunks(&f, 9, 777);
    assert_eq!(cs.len(), 48);
    cs.reverse();
    cs.swap(3, 30);
    let mut asm = Box::new(FrameAssembler::new());
    let last = cs.pop().unwrap();
    for c in &cs {
        assert_eq!(asm.push(c), None);
    }
    assert_eq!(
        asm.push(&cs[0]),
        None,
        "a duplicate does not complete the frame"
    );
    assert_eq!(asm.push(&last), Some(WireTime(777)));
    assert_eq!(&asm.frame()[..], &f[..]);
    assert_eq!(asm.frames_complete(), 1);
    assert_eq!(asm.frames_incomplete(), 0);
}

#[test]
fn assembler_drops_incomplete_frames_and_rejects_bad_chunks() {
    let a = frame(1, 1);
    let b = frame(2, 1);
    let mut asm = Box::new(FrameAssembler::new());
    let ca = chunks(&a, 1, 100);
    for c in ca.iter().take(47) {
        assert_eq!(asm.push(c), None);
    }
    let mut done = None;
    for c in chunks(&b, 2, 200) {
        done = asm.push(&c).or(done);
    }
    assert_eq!(done, Some(WireTime(200)));
    assert_eq!(&asm.frame()[..], &b[..]);
    assert_eq!(asm.frames_incomplete(), 1);

    let mut odd = ca[0].clone();
    odd.offset = 3;
    assert_eq!(asm.push(&odd), None);
    let mut short = ca[1].clone();
    short.data.truncate(100);
    assert_eq!(asm.push(&short), None);
    let mut beyond = ca[2].clone();
    beyond.offset = STEREO_FRAME_BYTES as u16;
    assert_eq!(asm.push(&beyond), None);
    assert_eq!(asm.bad_chunks(), 3);
}

#[test]
fn host_link_frames_reach_the_frame_task() {
    let mut board = app();
    let mut asm = Box::new(FrameAssembler::new());
    let f0 = frame(3, 2);
    let f1 = frame(4, 2);
    let mut wire = Vec::new();
    // Frame 0 near the end of the host's u32 clock, frame 1 after it wrapped.
    for c in chunks(&f0, 0, u32::MAX - 10) {
        wire.extend(enc(&HostToBoard::FrameChunk(c)));
    }
    wire.extend(enc(&HostToBoard::Heartbeat(Heartbeat::new(Node::Host, 1))));
    for c in chunks(&f1, 1, 30) {
        wire.extend(enc(&HostToBoard::FrameChunk(c)));
    }
    let mut got: Vec<(Box<[u8; STEREO_FRAME_BYTES]>, u64)> = Vec::new();
    // Arbitrary split points, as the receive queue delivers them.
    for piece in wire.chunks(333) {
        board.on_host_bytes(piece, &mut asm, |fr, t| {
            got.push((Box::new(*fr), t.as_micros()));
            false
        });
    }
    assert_eq!(got.len(), 2);
    assert_eq!(&got[0].0[..], &f0[..]);
    assert_eq!(&got[1].0[..], &f1[..]);
    assert_eq!(got[0].1, u64::from(u32::MAX - 10));
    assert_eq!(got[1].1, (1u64 << 32) + 30, "host clock unwrapped");
    assert_eq!(board.host_link_errors().total(), 0);
    assert_eq!(board.counters().frames_dropped, 0);
}

#[test]
fn incomplete_host_frames_count_as_dropped() {
    let mut board = app();
    let mut asm = Box::new(FrameAssembler::new());
    let mut wire = Vec::new();
    for c in chunks(&frame(0, 0), 0, 0).into_iter().skip(1) {
        wire.extend(enc(&HostToBoard::FrameChunk(c)));
    }
    for c in chunks(&frame(1, 0), 1, 40_000) {
        wire.extend(enc(&HostToBoard::FrameChunk(c)));
    }
    let mut n = 0;
    board.on_host_bytes(&wire, &mut asm, |_, _| {
        n += 1;
        false
    });
    assert_eq!(n, 1);
    assert_eq!(board.counters().frames_dropped, 1);
}

#[test]
fn the_app_fits_a_ccm_static() {
    // Placed in the 64 kB CCM next to nothing else large.
    assert!(size_of::<StereoBoardApp>() < 24 * 1024);
    assert!(size_of::<FrameAssembler>() < STEREO_FRAME_BYTES + 64);
}

mod prop {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        #[test]
        fn arbitrary_link_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600),
                                            now in any::<u64>()) {
            let mut board = app();
            let mut asm = Box::new(FrameAssembler::new());
            let mut out = Vec::new();
            board.on_rx_bytes(&bytes, at(now), &mut |b| out.extend_from_slice(b), None);
            board.on_host_bytes(&bytes, &mut asm, |_, _| false);
            board.status_tick(at(now), None, &mut |b| out.extend_from_slice(b), &mut |_| {});
            let (_, errors) = decode_out(&out);
            prop_assert_eq!(errors.total(), 0);
        }

        #[test]
        fn any_chunk_is_handled(frame_id in any::<u16>(), offset in any::<u16>(),
                                len in 0usize..=FRAME_CHUNK_BYTES, capture in any::<u32>()) {
            let mut asm = Box::new(FrameAssembler::new());
            let chunk = FrameChunk {
                frame_id, capture_us: WireTime(capture), offset,
                data: heapless::Vec::from_slice(&vec![7u8; len]).unwrap(),
            };
            prop_assert_eq!(asm.push(&chunk), None);
        }
    }
}

#[test]
fn autopilot_decoder_type_matches_the_link() {
    // The firmware sizes its RX DMA buffer from this decoder type's frame size.
    let _d: AutopilotToStereoDecoder = AutopilotToStereoDecoder::new();
    assert_eq!(size_of::<[u8; AutopilotToStereo::MAX_FRAME_BYTES]>(), A2S_N);
}
