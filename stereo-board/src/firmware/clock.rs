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

/// World time of the lockstep flavours, µs, and the extender of the autopilot's `u32` gyro
/// timestamps onto it.
#[cfg(any(feature = "qemu", feature = "hil"))]
static WORLD: cortex_m::interrupt::Mutex<
    core::cell::RefCell<(u64, stereo_board::app::ClockExtender)>,
> = cortex_m::interrupt::Mutex::new(core::cell::RefCell::new((
    0,
    stereo_board::app::ClockExtender::new(),
)));

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
pub fn observe_world_gyro(t: u32) {
    cortex_m::interrupt::free(|cs| {
        let mut w = WORLD.borrow(cs).borrow_mut();
        let t = w.1.extend(t);
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
