//! Framing: COBS frames with a protocol-version byte and a CRC, and a streaming decoder.
//!
//! A frame on the wire is `COBS(raw) 0x00`, where
//!
//! ```text
//! raw = [PROTOCOL_VERSION] [postcard payload ...] [CRC, little endian]
//! ```
//!
//! The CRC covers the version byte and the payload. Its width depends on the raw length, so
//! that the 25 Hz [`crate::Estimate`] stays within 34 bytes on the wire while long frames keep
//! a strong check:
//!
//! * raw length <= [`SHORT_RAW_MAX`] (64 bytes): CRC-16/IBM-3740 (CCITT polynomial 0x1021,
//!   Hamming distance 4 at these lengths: every error of up to 3 bits is detected);
//! * raw length >= [`SHORT_RAW_MAX`] + 3 (67 bytes): CRC-32/ISO-HDLC. For a 4 kbit HIL frame
//!   chunk the 2^-16 pass rate of a 16-bit check on a heavily corrupted frame is too high.
//!
//! The encoder chooses the width from the payload length; the decoder from the frame length
//! (lengths 65 and 66 cannot occur and are rejected). COBS removes every 0x00 from the frame, so
//! a receiver resynchronises at the next delimiter after any garbage.
//!
//! Nothing here panics on any input, allocates, or reads a clock.

use crate::messages::{LinkErrorCounts, Message, PROTOCOL_VERSION};
use core::marker::PhantomData;
use crc::{Crc, CRC_16_IBM_3740, CRC_32_ISO_HDLC};
use serde::Serialize;

/// The frame delimiter.
pub const DELIMITER: u8 = 0x00;

/// Longest raw frame (version + payload + CRC) protected by CRC-16; longer frames use CRC-32.
pub const SHORT_RAW_MAX: usize = 64;

/// Shortest valid raw frame: version byte, one payload byte (the enum tag) and a CRC-16.
pub const MIN_RAW_LEN: usize = 1 + 1 + 2;

const CRC16: Crc<u16> = Crc::<u16>::new(&CRC_16_IBM_3740);
const CRC32: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);

/// Why a message could not be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum EncodeError {
    /// The output buffer cannot hold the encoded frame.
    BufferTooSmall,
    /// The message could not be serialised (a serde error other than running out of space).
    Serialize,
}

impl core::fmt::Display for EncodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::BufferTooSmall => f.write_str("output buffer too small for the encoded frame"),
            Self::Serialize => f.write_str("message could not be serialised"),
        }
    }
}

/// Why a received frame was rejected. Each kind has a counter in [`LinkErrorCounts`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum FrameError {
    /// The frame was not valid COBS.
    Cobs,
    /// Shorter than [`MIN_RAW_LEN`] after COBS decoding (includes empty frames).
    TooShort,
    /// Longer than the receive buffer.
    TooLong,
    /// The CRC did not match (or the length cannot carry a CRC).
    Crc,
    /// The CRC matched but the frame carries another protocol version.
    VersionMismatch(u8),
    /// The message tag is not one this build knows.
    UnknownMessage,
    /// The payload did not decode as the message type.
    Malformed,
}

/// Number of COBS overhead bytes that encoding `raw_len` bytes can add (upper bound).
const fn cobs_overhead(raw_len: usize) -> usize {
    raw_len / 254 + 1
}

/// Upper bound of the bytes on the wire for a raw frame of `raw_len` bytes (COBS + delimiter).
pub const fn max_wire_len(raw_len: usize) -> usize {
    raw_len + cobs_overhead(raw_len) + 1
}

/// CRC width in bytes for a raw frame of `raw_len` bytes, or `None` if no frame has that length.
const fn crc_len_for_raw(raw_len: usize) -> Option<usize> {
    if raw_len <= SHORT_RAW_MAX {
        Some(2)
    } else if raw_len >= SHORT_RAW_MAX + 3 {
        Some(4)
    } else {
        None
    }
}

