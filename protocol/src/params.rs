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
//! behind a magic, a format version, the table's [`table_hash`] (names and kinds) and a save
//! sequence number, closed by a CRC-32: a blank, corrupt, older-format or other-table record
//! decodes to an error. A board with a host link key saves it in every record
//! ([`ParamStorage::key`], format [`RECORD_FORMAT_KEYED`]: the [`KeyRecord`] before the CRC);
//! records without one keep format [`RECORD_FORMAT_VERSION`] and load as before. The key is
//! read back with [`ParamTable::load_link_key`], and put beside the saved configuration
//! without saving the one in use with [`ParamTable::save_link_key`] (the board, for a key
//! provisioned over its link) or [`ParamTable::record_with_key`] (the SWD flashing tool). A board's storage is a [`RecordStore`] (its flash sectors in the
//! firmware, a [`MemStore`] or [`MemSlots`] on the host) of one or two separately erased
//! slots. [`ParamTable::load`] reads every slot at boot and takes the good record with the
//! highest sequence number; [`ParamTable::save`] writes the next number into the slot that
//! does not hold it and reads it back, so with two slots a power loss at any point of a save
//! leaves the last complete record to boot on. A board whose boot found no good record (other
//! than a blank store) runs on its defaults and reports why; [`StorageStatus::blocks_arming`]
//! holds until a save succeeds or the failure is acknowledged ([`ParamOp::Acknowledge`]).
//! [`ParamOp::Storage`] reports what the boot loaded and the saves since.

use serde::{Deserialize, Serialize};

use crate::signing::{KeyRecord, KEY_RECORD_BYTES};
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
    /// Signed integer (calibration offsets).
    I32,
}

impl ParamKind {
    /// Lower-case name for tables and files.
    pub fn name(self) -> &'static str {
        match self {
            ParamKind::F32 => "f32",
            ParamKind::U32 => "u32",
            ParamKind::Bool => "bool",
            ParamKind::I32 => "i32",
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
    /// A signed integer.
    I32(i32),
}

impl ParamValue {
    /// The value's kind.
    pub fn kind(self) -> ParamKind {
        match self {
            ParamValue::F32(_) => ParamKind::F32,
            ParamValue::U32(_) => ParamKind::U32,
            ParamValue::Bool(_) => ParamKind::Bool,
            ParamValue::I32(_) => ParamKind::I32,
        }
    }

    /// The 32 bits the flash record stores (f32 bit pattern, the integer (two's complement
    /// for a signed one), 0 / 1).
    pub fn to_bits(self) -> u32 {
        match self {
            ParamValue::F32(x) => x.to_bits(),
            ParamValue::U32(x) => x,
            ParamValue::Bool(b) => u32::from(b),
            ParamValue::I32(x) => u32::from_le_bytes(x.to_le_bytes()),
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
            ParamKind::I32 => Some(ParamValue::I32(i32::from_le_bytes(bits.to_le_bytes()))),
        }
    }
}

impl core::fmt::Display for ParamValue {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ParamValue::F32(x) => write!(f, "{x}"),
            ParamValue::U32(x) => write!(f, "{x}"),
            ParamValue::Bool(b) => write!(f, "{b}"),
            ParamValue::I32(x) => write!(f, "{x}"),
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
            (ParamValue::I32(x), ParamValue::I32(lo), ParamValue::I32(hi)) => x >= lo && x <= hi,
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
            ParamKind::I32 => 4,
        };
        // A separator and the kind after each name.
        h = (h ^ (0x100 | kind)).wrapping_mul(0x0100_0193);
        i += 1;
    }
    h
}

/// A configuration field's type, seen as a parameter value (`u8`..`u64` as [`ParamKind::U32`],
/// `i8`..`i32` as [`ParamKind::I32`]; a board implements it for its own enum choices).
pub trait ParamField: Sized + Copy {
    /// The field as a parameter value (an unsigned field above `u32::MAX` saturates).
    fn to_param(self) -> ParamValue;
    /// The field of value `v`; `None` for another kind or a value the field cannot hold.
    fn from_param(v: ParamValue) -> Option<Self>;
}

impl ParamField for f32 {
    fn to_param(self) -> ParamValue {
        ParamValue::F32(self)
    }
    fn from_param(v: ParamValue) -> Option<Self> {
        match v {
            ParamValue::F32(x) => Some(x),
            _ => None,
        }
    }
}

impl ParamField for bool {
    fn to_param(self) -> ParamValue {
        ParamValue::Bool(self)
    }
    fn from_param(v: ParamValue) -> Option<Self> {
        match v {
            ParamValue::Bool(x) => Some(x),
            _ => None,
        }
    }
}

macro_rules! integer_field {
    ($variant:ident, $wide:ty, $sat:expr; $($t:ty),*) => {$(
        impl ParamField for $t {
            fn to_param(self) -> ParamValue {
                ParamValue::$variant(<$wide>::try_from(self).unwrap_or($sat))
            }
            fn from_param(v: ParamValue) -> Option<Self> {
                match v {
                    ParamValue::$variant(x) => <$t>::try_from(x).ok(),
                    _ => None,
                }
            }
        }
    )*};
}
integer_field!(U32, u32, u32::MAX; u8, u16, u32, u64);
integer_field!(I32, i32, i32::MAX; i8, i16, i32);

/// Reads and writes one field of a configuration `C` (one per [`ParamSpec`]; built by
/// [`crate::param_table!`]).
pub struct ParamAccess<C> {
    /// The field's value.
    pub get: fn(&C) -> ParamValue,
    /// Writes the field; false (nothing written) for a value the field cannot hold.
    pub set: fn(&mut C, ParamValue) -> bool,
}

