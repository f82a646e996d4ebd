//! Named, typed parameters: the table a board publishes, the messages that list, read, write
//! and save them, and the flash record they are saved in.
//!
//! Each board has one const table of [`ParamSpec`]s (name, kind, unit, bounds, writable); its
//! values live in the board's configuration struct. A host lists the table entry by entry
//! ([`ParamOp::List`] with an index, answered with a [`ParamEntry`] that carries the count),
//! reads and writes by name (names survive a reordered table; indices need not), and asks for a
//! save. Every request is answered with one [`ParamResponse`].
//!
//! The flash record ([`encode_record`], [`decode_record`]) holds the values in table order
//! behind a magic, a format version and the table's [`table_hash`] (names and kinds), closed
//! by a CRC-32: a blank, corrupt, older-format or other-table record decodes to an error, and
//! the board keeps its defaults and reports why.

use serde::{Deserialize, Serialize};

use crate::Node;

/// Longest parameter name, bytes.
pub const PARAM_NAME_LEN: usize = 24;
/// Longest unit string, bytes.
pub const PARAM_UNIT_LEN: usize = 8;

/// A parameter name on the wire.
pub type ParamName = heapless::String<PARAM_NAME_LEN>;
/// A unit string on the wire.
pub type ParamUnit = heapless::String<PARAM_UNIT_LEN>;

/// The type of a parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ParamKind {
    /// 32-bit float.
    F32,
    /// Unsigned integer (durations in µs, counts, enum choices).
    U32,
    /// Flag.
    Bool,
}

impl ParamKind {
    /// Lower-case name for tables and files.
    pub fn name(self) -> &'static str {
        match self {
            ParamKind::F32 => "f32",
            ParamKind::U32 => "u32",
            ParamKind::Bool => "bool",
        }
    }
}

/// A parameter's value, tagged with its kind.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ParamValue {
    /// A float.
    F32(f32),
    /// An unsigned integer.
    U32(u32),
    /// A flag.
    Bool(bool),
}

impl ParamValue {
    /// The value's kind.
    pub fn kind(self) -> ParamKind {
        match self {
            ParamValue::F32(_) => ParamKind::F32,
            ParamValue::U32(_) => ParamKind::U32,
            ParamValue::Bool(_) => ParamKind::Bool,
        }
    }

    /// The 32 bits the flash record stores (f32 bit pattern, the integer, 0 / 1).
    pub fn to_bits(self) -> u32 {
        match self {
            ParamValue::F32(x) => x.to_bits(),
            ParamValue::U32(x) => x,
            ParamValue::Bool(b) => u32::from(b),
        }
    }

    /// The value of `kind` stored as `bits`; `None` for a flag other than 0 / 1.
    pub fn from_bits(kind: ParamKind, bits: u32) -> Option<Self> {
        match kind {
            ParamKind::F32 => Some(ParamValue::F32(f32::from_bits(bits))),
            ParamKind::U32 => Some(ParamValue::U32(bits)),
            ParamKind::Bool => match bits {
                0 => Some(ParamValue::Bool(false)),
                1 => Some(ParamValue::Bool(true)),
                _ => None,
            },
        }
    }
}

impl core::fmt::Display for ParamValue {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ParamValue::F32(x) => write!(f, "{x}"),
            ParamValue::U32(x) => write!(f, "{x}"),
            ParamValue::Bool(b) => write!(f, "{b}"),
        }
    }
}

/// One entry of a board's parameter table.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParamSpec {
    /// Name, `snake_case`, at most [`PARAM_NAME_LEN`] bytes (tested per table).
    pub name: &'static str,
    /// Kind of the value.
    pub kind: ParamKind,
    /// Unit (SI, `us` for microseconds, `-` for none), at most [`PARAM_UNIT_LEN`] bytes.
    pub unit: &'static str,
    /// Smallest accepted value (same kind; a flag's bounds are `false..=true`).
    pub min: ParamValue,
    /// Largest accepted value.
    pub max: ParamValue,
    /// False for a value the board shows but does not take at run time (fixed by hardware).
    pub writable: bool,
}

impl ParamSpec {
    /// Checks that `value` has this parameter's kind and lies within its bounds (a float must
    /// also be finite).
    pub fn check(&self, value: ParamValue) -> Result<(), ParamError> {
        if value.kind() != self.kind {
            return Err(ParamError::WrongKind);
        }
        let inside = match (value, self.min, self.max) {
            (ParamValue::F32(x), ParamValue::F32(lo), ParamValue::F32(hi)) => {
                x.is_finite() && x >= lo && x <= hi
            }
            (ParamValue::U32(x), ParamValue::U32(lo), ParamValue::U32(hi)) => x >= lo && x <= hi,
            (ParamValue::Bool(_), _, _) => true,
            _ => false,
        };
        if inside {
            Ok(())
        } else {
            Err(ParamError::OutOfBounds)
        }
    }
}

/// Index of the parameter called `name` in `table`.
pub fn find_param(table: &[ParamSpec], name: &str) -> Option<usize> {
    table.iter().position(|s| s.name == name)
}