/// Encodes `msg` as one complete frame (COBS, CRC and the trailing delimiter) into `out`.
///
/// Returns the number of bytes written. Never panics: a buffer that is too small gives
/// [`EncodeError::BufferTooSmall`] and the content of `out` is then unspecified.
pub fn encode<M: Serialize + ?Sized>(msg: &M, out: &mut [u8]) -> Result<usize, EncodeError> {
    let n = out.len();
    // The raw frame is serialised at an offset large enough that COBS can encode it in place,
    // front to back, without the write position overtaking the read position.
    let offset = cobs_overhead(n);
    // Room for the raw frame: keep the delimiter and the largest CRC free at the end.
    let raw_space_end = n.checked_sub(1 + 4).ok_or(EncodeError::BufferTooSmall)?;
    if raw_space_end <= offset + 1 {
        return Err(EncodeError::BufferTooSmall);
    }
    let raw = out.get_mut(offset..).ok_or(EncodeError::BufferTooSmall)?;
    raw[0] = PROTOCOL_VERSION;
    let payload_space = raw
        .get_mut(1..raw_space_end - offset)
        .ok_or(EncodeError::BufferTooSmall)?;
    let payload_len = match postcard::to_slice(msg, payload_space) {
        Ok(used) => used.len(),
        Err(postcard::Error::SerializeBufferFull) => return Err(EncodeError::BufferTooSmall),
        Err(_) => return Err(EncodeError::Serialize),
    };
    let body_len = 1 + payload_len;
    let raw_len = if body_len + 2 <= SHORT_RAW_MAX {
        let crc = CRC16.checksum(&raw[..body_len]).to_le_bytes();
        raw[body_len..body_len + 2].copy_from_slice(&crc);
        body_len + 2
    } else {
        let crc = CRC32.checksum(&raw[..body_len]).to_le_bytes();
        raw[body_len..body_len + 4].copy_from_slice(&crc);
        body_len + 4
    };
    let encoded_len =
        cobs_encode_in_place(out, offset, raw_len).ok_or(EncodeError::BufferTooSmall)?;
    let delimiter = out
        .get_mut(encoded_len)
        .ok_or(EncodeError::BufferTooSmall)?;
    *delimiter = DELIMITER;
    Ok(encoded_len + 1)
}

/// Encodes `msg` as one complete frame into a new fixed-capacity vector.
pub fn encode_to_vec<M: Serialize + ?Sized, const N: usize>(
    msg: &M,
) -> Result<heapless::Vec<u8, N>, EncodeError> {
    let mut buf = [0u8; N];
    let len = encode(msg, &mut buf)?;
    heapless::Vec::from_slice(buf.get(..len).ok_or(EncodeError::BufferTooSmall)?)
        .map_err(|_| EncodeError::BufferTooSmall)
}

/// COBS-encodes `buf[src..src + len]` into `buf[0..]`, returning the encoded length.
///
/// The `cobs` crate's encoder state machine says where each byte goes; the bytes are written
/// into the front of the same buffer. Requires `src >= cobs_overhead(len)`, so that the write
/// index never passes the read index; returns `None` (instead of panicking) if the buffer is
/// too short.
fn cobs_encode_in_place(buf: &mut [u8], src: usize, len: usize) -> Option<usize> {
    let end = src.checked_add(len)?;
    if end > buf.len() || src < cobs_overhead(len) {
        return None;
    }
    let mut state = cobs::EncoderState::default();
    // Index 0 holds the first block's code, written when the block closes.
    let mut write = 1usize;
    // Whether the last byte closed a full block: then no empty block follows it (as the
    // crate's own `CobsEncoder` ends a message).
    let mut closed_full_block = false;
    for read in src..end {
        let byte = *buf.get(read)?;
        closed_full_block = false;
        match state.push(byte) {
            cobs::PushResult::AddSingle(byte) => {
                *buf.get_mut(write)? = byte;
                write += 1;
            }
            cobs::PushResult::ModifyFromStartAndSkip((code_at, code)) => {
                *buf.get_mut(code_at)? = code;
                write += 1;
            }
            cobs::PushResult::ModifyFromStartAndPushAndSkip((code_at, code, byte)) => {
                *buf.get_mut(code_at)? = code;
                *buf.get_mut(write)? = byte;
                write += 2;
                closed_full_block = true;
            }
        }
    }
    if closed_full_block {
        return Some(write - 1);
    }
    let (code_at, code) = state.finalize();
    *buf.get_mut(code_at)? = code;
    Some(write)
}

