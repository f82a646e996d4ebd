//! The firmware flavours both boards build in, and the contract each board's flavour module
//! fulfils (MCU only).
//!
//! | flavour | feature | the board's sensors | time the library sees | host link | parameter flash |
//! |---|---|---|---|---|---|
//! | `real` | none | its own | the board clock | the autopilot's telemetry port; none on the camera board | yes |
//! | `hil` | `hil` | the host's simulated world sends what they would | the world's | [`crate::link::HOST_BAUD`], received by DMA ([`crate::uart_dma`]) | yes |
//! | `qemu` | `qemu` | the same | the world's | [`crate::link::HOST_BAUD`], received by RXNE | none (QEMU models no flash interface) |
//!
//! `hil` and `qemu` are the lockstep flavours: the board runs in step with a host's world
//! simulation. Each board's firmware keeps what differs between flavours in one module per
//! kind, `real.rs` and `lockstep.rs`, selected as `flavour` by one `cfg` (the pattern of
//! embassy's chip-family modules), and each such module has a type implementing [`Flavour`]
//! beside the items only its board has. What differs for both boards alike is here: whether
//! there is a parameter flash ([`PARAM_STORAGE`]) and how a host link receives ([`HostRx`],
//! [`host_receiver`]).

use crate::uart_dma::RxStream;
use crate::watchdog::Timeout;
use stm32f4xx_hal::serial;

/// What each board's flavour module provides (its type `Current`), the same in both boards.
pub trait Flavour {
    /// Whether the board reads its own sensors (the camera board its cameras; the autopilot its
    /// IMU, barometer, supply voltage and RC receiver). `false`: the host's simulated world
    /// sends what they would, over the host link.
    const OWN_SENSORS: bool;
    /// The board's independent-watchdog timeout in this flavour (the boards' timeouts side by
    /// side: [`crate::watchdog`]).
    const WATCHDOG: Timeout;
    /// The time the board's flight library sees: the board clock, or in the lockstep flavours
    /// the world time of the host's simulation (as the host's messages carry it) as the flight
    /// clock.
    fn lib_now() -> timebase::Instant;
}

/// Whether the board has its parameter flash ([`crate::param_flash`]): every flavour but
/// `qemu`, whose machine models no flash interface.
pub const PARAM_STORAGE: bool = !cfg!(feature = "qemu");

/// A host link's receiver: its RXNE interrupt, or in the `hil` flavour a circular DMA
/// (921,600 Bd: a byte lasts less than logging holds the interrupts off, see
/// [`crate::uart_dma`]).
#[cfg(not(all(feature = "hil", not(feature = "qemu"))))]
pub type HostRx<U> = serial::Rx<U>;
/// A host link's receiver (see the other flavours').
#[cfg(all(feature = "hil", not(feature = "qemu")))]
pub type HostRx<U> = crate::uart_dma::DmaRx<U>;

/// Takes over a host link's receive side, `rx` of a configured USART: its RXNE interrupt on
/// (`dma` is the `hil` flavour's).
#[cfg(not(all(feature = "hil", not(feature = "qemu"))))]
pub fn host_receiver<U>(mut rx: serial::Rx<U>, dma: RxStream) -> HostRx<U>
where
    U: serial::Instance + stm32f4xx_hal::Ptr<RB = stm32f4xx_hal::pac::usart1::RegisterBlock>,
{
    use stm32f4xx_hal::serial::RxListen as _;
    let _ = dma;
    rx.listen();
    rx
}

/// Takes over a host link's receive side, `rx` of a configured USART (consumed): circular DMA
/// on `dma`, the stream and channel that serve its receive requests, into a buffer in SRAM.
/// A firmware has one host link: a second call is fatal.
#[cfg(all(feature = "hil", not(feature = "qemu")))]
pub fn host_receiver<U>(rx: serial::Rx<U>, dma: RxStream) -> HostRx<U>
where
    U: serial::Instance + stm32f4xx_hal::Ptr<RB = stm32f4xx_hal::pac::usart1::RegisterBlock>,
{
    let buf = cortex_m::singleton!(: [u8; 1024] = [0; 1024])
        .unwrap_or_else(|| crate::log::fatal("the host link's DMA buffer is taken once"));
    drop(rx);
    // SAFETY: the USART's receive side is handed over here (its HAL `Rx` is consumed); `dma`
    // serves only it (the board's definition); the buffer is a static in SRAM, which both DMA
    // controllers reach.
    unsafe { crate::uart_dma::DmaRx::start(dma, buf) }
}
