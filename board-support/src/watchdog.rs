//! The independent watchdog's timeout across the LSI's spread, and task liveness stamps for a
//! feeder that must starve when any watched task hangs.
//!
//! The independent watchdog counts LSI cycles: 17 to 47 kHz on the STM32F405/407/415
//! (DS8626 table 41, LSI characteristics), so one programmed prescaler and reload is a time
//! that varies 2.8-fold from part to part and with temperature. A [`Timeout`] is chosen for one
//! end of that spread ([`Timeout::within_ms`]) and states its time at any LSI
//! ([`Timeout::us_at`]), so a firmware can promise a bound at the slowest LSI and check its
//! feeding period against the fastest.
//!
//! The boards' timeouts:
//!
//! | timeout | whose | fed by |
//! |---|---|---|
//! | [`HEARTBEAT_FED`], 2 s | the camera board (every flavour); the autopilot's lockstep flavours (`hil`, `qemu`) | the board's 1 Hz task |
//! | `autopilot::board::WATCHDOG`, 50 ms with its guidance window at the slowest LSI | the autopilot's `real` flavour | the 512 Hz control loop, while its guidance task and heartbeat run |
//! | [`SAVE`], 6 s | both boards, while a parameter save erases and programs flash | nobody (the core stalls) |
//!
//! The autopilot's real flavour needs the short one: a hung firmware must not keep the motors
//! running (a drone falls 1.2 cm in 50 ms). The camera board drives no actuator, and in the
//! lockstep flavours the world clock (and with it the autopilot's periodic tasks) may stall
//! while the host computes, so a 1 Hz task on the board clock feeds those.

use core::sync::atomic::{AtomicU32, Ordering};
use timebase::{Duration, Instant};

/// The slowest LSI of the datasheets, Hz (DS8626 table 41).
pub const LSI_HZ_SLOWEST: u32 = 17_000;
/// The typical LSI, Hz (what the HAL computes its timeouts at).
pub const LSI_HZ_TYPICAL: u32 = 32_000;
/// The fastest LSI of the datasheets, Hz.
pub const LSI_HZ_FASTEST: u32 = 47_000;

/// The prescaler dividers `IWDG_PR` selects, in register order (RM0090 21.4.2).
const DIVIDERS: [u32; 7] = [4, 8, 16, 32, 64, 128, 256];
/// Counts the 12-bit reload can hold (`IWDG_RLR` + 1).
const MAX_COUNTS: u32 = 1 << 12;

/// A programmed independent-watchdog timeout: prescaler and reload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Timeout {
    /// `IWDG_PR`: the divider's index in [`DIVIDERS`].
    prescaler: u8,
    /// `IWDG_RLR`: the counter counts `reload + 1` prescaled cycles.
    reload: u16,
}

impl Timeout {
    /// The longest timeout that lasts at most `ms` when the LSI runs at `lsi_hz` (the finest
    /// prescaler that reaches it). Clamped to the longest the watchdog has (4096 x 256
    /// cycles) and to one prescaled cycle at the shortest.
    pub const fn within_ms(ms: u32, lsi_hz: u32) -> Self {
        let cycles = ms as u64 * lsi_hz as u64 / 1_000;
        let mut prescaler = 0;
        while prescaler + 1 < DIVIDERS.len()
            && cycles / DIVIDERS[prescaler] as u64 > MAX_COUNTS as u64
        {
            prescaler += 1;
        }
        let mut counts = cycles / DIVIDERS[prescaler] as u64;
        if counts > MAX_COUNTS as u64 {
            counts = MAX_COUNTS as u64;
        }
        if counts == 0 {
            counts = 1;
        }
        Self {
            prescaler: prescaler as u8,
            reload: (counts - 1) as u16,
        }
    }

    /// LSI cycles from a feed to the reset.
    pub const fn lsi_cycles(self) -> u32 {
        (self.reload as u32 + 1) * DIVIDERS[self.prescaler as usize]
    }

