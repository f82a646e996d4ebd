//! The flash record of a parameter table: its layout (magic, format, count, table hash,
//! sequence number, the values, an optional link key, a CRC-32), its encoding and its checked
//! decoding.

use serde::{Deserialize, Serialize};

use super::value::{table_hash, ParamSpec, ParamValue};
use crate::envelope::{KeyRecord, KEY_RECORD_BYTES};

/// First word of a parameter record ("PDPR" little-endian).
pub const RECORD_MAGIC: u32 = u32::from_le_bytes(*b"PDPR");
/// Layout version of a record without a link key (header fields, value encoding, CRC).
pub const RECORD_FORMAT_VERSION: u16 = 2;
/// Layout version of a record that carries the link key: version 2's layout with the
/// [`KeyRecord`] ([`KEY_RECORD_BYTES`]) between the values and the CRC, which covers it too.
pub const RECORD_FORMAT_KEYED: u16 = 3;
/// Bytes before the values: magic, format version, count, table hash, sequence number.
pub const RECORD_HEADER_BYTES: usize = 16;

/// Bytes of the record of a `count`-entry table (header, 4 bytes a value, CRC-32).
pub const fn record_bytes(count: usize) -> usize {
    RECORD_HEADER_BYTES + 4 * count + 4
}

/// Most entries a table can have to be saved ([`ParamTable::save`] encodes into a buffer of
/// [`MAX_RECORD_BYTES`] on the stack).
///
/// [`ParamTable::save`]: super::ParamTable::save
pub const MAX_PARAMS: usize = 160;
/// Bytes of the record of a table of [`MAX_PARAMS`] entries with a link key.
pub const MAX_RECORD_BYTES: usize = record_bytes(MAX_PARAMS) + KEY_RECORD_BYTES;

/// Why a flash record was not loaded (the board keeps its defaults).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RecordError {
    /// Erased flash: nothing was ever saved.
    Blank,
    /// Not a parameter record (wrong magic).
    BadMagic,
    /// Written by another record format (the value).
    FormatVersion(u16),
    /// Written for another parameter table (names or kinds changed).
    TableChanged,
    /// The record is cut short, or the output buffer is too small.
    Length,
    /// The CRC does not match: corrupt or partly written.
    BadCrc,
    /// A stored value is not of its kind, outside its bounds or not finite (its index).
    BadValue(u16),
}

const RECORD_CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// Writes the record of `values` (in `table` order, each checked against its spec) into
/// `out`; returns its length ([`record_bytes`]).
pub fn encode_record(
    table: &[ParamSpec],
    values: &[ParamValue],
    out: &mut [u8],
) -> Result<usize, RecordError> {
    if values.len() != table.len() {
        return Err(RecordError::Length);
    }
    encode_values(table, values.iter().copied(), 0, None, out)
}

/// Whether sequence number `seq` is newer than `than`: sequence numbers wrap, and the newer
/// is the one the other is behind.
pub(super) fn is_newer(seq: u32, than: u32) -> bool {
    i32::from_le_bytes(seq.wrapping_sub(than).to_le_bytes()) > 0
}

/// Why a link key was not written to a board's storage ([`ParamTable::save_link_key`]).
///
/// [`ParamTable::save_link_key`]: super::ParamTable::save_link_key
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum KeySaveError {
    /// No slot holds a good record to keep, and not every slot is blank (why).
    Record(RecordError),
    /// The flash refused the write, or holds other bytes after it.
    SaveFailed,
}

