//! Boots both firmwares (qemu flavour) in two QEMUs whose board-to-board UARTs are joined
//! through this test (loopback sockets), which decodes every byte in both directions on the
//! way. The camera board gets synthetic frames on its host link, so estimates flow too. The
//! autopilot runs in lockstep with its host link's IMU samples (world time): a feeder sends
//! samples of a drone at rest, so its periodic tasks (gyro/attitude to the camera board) run.
//!
//! Passes when the protocol flows both ways (heartbeats, status, estimates one way; heartbeats
//! and gyro/attitude the other) with zero decoding errors, seen both by this relay and by the
//! boards' own counters (their semihosting status lines).

#[path = "qemu_support.rs"]
mod support;

use protocol::{
    AutopilotToStereo, AutopilotToStereoDecoder, LinkErrorCounts, StereoToAutopilot,
    StereoToAutopilotDecoder, STEREO_FRAME_BYTES,
};
use std::io::{Read, Write};
use std::net::TcpStream;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use support::{last_field, qemu_firmwares, require_qemu, HostLink, Port, Qemu, RestImuFeeder};

/// Frames streamed to the camera board (each takes seconds through QEMU's USART model).
const FRAMES: usize = 3;

#[derive(Debug, Default, Clone)]
struct Seen {
    s2a_heartbeat: u32,
    s2a_status: u32,
    s2a_estimate: u32,
    s2a_errors: LinkErrorCounts,
    a2s_heartbeat: u32,
    a2s_gyro: u32,
    a2s_errors: LinkErrorCounts,
}

/// Copies `from` to `to`, decoding every byte with `decode`.
fn relay(mut from: TcpStream, mut to: TcpStream, mut decode: impl FnMut(&[u8]) + Send + 'static) {
    std::thread::spawn(move || {
        let mut buf = [0u8; 1024];
        while let Ok(n) = from.read(&mut buf) {
            if n == 0 {
                break;
            }
            decode(&buf[..n]);
            if to.write_all(&buf[..n]).is_err() {
                break;
            }
        }
    });
}

fn synthetic_frame(k: usize) -> Vec<u8> {
    let mut f = vec![0u8; STEREO_FRAME_BYTES];
    for y in 0..96 {
        for x in 0..128 {
            let tex = |u: usize| ((u * 2654435761usize) >> 7) as u8 & 0xF0 | (y as u8 & 0x0F);
            let i = 2 * (y * 128 + x);
            f[i] = tex(x + k);
            f[i + 1] = tex(x + k + 4);
        }
    }
    f
}

