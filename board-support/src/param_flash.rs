//! The parameter sectors: the last two sectors of the 1 MiB flash of both boards' parts
//! (sectors 11 and 10, 128 KiB each at `0x080E_0000` and `0x080C_0000`, RM0090 table 5), kept
//! out of the firmware by each `memory.x`, and erased and programmed through the flash
//! interface's registers (RM0090 sections 3.5-3.6).
//!
//! [`ParamSector`] is a two-slot [`protocol::params::RecordStore`] (slot 0 is sector 11, slot 1
//! sector 10; erase is per sector, so each slot erases alone): the board's library decides which
//! slot a save writes (the one not holding the newest record), numbers the record and checks
//! what reads back, so a power loss at any point of a save leaves the last complete record in
//! the other sector. A write erases its sector (x32 parallelism, the 2.7-3.6 V
//! row of RM0090 table 13; DS8626 / DS8597: 1 s typical, 2 s at most for a 128 KiB sector) and
//! programs the record a word at a time (16 µs typical each). While the flash erases or programs
//! no code or data can be fetched from it (RM0090 3.5.4 / 3.6.3): the whole core stalls, every
//! task and interrupt with it, which is why a save is only made on the ground. The waits poll
//! `BSY` (the F405's device crate names no flash interrupt to wait on).
//!
//! Registers, not `stm32f4xx_hal::flash`: its `UnlockedFlash` erases and programs at x8
//! parallelism (twice the erase time of x32 on DS8626's table, and four program operations a
//! word) and asserts (panics) when the unlock sequence fails; a firmware here never panics.
//! After a write the data cache is reset (RM0090 3.5.2: it may hold lines of the erased sector).

use crate::watchdog::{self, Timeout};
use protocol::params::{ParamError, RecordStore};
use stm32f4xx_hal::pac::FLASH;

/// First address of slot 0, sector 11 (RM0090 table 5).
pub const BASE: usize = 0x080E_0000;
/// Bytes of each slot (one 128 KiB sector).
pub const SIZE: usize = 128 * 1024;
/// Slot 0's sector number (`FLASH_CR.SNB`).
pub const SECTOR: u8 = 11;
/// The slots: (first address, sector number), slot 0 first. Sector 11 is slot 0 so a record
/// saved in it before the second slot existed is still found.
pub const SLOTS: [(usize, u8); 2] = [(BASE, SECTOR), (0x080C_0000, 10)];

/// RM0090 3.9.2: the unlock keys of `FLASH_CR`.
const KEY1: u32 = 0x4567_0123;
const KEY2: u32 = 0xCDEF_89AB;
/// `FLASH_SR` error flags (PGSERR, PGPERR, PGAERR, WRPERR, OPERR) and EOP, write-1-to-clear.
const SR_ERRORS: u32 = (1 << 7) | (1 << 6) | (1 << 5) | (1 << 4) | (1 << 1);
const SR_EOP: u32 = 1 << 0;
/// Core cycles between two reads of `BSY` (6 µs at 168 MHz).
const POLL_CYCLES: u32 = 1_000;

/// Why the flash refused an erase or a program (the `FLASH_SR` flag, RM0090 3.9.4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, defmt::Format)]
pub enum FlashError {
    /// The unlock sequence did not clear `LOCK` (locked until reset).
    Locked,
    /// The record is longer than the sector, or not a whole number of words.
    Length,
    /// `PGSERR`: programming sequence error.
    Sequence,
    /// `PGPERR`: the access size does not match `PSIZE`.
    Parallelism,
    /// `PGAERR`: alignment.
    Alignment,
    /// `WRPERR`: the sector is write-protected.
    WriteProtected,
    /// `OPERR` alone.
    Operation,
}

/// The two parameter sectors and the flash interface that writes them.
pub struct ParamSector {
    flash: FLASH,
    /// The flash error of the last write, for the log.
    last_error: Option<FlashError>,
}

impl ParamSector {
    /// Takes the flash interface (nothing else in the firmware uses it after the clock set-up).
    pub fn new(flash: FLASH) -> Self {
        Self {
            flash,
            last_error: None,
        }
    }

    /// Why the last write failed, if it did.
    pub fn last_error(&self) -> Option<FlashError> {
        self.last_error
    }

    /// Waits for the operation under way to end.
    fn wait(&self) {
        while self.flash.sr().read().bsy().bit_is_set() {
            cortex_m::asm::delay(POLL_CYCLES);
        }
    }

    fn error(&self) -> Option<FlashError> {
        let sr = self.flash.sr().read();
        if sr.pgserr().bit_is_set() {
            Some(FlashError::Sequence)
        } else if sr.pgperr().bit_is_set() {
            Some(FlashError::Parallelism)
        } else if sr.pgaerr().bit_is_set() {
            Some(FlashError::Alignment)
        } else if sr.wrperr().bit_is_set() {
            Some(FlashError::WriteProtected)
        } else if sr.operr().bit_is_set() {
            Some(FlashError::Operation)
        } else {
            None
        }
    }

    fn unlock(&mut self) -> Result<(), FlashError> {
        if self.flash.cr().read().lock().bit_is_set() {
            // SAFETY: KEYR takes any 32-bit value; these are RM0090 3.9.2's two keys in order.
            self.flash.keyr().write(|w| unsafe { w.key().bits(KEY1) });
            // SAFETY: as above, the second key.
            self.flash.keyr().write(|w| unsafe { w.key().bits(KEY2) });
        }
        if self.flash.cr().read().lock().bit_is_set() {
            Err(FlashError::Locked)
        } else {
            Ok(())
        }
    }