/// Declares a board's parameter table over its configuration type: a `const` slice of
/// [`ParamSpec`]s and one of [`ParamAccess`]es, entry by entry in the same order.
///
/// ```
/// #[derive(Clone, Copy, Default)]
/// struct Config { gain: f32, shift: i8 }
/// protocol::param_table! {
///     /// The table.
///     pub SPECS, ACCESS: Config {
///         "gain": F32 ["-"] 0.0, 2.0, true => |c| c.gain;
///         "shift": I32 ["px"] -20, 20, true => |c| c.shift;
///     }
/// }
/// assert_eq!(SPECS[1].name, "shift");
/// let mut c = Config::default();
/// assert!((ACCESS[1].set)(&mut c, protocol::ParamValue::I32(-3)));
/// assert_eq!(c.shift, -3);
/// ```
#[macro_export]
macro_rules! param_table {
    ($(#[$meta:meta])* $vis:vis $specs:ident, $access:ident : $cfg:ty {
        $( $name:literal : $kind:ident [$unit:literal] $min:expr, $max:expr, $writable:literal
            => |$c:ident| $place:expr; )*
    }) => {
        $(#[$meta])*
        $vis const $specs: &[$crate::params::ParamSpec] = &[$(
            $crate::params::ParamSpec {
                name: $name,
                kind: $crate::params::ParamKind::$kind,
                unit: $unit,
                min: $crate::params::ParamValue::$kind($min),
                max: $crate::params::ParamValue::$kind($max),
                writable: $writable,
            },
        )*];

        const $access: &[$crate::params::ParamAccess<$cfg>] = &[$(
            $crate::params::ParamAccess {
                get: |$c: &$cfg| $crate::params::ParamField::to_param($place),
                set: |$c: &mut $cfg, v: $crate::params::ParamValue| {
                    match $crate::params::ParamField::from_param(v) {
                        Some(x) => {
                            $place = x;
                            true
                        }
                        None => false,
                    }
                },
            },
        )*];
    };
}

/// Two parameters whose values disagree: a bound of one depends on the other (a board's
/// consistency check returns it, [`ParamTable::consistent`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Conflict {
    /// The parameter reported at fault.
    pub name: &'static str,
    /// The parameter its bound depends on.
    pub other: &'static str,
    /// Why the two disagree, read between the two names ("`name` must be below `other`").
    pub reason: &'static str,
}

impl Conflict {
    /// `name` disagrees with `other` because of `reason`.
    pub const fn new(name: &'static str, other: &'static str, reason: &'static str) -> Self {
        Self {
            name,
            other,
            reason,
        }
    }
}

/// Why a configuration, or one parameter change, was refused.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rejected {
    /// The parameter at fault (its index in the table); `None` for a refusal that is not about
    /// one value (e.g. while armed).
    pub index: Option<usize>,
    /// Its entry in the table.
    pub spec: Option<&'static ParamSpec>,
    /// Why.
    pub error: ParamError,
    /// For [`ParamError::Inconsistent`]: the two parameters that disagree and why.
    pub conflict: Option<Conflict>,
}

impl Rejected {
    /// A refusal that is not about one parameter.
    pub const fn refused(error: ParamError) -> Self {
        Self {
            index: None,
            spec: None,
            error,
            conflict: None,
        }
    }

    /// The name of the parameter at fault, or `""`.
    pub fn name(&self) -> &'static str {
        self.spec.map_or("", |s| s.name)
    }
}

impl core::fmt::Display for Rejected {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match (self.index, self.spec) {
            (Some(i), Some(s)) => {
                write!(f, "parameter {} ({}): {}", s.name, i, self.error.describe())?;
                if self.error == ParamError::OutOfBounds {
                    write!(f, " [{} ..= {}] {}", s.min, s.max, s.unit)?;
                }
            }
            _ => f.write_str(self.error.describe())?,
        }
        if let Some(c) = self.conflict {
            write!(f, ": {} {} {}", c.name, c.reason, c.other)?;
        }
        Ok(())
    }
}

/// A board's parameter table over its configuration type `C`: the specs, how each reaches
/// its field, the defaults and the check of values that only make sense together. Both
/// boards serve theirs through it, so listing, reading, writing and the flash record behave
/// alike on each.
pub struct ParamTable<C: 'static> {
    /// The entries, in the order they are listed and stored.
    pub specs: &'static [ParamSpec],
    /// One accessor per entry.
    pub access: &'static [ParamAccess<C>],
    /// The configuration the firmware starts with.
    pub defaults: fn() -> C,
    /// Checks values against each other (each is already within its bounds): the first pair
    /// that disagrees.
    pub consistent: fn(&C) -> Result<(), Conflict>,
}

/// Copies `s` into a wire string, cut at its capacity.
fn wire_str<const N: usize>(s: &str) -> heapless::String<N> {
    let mut out = heapless::String::new();
    for ch in s.chars() {
        if out.push(ch).is_err() {
            break;
        }
    }
    out
}

impl<C: Copy> ParamTable<C> {
    /// Number of parameters.
    pub const fn len(&self) -> usize {
        self.specs.len()
    }

    /// True for a table without parameters.
    pub const fn is_empty(&self) -> bool {
        self.specs.is_empty()
    }

    /// The table's version for flash records ([`table_hash`]).
    pub const fn hash(&self) -> u32 {
        table_hash(self.specs)
    }

    /// Index of the parameter called `name`.
    pub fn index_of(&self, name: &str) -> Option<usize> {
        find_param(self.specs, name)
    }

    /// The value of parameter `index` in `cfg`.
    pub fn get(&self, cfg: &C, index: usize) -> Option<ParamValue> {
        self.access.get(index).map(|a| (a.get)(cfg))
    }

    fn rejected(&self, index: usize, error: ParamError) -> Rejected {
        Rejected {
            index: Some(index),
            spec: self.specs.get(index),
            error,
            conflict: None,
        }
    }

    /// Writes parameter `index` of `cfg`, if it is writable, the value has its kind, lies
    /// within its bounds and leaves the configuration consistent ([`ParamTable::validate`]);
    /// otherwise `cfg` is unchanged.
    pub fn set(&self, cfg: &mut C, index: usize, value: ParamValue) -> Result<(), Rejected> {
        let (spec, access) = match (self.specs.get(index), self.access.get(index)) {
            (Some(s), Some(a)) => (s, a),
            _ => return Err(self.rejected(index, ParamError::UnknownIndex)),
        };
        if !spec.writable {
            return Err(self.rejected(index, ParamError::ReadOnly));
        }
        spec.check(value).map_err(|e| self.rejected(index, e))?;
        let mut next = *cfg;
        if !(access.set)(&mut next, value) {
            return Err(self.rejected(index, ParamError::WrongKind));
        }
        match self.validate(&next) {
            Ok(()) => {
                *cfg = next;
                Ok(())
            }
            // The change made another value inconsistent: name the one that was set.
            Err(r) if r.error == ParamError::Inconsistent => Err(Rejected {
                conflict: r.conflict,
                ..self.rejected(index, ParamError::Inconsistent)
            }),
            Err(r) => Err(r),
        }
    }

    /// Writes parameter `name` of `cfg` (see [`ParamTable::set`]).
    pub fn set_by_name(&self, cfg: &mut C, name: &str, value: ParamValue) -> Result<(), Rejected> {
        let index = self
            .index_of(name)
            .ok_or(Rejected::refused(ParamError::UnknownName))?;
        self.set(cfg, index, value)
    }

    /// Checks a whole configuration: every value within its bounds (read-only ones at their
    /// fixed value), and the values consistent with each other.
    pub fn validate(&self, cfg: &C) -> Result<(), Rejected> {
        for (i, (spec, access)) in self.specs.iter().zip(self.access).enumerate() {
            spec.check((access.get)(cfg))
                .map_err(|e| self.rejected(i, e))?;
        }
        (self.consistent)(cfg).map_err(|c| {
            let at = match self.index_of(c.name) {
                Some(i) => self.rejected(i, ParamError::Inconsistent),
                None => Rejected::refused(ParamError::Inconsistent),
            };
            Rejected {
                conflict: Some(c),
                ..at
            }
        })
    }

