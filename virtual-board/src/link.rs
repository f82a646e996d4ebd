//! Serial lines: what a board's UART sends and hears, and two boards' UARTs joined.
//!
//! A [`WireEnd`] is the far end of one board's USART (rigless's `chip::uart::Peer`): every
//! word the board sends goes onto its outgoing [`Line`], every word on its incoming line whose
//! instant has come is offered to the USART, which times its reception at its own baud (so a
//! word arrives one frame after the USART takes it: on a joined link, one frame after the
//! sender finished it, at most one lockstep quantum later).
//!
//! [`join`] crosses two ends (TX to RX both ways). Each line carries the baud its sender is set
//! to (the boards read it off `BRR` and the bus clock); a receiver set more than 2.5 % away
//! (beyond what 16x oversampling tolerates, RM0090 section 30.3.5) hears garbled words, as a
//! real one would, and counts them. A line can be cut (a test's fault): what is sent on it is
//! lost.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

use rigless::chip::Timeline;
use rigless::chip::uart::Peer;
use rigless::snapshot::Store;
use rigless::time::VirtualNanos;

use crate::bench::OnBarrier;

/// One direction of a serial line.
#[derive(Debug, Default)]
pub struct LineState {
    /// Words on the way: (instant the sender finished it, ns; word).
    queue: VecDeque<(u64, u16)>,
    /// Words the receiver may take: those finished before this instant, ns.
    released_until: u64,
    /// Every word sent, with its instant, ns.
    sent: Vec<(u64, u16)>,
    /// Every word the receiver took, with its instant, ns.
    delivered: Vec<(u64, u16)>,
    /// The sender's configured baud, when known.
    sender_baud: Option<u32>,
    /// The receiver's configured baud, when known.
    receiver_baud: Option<u32>,
    /// Words garbled by a baud mismatch.
    garbled: u64,
    /// Words lost on a cut line.
    lost: u64,
    cut: bool,
}

/// One direction of a serial line, shared by its two ends.
#[derive(Debug, Clone, Default)]
pub struct Line(Arc<Mutex<LineState>>);

impl Line {
    /// A line whose words the receiver may take as soon as they are due (a test feeding one
    /// board, no lockstep).
    #[must_use]
    pub fn open() -> Self {
        let line = Self::default();
        line.state().released_until = u64::MAX;
        line
    }

    fn state(&self) -> std::sync::MutexGuard<'_, LineState> {
        self.0.lock().expect("line lock")
    }

    /// Puts `bytes` on the line as if a sender finished them at `at_ns` (a test's host).
    pub fn send_at(&self, at_ns: u64, bytes: &[u8]) {
        let mut state = self.state();
        for &byte in bytes {
            state.queue.push_back((at_ns, u16::from(byte)));
            state.sent.push((at_ns, u16::from(byte)));
        }
    }

    /// Every byte sent on the line so far.
    #[must_use]
    pub fn sent_bytes(&self) -> Vec<u8> {
        self.state()
            .sent
            .iter()
            .map(|&(_, w)| (w & 0xFF) as u8)
            .collect()
    }

    /// The bytes sent on the line after the first `skip` (a reader that keeps its place).
    #[must_use]
    pub fn sent_bytes_from(&self, skip: usize) -> Vec<u8> {
        self.state()
            .sent
            .iter()
            .skip(skip)
            .map(|&(_, w)| (w & 0xFF) as u8)
            .collect()
    }

    /// Every word sent, with its instant (ns).
    #[must_use]
    pub fn sent(&self) -> Vec<(u64, u16)> {
        self.state().sent.clone()
    }

    /// Every byte the receiver took.
    #[must_use]
    pub fn delivered_bytes(&self) -> Vec<u8> {
        self.state()
            .delivered
            .iter()
            .map(|&(_, w)| (w & 0xFF) as u8)
            .collect()
    }

    /// Cuts (or mends) the line: while cut, what is sent is lost.
    pub fn set_cut(&self, cut: bool) {
        self.state().cut = cut;
    }

    /// The sender's configured baud.
    pub fn set_sender_baud(&self, baud: Option<u32>) {
        self.state().sender_baud = baud;
    }

    /// The receiver's configured baud.
    pub fn set_receiver_baud(&self, baud: Option<u32>) {
        self.state().receiver_baud = baud;
    }

    /// The sender's and receiver's configured bauds.
    #[must_use]
    pub fn bauds(&self) -> (Option<u32>, Option<u32>) {
        let state = self.state();
        (state.sender_baud, state.receiver_baud)
    }

    /// Words garbled by a baud mismatch.
    #[must_use]
    pub fn garbled(&self) -> u64 {
        self.state().garbled
    }

    /// Words lost while cut.
    #[must_use]
    pub fn lost(&self) -> u64 {
        self.state().lost
    }

    fn push(&self, at_ns: u64, word: u16) {
        let mut state = self.state();
        state.sent.push((at_ns, word));
        if state.cut {
            state.lost += 1;
        } else {
            state.queue.push_back((at_ns, word));
        }
    }

    fn pop(&self, now_ns: u64) -> Option<u16> {
        let mut state = self.state();
        let &(at, word) = state.queue.front()?;
        if at > now_ns || (at >= state.released_until && state.released_until != u64::MAX) {
            return None;
        }
        state.queue.pop_front();
        let word = match (state.sender_baud, state.receiver_baud) {
            (Some(tx), Some(rx)) if mismatched(tx, rx) => {
                state.garbled += 1;
                // Sampled at the wrong rate: bits shifted and a framing error; this is one of
                // the wrong words a real receiver could assemble.
                (word ^ 0x55) & 0xFF
            }
            _ => word,
        };
        state.delivered.push((now_ns, word));
        Some(word)
    }
}

