//! A board's host-facing UART on a TCP socket, so that a ground tool talks to the real
//! firmware image on the bench as it would to a board on a serial port: `sim-host monitor
//! --port tcp:HOST:PORT` reads the virtual autopilot's telemetry exactly as it reads a real
//! one's.
//!
//! [`TcpBridge`] is a [`Probe`]: at every bench stop it sends the client the bytes the board's
//! UART has sent since the last stop, and puts what the client sent on the board's receive
//! line at that instant (the USART then takes it at its own baud). With a pace set, the bench
//! is held back to that many virtual seconds per wall second, so a tool that judges the link
//! by the wall clock (a timeout, a rate) sees the board's own timing. The run ends when the
//! client disconnects.
//!
//! [`hil`] serves both boards' `hil`-flavour images at once, their link UARTs joined as in the
//! drone, to `sim-host hil`: the camera board's host UART (USART2) and the autopilot's
//! (telemetry, USART1) each to its own client, exactly as two boards on serial ports or two
//! QEMUs. The lockstep on world time needs no pace (the boards run on the world time the host
//! sends, and the world waits for their replies), but a bench left to itself runs ahead of a
//! host that is computing: idle in WFI, a board skips through virtual time far faster than the
//! host answers (unpaced, 60 s of virtual time passed in the first second of world time). So
//! those bridges wait for the host's answer ([`TcpBridge::answering_within`]): at a stop where
//! the board sent something, the bench holds until the client's next bytes arrive (or a short
//! wall-clock limit passes), and they reach the board at that virtual instant, as from a host
//! that answers at once.

use std::io::{ErrorKind, Read as _, Write as _};
use std::net::{TcpListener, TcpStream};
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::bench::{At, BenchBoard, Flow, OnBarrier, Options, Outcome, Probe, Setup, run_pair};
use crate::boards::autopilot::Autopilot;
use crate::boards::camera::CameraBoard;
use crate::firmware::Firmware;
use crate::frames::Recorded;
use crate::link::{self, WireEnd};

/// Bridges one UART of a board (the [`WireEnd`] the board's [`BenchBoard`] exposes, chosen by
/// `uart`) to one TCP client.
pub struct TcpBridge<B> {
    stream: TcpStream,
    uart: fn(&mut B) -> &mut WireEnd,
    forwarded: usize,
    pace: Option<f64>,
    answer_wait: Option<Duration>,
    started: Option<(Instant, u64)>,
    /// Bytes sent to the client.
    pub bytes_out: u64,
    /// Bytes received from the client.
    pub bytes_in: u64,
    /// Why the bridge ended the run, if it did.
    pub ended: Option<String>,
}

impl<B> TcpBridge<B> {
    /// Waits for one client on `listener` and bridges `uart` to it; `pace` is virtual seconds
    /// per wall second (`None`: as fast as the bench runs).
    ///
    /// # Errors
    /// Accepting the client or setting up its socket failed.
    pub fn accept(
        listener: &TcpListener,
        uart: fn(&mut B) -> &mut WireEnd,
        pace: Option<f64>,
    ) -> std::io::Result<Self> {
        let (stream, _) = listener.accept()?;
        stream.set_nonblocking(true)?;
        stream.set_nodelay(true)?;
        Ok(Self {
            stream,
            uart,
            forwarded: 0,
            pace,
            answer_wait: None,
            started: None,
            bytes_out: 0,
            bytes_in: 0,
            ended: None,
        })
    }

    /// The same bridge, holding the bench at every stop where the board sent the client
    /// something until the client's next bytes arrive, at most `wait` of wall time: what they
    /// carry reaches the board at that stop's instant (see the module docs).
    #[must_use]
    pub fn answering_within(self, wait: Duration) -> Self {
        Self {
            answer_wait: Some(wait),
            ..self
        }
    }

    /// Closes the connection (both directions): the client sees the board gone. For when the
    /// run has ended but the bridge is kept (its counts).
    pub fn close(&self) {
        let _ = self.stream.shutdown(std::net::Shutdown::Both);
    }

    fn hold_to_pace(&mut self, now_ns: u64) {
        let Some(pace) = self.pace.filter(|p| *p > 0.0) else {
            return;
        };
        let (wall0, virtual0) = *self.started.get_or_insert((Instant::now(), now_ns));
        let due = Duration::from_secs_f64((now_ns - virtual0) as f64 / 1e9 / pace);
        let elapsed = wall0.elapsed();
        if due > elapsed {
            std::thread::sleep(due - elapsed);
        }
    }