    /// Parameter `index` of `cfg` as it goes on the wire.
    pub fn entry(&self, cfg: &C, index: usize) -> Option<ParamEntry> {
        let spec = self.specs.get(index)?;
        let defaults = (self.defaults)();
        Some(ParamEntry {
            index: u16::try_from(index).ok()?,
            count: u16::try_from(self.len()).unwrap_or(u16::MAX),
            name: wire_str(spec.name),
            unit: wire_str(spec.unit),
            value: self.get(cfg, index)?,
            default: self.get(&defaults, index)?,
            min: spec.min,
            max: spec.max,
            writable: spec.writable,
        })
    }

    /// Answers `op` for the configuration `cfg`: `List` and `Get` with the entry; `Set` by
    /// [`ParamTable::set`] on a copy, which `apply` then puts in use (it may refuse, e.g.
    /// while armed), answered with the entry now in use; `Save` by [`ParamTable::save`] into
    /// `storage` and `Storage` with its status. A board without storage (`None`) answers both
    /// `NoStorage`. A board that must refuse a save (the motors may run) does so before this
    /// is called.
    pub fn answer(
        &self,
        cfg: &C,
        op: &ParamOp,
        apply: impl FnOnce(C) -> Result<(), Rejected>,
        storage: Option<ParamStorage<'_>>,
    ) -> ParamReply {
        let entry_or = |c: &C, i: Option<usize>, e: ParamError| {
            i.and_then(|i| self.entry(c, i))
                .map_or(ParamReply::Error(e), ParamReply::Entry)
        };
        match op {
            ParamOp::List(i) => entry_or(cfg, Some(usize::from(*i)), ParamError::UnknownIndex),
            ParamOp::Get(name) => entry_or(cfg, self.index_of(name), ParamError::UnknownName),
            ParamOp::Set(name, value) => {
                let Some(index) = self.index_of(name) else {
                    return ParamReply::Error(ParamError::UnknownName);
                };
                let mut next = *cfg;
                match self
                    .set(&mut next, index, *value)
                    .and_then(|()| apply(next))
                {
                    Ok(()) => entry_or(&next, Some(index), ParamError::UnknownIndex),
                    Err(r) => ParamReply::Error(r.error),
                }
            }
            ParamOp::Save => storage.map_or(ParamReply::Error(ParamError::NoStorage), |s| {
                self.save(cfg, s)
            }),
            ParamOp::Storage => storage.map_or(ParamReply::Error(ParamError::NoStorage), |s| {
                ParamReply::Storage(*s.status)
            }),
            ParamOp::Acknowledge => storage.map_or(ParamReply::Error(ParamError::NoStorage), |s| {
                s.status.acknowledged = true;
                ParamReply::Storage(*s.status)
            }),
        }
    }

    /// Answers `req` on the board `own`: another board's table is refused (`NoSuchBoard`),
    /// this one's is answered by [`ParamTable::answer`].
    pub fn respond(
        &self,
        own: Node,
        req: &ParamRequest,
        cfg: &C,
        apply: impl FnOnce(C) -> Result<(), Rejected>,
        storage: Option<ParamStorage<'_>>,
    ) -> ParamResponse {
        let reply = if req.board == own {
            self.answer(cfg, &req.op, apply, storage)
        } else {
            ParamReply::Error(ParamError::NoSuchBoard)
        };
        ParamResponse {
            board: req.board,
            reply,
        }
    }

    /// The flash record of `cfg` ([`encode_record`], sequence number 0) written into `out`;
    /// returns its length,
    /// [`record_bytes`] of the table's length.
    pub fn encode_record(&self, cfg: &C, out: &mut [u8]) -> Result<usize, RecordError> {
        encode_values(
            self.specs,
            self.access.iter().map(|a| (a.get)(cfg)),
            0,
            None,
            out,
        )
    }

    /// The configuration saved in `store` ([`ParamTable::decode_record`]) and the storage's
    /// status from it: of the store's slots, the good record with the highest sequence number
    /// when there is one; otherwise the defaults and, in [`StorageStatus::loaded`], why (the
    /// first slot's reason that is not a blank slot, or `Blank` when every slot is).
    pub fn load(&self, store: &dyn RecordStore) -> (C, StorageStatus) {
        let (cfg, loaded) = match self.newest(store) {
            Ok((_, _, cfg)) => (cfg, Ok(())),
            Err(e) => ((self.defaults)(), Err(e)),
        };
        (cfg, StorageStatus::booted(loaded))
    }

    /// The store's newest good record: its slot, sequence number and configuration; or why no
    /// slot holds one. One copy in a firmware, however many callers (each would otherwise
    /// inline the whole table's decode).
    #[inline(never)]
    fn newest(&self, store: &dyn RecordStore) -> Result<(usize, u32, C), RecordError> {
        let mut best: Option<(usize, u32, C)> = None;
        let mut why = RecordError::Blank;
        for slot in 0..store.slots() {
            let bytes = store.slot(slot);
            match self.decode_record(bytes) {
                (cfg, Ok(())) => {
                    let seq = record_sequence(bytes).unwrap_or(0);
                    let newer = best.as_ref().is_none_or(|&(_, b, _)| is_newer(seq, b));
                    if newer {
                        best = Some((slot, seq, cfg));
                    }
                }
                (_, Err(RecordError::Blank)) => {}
                (_, Err(e)) => {
                    if why == RecordError::Blank {
                        why = e;
                    }
                }
            }
        }
        best.ok_or(why)
    }

    /// Saves `cfg`: writes its record ([`ParamTable::encode_record`]), numbered one after the
    /// store's newest good record, into the slot that does not hold that record (the only slot
    /// of a one-slot store) and reads it back; `Saved`, or `SaveFailed` when the store refused
    /// or holds other bytes. Counted in the storage's status. Until the write is read back the
    /// newest record stays where it was, so a two-slot store interrupted at any point boots
    /// on it. The write takes as long as the slot's erase (a second or two for a 128 KiB flash
    /// sector).
    pub fn save(&self, cfg: &C, storage: ParamStorage<'_>) -> ParamReply {
        let ParamStorage { store, status, key } = storage;
        let (slot, sequence) = match self.newest(store) {
            Ok((current, seq, _)) => ((current + 1) % store.slots().max(1), seq.wrapping_add(1)),
            Err(_) => (0, 1),
        };
        let mut record = [0u8; MAX_RECORD_BYTES];
        let values = self.access.iter().map(|a| (a.get)(cfg));
        let written = match encode_values(self.specs, values, sequence, key.as_ref(), &mut record) {
            Ok(n) => {
                let record = record.get(..n).unwrap_or(&[]);
                store.write_slot(slot, record).is_ok() && store.slot(slot).get(..n) == Some(record)
            }
            // A configuration in use passed `validate` and a table fits MAX_PARAMS: it always
            // encodes.
            Err(_) => false,
        };
        if written {
            status.saves = status.saves.saturating_add(1);
            ParamReply::Saved
        } else {
            status.failed_saves = status.failed_saves.saturating_add(1);
            ParamReply::Error(ParamError::SaveFailed)
        }
    }

