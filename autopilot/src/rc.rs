//! RC input: an SBUS receiver (Futaba protocol, FrSky/others compatible) mapped to pilot
//! commands.
//!
//! SBUS is chosen over PPM because it needs one UART RX pin and no timer capture, carries 16
//! proportional channels with an explicit frame-lost and failsafe flag, and is what small
//! receivers (FrSky XM, R-XSR) deliver. The line is 100,000 Bd, 8 data bits, even parity,
//! 2 stop bits, **inverted**: an STM32F4 USART cannot invert, so the receiver's non-inverted
//! pad or a one-transistor inverter is needed (see `docs/hardware.md`).
//!
//! A frame is 25 bytes, sent every 7 ms (high speed) or 14 ms:
//!
//! | byte | content |
//! |---|---|
//! | 0 | header `0x0F` |
//! | 1..=22 | 16 channels of 11 bits, little-endian bit order (channel 1 in the lowest bits) |
//! | 23 | flags: bit 0 digital channel 17, bit 1 digital channel 18, bit 2 frame lost, bit 3 failsafe |
//! | 24 | footer `0x00` (SBUS2 receivers cycle `0x04`, `0x14`, `0x24`, `0x34`) |
//!
//! [`SbusDecoder`] finds frames in any byte stream (sync on header + footer, resync after
//! garbage) and never panics; [`RcCommands`] turns frames (or their absence) into
//! [`PilotCommand`]s for [`crate::Autopilot::on_command`]:
//!
//! * kill switch (channel 6 by default) high, the receiver's failsafe flag, or no valid frame
//!   for [`RcConfig::timeout`] once RC has been seen => `Kill` (sent once per entry);
//! * arm switch (channel 5) low -> high while not killed => `Arm`; high -> low => `Land`.
//!
//! Before the first valid frame RC is "not in use" and produces nothing, so a drone armed
//! from the host link (HIL, ground tool) is not killed by a missing receiver.

use protocol::PilotCommand;
use timebase::{Duration, Instant};

/// Bytes in one SBUS frame.
pub const SBUS_FRAME_BYTES: usize = 25;
/// SBUS header byte.
pub const SBUS_HEADER: u8 = 0x0F;
/// SBUS baud rate (8E2, inverted).
pub const SBUS_BAUD: u32 = 100_000;
/// Proportional channels in a frame.
pub const SBUS_CHANNELS: usize = 16;

/// One decoded SBUS frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SbusFrame {
    /// Channels 1..=16, raw 11-bit values (0..=2047; sticks and switches span about 172..=1811,
    /// 992 is centre).
    pub channels: [u16; SBUS_CHANNELS],
    /// Digital channel 17.
    pub ch17: bool,
    /// Digital channel 18.
    pub ch18: bool,
    /// The receiver missed this frame from the transmitter (it repeats the last one).
    pub frame_lost: bool,
    /// The receiver is in failsafe: the transmitter link is gone.
    pub failsafe: bool,
}

impl SbusFrame {
    /// Decodes a 25-byte frame; `None` unless header and footer are valid.
    pub fn parse(bytes: &[u8; SBUS_FRAME_BYTES]) -> Option<Self> {
        let [header, data @ .., flags, footer] = bytes;
        if *header != SBUS_HEADER || !valid_footer(*footer) {
            return None;
        }
        let mut channels = [0u16; SBUS_CHANNELS];
        let mut acc: u32 = 0;
        let mut bits = 0u32;
        let mut bytes_in = data.iter();
        for ch in channels.iter_mut() {
            while bits < 11 {
                let b = bytes_in.next().copied().unwrap_or(0);
                acc |= u32::from(b) << bits;
                bits += 8;
            }
            *ch = (acc & 0x7FF) as u16;
            acc >>= 11;
            bits -= 11;
        }
        Some(Self {
            channels,
            ch17: flags & 0x01 != 0,
            ch18: flags & 0x02 != 0,
            frame_lost: flags & 0x04 != 0,
            failsafe: flags & 0x08 != 0,
        })
    }

    /// Encodes the frame (for tests and simulated receivers). Channel values are masked to
    /// 11 bits.
    pub fn encode(&self) -> [u8; SBUS_FRAME_BYTES] {
        let mut out = [0u8; SBUS_FRAME_BYTES];
        out[0] = SBUS_HEADER;
        let mut acc: u32 = 0;
        let mut bits = 0u32;
        let mut i = 1;
        for &ch in &self.channels {
            acc |= u32::from(ch & 0x7FF) << bits;
            bits += 11;
            while bits >= 8 {
                if let Some(slot) = out.get_mut(i) {
                    *slot = acc as u8;
                }
                i += 1;
                acc >>= 8;
                bits -= 8;
            }
        }
        out[23] = u8::from(self.ch17)
            | u8::from(self.ch18) << 1
            | u8::from(self.frame_lost) << 2
            | u8::from(self.failsafe) << 3;
        out[24] = 0x00;
        out
    }