/// Checks the COBS, length, CRC and version of a frame received in `buf` (delimiter removed)
/// and returns the range of the payload inside `buf`.
fn check_frame(buf: &mut [u8]) -> Result<core::ops::Range<usize>, FrameError> {
    let raw_len = cobs::decode_in_place(buf).map_err(|e| match e {
        cobs::DecodeError::EmptyFrame => FrameError::TooShort,
        _ => FrameError::Cobs,
    })?;
    if raw_len < MIN_RAW_LEN {
        return Err(FrameError::TooShort);
    }
    let raw = &buf[..raw_len];
    let crc_len = crc_len_for_raw(raw_len).ok_or(FrameError::Crc)?;
    let body_len = raw_len - crc_len;
    let (body, crc) = raw.split_at(body_len);
    let crc_ok = match *crc {
        [a, b] => CRC16.checksum(body) == u16::from_le_bytes([a, b]),
        [a, b, c, d] => CRC32.checksum(body) == u32::from_le_bytes([a, b, c, d]),
        _ => false,
    };
    if !crc_ok {
        return Err(FrameError::Crc);
    }
    match body.first() {
        Some(&PROTOCOL_VERSION) => Ok(1..body_len),
        Some(&other) => Err(FrameError::VersionMismatch(other)),
        None => Err(FrameError::TooShort),
    }
}

/// Reads the enum tag (a postcard varint) at the start of a payload.
fn payload_tag(payload: &[u8]) -> Option<u32> {
    let mut value: u32 = 0;
    for (i, &byte) in payload.iter().take(5).enumerate() {
        value |= u32::from(byte & 0x7F).checked_shl(7 * i as u32)?;
        if byte & 0x80 == 0 {
            return Some(value);
        }
    }
    None
}

/// Decodes one frame (delimiter removed, COBS-encoded bytes in `buf`, modified in place) into a
/// message. This is the whole receive path of [`Decoder`] for a frame that is already split.
pub fn decode_frame<M: Message>(buf: &mut [u8]) -> Result<M, FrameError> {
    let payload_range = check_frame(buf)?;
    let payload = buf.get(payload_range).ok_or(FrameError::TooShort)?;
    match payload_tag(payload) {
        Some(tag) if tag < M::VARIANT_COUNT => {}
        _ => return Err(FrameError::UnknownMessage),
    }
    match postcard::take_from_bytes::<M>(payload) {
        Ok((msg, [])) => Ok(msg),
        _ => Err(FrameError::Malformed),
    }
}

/// Streaming frame decoder for messages of type `M`, with an `N`-byte receive buffer.
///
/// Feed it bytes as they arrive (from an interrupt, a DMA buffer or a socket). It never panics,
/// never allocates, resynchronises at the next delimiter after garbage, and counts rejected
/// frames by kind. `N` must hold the longest COBS-encoded frame without its delimiter
/// (`M::MAX_FRAME_BYTES` is a safe choice; see [`StereoToAutopilotDecoder`] and friends).
#[derive(Debug, Clone)]
pub struct Decoder<M: Message, const N: usize> {
    buf: [u8; N],
    len: usize,
    overflowed: bool,
    /// Not yet aligned to the stream: the frame in progress may be the tail of one that began
    /// before this receiver started listening, so its rejection is not counted.
    joining: bool,
    errors: LinkErrorCounts,
    frames_ok: u32,
    peer_version: Option<u8>,
    _message: PhantomData<fn() -> M>,
}

impl<M: Message, const N: usize> Default for Decoder<M, N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<M: Message, const N: usize> Decoder<M, N> {
    /// An empty decoder with zeroed counters, for a stream that starts at a frame boundary (a
    /// socket or a simulated link open from the first byte). Every rejected frame is counted.
    pub const fn new() -> Self {
        Self::with_start(false)
    }

    /// An empty decoder for a stream joined at an unknown point: a UART enabled while the peer
    /// is already talking (a board booting, or reset by its watchdog, mid-flight). The first
    /// frame is delivered if it is valid; if it is not, it is taken for the tail of a frame
    /// that began before this receiver listened and is dropped without being counted. Every
    /// later rejection is counted as with [`Decoder::new`].
    pub const fn new_mid_stream() -> Self {
        Self::with_start(true)
    }

    const fn with_start(joining: bool) -> Self {
        Self {
            buf: [0; N],
            len: 0,
            overflowed: false,
            joining,
            errors: LinkErrorCounts {
                crc: 0,
                cobs: 0,
                too_long: 0,
                too_short: 0,
                unknown_message: 0,
                malformed: 0,
                version_mismatch: 0,
            },
            frames_ok: 0,
            peer_version: None,
            _message: PhantomData,
        }
    }

    /// Takes one byte. Returns a message when `byte` completes a valid frame.
    pub fn push(&mut self, byte: u8) -> Option<M> {
        self.push_checked(byte).and_then(Result::ok)
    }