    /// The link key saved in `store`: the key of the record [`ParamTable::load`] takes (the
    /// newest good one), or, when no record is good for this table (a firmware whose table
    /// changed since the save), of the newest whole record (magic, format, CRC), so that a
    /// board keeps its key across a firmware update. `None` when that record has no key or no
    /// slot holds a whole record.
    pub fn load_link_key(&self, store: &dyn RecordStore) -> Option<KeyRecord> {
        if let Ok((slot, _, _)) = self.newest(store) {
            return record_link_key(store.slot(slot)).ok().flatten();
        }
        let mut best: Option<(u32, Option<KeyRecord>)> = None;
        for slot in 0..store.slots() {
            let bytes = store.slot(slot);
            if let (Ok(key), Some(seq)) = (record_link_key(bytes), record_sequence(bytes)) {
                if best.is_none_or(|(b, _)| is_newer(seq, b)) {
                    best = Some((seq, key));
                }
            }
        }
        best.and_then(|(_, key)| key)
    }

    /// The record that puts `key` beside the configuration `store` holds, written into `out`:
    /// the newest good record's values (the defaults when every slot is blank), numbered one
    /// after it, for the slot that does not hold it. Returns that slot and the record's length.
    /// A store whose records are all bad (corrupt, another table) is refused with the first
    /// slot's reason: its defaults would otherwise replace a configuration the board reports as
    /// lost ([`StorageStatus::blocks_arming`]).
    pub fn record_with_key(
        &self,
        store: &dyn RecordStore,
        key: &KeyRecord,
        out: &mut [u8],
    ) -> Result<(usize, usize), RecordError> {
        let (slot, sequence, cfg) = match self.newest(store) {
            Ok((current, seq, cfg)) => (
                (current + 1) % store.slots().max(1),
                seq.wrapping_add(1),
                cfg,
            ),
            Err(RecordError::Blank) => (0, 1, (self.defaults)()),
            Err(e) => return Err(e),
        };
        let values = self.access.iter().map(|a| (a.get)(&cfg));
        let n = encode_values(self.specs, values, sequence, Some(key), out)?;
        Ok((slot, n))
    }

    /// Writes `key` into `store` beside the configuration it holds ([`ParamTable::record_with_key`]:
    /// the parameters saved stay as they are, unsaved changes stay unsaved) and reads it back.
    /// Like a save, it erases a slot (a second or two on a board's flash).
    pub fn save_link_key(
        &self,
        store: &mut dyn RecordStore,
        key: &KeyRecord,
    ) -> Result<(), KeySaveError> {
        let mut record = [0u8; MAX_RECORD_BYTES];
        let (slot, n) = self
            .record_with_key(store, key, &mut record)
            .map_err(KeySaveError::Record)?;
        let record = record.get(..n).unwrap_or(&[]);
        if store.write_slot(slot, record).is_ok() && store.slot(slot).get(..n) == Some(record) {
            Ok(())
        } else {
            Err(KeySaveError::SaveFailed)
        }
    }

    /// Writes every value of `cfg` in table order into `out` (at least [`ParamTable::len`]
    /// long; returns the number written).
    pub fn values(&self, cfg: &C, out: &mut [ParamValue]) -> usize {
        let mut n = 0;
        for (slot, a) in out.iter_mut().zip(self.access) {
            *slot = (a.get)(cfg);
            n += 1;
        }
        n
    }

    /// The configuration a flash record holds: every value from the record when the whole
    /// record is good and the values agree ([`ParamTable::validate`]); otherwise the defaults
    /// and why (an inconsistent set of values is [`RecordError::BadValue`] of the parameter
    /// at fault).
    pub fn decode_record(&self, bytes: &[u8]) -> (C, Result<(), RecordError>) {
        let defaults = (self.defaults)();
        let mut cfg = defaults;
        let mut stored = true;
        let decoded = decode_record(self.specs, bytes, |i, v| {
            stored &= self.access.get(i).is_some_and(|a| (a.set)(&mut cfg, v));
        });
        let result = match decoded {
            Err(e) => Err(e),
            Ok(()) if !stored => Err(RecordError::BadValue(0)),
            Ok(()) => self.validate(&cfg).map_err(|r| {
                RecordError::BadValue(u16::try_from(r.index.unwrap_or(0)).unwrap_or(u16::MAX))
            }),
        };
        match result {
            Ok(()) => (cfg, Ok(())),
            Err(e) => (defaults, Err(e)),
        }
    }
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
    /// What the board's parameter storage holds (answered with [`ParamReply::Storage`]).
    Storage,
    /// Accepts that the boot's record failed to load, so that the defaults in use may fly
    /// ([`StorageStatus::blocks_arming`]); answered with [`ParamReply::Storage`].
    Acknowledge,
}

/// A parameter request to one board (host -> autopilot; the autopilot answers for itself and
/// passes a request for the camera board on over the board-to-board link, and its answer back).
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
    /// The board's parameter storage: what the boot loaded, and the saves since.
    Storage(StorageStatus),
}

/// What a board's parameter storage says (the answer to [`ParamOp::Storage`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StorageStatus {
    /// What the boot found in flash: `Ok`, the saved values are in use; otherwise why the
    /// board runs on its defaults (a blank sector, a corrupt, older or other-table record, a
    /// value out of bounds).
    pub loaded: Result<(), RecordError>,
    /// Saves written and read back since boot.
    pub saves: u32,
    /// Saves that failed since boot (the flash refused, or read back wrong).
    pub failed_saves: u32,
    /// A failed load was acknowledged ([`ParamOp::Acknowledge`]).
    pub acknowledged: bool,
}

impl StorageStatus {
    /// The status of a boot that loaded `loaded`, before any save.
    pub const fn booted(loaded: Result<(), RecordError>) -> Self {
        Self {
            loaded,
            saves: 0,
            failed_saves: 0,
            acknowledged: false,
        }
    }

    /// True while the board must not arm: the boot found a record it could not load (a blank
    /// store is a board never saved, not a failure), and neither has a save succeeded since
    /// nor has the failure been acknowledged. The defaults in use are not what was saved.
    pub const fn blocks_arming(&self) -> bool {
        matches!(self.loaded, Err(e) if !matches!(e, RecordError::Blank))
            && self.saves == 0
            && !self.acknowledged
    }
}

