//! Shared helpers of the QEMU tests (`qemu_*.rs` include this file with `#[path]`): build the
//! `qemu` flavour of the firmwares, start `qemu-system-arm -M netduinoplus2` with its USARTs on
//! loopback sockets served by the test, and always kill QEMU (a guard kills on drop, also
//! when a test panics).
//!
//! The tests need `qemu-system-arm` and the `thumbv7em-none-eabihf` target (`cargo xtask test`
//! installs both). Where either is missing they fail with a message saying so: a check that
//! silently skips is no check.
#![allow(dead_code)]

use std::io::Read;
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// Workspace root.
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map(Path::to_path_buf)
        .expect("tests/ has a parent")
}

/// The cargo target directory this test binary was built into (`<target>/debug/deps/exe`).
fn target_dir() -> PathBuf {
    if let Some(dir) = std::env::var_os("CARGO_TARGET_DIR") {
        return PathBuf::from(dir);
    }
    let exe = std::env::current_exe().expect("test executable path");
    exe.ancestors()
        .nth(3)
        .map(Path::to_path_buf)
        .unwrap_or_else(|| workspace_root().join("target"))
}

/// Panics, saying what is missing, unless QEMU tests can run here.
pub fn require_qemu() {
    let qemu = Command::new("qemu-system-arm")
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .map(|s| s.success())
        .unwrap_or(false);
    let target = Command::new("rustup")
        .args(["target", "list", "--installed"])
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).contains("thumbv7em-none-eabihf"))
        .unwrap_or(true);
    let ok = qemu && target;
    if !ok {
        let why = format!(
            "QEMU test cannot run: qemu-system-arm {} / thumbv7em-none-eabihf target {} \
             (run `cargo xtask test`, which installs both)",
            if qemu { "found" } else { "missing" },
            if target { "found" } else { "missing" }
        );
        panic!("{why}");
    }
}

/// Builds both firmwares in the `qemu` flavour (once per test binary) and returns the ELF
/// paths (stereo board, autopilot). Uses its own target directory so the outer cargo's lock
/// is not needed (the same one `cargo xtask qemu` uses).
pub fn qemu_firmwares() -> (PathBuf, PathBuf) {
    static BUILT: OnceLock<(PathBuf, PathBuf)> = OnceLock::new();
    BUILT
        .get_or_init(|| {
            let dir = target_dir().join("fw-qemu");
            let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
            // One invocation per board: each selects its own part's HAL feature.
            for package in ["stereo-board", "autopilot"] {
                let status = Command::new(&cargo)
                    .current_dir(workspace_root())
                    .args(["build", "--release", "--target", "thumbv7em-none-eabihf"])
                    .args(["-p", package])
                    .args(["--features", &format!("{package}/qemu")])
                    .arg("--target-dir")
                    .arg(&dir)
                    .status()
                    .expect("running cargo build for the qemu firmwares");
                assert!(status.success(), "qemu firmware build of {package} failed");
            }
            let out = dir.join("thumbv7em-none-eabihf").join("release");
            (out.join("stereo-board"), out.join("autopilot"))
        })
        .clone()
}

/// A loopback listener for one QEMU USART (QEMU connects as a client).
pub struct Port {
    listener: TcpListener,
    /// The port number.
    pub port: u16,
}

impl Port {
    /// Binds a free loopback port.
    pub fn bind() -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").expect("bind loopback");
        let port = listener.local_addr().expect("local addr").port();
        Self { listener, port }
    }

    /// The `-chardev` spec that connects QEMU to this port. `nodelay=on`: without it Nagle's
    /// algorithm holds QEMU's small writes (a 30-byte reply) for a delayed ACK, about 40 ms
    /// per round trip, which throttled the HIL lockstep to 0.04x real time.
    pub fn chardev(&self, id: &str) -> String {
        format!(
            "socket,id={id},host=127.0.0.1,port={},nodelay=on",
            self.port
        )
    }

    /// Accepts QEMU's connection (within `timeout`).
    pub fn accept(&self, timeout: Duration) -> TcpStream {
        self.listener.set_nonblocking(true).expect("nonblocking");
        let start = Instant::now();
        loop {
            match self.listener.accept() {
                Ok((s, _)) => {
                    s.set_nonblocking(false).expect("blocking stream");
                    s.set_nodelay(true).ok();
                    return s;
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                    assert!(start.elapsed() < timeout, "QEMU did not connect");
                    std::thread::sleep(Duration::from_millis(20));
                }
                Err(e) => panic!("accept: {e}"),
            }
        }
    }
}

