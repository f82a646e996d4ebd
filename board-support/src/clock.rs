//! The board's microsecond clock: the RTIC SysTick monotonic (1 kHz ticks) refined with the
//! SysTick down-counter, so timestamps have core-clock resolution without another timer
//! (QEMU emulates SysTick faithfully, unlike the DWT cycle counter).

use cortex_m::peripheral::{SCB, SYST};

/// Microseconds since boot. `ms_ticks` reads the 1 kHz monotonic's tick count (RTIC's
/// `systick_monotonic!` type is generated in each firmware); `systick_hz` is its input clock.
/// Wraps after 49 days with a 32-bit millisecond tick.
pub fn now_us(ms_ticks: impl Fn() -> u32, systick_hz: u32) -> u64 {
    let ticks_per_ms = (systick_hz / 1_000).max(1);
    loop {
        let ms = ms_ticks();
        let val = SYST::get_current();
        // A SysTick wrap whose interrupt has not run yet (we may be above its priority).
        let pending = SCB::is_pendst_pending();
        if ms_ticks() != ms {
            continue;
        }
        let into_tick = (ticks_per_ms - 1).saturating_sub(val);
        let sub_us = u64::from(into_tick) * 1_000 / u64::from(ticks_per_ms);
        let ms = u64::from(ms) + u64::from(pending && val > ticks_per_ms / 2);
        return ms * 1_000 + sub_us;
    }
}