/// FNV-1a hash of every name and kind of `table`, in order: the table version a flash record
/// is bound to (a renamed, retyped, added or moved parameter changes it).
pub const fn table_hash(table: &[ParamSpec]) -> u32 {
    let mut h: u32 = 0x811c_9dc5;
    let mut i = 0;
    while i < table.len() {
        let name = table[i].name.as_bytes();
        let mut j = 0;
        while j < name.len() {
            h = (h ^ name[j] as u32).wrapping_mul(0x0100_0193);
            j += 1;
        }
        let kind = match table[i].kind {
            ParamKind::F32 => 1u32,
            ParamKind::U32 => 2,
            ParamKind::Bool => 3,
        };
        // A separator and the kind after each name.
        h = (h ^ (0x100 | kind)).wrapping_mul(0x0100_0193);
        i += 1;
    }
    h
}

/// What a host asks a board's parameter table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ParamOp {
    /// The entry at this index (answered with [`ParamReply::Entry`], which carries the count).
    List(u16),
    /// The entry of this name.
    Get(ParamName),
    /// Writes this value (checked against the kind and bounds; refused while the motors may
    /// run). Answered with the entry holding the value now in use.
    Set(ParamName, ParamValue),
    /// Saves every value to flash (refused while the motors may run).
    Save,
}

/// A parameter request to one board (host -> autopilot; the autopilot answers for itself).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ParamRequest {
    /// The board whose table is meant.
    pub board: Node,
    /// What to do.
    pub op: ParamOp,
}

/// One parameter as a board reports it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ParamEntry {
    /// Index in the board's table.
    pub index: u16,
    /// Number of entries in the table.
    pub count: u16,
    /// Name.
    pub name: ParamName,
    /// Unit.
    pub unit: ParamUnit,
    /// The value in use.
    pub value: ParamValue,
    /// The firmware's default.
    pub default: ParamValue,
    /// Smallest accepted value.
    pub min: ParamValue,
    /// Largest accepted value.
    pub max: ParamValue,
    /// False: shown, not settable.
    pub writable: bool,
}

/// Why a parameter request failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ParamError {
    /// No parameter of that name.
    UnknownName,
    /// Index past the end of the table.
    UnknownIndex,
    /// The value is not of the parameter's kind.
    WrongKind,
    /// The value is outside the parameter's bounds (or not finite).
    OutOfBounds,
    /// The parameter cannot be set at run time.
    ReadOnly,
    /// The motors may run (armed, flying, landing): set and save wait for the ground.
    Armed,
    /// The value is within its bounds but the configuration it makes is inconsistent (e.g. a
    /// minimum above its maximum); the previous value stays.
    Inconsistent,
    /// This board does not serve that board's table.
    NoSuchBoard,
    /// The flash could not be written or read back.
    SaveFailed,
    /// This build has no parameter storage.
    NoStorage,
}

impl ParamError {
    /// A short sentence for a user.
    pub fn describe(self) -> &'static str {
        match self {
            ParamError::UnknownName => "no parameter of that name",
            ParamError::UnknownIndex => "index past the end of the table",
            ParamError::WrongKind => "value of the wrong type",
            ParamError::OutOfBounds => "value outside the parameter's bounds",
            ParamError::ReadOnly => "the parameter is read-only",
            ParamError::Armed => "refused while armed (the motors may run)",
            ParamError::Inconsistent => "the configuration would be inconsistent",
            ParamError::NoSuchBoard => "this board does not serve that board's parameters",
            ParamError::SaveFailed => "writing the flash failed",
            ParamError::NoStorage => "this build has no parameter storage",
        }
    }
}

/// A board's answer to one [`ParamRequest`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ParamReply {
    /// The entry asked for (or written).
    Entry(ParamEntry),
    /// Every value was saved to flash.
    Saved,
    /// The request failed; nothing changed.
    Error(ParamError),
}

/// A parameter answer (board -> host).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ParamResponse {
    /// The board whose table the answer is about (the request's).
    pub board: Node,
    /// The answer.
    pub reply: ParamReply,
}

/// First word of a parameter record ("PDPR" little-endian).
pub const RECORD_MAGIC: u32 = u32::from_le_bytes(*b"PDPR");
/// Layout version of the record (header fields, value encoding, CRC).
pub const RECORD_FORMAT_VERSION: u16 = 1;
/// Bytes before the values: magic, format version, count, table hash.
pub const RECORD_HEADER_BYTES: usize = 12;

