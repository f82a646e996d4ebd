//! The board's microsecond clock: the RTIC SysTick monotonic refined with the SysTick
//! down-counter (shared with the other board in `board_support::clock`). The time the library
//! sees is the flavour's (`board_support::flavour::Flavour::lib_now_us`).

use super::Mono;
use rtic_monotonics::Timebase as _;
use timebase::Instant;

/// The board clock (see [`board_support::clock::now_us`]).
pub fn now() -> Instant {
    Instant::from_micros(board_support::clock::now_us(
        || Mono::now().as_ticks(),
        board_support::clocks::SYSTICK_HZ,
    ))
}
