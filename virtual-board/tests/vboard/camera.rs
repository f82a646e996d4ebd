//! Test 2: the camera board captures recorded frames through its DCMI and sends estimates over
//! its link that are bit-exact with the host library on the same frames, with no frame dropped.
//!
//! The unmodified `real` image runs on the camera board (`boards::camera`): the TCM8230 pair
//! streams recorded data-set images at its frame rate (24.65 fps from the 21 MHz master clock)
//! only once the firmware has brought it up as the original board does; the DCMI captures them
//! into memory through DMA2; the firmware's estimates leave on UART4. The host reference is the
//! same `stereo-board` library fed the same frames with the capture times the firmware reported.
//!
//! It runs at both core rates ([`CoreRate`]): the worst frame's processing time (the board's
//! own `max_processing_us`, in virtual time) against the 40 ms period of 25 fps, and the link's
//! queues (nothing received lost, nothing to send dropped).

use std::path::PathBuf;

use protocol::{Decoder, Estimate, StereoToAutopilot};
use stereo_board::app::{StereoBoardApp, StereoFrame};
use stereo_board::edge_fs::EdgeFsParams;
use virtual_board::bench::{Options, Setup, Watching, run};
use virtual_board::boards::camera::CameraBoard;
use virtual_board::firmware::Firmware;
use virtual_board::frames::Recorded;
use virtual_board::timing::CoreRate;

/// The frame period the processing must fit, µs: 25 fps.
const FRAME_PERIOD_US: u32 = 40_000;

/// Recorded frames streamed: three seconds of the camera's output (the 1 Hz status reports
/// come in too).
const FRAMES: usize = 74;

/// The recorded take the test plays (see [`virtual_board::frames::data_set_take_1`]).
fn take() -> PathBuf {
    virtual_board::frames::data_set_take_1()
}

fn decode(bytes: &[u8]) -> (Vec<StereoToAutopilot>, u32) {
    let mut decoder: Decoder<StereoToAutopilot, 256> = Decoder::new_mid_stream();
    let mut out = Vec::new();
    decoder.feed(bytes, |m| out.push(m));
    (out, decoder.errors().total())
}

fn same(a: &Estimate, b: &Estimate) -> bool {
    a.seq == b.seq
        && a.capture_us == b.capture_us
        && a.forward_mps.to_bits() == b.forward_mps.to_bits()
        && a.sideways_mps.to_bits() == b.sideways_mps.to_bits()
        && a.obstacle_m.map(f32::to_bits) == b.obstacle_m.map(f32::to_bits)
        && a.quality == b.quality
        && a.flags == b.flags
}

#[test]
fn estimates_over_the_link_equal_the_host_library_on_recorded_frames() {
    estimates_at(CoreRate::Default);
}

/// The same at 1.5 cycles per instruction: every frame still processed within its period.
#[test]
fn estimates_keep_up_with_the_camera_on_a_slow_core() {
    estimates_at(CoreRate::Pessimistic);
}