/// Bytes of the record of a `count`-entry table (header, 4 bytes a value, CRC-32).
pub const fn record_bytes(count: usize) -> usize {
    RECORD_HEADER_BYTES + 4 * count + 4
}

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
    let n = record_bytes(table.len());
    if values.len() != table.len() || out.len() < n || table.len() > usize::from(u16::MAX) {
        return Err(RecordError::Length);
    }
    for (i, (spec, v)) in table.iter().zip(values).enumerate() {
        if spec.check(*v).is_err() {
            return Err(RecordError::BadValue(i as u16));
        }
    }
    let (head, rest) = out.split_at_mut(RECORD_HEADER_BYTES);
    head[0..4].copy_from_slice(&RECORD_MAGIC.to_le_bytes());
    head[4..6].copy_from_slice(&RECORD_FORMAT_VERSION.to_le_bytes());
    head[6..8].copy_from_slice(&(table.len() as u16).to_le_bytes());
    head[8..12].copy_from_slice(&table_hash(table).to_le_bytes());
    for (chunk, v) in rest.chunks_exact_mut(4).zip(values) {
        chunk.copy_from_slice(&v.to_bits().to_le_bytes());
    }
    let crc = RECORD_CRC.checksum(&out[..n - 4]);
    out[n - 4..n].copy_from_slice(&crc.to_le_bytes());
    Ok(n)
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
    let magic = word(0).ok_or(RecordError::Length)?;
    if magic == u32::MAX {
        return Err(RecordError::Blank);
    }
    if magic != RECORD_MAGIC {
        return Err(RecordError::BadMagic);
    }
    let head = bytes
        .get(4..RECORD_HEADER_BYTES)
        .ok_or(RecordError::Length)?;
    let format = u16::from_le_bytes([head[0], head[1]]);
    if format != RECORD_FORMAT_VERSION {
        return Err(RecordError::FormatVersion(format));
    }
    let count = usize::from(u16::from_le_bytes([head[2], head[3]]));
    let hash = u32::from_le_bytes([head[4], head[5], head[6], head[7]]);
    let n = record_bytes(count);
    let body = bytes.get(..n).ok_or(RecordError::Length)?;
    let crc = word(n - 4).ok_or(RecordError::Length)?;
    if RECORD_CRC.checksum(&body[..n - 4]) != crc {
        return Err(RecordError::BadCrc);
    }
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

    const TABLE: &[ParamSpec] = &[
        ParamSpec {
            name: "gain",
            kind: ParamKind::F32,
            unit: "-",
            min: ParamValue::F32(0.0),
            max: ParamValue::F32(2.0),
            writable: true,
        },
        ParamSpec {
            name: "timeout_us",
            kind: ParamKind::U32,
            unit: "us",
            min: ParamValue::U32(10),
            max: ParamValue::U32(1_000_000),
            writable: true,
        },
        ParamSpec {
            name: "adapt",
            kind: ParamKind::Bool,
            unit: "-",
            min: ParamValue::Bool(false),
            max: ParamValue::Bool(true),
            writable: true,
        },
    ];

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
    fn bounds_and_kinds_are_checked() {
        assert_eq!(TABLE[0].check(ParamValue::F32(2.0)), Ok(()));
        assert_eq!(
            TABLE[0].check(ParamValue::F32(2.01)),
            Err(ParamError::OutOfBounds)
        );
        assert_eq!(
            TABLE[0].check(ParamValue::F32(f32::NAN)),
            Err(ParamError::OutOfBounds)
        );
        assert_eq!(
            TABLE[0].check(ParamValue::U32(1)),
            Err(ParamError::WrongKind)
        );
        assert_eq!(
            TABLE[1].check(ParamValue::U32(9)),
            Err(ParamError::OutOfBounds)
        );
        assert_eq!(TABLE[2].check(ParamValue::Bool(false)), Ok(()));
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

    #[test]
    fn the_largest_messages_fit_their_frames() {
        use crate::{encode, BoardToHost, HostToBoard, Message};
        let name = ParamName::try_from("n".repeat(PARAM_NAME_LEN).as_str()).unwrap();
        let unit = ParamUnit::try_from("u".repeat(PARAM_UNIT_LEN).as_str()).unwrap();
        // Values whose encodings are the longest (u32::MAX is a 5-byte varint).
        let big = ParamValue::U32(u32::MAX);
        let answer = BoardToHost::Param(ParamResponse {
            board: Node::StereoBoard,
            reply: ParamReply::Entry(ParamEntry {
                index: u16::MAX,
                count: u16::MAX,
                name: name.clone(),
                unit,
                value: big,
                default: big,
                min: big,
                max: big,
                writable: true,
            }),
        });
        let mut buf = [0u8; 1024];
        let n = encode(&answer, &mut buf).unwrap();
        assert!(n <= BoardToHost::MAX_FRAME_BYTES, "{n} bytes");
        let request = HostToBoard::Param(ParamRequest {
            board: Node::StereoBoard,
            op: ParamOp::Set(name, big),
        });
        let n = encode(&request, &mut buf).unwrap();
        assert!(n <= HostToBoard::MAX_FRAME_BYTES, "{n} bytes");
    }

    #[test]
    fn the_table_hash_follows_names_kinds_and_order() {
        let h = table_hash(TABLE);
        let mut t = TABLE.to_vec();
        t.swap(0, 1);
        assert_ne!(table_hash(&t), h);
        let mut t = TABLE.to_vec();
        t[2].kind = ParamKind::U32;
        assert_ne!(table_hash(&t), h);
        let mut t = TABLE.to_vec();
        t[0].unit = "m";
        t[0].max = ParamValue::F32(9.0);
        assert_eq!(
            table_hash(&t),
            h,
            "units and bounds are not part of the layout"
        );
    }
}
