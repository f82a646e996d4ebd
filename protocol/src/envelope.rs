//! What a signed host message and a link key are on the wire: the envelope
//! [`SignedMessage`] and the [`LinkKey`] (how they are made and checked:
//! [`crate::signing`]).

use serde::{Deserialize, Serialize};

/// Bytes of a link key.
pub const KEY_BYTES: usize = 32;
/// Bytes of the truncated MAC carried in each envelope.
pub const MAC_BYTES: usize = 6;
/// Largest inner message an envelope carries, bytes (postcard encoding).
pub const SIGNED_PAYLOAD_MAX: usize = 64;
/// Largest signing timestamp: timestamps are 48-bit.
pub const TIMESTAMP_MAX: u64 = (1 << 48) - 1;
/// The shared secret of a host link. Its `Debug` form never shows the bytes.
#[derive(Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct LinkKey(pub [u8; KEY_BYTES]);

impl core::fmt::Debug for LinkKey {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("LinkKey(<secret>)")
    }
}

/// Why a key's text (a key file's content) is not a link key.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KeyTextError {
    /// Not `2 * KEY_BYTES` characters once surrounding white space is trimmed (the number).
    Length(usize),
    /// The two characters at this position are not a hexadecimal byte.
    NotHex(usize),
}

impl core::fmt::Display for KeyTextError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Length(n) => write!(
                f,
                "expected {} hexadecimal digits, found {n} characters",
                2 * KEY_BYTES
            ),
            Self::NotHex(at) => write!(f, "the characters at position {at} are not hexadecimal"),
        }
    }
}

impl LinkKey {
    /// The key written as `2 * KEY_BYTES` hexadecimal digits (a key file's one line),
    /// surrounding white space ignored.
    pub fn from_hex(text: &str) -> Result<Self, KeyTextError> {
        let hex = text.trim().as_bytes();
        if hex.len() != 2 * KEY_BYTES {
            return Err(KeyTextError::Length(text.trim().chars().count()));
        }
        let digit = |c: u8| char::from(c).to_digit(16);
        let mut key = [0u8; KEY_BYTES];
        for (i, (byte, pair)) in key.iter_mut().zip(hex.chunks_exact(2)).enumerate() {
            match (digit(pair[0]), digit(pair[1])) {
                (Some(hi), Some(lo)) => *byte = (hi * 16 + lo) as u8,
                _ => return Err(KeyTextError::NotHex(2 * i)),
            }
        }
        Ok(Self(key))
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for LinkKey {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "LinkKey(<secret>)")
    }
}

/// A host message with its signature ([`crate::messages::HostToBoard::Signed`]).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SignedMessage {
    /// The signer's stream id; the replay check is per id.
    pub link_id: u8,
    /// Signing time, 10 µs units since 2015-01-01 00:00 UTC, at most [`TIMESTAMP_MAX`].
    pub timestamp: u64,
    /// The truncated HMAC-SHA-256 of the signed bytes.
    pub mac: [u8; MAC_BYTES],
    /// The postcard encoding of the inner message.
    pub payload: heapless::Vec<u8, SIGNED_PAYLOAD_MAX>,
}