    /// Channel `n` (1-based), if it exists.
    pub fn channel(&self, n: usize) -> Option<u16> {
        n.checked_sub(1).and_then(|i| self.channels.get(i)).copied()
    }
}

fn valid_footer(b: u8) -> bool {
    b == 0x00 || (b & 0x0F == 0x04 && b >> 4 <= 3)
}

/// Finds SBUS frames in a byte stream of any chunking.
///
/// Keeps the last 25 bytes; whenever they form a valid frame (header, footer), it is returned
/// and the window starts over. A byte gap longer than [`SbusDecoder::GAP`] (the inter-frame
/// pause) also starts over, which resynchronises at once on a clean line.
#[derive(Debug, Clone)]
pub struct SbusDecoder {
    buf: [u8; SBUS_FRAME_BYTES],
    len: usize,
    last_byte: Option<Instant>,
    frames: u32,
    rejected: u32,
}

impl Default for SbusDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl SbusDecoder {
    /// Pause between bytes that marks a frame boundary (a byte takes 120 µs; frames are
    /// 3-11 ms apart).
    pub const GAP: Duration = Duration::from_millis(2);

    /// An empty decoder.
    pub const fn new() -> Self {
        Self {
            buf: [0; SBUS_FRAME_BYTES],
            len: 0,
            last_byte: None,
            frames: 0,
            rejected: 0,
        }
    }

    /// One received byte at `now`. Returns a frame when this byte completes one.
    pub fn push(&mut self, byte: u8, now: Instant) -> Option<SbusFrame> {
        if let Some(t) = self.last_byte {
            if now.since(t) > Self::GAP && self.len > 0 {
                self.rejected = self.rejected.saturating_add(1);
                self.len = 0;
            }
        }
        self.last_byte = Some(now);
        if self.len < SBUS_FRAME_BYTES {
            if let Some(slot) = self.buf.get_mut(self.len) {
                *slot = byte;
            }
            self.len += 1;
        } else {
            // Sliding window: drop the oldest byte.
            self.buf.copy_within(1.., 0);
            if let Some(last) = self.buf.last_mut() {
                *last = byte;
            }
        }
        // Nothing can start without a header: skip garbage quickly.
        if self.len == 1 && byte != SBUS_HEADER {
            self.len = 0;
            return None;
        }
        if self.len == SBUS_FRAME_BYTES {
            if let Some(frame) = SbusFrame::parse(&self.buf) {
                self.len = 0;
                self.frames = self.frames.saturating_add(1);
                return Some(frame);
            }
        }
        None
    }

    /// Feeds a chunk of bytes received at `now`; calls `on_frame` for every frame.
    pub fn feed(&mut self, bytes: &[u8], now: Instant, mut on_frame: impl FnMut(SbusFrame)) {
        for &b in bytes {
            if let Some(f) = self.push(b, now) {
                on_frame(f);
            }
        }
    }

    /// Valid frames decoded.
    pub fn frames(&self) -> u32 {
        self.frames
    }

    /// Partial frames abandoned at an inter-frame gap.
    pub fn rejected(&self) -> u32 {
        self.rejected
    }
}

/// Channel assignment and timing of the RC mapping.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RcConfig {
    /// Arm switch channel (1-based): high arms (on the edge), low lands.
    pub arm_channel: usize,
    /// Kill switch channel (1-based): high kills.
    pub kill_channel: usize,
    /// A switch is high above this raw value (992 is the centre; switches sit at ~172 / ~1811).
    pub switch_threshold: u16,
    /// No valid frame for this long (once RC was seen) => kill.
    pub timeout: Duration,
}

impl RcConfig {
    /// Arm on channel 5, kill on channel 6, switches high above 1400, 200 ms timeout.
    pub const DEFAULT: Self = Self {
        arm_channel: 5,
        kill_channel: 6,
        switch_threshold: 1_400,
        timeout: Duration::from_millis(200),
    };
}

impl Default for RcConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Why RC currently demands a kill.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RcKill {
    /// The kill switch is high.
    Switch,
    /// The receiver reports failsafe.
    Failsafe,
    /// No valid frame within the timeout.
    Timeout,
}

/// Turns SBUS frames into pilot commands (see the module docs).
#[derive(Debug, Clone)]
pub struct RcCommands {
    cfg: RcConfig,
    last_frame: Option<Instant>,
    arm_high: Option<bool>,
    killed: Option<RcKill>,
}

