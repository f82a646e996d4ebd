//! Logging and fatal-stop helpers: defmt over RTT always; in the `qemu` flavour the same lines
//! also go to the host's stdout through semihosting, and [`fatal`] ends QEMU with a failing
//! exit code (a panic does too: [`crate::fault`]).

/// Logs an info line (defmt over RTT; semihosting too in the `qemu` flavour).
///
/// The arguments must be valid for both `defmt` and `core::fmt` (plain `{}` placeholders). The
/// `qemu` check is made in the calling crate (each firmware has a `qemu` feature that enables
/// this crate's), which must depend on `defmt` and `cortex-m-semihosting`.
#[doc(hidden)]
#[macro_export]
macro_rules! __board_support_info {
    ($($arg:tt)*) => {{
        defmt::info!($($arg)*);
        #[cfg(feature = "qemu")]
        cortex_m_semihosting::hprintln!($($arg)*);
    }};
}
pub use crate::__board_support_info as info;

/// Stops the firmware after an unrecoverable set-up error (never called on bad input): logs
/// it, then waits, interrupts off, for the independent watchdog (started here if it was not
/// yet) to reset the board.
pub fn fatal(what: &str) -> ! {
    defmt::error!("fatal: {}", what);
    #[cfg(feature = "qemu")]
    {
        cortex_m_semihosting::hprintln!("fatal: {}", what);
        cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
    }
    crate::fault::reset_by_watchdog()
}

/// Ends a QEMU run successfully (semihosting exit 0).
#[cfg(feature = "qemu")]
pub fn exit_success() -> ! {
    cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::nop();
    }
}
