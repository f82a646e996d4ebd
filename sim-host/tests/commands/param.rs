//! `sim-host param` against the autopilot library served on TCP and on a serial port (a
//! pseudo-terminal) the way the firmware serves its telemetry port (requests decoded from the
//! byte stream, answers framed back, telemetry interleaved; the camera board's requests passed
//! on to its library over encoded link bytes; both boards with a parameter store of flash
//! rules): the client API and the command line, success and refusal, save and storage.

use autopilot::app::Autopilot;
use autopilot::params;
use autopilot::HostOutcome;
use protocol::params::MemStore;
use protocol::{BoardToHost, HostToBoardDecoder, Node, ParamValue};
use sim_host::param::ParamClient;
use std::io::{ErrorKind, Read, Write};
use std::net::TcpListener;
use std::process::Command;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use stereo_board::app::StereoBoardApp;
use stereo_board::edge_fs::EdgeFsParams;

/// A parameter sector with flash rules.
type Sector = MemStore<1024>;

/// The boards a test serves: the autopilot, and the camera board behind it on the
/// board-to-board link, each booted from its (erased) parameter sector.
#[derive(Clone)]
struct Boards {
    ap: Arc<Mutex<Autopilot>>,
    camera: Arc<Mutex<Box<StereoBoardApp>>>,
    ap_flash: Arc<Mutex<Sector>>,
    camera_flash: Arc<Mutex<Sector>>,
}

impl Boards {
    fn new() -> Self {
        let (ap_flash, camera_flash) = (Sector::blank(), Sector::blank());
        let ap = Autopilot::from_store(&ap_flash).0;
        let mut camera = Box::new(StereoBoardApp::new(EdgeFsParams::default_config()));
        let _ = camera.load_params(&camera_flash);
        Self {
            ap: Arc::new(Mutex::new(ap)),
            camera: Arc::new(Mutex::new(camera)),
            ap_flash: Arc::new(Mutex::new(ap_flash)),
            camera_flash: Arc::new(Mutex::new(camera_flash)),
        }
    }
}

/// Serves the boards to every client that connects, one after the other (telemetry every
/// 100 ms of silence and before each answer, as the firmware's 10 Hz telemetry interleaves).
fn serve(boards: Boards) -> u16 {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            let Ok(mut s) = stream else { return };
            s.set_read_timeout(Some(Duration::from_millis(100)))
                .unwrap();
            let boards = boards.clone();
            std::thread::spawn(move || board(&mut s, &boards, &|| false));
        }
    });
    port
}

/// Answers the host on `s` until it closes, fails, or `stop()` says so while it is silent.
fn board(s: &mut impl ReadWrite, boards: &Boards, stop: &dyn Fn() -> bool) {
    let mut dec = HostToBoardDecoder::new();
    let mut buf = [0u8; 256];
    loop {
        let n = match s.read(&mut buf) {
            Ok(0) => return,
            Ok(n) => n,
            Err(e) if matches!(e.kind(), ErrorKind::TimedOut | ErrorKind::WouldBlock) => {
                if stop() {
                    return;
                }
                // The telemetry the firmware streams from boot (the tool waits for it); a
                // serial port with no tool open may refuse it.
                let telemetry = BoardToHost::Telemetry(
                    boards
                        .ap
                        .lock()
                        .unwrap()
                        .telemetry(timebase::Instant::from_micros(0)),
                );
                let _ = s.write_all(&protocol::encode_to_vec::<_, 128>(&telemetry).unwrap());
                continue;
            }
            Err(_) => return,
        };
        let mut msgs = Vec::new();
        dec.feed(&buf[..n], |m| msgs.push(m));
        for m in msgs {
            let mut ap = boards.ap.lock().unwrap();
            let telemetry = BoardToHost::Telemetry(ap.telemetry(timebase::Instant::from_micros(0)));
            let mut ap_flash = boards.ap_flash.lock().unwrap();
            let answer = match ap.on_host_message(
                m,
                timebase::Instant::from_micros(0),
                Some(&mut *ap_flash),
            ) {
                HostOutcome::Reply(answer) => Some(answer),
                // The camera board's request goes over the link as encoded bytes, and its
                // answer comes back the same way, as on the boards.
                HostOutcome::ToCamera(msg) => {
                    let frame = protocol::encode_to_vec::<_, 64>(&msg).unwrap();
                    let mut back = Vec::new();
                    let now = timebase::Instant::ZERO;
                    let mut camera_flash = boards.camera_flash.lock().unwrap();
                    boards.camera.lock().unwrap().on_rx_bytes(
                        &frame,
                        now,
                        &mut |b| back.extend_from_slice(b),
                        Some(&mut *camera_flash),
                    );
                    ap.on_stereo_bytes(&back, timebase::Instant::from_micros(0));
                    ap.take_camera_param_reply().map(BoardToHost::Param)
                }
                _ => None,
            };
            if let Some(answer) = answer {
                for msg in [telemetry, answer] {
                    let frame = protocol::encode_to_vec::<_, 128>(&msg).unwrap();
                    if s.write_all(&frame).is_err() {
                        return;
                    }
                }
            }
        }
    }
}

