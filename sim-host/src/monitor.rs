//! `sim-host monitor`: a live terminal view of a board's telemetry link, recorded to MCAP as
//! it is shown.
//!
//! The autopilot's telemetry port (USART1 on the Lisa/MX, the WiFi modem's UART) carries
//! [`BoardToHost`] frames: `Telemetry` at 10 Hz and a `Heartbeat` at 1 Hz; a board in the `hil`
//! flavour also sends `Motors` and the camera board mirrors its `Estimate`s. The monitor
//! decodes whatever arrives, counts every frame it has to reject (by kind, as the boards do),
//! and shows mode, FSM state, estimates, height, link health and errors. A link that goes
//! silent for longer than `--link-timeout` is shown as lost, and a board whose protocol
//! version is not this host's is flagged. The monitor sends the host's `Heartbeat` once a
//! second: the autopilot lands when its host falls silent.
//!
//! Message times in the log are wall-clock nanoseconds since the Unix epoch at reception
//! (monotonic within one run); the board's own clock is logged beside them (`/board_clock`).

use crate::log::records::{
    BoardClockRecord, EstimateRecord, HeartbeatRecord, LinkErrorsRecord, LinkRecord, MotorsRecord,
    StateRecord,
};
use crate::log::scene3d::CameraMount;
use crate::log::view3d::{View3d, ViewRates, ViewSample};
use crate::log::{write_telemetry, FlightLog, TelemetryExtras};
use crate::transport::{open_link, Link};
use anyhow::Context as _;
use protocol::{
    BoardToHost, BoardToHostDecoder, Estimate, Heartbeat, HostToBoard, LinkErrorCounts, Node,
    Telemetry, PROTOCOL_VERSION,
};
use std::fmt::Write as _;
use std::io::{IsTerminal as _, Write as _};
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::mpsc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// Options of `sim-host monitor`.
#[derive(Debug, clap::Args)]
pub struct MonitorArgs {
    /// The board's telemetry port: a serial device (`/dev/ttyUSB0`, `COM3`) or `tcp:HOST:PORT`.
    #[arg(long)]
    pub port: String,
    /// Baud rate of a serial port (the autopilot's telemetry UART runs at this rate).
    #[arg(long, default_value_t = autopilot::board::TELEMETRY_BAUD)]
    pub baud: u32,
    /// Where to record the MCAP log.
    #[arg(long, default_value = "out/monitor.mcap")]
    pub mcap: PathBuf,
    /// Serve the log's channels live over the Foxglove WebSocket protocol on 127.0.0.1 as
    /// they are written (see `--live-port`).
    #[arg(long)]
    pub live: bool,
    /// Port of the live view (0: any free port; the address is printed at the start).
    #[arg(long, default_value_t = crate::log::live::DEFAULT_PORT)]
    pub live_port: u16,
    /// Stop after this many seconds (default: until Ctrl-C or the link closes).
    #[arg(long)]
    pub duration: Option<f64>,
    /// A link silent for longer than this, s, is shown as lost.
    #[arg(long, default_value_t = 0.5)]
    pub link_timeout: f64,
    /// Print one status line a second instead of redrawing the screen (the default when
    /// standard output is not a terminal).
    #[arg(long)]
    pub plain: bool,
    /// The link key file (`sim-host key new`): the host heartbeat is signed with it (a board
    /// with a key ignores unsigned heartbeats and counts them).
    #[arg(long)]
    pub key: Option<PathBuf>,
}

/// How the link to the board is doing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LinkHealth {
    /// Nothing has arrived yet.
    NeverHeard,
    /// A message arrived within the link timeout.
    Up,
    /// Silent for this long, s (longer than the timeout).
    Lost(f64),
}

/// What the monitor knows of the board, from the messages it has decoded.
pub struct BoardView {
    decoder: BoardToHostDecoder,
    link_timeout_s: f64,
    /// The newest telemetry and when it arrived (s since the monitor started).
    pub telemetry: Option<(Telemetry, f64)>,
    /// The newest heartbeat of each board node (stereo board, autopilot) and when it arrived.
    pub heartbeats: [Option<(Heartbeat, f64)>; 2],
    /// The newest estimate.
    pub estimate: Option<Estimate>,
    /// The newest motor command.
    pub motors: Option<[f32; 4]>,
    /// Messages decoded, by kind: heartbeat, motors, telemetry, estimate.
    pub counts: [u64; 4],
    /// Estimates with no invalidity flag.
    pub valid_estimates: u64,
    /// Arrival times of the telemetry of the last second, for its rate.
    telemetry_times: std::collections::VecDeque<f64>,
    /// When the last message of any kind arrived.
    last_message_s: Option<f64>,
    /// Bytes received.
    pub bytes: u64,
}

