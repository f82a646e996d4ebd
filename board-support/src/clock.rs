//! The board's microsecond clock: the RTIC SysTick monotonic (1 kHz ticks) refined with the
//! SysTick down-counter, so timestamps have core-clock resolution without another timer
//! (QEMU emulates SysTick faithfully, unlike the DWT cycle counter).
//!
//! The monotonic counts milliseconds in a `u32`, which wraps after 2^32 ms (49.7 days of
//! uptime); [`TickExtender`] carries the count on in 64 bits, so the instants the flight
//! libraries are handed never go back and an input's age stays its age across the wrap.

/// Extends a wrapping 32-bit tick count onto 64 bits: a count below the previous one is a wrap.
/// It must see the count at least once per wrap period (49.7 days at 1 kHz; the boards read
/// their clock hundreds of times a second).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TickExtender {
    last: u32,
    wraps: u32,
}

impl TickExtender {
    /// An extender that has seen no count (the first one maps to itself).
    pub const fn new() -> Self {
        Self { last: 0, wraps: 0 }
    }

    /// `ticks` on the 64-bit count.
    pub fn extend(&mut self, ticks: u32) -> u64 {
        if ticks < self.last {
            self.wraps = self.wraps.wrapping_add(1);
        }
        self.last = ticks;
        (u64::from(self.wraps) << 32) | u64::from(ticks)
    }
}

/// The extender of the board's millisecond tick (one clock per board).
#[cfg(target_os = "none")]
static MS_EXTENDER: cortex_m::interrupt::Mutex<core::cell::Cell<TickExtender>> =
    cortex_m::interrupt::Mutex::new(core::cell::Cell::new(TickExtender::new()));

/// The board clock: the time since boot to the microsecond (it does not wrap). `ms_ticks` reads
/// the 1 kHz monotonic's tick count (RTIC's `systick_monotonic!` type is generated in each
/// firmware); `systick_hz` is its input clock. Runs with interrupts masked for a few dozen
/// cycles, so that callers at every priority extend the tick count in the order they read it.
///
/// The tick count never lags the SysTick counter read after it, even while the SysTick
/// interrupt is pending (masked here, or below the caller's priority): the monotonic's `now()`
/// counts a wrap itself from the counter's COUNTFLAG before its interrupt runs. A wrap between
/// the two reads changes the count, and the pair is read again. (Adding a millisecond for a
/// pending SysTick as well counted such a wrap twice: a clock 1 ms ahead until the interrupt
/// ran, seen as a 1 ms jump in the 512 Hz loop's period.)
#[cfg(target_os = "none")]
pub fn now(ms_ticks: impl Fn() -> u32, systick_hz: u32) -> timebase::Instant {
    use cortex_m::peripheral::SYST;
    let ticks_per_ms = (systick_hz / 1_000).max(1);
    cortex_m::interrupt::free(|cs| loop {
        let ms = ms_ticks();
        let val = SYST::get_current();
        if ms_ticks() != ms {
            continue;
        }
        let into_tick = (ticks_per_ms - 1).saturating_sub(val);
        let sub_us = u64::from(into_tick) * 1_000 / u64::from(ticks_per_ms);
        let cell = MS_EXTENDER.borrow(cs);
        let mut extender = cell.get();
        let ms = extender.extend(ms);
        cell.set(extender);
        return timebase::Instant::from_micros(ms * 1_000 + sub_us);
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tick_count_carries_on_across_its_wrap() {
        let mut x = TickExtender::new();
        // Started just before the wrap, read every millisecond or so across it, twice.
        let start = u32::MAX - 5;
        let mut previous = x.extend(start);
        assert_eq!(previous, u64::from(start));
        let mut ticks = start;
        for step in [1u32, 2, 1, 3, 1, 1].iter().cycle().take(20) {
            ticks = ticks.wrapping_add(*step);
            let t = x.extend(ticks);
            assert_eq!(t - previous, u64::from(*step), "{ticks}");
            previous = t;
        }
        assert_eq!(previous, (1 << 32) + u64::from(ticks));
        // A second wrap, after 2^32 ms more, read at least once on the way.
        x.extend(u32::MAX / 2);
        assert_eq!(x.extend(3), (2 << 32) + 3);
        // The same count twice is no wrap.
        assert_eq!(x.extend(3), (2 << 32) + 3);
    }

    #[test]
    fn an_age_across_the_wrap_is_the_time_elapsed() {
        // An input stamped 40 ms before the wrap, read 60 ms after it: 100 ms old, not fresh
        // (a `saturating_sub` of the raw counts would make it 0 ms old).
        let mut x = TickExtender::new();
        let stamped = x.extend(u32::MAX - 39);
        let now = x.extend(60);
        assert_eq!(now - stamped, 100);
        assert_eq!(60u32.saturating_sub(u32::MAX - 39), 0);
    }
}