    fn write_all(&mut self, mut bytes: &[u8]) -> std::io::Result<()> {
        while !bytes.is_empty() {
            match self.stream.write(bytes) {
                Ok(0) => return Err(ErrorKind::WriteZero.into()),
                Ok(n) => bytes = &bytes[n..],
                Err(e) if e.kind() == ErrorKind::WouldBlock => {
                    std::thread::sleep(Duration::from_micros(200));
                }
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }

    /// Waits up to `wait` for the client's next bytes and puts them on the board's line at
    /// `now_ns`.
    fn await_answer(&mut self, now_ns: u64, end: &WireEnd, wait: Duration) -> Result<(), String> {
        let mut buf = [0u8; 1024];
        let set = |stream: &TcpStream, blocking: bool| {
            stream
                .set_nonblocking(!blocking)
                .and_then(|()| stream.set_read_timeout(blocking.then_some(wait)))
                .map_err(|e| format!("the client's socket: {e}"))
        };
        set(&self.stream, true)?;
        let read = self.stream.read(&mut buf);
        set(&self.stream, false)?;
        match read {
            Ok(0) => Err(CLIENT_DISCONNECTED.into()),
            Ok(n) => {
                end.rx.send_at(now_ns, &buf[..n]);
                self.bytes_in += n as u64;
                Ok(())
            }
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => Ok(()),
            Err(e) if e.kind() == ErrorKind::Interrupted => Ok(()),
            Err(e) => Err(run_end(&e, "reading from")),
        }
    }

    fn exchange(&mut self, now_ns: u64, end: &WireEnd) -> Result<(), String> {
        let sent = end.tx.sent_bytes_from(self.forwarded);
        self.forwarded += sent.len();
        self.write_all(&sent)
            .map_err(|e| run_end(&e, "writing to"))?;
        self.bytes_out += sent.len() as u64;
        if let Some(wait) = self.answer_wait.filter(|_| !sent.is_empty()) {
            self.await_answer(now_ns, end, wait)?;
        }
        let mut buf = [0u8; 1024];
        loop {
            match self.stream.read(&mut buf) {
                Ok(0) => return Err(CLIENT_DISCONNECTED.into()),
                Ok(n) => {
                    end.rx.send_at(now_ns, &buf[..n]);
                    self.bytes_in += n as u64;
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => return Ok(()),
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(run_end(&e, "reading from")),
            }
        }
    }
}

/// How a run ends when the client goes away (closed or reset).
const CLIENT_DISCONNECTED: &str = "the client disconnected";

/// Why the run ends on a failed read or write (`doing`: "reading from", "writing to"). A client
/// that closes its socket while our telemetry is still unread in its buffer resets the
/// connection instead of closing it, and a write after its close breaks the pipe: it went away
/// all the same, whether a read or a write notices.
fn run_end(e: &std::io::Error, doing: &str) -> String {
    match e.kind() {
        ErrorKind::ConnectionReset | ErrorKind::ConnectionAborted | ErrorKind::BrokenPipe => {
            CLIENT_DISCONNECTED.into()
        }
        _ => format!("{doing} the client: {e}"),
    }
}

impl<B: BenchBoard + Send> Probe<B> for TcpBridge<B> {
    fn at(&mut self, at: &mut At<'_, B>) -> Flow {
        let now = at.now;
        self.hold_to_pace(now);
        let end = (self.uart)(at.board()).clone();
        match self.exchange(now, &end) {
            Ok(()) => Flow::Continue,
            Err(why) => {
                self.ended = Some(why);
                Flow::Stop
            }
        }
    }
}

/// How long a [`hil`] bridge holds the bench for the host's answer, wall time: far longer than
/// `sim-host hil` takes to step its world and send the next IMU sample (tens of microseconds),
/// short enough that the stops where no answer comes (heartbeats, status) cost little.
pub const HIL_ANSWER_WAIT: Duration = Duration::from_millis(20);

/// What [`hil`] leaves: each board's run (the board, its log, its bridge's counts).
pub type HilOutcome = (
    Outcome<CameraBoard, TcpBridge<CameraBoard>>,
    Outcome<Autopilot, TcpBridge<Autopilot>>,
);

/// The camera board's host UART (USART2), for [`TcpBridge::accept`].
pub fn camera_host(board: &mut CameraBoard) -> &mut WireEnd {
    &mut board.host
}

/// The autopilot's host UART (its telemetry port, USART1), for [`TcpBridge::accept`].
pub fn autopilot_host(board: &mut Autopilot) -> &mut WireEnd {
    &mut board.telemetry
}

/// Runs both `hil`-flavour images (`Firmware::hil`) on their boards, the camera board's UART4
/// joined to the autopilot's USART2 byte for byte, in lockstep at every `options.step_ns`; the
/// camera board's host UART goes to `camera`'s client and the autopilot's to `autopilot`'s
/// (accepted with [`camera_host`] and [`autopilot_host`]); both bridges wait for the host's
/// answers ([`TcpBridge::answering_within`] [`HIL_ANSWER_WAIT`]). `seed` draws the autopilot IMU's
/// noise (the hil image does not read its IMU). The camera sees no scene: its frames come over
/// the host UART, and the hil image holds the sensors in reset. Ends when either client leaves
/// (its bridge's [`TcpBridge::ended`] says why) or at `options.until_ns`.
///
/// # Errors
/// An image is missing or does not fit its part, a board fails to assemble, or rigless refuses
/// the run.
pub fn hil(
    camera: TcpBridge<CameraBoard>,
    autopilot: TcpBridge<Autopilot>,
    seed: u64,
    options: Options,
) -> Result<HilOutcome, String> {
    let (camera_end, autopilot_end) = link::join();
    let camera_rx: Arc<dyn OnBarrier> = Arc::new(camera_end.rx.clone());
    let autopilot_rx: Arc<dyn OnBarrier> = Arc::new(autopilot_end.rx.clone());
    let camera_board = CameraBoard::with_link(Box::new(Recorded::new(Vec::new())), camera_end)
        .map_err(|e| format!("the camera board: {e:?}"))?;
    let autopilot_board =
        Autopilot::with_link(seed, autopilot_end).map_err(|e| format!("the autopilot: {e:?}"))?;
    let (camera, autopilot) = run_pair(
        Setup {
            board: camera_board,
            firmware: Firmware::hil("stereo-board")?,
            probe: camera.answering_within(HIL_ANSWER_WAIT),
        },
        Setup {
            board: autopilot_board,
            firmware: Firmware::hil("autopilot")?,
            probe: autopilot.answering_within(HIL_ANSWER_WAIT),
        },
        options,
        vec![camera_rx],
        vec![autopilot_rx],
    )?;
    // The boards are off: their clients must not wait for them.
    camera.probe.close();
    autopilot.probe.close();
    Ok((camera, autopilot))
}
