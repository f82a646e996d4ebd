//! The firmware side of the board definition ([`stereo_board::board`], which holds every pin,
//! peripheral, clock and rate): the clock configuration of each flavour and the constants the
//! firmware shell shares with the other board.

use stm32f4xx_hal::rcc::Config;

/// Baud rate of the host link (USART2, `hil` and `qemu` flavours).
#[cfg(any(feature = "qemu", feature = "hil"))]
pub use board_support::clocks::HOST_BAUD;
pub use board_support::clocks::SYSTICK_HZ;

/// Clock configuration of this flavour (the board's 12 MHz crystal and PLL to 168 MHz; the HSI
/// in QEMU).
pub fn clocks() -> Config {
    board_support::clocks::config(stereo_board::board::HSE_HZ)
}

/// The DMA stream that takes the host link's received bytes in the `hil` flavour (921,600 Bd;
/// see `board_support::uart_dma`): USART2_RX is DMA1 stream 5, channel 4 (RM0090 table 42).
#[cfg(all(feature = "hil", not(feature = "qemu")))]
pub const HOST_RX_DMA: board_support::uart_dma::RxStream = board_support::uart_dma::RxStream {
    controller: board_support::uart_dma::Controller::Dma1,
    stream: 5,
    channel: 4,
};
