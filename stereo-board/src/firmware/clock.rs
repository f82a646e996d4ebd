//! The board's clocks: its microsecond clock (the RTIC SysTick monotonic refined with the
//! SysTick down-counter, shared with the other board in `board_support::clock`) and the time
//! the library sees.

use super::{board, Mono};
use rtic_monotonics::Timebase as _;

/// Microseconds since boot (see [`board_support::clock::now_us`]).
pub fn now_us() -> u64 {
    board_support::clock::now_us(|| Mono::now().as_ticks(), board::SYSTICK_HZ)
}

/// World time of the lockstep flavours, µs, and the extender of the autopilot's `u32` gyro
/// timestamps onto it.
#[cfg(any(feature = "qemu", feature = "hil"))]
static WORLD: cortex_m::interrupt::Mutex<
    core::cell::RefCell<(u64, timebase::WrapExtender<timebase::WorldTime>)>,
> = cortex_m::interrupt::Mutex::new(core::cell::RefCell::new((0, timebase::WrapExtender::new())));

/// A world time seen on a link (a frame's exposure time, µs): the world clock moves forward
/// to it (never back).
#[cfg(any(feature = "qemu", feature = "hil"))]
pub fn observe_world_us(t: u64) {
    cortex_m::interrupt::free(|cs| {
        let mut w = WORLD.borrow(cs).borrow_mut();
        w.0 = w.0.max(t);
    });
}

/// A gyro timestamp from the autopilot (its world time, wrapping `u32` µs).
#[cfg(any(feature = "qemu", feature = "hil"))]
pub fn observe_world_gyro(t: timebase::WireTime) {
    cortex_m::interrupt::free(|cs| {
        let mut w = WORLD.borrow(cs).borrow_mut();
        let t: u64 = w.1.extend(t).as_micros();
        w.0 = w.0.max(t);
    });
}

/// The time the Edge-FS library sees, µs: the board clock on hardware; in the lockstep
/// flavours (`hil`, `qemu`) the world time of the host's simulation, as carried by the frames'
/// exposure times and the autopilot's gyro timestamps (the autopilot runs on world time too).
pub fn lib_now_us() -> u64 {
    #[cfg(any(feature = "qemu", feature = "hil"))]
    {
        cortex_m::interrupt::free(|cs| WORLD.borrow(cs).borrow().0)
    }
    #[cfg(not(any(feature = "qemu", feature = "hil")))]
    {
        now_us()
    }
}
