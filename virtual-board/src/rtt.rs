//! The firmware's defmt log over RTT, read as a debug probe reads it, and decoded.
//!
//! SEGGER's RTT control block (`_SEGGER_RTT`): a 16-byte id, the up and down buffer counts, then
//! the up buffers, each `{name, buffer, size, write offset, read offset, flags}` of 32-bit words.
//! The bench drains up-channel 0 at every stop it makes (between the firmware's instructions),
//! writes the read offset back as a probe does, and decodes the bytes with the firmware's defmt
//! table (`defmt-decoder`).

use rigless::emulator::Memory;
use rigless::soc::Width;

/// Offset of up-buffer 0 in the control block, and of its fields.
const UP0: u64 = 24;
const BUFFER: u64 = 4;
const SIZE: u64 = 8;
const WRITE: u64 = 12;
const READ: u64 = 16;

/// One decoded log line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Line {
    /// Virtual time of the drain that brought it, ns (the line was logged at or before it).
    pub at_ns: u64,
    /// The message as defmt formats it, with its level.
    pub text: String,
}

/// Reads and decodes one firmware's RTT up-channel 0.
pub struct RttLog {
    control: Option<u64>,
    decoder: Option<Box<dyn defmt_decoder::StreamDecoder + Send + Sync + 'static>>,
    raw: Vec<u8>,
    lines: Vec<Line>,
    errors: u32,
}

impl std::fmt::Debug for RttLog {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RttLog")
            .field("control", &self.control)
            .field("raw", &self.raw.len())
            .field("lines", &self.lines.len())
            .finish_non_exhaustive()
    }
}

impl RttLog {
    /// A reader of the control block at `control` (`None`: the firmware has none), decoding with
    /// `table` (`None`: bytes kept raw).
    #[must_use]
    pub fn new(control: Option<u64>, table: Option<&'static defmt_decoder::Table>) -> Self {
        Self {
            control,
            decoder: table.map(|table| table.new_stream_decoder()),
            raw: Vec::new(),
            lines: Vec::new(),
            errors: 0,
        }
    }

    /// Drains what the firmware wrote since the last drain, at virtual time `at_ns`.
    pub fn drain(&mut self, memory: &mut dyn Memory, at_ns: u64) {
        let Some(control) = self.control else {
            return;
        };
        let word = |memory: &mut dyn Memory, address: u64| memory.read(address, Width::W32).ok();
        let up = control + UP0;
        let (Some(buffer), Some(size), Some(write), Some(read)) = (
            word(memory, up + BUFFER),
            word(memory, up + SIZE),
            word(memory, up + WRITE),
            word(memory, up + READ),
        ) else {
            return;
        };
        // Before the firmware has set the block up, its fields are zero or garbage.
        if size == 0 || write >= size || read >= size || buffer == 0 {
            return;
        }
        let mut bytes = Vec::new();
        let mut at = read;
        while at != write {
            match memory.read(buffer + at, Width::W8) {
                Ok(byte) => bytes.push(byte as u8),
                Err(_) => return,
            }
            at = (at + 1) % size;
        }
        if bytes.is_empty() {
            return;
        }
        if memory.write(up + READ, Width::W32, write).is_err() {
            return;
        }
        self.raw.extend_from_slice(&bytes);
        if let Some(decoder) = &mut self.decoder {
            decoder.received(&bytes);
            loop {
                match decoder.decode() {
                    Ok(frame) => self.lines.push(Line {
                        at_ns,
                        text: frame.display(false).to_string(),
                    }),
                    Err(defmt_decoder::DecodeError::UnexpectedEof) => break,
                    Err(defmt_decoder::DecodeError::Malformed) => {
                        self.errors += 1;
                        if self.errors > 1000 {
                            break;
                        }
                    }
                }
            }
        }
    }

    /// The decoded lines so far.
    #[must_use]
    pub fn lines(&self) -> &[Line] {
        &self.lines
    }

    /// The value of `key=` in the last status line (`status uptime_ms=... key=value ...`, one
    /// a second from each board's firmware) drained before `before_ns`; `true` and `false`
    /// read as 1 and 0.
    #[must_use]
    pub fn status_before(&self, key: &str, before_ns: u64) -> Option<u64> {
        let pattern = format!("{key}=");
        let line = self
            .lines
            .iter()
            .rev()
            .filter(|l| l.at_ns < before_ns)
            .find(|l| l.text.contains("status uptime_ms="))?;
        line.text
            .split_whitespace()
            .find_map(|field| field.strip_prefix(pattern.as_str()))
            .and_then(|v| match v {
                "true" => Some(1),
                "false" => Some(0),
                v => v.parse().ok(),
            })
    }

    /// The value of `key=` in the last status line (see [`RttLog::status_before`]).
    #[must_use]
    pub fn status(&self, key: &str) -> Option<u64> {
        self.status_before(key, u64::MAX)
    }

    /// Every raw byte drained.
    #[must_use]
    pub fn raw(&self) -> &[u8] {
        &self.raw
    }

    /// Malformed frames the decoder rejected.
    #[must_use]
    pub fn malformed(&self) -> u32 {
        self.errors
    }

    /// The log as text, one line each with its virtual time in ms.
    #[must_use]
    pub fn text(&self) -> String {
        let mut out = String::new();
        for line in &self.lines {
            out += &format!("[{:>10.3} ms] {}\n", line.at_ns as f64 / 1e6, line.text);
        }
        if self.decoder.is_none() && !self.raw.is_empty() {
            out += &format!("({} raw RTT bytes, no defmt table)\n", self.raw.len());
        }
        out
    }
}
