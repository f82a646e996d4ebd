//! Signed host commands: a keyed MAC and a replay-proof timestamp on host -> autopilot
//! messages, modelled on MAVLink 2 message signing.
//!
//! A host that holds the link key wraps a [`HostToBoard`] message in a
//! [`HostToBoard::Signed`] envelope ([`SignedMessage`]):
//!
//! ```text
//! link_id    u8       the signer's stream (one per host tool instance)
//! timestamp  u64      10 µs units since 2015-01-01 00:00 UTC, < 2^48 (MAVLink's clock)
//! mac        [u8; 6]  first 6 bytes of HMAC-SHA-256(key, signed bytes)
//! payload    bytes    the postcard encoding of the inner HostToBoard message (<= 64 bytes)
//!
//! signed bytes = PROTOCOL_VERSION, link_id, timestamp (6 bytes little endian), payload
//! ```
//!
//! The receiver checks, in order: the MAC (compared in constant time), that the payload is one
//! whole inner message that is not itself an envelope, and the [`ReplayGuard`]: the timestamp
//! must be strictly greater than the last one accepted on its link id, above the floor stored
//! with the key ([`KeyRecord::min_timestamp`]) and, once a timestamp has been accepted since
//! boot, not more than [`FUTURE_WINDOW`] ahead of the receiver's running notion of the signer's
//! clock. Every check that fails says why ([`SignError`]), so the receiver counts it.
//!
//! The key is 32 bytes. It is provisioned while no key is set with [`HostToBoard::SetKey`], or
//! written over SWD into the parameter record as a [`KeyRecord`] (see `docs/protocol.md`).
//!
//! Nothing here reads a clock: the signer's and the receiver's times are passed in.

use sha2::{Digest, Sha256};
use timebase::Instant;

use crate::messages::{HostToBoard, PROTOCOL_VERSION};

pub use crate::envelope::{
    KeyRecord, KeyRecordError, KeyTextError, LinkKey, SignedMessage, KEY_BYTES, KEY_RECORD_BYTES,
    MAC_BYTES, SIGNED_PAYLOAD_MAX, TIMESTAMP_MAX,
};

/// Signing timestamps per second (the unit is 10 µs).
pub const TIMESTAMP_TICKS_PER_S: u64 = 100_000;
/// How far ahead of the receiver's notion of the signer's clock a timestamp may be, in
/// timestamp ticks (60 s, MAVLink's window).
pub const FUTURE_WINDOW: u64 = 60 * TIMESTAMP_TICKS_PER_S;
/// Link ids a [`ReplayGuard`] tracks at once; a new id beyond them replaces the least recent.
pub const REPLAY_STREAMS: usize = 4;

/// Why a signed message was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SignError {
    /// The MAC does not match: another key, or the message was altered.
    BadMac,
    /// The MAC matched but the payload is not one inner message, or is itself an envelope.
    BadPayload,
    /// The timestamp is not newer than the last accepted on its link (a replay), or not above
    /// the key's stored floor.
    Replay,
    /// The timestamp is beyond 48 bits or too far ahead of the receiver's notion of the
    /// signer's clock.
    Future,
    /// The message to sign does not fit [`SIGNED_PAYLOAD_MAX`] bytes.
    TooLong,
}

impl core::fmt::Display for SignError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::BadMac => "signature does not match",
            Self::BadPayload => "signed payload is not one host message",
            Self::Replay => "timestamp not newer than the last accepted (replay)",
            Self::Future => "timestamp too far in the future",
            Self::TooLong => "message too long to sign",
        })
    }
}

const HMAC_BLOCK: usize = 64;

/// HMAC-SHA-256 (RFC 2104) of `parts` concatenated, under `key`.
fn hmac_sha256(key: &LinkKey, parts: &[&[u8]]) -> [u8; 32] {
    let mut ipad = [0x36u8; HMAC_BLOCK];
    let mut opad = [0x5cu8; HMAC_BLOCK];
    for ((i, o), k) in ipad.iter_mut().zip(opad.iter_mut()).zip(key.0.iter()) {
        *i ^= k;
        *o ^= k;
    }
    let mut inner = Sha256::new();
    inner.update(ipad);
    for part in parts {
        inner.update(part);
    }
    let inner = inner.finalize();
    let mut outer = Sha256::new();
    outer.update(opad);
    outer.update(inner);
    outer.finalize().into()
}

