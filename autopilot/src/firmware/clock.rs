//! The board's clocks: its microsecond clock (the RTIC SysTick monotonic refined with the
//! SysTick down-counter, shared with the other board in `board_support::clock`) and the time
//! the library sees.

use super::{board, Mono};
use rtic_monotonics::Timebase as _;

/// Microseconds since boot (see [`board_support::clock::now_us`]).
pub fn now_us() -> u64 {
    board_support::clock::now_us(|| Mono::now().as_ticks(), board::SYSTICK_HZ)
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