impl BoardView {
    /// A view with nothing received; a link silent for `link_timeout_s` counts as lost.
    pub fn new(link_timeout_s: f64) -> Self {
        Self {
            decoder: BoardToHostDecoder::new(),
            link_timeout_s,
            telemetry: None,
            heartbeats: [None, None],
            estimate: None,
            motors: None,
            counts: [0; 4],
            valid_estimates: 0,
            telemetry_times: std::collections::VecDeque::new(),
            last_message_s: None,
            bytes: 0,
        }
    }

    /// Feeds bytes received at `now_s` (s since the monitor started); returns the messages
    /// they completed.
    pub fn on_bytes(&mut self, now_s: f64, bytes: &[u8]) -> Vec<BoardToHost> {
        self.bytes += bytes.len() as u64;
        let mut messages = Vec::new();
        self.decoder.feed(bytes, |m| messages.push(m));
        for m in &messages {
            self.last_message_s = Some(now_s);
            match m {
                BoardToHost::Heartbeat(h) => {
                    self.counts[0] += 1;
                    match h.node {
                        Node::StereoBoard => self.heartbeats[0] = Some((*h, now_s)),
                        Node::Autopilot => self.heartbeats[1] = Some((*h, now_s)),
                        Node::Host => {}
                    }
                }
                BoardToHost::Motors(c) => {
                    self.counts[1] += 1;
                    self.motors = Some(c.throttle);
                }
                BoardToHost::Telemetry(t) => {
                    self.counts[2] += 1;
                    self.telemetry = Some((*t, now_s));
                    self.telemetry_times.push_back(now_s);
                }
                BoardToHost::Estimate(e) => {
                    self.counts[3] += 1;
                    self.valid_estimates += u64::from(e.is_valid());
                    self.estimate = Some(*e);
                }
                // Answers to another tool's parameter requests: not telemetry.
                BoardToHost::Param(_) => {}
            }
        }
        messages
    }

    /// Frames rejected so far, by kind.
    pub fn errors(&self) -> LinkErrorCounts {
        self.decoder.errors()
    }

    /// The link's health at `now_s`.
    pub fn health(&self, now_s: f64) -> LinkHealth {
        match self.last_message_s {
            None => LinkHealth::NeverHeard,
            Some(t) if now_s - t > self.link_timeout_s => LinkHealth::Lost(now_s - t),
            Some(_) => LinkHealth::Up,
        }
    }

    /// Telemetry messages per second over the last second.
    pub fn telemetry_rate_hz(&mut self, now_s: f64) -> usize {
        while self
            .telemetry_times
            .front()
            .is_some_and(|&t| now_s - t > 1.0)
        {
            self.telemetry_times.pop_front();
        }
        self.telemetry_times.len()
    }

    /// Problems the user should see: a lost link, rejected frames, a board of another
    /// protocol version, a failsafe mode.
    pub fn warnings(&self, now_s: f64) -> Vec<String> {
        let mut w = Vec::new();
        if let LinkHealth::Lost(silent) = self.health(now_s) {
            w.push(format!("LINK LOST: nothing received for {silent:.1} s"));
        }
        let e = self.errors();
        if e.version_mismatch > 0 {
            let theirs = self
                .decoder
                .peer_version_mismatch()
                .map_or("another".to_string(), |v| v.to_string());
            w.push(format!(
                "{} frames of protocol version {theirs} rejected (this host speaks {PROTOCOL_VERSION}): flash matching firmware",
                e.version_mismatch
            ));
        }
        if let Some((t, _)) = &self.telemetry {
            if t.link_errors.total() > 0 {
                w.push(format!(
                    "the autopilot rejected {} frames from the camera board",
                    t.link_errors.total()
                ));
            }
            use protocol::FlightMode::{ImuFault, Killed};
            if matches!(t.flight_mode, ImuFault | Killed) {
                w.push(format!("flight mode {}", t.flight_mode.name()));
            }
            if let Some(b) = t.battery.filter(|b| b.state != protocol::BatteryState::Ok) {
                w.push(format!(
                    "battery {} ({:.2} V resting): the autopilot lands",
                    b.state.name(),
                    b.resting_v
                ));
            }
        }
        w
    }

