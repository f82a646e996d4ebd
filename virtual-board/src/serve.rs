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

use std::io::{ErrorKind, Read as _, Write as _};
use std::net::{TcpListener, TcpStream};
use std::time::{Duration, Instant};

use crate::bench::{At, BenchBoard, Flow, Probe};
use crate::link::WireEnd;

/// Bridges one UART of a board (the [`WireEnd`] the board's [`BenchBoard`] exposes, chosen by
/// `uart`) to one TCP client.
pub struct TcpBridge<B> {
    stream: TcpStream,
    uart: fn(&mut B) -> &mut WireEnd,
    forwarded: usize,
    pace: Option<f64>,
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
            started: None,
            bytes_out: 0,
            bytes_in: 0,
            ended: None,
        })
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

    fn exchange(&mut self, now_ns: u64, end: &WireEnd) -> Result<(), String> {
        let sent = end.tx.sent_bytes_from(self.forwarded);
        self.forwarded += sent.len();
        self.write_all(&sent)
            .map_err(|e| format!("the client went away: {e}"))?;
        self.bytes_out += sent.len() as u64;
        let mut buf = [0u8; 1024];
        loop {
            match self.stream.read(&mut buf) {
                Ok(0) => return Err("the client disconnected".into()),
                Ok(n) => {
                    end.rx.send_at(now_ns, &buf[..n]);
                    self.bytes_in += n as u64;
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => return Ok(()),
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(format!("reading from the client: {e}")),
            }
        }
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