/// Runs a `sim-host` command: whether it succeeded, and what it printed (stdout, then stderr).
fn sim_host(cmd: &mut Command) -> (bool, String) {
    let out = cmd.output().unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

/// A byte stream to a host: a TCP connection or a serial port.
trait ReadWrite: Read + Write {}
impl<T: Read + Write> ReadWrite for T {}

fn client(port: u16, board: Node) -> ParamClient<'static> {
    ParamClient::open(
        &format!("tcp:127.0.0.1:{port}"),
        0,
        board,
        Duration::from_secs(2),
    )
    .unwrap()
}

#[test]
fn the_client_lists_reads_and_writes_the_autopilots_table() {
    let boards = Boards::new();
    let (ap, flash) = (boards.ap.clone(), boards.ap_flash.clone());
    let mut c = client(serve(boards), Node::Autopilot);
    let all = c.list().unwrap();
    assert_eq!(all.len(), params::COUNT);
    for (i, (e, spec)) in all.iter().zip(params::TABLE).enumerate() {
        assert_eq!((usize::from(e.index), e.name.as_str()), (i, spec.name));
        assert_eq!(e.value, e.default, "{}", spec.name);
    }
    let e = c.set("guid_kp", "0.3").unwrap();
    assert_eq!(e.value, ParamValue::F32(0.3));
    assert_eq!(ap.lock().unwrap().config().guidance.kp, 0.3);
    let e = c.set("indi_adapt", "false").unwrap();
    assert_eq!(e.value, ParamValue::Bool(false));
    assert!(!ap.lock().unwrap().config().indi.adapt);

    let err = |r: anyhow::Result<protocol::ParamEntry>| r.unwrap_err().to_string();
    let e = err(c.set("target_height", "9"));
    assert!(e.contains("outside [0.2 ..= 3]"), "{e}");
    let e = err(c.set("fsm_variant", "0.5"));
    assert!(e.contains("not a whole number"), "{e}");
    let e = err(c.set("no_such_param", "1"));
    assert!(e.contains("no parameter of that name"), "{e}");
    let e = err(c.set("indi_rate_hz", "512"));
    assert!(e.contains("read-only"), "{e}");
    assert_eq!(ap.lock().unwrap().config().setpoints.target_height_m, 1.0);
    // Saved with a CRC and a version: the next boot runs on the values.
    c.save().unwrap();
    let status = c.storage().unwrap();
    assert_eq!((status.saves, status.failed_saves), (1, 0));
    let (next, loaded) = Autopilot::from_store(&*flash.lock().unwrap());
    assert_eq!(loaded, Ok(()));
    assert_eq!(next.config().guidance.kp, 0.3);
}

#[test]
fn the_command_line_works_over_tcp() {
    let boards = Boards::new();
    let (ap, camera) = (boards.ap.clone(), boards.camera.clone());
    let camera_flash = boards.camera_flash.clone();
    let port = serve(boards);
    let run = |args: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_sim-host"))
            .args(["param", "--port", &format!("tcp:127.0.0.1:{port}")])
            .args(args)
            .output()
            .unwrap();
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stdout).into_owned(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let (ok, out, err) = run(&["list"]);
    assert!(ok, "{err}");
    assert_eq!(out.lines().count(), params::COUNT, "{out}");
    assert!(out.contains("fs_imu_timeout_us"), "{out}");
    let (ok, out, err) = run(&["set", "land_rate", "0.4"]);
    assert!(ok && out.contains("land_rate"), "{out}{err}");
    let (ok, out, _) = run(&["get", "land_rate"]);
    assert!(ok && out.contains(" 0.4 "), "{out}");
    assert_eq!(ap.lock().unwrap().config().setpoints.land_rate_mps, 0.4);
    let (ok, _, err) = run(&["set", "land_rate", "true"]);
    assert!(!ok && err.contains("not a finite number"), "{err}");
    // The camera board's table, through the autopilot.
    let (ok, out, err) = run(&["--board", "camera", "list"]);
    assert!(ok, "{err}");
    assert_eq!(out.lines().count(), stereo_board::params::COUNT, "{out}");
    assert!(out.contains("stereo_shift"), "{out}");
    let (ok, out, err) = run(&["--board", "camera", "set", "stereo_shift", "-4"]);
    assert!(ok && out.contains("stereo_shift"), "{out}{err}");
    assert_eq!(camera.lock().unwrap().params().stereo_shift_px, -4);
    let (ok, out, _) = run(&["--board", "camera", "get", "stereo_shift"]);
    assert!(ok && out.contains(" -4 "), "{out}");
    let (ok, _, err) = run(&["--board", "camera", "set", "stereo_shift", "30"]);
    assert!(!ok && err.contains("outside [-20 ..= 20] px"), "{err}");
    let (ok, _, err) = run(&["--board", "camera", "set", "half_window", "-1"]);
    assert!(!ok && err.contains("not a whole number >= 0"), "{err}");
    assert_eq!(camera.lock().unwrap().params().half_window, 6);
    // Saved in the camera board's own sector: the next boot runs on it.
    let (ok, out, err) = run(&["--board", "camera", "save"]);
    assert!(ok && out.contains("saved"), "{out}{err}");
    let (ok, out, err) = run(&["--board", "camera", "storage"]);
    assert!(ok, "{err}");
    assert!(
        out.contains(
            "defaults in use: nothing saved (erased flash); saves since boot: 1, failed: 0"
        ),
        "{out}"
    );
    let mut next = StereoBoardApp::new(EdgeFsParams::default_config());
    assert_eq!(next.load_params(&*camera_flash.lock().unwrap()), Ok(()));
    assert_eq!(next.params().stereo_shift_px, -4);
}