/// The truncated MAC of an envelope's fields.
fn mac_of(key: &LinkKey, link_id: u8, timestamp: u64, payload: &[u8]) -> [u8; MAC_BYTES] {
    let ts = timestamp.to_le_bytes();
    let full = hmac_sha256(
        key,
        &[
            &[PROTOCOL_VERSION, link_id],
            ts.get(..6).unwrap_or(&ts),
            payload,
        ],
    );
    let mut mac = [0u8; MAC_BYTES];
    mac.copy_from_slice(full.get(..MAC_BYTES).unwrap_or(&[0; MAC_BYTES]));
    mac
}

/// Equality of two MACs in time independent of where they differ.
fn macs_equal(a: &[u8; MAC_BYTES], b: &[u8; MAC_BYTES]) -> bool {
    let diff = a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y));
    core::hint::black_box(diff) == 0
}

impl SignedMessage {
    /// Signs `msg` under `key` as stream `link_id` at `timestamp` (10 µs units; use a
    /// [`Signer`] to keep timestamps increasing). An envelope inside an envelope is refused
    /// ([`SignError::BadPayload`]).
    pub fn sign(
        key: &LinkKey,
        link_id: u8,
        timestamp: u64,
        msg: &HostToBoard,
    ) -> Result<Self, SignError> {
        if matches!(msg, HostToBoard::Signed(_)) {
            return Err(SignError::BadPayload);
        }
        if timestamp > TIMESTAMP_MAX {
            return Err(SignError::Future);
        }
        let mut buf = [0u8; SIGNED_PAYLOAD_MAX];
        let used = postcard::to_slice(msg, &mut buf)
            .map_err(|_| SignError::TooLong)?
            .len();
        let payload = heapless::Vec::from_slice(buf.get(..used).ok_or(SignError::TooLong)?)
            .map_err(|_| SignError::TooLong)?;
        Ok(Self {
            link_id,
            timestamp,
            mac: mac_of(key, link_id, timestamp, &payload),
            payload,
        })
    }

    /// Checks the MAC under `key` and returns the inner message. The timestamp is not judged
    /// here: pass it to a [`ReplayGuard`] after this succeeds.
    pub fn open(&self, key: &LinkKey) -> Result<HostToBoard, SignError> {
        let expected = mac_of(key, self.link_id, self.timestamp, &self.payload);
        if !macs_equal(&expected, &self.mac) {
            return Err(SignError::BadMac);
        }
        if self.timestamp > TIMESTAMP_MAX {
            return Err(SignError::Future);
        }
        self.open_unverified()
    }

    /// The inner message without checking the MAC: for a receiver with no key (an unsigned
    /// link takes an envelope's content as it takes an unsigned message).
    pub fn open_unverified(&self) -> Result<HostToBoard, SignError> {
        match postcard::take_from_bytes::<HostToBoard>(&self.payload) {
            Ok((HostToBoard::Signed(_), _)) => Err(SignError::BadPayload),
            Ok((msg, [])) => Ok(msg),
            _ => Err(SignError::BadPayload),
        }
    }
}

/// The receiver's anti-replay state: the last accepted timestamp per link id, and its running
/// notion of the signer's clock (the newest accepted timestamp, advanced by the receiver's own
/// time since). RAM only: see [`ReplayGuard::new`] for what a reboot keeps.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReplayGuard {
    /// Timestamps at or below this are refused on every link (the key record's floor).
    floor: u64,
    /// Per link id: the last accepted timestamp and the receiver time it was accepted at.
    streams: [Option<(u8, u64, Instant)>; REPLAY_STREAMS],
    /// The newest timestamp of a link id dropped from `streams`: a link id not in the table
    /// must be above it, so that dropping a link cannot reopen its old timestamps.
    evicted: u64,
    /// The newest accepted timestamp and the receiver time it was accepted at.
    newest: Option<(u64, Instant)>,
}

impl ReplayGuard {
    /// A guard after boot: every timestamp at or below `floor` (the key's stored
    /// [`KeyRecord::min_timestamp`]) is refused; above it the first timestamp of each link id
    /// is accepted, then only newer ones.
    pub const fn new(floor: u64) -> Self {
        Self {
            floor,
            streams: [None; REPLAY_STREAMS],
            evicted: 0,
            newest: None,
        }
    }

    /// The newest timestamp accepted since boot (or the floor).
    pub fn newest(&self) -> u64 {
        self.newest.map_or(self.floor, |(ts, _)| ts)
    }