/// Two bauds too far apart for a 16x-oversampling receiver (RM0090 30.3.5: about 3.75 %
/// total; we allow 2.5 % between the two ends).
fn mismatched(a: u32, b: u32) -> bool {
    let (a, b) = (f64::from(a), f64::from(b));
    (a - b).abs() / a.max(b) > 0.025
}

/// Releases a line's words to its receiver at a lockstep barrier.
impl OnBarrier for Line {
    fn barrier(&self, now: u64) {
        self.state().released_until = now;
    }
}

/// The far end of one board's USART: what it sends goes on `tx`, what it hears comes off `rx`.
#[derive(Debug, Clone)]
pub struct WireEnd {
    /// What the board sends.
    pub tx: Line,
    /// What the board hears.
    pub rx: Line,
}

impl WireEnd {
    /// An end on two open lines: a test reads `tx` and feeds `rx`.
    #[must_use]
    pub fn open() -> Self {
        Self {
            tx: Line::open(),
            rx: Line::open(),
        }
    }
}

impl Store for WireEnd {}

impl Peer for WireEnd {
    fn receive(&mut self, word: u16, context: &mut Timeline<'_, '_>) {
        self.tx.push(context.now().0, word);
    }

    fn transmit(&mut self, now: VirtualNanos) -> Option<u16> {
        self.rx.pop(now.0)
    }
}

/// Two boards' UARTs crossed: `a`'s TX is `b`'s RX and the other way round. Give `a` to one
/// board's USART and `b` to the other's; release `a.rx` on board A's barrier and `b.rx` on
/// board B's ([`crate::bench::run_pair`]).
#[must_use]
pub fn join() -> (WireEnd, WireEnd) {
    let a_to_b = Line::default();
    let b_to_a = Line::default();
    (
        WireEnd {
            tx: a_to_b.clone(),
            rx: b_to_a.clone(),
        },
        WireEnd {
            tx: b_to_a,
            rx: a_to_b,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_joined_line_releases_words_only_past_the_barrier() {
        let (a, b) = join();
        a.tx.push(100, 0x41);
        assert_eq!(b.rx.pop(1_000), None, "not released yet");
        b.rx.barrier(100);
        assert_eq!(
            b.rx.pop(1_000),
            None,
            "finished at the barrier instant: next quantum"
        );
        b.rx.barrier(200);
        assert_eq!(b.rx.pop(50), None, "not due before it was sent");
        assert_eq!(b.rx.pop(200), Some(0x41));
    }

    #[test]
    fn mismatched_bauds_garble_and_a_cut_line_loses() {
        let (a, b) = join();
        a.tx.set_sender_baud(Some(115_200));
        a.tx.set_receiver_baud(Some(921_600));
        a.tx.push(0, 0x41);
        b.rx.barrier(10);
        assert_ne!(b.rx.pop(10), Some(0x41));
        assert_eq!(a.tx.garbled(), 1);
        a.tx.set_cut(true);
        a.tx.push(20, 0x42);
        assert_eq!(a.tx.lost(), 1);
    }
}
