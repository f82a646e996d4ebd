//! Real recorded frames (the shared data set) streamed to the camera-board firmware (qemu
//! flavour) over its host link, as `sim-host` does in HIL; the estimates it sends back must
//! equal what the host-side library computes for the same bytes.
//!
//! Expected: bit-exact. Both sides run the same `StereoBoardApp` code on IEEE-754 single
//! precision (the Cortex-M4F FPU and x86-64 SSE round every f32 operation the same way; f64
//! is soft-float on the M4 but equally correctly rounded; transcendental functions come from
//! the same pure-Rust `libm`), and Rust does not contract `a * b + c` into fused multiply-adds
//! on either target. Only `processing_us` differs (measured on each side).

#[path = "qemu_support.rs"]
mod support;

use protocol::STEREO_FRAME_BYTES;
use sim_host::eval::dataset::{discover_takes, load_frame};
use std::time::Duration;
use stereo_board::app::{FrameAssembler, StereoBoardApp};
use stereo_board::edge_fs::EdgeFsParams;
use support::{qemu_firmwares, require_qemu, HostLink, Port, Qemu};

/// Frames streamed: more than the flow horizon (5) + 1, so velocities are estimated.
const FRAMES: usize = 8;

#[test]
fn firmware_estimates_equal_the_host_library_on_real_frames() {
    require_qemu();
    let takes = discover_takes(&integration_tests::shared_dataset_dir()).expect("data set");
    let take = &takes[0];
    let frames: Vec<Box<[u8; STEREO_FRAME_BYTES]>> = (1..=FRAMES)
        .map(|i| load_frame(&take.image_path(i)).expect("frame loads"))
        .collect();

    let (stereo_elf, _) = qemu_firmwares();
    let s_host = Port::bind();
    let mut stereo = Qemu::start(&stereo_elf, "null,id=link", &s_host.chardev("host"));
    let mut host = HostLink::new(s_host.accept(Duration::from_secs(30)));
    stereo.wait_for_log("status", Duration::from_secs(30));

    // The host-side reference: the same app, fed the same frames through the same assembly
    // path (so the capture times are unwrapped identically).
    let mut reference = Box::new(StereoBoardApp::new(EdgeFsParams::default_config()));
    let mut assembler = Box::new(FrameAssembler::new());

    let mut compared = 0;
    let mut valid_velocity = 0;
    for (k, frame) in frames.iter().enumerate() {
        // 40 ms frame spacing on the host's (wrapping) clock.
        let capture = (k as u32) * 40_000;
        host.send_frame(&frame[..], k as u16, capture);
        let got = host
            .next_estimate(Duration::from_secs(120))
            .unwrap_or_else(|| panic!("no estimate for frame {k}; log:\n{}", stereo.log()));
        stereo.assert_running();

        let mut bytes = Vec::new();
        for (i, data) in frame.chunks(protocol::FRAME_CHUNK_BYTES).enumerate() {
            let msg = protocol::HostToBoard::FrameChunk(protocol::FrameChunk {
                frame_id: k as u16,
                capture_us: protocol::WireTime(capture),
                offset: (i * protocol::FRAME_CHUNK_BYTES) as u16,
                data: data.try_into().unwrap(),
            });
            let mut buf = [0u8; 600];
            let n = protocol::encode(&msg, &mut buf).unwrap();
            bytes.extend_from_slice(&buf[..n]);
        }
        let mut ready = None;
        reference.on_host_bytes(&bytes, &mut assembler, |_, t| ready = Some(t));
        let capture: timebase::Instant = ready.expect("host assembles the frame");
        let want = reference.on_frame(assembler.frame(), capture, capture, &mut |_| {});

        let same = got.seq == want.seq
            && got.capture_us == want.capture_us
            && got.forward_mps.to_bits() == want.forward_mps.to_bits()
            && got.sideways_mps.to_bits() == want.sideways_mps.to_bits()
            && got.obstacle_m.map(f32::to_bits) == want.obstacle_m.map(f32::to_bits)
            && got.quality == want.quality
            && got.flags == want.flags;
        assert!(same, "frame {k}: firmware {got:?}\nhost     {want:?}");
        compared += 1;
        if got.forward_mps != 0.0 || got.sideways_mps != 0.0 {
            valid_velocity += 1;
        }
    }
    assert_eq!(compared, FRAMES);
    assert!(
        valid_velocity >= 1,
        "velocities were estimated (history filled)"
    );
    assert_eq!(host.errors().total(), 0);
    let log = stereo.log();
    assert_eq!(
        support::last_field(&log, "status", "host_errors"),
        Some(0),
        "{log}"
    );
    assert_eq!(
        support::last_field(&log, "status", "dropped"),
        Some(0),
        "{log}"
    );
    assert_eq!(
        support::last_field(&log, "status", "rx_lost"),
        Some(0),
        "{log}"
    );
}