impl RcCommands {
    /// Nothing seen yet (RC not in use).
    pub const fn new(cfg: RcConfig) -> Self {
        Self {
            cfg,
            last_frame: None,
            arm_high: None,
            killed: None,
        }
    }

    /// True once a valid frame has been seen.
    pub fn in_use(&self) -> bool {
        self.last_frame.is_some()
    }

    /// The current kill reason, if RC demands a kill.
    pub fn kill_reason(&self) -> Option<RcKill> {
        self.killed
    }

    /// A frame received at `now`. Returns the command to hand to the autopilot, if any.
    pub fn on_frame(&mut self, frame: &SbusFrame, now: Instant) -> Option<PilotCommand> {
        self.last_frame = Some(now);
        let high = |ch: usize| {
            frame
                .channel(ch)
                .is_some_and(|v| v > self.cfg.switch_threshold)
        };
        let kill = if frame.failsafe {
            Some(RcKill::Failsafe)
        } else if high(self.cfg.kill_channel) {
            Some(RcKill::Switch)
        } else {
            None
        };
        if let Some(why) = kill {
            let first = self.killed.is_none();
            self.killed = Some(why);
            // While killed the arm switch is tracked, so releasing the kill does not arm.
            self.arm_high = Some(high(self.cfg.arm_channel));
            return first.then_some(PilotCommand::Kill);
        }
        self.killed = None;
        // A lost frame repeats stale switch positions: no edges from it.
        if frame.frame_lost {
            return None;
        }
        let arm = high(self.cfg.arm_channel);
        let before = self.arm_high.replace(arm);
        match (before, arm) {
            (Some(false), true) => Some(PilotCommand::Arm),
            (Some(true), false) => Some(PilotCommand::Land),
            _ => None,
        }
    }

