//! The boards' flash beside the firmware: the two parameter slots (sector 11, 128 KiB at
//! `0x080E_0000`, and sector 10 at `0x080C_0000`, reserved by both firmwares' `memory.x`), and
//! what of the flash interface the bench models.
//!
//! rigless 0.4.0's flash interface model (`soc::stm32f427::peripherals::flash`) answers the
//! registers: the `KEYR` unlock sequence (a wrong key locks `CR` until reset, told to the
//! session), `CR` frozen while locked, a sector erase (`SER`, `SNB`, `STRT`) holding `BSY` for
//! the datasheet's typical erase time of the sector at its `PSIZE` (DS9405 table 48: 1 s for a
//! 128 KiB sector at x32), `PG` and `PSIZE` stored, the error flags from register state, `ACR`
//! with `DCRST` held while `DCEN` is set. It does not model the array itself (its own notes:
//! "programming needs a way for a model to write the array, which is still to come"): a store
//! into flash is dropped, an erase leaves the bytes as they were, and the runtime's
//! programmed-region path (`Region::programmed_by`) is not named by the F427's memory map,
//! which neither our [`crate::soc::Soc`] nor a board can change. So within one run a firmware
//! reads back what the run started with, never what it programmed.
//!
//! What the bench does model is what a power cycle keeps: a board's [`FlashContents`] are
//! placed in flash before the first instruction ([`crate::bench::BenchBoard::flash_contents`]),
//! as the firmware finds a sector it saved on an earlier power-up. Tests put a record there
//! (encoded by the board library's own `params::encode_record`, the bytes its save programs),
//! or a corrupted one, and check what the unmodified image boots with.

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
