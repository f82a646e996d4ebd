//! The firmware side of the board definition ([`stereo_board::board`], which holds every pin,
//! peripheral, clock and rate): the clock configuration, and the link UART, which QEMU's machine
//! has elsewhere.

use board_support::log;
use stm32f4xx_hal::gpio::{PA0, PA1, PA10, PA9};
use stm32f4xx_hal::pac;
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::rcc::{Config, Rcc};
use stm32f4xx_hal::serial::{self, Serial};

pub use board_support::clocks::SYSTICK_HZ;

/// Clock configuration of this flavour (the board's 12 MHz crystal and PLL to 168 MHz; the HSI
/// in QEMU).
pub fn clocks() -> Config {
    board_support::clocks::config(stereo_board::board::HSE_HZ)
}

/// The link UART: UART4 on the camera board ([`stereo_board::board::LINK_UART`]).
#[cfg(not(feature = "qemu"))]
pub type LinkUart = pac::UART4;
/// The link UART: USART1 on QEMU's netduinoplus2 (its first `-serial` port).
#[cfg(feature = "qemu")]
pub type LinkUart = pac::USART1;
/// The link UART's interrupt.
#[cfg(not(feature = "qemu"))]
pub const LINK_IRQ: pac::Interrupt = pac::Interrupt::UART4;
/// The link UART's interrupt (QEMU).
#[cfg(feature = "qemu")]
pub const LINK_IRQ: pac::Interrupt = pac::Interrupt::USART1;

/// The link UART at [`stereo_board::board::LINK_BAUD`]: UART4 on PA0/PA1 (the first pair);
/// USART1 on PA9/PA10 (the second) is left at reset.
#[cfg(not(feature = "qemu"))]
pub fn link_serial(
    (uart4, pins): (pac::UART4, (PA0, PA1)),
    _qemu: (pac::USART1, (PA9, PA10)),
    rcc: &mut Rcc,
) -> Serial<LinkUart> {
    uart4
        .serial::<u8>(pins, link_config(), rcc)
        .unwrap_or_else(|_| log::fatal("UART4 configuration"))
}

/// The link UART at [`stereo_board::board::LINK_BAUD`] in QEMU: USART1 on PA9/PA10 (the second
/// pair); UART4 on PA0/PA1 (the first) is left at reset.
#[cfg(feature = "qemu")]
pub fn link_serial(
    _board: (pac::UART4, (PA0, PA1)),
    (usart1, pins): (pac::USART1, (PA9, PA10)),
    rcc: &mut Rcc,
) -> Serial<LinkUart> {
    usart1
        .serial::<u8>(pins, link_config(), rcc)
        .unwrap_or_else(|_| log::fatal("USART1 configuration"))
}

/// The link's line settings: 8N1 at the baud rate both boards share.
fn link_config() -> serial::Config {
    serial::Config::default().baudrate(stereo_board::board::LINK_BAUD.bps())
}