    /// Takes one byte. When `byte` ends a frame, returns the message or why it was rejected
    /// (and counted). A rejected first frame of a decoder joining mid-stream is neither
    /// counted nor returned.
    pub fn push_checked(&mut self, byte: u8) -> Option<Result<M, FrameError>> {
        if byte != DELIMITER {
            match self.buf.get_mut(self.len) {
                Some(slot) if !self.overflowed => {
                    *slot = byte;
                    self.len += 1;
                }
                _ => self.overflowed = true,
            }
            return None;
        }
        let result = if self.overflowed {
            Err(FrameError::TooLong)
        } else {
            let len = self.len;
            match self.buf.get_mut(..len) {
                Some(frame) => decode_frame::<M>(frame),
                None => Err(FrameError::TooLong),
            }
        };
        self.len = 0;
        self.overflowed = false;
        let joining = core::mem::replace(&mut self.joining, false);
        match &result {
            Ok(_) => self.frames_ok = self.frames_ok.wrapping_add(1),
            Err(_) if joining => return None,
            Err(error) => self.count(*error),
        }
        Some(result)
    }

    /// Takes a slice of bytes, calling `on_message` for every valid message completed.
    pub fn feed(&mut self, bytes: &[u8], mut on_message: impl FnMut(M)) {
        for &byte in bytes {
            if let Some(msg) = self.push(byte) {
                on_message(msg);
            }
        }
    }

    /// Drops a partly received frame (e.g. after a UART overrun, which the caller counts as
    /// it sees fit) and rejoins the stream: the bytes up to the next delimiter are the rest of
    /// the dropped frame, so their rejection is not counted either (see
    /// [`Decoder::new_mid_stream`]).
    pub fn reset_frame(&mut self) {
        self.len = 0;
        self.overflowed = false;
        self.joining = true;
    }

    /// Rejected frames since creation, by kind.
    pub fn errors(&self) -> LinkErrorCounts {
        self.errors
    }

    /// Valid messages decoded since creation (wrapping).
    pub fn frames_ok(&self) -> u32 {
        self.frames_ok
    }

    /// The protocol version of the last frame that carried a version other than ours (a peer
    /// running other firmware), if any.
    pub fn peer_version_mismatch(&self) -> Option<u8> {
        self.peer_version
    }

    fn count(&mut self, error: FrameError) {
        let e = &mut self.errors;
        let counter = match error {
            FrameError::Cobs => &mut e.cobs,
            FrameError::TooShort => &mut e.too_short,
            FrameError::TooLong => &mut e.too_long,
            FrameError::Crc => &mut e.crc,
            FrameError::VersionMismatch(version) => {
                self.peer_version = Some(version);
                &mut e.version_mismatch
            }
            FrameError::UnknownMessage => &mut e.unknown_message,
            FrameError::Malformed => &mut e.malformed,
        };
        *counter = counter.saturating_add(1);
    }
}

impl LinkErrorCounts {
    /// Sum of all error counters (saturating).
    pub fn total(&self) -> u32 {
        [
            self.crc,
            self.cobs,
            self.too_long,
            self.too_short,
            self.unknown_message,
            self.malformed,
            self.version_mismatch,
        ]
        .iter()
        .fold(0u32, |acc, &c| acc.saturating_add(c))
    }
}

/// Decoder for the camera board -> autopilot direction, sized for its longest frame.
pub type StereoToAutopilotDecoder =
    Decoder<crate::StereoToAutopilot, { <crate::StereoToAutopilot as Message>::MAX_FRAME_BYTES }>;
/// Decoder for the autopilot -> camera board direction, sized for its longest frame.
pub type AutopilotToStereoDecoder =
    Decoder<crate::AutopilotToStereo, { <crate::AutopilotToStereo as Message>::MAX_FRAME_BYTES }>;
/// Decoder for the host -> board direction (HIL, ground tool), sized for its longest frame.
pub type HostToBoardDecoder =
    Decoder<crate::HostToBoard, { <crate::HostToBoard as Message>::MAX_FRAME_BYTES }>;