#[test]
fn both_firmwares_talk_over_loopback_without_errors() {
    require_qemu();
    let (stereo_elf, autopilot_elf) = qemu_firmwares();
    let s_link = Port::bind();
    let a_link = Port::bind();
    let s_host = Port::bind();
    let mut stereo = Qemu::start(
        &stereo_elf,
        &s_link.chardev("link"),
        &s_host.chardev("host"),
    );
    let a_host = Port::bind();
    let mut autopilot = Qemu::start_autopilot(
        &autopilot_elf,
        &a_link.chardev("link"),
        &a_host.chardev("host"),
    );
    let timeout = Duration::from_secs(30);
    let s = s_link.accept(timeout);
    let a = a_link.accept(timeout);
    let mut host = HostLink::new(s_host.accept(timeout));
    let a_host = a_host.accept(timeout);

    let seen = Arc::new(Mutex::new(Seen::default()));
    {
        let seen = Arc::clone(&seen);
        let mut dec = StereoToAutopilotDecoder::new();
        relay(
            s.try_clone().unwrap(),
            a.try_clone().unwrap(),
            move |bytes| {
                let mut g = seen.lock().unwrap();
                dec.feed(bytes, |m| match m {
                    StereoToAutopilot::Heartbeat(_) => g.s2a_heartbeat += 1,
                    StereoToAutopilot::Status(_) => g.s2a_status += 1,
                    StereoToAutopilot::Estimate(_) => g.s2a_estimate += 1,
                    StereoToAutopilot::ConfigAck(_) | StereoToAutopilot::Param(_) => {}
                });
                g.s2a_errors = dec.errors();
            },
        );
    }
    {
        let seen = Arc::clone(&seen);
        let mut dec = AutopilotToStereoDecoder::new();
        relay(a, s, move |bytes| {
            let mut g = seen.lock().unwrap();
            dec.feed(bytes, |m| match m {
                AutopilotToStereo::Heartbeat(_) => g.a2s_heartbeat += 1,
                AutopilotToStereo::GyroAttitude(_) => g.a2s_gyro += 1,
                AutopilotToStereo::Config(_) | AutopilotToStereo::Param(_) => {}
            });
            g.a2s_errors = dec.errors();
        });
    }
    // Frames go in one at a time (QEMU's USART model takes a few kB/s, so a frame needs
    // seconds): the next one when the estimate of the previous one is back.
    stereo.wait_for_log("status", timeout);
    autopilot.wait_for_log("status", timeout);
    let feeder = RestImuFeeder::start(a_host);
    let start = Instant::now();
    let mut estimates = 0;
    for k in 0..FRAMES {
        host.send_frame(&synthetic_frame(k), k as u16, (k as u32) * 40_000);
        if host.next_estimate(Duration::from_secs(120)).is_some() {
            estimates += 1;
        }
        stereo.assert_running();
        autopilot.assert_running();
    }
    // Let the last estimate and a status go through, and the link run a few seconds.
    let settle =
        Duration::from_secs(6).saturating_sub(start.elapsed()) + Duration::from_millis(1500);
    std::thread::sleep(settle);
    let (imu_sent, motor_replies) = feeder.finish();
    let g = seen.lock().unwrap().clone();
    let slog = stereo.log();
    let alog = autopilot.log();
    drop(stereo);
    drop(autopilot);
    let report = format!("{g:#?}\nimu samples {imu_sent}, motor replies {motor_replies}\nstereo log:\n{slog}\nautopilot log:\n{alog}");

    assert_eq!(
        estimates, FRAMES,
        "every frame answered on the host link: {report}"
    );
    assert_eq!(host.errors().total(), 0, "{report}");
    assert!(
        motor_replies + 2 >= imu_sent && imu_sent >= 500,
        "the autopilot answers every IMU sample: {report}"
    );
    assert_eq!(g.s2a_errors.total(), 0, "{report}");
    assert_eq!(g.a2s_errors.total(), 0, "{report}");
    assert!(g.s2a_heartbeat >= 3 && g.s2a_status >= 3, "{report}");
    assert!(
        g.s2a_estimate >= 3,
        "estimates flow to the autopilot: {report}"
    );
    assert!(g.a2s_heartbeat >= 3, "{report}");
    assert!(g.a2s_gyro >= 100, "gyro/attitude at 128 Hz: {report}");
    // The boards' own view.
    assert_eq!(
        last_field(&slog, "status", "link_errors"),
        Some(0),
        "{report}"
    );
    assert_eq!(
        last_field(&slog, "status", "host_errors"),
        Some(0),
        "{report}"
    );
    assert_eq!(last_field(&slog, "status", "rx_lost"), Some(0), "{report}");
    assert!(
        last_field(&slog, "status", "link_rx_ok").unwrap_or(0) >= 100,
        "{report}"
    );
    assert!(
        last_field(&slog, "status", "frames").unwrap_or(0) >= FRAMES as u64 - 1,
        "{report}"
    );
    assert_eq!(
        last_field(&alog, "status", "link_errors"),
        Some(0),
        "{report}"
    );
    assert_eq!(last_field(&alog, "status", "rx_lost"), Some(0), "{report}");
    assert!(
        last_field(&alog, "status", "estimates").unwrap_or(0) >= FRAMES as u64 - 1,
        "{report}"
    );
}