fn estimates_at(rate: CoreRate) {
    let recorded = Recorded::from_take(&take(), FRAMES).expect("the data set's take 1");
    let images = recorded.images().to_vec();
    let firmware = Firmware::real("stereo-board").expect("the camera-board image");
    let mut board = CameraBoard::new(Box::new(recorded)).expect("the board");
    board.soc.set_core_rate(rate);
    // Boot and camera bring-up, then the frames at 40.56 ms each, and one frame of slack.
    let outcome = run(
        Setup {
            board,
            firmware,
            probe: Watching,
        },
        Options::seconds(0.5 + (FRAMES + 1) as f64 * 0.040_56),
    )
    .expect("the run");
    outcome.assert_clean();
    let board = outcome.board();
    let report = || {
        format!(
            "{}\ndcmi {:?}\nsensor {:?}",
            outcome.report(),
            board.dcmi_stats(),
            board.sensor.lock().power()
        )
    };
    let captured = board.captured();
    let stats = board.dcmi_stats();
    assert!(
        captured.len() >= FRAMES - 2,
        "the DCMI captured {} frames of {FRAMES}\n{}",
        captured.len(),
        report()
    );
    assert_eq!(stats.words_lost, 0, "no overrun\n{}", report());
    for pair in captured.windows(2) {
        assert_eq!(
            pair[1].0,
            pair[0].0 + 1,
            "the DCMI captured every camera frame in turn\n{}",
            report()
        );
    }

    let (messages, errors) = decode(&board.link.tx.sent_bytes());
    assert_eq!(errors, 0, "the link carried only well-formed frames");
    // The board's own account (its 1 Hz status): every frame processed, none dropped, none torn,
    // the camera running.
    let statuses: Vec<_> = messages
        .iter()
        .filter_map(|m| match m {
            StereoToAutopilot::Status(s) => Some(*s),
            _ => None,
        })
        .collect();
    let last = statuses.last().expect("the board reports its status");
    assert!(statuses.len() >= 3, "a status a second\n{}", report());
    // The worst frame of each second after the first (the first status line may cover none).
    let worst_us = statuses[1..]
        .iter()
        .map(|s| s.max_processing_us)
        .max()
        .unwrap_or(0);
    println!(
        "{}: worst frame {worst_us} us of the {FRAME_PERIOD_US} us frame period ({:.1} %), {} \
         statuses",
        rate.label(),
        f64::from(worst_us) / f64::from(FRAME_PERIOD_US) * 100.0,
        statuses.len()
    );
    assert!(
        worst_us > 0 && worst_us < FRAME_PERIOD_US,
        "worst frame {worst_us} us, period {FRAME_PERIOD_US} us\n{}",
        report()
    );
    for queue in ["rx_lost", "link_tx_dropped"] {
        assert_eq!(
            outcome.log.status(queue),
            Some(0),
            "{queue} in the last status line\n{}",
            report()
        );
    }
    assert!(
        last.frames_dropped == 0
            && !last.camera_stopped
            && last.capture.frames_torn == 0
            && last.capture.dcmi_overruns == 0
            && last.capture.dma_errors == 0
            && last.frames_processed >= 48,
        "the board's status: {last:?}\n{}",
        report()
    );
    let estimates: Vec<Estimate> = messages
        .iter()
        .filter_map(|m| match m {
            StereoToAutopilot::Estimate(e) => Some(*e),
            _ => None,
        })
        .collect();
    // Every captured frame but possibly the last (still being processed at the end) has its
    // estimate, in order, with consecutive sequence numbers: no frame dropped.
    assert!(
        estimates.len() + 1 >= captured.len(),
        "{} estimates for {} captured frames\n{}",
        estimates.len(),
        captured.len(),
        report()
    );
    let mut reference = StereoBoardApp::new(EdgeFsParams::default_config());
    let mut valid_velocity = 0;
    for (k, got) in estimates.iter().enumerate() {
        if k > 0 {
            assert_eq!(
                got.seq,
                estimates[k - 1].seq.wrapping_add(1),
                "frame dropped"
            );
        }
        let scene = usize::try_from(captured[k].0)
            .expect("a frame number")
            .min(FRAMES - 1);
        let frame = images[scene].interleaved();
        let capture = timebase::Instant::from_micros(u64::from(got.capture_us.as_micros()));
        let input = StereoFrame {
            pixels: &frame,
            capture,
            start: capture,
        };
        let want = reference
            .on_frame(0, Some(input), || Some(capture), &mut |_| {}, &mut |_| {})
            .estimate()
            .expect("an intact frame sends an estimate");
        assert!(
            same(got, &want),
            "frame {k} (scene {scene}): firmware {got:?}\nhost     {want:?}\n{}",
            report()
        );
        if got.forward_mps != 0.0 || got.sideways_mps != 0.0 {
            valid_velocity += 1;
        }
    }
    assert!(
        valid_velocity >= 1,
        "velocities were estimated (history filled)"
    );
}
