//! The firmware side of the board definition ([`stereo_board::board`], which holds every pin,
//! peripheral, clock and rate): the clock configuration, the UARTs the link can run on (the
//! flavour picks one, `flavour::LinkUart`: QEMU's machine has it elsewhere) and the host link's
//! receive DMA stream.

use board_support::log;
use board_support::uart_dma::{Controller, RxStream};
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

/// The candidates for the link UART, each with its pins: the board's UART4 on PA0/PA1
/// ([`stereo_board::board::LINK_UART`]) and USART1 on PA9/PA10, QEMU's netduinoplus2's first
/// `-serial` port. The flavour's link UART takes its own; the other is left at reset.
pub type LinkCandidates = ((pac::UART4, (PA0, PA1)), (pac::USART1, (PA9, PA10)));

/// A UART the link can run on.
pub trait LinkPort: serial::Instance + Sized {
    /// Its interrupt.
    const IRQ: pac::Interrupt;
    /// Configures it at [`stereo_board::board::LINK_BAUD`], taken from `candidates`.
    fn open(candidates: LinkCandidates, rcc: &mut Rcc) -> Serial<Self>;
}

impl LinkPort for pac::UART4 {
    const IRQ: pac::Interrupt = pac::Interrupt::UART4;
    fn open(((uart4, pins), _): LinkCandidates, rcc: &mut Rcc) -> Serial<Self> {
        uart4
            .serial::<u8>(pins, link_config(), rcc)
            .unwrap_or_else(|_| log::fatal("UART4 configuration"))
    }
}

impl LinkPort for pac::USART1 {
    const IRQ: pac::Interrupt = pac::Interrupt::USART1;
    fn open((_, (usart1, pins)): LinkCandidates, rcc: &mut Rcc) -> Serial<Self> {
        usart1
            .serial::<u8>(pins, link_config(), rcc)
            .unwrap_or_else(|_| log::fatal("USART1 configuration"))
    }
}

/// The link's line settings: 8N1 at the baud rate both boards share.
fn link_config() -> serial::Config {
    serial::Config::default().baudrate(stereo_board::board::LINK_BAUD.bps())
}

/// The DMA stream that takes the host link's received bytes in the `hil` flavour (921,600 Bd;
/// see `board_support::uart_dma`): USART2_RX is DMA1 stream 5, channel 4 (RM0090 table 42).
pub const HOST_RX_DMA: RxStream = RxStream {
    controller: Controller::Dma1,
    stream: 5,
    channel: 4,
};