    /// The time from a feed to the reset when the LSI runs at `lsi_hz`, µs (rounded down).
    pub const fn us_at(self, lsi_hz: u32) -> u32 {
        (self.lsi_cycles() as u64 * 1_000_000 / lsi_hz as u64) as u32
    }

    /// The `IWDG_PR` value.
    pub const fn prescaler_bits(self) -> u8 {
        self.prescaler
    }

    /// The `IWDG_RLR` value.
    pub const fn reload_bits(self) -> u16 {
        self.reload
    }
}

/// Timeout of a watchdog fed by a board's 1 Hz task, ms at the typical LSI.
pub const HEARTBEAT_FED_MS: u32 = 2_000;
/// [`HEARTBEAT_FED_MS`] at the typical LSI: 1.36 s at the fastest, still above the 1 s feeding
/// period; 3.76 s at the slowest.
pub const HEARTBEAT_FED: Timeout = Timeout::within_ms(HEARTBEAT_FED_MS, LSI_HZ_TYPICAL);

/// Timeout while a parameter save erases and programs a flash sector, ms at the typical LSI.
/// The core stalls for the whole erase (2 s at most for a 128 KiB sector at x32, DS8626 /
/// DS8597), so no task feeds the watchdog meanwhile; 6 s at the LSI's nominal 32 kHz is 4 s at
/// its fastest 47 kHz, still twice the erase. Each board saves only on the ground (the
/// autopilot with its motors off; it passes a save on to the camera board only then) and gives
/// its own timeout back after the save (`param_flash::WatchedSector`).
pub const SAVE_MS: u32 = 6_000;
/// [`SAVE_MS`] at the typical LSI.
pub const SAVE: Timeout = Timeout::within_ms(SAVE_MS, LSI_HZ_TYPICAL);

/// When a task last ran, on the board's clock (kept as 32-bit wrapping microseconds: only ages
/// much shorter than 2^31 µs are compared). Written by the task, read by the watchdog's feeder
/// at any priority.
#[derive(Debug)]
pub struct Liveness {
    last_us: AtomicU32,
}

impl Liveness {
    /// A task seen at boot: call [`Liveness::ran`] when the firmware starts the watchdog.
    pub const fn new() -> Self {
        Self {
            last_us: AtomicU32::new(0),
        }
    }

    /// The task ran at `now`.
    pub fn ran(&self, now: Instant) {
        self.last_us
            .store(now.as_micros() as u32, Ordering::Relaxed);
    }

    /// Whether the task ran within `window` before `now` (a stamp after `now`, from a task that
    /// ran since the caller read its clock, counts as recent). `window` is, as the ages, much
    /// shorter than 2^31 µs.
    pub fn within(&self, now: Instant, window: Duration) -> bool {
        let last = self.last_us.load(Ordering::Relaxed);
        let age = (now.as_micros() as u32).wrapping_sub(last) as i32;
        age <= window.as_micros() as u32 as i32
    }
}

impl Default for Liveness {
    fn default() -> Self {
        Self::new()
    }
}

