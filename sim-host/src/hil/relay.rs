//! The board-to-board UART relayed through the host ([`Relay`]): bytes copied unchanged both
//! ways and decoded on the way to count messages and decoding errors; with the thread that
//! reads a link in chunks ([`read_chunks`]) and the sum of two links' error counts
//! ([`add_errors`]), which the rest of the HIL bridge uses too.

use crate::transport::{is_transient_read_error, Link};
use protocol::{
    AutopilotToStereo, AutopilotToStereoDecoder, LinkErrorCounts, StereoToAutopilot,
    StereoToAutopilotDecoder,
};
use std::io::{Read, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

/// Relays the board-to-board UART through the host: bytes are copied unchanged both ways and
/// decoded on the way (for counting). Threads end when either side closes.
pub struct Relay {
    seen: Arc<Mutex<RelayCounts>>,
}

#[derive(Debug, Default, Clone, Copy)]
struct RelayCounts {
    s2a: u64,
    a2s: u64,
    s2a_errors: LinkErrorCounts,
    a2s_errors: LinkErrorCounts,
}

impl Relay {
    /// Starts relaying between the camera board's and the autopilot's USART1.
    pub fn start(stereo: Box<dyn Link>, autopilot: Box<dyn Link>) -> anyhow::Result<Self> {
        let seen = Arc::new(Mutex::new(RelayCounts::default()));
        let (s_r, s_w) = (stereo.try_clone_link()?, stereo);
        let (a_r, a_w) = (autopilot.try_clone_link()?, autopilot);
        {
            let seen = Arc::clone(&seen);
            let mut dec = StereoToAutopilotDecoder::new_mid_stream();
            pump(s_r, a_w, move |bytes| {
                let mut g = seen.lock().unwrap_or_else(|e| e.into_inner());
                let mut n = 0;
                dec.feed(bytes, |_: StereoToAutopilot| n += 1);
                g.s2a += n;
                g.s2a_errors = dec.errors();
            });
        }
        {
            let seen = Arc::clone(&seen);
            let mut dec = AutopilotToStereoDecoder::new_mid_stream();
            pump(a_r, s_w, move |bytes| {
                let mut g = seen.lock().unwrap_or_else(|e| e.into_inner());
                let mut n = 0;
                dec.feed(bytes, |_: AutopilotToStereo| n += 1);
                g.a2s += n;
                g.a2s_errors = dec.errors();
            });
        }
        Ok(Self { seen })
    }

    /// Messages relayed (camera -> autopilot, autopilot -> camera) and decoding errors (both
    /// directions added up) so far.
    pub fn counts(&self) -> ([u64; 2], LinkErrorCounts) {
        let g = *self.seen.lock().unwrap_or_else(|e| e.into_inner());
        ([g.s2a, g.a2s], add_errors(g.s2a_errors, g.a2s_errors))
    }
}

pub(super) fn add_errors(a: LinkErrorCounts, b: LinkErrorCounts) -> LinkErrorCounts {
    LinkErrorCounts {
        crc: a.crc + b.crc,
        cobs: a.cobs + b.cobs,
        too_long: a.too_long + b.too_long,
        too_short: a.too_short + b.too_short,
        unknown_message: a.unknown_message + b.unknown_message,
        malformed: a.malformed + b.malformed,
        version_mismatch: a.version_mismatch + b.version_mismatch,
    }
}

/// Reads `from` on a thread until it ends, fails, `stop` is set, or `on_chunk` returns false.
pub(super) fn read_chunks(
    mut from: Box<dyn Link>,
    stop: Arc<AtomicBool>,
    mut on_chunk: impl FnMut(&[u8]) -> bool + Send + 'static,
) {
    std::thread::spawn(move || {
        let mut buf = [0u8; 1024];
        while !stop.load(Ordering::Relaxed) {
            match from.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => {
                    if !on_chunk(buf.get(..n).unwrap_or(&[])) {
                        break;
                    }
                }
                Err(e) if is_transient_read_error(&e) => {}
                Err(_) => break,
            }
        }
    });
}

/// Copies `from` to `to` on a thread, showing every chunk to `tap` first.
fn pump(from: Box<dyn Link>, mut to: Box<dyn Link>, mut tap: impl FnMut(&[u8]) + Send + 'static) {
    read_chunks(from, Arc::new(AtomicBool::new(false)), move |bytes| {
        tap(bytes);
        to.write_all(bytes).is_ok()
    });
}
