//! The board's microsecond clock: the RTIC SysTick monotonic (1 kHz ticks) refined with the
//! SysTick down-counter, so timestamps have core-clock resolution without another timer
//! (QEMU emulates SysTick faithfully, unlike the DWT cycle counter).

use super::{board, Mono};
use cortex_m::peripheral::{SCB, SYST};
use rtic_monotonics::Timebase as _;

/// Microseconds since boot (wraps after 49 days with the 32-bit millisecond tick).
pub fn now_us() -> u64 {
    let ticks_per_ms = board::SYSTICK_HZ / 1_000;
    loop {
        let ms = Mono::now().as_ticks();
        let val = SYST::get_current();
        // A SysTick wrap whose interrupt has not run yet (we may be above its priority).
        let pending = SCB::is_pendst_pending();
        if Mono::now().as_ticks() != ms {
            continue;
        }
        let into_tick = (ticks_per_ms - 1).saturating_sub(val);
        let sub_us = u64::from(into_tick) * 1_000 / u64::from(ticks_per_ms);
        let ms = u64::from(ms) + u64::from(pending && val > ticks_per_ms / 2);
        return ms * 1_000 + sub_us;
    }
}

/// World time of the lockstep flavours, µs (set by the host link's IMU samples).
#[cfg(any(feature = "qemu", feature = "hil"))]
static WORLD_US: cortex_m::interrupt::Mutex<core::cell::Cell<u64>> =
    cortex_m::interrupt::Mutex::new(core::cell::Cell::new(0));

/// Sets the world time (lockstep flavours; see [`autopilot::lockstep`]).
#[cfg(any(feature = "qemu", feature = "hil"))]
pub fn set_world_us(t: u64) {
    cortex_m::interrupt::free(|cs| WORLD_US.borrow(cs).set(t));
}

/// The time the flight library sees, µs: the board clock on hardware, the host's world time
/// in the lockstep flavours (`hil`, `qemu`).
pub fn lib_now_us() -> u64 {
    #[cfg(any(feature = "qemu", feature = "hil"))]
    {
        cortex_m::interrupt::free(|cs| WORLD_US.borrow(cs).get())
    }
    #[cfg(not(any(feature = "qemu", feature = "hil")))]
    {
        now_us()
    }
}