    /// Periodic check at `now` (e.g. from the guidance task): RC that was in use and went
    /// silent for the timeout demands a kill (returned once).
    pub fn poll(&mut self, now: Instant) -> Option<PilotCommand> {
        let last = self.last_frame?;
        if now.since(last) > self.cfg.timeout && self.killed.is_none() {
            self.killed = Some(RcKill::Timeout);
            self.arm_high = None;
            return Some(PilotCommand::Kill);
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::at;
    use proptest::prelude::*;

    const LOW: u16 = 172;
    const HIGH: u16 = 1811;

    fn frame(arm: u16, kill: u16) -> SbusFrame {
        let mut channels = [992u16; SBUS_CHANNELS];
        channels[4] = arm;
        channels[5] = kill;
        SbusFrame {
            channels,
            ch17: false,
            ch18: false,
            frame_lost: false,
            failsafe: false,
        }
    }

    #[test]
    fn known_frame_decodes_bit_exact() {
        // All channels 0x400 (1024): the bit pattern repeats every 11 bytes.
        let mut bytes = [0u8; SBUS_FRAME_BYTES];
        bytes[0] = SBUS_HEADER;
        let pattern = [
            0x00, 0x04, 0x20, 0x00, 0x01, 0x08, 0x40, 0x00, 0x02, 0x10, 0x80,
        ];
        for (i, b) in bytes[1..23].iter_mut().enumerate() {
            *b = pattern[i % 11];
        }
        bytes[23] = 0x0C; // frame lost + failsafe
        let f = SbusFrame::parse(&bytes).expect("valid frame");
        assert_eq!(f.channels, [1024; 16]);
        assert!(f.frame_lost && f.failsafe && !f.ch17 && !f.ch18);
        assert_eq!(f.encode(), bytes);
    }

    #[test]
    fn bad_header_or_footer_is_rejected() {
        let mut b = frame(LOW, LOW).encode();
        b[24] = 0x55;
        assert_eq!(SbusFrame::parse(&b), None);
        b[24] = 0x24; // SBUS2 footer
        assert!(SbusFrame::parse(&b).is_some());
        b[0] = 0x0E;
        assert_eq!(SbusFrame::parse(&b), None);
    }

    #[test]
    fn decoder_resyncs_after_garbage_and_on_gaps() {
        let mut d = SbusDecoder::new();
        let f = frame(HIGH, LOW);
        let mut got = 0;
        // Garbage (including header bytes) before the frame, in one burst.
        let mut stream = heapless::Vec::<u8, 40>::new();
        stream
            .extend_from_slice(&[0x0F, 0x33, 0x0F, 0x00, 0x12])
            .unwrap();
        stream.extend_from_slice(&f.encode()).unwrap();
        d.feed(&stream, at(0), |g| {
            assert_eq!(g, f);
            got += 1;
        });
        assert_eq!(got, 1);
        // A truncated frame, then the gap, then a whole frame.
        d.feed(&f.encode()[..10], at(10_000), |_| panic!("partial frame"));
        d.feed(&f.encode(), at(17_000), |_| got += 1);
        assert_eq!(got, 2);
        assert_eq!(d.frames(), 2);
        assert!(d.rejected() >= 1);
    }

    #[test]
    fn arm_land_kill_and_failsafe_map_to_commands() {
        let mut rc = RcCommands::new(RcConfig::default());
        assert_eq!(rc.poll(at(1_000_000)), None, "no RC yet: no kill");
        assert_eq!(rc.on_frame(&frame(LOW, LOW), at(0)), None);
        assert_eq!(
            rc.on_frame(&frame(HIGH, LOW), at(7_000)),
            Some(PilotCommand::Arm)
        );
        assert_eq!(rc.on_frame(&frame(HIGH, LOW), at(14_000)), None);
        assert_eq!(
            rc.on_frame(&frame(LOW, LOW), at(21_000)),
            Some(PilotCommand::Land)
        );
        assert_eq!(
            rc.on_frame(&frame(HIGH, LOW), at(28_000)),
            Some(PilotCommand::Arm)
        );
        // Kill switch: one Kill; releasing it with the arm switch still high does not arm.
        assert_eq!(
            rc.on_frame(&frame(HIGH, HIGH), at(35_000)),
            Some(PilotCommand::Kill)
        );
        assert_eq!(rc.kill_reason(), Some(RcKill::Switch));
        assert_eq!(rc.on_frame(&frame(HIGH, HIGH), at(42_000)), None);
        assert_eq!(rc.on_frame(&frame(HIGH, LOW), at(49_000)), None);
        assert_eq!(
            rc.on_frame(&frame(LOW, LOW), at(56_000)),
            Some(PilotCommand::Land)
        );
        assert_eq!(
            rc.on_frame(&frame(HIGH, LOW), at(63_000)),
            Some(PilotCommand::Arm)
        );
        // Receiver failsafe.
        let mut fs = frame(HIGH, LOW);
        fs.failsafe = true;
        assert_eq!(rc.on_frame(&fs, at(70_000)), Some(PilotCommand::Kill));
        assert_eq!(rc.kill_reason(), Some(RcKill::Failsafe));
        // The failsafe clears with the arm switch still high: no re-arm without an edge.
        assert_eq!(rc.on_frame(&frame(HIGH, LOW), at(77_000)), None);
        // Silence after RC was in use.
        assert_eq!(rc.poll(at(77_000 + 200_000)), None);
        assert_eq!(rc.poll(at(77_000 + 200_001)), Some(PilotCommand::Kill));
        assert_eq!(rc.poll(at(77_000 + 300_000)), None, "once");
        assert_eq!(rc.kill_reason(), Some(RcKill::Timeout));
    }

    #[test]
    fn lost_frames_make_no_edges() {
        let mut rc = RcCommands::new(RcConfig::default());
        rc.on_frame(&frame(LOW, LOW), at(0));
        let mut lost = frame(HIGH, LOW);
        lost.frame_lost = true;
        assert_eq!(rc.on_frame(&lost, at(7_000)), None);
    }

    proptest! {
        #[test]
        fn arbitrary_bytes_never_panic(
            chunks in proptest::collection::vec(
                (proptest::collection::vec(any::<u8>(), 0..80), 0u64..5_000),
                0..20,
            )
        ) {
            let mut d = SbusDecoder::new();
            let mut rc = RcCommands::new(RcConfig::default());
            let mut t = 0u64;
            for (bytes, dt) in chunks {
                t += dt;
                let mut frames = heapless::Vec::<SbusFrame, 4>::new();
                d.feed(&bytes, at(t), |f| {
                    let _ = frames.push(f);
                });
                for f in &frames {
                    prop_assert!(f.channels.iter().all(|&c| c <= 0x7FF));
                    let _ = rc.on_frame(f, at(t));
                }
                let _ = rc.poll(at(t));
            }
        }

        #[test]
        fn encode_parse_round_trip(ch in proptest::array::uniform16(0u16..2048), flags in 0u8..16) {
            let f = SbusFrame {
                channels: ch,
                ch17: flags & 1 != 0,
                ch18: flags & 2 != 0,
                frame_lost: flags & 4 != 0,
                failsafe: flags & 8 != 0,
            };
            prop_assert_eq!(SbusFrame::parse(&f.encode()), Some(f));
        }
    }
}
