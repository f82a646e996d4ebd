//! Pin map and clock tree of the camera board, per flavour.
//!
//! | function | peripheral | pins |
//! |---|---|---|
//! | link to the autopilot (protocol, 921,600 Bd 8N1) | USART1 | PA9 TX, PA10 RX |
//! | HIL / host link (frames in, estimates out) | USART2 | PA2 TX, PA3 RX |
//! | status LED (active high) | GPIO | PC13 |
//!
//! Wiring between the boards: camera PA9 (TX) -> autopilot RX, camera PA10 (RX) <- autopilot
//! TX, common ground. In QEMU (`-M netduinoplus2`) USART1 is the first `-serial` and USART2 the
//! second.

use stm32f4xx_hal::rcc::Config;

pub use board_support::clocks::{LINK_BAUD, SYSTICK_HZ, WATCHDOG_MS};

/// Crystal of the camera board, Hz.
pub const HSE_HZ: u32 = 12_000_000;

/// Clock configuration of this flavour (HSE + PLL to 168 MHz; the HSI in QEMU).
pub fn clocks() -> Config {
    board_support::clocks::config(HSE_HZ)
}