/// A running QEMU; killed (and reaped) on drop. Its stdout (the semihosting log) goes to a
/// temporary file: written through at once, unlike a pipe.
pub struct Qemu {
    child: Child,
    log_path: PathBuf,
}

impl Qemu {
    /// Starts `elf` with USART1 and USART2 on the given chardev specs (ids `link` and `host`).
    pub fn start(elf: &Path, usart1: &str, usart2: &str) -> Self {
        Self::start_serials(elf, [(usart1, "link"), (usart2, "host")])
    }

    /// Starts the autopilot: its USART1 is the telemetry (host) port, USART2 the link to the
    /// camera board (the Lisa/MX's wiring). `link` and `host` are `-chardev` specs with ids
    /// `link` and `host`.
    pub fn start_autopilot(elf: &Path, link: &str, host: &str) -> Self {
        Self::start_serials(elf, [(host, "host"), (link, "link")])
    }

    /// Starts QEMU with `serials` as USART1 and USART2: each a `-chardev` spec and its id.
    fn start_serials(elf: &Path, serials: [(&str, &str); 2]) -> Self {
        static RUN: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let n = RUN.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let log_path =
            std::env::temp_dir().join(format!("pocket-drone-qemu-{}-{n}.log", std::process::id()));
        let _ = std::fs::remove_file(&log_path);
        let child = Command::new("qemu-system-arm")
            .args(["-M", "netduinoplus2", "-nographic", "-monitor", "none"])
            .args(["-semihosting-config", "enable=on,target=native"])
            .args(["-icount", "shift=auto"])
            .args(["-chardev", serials[0].0, "-serial"])
            .arg(format!("chardev:{}", serials[0].1))
            .args(["-chardev", serials[1].0, "-serial"])
            .arg(format!("chardev:{}", serials[1].1))
            .arg("-kernel")
            .arg(elf)
            .stdin(Stdio::null())
            .stdout(std::fs::File::create(&log_path).expect("QEMU log file"))
            .stderr(Stdio::inherit())
            .spawn()
            .expect("starting qemu-system-arm");
        Self { child, log_path }
    }

    /// The semihosting log so far.
    pub fn log(&self) -> String {
        std::fs::read_to_string(&self.log_path).unwrap_or_default()
    }