    /// Judges `timestamp` from `link_id` at receiver time `now` and, if accepted, records it.
    pub fn accept(&mut self, link_id: u8, timestamp: u64, now: Instant) -> Result<(), SignError> {
        if timestamp > TIMESTAMP_MAX {
            return Err(SignError::Future);
        }
        if timestamp <= self.floor {
            return Err(SignError::Replay);
        }
        if let Some((ts, at)) = self.newest {
            // Timestamps count 10 µs ticks.
            let elapsed_ticks = now.since(at).as_micros() / 10;
            let horizon = ts
                .saturating_add(elapsed_ticks)
                .saturating_add(FUTURE_WINDOW);
            if timestamp > horizon {
                return Err(SignError::Future);
            }
        }
        let slot = self
            .streams
            .iter()
            .position(|s| matches!(s, Some((id, _, _)) if *id == link_id));
        let last = match slot.and_then(|i| self.streams.get(i)) {
            Some(Some((_, last, _))) => *last,
            _ => self.evicted,
        };
        if timestamp <= last {
            return Err(SignError::Replay);
        }
        // A new link id takes a free slot or the one accepted least recently.
        let index = slot.unwrap_or_else(|| {
            self.streams
                .iter()
                .enumerate()
                .min_by_key(|(_, s)| s.map_or(0, |(_, _, at)| at.as_micros().saturating_add(1)))
                .map_or(0, |(i, _)| i)
        });
        if let Some(s) = self.streams.get_mut(index) {
            if let Some((id, dropped, _)) = *s {
                if id != link_id {
                    self.evicted = self.evicted.max(dropped);
                }
            }
            *s = Some((link_id, timestamp, now));
        }
        if self.newest.is_none_or(|(ts, _)| timestamp > ts) {
            self.newest = Some((timestamp, now));
        }
        Ok(())
    }
}

/// A host's signing state: the key, its link id and the last timestamp it used, so that every
/// message gets a strictly increasing timestamp even when the clock stalls or steps back.
#[derive(Debug, Clone)]
pub struct Signer {
    key: LinkKey,
    link_id: u8,
    last: u64,
}

impl Signer {
    /// A signer for stream `link_id` under `key`.
    pub fn new(key: LinkKey, link_id: u8) -> Self {
        Self {
            key,
            link_id,
            last: 0,
        }
    }

    /// Signs `msg` with timestamp `max(clock, last + 1)`, where `clock` is the signer's time in
    /// 10 µs units since 2015-01-01 UTC ([`timestamp_from_unix_us`]).
    pub fn sign(&mut self, msg: &HostToBoard, clock: u64) -> Result<HostToBoard, SignError> {
        let ts = clock.max(self.last.saturating_add(1));
        let signed = SignedMessage::sign(&self.key, self.link_id, ts, msg)?;
        self.last = ts;
        Ok(HostToBoard::Signed(signed))
    }
}

/// Unix time 2015-01-01 00:00 UTC, seconds: the epoch of signing timestamps.
pub const SIGNING_EPOCH_UNIX_S: u64 = 1_420_070_400;