    /// Erases sector `sector` and programs `record` at its start `base`, a word at a time;
    /// `LOCK` is set again whatever happened.
    fn erase_and_program(
        &mut self,
        (base, sector): (usize, u8),
        record: &[u8],
    ) -> Result<(), FlashError> {
        if record.len() > SIZE || !record.len().is_multiple_of(4) {
            return Err(FlashError::Length);
        }
        self.wait();
        self.unlock()?;
        // SAFETY: writing 1s to SR's error and EOP flags only clears them (write-1-to-clear).
        self.flash
            .sr()
            .write(|w| unsafe { w.bits(SR_ERRORS | SR_EOP) });
        let result = self.erase(sector).and_then(|()| self.program(base, record));
        self.flash.cr().modify(|_, w| w.lock().set_bit());
        self.reset_data_cache();
        result
    }

    fn erase(&mut self, sector: u8) -> Result<(), FlashError> {
        // `modify`, never `write`: a write starts from CR's reset value, whose LOCK is set.
        // SAFETY: SNB takes a sector number; `sector` is one of SLOTS', which hold no code.
        self.flash.cr().modify(|_, w| unsafe {
            w.pg().clear_bit().mer().clear_bit().psize().psize32();
            w.ser().set_bit().snb().bits(sector)
        });
        self.flash.cr().modify(|_, w| w.strt().set_bit());
        self.wait();
        self.flash.cr().modify(|_, w| w.ser().clear_bit());
        self.error().map_or(Ok(()), Err)
    }

    fn program(&mut self, base: usize, record: &[u8]) -> Result<(), FlashError> {
        self.flash
            .cr()
            .modify(|_, w| w.ser().clear_bit().psize().psize32().pg().set_bit());
        for (i, word) in record.chunks_exact(4).enumerate() {
            let value = u32::from_le_bytes([word[0], word[1], word[2], word[3]]);
            // SAFETY: the address is word-aligned and inside a parameter sector (`base` is one of
            // SLOTS', the length was checked against SIZE), which memory.x keeps free of code
            // and data; with PG set
            // a word store there is a program operation (RM0090 3.6.4), at the PSIZE set above.
            unsafe { core::ptr::write_volatile((base + 4 * i) as *mut u32, value) };
            self.wait();
            if let Some(e) = self.error() {
                self.flash.cr().modify(|_, w| w.pg().clear_bit());
                return Err(e);
            }
        }
        self.flash.cr().modify(|_, w| w.pg().clear_bit());
        Ok(())
    }

    /// RM0090 3.5.2: the data cache may hold lines of the sector as it was; `DCRST` is written
    /// with the cache disabled.
    fn reset_data_cache(&mut self) {
        let was_on = self.flash.acr().read().dcen().bit_is_set();
        self.flash.acr().modify(|_, w| w.dcen().clear_bit());
        self.flash.acr().modify(|_, w| w.dcrst().set_bit());
        self.flash.acr().modify(|_, w| w.dcrst().clear_bit());
        if was_on {
            self.flash.acr().modify(|_, w| w.dcen().set_bit());
        }
    }
}

impl RecordStore for ParamSector {
    fn bytes(&self) -> &[u8] {
        self.slot(0)
    }

    fn write(&mut self, record: &[u8]) -> Result<(), ParamError> {
        self.write_slot(0, record)
    }

    fn slots(&self) -> usize {
        SLOTS.len()
    }

    fn slot(&self, slot: usize) -> &[u8] {
        match SLOTS.get(slot) {
            // SAFETY: the sectors are always mapped (RM0090 2.3), memory.x places nothing in
            // them, and they only change in `write_slot`, which takes `&mut self` and so cannot
            // run while this borrow lives.
            Some(&(base, _)) => unsafe { core::slice::from_raw_parts(base as *const u8, SIZE) },
            None => &[],
        }
    }

    fn write_slot(&mut self, slot: usize, record: &[u8]) -> Result<(), ParamError> {
        let Some(&sector) = SLOTS.get(slot) else {
            return Err(ParamError::SaveFailed);
        };
        let result = self.erase_and_program(sector, record);
        self.last_error = result.err();
        result.map_err(|_| ParamError::SaveFailed)
    }
}

/// The parameter sector with the board's watchdog, the one way both boards save: a write runs
/// under [`watchdog::SAVE`] (the flash stalls the core, nothing feeds the watchdog meanwhile)
/// and the board's own timeout is given back after it. Passed as the
/// [`protocol::params::RecordStore`] of the boards' libraries, it programs the watchdog only
/// when they write.
pub struct WatchedSector<'a, F: FnMut(Timeout)> {
    sector: &'a mut ParamSector,
    own: Timeout,
    program: F,
}

impl<'a, F: FnMut(Timeout)> WatchedSector<'a, F> {
    /// `sector` under the board's watchdog: `program` programs a timeout into it
    /// ([`watchdog::set`], under the firmware's lock); `own` is the board's own timeout.
    pub fn new(sector: &'a mut ParamSector, own: Timeout, program: F) -> Self {
        Self {
            sector,
            own,
            program,
        }
    }
}

impl<F: FnMut(Timeout)> RecordStore for WatchedSector<'_, F> {
    fn bytes(&self) -> &[u8] {
        self.sector.bytes()
    }

    fn write(&mut self, record: &[u8]) -> Result<(), ParamError> {
        self.write_slot(0, record)
    }

    fn slots(&self) -> usize {
        self.sector.slots()
    }

    fn slot(&self, slot: usize) -> &[u8] {
        self.sector.slot(slot)
    }

    fn write_slot(&mut self, slot: usize, record: &[u8]) -> Result<(), ParamError> {
        (self.program)(watchdog::SAVE);
        let result = self.sector.write_slot(slot, record);
        (self.program)(self.own);
        result
    }
}