    /// Waits until the log contains `needle` (e.g. the first `status` line: the firmware is
    /// initialised and its USARTs receive; QEMU drops bytes sent before that).
    pub fn wait_for_log(&mut self, needle: &str, timeout: Duration) {
        let start = Instant::now();
        while !self.log().contains(needle) {
            self.assert_running();
            assert!(
                start.elapsed() < timeout,
                "no {needle:?} in the QEMU log within {timeout:?}:\n{}",
                self.log()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Fails if QEMU has exited (a semihosting exit means a panic or fatal error).
    pub fn assert_running(&mut self) {
        if let Ok(Some(status)) = self.child.try_wait() {
            panic!("QEMU exited early with {status}; log:\n{}", self.log());
        }
    }
}

impl Drop for Qemu {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_file(&self.log_path);
    }
}

/// The value of `key=` in the last log line starting with `prefix` (e.g. `status`).
pub fn last_field(log: &str, prefix: &str, key: &str) -> Option<u64> {
    log.lines()
        .rev()
        .filter(|l| l.starts_with(prefix))
        .find_map(|l| {
            l.split_whitespace()
                .find_map(|kv| kv.strip_prefix(key)?.strip_prefix('='))
                .and_then(|v| v.parse().ok())
        })
}

/// The camera board's host link as the HIL host sees it: frames out, mirrored estimates in.
pub struct HostLink {
    stream: TcpStream,
    decoder: protocol::BoardToHostDecoder,
    pending: std::collections::VecDeque<protocol::BoardToHost>,
}

impl HostLink {
    /// Wraps an accepted connection.
    pub fn new(stream: TcpStream) -> Self {
        Self {
            stream,
            decoder: protocol::BoardToHostDecoder::new(),
            pending: Default::default(),
        }
    }

    /// Streams one interleaved frame as `FrameChunk`s.
    pub fn send_frame(&mut self, frame: &[u8], frame_id: u16, capture_us: u32) {
        use protocol::{encode, FrameChunk, HostToBoard, Message, FRAME_CHUNK_BYTES};
        use std::io::Write;
        let mut out = Vec::new();
        for (i, data) in frame.chunks(FRAME_CHUNK_BYTES).enumerate() {
            let msg = HostToBoard::FrameChunk(FrameChunk {
                frame_id,
                capture_us: protocol::WireTime(capture_us),
                offset: (i * FRAME_CHUNK_BYTES) as u16,
                data: data.try_into().expect("chunk fits"),
            });
            let mut buf = [0u8; HostToBoard::MAX_FRAME_BYTES];
            let n = encode(&msg, &mut buf).expect("encodes");
            out.extend_from_slice(&buf[..n]);
        }
        self.stream.write_all(&out).expect("stream a frame");
    }

    /// The next estimate mirrored on the host link, within `timeout`.
    pub fn next_estimate(&mut self, timeout: Duration) -> Option<protocol::Estimate> {
        let deadline = Instant::now() + timeout;
        loop {
            while let Some(msg) = self.pending.pop_front() {
                if let protocol::BoardToHost::Estimate(e) = msg {
                    return Some(e);
                }
            }
            let left = deadline.checked_duration_since(Instant::now())?;
            self.stream
                .set_read_timeout(Some(left.max(Duration::from_millis(1))))
                .ok()?;
            let mut buf = [0u8; 512];
            match self.stream.read(&mut buf) {
                Ok(0) => return None,
                Ok(n) => {
                    let pending = &mut self.pending;
                    self.decoder.feed(&buf[..n], |m| pending.push_back(m));
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) => {}
                Err(_) => return None,
            }
        }
    }

    /// Decoding errors on the host link so far.
    pub fn errors(&self) -> protocol::LinkErrorCounts {
        self.decoder.errors()
    }
}

/// Drives the autopilot's world clock in the lockstep flavours (see `autopilot::lockstep`):
/// a thread sends IMU samples of a drone at rest, level (and a height fix every 5th sample),
/// one per 1/512 s of world time, each after the `Motors` reply to the previous one (or a
/// 2 s timeout). Stops (and joins) on drop.
pub struct RestImuFeeder {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<(u64, u64)>>,
}

impl RestImuFeeder {
    /// Starts feeding over an accepted connection to the autopilot's host USART.
    pub fn start(mut stream: TcpStream) -> Self {
        use protocol::{encode, BoardToHost, ExternalPosition, HostToBoard, ImuSample, Message};
        use std::io::Write;
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let flag = std::sync::Arc::clone(&stop);
        let thread = std::thread::spawn(move || {
            let mut dec = protocol::BoardToHostDecoder::new();
            let (mut sent, mut replies) = (0u64, 0u64);
            let mut k = 0u64;
            while !flag.load(std::sync::atomic::Ordering::Relaxed) {
                let t = protocol::WireTime((k * 1_000_000 / 512) as u32);
                let mut out = Vec::new();
                let mut push = |m: &HostToBoard| {
                    let mut buf = [0u8; HostToBoard::MAX_FRAME_BYTES];
                    let n = encode(m, &mut buf).expect("encodes");
                    out.extend_from_slice(&buf[..n]);
                };
                if k.is_multiple_of(5) {
                    push(&HostToBoard::ExternalPosition(ExternalPosition {
                        timestamp_us: t,
                        position_m: [0.0; 3],
                    }));
                }
                push(&HostToBoard::Imu(ImuSample {
                    timestamp_us: t,
                    gyro_radps: [0.0; 3],
                    accel_mps2: [0.0, 0.0, -9.81],
                }));
                if stream.write_all(&out).is_err() {
                    break;
                }
                sent += 1;
                k += 1;
                let deadline = Instant::now() + Duration::from_secs(2);
                let mut got = false;
                while !got && Instant::now() < deadline {
                    stream
                        .set_read_timeout(Some(Duration::from_millis(100)))
                        .ok();
                    let mut buf = [0u8; 256];
                    match stream.read(&mut buf) {
                        Ok(0) => return (sent, replies),
                        Ok(n) => dec.feed(&buf[..n], |m| {
                            if matches!(m, BoardToHost::Motors(c) if c.timestamp_us == t) {
                                got = true;
                            }
                        }),
                        Err(_) => {}
                    }
                }
                replies += u64::from(got);
            }
            (sent, replies)
        });
        Self {
            stop,
            thread: Some(thread),
        }
    }

    /// Stops the feeder; returns (samples sent, motor replies received).
    pub fn finish(mut self) -> (u64, u64) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        self.thread
            .take()
            .and_then(|t| t.join().ok())
            .unwrap_or((0, 0))
    }
}

impl Drop for RestImuFeeder {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