    /// The full-screen view at `now_s`.
    pub fn render(&mut self, now_s: f64, port: &str) -> String {
        let mut s = String::new();
        let health = match self.health(now_s) {
            LinkHealth::NeverHeard => "waiting for the board".to_string(),
            LinkHealth::Up => "up".to_string(),
            LinkHealth::Lost(t) => format!("LOST ({t:.1} s silent)"),
        };
        let rate = self.telemetry_rate_hz(now_s);
        let _ = writeln!(
            s,
            "pocket-drone monitor   {port}   {now_s:.1} s   link {health}"
        );
        let _ = writeln!(
            s,
            "received    {} B: {} telemetry ({rate} Hz), {} heartbeats, {} estimates ({} valid), {} motor commands",
            self.bytes,
            self.counts[2],
            self.counts[0],
            self.counts[3],
            self.valid_estimates,
            self.counts[1]
        );
        for (h, at) in self.heartbeats.iter().flatten() {
            let _ = writeln!(
                s,
                "board       {:?}: protocol v{}, up {:.1} s (heard {:.1} s ago)",
                h.node,
                h.protocol_version,
                f64::from(h.uptime_ms) / 1e3,
                now_s - at
            );
        }
        match &self.telemetry {
            None => {
                let _ = writeln!(s, "telemetry   none yet");
            }
            Some((t, at)) => {
                let deg = |r: f32| r.to_degrees();
                let _ = writeln!(
                    s,
                    "mode        {:<18} fsm {:<10} (board time {:.3} s, {:.1} s ago)",
                    t.flight_mode.name(),
                    t.fsm_state.map_or("inactive", |f| f.name()),
                    f64::from(t.timestamp_us.as_micros()) / 1e6,
                    now_s - at
                );
                let _ = writeln!(
                    s,
                    "attitude    roll {:+6.1} deg  pitch {:+6.1} deg  yaw {:+7.1} deg",
                    deg(t.attitude_rad[0]),
                    deg(t.attitude_rad[1]),
                    deg(t.attitude_rad[2])
                );
                let _ = writeln!(
                    s,
                    "velocity    forward {:+5.2} m/s  sideways {:+5.2} m/s   setpoint {:+5.2} / {:+5.2} m/s",
                    t.velocity_mps[0],
                    t.velocity_mps[1],
                    t.velocity_setpoint_mps[0],
                    t.velocity_setpoint_mps[1]
                );
                let obstacle = t
                    .obstacle_m
                    .map_or("nothing in range".to_string(), |m| format!("{m:.2} m"));
                let baro = t.baro.map_or("no reading".to_string(), |b| {
                    format!("{:.0} Pa {:.1} °C", b.pressure_pa, b.temperature_c)
                });
                let _ = writeln!(
                    s,
                    "height      {:.2} m   barometer {baro}   obstacle {obstacle}",
                    t.height_m
                );
                let battery = t.battery.map_or("no reading".to_string(), |b| {
                    format!(
                        "{:.2} V read, {:.2} V resting, {}",
                        b.voltage_v,
                        b.resting_v,
                        b.state.name()
                    )
                });
                let _ = writeln!(s, "battery     {battery}");
                let a = t.link_auth;
                let _ = if a.keyed {
                    writeln!(
                        s,
                        "link        signed: {} accepted, refused {} unsigned, {} bad signature, {} replayed",
                        a.accepted, a.unsigned, a.bad_signature, a.replayed
                    )
                } else {
                    writeln!(
                        s,
                        "link        UNSIGNED: no key set, anyone on the link can command the drone"
                    )
                };
            }
        }
        if let Some(e) = &self.estimate {
            let _ = writeln!(
                s,
                "estimate    #{} forward {:+5.2} m/s sideways {:+5.2} m/s quality {} {}",
                e.seq,
                e.forward_mps,
                e.sideways_mps,
                e.quality,
                if e.is_valid() {
                    "valid".to_string()
                } else {
                    format!(
                        "invalid ({})",
                        crate::log::records::flag_names(e.flags).join(", ")
                    )
                }
            );
        }
        if let Some(m) = self.motors {
            let _ = writeln!(
                s,
                "motors      {:.3} {:.3} {:.3} {:.3}",
                m[0], m[1], m[2], m[3]
            );
        }
        let _ = writeln!(
            s,
            "errors      host link {}   camera link (autopilot) {}",
            describe_errors(&self.errors()),
            self.telemetry
                .as_ref()
                .map_or("unknown".to_string(), |(t, _)| describe_errors(
                    &t.link_errors
                ))
        );
        for w in self.warnings(now_s) {
            let _ = writeln!(s, "WARNING     {w}");
        }
        s
    }

