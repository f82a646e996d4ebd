//! The boards' flash beside the firmware: the two parameter slots (sector 11, 128 KiB at
//! `0x080E_0000`, and sector 10 at `0x080C_0000`, reserved by both firmwares' `memory.x`), what
//! of the flash interface the bench models, and the array a save leaves when the power is cut.
//!
//! rigless 0.4.0's flash interface model (`soc::stm32f427::peripherals::flash`) answers the
//! registers: the `KEYR` unlock sequence (a wrong key locks `CR` until reset, told to the
//! session), `CR` frozen while locked, a sector erase (`SER`, `SNB`, `STRT`) holding `BSY` for
//! the datasheet's typical erase time of the sector at its `PSIZE` (DS9405 table 48: 1 s for a
//! 128 KiB sector at x32), `PG` and `PSIZE` stored, the error flags from register state, `ACR`
//! with `DCRST` held while `DCEN` is set. It does not model the array itself (its own notes:
//! "programming needs a way for a model to write the array, which is still to come"): a store
//! into flash is dropped, an erase leaves the bytes as they were. Nor can our
//! [`crate::soc::Soc`] program it: the runtime lands a model's `DeviceContext::program` only in
//! a region that names the model (`Region::programmed_by`), the F427's memory map names none
//! for its 2 MiB array, a board cannot replace or overlap that region (`Bus::add_region` refuses
//! an overlap, and the map is the private part of rigless's bus description), and a host's
//! write into memory the core maps read-only is refused. A dropped store reaches no model and
//! no driver with its value. So within one run a firmware reads back what the run started
//! with, never what it programmed, and its save's read-back answers `SaveFailed`.
//!
//! What the bench does model is what a power cycle keeps: a board's [`FlashContents`] are
//! placed in flash before the first instruction ([`crate::bench::BenchBoard::flash_contents`]),
//! as the firmware finds a sector it saved on an earlier power-up. Tests put a record there
//! (encoded by the board library's own `params::encode_record`, the bytes its save programs),
//! or a corrupted one, and check what the unmodified image boots with.
//!
//! [`FlashArray`] is the two slots' array as RM0090 section 3.6 programs it, behind the board
//! libraries' [`RecordStore`]: a sector erase sets the sector to `0xFF`; a word programmed at
//! x32 lands as the bits the cells held and the new word both leave at 0 (programming only
//! clears bits, 3.6.4), and a word that needed a bit set again is refused as the save's
//! failure. A [`PowerCut`] stops the array at a chosen instant of a save (mid-erase, between the
//! erase and the first word, after `n` words, after the last word before the read-back), and
//! [`FlashArray::contents`] hands the array as it was left to the next power-up. The save
//! sequence itself is the library's (`ParamTable::save`, the code the images run, slot choice,
//! sequence number and read-back), compiled for the host.

use protocol::ParamError;
use protocol::params::RecordStore;

/// First address of the parameter sector (the first slot, sector 11).
pub const PARAM_SECTOR: u64 = 0x080E_0000;
/// First address of the second parameter slot (sector 10).
pub const PARAM_SECTOR_2: u64 = 0x080C_0000;
/// Bytes of each parameter sector.
pub const PARAM_SECTOR_BYTES: usize = 128 * 1024;

/// What a board's flash holds at power-on beside the firmware image.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct FlashContents {
    placed: Vec<(u64, Vec<u8>)>,
}

impl FlashContents {
    /// Erased flash beside the image (what a new board has).
    #[must_use]
    pub fn erased() -> Self {
        Self::default()
    }

    /// The parameter sector holding `bytes` from its start, erased (`0xFF`) after them.
    ///
    /// # Panics
    /// If `bytes` is longer than the sector (a test bug).
    #[must_use]
    pub fn param_sector(bytes: &[u8]) -> Self {
        assert!(bytes.len() <= PARAM_SECTOR_BYTES, "longer than the sector");
        let mut sector = vec![0xff; PARAM_SECTOR_BYTES];
        sector[..bytes.len()].copy_from_slice(bytes);
        Self {
            placed: vec![(PARAM_SECTOR, sector)],
        }
    }

    /// Both parameter slots: sector 11 holding `first` from its start and sector 10 holding
    /// `second`, each erased (`0xFF`) after its bytes (what a save into one slot, complete or
    /// cut short, leaves beside the other).
    ///
    /// # Panics
    /// If either is longer than a sector (a test bug).
    #[must_use]
    pub fn param_slots(first: &[u8], second: &[u8]) -> Self {
        assert!(second.len() <= PARAM_SECTOR_BYTES, "longer than the sector");
        let mut slots = Self::param_sector(first);
        let mut sector = vec![0xff; PARAM_SECTOR_BYTES];
        sector[..second.len()].copy_from_slice(second);
        slots.placed.push((PARAM_SECTOR_2, sector));
        slots
    }

