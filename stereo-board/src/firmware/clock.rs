//! The board's microsecond clock: the RTIC SysTick monotonic refined with the SysTick
//! down-counter (shared with the other board in `board_support::clock`). The time the library
//! sees is the flavour's (`board_support::flavour::Flavour::lib_now`).

use super::{board, Mono};
use rtic_monotonics::Timebase as _;
use timebase::Instant;

/// The board clock (see [`board_support::clock::now`]).
pub fn now() -> Instant {
    board_support::clock::now(|| Mono::now().as_ticks(), board::SYSTICK_HZ)
}
