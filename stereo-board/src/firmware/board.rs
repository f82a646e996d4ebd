//! The firmware side of the board definition ([`stereo_board::board`], which holds every pin,
//! peripheral, clock and rate): the clock configuration of each flavour and the constants the
//! firmware shell shares with the other board.

use stm32f4xx_hal::rcc::Config;

/// Baud rate of the host link (USART2, `hil` and `qemu` flavours).
#[cfg(any(feature = "qemu", feature = "hil"))]
pub use board_support::clocks::HOST_BAUD;
pub use board_support::clocks::{SYSTICK_HZ, WATCHDOG_MS};

/// Clock configuration of this flavour (the board's 12 MHz crystal and PLL to 168 MHz; the HSI
/// in QEMU).
pub fn clocks() -> Config {
    board_support::clocks::config(stereo_board::board::HSE_HZ)
}