/// Programs `timeout` into the watchdog, starts it if it was not running and feeds it once
/// the new values are in use (RM0090 21.3.2: `IWDG_PR` and `IWDG_RLR` reach the watchdog's
/// LSI domain some cycles after the write, `IWDG_SR` tells when).
#[cfg(target_os = "none")]
pub fn set(w: &mut stm32f4xx_hal::watchdog::IndependentWatchdog, timeout: Timeout) {
    // SAFETY: the watchdog's registers are `w`'s (borrowed mutably here).
    let iwdg = unsafe { &*stm32f4xx_hal::pac::IWDG::ptr() };
    let updating = || iwdg.sr().read().bits() & 0b11 != 0;
    while updating() {}
    // SAFETY: 0x5555 is the key that unlocks IWDG_PR and IWDG_RLR.
    iwdg.kr().write(|k| unsafe { k.key().bits(0x5555) });
    // SAFETY: a prescaler index of `Timeout` is 0..=6, each a divider of IWDG_PR.
    iwdg.pr()
        .write(|p| unsafe { p.pr().bits(timeout.prescaler) });
    iwdg.rlr().write(|r| r.rl().set(timeout.reload));
    // SAFETY: 0xCCCC is the start key (it changes nothing on a running watchdog).
    iwdg.kr().write(|k| unsafe { k.key().bits(0xCCCC) });
    while updating() {}
    w.feed();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_timeout_within_a_bound_at_the_slowest_lsi_keeps_it_there_and_shrinks_at_the_fastest() {
        let t = Timeout::within_ms(25, LSI_HZ_SLOWEST);
        // 425 cycles at 17 kHz: /4, 106 counts (424 cycles).
        assert_eq!((t.prescaler_bits(), t.reload_bits()), (0, 105));
        assert_eq!(t.us_at(LSI_HZ_SLOWEST), 24_941);
        assert_eq!(t.us_at(LSI_HZ_TYPICAL), 13_250);
        assert_eq!(t.us_at(LSI_HZ_FASTEST), 9_021);
    }

    #[test]
    fn every_bound_is_met_and_nearly_reached() {
        for lsi in [LSI_HZ_SLOWEST, LSI_HZ_TYPICAL, LSI_HZ_FASTEST] {
            for ms in [1, 2, 10, 25, 50, 100, 1_000, 2_000, 6_000, 20_000] {
                let t = Timeout::within_ms(ms, lsi);
                let us = t.us_at(lsi);
                assert!(us <= ms * 1_000, "{ms} ms at {lsi} Hz: {us} us");
                // At most one prescaled cycle short (and the divider is the finest that fits).
                let cycle_us = 1_000_000 * DIVIDERS[t.prescaler as usize] / lsi;
                assert!(us + cycle_us >= ms * 1_000, "{ms} ms at {lsi} Hz: {us} us");
                if t.prescaler > 0 {
                    let finer = DIVIDERS[t.prescaler as usize - 1];
                    assert!(u64::from(ms) * u64::from(lsi) / 1_000 / u64::from(finer) > 4_096);
                }
            }
        }
    }

    #[test]
    fn the_typical_lsi_gives_the_hals_two_seconds() {
        // 64,000 cycles: /16, 4,000 counts.
        let t = Timeout::within_ms(2_000, LSI_HZ_TYPICAL);
        assert_eq!((t.prescaler_bits(), t.reload_bits()), (2, 3_999));
        assert_eq!(t.us_at(LSI_HZ_TYPICAL), 2_000_000);
    }

    #[test]
    fn the_heartbeat_and_save_timeouts_outlast_their_feeding_and_the_erase_at_every_lsi() {
        // The HAL's 2 s and 6 s at 32 kHz (its prescaler /256, reloads 249 and 749): the same
        // LSI cycles.
        assert_eq!(HEARTBEAT_FED.lsi_cycles(), 250 * 256);
        assert_eq!(SAVE.lsi_cycles(), 750 * 256);
        assert!(HEARTBEAT_FED.us_at(LSI_HZ_FASTEST) > 1_000_000);
        assert!(SAVE.us_at(LSI_HZ_FASTEST) >= 2 * 2_000_000);
    }

    #[test]
    fn out_of_range_bounds_are_clamped() {
        let long = Timeout::within_ms(60_000, LSI_HZ_FASTEST);
        assert_eq!((long.prescaler_bits(), long.reload_bits()), (6, 4_095));
        let short = Timeout::within_ms(0, LSI_HZ_SLOWEST);
        assert_eq!(short.lsi_cycles(), 4);
    }

    #[test]
    fn liveness_ages_across_the_wrap_of_its_stamp() {
        let at = Instant::from_micros;
        let window = Duration::from_millis(25);
        let task = Liveness::new();
        task.ran(at(1_000));
        assert!(task.within(at(26_000), window));
        assert!(!task.within(at(26_001), window));
        // Stamped after the reader's clock: recent.
        assert!(task.within(at(900), window));
        // Across the 32-bit wrap of the microsecond stamp.
        let before_wrap = (1u64 << 32) - 10_000;
        task.ran(at(before_wrap));
        assert!(task.within(at(before_wrap + 20_000), window));
        assert!(!task.within(at(before_wrap + 30_000), window));
    }
}