    /// Every range placed, `(address, bytes)`.
    #[must_use]
    pub fn ranges(&self) -> &[(u64, Vec<u8>)] {
        &self.placed
    }
}

/// Typical time of a 128 KiB sector erase at x32, ns (DS9405 table 48), the time rigless's
/// model holds `BSY`.
pub const SECTOR_ERASE_NS: u64 = 1_000_000_000;
/// Typical time to program one word at x32, ns (DS9405 table 48).
pub const WORD_PROGRAM_NS: u64 = 16_000;

/// An instant of a save at which the board loses its supply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PowerCut {
    /// Before the erase starts: the slot as it was.
    BeforeErase,
    /// During the erase. RM0090 3.6 leaves a sector's contents undefined after a reset during an
    /// operation; the array here is left with every other bit of the sector erased (each byte
    /// ORed with `0x55`): what it held neither intact nor blank.
    MidErase,
    /// After the erase, before the first word is programmed: the slot erased.
    AfterErase,
    /// After this many words of the record are programmed (the rest erased).
    AfterWords(usize),
    /// After the last word is programmed, before the save reads the record back.
    BeforeVerify,
}

/// The two parameter slots' array: slot 0 is sector 11 (`0x080E_0000`), slot 1 sector 10
/// (`0x080C_0000`), the firmwares' order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FlashArray {
    slots: [Vec<u8>; 2],
    cut: Option<PowerCut>,
    powered: bool,
    busy_ns: u64,
    words_programmed: usize,
}

impl FlashArray {
    /// Both slots erased (a new board).
    #[must_use]
    pub fn erased() -> Self {
        Self::with_slots(&[], &[])
    }

    /// Slot 0 holding `first` from its start and slot 1 `second`, each erased after its bytes.
    ///
    /// # Panics
    /// If either is longer than a sector (a test bug).
    #[must_use]
    pub fn with_slots(first: &[u8], second: &[u8]) -> Self {
        let sector = |bytes: &[u8]| {
            assert!(bytes.len() <= PARAM_SECTOR_BYTES, "longer than the sector");
            let mut sector = vec![0xff; PARAM_SECTOR_BYTES];
            sector[..bytes.len()].copy_from_slice(bytes);
            sector
        };
        Self {
            slots: [sector(first), sector(second)],
            cut: None,
            powered: true,
            busy_ns: 0,
            words_programmed: 0,
        }
    }

    /// Cuts the supply at `cut` of the next save.
    #[must_use]
    pub fn cut_at(self, cut: PowerCut) -> Self {
        Self {
            cut: Some(cut),
            ..self
        }
    }

    /// Whether the supply is still on (no cut reached).
    #[must_use]
    pub fn powered(&self) -> bool {
        self.powered
    }

    /// Time the array held `BSY` so far (erases and words), ns.
    #[must_use]
    pub fn busy_ns(&self) -> u64 {
        self.busy_ns
    }

    /// Words programmed so far.
    #[must_use]
    pub fn words_programmed(&self) -> usize {
        self.words_programmed
    }

    /// The array as it is, as the flash a board finds at its next power-up.
    #[must_use]
    pub fn contents(&self) -> FlashContents {
        FlashContents::param_slots(&self.slots[0], &self.slots[1])
    }

    /// Slot `slot`'s sector as it is.
    #[must_use]
    pub fn sector(&self, slot: usize) -> &[u8] {
        self.slots.get(slot).map_or(&[], Vec::as_slice)
    }

    /// Erases slot `slot`'s sector (RM0090 3.6.3): every byte `0xFF` after the erase time.
    fn erase(&mut self, slot: usize) {
        if self.cut == Some(PowerCut::MidErase) {
            self.slots[slot].iter_mut().for_each(|b| *b |= 0x55);
            self.busy_ns += SECTOR_ERASE_NS / 2;
            self.powered = false;
            return;
        }
        self.slots[slot].fill(0xff);
        self.busy_ns += SECTOR_ERASE_NS;
    }

    /// Programs the word at byte `offset` of slot `slot` (RM0090 3.6.4, x32): the cells keep a
    /// bit at 0 that either the array or `value` has at 0. `Err` when `value` needed a bit the
    /// array holds at 0 set again (only an erase sets bits).
    fn program_word(&mut self, slot: usize, offset: usize, value: u32) -> Result<(), ()> {
        let cells = &mut self.slots[slot][offset..offset + 4];
        let held = u32::from_le_bytes([cells[0], cells[1], cells[2], cells[3]]);
        let landed = held & value;
        cells.copy_from_slice(&landed.to_le_bytes());
        self.busy_ns += WORD_PROGRAM_NS;
        self.words_programmed += 1;
        if landed == value { Ok(()) } else { Err(()) }
    }

