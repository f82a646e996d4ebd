//! Simulated UART: carries the real protocol bytes one way at a configured baud rate (8N1: ten
//! bit times per byte), with fault injection: bit errors, dropped bytes and outages.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::VecDeque;
use timebase::WorldTime;

/// Bits on the wire per byte, 8N1: start bit, 8 data bits, stop bit.
const BITS_PER_BYTE: f64 = 10.0;

/// Faults injected on a link.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LinkFaults {
    /// Probability that any one data bit is flipped.
    pub bit_error_rate: f64,
    /// Probability that a byte is lost (framing error, overrun).
    pub drop_rate: f64,
    /// Outages `[start, end)` in µs of simulation time: every byte on the wire is lost.
    pub outages: Vec<(u64, u64)>,
}

impl LinkFaults {
    /// True while an outage is in progress at `t_us`.
    pub fn in_outage(&self, t_us: u64) -> bool {
        self.outages.iter().any(|&(a, b)| t_us >= a && t_us < b)
    }
}

/// Link statistics.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct UartStats {
    /// Bytes written by the sender.
    pub bytes_sent: u64,
    /// Bytes delivered to the receiver.
    pub bytes_delivered: u64,
    /// Bytes with at least one flipped bit.
    pub bytes_corrupted: u64,
    /// Bytes lost (drops, outages, transmit-buffer overflow).
    pub bytes_lost: u64,
}

/// One direction of a UART.
#[derive(Debug, Clone)]
pub struct SimUart {
    /// Baud rate, bit/s.
    pub baud: u32,
    /// Faults.
    pub faults: LinkFaults,
    /// Largest number of bytes queued for transmission (the sender's DMA buffer); more are lost.
    pub tx_capacity: usize,
    queue: VecDeque<(u64, u8)>,
    line_free_us: f64,
    rng: ChaCha8Rng,
    stats: UartStats,
}

impl SimUart {
    /// A link at `baud` with `faults`, its fault randomness seeded by `seed`.
    pub fn new(baud: u32, faults: LinkFaults, seed: u64) -> Self {
        Self {
            baud: baud.max(1),
            faults,
            tx_capacity: 4096,
            queue: VecDeque::new(),
            line_free_us: 0.0,
            rng: ChaCha8Rng::seed_from_u64(seed),
            stats: UartStats::default(),
        }
    }

    /// Time on the wire of one byte, µs.
    pub fn byte_time_us(&self) -> f64 {
        BITS_PER_BYTE * super::US_PER_S / self.baud as f64
    }

    /// The sender writes `bytes` at `now`; they go out back to back after anything queued.
    pub fn write(&mut self, now: WorldTime, bytes: &[u8]) {
        let bt = self.byte_time_us();
        // The line's own clock runs in fractional microseconds.
        let mut t = self.line_free_us.max(now.as_micros() as f64);
        for &b in bytes {
            self.stats.bytes_sent += 1;
            if self.queue.len() >= self.tx_capacity {
                self.stats.bytes_lost += 1;
                continue;
            }
            t += bt;
            let arrive = t.ceil() as u64;
            if self.faults.in_outage(arrive) || self.rng.random::<f64>() < self.faults.drop_rate {
                self.stats.bytes_lost += 1;
                continue;
            }
            let mut byte = b;
            if self.faults.bit_error_rate > 0.0 {
                for bit in 0..8 {
                    if self.rng.random::<f64>() < self.faults.bit_error_rate {
                        byte ^= 1 << bit;
                    }
                }
                if byte != b {
                    self.stats.bytes_corrupted += 1;
                }
            }
            self.queue.push_back((arrive, byte));
        }
        self.line_free_us = t;
    }

    /// Moves every byte that has fully arrived by `now` into `out`.
    pub fn receive(&mut self, now: WorldTime, out: &mut Vec<u8>) {
        while let Some(&(t, b)) = self.queue.front() {
            if t > now.as_micros() {
                break;
            }
            self.queue.pop_front();
            self.stats.bytes_delivered += 1;
            out.push(b);
        }
    }

    /// Arrival time of the next byte in flight.
    pub fn next_arrival(&self) -> Option<WorldTime> {
        self.queue.front().map(|&(t, _)| WorldTime::from_micros(t))
    }

    /// Statistics so far.
    pub fn stats(&self) -> UartStats {
        self.stats
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_take_ten_bit_times_and_keep_order() {
        let mut u = SimUart::new(115_200, LinkFaults::default(), 1);
        u.write(WorldTime::from_micros(1000), &[1, 2, 3]);
        let mut out = Vec::new();
        u.receive(WorldTime::from_micros(1000 + 86), &mut out);
        assert!(out.is_empty());
        u.receive(WorldTime::from_micros(1000 + 87), &mut out);
        assert_eq!(out, [1]);
        u.receive(WorldTime::from_micros(1000 + 261), &mut out);
        assert_eq!(out, [1, 2, 3]);
    }

    #[test]
    fn faults_corrupt_drop_and_black_out() {
        let faults = LinkFaults {
            bit_error_rate: 1e-2,
            drop_rate: 0.0,
            outages: vec![(1_000_000, 2_000_000)],
        };
        let mut u = SimUart::new(1_000_000, faults, 2);
        let data = vec![0x55u8; 4_000];
        u.write(WorldTime::from_micros(0), &data);
        let mut out = Vec::new();
        u.receive(WorldTime::from_micros(u64::MAX), &mut out);
        let s = u.stats();
        assert_eq!(out.len(), 4_000);
        // 8 bits at 1e-2: ~7.7 % of the bytes corrupted.
        assert!(s.bytes_corrupted > 200 && s.bytes_corrupted < 420, "{s:?}");
        u.write(WorldTime::from_micros(1_500_000), &data[..100]);
        out.clear();
        u.receive(WorldTime::from_micros(u64::MAX), &mut out);
        assert!(out.is_empty());
        assert_eq!(u.stats().bytes_lost, 100);
    }
}