/// The sequence number in the header of the record at the start of `bytes` (meaningful once
/// [`decode_record`] accepted it); `None` when `bytes` is shorter than a header.
pub fn record_sequence(bytes: &[u8]) -> Option<u32> {
    let b = bytes.get(12..RECORD_HEADER_BYTES)?;
    Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

/// [`encode_record`] of values in table order as they come (one per entry of `table`),
/// numbered `sequence`, with `key` ([`RECORD_FORMAT_KEYED`]) or without.
pub(super) fn encode_values(
    table: &[ParamSpec],
    values: impl Iterator<Item = ParamValue>,
    sequence: u32,
    key: Option<&KeyRecord>,
    out: &mut [u8],
) -> Result<usize, RecordError> {
    let values_end = record_bytes(table.len()) - 4;
    let n = record_len(key.is_some(), table.len());
    if out.len() < n || table.len() > usize::from(u16::MAX) {
        return Err(RecordError::Length);
    }
    let format = if key.is_some() {
        RECORD_FORMAT_KEYED
    } else {
        RECORD_FORMAT_VERSION
    };
    let (head, rest) = out.split_at_mut(RECORD_HEADER_BYTES);
    head[0..4].copy_from_slice(&RECORD_MAGIC.to_le_bytes());
    head[4..6].copy_from_slice(&format.to_le_bytes());
    head[6..8].copy_from_slice(&(table.len() as u16).to_le_bytes());
    head[8..12].copy_from_slice(&table_hash(table).to_le_bytes());
    head[12..16].copy_from_slice(&sequence.to_le_bytes());
    let mut written = 0;
    for (i, ((chunk, v), spec)) in rest.chunks_exact_mut(4).zip(values).zip(table).enumerate() {
        if spec.check(v).is_err() {
            return Err(RecordError::BadValue(i as u16));
        }
        chunk.copy_from_slice(&v.to_bits().to_le_bytes());
        written += 1;
    }
    if written != table.len() {
        return Err(RecordError::Length);
    }
    if let Some(key) = key {
        out[values_end..values_end + KEY_RECORD_BYTES].copy_from_slice(&key.encode());
    }
    let crc = RECORD_CRC.checksum(&out[..n - 4]);
    out[n - 4..n].copy_from_slice(&crc.to_le_bytes());
    Ok(n)
}

/// Bytes of a record of `count` values, with a link key or without.
const fn record_len(keyed: bool, count: usize) -> usize {
    record_bytes(count) + if keyed { KEY_RECORD_BYTES } else { 0 }
}

/// What a record's frame says, once its magic, format, length and CRC are checked.
struct RecordFrame {
    count: usize,
    hash: u32,
    key: Option<KeyRecord>,
}

/// Checks the frame of the record at the start of `bytes` (magic, format, length, CRC, and a
/// keyed record's key), not its table or values.
fn record_frame(bytes: &[u8]) -> Result<RecordFrame, RecordError> {
    let word = |at: usize| -> Option<u32> {
        let b = bytes.get(at..at + 4)?;
        Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let magic = word(0).ok_or(RecordError::Length)?;
    if magic == u32::MAX {
        return Err(RecordError::Blank);
    }
    if magic != RECORD_MAGIC {
        return Err(RecordError::BadMagic);
    }
    let head = bytes.get(4..12).ok_or(RecordError::Length)?;
    let format = u16::from_le_bytes([head[0], head[1]]);
    let keyed = match format {
        RECORD_FORMAT_VERSION => false,
        RECORD_FORMAT_KEYED => true,
        other => return Err(RecordError::FormatVersion(other)),
    };
    let count = usize::from(u16::from_le_bytes([head[2], head[3]]));
    let hash = u32::from_le_bytes([head[4], head[5], head[6], head[7]]);
    let n = record_len(keyed, count);
    let body = bytes.get(..n - 4).ok_or(RecordError::Length)?;
    let crc = word(n - 4).ok_or(RecordError::Length)?;
    if RECORD_CRC.checksum(body) != crc {
        return Err(RecordError::BadCrc);
    }
    let key = if keyed {
        let at = record_bytes(count) - 4;
        let section = body.get(at..).ok_or(RecordError::Length)?;
        // The CRC matched: a key that does not decode was written so (not by this code).
        Some(KeyRecord::decode(section).map_err(|_| RecordError::BadCrc)?)
    } else {
        None
    };
    Ok(RecordFrame { count, hash, key })
}

/// The link key the record at the start of `bytes` carries (`None`: a record without one),
/// once its frame (magic, format, length, CRC) is checked; its table and values are not.
pub fn record_link_key(bytes: &[u8]) -> Result<Option<KeyRecord>, RecordError> {
    record_frame(bytes).map(|f| f.key)
}

/// Reads a record written for `table` from `bytes` (which may extend past it), handing each
/// value to `store(index, value)` only once the whole record has been checked.
pub fn decode_record(
    table: &[ParamSpec],
    bytes: &[u8],
    mut store: impl FnMut(usize, ParamValue),
) -> Result<(), RecordError> {
    let word = |at: usize| -> Option<u32> {
        let b = bytes.get(at..at + 4)?;
        Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let RecordFrame { count, hash, .. } = record_frame(bytes)?;
    if count != table.len() || hash != table_hash(table) {
        return Err(RecordError::TableChanged);
    }
    let value = |i: usize| -> Result<ParamValue, RecordError> {
        let bits = word(RECORD_HEADER_BYTES + 4 * i).ok_or(RecordError::Length)?;
        let v =
            ParamValue::from_bits(table[i].kind, bits).ok_or(RecordError::BadValue(i as u16))?;
        table[i]
            .check(v)
            .map_err(|_| RecordError::BadValue(i as u16))?;
        Ok(v)
    };
    for i in 0..count {
        value(i)?;
    }
    for i in 0..count {
        store(i, value(i)?);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::params::fixtures::TABLE;

    const VALUES: [ParamValue; 3] = [
        ParamValue::F32(1.25),
        ParamValue::U32(500_000),
        ParamValue::Bool(true),
    ];

    fn record() -> [u8; record_bytes(3)] {
        let mut buf = [0u8; record_bytes(3)];
        assert_eq!(encode_record(TABLE, &VALUES, &mut buf), Ok(buf.len()));
        buf
    }

    #[test]
    fn a_record_reads_back() {
        let buf = record();
        let mut got = [ParamValue::U32(0); 3];
        // Trailing erased flash after the record is ignored.
        let mut flash = [0xffu8; 64];
        flash[..buf.len()].copy_from_slice(&buf);
        decode_record(TABLE, &flash, |i, v| got[i] = v).unwrap();
        assert_eq!(got, VALUES);
    }

    #[test]
    fn every_damaged_record_is_refused_and_nothing_is_stored() {
        let good = record();
        let refuse = |bytes: &[u8]| {
            let mut stored = 0;
            let r = decode_record(TABLE, bytes, |_, _| stored += 1);
            assert_eq!(stored, 0);
            r.unwrap_err()
        };
        assert_eq!(refuse(&[0xff; 64]), RecordError::Blank);
        assert_eq!(refuse(&good[..10]), RecordError::Length);
        assert_eq!(refuse(&good[..good.len() - 1]), RecordError::Length);
        // Every single-bit flip after the magic is caught (by the CRC or a header check).
        for byte in 4..good.len() {
            for bit in 0..8 {
                let mut bad = good;
                bad[byte] ^= 1 << bit;
                refuse(&bad);
            }
        }
        let mut wrong_magic = good;
        wrong_magic[0] = b'X';
        assert_eq!(refuse(&wrong_magic), RecordError::BadMagic);
        let mut older = good;
        older[4..6].copy_from_slice(&0u16.to_le_bytes());
        assert_eq!(refuse(&older), RecordError::FormatVersion(0));
        // A record of another table (a renamed parameter), with a valid CRC.
        let mut renamed = TABLE.to_vec();
        renamed[1].name = "timeout2_us";
        let mut other = [0u8; record_bytes(3)];
        encode_record(&renamed, &VALUES, &mut other).unwrap();
        assert_eq!(refuse(&other), RecordError::TableChanged);
        // A record whose value is out of this table's bounds, with a valid CRC.
        let mut narrower = TABLE.to_vec();
        narrower[0].max = ParamValue::F32(1.0);
        assert_eq!(
            decode_record(&narrower, &good, |_, _| ()),
            Err(RecordError::BadValue(0))
        );
    }

    #[test]
    fn out_of_bounds_values_are_not_saved() {
        let mut buf = [0u8; record_bytes(3)];
        let mut v = VALUES;
        v[1] = ParamValue::U32(0);
        assert_eq!(
            encode_record(TABLE, &v, &mut buf),
            Err(RecordError::BadValue(1))
        );
        assert_eq!(
            encode_record(TABLE, &VALUES, &mut buf[..10]),
            Err(RecordError::Length)
        );
    }
}
