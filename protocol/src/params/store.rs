//! Where a board's record is kept: the [`RecordStore`] of one or two flash slots, the
//! in-memory stores that stand in for flash on the host ([`MemStore`], [`MemSlots`]), and the
//! [`ParamStorage`] a table saves through, with its [`StorageStatus`].

use serde::{Deserialize, Serialize};

use super::error::ParamError;
use super::record::RecordError;
use crate::envelope::KeyRecord;

/// What a board's parameter storage says (the answer to [`ParamOp::Storage`]).
///
/// [`ParamOp::Storage`]: super::ParamOp::Storage
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
    ///
    /// [`ParamOp::Acknowledge`]: super::ParamOp::Acknowledge
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
///
/// [`ParamTable::answer`]: super::ParamTable::answer
/// [`ParamTable::save`]: super::ParamTable::save
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