/// Decoder for the board -> host direction, sized for its longest frame.
pub type BoardToHostDecoder =
    Decoder<crate::BoardToHost, { <crate::BoardToHost as Message>::MAX_FRAME_BYTES }>;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::*;
    use rand::{Rng, SeedableRng};

    fn estimate() -> Estimate {
        Estimate {
            seq: 7,
            capture_us: WireTime(123_456),
            forward_mps: 0.31,
            sideways_mps: -0.02,
            obstacle_m: Some(1.4),
            quality: 200,
            flags: EstimateFlags::NONE,
            processing_us: 900,
            depth_coverage: 180,
            near_columns: 3,
            fit: Some(FrameFit {
                forward_mps: 0.35,
                sideways_mps: -0.04,
                quality: 150,
            }),
            up_mps: 0.0,
            up_flags: EstimateFlags::NO_FLOW_MATCH,
            fit_r2: 0,
            divergence: None,
        }
    }

    #[test]
    fn estimate_round_trips_through_the_decoder() {
        let mut wire = [0u8; 64];
        let msg = StereoToAutopilot::Estimate(estimate());
        let n = encode(&msg, &mut wire).unwrap();
        assert_eq!(wire[n - 1], DELIMITER);
        assert!(
            !wire[..n - 1].contains(&DELIMITER),
            "COBS leaves no zero inside a frame"
        );
        let mut dec = StereoToAutopilotDecoder::new();
        let mut got = None;
        dec.feed(&wire[..n], |m| got = Some(m));
        assert_eq!(got, Some(msg));
        assert_eq!(dec.errors().total(), 0);
    }

    #[test]
    fn cobs_handles_long_runs_without_zeros() {
        // 600 non-zero bytes exercise the 0xFF code path several times.
        let mut data = [0u8; 700];
        let len = 600;
        let src = cobs_overhead(len);
        for (i, b) in data[src..src + len].iter_mut().enumerate() {
            *b = (i % 255 + 1) as u8;
        }
        let expect: heapless::Vec<u8, 600> =
            heapless::Vec::from_slice(&data[src..src + len]).unwrap();
        let enc = cobs_encode_in_place(&mut data, src, len).unwrap();
        assert!(!data[..enc].contains(&0));
        let dec = cobs::decode_in_place(&mut data[..enc]).unwrap();
        assert_eq!(&data[..dec], &expect[..]);
    }

    #[test]
    fn in_place_encoding_equals_the_crates_two_buffer_encoding() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(35);
        // From 1 byte: a raw frame is never empty (the crate encodes nothing as nothing).
        for len in (1..700).chain([253, 254, 255, 508, 509, 510]) {
            // Runs of zeros, runs without, and mixtures: every code path of the encoder.
            let zeros_per_256 = [0u32, 1, 16, 128, 256][len % 5];
            let raw: heapless::Vec<u8, 800> = (0..len)
                .map(|_| {
                    if rng.random_range(0..256) < zeros_per_256 {
                        0
                    } else {
                        rng.random_range(1..=255)
                    }
                })
                .collect();
            let mut expected = [0u8; 800];
            let expected_len = cobs::encode(&raw, &mut expected);
            let mut buf = [0u8; 800];
            let src = cobs_overhead(len);
            buf[src..src + len].copy_from_slice(&raw);
            let enc = cobs_encode_in_place(&mut buf, src, len).unwrap();
            assert_eq!(&buf[..enc], &expected[..expected_len], "length {len}");
        }
    }

    #[test]
    fn tiny_buffers_are_refused_not_panicked() {
        let msg = StereoToAutopilot::Estimate(estimate());
        for size in 0..32 {
            let mut buf = [0u8; 40];
            let r = encode(&msg, &mut buf[..size]);
            assert!(r.is_err() || r.unwrap() <= size);
        }
    }

    #[test]
    fn version_mismatch_is_detected_and_reported() {
        // Build a frame by hand with version 99 and a valid CRC.
        let mut raw = [0u8; 16];
        raw[0] = 99;
        let payload = postcard::to_slice(
            &AutopilotToStereo::Heartbeat(Heartbeat::new(Node::Autopilot, 5)),
            &mut raw[1..12],
        )
        .unwrap()
        .len();
        let crc = CRC16.checksum(&raw[..1 + payload]).to_le_bytes();
        raw[1 + payload..3 + payload].copy_from_slice(&crc);
        let raw_len = 3 + payload;
        let mut wire = [0u8; 32];
        let off = cobs_overhead(32);
        wire[off..off + raw_len].copy_from_slice(&raw[..raw_len]);
        let n = cobs_encode_in_place(&mut wire, off, raw_len).unwrap();
        wire[n] = 0;
        let mut dec = AutopilotToStereoDecoder::new();
        let mut count = 0;
        dec.feed(&wire[..=n], |_| count += 1);
        assert_eq!(count, 0);
        assert_eq!(dec.errors().version_mismatch, 1);
        assert_eq!(dec.peer_version_mismatch(), Some(99));
    }
}
