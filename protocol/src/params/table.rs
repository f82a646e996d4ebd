//! A board's parameter table over its configuration type: the accessors the
//! [`crate::param_table!`] macro declares, and [`ParamTable`], which checks, writes, answers,
//! saves and loads through them.

use super::error::ParamError;
use super::record::{
    decode_record, encode_values, is_newer, record_link_key, record_sequence, KeySaveError,
    RecordError, MAX_RECORD_BYTES,
};
use super::store::{ParamStorage, RecordStore, StorageStatus};
use super::value::{find_param, table_hash, ParamSpec, ParamValue};
use super::wire::{ParamEntry, ParamOp, ParamReply, ParamRequest, ParamResponse};
use crate::envelope::KeyRecord;
use crate::Node;

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
    ///
    /// [`encode_record`]: super::encode_record
    /// [`record_bytes`]: super::record_bytes
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

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::envelope::KEY_RECORD_BYTES;
    use crate::params::fixtures::{Cfg, CFG_DEFAULT, CFG_SPECS, CFG_TABLE};
    use crate::params::record::{encode_record, record_bytes};
    use crate::params::store::{MemSlots, MemStore};
    use crate::params::value::ParamName;

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
}