/// A signing timestamp (10 µs units since 2015-01-01 UTC) from Unix time in µs.
pub fn timestamp_from_unix_us(unix_us: u64) -> u64 {
    unix_us.saturating_sub(SIGNING_EPOCH_UNIX_S * 1_000_000) / 10
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::messages::{ExternalPosition, Heartbeat, Node, PilotCommand, WireTime};

    const KEY: LinkKey = LinkKey([7; KEY_BYTES]);
    const ARM: HostToBoard = HostToBoard::Command(PilotCommand::Arm);

    #[test]
    fn a_signed_message_opens_to_itself_under_its_key() {
        let fix = HostToBoard::ExternalPosition(ExternalPosition {
            timestamp_us: WireTime(5),
            position_m: [1.0, 2.0, -0.5],
        });
        for msg in [
            ARM,
            fix,
            HostToBoard::Heartbeat(Heartbeat::new(Node::Host, 9)),
        ] {
            let s = SignedMessage::sign(&KEY, 3, 1_000, &msg).unwrap();
            assert_eq!(s.open(&KEY), Ok(msg));
        }
    }

    #[test]
    fn the_mac_is_hmac_sha256_truncated() {
        // RFC 4231 test case 2 checks the HMAC itself (key "Jefe" padded: HMAC pads short keys
        // with zeros, so a 32-byte key with trailing zeros is the same key).
        let mut k = [0u8; KEY_BYTES];
        k[..4].copy_from_slice(b"Jefe");
        let mac = hmac_sha256(&LinkKey(k), &[b"what do ya want ", b"for nothing?"]);
        assert_eq!(
            mac[..8],
            [0x5b, 0xdc, 0xc1, 0x46, 0xbf, 0x60, 0x75, 0x4e],
            "RFC 4231 case 2"
        );
    }

    #[test]
    fn any_flipped_bit_is_refused() {
        let s = SignedMessage::sign(&KEY, 1, 42, &ARM).unwrap();
        for byte in 0..s.payload.len() {
            for bit in 0..8 {
                let mut t = s.clone();
                t.payload[byte] ^= 1 << bit;
                assert_eq!(t.open(&KEY), Err(SignError::BadMac));
            }
        }
        for bit in 0..MAC_BYTES * 8 {
            let mut t = s.clone();
            t.mac[bit / 8] ^= 1 << (bit % 8);
            assert_eq!(t.open(&KEY), Err(SignError::BadMac));
        }
        let mut t = s.clone();
        t.timestamp += 1;
        assert_eq!(t.open(&KEY), Err(SignError::BadMac), "timestamp is signed");
        let mut t = s;
        t.link_id ^= 1;
        assert_eq!(t.open(&KEY), Err(SignError::BadMac), "link id is signed");
    }

    #[test]
    fn another_key_is_refused() {
        let s = SignedMessage::sign(&KEY, 1, 42, &ARM).unwrap();
        let mut other = KEY;
        other.0[31] ^= 0x80;
        assert_eq!(s.open(&other), Err(SignError::BadMac));
    }

    #[test]
    fn an_envelope_inside_an_envelope_is_refused() {
        let inner = HostToBoard::Signed(SignedMessage::sign(&KEY, 1, 42, &ARM).unwrap());
        assert_eq!(
            SignedMessage::sign(&KEY, 1, 43, &inner),
            Err(SignError::BadPayload)
        );
        // Forged by hand: a valid MAC over a payload that is itself an envelope.
        let mut buf = [0u8; SIGNED_PAYLOAD_MAX];
        let n = postcard::to_slice(&inner, &mut buf).map(|s| s.len());
        if let Ok(n) = n {
            let payload = heapless::Vec::from_slice(&buf[..n]).unwrap();
            let s = SignedMessage {
                link_id: 1,
                timestamp: 50,
                mac: mac_of(&KEY, 1, 50, &payload),
                payload,
            };
            assert_eq!(s.open(&KEY), Err(SignError::BadPayload));
        }
    }

    #[test]
    fn a_replay_is_refused_per_link() {
        let mut g = ReplayGuard::new(0);
        assert_eq!(g.accept(1, 100, Instant::from_micros(0)), Ok(()));
        assert_eq!(
            g.accept(1, 100, Instant::from_micros(10)),
            Err(SignError::Replay),
            "same timestamp"
        );
        assert_eq!(
            g.accept(1, 99, Instant::from_micros(20)),
            Err(SignError::Replay),
            "older"
        );
        assert_eq!(
            g.accept(2, 50, Instant::from_micros(30)),
            Ok(()),
            "another link has its own sequence"
        );
        assert_eq!(
            g.accept(2, 50, Instant::from_micros(40)),
            Err(SignError::Replay)
        );
        assert_eq!(g.accept(1, 101, Instant::from_micros(50)), Ok(()));
    }

    #[test]
    fn the_floor_refuses_timestamps_from_before_provisioning() {
        let mut g = ReplayGuard::new(1_000);
        assert_eq!(
            g.accept(0, 1_000, Instant::from_micros(0)),
            Err(SignError::Replay)
        );
        assert_eq!(g.accept(0, 1_001, Instant::from_micros(0)), Ok(()));
    }

    #[test]
    fn a_timestamp_far_ahead_is_refused_and_the_window_follows_receiver_time() {
        let mut g = ReplayGuard::new(0);
        assert_eq!(g.accept(0, 1_000, Instant::from_micros(0)), Ok(()));
        let limit = 1_000 + FUTURE_WINDOW;
        assert_eq!(
            g.accept(0, limit + 1, Instant::from_micros(0)),
            Err(SignError::Future)
        );
        assert_eq!(g.accept(0, limit, Instant::from_micros(0)), Ok(()));
        // Ten seconds of receiver time later the window has moved by 10 s.
        let later = limit + 10 * TIMESTAMP_TICKS_PER_S;
        assert_eq!(g.accept(1, later, Instant::from_micros(10_000_000)), Ok(()));
    }

    #[test]
    fn timestamps_stop_at_48_bits() {
        let mut g = ReplayGuard::new(0);
        assert_eq!(g.accept(0, TIMESTAMP_MAX, Instant::from_micros(0)), Ok(()));
        assert_eq!(
            g.accept(0, TIMESTAMP_MAX + 1, Instant::from_micros(0)),
            Err(SignError::Future)
        );
        // After the largest timestamp nothing newer exists on that link: no wrap to small
        // values is accepted.
        assert_eq!(
            g.accept(0, 1, Instant::from_micros(0)),
            Err(SignError::Replay)
        );
        assert_eq!(
            SignedMessage::sign(&KEY, 0, TIMESTAMP_MAX + 1, &ARM),
            Err(SignError::Future)
        );
    }

    #[test]
    fn a_new_link_beyond_the_table_replaces_the_least_recent() {
        let mut g = ReplayGuard::new(0);
        for id in 0..REPLAY_STREAMS as u8 {
            assert_eq!(
                g.accept(id, 10 + u64::from(id), Instant::from_micros(u64::from(id))),
                Ok(())
            );
        }
        assert_eq!(g.accept(200, 100, Instant::from_micros(100)), Ok(()));
        // Link 1 still remembers its timestamp; link 0 was dropped, and its old timestamp stays
        // refused.
        assert_eq!(
            g.accept(1, 11, Instant::from_micros(101)),
            Err(SignError::Replay)
        );
        assert_eq!(
            g.accept(0, 10, Instant::from_micros(102)),
            Err(SignError::Replay)
        );
        assert_eq!(g.accept(0, 11, Instant::from_micros(103)), Ok(()));
    }

    #[test]
    fn the_signer_keeps_timestamps_increasing() {
        let mut s = Signer::new(KEY, 4);
        let mut g = ReplayGuard::new(0);
        for clock in [500, 500, 400, 501] {
            let HostToBoard::Signed(m) = s.sign(&ARM, clock).unwrap() else {
                panic!("a signer makes envelopes");
            };
            assert_eq!(m.open(&KEY), Ok(ARM));
            assert_eq!(
                g.accept(m.link_id, m.timestamp, Instant::from_micros(0)),
                Ok(())
            );
        }
    }

    #[test]
    fn a_key_record_round_trips_and_rejects_damage() {
        let r = KeyRecord {
            key: KEY,
            min_timestamp: 123_456_789,
        };
        let bytes = r.encode();
        assert_eq!(KeyRecord::decode(&bytes), Ok(r));
        assert_eq!(
            KeyRecord::decode(&[0xFF; KEY_RECORD_BYTES]),
            Err(KeyRecordError::Blank)
        );
        for i in 0..KEY_RECORD_BYTES {
            let mut b = bytes;
            b[i] ^= 0x10;
            assert_eq!(
                KeyRecord::decode(&b),
                Err(KeyRecordError::Corrupt),
                "byte {i}"
            );
        }
        assert_eq!(
            KeyRecord::decode(&bytes[..40]),
            Err(KeyRecordError::Corrupt)
        );
    }

    #[test]
    fn a_key_reads_from_its_hexadecimal_text() {
        let text = "  00ff10ABcdef0123456789abcdef0123456789abcdef0123456789abcdef0123\n";
        let key = LinkKey::from_hex(text).unwrap();
        assert_eq!(key.0[..4], [0x00, 0xff, 0x10, 0xab]);
        assert_eq!(key.0[31], 0x23);
        assert_eq!(LinkKey::from_hex("ab"), Err(KeyTextError::Length(2)));
        let mut bad = [b'0'; 64];
        bad[10] = b'g';
        let bad = core::str::from_utf8(&bad).unwrap();
        assert_eq!(LinkKey::from_hex(bad), Err(KeyTextError::NotHex(10)));
        // A multi-byte character is not a digit, wherever it falls.
        let wide = "é".repeat(32);
        assert_eq!(LinkKey::from_hex(&wide), Err(KeyTextError::NotHex(0)));
    }

    #[test]
    fn the_key_is_not_shown_in_debug_output() {
        extern crate std;
        let shown = std::format!("{:?}", HostToBoard::SetKey(LinkKey([0xAB; 32])));
        assert!(!shown.contains("171"), "{shown}");
    }
}