    /// Whether the supply is cut before anything of this step happens.
    fn cut_before(&mut self, step: PowerCut) -> bool {
        if self.powered && self.cut == Some(step) {
            self.powered = false;
        }
        !self.powered
    }
}

impl RecordStore for FlashArray {
    fn bytes(&self) -> &[u8] {
        self.sector(0)
    }

    fn write(&mut self, record: &[u8]) -> Result<(), ParamError> {
        self.write_slot(0, record)
    }

    fn slots(&self) -> usize {
        self.slots.len()
    }

    fn slot(&self, slot: usize) -> &[u8] {
        self.sector(slot)
    }

    /// The firmwares' sequence (board-support's `ParamSector`): erase the slot's sector,
    /// then program the record a word at a time; stopped where the [`PowerCut`] falls.
    fn write_slot(&mut self, slot: usize, record: &[u8]) -> Result<(), ParamError> {
        if slot >= self.slots.len()
            || record.len() > PARAM_SECTOR_BYTES
            || !record.len().is_multiple_of(4)
            || self.cut_before(PowerCut::BeforeErase)
        {
            return Err(ParamError::SaveFailed);
        }
        self.erase(slot);
        if !self.powered || self.cut_before(PowerCut::AfterErase) {
            return Err(ParamError::SaveFailed);
        }
        for (i, word) in record.chunks_exact(4).enumerate() {
            if self.cut_before(PowerCut::AfterWords(i)) {
                return Err(ParamError::SaveFailed);
            }
            let value = u32::from_le_bytes([word[0], word[1], word[2], word[3]]);
            self.program_word(slot, 4 * i, value)
                .map_err(|()| ParamError::SaveFailed)?;
        }
        if self.cut_before(PowerCut::AfterWords(record.len() / 4))
            || self.cut_before(PowerCut::BeforeVerify)
        {
            return Err(ParamError::SaveFailed);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_erase_sets_every_byte_and_programming_only_clears_bits() {
        let mut array = FlashArray::with_slots(&[0x0f, 0xf0, 0x00, 0xff], &[]);
        assert_eq!(array.program_word(0, 0, 0xffff_ffff), Err(()));
        assert_eq!(&array.sector(0)[..4], &[0x0f, 0xf0, 0x00, 0xff]);
        assert_eq!(array.program_word(0, 4, 0x1234_5678), Ok(()));
        assert_eq!(&array.sector(0)[4..8], &0x1234_5678_u32.to_le_bytes());
        // Over a programmed word, only the bits both leave at 0.
        assert_eq!(array.program_word(0, 4, 0x0000_00ff), Err(()));
        assert_eq!(&array.sector(0)[4..8], &0x0000_0078_u32.to_le_bytes());
        array.erase(0);
        assert!(array.sector(0).iter().all(|&b| b == 0xff));
        assert_eq!(array.busy_ns(), SECTOR_ERASE_NS + 3 * WORD_PROGRAM_NS);
    }

    #[test]
    fn a_write_erases_then_programs_and_a_cut_stops_it_where_it_falls() {
        let record: Vec<u8> = (0..16u8).collect();
        let mut array = FlashArray::with_slots(&[0u8; 32], &[]);
        assert_eq!(array.write_slot(0, &record), Ok(()));
        assert_eq!(&array.sector(0)[..16], &record[..]);
        assert!(array.sector(0)[16..].iter().all(|&b| b == 0xff));

        let old = [0u8; 32];
        let cut = |cut| {
            let mut array = FlashArray::with_slots(&old, &[]).cut_at(cut);
            assert_eq!(array.write_slot(0, &record), Err(ParamError::SaveFailed));
            assert!(!array.powered());
            array
        };
        assert_eq!(&cut(PowerCut::BeforeErase).sector(0)[..32], &old[..]);
        let mid = cut(PowerCut::MidErase);
        assert!(mid.sector(0)[..32].iter().all(|&b| b == 0x55));
        assert!(mid.sector(0)[32..].iter().all(|&b| b == 0xff));
        assert!(
            cut(PowerCut::AfterErase)
                .sector(0)
                .iter()
                .all(|&b| b == 0xff)
        );
        let two = cut(PowerCut::AfterWords(2));
        assert_eq!(&two.sector(0)[..8], &record[..8]);
        assert!(two.sector(0)[8..].iter().all(|&b| b == 0xff));
        assert_eq!(&cut(PowerCut::BeforeVerify).sector(0)[..16], &record[..]);
    }
}