/// A board's parameter storage as [`ParamTable::answer`] and [`ParamTable::save`] use it: the
/// region the record is written to and the status that counts the saves.
pub struct ParamStorage<'a> {
    /// The region (the firmware's flash sector, a test's [`MemStore`]).
    pub store: &'a mut dyn RecordStore,
    /// What the boot loaded, and the saves since.
    pub status: &'a mut StorageStatus,
    /// The link key the board holds, written into every record it saves (`None`: records
    /// without a key).
    pub key: Option<KeyRecord>,
}

impl<'a> ParamStorage<'a> {
    /// The storage of a board that has both a store and a status; `None` (no storage) when
    /// either is missing.
    pub fn of<'s: 'a>(
        store: Option<&'a mut (dyn RecordStore + 's)>,
        status: Option<&'a mut StorageStatus>,
    ) -> Option<Self> {
        Some(Self {
            store: store?,
            status: status?,
            key: None,
        })
    }

    /// The same storage saving `key` with every record.
    pub fn with_key(self, key: Option<KeyRecord>) -> Self {
        Self { key, ..self }
    }
}

/// A [`RecordStore`] in memory with a flash sector's rules: erased bytes are `0xFF` and
/// programming only clears bits. Host tests and simulated boards use it in place of flash.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MemStore<const N: usize> {
    /// The region's bytes.
    pub bytes: [u8; N],
    /// While set, every write fails as a flash error would (`SaveFailed`), leaving the bytes.
    pub refuse: bool,
    /// Writes asked for (refused ones too).
    pub writes: u32,
}

impl<const N: usize> MemStore<N> {
    /// An erased region.
    pub const fn blank() -> Self {
        Self {
            bytes: [0xff; N],
            refuse: false,
            writes: 0,
        }
    }
}

impl<const N: usize> Default for MemStore<N> {
    fn default() -> Self {
        Self::blank()
    }
}

impl<const N: usize> RecordStore for MemStore<N> {
    fn bytes(&self) -> &[u8] {
        &self.bytes
    }

    fn write(&mut self, record: &[u8]) -> Result<(), ParamError> {
        self.writes = self.writes.saturating_add(1);
        if self.refuse || record.len() > N {
            return Err(ParamError::SaveFailed);
        }
        self.bytes.fill(0xff);
        for (cell, b) in self.bytes.iter_mut().zip(record) {
            *cell &= *b;
        }
        Ok(())
    }
}

/// A two-slot [`RecordStore`] in memory with a flash sector's rules per slot (erased bytes are
/// `0xFF`, programming only clears bits) and a power supply a test can cut: after
/// [`MemSlots::power_steps`] more steps of a write (an erase is four steps of a quarter slot
/// each, a program one step a 32-bit word) the power fails, leaving the step under way half
/// done (a quarter half erased, a word with half its bits programmed), and every later write
/// fails until [`MemSlots::power_on`]. Host tests and simulated boards use it in place of two
/// flash sectors.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MemSlots<const N: usize> {
    /// The two slots' bytes.
    pub bytes: [[u8; N]; 2],
    /// Steps left before the power fails (`None`: it never does).
    pub power_steps: Option<u32>,
    /// Writes asked for (refused ones too).
    pub writes: u32,
    /// Set when the power failed; writes fail until [`MemSlots::power_on`].
    pub powered_off: bool,
}

impl<const N: usize> MemSlots<N> {
    /// Both slots erased, the power on.
    pub const fn blank() -> Self {
        Self {
            bytes: [[0xff; N]; 2],
            power_steps: None,
            writes: 0,
            powered_off: false,
        }
    }

    /// The power back (a reset): writes work again, with no cut planned.
    pub fn power_on(&mut self) {
        self.powered_off = false;
        self.power_steps = None;
    }

    /// Steps a write of `len` bytes takes (four for the erase, one per word).
    pub const fn steps_of(len: usize) -> u32 {
        4 + len.div_ceil(4) as u32
    }

    /// Takes one step; false (and the power off) when the supply fails during it.
    fn step(&mut self) -> bool {
        match self.power_steps {
            Some(0) => {
                self.powered_off = true;
                false
            }
            Some(ref mut n) => {
                *n -= 1;
                true
            }
            None => true,
        }
    }
}

impl<const N: usize> Default for MemSlots<N> {
    fn default() -> Self {
        Self::blank()
    }
}

impl<const N: usize> RecordStore for MemSlots<N> {
    fn bytes(&self) -> &[u8] {
        &self.bytes[0]
    }

    fn write(&mut self, record: &[u8]) -> Result<(), ParamError> {
        self.write_slot(0, record)
    }

    fn slots(&self) -> usize {
        2
    }

    fn slot(&self, slot: usize) -> &[u8] {
        self.bytes.get(slot).map_or(&[], |b| &b[..])
    }

    fn write_slot(&mut self, slot: usize, record: &[u8]) -> Result<(), ParamError> {
        self.writes = self.writes.saturating_add(1);
        if self.powered_off || slot >= 2 || record.len() > N {
            return Err(ParamError::SaveFailed);
        }
        let quarter = N.div_ceil(4);
        for q in 0..4 {
            let start = (q * quarter).min(N);
            let end = ((q + 1) * quarter).min(N);
            if !self.step() {
                // Cut during this quarter's erase: its first half erased.
                let half = start + (end - start) / 2;
                self.bytes[slot][start..half].fill(0xff);
                return Err(ParamError::SaveFailed);
            }
            self.bytes[slot][start..end].fill(0xff);
        }
        for (i, word) in record.chunks(4).enumerate() {
            let powered = self.step();
            let cells = &mut self.bytes[slot][4 * i..4 * i + word.len()];
            // Cut while programming this word: only the low bits of each byte cleared.
            let kept = if powered { 0x00 } else { 0xf0 };
            for (cell, b) in cells.iter_mut().zip(word) {
                *cell &= *b | kept;
            }
            if !powered {
                return Err(ParamError::SaveFailed);
            }
        }
        Ok(())
    }
}

