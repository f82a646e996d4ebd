//! The firmware shell pieces the camera board and the autopilot share (an STM32F407 and an
//! STM32F415, the same clock tree from a 12 MHz crystal, the same QEMU flavour).
//!
//! * [`link`]: the board-to-board link's baud rate, one constant both boards use (host too).
//! * [`pins`]: the wiring tables' vocabulary (port, pin, function, pull, output stage), one for
//!   both boards' tables (host too).
//! * `clocks`: clock tree and link constants per flavour (MCU only).
//! * [`clock`]: the board's microsecond clock from the RTIC SysTick monotonic (MCU only), and
//!   the extender that carries its 32-bit millisecond tick on across the wrap.
//! * `uart_dma`: UART receive by circular DMA with the IDLE-line interrupt, for the `hil`
//!   flavour's 921,600 Bd host links (MCU only).
//! * `uart_rx`: UART receive by the RXNE interrupt into a queue, with back-pressure (MCU only).
//! * `uart_link`: one UART link as one bundle: its queues and the decoding task's wake-up,
//!   split into the tasks', the interrupt's and the decoding task's ends (MCU only).
//! * `uart_tx`: UART transmit from an interrupt-driven queue; never blocks, never panics, a
//!   full queue drops the frame and counts it (MCU only).
//! * `flavour`: the `real`, `hil` and `qemu` flavours: the contract each board's flavour module
//!   fulfils, and what differs between them for both boards alike (MCU only).
//! * `fault`: panic and HardFault handlers: actuators off first, then log, then the
//!   watchdog; the reset cause at boot (MCU only).
//! * `log`: `info!` (defmt, plus semihosting in the `qemu` flavour), `fatal`, the QEMU panic
//!   handler (MCU only).
//! * `param_flash`: the two parameter slots (flash sectors 11 and 10), erased and programmed
//!   through the flash interface; the `protocol::params::RecordStore` of both boards, and the
//!   one way both save under the watchdog (MCU only).
//! * `stack`: stack painting and the low-water headroom of the main stack (MCU only).
//! * [`build`]: the linker set-up both firmwares' `build.rs` run (host, build scripts).
//! * [`watchdog`]: the independent watchdog's timeout across the LSI's spread, the boards'
//!   timeouts, and the task liveness stamps its feeder checks (programming it: MCU only).
//!
//! Each board keeps what is its own: pin map, crystal, drivers, the RTIC app.
#![cfg_attr(target_os = "none", no_std)]
#![warn(missing_docs)]

#[cfg(not(target_os = "none"))]
pub mod build;
pub mod chip;
pub mod clock;
#[cfg(target_os = "none")]
pub mod clocks;
#[cfg(target_os = "none")]
pub mod fault;
#[cfg(target_os = "none")]
pub mod flavour;
pub mod link;
#[cfg(target_os = "none")]
pub mod log;
#[cfg(target_os = "none")]
pub mod param_flash;
pub mod pins;
#[cfg(target_os = "none")]
pub mod stack;
#[cfg(target_os = "none")]
pub mod uart_dma;
#[cfg(target_os = "none")]
pub mod uart_link;
#[cfg(target_os = "none")]
pub mod uart_rx;
#[cfg(target_os = "none")]
pub mod uart_tx;
pub mod watchdog;