    /// One status line at `now_s`.
    pub fn status_line(&mut self, now_s: f64) -> String {
        let rate = self.telemetry_rate_hz(now_s);
        let state = self
            .telemetry
            .as_ref()
            .map_or("no telemetry".to_string(), |(t, _)| {
                format!(
                    "{} fsm {} v {:+.2}/{:+.2} m/s h {:.2} m",
                    t.flight_mode.name(),
                    t.fsm_state.map_or("inactive", |f| f.name()),
                    t.velocity_mps[0],
                    t.velocity_mps[1],
                    t.height_m
                )
            });
        let health = match self.health(now_s) {
            LinkHealth::NeverHeard => "waiting".to_string(),
            LinkHealth::Up => "up".to_string(),
            LinkHealth::Lost(t) => format!("LOST {t:.1}s"),
        };
        let mut line = format!(
            "{now_s:6.1} s  link {health}  telemetry {rate} Hz  {state}  host-link errors {}",
            self.errors().total()
        );
        for w in self.warnings(now_s) {
            line.push_str("  | ");
            line.push_str(&w);
        }
        line
    }
}

/// Errors by kind, only the kinds that occurred ("0" when none).
pub fn describe_errors(e: &LinkErrorCounts) -> String {
    let kinds = [
        ("crc", e.crc),
        ("cobs", e.cobs),
        ("too long", e.too_long),
        ("too short", e.too_short),
        ("unknown message", e.unknown_message),
        ("malformed", e.malformed),
        ("version", e.version_mismatch),
    ];
    let parts: Vec<String> = kinds
        .iter()
        .filter(|(_, n)| *n > 0)
        .map(|(k, n)| format!("{k} {n}"))
        .collect();
    if parts.is_empty() {
        "0".into()
    } else {
        format!("{} ({})", e.total(), parts.join(", "))
    }
}

/// The 3D view of a real board: what it believes (attitude, height, the path its velocity
/// estimate integrates to, the nearest obstacle, its state), with the camera board's mounting.
fn board_view3d() -> View3d {
    let camera = crate::sim::camera::CameraParams::default();
    View3d::new(
        ViewRates::default(),
        CameraMount {
            forward_m: camera.forward_offset_m,
            baseline_m: camera.baseline_m,
        },
    )
}

/// Writes the records of the messages received at `t_ns` to the log.
fn record(
    log: &mut FlightLog,
    t_ns: u64,
    view: &BoardView,
    view3d: &mut View3d,
    messages: &[BoardToHost],
) -> anyhow::Result<()> {
    for m in messages {
        match m {
            BoardToHost::Telemetry(t) => {
                write_telemetry(log, t_ns, t, &TelemetryExtras::default())?;
                let state = StateRecord::new(t.fsm_state, t.flight_mode);
                let label = format!("{} / {}", state.fsm_state, state.mode);
                let sample = ViewSample {
                    truth: None,
                    attitude_rad: t.attitude_rad,
                    velocity_mps: t.velocity_mps,
                    height_m: t.height_m,
                    obstacle_m: t.obstacle_m,
                    state: &label,
                };
                view3d.step(log, t_ns / 1_000, &sample)?;
                log.write(t_ns, &BoardClockRecord::telemetry(t))?;
                log.write(
                    t_ns,
                    &LinkRecord {
                        camera_link_errors: t.link_errors.into(),
                        host_link_errors: Some(LinkErrorsRecord::from(view.errors())),
                        estimates_received: view.counts[3],
                        estimates_valid: view.valid_estimates,
                        frames_dropped: None,
                        camera_to_autopilot_bytes_lost: None,
                        camera_to_autopilot_bytes_corrupted: None,
                        autopilot_to_camera_bytes_lost: None,
                        timeouts: None,
                    },
                )?;
            }
            BoardToHost::Heartbeat(h) => log.write(t_ns, &HeartbeatRecord::from(h))?,
            BoardToHost::Estimate(e) => log.write(t_ns, &EstimateRecord::from(e))?,
            BoardToHost::Motors(c) => log.write(t_ns, &MotorsRecord::from(c.throttle))?,
            BoardToHost::Param(_) => {}
        }
    }
    Ok(())
}

