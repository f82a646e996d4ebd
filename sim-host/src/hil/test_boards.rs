//! Two software boards for the tests, on loopback TCP: the autopilot's and the camera board's
//! own libraries run the way their lockstep firmwares do, their link UARTs wired to each
//! other; [`software_boards`] starts them and returns the host ends.

use crate::transport::is_transient_read_error;
use autopilot::app::Autopilot;
use autopilot::lockstep::{WorldClock, WorldTimers};
use autopilot::AutopilotConfig;
use autopilot::HostOutcome;
use protocol::{AutopilotToStereo, BoardToHost, Heartbeat, HostToBoardDecoder, MotorCommand, Node};
use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use stereo_board::app::{send_to_host, FrameAssembler, StereoBoardApp, StereoFrame};
use stereo_board::edge_fs::EdgeFsParams;

type Wire = Arc<Mutex<Vec<u8>>>;

fn send_host(stream: &mut TcpStream, msg: &BoardToHost) {
    let mut out = Vec::new();
    send_to_host(msg, &mut |b| out.extend_from_slice(b));
    let _ = stream.write_all(&out);
}

fn take(wire: &Wire) -> Vec<u8> {
    std::mem::take(&mut *wire.lock().unwrap())
}

/// The autopilot firmware's lockstep flavour, in software.
fn autopilot_board(mut s: TcpStream, to_camera: Wire, from_camera: Wire) {
    let mut ap = Autopilot::new(AutopilotConfig::default());
    let (mut clock, mut timers) = (WorldClock::new(), WorldTimers::new());
    let mut dec = HostToBoardDecoder::new();
    send_host(
        &mut s,
        &BoardToHost::Heartbeat(Heartbeat::new(Node::Autopilot, 0)),
    );
    let mut buf = [0u8; 512];
    while let Ok(n) = s.read(&mut buf) {
        if n == 0 {
            return;
        }
        let mut msgs = Vec::new();
        dec.feed(&buf[..n], |m| msgs.push(m));
        for m in msgs {
            // Lockstep: the world's time is the autopilot's clock.
            let now = clock.now().as_flight_clock();
            match ap.on_host_message(m, now, None) {
                HostOutcome::Imu(imu) => {
                    let world = clock.observe(imu.timestamp_us);
                    let now = world.as_flight_clock();
                    ap.on_stereo_bytes(&take(&from_camera), now);
                    let throttle = ap.on_imu(&imu, now);
                    let reply = MotorCommand {
                        timestamp_us: now.to_wire(),
                        throttle,
                    };
                    send_host(&mut s, &BoardToHost::Motors(reply));
                    let due = timers.due(now);
                    if due.guidance {
                        ap.guidance_step(now);
                    }
                    if due.gyro_tx {
                        let msg = AutopilotToStereo::GyroAttitude(ap.gyro_attitude(now));
                        let mut w = to_camera.lock().unwrap();
                        crate::sim::boards::send(&msg, &mut |b| w.extend_from_slice(b));
                    }
                    if due.telemetry {
                        send_host(&mut s, &BoardToHost::Telemetry(ap.telemetry(now)));
                    }
                    if let Some(answer) = ap.take_camera_param_reply() {
                        send_host(&mut s, &BoardToHost::Param(answer));
                    }
                }
                HostOutcome::Reply(reply) => send_host(&mut s, &reply),
                HostOutcome::ToCamera(msg) => {
                    {
                        let mut w = to_camera.lock().unwrap();
                        crate::sim::boards::send(&msg, &mut |b| w.extend_from_slice(b));
                    }
                    // As the firmware's link task: the answer goes to the host as it comes
                    // (the camera board answers on its own thread).
                    let deadline = Instant::now() + Duration::from_secs(2);
                    while Instant::now() < deadline {
                        ap.on_stereo_bytes(&take(&from_camera), clock.now().as_flight_clock());
                        if let Some(answer) = ap.take_camera_param_reply() {
                            send_host(&mut s, &BoardToHost::Param(answer));
                            break;
                        }
                        std::thread::sleep(Duration::from_millis(1));
                    }
                }
                HostOutcome::Done => {}
            }
        }
    }
}

/// The camera board firmware's lockstep flavour, in software.
fn camera_board(mut s: TcpStream, to_autopilot: Wire, from_autopilot: Wire) {
    let mut cb = Box::new(StereoBoardApp::new(EdgeFsParams::default_config()));
    let mut frames = Box::new(FrameAssembler::new());
    send_host(
        &mut s,
        &BoardToHost::Heartbeat(Heartbeat::new(Node::StereoBoard, 0)),
    );
    let mut world = timebase::Instant::ZERO;
    let mut buf = [0u8; 4096];
    // Until the first frame the board also answers the autopilot link as bytes come (the
    // parameter requests before a flight); from then on at each frame, as before.
    let mut first_frame_seen = false;
    s.set_read_timeout(Some(Duration::from_millis(2))).unwrap();
    loop {
        let n = match s.read(&mut buf) {
            Ok(0) => return,
            Ok(n) => n,
            Err(e) if is_transient_read_error(&e) => {
                if !first_frame_seen {
                    let mut w = to_autopilot.lock().unwrap();
                    cb.on_rx_bytes(
                        &take(&from_autopilot),
                        world,
                        &mut |b| w.extend_from_slice(b),
                        None,
                    );
                }
                continue;
            }
            Err(_) => return,
        };
        let mut ready = None;
        cb.on_host_bytes(&buf[..n], &mut frames, |_, t| {
            ready = Some(t);
            false
        });
        if let Some(capture) = ready {
            first_frame_seen = true;
            world = world.max(capture);
            let mut w = to_autopilot.lock().unwrap();
            cb.on_rx_bytes(
                &take(&from_autopilot),
                world,
                &mut |b| w.extend_from_slice(b),
                None,
            );
            let frame = StereoFrame {
                pixels: frames.frame(),
                capture,
                start: world,
            };
            let mut to_host = Vec::new();
            cb.on_frame(
                0,
                Some(frame),
                || Some(world),
                &mut |b| w.extend_from_slice(b),
                &mut |b| to_host.extend_from_slice(b),
            );
            drop(w);
            let _ = s.write_all(&to_host);
        }
    }
}

fn pair() -> (TcpStream, TcpStream) {
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    let c = TcpStream::connect(l.local_addr().unwrap()).unwrap();
    let (s, _) = l.accept().unwrap();
    c.set_nodelay(true).unwrap();
    s.set_nodelay(true).unwrap();
    (c, s)
}

/// The two software boards, wired to each other; returns the host ends (camera,
/// autopilot).
pub(super) fn software_boards() -> (TcpStream, TcpStream) {
    let (a2s, s2a): (Wire, Wire) = Default::default();
    let (ap_host, ap_board) = pair();
    let (cam_host, cam_board) = pair();
    {
        let (a, b) = (Arc::clone(&a2s), Arc::clone(&s2a));
        std::thread::spawn(move || autopilot_board(ap_board, a, b));
    }
    {
        let (a, b) = (Arc::clone(&s2a), Arc::clone(&a2s));
        std::thread::spawn(move || camera_board(cam_board, a, b));
    }
    (cam_host, ap_host)
}
