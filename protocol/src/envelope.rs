//! What a signed host message and a link key are on the wire and in flash: the envelope
//! [`SignedMessage`], the [`LinkKey`] and its [`KeyRecord`] (how messages are signed and
//! checked: [`crate::signing`]).

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

/// Why a key record could not be read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum KeyRecordError {
    /// Erased flash: no key provisioned.
    Blank,
    /// Wrong magic, length or CRC.
    Corrupt,
}

/// The link key as stored in the parameter record (`crate::params`, format
/// `RECORD_FORMAT_KEYED`): written over SWD by `cargo xtask flash --key`, or by the board when
/// a key is provisioned over the link, and with every parameter save.
///
/// Layout, 48 bytes: `b"PDK1"`, the key (32 bytes), `min_timestamp` (u64 little endian), and a
/// CRC-32/ISO-HDLC of the preceding 44 bytes (little endian).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct KeyRecord {
    /// The key.
    pub key: LinkKey,
    /// Replay floor after boot ([`ReplayGuard::new`](crate::signing::ReplayGuard::new)): the signing time of the provisioning.
    pub min_timestamp: u64,
}

/// Bytes of an encoded [`KeyRecord`].
pub const KEY_RECORD_BYTES: usize = 48;
const KEY_RECORD_MAGIC: [u8; 4] = *b"PDK1";
const KEY_CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

impl KeyRecord {
    /// The record's bytes.
    pub fn encode(&self) -> [u8; KEY_RECORD_BYTES] {
        let mut out = [0u8; KEY_RECORD_BYTES];
        let (body, crc) = out.split_at_mut(KEY_RECORD_BYTES - 4);
        let (magic, rest) = body.split_at_mut(4);
        magic.copy_from_slice(&KEY_RECORD_MAGIC);
        let (key, ts) = rest.split_at_mut(KEY_BYTES);
        key.copy_from_slice(&self.key.0);
        ts.copy_from_slice(&self.min_timestamp.to_le_bytes());
        crc.copy_from_slice(&KEY_CRC.checksum(body).to_le_bytes());
        out
    }

    /// Reads a record from the start of `bytes`.
    pub fn decode(bytes: &[u8]) -> Result<Self, KeyRecordError> {
        let record = bytes
            .get(..KEY_RECORD_BYTES)
            .ok_or(KeyRecordError::Corrupt)?;
        if record.iter().all(|&b| b == 0xFF) {
            return Err(KeyRecordError::Blank);
        }
        let (body, crc) = record.split_at(KEY_RECORD_BYTES - 4);
        let stored_crc = u32::from_le_bytes(crc.try_into().map_err(|_| KeyRecordError::Corrupt)?);
        if body.get(..4) != Some(&KEY_RECORD_MAGIC[..]) || KEY_CRC.checksum(body) != stored_crc {
            return Err(KeyRecordError::Corrupt);
        }
        let key: [u8; KEY_BYTES] = body
            .get(4..4 + KEY_BYTES)
            .and_then(|k| k.try_into().ok())
            .ok_or(KeyRecordError::Corrupt)?;
        let ts: [u8; 8] = body
            .get(4 + KEY_BYTES..)
            .and_then(|t| t.try_into().ok())
            .ok_or(KeyRecordError::Corrupt)?;
        Ok(Self {
            key: LinkKey(key),
            min_timestamp: u64::from_le_bytes(ts),
        })
    }
}