/// What the reader thread hands the monitor.
enum Received {
    Bytes(Vec<u8>),
    Closed,
    Failed(std::io::Error),
}

/// The peer closed the connection (a reset or a broken pipe), as opposed to a failing port.
fn closed_by_peer(e: &std::io::Error) -> bool {
    use std::io::ErrorKind::{BrokenPipe, ConnectionAborted, ConnectionReset};
    matches!(e.kind(), BrokenPipe | ConnectionAborted | ConnectionReset)
}

fn reader(mut link: Box<dyn Link>, tx: mpsc::Sender<Received>) {
    let mut buf = [0u8; 1024];
    loop {
        let r = match link.read(&mut buf) {
            Ok(0) => Received::Closed,
            Ok(n) => Received::Bytes(buf[..n].to_vec()),
            Err(e) if crate::transport::is_transient_read_error(&e) => continue,
            // A peer that closed with our heartbeats unread resets the connection.
            Err(e) if closed_by_peer(&e) => Received::Closed,
            Err(e) => Received::Failed(e),
        };
        let last = !matches!(r, Received::Bytes(_));
        if tx.send(r).is_err() || last {
            return;
        }
    }
}

/// What one monitoring run saw.
pub struct MonitorSummary {
    /// Messages decoded, by kind: heartbeat, motors, telemetry, estimate.
    pub counts: [u64; 4],
    /// Frames rejected.
    pub errors: LinkErrorCounts,
    /// Bytes received.
    pub bytes: u64,
    /// Why it ended.
    pub ended: &'static str,
}