/// The same tool on a serial port: the board answers on a pseudo-terminal's master side, the
/// tool opens its slave device at a baud rate as it opens a USB-serial adapter.
#[cfg(unix)]
#[test]
fn the_command_line_works_over_a_serial_port() {
    use serialport::SerialPort as _;
    use std::sync::atomic::{AtomicBool, Ordering};
    let boards = Boards::new();
    let ap = boards.ap.clone();
    let (mut master, slave) = serialport::TTYPort::pair().unwrap();
    let path = slave.name().unwrap();
    master.set_timeout(Duration::from_millis(100)).unwrap();
    let done = Arc::new(AtomicBool::new(false));
    let stop = done.clone();
    let served = std::thread::spawn(move || {
        board(&mut master, &boards, &|| stop.load(Ordering::Relaxed));
    });
    let run = |args: &[&str]| {
        sim_host(
            Command::new(env!("CARGO_BIN_EXE_sim-host"))
                .args(["param", "--port", &path, "--baud", "57600"])
                .args(args),
        )
    };
    let (ok, out) = run(&["set", "target_height", "0.8"]);
    assert!(ok && out.contains(" 0.8 "), "{out}");
    let (ok, out) = run(&["save"]);
    assert!(ok && out.contains("saved"), "{out}");
    let (ok, out) = run(&["--board", "camera", "get", "stereo_shift"]);
    assert!(ok && out.contains(" 0 "), "{out}");
    done.store(true, Ordering::Relaxed);
    served.join().unwrap();
    drop(slave);
    assert_eq!(ap.lock().unwrap().config().setpoints.target_height_m, 0.8);
}

#[test]
fn nobody_answering_is_an_error_not_a_hang() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let silent = std::thread::spawn(move || listener.accept().map(|(s, _)| s));
    let mut c = ParamClient::open(
        &format!("tcp:127.0.0.1:{port}"),
        0,
        Node::Autopilot,
        Duration::from_millis(100),
    )
    .unwrap();
    let _held_open = silent.join().unwrap().unwrap();
    let e = c.get("guid_kp").unwrap_err().to_string();
    assert!(e.contains("no answer"), "{e}");
}

#[test]
fn fly_reads_a_parameter_file_and_refuses_a_bad_one() {
    let dir = std::env::temp_dir().join(format!("sim-host-params-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let fly = |params: &str| {
        let file = dir.join("params.toml");
        std::fs::write(&file, params).unwrap();
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_sim-host"));
        cmd.args([
            "fly",
            "--duration",
            "1",
            "--quiet",
            "--format",
            "csv",
            "--params",
        ])
        .arg(&file)
        .arg("--out")
        .arg(dir.join("out"));
        sim_host(&mut cmd)
    };
    let (ok, text) = fly("[autopilot]\ntarget_height = 4.0\n");
    assert!(!ok, "{text}");
    assert!(
        text.contains("params.toml: [autopilot] target_height: parameter target_height"),
        "{text}"
    );
    assert!(
        text.contains("outside the parameter's bounds [0.2 ..= 3] m"),
        "{text}"
    );
    let (ok, text) = fly("[camera]\nstereo_shift = 30\n");
    assert!(!ok, "{text}");
    assert!(
        text.contains("params.toml: [camera] stereo_shift: parameter stereo_shift"),
        "{text}"
    );
    let (ok, text) =
        fly("[autopilot]\ntarget_height = 0.8\nfsm_variant = 1\n[camera]\nstereo_shift = -2\n");
    assert!(ok, "{text}");
    assert!(text.contains("seed,duration_s"), "{text}");
    let _ = std::fs::remove_dir_all(&dir);
}