/// A board's parameter storage: one or two slots, each a separately erasable region (a flash
/// sector, a test's buffer) that holds one record at its start. The firmware implements it on
/// its flash; the library decides what is written where and checks what reads back. A store
/// of one slot (`bytes` and `write` alone) saves by erasing its only record first; one of two
/// ([`RecordStore::slots`], [`RecordStore::slot`], [`RecordStore::write_slot`]) always keeps
/// the last complete record.
pub trait RecordStore {
    /// The first slot's bytes from its start (erased bytes read `0xFF`).
    fn bytes(&self) -> &[u8];
    /// Erases the first slot and writes `record` at its start; `SaveFailed` if the flash
    /// refused.
    fn write(&mut self, record: &[u8]) -> Result<(), ParamError>;
    /// Number of slots (1 or 2).
    fn slots(&self) -> usize {
        1
    }
    /// Slot `slot`'s bytes from its start (empty past the last slot).
    fn slot(&self, slot: usize) -> &[u8] {
        if slot == 0 {
            self.bytes()
        } else {
            &[]
        }
    }
    /// Erases slot `slot` and writes `record` at its start; `SaveFailed` if the flash refused
    /// or there is no such slot.
    fn write_slot(&mut self, slot: usize, record: &[u8]) -> Result<(), ParamError> {
        if slot == 0 {
            self.write(record)
        } else {
            Err(ParamError::SaveFailed)
        }
    }
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
fn is_newer(seq: u32, than: u32) -> bool {
    i32::from_le_bytes(seq.wrapping_sub(than).to_le_bytes()) > 0
}

/// Why a link key was not written to a board's storage ([`ParamTable::save_link_key`]).
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
fn encode_values(
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

    #[derive(Debug, Clone, Copy, PartialEq)]
    struct Cfg {
        gain: f32,
        shift: i8,
        lo: u8,
        hi: u8,
    }

    const CFG_DEFAULT: Cfg = Cfg {
        gain: 1.0,
        shift: -2,
        lo: 1,
        hi: 5,
    };

    crate::param_table! {
        CFG_SPECS, CFG_ACCESS: Cfg {
            "gain": F32 ["-"] 0.0, 2.0, true => |c| c.gain;
            "shift": I32 ["px"] -20, 20, true => |c| c.shift;
            "lo": U32 ["-"] 0, 10, true => |c| c.lo;
            "hi": U32 ["-"] 0, 10, false => |c| c.hi;
        }
    }

    const CFG_TABLE: ParamTable<Cfg> = ParamTable {
        specs: CFG_SPECS,
        access: CFG_ACCESS,
        defaults: || CFG_DEFAULT,
        consistent: |c| {
            if c.lo > c.hi {
                Err(Conflict::new("lo", "hi", "must not exceed"))
            } else {
                Ok(())
            }
        },
    };

    #[test]
    fn signed_values_keep_their_sign_bounds_and_bits() {
        let spec = &CFG_SPECS[1];
        assert_eq!(spec.check(ParamValue::I32(-20)), Ok(()));
        assert_eq!(
            spec.check(ParamValue::I32(-21)),
            Err(ParamError::OutOfBounds)
        );
        assert_eq!(spec.check(ParamValue::U32(3)), Err(ParamError::WrongKind));
        for x in [i32::MIN, -1, 0, 7, i32::MAX] {
            let v = ParamValue::I32(x);
            assert_eq!(ParamValue::from_bits(ParamKind::I32, v.to_bits()), Some(v));
        }
        // A narrow field refuses what it cannot hold instead of wrapping.
        assert_eq!(<i8 as ParamField>::from_param(ParamValue::I32(200)), None);
        assert_eq!(
            <i8 as ParamField>::from_param(ParamValue::I32(-7)),
            Some(-7)
        );
        assert_eq!(<u8 as ParamField>::from_param(ParamValue::I32(3)), None);
    }

    #[test]
    fn a_table_sets_checks_and_answers_through_its_accessors() {
        let t = CFG_TABLE;
        let mut c = CFG_DEFAULT;
        t.set_by_name(&mut c, "shift", ParamValue::I32(-9)).unwrap();
        assert_eq!(c.shift, -9);
        let r = t
            .set_by_name(&mut c, "shift", ParamValue::I32(21))
            .unwrap_err();
        assert_eq!((r.name(), r.error), ("shift", ParamError::OutOfBounds));
        assert!(std::format!("{r}").contains("[-20 ..= 20] px"), "{r}");
        let r = t.set_by_name(&mut c, "lo", ParamValue::U32(6)).unwrap_err();
        assert_eq!((r.name(), r.error), ("lo", ParamError::Inconsistent));
        // The reason names both parameters of the pair.
        let why = std::format!("{r}");
        assert!(why.contains("lo must not exceed hi"), "{why}");
        let r = t.set_by_name(&mut c, "hi", ParamValue::U32(9)).unwrap_err();
        assert_eq!(r.error, ParamError::ReadOnly);
        assert_eq!(c.lo, 1);

        // Set answers with the entry in use once `apply` took it; a refusal changes nothing.
        let set = |v| ParamOp::Set(ParamName::try_from("shift").unwrap(), ParamValue::I32(v));
        let mut applied = None;
        let apply = |n| {
            applied = Some(n);
            Ok(())
        };
        match t.answer(&c, &set(4), apply, None) {
            ParamReply::Entry(e) => {
                assert_eq!(
                    (e.value, e.default),
                    (ParamValue::I32(4), ParamValue::I32(-2))
                );
                assert_eq!((e.index, e.count), (1, 4));
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(applied.map(|n| n.shift), Some(4));
        let refused = t.answer(
            &c,
            &set(5),
            |_| Err(Rejected::refused(ParamError::Armed)),
            None,
        );
        assert_eq!(refused, ParamReply::Error(ParamError::Armed));
        assert_eq!(
            t.answer(&c, &ParamOp::List(4), |_| Ok(()), None),
            ParamReply::Error(ParamError::UnknownIndex)
        );
        for op in [ParamOp::Save, ParamOp::Storage] {
            assert_eq!(
                t.answer(&c, &op, |_| Ok(()), None),
                ParamReply::Error(ParamError::NoStorage)
            );
        }

        // A record with a negative value reads back; an inconsistent one means defaults.
        let mut vals = [ParamValue::U32(0); 4];
        assert_eq!(t.values(&c, &mut vals), 4);
        let mut rec = [0xffu8; 64];
        encode_record(CFG_SPECS, &vals, &mut rec).unwrap();
        assert_eq!(t.decode_record(&rec), (c, Ok(())));
        let mut bad = c;
        bad.lo = 9;
        t.values(&bad, &mut vals);
        encode_record(CFG_SPECS, &vals, &mut rec).unwrap();
        assert_eq!(
            t.decode_record(&rec),
            (CFG_DEFAULT, Err(RecordError::BadValue(2)))
        );
    }

    fn save_to(store: &mut MemSlots<64>, status: &mut StorageStatus, c: &Cfg) -> ParamReply {
        CFG_TABLE.save(
            c,
            ParamStorage {
                store,
                status,
                key: None,
            },
        )
    }

    fn with_shift(shift: i8) -> Cfg {
        Cfg {
            shift,
            ..CFG_DEFAULT
        }
    }

    #[test]
    fn a_power_loss_at_any_step_of_a_save_boots_on_the_last_complete_record() {
        let t = CFG_TABLE;
        let steps = MemSlots::<64>::steps_of(record_bytes(CFG_SPECS.len()));
        // Saves 0 and 1 fill both slots; save 2 overwrites the older one (slot 0), and so on:
        // each is cut at every step, each slot is cut in every position.
        for saved in 1..=3u8 {
            for cut in 0..=steps {
                let mut store = MemSlots::<64>::blank();
                let mut status = StorageStatus::booted(Err(RecordError::Blank));
                for k in 0..saved {
                    let c = with_shift(i8::try_from(k).unwrap());
                    assert_eq!(save_to(&mut store, &mut status, &c), ParamReply::Saved);
                }
                let last = with_shift(i8::try_from(saved - 1).unwrap());
                let next = with_shift(-9);
                store.power_steps = Some(cut);
                let reply = save_to(&mut store, &mut status, &next);
                store.power_on();
                let (cfg, boot) = t.load(&store);
                let complete = cut == steps;
                assert_eq!(reply == ParamReply::Saved, complete, "cut at {cut}");
                let expected = if complete { next } else { last };
                assert_eq!(
                    (cfg, boot.loaded),
                    (expected, Ok(())),
                    "saved {saved}, cut at {cut}"
                );
                assert!(!boot.blocks_arming());
                // The save after the reset numbers on from the record the boot took.
                let after = with_shift(7);
                assert_eq!(save_to(&mut store, &mut status, &after), ParamReply::Saved);
                assert_eq!(
                    t.load(&store).0,
                    after,
                    "saved {saved}, cut at {cut}, then saved"
                );
            }
        }
        // The first save ever, cut: nothing complete, so the defaults, and arming blocked
        // unless the cut left the slot blank (cut during the erase, before any word).
        for cut in 0..steps {
            let mut store = MemSlots::<64>::blank();
            let mut status = StorageStatus::booted(Err(RecordError::Blank));
            store.power_steps = Some(cut);
            assert_ne!(
                save_to(&mut store, &mut status, &with_shift(3)),
                ParamReply::Saved
            );
            store.power_on();
            let (cfg, boot) = t.load(&store);
            assert_eq!(cfg, CFG_DEFAULT, "cut at {cut}");
            assert_eq!(
                boot.loaded == Err(RecordError::Blank),
                cut < 4,
                "cut at {cut}"
            );
            assert_eq!(boot.blocks_arming(), cut >= 4, "cut at {cut}");
        }
    }

    const LINK_KEY: KeyRecord = KeyRecord {
        key: crate::signing::LinkKey([0x5A; 32]),
        min_timestamp: 1_234,
    };

    #[test]
    fn a_save_carries_the_link_key_and_a_record_without_one_still_loads() {
        let t = CFG_TABLE;
        let mut store = MemSlots::<128>::blank();
        let mut status = StorageStatus::booted(Err(RecordError::Blank));
        let storage = ParamStorage {
            store: &mut store,
            status: &mut status,
            key: None,
        };
        assert_eq!(t.save(&with_shift(3), storage), ParamReply::Saved);
        assert_eq!(t.load(&store).0, with_shift(3));
        assert_eq!(
            t.load_link_key(&store),
            None,
            "a format-2 record has no key"
        );
        let storage = ParamStorage {
            store: &mut store,
            status: &mut status,
            key: None,
        }
        .with_key(Some(LINK_KEY));
        assert_eq!(t.save(&with_shift(4), storage), ParamReply::Saved);
        let (cfg, boot) = t.load(&store);
        assert_eq!((cfg, boot.loaded), (with_shift(4), Ok(())));
        assert_eq!(t.load_link_key(&store), Some(LINK_KEY));
        assert_eq!(
            record_link_key(store.slot(1)).map(|k| k.is_some()),
            Ok(true)
        );
        // Every bit of the key is covered by the record's CRC.
        let at = record_bytes(CFG_SPECS.len()) - 4;
        for byte in at..at + KEY_RECORD_BYTES {
            let mut damaged = store.clone();
            damaged.bytes[1][byte] ^= 0x04;
            assert_eq!(record_link_key(damaged.slot(1)), Err(RecordError::BadCrc));
            // The older record (no key) is what boots then.
            assert_eq!(t.load(&damaged).0, with_shift(3));
            assert_eq!(t.load_link_key(&damaged), None);
        }
    }

    #[test]
    fn a_key_is_put_beside_the_saved_configuration_in_the_other_slot() {
        let t = CFG_TABLE;
        let mut store = MemSlots::<128>::blank();
        // Erased flash: the defaults and the key, first slot, sequence 1.
        let mut out = [0u8; MAX_RECORD_BYTES];
        let (slot, n) = t.record_with_key(&store, &LINK_KEY, &mut out).unwrap();
        assert_eq!((slot, n), (0, record_bytes(4) + KEY_RECORD_BYTES));
        assert_eq!(record_sequence(&out), Some(1));
        assert_eq!(t.decode_record(&out[..n]), (CFG_DEFAULT, Ok(())));
        // A saved configuration (sequence 1 in slot 0) is kept; the key goes to slot 1 as 2.
        let mut status = StorageStatus::booted(Ok(()));
        assert_eq!(
            save_to_slots(&mut store, &mut status, &with_shift(-5)),
            ParamReply::Saved
        );
        assert_eq!(t.save_link_key(&mut store, &LINK_KEY), Ok(()));
        assert_eq!(record_sequence(store.slot(1)), Some(2));
        assert_eq!(t.load(&store).0, with_shift(-5));
        assert_eq!(t.load_link_key(&store), Some(LINK_KEY));
        // Only bad records: refused with why, nothing written.
        let mut bad = MemSlots::<128>::blank();
        bad.bytes[0][..n].copy_from_slice(&out[..n]);
        bad.bytes[0][20] ^= 1;
        let writes = bad.writes;
        assert_eq!(
            t.save_link_key(&mut bad, &LINK_KEY),
            Err(KeySaveError::Record(RecordError::BadCrc))
        );
        assert_eq!(bad.writes, writes);
    }

    #[test]
    fn the_key_survives_a_table_change_and_a_cut_key_save() {
        let t = CFG_TABLE;
        // A keyed record of another table: the board boots on its defaults but keeps the key.
        let mut store = MemSlots::<128>::blank();
        let narrower = &CFG_SPECS[..3];
        let vals = [ParamValue::F32(1.0), ParamValue::I32(0), ParamValue::U32(1)];
        let n = encode_values(
            narrower,
            vals.into_iter(),
            7,
            Some(&LINK_KEY),
            &mut store.bytes[0],
        );
        assert!(n.is_ok(), "{n:?}");
        assert_eq!(t.load(&store).1.loaded, Err(RecordError::TableChanged));
        assert_eq!(t.load_link_key(&store), Some(LINK_KEY));
        // A key save cut at any step leaves the configuration saved before, with the old key
        // or the new one, never a mixture.
        let mut saved = MemSlots::<128>::blank();
        let mut status = StorageStatus::booted(Ok(()));
        save_to_slots(&mut saved, &mut status, &with_shift(2));
        let steps = MemSlots::<128>::steps_of(record_bytes(4) + KEY_RECORD_BYTES);
        for cut in 0..=steps {
            let mut store = saved.clone();
            store.power_steps = Some(cut);
            let result = t.save_link_key(&mut store, &LINK_KEY);
            store.power_on();
            assert_eq!(t.load(&store).0, with_shift(2), "cut at {cut}");
            let key = t.load_link_key(&store);
            assert_eq!(key.is_some(), result.is_ok(), "cut at {cut}: {result:?}");
        }
    }

    fn save_to_slots(store: &mut MemSlots<128>, status: &mut StorageStatus, c: &Cfg) -> ParamReply {
        CFG_TABLE.save(
            c,
            ParamStorage {
                store,
                status,
                key: None,
            },
        )
    }

    #[test]
    fn the_newest_sequence_number_wins_across_the_wrap() {
        let t = CFG_TABLE;
        let mut vals = [ParamValue::U32(0); 4];
        let mut store = MemSlots::<64>::blank();
        // Slot 0 numbered just before the wrap, slot 1 just after it: slot 1 is newer.
        for (slot, (seq, shift)) in [(u32::MAX, 4), (0, 6)].into_iter().enumerate() {
            t.values(&with_shift(shift), &mut vals);
            let values = vals.iter().copied();
            let n = encode_values(CFG_SPECS, values, seq, None, &mut store.bytes[slot]).unwrap();
            assert_eq!(n, record_bytes(4));
        }
        assert_eq!(t.load(&store).0, with_shift(6));
        let mut status = StorageStatus::booted(Ok(()));
        assert_eq!(
            save_to(&mut store, &mut status, &with_shift(8)),
            ParamReply::Saved
        );
        assert_eq!(
            record_sequence(&store.bytes[0]),
            Some(1),
            "written over the older slot"
        );
        assert_eq!(t.load(&store).0, with_shift(8));
    }

    #[test]
    fn a_failed_load_blocks_arming_until_acknowledged_or_saved() {
        let t = CFG_TABLE;
        let mut store = MemSlots::<64>::blank();
        let mut status = StorageStatus::booted(Err(RecordError::Blank));
        assert!(
            !status.blocks_arming(),
            "a board never saved flies its defaults"
        );
        save_to(&mut store, &mut status, &with_shift(5));
        // Both slots unreadable (the only record corrupted): the defaults, blocked.
        store.bytes[0][20] ^= 0x01;
        let (cfg, mut boot) = t.load(&store);
        assert_eq!((cfg, boot.loaded), (CFG_DEFAULT, Err(RecordError::BadCrc)));
        assert!(boot.blocks_arming());
        let storage = ParamStorage {
            store: &mut store,
            status: &mut boot,
            key: None,
        };
        let reply = t.answer(&cfg, &ParamOp::Acknowledge, |_| Ok(()), Some(storage));
        assert!(matches!(reply, ParamReply::Storage(s) if s.acknowledged));
        assert!(!boot.blocks_arming());
        // A save clears it too.
        let (_, mut boot) = t.load(&store);
        assert_eq!(save_to(&mut store, &mut boot, &cfg), ParamReply::Saved);
        assert!(!boot.blocks_arming());
        assert_eq!(t.load(&store).1.loaded, Ok(()));
    }

    #[test]
    fn a_table_saves_to_its_store_and_loads_back() {
        let t = CFG_TABLE;
        let mut store = MemStore::<64>::blank();
        let (c, mut status) = t.load(&store);
        assert_eq!((c, status.loaded), (CFG_DEFAULT, Err(RecordError::Blank)));
        let mut c = CFG_DEFAULT;
        t.set_by_name(&mut c, "shift", ParamValue::I32(-7)).unwrap();
        fn answer(
            c: &Cfg,
            op: &ParamOp,
            store: &mut MemStore<64>,
            status: &mut StorageStatus,
        ) -> ParamReply {
            let storage = ParamStorage {
                store,
                status,
                key: None,
            };
            CFG_TABLE.answer(c, op, |_| Ok(()), Some(storage))
        }
        assert_eq!(
            answer(&c, &ParamOp::Save, &mut store, &mut status),
            ParamReply::Saved
        );
        assert_eq!(
            answer(&c, &ParamOp::Storage, &mut store, &mut status),
            ParamReply::Storage(StorageStatus {
                loaded: Err(RecordError::Blank),
                saves: 1,
                failed_saves: 0,
                acknowledged: false,
            })
        );
        // The next boot loads the saved values and says so.
        let (loaded, next) = t.load(&store);
        assert_eq!((loaded, next.loaded, next.saves), (c, Ok(()), 0));

        // A store that refuses is a failed save, counted; the old record stays.
        store.refuse = true;
        assert_eq!(
            answer(&CFG_DEFAULT, &ParamOp::Save, &mut store, &mut status),
            ParamReply::Error(ParamError::SaveFailed)
        );
        assert_eq!((status.saves, status.failed_saves), (1, 1));
        assert_eq!(t.load(&store).0, c);

        // A corrupt record: the defaults, and why.
        store.bytes[20] ^= 0x04;
        assert_eq!(
            t.load(&store),
            (
                CFG_DEFAULT,
                StorageStatus {
                    loaded: Err(RecordError::BadCrc),
                    saves: 0,
                    failed_saves: 0,
                    acknowledged: false,
                }
            )
        );
        // The table's record and the free function's are the same bytes.
        let mut vals = [ParamValue::U32(0); 4];
        t.values(&c, &mut vals);
        let (mut a, mut b) = ([0u8; 40], [0u8; 40]);
        assert_eq!(t.encode_record(&c, &mut a), Ok(record_bytes(4)));
        assert_eq!(encode_record(CFG_SPECS, &vals, &mut b), Ok(record_bytes(4)));
        assert_eq!(a, b);
        assert_eq!(
            t.encode_record(&c, &mut a[..record_bytes(4) - 1]),
            Err(RecordError::Length)
        );
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
        use crate::{
            encode, AutopilotToStereo, BoardToHost, HostToBoard, Message, StereoToAutopilot,
        };
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
        let BoardToHost::Param(response) = answer else {
            unreachable!()
        };
        let n = encode(&StereoToAutopilot::Param(response), &mut buf).unwrap();
        assert!(n <= StereoToAutopilot::MAX_FRAME_BYTES, "{n} bytes");
        let req = ParamRequest {
            board: Node::StereoBoard,
            op: ParamOp::Set(name, big),
        };
        let n = encode(&HostToBoard::Param(req.clone()), &mut buf).unwrap();
        assert!(n <= HostToBoard::MAX_FRAME_BYTES, "{n} bytes");
        let n = encode(&AutopilotToStereo::Param(req), &mut buf).unwrap();
        assert!(n <= AutopilotToStereo::MAX_FRAME_BYTES, "{n} bytes");
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