/// Runs `sim-host monitor`.
pub fn run(args: &MonitorArgs) -> anyhow::Result<()> {
    let link = open_link(&args.port, args.baud)?;
    if let Some(dir) = args.mcap.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let mut log = FlightLog::create(&args.mcap)?;
    if args.live {
        log.serve_live(crate::log::live::LiveServer::start_announced(
            args.live_port,
        )?);
    }
    let mut view3d = board_view3d();
    let stop = crate::interrupt_flag()?;
    // The host's heartbeat goes out on the same link: the autopilot counts a silent host as a
    // lost telemetry link (it lands) and refuses to arm without one.
    let mut heartbeat_out = link
        .try_clone_link()
        .context("cloning the link for writing")?;
    let mut next_heartbeat = 0.0;
    let mut signer =
        crate::key::HostSigner::from_file(args.key.as_deref(), crate::key::link_id::MONITOR)?;
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || reader(link, tx));

    let full_screen = !args.plain && std::io::stdout().is_terminal();
    let redraw_every = if full_screen { 0.2 } else { 1.0 };
    let start = Instant::now();
    let epoch_ns = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64);
    view3d.start(&mut log, epoch_ns / 1_000, None)?;
    let mut view = BoardView::new(args.link_timeout);
    let mut next_draw = 0.0;
    let mut was_lost = false;
    let mut stdout = std::io::stdout();
    let ended = loop {
        let now = start.elapsed().as_secs_f64();
        if stop.load(Ordering::SeqCst) {
            break "interrupted";
        }
        if args.duration.is_some_and(|d| now >= d) {
            break "duration reached";
        }
        if now >= next_heartbeat {
            next_heartbeat = now + crate::param::HOST_HEARTBEAT_PERIOD.as_secs_f64();
            let hb = HostToBoard::Heartbeat(Heartbeat::new(Node::Host, (now * 1e3) as u32));
            let frame = signer.frame(hb)?;
            match heartbeat_out.write_all(&frame) {
                Ok(()) => {}
                Err(e) if closed_by_peer(&e) => break "the link closed",
                Err(e) => {
                    let _ = log.finish();
                    return Err(e)
                        .with_context(|| format!("writing the heartbeat to {}", args.port));
                }
            }
        }
        match rx.recv_timeout(Duration::from_millis(50)) {
            Ok(Received::Bytes(bytes)) => {
                let now = start.elapsed().as_secs_f64();
                let messages = view.on_bytes(now, &bytes);
                // Whole microseconds, the 3D view's resolution, so that its messages keep the
                // log in time order with the records of the same arrival.
                let t_ns = (epoch_ns + start.elapsed().as_nanos() as u64) / 1_000 * 1_000;
                record(&mut log, t_ns, &view, &mut view3d, &messages)?;
            }
            Ok(Received::Closed) => break "the link closed",
            Ok(Received::Failed(e)) => {
                let _ = log.finish();
                return Err(e).with_context(|| format!("reading {}", args.port));
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Err(mpsc::RecvTimeoutError::Disconnected) => break "the link closed",
        }
        let now = start.elapsed().as_secs_f64();
        let lost = matches!(view.health(now), LinkHealth::Lost(_));
        if now >= next_draw || lost != was_lost {
            was_lost = lost;
            next_draw = now + redraw_every;
            if full_screen {
                let _ = write!(stdout, "\x1b[H\x1b[2J{}", view.render(now, &args.port));
            } else {
                let _ = writeln!(stdout, "{}", view.status_line(now));
            }
            let _ = stdout.flush();
        }
    };
    let summary = log.finish()?;
    println!(
        "monitor ended ({ended}): {} B, {} telemetry, {} heartbeats, {} estimates, {} motor commands, host-link errors {}",
        view.bytes,
        view.counts[2],
        view.counts[0],
        view.counts[3],
        view.counts[1],
        describe_errors(&view.errors())
    );
    println!(
        "flight log        {} ({} messages on {} channels, MCAP)",
        summary.path.display(),
        summary.total(),
        summary.counts.len()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{FlightMode, FsmState, Message};

    fn frame(m: &BoardToHost) -> Vec<u8> {
        let mut buf = vec![0u8; BoardToHost::MAX_FRAME_BYTES + 8];
        let n = protocol::encode(m, &mut buf).unwrap();
        buf.truncate(n);
        buf
    }

    fn telemetry(mode: FlightMode) -> Telemetry {
        Telemetry {
            timestamp_us: protocol::WireTime(1_000_000),
            fsm_state: Some(FsmState::Forward),
            flight_mode: mode,
            attitude_rad: [0.01, -0.02, 0.5],
            velocity_mps: [0.3, 0.0],
            velocity_setpoint_mps: [0.3, 0.0],
            obstacle_m: Some(1.5),
            height_m: 1.0,
            baro: Some(protocol::BaroTelemetry {
                pressure_pa: 101_200.0,
                temperature_c: 24.5,
            }),
            link_errors: LinkErrorCounts::default(),
            failsafe_reason: None,
            battery: Some(protocol::BatteryTelemetry {
                voltage_v: 3.61,
                resting_v: 3.95,
                state: protocol::BatteryState::Ok,
            }),
            link_auth: protocol::LinkAuthTelemetry::default(),
        }
    }

    #[test]
    fn shows_mode_fsm_and_counts_rejected_frames() {
        let mut v = BoardView::new(0.5);
        let mut bytes = frame(&BoardToHost::Telemetry(telemetry(FlightMode::Flying)));
        let mut corrupt = frame(&BoardToHost::Telemetry(telemetry(FlightMode::Flying)));
        corrupt[5] ^= 0x40;
        bytes.extend_from_slice(&corrupt);
        let got = v.on_bytes(0.1, &bytes);
        assert_eq!(got.len(), 1);
        assert_eq!(v.errors().total(), 1);
        let screen = v.render(0.2, "tcp:test");
        assert!(screen.contains("flying"), "{screen}");
        assert!(screen.contains("forward"), "{screen}");
        assert!(screen.contains("barometer 101200 Pa 24.5 °C"), "{screen}");
        assert!(
            screen.contains("battery     3.61 V read, 3.95 V resting, ok"),
            "{screen}"
        );
        assert!(screen.contains("host link 1 ("), "{screen}");
        assert_eq!(v.health(0.2), LinkHealth::Up);
    }

    #[test]
    fn a_silent_link_is_lost_and_a_failsafe_is_a_warning() {
        let mut v = BoardView::new(0.5);
        assert_eq!(v.health(3.0), LinkHealth::NeverHeard);
        v.on_bytes(
            1.0,
            &frame(&BoardToHost::Telemetry(telemetry(FlightMode::ImuFault))),
        );
        assert!(matches!(v.health(2.0), LinkHealth::Lost(s) if (s - 1.0).abs() < 1e-9));
        let w = v.warnings(2.0).join("\n");
        assert!(w.contains("LINK LOST"), "{w}");
        assert!(w.contains("imu-fault"), "{w}");
    }
}
