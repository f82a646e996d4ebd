//! The byte stream to a board that every host tool opens (`hil`, `monitor`, `param`, `key`): a
//! serial port, or a TCP connection to a QEMU chardev or a virtual board.

use anyhow::{anyhow, bail, Context};
use std::io::{Read, Write};
use std::time::{Duration, Instant};

/// One byte stream to a board: a serial device or a TCP connection to a QEMU chardev.
pub trait Link: Read + Write + Send {
    /// A second handle on the same stream (one thread reads, another writes).
    fn try_clone_link(&self) -> std::io::Result<Box<dyn Link>>;
}

/// A read error that only means "nothing yet" (a serial port's read timeout, a non-blocking
/// socket, a signal): the reader tries again instead of closing the link.
pub fn is_transient_read_error(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        std::io::ErrorKind::WouldBlock
            | std::io::ErrorKind::TimedOut
            | std::io::ErrorKind::Interrupted
    )
}

impl Link for std::net::TcpStream {
    fn try_clone_link(&self) -> std::io::Result<Box<dyn Link>> {
        Ok(Box::new(self.try_clone()?))
    }
}

/// Opens `addr`: `tcp:HOST:PORT` (or `HOST:PORT`) connects to a TCP server such as a QEMU
/// `-chardev socket,server=on,...`; anything else is a serial port (`/dev/ttyUSB0`, `COM3`)
/// opened raw 8N1, no flow control, at `baud` bit/s (any rate the adapter supports).
pub fn open_link(addr: &str, baud: u32) -> anyhow::Result<Box<dyn Link>> {
    let tcp = addr
        .strip_prefix("tcp:")
        .or_else(|| (!addr.starts_with('/') && addr.contains(':')).then_some(addr));
    if let Some(hostport) = tcp {
        let s = std::net::TcpStream::connect(hostport)
            .with_context(|| format!("connecting to {hostport}"))?;
        s.set_nodelay(true).ok();
        return Ok(Box::new(s));
    }
    Ok(Box::new(SerialLink::open(addr, baud)?))
}

/// A serial port (through the `serialport` crate) as a [`Link`].
///
/// Reads wait at most [`SerialLink::POLL`] and then report `TimedOut`, so reader threads can
/// notice that they should stop; writes go on waiting for the port's transmit buffer for up
/// to [`SerialLink::WRITE_TIMEOUT`] in all before they fail.
pub struct SerialLink {
    port: Box<dyn serialport::SerialPort>,
}

impl SerialLink {
    /// Longest single wait of a read.
    pub const POLL: Duration = Duration::from_millis(100);
    /// Longest time a write may wait for room in the transmit buffer.
    pub const WRITE_TIMEOUT: Duration = Duration::from_secs(10);

    /// Opens `path` raw 8N1 at `baud` bit/s without flow control; errors name the port.
    pub fn open(path: &str, baud: u32) -> anyhow::Result<Self> {
        if baud == 0 {
            bail!("serial port {path}: baud rate 0 (give the board's rate, e.g. 921600)");
        }
        let port = serialport::new(path, baud)
            .data_bits(serialport::DataBits::Eight)
            .parity(serialport::Parity::None)
            .stop_bits(serialport::StopBits::One)
            .flow_control(serialport::FlowControl::None)
            .timeout(Self::POLL)
            .open()
            .map_err(|e| anyhow!("serial port {path} at {baud} Bd: {}", describe(&e)))?;
        Ok(Self { port })
    }
}

/// A serialport error in words a user can act on.
fn describe(e: &serialport::Error) -> String {
    match e.kind() {
        serialport::ErrorKind::NoDevice => format!("no such device or it is busy ({e})"),
        serialport::ErrorKind::InvalidInput => format!("not accepted ({e})"),
        serialport::ErrorKind::Io(std::io::ErrorKind::NotFound) => {
            format!("no such device ({e})")
        }
        serialport::ErrorKind::Io(std::io::ErrorKind::PermissionDenied) => {
            format!("permission denied (is the user in the dialout group?) ({e})")
        }
        // ENOTTY from the terminal set-up calls (nix words it "Not a typewriter").
        serialport::ErrorKind::Unknown
            if ["typewriter", "ioctl", "tty"]
                .iter()
                .any(|w| e.description.to_ascii_lowercase().contains(w)) =>
        {
            format!("not a serial device ({e})")
        }
        _ => e.to_string(),
    }
}

impl Read for SerialLink {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        self.port.read(buf)
    }
}

impl Write for SerialLink {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let deadline = Instant::now() + Self::WRITE_TIMEOUT;
        loop {
            match self.port.write(buf) {
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut && Instant::now() < deadline => {
                }
                other => return other,
            }
        }
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.port.flush()
    }
}

impl Link for SerialLink {
    fn try_clone_link(&self) -> std::io::Result<Box<dyn Link>> {
        let port = self.port.try_clone().map_err(std::io::Error::from)?;
        Ok(Box::new(SerialLink { port }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    #[cfg(unix)]
    use protocol::{BoardToHost, BoardToHostDecoder, Heartbeat, Node};
    #[cfg(unix)]
    use stereo_board::app::send_to_host;

    #[test]
    fn addresses_parse() {
        let e = open_link("tcp:127.0.0.1:1", 921_600)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("127.0.0.1:1"), "nothing listens: {e}");
        let e = open_link("/dev/null", 921_600).err().unwrap().to_string();
        assert!(
            e.contains("/dev/null") && e.contains("not a serial device"),
            "{e}"
        );
        let e = open_link("/dev/ttyNOSUCH7", 921_600)
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("/dev/ttyNOSUCH7") && e.contains("no such device"),
            "{e}"
        );
        let e = open_link("/dev/null", 0).err().unwrap().to_string();
        assert!(e.contains("baud rate 0"), "{e}");
    }

    /// A pseudo-terminal is a real tty: open it at rates below 115,200 and off the standard
    /// list, and pass a message through it both ways.
    #[cfg(unix)]
    #[test]
    fn serial_ports_open_at_any_baud_rate_and_carry_bytes() {
        use serialport::SerialPort as _;
        for baud in [9_600, 57_600, 250_000, 921_600] {
            let (mut master, slave) = serialport::TTYPort::pair().unwrap();
            let path = slave.name().unwrap();
            drop(slave);
            master.set_timeout(Duration::from_secs(2)).unwrap();
            let mut link = open_link(&path, baud).unwrap_or_else(|e| panic!("{path}: {e:#}"));
            let mut reader = link.try_clone_link().unwrap();
            let msg = BoardToHost::Heartbeat(Heartbeat::new(Node::Autopilot, 7));
            let mut bytes = Vec::new();
            send_to_host(&msg, &mut |b| bytes.extend_from_slice(b));
            master.write_all(&bytes).unwrap();
            let mut got = Vec::new();
            let mut dec = BoardToHostDecoder::new();
            let mut buf = [0u8; 64];
            let deadline = Instant::now() + Duration::from_secs(5);
            while got.is_empty() && Instant::now() < deadline {
                match reader.read(&mut buf) {
                    Ok(n) => dec.feed(&buf[..n], |m| got.push(m)),
                    Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
                    Err(e) => panic!("{path} at {baud}: {e}"),
                }
            }
            assert_eq!(got, vec![msg], "{path} at {baud} Bd");
            link.write_all(b"pong").unwrap();
            let mut back = [0u8; 4];
            master.read_exact(&mut back).unwrap();
            assert_eq!(&back, b"pong");
        }
    }
}
